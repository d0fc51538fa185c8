"""hardware_node end to end over real EtherCAT frames: software slaves on a veth pair
(test/ethercat), hardware_node and controller_node as separate processes."""
import math
import pathlib
import signal
import time

import numpy as np
import pytest
import yaml
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from seaforce_msgs.msg import ActuatorCommand, ActuatorState
from std_srvs.srv import Trigger

from ethercat.emulator.config import default_config
from helpers.commands import command_only
from helpers.nodes import CONFIG, start_node
from helpers.processes import executable
from helpers.states import (by_cycle, counted_past, stamp_ns, torque_off_after_commands_stop,
                            value)
from seaforce_ros.core.analysis import impedance_from_position

BUS = pathlib.Path(__file__).resolve().parent / 'data' / 'bus_emulated.yaml'
RELAXED = {'state_timeout': 0.5}
# The EtherCAT loop at the real rate; the tests whose subject is timing (the 2 kHz direct loop,
# the watchdogs: a pulled cable, a killed controller, a channel's commands that stop) with a
# CPU-burning process per core beside them (the cpu_hog fixture: the other xdist worker
# pauses meanwhile); the others (identity, lifecycle, faults, SIGINT) beside the hogs only
# under scripts/test --cpu-hog (with hogs beside every test the quiet suite spent about 30 s
# more on them). The emulator (SCHED_FIFO 50, test/ethercat/fixtures.py)
# and the plant (40) run at real-time priority, as on a rig (docs/ethercat-hardware.md). Most
# tests run hardware_bringup loop:=direct, the layout for a 2 kHz rig: a separate 2 kHz controller
# process costs about half a core more, and a 2-core host busy with the emulator and the
# hogs does not have it. The tests about the controller process itself (killed, replaced)
# run it separately, at normal priority: how late its commands come does not matter there.
RATE = 2000.0
TIMEOUT = 30.0      # parameter and service calls of the (CPU-starved) test process
# The test watches actuator_state best-effort: a reliable observer in this (busy) test process
# would make the node's reliable writer wait for its acknowledgements.
OBSERVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                         reliability=ReliabilityPolicy.BEST_EFFORT)


def emulator_config():
    config = default_config()
    config['cycle_time'] = 1.0 / RATE   # plant step per process-data frame
    return config


def driven_config(amplitude=0.5, frequency=1.0):
    config = emulator_config()
    config['channels']['pinch']['environment'] = {
        'mode': 'position_sine', 'amplitude': amplitude, 'frequency': frequency}
    return config


def start_hardware(processes, tmp_path, harness, overrides=None, bus=BUS, wait=True):
    # a loaded test host (and the emulator serving its side channel) can delay frames: the
    # tests tolerate 100 ms of working-counter errors (the cable-pull test uses the default
    # 10 cycles) and program a 0.5 s drive watchdog instead of 0.1 s
    # autostart active: these tests are about the running loop (the lifecycle has its own)
    values = {'interface': harness.master_interface, 'bus_config': str(bus),
              'torque_limit': 5.0, 'wkc_error_limit': 200, 'drive_watchdog': 0.5,
              'autostart': 'active', **(overrides or {})}
    # real-time priority, as on a real rig (docs/ethercat-hardware.md): a starved cycle thread
    # lets the drives' watchdogs expire on this shared 2-core host
    return start_node(processes, 'hardware_node', 'hardware', tmp_path,
                      {'rate': RATE, **values}, wait=wait, prefix=('chrt', '-f', '40'))


def start_controller(processes, tmp_path, overrides=None):
    return start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'rate': RATE, **RELAXED, **(overrides or {})})


def start_bringup(processes, tmp_path, harness, overrides=None, bus=BUS):
    """hardware_bringup loop:=direct at SCHED_FIFO 40 (hardware + controller, one process)."""
    values = {'interface': harness.master_interface, 'bus_config': str(bus), 'rate': RATE,
              'torque_limit': 5.0, 'wkc_error_limit': 200, 'drive_watchdog': 0.5,
              'loop': 'direct', 'autostart': 'active', **RELAXED, **(overrides or {})}
    path = tmp_path / 'bringup.yaml'
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': values}}))
    proc = processes.start(['chrt', '-f', '40', str(executable('hardware_bringup')),
                            '--ros-args', '--params-file', str(CONFIG), '--params-file',
                            str(path)], name='hardware_bringup')
    assert proc.wait_for_output('spinning with', timeout=60), proc.output()
    assert 'loop=direct' in proc.output()
    return proc


def pinch(msg, field):
    return value(msg, 'pinch', field)


def measured_impedance_db(client, omega, periods=1.0, settle=1.0):
    """|Z| = |F_e / V_e| of the pinch finger from the emulator's true plant trace."""
    needed = periods * 2 * math.pi / omega + 0.05
    time.sleep(settle)
    # coarse trace: serving a long one stalls the emulator past the drives' 100 ms watchdog
    client.start_trace(decimation=20, max_samples=20000)
    # simulated time advances one 0.5 ms step per process-data frame: wait on the steps
    start = client.channel('pinch')['steps']
    deadline = time.monotonic() + 10 * needed + 30
    while (client.channel('pinch')['steps'] - start) / RATE < needed:
        assert time.monotonic() < deadline, 'the emulated plant stopped advancing'
        time.sleep(0.25)
    trace = client.trace(stop=True)['pinch']
    dt = float(np.median(np.diff(trace['time'])))
    z = impedance_from_position(np.asarray(trace['external_force']),
                                np.asarray(trace['endpoint_position']), omega, dt)
    return 20 * math.log10(abs(z))


def _diag(probe, name, predicate, timeout=10.0):
    msgs = probe.wait_messages('/diagnostics', 1, timeout=timeout, where=lambda d: any(
        s.name == name and predicate(s) for s in d.status))
    return [s for s in msgs[-1].status if s.name == name][0]


def _value(status, key):
    """A /diagnostics status's value of ``key`` ('' when it has none)."""
    return next((kv.value for kv in status.values if kv.key == key), '')


@pytest.mark.usefixtures('cpu_hog')
def test_cable_pull_latches_bus_fault_and_drive_watchdog_drops_torque(
        ecat_emulator, processes, tmp_path, probe):
    harness = ecat_emulator(driven_config(amplitude=0.2))
    # the real settings here: 10 cycles to latch, a 100 ms drive watchdog
    start_bringup(processes, tmp_path, harness, {'wkc_error_limit': 10, 'drive_watchdog': 0.1,
                                                 'pinch.mode': 'hold'})
    probe.record(DiagnosticArray, '/diagnostics')
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    probe.wait_for(lambda: harness.client.torque_applied('pinch_drive'), timeout=30,
                   what='torque applied by the emulated drive')
    harness.client.silent(True)
    status = _diag(probe, 'hardware: bus', lambda s: 'FAULT' in s.message)
    assert '10 consecutive working-counter errors' in status.message, status.message
    # the drive's process-data watchdog (100 ms) removes the torque on its own
    probe.wait_for(lambda: not harness.client.torque_applied('pinch_drive'), timeout=10,
                   what='the emulated drive dropping torque')
    assert any('watchdog' in e['text'].lower() for e in harness.client.events())
    # cable back: the watchdog left the drives in SAFE-OP + ERR 0x001B, so every frame comes
    # back incomplete (no state is published) and /diagnostics names the AL code
    back_ns = time.time_ns()
    harness.client.silent(False)
    status = _diag(probe, 'hardware: bus', lambda s: '0x001B' in _value(s, 'al_status'))
    assert 'sync manager watchdog' in _value(status, 'al_status')
    assert not harness.client.torque_applied('pinch_drive')
    # ~/reset acknowledges the AL errors (SAFE-OP + ERR -> SAFE-OP), brings OP back, resets
    # the drives' fault: torque only once they are in Operation enabled again (the fixture
    # holds the drives' count of frames that carried torque to one that was not)
    harness.client.clear_history()
    assert probe.call(Trigger, '/hardware/reset', timeout=TIMEOUT).success
    probe.wait_for(lambda: {harness.client.cia402_state(d) for d in DRIVES}
                   == {'operation_enabled'}, timeout=15, what='the drives enabled again')
    assert [e['value'] for e in harness.client.al_history()
            if e['slave'] == 'pinch_drive'][:2] == [0x14, 0x08]
    states = probe.wait_messages('actuator_state', 50, where=lambda m: stamp_ns(m) > back_ns
                                 and pinch(m, 'status') == 0)
    assert any(pinch(m, 'motor_effort') != 0.0 for m in states)


@pytest.mark.usefixtures('cpu_hog')
def test_controller_killed_gives_zero_torque(ecat_emulator, processes, tmp_path, probe):
    harness = ecat_emulator(driven_config(amplitude=0.2))
    started_ns = time.time_ns()
    hardware = start_hardware(processes, tmp_path, harness)
    ctrl = start_controller(processes, tmp_path, {'pinch.mode': 'hold'})
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    probe.wait_for(lambda: harness.client.torque_applied('pinch_drive'), timeout=30,
                   what='torque applied by the emulated drive')
    # the probe itself must have seen the driven states (on a starved host its subscription
    # can match after the torque was already on)
    probe.wait_messages('actuator_state', 20, timeout=30,
                        where=lambda m: pinch(m, 'motor_effort') != 0.0)
    killed_ns = time.time_ns()
    ctrl.send_signal(signal.SIGKILL)
    ctrl.wait(timeout=5)
    # by the plant's stamps, not by the last state the probe has seen: a starved probe lags
    # the plant by up to seconds
    after = killed_ns + 50_000_000              # 5x command_timeout past the kill
    probe.wait_messages('actuator_state', 1, timeout=30, where=lambda m: (
        stamp_ns(m) > after and pinch(m, 'status') & ActuatorState.STATUS_COMMAND_TIMEOUT))
    probe.wait_messages('actuator_state', 50, timeout=30, where=lambda m: stamp_ns(m) > after)
    # only this test's hardware node (a sample from an earlier test's node, late in the same
    # DDS domain, would carry an older stamp)
    states = by_cycle(m for m in probe.messages('actuator_state') if stamp_ns(m) > started_ns)
    cycles, flags, efforts, last_driven, first_to = torque_off_after_commands_stop(states,
                                                                                   'pinch')
    # zero torque from the first flagged cycle, within command_timeout (0.01 s) + 1 cycle of
    # the last command that drove the finger, in the plant's cycles. A longer gap has two
    # readings: the probe saw states in it (fresh, zero, unflagged: the controller had zeroed
    # its own output, a starved controller's stale states, with its reason in its log), or it
    # saw none (the best-effort probe missed those cycles -- a CI run's last driven state was
    # stamped over 50 ms before the kill -- and the gap says nothing; the check below of every
    # state 5x command_timeout past the kill still holds it)
    gap = cycles[first_to] - cycles[last_driven]
    if gap > 0.01 * RATE + 1 and first_to > last_driven + 1:
        assert 'zero torque' in ctrl.output(), (gap, ctrl.output()[-3000:])
    assert np.all(efforts[first_to:] == 0.0)
    # every state 5x command_timeout (in the plant's cycles) past the kill is flagged
    # (between the first flag and then, an answer the starved controller had sent before it
    # died may still arrive fresh: it clears the flag, it cannot bring torque back after
    # command_timeout)
    late = counted_past(states, cycles, killed_ns, 5 * round(0.01 * RATE))
    assert late.any() and np.all(flags[late] > 0), cycles[late & (flags == 0)]
    assert not harness.client.torque_applied('pinch_drive')
    assert hardware.wait_for_output('pinch: no fresh actuator_command', timeout=5), \
        hardware.output()


def test_drive_fault_zero_torque_then_reset_recovers(ecat_emulator, processes, tmp_path, probe):
    harness = ecat_emulator(driven_config(amplitude=0.2))
    bringup = start_bringup(processes, tmp_path, harness, {'pinch.mode': 'hold'})
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    probe.record(DiagnosticArray, '/diagnostics')
    probe.wait_for(lambda: harness.client.torque_applied('pinch_drive'), timeout=30,
                   what='torque applied')
    harness.client.drive_fault('pinch_drive', code=0x2310)
    probe.wait_messages('actuator_state', 1, where=lambda m: pinch(
        m, 'status') & ActuatorState.STATUS_FAULT)
    probe.clear('actuator_state')
    after = probe.wait_messages('actuator_state', 50)
    assert all(pinch(m, 'motor_effort') == 0.0 for m in after)
    assert all(pinch(m, 'status') & ActuatorState.STATUS_FAULT for m in after)
    assert harness.client.cia402_state('pinch_drive') == 'fault'
    # the drive's error code (0x603F, mapped) and its emergency in the fault and /diagnostics
    status = _diag(probe, 'hardware: pinch', lambda s: 'emergency' in s.message)
    assert status.message == ('FAULT: drive fault 0x2310 (continuous over current), '
                              'emergency 0x2310 register 0x03'), status.message
    assert _value(status, 'error_code') == '0x2310 (continuous over current)'
    response = probe.call(Trigger, '/hardware/reset', timeout=TIMEOUT)
    # (a starved test process may re-send the request: the answer it gets can be the second)
    assert response.success
    assert bringup.wait_for_output('reset: cleared pinch: drive fault 0x2310', timeout=10)
    probe.wait_for(lambda: harness.client.cia402_state('pinch_drive') == 'operation_enabled',
                   timeout=10, what='Operation enabled after ~/reset')
    probe.clear('actuator_state')
    probe.wait_messages('actuator_state', 1, where=lambda m: pinch(m, 'status') == 0
                        and pinch(m, 'motor_effort') != 0.0)


def test_wrong_product_code_refuses_to_start(ecat_emulator, processes, tmp_path):
    harness = ecat_emulator(emulator_config())
    bus = yaml.safe_load(BUS.read_text())
    bus['slaves'][1]['product_code'] = 0x0403
    wrong = tmp_path / 'bus_wrong.yaml'
    wrong.write_text(yaml.safe_dump(bus))
    proc = start_hardware(processes, tmp_path, harness, bus=wrong, wait=False)
    code = proc.wait(timeout=60)
    out = proc.output()
    assert code == 2, out
    assert 'pinch_drive' in out and '0x00000402' in out and '0x00000403' in out, out
    assert 'Traceback' not in out
    # nothing was enabled, no torque ever
    assert harness.client.cia402_state('pinch_drive') != 'operation_enabled'
    assert not any(e['value'] & 0x0F == 8 for e in harness.client.al_history())


def test_sigint_disables_drives_and_returns_bus_to_init(ecat_emulator, processes, tmp_path):
    harness = ecat_emulator(emulator_config())
    hw = start_bringup(processes, tmp_path, harness)
    deadline = time.monotonic() + 30
    while harness.client.cia402_state('pinch_drive') != 'operation_enabled':
        assert time.monotonic() < deadline, 'drives never enabled'
        time.sleep(0.1)
    hw.send_signal(signal.SIGINT)
    assert hw.wait(timeout=5) == 0, hw.output()
    for drive in ('wrist_drive', 'pinch_drive'):
        assert harness.client.cia402_state(drive) == 'switch_on_disabled'
        assert not harness.client.torque_applied(drive)
        assert harness.client.last_al_request(drive) & 0x0F == 1       # INIT requested
        assert harness.client.al_state(drive) == 1
    assert 'bus in INIT' in hw.output()


@pytest.mark.usefixtures('cpu_hog')
def test_commands_naming_only_wrist_do_not_keep_pinch_torque(ecat_emulator, processes, tmp_path,
                                                             probe):
    """Defect: any actuator_command fed one shared watchdog, so after the controller was gone
    a publisher naming only wrist kept pinch at its last torque (2 N m) with no timeout
    status. Now each channel has its own watchdog."""
    harness = ecat_emulator(driven_config(amplitude=0.2))
    # a generous command_timeout: this (CPU-starved) test process receives states late, and
    # its answers count only while the state they answer is at most command_timeout old
    start_hardware(processes, tmp_path, harness, {'command_timeout': 1.0})
    ctrl = start_controller(processes, tmp_path, {'pinch.mode': 'hold', 'wrist.mode': 'hold'})
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    probe.wait_for(lambda: harness.client.torque_applied('pinch_drive'), timeout=30,
                   what='torque applied by the emulated pinch drive')
    ctrl.stop()
    probe.wait_for(lambda: probe.node.count_publishers('/actuator_command') == 0, timeout=60,
                   what='the stopped controller gone from the graph')
    # from here on the only commands are the test's: past command_timeout (by the plant's
    # stamps), pinch has none
    settled_ns = time.time_ns() + 1_100_000_000
    seen = command_only(probe, {'wrist': 0.3}, after_ns=settled_ns)
    assert all(pinch(m, 'motor_effort') == 0.0
               and pinch(m, 'status') & ActuatorState.STATUS_COMMAND_TIMEOUT for m in seen)
    assert not harness.client.torque_applied('pinch_drive')


@pytest.mark.usefixtures('cpu_hog')
def test_direct_layout_over_ethercat(ecat_emulator, processes, tmp_path, probe):
    """hardware_bringup loop:=direct: the cycle thread calls the controller between reading
    and writing the bus. The pinch drive needs distributed clocks (it refuses OP without
    SYNC0): its bus YAML entry starts SYNC0 and the cycle locks to the reference clock. The
    feed-forward lowers |Z| over real frames, every state and command is published, each
    cycle's torque is the command answering the state just before, and parameters and
    ~/reset work from the executor."""
    config = driven_config()
    config['slaves'][1]['profile'] = 'requires_dc'
    harness = ecat_emulator(config)
    bus = yaml.safe_load(BUS.read_text())
    bus['slaves'][1].update(product_code=0x00004402,
                            dc={'assign_activate': 0x0300, 'sync0_shift_ns': 250000},
                            # this loaded 2-core host: a generous sync error limit
                            sdo=[[0x10F1, 2, 'u16', 1000]])
    path = tmp_path / 'bus_dc.yaml'
    path.write_text(yaml.safe_dump(bus))
    bringup = start_bringup(processes, tmp_path, harness, bus=path)
    assert 'SYNC0 on pinch_drive' in bringup.output()
    probe.record(DiagnosticArray, '/diagnostics')
    diag = _diag(probe, 'hardware: bus', lambda s: any(
        kv.key == 'layout' and kv.value == 'direct' for kv in s.values), timeout=30)
    assert diag.level == DiagnosticStatus.OK, diag.message
    diag = _diag(probe, 'hardware: bus', lambda s: _value(s, 'dc') == 'locked', timeout=30)
    assert _value(diag, 'pinch_drive.sm_event_missed') != ''       # 0x1C32:0B read
    pinch_status = harness.client.slave('pinch_drive')
    assert pinch_status['sync0_active'] and pinch_status['sync0_cycle_ns'] == 500000
    assert harness.client.slave('wrist_drive')['dc_activation'] == 0   # free run stays so
    z_passive = measured_impedance_db(harness.client, 1.0)
    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'dob_full_ff'},
                                      timeout=TIMEOUT)
    assert ok, reason
    z_ff = measured_impedance_db(harness.client, 1.0)
    print(f'|Z| at 1 rad/s, direct layout over EtherCAT: passive {z_passive:.1f} dB, '
          f'dob_full_ff {z_ff:.1f} dB')
    assert z_ff <= z_passive - 7.0, (z_passive, z_ff)
    # every command published answers a state; each state's torque came from the command
    # answering the state before it (the one modelled frame of delay)
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    probe.record(ActuatorCommand, 'actuator_command', OBSERVE_QOS)
    probe.wait_messages('actuator_command', 1000, timeout=60)
    probe.stop_recording('actuator_state')
    probe.stop_recording('actuator_command')
    states = by_cycle(probe.messages('actuator_state'))
    commands = {m.cycle: m for m in probe.messages('actuator_command')}
    pairs = [(s, commands.get(s.cycle - 1)) for s in states]
    pairs = [(s, c) for s, c in pairs if c is not None]
    assert len(pairs) > 200, len(pairs)
    driven = [(pinch(s, 'motor_effort'), pinch(c, 'effort')) for s, c in pairs
              if not pinch(s, 'status')]
    assert len(driven) > 0.99 * len(pairs)
    assert all(abs(applied - commanded) <= 0.5 / 1000 for applied, commanded in driven)
    assert 'no fault was latched' in probe.call(Trigger, '/controller/reset',
                                                timeout=TIMEOUT).message


# --- the managed node: lifecycle_msgs services over the emulated bus -----------------------
DRIVES = ('wrist_drive', 'pinch_drive')
SLAVES = DRIVES + ('pressure_terminal',)
OP = 8


class Lifecycle:
    """The test's client of /hardware's lifecycle services (what `ros2 lifecycle` calls).

    One client per service for the whole test. A change is not idempotent, so it is re-sent
    only after a long silence (an answer lost to the discovery race); what it did is then
    judged by the state it left, read with ``get_state``."""

    def __init__(self, probe):
        self.probe = probe
        self.change = probe.node.create_client(ChangeState, '/hardware/change_state')
        self.get = probe.node.create_client(GetState, '/hardware/get_state')
        for client in (self.change, self.get):
            assert client.wait_for_service(timeout_sec=30.0), 'no lifecycle services'

    def state(self):
        return self.probe._request(lambda: self.get.call_async(GetState.Request()), TIMEOUT,
                                   'get_state').current_state.label

    def set(self, transition):
        """Request ``transition`` (a Transition id); returns (success, state after)."""
        request = ChangeState.Request(transition=Transition(id=transition))
        response = self.probe._request(lambda: self.change.call_async(request), 4 * TIMEOUT,
                                       'change_state')
        return response.success, self.state()


def _slaves(client, key):
    return {name: client.slave(name)[key] for name in SLAVES}


def assert_no_torque(client):
    """No drive enabled or commanded: target torque 0 as the drives received it, none
    applied, no drive in Operation enabled."""
    for drive in DRIVES:
        status = client.slave(drive)
        assert status['target_torque'] == 0, (drive, status)
        assert not status['torque_applied'], (drive, status)
        assert status['cia402_state'] != 'operation_enabled', (drive, status)


def test_lifecycle_transitions_gate_the_torque_over_the_bus(ecat_emulator, processes, tmp_path,
                                                            probe):
    """hardware_bringup (direct layout) started unconfigured, moved by the standard
    lifecycle_msgs services: configure = bus in SAFE-OP, no torque; activate = OP, a command
    reaches the drive; deactivate = zero torque, drives disabled, SAFE-OP (and activate again
    works); cleanup = bus in INIT."""
    harness = ecat_emulator(driven_config(amplitude=0.2))
    client = harness.client
    bringup = start_bringup(processes, tmp_path, harness,
                            {'autostart': 'unconfigured', 'pinch.mode': 'hold'})
    lifecycle = Lifecycle(probe)
    assert lifecycle.state() == 'unconfigured'
    assert set(_slaves(client, 'al_state').values()) == {1}        # never touched: INIT

    ok, state = lifecycle.set(Transition.TRANSITION_CONFIGURE)
    assert state == 'inactive', (ok, bringup.output()[-3000:])
    assert set(_slaves(client, 'al_state').values()) == {4}, _slaves(client, 'al_state')
    assert 'identities checked' in bringup.output()
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    time.sleep(1.0)              # inactive for a while: still nothing reaches a drive
    assert_no_torque(client)
    assert not any(e['value'] & 0x0F == OP for e in client.al_history())
    assert probe.messages('actuator_state') == []      # the loop is open: no state published

    for round_ in range(2):      # activate after a deactivate starts the loop afresh
        ok, state = lifecycle.set(Transition.TRANSITION_ACTIVATE)
        assert state == 'active', (round_, ok, bringup.output()[-3000:])
        probe.wait_for(lambda: client.torque_applied('pinch_drive'), timeout=30,
                       what=f'torque applied by the emulated drive (activation {round_ + 1})')
        assert client.slave('pinch_drive')['target_torque'] != 0
        assert set(_slaves(client, 'al_state').values()) == {OP}
        probe.wait_messages('actuator_state', 10, timeout=30)

        ok, state = lifecycle.set(Transition.TRANSITION_DEACTIVATE)
        assert state == 'inactive', (round_, ok, bringup.output()[-3000:])
        assert_no_torque(client)
        assert {client.cia402_state(d) for d in DRIVES} == {'switch_on_disabled'}
        assert set(_slaves(client, 'al_state').values()) == {4}
        probe.clear('actuator_state')
        time.sleep(1.0)          # and it stays so: no frame, no watchdog fault, no state
        assert_no_torque(client)
        assert {client.cia402_state(d) for d in DRIVES} == {'switch_on_disabled'}
        assert probe.messages('actuator_state') == []

    ok, state = lifecycle.set(Transition.TRANSITION_CLEANUP)
    assert state == 'unconfigured', (ok, bringup.output()[-3000:])
    assert set(_slaves(client, 'al_state').values()) == {1}
    assert {client.last_al_request(s) & 0x0F for s in SLAVES} == {1}
    assert not any('watchdog' in e['text'].lower() for e in client.events())

    # a transition that does not exist from here is refused, the node lives on
    ok, state = lifecycle.set(Transition.TRANSITION_ACTIVATE)
    assert not ok and state == 'unconfigured'
    assert 'transition 3 refused: not available from unconfigured' in bringup.output()
    bringup.send_signal(signal.SIGINT)
    assert bringup.wait(timeout=10) == 0, bringup.output()
    out = bringup.output()
    assert 'Traceback' not in out and 'FATAL' not in out, out


def test_activating_again_after_a_short_activation_re_enters_from_zero_torque(
        ecat_emulator, processes, tmp_path, probe):
    """A deactivate/activate shorter than state_timeout, the pinch channel in hold against a
    1.5 N m torque sine (its torque follows the load): after each activate the drive's torque
    starts from zero and rises as after a first start -- no step to the torque of the last
    run (the plant's state numbers go on across activations, so the controller neither
    answers the new run's states from its cache nor drops them as out of order: before, the
    first torque was the last run's, then a run hit the 5 N m limit), and the state numbers
    after it continue those before it."""
    config = emulator_config()
    config['channels']['pinch']['environment'] = {'mode': 'torque_sine', 'amplitude': 1.5,
                                                  'frequency': 3.0}
    harness = ecat_emulator(config)
    client = harness.client
    bringup = start_bringup(processes, tmp_path, harness,
                            {'autostart': 'inactive', 'pinch.mode': 'hold',
                             'state_timeout': 0.05})
    lifecycle = Lifecycle(probe)
    probe.record(ActuatorState, 'actuator_state', OBSERVE_QOS)
    for round_ in range(4):
        client.start_trace(decimation=1, max_samples=40000)
        ok, state = lifecycle.set(Transition.TRANSITION_ACTIVATE)
        assert state == 'active', (round_, ok, bringup.output()[-3000:])
        probe.wait_for(lambda: abs(client.slave('pinch_drive')['target_torque']) > 0,
                       timeout=30, what='torque before the short deactivation')
        time.sleep(0.03)
        before = [m.cycle for m in probe.messages('actuator_state')]
        assert lifecycle.set(Transition.TRANSITION_DEACTIVATE)[1] == 'inactive'
        assert lifecycle.set(Transition.TRANSITION_ACTIVATE)[1] == 'active'
        time.sleep(0.5)
        assert lifecycle.set(Transition.TRANSITION_DEACTIVATE)[1] == 'inactive'
        torque = np.asarray(client.trace(stop=True)['pinch']['torque'])
        on = np.flatnonzero(torque)
        runs = np.split(on, np.flatnonzero(np.diff(on) > 10) + 1)
        assert len(runs) == 2, (round_, [(int(r[0]), int(r[-1])) for r in runs if r.size])
        for k, run in enumerate(runs):
            # the first 50 ms of each activation (its end, a deactivate, drops it to zero)
            start = torque[run[0]:min(run[0] + 100, run[-1] + 1)]
            steps = np.abs(np.diff(np.concatenate([[0.0], start])))
            assert steps.max() < 0.3, (round_, k, np.round(start[:8], 3).tolist())
        assert np.abs(torque).max() < 4.99, (round_, float(np.abs(torque).max()))
        after = [m.cycle for m in probe.messages('actuator_state')][len(before):]
        assert before and after and min(after) > max(before), (round_, before[-3:], after[:3])
        probe.clear('actuator_state')
    out = bringup.output()
    assert 'Traceback' not in out and 'went back' not in out, out[-3000:]


def test_wrong_identity_fails_configure_with_the_reason(ecat_emulator, processes, tmp_path,
                                                         probe):
    """configure through ~/change_state on a bus whose pinch drive has another product code:
    the transition fails, the node stays unconfigured with the reason in its log, no drive
    was enabled and the bus is back in INIT."""
    harness = ecat_emulator(emulator_config())
    bus = yaml.safe_load(BUS.read_text())
    bus['slaves'][1]['product_code'] = 0x0403
    wrong = tmp_path / 'bus_wrong.yaml'
    wrong.write_text(yaml.safe_dump(bus))
    hardware = start_hardware(processes, tmp_path, harness, {'autostart': 'unconfigured'},
                              bus=wrong)
    lifecycle = Lifecycle(probe)
    ok, state = lifecycle.set(Transition.TRANSITION_CONFIGURE)
    assert not ok and state == 'unconfigured', (ok, state)
    assert hardware.wait_for_output('configure failed: slave 2 (pinch_drive', timeout=10), \
        hardware.output()
    out = hardware.output()
    assert '0x00000402' in out and '0x00000403' in out and 'Traceback' not in out, out
    assert hardware.popen.poll() is None, out          # still there, unconfigured
    assert_no_torque(harness.client)
    assert not any(e['value'] & 0x0F == OP for e in harness.client.al_history())
    assert set(_slaves(harness.client, 'al_state').values()) == {1}


def test_failed_activate_returns_to_inactive_with_zero_torque(ecat_emulator, processes,
                                                              tmp_path, probe):
    """hardware_node with the default autostart (inactive: bus checked, drives disabled). An AL
    error left on a slave is acknowledged by activate (and said so); a drive that refuses OP
    -- one that needs SYNC0 on a bus YAML without dc -- fails activate with one line naming
    its AL code and the fix, the node stays inactive with no torque and the bus in SAFE-OP."""
    config = emulator_config()
    config['slaves'][1]['profile'] = 'requires_dc'
    harness = ecat_emulator(config)
    client = harness.client
    bus = yaml.safe_load(BUS.read_text())
    bus['slaves'][1]['product_code'] = 0x00004402         # that model's code
    path = tmp_path / 'bus_no_dc.yaml'
    path.write_text(yaml.safe_dump(bus))
    hardware = start_hardware(processes, tmp_path, harness, {'autostart': 'inactive'}, bus=path)
    lifecycle = Lifecycle(probe)
    assert lifecycle.state() == 'inactive'
    assert set(_slaves(client, 'al_state').values()) == {4}
    assert_no_torque(client)
    client.al_error('wrist_drive')
    ok, state = lifecycle.set(Transition.TRANSITION_ACTIVATE)
    assert not ok and state == 'inactive', (ok, state, hardware.output()[-3000:])
    assert hardware.wait_for_output('activate failed: slaves did not reach OP', timeout=10)
    line = [ln for ln in hardware.output().splitlines() if 'activate failed' in ln][0]
    assert 'pinch_drive: SAFE-OP+ERR 0x0030 (invalid DC SYNC configuration)' in line, line
    assert 'add dc: {assign_activate: 0x0300} to this slave' in line, line
    assert any(e['value'] == 0x14 and e['slave'] == 'wrist_drive' for e in client.al_history())
    assert_no_torque(client)
    assert set(_slaves(client, 'al_state').values()) == {4}
    assert 'Traceback' not in hardware.output()

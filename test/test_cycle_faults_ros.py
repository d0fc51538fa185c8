"""Faults of the real-time loop, through ROS processes and topics: each test reproduces a
defect once measured on the loop and checks the behaviour now.

The plant side is the sim here (hardware_node shares PlantCycle with it; its own loop faults
are in test_hardware_node.py); the controller side is controller_node fed by the test's own
states where a plant could not produce the fault.
"""
import math
import signal
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from seaforce_msgs.msg import ActuatorCommand, ActuatorState, ControllerStatus
from std_srvs.srv import Trigger

from helpers.commands import command_only
from helpers.nodes import own_domain, start_node
from helpers.probe import Probe
from helpers.processes import ProcessGroup
from helpers.states import by_cycle, value

# a loaded 2-core host delays single samples by tens of ms now and then; the stream checks
# have their own tests below
RELAXED = {'state_timeout': 0.5}
STATUS_FAULT = ActuatorState.STATUS_FAULT
STATUS_TIMEOUT = ActuatorState.STATUS_COMMAND_TIMEOUT


def pinch(msg, field):
    return value(msg, 'pinch', field)


class StateSource:
    """The test plays the plant: publishes actuator_state, reads the controller's answers."""

    def __init__(self, probe, names=('wrist', 'pinch')):
        self.probe = probe
        self.names = list(names)
        self.pub = probe.publisher(ActuatorState, 'actuator_state')
        self.clock = probe.node.get_clock()
        self.cycle = 0
        probe.record(ActuatorCommand, 'actuator_command')

    def send(self, x=0.0, v=0.0, fp=0.0, fa=0.0, n=1, stamp_offset=0.0, status=None,
             names=None):
        """Publish ``n`` states (every channel the same values); returns the last cycle."""
        names = list(self.names if names is None else names)
        for _ in range(n):
            self.cycle += 1
            msg = ActuatorState()
            now_ns = time.time_ns() + int(stamp_offset * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now_ns, 10**9)
            msg.cycle = self.cycle
            msg.name = names
            k = len(names)
            msg.motor_position = [x] * k
            msg.motor_velocity = [v] * k
            msg.pressure_force = [fp] * k
            msg.motor_effort = [fa] * k
            msg.endpoint_position = [math.nan] * k
            msg.external_force = [math.nan] * k
            msg.status = [0] * k if status is None else list(status)
            self.pub.publish(msg)
            time.sleep(0.002)
        return self.cycle

    def answer(self, timeout=20.0):
        """The controller's answer to the newest state."""
        cycle = self.cycle
        self.probe.wait_for(lambda: any(m.cycle == cycle for m in
                                        self.probe.messages('actuator_command')),
                            timeout=timeout, what=f'the answer to state {cycle}')
        return [m for m in self.probe.messages('actuator_command') if m.cycle == cycle][-1]

    def connect(self):
        """Wait until the controller answers (discovery)."""
        self.probe.wait_for(lambda: (self.send() and False) or bool(
            self.probe.messages('actuator_command')), timeout=30, what='first command')
        self.send(n=3)
        return self.answer()


def start_controller(processes, tmp_path, overrides=None, **kw):
    return start_node(processes, 'controller_node', 'controller', tmp_path,
                      {**RELAXED, **(overrides or {})}, **kw)


#: what the tests on the shared controller change: each starts from the values it began with
CONFIGURED = ('pinch.mode', 'wrist.mode', 'status_rate', 'state_timeout', 'pinch.max_torque',
              'state_limits.force', 'state_limits.velocity', 'state_limits.position')


class FedController:
    """One controller_node fed by the test's own states (a :class:`StateSource` whose cycles
    go on from test to test), in a DDS domain of its own, for :class:`TestOneController`."""

    def __init__(self, tmp_path, domain):
        self.group = ProcessGroup()
        self.probe = Probe('probe_cycle_faults', domain)
        try:
            self.ctrl = start_controller(self.group, tmp_path, domain=domain)
            self.source = StateSource(self.probe)
            self.probe.record(ControllerStatus, 'controller_status')
            self.probe.record(DiagnosticArray, '/diagnostics')
            self.start = self.probe.get_parameters('/controller', list(CONFIGURED))
        except BaseException:
            self.close()
            raise
        self._log_from = 0

    def configure(self, overrides):
        """The controller as one started with ``overrides`` would be: the parameters of
        :data:`CONFIGURED` at their starting values but ``overrides``, every latched fault
        reset, the records and the log from here on, answering the source's states."""
        ok, reason = self.probe.set_parameters('/controller', {**self.start, **overrides})
        assert ok, reason
        self.probe.call(Trigger, '/controller/reset')     # (nothing latched: says so)
        for topic in ('actuator_command', 'controller_status', '/diagnostics'):
            self.probe.clear(topic)
        self._log_from = len(self.ctrl.output())
        self.source.connect()
        return self.source

    def output(self):
        """The controller's log since :meth:`configure`."""
        return self.ctrl.output()[self._log_from:]

    def close(self):
        self.probe.close()
        self.group.stop_all()


@pytest.fixture(scope='class')
def fed(tmp_path_factory):
    controller = FedController(tmp_path_factory.mktemp('fed'), own_domain(0))
    try:
        yield controller
    finally:
        controller.close()


class TestOneController:
    """The defects of the controller side, each on one controller_node that the test feeds
    (the class's: configured by each test as a fresh one with its settings would be, latched
    faults reset)."""

    def test_malformed_state_faults_instead_of_crashing(self, fed):
        """Defect: a status array shorter than name raised IndexError, exit 1."""
        source = fed.configure({'pinch.mode': 'hold', 'wrist.mode': 'hold'})
        source.send(x=0.01)
        assert pinch(source.answer(), 'effort') < -0.1
        source.send(x=0.01, status=[0])                  # 2 names, 1 status
        cmd = source.answer()
        assert list(cmd.effort) == [0.0, 0.0]
        source.send(x=0.02, n=5)
        assert list(source.answer().effort) == [0.0, 0.0]        # latched
        assert fed.ctrl.popen.poll() is None, fed.output()
        fed.probe.wait_for(lambda: 'malformed actuator_state: 2 names but status 1 entries'
                           in fed.output(), timeout=5, what='the malformed state logged')
        assert 'Traceback' not in fed.ctrl.output()
        response = fed.probe.call(Trigger, '/controller/reset')
        assert response.success and 'pinch' in response.message
        source.send(x=0.02, n=3)
        assert pinch(source.answer(), 'effort') == pytest.approx(0.0, abs=1e-9)   # re-captured
        source.send(x=0.03, n=3)
        assert pinch(source.answer(), 'effort') < -0.1

    @pytest.mark.parametrize('mode', ['dob_linear_ff', 'dob_full_ff', 'impedance'])
    def test_huge_finite_state_never_gives_nan_torque(self, fed, mode):
        """Defect: inputs of 1e308 gave NaN torque with diagnostics OK; ~/reset did nothing
        and the NaN persisted. Now: a latched fault with its reason in controller_status and
        /diagnostics, finite zero torque, and a reset that really restarts the channel."""
        source = fed.configure({'pinch.mode': mode, 'wrist.mode': mode,
                                'state_limits.force': 1e308, 'state_limits.velocity': 1e308,
                                'state_limits.position': 1e308})
        probe = fed.probe
        source.send(x=1e308, v=1e308, fp=1e308, n=2)
        for _ in range(3):
            source.send(fp=0.01, n=20)
            cmd = source.answer()
            assert all(math.isfinite(e) for e in cmd.effort) and list(cmd.effort) == [0.0, 0.0]
        status = probe.wait_messages('controller_status', 1,
                                     where=lambda m: pinch(m, 'fault'))[-1]
        # (1e308 rad is far beyond the joint range too: whichever check meets it first)
        assert any(word in pinch(status, 'fault') for word in ('torque', 'overflow',
                                                               'beyond the joint range'))
        probe.wait_messages('/diagnostics', 1, timeout=5, where=lambda d: any(
            s.name == 'controller: pinch' and s.message.startswith('FAULT') for s in d.status))
        assert probe.call(Trigger, '/controller/reset').success
        source.send(fp=0.01, n=20)
        cmd = source.answer()
        assert all(math.isfinite(e) for e in cmd.effort) and pinch(cmd, 'effort') != 0.0

    def test_state_from_the_future_latches(self, fed):
        """Defect: a state stamped a day in the future passed the stale check."""
        source = fed.configure({'pinch.mode': 'hold', 'wrist.mode': 'hold',
                                'status_rate': 2000.0})
        source.send(x=0.01, stamp_offset=86400.0)
        assert list(source.answer().effort) == [0.0, 0.0]
        source.send(x=0.02, n=10)
        assert list(source.answer().effort) == [0.0, 0.0]
        status = fed.probe.wait_messages('controller_status', 1,
                                         where=lambda m: 'in the future' in pinch(m, 'fault'))[-1]
        assert 'in the future' in value(status, 'wrist', 'fault')

    def test_controller_status_is_live_during_a_fault(self, fed):
        """Defect: controller_status froze at the pre-fault snapshot and had no fault field."""
        source = fed.configure({'pinch.mode': 'dob_full_ff', 'status_rate': 500.0,
                                'pinch.max_torque': 1e-3})
        probe = fed.probe
        source.send(fp=0.5, n=5)                                  # -> beyond max_torque

        def latched_status():
            # states keep coming while the test waits: a status goes out at status_rate from
            # the cycle, and a fresh clone's run beside the hog saw none after the five-state
            # burst alone (30 s, the loop not advancing)
            source.send(fp=0.5)
            return [m for m in probe.messages('controller_status')
                    if 'max_torque' in pinch(m, 'fault')]
        probe.wait_for(lambda: bool(latched_status()), timeout=30,
                       what='a controller_status with the max_torque fault')
        latched = latched_status()[-1]
        probe.clear('controller_status')
        for k in range(40):
            source.send(v=0.05 * k, fp=0.01 * k)
        live = probe.wait_messages('controller_status', 5)
        assert all('max_torque' in pinch(m, 'fault') for m in live)
        assert all(pinch(m, 'mode') == 'dob_full_ff' for m in live)
        estimates = {pinch(m, 'endpoint_velocity_estimate') for m in live}
        assert len(estimates) >= 3 and latched.cycle < live[-1].cycle
        assert value(live[-1], 'wrist', 'fault') == ''


def test_stale_state_rearms_by_itself_without_a_step(processes, tmp_path, probe):
    """Defect: a stall latched `stale state` and needed a manual ~/reset although the plant
    had already zeroed the torque. Now the torque is zero while the stream is stale and the
    channel re-arms from the plant's present state once fresh states flow: no reset, no step,
    one log line per episode (a controller of its own: its log throttles the episodes it
    reports)."""
    # (RELAXED's state_timeout 0.5 s and a 2 s old state: a busy host delays a fresh state
    # too -- 318 ms at a load average of 15 -- and only the old one may be stale)
    ctrl = start_controller(processes, tmp_path, {'pinch.mode': 'hold', 'wrist.mode': 'hold'})
    source = StateSource(probe)
    source.connect()
    source.send(x=0.01, n=3)
    assert pinch(source.answer(), 'effort') < -0.1
    for episode in range(3):
        source.send(x=0.01 * (episode + 2), stamp_offset=-2.0)          # a 2 s old state
        assert list(source.answer().effort) == [0.0, 0.0]
        source.send(x=0.01 * (episode + 2))                              # fresh again
        assert pinch(source.answer(), 'effort') == pytest.approx(0.0, abs=1e-9)
        source.send(x=0.01 * (episode + 2) + 0.01, n=2)
        assert pinch(source.answer(), 'effort') < -0.1                   # holding again
    out = ctrl.output()
    assert out.count('stale state') == 1, out          # later episodes only counted
    assert 'FAULT latched' not in out


def _drive(amplitude=0.2, offset=0.0):
    # (an offset drive snaps the finger there at start: 34 rad/s for a moment, beyond the
    # default velocity trip)
    return {'pinch.environment.mode': 'position_sine', 'pinch.environment.amplitude': amplitude,
            'pinch.environment.frequency': 1.0, 'pinch.environment.offset': offset,
            'max_velocity': 0.0 if offset else 30.0}


def test_plant_restart_causes_no_torque_step(processes, tmp_path, probe):
    """Defect: controller in hold, SIGKILL sim_node, start a new one: the controller applied
    -9.87 N m in one cycle (old hold target, nothing noticed the cycle going back). Now its
    first commands to the new plant continue from the torque the new plant applies."""
    sim = start_node(processes, 'sim_node', 'sim', tmp_path, _drive(0.05, offset=0.4))
    start_controller(processes, tmp_path, {'pinch.mode': 'hold'})
    probe.record(ActuatorState, 'actuator_state')
    probe.record(ActuatorCommand, 'actuator_command')
    # the finger sits around 0.4 rad: hold captured its target there
    probe.wait_messages('actuator_state', 1, timeout=30, where=lambda m: m.cycle > 2000 and abs(
        pinch(m, 'motor_effort')) > 0.05)
    sim.send_signal(signal.SIGKILL)
    assert sim.wait(timeout=5) is not None
    time.sleep(0.5)
    probe.clear('actuator_state')
    probe.clear('actuator_command')
    # the new plant: the finger at rest at 0 (0.4 rad from the old hold target: K_p = 20
    # would have commanded 8 N m at once)
    start_node(processes, 'sim_node', 'sim', tmp_path, _drive(0.05, offset=0.0))
    probe.wait_messages('actuator_command', 400, timeout=30)
    commands = by_cycle(probe.messages('actuator_command'))
    # the new plant applies zero until its first command arrives (its watchdog): the first
    # command answering it must be that zero, within 0.05 N m
    first = commands[0]                   # (after discovery: a few thousand cycles in)
    assert abs(pinch(first, 'effort')) <= 0.05, pinch(first, 'effort')
    peak = max(abs(pinch(c, 'effort')) for c in commands[:400])      # the first 200 ms
    assert peak < 1.0, peak


def test_two_controllers_give_zero_torque_and_never_chatter(processes, tmp_path, probe):
    """Defect: with two controller_nodes the plant applied whichever command came last
    (1107 flips in 2 s, up to 10.6 N m) and nothing warned. Now the sim zeroes every channel,
    says which publishers it sees, and keeps the torque at zero until one is left and reset."""
    start_node(processes, 'sim_node', 'sim', tmp_path, _drive(0.2))
    start_controller(processes, tmp_path, {'pinch.mode': 'hold'})
    probe.record(ActuatorState, 'actuator_state')
    probe.record(DiagnosticArray, '/diagnostics')
    probe.wait_messages('actuator_state', 1, timeout=30,
                        where=lambda m: abs(pinch(m, 'motor_effort')) > 0.05)
    second = start_node(processes, 'controller_node', 'controller_b', tmp_path,
                        {**RELAXED, 'pinch.mode': 'passive'},
                        ros_args=('-r', '__node:=controller_b'))
    first_fault = probe.wait_messages('actuator_state', 1, timeout=30, where=lambda m: pinch(
        m, 'status') & STATUS_FAULT)[0].cycle
    probe.wait_cycle('actuator_state', first_fault + 4001, timeout=30)       # 2 s more
    after = [m for m in by_cycle(probe.messages('actuator_state')) if m.cycle >= first_fault]
    efforts = np.array([[value(m, c, 'motor_effort') for c in ('wrist', 'pinch')] for m in after])
    assert np.all(efforts[1:] == 0.0), np.flatnonzero(efforts[1:].any(axis=1))[:10]
    assert all(value(m, c, 'status') & STATUS_FAULT for m in after for c in ('wrist', 'pinch'))
    diag = probe.wait_messages('/diagnostics', 1, timeout=10, where=lambda d: any(
        s.name == 'sim: cycle' and '/controller_b' in s.message for s in d.status))[-1]
    message = [s for s in diag.status if s.name == 'sim: cycle'][0].message
    assert '/controller' in message and '/controller_b' in message, message
    # one source left: a reset clears it and torque resumes
    second.stop()
    probe.wait_for(lambda: probe.call(Trigger, '/sim/reset').success and not any(
        pinch(m, 'status') & STATUS_FAULT for m in probe.messages('actuator_state')[-20:]),
        timeout=30, what='the conflict cleared by ~/reset with one publisher left')
    probe.wait_messages('actuator_state', 1, timeout=30, where=lambda m: not pinch(
        m, 'status') & STATUS_FAULT and abs(pinch(m, 'motor_effort')) > 0.05)


def test_commands_for_one_channel_do_not_keep_another_alive(processes, tmp_path, probe):
    """A publisher that names only wrist feeds no watchdog of pinch: after the controller
    died, pinch gets zero torque with STATUS_COMMAND_TIMEOUT while wrist is commanded."""
    start_node(processes, 'sim_node', 'sim', tmp_path, _drive(0.2))
    ctrl = start_controller(processes, tmp_path, {'pinch.mode': 'hold', 'wrist.mode': 'hold'})
    probe.record(ActuatorState, 'actuator_state')
    probe.wait_messages('actuator_state', 1, timeout=30,
                        where=lambda m: abs(pinch(m, 'motor_effort')) > 0.05)
    ctrl.stop()
    # (a killed one would stay in the graph until its DDS lease expires: while the sim sees
    # two publishers it rightly applies nothing; test_hardware_node kills it)
    probe.wait_for(lambda: probe.node.count_publishers('/actuator_command') == 0, timeout=60,
                   what='the stopped controller gone from the graph')
    seen = command_only(probe, {'wrist': 0.3})
    assert all(pinch(m, 'motor_effort') == 0.0 and pinch(m, 'status') & STATUS_TIMEOUT
               for m in seen)

"""sim_node + controller_node as real processes: modes by parameter, rejection, watchdog, faults,
and lockstep equivalence with the offline simulator."""
import math
import signal
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from seaforce_msgs.msg import ActuatorState, ControllerStatus, ActuatorCommand
from std_srvs.srv import Trigger

from helpers.nodes import own_domain, start_node
from helpers.probe import Probe
from helpers.processes import ProcessGroup
from helpers.states import (by_cycle, counted_past, stamp_ns, torque_off_after_commands_stop,
                            value)

DRIVE = {'pinch.environment.mode': 'position_sine', 'pinch.environment.amplitude': 0.2,
         'pinch.environment.frequency': 1.0}
# a loaded 2-core machine delays single samples by 10-20 ms now and then; these tests are
# about behaviour, not about the stale-state check (which has its own test)
RELAXED = {'state_timeout': 0.5}
# tests that are not about real time run the sim in lockstep: one sample per answer, however
# busy the host (the plant's stamps are wall time: the controller's state_timeout must allow
# for a state held back by the scheduler)
LOCKSTEP = {'clock_mode': 'lockstep'}
LOCKSTEP_CONTROLLER = {'state_timeout': 5.0}


def pinch(msg, field):
    return value(msg, 'pinch', field)


#: The shared lockstep stack: the sim (seed 7, the drive at 0.5 rad) and the controller
#: (pinch dob_full_ff, wrist dob) as the offline equivalence test needs them from state 0.
STACK_SIM = {**DRIVE, **LOCKSTEP, 'pinch.environment.amplitude': 0.5, 'seed': 7}
STACK_CONTROLLER = {**LOCKSTEP_CONTROLLER, 'pinch.mode': 'dob_full_ff', 'wrist.mode': 'dob'}


#: states of the shared stack kept from its start (the equivalence test's record)
FIRST_CYCLES = 3000


def _modes_change_behaviour(probe):
    """The parameter services of the running stack answer and change what the finger feels:
    passive, then hold through SetParameters (what `ros2 param set` calls), then dob through
    SetParametersAtomically. ``probe`` records actuator_state."""
    probe.record(ControllerStatus, 'controller_status')
    ok, reason = probe.set_parameters('/sim', {'pinch.environment.amplitude': 0.2})
    assert ok, reason
    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'passive'})
    assert ok, reason
    passive = probe.wait_messages('controller_status', 1,
                                  where=lambda m: pinch(m, 'mode') == 'passive')[0].cycle
    # passive: zero torque while the finger is backdriven (from the cycle after the status
    # said so: the torque applied in a state is the answer to the one before)
    states = probe.wait_messages('actuator_state', 200, where=lambda m: m.cycle > passive + 1)
    assert all(pinch(m, 'motor_effort') == 0.0 for m in states)

    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'hold'}, atomic=False)
    assert ok, reason
    probe.wait_messages('controller_status', 1, where=lambda m: pinch(m, 'mode') == 'hold')
    probe.clear('actuator_state')
    states = probe.wait_messages('actuator_state', 2000)
    efforts = np.array([pinch(m, 'motor_effort') for m in states])
    assert np.max(np.abs(efforts)) > 0.05, 'hold must push back against the drive'
    # the motor is held: unpowered it follows the finger almost fully (k_s/(k_s+k) = 0.99);
    # held by K_p = 20 behind the hose it moves k_s/(k_s+K_p) ~ 0.4 of it
    xs = np.array([pinch(m, 'motor_position') for m in states])
    xes = np.array([pinch(m, 'endpoint_position') for m in states])
    assert np.ptp(xs) < 0.75 * np.ptp(xes), (np.ptp(xs), np.ptp(xes))

    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'dob'})
    assert ok, reason
    st = probe.wait_messages('controller_status', 1, where=lambda m: pinch(m, 'mode') == 'dob')
    assert math.isfinite(pinch(st[-1], 'disturbance'))  # the DOB is running


@pytest.fixture(scope='class')
def stack(tmp_path_factory):
    """:class:`TestOneLockstepStack`'s sim_node + controller_node (the class's: it runs
    while its tests do), in a DDS domain of its own, and a probe there recording
    actuator_state: ``(probe, the states of the first FIRST_CYCLES cycles)``; every process
    ended by its PID, pass or fail."""
    domain = own_domain(0)
    group = ProcessGroup()
    probe = Probe('probe_closed_loop_stack', domain)
    try:
        tmp = tmp_path_factory.mktemp('stack')
        probe.record(ActuatorState, 'actuator_state')
        start_node(group, 'sim_node', 'sim', tmp, STACK_SIM, domain=domain)
        # the sim re-publishes state 0 until a controller answers: the loop seen from its
        # start (discovery can take seconds on a loaded host)
        probe.wait_messages('actuator_state', 1, timeout=60, where=lambda m: m.cycle == 0)
        start_node(group, 'controller_node', 'controller', tmp, STACK_CONTROLLER,
                   domain=domain)
        probe.wait_cycle('actuator_state', FIRST_CYCLES, timeout=120)
        yield probe, [m for m in probe.messages('actuator_state') if m.cycle < FIRST_CYCLES]
    finally:
        probe.close()
        group.stop_all()


class TestOneLockstepStack:
    """The tests that watch a loop and change only what they set first share one lockstep
    sim_node + controller_node (the class's fixture: it runs while they do)."""

    def test_lockstep_loop_reproduces_offline_simulation(self, stack):
        """Same config, same seeds: the ROS loop and run_closed_loop give identical samples."""
        from seaforce_ros.core.controller import ChannelController
        from seaforce_ros.core.environment import position_sine
        from seaforce_ros.core.params import ControllerConfig, DahlParams, PlantParams
        from seaforce_ros.core.simulator import ChannelSimulator, run_closed_loop

        n_cycles = FIRST_CYCLES
        by_cycle = {}
        for m in stack[1]:
            by_cycle.setdefault(m.cycle, m)
        received = sorted(c for c in by_cycle if c < n_cycles)
        assert len(received) > 0.9 * n_cycles, len(received)

        plant = PlantParams.table_i()
        offline = {}
        for index, (channel, mode, env) in enumerate(
                [('wrist', 'dob', None), ('pinch', 'dob_full_ff', position_sine(0.5, 1.0))]):
            sim = ChannelSimulator(plant, dahl=DahlParams(), seed=7 + index, environment=env,
                                   torque_saturation=20.0)
            ctrl = ChannelController(ControllerConfig(plant=plant, mode=mode, max_torque=20.0))
            offline[channel] = run_closed_loop(sim, ctrl, n_cycles)
        worst = 0.0
        for channel in ('wrist', 'pinch'):
            rec = offline[channel]
            for field, key in (('motor_position', 'x'), ('motor_velocity', 'v'),
                               ('pressure_force', 'f_p'), ('endpoint_position', 'x_e'),
                               ('external_force', 'f_e'), ('motor_effort', 'f_a')):
                ros = np.array([value(by_cycle[c], channel, field) for c in received])
                ref = np.asarray(rec[key])[np.array(received)]
                diff = np.max(np.abs(ros - ref))
                worst = max(worst, diff)
                assert diff <= 1e-9, (channel, field, diff)
        # the drive really moved the finger and the controller really acted
        xe = np.array([pinch(by_cycle[c], 'endpoint_position') for c in received])
        assert np.ptp(xe) > 0.2

    def test_mode_change_by_parameter_changes_behaviour_events_executor(self, stack):
        """The default executor (events, spun so that services answer)."""
        _modes_change_behaviour(stack[0])

    def test_environment_changes_at_run_time_and_standard_topics_flow(self, stack):
        """The sim's environment is a run-time parameter; joint_states and /diagnostics flow."""
        from sensor_msgs.msg import JointState
        probe = stack[0]
        probe.record(JointState, 'joint_states')
        probe.record(DiagnosticArray, '/diagnostics')
        ok, reason = probe.set_parameters('/sim', {'pinch.environment.mode': 'free'})
        assert ok, reason
        free = probe.messages('actuator_state')[-1].cycle + 200     # the change is in by then
        states = probe.wait_messages('actuator_state', 100, where=lambda m: m.cycle > free)
        assert all(pinch(m, 'external_force') == 0.0 for m in states)
        ok, reason = probe.set_parameters('/sim', {'pinch.environment.mode': 'torque_sine',
                                                   'pinch.environment.amplitude': 0.3,
                                                   'pinch.environment.frequency': 10.0})
        assert ok, reason
        # (as above: judged once the change is in)
        sine = probe.messages('actuator_state')[-1].cycle + 200
        moved = probe.wait_messages('actuator_state', 1, where=lambda m: m.cycle > sine and abs(
            pinch(m, 'external_force')) > 0.1)
        assert abs(pinch(moved[-1], 'external_force')) <= 0.3
        # a bad environment value is rejected by the descriptor range / choices
        ok, reason = probe.set_parameters('/sim', {'pinch.environment.mode': 'earthquake'})
        assert not ok and 'one of' in reason
        js = probe.wait_messages('joint_states', 3)[-1]
        assert list(js.name) == ['wrist_motor', 'wrist_endpoint', 'pinch_motor', 'pinch_endpoint']
        assert len(js.position) == len(js.velocity) == len(js.effort) == 4
        assert all(math.isfinite(v) for v in (*js.position, *js.velocity, *js.effort))
        # the torque-driven pinch finger moves: its endpoint effort is the external torque
        moving = probe.wait_messages('joint_states', 1, where=lambda j: abs(j.effort[3]) > 0.05)
        assert abs(moving[-1].effort[3]) <= 0.3
        diag = probe.wait_messages('/diagnostics', 1, timeout=5, where=lambda d: any(
            s.name == 'sim: cycle' for s in d.status))[-1]
        keys = {kv.key for s in diag.status if s.name == 'sim: cycle' for kv in s.values}
        assert {'rate_hz', 'period_p99_ms', 'missed_deadlines', 'command_timeouts',
                'round_trip_p50_ms'} <= keys


def test_mode_change_by_parameter_changes_behaviour_single_threaded_executor(
        processes, tmp_path, probe):
    """The single-threaded executor (read-only: a controller of its own)."""
    start_node(processes, 'sim_node', 'sim', tmp_path, {**DRIVE, **LOCKSTEP})
    start_node(processes, 'controller_node', 'controller', tmp_path,
               {**LOCKSTEP_CONTROLLER, 'executor': 'single_threaded'})
    probe.record(ActuatorState, 'actuator_state')
    _modes_change_behaviour(probe)


def test_non_passive_dob_is_rejected_with_reason_and_old_values_stay(processes, tmp_path, probe):
    start_node(processes, 'controller_node', 'controller', tmp_path)
    before = probe.get_parameters('/controller', ['pinch.dob.nominal_inertia', 'pinch.mode'])
    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'dob',
                                                      'pinch.dob.nominal_inertia': 1e-5})
    assert not ok
    assert 'nominal_inertia' in reason and 'eq. 28' in reason, reason
    after = probe.get_parameters('/controller', ['pinch.dob.nominal_inertia', 'pinch.mode'])
    assert after == before  # atomic: the valid mode change went nowhere either
    # out-of-range stiffness (k_n > k + lambda b_n) alone
    ok, reason = probe.set_parameters('/controller', {'pinch.dob.nominal_stiffness': 5.0})
    assert not ok and 'nominal_stiffness' in reason, reason
    # the same through SetParameters, one parameter (what `ros2 param set` shows the user)
    ok, reason = probe.set_parameters('/controller', {'pinch.dob.nominal_inertia': 1e-5},
                                      atomic=False)
    assert not ok and 'nominal_inertia' in reason and 'eq. 28' in reason, reason
    assert probe.get_parameters('/controller', ['pinch.dob.nominal_inertia']) == {
        'pinch.dob.nominal_inertia': before['pinch.dob.nominal_inertia']}
    # explicitly allowing non-passive settings is the documented override
    ok, reason = probe.set_parameters('/controller', {'pinch.allow_non_passive': True,
                                                      'pinch.dob.nominal_inertia': 1e-5})
    assert ok, reason
    # an unknown mode is rejected by the choice check
    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'turbo'})
    assert not ok and 'one of' in reason, reason


def test_sim_zeroes_torque_when_controller_is_killed(processes, tmp_path, probe):
    sim = start_node(processes, 'sim_node', 'sim', tmp_path, DRIVE)
    ctrl = start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'pinch.mode': 'hold', **RELAXED})
    probe.record(ActuatorState, 'actuator_state')
    # torque flows: hold pushes back against the position drive
    probe.wait_messages('actuator_state', 1, timeout=30,
                        where=lambda m: abs(pinch(m, 'motor_effort')) > 0.05)
    killed_ns = time.time_ns()
    ctrl.send_signal(signal.SIGKILL)
    assert ctrl.wait(timeout=5) is not None
    t_kill = time.monotonic()
    # by the plant's stamps, not by the last state the probe has seen: a starved probe lags
    # the plant by up to seconds
    after = killed_ns + 50_000_000              # 5x command_timeout past the kill
    probe.wait_messages('actuator_state', 1, where=lambda m: stamp_ns(m) > after and (
        pinch(m, 'status') & ActuatorState.STATUS_COMMAND_TIMEOUT))
    # then enough later states to see it stay so (counted, not slept for: a loaded host
    # delivers them late)
    probe.wait_messages('actuator_state', 200, where=lambda m: stamp_ns(m) > after)
    states = by_cycle(probe.messages('actuator_state'))
    # the last cycle whose torque came from a command, and the first flagged cycle after it
    cycles, flags, efforts, last_driven, first_to = torque_off_after_commands_stop(states,
                                                                                   'pinch')
    assert flags[first_to] > 0, list(zip(cycles[-50:], flags[-50:], efforts[-50:]))
    timeout_cycles = 0.01 / 5e-4
    # The last command arrived in the cycle before `last_driven` (or, racing the cycle thread,
    # just after its start): zero torque within command_timeout (20 cycles) + one cycle of it.
    assert cycles[first_to] - cycles[last_driven] <= timeout_cycles + 1, (
        cycles[last_driven], cycles[first_to])
    # from then on zero torque; the flag held on every state 5x command_timeout (in the
    # plant's cycles) past the kill (until then an answer the starved controller had sent
    # before it died may still arrive fresh: it clears the flag, it cannot bring torque back
    # after command_timeout)
    assert np.all(efforts[first_to + 1:] == 0.0)
    late = counted_past(states, cycles, killed_ns, 5 * timeout_cycles)
    assert late.any() and np.all(flags[late] > 0), cycles[late & (flags == 0)]
    assert len(states) - first_to > 100  # and it stayed so for a while
    assert sim.popen.poll() is None, 'the sim keeps running'
    assert time.monotonic() - t_kill < 30


def _state(cycle, x, names=('wrist', 'pinch'), fp=0.0, nan=False, stamp=None):
    msg = ActuatorState()
    msg.header.stamp = stamp
    msg.cycle = cycle
    msg.name = list(names)
    msg.motor_position = [x, x]
    msg.motor_velocity = [0.0, math.nan if nan else 0.0]
    msg.pressure_force = [fp, fp]
    msg.motor_effort = [0.0, 0.0]
    msg.endpoint_position = [math.nan, math.nan]
    msg.external_force = [math.nan, math.nan]
    msg.status = [0, 0]
    return msg


def test_nan_state_latches_fault_until_reset(processes, tmp_path, probe):
    start_node(processes, 'controller_node', 'controller', tmp_path,
               {'pinch.mode': 'hold', 'wrist.mode': 'hold', 'state_timeout': 1.0})
    probe.record(ActuatorCommand, 'actuator_command')
    probe.record(DiagnosticArray, '/diagnostics')
    pub = probe.publisher(ActuatorState, 'actuator_state')
    clock = probe.node.get_clock()
    cycle = [0]

    def send(x, nan=False, n=1):
        for _ in range(n):
            cycle[0] += 1
            pub.publish(_state(cycle[0], x, nan=nan, stamp=clock.now().to_msg()))
            time.sleep(0.002)

    def last_answer():
        cmds = probe.messages('actuator_command')
        return cmds[-1] if cmds else None

    # wait for discovery, then hold around x = 0 and push the motor away: torque resists
    probe.wait_for(lambda: (send(0.0) or last_answer() is not None), what='first command')
    send(0.0, n=5)
    send(0.01, n=5)
    probe.wait_for(lambda: last_answer().cycle == cycle[0], what='answer')
    assert pinch(last_answer(), 'effort') < -0.1
    send(0.01, nan=True)
    probe.wait_for(lambda: last_answer().cycle == cycle[0], what='answer to NaN')
    assert pinch(last_answer(), 'effort') == 0.0
    assert pinch(last_answer(), 'effort') == 0.0 and last_answer().effort[0] != 0.0  # wrist runs
    # latched: valid states still give zero on pinch
    send(0.02, n=10)
    probe.wait_for(lambda: last_answer().cycle == cycle[0], what='answer')
    assert pinch(last_answer(), 'effort') == 0.0
    diag = probe.wait_messages('/diagnostics', 1, timeout=5, where=lambda d: any(
        s.name == 'controller: pinch' and 'FAULT' in s.message for s in d.status))
    assert any('non-finite' in s.message or 'bad state' in s.message
               for s in diag[-1].status if s.name == 'controller: pinch')
    # reset clears it; hold re-captures the current position, then resists motion again
    response = probe.call(Trigger, '/controller/reset')
    assert response.success and 'pinch' in response.message
    send(0.02, n=5)
    send(0.04, n=5)
    probe.wait_for(lambda: last_answer().cycle == cycle[0], what='answer after reset')
    assert pinch(last_answer(), 'effort') < -0.1

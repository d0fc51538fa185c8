"""controller_node over ROS: the `impedance` and `chirp` modes, and the faults a state or a
torque can latch (torque limit, channel missing), each with its log line and diagnostics."""
import math
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from seaforce_msgs.msg import ActuatorCommand, ActuatorState
from std_srvs.srv import Trigger

from helpers.nodes import start_node
from helpers.states import value
from seaforce_ros.core.analysis import impedance_from_position

DT = 5e-4


def test_impedance_and_chirp_modes_over_ros(processes, tmp_path, probe):
    """Lockstep sim + controller: pinch renders a virtual spring-damper set by parameters
    (|Z| = target within 5 % at the drive frequency), wrist plays the open-loop chirp."""
    kt, bt, w = 2.0, 0.05, 3.0
    settle, periods = 1.0, 2
    n_cycles = int((settle + periods * 2 * math.pi / w) / DT) + 10
    probe.record(ActuatorState, 'actuator_state')
    start_node(processes, 'sim_node', 'sim', tmp_path,
               {'clock_mode': 'lockstep', 'pinch.environment.mode': 'position_sine',
                'pinch.environment.amplitude': 0.2, 'pinch.environment.frequency': w})
    probe.wait_messages('actuator_state', 1, timeout=60, where=lambda m: m.cycle == 0)
    start_node(processes, 'controller_node', 'controller', tmp_path,
               {'state_timeout': 5.0,
                'pinch.mode': 'impedance', 'pinch.target.stiffness': kt,
                'pinch.target.damping': bt,
                'wrist.mode': 'chirp', 'wrist.chirp.amplitude': 0.2,
                'wrist.chirp.start_frequency': 1.0, 'wrist.chirp.end_frequency': 100.0,
                'wrist.chirp.duration': 2.0})
    probe.wait_cycle('actuator_state', n_cycles, timeout=180)
    by_cycle = {}
    for m in probe.messages('actuator_state'):
        by_cycle.setdefault(m.cycle, m)
    cycles = np.arange(1, n_cycles)
    have = np.array([c for c in cycles if c in by_cycle])
    assert len(have) > 0.99 * len(cycles), f'{len(have)} of {len(cycles)} states received'

    def series(name, field):
        values = np.array([value(by_cycle[c], name, field) for c in have])
        return np.interp(cycles, have, values)

    # pinch: the rendered impedance F_e / V_e equals the target k/(jw) + b
    z = impedance_from_position(series('pinch', 'external_force'),
                                series('pinch', 'endpoint_position'), w, DT, settle)
    target = kt / (1j * w) + bt
    assert abs(z - target) < 0.05 * abs(target), (z, target)
    # wrist: open-loop log chirp, bounded by its amplitude, rising in frequency, then zero
    u = series('wrist', 'motor_effort')
    assert np.max(np.abs(u)) <= 0.2 + 1e-9 and np.max(np.abs(u[:4000])) > 0.19
    crossings = lambda x: np.count_nonzero(np.diff(np.sign(x)) != 0)  # noqa: E731
    assert crossings(u[2000:4000]) > 5 * crossings(u[:2000])
    assert np.all(u[4010:] == 0.0)


def _state(cycle, stamp, x=0.0, names=('wrist', 'pinch')):
    msg = ActuatorState()
    msg.header.stamp = stamp
    msg.cycle = cycle
    msg.name = list(names)
    n = len(names)
    msg.motor_position = [x] * n
    msg.motor_velocity = [0.0] * n
    msg.pressure_force = [0.0] * n
    msg.motor_effort = [0.0] * n
    msg.endpoint_position = [math.nan] * n
    msg.external_force = [math.nan] * n
    msg.status = [0] * n
    return msg


def test_torque_limit_and_missing_channel_latch_faults(processes, tmp_path, probe):
    ctrl = start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'pinch.mode': 'hold', 'wrist.mode': 'hold', 'state_timeout': 1.0,
                       'pinch.max_torque': 0.5})
    probe.record(ActuatorCommand, 'actuator_command')
    probe.record(DiagnosticArray, '/diagnostics')
    pub = probe.publisher(ActuatorState, 'actuator_state')
    clock = probe.node.get_clock()
    cycle = [0]

    def send(x, n=1, names=('wrist', 'pinch')):
        for _ in range(n):
            cycle[0] += 1
            pub.publish(_state(cycle[0], clock.now().to_msg(), x, names))
            time.sleep(0.002)

    def answer():
        probe.wait_for(lambda: probe.messages('actuator_command')
                       and probe.messages('actuator_command')[-1].cycle == cycle[0],
                       what=f'the answer to state {cycle[0]}')
        return probe.messages('actuator_command')[-1]

    def fault_reported(name, text):
        probe.wait_messages('/diagnostics', 1, timeout=5, where=lambda d: any(
            s.name == f'controller: {name}' and 'FAULT' in s.message and text in s.message
            for s in d.status))

    probe.wait_for(lambda: (send(0.0) or bool(probe.messages('actuator_command'))),
                   what='first command')
    send(0.0, n=5)
    # a small push: hold resists within the limit (K_p = 20: 0.01 rad -> 0.2 N m)
    send(0.01, n=3)
    cmd = answer()
    assert -0.5 <= value(cmd, 'pinch', 'effort') < -0.1
    # a large push: the hold torque would exceed pinch.max_torque = 0.5 -> latched, zero
    send(0.1, n=3)
    cmd = answer()
    assert value(cmd, 'pinch', 'effort') == 0.0
    assert value(cmd, 'wrist', 'effort') < -0.5      # wrist (max_torque 20) keeps holding
    fault_reported('pinch', 'max_torque')
    send(0.0, n=5)                                     # back in range: still latched
    assert value(answer(), 'pinch', 'effort') == 0.0
    assert ctrl.wait_for_output('pinch: FAULT latched, zero torque: torque -',
                                timeout=5), ctrl.output()
    # a state without the wrist channel latches a fault on wrist only after reset
    response = probe.call(Trigger, '/controller/reset')
    assert response.success and 'pinch' in response.message, response.message
    send(0.0, n=3, names=('pinch',))
    cmd = answer()
    assert value(cmd, 'wrist', 'effort') == 0.0
    fault_reported('wrist', 'channel missing')
    send(0.01, n=3)                                    # full state again: wrist stays latched
    cmd = answer()
    assert value(cmd, 'wrist', 'effort') == 0.0 and value(cmd, 'pinch', 'effort') < -0.1
    assert ctrl.wait_for_output('wrist: FAULT latched, zero torque: channel missing', timeout=5)

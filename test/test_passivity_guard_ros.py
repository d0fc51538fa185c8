"""The passivity guard over ROS: the parameter and its values, a non-passive DOB
accepted with a warning when the guard is active, the guard's figures in controller_status and
/diagnostics, and a light finger held stable against the sim's stiff bonded drive."""
import math

from diagnostic_msgs.msg import DiagnosticArray
from seaforce_msgs.msg import ControllerStatus

from helpers.nodes import start_node
from helpers.states import value

LIGHT = 1.1116e-4          # 0.1 m: far below eq. 28's m - b/lambda = 8.7e-4 at 2 pi 20 rad/s


def pinch(msg, field):
    return value(msg, 'pinch', field)


def test_guard_carries_a_light_finger_against_the_stiff_drive(processes, tmp_path, probe):
    start_node(processes, 'sim_node', 'sim', tmp_path,
               {'pinch.environment.mode': 'position_sine', 'pinch.environment.amplitude': 0.05,
                'pinch.environment.frequency': 10.0})
    controller = start_node(processes, 'controller_node', 'controller', tmp_path,
                            {'state_timeout': 0.5})
    probe.record(ControllerStatus, 'controller_status')
    probe.record(DiagnosticArray, '/diagnostics')
    # off/on would be YAML booleans: the values are disabled / monitor / active
    ok, reason = probe.set_parameters('/controller', {'pinch.passivity_guard': 'on'})
    assert not ok and 'disabled, monitor, active' in reason and 'YAML' in reason, reason
    # without the guard the light setting is rejected; with it, accepted with a warning
    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'dob',
                                                      'pinch.dob.nominal_inertia': LIGHT})
    assert not ok and 'eq. 28' in reason, reason
    ok, reason = probe.set_parameters('/controller', {'pinch.mode': 'dob',
                                                      'pinch.passivity_guard': 'active',
                                                      'pinch.dob.nominal_inertia': LIGHT})
    assert ok, reason
    assert controller.wait_for_output('accepted because passivity_guard is active', 10), \
        controller.output()
    # the guard has to act against the drive; the torque never reaches max_torque (a fault)
    active = probe.wait_messages('controller_status', 1, timeout=20, where=lambda m: (
        pinch(m, 'mode') == 'dob' and pinch(m, 'passivity_damping') > 0.0))
    last = probe.wait_messages('controller_status', len(probe.messages('controller_status'))
                               + 300)[-1]
    assert pinch(last, 'fault') == '', pinch(last, 'fault')
    assert pinch(last, 'passivity_dissipated') > 0.0
    assert pinch(last, 'passivity_energy') <= 1e-3          # at most the reserve
    assert math.isnan(value(last, 'wrist', 'passivity_energy'))   # disabled there
    assert active
    diag = probe.wait_messages('/diagnostics', 1, where=lambda m: any(
        s.name == 'controller: pinch' and any(kv.key == 'passivity_guard'
                                               and kv.value == 'active' for kv in s.values)
        for s in m.status))[-1]
    values = {kv.key: kv.value for s in diag.status if s.name == 'controller: pinch'
              for kv in s.values}
    assert float(values['passivity_damping']) >= 0.0 and 'passivity_energy' in values

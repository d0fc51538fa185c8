"""config/urdf/seaforce_gripper.urdf.xacro: xacro (PyPI) -> URDF text -> urdf_parser_py (PyPI).

* Against one running sim_node + controller_node (module-scoped): the URDF's joints are
  exactly the names on joint_states (<channel>_motor, <channel>_endpoint), and every joint's
  limits are the parameters the nodes run with: lower / upper the controller's
  <channel>.limits.position_min / max less the walls' band, velocity the sim's max_velocity (motor) and the
  controller's <channel>.grasp.gripper_velocity (finger: the speed MoveIt plans with), effort
  the sim's torque_limit.
* Without nodes: a parameter file that leaves the limits out gives the schema's defaults
  (sim and hardware), one with three channels and its own limits gives those; the installed
  copy is the source (what display.launch.xml runs); the MoveIt snippets of
  docs/gripper-actions.md command a finger joint of the URDF through the action the
  controller serves, with an effort cap, at the URDF's speed.
"""
import re

import pytest
import yaml
import xacro
from sensor_msgs.msg import JointState
from urdf_parser_py.urdf import URDF

from seaforce_ros.nodes import hardware_node, param_specs, sim_node
from seaforce_ros.nodes.gripper_actions import action_namespace

from helpers import moveit
from helpers.nodes import CONFIG
from helpers.processes import ROOT
from helpers.sim_stack import SimStack

XACRO = ROOT / 'config' / 'urdf' / 'seaforce_gripper.urdf.xacro'
INSTALLED = ROOT / 'install' / 'seaforce_ros' / 'share' / 'seaforce_ros' / 'config' / 'urdf'


def urdf(**mappings):
    """The xacro's URDF text with these arguments, parsed by urdf_parser_py."""
    text = xacro.process_file(str(XACRO), mappings={k: str(v) for k, v in mappings.items()})
    return URDF.from_xml_string(text.toxml())


def limits(robot):
    """joint name -> (lower, upper, velocity, effort)."""
    return {j.name: (j.limit.lower, j.limit.upper, j.limit.velocity, j.limit.effort)
            for j in robot.joints}


@pytest.fixture(scope='module')
def live(tmp_path_factory):
    """(joint_states names, the limits the running nodes use per joint)."""
    stack = SimStack(tmp_path_factory.mktemp('urdf'), 'urdf')
    try:
        stack.probe.record(JointState, 'joint_states')
        names = list(stack.probe.wait_messages('joint_states', 1, timeout=30)[-1].name)
        plant = stack.probe.get_parameters('/sim', ['channels', 'max_velocity', 'torque_limit'])
        expected = {}
        for channel in plant['channels']:
            keys = [f'{channel}.limits.position_min', f'{channel}.limits.position_max',
                    f'{channel}.limits.wall_band', f'{channel}.grasp.gripper_velocity']
            ranges = stack.probe.get_parameters('/controller', keys)
            band = ranges[keys[2]]
            for joint, velocity in (('motor', plant['max_velocity']),
                                    ('endpoint', ranges[keys[3]])):
                expected[f'{channel}_{joint}'] = (ranges[keys[0]] + band, ranges[keys[1]] - band,
                                                  velocity, plant['torque_limit'])
    finally:
        stack.close()
    return names, expected


def test_joint_names_are_those_on_joint_states(live):
    names, _ = live
    robot = urdf()
    assert sorted(j.name for j in robot.joints) == sorted(names), names
    assert all(j.type == 'revolute' for j in robot.joints)
    # each channel's finger is the endpoint joint; its motor the motor joint
    for joint in robot.joints:
        assert joint.parent == 'base_link'
        assert joint.child == joint.name.replace('_endpoint', '_finger_link').replace(
            '_motor', '_motor_link')


def test_limits_are_the_running_parameters(live):
    _, expected = live
    assert limits(urdf()) == expected     # the values pass through text exactly


def _defaults(specs):
    return {s.name: s.default for s in specs}


@pytest.mark.parametrize('plant, node', [('sim', sim_node), ('hardware', hardware_node)])
def test_limits_default_to_the_schema(tmp_path, plant, node):
    """A parameter file without the plant section or the friction keys."""
    params = tmp_path / 'bare.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': {'channels': ['pinch']}}}))
    node_defaults = _defaults(node.node_specs())
    channel = _defaults(param_specs.controller_channel_specs('pinch'))
    band = channel['pinch.limits.wall_band']
    row = (channel['pinch.limits.position_min'] + band, channel['pinch.limits.position_max'] - band,
           node_defaults['max_velocity'], node_defaults['torque_limit'])
    finger = row[:2] + (channel['pinch.grasp.gripper_velocity'],) + row[3:]
    assert limits(urdf(params_file=params, plant=plant)) == \
        {'pinch_motor': row, 'pinch_endpoint': finger}


def test_channels_and_limits_follow_the_parameter_file(tmp_path):
    data = yaml.safe_load(CONFIG.read_text())
    data['/**']['ros__parameters']['channels'] = ['a', 'b', 'c']
    for i, channel in enumerate('abc'):
        data['/**']['ros__parameters'][channel] = {
            'limits': {'position_min': -0.5 - i, 'position_max': 0.25 + i, 'wall_band': 0.125},
            'grasp': {'gripper_velocity': 0.1 * (i + 1)}}
    data['/**/hardware'] = {'ros__parameters': {'torque_limit': 3.5, 'max_velocity': 12.0}}
    data['/**']['ros__parameters']['max_velocity'] = 50.0
    params = tmp_path / 'three.yaml'
    params.write_text(yaml.safe_dump(data))
    found = limits(urdf(params_file=params, plant='hardware'))
    assert found == {f'{c}_{j}': (-0.5 - i + 0.125, 0.25 + i - 0.125,
                                  12.0 if j == 'motor' else 0.1 * (i + 1), 3.5)
                     for i, c in enumerate('abc') for j in ('motor', 'endpoint')}
    # the sim: no section of its own, its keys under /** (max_velocity) or the defaults
    assert {v[2:] for k, v in limits(urdf(params_file=params)).items()
            if k.endswith('_motor')} == {(50.0, 20.0)}


def test_installed_copy_is_the_source():
    assert (INSTALLED / XACRO.name).read_bytes() == XACRO.read_bytes(), \
        'rebuild: source scripts/setup.sh'


def test_the_moveit_snippet_commands_a_urdf_finger_joint():
    """The MoveIt snippets of docs/gripper-actions.md: a GripperCommand controller per
    channel on the action the controller serves, with a max_effort MoveIt sends (0 is
    refused) within the channel's limits; joint limits for the URDF's finger joint at the
    speed a gripper command moves (the URDF's limit, grasp.gripper_velocity) with an
    acceleration limit (MoveIt's time parameterisation needs both)."""
    controllers, joint_limits = moveit.snippets()
    robot = urdf()
    joints = {j.name: j for j in robot.joints}
    defaults = {s.name: s.default for s in param_specs.controller_channel_specs('pinch')}
    for name in controllers['controller_names']:
        controller = controllers[name]
        assert controller['type'] == 'GripperCommand' and controller['default'] is True
        assert controller['action_ns'] == 'gripper_cmd'
        (joint,) = controller['joints']
        assert joint in joints and joint.endswith('_endpoint'), joint
        assert name == action_namespace(joint[:-len('_endpoint')], '')
        assert defaults['pinch.grasp.approach_force'] < controller['max_effort'] \
            <= defaults['pinch.max_torque']
        limits = joint_limits[joint]
        assert limits['has_velocity_limits'] and limits['has_acceleration_limits']
        assert limits['max_velocity'] == joints[joint].limit.velocity \
            == defaults['pinch.grasp.gripper_velocity']
        assert limits['max_acceleration'] > 0.0

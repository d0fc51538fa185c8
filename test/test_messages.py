"""seaforce_msgs over real topics between processes, and byte compatibility with rosbags."""
import json
import pathlib
import time

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from helpers.msgdict import rosbags_to_plain, same, sample_messages, to_plain

HELPERS = pathlib.Path(__file__).parent / 'helpers'
TYPES = {'actuator_state': 'ActuatorState', 'actuator_command': 'ActuatorCommand',
         'controller_status': 'ControllerStatus'}


def test_message_fields_match_design():
    """The generated types carry exactly the fields, types and constants the nodes rely on."""
    from seaforce_msgs.msg import ActuatorCommand, ActuatorState, ControllerStatus

    assert ActuatorState.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'cycle': 'uint64', 'name': 'sequence<string>',
        'motor_position': 'sequence<double>', 'motor_velocity': 'sequence<double>',
        'pressure_force': 'sequence<double>', 'motor_effort': 'sequence<double>',
        'endpoint_position': 'sequence<double>', 'external_force': 'sequence<double>',
        'status': 'sequence<uint8>'}
    assert list(ActuatorState.get_fields_and_field_types()) == [
        'header', 'cycle', 'name', 'motor_position', 'motor_velocity', 'pressure_force',
        'motor_effort', 'endpoint_position', 'external_force', 'status']
    assert (ActuatorState.STATUS_OK, ActuatorState.STATUS_COMMAND_TIMEOUT,
            ActuatorState.STATUS_LIMIT, ActuatorState.STATUS_FAULT) == (0, 1, 2, 4)
    assert ActuatorCommand.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'cycle': 'uint64', 'name': 'sequence<string>',
        'effort': 'sequence<double>'}
    assert list(ControllerStatus.get_fields_and_field_types().items()) == [
        ('header', 'std_msgs/Header'), ('cycle', 'uint64'), ('name', 'sequence<string>'),
        ('mode', 'sequence<string>'), ('disturbance', 'sequence<double>'),
        ('feedforward', 'sequence<double>'), ('endpoint_velocity_estimate', 'sequence<double>'),
        ('dahl_force', 'sequence<double>'), ('fault', 'sequence<string>'),
        ('contact', 'sequence<boolean>'), ('contact_position', 'sequence<double>'),
        ('contact_force', 'sequence<double>'), ('object_stiffness', 'sequence<double>'),
        ('object_stiffness_sigma', 'sequence<double>'), ('object_damping', 'sequence<double>'),
        ('object_damping_sigma', 'sequence<double>'), ('grasp_phase', 'sequence<string>'),
        ('passivity_energy', 'sequence<double>'), ('passivity_dissipated', 'sequence<double>'),
        ('passivity_damping', 'sequence<double>')]


def test_grasp_action_interface():
    """The action's goal and result are a fixed interface (other tools depend on them), the feedback the
    grasp's progress; rosbags knows the feedback topic's message with rosidl's own type hash."""
    from ament_index_python.packages import get_package_share_directory
    from seaforce_msgs.action import Grasp

    from seaforce_ros.bags.definitions import make_typestore
    assert list(Grasp.Goal.get_fields_and_field_types().items()) == [
        ('channel', 'string'), ('closing_velocity', 'double'), ('grip_force', 'double'),
        ('max_force', 'double'), ('probe', 'boolean')]
    assert list(Grasp.Result.get_fields_and_field_types().items()) == [
        ('contact', 'boolean'), ('contact_position', 'double'), ('object_stiffness', 'double'),
        ('object_stiffness_sigma', 'double'), ('object_damping', 'double'),
        ('object_damping_sigma', 'double'), ('grip_force', 'double'), ('message', 'string')]
    assert list(Grasp.Feedback.get_fields_and_field_types()) == [
        'phase', 'endpoint_position', 'force', 'object_stiffness', 'object_damping']
    share = pathlib.Path(get_package_share_directory('seaforce_msgs'))
    hashes = {h['type_name']: h['hash_string'] for h in
              json.loads((share / 'action' / 'Grasp.json').read_text())['type_hashes']}
    store = make_typestore()
    for part in ('Goal', 'Result', 'Feedback', 'FeedbackMessage'):
        name = f'seaforce_msgs/action/Grasp_{part}'
        assert store.hash_rihs01(name) == hashes[name], part


def test_calibrate_friction_action_interface():
    """The calibration's goal (channel, amplitude, speed, apply), result (old/new values,
    1-sigma, change, message) and feedback; rosbags hashes them as rosidl does."""
    from ament_index_python.packages import get_package_share_directory
    from seaforce_msgs.action import CalibrateFriction

    from seaforce_ros.bags.definitions import make_typestore
    assert list(CalibrateFriction.Goal.get_fields_and_field_types().items()) == [
        ('channel', 'string'), ('amplitude', 'double'), ('speed', 'double'),
        ('apply', 'boolean')]
    assert list(CalibrateFriction.Result.get_fields_and_field_types()) == [
        'names', 'old_values', 'new_values', 'new_values_sigma', 'change', 'applied',
        'message']
    assert list(CalibrateFriction.Feedback.get_fields_and_field_types()) == [
        'phase', 'progress']
    share = pathlib.Path(get_package_share_directory('seaforce_msgs'))
    hashes = {h['type_name']: h['hash_string'] for h in json.loads(
        (share / 'action' / 'CalibrateFriction.json').read_text())['type_hashes']}
    store = make_typestore()
    for part in ('Goal', 'Result', 'Feedback', 'FeedbackMessage'):
        name = f'seaforce_msgs/action/CalibrateFriction_{part}'
        assert store.hash_rihs01(name) == hashes[name], part


def test_messages_cross_process_field_for_field(processes, ros_context):
    """Each message published here arrives unchanged in another process over a real topic."""
    import rclpy

    echo = processes.start_python(HELPERS / 'echo_json.py',
                                  *[f'{topic}:{t}' for topic, t in TYPES.items()])
    assert echo.wait_for_output('READY', timeout=30), echo.output()

    node = rclpy.create_node('message_sender', context=ros_context)
    try:
        messages = sample_messages()
        publishers = {topic: node.create_publisher(type(msg), topic, 10)
                      for topic, msg in messages.items()}
        received = {}
        deadline = time.monotonic() + 30
        while len(received) < len(messages) and time.monotonic() < deadline:
            for topic, msg in messages.items():
                if topic not in received:
                    publishers[topic].publish(msg)
            time.sleep(0.2)
            for line in echo.output().splitlines():
                if line.startswith('{'):
                    item = json.loads(line)
                    received[item['topic']] = item['msg']
        assert set(received) == set(messages), echo.output()
        for topic, msg in messages.items():
            sent = to_plain(msg)
            assert same(sent, received[topic]), (topic, sent, received[topic])
    finally:
        node.destroy_node()


@pytest.mark.parametrize('topic', sorted(TYPES))
def test_rosbags_and_rclpy_serialisation_interoperate(topic):
    """CDR bytes from rclpy decode in rosbags and vice versa, value for value."""
    from seaforce_ros.bags.definitions import make_typestore

    store = make_typestore()
    msg = sample_messages()[topic]
    type_name = f'seaforce_msgs/msg/{TYPES[topic]}'

    # rclpy -> rosbags
    raw = serialize_message(msg)
    decoded = store.deserialize_cdr(raw, type_name)
    assert same(rosbags_to_plain(decoded), to_plain(msg))

    # rosbags -> rclpy. Same layout and length; the bytes themselves may differ only in CDR
    # alignment padding, which Fast CDR leaves uninitialised and rosbags zero-fills.
    reencoded = bytes(store.serialize_cdr(decoded, type_name))
    assert len(reencoded) == len(raw)
    back = deserialize_message(reencoded, type(msg))
    assert same(to_plain(back), to_plain(msg))


def test_rosbags_typestore_uses_msg_defs_text():
    """The definitions registered for bags are the msg_defs files themselves (one source)."""
    from seaforce_ros.bags.definitions import make_typestore, message_definitions

    root = pathlib.Path(__file__).resolve().parent.parent
    defs = message_definitions()
    for name in TYPES.values():
        assert defs[f'seaforce_msgs/msg/{name}'] == (root / 'msg_defs' / 'msg' / f'{name}.msg').read_text()
    store = make_typestore()
    msgdef = store.generate_msgdef('seaforce_msgs/msg/ActuatorState')
    assert 'uint8 STATUS_FAULT=4' in msgdef[0]

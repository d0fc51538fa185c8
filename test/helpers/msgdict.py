"""Message <-> plain data for field-by-field comparisons in tests."""
import array
import math


def to_plain(msg):
    """Recursively convert an rclpy message to dicts / lists / scalars."""
    if hasattr(msg, 'get_fields_and_field_types'):
        return {field: to_plain(getattr(msg, field)) for field in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple, array.array)):
        return [to_plain(v) for v in msg]
    if hasattr(msg, 'tolist'):  # numpy arrays / scalars
        return msg.tolist()
    if isinstance(msg, (bytes, bytearray)):
        return list(msg)
    return msg


def rosbags_to_plain(msg):
    """Same conversion for a rosbags (dataclass) message."""
    if hasattr(msg, '__dataclass_fields__'):
        return {field: rosbags_to_plain(getattr(msg, field))
                for field in msg.__dataclass_fields__
                if field != '__msgtype__' and not field.isupper()}  # constants are fields too
    if hasattr(msg, 'tolist'):
        return msg.tolist()
    if isinstance(msg, (list, tuple)):
        return [rosbags_to_plain(v) for v in msg]
    return msg


def same(a, b) -> bool:
    """Exact equality of plain data, where NaN equals NaN."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def sample_messages():
    """One populated instance of each seaforce_msgs message, with awkward values."""
    from seaforce_msgs.msg import ActuatorCommand, ActuatorState, ControllerStatus

    names = ['wrist', 'pinch']
    state = ActuatorState()
    state.header.stamp.sec = 1_790_000_000
    state.header.stamp.nanosec = 123_456_789
    state.header.frame_id = 'gripper'
    state.cycle = 2**64 - 1
    state.name = names
    state.motor_position = [0.125, -1.0e-300]
    state.motor_velocity = [float('inf'), -3.5]
    state.pressure_force = [0.0321, -0.0]
    state.motor_effort = [1.0e300, -2.25]
    state.endpoint_position = [float('nan'), 0.4999999999999999]
    state.external_force = [float('nan'), 1.0 / 3.0]
    state.status = [ActuatorState.STATUS_OK,
                    ActuatorState.STATUS_COMMAND_TIMEOUT | ActuatorState.STATUS_FAULT]

    command = ActuatorCommand()
    command.header.stamp.sec = 7
    command.cycle = 42
    command.name = names
    command.effort = [0.3, -float('inf')]

    status = ControllerStatus()
    status.header.frame_id = 'gripper'
    status.cycle = 12345678901234
    status.name = names
    status.mode = ['dob_full_ff', 'hold']
    status.disturbance = [1e-9, -0.2]
    status.feedforward = [0.0, 5.5]
    status.endpoint_velocity_estimate = [-1.0, float('nan')]
    status.dahl_force = [0.032, -0.031999]
    status.fault = ['', 'torque 7.5 N m beyond max_torque 5 N m']
    status.contact = [False, True]
    status.contact_position = [float('nan'), 0.2125]
    status.contact_force = [1e-5, 0.5]
    status.object_stiffness = [float('nan'), 4.75]
    status.object_stiffness_sigma = [float('nan'), float('inf')]
    status.object_damping = [float('nan'), -0.0021]
    status.object_damping_sigma = [float('nan'), 0.012]
    status.grasp_phase = ['', 'hold']
    status.passivity_energy = [float('nan'), -2.5e-4]
    status.passivity_dissipated = [float('nan'), 0.0125]
    status.passivity_damping = [float('nan'), 0.5]
    return {'actuator_state': state, 'actuator_command': command, 'controller_status': status}

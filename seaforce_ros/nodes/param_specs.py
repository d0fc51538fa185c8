"""The ROS parameters of the nodes, generated from the core's parameter tables.

Per-channel keys are ``<channel>.<key>`` with ``<key>`` from
:data:`seaforce_ros.core.params.PARAMETERS` (controller: description and range per key) and
the simulator tables below. A value is checked against its range (and type, finiteness,
allowed strings) at declaration and on every set; cross-parameter rules (DOB passivity,
eq. 28) are checked by the core in the nodes' on-set callbacks.
"""
from __future__ import annotations

from typing import Dict, List

from ..core.environment import DRIVE_DAMPING, DRIVE_STIFFNESS, ENVIRONMENT_MODES
from ..core.errors import InvalidParameterError
from ..core.params import MODES, PARAMETERS, ControllerConfig, PlantParams
from ..core.sensors import SensorParams
from .ros_common import EXECUTORS, ParamSpec, StartupError

#: The zero-torque mode was called ``off``, which YAML 1.1 reads as a boolean.
MODE_RENAMED = 'the zero-torque mode formerly called off is passive'
#: The passivity guard's settings are not off/on, which YAML 1.1 reads as booleans.
GUARD_RENAMED = 'the guard is disabled, monitor or active (off/on would be YAML booleans)'

PLANT_KEYS = tuple(k for k in PARAMETERS if k.startswith('plant.'))
DAHL_KEYS = tuple(k for k in PARAMETERS if k.startswith('dahl.'))

ENVIRONMENT_SPECS = (
    ('environment.mode', 'free', 'endpoint environment: ' + ', '.join(ENVIRONMENT_MODES), None),
    ('environment.amplitude', 0.5, 'amplitude [N m for torque modes, rad for position_sine]',
     (0.0, 100.0)),
    ('environment.frequency', 1.0, 'sine frequency [rad/s]', (0.0, 1e5)),
    ('environment.start_frequency', 0.01, 'torque chirp start frequency [Hz]', (1e-6, 1e4)),
    ('environment.end_frequency', 1000.0, 'torque chirp end frequency [Hz]', (1e-6, 1e4)),
    ('environment.duration', 60.0, 'torque chirp duration [s]', (1e-3, 1e6)),
    ('environment.stiffness', DRIVE_STIFFNESS,
     'position drive spring to the endpoint, or the object\'s stiffness k_o [N m/rad]',
     (0.0, 1e6)),
    ('environment.damping', DRIVE_DAMPING,
     'position drive damper to the endpoint, or the object\'s damping b_o [N m s/rad]',
     (0.0, 1e4)),
    ('environment.offset', 0.0, 'centre of the position drive [rad]', (-100.0, 100.0)),
    ('environment.position', 0.0, 'object surface: mode object touches the endpoint at '
     'X_e > position, F_e = -(k_o (X_e - position) + b_o V_e) while it pushes [rad]',
     (-100.0, 100.0)),
)

_SENSORS = SensorParams()
SIM_CHANNEL_SPECS = (
    ('sim.motor_coulomb', 0.0, 'motor Coulomb friction [N m]', (0.0, 100.0)),
    ('sim.endpoint_coulomb', 0.0,
     'endpoint Coulomb friction [N m] (unobservable from pressure)', (0.0, 100.0)),
    ('sim.backlash', 0.0, 'dead zone between position drive and endpoint [rad]', (0.0, 10.0)),
    ('sim.torque_saturation', 10.0, 'motor and drive torque saturation of the simulated '
     'plant [N m] (physics; the safety clamp is the node\'s torque_limit)', (1e-6, 1e3)),
    ('sensors.pressure_range', float(_SENSORS.pressure_range),
     'pressure ADC full scale, as +-F_p [N m]', (1e-6, 1e4)),
    ('sensors.pressure_noise', float(_SENSORS.pressure_noise),
     'pressure noise standard deviation [N m]', (0.0, 100.0)),
    ('sensors.motor_counts_per_rev', int(_SENSORS.motor_counts_per_rev),
     'motor encoder counts per revolution (0: ideal)', (0, 2**40)),
    ('sensors.endpoint_counts_per_rev', int(_SENSORS.endpoint_counts_per_rev),
     'endpoint encoder counts per revolution (0: ideal)', (0, 2**40)),
)


def channels_spec(default=('wrist', 'pinch')) -> ParamSpec:
    return ParamSpec('channels', list(default),
                     'names of the actuator channels, in message order (same in every node)',
                     read_only=True)


def executor_spec(default='events') -> ParamSpec:
    return ParamSpec('executor', default,
                     'rclpy executor: events (fast; spun so parameter services answer) or '
                     'single_threaded', choices=EXECUTORS, read_only=True)


def controller_channel_specs(channel: str) -> List[ParamSpec]:
    """Every controller parameter of one channel, defaults = Table I config."""
    defaults = ControllerConfig(plant=PlantParams.table_i()).to_dict()
    specs = []
    for key, info in PARAMETERS.items():
        default = defaults[key]
        if isinstance(default, int) and not isinstance(default, bool):
            default = float(default)
        specs.append(ParamSpec(f'{channel}.{key}', default, info.description, low=info.low,
                               high=info.high,
                               choices=MODES if key == 'mode' else info.choices,
                               choice_hint=MODE_RENAMED if key == 'mode' else (
                                   GUARD_RENAMED if key == 'passivity_guard' else '')))
    return specs


def sim_channel_specs(channel: str) -> List[ParamSpec]:
    """Simulated-plant parameters of one channel: the model (``plant.*``, ``dahl.*``, read-only,
    as the controller has it), the sim's own settings and the environment. The true plant
    ``sim.plant.*`` / ``sim.dahl.*`` follows from the model: :func:`sim_plant_specs`."""
    defaults = ControllerConfig(plant=PlantParams.table_i()).to_dict()
    specs = []
    for key in PLANT_KEYS + DAHL_KEYS:
        info = PARAMETERS[key]
        specs.append(ParamSpec(f'{channel}.{key}', float(defaults[key]),
                               info.description + ' (the model; the simulated plant is '
                               f'{channel}.sim.{key})', low=info.low, high=info.high,
                               read_only=True))
    for key, default, description, rng in SIM_CHANNEL_SPECS:
        low, high = rng
        specs.append(ParamSpec(f'{channel}.{key}', default, description, low=low, high=high,
                               read_only=True))
    for key, default, description, rng in ENVIRONMENT_SPECS:
        low, high = rng if rng else (None, None)
        specs.append(ParamSpec(f'{channel}.{key}', default, description, low=low, high=high,
                               choices=ENVIRONMENT_MODES if key == 'environment.mode' else ()))
    return specs


def sim_plant_specs(channel: str, model: Dict[str, object]) -> List[ParamSpec]:
    """The simulated gripper's true plant and Dahl hysteresis, ``<channel>.sim.plant.*`` /
    ``<channel>.sim.dahl.*``, each defaulting to the model's value in ``model``
    (``{'<channel>.plant.<x>': value}``): set them to run the controller on a wrong model;
    they change at run time (a drifting plant)."""
    return [ParamSpec(f'{channel}.sim.{key}', float(model[f'{channel}.{key}']),
                      PARAMETERS[key].description + ' (the simulated plant, default the model)',
                      low=PARAMETERS[key].low, high=PARAMETERS[key].high)
            for key in PLANT_KEYS + DAHL_KEYS]


def channel_values(values: Dict[str, object], channel: str, prefix: str = '') -> Dict[str, object]:
    """``{'<channel>.<prefix>x': v}`` -> ``{'<prefix>x': v}`` for one channel."""
    head = f'{channel}.{prefix}'
    return {k[len(channel) + 1:]: v for k, v in values.items() if k.startswith(head)}


def channels_from(values: Dict[str, object]) -> List[str]:
    """The validated ``channels`` parameter: unique, non-empty ROS-name-safe tokens.

    Raises :class:`~seaforce_ros.nodes.ros_common.StartupError` saying what to write instead.
    """
    channels = list(values['channels'])
    if not channels:
        raise StartupError('channels is empty: name at least one channel, e.g. [wrist, pinch]')
    for name in channels:
        if not name or not name.replace('_', 'a').isalnum() or name[0].isdigit():
            raise StartupError(f'channel name {name!r} must be letters, digits and _, '
                               'not starting with a digit')
    if len(set(channels)) != len(channels):
        raise StartupError(f'channel names must be unique: {channels}')
    return channels


def channel_error(exc: Exception, channel: str) -> str:
    """The core's rejection of one channel's setting, naming every parameter in full
    (``pinch.dob.nominal_inertia``, ``pinch.allow_non_passive``) as a ROS user sets it."""
    if isinstance(exc, InvalidParameterError):
        return str(exc.in_channel(channel))
    return f'channel {channel}: {exc}'

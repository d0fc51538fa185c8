"""Control core of seaforce_ros: plain Python + numpy (+ python-control/scipy
for analysis). Never imports rclpy, message packages or pysoem.

Modules
-------
errors      exception types
params      validated parameter dataclasses, flat ROS-key mapping
plant       continuous LTI model (Fig. 4 plants, impedances)
passivity   DOB admittance (eq. 25), passivity bounds (eq. 28), numerical check
passivity_guard  time-domain passivity guard of the DOB's motor port
analysis    force-feedback comparison (Fig. 7), low-frequency limits, Z-width,
            impedance from time series, hold-gain design
dahl        Dahl hysteresis (eq. 14-15), exact per-sample update
controller  ChannelController (all modes), 2 kHz hot path
sensors     sensor models
environment endpoint environments
simulator   ChannelSimulator, run_closed_loop
"""

from .errors import (SeaforceError, InvalidParameterError, NonPassiveError,
                     NonFiniteInputError)
from .params import (MODES, DOB_MODES, PlantParams, DahlParams, DobParams,
                     ControllerConfig, PARAMETERS)
from .dahl import DahlState
from .controller import ChannelController
from .sensors import SensorParams
from .environment import (Environment, free, torque_sine, torque_chirp,
                          position_sine, environment_from_dict)
from .simulator import Measurement, ChannelSimulator, run_closed_loop

__all__ = [
    "SeaforceError", "InvalidParameterError", "NonPassiveError", "NonFiniteInputError",
    "MODES", "DOB_MODES", "PlantParams", "DahlParams", "DobParams", "ControllerConfig",
    "PARAMETERS", "DahlState", "ChannelController", "SensorParams",
    "Environment", "free", "torque_sine", "torque_chirp", "position_sine",
    "environment_from_dict", "Measurement", "ChannelSimulator", "run_closed_loop",
]

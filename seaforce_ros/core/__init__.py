"""Control core of seaforce_ros: plain Python + numpy (+ python-control/scipy for analysis).
Never imports rclpy, message packages or pysoem (a test enforces it).

Modules
-------
errors               exception types (one root, :class:`SeaforceError`)
schema               the parameter schema: one row per parameter, everything else derived
params               the controller's parameter groups per channel, passivity rules (eq. 28)
settings             the nodes' own parameters (rates, executors, files, the sim's physics)
plant                continuous LTI model (Fig. 4 plants, impedances)
passivity            DOB admittance (eq. 25), passivity bounds (eq. 28), numerical check
passivity_guard      time-domain passivity guard of the DOB's motor port
analysis             force-feedback comparison (Fig. 7), low-frequency limits, Z-width,
                     impedance from time series, hold-gain design
dahl                 Dahl hysteresis (eq. 14-15), exact per-sample update
signals              log chirps and their fades
observer             endpoint observer: hose inversion, Dahl play, friction feed-forward
dob                  disturbance observer (eq. 19), bumpless entry
modes                the nine modes, one small class each, keyed by name
controller           ChannelController: the 2 kHz update of one channel, in stages
estimator            contact detection and object impedance from motor state and pressure
jobs                 what overrides a channel's mode for a while: the job protocol
grasp                a grasp: approach, squeeze, probe, hold, release
gripper              a gripper command: a grasp whose approach stops at a position
friction_calibration endpoint friction calibration and online adaptation
handover             hand-over of values between threads at a safe point
episodes             repeated conditions counted, reported once per episode, throttled
control_cycle        the controller side of the real-time cycle: checks, faults, torque
plant_cycle          the plant side: what torque each channel may have this cycle
sensors              sensor models
environment          endpoint environments of the simulator
simulator            ChannelSimulator, run_closed_loop
nonlinear_effects    the sim's nonlinear effects (sim.nonlinear.*), their forces and draws
nonlinear_simulator  NonlinearChannelSimulator, make_simulator
backend              PlantBackend: the plant behind a plant node, with a lifecycle
sim_backend          SimBackend: the simulator as a PlantBackend
"""

from .errors import (SeaforceError, InvalidParameterError, NonPassiveError,
                     NonFiniteInputError)
from .params import (MODES, DOB_MODES, PlantParams, DahlParams, DobParams, TargetParams,
                     HoldParams, ForceFeedbackParams, ChirpParams, FeedforwardParams,
                     EstimatorParams, GraspParams, FrictionParams, GuardParams,
                     ControllerConfig, PARAMETERS)
from .dahl import DahlState
from .controller import ChannelController
from .sensors import SensorParams
from .environment import (Environment, free, torque_sine, torque_chirp,
                          position_sine, contact_object, environment_from_dict)
from .simulator import Measurement, ChannelSimulator, run_closed_loop

__all__ = [
    "SeaforceError", "InvalidParameterError", "NonPassiveError", "NonFiniteInputError",
    "MODES", "DOB_MODES", "PlantParams", "DahlParams", "DobParams", "TargetParams",
    "HoldParams", "ForceFeedbackParams", "ChirpParams", "FeedforwardParams", "EstimatorParams",
    "GraspParams", "FrictionParams", "GuardParams", "ControllerConfig", "PARAMETERS",
    "DahlState", "ChannelController", "SensorParams", "Environment", "free", "torque_sine",
    "torque_chirp", "position_sine", "contact_object", "environment_from_dict",
    "Measurement", "ChannelSimulator", "run_closed_loop",
]

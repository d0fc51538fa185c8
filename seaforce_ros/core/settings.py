"""The nodes' own parameters (no algorithm reads them: rates, executors, files, the sim's
physics and the hardware's bus), as :mod:`.schema` rows like every other parameter.

The groups of the algorithms live with them: the controller's per channel in :mod:`.params`,
:class:`~.control_cycle.StateChecks` (the controller's state checks),
:class:`~.plant_cycle.PlantLimits` (what a plant allows), the sim's
:class:`~.environment.Environment` and :class:`~.sensors.SensorParams`. The sim also declares
the controller's model (``plant.*``, ``dahl.*``) read-only and the true plant it simulates
(``sim.plant.*``, ``sim.dahl.*``, default: the model): :data:`SIM_MODEL_GROUPS`.
"""
from __future__ import annotations

from typing import Tuple

from .params import DahlParams, PlantParams
from .schema import (BRINGUP, CONTROLLER, HARDWARE, PLANTS, RECORDER, SIM, ParameterGroup,
                     group, param)

__all__ = ["CommonSettings", "ControllerSettings", "BringupSettings", "PlantSettings",
           "SimSettings", "SimulatorParams", "HardwareSettings", "RecorderSettings",
           "EXECUTORS", "CONTROL_QOS", "LOOPS", "CLOCK_MODES", "AUTOSTART_STATES", "STORAGES",
           "DEFAULT_TOPICS",
           "SIM_MODEL_GROUPS", "SIM_PREFIX"]

EXECUTORS = ("events", "single_threaded")
CONTROL_QOS = ("reliable", "best_effort")
LOOPS = ("topics", "direct")
CLOCK_MODES = ("realtime", "lockstep")
#: The lifecycle states a plant node can take by itself at start (managed-node labels).
AUTOSTART_STATES = ("unconfigured", "inactive", "active")
STORAGES = ("mcap", "sqlite3")
#: The package's own topics bag_recorder records by default.
DEFAULT_TOPICS = ("actuator_state", "actuator_command", "controller_status")
#: The model groups the sim declares read-only (the controller's model) and again under
#: :data:`SIM_PREFIX` (the plant it simulates, default the model; they change at run time).
SIM_MODEL_GROUPS: Tuple[type[ParameterGroup], ...] = (PlantParams, DahlParams)
SIM_PREFIX = "sim."

_CONTROL_NODES = (CONTROLLER, SIM, HARDWARE)


@group("", nodes=_CONTROL_NODES, per_channel=False)
class CommonSettings(ParameterGroup):
    """What every node of the control loop declares alike."""

    channels: list = param(["wrist", "pinch"], "", "names of the actuator channels, in message "
                           "order (the same in every node of a setup)", read_only=True)
    rate: float = param(2000.0, "Hz", "cycle rate of a plant; the controller derives its sample "
                        "period from it and must have its state source's", ge=1.0, le=20000.0,
                        read_only=True)
    executor: str = param("events", "", "rclpy executor: events (fast; spun so parameter "
                          "services answer) or single_threaded", choices=EXECUTORS,
                          read_only=True, nodes=_CONTROL_NODES + (RECORDER,))
    control_qos: str = param("reliable", "", "reliability of actuator_state/actuator_command: "
                             "reliable (required by lockstep) or best_effort",
                             choices=CONTROL_QOS, read_only=True)
    diagnostics_period: float = param(1.0, "s", "/diagnostics period", ge=0.05, le=60.0,
                                      read_only=True)


@group("", nodes=(CONTROLLER,), per_channel=False)
class ControllerSettings(ParameterGroup):
    """controller_node's own settings (its state checks: :class:`~.control_cycle.StateChecks`)."""

    status_rate: float = param(100.0, "Hz", "controller_status rate, 0 = off", ge=0.0,
                               le=20000.0)
    commissioning_directory: str = param(
        "", "", "where ~/commission writes a directory per run (report, record, params and "
        "rollback files) and finds the last run of a channel, read at each goal; default "
        "seaforce_commissioning in the working directory", key="commissioning.directory")
    commissioning_params_file: str = param(
        "", "", "params file ~/commission writes the tuned values into, its comments kept (the "
        "setup's YAML, say), read at each goal; default params.yaml in the run's directory",
        key="commissioning.params_file")


@group("", nodes=(BRINGUP,), per_channel=False)
class BringupSettings(ParameterGroup):
    """What the composed executables (bringup, hardware_bringup) add to the controller."""

    loop: str = param("topics", "", "topics: states and commands through DDS; direct: the "
                      "plant's cycle thread calls the controller (both still published)",
                      choices=LOOPS, read_only=True)


@group("", nodes=PLANTS, per_channel=False)
class PlantSettings(ParameterGroup):
    """What sim_node and hardware_node declare alike (their limits:
    :class:`~.plant_cycle.PlantLimits`)."""

    joint_state_rate: float = param(100.0, "Hz", "sensor_msgs/JointState rate, 0 = off",
                                    ge=0.0, le=20000.0)
    # hardware: inactive, so that a drive is enabled only by an explicit `activate`, while a
    # bus fault (a missing slave, a wrong identity) still shows at start, as before
    autostart: str = param("inactive", "", "lifecycle state the node goes to by itself at "
                           "start: unconfigured (wait for configure), inactive (configured: "
                           "plant checked, no torque; wait for activate) or active (torque "
                           "follows actuator_command at once); then `ros2 lifecycle set` moves "
                           "it", choices=AUTOSTART_STATES, read_only=True,
                           node_defaults={SIM: "active"})


@group("", nodes=(SIM,), per_channel=False)
class SimSettings(ParameterGroup):
    """sim_node's own settings."""

    clock_mode: str = param("realtime", "", "realtime: own cycle at `rate`; lockstep: one "
                            "sample per received command", choices=CLOCK_MODES,
                            read_only=True)
    seed: int = param(0, "", "seed of the sensor noise generators (channel i uses seed + i)",
                      ge=0, le=2**31 - 1, read_only=True)


@group("sim", nodes=(SIM,))
class SimulatorParams(ParameterGroup):
    """The simulated gripper's physics beyond the model (per channel)."""

    motor_coulomb: float = param(0.0, "N m", "motor Coulomb friction", ge=0.0, le=100.0,
                                 read_only=True)
    endpoint_coulomb: float = param(0.0, "N m", "endpoint Coulomb friction (unobservable "
                                    "from pressure)", ge=0.0, le=100.0, read_only=True)
    backlash: float = param(0.0, "rad", "dead zone between position drive and endpoint",
                            ge=0.0, le=10.0, read_only=True)
    torque_saturation: float = param(10.0, "N m", "motor and drive torque saturation of the "
                                     "simulated plant (physics; the safety clamp is the node's "
                                     "torque_limit)", gt=0.0, le=1e3, read_only=True)


@group("", nodes=(HARDWARE,), per_channel=False)
class HardwareSettings(ParameterGroup):
    """hardware_node's own settings (the bus)."""

    interface: str = param("", "", "network interface of the EtherCAT bus (required; `ip link` "
                           "lists them; a dedicated NIC)", read_only=True)
    bus_config: str = param("", "", "bus YAML: slaves in bus order with identities, PDO "
                            "entries and how each is configured at PRE-OP (CoE mapping, "
                            "start-up SDOs, distributed clocks), scaling (its keys: the Bus "
                            "YAML section below)", read_only=True,
                            default_note="the package's config/ethercat_bus.yaml")
    drive_watchdog: float = param(0.1, "s", "process-data watchdog programmed into every "
                                  "drive: it drops torque on its own when the master stops "
                                  "for this long", ge=0.001, le=6.0, read_only=True)
    receive_timeout: float = param(4e-4, "s", "wait for the process-data frame", ge=1e-5,
                                   le=0.1, read_only=True)
    fault_reset_time: float = param(0.01, "s", "each half of a drive's fault-reset pulse "
                                    "(controlword bit 7 low, then high) is held this long, so "
                                    "that a drive sampling the controlword slower than the "
                                    "cycle sees the edge", ge=1e-4, le=0.04, read_only=True,
                                    hint="a reset's grace period for a drive still in Fault "
                                    "is 0.1 s")


@group("", nodes=(RECORDER,), per_channel=False)
class RecorderSettings(ParameterGroup):
    """bag_recorder's settings."""

    topics: list = param(list(DEFAULT_TOPICS), "", "topics to record (relative names resolve "
                         "in the node namespace)", read_only=True)
    output: str = param("", "", "bag directory (created; must be new or empty); default "
                        "bag_recorder_<date>_<time> in the working directory", read_only=True)
    storage: str = param("mcap", "", "rosbag2 storage plugin", choices=STORAGES,
                         read_only=True)
    split_duration: float = param(10.0, "s", "receive time per storage file; metadata.yaml is "
                                  "rewritten as each one closes", ge=0.1, le=86400.0,
                                  read_only=True)
    chunk_period: float = param(0.5, "s", "mcap: a chunk is written at least this often (a "
                                "SIGKILL loses about this much of the open file)", ge=0.01,
                                le=60.0, read_only=True)
    queue_limit: float = param(64.0, "MB", "messages waiting for the writer beyond this are "
                               "dropped and counted", ge=1.0, le=65536.0, read_only=True)
    reliability: str = param("reliable", "", "QoS reliability of the subscriptions (must be "
                             "compatible with the publishers: best_effort also matches "
                             "reliable ones)", choices=CONTROL_QOS, read_only=True)
    report_period: float = param(5.0, "s", "period of the count log line and /diagnostics",
                                 ge=0.1, le=3600.0, read_only=True)

"""The plant behind a plant node, as a backend with a lifecycle (no ROS).

A plant node (sim_node, hardware_node) keeps the ROS side of the loop once -- the topics, the
parameters, the cycle thread, :class:`~.plant_cycle.PlantCycle`'s judging -- and composes one
:class:`PlantBackend`: the simulator (:class:`~.sim_backend.SimBackend`) or the EtherCAT bus
(:class:`seaforce_ros.ethercat.backend.EthercatBackend`). The split is ros2_control's: a
hardware component (``hardware_interface::SystemInterface``) is a plain class with lifecycle
callbacks and ``read``/``write``; the manager that owns it drives the lifecycle and the loop.

Lifecycle of a backend (each step is called by the managed node's transition of the same
meaning; ``closed`` is where a backend starts)::

    closed --open()--> opened --configure()--> configured --activate()--> active
    active --deactivate()--> configured            any state --close()--> closed

``open``
    Take what the backend needs without acting on the plant (EtherCAT: the network
    interface). ros2_control does this in ``on_init``/``on_configure``.
``configure``
    ros2_control's ``on_configure``: communication with the plant is established and
    checked (EtherCAT: every slave found with its identity checked, process data mapped, bus
    in SAFE-OP, the drives' watchdog programmed). Nothing can reach an actuator yet: no
    torque.
``activate``
    ``on_activate``: the actuators may take torque (EtherCAT: bus in OP, drives told to walk
    to Operation enabled). The node's cycle starts right after it; from then on the backend
    expects one :meth:`~PlantBackend.read` / :meth:`~PlantBackend.write` pair per cycle.
``read`` / :meth:`~PlantBackend.drives` / ``write``
    Once per cycle on the cycle thread, in that order: take a sample, report the drives'
    readiness to PlantCycle, apply what PlantCycle allowed (a :class:`~.plant_cycle.PlantOutput`).
``deactivate``
    ``on_deactivate``: zero torque, actuators disabled (EtherCAT: drives in Switch on
    disabled, bus back in SAFE-OP); the backend is configured again, no cycle runs.
``close``
    ``on_cleanup`` / ``on_shutdown``: from any state (it deactivates first when active),
    communication closed (EtherCAT: bus in INIT, the interface given back as it was).
    Idempotent; never raises: it is the safe-state path of every error.

A transition that cannot be done raises :class:`BackendError` (or a subclass) whose message
says what to check or fix; the backend is then left where the node's error handling can take
it back down with :meth:`~PlantBackend.deactivate` or :meth:`~PlantBackend.close`.
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from typing import Any, Dict, List, NamedTuple, Optional, Sequence, Tuple

from .errors import SeaforceError
from .plant_cycle import PlantOutput

__all__ = ["BackendError", "PlantSample", "LinkStatus", "LINK_COMPLETE", "LINK_NOTHING",
           "ChannelReport", "BackendReport", "PlantBackend"]

NAN = math.nan


class BackendError(SeaforceError, RuntimeError):
    """A backend's transition could not be done; the message says what to check or fix."""


class PlantSample:
    """One synchronous sample of every channel, as :meth:`PlantBackend.read` fills it (each
    list indexed like the backend's channels).

    Attributes
    ----------
    position : list of float
        Motor position X [rad].
    velocity : list of float
        Motor velocity V [rad/s].
    pressure_force : list of float
        Internal (pressure) force F_p [N m].
    effort : list of float
        Motor torque F_a applied during the cycle that led to this sample [N m].
    endpoint_position : list of float
        Endpoint position X_e [rad]; NaN where there is no endpoint encoder.
    external_force : list of float
        External force F_e [N m]; NaN where it is not measured.
    endpoint_velocity : list of float
        Endpoint velocity V_e [rad/s] for ``joint_states``; NaN where it is not measured.
    flags : list of int
        Status bits the plant adds to PlantCycle's (``STATUS_LIMIT`` while a simulated drive
        saturates).
    """

    __slots__ = ("position", "velocity", "pressure_force", "effort", "endpoint_position",
                 "external_force", "endpoint_velocity", "flags")

    def __init__(self, n: int) -> None:
        self.position = [0.0] * n
        self.velocity = [0.0] * n
        self.pressure_force = [0.0] * n
        self.effort = [0.0] * n
        self.endpoint_position = [NAN] * n
        self.external_force = [NAN] * n
        self.endpoint_velocity = [NAN] * n
        self.flags = [0] * n


class LinkStatus(NamedTuple):
    """How a :meth:`PlantBackend.read` went (PlantCycle judges it with
    :meth:`~.plant_cycle.PlantCycle.exchange`).

    Attributes
    ----------
    received : bool
        An answer to the previous write came back; False when none was in flight (the first
        cycle after activation): no sample and no error.
    counter : int
        Working counter of that answer (EtherCAT); ``expected`` when it was complete.
    expected : int
        The counter of a complete answer; the sample is fresh only when the two agree.
    """

    received: bool
    counter: int
    expected: int


#: A backend without a link to lose (the simulator): every read is complete.
LINK_COMPLETE = LinkStatus(True, 1, 1)
#: Nothing was in flight: no sample this cycle, no error.
LINK_NOTHING = LinkStatus(False, 0, 0)


@dataclass
class ChannelReport:
    """What a backend reports about one channel for ``/diagnostics``.

    Attributes
    ----------
    hardware_id : str
        The device (a drive's name on the bus, ``seaforce_sim/<channel>``).
    values : dict
        Extra key/values; a ``state`` entry becomes the status message when all is well.
    """

    hardware_id: str
    values: Dict[str, Any] = field(default_factory=dict)


@dataclass
class BackendReport:
    """What a backend reports for ``/diagnostics`` while active.

    Attributes
    ----------
    name : str
        Name of the node-level status (``hardware: bus``, ``sim: cycle``).
    hardware_id : str
        The device of the node-level status (the interface, ``seaforce_sim``).
    running : str
        Message while all is well (``OP``, ``running (realtime)``).
    warning : str
        A condition worth a WARN ('' when none).
    values : dict
        Key/values appended to the node's own figures.
    channel_prefix : str
        Prefix of the per-channel statuses (``hardware`` -> ``hardware: pinch``).
    channels : list of ChannelReport
        One per channel, in channel order.
    """

    name: str
    hardware_id: str
    running: str
    warning: str = ""
    values: Dict[str, Any] = field(default_factory=dict)
    channel_prefix: str = ""
    channels: List[ChannelReport] = field(default_factory=list)


class PlantBackend(abc.ABC):
    """The plant a plant node composes (see the module docstring for the lifecycle).

    Attributes
    ----------
    channels : tuple of str
        Channel names, in the order of every per-channel list.
    units_per_nm : tuple of float or None
        Drive units per N m per channel (PlantCycle rounds torques to them), None when the
        plant takes torque in N m.
    status_name : str
        Name of the node-level ``/diagnostics`` status, also before configure.
    hardware_id : str
        The device of that status.
    channel_prefix : str
        Prefix of the per-channel ``/diagnostics`` status names (``<prefix>: <channel>``).
    """

    channels: Tuple[str, ...]
    units_per_nm: Optional[Tuple[float, ...]] = None
    status_name: str = ""
    hardware_id: str = ""
    channel_prefix: str = ""

    # --- lifecycle ------------------------------------------------------------------------------
    @abc.abstractmethod
    def open(self) -> str:
        """Take the backend's resources without acting on the plant; returns what was done
        (for the log). Raises :class:`BackendError`."""

    @abc.abstractmethod
    def configure(self) -> str:
        """Establish and check communication with the plant; no torque can reach an
        actuator. Returns what was done. Raises :class:`BackendError`."""

    @abc.abstractmethod
    def activate(self) -> str:
        """Let the actuators take torque; the cycle (read, drives, write) follows at once.
        Returns what was done. Raises :class:`BackendError`."""

    @abc.abstractmethod
    def deactivate(self) -> str:
        """Zero torque and actuators disabled; configured again. Returns what was done.
        Raises :class:`BackendError` if the plant did not follow."""

    @abc.abstractmethod
    def close(self) -> str:
        """Back to closed from any state, the plant left safe; returns what was done ('' if
        there was nothing to close). Never raises."""

    # --- the cycle ------------------------------------------------------------------------------
    @abc.abstractmethod
    def read(self, sample: PlantSample) -> LinkStatus:
        """Fill ``sample`` with the newest sample of the plant; its values count only when
        the returned status is complete (``received`` and ``counter == expected``)."""

    def drives(self) -> Optional[Sequence[Tuple[bool, bool] | Tuple[bool, bool, str]]]:
        """Per channel ``(torque_allowed, faulted)`` of the drives after the newest read, with
        the fault's reason as a third element where the backend knows it (the ``drives`` of
        :meth:`~.plant_cycle.PlantCycle.step`); None: no drives and no fault (simulation)."""
        return None

    def clock_correction(self) -> float:
        """How far to shift the cycle's next deadlines [s] (negative: earlier) so that it
        follows the plant's clock (EtherCAT distributed clocks); 0.0: the host's own clock.
        Called once per cycle after :meth:`write`."""
        return 0.0

    @abc.abstractmethod
    def write(self, command: PlantOutput) -> None:
        """Apply PlantCycle's decision: ``command.torque`` [N m] (or ``command.units``),
        ``command.enable`` and ``command.fault_reset`` per channel."""

    # --- monitoring -----------------------------------------------------------------------------
    @abc.abstractmethod
    def diagnostics(self) -> BackendReport:
        """The backend's figures for ``/diagnostics`` while active."""

"""The simulated gripper as a :class:`~.backend.PlantBackend` (no ROS).

One :class:`~.simulator.ChannelSimulator` per channel. Its lifecycle steps only keep the
physics still: nothing to open or check, and nothing runs while the backend is not active
(the node's cycle stops), so the simulated fingers rest where they were. An environment or a
true-plant change (:meth:`SimBackend.set_environment`, :meth:`SimBackend.set_plant`, from the
node's parameter callbacks on another thread) takes effect at the next :meth:`SimBackend.write`,
i.e. at the start of a simulated step.

A channel whose physics leaves the finite numbers (:class:`~.errors.SimulationDivergedError`:
a nonlinear plant too stiff for the step) is a drive that faults: :meth:`SimBackend.drives`
reports it with the reason, the plant cycle latches it (zero torque, ``STATUS_FAULT``) and the
channel stays at its last finite state, stepping no more, until the cycle's fault reset
(``~/reset``) restarts it at rest. The other channels run on.
"""
from __future__ import annotations

from typing import Dict, Optional, Sequence, Tuple

from .backend import (LINK_COMPLETE, BackendReport, ChannelReport, LinkStatus, PlantBackend,
                      PlantSample)
from .environment import Environment
from .errors import SimulationDivergedError
from .params import DahlParams, PlantParams
from .plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_LIMIT, PlantOutput
from .simulator import ChannelSimulator

__all__ = ["SimBackend"]


class SimBackend(PlantBackend):
    """The simulated gripper (see module docstring).

    Parameters
    ----------
    channels : sequence of str
        Channel names.
    simulators : sequence of ChannelSimulator
        One per channel, in channel order.
    clock_mode : str
        ``realtime`` or ``lockstep``: how the node paces the cycle (reported; in lockstep a
        channel waiting for its command is not a warning: the simulation waits too).
    """

    status_name = "sim: cycle"
    hardware_id = "seaforce_sim"
    channel_prefix = "sim"

    def __init__(self, channels: Sequence[str], simulators: Sequence[ChannelSimulator],
                 clock_mode: str = "realtime") -> None:
        self.channels = tuple(channels)
        if len(simulators) != len(self.channels):
            raise ValueError(f"{len(simulators)} simulators for {len(self.channels)} channels")
        self.sims = list(simulators)
        self.clock_mode = clock_mode
        self._pending_env: Dict[int, Environment] = {}
        self._pending_plant: Dict[int, Tuple[PlantParams, Optional[DahlParams]]] = {}
        self._status: Sequence[int] = [STATUS_COMMAND_TIMEOUT] * len(self.channels)
        #: per channel: why its simulation stopped ('' while it runs)
        self.diverged: list[str] = [""] * len(self.channels)

    # --- run-time changes (any thread) -------------------------------------------------------
    def set_environment(self, index: int, environment: Environment) -> None:
        """Give channel ``index`` a new endpoint environment at its next step."""
        self._pending_env[index] = environment

    def set_plant(self, index: int, plant: PlantParams, dahl: Optional[DahlParams]) -> None:
        """Give channel ``index`` a new true plant (and Dahl hysteresis) at its next step."""
        self._pending_plant[index] = (plant, dahl)

    # --- lifecycle: the physics only rests --------------------------------------------------
    def open(self) -> str:
        return "simulated plant ready"

    def configure(self) -> str:
        return "simulated plant configured (no torque until activated)"

    def activate(self) -> str:
        return "simulated plant active"

    def deactivate(self) -> str:
        return "zero torque, simulated plant at rest"

    def close(self) -> str:
        return ""

    # --- the cycle ------------------------------------------------------------------------------
    def read(self, sample: PlantSample) -> LinkStatus:
        """The sensors' view of every channel now (advances nothing)."""
        x, v, fp, fa = sample.position, sample.velocity, sample.pressure_force, sample.effort
        xe, fe, ve, flags = (sample.endpoint_position, sample.external_force,
                             sample.endpoint_velocity, sample.flags)
        for i, sim in enumerate(self.sims):
            m = sim.measurement()
            x[i], v[i], fp[i], fa[i], xe[i], fe[i] = m.x, m.v, m.f_p, m.f_a, m.x_e, m.f_e
            ve[i] = sim.endpoint_velocity     # the simulator knows the true one
            flags[i] = STATUS_LIMIT if sim.limited else 0
        return LINK_COMPLETE

    def write(self, command: PlantOutput) -> None:
        """One simulated step [dt] of every channel under ``command.torque`` [N m]."""
        pending = self._pending_env
        if pending:
            for index in list(pending):
                self.sims[index].set_environment(pending.pop(index))
        plants = self._pending_plant
        if plants:
            for index in list(plants):
                self.sims[index].set_plant(*plants.pop(index))
        diverged = self.diverged
        for i, (sim, torque) in enumerate(zip(self.sims, command.torque)):
            if diverged[i]:
                if command.fault_reset[i]:       # ~/reset: the channel restarts at rest
                    sim.reset()
                    diverged[i] = ""
                continue
            try:
                sim.step(torque)
            except SimulationDivergedError as exc:
                diverged[i] = f"{exc}; stopped at its last finite state until ~/reset"
        self._status = command.status

    def drives(self) -> Optional[Sequence[Tuple[bool, bool, str]]]:
        """None while every channel's simulation runs; else each channel's (torque allowed,
        faulted, reason): a diverged one is a faulted drive (module docstring)."""
        if not any(self.diverged):
            return None
        return [(not d, bool(d), d) for d in self.diverged]

    # --- monitoring -----------------------------------------------------------------------------
    def diagnostics(self) -> BackendReport:
        mode = self.clock_mode
        waiting = [c for c, s in zip(self.channels, self._status) if s & STATUS_COMMAND_TIMEOUT]
        warning = ""
        if waiting and mode != "lockstep":
            warning = "command timeout: zero torque on " + ", ".join(waiting)
        return BackendReport(
            name=self.status_name, hardware_id=self.hardware_id, running=f"running ({mode})",
            warning=warning, values={"clock_mode": mode}, channel_prefix=self.channel_prefix,
            channels=[ChannelReport(f"seaforce_sim/{c}", {"environment": sim.environment.mode})
                      for c, sim in zip(self.channels, self.sims)])

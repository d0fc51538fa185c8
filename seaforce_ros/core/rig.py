"""The controller's whole cycle on the simulator, one channel, without ROS.

:class:`CycleRig` runs what the direct layout runs per sample -- the simulator's state through
:class:`~.control_cycle.ControlCycle` (state checks, :class:`~.controller.ChannelController`,
the torque and joint-limit checks, latched faults) back to the simulator, with the one-sample
command delay of :class:`~.simulator.ChannelSimulator` -- so that a test or a bench can judge
what the finger does under everything that decides torque, not only under the controller.
It records the few signals a safety judgement needs, as Python floats (the caller keeps what
it wants).
"""

from __future__ import annotations

from .control_cycle import ControlCycle
from .controller import ChannelController
from .environment import Environment
from .params import ControllerConfig
from .simulator import ChannelSimulator

__all__ = ["CycleRig"]

_T0_NS = 1_700_000_000_000_000_000


class CycleRig:
    """One channel's :class:`ControlCycle` closed around a :class:`ChannelSimulator`.

    Parameters
    ----------
    sim : ChannelSimulator
        The true plant (its ``dt`` is the cycle's).
    config : ControllerConfig
        The controller's (its model may differ from ``sim``'s plant).
    channel : str

    Attributes
    ----------
    sim, controller, cycle
    k : int
        Samples run.
    effort : float
        The last command [N m].
    """

    def __init__(self, sim: ChannelSimulator, config: ControllerConfig,
                 channel: str = "pinch") -> None:
        self.sim = sim
        self.dt = sim.dt
        self.controller = ChannelController(config, dt=sim.dt)
        self.cycle = ControlCycle((channel,), [self.controller], quiet_period=1e9)
        self.k = 0
        self.effort = 0.0
        self._names = [channel]

    def configure(self, config: ControllerConfig) -> None:
        """A new configuration (a mode switch), taken at the start of the next sample."""
        self.cycle.configure_channels({0: config})

    def set_environment(self, environment: Environment) -> None:
        """The simulator's environment from now on."""
        self.sim.set_environment(environment)

    def step(self) -> float:
        """One sample: the state through the cycle, the command to the plant. Returns the
        command [N m]."""
        m = self.sim.measurement()
        self.k += 1
        now_ns = _T0_NS + int(round(self.k * self.dt * 1e9))
        out = self.cycle.step(self._names, self.k, now_ns, [m.x], [m.v], [m.f_p], [m.f_a],
                              [0], now_ns, self.k * self.dt)
        u = out.effort[0] if out.answered else self.effort
        self.effort = u
        self.sim.step(u)
        return u

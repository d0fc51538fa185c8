"""Exception types of the control core.

Every error raised for bad input is a :class:`SeaforceError`, so that a caller
(the ROS node layer) can catch one type, report the message as the reason for
rejecting a parameter, and keep running.
"""
from typing import Any, Self

__all__ = ["SeaforceError", "InvalidParameterError", "NonPassiveError",
           "NonFiniteInputError", "SimulationDivergedError"]


class SeaforceError(Exception):
    """Base class of every error raised by :mod:`seaforce_ros.core`."""


class InvalidParameterError(SeaforceError, ValueError):
    """A parameter value is outside its allowed range.

    Parameters
    ----------
    name : str
        Parameter name: the flat key relative to the channel (``plant.motor_inertia``);
        :meth:`in_channel` qualifies it with the channel (``pinch.plant.motor_inertia``).
    value : object
        The rejected value.
    bound : str
        Human-readable description of the allowed range (``"> 0 and finite"``).
    hint : str, optional
        Why the bound exists; appended to the message.
    override : str, optional
        Key of the boolean parameter that lifts the bound (``allow_non_passive``), named
        in the message as the way to go outside it deliberately.

    Attributes
    ----------
    name, value, bound, hint, override : as given.
    """

    def __init__(self, name: str, value: Any, bound: str, hint: str = "",
                 override: str = "") -> None:
        self.name = name
        self.value = value
        self.bound = bound
        self.hint = hint
        self.override = override
        super().__init__(self._message())

    def _message(self) -> str:
        message = f"invalid parameter {self.name} = {self.value!r}: must be {self.bound}"
        if self.hint:
            message += f"; {self.hint}"
        if self.override:
            message += f"; set {self.override} to true to override"
        return message

    def in_channel(self, channel: str) -> Self:
        """The same error with every parameter it names qualified by ``channel``
        (``dob.nominal_inertia`` -> ``pinch.dob.nominal_inertia``), as a ROS user sets it."""
        qualified = Exception.__new__(type(self))
        qualified.__dict__.update(self.__dict__)
        qualified.name = f"{channel}.{self.name}"
        if self.override:
            qualified.override = f"{channel}.{self.override}"
        Exception.__init__(qualified, qualified._message())
        return qualified


class NonPassiveError(InvalidParameterError):
    """A controller setting violates the passivity bounds (paper eq. 28).

    Raised for disturbance-observer settings outside ``m_n >= m - b/lambda``
    and ``0 <= k_n <= k + lambda*b_n``, and for a proportional force-feedback
    gain outside ``-1 <= K_f <= 1``, unless the configuration sets
    ``allow_non_passive``.
    """

    def __init__(self, name: str, value: Any, bound: str) -> None:
        super().__init__(
            name, value, bound,
            hint=("the closed loop would not be passive (coupled stability with "
                  "any passive environment is lost)"),
            override="allow_non_passive")


class NonFiniteInputError(SeaforceError, ValueError):
    """A per-sample input (position, velocity, pressure force) is NaN or inf.

    Raised by :meth:`seaforce_ros.core.controller.ChannelController.update` (which
    changes nothing: validating and latching is
    :class:`~seaforce_ros.core.control_cycle.ControlCycle`'s job) and by the simulator's
    ``step`` for a non-finite torque.
    """

    def __init__(self, name: str, value: Any) -> None:
        self.name = name
        self.value = value
        super().__init__(f"non-finite input {name} = {value!r}")


class SimulationDivergedError(SeaforceError, ArithmeticError):
    """The simulated plant's state left the finite numbers: the nonlinear effects'
    magnitudes with this motion are too stiff for the simulator's step (raised by
    :class:`~seaforce_ros.core.nonlinear_simulator.NonlinearChannelSimulator`'s ``step``)."""

    def __init__(self, t: float, state: Any) -> None:
        self.t = t
        self.state = state
        super().__init__(
            f"the simulated plant diverged at t = {t:.4f} s (state {state}): the nonlinear "
            "effects (sim.nonlinear.*) are too stiff for this motion at the simulator's step; "
            "lower sim.nonlinear.hose_damping_rise or hose_stiffening, or the drive's speed")

"""Exception types of the control core.

Every error raised for bad input is a :class:`SeaforceError`, so that a caller
(the ROS node layer) can catch one type, report the message as the reason for
rejecting a parameter, and keep running.
"""

__all__ = ["SeaforceError", "InvalidParameterError", "NonPassiveError",
           "NonFiniteInputError"]


class SeaforceError(Exception):
    """Base class of every error raised by :mod:`seaforce_ros.core`."""


class InvalidParameterError(SeaforceError, ValueError):
    """A parameter value is outside its allowed range.

    Parameters
    ----------
    name : str
        Parameter name, preferably the flat ROS-style key (``plant.motor_inertia``).
    value : object
        The rejected value.
    bound : str
        Human-readable description of the allowed range (``"> 0 and finite"``).
    hint : str, optional
        What to do about it; appended to the message.

    Attributes
    ----------
    name, value, bound : as given.
    """

    def __init__(self, name, value, bound, hint=""):
        self.name = name
        self.value = value
        self.bound = bound
        message = f"invalid parameter {name} = {value!r}: must be {bound}"
        if hint:
            message += f"; {hint}"
        super().__init__(message)


class NonPassiveError(InvalidParameterError):
    """A controller setting violates the passivity bounds (paper eq. 28).

    Raised for disturbance-observer settings outside ``m_n >= m - b/lambda``
    and ``0 <= k_n <= k + lambda*b_n``, and for a proportional force-feedback
    gain outside ``-1 <= K_f <= 1``, unless the configuration sets
    ``allow_non_passive``.
    """

    def __init__(self, name, value, bound):
        super().__init__(
            name, value, bound,
            hint=("the closed loop would not be passive (coupled stability with "
                  "any passive environment is lost); set allow_non_passive to "
                  "true to override"))


class NonFiniteInputError(SeaforceError, ValueError):
    """A per-sample input (position, velocity, pressure force) is NaN or inf.

    Raised by :meth:`seaforce_ros.core.controller.ChannelController.update` (which
    changes nothing: validating and latching is
    :class:`~seaforce_ros.core.control_cycle.ControlCycle`'s job) and by the simulator's
    ``step`` for a non-finite torque.
    """

    def __init__(self, name, value):
        self.name = name
        self.value = value
        super().__init__(f"non-finite input {name} = {value!r}")

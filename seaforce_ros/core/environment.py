"""Endpoint environments of the offline simulator (what the bonded second
finger did in the paper's experiments).

* :func:`free` -- nothing attached, F_e = 0.
* :func:`torque_sine` -- external torque ``F_e = A sin(w t)``.
* :func:`torque_chirp` -- log chirp ``F_e = A sin(phi(t))``, instantaneous
  frequency ``f0 (f1/f0)^(t/T)`` Hz for ``0 <= t < T``, then 0 (paper: 0.3 N m,
  0.01-1000 Hz).
* :func:`position_sine` -- the endpoint is driven through a stiff
  spring-damper ``F_e = k_env (x_d - X_e) + b_env (v_d - V_e)`` by
  ``x_d = offset + A sin(w t)``. The reported F_e is that spring-damper force.
  Defaults: ``k_env = 1000 N m/rad`` (about 75x the hose stiffness k_s, so
  X_e follows x_d within ~1.3 % even in ``hold``) and ``b_env = 1.2 N m s/rad``
  (damping ratio ~0.7 for the endpoint inertia m_e of Table I against
  k_env). The drive (a harmonic oscillator) and the spring-damper are part of
  the simulator's exact (matrix-exponential) discretisation, so this stiff
  coupling is integrated exactly at any step.
* :func:`contact_object` -- an object at the endpoint position ``position``
  [rad] (Kelvin-Voigt): while the endpoint is beyond it and pushes into it,
  ``F_e = -(k_o (X_e - position) + b_o V_e)``, zero otherwise (it never pulls).
  In contact it is the position drive's spring-damper to a fixed set point
  (same exact discretisation); contact starts and ends at the start of a step.

Times are measured from when the environment is installed in the simulator.
Sine frequencies are in rad/s, chirp frequencies in Hz (DESIGN.md).
"""

import math
from dataclasses import dataclass

from .errors import InvalidParameterError
from .signals import log_chirp_phase

__all__ = ["Environment", "free", "torque_sine", "torque_chirp", "position_sine",
           "contact_object", "ENVIRONMENT_MODES", "environment_from_dict"]

ENVIRONMENT_MODES = ("free", "torque_sine", "torque_chirp", "position_sine", "object")

#: Default stiffness [N m/rad] / damping [N m s/rad] of the position drive.
DRIVE_STIFFNESS = 1000.0
DRIVE_DAMPING = 1.2


def _finite(name, value, lower=None, strict=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise InvalidParameterError(name, value, "a finite number")
    if lower is not None and (value <= lower if strict else value < lower):
        raise InvalidParameterError(name, value, ("> " if strict else ">= ") + str(lower))


@dataclass(frozen=True)
class Environment:
    """An endpoint environment (use the factory functions).

    Attributes
    ----------
    mode : str
        One of :data:`ENVIRONMENT_MODES`.
    amplitude : float
        N m (torque modes) or rad (position_sine).
    frequency : float
        rad/s (sines).
    start_frequency, end_frequency : float
        Hz (chirp).
    duration : float
        s (chirp).
    stiffness, damping : float
        Position drive spring-damper, or the object's k_o and b_o [N m/rad], [N m s/rad].
    offset : float
        Centre of the position drive [rad].
    position : float
        Where the object's surface is (contact at X_e > position) [rad].
    """

    mode: str = "free"
    amplitude: float = 0.0
    frequency: float = 1.0
    start_frequency: float = 0.01
    end_frequency: float = 1000.0
    duration: float = 60.0
    stiffness: float = DRIVE_STIFFNESS
    damping: float = DRIVE_DAMPING
    offset: float = 0.0
    position: float = 0.0

    def __post_init__(self):
        if self.mode not in ENVIRONMENT_MODES:
            raise InvalidParameterError("environment.mode", self.mode,
                                        "one of " + ", ".join(ENVIRONMENT_MODES))
        _finite("environment.amplitude", self.amplitude, 0.0)
        _finite("environment.frequency", self.frequency, 0.0)
        _finite("environment.start_frequency", self.start_frequency, 0.0, strict=True)
        _finite("environment.end_frequency", self.end_frequency, 0.0, strict=True)
        _finite("environment.duration", self.duration, 0.0, strict=True)
        _finite("environment.stiffness", self.stiffness, 0.0)
        _finite("environment.damping", self.damping, 0.0)
        _finite("environment.offset", self.offset)
        _finite("environment.position", self.position)

    @property
    def is_position_drive(self):
        return self.mode == "position_sine"

    @property
    def is_object(self):
        return self.mode == "object"

    def torque(self, t):
        """External torque F_e [N m] at time ``t`` [s] (torque modes; else 0)."""
        if self.mode == "torque_sine":
            return self.amplitude * math.sin(self.frequency * t)
        if self.mode == "torque_chirp":
            if t < 0.0 or t >= self.duration:
                return 0.0
            return self.amplitude * math.sin(self.chirp_phase(t))
        return 0.0

    def chirp_phase(self, t):
        """Log-chirp phase [rad] at ``t`` [s]."""
        return log_chirp_phase(t, self.start_frequency, self.end_frequency, self.duration)


def free():
    """Nothing attached to the endpoint (F_e = 0)."""
    return Environment("free")


def torque_sine(amplitude, frequency):
    """External torque sine, ``amplitude`` [N m], ``frequency`` [rad/s]."""
    return Environment("torque_sine", amplitude=amplitude, frequency=frequency)


def torque_chirp(amplitude=0.3, start_frequency=0.01, end_frequency=1000.0,
                 duration=60.0):
    """External torque log chirp (frequencies in Hz, duration in s)."""
    return Environment("torque_chirp", amplitude=amplitude,
                       start_frequency=start_frequency, end_frequency=end_frequency,
                       duration=duration)


def position_sine(amplitude=0.5, frequency=1.0, stiffness=DRIVE_STIFFNESS,
                  damping=DRIVE_DAMPING, offset=0.0):
    """Stiff position drive of the endpoint, ``amplitude`` [rad] at
    ``frequency`` [rad/s] through ``stiffness`` [N m/rad] and ``damping``
    [N m s/rad]."""
    return Environment("position_sine", amplitude=amplitude, frequency=frequency,
                       stiffness=stiffness, damping=damping, offset=offset)


def contact_object(position, stiffness, damping):
    """An object whose surface is at ``position`` [rad] (contact at X_e > position), with
    stiffness k_o = ``stiffness`` [N m/rad] and damping b_o = ``damping`` [N m s/rad]."""
    return Environment("object", stiffness=stiffness, damping=damping, position=position)


def environment_from_dict(values):
    """Build an environment from flat keys ``mode, amplitude, frequency,
    start_frequency, end_frequency, duration, stiffness, damping, offset, position``
    (optionally prefixed by
    ``environment.`` or ``<channel>.environment.``)."""
    kwargs = {}
    for key, value in values.items():
        name = key.rsplit(".", 1)[-1]
        if name not in Environment.__dataclass_fields__:
            raise InvalidParameterError(key, value, "an environment key: " +
                                        ", ".join(Environment.__dataclass_fields__))
        if isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        kwargs[name] = value
    return Environment(**kwargs)

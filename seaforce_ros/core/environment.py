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
Sine frequencies are in rad/s, chirp frequencies in Hz (as the sim's parameters have them).
"""

import math
from typing import Any, Mapping

from .schema import SIM, ParameterGroup, group, param
from .signals import log_chirp_phase

__all__ = ["Environment", "free", "torque_sine", "torque_chirp", "position_sine",
           "contact_object", "ENVIRONMENT_MODES", "environment_from_dict"]

ENVIRONMENT_MODES = ("free", "torque_sine", "torque_chirp", "position_sine", "object")

#: Default stiffness [N m/rad] / damping [N m s/rad] of the position drive.
DRIVE_STIFFNESS = 1000.0
DRIVE_DAMPING = 1.2


@group("environment", nodes=(SIM,))
class Environment(ParameterGroup):
    """An endpoint environment of the simulated gripper (use the factory functions in code)."""

    mode: str = param("free", "", "endpoint environment: free, a torque sine or log chirp, a "
                      "position drive (position_sine: the paper's bonded finger), or an object "
                      "to grasp", choices=ENVIRONMENT_MODES)
    amplitude: float = param(0.5, "N m or rad", "amplitude (N m for the torque modes, rad for "
                             "position_sine)", ge=0.0, le=100.0)
    frequency: float = param(1.0, "rad/s", "sine frequency", ge=0.0, le=1e5)
    start_frequency: float = param(0.01, "Hz", "torque chirp start frequency", ge=1e-6,
                                   le=1e4)
    end_frequency: float = param(1000.0, "Hz", "torque chirp end frequency", ge=1e-6, le=1e4)
    duration: float = param(60.0, "s", "torque chirp duration", ge=1e-3, le=1e6)
    stiffness: float = param(DRIVE_STIFFNESS, "N m/rad", "position drive spring to the "
                             "endpoint, or the object's stiffness k_o", ge=0.0, le=1e6)
    damping: float = param(DRIVE_DAMPING, "N m s/rad", "position drive damper to the endpoint, "
                           "or the object's damping b_o", ge=0.0, le=1e4)
    offset: float = param(0.0, "rad", "centre of the position drive", ge=-100.0, le=100.0)
    position: float = param(0.0, "rad", "object surface: mode object touches the endpoint at "
                            "X_e > position, F_e = -(k_o (X_e - position) + b_o V_e) while it "
                            "pushes", ge=-100.0, le=100.0)

    @property
    def is_position_drive(self) -> bool:
        """The endpoint is driven (``position_sine``)."""
        return self.mode == "position_sine"

    @property
    def is_object(self) -> bool:
        """An object to grasp is at the endpoint (``object``)."""
        return self.mode == "object"

    def torque(self, t: float) -> float:
        """External torque F_e [N m] at time ``t`` [s] (torque modes; else 0)."""
        if self.mode == "torque_sine":
            return self.amplitude * math.sin(self.frequency * t)
        if self.mode == "torque_chirp":
            if t < 0.0 or t >= self.duration:
                return 0.0
            return self.amplitude * math.sin(self.chirp_phase(t))
        return 0.0

    def chirp_phase(self, t: float) -> float:
        """Log-chirp phase [rad] at ``t`` [s]."""
        return log_chirp_phase(t, self.start_frequency, self.end_frequency, self.duration)


def free() -> Environment:
    """Nothing attached to the endpoint (F_e = 0)."""
    return Environment("free")


def torque_sine(amplitude: float, frequency: float) -> Environment:
    """External torque sine, ``amplitude`` [N m], ``frequency`` [rad/s]."""
    return Environment("torque_sine", amplitude=amplitude, frequency=frequency)


def torque_chirp(amplitude: float = 0.3, start_frequency: float = 0.01,
                 end_frequency: float = 1000.0, duration: float = 60.0) -> Environment:
    """External torque log chirp (frequencies in Hz, duration in s)."""
    return Environment("torque_chirp", amplitude=amplitude,
                       start_frequency=start_frequency, end_frequency=end_frequency,
                       duration=duration)


def position_sine(amplitude: float = 0.5, frequency: float = 1.0,
                  stiffness: float = DRIVE_STIFFNESS, damping: float = DRIVE_DAMPING,
                  offset: float = 0.0) -> Environment:
    """Stiff position drive of the endpoint, ``amplitude`` [rad] at
    ``frequency`` [rad/s] through ``stiffness`` [N m/rad] and ``damping``
    [N m s/rad]."""
    return Environment("position_sine", amplitude=amplitude, frequency=frequency,
                       stiffness=stiffness, damping=damping, offset=offset)


def contact_object(position: float, stiffness: float, damping: float) -> Environment:
    """An object whose surface is at ``position`` [rad] (contact at X_e > position), with
    stiffness k_o = ``stiffness`` [N m/rad] and damping b_o = ``damping`` [N m s/rad]."""
    return Environment("object", stiffness=stiffness, damping=damping, position=position)


def environment_from_dict(values: Mapping[str, Any]) -> Environment:
    """An environment from flat keys ``mode, amplitude, frequency, start_frequency,
    end_frequency, duration, stiffness, damping, offset, position``, optionally prefixed by
    ``environment.`` or ``<channel>.environment.``; an unknown key or a bad value raises
    :class:`InvalidParameterError` naming it."""
    return Environment.from_values({"environment." + key.rsplit(".", 1)[-1]: value
                                    for key, value in values.items()})

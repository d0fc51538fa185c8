"""The motor position servo the jobs move a free finger with (the tare, commissioning's
verification): ``F_a = bias + K_p e + K_d e'`` (``e`` the reference less X), entered from the
channel's torque bumplessly, that torque fading in :data:`~.modes.TRANSFER_TIME` so that
nothing of the mode it interrupted stays on as an offset. Plain floats, no allocation per
sample. Nothing here imports ROS.
"""
from __future__ import annotations

import math

from .modes import TRANSFER_TIME

__all__ = ["MotorServo"]


class MotorServo:
    """``K_p`` [N m/rad], ``K_d`` [N m s/rad], sample period ``dt`` [s] (module docstring)."""

    __slots__ = ("kp", "kd", "bias", "_decay")

    def __init__(self, kp: float, kd: float, dt: float) -> None:
        self.kp, self.kd = float(kp), float(kd)
        self.bias = 0.0
        self._decay = math.exp(-dt / TRANSFER_TIME)

    def start(self, torque: float, v: float) -> None:
        """Enter from ``torque`` [N m] at motor speed ``v`` [rad/s] (with zero errors the
        first output is that torque)."""
        self.bias = torque + self.kd * v

    def output(self, error: float, rate_error: float, steps: int = 1) -> float:
        """F_a [N m] for the position error [rad] and its rate [rad/s]; ``steps`` sample
        periods since the previous output."""
        u = self.bias + self.kp * error + self.kd * rate_error
        self.bias *= self._decay if steps == 1 else self._decay ** steps
        return u

"""A model-free contact test for a motion about a known centre: the two sides' stiffness.

A free finger moved about a centre ``x_0`` is (nearly) linear there, so the pressure force's
apparent stiffness is the same above the centre as below it (the damping and the quadrature
part of the Dahl hysteresis cancel over each lobe, inertia and springs are symmetric); an
object in the way acts on one side only. The test fits ``F_p = c - k_+ d_+ - k_- d_-`` by least
squares over the motion (``d = X - x_0``, ``d_+ = max(d, 0)``, ``d_- = min(d, 0)``, one offset
``c`` for both sides) from running sums, and compares the two sides. It uses no model, so a
model wrong by 0.5x..2x does not upset it -- which is why
:class:`~seaforce_ros.core.friction_calibration.FrictionCalibration` uses it before it learns
friction from the motion (the commissioning excitation has its own chirp version,
:mod:`seaforce_ros.commissioning.excitation`).

``level = |k_+ - k_-| / (stiffness + ratio |Z|)``, ``|Z|`` the rms of the force over the rms of
``d``: above 1 the finger is not free. The caller judges (:meth:`SidedStiffness.judge`) at whole
periods of the motion since the sums started: over a part of a lobe the quadrature terms do
not cancel (a finger whose Dahl force dominates its spring, F_c 0.064 N m against k_e 0.054 N m/rad
at 0.5 rad, swung k_+ - k_- by +-0.07 N m/rad within a period in free air; at whole periods
0.001). Plain floats, no allocation per sample.
"""

from __future__ import annotations

import math

__all__ = ["SidedStiffness"]


class SidedStiffness:
    """The two sides' apparent stiffness of a motion about ``x_0`` (module docstring).

    Parameters
    ----------
    stiffness : float > 0
        The threshold's absolute part [N m/rad].
    ratio : float >= 0
        Its part relative to ``|Z|``.
    min_motion : float > 0
        The rms motion [rad] each side must have before the test judges.

    Attributes
    ----------
    level : float
        The latest ``|k_+ - k_-|`` over the threshold (0 until both sides moved).
    peak : float
        The largest level so far.
    upper, lower : float
        k_+ and k_- [N m/rad] at the latest judgement (NaN before).
    """

    __slots__ = ("_stiffness", "_ratio", "_least", "x0", "_s", "level", "peak", "upper",
                 "lower")

    def __init__(self, stiffness: float, ratio: float, min_motion: float) -> None:
        self._stiffness, self._ratio = stiffness, ratio
        self._least = min_motion * min_motion
        self.reset(0.0)

    def reset(self, x0: float) -> None:
        """Start again about the centre ``x0`` [rad]."""
        self.x0 = x0
        # n, sum d+, sum d-, sum d+^2, sum d-^2, sum F, sum F d+, sum F d-, sum F^2, n+, n-
        self._s = [0.0] * 11
        self.level = self.peak = 0.0
        self.upper = self.lower = math.nan

    def update(self, x: float, f: float) -> None:
        """One sample: position X [rad], pressure force F_p [N m]."""
        d = x - self.x0
        s = self._s
        s[0] += 1.0
        s[5] += f
        s[8] += f * f
        if d > 0.0:
            s[1] += d
            s[3] += d * d
            s[6] += f * d
            s[9] += 1.0
        else:
            s[2] += d
            s[4] += d * d
            s[7] += f * d
            s[10] += 1.0

    def judge(self) -> float:
        """The test over the samples so far (call it at a whole number of periods): returns
        :attr:`level` (0 while a side has not moved ``min_motion``)."""
        n, sp, sn, spp, snn, sf, sfp, sfn, sff, n_up, n_down = self._s
        if n_up < 2 or n_down < 2 or spp < n_up * self._least or snn < n_down * self._least:
            return self.level
        # normal equations of F = c + a d+ + b d- (d+ d- = 0): eliminate c
        mp, mn, mf = sp / n, sn / n, sf / n
        a11, a22, a12 = spp - sp * mp, snn - sn * mn, -sp * mn
        r1, r2 = sfp - sp * mf, sfn - sn * mf
        det = a11 * a22 - a12 * a12
        if not det > 0.0:
            return self.level
        a = (r1 * a22 - r2 * a12) / det
        b = (r2 * a11 - r1 * a12) / det
        c = mf - a * mp - b * mn          # (the offset: not judged)
        kp, kn = -a, -b
        self.upper, self.lower = kp, kn
        # |Z|: the rms of the force about its offset over the rms motion
        magnitude = math.sqrt(max(0.0, sff / n - mf * mf) / ((spp + snn) / n))
        level = self.level = abs(kp - kn) / (self._stiffness + self._ratio * magnitude)
        if level > self.peak:
            self.peak = level
        del c
        return level

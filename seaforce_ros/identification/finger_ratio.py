"""The finger's four-bar ratio r(q) from a bonded-finger record (the paper's Section IV: "a
nonlinear four-bar mechanism gear ratio in the finger joint").

A free-air record cannot show it: the ratio acts on a force at the finger, and in free air
there is none. A bonded-finger record -- the finger driven through its stroke by a position
drive (``position_sine``, the ``zwidth`` backdrives), its encoder q recorded beside the motor
position X and the pressure force F_p -- shows it by kinematics alone. The actuator's
endpoint is ``X_e = X + d`` with the hose's deflection ``d = F_p/k_s`` at the record's low
frequencies (to first order in the hose's stiffening with pressure, ``- kappa |F_p| F_p /
k_s^3``), and the four-bar maps the finger to it, ``X_e = g(q)``, ``r(q) = dX_e/dq``. So::

    X = e_0 + r_0 q + a_2 q^2 + a_3 q^3 - F_p / k_s + h |F_p| F_p

is linear in its coefficients, and k_s and the hose's stiffening come out of the fit with the
four-bar's: no parameter of the gripper is needed. It is fitted by least squares on the
record low-passed at :data:`CUTOFF` (zero phase, the same filter on every column) and
decimated; the ratio relative to its value at the centre of the finger's frame (q = 0) is
then ``r(q)/r_0 = 1 + c_1 (q/L) + c_2 (q/L)^2`` with ``c_1 = 2 a_2 L/r_0``, ``c_2 = 3 a_3
L^2/r_0`` and L the half-stroke the record reached (the oracle's model of the four-bar).

The 1-sigmas take the residual's autocorrelation (the fit's covariance times the residual's
integrated autocorrelation time). The ratio is *resolved* when the record's stroke spans at
least twice :data:`MIN_STROKE` across the centre q = 0, the motor moves at least
:data:`MIN_TRAVEL` of the finger's stroke (in a stiff mode the hose takes the finger's motion
and the pressure follows q), the ratio at an end of the stroke the record reached differs
from r_0 by at least :data:`MIN_RISE` and :data:`RESOLVED_SIGMAS` of its 1-sigmas, and the
stroke's two directions (q rising, q falling) give the ends' ratios within
:data:`CONSISTENCY` of each other: a kinematic map is the same both ways, while an error of
the hose's deflection that follows the force (the endpoint's friction reverses with the
motion) is not. Otherwise the reason is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Tuple

import numpy as np
import numpy.typing as npt
import scipy.signal

__all__ = ["FingerRatio", "fit_finger_ratio", "CUTOFF", "MIN_STROKE",
           "MIN_RISE", "MIN_TRAVEL", "RESOLVED_SIGMAS", "CONSISTENCY"]

_Real = npt.NDArray[np.float64]

#: Zero-phase low-pass [Hz] of every column (the kinematics hold at any frequency; the cut
#: takes the sensors' noise and the hose's dynamics, d = F_p/(k_s + b_s s), out).
CUTOFF = 5.0
#: The fit's samples are this many times the cut-off's Nyquist rate.
OVERSAMPLE = 4
#: The half-stroke [rad] the record must reach for the ratio's change to show.
MIN_STROKE = 0.2
#: The smallest change of r/r_0 over the stroke that counts (a four-bar within 1 % of a
#: constant ratio is a constant ratio).
MIN_RISE = 0.01
#: The change must be this many 1-sigmas.
RESOLVED_SIGMAS = 3.0
#: The two directions' ends' ratios may differ by this much [-] (absolute on r/r_0).
CONSISTENCY = 0.01
#: Seconds left out at each end (the filter's transients).
EDGE = 0.5
#: The motor's travel over the finger's [-] at least: in a stiff mode (``hold``) the motor
#: stays and the hose takes the finger's motion, so F_p follows q and the hose's compliance
#: and the four-bar's terms are not separable (on the oracle: c_2 27.6 +- 89 for a true 0.13).
MIN_TRAVEL = 0.5


@dataclass(frozen=True)
class FingerRatio:
    """The four-bar's ratio from one bonded-finger record.

    Attributes
    ----------
    c_1, c_2 : float
        ``r(q)/r_0 = 1 + c_1 (q/L) + c_2 (q/L)^2`` (NaN when not fitted).
    sigma : tuple (float, float)
        Their 1-sigmas.
    half_stroke : float
        L [rad]: the largest |q| the record reached.
    stroke : tuple (float, float)
        The smallest and the largest q [rad] the record reached (filtered).
    ends : tuple (float, float)
        r/r_0 there.
    hose_stiffness : float
        The fit's k_s [N m/rad] (a check: the hose the identification knows).
    misfit : float
        rms residual over the rms deviation of the fitted X from its mean (filtered).
    resolved : bool
    reason : str
        '' when resolved, else why not.
    """

    c_1: float
    c_2: float
    sigma: Tuple[float, float]
    half_stroke: float
    stroke: Tuple[float, float]
    ends: Tuple[float, float]
    hose_stiffness: float
    misfit: float
    resolved: bool
    reason: str

    def line(self) -> str:
        """One line for a report."""
        if not math.isfinite(self.c_2):
            return f"finger ratio r(q) of the four-bar: not resolved ({self.reason})"
        head = (f"finger ratio r(q)/r(0) of the four-bar: {self.ends[0]:.3f} at q = "
                f"{self.stroke[0]:.3g} rad, {self.ends[1]:.3f} at {self.stroke[1]:.3g} "
                f"rad (c_1 {self.c_1:.3g} +- {self.sigma[0]:.2g}, c_2 {self.c_2:.3g} +- "
                f"{self.sigma[1]:.2g}; the fit's k_s {self.hose_stiffness:.3g} N m/rad, "
                f"misfit {100 * self.misfit:.2g} %)")
        return head + (", resolved" if self.resolved else f", not resolved ({self.reason})")


def _tau(r: _Real) -> float:
    """Integrated autocorrelation time [samples] of a residual (summed to its first
    non-positive lag), at least 1."""
    r = r - r.mean()
    n = r.size
    spec = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[:n]
    if acf[0] <= 0.0:
        return 1.0
    rho = acf / acf[0]
    stop = np.nonzero(rho <= 0.0)[0]
    last = int(stop[0]) if stop.size else n
    return max(1.0, 1.0 + 2.0 * float(rho[1:last].sum()))


def _fit(cols: Dict[str, _Real], y: _Real, names: Tuple[str, ...]
         ) -> Tuple[_Real, _Real, float]:
    """(coefficients, their covariance with the residual's autocorrelation, rss)."""
    a = np.stack([cols[k] for k in names], axis=1)
    scale = np.sqrt(np.sum(a ** 2, axis=0))
    scale[scale == 0.0] = 1.0
    an = a / scale
    coef, *_ = np.linalg.lstsq(an, y, rcond=None)
    r = y - an @ coef
    n, p = an.shape
    s2 = float(r @ r) / max(n - p, 1) * _tau(r)
    cov = np.linalg.pinv(an.T @ an) * s2
    return coef / scale, cov / np.outer(scale, scale), float(r @ r)


def _relative(coef: _Real, cov: _Real, half: float) -> Tuple[float, float, _Real]:
    """(c_1, c_2, their 2x2 covariance) from the fit's r_0, a_2, a_3 (indices 1, 2, 3; the
    delta method)."""
    r0, a2, a3 = (float(coef[i]) for i in (1, 2, 3))
    c1, c2 = 2.0 * a2 * half / r0, 3.0 * a3 * half ** 2 / r0
    j = np.array([[-c1 / r0, 2.0 * half / r0, 0.0],
                  [-c2 / r0, 0.0, 3.0 * half ** 2 / r0]])
    return c1, c2, j @ cov[np.ix_([1, 2, 3], [1, 2, 3])] @ j.T


def _change(c1: float, c2: float, u: float) -> float:
    """r/r_0 - 1 at u = q/L."""
    return c1 * u + c2 * u * u


_NAMES = ("one", "q", "q2", "q3", "f_p", "f_p2")


def fit_finger_ratio(q: npt.ArrayLike, x: npt.ArrayLike, f_p: npt.ArrayLike, dt: float
                     ) -> FingerRatio:
    """The four-bar's ratio from a bonded-finger record (module docstring).

    Parameters
    ----------
    q : array
        The finger's encoder [rad] (the record's ``x_e``).
    x : array
        The motor position [rad].
    f_p : array
        The pressure force [N m].
    dt : float > 0
        Sample period [s].

    Returns
    -------
    FingerRatio
        Not resolved, with the reason, where the record cannot show it (too short, too small
        a stroke, not finite).
    """
    q_a, x_a, f_a = (np.asarray(v, float).ravel() for v in (q, x, f_p))
    nan2 = (math.nan, math.nan)

    def unresolved(reason: str, half: float = math.nan) -> FingerRatio:
        return FingerRatio(math.nan, math.nan, nan2, half, nan2, nan2, math.nan, math.nan,
                           False, reason)

    if not (q_a.size == x_a.size == f_a.size):
        return unresolved(f"q, x and f_p differ in length ({q_a.size}, {x_a.size}, "
                          f"{f_a.size})")
    if not (math.isfinite(dt) and dt > 0.0):
        return unresolved(f"sample period {dt!r} s")
    if not 0.5 / dt > 2.0 * CUTOFF:
        return unresolved(f"sample period {dt:.3g} s: too long for the {CUTOFF:g} Hz low-pass")
    if not (np.isfinite(q_a).all() and np.isfinite(x_a).all() and np.isfinite(f_a).all()):
        return unresolved("the record has samples that are not finite")
    edge = int(round(EDGE / dt))
    step = max(1, int(1.0 / (2.0 * CUTOFF * OVERSAMPLE * dt)))
    if q_a.size < 2 * edge + 40 * step:
        return unresolved(f"the record is too short ({q_a.size * dt:.3g} s)")
    sos = scipy.signal.butter(4, CUTOFF, fs=1.0 / dt, output="sos")
    filt = {k: scipy.signal.sosfiltfilt(sos, v)[edge:q_a.size - edge:step]
            for k, v in (("q", q_a), ("x", x_a), ("f_p", f_a))}
    qf = filt["q"]
    lo, hi = float(qf.min()), float(qf.max())
    half = max(-lo, hi)
    if not 0.5 * (hi - lo) >= MIN_STROKE:
        return unresolved(f"the record's stroke is {hi - lo:.3g} rad, under "
                          f"{2 * MIN_STROKE:g} rad: too short for the ratio's change to show",
                          half)
    if not lo < 0.0 < hi:
        return unresolved(f"the record's stroke ({lo:.3g} .. {hi:.3g} rad) does not pass "
                          "the finger's centre q = 0, where the ratio is referred to", half)
    travel = float(np.ptp(filt["x"])) / float(hi - lo)
    if travel < MIN_TRAVEL:
        return unresolved(f"the motor moved {100 * travel:.2g} % of the finger's stroke: a "
                          "stiff mode, whose hose takes the motion (the pressure then follows "
                          "the finger and the fit cannot tell the hose from the four-bar); "
                          "take a record of a soft mode (passive, dob_full_ff)", half)
    cols = {"one": np.ones_like(qf), "q": qf, "q2": qf ** 2, "q3": qf ** 3,
            "f_p": filt["f_p"], "f_p2": np.abs(filt["f_p"]) * filt["f_p"]}
    y = filt["x"]
    coef, cov, rss = _fit(cols, y, _NAMES)
    if not (np.isfinite(coef).all() and np.isfinite(cov).all() and coef[1] > 0.0):
        return unresolved("the fit found no ratio (the finger's encoder does not follow "
                          "the motor)", half)
    c1, c2, c_cov = _relative(coef, cov, half)
    k_s = -1.0 / float(coef[4]) if coef[4] < 0.0 else math.nan
    us = (lo / half, hi / half)
    ends = tuple(1.0 + _change(c1, c2, u) for u in us)
    # each end's change and its 1-sigma, (c_1, c_2)'s covariance counted
    sds = [math.sqrt(max(float(np.array([u, u * u]) @ c_cov @ np.array([u, u * u])), 0.0))
           for u in us]
    misfit = math.sqrt(rss / max(float(np.sum((y - y.mean()) ** 2)), 1e-300))
    sigma = (math.sqrt(max(float(c_cov[0, 0]), 0.0)), math.sqrt(max(float(c_cov[1, 1]), 0.0)))
    base = (c1, c2, sigma, half, (lo, hi), (ends[0], ends[1]), k_s, misfit)
    rise, sd = max((abs(e - 1.0), d) for e, d in zip(ends, sds))
    if rise < MIN_RISE:
        return FingerRatio(*base, False, f"the ratio changes by {100 * rise:.2g} % over the "
                           f"stroke, under {100 * MIN_RISE:g} %: a constant ratio")
    if not rise >= RESOLVED_SIGMAS * sd:
        return FingerRatio(*base, False, f"its change ({rise:.3g}) is within "
                           f"{RESOLVED_SIGMAS:g} 1-sigmas ({sd:.2g})")
    rising = np.gradient(qf) > 0.0
    parts = []
    for mask in (rising, ~rising):
        if mask.sum() < 40 or not 0.5 * float(np.ptp(qf[mask])) >= MIN_STROKE:
            return FingerRatio(*base, False, "the record does not drive the stroke both "
                               "ways (one direction is needed against the other)")
        c, v, _ = _fit({k: a[mask] for k, a in cols.items()}, y[mask], _NAMES)
        if not (np.isfinite(c).all() and c[1] > 0.0):
            return FingerRatio(*base, False, "one direction of the stroke gives no ratio")
        p1, p2, _ = _relative(c, v, half)
        parts.append(tuple(1.0 + _change(p1, p2, u) for u in us))
    gap = max(abs(a - b) for a, b in zip(*parts))
    if not gap <= CONSISTENCY:
        return FingerRatio(*base, False, "the two directions of the stroke give "
                           + " and ".join(f"{a:.3f} / {b:.3f}" for a, b in parts)
                           + f" at the ends (beyond {CONSISTENCY:g}): the hose's deflection "
                           "is not F_p/k_s here (take a record of a soft mode)")
    return FingerRatio(*base, True, "")

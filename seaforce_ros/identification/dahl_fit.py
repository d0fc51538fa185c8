"""Dahl hysteresis fit from a quasi-static work loop (paper Section IV, eq. 14-15, Fig. 6).

The endpoint is backdriven slowly (0.5 rad at 1 rad/s). Its force balance is
``F_e - F_p = m_e A_e + b_e V_e + k_e (X_e - x_0) + F_d`` (``x_0`` the rest position, an
unknown constant). With the identified linear endpoint terms removed, what is left of the
external loop is the hysteresis F_d, fitted with the Dahl model (eq. 14; exponent n = 1 gives
eq. 15) by nonlinear least squares on (log sigma, log F_c[, n]); the constant ``k_e x_0`` is
solved linearly at every step. V_e and A_e come from the endpoint encoder through a zero-phase
low-pass (the 40,000 counts/rev encoder quantises the velocity at 0.3 rad/s per count at 2 kHz);
F_d itself is driven by the raw encoder path (quantisation causes no spurious reversals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Dict, List, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt
import scipy.optimize
import scipy.signal

from .dahl_model import dahl_force
from .errors import IdentificationError

if TYPE_CHECKING:
    from ..core.params import PlantParams
    from .timeseries import Series

__all__ = ["DahlFit", "fit_dahl_loop", "linear_endpoint_force"]


@dataclass
class DahlFit:
    """sigma [N m/rad], coulomb_force F_c [N m], exponent n and their 1-sigma; rms of the
    loop residual after the fit [N m]; the loop arrays (for the plot). ``*_reason`` says why a
    value is not identified (the search ended on its bound, or the covariance is degenerate);
    empty when it is."""

    sigma: float
    coulomb_force: float
    exponent: float
    sigma_1s: float
    coulomb_force_1s: float
    exponent_1s: float
    rms: float
    rms_linear_only: float
    x_e: npt.NDArray[np.float64]
    residual_force: npt.NDArray[np.float64]
    model_force: npt.NDArray[np.float64]
    offset: float
    sigma_reason: str = ""
    coulomb_force_reason: str = ""
    exponent_reason: str = ""

    @property
    def identified(self) -> bool:
        """Every fitted value is identified (no ``*_reason``)."""
        return not (self.sigma_reason or self.coulomb_force_reason or self.exponent_reason)


def linear_endpoint_force(x_e: npt.ArrayLike, dt: float, plant: PlantParams,
                          cutoff: float = 30.0) -> npt.NDArray[np.float64]:
    """``m_e A_e + b_e V_e + k_e X_e`` from encoder samples (zero-phase low-pass for the
    derivatives, ``cutoff`` rad/s)."""
    x = np.asarray(x_e, float)
    wn = cutoff * dt / math.pi
    if not 0 < wn < 1:
        raise IdentificationError(f"derivative filter cut-off {cutoff} rad/s is not below the "
                                  "Nyquist frequency")
    b, a = scipy.signal.butter(2, wn)
    xf = scipy.signal.filtfilt(b, a, x)
    v = np.gradient(xf, dt)
    acc = np.gradient(v, dt)
    return (plant.endpoint_inertia * acc + plant.endpoint_damping * v
            + plant.endpoint_stiffness * x)


def fit_dahl_loop(series: Series, plant: PlantParams, settle: Optional[float] = None,
                  fit_exponent: bool = False, exponent: float = 1.0,
                  external_force_delay: float = 0.0) -> DahlFit:
    """Fit the Dahl model to the external work loop of ``series``.

    Parameters
    ----------
    series : Series
        Needs x_e, f_e, f_p.
    plant : PlantParams
        Identified linear endpoint terms (m_e, b_e, k_e).
    settle : float, optional
        Seconds to ignore at the start (default: the first 10 % of the record, at most one
        drive period of 2 pi s).
    fit_exponent : bool
        Fit n too (else fixed at ``exponent``).

    Raises
    ------
    IdentificationError
        No motion, too little data.
    """
    s = series.signals
    dt = series.dt
    x_e, f_e, f_p = s["x_e"], s["f_e"], s["f_p"]
    if np.ptp(x_e) < 1e-3:
        raise IdentificationError("too little motion for a Dahl fit: the endpoint moved "
                                  f"{np.ptp(x_e):.2g} rad (record a work loop, e.g. the sim's "
                                  "position_sine environment, 0.5 rad at 1 rad/s)")
    if settle is None:
        settle = min(0.1 * series.duration, 2 * math.pi)
    k0 = int(settle / dt)
    if series.n - k0 < 1000:
        raise IdentificationError("too little data for a Dahl fit: record at least one full "
                                  "loop after the transient")
    f_lin = linear_endpoint_force(x_e, dt, plant)
    if external_force_delay:
        f_e = np.interp(np.arange(series.n) - external_force_delay, np.arange(series.n), f_e)
    resid_force = f_e - f_p - f_lin
    # the zero-phase derivative filter is wrong near the end of the record: drop 0.25 s
    k1 = series.n - int(0.25 / dt)
    x_e = x_e[:k1]
    resid_force = resid_force[:k1]
    target = resid_force[k0:]

    def model(p: Sequence[float]) -> npt.NDArray[np.float64]:
        sig, fc = math.exp(p[0]), math.exp(p[1])
        n = p[2] if fit_exponent else exponent
        return dahl_force(x_e, sig, fc, n)[k0:]

    def resid(p: Sequence[float]) -> npt.NDArray[np.float64]:
        fd = model(p)
        offset = float(np.mean(target - fd))
        return target - fd - offset

    # start: F_c from the loop's half-height, sigma from a grid
    half = 0.5 * (np.percentile(target, 95) - np.percentile(target, 5))
    fc0 = max(half, 1e-4)
    best: Optional[Tuple[float, List[float]]] = None
    for sig0 in (1.0, 3.0, 10.0, 30.0, 100.0, 300.0):
        p0 = [math.log(sig0), math.log(fc0)] + ([exponent] if fit_exponent else [])
        c = float(np.sum(resid(p0) ** 2))
        if best is None or c < best[0]:
            best = (c, p0)
    lower = [-10, -15] + ([0.05] if fit_exponent else [])
    upper = [15, 5] + ([5.0] if fit_exponent else [])
    # best is set: the loop above has six starts
    res = scipy.optimize.least_squares(resid, best[1],  # type: ignore[index]
                                       bounds=(lower, upper), x_scale=1.0, diff_step=1e-4)
    p = res.x
    r = res.fun
    dof = max(1, r.size - len(p) - 1)
    s2 = float(r @ r) / dof
    names = ["sigma", "coulomb_force"] + (["exponent"] if fit_exponent else [])
    reasons: Dict[str, str] = {}
    for i, name in enumerate(names):
        if res.active_mask[i] != 0 or min(p[i] - lower[i], upper[i] - p[i]) < 1e-6:
            side = "lower" if p[i] - lower[i] < upper[i] - p[i] else "upper"
            reasons[name] = (f"the search ended on its {side} bound: the loop does not "
                             "constrain it")
    jtj = res.jac.T @ res.jac
    cs = np.sqrt(np.diag(jtj))
    cond = np.linalg.cond(jtj / np.outer(cs, cs)) if np.all(cs > 0) else math.inf
    if not (np.isfinite(cond) and cond < 1e10):
        for name in names:
            reasons.setdefault(name, f"degenerate covariance (condition number {cond:.3g}): "
                                     "the loop does not tell the parameters apart")
        sd = np.full(len(p), np.nan)
    else:
        sd = np.sqrt(np.abs(np.diag(np.linalg.pinv(jtj) * s2)))
    for i, name in enumerate(names):
        if name not in reasons and not (np.isfinite(sd[i]) and sd[i] > 0):
            reasons[name] = "its 1-sigma is zero or undefined: degenerate covariance"
    sig, fc = math.exp(p[0]), math.exp(p[1])
    n = float(p[2]) if fit_exponent else float(exponent)
    fd_full = dahl_force(x_e, sig, fc, n)
    offset = float(np.mean(target - fd_full[k0:]))
    return DahlFit(sig, fc, n, sig * sd[0], fc * sd[1], float(sd[2]) if fit_exponent else 0.0,
                   float(np.sqrt(np.mean(r ** 2))),
                   float(np.std(target - np.mean(target))),
                   x_e[k0:], target - offset, fd_full[k0:], offset,
                   reasons.get("sigma", ""), reasons.get("coulomb_force", ""),
                   reasons.get("exponent", ""))

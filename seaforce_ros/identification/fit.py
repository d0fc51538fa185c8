"""Model fits to the Blackman-Tukey frequency responses (paper Section II-C, Fig. 4).

* :func:`fit_mass_spring_damper` -- X/F = 1/(m s^2 + b s + k) (Fig. 4A motor plant, Fig. 4B
  endpoint plant): weighted linear least squares on the inverse response.
* :func:`fit_hose` -- F_p/(X_e - X) = b_s s + k_s (Fig. 4C).
* :func:`fit_endpoint_with_dahl` -- the endpoint plant when the finger has Dahl hysteresis
  (eq. 14): the hysteresis force F_d(t; sigma, F_c) is computed from the measured endpoint
  path and removed from the endpoint's input before the linear fit, and (sigma, F_c) are
  chosen to minimise the misfit (variable projection: linear inner fit, 2-D outer search).
  Without it the hysteresis -- at large slow amplitudes a Coulomb force, at small fast ones a
  stiffness of up to sigma -- is lumped into m_e, b_e and k_e (25 % magnitude error on Fig. 4B
  with the paper's F_c = 0.032 N m, sigma = 12.8 N m/rad).
* :func:`fit_rational` -- the 2-zero/4-pole model of X_e/F_e (Fig. 4D, MATLAB ``tfest``):
  Sanathanan-Koerner iterations, then nonlinear least squares on the relative error.

All fits weight each frequency by its 1-sigma band (floored at ``SIGMA_FLOOR`` relative: the
coherence of a noise-free chirp is 1 and its formal variance 0) and return the 1-sigma of the
parameters from the weighted Jacobian, scaled by sqrt(chi^2/dof) when the model misfit exceeds
the bands (so an inadequate model widens the reported uncertainty instead of hiding it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt
import scipy.optimize

from .dahl_model import DahlPath

if TYPE_CHECKING:
    from .spectral import BlackmanTukey, FrequencyResponse

__all__ = ["SIGMA_FLOOR", "ParameterFit", "fit_mass_spring_damper", "fit_hose",
           "fit_endpoint_with_dahl", "HysteresisEstimate", "RationalFit", "fit_rational",
           "fit_error"]

#: floor of the relative 1-sigma used as a weight
SIGMA_FLOOR = 2e-3

_Real = npt.NDArray[np.float64]
_Complex = npt.NDArray[np.complex128]


@dataclass
class ParameterFit:
    """Result of one plant fit.

    names : parameter names; values, sigma : value and 1-sigma per name;
    fit_error : rms relative misfit |H_model - H| / |H| over the band [-];
    chi2_dof : weighted misfit per degree of freedom; band : (lo, hi) [rad/s].
    """

    names: List[str]
    values: _Real
    sigma: _Real
    fit_error: float
    chi2_dof: float
    band: Tuple[float, float]
    extra: Dict[str, float] = field(default_factory=dict)
    hysteresis: Optional["HysteresisEstimate"] = None

    def as_dict(self) -> Dict[str, float]:
        """``{name: value}``."""
        return dict(zip(self.names, self.values))


def _weights(resp: FrequencyResponse) -> _Real:
    return 1.0 / (np.abs(resp.h) * np.maximum(resp.rel_sigma, SIGMA_FLOOR))


def fit_error(h_model: _Complex, h: _Complex) -> float:
    """rms of |h_model - h|/|h|."""
    return float(np.sqrt(np.mean(np.abs(h_model - h) ** 2 / np.abs(h) ** 2)))


def _wls(design: _Complex, target: npt.NDArray[np.inexact],
         weight: _Real) -> Tuple[_Real, _Real, float]:
    """Weighted least squares, complex rows stacked as real/imag.

    design : (n, p) complex; target : (n,) complex; weight : (n,) real (1/sigma).
    Returns theta, cov (scaled), chi2/dof.
    """
    a = np.vstack([design.real * weight[:, None], design.imag * weight[:, None]])
    y = np.concatenate([target.real * weight, target.imag * weight])
    keep = np.any(a != 0, axis=0)
    scale = np.where(keep, np.sqrt(np.sum(a ** 2, axis=0)), 1.0)
    theta_s, *_ = np.linalg.lstsq(a / scale, y, rcond=None)
    theta = theta_s / scale
    resid = y - a @ theta
    dof = max(1, y.size - a.shape[1])
    chi2 = float(resid @ resid) / dof
    jtj = (a / scale).T @ (a / scale)
    cov = np.linalg.pinv(jtj) / np.outer(scale, scale) * max(1.0, chi2)
    return theta, cov, chi2


def _check_band(resp: FrequencyResponse, lo: float, hi: float, what: str) -> FrequencyResponse:
    sel = resp.band(lo, hi)
    if sel.omega.size < 4:
        raise ValueError(f"{what}: fewer than 4 frequencies in {lo:g}-{hi:g} rad/s")
    return sel


def fit_mass_spring_damper(resp: FrequencyResponse, lo: float, hi: float,
                           names: Sequence[str] = ("inertia", "damping", "stiffness")
                           ) -> ParameterFit:
    """Fit ``H = 1/(m s^2 + b s + k)`` to a response over ``lo..hi`` rad/s.

    The inverse ``1/H = k - m w^2 + j b w`` is linear in (m, b, k); its relative sigma equals
    that of H.
    """
    r = _check_band(resp, lo, hi, "mass-spring-damper fit")
    g = 1.0 / r.h
    w = r.omega
    design = np.stack([-(w ** 2) + 0j, 1j * w, np.ones_like(w) + 0j], axis=1)
    weight = 1.0 / (np.abs(g) * np.maximum(r.rel_sigma, SIGMA_FLOOR))
    theta, cov, chi2 = _wls(design, g, weight)
    model = 1.0 / (design @ theta)
    return ParameterFit(list(names), theta, np.sqrt(np.diag(cov)), fit_error(model, r.h),
                        chi2, (lo, hi))


def fit_hose(resp: FrequencyResponse, lo: float, hi: float,
             names: Sequence[str] = ("hose_damping", "hose_stiffness")) -> ParameterFit:
    """Fit ``H = b_s s + k_s`` over ``lo..hi`` rad/s."""
    r = _check_band(resp, lo, hi, "hose fit")
    w = r.omega
    design = np.stack([1j * w, np.ones_like(w) + 0j], axis=1)
    theta, cov, chi2 = _wls(design, r.h, _weights(r))
    model = design @ theta
    return ParameterFit(list(names), theta, np.sqrt(np.diag(cov)), fit_error(model, r.h),
                        chi2, (lo, hi))


@dataclass
class HysteresisEstimate:
    """The endpoint hysteresis seen in a chirp (:func:`fit_endpoint_with_dahl`).

    model : 'dahl' (sigma and F_c), 'coulomb' (the Dahl model's sigma -> inf limit: only F_c),
        'spring' (the hysteresis acts as a linear spring: neither is separable from k_e) or
        'none' (no hysteresis detected).
    sigma, coulomb_force : float
        sigma [N m/rad], F_c [N m] the fit used (NaN: not in the model); a value is only an
        identified value when its ``*_reason`` is empty.
    sigma_1s, coulomb_force_1s : float
        1-sigma (meaningful only when identified).
    ratio : float
        sigma/F_c [1/rad] of the model used (inf for 'coulomb').
    sigma_reason, coulomb_force_reason : str
        Why the value is not identified ('' when it is).
    cost_linear, cost : float
        Weighted misfit of the purely linear fit and of the fit with this model.
    search : (lo, hi)
        Bounds of the sigma/F_c search [1/rad].
    """

    model: str
    sigma: float = math.nan
    coulomb_force: float = math.nan
    sigma_1s: float = math.nan
    coulomb_force_1s: float = math.nan
    ratio: float = math.nan
    sigma_reason: str = ""
    coulomb_force_reason: str = ""
    cost_linear: float = math.nan
    cost: float = math.nan
    search: Tuple[float, float] = (math.nan, math.nan)

    @property
    def sigma_identified(self) -> bool:
        """sigma is identified (no ``sigma_reason``)."""
        return not self.sigma_reason

    @property
    def coulomb_force_identified(self) -> bool:
        """F_c is identified (no ``coulomb_force_reason``)."""
        return not self.coulomb_force_reason


#: grid points per decade of the sigma/F_c search
RATIO_GRID_PER_DECADE = 4
#: the misfit reduction (fraction of the linear-only misfit) below which no hysteresis is seen
MIN_COST_REDUCTION = 0.05
#: F_c must exceed this many of its 1-sigma to count as seen
MIN_COULOMB_SNR = 3.0
#: condition number of the scaled normal matrix above which the covariance is degenerate
MAX_CONDITION = 1e10


def _ratio_bounds(path: DahlPath) -> Tuple[float, float]:
    """Search bounds of ``a = sigma/F_c`` [1/rad] a record can tell apart.

    Lower: the pre-sliding displacement 1/a equals half the motion's span (below it the Dahl
    force is a linear spring sigma x over the whole record). Upper: 1/a is a third of the
    smallest position step (an encoder quantum): each step then relaxes the force by a factor
    e^-3, and the model on the measured path is the Coulomb relay.
    """
    lo = 2.0 / max(path.span, 1e-12)
    hi = 3.0 / max(path.resolution, 1e-12)
    return lo, max(hi, 10.0 * lo)


def fit_endpoint_with_dahl(bt: BlackmanTukey, s_xe: _Complex, s_input: _Complex,
                           x_e: Union[npt.ArrayLike, DahlPath], lo: float, hi: float,
                           rel_sigma: _Real, dahl_delay: float = 0.0, exponent: float = 1.0,
                           progress: Optional[Callable[[str, float], object]] = None,
                           dahl_spectra: Optional[Dict[float, _Complex]] = None
                           ) -> ParameterFit:
    """Endpoint plant ``X_e/(F_e - F_p - F_d) = 1/(m_e s^2 + b_e s + k_e)`` with Dahl (eq. 14).

    Method (variable projection with one nonlinear parameter). The Dahl force is
    ``F_d = F_c f(X_e; a)`` with ``a = sigma/F_c`` (:class:`~.dahl_model.DahlPath`), so the
    endpoint's balance in cross-spectra with the excitation r::

        S_r(F_e - F_p) = (m_e s^2 + b_e s + k_e) S_rXe + F_c S_rf(a)

    is linear in (m_e, b_e, k_e, F_c) for a given a. The weighted misfit of that linear fit
    is profiled over log a on a grid between the bounds a record can tell apart
    (:func:`_ratio_bounds`), plus the Coulomb limit a = inf, then refined (bounded Brent).
    The 1-sigma of all five come from the Jacobian of the weighted residual.

    Outcomes (:class:`HysteresisEstimate`):

    * minimum inside the bounds, covariance regular: sigma and F_c identified;
    * minimum on the upper bound or at the Coulomb limit: the pre-sliding displacement
      F_c/sigma is below what the endpoint encoder resolves; sigma is not identified, the fit
      uses the Coulomb limit, which is the same force on the measured path, so the linear
      parameters stay unbiased, and F_c is identified;
    * minimum on the lower bound: the hysteresis acts as a linear spring over the whole
      record, so sigma and F_c cannot be told from k_e (reported, linear fit);
    * a degenerate covariance (flat profile) marks the parameter as not identified;
    * no misfit reduction or an F_c within 3 sigma of 0: no hysteresis (linear fit).

    Parameters
    ----------
    bt : BlackmanTukey
        Spectral estimator (reference = the excitation).
    s_xe : complex array
        S_r,Xe on the grid.
    s_input : complex array
        S_r,(F_e - F_p) on the grid (the endpoint's input without hysteresis).
    x_e : array or DahlPath
        Endpoint position samples [rad] (drive F_d).
    lo, hi : float
        Band [rad/s].
    rel_sigma : array
        Relative 1-sigma of the raw endpoint response (weights, fixed during the search).
    dahl_delay : float
        Delay of F_d relative to the samples of X_e, in samples (0: a continuous friction
        force; 0.5: a force held over the step, as the core simulator does).
    exponent : float
        Dahl exponent n (fixed).
    dahl_spectra : dict, optional
        Cache of ``S_rf(a)`` in the band per ratio a, filled by the search: fits that share
        ``bt``, ``x_e``, the band, ``dahl_delay`` and ``exponent`` and differ only in
        ``s_input`` (two alignments of the external force) pass the same dict and evaluate
        each a once.

    Returns
    -------
    ParameterFit with names endpoint_inertia, endpoint_damping, endpoint_stiffness and
    ``hysteresis`` (a :class:`HysteresisEstimate`); ``extra`` repeats its numbers
    (sigma, coulomb_force, sigma_1s, coulomb_force_1s, cost_linear, cost_dahl; NaN where not
    identified).
    """
    sel = (bt.omega >= lo) & (bt.omega <= hi)
    if sel.sum() < 6:
        raise ValueError(f"endpoint fit: fewer than 6 frequencies in {lo:g}-{hi:g} rad/s")
    path = x_e if isinstance(x_e, DahlPath) else DahlPath(x_e)
    w = bt.omega[sel]
    sx = s_xe[sel]
    su = s_input[sel]
    weight = 1.0 / (np.abs(su) * np.maximum(rel_sigma[sel], SIGMA_FLOOR))
    design = np.stack([-(w ** 2) * sx, 1j * w * sx, sx], axis=1)

    def stack(z: _Complex) -> _Real:
        return np.concatenate([z.real * weight, z.imag * weight])

    a_lin = np.vstack([design.real * weight[:, None], design.imag * weight[:, None]])
    y = stack(su)
    scale3 = np.sqrt(np.sum(a_lin ** 2, axis=0))
    cache: Dict[float, _Complex] = {} if dahl_spectra is None else dahl_spectra
    calls = [0]

    def s_dahl(ratio: float) -> _Complex:
        key = float(ratio)
        if key not in cache:
            calls[0] += 1
            if progress is not None:
                progress(f"Dahl search: evaluation {calls[0]}", min(0.95, calls[0] / 32.0))
            f = path.normalized(ratio, exponent)
            cache[key] = bt.cross(f, delay=dahl_delay)[sel]
        return cache[key]

    def solve(ratio: float) -> Tuple[_Real, _Real, _Real]:
        """(theta, residual, A) of the 4-parameter linear fit for this ratio."""
        a = np.hstack([a_lin, stack(s_dahl(ratio))[:, None]])      # y = A theta + F_c S_rf
        sc = np.sqrt(np.sum(a ** 2, axis=0))
        sc[sc == 0] = 1.0
        th, *_ = np.linalg.lstsq(a / sc, y, rcond=None)
        th = th / sc
        return th, y - a @ th, a

    def cost_of(log_ratio: float) -> float:
        r = solve(math.exp(log_ratio))[1]
        return float(r @ r)

    th_lin, *_ = np.linalg.lstsq(a_lin / scale3, y, rcond=None)
    th_lin = th_lin / scale3
    r_lin = y - a_lin @ th_lin
    cost_linear = float(r_lin @ r_lin)

    r_lo, r_hi = _ratio_bounds(path)
    n_grid = max(6, int(math.ceil(RATIO_GRID_PER_DECADE * math.log10(r_hi / r_lo))) + 1)
    grid = np.linspace(math.log(r_lo), math.log(r_hi), n_grid)
    costs = np.array([cost_of(g) for g in grid])
    _, res_inf, _ = solve(math.inf)
    cost_inf = float(res_inf @ res_inf)
    i_best = int(np.argmin(costs))
    est = HysteresisEstimate("none", cost_linear=cost_linear, search=(r_lo, r_hi))

    def finish(theta3: _Real, cost: float,
               hyst: HysteresisEstimate) -> Tuple[_Real, float, HysteresisEstimate]:
        dof = max(1, y.size - (3 if hyst.model in ("none", "spring") else
                               (4 if hyst.model == "coulomb" else 5)))
        chi2 = cost / dof
        hyst.cost = cost
        return theta3, chi2, hyst

    if min(costs.min(), cost_inf) > (1.0 - MIN_COST_REDUCTION) * cost_linear:
        est.sigma_reason = est.coulomb_force_reason = (
            "no hysteresis seen: a Dahl force does not reduce the endpoint misfit by "
            f"{100 * MIN_COST_REDUCTION:.0f} %")
        theta, chi2, est = finish(th_lin, cost_linear, est)
        sig = _linear_sigma(a_lin, chi2)
        return _endpoint_result(theta, sig, chi2, w, sx, su, None, lo, hi, est)

    if cost_inf <= costs.min() or i_best == n_grid - 1:
        # the search ran to its upper bound: Coulomb limit (sigma not identified)
        use_inf = cost_inf <= costs[-1]
        ratio = math.inf if use_inf else math.exp(grid[-1])
        th, res, a = solve(ratio)
        est.model = "coulomb"
        est.ratio = ratio
        est.sigma_reason = (
            f"the search for sigma/F_c ran to its upper bound ({r_hi:.3g} /rad: a pre-sliding "
            f"displacement F_c/sigma below {1e3 / r_hi:.2g} mrad, a third of the endpoint "
            "encoder's step); the hysteresis acts as Coulomb friction in this record, fitted "
            "as such (F_c only)")
        jac = -a
    elif i_best == 0:
        est.model = "spring"
        est.sigma_reason = est.coulomb_force_reason = (
            f"the search for sigma/F_c ran to its lower bound ({r_lo:.3g} /rad: a pre-sliding "
            "displacement F_c/sigma as large as half the motion); the hysteresis acts as a "
            "linear spring in this record and cannot be told from k_e, which includes it")
        theta, chi2, est = finish(th_lin, cost_linear, est)
        sig = _linear_sigma(a_lin, chi2)
        return _endpoint_result(theta, sig, chi2, w, sx, su, None, lo, hi, est)
    else:
        opt = scipy.optimize.minimize_scalar(
            cost_of, bounds=(grid[i_best - 1], grid[i_best + 1]), method="bounded",
            options={"xatol": 2e-3})
        log_ratio = float(opt.x) if opt.fun <= costs[i_best] else float(grid[i_best])
        ratio = math.exp(log_ratio)
        th, res, a = solve(ratio)
        est.model = "dahl"
        est.ratio = ratio
        # Jacobian of the weighted residual in (m_e, b_e, k_e, F_c, log a)
        h = 0.01
        d_col = (stack(s_dahl(math.exp(log_ratio + h)))
                 - stack(s_dahl(math.exp(log_ratio - h)))) / (2 * h)
        jac = np.hstack([-a, (-th[3] * d_col)[:, None]])
    cost = float(res @ res)
    theta3, chi2, est = finish(th[:3], cost, est)
    cs = np.sqrt(np.sum(jac ** 2, axis=0))
    cs[cs == 0] = 1.0
    jn = jac / cs
    normal = jn.T @ jn
    cond = np.linalg.cond(normal)
    cov = np.linalg.pinv(normal) / np.outer(cs, cs) * max(1.0, chi2)
    sd = np.sqrt(np.abs(np.diag(cov)))
    fc, fc_sd = float(th[3]), float(sd[3])
    degenerate = not (np.isfinite(cond) and cond < MAX_CONDITION) or not np.all(
        np.isfinite(sd)) or np.any(sd == 0)
    if not (fc > 0 and fc > MIN_COULOMB_SNR * fc_sd):
        # a "hysteresis" force of the wrong sign or lost in its own uncertainty
        est = HysteresisEstimate("none", cost_linear=cost_linear, search=(r_lo, r_hi))
        est.sigma_reason = est.coulomb_force_reason = (
            f"no hysteresis seen: the fitted F_c = {fc:.3g} +- {fc_sd:.2g} N m is not "
            f"positive by {MIN_COULOMB_SNR:g} sigma")
        theta, chi2, est = finish(th_lin, cost_linear, est)
        sig = _linear_sigma(a_lin, chi2)
        return _endpoint_result(theta, sig, chi2, w, sx, su, None, lo, hi, est)
    est.coulomb_force, est.coulomb_force_1s = fc, fc_sd
    if degenerate:
        reason = (f"degenerate covariance (condition number {cond:.3g} of the normal "
                  "matrix): the record does not tell these parameters apart")
        est.sigma_reason = est.sigma_reason or reason
        est.coulomb_force_reason = reason
    if est.model == "dahl":
        est.sigma = est.ratio * fc
        if not est.sigma_reason:
            # sigma = a F_c: var(log sigma) = var(log a) + var(log F_c) + 2 cov(log a, log F_c)
            var_log_s = sd[4] ** 2 + (fc_sd / fc) ** 2 + 2.0 * cov[3, 4] / fc
            est.sigma_1s = est.sigma * math.sqrt(max(float(var_log_s), 0.0))
            if not est.sigma_1s < est.sigma:
                est.sigma_reason = (f"its 1-sigma ({est.sigma_1s:.3g} N m/rad) exceeds its "
                                    "value: the misfit is flat along sigma/F_c")
    return _endpoint_result(theta3, sd[:3], chi2, w, sx, su, fc * s_dahl(est.ratio), lo, hi,
                            est)


def _linear_sigma(a_lin: _Real, chi2: float) -> _Real:
    cs = np.sqrt(np.sum(a_lin ** 2, axis=0))
    cs[cs == 0] = 1.0
    cov = np.linalg.pinv((a_lin / cs).T @ (a_lin / cs)) / np.outer(cs, cs) * max(1.0, chi2)
    return np.sqrt(np.abs(np.diag(cov)))


def _endpoint_result(theta: _Real, sig: _Real, chi2: float, w: _Real, sx: _Complex,
                     su: _Complex, s_fd: Optional[_Complex], lo: float, hi: float,
                     est: HysteresisEstimate) -> ParameterFit:
    target = su if s_fd is None else su - s_fd
    h_meas = sx / target
    h_model = 1.0 / (-(w ** 2) * theta[0] + 1j * w * theta[1] + theta[2])
    nan = math.nan
    extra = {"cost_linear": est.cost_linear, "cost_dahl": est.cost,
             "sigma": est.sigma if est.sigma_identified else nan,
             "coulomb_force": est.coulomb_force if est.coulomb_force_identified else nan,
             "sigma_1s": est.sigma_1s if est.sigma_identified else nan,
             "coulomb_force_1s": (est.coulomb_force_1s if est.coulomb_force_identified
                                  else nan)}
    return ParameterFit(["endpoint_inertia", "endpoint_damping", "endpoint_stiffness"],
                        np.asarray(theta, float), np.asarray(sig, float),
                        fit_error(h_model, h_meas), chi2, (lo, hi), extra, est)


@dataclass
class RationalFit:
    """``H(s) = num(s)/den(s)`` (den monic), numpy coefficient order (highest first)."""

    num: _Real
    den: _Real
    fit_error: float
    band: Tuple[float, float]

    @property
    def poles(self) -> _Complex:
        """Roots of den, sorted (real part, then imaginary)."""
        # numpy types sort_complex for complex input; np.roots returns real roots as floats
        return np.sort_complex(np.roots(self.den))  # type: ignore[arg-type]

    @property
    def zeros(self) -> _Complex:
        """Roots of num, sorted (real part, then imaginary)."""
        return np.sort_complex(np.roots(self.num))  # type: ignore[arg-type]  # (as poles)

    def __call__(self, omega: npt.ArrayLike) -> _Complex:
        s = 1j * np.asarray(omega, float)
        return np.polyval(self.num, s) / np.polyval(self.den, s)


def fit_rational(resp: FrequencyResponse, lo: float, hi: float, n_zeros: int = 2,
                 n_poles: int = 4, iterations: int = 20) -> RationalFit:
    """Fit ``num/den`` with ``n_zeros`` zeros and ``n_poles`` poles over ``lo..hi`` rad/s.

    Frequencies are scaled by the band's geometric centre for conditioning. SK iterations of
    Levy's linearisation, then :func:`scipy.optimize.least_squares` on the weighted complex
    error.
    """
    r = _check_band(resp, lo, hi, "rational fit")
    w0 = math.sqrt(max(lo, r.omega[0]) * hi)
    s = 1j * r.omega / w0
    h = r.h
    wt = _weights(r)
    vn = np.vander(s, n_zeros + 1)            # s^nz .. 1
    vd = np.vander(s, n_poles)                # s^(np-1) .. 1 (den monic)
    d_prev = np.ones_like(s)
    theta = None
    for _ in range(iterations):
        # num - h (s^np + den_rest) = 0  ->  [vn, -h vd] theta = h s^np
        design = np.hstack([vn, -h[:, None] * vd]) / d_prev[:, None]
        target = h * s ** n_poles / d_prev
        a = np.vstack([(design.real * wt[:, None]), (design.imag * wt[:, None])])
        y = np.concatenate([target.real * wt, target.imag * wt])
        new, *_ = np.linalg.lstsq(a, y, rcond=None)
        if theta is not None and np.allclose(new, theta, rtol=1e-10, atol=0):
            theta = new
            break
        theta = new
        d_prev = s ** n_poles + vd @ theta[n_zeros + 1:]
        d_prev = np.where(np.abs(d_prev) < 1e-12, 1e-12, d_prev)

    def resid(th: _Real) -> _Real:
        num = vn @ th[:n_zeros + 1]
        den = s ** n_poles + vd @ th[n_zeros + 1:]
        e = (num / den - h) * wt
        return np.concatenate([e.real, e.imag])

    theta = scipy.optimize.least_squares(resid, theta, method="lm", max_nfev=2000).x
    # unscale: s' = s/w0
    num = theta[:n_zeros + 1] * w0 ** -np.arange(n_zeros, -1, -1)
    den = np.r_[1.0, theta[n_zeros + 1:]] * w0 ** -np.arange(n_poles, -1, -1)
    num, den = num / den[0], den / den[0]
    fitted = RationalFit(num, den, 0.0, (lo, hi))
    fitted.fit_error = fit_error(fitted(r.omega), r.h)
    return fitted

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
from typing import Dict, List

import numpy as np
import scipy.optimize

from .dahl_model import dahl_force
from .spectral import FrequencyResponse

__all__ = ["SIGMA_FLOOR", "ParameterFit", "fit_mass_spring_damper", "fit_hose",
           "fit_endpoint_with_dahl", "RationalFit", "fit_rational", "fit_error"]

#: floor of the relative 1-sigma used as a weight
SIGMA_FLOOR = 2e-3


@dataclass
class ParameterFit:
    """Result of one plant fit.

    names : parameter names; values, sigma : value and 1-sigma per name;
    fit_error : rms relative misfit |H_model - H| / |H| over the band [-];
    chi2_dof : weighted misfit per degree of freedom; band : (lo, hi) [rad/s].
    """

    names: List[str]
    values: np.ndarray
    sigma: np.ndarray
    fit_error: float
    chi2_dof: float
    band: tuple
    extra: Dict[str, float] = field(default_factory=dict)

    def as_dict(self):
        return dict(zip(self.names, self.values))


def _weights(resp):
    return 1.0 / (np.abs(resp.h) * np.maximum(resp.rel_sigma, SIGMA_FLOOR))


def fit_error(h_model, h):
    """rms of |h_model - h|/|h|."""
    return float(np.sqrt(np.mean(np.abs(h_model - h) ** 2 / np.abs(h) ** 2)))


def _wls(design, target, weight):
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


def _check_band(resp, lo, hi, what):
    sel = resp.band(lo, hi)
    if sel.omega.size < 4:
        raise ValueError(f"{what}: fewer than 4 frequencies in {lo:g}-{hi:g} rad/s")
    return sel


def fit_mass_spring_damper(resp, lo, hi, names=("inertia", "damping", "stiffness")):
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


def fit_hose(resp, lo, hi, names=("hose_damping", "hose_stiffness")):
    """Fit ``H = b_s s + k_s`` over ``lo..hi`` rad/s."""
    r = _check_band(resp, lo, hi, "hose fit")
    w = r.omega
    design = np.stack([1j * w, np.ones_like(w) + 0j], axis=1)
    theta, cov, chi2 = _wls(design, r.h, _weights(r))
    model = design @ theta
    return ParameterFit(list(names), theta, np.sqrt(np.diag(cov)), fit_error(model, r.h),
                        chi2, (lo, hi))


def fit_endpoint_with_dahl(bt, s_xe, s_input, x_e, lo, hi, rel_sigma, dahl_delay=0.5,
                           exponent=1.0, progress=None):
    """Endpoint plant ``X_e/(F_e - F_p - F_d) = 1/(m_e s^2 + b_e s + k_e)`` with Dahl.

    Parameters
    ----------
    bt : BlackmanTukey
        Spectral estimator (reference = the excitation).
    s_xe : complex array
        S_r,Xe on the grid.
    s_input : complex array
        S_r,(F_e - F_p) on the grid (the endpoint's input without hysteresis).
    x_e : array
        Endpoint position samples [rad] (drives F_d).
    lo, hi : float
        Band [rad/s].
    rel_sigma : array
        Relative 1-sigma of the raw endpoint response (weights, fixed during the search).
    dahl_delay : float
        Delay of the held F_d in samples (the simulator holds it over the next step: 0.5).

    Returns
    -------
    ParameterFit with names endpoint_inertia, endpoint_damping, endpoint_stiffness, and
    ``extra`` = {sigma, coulomb_force, sigma_1s, coulomb_force_1s, cost_linear, cost_dahl}
    (sigma = 0 when the hysteresis does not reduce the misfit).
    """
    sel = (bt.omega >= lo) & (bt.omega <= hi)
    if sel.sum() < 6:
        raise ValueError(f"endpoint fit: fewer than 6 frequencies in {lo:g}-{hi:g} rad/s")
    w = bt.omega[sel]
    sx = s_xe[sel]
    su = s_input[sel]
    weight = 1.0 / (np.abs(su) * np.maximum(rel_sigma[sel], SIGMA_FLOOR))
    design = np.stack([-(w ** 2) * sx, 1j * w * sx, sx], axis=1)
    a = np.vstack([design.real * weight[:, None], design.imag * weight[:, None]])
    scale = np.sqrt(np.sum(a ** 2, axis=0))
    a_s = a / scale
    q, _ = np.linalg.qr(a_s)

    def resid_for(target):
        y = np.concatenate([target.real * weight, target.imag * weight])
        return y - q @ (q.T @ y)

    cache = {}

    def s_dahl(log_sigma, log_fc):
        key = (round(log_sigma, 12), round(log_fc, 12))
        if key not in cache:
            fd = dahl_force(x_e, math.exp(log_sigma), math.exp(log_fc), exponent)
            cache[key] = bt.cross(fd, delay=dahl_delay)[sel]
        return cache[key]

    def cost(p):
        r = resid_for(su - s_dahl(*p))
        return float(r @ r)

    cost_linear = float(resid_for(su) @ resid_for(su))
    # coarse grid, then a trust-region least-squares refinement in log space
    grid = [(ls, lf) for ls in np.log([3.0, 20.0, 120.0]) for lf in np.log([0.004, 0.02, 0.1])]
    costs = []
    for i, p in enumerate(grid):
        costs.append(cost(p))
        if progress is not None:
            progress(f"Dahl search: grid {i + 1}/{len(grid)}", (i + 1) / (len(grid) + 25))
    best = np.array(grid[int(np.argmin(costs))])
    calls = [0]

    def resid_p(p):
        calls[0] += 1
        if progress is not None:
            progress(f"Dahl search: refinement step {calls[0]}",
                     min(0.99, (len(grid) + calls[0]) / (len(grid) + 25)))
        return resid_for(su - s_dahl(*p))

    res = scipy.optimize.least_squares(resid_p, best, method="trf", diff_step=1e-3,
                                       xtol=1e-4, ftol=1e-6, max_nfev=40)
    res.fun = float(res.fun @ res.fun)
    p_opt = res.x
    cost_dahl = float(res.fun)
    use_dahl = cost_dahl < 0.9 * cost_linear
    target = su - s_dahl(*p_opt) if use_dahl else su
    y = np.concatenate([target.real * weight, target.imag * weight])
    theta_s, *_ = np.linalg.lstsq(a_s, y, rcond=None)
    theta = theta_s / scale
    resid = y - a @ theta
    n_par = 5 if use_dahl else 3
    dof = max(1, y.size - n_par)
    chi2 = float(resid @ resid) / dof
    # covariance of all parameters from a finite-difference Jacobian of the full residual
    extra = {"cost_linear": cost_linear, "cost_dahl": cost_dahl}
    if use_dahl:
        def full_resid(params):
            th = params[:3]
            tgt = su - s_dahl(params[3], params[4])
            yy = np.concatenate([tgt.real * weight, tgt.imag * weight])
            return yy - a @ th
        p_all = np.r_[theta, p_opt]
        jac = np.empty((y.size, 5))
        jac[:, :3] = -a                       # the residual is linear in (m_e, b_e, k_e)
        for k in (3, 4):
            h = 1e-3
            dp = np.zeros(5)
            dp[k] = h
            jac[:, k] = (full_resid(p_all + dp) - full_resid(p_all - dp)) / (2 * h)
        cs = np.sqrt(np.sum(jac ** 2, axis=0))
        cs[cs == 0] = 1.0
        cov = np.linalg.pinv((jac / cs).T @ (jac / cs)) / np.outer(cs, cs) * max(1.0, chi2)
        sig = np.sqrt(np.abs(np.diag(cov)))
        s_val, f_val = math.exp(p_opt[0]), math.exp(p_opt[1])
        extra.update(sigma=s_val, coulomb_force=f_val, sigma_1s=s_val * sig[3],
                     coulomb_force_1s=f_val * sig[4])
        sig = sig[:3]
    else:
        cov = np.linalg.pinv(a_s.T @ a_s) / np.outer(scale, scale) * max(1.0, chi2)
        sig = np.sqrt(np.diag(cov))
        extra.update(sigma=0.0, coulomb_force=0.0, sigma_1s=0.0, coulomb_force_1s=0.0)
    h_meas = sx / target
    h_model = 1.0 / (-(w ** 2) * theta[0] + 1j * w * theta[1] + theta[2])
    return ParameterFit(["endpoint_inertia", "endpoint_damping", "endpoint_stiffness"], theta,
                        sig, fit_error(h_model, h_meas), chi2, (lo, hi), extra)


@dataclass
class RationalFit:
    """``H(s) = num(s)/den(s)`` (den monic), numpy coefficient order (highest first)."""

    num: np.ndarray
    den: np.ndarray
    fit_error: float
    band: tuple

    @property
    def poles(self):
        return np.sort_complex(np.roots(self.den))

    @property
    def zeros(self):
        return np.sort_complex(np.roots(self.num))

    def __call__(self, omega):
        s = 1j * np.asarray(omega, float)
        return np.polyval(self.num, s) / np.polyval(self.den, s)


def fit_rational(resp, lo, hi, n_zeros=2, n_poles=4, iterations=20):
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

    def resid(th):
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

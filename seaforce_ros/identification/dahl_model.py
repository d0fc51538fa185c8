"""Vectorised Dahl hysteresis (paper eq. 14-15) along a sampled position path.

Same exact solution as :mod:`seaforce_ros.core.dahl` (``u = 1 - s F_d/F_c`` relaxes along the
path length xi as ``du/dxi = -(sigma/F_c) u^n``), but evaluated for a whole record: the path is
cut into monotone runs; the only sequential part is the value of u at the start of each run
(``u_start = 2 - u_end`` of the previous run at a reversal), a scalar loop over runs; inside a
run the closed form is evaluated with numpy. Used by the fits, which evaluate it many times.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dahl_force"]


def _relax(u0, c, n):
    """u after path ``c = sigma xi/F_c`` (array) from ``u0`` (array or scalar), exponent n."""
    if n == 1.0:
        return u0 * np.exp(-c)
    if n < 1.0:
        p = 1.0 - n
        base = np.power(u0, p) - p * c
        return np.where(base > 0.0, np.power(np.maximum(base, 0.0), 1.0 / p), 0.0)
    p = n - 1.0
    with np.errstate(divide="ignore"):
        inv = np.where(u0 > 0.0, np.power(np.maximum(u0, 1e-300), -p), np.inf)
    return np.power(inv + p * c, -1.0 / p)


def _relax_scalar(n):
    """Scalar form of :func:`_relax` for the run recursion."""
    import math
    if n < 1.0:
        p = 1.0 - n

        def relax(u0, c):
            base = u0 ** p - p * c
            return base ** (1.0 / p) if base > 0.0 else 0.0
    else:
        p = n - 1.0

        def relax(u0, c):
            if u0 <= 0.0:
                return 0.0
            return (u0 ** -p + p * c) ** (-1.0 / p)
    return relax


def dahl_force(x, sigma, coulomb_force, exponent=1.0, initial_force=0.0):
    """Dahl force F_d [N m] after each sample of the path ``x`` [rad].

    ``F_d[k]`` is the force once the position has reached ``x[k]`` (``F_d[0] =
    initial_force``), i.e. what the simulator holds over the step that follows sample k.

    Parameters
    ----------
    x : array
        Position samples [rad] (motor frame).
    sigma : float >= 0
        sigma [N m/rad].
    coulomb_force : float > 0
        F_c [N m].
    exponent : float >= 0
        n.
    """
    x = np.asarray(x, float)
    out = np.full(x.shape, float(initial_force))
    if sigma <= 0.0 or x.size < 2:
        return out
    fc = float(coulomb_force)
    dx = np.diff(x)
    moving = np.flatnonzero(dx != 0.0)
    if moving.size == 0:
        return out
    sgn = np.sign(dx[moving])
    # runs of equal direction among the moving increments
    starts = np.flatnonzero(np.r_[True, sgn[1:] != sgn[:-1]])
    ends = np.r_[starts[1:], moving.size]
    # path length inside each run, cumulative per increment
    step = np.abs(dx[moving]) * (sigma / fc)
    cum = np.cumsum(step)
    run_of = np.repeat(np.arange(starts.size), ends - starts)
    base = np.r_[0.0, cum][starts]                    # cumulative path before each run
    c_in_run = cum - base[run_of]                     # path from run start to after this step
    run_total = cum[ends - 1] - base
    # scalar recursion over runs: u at run start (after the first run every run starts at a
    # reversal, where u_start = 2 - u_end of the previous run)
    s_run = sgn[starts]
    u0 = max(0.0, 1.0 - s_run[0] * float(initial_force) / fc)
    totals = run_total.tolist()
    starts_u = [u0]
    if exponent == 1.0:
        decay = np.exp(-run_total).tolist()
        for r in range(1, starts.size):
            u0 = 2.0 - u0 * decay[r - 1]
            starts_u.append(u0)
    else:
        relax = _relax_scalar(exponent)
        for r in range(1, starts.size):
            u0 = 2.0 - relax(u0, totals[r - 1])
            starts_u.append(u0)
    u_start = np.asarray(starts_u)
    u = _relax(u_start[run_of], c_in_run, exponent)
    f_moving = s_run[run_of] * fc * (1.0 - u)
    # forward-fill: F_d after sample k+1 for each moving increment k
    idx = np.zeros(x.size, dtype=np.int64)
    idx[moving + 1] = np.arange(1, moving.size + 1)
    idx = np.maximum.accumulate(idx)
    values = np.r_[float(initial_force), f_moving]
    return values[idx]

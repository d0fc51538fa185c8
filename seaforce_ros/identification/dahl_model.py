"""Vectorised Dahl hysteresis (paper eq. 14-15) along a sampled position path.

Same exact solution as :mod:`seaforce_ros.core.dahl` (``u = 1 - s F_d/F_c`` relaxes along the
path length xi as ``du/dxi = -(sigma/F_c) u^n``), but evaluated for a whole record: the path is
cut into monotone runs; the only sequential part is the value of u at the start of each run
(``u_start = 2 - u_end`` of the previous run at a reversal), a scalar loop over runs; inside a
run the closed form is evaluated with numpy. Used by the fits, which evaluate it many times.
"""

from __future__ import annotations

import math
from typing import Callable, Union

import numpy as np
import numpy.typing as npt

__all__ = ["dahl_force", "DahlPath"]

_Array = npt.NDArray[np.float64]


def _relax(u0: Union[_Array, float], c: _Array, n: float) -> _Array:
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


def _relax_scalar(n: float) -> Callable[[float, float], float]:
    """Scalar form of :func:`_relax` for the run recursion."""
    if n < 1.0:
        p = 1.0 - n

        def relax(u0: float, c: float) -> float:
            base = u0 ** p - p * c
            return base ** (1.0 / p) if base > 0.0 else 0.0
    else:
        p = n - 1.0

        def relax(u0: float, c: float) -> float:
            if u0 <= 0.0:
                return 0.0
            return (u0 ** -p + p * c) ** (-1.0 / p)
    return relax


class DahlPath:
    """A sampled position path prepared for many Dahl evaluations (the fits' inner loop).

    Everything that depends on the path alone (monotone runs, path length inside each run,
    forward-fill indices) is computed once; :meth:`normalized` then costs a few passes over
    the samples. For any exponent n the Dahl force is ``F_d = F_c f(x; sigma/F_c, n)``: with
    ``u = 1 - s F_d/F_c`` eq. 14 reads ``du/dxi = -(sigma/F_c) u^n``, so the normalised force
    ``f = F_d/F_c`` depends on sigma and F_c only through their ratio ``a = sigma/F_c``
    [1/rad] (the inverse of the pre-sliding displacement). F_c is therefore a linear
    parameter of any fit that is linear in the force.

    Parameters
    ----------
    x : array
        Position samples [rad] (motor frame).
    """

    def __init__(self, x: npt.ArrayLike) -> None:
        x = np.asarray(x, float)
        self.n = x.size
        dx = np.diff(x) if x.size > 1 else np.zeros(0)
        moving = np.flatnonzero(dx != 0.0)
        self.moving = moving.size
        if moving.size == 0:
            return
        sgn = np.sign(dx[moving])
        starts = np.flatnonzero(np.r_[True, sgn[1:] != sgn[:-1]])
        ends = np.r_[starts[1:], moving.size]
        cum = np.cumsum(np.abs(dx[moving]))
        run_of = np.repeat(np.arange(starts.size), ends - starts)
        base = np.r_[0.0, cum][starts]
        #: path [rad] from the start of its run to after each moving increment
        self._xi = cum - base[run_of]
        #: path [rad] of each run
        self._run_length = cum[ends - 1] - base
        self._run_of = run_of
        self._s_run = sgn[starts]
        self._s_inc = sgn
        idx = np.zeros(x.size, dtype=np.int64)
        idx[moving + 1] = np.arange(1, moving.size + 1)
        self._fill = np.maximum.accumulate(idx)
        #: smallest increment [rad] (an encoder's quantum when quantised)
        self.resolution = float(np.min(np.abs(dx[moving])))
        self.span = float(np.ptp(x))

    def normalized(self, ratio: float, exponent: float = 1.0, initial: float = 0.0) -> _Array:
        """``f = F_d/F_c`` after each sample for ``ratio = sigma/F_c`` [1/rad] (``inf``: the
        Coulomb limit, ``f = sgn`` of the last move), starting from ``f = initial``."""
        out = np.full(self.n, float(initial))
        if self.moving == 0 or ratio <= 0.0:
            return out
        if math.isinf(ratio):
            values = np.r_[float(initial), self._s_inc]
            return values[self._fill]
        s_run = self._s_run
        totals = (ratio * self._run_length).tolist()
        u0 = max(0.0, 1.0 - s_run[0] * float(initial))
        starts_u = [u0]
        if exponent == 1.0:
            decay = np.exp(-ratio * self._run_length).tolist()
            for r in range(1, len(totals)):
                u0 = 2.0 - u0 * decay[r - 1]
                starts_u.append(u0)
        else:
            relax = _relax_scalar(exponent)
            for r in range(1, len(totals)):
                u0 = 2.0 - relax(u0, totals[r - 1])
                starts_u.append(u0)
        u = _relax(np.asarray(starts_u)[self._run_of], ratio * self._xi, exponent)
        values = np.empty(u.size + 1)
        values[0] = float(initial)
        np.multiply(s_run[self._run_of], 1.0 - u, out=values[1:])
        return values[self._fill]


def dahl_force(x: npt.ArrayLike, sigma: float, coulomb_force: float, exponent: float = 1.0,
               initial_force: float = 0.0) -> _Array:
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
    if sigma <= 0.0 or x.size < 2:
        return np.full(x.shape, float(initial_force))
    fc = float(coulomb_force)
    return fc * DahlPath(x).normalized(sigma / fc, exponent, float(initial_force) / fc)

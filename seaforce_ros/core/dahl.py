"""Dahl hysteresis state (paper eq. 14-15), exact per-sample update.

Model (eq. 14)::

    dF_d/dx = sigma |1 - (F_d/F_c) sgn(xdot)|^n sgn(1 - (F_d/F_c) sgn(xdot))

Within one sample the position moves monotonically by ``dx`` (direction
``s = sgn(dx)``). With ``u = 1 - s F_d/F_c`` (``0 <= u <= 2`` whenever
``|F_d| <= F_c``) and the path length ``xi = |dx|``, eq. 14 becomes
``du/dxi = -(sigma/F_c) u^n`` which has the closed-form solution

* n = 1: ``u = u0 exp(-sigma xi / F_c)`` (eq. 15's exponential relaxation);
* n != 1: ``u^(1-n) = u0^(1-n) - (1-n)(sigma/F_c) xi``, clipped at ``u = 0``
  (for n < 1 the force reaches F_c after a finite path).

The update is therefore exact for any step size (unconditionally stable),
``u`` never changes sign, and ``|F_d| <= F_c`` holds after every step.
"""

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .params import DahlParams

__all__ = ["DahlState", "dahl_step"]


def dahl_step(force: float, dx: float, sigma: float, coulomb_force: float,
              exponent: float) -> float:
    """Dahl force after a monotone position increment (eq. 14, exact).

    Parameters
    ----------
    force : float
        F_d before the step [N m], ``|force| <= coulomb_force``.
    dx : float
        Position increment [rad].
    sigma : float >= 0
        sigma [N m/rad].
    coulomb_force : float > 0
        F_c [N m].
    exponent : float >= 0
        n.

    Returns
    -------
    float
        F_d after the step [N m].
    """
    if dx == 0.0 or sigma == 0.0:
        return force
    s = 1.0 if dx > 0.0 else -1.0
    u0 = 1.0 - s * force / coulomb_force
    if u0 <= 0.0:
        return s * coulomb_force
    c = sigma * abs(dx) / coulomb_force
    if exponent == 1.0:
        u = u0 * math.exp(-c)
    elif exponent < 1.0:
        p = 1.0 - exponent
        base = u0 ** p - p * c
        u = base ** (1.0 / p) if base > 0.0 else 0.0
    else:
        p = exponent - 1.0
        u = (u0 ** (-p) + p * c) ** (-1.0 / p)
    return s * coulomb_force * (1.0 - u)


class DahlState:
    """Dahl hysteresis force driven by a position signal, one sample at a time.

    Parameters
    ----------
    params : DahlParams
        sigma [N m/rad], F_c [N m], n.
    position : float, optional
        Initial position [rad] (the first increment is taken from it).

    Attributes
    ----------
    force : float
        Current F_d [N m], always within ``[-F_c, F_c]``.
    position : float
        Last position [rad].
    """

    __slots__ = ("sigma", "coulomb_force", "exponent", "force", "position")

    def __init__(self, params: "DahlParams", position: float = 0.0) -> None:
        self.sigma = float(params.sigma)
        self.coulomb_force = float(params.coulomb_force)
        self.exponent = float(params.exponent)
        self.force = 0.0
        self.position = float(position)

    def reset(self, position: float = 0.0, force: float = 0.0) -> None:
        """Set the position and force (clipped to ``[-F_c, F_c]``)."""
        self.position = float(position)
        fc = self.coulomb_force
        self.force = min(fc, max(-fc, float(force)))

    def set_params(self, params: "DahlParams") -> None:
        """Change sigma, F_c, n keeping the state (force clipped to the new F_c)."""
        self.sigma = float(params.sigma)
        self.coulomb_force = float(params.coulomb_force)
        self.exponent = float(params.exponent)
        self.reset(self.position, self.force)

    def update(self, position: float) -> float:
        """Advance to ``position`` [rad]; return the new F_d [N m]."""
        dx = position - self.position
        self.position = position
        if dx != 0.0 and self.sigma != 0.0:
            if self.exponent == 1.0:
                # inlined n = 1 case of dahl_step (hot path)
                fc = self.coulomb_force
                if dx > 0.0:
                    self.force = fc - (fc - self.force) * math.exp(-self.sigma * dx / fc)
                else:
                    self.force = -fc + (fc + self.force) * math.exp(self.sigma * dx / fc)
            else:
                self.force = dahl_step(self.force, dx, self.sigma, self.coulomb_force,
                                       self.exponent)
        return self.force

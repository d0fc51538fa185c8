"""Passivity of the DOB-controlled motor port (paper Section III-C, eq. 25-28).

A linear one-port with admittance Y(s) is passive iff (i) Y has no poles in
the open right half plane, (ii) poles on the imaginary axis are simple with
real positive residues, (iii) Re Y(jw) >= 0 for all w (Colgate & Hogan).

:func:`dob_passivity_closed_form` gives the paper's closed-form verdict
(eq. 28 together with the Routh-Hurwitz / imaginary-pole conditions);
:func:`numerical_passivity` checks (i)-(iii) numerically for any rational
Y, and is used to cross-check the closed form.
"""

from typing import TYPE_CHECKING, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from .params import DobParams, PlantParams
from .params import guard_carries  # noqa: F401 (re-exported)
from .plant import poly_tf

if TYPE_CHECKING:                       # imported where used (slow to import)
    import control

__all__ = [
    "dob_admittance_coefficients", "dob_admittance", "dob_admittance_at",
    "DobBounds", "dob_passivity_bounds", "dob_passivity_closed_form",
    "PassivityVerdict", "numerical_passivity", "guard_carries",
]


_Coefficients = npt.NDArray[np.float64]
#: Frequencies [rad/s]: a sequence or an array (indexed, so not any array_like).
_Grid = Union[Sequence[float], npt.NDArray[np.float64]]


def _mbk(plant: PlantParams) -> Tuple[float, float, float]:
    return plant.motor_inertia, plant.motor_damping, plant.motor_stiffness


def _nominal(plant: PlantParams, dob: DobParams) -> Tuple[float, float, float, float]:
    m_n = plant.motor_inertia if dob.nominal_inertia is None else dob.nominal_inertia
    return dob.cutoff, m_n, dob.nominal_damping, dob.nominal_stiffness


def dob_admittance_coefficients(m: float, b: float, k: float, lam: float, m_n: float, b_n: float,
                                k_n: float) -> Tuple[_Coefficients, _Coefficients]:
    """Numerator and denominator coefficients (highest power first) of eq. 25::

        Y(s) = V/F_p = s (s + lam) / (m s^3 + (lam m_n + b) s^2
                                      + (k + lam b_n) s + lam k_n)
    """
    num = np.array([1.0, lam, 0.0])
    den = np.array([m, lam * m_n + b, k + lam * b_n, lam * k_n])
    return num, den


def dob_admittance(plant: PlantParams, dob: DobParams) -> "control.TransferFunction":
    """Eq. 25 as a :class:`control.TransferFunction` (V/F_p, rad/(s N m))."""
    lam, m_n, b_n, k_n = _nominal(plant, dob)
    num, den = dob_admittance_coefficients(*_mbk(plant), lam, m_n, b_n, k_n)
    return poly_tf(num, den)


def dob_admittance_at(plant: PlantParams, dob: DobParams,
                      omega: npt.ArrayLike) -> npt.NDArray[np.complex128]:
    """Complex Y(j omega) of eq. 25 for an array of frequencies [rad/s]."""
    lam, m_n, b_n, k_n = _nominal(plant, dob)
    num, den = dob_admittance_coefficients(*_mbk(plant), lam, m_n, b_n, k_n)
    s = 1j * np.asarray(omega, float)
    return np.polyval(num, s) / np.polyval(den, s)


class DobBounds(NamedTuple):
    """Closed-form passivity bounds of eq. 28.

min_nominal_inertia : m - b/lambda [N m s^2/rad]
min_nominal_stiffness : 0 [N m/rad]
max_nominal_stiffness : k + lambda b_n [N m/rad]
min_nominal_damping : -k/lambda [N m s/rad] (needed for k_n >= 0 to be feasible)
"""

    min_nominal_inertia: float
    min_nominal_stiffness: float
    max_nominal_stiffness: float
    min_nominal_damping: float


def dob_passivity_bounds(plant: PlantParams, cutoff: float,
                         nominal_damping: float = 0.0) -> DobBounds:
    """Eq. 28 bounds for a plant and a cut-off lambda [rad/s].

    >>> round(dob_passivity_bounds(PlantParams.table_i(), 2*math.pi*20).min_nominal_inertia, 10)
    0.0008743477
    """
    m, b, k = _mbk(plant)
    lam = float(cutoff)
    if not lam > 0.0:
        raise ValueError("cutoff must be > 0")
    return DobBounds(m - b / lam, 0.0, k + lam * nominal_damping, -k / lam)


def dob_passivity_closed_form(m: float, b: float, k: float, lam: float, m_n: float, b_n: float,
                              k_n: float) -> bool:
    """Closed-form passivity verdict of the DOB motor port (Section III-C).

    Passive iff (Routh-Hurwitz, criterion i) ``m_n > -b/lam``,
    ``b_n >= -k/lam``, ``0 <= k_n <= (lam m_n + b)(lam b_n + k)/(lam m)``,
    (criterion ii) not the double pole at the origin, and (criterion iii)
    ``m_n >= m - b/lam`` and ``k_n <= k + lam b_n`` -- which together reduce
    to eq. 28 when m > 0.

    Returns
    -------
    bool
    """
    if not (m > 0 and lam > 0):
        raise ValueError("m and lambda must be > 0")
    routh = (m_n > -b / lam and b_n >= -k / lam and k_n >= 0.0
             and k_n <= (lam * m_n + b) * (lam * b_n + k) / (lam * m))
    realpart = m_n >= m - b / lam and k_n <= k + lam * b_n
    return bool(routh and realpart)


class PassivityVerdict(NamedTuple):
    """Result of :func:`numerical_passivity`.

passive : bool
reason : str, "" when passive, else which criterion fails
poles : ndarray, poles of the (cancelled) admittance
min_real_part : float, min Re Y(jw) on the grid
min_real_frequency : float, where it occurs [rad/s]
"""

    passive: bool
    reason: str
    poles: npt.NDArray[np.inexact]
    min_real_part: float
    min_real_frequency: float


def _cancel_origin(num: npt.ArrayLike,
                   den: npt.ArrayLike) -> Tuple[_Coefficients, _Coefficients]:
    num = np.trim_zeros(np.asarray(num, float), "f")
    den = np.trim_zeros(np.asarray(den, float), "f")
    while num.size > 1 and den.size > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    return num, den


def _even_odd(coeffs: npt.ArrayLike) -> Tuple[np.poly1d, np.poly1d]:
    """Real and imaginary parts of p(jw) as polynomials in w (highest first)."""
    c = np.asarray(coeffs, float)[::-1]          # ascending powers of s
    re = np.zeros(c.size)
    im = np.zeros(c.size)
    for i, ci in enumerate(c):
        # (j w)^i = j^i w^i
        r = i % 4
        if r == 0:
            re[i] = ci
        elif r == 1:
            im[i] = ci
        elif r == 2:
            re[i] = -ci
        else:
            im[i] = -ci
    return np.poly1d(re[::-1]), np.poly1d(im[::-1])


def numerical_passivity(num: npt.ArrayLike, den: npt.ArrayLike,
                        omega: Optional[_Grid] = None,
                        tol: float = 1e-9) -> PassivityVerdict:
    """Numerical passivity verdict of a rational admittance ``Y = num/den``.

    Checks (i) poles (roots of ``den``) in the closed left half plane, (ii)
    poles on the imaginary axis simple with positive real residues, (iii)
    ``Re Y(jw) >= 0``: on a dense log grid (reported as ``min_real_part``)
    and, beyond the grid, exactly, via the sign changes of the polynomial
    ``Re[num(jw) conj(den(jw))]`` (its positive real roots of odd
    multiplicity and its behaviour as w -> 0 and w -> inf).

    Parameters
    ----------
    num, den : array_like
        Polynomial coefficients in s, highest power first.
    omega : array_like, optional
        Grid [rad/s]; default 4000 log-spaced points, 1e-3..1e6 rad/s.
    tol : float
        Relative tolerance for "on the imaginary axis".

    Returns
    -------
    PassivityVerdict
    """
    num, den = _cancel_origin(num, den)
    if omega is None:
        omega = np.logspace(-3, 6, 4000)
    poles = np.roots(den) if den.size > 1 else np.array([], complex)
    scale = max(1.0, float(np.max(np.abs(poles)))) if poles.size else 1.0
    s = 1j * np.asarray(omega, float)
    y = np.polyval(num, s) / np.polyval(den, s)
    i_min = int(np.argmin(y.real))
    min_re, w_min = float(y.real[i_min]), float(omega[i_min])

    def verdict(ok: bool, reason: str) -> PassivityVerdict:
        return PassivityVerdict(ok, reason, poles, min_re, w_min)

    # (i) right-half-plane poles
    if np.any(poles.real > tol * scale):
        return verdict(False, "pole in the right half plane")
    # (ii) imaginary-axis poles: simple, positive real residue
    on_axis = poles[np.abs(poles.real) <= tol * scale]
    for p in on_axis:
        close = np.abs(poles - p) <= 1e-6 * scale
        if np.count_nonzero(close) > 1:
            return verdict(False, "repeated pole on the imaginary axis")
        others = poles[~close]
        residue = np.polyval(num, p) / (den[0] * np.prod(p - others))
        if not (residue.real > 0 and abs(residue.imag) <= 1e-6 * abs(residue) + 1e-300):
            return verdict(False, "imaginary-axis pole with non-positive residue")
    # (iii) Re Y(jw) >= 0 -- grid
    if min_re < -tol * max(1.0, float(np.max(np.abs(y)))):
        return verdict(False, f"Re Y(jw) = {min_re:.3g} < 0 at w = {w_min:.4g} rad/s")
    # (iii) -- exact sign analysis of Re[N conj(D)] = Nr Dr + Ni Di
    nr, ni = _even_odd(num)
    dr, di = _even_odd(den)
    rp = np.poly1d(np.trim_zeros((nr * dr + ni * di).coeffs, "f"))
    c = rp.coeffs
    if c.size == 0 or np.all(c == 0.0):
        return verdict(True, "")
    cscale = float(np.max(np.abs(c)))
    c = np.where(np.abs(c) <= 1e-14 * cscale, 0.0, c)
    c = np.trim_zeros(c, "f")
    if c.size and c[0] < 0:
        return verdict(False, "Re Y(jw) < 0 as w -> infinity")
    nz = np.trim_zeros(c, "b")
    if nz.size and nz[-1] < 0:
        return verdict(False, "Re Y(jw) < 0 as w -> 0")
    roots = np.roots(c) if c.size > 1 else np.array([])
    for r in roots:
        if abs(r.imag) <= 1e-9 * max(1.0, abs(r)) and r.real > 0:
            w = r.real
            lo, hi = np.polyval(c, w * (1 - 1e-6)), np.polyval(c, w * (1 + 1e-6))
            if min(lo, hi) < 0:
                return verdict(False, f"Re Y(jw) < 0 near w = {w:.4g} rad/s")
    return verdict(True, "")


"""Self-identification in free air: the eight Table I parameters and the Dahl hysteresis from a
motor-torque excitation, without an endpoint encoder or a force sensor.

The record (:class:`~.record.ExcitationRecord`) holds the motor position X, velocity V, the
pressure force F_p, the torque the plant applied F_a and the excitation part r of the command
(the finger may be under a weak centring servo: F_a is partly feedback, r is not). Motor frame,
rotational SI units; the physics (paper Section II-C, eq. 14-15)::

    motor     Z_m X   = F_a + F_p,                 Z_m = m s^2 + b s + k
    endpoint  Z_e X_e = F_e - F_p - F_d,           Z_e = m_e s^2 + b_e s + k_e
    hose      F_p     = Z_s (X_e - X),             Z_s = b_s s + k_s

with F_e = 0 in free air and F_d the Dahl force (sigma, F_c, n = 1).

Method
------
1. Blackman-Tukey cross-spectra of X, F_p and F_a against r
   (:class:`~seaforce_ros.identification.spectral.BlackmanTukey`, a Hann lag window spanning
   :data:`PERIODS` periods, positions prewhitened as ``identify`` does), so that the servo's
   feedback, the pressure noise and the encoder quantisation drop out. F_a is the torque held
   over the sample interval *before* its sample (the ``held`` convention): its cross-spectrum
   is shifted by half a sample and scaled by the hold's ``sinc(w T/2)``. Two responses, each
   with its 1-sigma and coherence, on :data:`N_FREQ` log-spaced frequencies of the band:

   * the motor plant ``A = X/(F_a + F_p) = 1/Z_m``;
   * the motor port ``P = F_p/X = -(Z_s Z_e X + Z_s F_d)/((Z_s + Z_e) X)``, which with F_d = 0
     is ``-Z_s Z_e/(Z_s + Z_e)``: six independent coefficients for five unknowns. X and F_p
     are sampled, but both respond to the held torque, whose images above the Nyquist
     frequency fold back onto the band: the port's model folds them too
     (:func:`_alias_factor`, with the motor's Z_m from A), which took the bias of b_s on exact
     data from 1.4 % (band to 1200 rad/s) and 3.7 % (to 2000 rad/s) to 0.3 % and 0.6 %.

2. How each parameter is resolved:

   * m, b, k -- from A alone (weighted linear least squares on 1/A,
     :func:`~seaforce_ros.identification.fit.fit_mass_spring_damper`) over the band up to
     :data:`MOTOR_TOP` rad/s (its model has the hold's sinc and half-sample shift but not the
     held torque's images, which grow as w^3 relative to X): m is the
     s^2 coefficient (the mass line above the motor's corner sqrt(k/m)), b the s coefficient,
     k the constant. Nothing of the endpoint or the hose enters A.
   * k_s, b_s -- from P above the hose resonance ``w_h = sqrt((k_s + k_e)/m_e)``, where
     ``-P -> Z_s``: k_s its real part, b_s its imaginary part over w (b_s also damps the
     resonance).
   * m_e -- from the hose resonance w_h of P (P's pole; with k_s known it fixes m_e).
   * b_e, k_e, sigma, F_c -- in the time domain, below :data:`FILTER_CUTOFF` Hz, where the
     endpoint moves far more than its pre-sliding displacement F_c/sigma: the free-air
     friction fit of the friction calibration
     (:class:`~seaforce_ros.core.friction_calibration.FrictionFit`, variable projection over
     sigma/F_c on :data:`RATIO_RANGE`), run on the endpoint position estimated through the
     identified hose, ``X_e_hat = X + F_p/(b_s s + k_s)`` (the controller's exact first-order
     hold, :func:`~seaforce_ros.core.observer.hose_coefficients`), with the identified m_e.
     A linear fit of P would lump the hysteresis into them (it acts as a stiffness sigma at
     small amplitudes and as a Coulomb force F_c at large ones). The fit sees every
     :data:`DECIMATE`-th sample; the inertia force m_e A_e (A_e the central second difference
     of X_e_hat) is added to F_p before it (the fit's own acceleration is half a sample late,
     which biased b_e and k_e); its Dahl states are driven by X_e_hat low-passed at
     :data:`DAHL_INPUT_CUTOFF` Hz. Its filter's cut-off :data:`FILTER_CUTOFF` is low so that
     the errors of m_e and of the hose, which enter through m_e A_e and X_e_hat, stay small
     next to the friction. When it sees no hysteresis (F_c not positive by 3 sigma), b_e and
     k_e are the port's linear fit's and sigma, F_c are not identified.

   m_e, k_s, b_s are first fitted with b_e, k_e free and no Dahl force (nonlinear weighted
   least squares on the relative error of P, within a factor :data:`PORT_SEARCH` of its start,
   from two starts -- a linear fit of P's coefficients, and P's shape: its resonance and its
   low band -- keeping the better);
   then, up to :data:`MAX_ITERATIONS` times until m_e, b_s, k_s change by less than
   :data:`CONVERGED`: the friction fit on X_e_hat, and the fit of P again for m_e, b_s, k_s
   with b_e, k_e held at the friction fit's values and the Dahl force of that fit (driven by
   X_e_hat) on the endpoint.

3. 1-sigma: from the weighted Jacobian of each fit, scaled by sqrt(chi^2/dof) when the misfit
   exceeds the spectral bands (frequency domain); the friction fit's own (residual variance
   per correlation time of its filter). They are statistical: they do not include the bias of
   a model that does not describe the gripper.

A parameter is *not identified* (value NaN, a reason) when its fit did not give a positive
value with a finite 1-sigma below the value; :meth:`FreeAirIdentification.plant` then raises.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt
import scipy.optimize
import scipy.signal

from ..core.friction_calibration import FrictionEstimate, FrictionFit, ratio_grid
from ..core.observer import hose_coefficients
from ..core.params import DahlParams, PlantParams
from ..identification.dahl_model import DahlPath
from ..identification.fit import SIGMA_FLOOR, fit_mass_spring_damper
from ..identification.plant_id import POSITION_ORDERS, excited_band
from ..identification.spectral import BlackmanTukey, FrequencyResponse
from .errors import CommissioningError
from .record import ExcitationRecord

if TYPE_CHECKING:
    from .report import ModelClass

__all__ = ["FreeAirIdentification", "Estimate", "Response", "identify_free_air",
           "RecordTooShortError", "NotExcitedError", "NonFiniteRecordError",
           "LowCoherenceError", "PLANT_KEYS", "DAHL_KEYS", "REQUIRED_BAND", "MOTOR_TOP",
           "PERIODS", "FORCE_ORDERS", "PORT_TOP", "ALIAS_IMAGES", "PORT_SEARCH", "PORT_RESTARTS",
           "CROSSING_FACTORS",
           "SK_ITERATIONS", "N_FREQ", "FILTER_CUTOFF", "DECIMATE", "RATIO_RANGE",
           "MAX_ITERATIONS", "CONVERGED", "MIN_COHERENCE", "SETTLE_TIME", "DAHL_INPUT_CUTOFF",
           "PATH_CUTOFF", "MODEL_CLASS_THRESHOLD", "model_class"]

_Real = npt.NDArray[np.float64]
_Complex = npt.NDArray[np.complex128]
_AnyComplex = npt.NDArray[np.complexfloating[Any, Any]]
Progress = Callable[[str, float], object]

#: The eight Table I parameters, in PlantParams' order.
PLANT_KEYS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
              "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")
#: The Dahl parameters identified (n = 1 is assumed).
DAHL_KEYS = ("sigma", "coulomb_force")
#: The band [rad/s] every record must excite: the motor's and the endpoint's corners lie above
#: its lower edge (with Table I: 12 and 1.4-46 rad/s), the hose's damping shows below its
#: upper edge (b_s w = 0.7 k_s at 1000 rad/s with Table I).
REQUIRED_BAND = (10.0, 1000.0)
#: Upper edge [rad/s] of the motor plant's fit.
MOTOR_TOP = 1000.0
#: Periods of w in the Blackman-Tukey lag window (resolution about w/PERIODS).
PERIODS = 40.0
#: Prewhitening of the pressure force (backward differences per band, see ``identify``): the
#: port's stiffness below the hose resonance and its damping above it leave F_p rising with w,
#: and the lag window leaks its low-frequency power into the high-frequency estimates.
FORCE_ORDERS = ((0, 5.0), (1, math.inf))
#: Upper edge [rad/s] of the port's default band (b_s w exceeds k_s below it with Table I; the
#: images of the held torque that alias into X and F_p are in the port's model).
PORT_TOP = 2000.0
#: Images of the held torque either side that the port's model folds back (aliasing).
ALIAS_IMAGES = 3
#: The port's nonlinear fit searches within this factor of its linear start.
PORT_SEARCH = 100.0
#: Restarts of a port fit that ended on its search bound (from where it ended).
PORT_RESTARTS = 2
#: The m_e of the first friction pass's retry from P's shape, as multiples of the crossing's
#: (:func:`_crossing_start`; when that pass's misfit would flag the model class).
CROSSING_FACTORS = (1.0, 10.0)
#: Two port fits whose parameters are all within this (of the log) ended at one minimum.
SAME_FIT = 0.05
#: Sanathanan-Koerner iterations of the port's linear start.
SK_ITERATIONS = 8
#: Frequencies of the spectral grid.
N_FREQ = 100
#: Cut-off [Hz] of the friction fit's state-variable filter. Low, so that the endpoint's
#: inertia force (m_e w^2 X_e, with m_e from the port) is small next to the friction: at the
#: contact estimator's 30 Hz a 1 % error of m_e moved sigma by 16-44 % and one of k_s by 100 %
#: (through X_e_hat); at 5 Hz by 9-11 % and 2 %.
FILTER_CUTOFF = 5.0
#: The friction fit works on every DECIMATE-th sample (after a zero-phase anti-alias filter):
#: its filter passes nothing above FILTER_CUTOFF, and the cost falls by this factor.
DECIMATE = 4
#: Candidate sigma/F_c [1/rad] of the friction fit (10 per decade): a pre-sliding displacement
#: F_c/sigma from 0.1 mrad to 0.1 rad.
RATIO_RANGE = (10.0, 1e4)
#: Alternations of the friction fit and the port fit at most ...
MAX_ITERATIONS = 3
#: ... stopping when m_e, b_s and k_s change by less than this (relative).
CONVERGED = 5e-3
#: Median squared coherence of X and F_p with the excitation below which the record is refused.
MIN_COHERENCE = 0.5
#: Seconds at the start the friction fit leaves out (its filter and the Dahl states settle).
SETTLE_TIME = 0.5
#: ... and the travel [rad] the estimated endpoint must have covered since the record's start
#: before the fit counts a sample. A Dahl state forgets its start through motion, not time:
#: a finger at rest under a preload (after a canceled excitation, |F_p(0)| up to 0.018 N m)
#: has a Dahl force the fit's states, started at 0, do not have, and the first slide fitted so
#: pulled the ratio up -- sigma 10.5-39.9 over 17 short records over ROS of one plant (12.8);
#: counted from 0.1 rad of travel (about 40 pre-sliding displacements at sigma/F_c = 400),
#: 12.5-14.7. (0.3 rad threw informative sliding away: twice the spread.)
SETTLE_TRAVEL = 0.1
#: Zero-phase low-pass [Hz] of the estimated endpoint path that drives the friction fit's Dahl
#: states (the fit sees nothing above FILTER_CUTOFF).
DAHL_INPUT_CUTOFF = 100.0
#: Zero-phase low-pass [Hz] of the estimated endpoint path that drives the Dahl force of the
#: port fit (the pressure noise would otherwise reverse it at every sample).
PATH_CUTOFF = 400.0


#: The misfits (rms relative, over the fitted band) beyond which the identified model class
#: -- the linear plant with the Dahl hysteresis -- is said not to describe the gripper.
MODEL_CLASS_THRESHOLD = {"motor": 0.03, "port": 0.025}


class RecordTooShortError(CommissioningError):
    """The record is too short for the band: record longer or raise the band's lower edge."""


class NotExcitedError(CommissioningError):
    """The excitation does not cover the band the fits need: widen the chirp."""


class NonFiniteRecordError(CommissioningError):
    """A NaN or inf in a measured signal: re-record (check the sensors)."""


class LowCoherenceError(CommissioningError):
    """The responses are mostly noise: raise the excitation's amplitude or record longer."""


@dataclass(frozen=True)
class Estimate:
    """One identified parameter.

    value, sigma : float
        The value and its 1-sigma (units of the parameter); NaN when not identified.
    reason : str
        '' when identified, else why not.
    """

    value: float
    sigma: float
    reason: str = ""

    @property
    def identified(self) -> bool:
        """The value may be used."""
        return not self.reason


@dataclass(frozen=True)
class Response:
    """A measured frequency response with the identified model's on the same grid.

    omega [rad/s]; h (complex, measured), sigma (its absolute 1-sigma), coherence (the squared
    coherence of its output with the excitation, 0..1), model (complex, identified model).
    """

    name: str
    omega: _Real
    h: _Complex
    sigma: _Real
    coherence: _Real
    model: _Complex


@dataclass
class FreeAirIdentification:
    """What :func:`identify_free_air` found.

    Attributes
    ----------
    parameters : dict of str -> Estimate
        :data:`PLANT_KEYS` and :data:`DAHL_KEYS`.
    motor, port : Response
        ``X/(F_a + F_p)`` [rad/(N m)] and ``F_p/X`` [N m/rad], measured and modelled (the port's
        model is the linear one, Dahl force left out: what a plot of the plant shows).
    misfit : dict of str -> float
        rms relative misfit ``|H_model - H|/|H|`` of ``motor`` and ``port`` over their fitted
        bands (the port's with the Dahl force).
    band, motor_band : (lo, hi) [rad/s]
        The fitted bands (the port's; the motor plant's).
    iterations : int
        Alternations of the friction fit and the port fit.
    notes : list of str
    pressure_offset : Estimate
        What the pressure force read beyond the free finger's forces [N m] -- the sensor's
        offset less the one the record was already corrected by, with the finger's spring
        relaxed at the rest position given -- from the friction fit's constant.
    """

    parameters: Dict[str, Estimate]
    motor: Response
    port: Response
    misfit: Dict[str, float]
    band: Tuple[float, float]
    motor_band: Tuple[float, float]
    iterations: int
    notes: List[str] = field(default_factory=list)
    pressure_offset: Estimate = field(
        default_factory=lambda: Estimate(math.nan, math.nan, "not fitted"))

    def value(self, key: str) -> float:
        """The value of one parameter (NaN when not identified)."""
        return self.parameters[key].value

    def not_identified(self) -> Dict[str, str]:
        """``{key: reason}`` of the parameters not identified."""
        return {k: e.reason for k, e in self.parameters.items() if not e.identified}

    def plant(self) -> PlantParams:
        """The identified :class:`~seaforce_ros.core.params.PlantParams`; raises
        :class:`~.errors.CommissioningError` naming what is not identified."""
        missing = {k: r for k, r in self.not_identified().items() if k in PLANT_KEYS}
        if missing:
            raise CommissioningError("the plant is not identified: " + "; ".join(
                f"{k}: {r}" for k, r in missing.items()))
        return PlantParams(**{k: self.parameters[k].value for k in PLANT_KEYS})

    def dahl(self) -> DahlParams:
        """The identified :class:`~seaforce_ros.core.params.DahlParams` (n = 1); raises
        :class:`~.errors.CommissioningError` when sigma or F_c is not identified."""
        missing = {k: r for k, r in self.not_identified().items() if k in DAHL_KEYS}
        if missing:
            raise CommissioningError("the Dahl hysteresis is not identified: " + "; ".join(
                f"{k}: {r}" for k, r in missing.items()))
        return DahlParams(sigma=self.parameters["sigma"].value,
                          coulomb_force=self.parameters["coulomb_force"].value, exponent=1.0)


# --- the record ------------------------------------------------------------------------------
def _signals(record: ExcitationRecord) -> Dict[str, _Real]:
    """The record's signals on its full cycle grid (gaps -- samples the controller skipped --
    filled by linear interpolation), checked finite."""
    names = ("x", "v", "f_p", "applied", "excitation")
    for name in names:
        a = np.asarray(getattr(record, name), float)
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise NonFiniteRecordError(
                f"record: {name} has {bad.size} non-finite samples (the first at index "
                f"{bad[0]}): re-record the excitation (check the sensor that gives {name})")
    cycle = np.asarray(record.cycle, np.int64)
    steps = np.diff(cycle)
    if np.any(steps <= 0):
        raise CommissioningError("record: cycle is not increasing; pass the samples in the "
                                 "order the controller ran them")
    out = {name: np.asarray(getattr(record, name), float) for name in names}
    if cycle.size and np.any(steps != 1):
        grid = np.arange(cycle[0], cycle[-1] + 1)
        out = {name: np.interp(grid, cycle, a) for name, a in out.items()}
    return out


def _bands(ref: _Real, dt: float, band: Optional[Tuple[float, float]]
           ) -> Tuple[float, float]:
    """The port's band: given, or the excited band less a margin; checked against the record's
    length and the excitation."""
    if np.std(ref) == 0.0:
        raise NotExcitedError("the excitation is constant: record a motor-torque chirp "
                              f"that spans at least {REQUIRED_BAND[0]:g}-{REQUIRED_BAND[1]:g} "
                              "rad/s")
    nyquist = math.pi / dt
    duration = ref.size * dt
    need = 4.0 * math.pi / REQUIRED_BAND[0]
    if duration < need:
        raise RecordTooShortError(
            f"record of {duration:.2f} s: the band from {REQUIRED_BAND[0]:g} rad/s needs at "
            f"least {need:.1f} s (two periods); record longer (tens of seconds)")
    ex_lo, ex_hi = excited_band(ref, dt)
    if band is None:
        lo = max(1.5 * ex_lo, 8.0 * math.pi / duration)
        hi = min(ex_hi / 1.2, PORT_TOP, 0.5 * nyquist)
    else:
        lo, hi = (float(b) for b in band)
        if not (0.0 < lo < hi and math.isfinite(hi)):
            raise CommissioningError(f"band = {band!r}: must be 0 < lo < hi (rad/s)")
        if hi > 0.5 * nyquist:
            raise CommissioningError(f"band up to {hi:g} rad/s: at most half the Nyquist "
                                     f"frequency, {0.5 * nyquist:.0f} rad/s")
    need = 4.0 * math.pi / min(lo, REQUIRED_BAND[0])
    if duration < need:
        raise RecordTooShortError(
            f"record of {duration:.2f} s: the band from {min(lo, REQUIRED_BAND[0]):g} rad/s "
            f"needs at least {need:.1f} s (two periods); record longer")
    if lo > REQUIRED_BAND[0] or hi < REQUIRED_BAND[1] or ex_lo > 1.05 * lo \
            or ex_hi < hi / 1.05:
        raise NotExcitedError(
            f"the excitation covers {ex_lo:.3g}-{ex_hi:.3g} rad/s and the band is "
            f"{lo:.3g}-{hi:.3g} rad/s: the fits need {REQUIRED_BAND[0]:g}-"
            f"{REQUIRED_BAND[1]:g} rad/s excited (e.g. a log chirp from 0.3 Hz to 800 Hz)")
    return lo, hi


# --- models ----------------------------------------------------------------------------------
def _impedances(theta: Dict[str, float], s: _AnyComplex
                ) -> Tuple[_AnyComplex, _AnyComplex, _AnyComplex]:
    """(Z_m, Z_e, Z_s) at ``s`` [rad/s]."""
    def z(*coef: float) -> _AnyComplex:
        return np.asarray(np.polyval(coef, s), dtype=np.complex128)
    return (z(theta["motor_inertia"], theta["motor_damping"], theta["motor_stiffness"]),
            z(theta["endpoint_inertia"], theta["endpoint_damping"], theta["endpoint_stiffness"]),
            z(theta["hose_damping"], theta["hose_stiffness"]))


def _alias_factor(theta: Dict[str, float], w: _Real, dt: float) -> _Complex:
    """F_p/X as sampled over F_p/X of the continuous model, for a motor torque held over each
    sample period ``dt`` [s] (no Dahl force): the held torque's images at ``w + j 2 pi/dt``
    (the hold's ``sinc e^{-j w dt/2}``) drive X and F_p alike, and sampling folds each back
    onto w, so the sampled ratio is ``sum_j H_p(w_j) h(w_j) / sum_j H_x(w_j) h(w_j)`` with
    ``H_x = 1/(Z_m + G)``, ``H_p = -G H_x``, ``G = Z_s Z_e/(Z_s + Z_e)``
    (:data:`ALIAS_IMAGES` images either side)."""
    ws = 2.0 * math.pi / dt
    num = np.zeros(w.size, complex)
    den = np.zeros(w.size, complex)
    for j in range(-ALIAS_IMAGES, ALIAS_IMAGES + 1):
        wj = w + j * ws
        zm, ze, zs = _impedances(theta, 1j * wj)
        g = zs * ze / (zs + ze)
        hold = np.sinc(wj * dt / (2.0 * math.pi)) * np.exp(-0.5j * wj * dt)
        hx = hold / (zm + g)
        num += -g * hx
        den += hx
    _, ze, zs = _impedances(theta, 1j * w)
    return np.asarray((num / den) / (-zs * ze / (zs + ze)), dtype=np.complex128)


def _port_model(theta: Dict[str, float], w: _Real, s_x: _Complex,
                s_fd: Optional[_Complex], dt: float) -> _Complex:
    """S_rF_p predicted from S_rX (and S_rF_d): ``-(Z_s Z_e X + Z_s F_d)/(Z_s + Z_e)``, times
    the aliasing of a torque held over ``dt`` [s] (:func:`_alias_factor`; 0: none)."""
    _, ze, zs = _impedances(theta, 1j * w)
    num = zs * ze * s_x if s_fd is None else zs * (ze * s_x + s_fd)
    out = -num / (zs + ze)
    if dt > 0.0:
        out = out * _alias_factor(theta, w, dt)
    return np.asarray(out, dtype=np.complex128)


_PORT_KEYS = ("endpoint_inertia", "endpoint_damping", "endpoint_stiffness", "hose_damping",
              "hose_stiffness")


def _port_start(w: _Real, p: _Complex, weight: _Real) -> Dict[str, float]:
    """Linear fit of ``-P = N/D``, ``D = s^2 + d1 s + d0``, ``N = n3 s^3 + .. + n0``
    (Sanathanan-Koerner iterations on the relative error), mapped to the five parameters
    (``k_e << k_s``): the nonlinear fit's start."""
    s = 1j * w
    g = -p
    design = np.stack([s ** 3, s ** 2, s, np.ones_like(s), -s * g, -g], axis=1)
    target = s ** 2 * g
    den = s ** 2 + s * w.max() + w.max() ** 2
    th = np.zeros(6)
    for _ in range(SK_ITERATIONS):
        wt = weight / np.abs(den * g)
        a = np.vstack([design.real * wt[:, None], design.imag * wt[:, None]])
        y = np.concatenate([target.real * wt, target.imag * wt])
        scale = np.sqrt(np.sum(a ** 2, axis=0))
        th = np.linalg.lstsq(a / scale, y, rcond=None)[0] / scale
        den = s ** 2 + th[4] * s + th[5]
    n3, n2, _, n0, d1, d0 = (float(v) for v in th)
    bs = abs(n3)
    ks = abs(n2 - bs * d1)
    me = ks / abs(d0)
    ke = abs(n0) * me / ks
    be = max(abs(me * d1 - bs), 1e-3 * bs)
    return {"endpoint_inertia": me, "endpoint_damping": be, "endpoint_stiffness": max(ke, 1e-6),
            "hose_damping": max(bs, 1e-9), "hose_stiffness": ks}


def _resonance_start(w: _Real, p: _Complex, linear: Dict[str, float]) -> Dict[str, float]:
    """A second start of the port's fit, from the shape of P (the linear fit's k_s, b_s):
    m_e from the resonance, where ``|P/Z_s| = |Z_e/(Z_s + Z_e)|`` peaks (``w_h^2 = k_s/m_e``,
    k_e << k_s); below a fifth of it ``-P ~ Z_e``: k_e its real part at the lowest
    frequency, b_e the median of its imaginary part over w."""
    g = -p
    ks, bs = linear["hose_stiffness"], linear["hose_damping"]
    w_peak = float(w[np.argmax(np.abs(g) / np.abs(ks + 1j * w * bs))])
    low = w <= w_peak / 5.0
    if not low.any():
        low = w <= w[0]
    be = float(np.median(g[low].imag / w[low]))
    return dict(linear, endpoint_inertia=ks / w_peak ** 2,
                endpoint_stiffness=max(float(g[0].real), 1e-6 * ks),
                endpoint_damping=be if be > 0.0 else linear["endpoint_damping"])


def _crossing_start(w: _Real, p: _Complex, linear: Dict[str, float]) -> Dict[str, float]:
    """A start for a resonance too damped to peak: m_e from where ``|P/Z_s|`` first
    reaches 1 (``m_e w^2 = k_s/2`` for a light, stiff-hosed endpoint: ``w_h/sqrt(2)``), the
    rest as :func:`_resonance_start`. (A hose resonance at 123 rad/s damped to 0.24 showed no
    peak: ``|P/Z_s|`` stayed 1.1-1.3 above it, its argmax at the band's top, and both other
    starts ended with m_e 10^4 too small and a 32 % misfit.)"""
    g = -p
    ks, bs = linear["hose_stiffness"], linear["hose_damping"]
    ratio = np.abs(g) / np.abs(ks + 1j * w * bs)
    above = np.flatnonzero(ratio >= 1.0)
    start = _resonance_start(w, p, linear)
    if above.size == 0 or above[0] == 0:
        return start
    i = int(above[0])
    # log-interpolated crossing
    f = math.log(ratio[i - 1]) / (math.log(ratio[i - 1]) - math.log(ratio[i]))
    w_c = math.exp(math.log(w[i - 1]) + f * (math.log(w[i]) - math.log(w[i - 1])))
    return dict(start, endpoint_inertia=ks / (2.0 * w_c ** 2))


def _fit_port(w: _Real, s_x: _Complex, s_fp: _Complex, s_fd: Optional[_Complex],
              rel_sigma: _Real, start: Dict[str, float], free: Sequence[str], dt: float
              ) -> Tuple[Dict[str, float], Dict[str, float], float]:
    """Weighted nonlinear least squares of the port on the relative error of S_rF_p, in the
    logarithms of the ``free`` parameters (the others held at ``start``). Returns (values,
    1-sigma of the free ones, rms relative misfit)."""
    weight = 1.0 / np.maximum(rel_sigma, SIGMA_FLOOR)
    scale = np.abs(s_fp)

    def theta_of(z: _Real) -> Dict[str, float]:
        th = dict(start)
        th.update({k: float(math.exp(v)) for k, v in zip(free, z)})
        return th

    def resid(z: _Real) -> _Real:
        e = (_port_model(theta_of(z), w, s_x, s_fd, dt) - s_fp) / scale * weight
        return np.concatenate([e.real, e.imag])

    z0 = np.log([start[k] for k in free])
    # within a factor PORT_SEARCH of the start (the linear start is within a few 10 % on
    # most records; Levenberg-Marquardt unbounded once ran off to overflow). A fit that ends
    # on that bound is started again from where it ended (at most PORT_RESTARTS times): a
    # linear start 100x off in m_e and b_e ended on the bound with a 14 % misfit
    span = math.log(PORT_SEARCH)
    for _ in range(1 + PORT_RESTARTS):
        sol = scipy.optimize.least_squares(resid, z0, method="trf",
                                           bounds=(z0 - span, z0 + span), x_scale=1.0,
                                           xtol=1e-12, ftol=1e-12,
                                           max_nfev=400 * (len(free) + 1))
        if not np.any(np.abs(sol.x - z0) > span * (1.0 - 1e-6)):
            break
        z0 = sol.x
    th = theta_of(sol.x)
    r = sol.fun
    dof = max(1, r.size - len(free))
    chi2 = float(r @ r) / dof
    jac = sol.jac
    try:
        cov = np.linalg.inv(jac.T @ jac) * max(1.0, chi2)
        sd_log = np.sqrt(np.abs(np.diag(cov)))
    except np.linalg.LinAlgError:
        sd_log = np.full(len(free), math.nan)
    sig = {k: th[k] * float(s) for k, s in zip(free, sd_log)}
    misfit = float(np.sqrt(np.mean(np.abs(_port_model(th, w, s_x, s_fd, dt) - s_fp) ** 2
                                   / scale ** 2)))
    return th, sig, misfit


# --- the time-domain friction fit ------------------------------------------------------------
def _endpoint_estimate(x: _Real, f_p: _Real, hose_damping: float, hose_stiffness: float,
                       dt: float) -> _Real:
    """X_e_hat = X + F_p/(b_s s + k_s), the hose inversion of the controller (exact for a
    piecewise-linear F_p), starting at rest (``delta = F_p/k_s``)."""
    a, c0, c1 = hose_coefficients(hose_stiffness, 1.0 / hose_damping, dt)
    zi = np.array([f_p[0] / hose_stiffness - c1 * f_p[0]])
    delta, _ = scipy.signal.lfilter([c1, c0], [1.0, -a], f_p, zi=zi)
    return np.asarray(x + delta, float)


def _fit_friction(xe: _Real, f_p: _Real, endpoint_inertia: float, dt: float,
                  rest: float = 0.0) -> FrictionEstimate:
    """:class:`FrictionFit` on X_e_hat and F_p (decimated by :data:`DECIMATE`), the spring
    relaxed at ``rest`` [rad] (its pressure offset is relative to it)."""
    q = DECIMATE
    # the fit's own inertia term lags: its acceleration is the mean slope of its filtered
    # velocity over the last period, half a (decimated) period late, which biased b_e by -6 %
    # and k_e by -20 % on exact data at q = 4. The inertia force goes into the input instead,
    # from the central second difference (on time), and the fit's m_e is 1e-12 (nothing).
    acc = np.gradient(np.gradient(xe, dt), dt)
    f_in = f_p + endpoint_inertia * acc
    # the Dahl input: X_e_hat low-passed (zero phase) at DAHL_INPUT_CUTOFF: the pressure noise
    # on X_e_hat (5e-4 N m/k_s, 40-80 urad rms) would reverse the Dahl states at every sample
    # and relax them by sigma/F_c times the noise (10 % and more for a pre-sliding
    # displacement near 1 mrad), which the fit answered with a sigma 30-50 % too large
    sos = scipy.signal.butter(4, DAHL_INPUT_CUTOFF, fs=1.0 / dt, output="sos")
    x_dahl = scipy.signal.sosfiltfilt(sos, xe)
    if q > 1:
        xd, fd, dd = (scipy.signal.decimate(a, q, ftype="fir", zero_phase=True).tolist()
                      for a in (xe, f_in, x_dahl))
    else:
        xd, fd, dd = xe.tolist(), f_in.tolist(), x_dahl.tolist()
    plant = dataclasses.replace(PlantParams.table_i(), endpoint_inertia=1e-12)
    lo, hi = RATIO_RANGE
    center = math.sqrt(lo * hi)
    ratios = ratio_grid(center, math.sqrt(hi / lo))
    fit = FrictionFit(plant, 1.0, ratios, dt * q, FILTER_CUTOFF, rest=rest)
    settle = _settled(xd, int(SETTLE_TIME / (dt * q)))
    for i, (a, d, b) in enumerate(zip(xd, dd, fd)):
        fit.update(a, d, b, record=i >= settle)
    fit.fold()
    return fit.estimate([fit.solve_candidate(k) for k in range(len(ratios))])


def _settled(path: Sequence[float], settle: int) -> int:
    """The first sample the friction fit counts: ``settle`` or later, once ``path`` has
    covered :data:`SETTLE_TRAVEL` since its start (``settle`` if it never does)."""
    a = np.asarray(path, dtype=float)
    if a.size == 0:
        return settle
    travel = np.maximum.accumulate(a) - np.minimum.accumulate(a)
    moved = np.flatnonzero(travel >= SETTLE_TRAVEL)
    return max(settle, int(moved[0])) if moved.size else settle


def _dahl_spectrum(bt: BlackmanTukey, xe: _Real, dt: float, ratio: float,
                   coulomb_force: float) -> _Complex:
    """S_rF_d of the Dahl force driven by X_e_hat (low-passed at :data:`PATH_CUTOFF`)."""
    sos = scipy.signal.butter(4, PATH_CUTOFF, fs=1.0 / dt, output="sos")
    path = scipy.signal.sosfiltfilt(sos, xe)
    return bt.cross(coulomb_force * DahlPath(path).normalized(ratio))


# --- the pipeline ----------------------------------------------------------------------------
def _estimate(value: float, sigma: float, reason: str = "") -> Estimate:
    if reason:
        return Estimate(math.nan, math.nan, reason)
    if not (math.isfinite(value) and value > 0.0):
        return Estimate(math.nan, math.nan, f"the fit gave {value:.4g}, not a positive value")
    if not (math.isfinite(sigma) and sigma < value):
        return Estimate(math.nan, math.nan,
                        f"its 1-sigma ({sigma:.3g}) is not below its value ({value:.4g}): "
                        "the record does not tell it apart")
    return Estimate(value, sigma)


def identify_free_air(record: ExcitationRecord, *, band: Optional[Tuple[float, float]] = None,
                      progress: Optional[Progress] = None,
                      rest: float = 0.0) -> FreeAirIdentification:
    """Identify m, b, k, m_e, b_e, k_e, b_s, k_s and the Dahl sigma, F_c from a free-air
    motor-torque excitation (the module docstring says how each is resolved).

    Parameters
    ----------
    record : ExcitationRecord
        Endpoint free (F_e = 0), excited from at most 10 rad/s to at least 1000 rad/s
        (:data:`REQUIRED_BAND`); X_e and F_e are not used.
    band : (lo, hi) [rad/s], optional
        The port's band (the motor plant's is capped at :data:`MOTOR_TOP`); default: the
        band the excitation covers (Welch power within 1e-3 of its peak), 1.5x inside at the
        bottom, 1.2x at the top, at most :data:`PORT_TOP`.
    progress : callable(str, float), optional
        Called with a message and the fraction done (0..1).
    rest : float
        Where the finger's spring is relaxed [rad] (``feedforward.rest_position``): the
        pressure offset is the one with which the finger's spring agrees with it.

    Returns
    -------
    FreeAirIdentification

    Raises
    ------
    NonFiniteRecordError, RecordTooShortError, NotExcitedError, LowCoherenceError
        (all :class:`~.errors.CommissioningError`) with what to do.
    """
    def report(msg: str, frac: float) -> None:
        if progress is not None:
            progress(msg, frac)

    if not isinstance(record, ExcitationRecord):
        raise TypeError("record must be an ExcitationRecord")
    dt = record.dt
    if len(record) < 64:
        raise RecordTooShortError(f"record of {len(record)} samples: record the whole "
                                  "excitation (tens of seconds)")
    sig = _signals(record)
    ref = sig["excitation"]
    lo, hi = _bands(ref, dt, band)
    report("Blackman-Tukey spectra", 0.05)
    omega = np.logspace(math.log10(lo), math.log10(hi), N_FREQ)
    bt = BlackmanTukey(ref, dt, omega, periods=PERIODS)
    x, f_p, applied = sig["x"], sig["f_p"], sig["applied"]
    s_x = bt.signal("x", x, orders=POSITION_ORDERS)
    s_fp = bt.signal("f_p", f_p, orders=FORCE_ORDERS)
    half = 0.5 * omega * dt
    # the applied torque was held over the interval before its sample: half a sample early,
    # and the hold's sinc on its (continuous) spectrum
    s_fa = bt.cross(applied, delay=-0.5) * (np.sin(half) / half)
    s_in = (s_fa + s_fp[0], bt.auto(applied + f_p))
    resp_a = bt.response(s_x, s_in, "X/(F_a+F_p)")
    resp_p = bt.response(s_fp, s_x, "F_p/X")
    coh_x = bt.coherence(*s_x)
    coh_p = bt.coherence(*s_fp)
    for name, coh in (("X", coh_x), ("F_p", coh_p)):
        med = float(np.median(coh))
        if med < MIN_COHERENCE:
            raise LowCoherenceError(
                f"the squared coherence of {name} with the excitation is {med:.2f} (median "
                f"over {lo:.3g}-{hi:.3g} rad/s), below {MIN_COHERENCE:g}: raise the "
                "excitation's amplitude or record longer")
    notes: List[str] = []
    report("motor plant", 0.15)
    motor_hi = min(hi, MOTOR_TOP)
    fit_a = fit_mass_spring_damper(resp_a, lo, motor_hi, PLANT_KEYS[:3])
    estimates: Dict[str, Estimate] = {
        k: _estimate(float(v), float(s)) for k, v, s in zip(fit_a.names, fit_a.values,
                                                               fit_a.sigma)}
    report("port: linear start", 0.2)
    w = omega
    weight = 1.0 / np.maximum(resp_p.rel_sigma, SIGMA_FLOOR)
    # the motor's impedance enters the port's model only through the aliasing of the held
    # torque (:func:`_alias_factor`): held at fit A's values
    start = dict(_port_start(w, resp_p.h, weight),
                 **{k: float(v) for k, v in zip(fit_a.names, fit_a.values)})
    # two starts (the linear fit's, and one from P's shape, for when the linear fit's m_e is
    # far off); without the Dahl force both misfit the port by a few %, so where they ended
    # apart the first friction pass fits the port from each and keeps the better
    starts = sorted((_fit_port(w, s_x[0], s_fp[0], None, resp_p.rel_sigma, st, _PORT_KEYS, dt)
                     for st in (start, _resonance_start(w, resp_p.h, start))),
                    key=lambda f: f[2])
    starts = starts[:1] + [f for f in starts[1:] if max(
        abs(math.log(f[0][k] / starts[0][0][k])) for k in _PORT_KEYS) > SAME_FIT]
    theta, sig_p, misfit_p = starts[0]
    held_keys = ("endpoint_inertia", "hose_damping", "hose_stiffness")

    def dahl_pass(theta: Dict[str, float]) -> Tuple[Optional[FrictionEstimate], _Real,
                                                     Optional[_Complex], Dict[str, float],
                                                     Tuple[Dict[str, float],
                                                           Dict[str, float], float]]:
        """(friction, X_e_hat, S_rF_d, the port's start, its fit) from ``theta``'s hose;
        friction None (and no fit) when the friction fit found no usable hysteresis."""
        xe = _endpoint_estimate(x, f_p, theta["hose_damping"], theta["hose_stiffness"], dt)
        friction = _fit_friction(xe, f_p, theta["endpoint_inertia"], dt, rest)
        if friction.reason or not (friction.endpoint_damping > 0.0
                                   and friction.endpoint_stiffness > 0.0):
            return friction, xe, None, theta, (theta, {}, math.inf)
        held = dict(theta, endpoint_damping=friction.endpoint_damping,
                    endpoint_stiffness=friction.endpoint_stiffness)
        s_fd = _dahl_spectrum(bt, xe, dt, friction.sigma / friction.coulomb_force,
                              friction.coulomb_force)
        fit = _fit_port(w, s_x[0], s_fp[0], s_fd, resp_p.rel_sigma, held, held_keys, dt)
        return friction, xe, s_fd, held, fit

    friction: Optional[FrictionEstimate] = None
    xe = x
    s_fd: Optional[_Complex] = None
    iterations = 0
    for it in range(MAX_ITERATIONS):
        iterations = it + 1
        report(f"friction fit, pass {iterations}", 0.3 + 0.6 * it / MAX_ITERATIONS)
        friction, xe, s_fd, held, fit = dahl_pass(theta)
        if not it:
            for other in starts[1:]:
                alt = dahl_pass(other[0])
                if alt[4][2] < fit[2]:
                    friction, xe, s_fd, held, fit = alt
                    sig_p = dict(other[1])
        if s_fd is None:
            assert friction is not None
            notes.append(f"friction fit: {friction.reason or 'a negative b_e or k_e'}; "
                         "b_e and k_e from the port's linear fit, no Dahl force")
            friction = None
            break
        if not it and fit[2] > MODEL_CLASS_THRESHOLD["port"]:
            # a first pass whose misfit would flag the model class is fitted again from P's
            # shape (m_e where |P/Z_s| reaches 1, the linear start's hose), and from a decade
            # above that m_e (for a resonance too damped to peak), and the best kept
            crossing = {k: v for k, v in _crossing_start(w, resp_p.h, start).items()
                        if k in held_keys}
            for factor in CROSSING_FACTORS:
                retry = dict(held, **crossing)
                retry["endpoint_inertia"] *= factor
                again = _fit_port(w, s_x[0], s_fp[0], s_fd, resp_p.rel_sigma, retry,
                                  held_keys, dt)
                fit = min(fit, again, key=lambda f: f[2])
        new, sig_new, misfit_p = fit
        change = max(abs(new[k] / theta[k] - 1.0) for k in held_keys)
        theta = new
        sig_p.update(sig_new)
        if change < CONVERGED:
            break
    report("results", 0.95)
    for k in ("endpoint_inertia", "hose_damping", "hose_stiffness"):
        estimates[k] = _estimate(theta[k], sig_p[k])
    nan = math.nan
    offset = Estimate(nan, nan, "no friction fit (see notes)")
    if friction is not None and math.isfinite(friction.pressure_offset_sigma):
        offset = Estimate(friction.pressure_offset, friction.pressure_offset_sigma)
    if friction is None:
        for k in ("endpoint_damping", "endpoint_stiffness"):
            estimates[k] = _estimate(theta[k], sig_p[k])
        why = "no hysteresis seen by the friction fit (see notes)"
        estimates["sigma"] = Estimate(nan, nan, why)
        estimates["coulomb_force"] = Estimate(nan, nan, why)
    else:
        estimates["endpoint_damping"] = _estimate(friction.endpoint_damping,
                                                  friction.endpoint_damping_sigma)
        estimates["endpoint_stiffness"] = _estimate(friction.endpoint_stiffness,
                                                    friction.endpoint_stiffness_sigma)
        estimates["coulomb_force"] = _estimate(friction.coulomb_force,
                                               friction.coulomb_force_sigma)
        estimates["sigma"] = _estimate(friction.sigma, friction.sigma_sigma,
                                       friction.sigma_reason)
    mass, damping, stiffness = (float(v) for v in fit_a.values)
    model_a = np.asarray(1.0 / (mass * (1j * w) ** 2 + damping * 1j * w + stiffness),
                         dtype=np.complex128)
    model_p = _port_model(theta, w, np.ones_like(w, dtype=complex), None, dt)
    sel_a = w <= motor_hi
    misfit = {"motor": float(np.sqrt(np.mean(np.abs(model_a[sel_a] - resp_a.h[sel_a]) ** 2
                                              / np.abs(resp_a.h[sel_a]) ** 2))),
              "port": misfit_p}
    report("done", 1.0)
    return FreeAirIdentification(
        parameters={k: estimates[k] for k in PLANT_KEYS + DAHL_KEYS},
        motor=_response(resp_a, coh_x, model_a),
        port=_response(resp_p, coh_p, model_p),
        misfit=misfit, band=(lo, hi), motor_band=(lo, motor_hi), iterations=iterations,
        notes=notes, pressure_offset=offset)


def _response(resp: FrequencyResponse, coherence: _Real, model: _Complex) -> Response:
    return Response(resp.name, resp.omega, resp.h, resp.sigma, coherence, model)


def model_class(ident: FreeAirIdentification,
                threshold: Optional[Dict[str, float]] = None,
                terms: Optional[Sequence[str]] = None,
                resolved: Sequence[str] = ()) -> "ModelClass":
    """Whether the identified model class describes the gripper: each fit's misfit against
    :data:`MODEL_CLASS_THRESHOLD` (or ``threshold``), and a warning that says what a misfit
    beyond it -- or a nonlinear term the record resolved (``resolved``: their labels) --
    means for the parameters and the predictions; ``terms``: the lines of the candidate
    nonlinear terms (:mod:`.nonlinear_terms`)."""
    from .report import ModelClass
    limits = dict(MODEL_CLASS_THRESHOLD if threshold is None else threshold)
    over = [k for k, v in ident.misfit.items() if k in limits and not v <= limits[k]]
    causes = [f"the {k} fit's misfit {100 * ident.misfit[k]:.2g} % exceeds "
              f"{100 * limits[k]:.2g} %" for k in over]
    if resolved:
        causes.append("the record resolves " + ", ".join(resolved))
    warning = ""
    if causes:
        warning = ("; ".join(causes)
                   + ": the linear model with the Dahl hysteresis does not describe this gripper "
                   "(nonlinear hose, diaphragm, finger or motor friction); its parameters are "
                   "equivalent values at this excitation's amplitudes, their 1-sigmas do not "
                   "cover that, and predictions of the softest modes are optimistic")
    return ModelClass(dict(ident.misfit), limits, warning, list(terms or []))

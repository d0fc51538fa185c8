"""Impedance analysis: force feedback (Fig. 7), low-frequency limits
(eq. 22-24), Z-width, impedance from time series, hold-gain design.
"""

import math
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterable, NamedTuple, Optional, Tuple

import numpy as np
import numpy.typing as npt

from .params import PlantParams
from .passivity import numerical_passivity
from .plant import PlantModel

if TYPE_CHECKING:                       # imported where used (slow to import)
    import control

__all__ = [
    "magnitude_db", "zwidth_db", "frequency_response", "max_passive_external_gain",
    "force_feedback_comparison", "low_frequency_stiffness_passive",
    "low_frequency_stiffness_internal", "low_frequency_stiffness_external",
    "eq22_stiffness", "eq23_stiffness", "eq24_stiffness",
    "fourier_coefficient", "impedance_from_series", "impedance_from_position",
    "ImpedanceFigures", "impedance_figures", "CENTRE_BAND", "AWAY_SHARE", "HARMONICS",
    "hold_loop", "HoldMargins", "hold_margins", "design_hold_gains",
]


#: A loop transfer function: frequencies [rad/s] -> complex L(e^{j omega dt}).
LoopGain = Callable[[npt.ArrayLike], npt.NDArray[np.complex128]]


def magnitude_db(z: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """20 log10 |z| (dB re 1 N m s/rad for impedances)."""
    return 20.0 * np.log10(np.abs(z))


def zwidth_db(z_low: npt.ArrayLike, z_high: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Z-width [dB] between a low- and a high-impedance curve:
    ``20 log10(|z_high| / |z_low|)`` elementwise."""
    return 20.0 * np.log10(np.abs(z_high) / np.abs(z_low))


def frequency_response(tf: "control.TransferFunction",
                       omega: npt.ArrayLike) -> npt.NDArray[np.complex128]:
    """Complex ``tf(j omega)`` of a SISO :class:`control.TransferFunction`."""
    num = np.asarray(tf.num[0][0], float)
    den = np.asarray(tf.den[0][0], float)
    s = 1j * np.asarray(omega, float)
    return np.polyval(num, s) / np.polyval(den, s)


def _admittance_passive(tf: "control.TransferFunction") -> bool:
    """Numerical passivity of the admittance 1/Z for an impedance tf."""
    return numerical_passivity(tf.den[0][0], tf.num[0][0]).passive


def max_passive_external_gain(plant: PlantParams, upper: float = 100.0,
                              tol: float = 1e-6) -> float:
    """Largest K_f for which external force feedback ``F_a = K_f F_e`` keeps
    the endpoint port passive (bisection on :func:`numerical_passivity`).

    Returns ``upper`` if every gain up to it is passive.
    """
    model = PlantModel(plant)
    lo = 0.0
    if not _admittance_passive(model.external_force_feedback_impedance(lo)):
        raise ValueError("the passive plant itself is not passive")
    hi = upper
    if _admittance_passive(model.external_force_feedback_impedance(hi)):
        return hi
    while hi - lo > tol * max(1.0, lo):
        mid = 0.5 * (lo + hi)
        if _admittance_passive(model.external_force_feedback_impedance(mid)):
            lo = mid
        else:
            hi = mid
    return lo


def force_feedback_comparison(plant: PlantParams, omega: npt.ArrayLike,
                              internal_gain: float = 1.0) -> Dict[str, Any]:
    """Endpoint |Z| curves of Fig. 7 for one parameter set.

    Returns
    -------
    dict with ``omega``, ``passive``, ``internal``, ``external`` (complex
    Z(j omega) arrays [N m s/rad]), ``external_gain`` (the maximum passive
    K_f used) and ``internal_gain``.
    """
    model = PlantModel(plant)
    k_ext = max_passive_external_gain(plant)
    return {
        "omega": np.asarray(omega, float),
        "passive": frequency_response(model.passive_impedance(), omega),
        "internal": frequency_response(
            model.internal_force_feedback_impedance(internal_gain), omega),
        "external": frequency_response(
            model.external_force_feedback_impedance(k_ext), omega),
        "external_gain": k_ext,
        "internal_gain": internal_gain,
    }


def low_frequency_stiffness_passive(plant: PlantParams) -> float:
    """``lim_{s->0} s Z(s)`` unpowered: ``k_e + k k_s/(k + k_s)`` [N m/rad]."""
    p = plant
    k, ks, ke = p.motor_stiffness, p.hose_stiffness, p.endpoint_stiffness
    return ke + k * ks / (k + ks)


def low_frequency_stiffness_internal(plant: PlantParams, gain: float = 1.0) -> float:
    """``lim s Z`` with internal force feedback ``F_a = K_f F_p``:
    ``k_e + k k_s/(k + (1+K_f) k_s)`` (eq. 22 for K_f = 1)."""
    p = plant
    k, ks, ke = p.motor_stiffness, p.hose_stiffness, p.endpoint_stiffness
    return ke + k * ks / (k + (1.0 + gain) * ks)


def low_frequency_stiffness_external(plant: PlantParams, gain: float) -> float:
    """``lim s Z`` with external force feedback ``F_a = K_f F_e``:
    ``(k_e (k + k_s) + k k_s)/(k + (1+K_f) k_s)``."""
    p = plant
    k, ks, ke = p.motor_stiffness, p.hose_stiffness, p.endpoint_stiffness
    return (ke * (k + ks) + k * ks) / (k + (1.0 + gain) * ks)


def eq22_stiffness(plant: PlantParams) -> float:
    """Eq. 22: ``((k + 2 k_e) k_s + k k_e)/(2 k_s + k)`` [N m/rad]."""
    p = plant
    k, ks, ke = p.motor_stiffness, p.hose_stiffness, p.endpoint_stiffness
    return ((k + 2.0 * ke) * ks + k * ke) / (2.0 * ks + k)


def eq23_stiffness(plant: PlantParams) -> float:
    """Eq. 23 (non-backdrivable actuator, k >> k_s, k_e): ``k_s + k_e``."""
    return plant.hose_stiffness + plant.endpoint_stiffness


def eq24_stiffness(plant: PlantParams) -> float:
    """Eq. 24 (backdrivable, k_s >> k, k_e): ``k/2 + k_e``."""
    return 0.5 * plant.motor_stiffness + plant.endpoint_stiffness


# --- impedance from time series ------------------------------------------------
def fourier_coefficient(y: npt.ArrayLike, omega: float, dt: float,
                        settle_time: float = 0.0) -> complex:
    """Single-frequency Fourier projection of a sampled signal.

    Uses the largest whole number of periods of ``omega`` that fits after
    ``settle_time`` (taken from the end of the record), so a steady-state
    sinusoid ``A sin(omega t + phi)`` gives ``A e^{j(phi - pi/2)}``.

    Parameters
    ----------
    y : array_like
        Samples at ``t_k = k dt``.
    omega : float > 0
        [rad/s].
    dt : float > 0
        [s].
    settle_time : float >= 0
        Transient to discard at the start [s].

    Returns
    -------
    complex
    """
    y = np.asarray(y, float)
    period = 2.0 * math.pi / omega
    start = int(math.ceil(settle_time / dt))
    available = (y.size - start) * dt
    n_periods = int(math.floor(available / period + 1e-9))
    if n_periods < 1:
        raise ValueError("record shorter than one period after settle_time")
    n = int(round(n_periods * period / dt))
    k0 = y.size - n
    t = (k0 + np.arange(n)) * dt
    return 2.0 / n * np.sum(y[k0:] * np.exp(-1j * omega * t))


def impedance_from_series(f_e: npt.ArrayLike, v_e: npt.ArrayLike, omega: float, dt: float,
                          settle_time: float = 0.0) -> complex:
    """Complex Z(j omega) = F_e/V_e from time series of F_e [N m] and V_e [rad/s]."""
    return (fourier_coefficient(f_e, omega, dt, settle_time)
            / fourier_coefficient(v_e, omega, dt, settle_time))


def impedance_from_position(f_e: npt.ArrayLike, x_e: npt.ArrayLike, omega: float, dt: float,
                            settle_time: float = 0.0) -> complex:
    """Complex Z(j omega) = F_e/(j omega X_e) from F_e [N m] and X_e [rad]."""
    return (fourier_coefficient(f_e, omega, dt, settle_time)
            / (1j * omega * fourier_coefficient(x_e, omega, dt, settle_time)))


#: Half-width [rad] of the work loop's centre band: the paper's Fig. 5 compensation holds
#: within +-0.2 rad of the stroke's centre.
CENTRE_BAND = 0.2
#: Harmonics of F_e reported (1 = the fundamental).
HARMONICS = 5
#: :attr:`ImpedanceFigures.peak_away` ends at this share of the stroke's half-width: a drive
#: of 0.5 rad leaves its last 0.05 rad each side out (at 1 rad/s the 0.9 s about each
#: reversal; the Dahl force re-sticks over F_c/sigma, about 3 mrad, of it).
AWAY_SHARE = 0.9
#: Harmonics of X_e the rms of V_e is summed over (a drive's path is smooth: its content
#: beyond them is the encoder's quantum).
_VELOCITY_HARMONICS = 20


class ImpedanceFigures(NamedTuple):
    """What a backdrive at one frequency shows of the endpoint impedance, the fundamental
    beside the rms (:func:`impedance_figures`).

    Attributes
    ----------
    omega : float
        Drive frequency w [rad/s].
    z : complex
        ``F_e/V_e`` of the fundamentals [N m s/rad].
    z_rms : float
        ``rms(F_e)/rms(V_e)`` [N m s/rad], both about their means over whole periods: every
        harmonic (and the noise) of F_e counts.
        rms(F_e)^2 is the power of its first 20 harmonics plus the mean square of what they
        leave, rms(V_e)^2 that of the first 20 harmonics of V_e.
    harmonics : tuple of float
        Amplitudes |F_e| at ``k w``, k = 1 .. :data:`HARMONICS` [N m].
    distortion : float
        Harmonic distortion of F_e (noise included): ``sqrt(rms^2 - rms_1^2)/rms_1``, rms_1
        the fundamental's rms; inf when the fundamental is 0.
    peak : float
        Largest |F_e| over the whole stroke [N m] (the work loop's).
    peak_centre : float
        Largest |F_e| within ``centre_band`` of the stroke's centre [N m] (NaN when the
        stroke never comes there).
    amplitude : float
        Amplitude of the fundamental of X_e [rad].
    centre_band : float
        The band's half-width [rad].
    periods : int
        Whole periods the figures are taken over.
    peak_away : float
        Largest |F_e| within :data:`AWAY_SHARE` of the stroke's half-width from its centre
        [N m]: the stroke without its ends, where the drive reverses and the Dahl force
        re-sticks (``peak_centre <= peak_away <= peak``).
    """

    omega: float
    z: complex
    z_rms: float
    harmonics: Tuple[float, ...]
    distortion: float
    peak: float
    peak_centre: float
    amplitude: float
    centre_band: float
    periods: int
    peak_away: float = math.nan

    @property
    def z_db(self) -> float:
        """``20 log10 |z|`` [dB re 1 N m s/rad]."""
        return 20.0 * math.log10(abs(self.z)) if self.z != 0 else -math.inf

    @property
    def z_rms_db(self) -> float:
        """``20 log10 z_rms`` [dB re 1 N m s/rad]."""
        return 20.0 * math.log10(self.z_rms) if self.z_rms > 0 else -math.inf

    @property
    def peak_ratio(self) -> float:
        """``peak / peak_centre``: how much the work loop's force grows outside the centre."""
        return self.peak / self.peak_centre if self.peak_centre > 0 else math.inf

    @property
    def away_ratio(self) -> float:
        """``peak_away / peak_centre``: the same without the stroke's ends (the reversals)."""
        return self.peak_away / self.peak_centre if self.peak_centre > 0 else math.inf

    def as_dict(self) -> Dict[str, Any]:
        """The figures as JSON-able numbers (``z`` as ``z_re``, ``z_im``; the dBs too)."""
        return {"omega": self.omega, "z_re": self.z.real, "z_im": self.z.imag,
                "z_db": self.z_db, "z_rms": self.z_rms, "z_rms_db": self.z_rms_db,
                "harmonics": list(self.harmonics), "distortion": self.distortion,
                "peak": self.peak, "peak_centre": self.peak_centre,
                "peak_away": self.peak_away,
                "amplitude": self.amplitude, "centre_band": self.centre_band,
                "periods": self.periods}


def _whole_periods(n_samples: int, omega: float, dt: float, settle_time: float) -> Tuple[int, int]:
    """(first sample, periods) of the largest whole number of periods after ``settle_time``,
    taken from the end of the record (as :func:`fourier_coefficient`)."""
    period = 2.0 * math.pi / omega
    # the settle ends within the sample it falls in (floor: a record of k periods after the
    # settle, both rounded to samples, keeps its k periods -- with ceil a backdrive of one
    # recorded period came out a sample short for about a quarter of the frequencies)
    start = int(math.floor(settle_time / dt + 1e-9))
    available = n_samples - start
    # a window up to one sample short of whole periods counts as whole periods (a record of
    # k periods rounded to samples; the harmonics are fitted by least squares, which a
    # fraction of a sample does not bias)
    periods = int(math.floor((available + 1.0) * dt / period))
    if periods < 1:
        raise ValueError("record shorter than one period after settle_time")
    return n_samples - min(available, int(round(periods * period / dt))), periods


def impedance_figures(f_e: npt.ArrayLike, x_e: npt.ArrayLike, omega: float, dt: float,
                      settle_time: float = 0.0, centre_band: float = CENTRE_BAND
                      ) -> ImpedanceFigures:
    """The endpoint impedance of a backdrive at ``omega``, the fundamental beside the rms.

    Over the largest whole number of drive periods after ``settle_time`` (from the end of the
    record): the Fourier coefficients of F_e at ``k omega`` (k = 1 .. :data:`HARMONICS`), the
    rms of F_e about its mean, the rms of V_e = X_e' summed over the first harmonics of X_e
    (robust to the encoder's quantum; exact for a drive's smooth path), the peaks of |F_e|
    over the stroke, within ``centre_band`` of its centre ((max + min)/2 of X_e) and within
    :data:`AWAY_SHARE` of its half-width (the stroke without its ends).

    Parameters
    ----------
    f_e : array_like
        External force F_e [N m] at ``t_k = k dt``.
    x_e : array_like
        Endpoint position X_e [rad], same samples.
    omega : float > 0
        Drive frequency [rad/s].
    dt : float > 0
        Sample period [s].
    settle_time : float >= 0
        Transient to discard at the start [s].
    centre_band : float > 0
        Half-width of the centre band [rad].

    Returns
    -------
    ImpedanceFigures
    """
    f = np.asarray(f_e, float)
    x = np.asarray(x_e, float)
    if f.shape != x.shape or f.ndim != 1:
        raise ValueError(f"f_e and x_e need the same one-dimensional shape, got {f.shape} and "
                         f"{x.shape}")
    if not (omega > 0.0 and dt > 0.0 and centre_band > 0.0):
        raise ValueError("omega, dt and centre_band must be > 0")
    k0, periods = _whole_periods(f.size, omega, dt, settle_time)
    fw, xw = f[k0:], x[k0:]
    n = fw.size
    t = (k0 + np.arange(n)) * dt
    orders = np.arange(1, _VELOCITY_HARMONICS + 1)
    # least squares on a mean and the harmonics (not projections: a period that is not a
    # whole number of samples would leak a large fundamental into the small harmonics)
    phase = omega * np.outer(t - t[0], orders)
    basis = np.hstack([np.ones((n, 1)), np.cos(phase), np.sin(phase)])
    coef = np.linalg.lstsq(basis, np.stack([fw, xw], axis=1), rcond=None)[0]
    rot = np.exp(-1j * orders * omega * t[0])        # back to the phase of t = k dt
    cf_all = (coef[1:1 + orders.size, 0] - 1j * coef[1 + orders.size:, 0]) * rot
    cf = cf_all[:HARMONICS]
    cx = (coef[1:1 + orders.size, 1] - 1j * coef[1 + orders.size:, 1]) * rot
    z = complex(cf[0] / (1j * omega * cx[0]))
    # the harmonics' power plus what they leave (noise, content beyond them): exact for a
    # periodic force whatever fraction of a sample the window is off whole periods
    resid = fw - basis @ coef[:, 0]
    rms_f = float(np.sqrt(0.5 * np.sum(np.abs(cf_all) ** 2) + np.mean(resid ** 2)))
    rms_v = float(np.sqrt(0.5 * np.sum((orders[:_VELOCITY_HARMONICS] * omega
                                        * np.abs(cx)) ** 2)))
    fundamental = float(abs(cf[0])) / math.sqrt(2.0)
    rest = math.sqrt(max(rms_f ** 2 - fundamental ** 2, 0.0))
    distortion = rest / fundamental if fundamental > 0 else math.inf
    centre = 0.5 * (float(xw.max()) + float(xw.min()))
    reach = np.abs(xw - centre)
    inside = reach <= centre_band
    peak_centre = float(np.max(np.abs(fw[inside]))) if inside.any() else math.nan
    peak_away = float(np.max(np.abs(fw[reach <= AWAY_SHARE * float(reach.max())])))
    return ImpedanceFigures(float(omega), z, rms_f / rms_v if rms_v > 0 else math.inf,
                            tuple(float(a) for a in np.abs(cf)), distortion,
                            float(np.max(np.abs(fw))), peak_centre, float(abs(cx[0])),
                            float(centre_band), periods, peak_away)


# --- hold (maximum impedance) gain design ---------------------------------------
def hold_loop(plant: PlantParams, stiffness: float, damping: float, dt: float = 5e-4,
              delay: int = 1, endpoint: str = "free",
              clamp_stiffness: float = 1e4) -> Tuple[npt.NDArray[np.float64], LoopGain]:
    """Discrete loop of the ``hold`` PD on the motor (ZOH plant, exact).

    ``u_k = -K_p x_k - K_d (x_k - x_{k-1})/dt`` (drive velocity), applied
    ``delay`` samples later.

    Parameters
    ----------
    endpoint : "free" or "clamped"
        Clamped: the endpoint is tied to ground by ``clamp_stiffness``.

    Returns
    -------
    (closed_loop_matrix, loop_gain) where ``loop_gain(omega)`` gives the
    complex loop transfer L(e^{j omega dt}) broken at the torque input.
    """
    from .simulator import discretise
    ken = clamp_stiffness if endpoint == "clamped" else 0.0
    ben = 2.0 * 0.7 * math.sqrt(ken * plant.endpoint_inertia) if ken else 0.0
    phi6, gam6 = discretise(plant, dt, ken, ben, 0.0)
    phi, gam = phi6[:4, :4], gam6[:4, 0]
    kp, kd = stiffness, damping
    # state: z (4), x_{k-1}, pending commands (delay)
    n = 4 + 1 + delay
    A = np.zeros((n, n))
    A[:4, :4] = phi
    ck = np.zeros(n)                   # u_k as a row of the state
    ck[0] = -(kp + kd / dt)
    ck[4] = kd / dt
    if delay == 0:
        A[:4, :] += np.outer(gam, ck)
    else:
        A[:4, 4 + delay] += gam        # oldest pending command applied
        for j in range(delay - 1, 0, -1):
            A[4 + j + 1, 4 + j] = 1.0  # shift register
        A[5, :] += ck
    A[4, 0] = 1.0                      # x_{k-1} <- x_k

    def loop_gain(omega: npt.ArrayLike) -> npt.NDArray[np.complex128]:
        z = np.exp(1j * np.asarray(omega, float) * dt)
        out = np.empty(z.shape, complex)
        eye = np.eye(4)
        for i, zi in enumerate(z.ravel()):
            g = np.linalg.solve(zi * eye - phi, gam)[0]     # X/u
            c = kp + kd * (1.0 - 1.0 / zi) / dt
            out.ravel()[i] = c * g * zi ** (-delay)
        return out

    return A, loop_gain


class HoldMargins(NamedTuple):
    """Stability margins of the discrete hold loop (:func:`hold_margins`)."""

    stable: bool
    modulus_margin: float
    gain_margin_db: float
    phase_margin_deg: float
    spectral_radius: float


def hold_margins(plant: PlantParams, stiffness: float, damping: float, dt: float = 5e-4,
                 delay: int = 1, endpoint: str = "free",
                 omega: Optional[npt.NDArray[np.float64]] = None) -> HoldMargins:
    """Stability margins of the discrete hold loop (:func:`hold_loop`).

    Returns
    -------
    HoldMargins
        ``stable`` (closed-loop spectral radius < 1), ``modulus_margin``
        (min |1 + L|), gain margin [dB] and phase margin [deg] (inf when
        there is no crossing).
    """
    A, loop = hold_loop(plant, stiffness, damping, dt, delay, endpoint)
    rho = float(np.max(np.abs(np.linalg.eigvals(A))))
    if omega is None:
        omega = np.logspace(-1, math.log10(math.pi / dt * 0.999), 3000)
    L = loop(omega)
    mm = float(np.min(np.abs(1.0 + L)))
    mag, ph = np.abs(L), np.unwrap(np.angle(L))
    gm = math.inf
    for i in range(len(omega) - 1):
        # phase crossings of -180 deg (mod 360)
        a = (ph[i] + math.pi) % (2 * math.pi)
        b = (ph[i + 1] + math.pi) % (2 * math.pi)
        if abs(a - b) > math.pi:
            gm = min(gm, -20 * math.log10(max(mag[i], 1e-300)))
    pm = math.inf
    for i in range(len(omega) - 1):
        if (mag[i] - 1.0) * (mag[i + 1] - 1.0) <= 0.0:
            pm = min(pm, math.degrees((ph[i] + math.pi) % (2 * math.pi)))
    return HoldMargins(rho < 1.0, mm, gm, pm, rho)


def design_hold_gains(plant: PlantParams, dt: float = 5e-4, delay: int = 1,
                      modulus_margin: float = 0.5,
                      stiffness_grid: Optional[Iterable[float]] = None,
                      damping_grid: Optional[Iterable[float]] = None) -> Tuple[float, float]:
    """Largest hold stiffness K_p (and its K_d) with a margin.

    Searches a log grid of (K_p, K_d); keeps the pairs whose discrete loop is
    stable with ``min |1 + L| >= modulus_margin`` (0.5 guarantees a gain
    margin >= 6 dB and a phase margin >= 29 deg) for the endpoint both free
    and clamped, and returns the one with the largest K_p (ties: smallest
    K_d).

    Returns
    -------
    (K_p [N m/rad], K_d [N m s/rad])
    """
    if stiffness_grid is None:
        stiffness_grid = np.round(np.logspace(0, 3, 31), 1)
    if damping_grid is None:
        damping_grid = np.round(np.logspace(-2, 0.5, 26), 3)
    best = None
    for kp in stiffness_grid:
        for kd in damping_grid:
            ok = True
            for endpoint in ("free", "clamped"):
                mg = hold_margins(plant, kp, kd, dt, delay, endpoint,
                                  omega=np.logspace(-1, math.log10(math.pi / dt * 0.999), 600))
                if not (mg.stable and mg.modulus_margin >= modulus_margin):
                    ok = False
                    break
            if ok and (best is None or kp > best[0]):
                best = (float(kp), float(kd))
    if best is None:
        raise ValueError("no stable hold gains on the grid")
    return best

"""What each controller mode renders, predicted from an identified plant and loop figures.

Motor frame, rotational SI units, sample period T (5e-4 s at 2 kHz). The prediction is the
steady-state response of the *sampled* closed loop to the measurement the project makes
(:mod:`seaforce_ros.identification.zwidth_lib`): the endpoint backdriven by the stiff position
drive of :func:`~seaforce_ros.core.environment.position_sine` at one frequency w, and
``Z(jw) = F_e/V_e`` from the first harmonics of F_e and X_e.

* The plant (the *true* one) is the exact zero-order-hold discretisation the simulator uses
  (:func:`~seaforce_ros.core.simulator.discretise`, drive oscillator included), the motor
  torque applied ``delay`` samples after the sample it answers.
* The controller is its own discretisation, built from ``config`` (its *model*, which may
  differ from the true plant): the drive's backward-difference velocity ``(x_k - x_{k-1})/T``;
  the hose inversion of eq. 29 with its first-order-hold coefficients
  (:func:`~seaforce_ros.core.observer.hose_coefficients`); ``F_cmp = b_e V_e_hat + k_e
  X_e_hat - r HP(V)`` (``r = feedforward.damping_reserve`` through the high-pass of
  ``feedforward.reserve_cutoff``, :func:`reserve_filter`) and the feed-forward's Dahl force,
  each with the margin of
  ``feedforward.margin`` (:meth:`~seaforce_ros.core.params.ControllerConfig.feedforward_friction`); the DOB of eq. 19 with its trapezoidal integrator
  ``I = (lambda T/2)(1 + z^-1)/(1 - z^-1) (F_ref + F_p - k_n X)``,
  ``F_a = F_ref + I - lambda m_n V - lambda b_n X``; hold ``F_a = -K_p X - K_d V``;
  force feedback ``F_a = K_f F_p``; impedance ``F_ref = F_cmp + F_d - K_t X_e_hat - B_t
  V_e_hat``.
* The Dahl hysteresis (eq. 14) -- the plant's, driven by X_e, and the feed-forward's, driven
  by X_e_hat through the play of ``feedforward.dahl_deadband`` -- is replaced by its
  describing function at the amplitude it sees (:func:`dahl_describing_function`): rate
  independent, so one complex gain ``F_d = N(A) X`` per amplitude. At ``A >> F_c/sigma`` it is
  Coulomb friction, ``N ~ j 4 F_c/(pi A)``: a damping ``4 F_c/(pi A w)``.

With these, one sample of the loop is ``z S = Phi S + Phi_d D + z^-d Gamma_m U + Gamma_e U_e``
with ``U = k_x(z) X + k_p(z) F_p`` (the mode's controller, :func:`controller_gains`) and
``U_e = -N X_e``: one complex 4x4 solve per frequency (:func:`predict_impedance`).

The same loop with the endpoint free gives the torque noise of the DOB
(:func:`torque_noise`): pressure noise and encoder quantisation through the closed loop.
Hold stability is the exact discrete loop of :func:`~seaforce_ros.core.analysis.hold_loop`
(:func:`hold_delay_limit`). :func:`wall_limits` is the classic virtual-wall Z-width chart of
impedance mode.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

from ..core.analysis import HoldMargins, hold_loop, hold_margins
from ..core.dahl import dahl_step
from ..core.environment import DRIVE_DAMPING, DRIVE_STIFFNESS
from ..core.observer import hose_coefficients
from ..core.params import ControllerConfig, DahlParams, PlantParams
from ..core.simulator import discretise
from .errors import CommissioningError

__all__ = ["PREDICTED_MODES", "LoopModel", "PredictionError", "dahl_describing_function",
           "controller_polynomials", "controller_gains", "closed_loop_radius",
           "closed_loop_matrix", "reserve_filter",
           "predict_impedance", "predict_modes", "ImpedanceBand",
           "predict_band", "perturbed_plants", "torque_noise", "hold_delay_limit",
           "HoldVerdict", "hold_verdict", "WallLimits", "wall_limits", "PLANT_FIELDS",
           "SIGMA_KEYS"]

#: The modes :func:`predict_impedance` predicts.
PREDICTED_MODES = ("passive", "hold", "force_feedback", "dob", "dob_linear_ff", "dob_full_ff",
                   "impedance")

#: The fields of :class:`~seaforce_ros.core.params.PlantParams` (Table I), in order.
PLANT_FIELDS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
                "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")

_Complex = npt.NDArray[np.complex128]
_Float = npt.NDArray[np.float64]
#: Polynomial coefficients (real or complex, as numpy's polynomial functions return them).
_Coefficients = npt.NDArray[Any]

#: Samples per half cycle for the describing function's quadrature.
_DF_POINTS = 512
#: Fixed-point passes that bring the describing functions' amplitudes to the predicted motion.
_DF_PASSES = 2


class PredictionError(CommissioningError):
    """A prediction asked for something it cannot give (a mode it does not model, a
    frequency at or beyond the Nyquist frequency, non-finite figures)."""


@dataclass(frozen=True)
class LoopModel:
    """What commissioning measured of the sensors and the loop.

    Attributes
    ----------
    pressure_noise : float >= 0
        Standard deviation of the pressure-force noise [N m] (white).
    encoder_resolution : float >= 0
        Motor encoder step Delta [rad] (the quantisation is uniform, variance Delta^2/12).
    delay_p50, delay_p99 : int >= 0
        Loop delay [samples] between the sample a command answers and the sample it is
        applied from: median and 99th percentile (1 for the direct layout).
    dt : float > 0
        Sample period T [s].
    """

    pressure_noise: float
    encoder_resolution: float
    delay_p50: int = 1
    delay_p99: int = 1
    dt: float = 5e-4

    def __post_init__(self) -> None:
        for name in ("pressure_noise", "encoder_resolution"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise PredictionError(f"figures: {name} = {value!r}, must be >= 0 and finite")
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise PredictionError(f"figures: dt = {self.dt!r} s, must be > 0 and finite")
        if not 0 <= self.delay_p50 <= self.delay_p99 <= 1000:
            raise PredictionError(
                f"figures: delays p50 = {self.delay_p50!r}, p99 = {self.delay_p99!r} samples; "
                "need 0 <= p50 <= p99 <= 1000")


# --- the Dahl hysteresis as a describing function ----------------------------------------
def dahl_describing_function(dahl: Optional[DahlParams], amplitude: float,
                             play: float = 0.0) -> complex:
    """First-harmonic gain ``N`` of the Dahl force (eq. 14) driven by ``x = A cos(theta)``.

    ``F_d ~ Re(N A e^{j theta})``: ``Re N`` is a stiffness [N m/rad], ``Im N / w`` a damping
    [N m s/rad] at frequency w (the model is rate independent). For ``A << F_c/sigma``
    ``N -> sigma``; for ``A >> F_c/sigma`` ``N -> j 4 F_c/(pi A)`` (Coulomb friction).

    Parameters
    ----------
    dahl : DahlParams or None
        sigma [N m/rad], F_c [N m], n; None (or sigma = 0): no hysteresis, N = 0.
    amplitude : float >= 0
        A [rad].
    play : float >= 0
        Total width of a play operator (dead zone) in front of the Dahl model [rad], as the
        feed-forward's ``feedforward.dahl_deadband``.

    Returns
    -------
    complex
        N [N m/rad].
    """
    if dahl is None or dahl.sigma == 0.0:
        return 0j
    half = 0.5 * play
    a_eff = float(amplitude) - half
    if not a_eff > 0.0:
        return 0j                       # the play swallows the motion: F_d stays put
    sigma, fc, n = dahl.sigma, dahl.coulomb_force, dahl.exponent
    theta = (np.arange(_DF_POINTS) + 0.5) * (math.pi / _DF_POINTS)
    # down stroke: x = A cos(theta) falls from A to -A; the play's output from A - h to -A + h
    y = np.minimum(a_eff, amplitude * np.cos(theta) + half)
    if n == 1.0:
        top = fc * math.tanh(sigma * a_eff / fc)
        force = -fc + (top + fc) * np.exp(-sigma * (a_eff - y) / fc)
    else:
        force = _dahl_down_stroke(y, sigma, fc, n)
    # F(theta + pi) = -F(theta): both half cycles give the same first harmonic
    coefficient = (2.0 / _DF_POINTS) * np.sum(force * np.exp(-1j * theta))
    return complex(coefficient / amplitude)


def _dahl_down_stroke(y: _Float, sigma: float, fc: float, n: float) -> _Float:
    """F_d along the down stroke ``y`` (from its top) in the symmetric steady cycle, any n:
    the top force is the fixed point of ``top -> -(force at the bottom)``."""
    top = 0.0
    out = np.empty_like(y)
    for _ in range(60):
        f = top
        prev = float(y[0])
        for i, yi in enumerate(y):
            f = dahl_step(f, float(yi) - prev, sigma, fc, n)
            prev = float(yi)
            out[i] = f
        # the last step of the stroke: from y[-1] to the bottom -A_eff = -y[0]
        bottom = dahl_step(f, -float(y[0]) - prev, sigma, fc, n)
        if abs(-bottom - top) <= 1e-12 * fc:
            break
        top = -bottom
    return out


# --- the controller, mode by mode, as z-domain gains on (X, F_p) --------------------------
_P = np.polynomial.polynomial


def controller_polynomials(config: ControllerConfig, mode: str, dt: float,
                           dahl_gain: complex = 0j) -> Tuple[_Coefficients, _Coefficients,
                                                             _Coefficients]:
    """The mode's command as polynomials in ``q = z^-1`` (ascending powers)::

        D(q) U = N_x(q) X + N_p(q) F_p

    from the measured motor position and pressure force (velocity: the drive's backward
    difference ``(1 - q)/T X``), as the core computes it (module docstring).

    Parameters
    ----------
    config : ControllerConfig
        The controller's settings and model (b_e, k_e, b_s, k_s; the DOB; the hold gains).
    mode : str
        One of :data:`PREDICTED_MODES`.
    dt : float > 0
        T [s].
    dahl_gain : complex
        Describing function of the feed-forward's Dahl force on X_e_hat [N m/rad].

    Returns
    -------
    (N_x [N m/rad], N_p [-], D with D[0] = 1) : coefficient arrays
    """
    if mode not in PREDICTED_MODES:
        raise PredictionError(f"mode {mode!r}: the predictor models "
                              + ", ".join(PREDICTED_MODES))
    one = np.array([1.0 + 0j])
    v_x = np.array([1.0, -1.0]) / dt                        # backward difference
    if mode == "passive":
        return 0 * one, 0 * one, one.real
    if mode == "hold":
        return (-_P.polyadd(config.hold.stiffness * one, config.hold.damping * v_x), 0 * one,
                one.real)
    if mode == "force_feedback":
        return 0 * one, config.force_feedback.gain * one, one.real
    p = config.plant
    a, c0, c1 = hose_coefficients(p.hose_stiffness, 1.0 / p.hose_damping, dt)
    d_h = np.array([1.0, -a])                   # the hose inversion's denominator
    d_i = np.array([1.0, -1.0])                 # the DOB integrator's
    # X_e_hat = X + delta, delta = [c1, c0]/d_h F_p; V_e_hat = V + (F_p - k_s delta)/b_s:
    # the X parts are polynomials, the F_p parts polynomials over d_h
    delta = np.array([c1, c0])
    xe_x, xe_p = one, delta
    ve_x, ve_p = v_x, _P.polysub(d_h, p.hose_stiffness * delta) / p.hose_damping
    ref_x, ref_p = 0 * one, 0 * one
    if mode != "dob":
        b_ff, k_ff, _ = config.feedforward_friction()       # with the margin
        ref_x = _P.polyadd(b_ff * ve_x, k_ff * xe_x)
        ref_p = _P.polyadd(b_ff * ve_p, k_ff * xe_p)
    if mode in ("dob_full_ff", "impedance"):
        ref_x = _P.polyadd(ref_x, dahl_gain * xe_x)
        ref_p = _P.polyadd(ref_p, dahl_gain * xe_p)
    if mode == "impedance":
        kt, bt = config.target.stiffness, config.target.damping
        ref_x = _P.polysub(ref_x, _P.polyadd(kt * xe_x, bt * ve_x))
        ref_p = _P.polysub(ref_p, _P.polyadd(kt * xe_p, bt * ve_p))
    dob = config.dob
    lam = dob.cutoff
    m_n = p.motor_inertia if dob.nominal_inertia is None else dob.nominal_inertia
    integ = 0.5 * lam * dt * np.array([1.0, 1.0])           # over d_i (trapezoidal)
    ramp = _P.polyadd(lam * m_n * v_x, lam * dob.nominal_damping * one)
    # U = F_ref + I/d_i (F_ref + F_p - k_n X) - ramp X, over d_h d_i
    error_x = _P.polysub(ref_x, [dob.nominal_stiffness])
    n_x = _P.polymul(_P.polysub(_P.polyadd(_P.polymul(ref_x, d_i), _P.polymul(integ, error_x)),
                                _P.polymul(ramp, d_i)), d_h)
    n_p = _P.polyadd(_P.polymul(ref_p, d_i), _P.polymul(integ, _P.polyadd(ref_p, d_h)))
    den = _P.polymul(d_h, d_i)
    reserve = config.feedforward.damping_reserve
    if mode != "dob" and reserve:
        # F_ref -= r HP(q) V: a part of F_ref enters U as (d_i + integ) d_h over d_h d_i, this
        # one over the high-pass's denominator as well
        hp_num, hp_den = reserve_filter(config.feedforward.reserve_cutoff, dt)
        gain = _P.polymul(_P.polyadd(d_i, integ), d_h)
        n_x = _P.polysub(_P.polymul(n_x, hp_den),
                         reserve * _P.polymul(gain, _P.polymul(hp_num, v_x)))
        n_p = _P.polymul(n_p, hp_den)
        den = _P.polymul(den, hp_den)
    return n_x, n_p, den


def reserve_filter(cutoff: float, dt: float) -> Tuple[_Coefficients, _Coefficients]:
    """The damping reserve's high-pass ``HP(q) = a (1 - q)/(1 - a q)``, ``a = exp(-cutoff
    T)``, as (numerator, denominator) in ``q = z^-1`` (cutoff 0: 1)."""
    if not cutoff:
        return np.array([1.0]), np.array([1.0])
    a = math.exp(-cutoff * dt)
    return np.array([a, -a]), np.array([1.0, -a])


def controller_gains(config: ControllerConfig, mode: str, z: _Complex, dt: float,
                     dahl_gain: complex = 0j) -> Tuple[_Complex, _Complex]:
    """:func:`controller_polynomials` at ``z = e^{j w T}``: ``U = k_x(z) X + k_p(z) F_p``,
    k_x [N m/rad], k_p [-], complex arrays like ``z``."""
    n_x, n_p, d = controller_polynomials(config, mode, dt, dahl_gain)
    q = 1.0 / np.asarray(z)
    den = _P.polyval(q, d)
    return _P.polyval(q, n_x) / den, _P.polyval(q, n_p) / den


def closed_loop_radius(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                       config: ControllerConfig, mode: str, *, delay: int = 1,
                       dt: float = 5e-4, endpoint_stiffness: float = 0.0,
                       endpoint_damping: float = 0.0, feedforward_dahl: float = 0.0,
                       polynomials: Optional[Tuple[_Coefficients, _Coefficients,
                                                   _Coefficients]] = None) -> float:
    """Spectral radius of :func:`closed_loop_matrix` (its arguments): < 1, stable."""
    return float(np.max(np.abs(np.linalg.eigvals(closed_loop_matrix(
        true_plant, true_dahl, config, mode, delay=delay, dt=dt,
        endpoint_stiffness=endpoint_stiffness, endpoint_damping=endpoint_damping,
        feedforward_dahl=feedforward_dahl, polynomials=polynomials)))))


def closed_loop_matrix(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                       config: ControllerConfig, mode: str, *, delay: int = 1,
                       dt: float = 5e-4, endpoint_stiffness: float = 0.0,
                       endpoint_damping: float = 0.0, feedforward_dahl: float = 0.0,
                       polynomials: Optional[Tuple[_Coefficients, _Coefficients,
                                                   _Coefficients]] = None) -> _Float:
    """The state matrix of the sampled closed loop of ``mode``, the endpoint tied to ground by a spring-damper (0, 0: free; the position drive's 1000 N m/rad,
    1.2 N m s/rad: held). The plant's Dahl hysteresis is its initial stiffness sigma (small
    motion); the feed-forward's stays in its play, or, given ``feedforward_dahl`` [N m/rad],
    is that stiffness on X_e_hat (its initial one, beyond the play: the feed-forward's sigma).
    ``polynomials``: :func:`controller_polynomials` of ``config`` and ``mode`` computed once
    for many plants (``feedforward_dahl`` is then theirs).

    State: the plant (4), the last L measured X and F_p, the last M commands; one row per
    sample of ``D(q) U = N_x(q) X + N_p(q) F_p`` (:func:`controller_polynomials`).
    """
    delay = _check_delay(delay)
    n_x_c, n_p_c, den = (controller_polynomials(config, mode, dt, feedforward_dahl + 0j)
                         if polynomials is None else polynomials)
    n_x, n_p = n_x_c.real, n_p_c.real
    phi6, gam6 = _discretised(true_plant, dt, endpoint_stiffness, endpoint_damping, 0.0)
    phi, gam_m = phi6[:4, :4].copy(), gam6[:4, 0]
    if true_dahl is not None:
        phi[:, 2] -= true_dahl.sigma * gam6[:4, 1]
    hose = _hose_row(true_plant)
    L = max(n_x.size, n_p.size) - 1
    M = max(den.size - 1, delay)
    n = 4 + 2 * L + M
    ix, ip, iu = 4, 4 + L, 4 + 2 * L          # first index of each history
    u_row = np.zeros(n)                       # u_k as a row of the state at k
    u_row[:4] = (n_x[0] * np.eye(4)[0] + n_p[0] * hose) / den[0]
    for i in range(1, L + 1):
        u_row[ix + i - 1] += (n_x[i] if i < n_x.size else 0.0) / den[0]
        u_row[ip + i - 1] += (n_p[i] if i < n_p.size else 0.0) / den[0]
    for i in range(1, den.size):
        u_row[iu + i - 1] -= den[i] / den[0]
    A = np.zeros((n, n))
    A[:4, :4] = phi
    if delay == 0:
        A[:4] += np.outer(gam_m, u_row)
    else:
        A[:4, iu + delay - 1] += gam_m
    for base, row in ((ix, np.eye(4)[0]), (ip, hose)):
        if L:
            A[base, :4] = row
            for i in range(1, L):
                A[base + i, base + i - 1] = 1.0
    if M:
        A[iu] = u_row
    for i in range(1, M):
        A[iu + i, iu + i - 1] = 1.0
    return A


@functools.lru_cache(maxsize=4096)
def _discretised(plant: PlantParams, dt: float, stiffness: float, damping: float,
                 omega: float) -> Tuple[_Float, _Float]:
    """:func:`~seaforce_ros.core.simulator.discretise`, remembered: a tuning evaluates many
    controllers on one plant (the arrays are shared: never write into them)."""
    return discretise(plant, dt, stiffness, damping, omega)


def _check_omega(omega: npt.ArrayLike, dt: float) -> _Float:
    w = np.atleast_1d(np.asarray(omega, float))
    if w.size == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0.0) \
            or np.any(w >= math.pi / dt):
        raise PredictionError(f"omega: every frequency must be in (0, pi/T) = (0, "
                              f"{math.pi / dt:.6g}) rad/s")
    return w


def _check_delay(delay: int) -> int:
    if not (isinstance(delay, (int, np.integer)) and 0 <= delay <= 1000):
        raise PredictionError(f"delay = {delay!r} samples: an int in 0..1000")
    return int(delay)


def _hose_row(plant: PlantParams) -> _Float:
    """F_p = k_s (X_e - X) + b_s (V_e - V) as a row on the plant state (X, V, X_e, V_e)."""
    return np.array([-plant.hose_stiffness, -plant.hose_damping, plant.hose_stiffness,
                     plant.hose_damping])


def _solve(phi: _Float, gam_m: _Float, gam_e: _Float, rhs: _Complex, z: complex, delay: int,
           k_x: complex, k_p: complex, hose: _Float, dahl_gain: complex) -> _Coefficients:
    """The plant state phasor S at the sample instants (module docstring)."""
    row = k_x * np.eye(4)[0] + k_p * hose
    M = z * np.eye(4) - phi - z ** (-delay) * np.outer(gam_m, row)
    M[:, 2] += dahl_gain * gam_e
    return np.linalg.solve(M, rhs)


def predict_modes(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                  config: ControllerConfig, modes: Sequence[str], omega: npt.ArrayLike, *,
                  delay: int = 1, dt: float = 5e-4, amplitude: float = 0.5,
                  drive_stiffness: float = DRIVE_STIFFNESS,
                  drive_damping: float = DRIVE_DAMPING) -> Dict[str, _Complex]:
    """:func:`predict_impedance` for several modes at once (the plant discretised once per
    frequency). Returns ``{mode: Z(j omega)}`` [N m s/rad]."""
    w = _check_omega(omega, dt)
    delay = _check_delay(delay)
    if not (math.isfinite(amplitude) and amplitude > 0.0):
        raise PredictionError(f"amplitude = {amplitude!r} rad, must be > 0 and finite")
    for mode in modes:
        if mode not in PREDICTED_MODES:
            raise PredictionError(f"mode {mode!r}: the predictor models "
                                  + ", ".join(PREDICTED_MODES))
    hose = _hose_row(true_plant)
    play = config.feedforward.dahl_deadband
    out = {mode: np.empty(w.size, complex) for mode in modes}
    ken, ben = drive_stiffness, drive_damping
    z = np.exp(1j * w * dt)
    deflection = _endpoint_deflection(config, z, dt)
    # the command is affine in the feed-forward's Dahl gain N: k = k(0) + N (k(1) - k(0))
    gains = {}
    for mode in modes:
        gx0, gp0 = controller_gains(config, mode, z, dt, 0j)
        gx1, gp1 = controller_gains(config, mode, z, dt, 1.0 + 0j)
        gains[mode] = (gx0, gp0, gx1 - gx0, gp1 - gp0)
    n_plant0 = dahl_describing_function(true_dahl, amplitude)
    dahl_ff = config.feedforward_friction()[2]          # the feed-forward's, with the margin
    n_ff0 = dahl_describing_function(dahl_ff, amplitude, play)
    for i, wi in enumerate(w):
        phi6, gam6 = _discretised(true_plant, dt, ken, ben, float(wi))
        phi, gam_m, gam_e = phi6[:4, :4], gam6[:4, 0], gam6[:4, 1]
        drive = np.array([1.0, 1j])             # x_d = Re(e^{jwt}), y_d = x_d'/w
        rhs = phi6[:4, 4:] @ drive
        zi = complex(z[i])
        for mode in modes:
            k_x0, k_p0, dk_x, dk_p = (complex(g[i]) for g in gains[mode])
            n_plant, n_ff = n_plant0, n_ff0
            s = np.zeros(4, complex)
            for _ in range(_DF_PASSES + 1):
                s = _solve(phi, gam_m, gam_e, rhs, zi, delay, k_x0 + n_ff * dk_x,
                           k_p0 + n_ff * dk_p, hose, n_plant)
                # the drive phasor is 1: the motion's amplitudes are |S| A
                n_plant = dahl_describing_function(true_dahl, abs(s[2]) * amplitude)
                xe_hat = s[0] + deflection[i] * (hose @ s)
                if dk_x != 0 or dk_p != 0:
                    n_ff = dahl_describing_function(dahl_ff, abs(xe_hat) * amplitude, play)
            f_e = ken * (1.0 - s[2]) + ben * (1j * wi - s[3])
            out[mode][i] = f_e / (1j * wi * s[2])
    return out


def _endpoint_deflection(config: ControllerConfig, z: _Complex, dt: float) -> _Complex:
    """The controller's hose deflection per F_p, ``delta/F_p`` at z (eq. 29 discretised)."""
    p = config.plant
    a, c0, c1 = hose_coefficients(p.hose_stiffness, 1.0 / p.hose_damping, dt)
    return (c0 / z + c1) / (1.0 - a / z)


def predict_impedance(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                      config: ControllerConfig, mode: str, omega: npt.ArrayLike, *,
                      delay: int = 1, dt: float = 5e-4, amplitude: float = 0.5) -> _Complex:
    """Endpoint impedance ``Z(j w) = F_e/V_e`` [N m s/rad] the mode renders on the true plant.

    Parameters
    ----------
    true_plant : PlantParams
        The gripper (m, b, k, m_e, b_e, k_e, b_s, k_s).
    true_dahl : DahlParams or None
        Its endpoint hysteresis (sigma, F_c, n; eq. 14).
    config : ControllerConfig
        The controller: its model (``config.plant``, ``config.dahl``: what F_cmp and F_d use),
        DOB, hold gains, K_f, targets. ``config.mode`` is ignored.
    mode : str
        One of :data:`PREDICTED_MODES`.
    omega : array_like of float in (0, pi/T)
        Frequencies [rad/s].
    delay : int >= 0
        Loop delay [samples] (1: the command applied one sample after its measurement).
    dt : float > 0
        Sample period T [s].
    amplitude : float > 0
        Drive amplitude A [rad] (what the describing functions see).

    Returns
    -------
    complex array
        Z(j omega) like the backdrive measurement gives it.
    """
    return predict_modes(true_plant, true_dahl, config, (mode,), omega, delay=delay, dt=dt,
                         amplitude=amplitude)[mode]


# --- the uncertainty band -----------------------------------------------------------------
def perturbed_plants(plant: PlantParams, plant_sigma: Mapping[str, float],
                     dahl: Optional[DahlParams], count: int,
                     rng: np.random.Generator) -> Sequence[Tuple[PlantParams,
                                                                 Optional[DahlParams]]]:
    """``count`` plants drawn around the identified one: each parameter Gaussian with its
    1-sigma (``plant_sigma[field]``; ``'sigma'`` and ``'coulomb_force'`` for the Dahl model),
    clipped to at least 5 % of its value (a physical plant)."""
    _check_sigma(plant_sigma)
    out = []
    for _ in range(count):
        values = {}
        for name in PLANT_FIELDS:
            v = getattr(plant, name)
            values[name] = max(0.05 * v, v + float(plant_sigma.get(name, 0.0))
                               * float(rng.standard_normal()))
        d = dahl
        if dahl is not None:
            d = DahlParams(
                sigma=max(0.05 * dahl.sigma, dahl.sigma + float(plant_sigma.get("sigma", 0.0))
                          * float(rng.standard_normal())),
                coulomb_force=max(0.05 * dahl.coulomb_force, dahl.coulomb_force
                                  + float(plant_sigma.get("coulomb_force", 0.0))
                                  * float(rng.standard_normal())),
                exponent=dahl.exponent)
        out.append((PlantParams(**values), d))
    return out


#: The keys a ``plant_sigma`` may have: the plant's, the Dahl model's and the stroke terms'
#: (``plant_terms``; the band leaves the terms out).
SIGMA_KEYS = PLANT_FIELDS + ("sigma", "coulomb_force", "stroke_asymmetry", "stroke_stiffness")


def _check_sigma(plant_sigma: Mapping[str, float]) -> None:
    known = SIGMA_KEYS
    for key, value in plant_sigma.items():
        if key not in known:
            raise PredictionError(f"plant_sigma: unknown key {key!r}; known: "
                                  + ", ".join(known))
        if not (math.isfinite(value) and value >= 0.0):
            raise PredictionError(f"plant_sigma[{key!r}] = {value!r}: a 1-sigma must be >= 0 "
                                  "and finite")


@dataclass(frozen=True)
class ImpedanceBand:
    """Predicted |Z| per mode with the band the parameters' 1-sigma give.

    Attributes
    ----------
    omega : float array
        [rad/s].
    nominal : dict mode -> complex array
        Z on the identified plant [N m s/rad].
    lower, upper : dict mode -> float array
        16th / 84th percentile of |Z| over the drawn plants (the 1-sigma band).
    zwidth_db, zwidth_lower_db, zwidth_upper_db : float arrays
        ``20 log10(|Z_hold|/|Z_dob_full_ff|)`` on the identified plant and its band [dB]
        (empty when either mode is not among those predicted).
    """

    omega: _Float
    nominal: Dict[str, _Complex]
    lower: Dict[str, _Float]
    upper: Dict[str, _Float]
    zwidth_db: _Float
    zwidth_lower_db: _Float
    zwidth_upper_db: _Float


def _zwidth(z: Mapping[str, _Complex]) -> _Float:
    if "hold" not in z or "dob_full_ff" not in z:
        return np.zeros(0)
    return np.asarray(20.0 * np.log10(np.abs(z["hold"]) / np.abs(z["dob_full_ff"])), float)


def predict_band(plant: PlantParams, plant_sigma: Mapping[str, float],
                 dahl: Optional[DahlParams], config: ControllerConfig,
                 omega: npt.ArrayLike, modes: Sequence[str] = PREDICTED_MODES, *,
                 draws: int = 40, seed: int = 0, delay: int = 1, dt: float = 5e-4,
                 amplitude: float = 0.5) -> ImpedanceBand:
    """|Z| per mode on the identified plant and its 1-sigma band (Monte Carlo over the
    identified parameters, :func:`perturbed_plants`; the controller keeps ``config``).

    Parameters
    ----------
    draws : int >= 2
        Plants drawn.
    seed : int
        Of the draws (the band is reproducible).
    """
    if draws < 2:
        raise PredictionError(f"draws = {draws!r}: at least 2 plants for a band")
    rng = np.random.default_rng(seed)
    nominal = predict_modes(plant, dahl, config, modes, omega, delay=delay, dt=dt,
                            amplitude=amplitude)
    samples = [predict_modes(p, d, config, modes, omega, delay=delay, dt=dt,
                             amplitude=amplitude)
               for p, d in perturbed_plants(plant, plant_sigma, dahl, draws, rng)]
    lower = {m: np.percentile([np.abs(s[m]) for s in samples], 15.87, axis=0) for m in modes}
    upper = {m: np.percentile([np.abs(s[m]) for s in samples], 84.13, axis=0) for m in modes}
    widths = [_zwidth(s) for s in samples]
    zw = _zwidth(nominal)
    zl = np.percentile(widths, 15.87, axis=0) if zw.size else zw
    zu = np.percentile(widths, 84.13, axis=0) if zw.size else zw
    return ImpedanceBand(np.atleast_1d(np.asarray(omega, float)), nominal, lower, upper, zw,
                         np.asarray(zl, float), np.asarray(zu, float))


# --- torque noise ---------------------------------------------------------------------------
def _noise_grid(dt: float) -> Tuple[_Float, _Float]:
    """Normalised frequencies theta in (0, pi) and trapezoid weights for (1/pi) int d theta:
    log-spaced (the closed loop's slow poles sit near theta = 0)."""
    theta = np.concatenate([np.logspace(-7, math.log10(math.pi * 0.999), 800), [math.pi]])
    weights = np.empty_like(theta)
    d = np.diff(theta)
    weights[0] = 0.5 * d[0]
    weights[-1] = 0.5 * d[-1]
    weights[1:-1] = 0.5 * (d[:-1] + d[1:])
    return theta, weights / math.pi


def torque_noise(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                 config: ControllerConfig, figures: LoopModel, mode: str = "dob_full_ff",
                 delay: Optional[int] = None) -> Tuple[float, float]:
    """RMS of the commanded F_a [N m] that the sensor noise causes, endpoint free.

    Pressure noise (white, std ``figures.pressure_noise``) and the encoder's quantisation
    (white, uniform, variance ``Delta^2/12``; the velocity is the backward difference of the
    quantised position) pass through the sampled closed loop: ``U = (1 + L)^-1 ...`` with L
    the loop broken at the command. The endpoint's Dahl hysteresis acts as its initial
    stiffness sigma at noise amplitudes; the feed-forward's Dahl force stays in its play.

    Checked against the simulator (Table I, free finger at rest): the pressure noise's share
    within 3 %; the quantisation's within 10 % where the noise moves the motor over many
    counts (dob_linear_ff, 2^20 counts/rev) and up to 35 % high where it moves it by one or
    two (dob): the white model is conservative there. In ``dob_full_ff`` the free finger also
    wanders slowly (the feed-forward cancels the hysteresis that held it: 0.02 rad rms over
    8 s, Table I), a torque of about k_e times that on top, which is motion, not noise.

    Returns
    -------
    (rms from the pressure noise, rms from the quantisation) [N m]; the total is their
    root-sum-square.
    """
    dt = figures.dt
    d = figures.delay_p50 if delay is None else _check_delay(delay)
    phi6, gam6 = _discretised(true_plant, dt, 0.0, 0.0, 0.0)
    phi, gam_m, gam_e = phi6[:4, :4], gam6[:4, 0], gam6[:4, 1]
    n_plant = 0.0 if true_dahl is None else true_dahl.sigma   # N -> sigma as A -> 0
    theta, weights = _noise_grid(dt)
    z = np.exp(1j * theta)
    k_x, k_p = controller_gains(config, mode, z, dt, 0j)
    hose = _hose_row(true_plant)
    # open plant with the Dahl spring: G = (zI - Phi + N Gamma_e e_2^T)^-1 Gamma_m
    base = phi.copy()
    base[:, 2] -= n_plant * gam_e
    M = z[:, None, None] * np.eye(4)[None] - base[None]
    g = np.linalg.solve(M, np.broadcast_to(gam_m, (z.size, 4))[..., None])[..., 0]
    # loop broken at the command: L = -(k_x G_x + k_p G_p) z^-d; U = k/(1 + L) noise
    loop = -(k_x * g[:, 0] + k_p * (g @ hose)) * z ** (-d)
    sens = 1.0 / (1.0 + loop)
    var_p = figures.pressure_noise ** 2 * float(np.sum(weights * np.abs(k_p * sens) ** 2))
    var_x = figures.encoder_resolution ** 2 / 12.0 * float(
        np.sum(weights * np.abs(k_x * sens) ** 2))
    return math.sqrt(var_p), math.sqrt(var_x)


# --- hold stability -------------------------------------------------------------------------
def hold_delay_limit(plant: PlantParams, stiffness: float, damping: float, *,
                     dt: float = 5e-4, endpoint: str = "free", clamp_stiffness: float = 1e4,
                     max_delay: int = 200) -> int:
    """Largest loop delay d [samples] such that the PD hold (K_p [N m/rad], K_d [N m s/rad])
    is stable at every delay 0..d: the spectral radius of the exact discrete loop
    (:func:`~seaforce_ros.core.analysis.hold_loop`) below 1. -1 when it is unstable even
    without delay; ``max_delay`` when no delay up to it destabilises it."""
    for d in range(0, max_delay + 1):
        A, _ = hold_loop(plant, stiffness, damping, dt, d, endpoint, clamp_stiffness)
        if float(np.max(np.abs(np.linalg.eigvals(A)))) >= 1.0:
            return d - 1
    return max_delay


@dataclass(frozen=True)
class HoldVerdict:
    """The hold's stability: the delay limit with the endpoint free and clamped, and the
    margins at the given delay (:func:`~seaforce_ros.core.analysis.hold_margins`, the worse
    of free and clamped)."""

    delay_limit_free: int
    delay_limit_clamped: int
    margins: HoldMargins

    @property
    def delay_limit(self) -> int:
        """The smaller of the two limits [samples]."""
        return min(self.delay_limit_free, self.delay_limit_clamped)


def hold_verdict(plant: PlantParams, stiffness: float, damping: float, delay: int = 1,
                 dt: float = 5e-4) -> HoldVerdict:
    """:class:`HoldVerdict` of the PD hold at ``delay`` samples."""
    omega = np.logspace(-1.0, math.log10(math.pi / dt * 0.999), 600)
    found = [hold_margins(plant, stiffness, damping, dt, delay, e, omega=omega)
             for e in ("free", "clamped")]
    worst = min(found, key=lambda m: (m.stable, m.modulus_margin))
    return HoldVerdict(hold_delay_limit(plant, stiffness, damping, dt=dt),
                       hold_delay_limit(plant, stiffness, damping, dt=dt, endpoint="clamped"),
                       worst)


# --- impedance mode: the virtual wall -------------------------------------------------------
@dataclass(frozen=True)
class WallLimits:
    """The Z-width chart of impedance mode: the largest target stiffness K_t against the
    target damping B_t.

    Attributes
    ----------
    damping : float array
        B_t [N m s/rad].
    passivity : float array
        ``(b - |B|)/(T/2 + d T)`` [N m/rad]: Colgate & Schenkel's ``b > K T/2 + |B|``
        with the loop delay (0 where B exceeds b).
    quantisation : float
        ``2 F_c/Delta`` [N m/rad] (Abbott & Okamura: Coulomb friction over the encoder
        resolution).
    stiffness : float array
        The smaller of the two: K_max(B).
    binding : tuple of str
        ``'passivity'`` or ``'quantisation'`` per B.
    physical_damping : float
        b [N m s/rad] the endpoint shows in the mode's base (``dob_full_ff``).
    """

    damping: _Float
    passivity: _Float
    quantisation: float
    stiffness: _Float
    binding: Tuple[str, ...]
    physical_damping: float


def wall_limits(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                config: ControllerConfig, figures: LoopModel, damping: npt.ArrayLike,
                band: Tuple[float, float] = (0.3, 10.0), amplitude: float = 0.5) -> WallLimits:
    """K_max(B) of impedance mode (:class:`WallLimits`).

    ``b`` is the physical damping the endpoint shows in impedance mode's base,
    ``dob_full_ff``: the smallest real part of its predicted Z over ``band`` [rad/s] (at
    least 0). ``d`` is ``figures.delay_p99``. ``F_c`` is the endpoint's Coulomb friction,
    the Dahl model's ``coulomb_force`` (0 without one: no quantisation limit).
    """
    b_t = np.atleast_1d(np.asarray(damping, float))
    if b_t.size == 0 or not np.all(np.isfinite(b_t)):
        raise PredictionError("damping: a non-empty array of finite B_t [N m s/rad]")
    omega = np.logspace(math.log10(band[0]), math.log10(band[1]), 12)
    z = predict_impedance(true_plant, true_dahl, config, "dob_full_ff", omega,
                          delay=figures.delay_p50, dt=figures.dt, amplitude=amplitude)
    b = max(0.0, float(np.min(z.real)))
    T = figures.dt
    passive = np.maximum(0.0, b - np.abs(b_t)) / (0.5 * T + figures.delay_p99 * T)
    fc = 0.0 if true_dahl is None else true_dahl.coulomb_force
    quant = math.inf if figures.encoder_resolution == 0.0 else \
        2.0 * fc / figures.encoder_resolution
    stiffness = np.minimum(passive, quant)
    binding = tuple("passivity" if pv <= quant else "quantisation" for pv in passive)
    return WallLimits(b_t, passive, quant, stiffness, binding, b)

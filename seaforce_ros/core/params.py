"""Validated parameter sets of one channel (motor frame, rotational SI units).

All classes are frozen dataclasses that call ``validate()`` in
``__post_init__``; a bad value raises
:class:`~seaforce_ros.core.errors.InvalidParameterError` (or
:class:`~seaforce_ros.core.errors.NonPassiveError`) naming the value and
its bound.

The flat-dict helpers :meth:`ControllerConfig.from_dict` and
:meth:`ControllerConfig.to_dict` map the per-channel ROS parameters 1:1 (the
keys below are relative to ``<channel>.``)::

    mode
    plant.{motor_inertia, motor_damping, motor_stiffness, endpoint_inertia,
           endpoint_damping, endpoint_stiffness, hose_damping, hose_stiffness}
    dahl.{sigma, coulomb_force, exponent}
    dob.{cutoff, nominal_inertia, nominal_damping, nominal_stiffness}
    target.{stiffness, damping, force}
    hold.{stiffness, damping}
    force_feedback.gain
    chirp.{amplitude, start_frequency, end_frequency, duration}
    feedforward.{rest_position, dahl_deadband}
    estimator.{filter_cutoff, contact_threshold, baseline_time, baseline_distance, forgetting_time,
               min_position_excitation, min_velocity_excitation, model_uncertainty}
    grasp.{approach_damping, approach_force, contact_damping, max_closing_velocity, max_travel,
           give_way_travel, squeeze_time, probe_amplitude, probe_start_frequency,
           probe_end_frequency, probe_duration, release_time}
    friction.{calibration_duration, max_speed, torque_limit, max_tracking_error, position_min,
              position_max, adaptation, adaptation_time, adaptation_bound,
              min_velocity_excitation, min_position_excitation}
    max_torque
    allow_non_passive
    passivity_guard
    passivity.{reserve, max_damping, velocity_deadband, release_time}
"""

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Optional

from .errors import InvalidParameterError, NonPassiveError

__all__ = [
    "MODES", "DOB_MODES", "PlantParams", "DahlParams", "DobParams", "EstimatorParams",
    "GraspParams",
    "FrictionParams",
    "GUARD_MODES", "GuardParams", "guard_carries",
    "ControllerConfig", "PARAMETERS", "ParameterInfo", "DEFAULT_CUTOFF",
    "DEFAULT_HOLD_STIFFNESS", "DEFAULT_HOLD_DAMPING", "MIN_CLOSING_VELOCITY",
]

#: Controller modes (DESIGN.md "Control").
MODES = ("passive", "hold", "force_feedback", "dob", "dob_linear_ff", "dob_full_ff",
         "impedance", "force", "chirp")

#: Modes that run the disturbance observer (eq. 19).
DOB_MODES = ("dob", "dob_linear_ff", "dob_full_ff", "impedance", "force")

#: Default DOB cut-off lambda [rad/s]: the 20 Hz of Section III-B.
DEFAULT_CUTOFF = 2.0 * math.pi * 20.0

#: Default hold (maximum impedance) PD gains on the motor position, K_p
#: [N m/rad] and K_d [N m s/rad]. Chosen with
#: :func:`seaforce_ros.core.analysis.design_hold_gains` for Table I at 2 kHz
#: with a one-sample command delay and the drive's backward-difference
#: velocity: the largest K_p on a (K_p, K_d) grid for which the discrete
#: closed loop keeps a 6 dB gain margin and closed-loop damping ratio >= 0.3,
#: with the endpoint both free and clamped (see core/README.md).
DEFAULT_HOLD_STIFFNESS = 150.0
DEFAULT_HOLD_DAMPING = 0.5

#: The slowest approach a grasp goal may ask for [rad/s] (slower, the approach's arming
#: cannot tell the speed from the friction model's error).
MIN_CLOSING_VELOCITY = 0.01


def _check_finite(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidParameterError(name, value, "a real number")
    if not math.isfinite(value):
        raise InvalidParameterError(name, value, "finite")


def _check_positive(name, value):
    _check_finite(name, value)
    if not value > 0.0:
        raise InvalidParameterError(name, value, "> 0 and finite")


def _check_nonnegative(name, value):
    _check_finite(name, value)
    if not value >= 0.0:
        raise InvalidParameterError(name, value, ">= 0 and finite")


@dataclass(frozen=True)
class PlantParams:
    """Lumped linear model of one channel (paper Section II-C, Table I).

    Motor ``(m s^2 + b s + k) X = F_a + F_p``; endpoint
    ``(m_e s^2 + b_e s + k_e) X_e = F_e - F_p``; hose
    ``F_p = (b_s s + k_s)(X_e - X)``.

    Parameters
    ----------
    motor_inertia : float > 0
        m [N m s^2/rad].
    motor_damping : float >= 0
        b [N m s/rad].
    motor_stiffness : float >= 0
        k [N m/rad].
    endpoint_inertia : float > 0
        m_e [N m s^2/rad].
    endpoint_damping : float >= 0
        b_e [N m s/rad].
    endpoint_stiffness : float >= 0
        k_e [N m/rad].
    hose_damping : float >= 0
        b_s [N m s/rad].
    hose_stiffness : float >= 0
        k_s [N m/rad].
    """

    motor_inertia: float
    motor_damping: float
    motor_stiffness: float
    endpoint_inertia: float
    endpoint_damping: float
    endpoint_stiffness: float
    hose_damping: float
    hose_stiffness: float

    def __post_init__(self):
        self.validate()

    def validate(self):
        """Raise :class:`InvalidParameterError` on the first bad value."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name in ("motor_inertia", "endpoint_inertia"):
                _check_positive("plant." + f.name, value)
            else:
                _check_nonnegative("plant." + f.name, value)

    @classmethod
    def table_i(cls):
        """The identified gripper parameters of the paper's Table I."""
        return cls(motor_inertia=1.1116e-3, motor_damping=2.9814e-2,
                   motor_stiffness=0.1642, endpoint_inertia=0.7089e-3,
                   endpoint_damping=3.3879e-2, endpoint_stiffness=0.0637,
                   hose_damping=9.2453e-3, hose_stiffness=13.0782)

    def scaled(self, **factors):
        """Copy with some parameters multiplied, e.g. ``scaled(endpoint_damping=10)``."""
        return dataclasses.replace(
            self, **{n: getattr(self, n) * f for n, f in factors.items()})


@dataclass(frozen=True)
class DahlParams:
    """Dahl endpoint hysteresis (paper eq. 14-15).

    Parameters
    ----------
    sigma : float >= 0
        sigma, stiffness at F_d = 0 [N m/rad]; 0 disables the hysteresis.
    coulomb_force : float > 0
        F_c, hysteresis amplitude [N m].
    exponent : float >= 0
        n, material exponent (1 gives eq. 15).
    """

    sigma: float = 12.8
    coulomb_force: float = 0.032
    exponent: float = 1.0

    def __post_init__(self):
        self.validate()

    def validate(self):
        _check_nonnegative("dahl.sigma", self.sigma)
        _check_positive("dahl.coulomb_force", self.coulomb_force)
        _check_nonnegative("dahl.exponent", self.exponent)


@dataclass(frozen=True)
class DobParams:
    """Disturbance observer on the motor plant (paper eq. 17-19).

    Nominal inverse plant ``P_n^-1 = m_n s + b_n + k_n/s`` and low-pass
    ``Q = lambda/(s + lambda)``.

    Parameters
    ----------
    cutoff : float > 0
        lambda [rad/s]; default 2*pi*20 (Section III-B; Fig. 5C's caption
        uses 20 rad/s, also supported).
    nominal_inertia : float >= 0 or None
        m_n [N m s^2/rad]; None means "the plant's motor inertia m" (the
        paper's conservative choice), resolved by :class:`ControllerConfig`.
    nominal_damping : float
        b_n [N m s/rad], may be slightly negative (> -k/lambda).
    nominal_stiffness : float >= 0
        k_n [N m/rad].
    """

    cutoff: float = DEFAULT_CUTOFF
    nominal_inertia: float = None
    nominal_damping: float = 0.0
    nominal_stiffness: float = 0.0

    def __post_init__(self):
        self.validate()

    def validate(self):
        _check_positive("dob.cutoff", self.cutoff)
        if self.nominal_inertia is not None:
            _check_nonnegative("dob.nominal_inertia", self.nominal_inertia)
        _check_finite("dob.nominal_damping", self.nominal_damping)
        _check_nonnegative("dob.nominal_stiffness", self.nominal_stiffness)


def _check_range(name, value, low, high, strict_low=False):
    _check_finite(name, value)
    if (value <= low if strict_low else value < low) or value > high:
        raise InvalidParameterError(name, value, f"{'>' if strict_low else '>='} {low:g} "
                                                 f"and <= {high:g}")


@dataclass(frozen=True)
class EstimatorParams:
    """Online contact detection and object impedance estimation (:mod:`.estimator`).

    Parameters
    ----------
    filter_cutoff : float, 1..400
        Cut-off of the second-order state-variable filter the estimator sees every signal
        through [Hz] (noise vs. delay: about ``0.23/filter_cutoff`` s of group delay).
    contact_threshold : float > 0
        |force residual| that starts a contact whatever the noise [N m]; in free motion the
        threshold adapts to 5 rms of the residual, down to a third of this
        (:mod:`.estimator`); a contact ends below half the threshold it started with.
    baseline_time : float > 0
        Time constant with which the residual's free-motion bias (model error) and its drift
        are tracked while the finger is slow [s].
    baseline_distance : float > 0
        ... and the distance over which they are tracked while it moves [rad] (the faster
        applies); an object softer than about ``e contact_threshold/baseline_distance`` hides
        in the tracked bias.
    forgetting_time : float > 0
        Memory of the fit while the finger moves [s]; a still finger forgets nothing.
    min_position_excitation : float > 0
        Endpoint motion (rms, over ``forgetting_time``) that only the stiffness can explain
        before a stiffness is reported [rad].
    min_velocity_excitation : float > 0
        Likewise for the damping, in endpoint velocity [rad/s].
    model_uncertainty : float, 0..1
        Relative 1-sigma error of the plant model (k_e, b_e, k_s, b_s, F_d) folded into the
        reported 1-sigma of the estimates.
    """

    filter_cutoff: float = 30.0
    contact_threshold: float = 0.003
    baseline_time: float = 1.0
    baseline_distance: float = 0.2
    forgetting_time: float = 1.0
    min_position_excitation: float = 1e-3
    min_velocity_excitation: float = 0.03
    model_uncertainty: float = 0.15

    def __post_init__(self):
        self.validate()

    def validate(self):
        _check_range("estimator.filter_cutoff", self.filter_cutoff, 1.0, 400.0)
        _check_positive("estimator.contact_threshold", self.contact_threshold)
        _check_positive("estimator.baseline_time", self.baseline_time)
        _check_positive("estimator.baseline_distance", self.baseline_distance)
        _check_positive("estimator.forgetting_time", self.forgetting_time)
        _check_positive("estimator.min_position_excitation", self.min_position_excitation)
        _check_positive("estimator.min_velocity_excitation", self.min_velocity_excitation)
        _check_range("estimator.model_uncertainty", self.model_uncertainty, 0.0, 1.0)


@dataclass(frozen=True)
class GraspParams:
    """How a grasp approaches, squeezes, probes and releases (:mod:`.grasp`).

    Parameters
    ----------
    approach_damping : float > 0
        Gain B of the approach's PI speed servo, ``F = B (v_cmd - V_e) + I`` [N m s/rad]
        (cross-over ``B/(m_n + m_e)``).
    approach_force : float > 0
        Most force the approach pushes with, and the force held at first contact [N m].
    contact_damping : float >= 0
        Damping rendered on the endpoint while in contact [N m s/rad]: without it a force
        source against a stiff object rings (the friction feed-forward cancels the finger's
        own damping); at most 10 b_s unless ``allow_non_passive`` (noise, as for
        ``target.damping``).
    max_closing_velocity : float >= MIN_CLOSING_VELOCITY
        Largest |closing_velocity| a goal may ask for [rad/s].
    max_travel : float > 0
        Approach distance without contact after which the grasp gives up [rad].
    give_way_travel : float > 0
        Travel past the contact point after which the object counts as given way (it broke,
        slipped out, was taken away, or is too soft for the grip): the grasp drops it [rad].
    squeeze_time : float > 0
        Duration of the ramp from the touch force to ``grip_force`` [s].
    probe_amplitude : float, 0..0.9
        Probe oscillation amplitude as a fraction of ``grip_force`` [dimensionless].
    probe_start_frequency, probe_end_frequency : float > 0
        Probe log chirp from/to [Hz].
    probe_duration : float > 0
        [s].
    release_time : float > 0
        Ramp of the grasp force to zero on a cancel or an abort [s].
    """

    approach_damping: float = 0.04
    approach_force: float = 0.02
    contact_damping: float = 0.08
    max_closing_velocity: float = 2.0
    max_travel: float = 1.5
    give_way_travel: float = 1.5
    squeeze_time: float = 0.1
    probe_amplitude: float = 0.3
    probe_start_frequency: float = 2.0
    probe_end_frequency: float = 6.0
    probe_duration: float = 0.3
    release_time: float = 0.05

    def __post_init__(self):
        self.validate()

    def validate(self):
        _check_nonnegative("grasp.contact_damping", self.contact_damping)
        _check_finite("grasp.max_closing_velocity", self.max_closing_velocity)
        if not self.max_closing_velocity >= MIN_CLOSING_VELOCITY:
            raise InvalidParameterError(
                "grasp.max_closing_velocity", self.max_closing_velocity,
                f">= {MIN_CLOSING_VELOCITY:g} rad/s (goals slower than that are refused)")
        for name in ("approach_damping", "approach_force", "max_travel", "give_way_travel",
                     "squeeze_time", "probe_start_frequency",
                     "probe_end_frequency", "probe_duration", "release_time"):
            _check_positive("grasp." + name, getattr(self, name))
        _check_range("grasp.probe_amplitude", self.probe_amplitude, 0.0, 0.9)


# --- endpoint friction calibration and adaptation (issue 13) ------------------------------
@dataclass(frozen=True)
class FrictionParams:
    """Endpoint friction calibration and online adaptation (:mod:`.friction_calibration`).

    Parameters
    ----------
    calibration_duration : float, 1..120
        Length of a calibration motion, fades included [s].
    max_speed : float > 0
        Largest peak speed a calibration goal may ask for [rad/s].
    torque_limit : float > 0
        Most torque the calibration's position servo commands [N m] (and never more than
        ``max_torque``).
    max_tracking_error : float > 0
        |X_ref - X| beyond which a calibration aborts: the finger is blocked, not free [rad].
    position_min, position_max : float
        Joint range of the endpoint the calibration motion must stay in [rad].
    adaptation : bool
        Adapt b_e, k_e, F_c, sigma slowly while the contact estimator says the finger is free.
    adaptation_time : float > 0
        Time constant with which adapted values follow the fit, and the fit's memory [s].
    adaptation_bound : float, 0..10
        Adapted values stay within ``[v/(1 + r), v (1 + r)]`` of the configured ``v``.
    min_velocity_excitation : float > 0
        Endpoint velocity only b_e explains (rms over the memory) below which adaptation
        stops [rad/s].
    min_position_excitation : float > 0
        Endpoint motion only k_e explains below which adaptation stops [rad].
    """

    calibration_duration: float = 12.0
    max_speed: float = 3.0
    torque_limit: float = 0.5
    max_tracking_error: float = 0.2
    position_min: float = -1.5
    position_max: float = 1.5
    adaptation: bool = False
    adaptation_time: float = 30.0
    adaptation_bound: float = 1.0
    min_velocity_excitation: float = 0.1
    min_position_excitation: float = 0.02

    def __post_init__(self):
        self.validate()

    def validate(self):
        _check_range("friction.calibration_duration", self.calibration_duration, 1.0, 120.0)
        for name in ("max_speed", "torque_limit", "max_tracking_error", "adaptation_time",
                     "min_velocity_excitation", "min_position_excitation"):
            _check_positive("friction." + name, getattr(self, name))
        _check_finite("friction.position_min", self.position_min)
        _check_finite("friction.position_max", self.position_max)
        if not self.position_max > self.position_min:
            raise InvalidParameterError("friction.position_max", self.position_max,
                                        f"> friction.position_min = {self.position_min:g} rad")
        if not isinstance(self.adaptation, bool):
            raise InvalidParameterError("friction.adaptation", self.adaptation, "a bool")
        _check_range("friction.adaptation_bound", self.adaptation_bound, 0.0, 10.0)


# --- the time-domain passivity guard (issue 13) -------------------------------------------
#: Settings of ``<channel>.passivity_guard``. Not off/on: YAML 1.1 reads those as booleans.
GUARD_MODES = ("disabled", "monitor", "active")


@dataclass(frozen=True)
class GuardParams:
    """Time-domain passivity guard on the DOB's motor port (:mod:`.passivity_guard`).

    Parameters
    ----------
    mode : str
        ``disabled``; ``monitor`` (observe the port energy, add nothing); ``active`` (add
        damping when the energy runs out: a DOB setting outside eq. 28 is then accepted
        without ``allow_non_passive``).
    reserve : float, 1e-9..1
        R: the port's initial energy and the most credit the observer keeps [J]; the damping
        starts when the energy has fallen to R/2 and is ``max_damping`` at 0.
    max_damping : float, 0..100
        alpha_max, the largest damping the guard adds [N m s/rad]; passivates the DOB at every
        frequency when ``>= lambda (m - m_n) - b`` (the high-frequency deficit of eq. 25).
    velocity_deadband : float, 0..100
        Dead zone of the motor velocity the damping acts on [rad/s] (a noisy velocity).
    release_time : float, 1e-3..1000
        tau_r: time constant with which damping the guard no longer needs is released [s].
    """

    mode: str = "disabled"
    reserve: float = 1e-3
    max_damping: float = 0.5
    velocity_deadband: float = 0.0
    release_time: float = 5.0

    def __post_init__(self):
        self.validate()

    def validate(self):
        if self.mode not in GUARD_MODES:
            raise InvalidParameterError("passivity_guard", self.mode,
                                        "one of " + ", ".join(GUARD_MODES))
        _check_range("passivity.reserve", self.reserve, 1e-9, 1.0)
        _check_range("passivity.max_damping", self.max_damping, 0.0, 100.0)
        _check_range("passivity.velocity_deadband", self.velocity_deadband, 0.0, 100.0)
        _check_range("passivity.release_time", self.release_time, 1e-3, 1e3)


def check_dob_passivity(plant, dob):
    """Raise :class:`NonPassiveError` if ``dob`` violates eq. 28 for ``plant``.

    Passive iff ``m_n >= m - b/lambda`` and ``0 <= k_n <= k + lambda*b_n``
    (the Routh-Hurwitz and imaginary-pole conditions of Section III-C are
    implied by these when m > 0).
    """
    m, b, k = plant.motor_inertia, plant.motor_damping, plant.motor_stiffness
    lam = dob.cutoff
    m_n = m if dob.nominal_inertia is None else dob.nominal_inertia
    m_min = m - b / lam
    if m_n < m_min:
        raise NonPassiveError(
            "dob.nominal_inertia", m_n,
            f">= m - b/lambda = {m:.6g} - {b:.6g}/{lam:.6g} = {m_min:.6g} "
            "N m s^2/rad (eq. 28)")
    k_max = k + lam * dob.nominal_damping
    if dob.nominal_stiffness > k_max:
        raise NonPassiveError(
            "dob.nominal_stiffness", dob.nominal_stiffness,
            f"<= k + lambda*b_n = {k:.6g} + {lam:.6g}*{dob.nominal_damping:.6g} = "
            f"{k_max:.6g} N m/rad (eq. 28)")


def guard_carries(config):
    """Why ``config`` (a validated :class:`~.params.ControllerConfig`) needs its passivity
    guard: the eq. 28 violation that ``passivity_guard: active`` let through without
    ``allow_non_passive``, and whether ``passivity.max_damping`` covers the DOB's
    high-frequency deficit ``lambda (m - m_n) - b``. '' when the DOB setting is passive, the
    guard is not active, or ``allow_non_passive`` accepted it anyway. The node logs it as a
    warning when the configuration is accepted.
    """
    if config.passivity.mode != "active" or config.allow_non_passive:
        return ""
    try:
        check_dob_passivity(config.plant, config.dob)
    except NonPassiveError as exc:
        text = (f"{exc.name} = {exc.value!r} is outside the passivity bound ({exc.bound}): "
                "accepted because passivity_guard is active, which adds damping when the "
                "motor port has given back its reserve")
        p, dob = config.plant, config.dob
        deficit = dob.cutoff * (p.motor_inertia - dob.nominal_inertia) - p.motor_damping
        if deficit > 0.0:
            alpha = config.passivity.max_damping
            text += (f"; passivity.max_damping = {alpha:g} N m s/rad "
                     + ("covers" if alpha >= deficit else "is below (the guard may not hold "
                        "it in every contact)")
                     + f" the high-frequency deficit lambda (m - m_n) - b = {deficit:.4g}")
        return text
    return ""


# --- the parameter table ----------------------------------------------------
@dataclass(frozen=True)
class ParameterInfo:
    """One per-channel controller parameter (key relative to ``<channel>.``).

    Attributes
    ----------
    field : str
        Where the value lives: an attribute of :class:`ControllerConfig`, or
        ``"<plant|dahl|dob>.<attribute>"`` of its parameter group.
    description : str
        Symbol, meaning, units and the equation it comes from (a ROS descriptor's text).
    low, high : float or None
        The range a ROS descriptor advertises (and a node enforces before the core's own
        checks, which add the cross-parameter rules such as eq. 28).
    """

    field: str
    description: str
    low: Optional[float] = None
    high: Optional[float] = None
    #: allowed strings of a string parameter other than ``mode`` (a ROS descriptor's choices)
    choices: tuple = ()


#: Every per-channel controller parameter: flat key -> :class:`ParameterInfo`. The ROS
#: descriptors, ranges and the flat-dict conversions all derive from this one table.
PARAMETERS = {
    "mode": ParameterInfo("mode", "controller mode, one of " + ", ".join(MODES)),
    "plant.motor_inertia": ParameterInfo(
        "plant.motor_inertia", "m, motor inertia [N m s^2/rad], > 0", 0.0, 10.0),
    "plant.motor_damping": ParameterInfo(
        "plant.motor_damping", "b, motor damping [N m s/rad], >= 0", 0.0, 1e3),
    "plant.motor_stiffness": ParameterInfo(
        "plant.motor_stiffness", "k, motor stiffness [N m/rad], >= 0", 0.0, 1e4),
    "plant.endpoint_inertia": ParameterInfo(
        "plant.endpoint_inertia", "m_e, endpoint inertia [N m s^2/rad], > 0", 0.0, 10.0),
    "plant.endpoint_damping": ParameterInfo(
        "plant.endpoint_damping", "b_e, endpoint damping [N m s/rad], >= 0", 0.0, 1e3),
    "plant.endpoint_stiffness": ParameterInfo(
        "plant.endpoint_stiffness", "k_e, endpoint stiffness [N m/rad], >= 0", 0.0, 1e4),
    "plant.hose_damping": ParameterInfo(
        "plant.hose_damping", "b_s, hose damping [N m s/rad], > 0 for the controller",
        0.0, 1e3),
    "plant.hose_stiffness": ParameterInfo(
        "plant.hose_stiffness", "k_s, hose stiffness [N m/rad], > 0 for the controller",
        0.0, 1e6),
    "dahl.sigma": ParameterInfo(
        "dahl.sigma", "sigma, Dahl stiffness at F_d = 0 [N m/rad], >= 0 (eq. 14)", 0.0, 1e6),
    "dahl.coulomb_force": ParameterInfo(
        "dahl.coulomb_force", "F_c, Dahl hysteresis amplitude [N m], > 0 (eq. 14)",
        0.0, 1e3),
    "dahl.exponent": ParameterInfo(
        "dahl.exponent", "n, Dahl exponent [dimensionless], >= 0 (1 gives eq. 15)",
        0.0, 10.0),
    "dob.cutoff": ParameterInfo(
        "dob.cutoff", "lambda, DOB low-pass cut-off [rad/s], > 0 (eq. 18)", 0.0, 1e4),
    "dob.nominal_inertia": ParameterInfo(
        "dob.nominal_inertia",
        "m_n, DOB nominal inertia [N m s^2/rad], >= m - b/lambda (eq. 28)", 0.0, 10.0),
    "dob.nominal_damping": ParameterInfo(
        "dob.nominal_damping", "b_n, DOB nominal damping [N m s/rad], > -k/lambda",
        -1e3, 1e3),
    "dob.nominal_stiffness": ParameterInfo(
        "dob.nominal_stiffness",
        "k_n, DOB nominal stiffness [N m/rad], 0..k + lambda b_n (eq. 28)", 0.0, 1e4),
    "target.stiffness": ParameterInfo(
        "target_stiffness",
        "rendered endpoint stiffness in impedance mode [N m/rad], 0..k_s", 0.0, 1e4),
    "target.damping": ParameterInfo(
        "target_damping",
        "rendered endpoint damping in impedance mode [N m s/rad], 0..10 b_s", 0.0, 1e3),
    "target.force": ParameterInfo(
        "target_force",
        "F_ref of force mode (eq. 19 with a reference): at rest the hose pushes the motor "
        "with F_p = -F_ref, the finger's own friction not compensated [N m]", -100.0, 100.0),
    "hold.stiffness": ParameterInfo(
        "hold_stiffness",
        "hold-mode PD stiffness K_p on the motor position [N m/rad], >= 0", 0.0, 1e5),
    "hold.damping": ParameterInfo(
        "hold_damping",
        "hold-mode PD damping K_d on the motor velocity [N m s/rad], >= 0", 0.0, 1e3),
    "force_feedback.gain": ParameterInfo(
        "force_feedback_gain",
        "K_f of F_a = K_f F_p (eq. 20) [dimensionless], -1..1 unless allow_non_passive",
        -100.0, 100.0),
    "chirp.amplitude": ParameterInfo(
        "chirp_amplitude", "open-loop chirp torque amplitude [N m], >= 0", 0.0, 100.0),
    "chirp.start_frequency": ParameterInfo(
        "chirp_start_frequency", "chirp start frequency [Hz], > 0", 0.0, 1e4),
    "chirp.end_frequency": ParameterInfo(
        "chirp_end_frequency", "chirp end frequency [Hz], > 0", 0.0, 1e4),
    "chirp.duration": ParameterInfo(
        "chirp_duration", "chirp duration [s], > 0", 0.0, 1e5),
    "feedforward.rest_position": ParameterInfo(
        "rest_position", "motor-frame endpoint position where k_e is relaxed [rad]",
        -100.0, 100.0),
    "feedforward.dahl_deadband": ParameterInfo(
        "dahl_deadband", "width of the dead zone (play) on the estimated endpoint position "
        "driving the Dahl feed-forward [rad], >= 0", 0.0, 1.0),
    "estimator.filter_cutoff": ParameterInfo(
        "estimator.filter_cutoff", "cut-off of the state-variable filter of the contact "
        "estimator (noise vs. delay) [Hz]", 1.0, 400.0),
    "estimator.contact_threshold": ParameterInfo(
        "estimator.contact_threshold", "|F_e_hat - free-motion bias| that starts a contact "
        "whatever the noise; in free motion the threshold adapts down to 5 rms of the "
        "residual, at least a third of this; a contact ends below half of it [N m]", 1e-6,
        100.0),
    "estimator.baseline_time": ParameterInfo(
        "estimator.baseline_time", "time constant tracking the force residual's bias in "
        "free motion (model error) while the finger is slow [s]", 1e-3, 100.0),
    "estimator.baseline_distance": ParameterInfo(
        "estimator.baseline_distance", "travel over which the force residual's bias is "
        "tracked while the finger moves (the faster of the two applies) [rad]", 1e-4, 100.0),
    "estimator.forgetting_time": ParameterInfo(
        "estimator.forgetting_time", "memory of the object fit while the finger moves; a "
        "still finger forgets nothing [s]", 1e-2, 1e3),
    "estimator.min_position_excitation": ParameterInfo(
        "estimator.min_position_excitation", "rms endpoint motion only the stiffness explains "
        "before a stiffness estimate is reported [rad]", 1e-6, 10.0),
    "estimator.min_velocity_excitation": ParameterInfo(
        "estimator.min_velocity_excitation", "rms endpoint velocity only the damping explains "
        "before a damping estimate is reported [rad/s]", 1e-6, 100.0),
    "estimator.model_uncertainty": ParameterInfo(
        "estimator.model_uncertainty", "relative 1-sigma error of the plant model, folded "
        "into the reported 1-sigma of the object estimates [dimensionless]", 0.0, 1.0),
    "grasp.approach_damping": ParameterInfo(
        "grasp.approach_damping", "gain B of the approach's PI speed servo, F = B (v_cmd - "
        "V_e) + I (cross-over B/(m_n + m_e)) [N m s/rad]", 1e-6, 100.0),
    "grasp.approach_force": ParameterInfo(
        "grasp.approach_force", "most force the approach pushes with, and the force held at "
        "first contact [N m]", 1e-6, 10.0),
    "grasp.contact_damping": ParameterInfo(
        "grasp.contact_damping", "damping rendered on the endpoint in contact (a stiff object "
        "rings against a pure force source), 0..10 b_s [N m s/rad]", 0.0, 1e3),
    "grasp.max_closing_velocity": ParameterInfo(
        "grasp.max_closing_velocity", "largest |closing_velocity| a grasp goal may ask for "
        "(goals slower than 0.01 rad/s are refused) [rad/s]", MIN_CLOSING_VELOCITY, 100.0),
    "grasp.max_travel": ParameterInfo(
        "grasp.max_travel", "approach distance without contact after which a grasp gives up "
        "[rad]", 1e-6, 100.0),
    "grasp.give_way_travel": ParameterInfo(
        "grasp.give_way_travel", "travel past the contact point after which the object "
        "counts as given way and the grasp drops it [rad]", 1e-6, 100.0),
    "grasp.squeeze_time": ParameterInfo(
        "grasp.squeeze_time", "ramp from the touch force to grip_force [s]", 1e-3, 100.0),
    "grasp.probe_amplitude": ParameterInfo(
        "grasp.probe_amplitude", "probe force oscillation amplitude, fraction of grip_force "
        "[dimensionless]", 0.0, 0.9),
    "grasp.probe_start_frequency": ParameterInfo(
        "grasp.probe_start_frequency", "probe log chirp start frequency [Hz]", 1e-2, 100.0),
    "grasp.probe_end_frequency": ParameterInfo(
        "grasp.probe_end_frequency", "probe log chirp end frequency [Hz]", 1e-2, 100.0),
    "grasp.probe_duration": ParameterInfo(
        "grasp.probe_duration", "probe duration [s]", 1e-2, 100.0),
    "grasp.release_time": ParameterInfo(
        "grasp.release_time", "ramp of the grasp force to zero on a cancel or an abort [s]",
        1e-3, 10.0),
    # --- endpoint friction calibration and adaptation (issue 13)
    "friction.calibration_duration": ParameterInfo(
        "friction.calibration_duration", "length of a ~/calibrate_friction motion, fades "
        "included [s]", 1.0, 120.0),
    "friction.max_speed": ParameterInfo(
        "friction.max_speed", "largest peak speed a friction calibration goal may ask for "
        "[rad/s]", 1e-3, 100.0),
    "friction.torque_limit": ParameterInfo(
        "friction.torque_limit", "most torque the friction calibration's position servo "
        "commands (and never more than max_torque) [N m]", 1e-3, 100.0),
    "friction.max_tracking_error": ParameterInfo(
        "friction.max_tracking_error", "|X_ref - X| beyond which a friction calibration "
        "aborts (the finger is blocked, not free) [rad]", 1e-4, 10.0),
    "friction.position_min": ParameterInfo(
        "friction.position_min", "lower end of the joint range a friction calibration "
        "motion must stay in [rad]", -100.0, 100.0),
    "friction.position_max": ParameterInfo(
        "friction.position_max", "upper end of the joint range a friction calibration "
        "motion must stay in [rad]", -100.0, 100.0),
    "friction.adaptation": ParameterInfo(
        "friction.adaptation", "adapt b_e, k_e, F_c, sigma (eq. 14, 29) slowly while the "
        "contact estimator says the finger is free (bool)"),
    "friction.adaptation_time": ParameterInfo(
        "friction.adaptation_time", "time constant of the online friction adaptation and "
        "memory of its fit [s]", 0.1, 1e4),
    "friction.adaptation_bound": ParameterInfo(
        "friction.adaptation_bound", "adapted b_e, k_e, F_c, sigma stay within [v/(1+r), "
        "v (1+r)] of the configured v [dimensionless]", 0.0, 10.0),
    "friction.min_velocity_excitation": ParameterInfo(
        "friction.min_velocity_excitation", "rms endpoint velocity only b_e explains below "
        "which the friction adaptation stops [rad/s]", 1e-6, 100.0),
    "friction.min_position_excitation": ParameterInfo(
        "friction.min_position_excitation", "rms endpoint motion only k_e explains below "
        "which the friction adaptation stops [rad]", 1e-6, 10.0),
    # time-domain passivity guard (issue 13)
    "passivity_guard": ParameterInfo(
        "passivity.mode", "time-domain passivity guard on the motor port, one of "
        + ", ".join(GUARD_MODES) + ": monitor observes the port energy, active also adds "
        "damping when it runs out (a DOB setting outside eq. 28 then needs no "
        "allow_non_passive)", choices=GUARD_MODES),
    "passivity.reserve": ParameterInfo(
        "passivity.reserve", "R, the motor port's initial energy and the most credit the "
        "guard keeps; damping starts below R/2 [J]", 1e-9, 1.0),
    "passivity.max_damping": ParameterInfo(
        "passivity.max_damping", "largest damping the guard adds to the motor port, reached "
        "at zero energy [N m s/rad] (passivates the DOB when >= lambda (m - m_n) - b)",
        0.0, 100.0),
    "passivity.velocity_deadband": ParameterInfo(
        "passivity.velocity_deadband", "dead zone of the motor velocity the guard's damping "
        "acts on (for a noisy velocity; a band leaves oscillations slower than it) [rad/s]",
        0.0, 100.0),
    "passivity.release_time": ParameterInfo(
        "passivity.release_time", "time constant with which the guard releases damping it "
        "no longer needs [s]", 1e-3, 1e3),
    "max_torque": ParameterInfo(
        "max_torque", "the controller's fault limit: a computed |F_a| above it latches a "
        "torque_limit fault (zero torque) [N m], > 0", 0.0, 1e3),
    "allow_non_passive": ParameterInfo(
        "allow_non_passive", "accept DOB / force-feedback / impedance settings outside the "
        "passivity bounds (eq. 28) (bool)"),
}

#: The parameter groups of :class:`ControllerConfig` (``<group>.<attribute>`` fields).
_GROUPS = ("plant", "dahl", "dob", "estimator", "grasp", "friction", "passivity")


@dataclass(frozen=True)
class ControllerConfig:
    """Everything one channel's controller needs.

    Parameters
    ----------
    mode : str
        One of :data:`MODES`.
    plant : PlantParams
        Identified model; the feed-forward uses b_e, k_e, b_s, k_s and the
        passivity check m, b, k.
    dahl : DahlParams
        Endpoint hysteresis model of the Dahl feed-forward.
    dob : DobParams
        DOB settings; ``nominal_inertia=None`` is replaced by ``plant.motor_inertia``.
    hold_stiffness, hold_damping : float >= 0
        K_p [N m/rad] and K_d [N m s/rad] of the ``hold`` PD on motor position.
    force_feedback_gain : float
        K_f of ``force_feedback`` (eq. 20), passive for -1 <= K_f <= 1.
    target_stiffness, target_damping : float >= 0
        Endpoint stiffness [N m/rad] / damping [N m s/rad] of ``impedance``
        mode; at most k_s and 10 b_s unless ``allow_non_passive``.
    target_force : float
        F_ref of ``force`` mode [N m] (eq. 19).
    estimator : EstimatorParams
        Contact detection and object impedance estimation.
    grasp : GraspParams
        Grasp phases.
    friction : FrictionParams
        Endpoint friction calibration and adaptation.
    passivity : GuardParams
        Time-domain passivity guard (``passivity_guard``, ``passivity.*``).
    chirp_amplitude : float >= 0
        [N m].
    chirp_start_frequency, chirp_end_frequency : float > 0
        [Hz] (log chirp).
    chirp_duration : float > 0
        [s].
    rest_position : float
        Endpoint position where k_e is relaxed, motor frame [rad].
    dahl_deadband : float >= 0
        Play (dead-zone width) on X_e_hat before the Dahl model [rad].
    max_torque : float > 0
        |F_a| limit [N m].
    allow_non_passive : bool
        Accept settings outside the passivity bounds.
    """

    mode: str = "passive"
    plant: PlantParams = field(default_factory=PlantParams.table_i)
    dahl: DahlParams = field(default_factory=DahlParams)
    dob: DobParams = field(default_factory=DobParams)
    hold_stiffness: float = DEFAULT_HOLD_STIFFNESS
    hold_damping: float = DEFAULT_HOLD_DAMPING
    force_feedback_gain: float = 1.0
    target_stiffness: float = 0.0
    target_damping: float = 0.0
    target_force: float = 0.0
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    grasp: GraspParams = field(default_factory=GraspParams)
    passivity: GuardParams = field(default_factory=GuardParams)
    chirp_amplitude: float = 0.3
    chirp_start_frequency: float = 0.01
    chirp_end_frequency: float = 1000.0
    chirp_duration: float = 60.0
    rest_position: float = 0.0
    dahl_deadband: float = 1e-4
    max_torque: float = 5.0
    allow_non_passive: bool = False
    friction: FrictionParams = field(default_factory=FrictionParams)

    def __post_init__(self):
        if isinstance(self.dob, DobParams) and self.dob.nominal_inertia is None \
                and isinstance(self.plant, PlantParams):
            object.__setattr__(self, "dob", dataclasses.replace(
                self.dob, nominal_inertia=self.plant.motor_inertia))
        self.validate()

    def validate(self):
        """Check every value and the cross-parameter (passivity) rules."""
        if self.mode not in MODES:
            raise InvalidParameterError("mode", self.mode, "one of " + ", ".join(MODES))
        for name, cls in (("plant", PlantParams), ("dahl", DahlParams), ("dob", DobParams),
                          ("estimator", EstimatorParams), ("grasp", GraspParams),
                          ("friction", FrictionParams), ("passivity", GuardParams)):
            if not isinstance(getattr(self, name), cls):
                raise InvalidParameterError(name, getattr(self, name), f"a {cls.__name__}")
        _check_positive("plant.hose_damping", self.plant.hose_damping)
        _check_positive("plant.hose_stiffness", self.plant.hose_stiffness)
        _check_nonnegative("hold.stiffness", self.hold_stiffness)
        _check_nonnegative("hold.damping", self.hold_damping)
        _check_finite("force_feedback.gain", self.force_feedback_gain)
        _check_nonnegative("target.stiffness", self.target_stiffness)
        _check_nonnegative("target.damping", self.target_damping)
        _check_finite("target.force", self.target_force)
        _check_nonnegative("chirp.amplitude", self.chirp_amplitude)
        _check_positive("chirp.start_frequency", self.chirp_start_frequency)
        _check_positive("chirp.end_frequency", self.chirp_end_frequency)
        _check_positive("chirp.duration", self.chirp_duration)
        _check_finite("feedforward.rest_position", self.rest_position)
        _check_nonnegative("feedforward.dahl_deadband", self.dahl_deadband)
        _check_positive("max_torque", self.max_torque)
        if not isinstance(self.allow_non_passive, bool):
            raise InvalidParameterError("allow_non_passive", self.allow_non_passive,
                                        "a bool")
        if not self.allow_non_passive:
            if self.passivity.mode != "active":     # an active guard carries eq. 28
                check_dob_passivity(self.plant, self.dob)
            # impedance mode: ranges verified stable in simulation (Table I,
            # endpoint free and driven); the free endpoint went unstable at
            # K_t ~ 2 k_s and at B_t ~ 25 b_s (V_e_hat amplifies the pressure
            # noise and the hose dynamics by B_t/b_s)
            if self.target_stiffness > self.plant.hose_stiffness:
                raise InvalidParameterError(
                    "target.stiffness", self.target_stiffness,
                    f"<= k_s = {self.plant.hose_stiffness:.6g} N m/rad (the hose "
                    "stiffness; stiffer targets destabilise a free endpoint)",
                    override="allow_non_passive")
            b_max = 10.0 * self.plant.hose_damping
            for name, value in (("target.damping", self.target_damping),
                                ("grasp.contact_damping", self.grasp.contact_damping)):
                if value > b_max:
                    raise InvalidParameterError(
                        name, value, f"<= 10 b_s = {b_max:.6g} N m s/rad (the velocity "
                        "estimate amplifies pressure noise by 1/b_s)",
                        override="allow_non_passive")
            if not -1.0 <= self.force_feedback_gain <= 1.0:
                raise NonPassiveError("force_feedback.gain", self.force_feedback_gain,
                                      "-1 <= K_f <= 1 (Section III-A, internal force "
                                      "feedback of a series-elastic system)")

    def replace(self, **changes):
        """Validated copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    # -- flat ROS-style dictionaries -------------------------------------
    def to_dict(self):
        """Flat ``{key: value}`` dict (keys of :data:`PARAMETERS`, relative to
        ``<channel>.``)."""
        out = {}
        for key, info in PARAMETERS.items():
            group, _, name = info.field.rpartition(".")
            value = getattr(getattr(self, group), name) if group else getattr(self, name)
            out[key] = value if isinstance(value, (str, bool)) else float(value)
        return out

    @classmethod
    def from_dict(cls, values, base=None):
        """Build a validated config from flat keys, overriding ``base``.

        Parameters
        ----------
        values : mapping
            ``{key: value}``; keys as in :data:`PARAMETERS`,
            optionally prefixed by ``<channel>.`` (the prefix is stripped when
            the remainder is a known key).
        base : ControllerConfig, optional
            Values for keys not given (default: ``ControllerConfig()``).

        Raises
        ------
        InvalidParameterError
            Unknown key or bad value (the error names the key and bound).
        """
        base = cls() if base is None else base
        groups = {group: {} for group in _GROUPS}
        simple = {}
        for raw_key, value in values.items():
            key = raw_key
            if key not in PARAMETERS and "." in key:
                tail = key.split(".", 1)[1]
                if tail in PARAMETERS:
                    key = tail
            if key not in PARAMETERS:
                raise InvalidParameterError(raw_key, value, "a known key: " +
                                            ", ".join(PARAMETERS))
            group, _, name = PARAMETERS[key].field.rpartition(".")
            if isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if group:
                groups[group][name] = value
            else:
                simple[name] = value
        replaced = {group: dataclasses.replace(getattr(base, group), **groups[group])
                    for group in _GROUPS}
        return dataclasses.replace(base, **replaced, **simple)

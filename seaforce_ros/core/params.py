"""The controller's parameters per channel (motor frame, rotational SI units).

Each group is a frozen dataclass of :mod:`.schema` rows, one row per parameter: the key
(``<group>.<field>`` relative to ``<channel>.``), default, unit, range, description; a bad
value raises :class:`~seaforce_ros.core.errors.InvalidParameterError` naming the key and its
bound. :class:`ControllerConfig` holds one of each and checks the rules between them -- the
DOB's passivity (eq. 28, :func:`check_dob_passivity`) and the limits the plant sets on the
impedance targets -- with :class:`~seaforce_ros.core.errors.NonPassiveError` where the closed
loop would not be passive. :meth:`ControllerConfig.from_dict` / :meth:`~ControllerConfig.to_dict`
map the flat ROS keys (:data:`PARAMETERS`) 1:1; the generated reference is
``docs/parameters.md``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import field
from typing import Any, Dict, List, Mapping, Optional, Tuple

from .errors import InvalidParameterError, NonPassiveError, SeaforceError
from .schema import ParameterGroup, Spec, group, param

__all__ = [
    "MODES", "DOB_MODES", "PlantParams", "PlantTermsParams", "DahlParams", "DobParams", "TargetParams",
    "HoldParams", "ForceFeedbackParams", "ChirpParams", "FeedforwardParams", "EstimatorParams",
    "GraspParams", "FrictionParams", "CommissioningParams", "GUARD_MODES", "GuardParams",
    "LimitParams", "MonitorParams", "VerificationParams", "FALLBACK_MODES", "MIN_UNCERTAINTY",
    "guard_carries", "settable_order",
    "check_dob_passivity", "ControllerConfig", "PARAMETERS", "DEFAULT_CUTOFF",
    "DEFAULT_HOLD_STIFFNESS", "DEFAULT_HOLD_DAMPING", "MIN_CLOSING_VELOCITY", "MODE_RENAMED",
    "GUARD_RENAMED",
]

#: Controller modes (the modes of the paper's Sections III-IV, plus chirp for identification).
MODES = ("passive", "hold", "force_feedback", "dob", "dob_linear_ff", "dob_full_ff",
         "impedance", "force", "chirp")

#: Modes that run the disturbance observer (eq. 19).
DOB_MODES = ("dob", "dob_linear_ff", "dob_full_ff", "impedance", "force")

#: Settings of ``<channel>.passivity_guard``. Not off/on: YAML 1.1 reads those as booleans.
GUARD_MODES = ("disabled", "monitor", "active")

#: The zero-torque mode was called ``off``, which YAML 1.1 reads as a boolean.
MODE_RENAMED = "the zero-torque mode formerly called off is passive"
#: The passivity guard's settings are not off/on, which YAML 1.1 reads as booleans.
GUARD_RENAMED = "the guard is disabled, monitor or active (off/on would be YAML booleans)"

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

#: The smallest relative uncertainty of a feed-forward term accepted without
#: ``allow_non_passive``: no identified value is exact (the fit's 1-sigma is not the model
#: class's error).
MIN_UNCERTAINTY = 0.01

#: The slowest approach a grasp goal may ask for [rad/s] (slower, the approach's arming
#: cannot tell the speed from the friction model's error).
MIN_CLOSING_VELOCITY = 0.01


@group("plant")
class PlantParams(ParameterGroup):
    """Lumped linear model of one channel (paper Section II-C, Table I; the defaults).

    Motor ``(m s^2 + b s + k) X = F_a + F_p``; endpoint
    ``(m_e s^2 + b_e s + k_e) X_e = F_e - F_p``; hose
    ``F_p = (b_s s + k_s)(X_e - X)``.
    """

    motor_inertia: float = param(1.1116e-3, "N m s^2/rad", "motor inertia", symbol="m",
                                 gt=0.0, le=10.0)
    motor_damping: float = param(2.9814e-2, "N m s/rad", "motor damping", symbol="b",
                                 ge=0.0, le=1e6)
    motor_stiffness: float = param(0.1642, "N m/rad", "motor stiffness", symbol="k",
                                   ge=0.0, le=1e10)
    endpoint_inertia: float = param(0.7089e-3, "N m s^2/rad", "endpoint inertia",
                                    symbol="m_e", gt=0.0, le=10.0)
    endpoint_damping: float = param(3.3879e-2, "N m s/rad", "endpoint damping (eq. 29)",
                                    symbol="b_e", ge=0.0, le=1e6)
    endpoint_stiffness: float = param(0.0637, "N m/rad", "endpoint stiffness (eq. 29)",
                                      symbol="k_e", ge=0.0, le=1e10)
    hose_damping: float = param(9.2453e-3, "N m s/rad", "hose damping; > 0 for the controller "
                                "(the hose inversion of eq. 29 divides by it)", symbol="b_s",
                                ge=0.0, le=1e6)
    hose_stiffness: float = param(13.0782, "N m/rad", "hose stiffness; > 0 for the "
                                  "controller", symbol="k_s", ge=0.0, le=1e10)

    @classmethod
    def table_i(cls) -> "PlantParams":
        """The identified gripper parameters of the paper's Table I."""
        return cls()

    def scaled(self, **factors: float) -> "PlantParams":
        """Copy with some parameters multiplied, e.g. ``scaled(endpoint_damping=10)``."""
        return dataclasses.replace(
            self, **{n: getattr(self, n) * f for n, f in factors.items()})


@group("plant_terms")
class PlantTermsParams(ParameterGroup):
    """The identified model's nonlinear terms beyond the linear plant (commissioning writes
    the ones its record resolves; 0: the linear model). ``d = X_e - X`` the hose's
    deflection, ``u = X_e - feedforward.rest_position`` the endpoint's stroke::

        hose      F_p = k_s d + b_s d' + c |d'| d' + kappa |d| d     (the observer inverts it)
        endpoint  F_k = k_e u + k_2 u^2 + k_3 u^3                      (the feed-forward)

    The feed-forward takes the stroke terms times their own margin's scale
    (``feedforward.stroke_uncertainty``)."""

    hose_flow: float = param(0.0, "N m s^2/rad^2", "the hose's viscous loss rising with flow "
                             "(c |d'| d'); 0: linear", symbol="c", ge=0.0, le=1e3)
    hose_pressure: float = param(0.0, "N m/rad^2", "the hose's stiffening with deflection, i.e. "
                                 "with pressure (kappa |d| d); 0: linear", symbol="kappa",
                                 ge=0.0, le=1e6)
    stroke_asymmetry: float = param(0.0, "N m/rad^2", "the diaphragm force's asymmetric stroke "
                                    "term (k_2 u^2); k_2^2 <= 3 k_e k_3: the force rises over "
                                    "the whole stroke", symbol="k_2", ge=-1e3, le=1e3)
    stroke_stiffness: float = param(0.0, "N m/rad^3", "the diaphragm force's stiffening at the "
                                    "stroke's ends (k_3 u^3)", symbol="k_3", ge=0.0, le=1e3)

    @property
    def hose(self) -> bool:
        """The hose has a nonlinear term."""
        return bool(self.hose_flow or self.hose_pressure)

    @property
    def stroke(self) -> bool:
        """The diaphragm has a stroke term."""
        return bool(self.stroke_asymmetry or self.stroke_stiffness)


@group("dahl")
class DahlParams(ParameterGroup):
    """Dahl endpoint hysteresis (paper eq. 14-15; the defaults are the paper's fit)."""

    sigma: float = param(12.8, "N m/rad", "Dahl stiffness at F_d = 0 (eq. 14); 0 disables "
                         "the hysteresis", symbol="sigma", ge=0.0, le=1e6)
    coulomb_force: float = param(0.032, "N m", "Dahl hysteresis amplitude (eq. 14)",
                                 symbol="F_c", gt=0.0, le=1e3)
    exponent: float = param(1.0, "-", "Dahl material exponent (1 gives eq. 15)", symbol="n",
                            ge=0.0, le=10.0)


@group("dob")
class DobParams(ParameterGroup):
    """Disturbance observer on the motor plant (paper eq. 17-19): nominal inverse plant
    ``P_n^-1 = m_n s + b_n + k_n/s`` and low-pass ``Q = lambda/(s + lambda)``."""

    cutoff: float = param(DEFAULT_CUTOFF, "rad/s", "DOB low-pass cut-off (eq. 18); default "
                          "2 pi 20 (the 20 Hz of Section III-B; Fig. 5C's caption uses "
                          "20 rad/s, also supported)", symbol="lambda", gt=0.0, le=1e4)
    nominal_inertia: Optional[float] = param(
        None, "N m s^2/rad", "DOB nominal inertia, >= m - b/lambda for passivity (eq. 28)",
        symbol="m_n", ge=0.0, le=10.0, type=float,
        default_note="the plant's motor inertia m (plant.motor_inertia), the paper's "
                     "conservative choice")
    nominal_damping: float = param(0.0, "N m s/rad", "DOB nominal damping; may be slightly "
                                   "negative (> -k/lambda)", symbol="b_n", ge=-1e3, le=1e3)
    nominal_stiffness: float = param(0.0, "N m/rad", "DOB nominal stiffness, <= k + lambda "
                                     "b_n for passivity (eq. 28)", symbol="k_n", ge=0.0,
                                     le=1e4)


@group("target")
class TargetParams(ParameterGroup):
    """What ``impedance`` and ``force`` mode render through the DOB."""

    stiffness: float = param(0.0, "N m/rad", "rendered endpoint stiffness in impedance mode, "
                             "at most k_s unless allow_non_passive (stiffer targets "
                             "destabilise a free endpoint)", symbol="K_t", ge=0.0, le=1e4)
    damping: float = param(0.0, "N m s/rad", "rendered endpoint damping in impedance mode, at "
                           "most 10 b_s unless allow_non_passive (the velocity estimate "
                           "amplifies pressure noise by 1/b_s)", symbol="B_t", ge=0.0, le=1e3)
    force: float = param(0.0, "N m", "the reference of force mode (eq. 19 with a reference): "
                         "at rest the hose pushes the motor with F_p = -F_ref, the finger's own "
                         "friction not compensated", symbol="F_ref", ge=-100.0, le=100.0)


@group("hold")
class HoldParams(ParameterGroup):
    """The ``hold`` mode's stiff PD on the motor position (maximum impedance)."""

    stiffness: float = param(DEFAULT_HOLD_STIFFNESS, "N m/rad", "hold-mode PD stiffness on the "
                             "motor position", symbol="K_p", ge=0.0, le=1e5)
    damping: float = param(DEFAULT_HOLD_DAMPING, "N m s/rad", "hold-mode PD damping on the "
                           "motor velocity", symbol="K_d", ge=0.0, le=1e3)


@group("force_feedback")
class ForceFeedbackParams(ParameterGroup):
    """Proportional internal force feedback ``F_a = K_f F_p`` (eq. 20-24)."""

    gain: float = param(1.0, "-", "the gain of F_a = K_f F_p (eq. 20), passive for -1..1 "
                        "unless allow_non_passive", symbol="K_f", ge=-100.0, le=100.0)


@group("chirp")
class ChirpParams(ParameterGroup):
    """The open-loop torque log chirp of ``chirp`` mode (identification on hardware)."""

    amplitude: float = param(0.3, "N m", "chirp torque amplitude", ge=0.0, le=100.0)
    start_frequency: float = param(0.01, "Hz", "chirp start frequency", gt=0.0, le=1e4)
    end_frequency: float = param(1000.0, "Hz", "chirp end frequency", gt=0.0, le=1e4)
    duration: float = param(60.0, "s", "chirp duration", gt=0.0, le=1e5)


@group("feedforward")
class FeedforwardParams(ParameterGroup):
    """The endpoint friction feed-forward (eq. 29 and the Dahl force, eq. 14)."""

    rest_position: float = param(0.0, "rad", "motor-frame endpoint position where k_e is "
                                 "relaxed", ge=-100.0, le=100.0)
    dahl_deadband: float = param(1e-4, "rad", "width of the dead zone (play) on the estimated "
                                 "endpoint position driving the Dahl feed-forward (3-4 sigma "
                                 "of its noise from the pressure sensor)", ge=0.0, le=1.0)
    margin: float = param(2.0, "-", "how many uncertainties (1-sigma) below the model the "
                          "feed-forward takes b_e, k_e and the Dahl F_c: the free finger "
                          "stays passive for every plant within margin x uncertainty; at "
                          "least 1 unless allow_non_passive", ge=0.0, le=10.0)
    damping_uncertainty: float = param(0.1, "-", "relative 1-sigma of the model's b_e, the "
                                       "fit's and the model class's (commissioning writes it; "
                                       "0.1 stands for hand-typed values); at least "
                                       "0.01 unless allow_non_passive", ge=0.0, le=1.0)
    stiffness_uncertainty: float = param(0.1, "-", "relative 1-sigma of the model's k_e, as "
                                         "damping_uncertainty", ge=0.0, le=1.0)
    dahl_uncertainty: float = param(0.1, "-", "relative 1-sigma of the model's F_c (eq. 14, "
                                    "the Dahl force's amplitude), as damping_uncertainty",
                                    ge=0.0, le=1.0)
    stroke_uncertainty: float = param(0.25, "-", "relative 1-sigma of the model's stroke "
                                      "terms (plant_terms.stroke_*; commissioning writes it, "
                                      "at least 0.15; 0.25 stands for hand-typed values), as "
                                      "damping_uncertainty", ge=0.0, le=1.0)
    dahl_stiffness_share: float = param(0.5, "-", "the share of the model's pre-sliding "
                                        "stiffness sigma the Dahl feed-forward cancels (its F_c "
                                        "in full, less the margin): cancelling sigma (200 times "
                                        "k_e) through the loop's lag makes the free finger "
                                        "oscillate; 0.5 also covers a sigma off by up to 2x; at "
                                        "most 0.5 unless allow_non_passive", ge=0.0, le=1.0)
    verified_share: float = param(0.0, "-", "the largest dahl_stiffness_share a free finger "
                                  "was verified to rest under, on the gripper (commissioning "
                                  "writes it; 0: none): the share may go up to it instead of "
                                  "0.5", ge=0.0, le=1.0)
    damping_reserve: float = param(0.01, "N m s/rad", "damping the feed-forward modes add on the "
                                   "motor velocity above reserve_cutoff (F_ref -= reserve x "
                                   "HP(V)): it damps the free finger's mode on its pre-sliding "
                                   "friction, which the feed-forward leaves undamped; 0.01 keeps "
                                   "every corner of Table I's +-20 % band stable; commissioning "
                                   "sizes it for the identified model", ge=0.0, le=0.1)
    reserve_cutoff: float = param(20.0, "rad/s", "corner of the first-order high-pass on the "
                                  "motor velocity the damping reserve acts on (0: every "
                                  "frequency): the mode it damps lies at 25-130 rad/s, the "
                                  "Z-width's band below 10", ge=0.0, le=1e3)
    plant_uncertainty: float = param(0.1, "-", "relative 1-sigma of the model's m_e, b_s, k_s "
                                     "and Dahl sigma: with margin, part of the band the "
                                     "damping reserve must hold a free finger over "
                                     "(commissioning writes it; 0.1 stands for hand-typed "
                                     "values)", ge=0.0, le=1.0)
    motor_uncertainty: float = param(0.1, "-", "likewise for the motor's m, b, k (commissioning "
                                     "writes the share of the margin that covers eq. 28's "
                                     "passivity_margin 1-sigmas)", ge=0.0, le=1.0)

    def dahl(self, model: "DahlParams") -> "DahlParams":
        """The Dahl parameters of the feed-forward's force: the model's F_c times the margin's
        scale, its sigma times ``dahl_stiffness_share`` (which stands for sigma's margin: at
        0.5 it covers a sigma off by up to 2x)."""
        sd = self.scales()[2]
        return dataclasses.replace(model, sigma=self.dahl_stiffness_share * model.sigma,
                                   coulomb_force=max(sd, 1e-12) * model.coulomb_force)

    def stroke_scale(self) -> float:
        """The factor ``1 - margin u`` (at least 0) the feed-forward applies to the stroke
        terms k_2, k_3."""
        return max(0.0, 1.0 - self.margin * self.stroke_uncertainty)

    def scales(self) -> Tuple[float, float, float]:
        """The factors ``1 - margin u`` (at least 0) the feed-forward applies to b_e, k_e and
        the Dahl F_c: the low edge of each term's uncertainty."""
        m = self.margin
        return (max(0.0, 1.0 - m * self.damping_uncertainty),
                max(0.0, 1.0 - m * self.stiffness_uncertainty),
                max(0.0, 1.0 - m * self.dahl_uncertainty))


@group("estimator")
class EstimatorParams(ParameterGroup):
    """Online contact detection and object impedance estimation (:mod:`.estimator`)."""

    filter_cutoff: float = param(30.0, "Hz", "cut-off of the second-order state-variable "
                                 "filter the estimator sees every signal through (noise vs. "
                                 "delay: about 0.23/filter_cutoff s of group delay)",
                                 ge=1.0, le=400.0)
    contact_threshold: float = param(0.003, "N m", "|force residual| that starts a contact "
                                     "whatever the noise; in free motion the threshold adapts "
                                     "to 5 rms of the residual, down to a third of this; a "
                                     "contact ends below half the threshold it started with",
                                     gt=0.0, le=100.0)
    baseline_time: float = param(1.0, "s", "time constant with which the residual's "
                                 "free-motion bias (model error) and its drift are tracked "
                                 "while the finger is slow", ge=1e-3, le=100.0)
    baseline_distance: float = param(0.2, "rad", "... and the travel over which they are "
                                     "tracked while it moves (the faster applies); an object "
                                     "softer than about e contact_threshold/baseline_distance "
                                     "hides in the tracked bias", ge=1e-4, le=100.0)
    forgetting_time: float = param(1.0, "s", "memory of the object fit while the finger moves; "
                                   "a still finger forgets nothing", ge=1e-2, le=1e3)
    min_position_excitation: float = param(1e-3, "rad", "endpoint motion (rms over "
                                           "forgetting_time) that only the stiffness can "
                                           "explain before a stiffness is reported", gt=0.0,
                                           le=10.0)
    min_velocity_excitation: float = param(0.03, "rad/s", "likewise for the damping, in "
                                           "endpoint velocity", gt=0.0, le=100.0)
    model_uncertainty: float = param(0.15, "-", "relative 1-sigma error of the plant model "
                                     "(k_e, b_e, k_s, b_s, F_d) folded into the reported "
                                     "1-sigma of the object estimates", ge=0.0, le=1.0)


@group("grasp")
class GraspParams(ParameterGroup):
    """How a grasp approaches, squeezes, probes and releases (:mod:`.grasp`)."""

    approach_damping: float = param(0.04, "N m s/rad", "gain B of the approach's PI speed "
                                    "servo, F = B (v_cmd - V_e) + I (cross-over B/(m_n + m_e))",
                                    gt=0.0, le=100.0)
    approach_force: float = param(0.02, "N m", "most force the approach pushes with, and the "
                                  "force held at first contact", gt=0.0, le=10.0)
    contact_damping: float = param(0.08, "N m s/rad", "damping rendered on the endpoint while "
                                   "in contact (a pure force source against a stiff object "
                                   "rings: the feed-forward cancels the finger's own damping); "
                                   "at most 10 b_s unless allow_non_passive", ge=0.0, le=1e3)
    max_closing_velocity: float = param(2.0, "rad/s", "largest |closing_velocity| a grasp goal "
                                        "may ask for", ge=MIN_CLOSING_VELOCITY, le=100.0,
                                        hint=f"goals slower than {MIN_CLOSING_VELOCITY:g} rad/s "
                                             "are refused")
    max_travel: float = param(1.5, "rad", "approach distance without contact after which the "
                              "grasp gives up", gt=0.0, le=100.0)
    give_way_travel: float = param(1.5, "rad", "travel past the contact point after which the "
                                   "object counts as given way (it broke, slipped out, was "
                                   "taken away, or is too soft for the grip): the grasp drops "
                                   "it", gt=0.0, le=100.0)
    squeeze_time: float = param(0.1, "s", "duration of the ramp from the touch force to "
                                "grip_force", ge=1e-3, le=100.0)
    probe_amplitude: float = param(0.3, "-", "probe force oscillation amplitude as a fraction "
                                   "of grip_force", ge=0.0, le=0.9)
    probe_start_frequency: float = param(2.0, "Hz", "probe log chirp start frequency",
                                         ge=1e-2, le=100.0)
    probe_end_frequency: float = param(6.0, "Hz", "probe log chirp end frequency",
                                       ge=1e-2, le=100.0)
    probe_duration: float = param(0.3, "s", "probe duration", ge=1e-2, le=100.0)
    release_time: float = param(0.05, "s", "ramp of the grasp force to zero on a cancel or an "
                                "abort", ge=1e-3, le=10.0)
    gripper_velocity: float = param(0.3, "rad/s", "speed of a gripper command (control_msgs "
                                    "GripperCommand, or ParallelGripperCommand without a "
                                    "velocity) towards its position X_e; the finger joint's "
                                    "velocity limit in the URDF, which MoveIt plans with",
                                    ge=MIN_CLOSING_VELOCITY, le=100.0)
    gripper_effort: float = param(0.3, "N m", "contact force cap of a ParallelGripperCommand "
                                  "without an effort (a max_effort or effort of 0 is refused: "
                                  "no force)", gt=0.0, le=100.0)
    gripper_tolerance: float = param(0.01, "rad", "|X_e - position| within which a gripper "
                                     "command has reached its goal", gt=0.0, le=1.0)
    gripper_namespace: str = param("", "ROS name", "namespace of the channel's control_msgs "
                                   "gripper actions <ns>/gripper_cmd and <ns>/parallel_gripper_cmd "
                                   "(empty: <channel>_gripper); read at start",
                                   read_only=True)
    gripper_allow_stalling: bool = param(False, "", "a gripper command an object stopped "
                                         "(stalled: gripping at its effort cap) ends SUCCEEDED; "
                                         "false, as ros2_controllers' allow_stalling: ABORTED "
                                         "(the grip goes on either way)")
    gripper_cancel: str = param("hold", "", "what a canceled gripper command leaves: hold (the "
                                "grip, or the finger where it is) or release (as a grasp's "
                                "cancel)", choices=("hold", "release"))


@group("friction")
class FrictionParams(ParameterGroup):
    """Endpoint friction calibration and online adaptation (:mod:`.friction_calibration`)."""

    calibration_duration: float = param(12.0, "s", "length of a ~/calibrate_friction motion, "
                                        "fades included", ge=1.0, le=120.0)
    max_speed: float = param(3.0, "rad/s", "largest peak speed a friction calibration goal "
                             "may ask for", ge=1e-3, le=100.0)
    torque_limit: float = param(0.5, "N m", "most torque the friction calibration's position "
                                "servo commands (and never more than max_torque)", ge=1e-3,
                                le=100.0)
    max_tracking_error: float = param(0.2, "rad", "|X_ref - X| beyond which a friction "
                                      "calibration aborts (the finger is blocked, not free)",
                                      ge=1e-4, le=10.0)
    position_min: float = param(-1.5, "rad", "lower end of the joint range a friction "
                                "calibration motion must stay in", ge=-100.0, le=100.0)
    position_max: float = param(1.5, "rad", "upper end of the joint range a friction "
                                "calibration motion must stay in (> position_min)",
                                ge=-100.0, le=100.0)
    plausible_ratio: float = param(2.0, "-", "a calibration whose b_e, k_e, F_c or sigma "
                                   "leaves [v/r, v r] of the present value v is refused, "
                                   "nothing applied (a finger that was not free)", gt=1.0,
                                   le=100.0)
    adaptation: bool = param(False, "", "adapt b_e, k_e, F_c, sigma (eq. 14, 29) slowly while "
                             "the contact estimator says the finger is free")
    adaptation_time: float = param(30.0, "s", "time constant with which adapted values follow "
                                   "the fit, and the fit's memory", ge=0.1, le=1e4)
    adaptation_bound: float = param(1.0, "-", "adapted b_e, k_e, F_c, sigma stay within "
                                    "[v/(1+r), v (1+r)] of the configured v", ge=0.0, le=10.0)
    min_velocity_excitation: float = param(0.1, "rad/s", "rms endpoint velocity only b_e "
                                           "explains (over the memory) below which the "
                                           "adaptation stops", gt=0.0, le=100.0)
    min_position_excitation: float = param(0.02, "rad", "rms endpoint motion only k_e explains "
                                           "below which the adaptation stops", gt=0.0, le=10.0)

    def check_rules(self) -> None:
        if not self.position_max > self.position_min:
            raise InvalidParameterError("friction.position_max", self.position_max,
                                        f"> friction.position_min = {self.position_min:g} rad")


@group("commissioning")
class CommissioningParams(ParameterGroup):
    """The free-air excitation of commissioning (:mod:`seaforce_ros.commissioning.excitation`):
    a motor-torque log chirp with the endpoint free, its band, length and the bounds its
    online amplitude adaptation keeps."""

    duration: float = param(40.0, "s", "length of the excitation's chirp, fades included (the "
                            "rest phase comes before it)", ge=2.0, le=600.0)
    start_frequency: float = param(0.2, "Hz", "chirp start frequency (the start fade covers up "
                                   "to 1.5 times it)", gt=0.0, le=100.0)
    end_frequency: float = param(800.0, "Hz", "chirp end frequency (the end fade covers down to "
                                 "it / 1.5); below the Nyquist frequency", gt=0.0, le=1e4)
    rest_duration: float = param(0.5, "s", "servo-only rest before the chirp (the pressure "
                                 "noise and the free-air pressure force are measured there)",
                                 ge=0.05, le=10.0)
    position_min: float = param(-1.5, "rad", "lower end of the joint range the excitation "
                                "must stay in (beyond it: abort)", ge=-100.0, le=100.0)
    position_max: float = param(1.5, "rad", "upper end of the joint range the excitation must "
                                "stay in (> position_min)", ge=-100.0, le=100.0)
    max_speed: float = param(10.0, "rad/s", "motor speed |V| beyond which the excitation "
                             "aborts; its amplitude adaptation aims at 60 % of it (keep it "
                             "below the plant's max_velocity)", gt=0.0, le=100.0)
    max_torque: float = param(1.0, "N m", "bound of the excitation torque |F_a| (and never more "
                              "than the channel's max_torque)", gt=0.0, le=100.0)
    stiffness: float = param(0.1, "N m/rad", "centring servo stiffness on X - x_0 (weak: the "
                             "finger must move freely)", symbol="K_p", ge=0.0, le=10.0)
    damping: float = param(0.002, "N m s/rad", "centring servo damping on V", symbol="K_d",
                           ge=0.0, le=1.0)
    band_low: float = param(0.3, "rad/s", "lower end of the band the tuning widens the "
                            "predicted Z-width over", gt=0.0, le=1000.0)
    band_high: float = param(10.0, "rad/s", "upper end of that band (> band_low, below the "
                             "Nyquist frequency)", gt=0.0, le=6000.0)
    noise_budget: float = param(0.01, "N m", "largest RMS motor torque the tuned DOB may add "
                                "from the pressure and encoder noise (in dob: the "
                                "feed-forward's own noise is reported beside it)", gt=0.0,
                                le=10.0)
    passivity_margin: float = param(2.0, "-", "1-sigmas of the identified m, b, k against which "
                                    "the tuned DOB must still satisfy eq. 28", ge=0.0,
                                    le=10.0)

    def check_rules(self) -> None:
        if not self.band_high > self.band_low:
            raise InvalidParameterError("commissioning.band_high", self.band_high,
                                        f"> commissioning.band_low = {self.band_low:g} rad/s")
        if not self.position_max > self.position_min:
            raise InvalidParameterError("commissioning.position_max", self.position_max,
                                        f"> commissioning.position_min = "
                                        f"{self.position_min:g} rad")
        if not self.end_frequency > self.start_frequency:
            raise InvalidParameterError("commissioning.end_frequency", self.end_frequency,
                                        f"> commissioning.start_frequency = "
                                        f"{self.start_frequency:g} Hz")


@group("verification")
class VerificationParams(ParameterGroup):
    """Commissioning's verification of the feed-forward on the free finger
    (:mod:`seaforce_ros.commissioning.verification`): each candidate in turn, at rest and
    pulsed, at two points of the stroke; the most compensating one whose finger comes to rest
    is taken."""

    enabled: bool = param(True, "", "verify the candidates on the gripper before one is tuned "
                          "(false: the model's most cautious candidate, unverified)")
    settle_time: float = param(2.0, "s", "a candidate passes where the finger, pulsed, comes to "
                               "rest within this (each window lasts this and 0.5 s)", gt=0.0,
                               le=10.0)
    band: float = param(0.005, "rad", "... and then moves less than this over the window's "
                        "last 0.5 s (a creep or a ring fails it)", gt=0.0, le=0.1)
    speed: float = param(1.0, "rad/s", "the finger's speed each pulse aims at (its force, "
                         "held 80 ms, from the model's motor and endpoint inertia): a flick",
                         gt=0.0, le=5.0)
    offset: float = param(0.25, "rad", "distance of the second point from the rest position",
                          ge=0.0, le=1.0)
    candidates: int = param(3, "-", "most candidates tried (each about 16 s of rig time)",
                            ge=1, le=10)


@group("limits")
class LimitParams(ParameterGroup):
    """The joint range the controller keeps the finger in, in every mode that commands torque
    (:mod:`.safety`): a soft virtual wall inside each end, a latched fault beyond it."""

    position_min: float = param(-1.5, "rad", "lower end of the joint range (motor position X and "
                                "estimated endpoint X_e_hat); beyond it a mode that commands "
                                "torque latches a joint_limit fault", ge=-100.0, le=100.0)
    position_max: float = param(1.5, "rad", "upper end of the joint range (> position_min + 2 "
                                "wall_band)", ge=-100.0, le=100.0)
    wall_band: float = param(0.15, "rad", "width of the soft virtual wall inside each end of "
                             "the joint range", gt=0.0, le=10.0)
    wall_stiffness: float = param(4.0, "N m/rad", "stiffness of the walls (their spring force "
                                  "at the end of the range is wall_stiffness x wall_band)",
                                  symbol="K_w", ge=0.0, le=1e4)
    wall_damping: float = param(0.1, "N m s/rad", "damping of the walls, full from a quarter "
                                "of the band in (it must exceed the friction a feed-forward "
                                "could over-compensate)", symbol="B_w", ge=0.0, le=100.0)

    def check_rules(self) -> None:
        if not self.position_max - self.position_min > 2.0 * self.wall_band:
            raise InvalidParameterError(
                "limits.position_max", self.position_max,
                f"> limits.position_min + 2 limits.wall_band = "
                f"{self.position_min + 2.0 * self.wall_band:g} rad")


#: What a channel falls back to when the runaway monitor trips (``monitor.fallback``).
FALLBACK_MODES = ("dob", "passive")


@group("monitor")
class MonitorParams(ParameterGroup):
    """The runaway monitor (:mod:`.safety`): a finger the controller drives away, in a mode
    that runs the DOB, falls back to a safe mode until ``~/reset``."""

    max_speed: float = param(10.0, "rad/s", "speed of the motor or of the estimated endpoint "
                             "beyond which, in a mode that runs the DOB, the finger counts as "
                             "driven away", gt=0.0, le=1000.0)
    trip_time: float = param(0.005, "s", "how long the speed must stay beyond max_speed before "
                             "the fall-back (the reaction time is this plus one sample)",
                             ge=0.0, le=1.0)
    wall_energy: float = param(0.02, "J", "energy the joint walls may take out of the finger "
                               "within about 2 s (forgotten with that time constant) before "
                               "the finger counts as driven into them", gt=0.0, le=100.0)
    settle_time: float = param(6.0, "s", "how long a finger may keep moving in a feed-forward "
                               "mode before /diagnostics warns that, if nothing moves it, the "
                               "feed-forward over-compensates its friction (a flicked finger "
                               "whose feed-forward is right rests within a few seconds)",
                               gt=0.0, le=1e4)
    wall_time: float = param(2.0, "s", "how long the joint walls may hold the finger still in a "
                             "mode that runs the DOB before it counts as pushed onto them",
                             gt=0.0, le=1e4)
    fallback: str = param("dob", "", "what a channel the monitor trips on runs until ~/reset: "
                          "dob (the DOB without feed-forward; a trip in it falls back to "
                          "passive) or passive (zero torque)", choices=FALLBACK_MODES)


@group("passivity")
class GuardParams(ParameterGroup):
    """Time-domain passivity guard on the DOB's motor port (:mod:`.passivity_guard`)."""

    mode: str = param("disabled", "", "time-domain passivity guard on the motor port: "
                      "disabled; monitor (observe the port energy, add nothing); active (add "
                      "damping when it runs out: a DOB setting outside eq. 28 then needs no "
                      "allow_non_passive)", choices=GUARD_MODES, key="passivity_guard",
                      hint=GUARD_RENAMED)
    reserve: float = param(1e-3, "J", "the motor port's initial energy and the most credit the "
                           "guard keeps; damping starts below R/2", symbol="R", ge=1e-9,
                           le=1.0)
    max_damping: float = param(0.5, "N m s/rad", "largest damping the guard adds to the motor "
                               "port, reached at zero energy (passivates the DOB at every "
                               "frequency when >= lambda (m - m_n) - b, the high-frequency "
                               "deficit of eq. 25)", symbol="alpha_max", ge=0.0, le=100.0)
    velocity_deadband: float = param(0.0, "rad/s", "dead zone of the motor velocity the "
                                     "guard's damping acts on (a noisy velocity; a band leaves "
                                     "oscillations slower than it)", ge=0.0, le=100.0)
    release_time: float = param(5.0, "s", "time constant with which the guard releases "
                                "damping it no longer needs", symbol="tau_r", ge=1e-3, le=1e3)


def check_dob_passivity(plant: PlantParams, dob: DobParams) -> None:
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


def guard_carries(config: "ControllerConfig") -> str:
    """Why ``config`` (a validated :class:`ControllerConfig`) needs its passivity guard: the
    eq. 28 violation that ``passivity_guard: active`` let through without
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
        m_n = p.motor_inertia if dob.nominal_inertia is None else dob.nominal_inertia
        deficit = dob.cutoff * (p.motor_inertia - m_n) - p.motor_damping
        if deficit > 0.0:
            alpha = config.passivity.max_damping
            text += (f"; passivity.max_damping = {alpha:g} N m s/rad "
                     + ("covers" if alpha >= deficit else "is below (the guard may not hold "
                        "it in every contact)")
                     + f" the high-frequency deficit lambda (m - m_n) - b = {deficit:.4g}")
        return text
    return ""


@group("")
class ControllerConfig(ParameterGroup):
    """Everything one channel's controller needs: its mode, one of each parameter group
    (``plant``: the identified model -- the feed-forward uses b_e, k_e, b_s, k_s and the
    passivity check m, b, k; ``dob``: ``nominal_inertia=None`` becomes ``plant.motor_inertia``)
    and the rules between them (:meth:`check_rules`)."""

    mode: str = param("passive", "", "controller mode", choices=MODES, hint=MODE_RENAMED)
    plant: PlantParams = field(default_factory=PlantParams)
    plant_terms: PlantTermsParams = field(default_factory=PlantTermsParams)
    dahl: DahlParams = field(default_factory=DahlParams)
    dob: DobParams = field(default_factory=DobParams)
    target: TargetParams = field(default_factory=TargetParams)
    hold: HoldParams = field(default_factory=HoldParams)
    force_feedback: ForceFeedbackParams = field(default_factory=ForceFeedbackParams)
    chirp: ChirpParams = field(default_factory=ChirpParams)
    feedforward: FeedforwardParams = field(default_factory=FeedforwardParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    grasp: GraspParams = field(default_factory=GraspParams)
    friction: FrictionParams = field(default_factory=FrictionParams)
    commissioning: CommissioningParams = field(default_factory=CommissioningParams)
    verification: VerificationParams = field(default_factory=VerificationParams)
    passivity: GuardParams = field(default_factory=GuardParams)
    limits: LimitParams = field(default_factory=LimitParams)
    monitor: MonitorParams = field(default_factory=MonitorParams)
    pressure_offset: float = param(0.0, "N m", "what the pressure sensor reads with no force in "
                                   "the hose: the controller subtracts it from F_p (commissioning, "
                                   "~/calibrate_friction and ~/tare measure it)", ge=-10.0,
                                   le=10.0)
    max_torque: float = param(5.0, "N m", "the controller's fault limit: a computed |F_a| above "
                              "it latches a torque_limit fault (zero torque)", gt=0.0, le=1e3)
    allow_non_passive: bool = param(False, "", "accept DOB / force-feedback / impedance "
                                    "settings outside the passivity bounds (eq. 28), and a "
                                    "feed-forward without its margin")

    def __post_init__(self) -> None:
        if isinstance(self.dob, DobParams) and self.dob.nominal_inertia is None \
                and isinstance(self.plant, PlantParams):
            object.__setattr__(self, "dob", dataclasses.replace(
                self.dob, nominal_inertia=self.plant.motor_inertia))
        super().__post_init__()

    @classmethod
    def groups(cls) -> Tuple[Tuple[str, type], ...]:
        """``(attribute, group class)`` of the nested groups, in field order."""
        return _NESTED

    @classmethod
    def rows(cls) -> Tuple[Spec, ...]:
        """Every row of a channel, in field order (the order of :data:`PARAMETERS`)."""
        return _ROWS

    def check_rules(self) -> None:
        """The nested groups are of their types, the hose can be inverted, and -- unless
        ``allow_non_passive`` -- the DOB is passive (eq. 28; an active guard carries it), the
        impedance targets and the contact damping stay within what the hose allows, and K_f
        within -1..1."""
        for name, cls in _NESTED:
            if not isinstance(getattr(self, name), cls):
                raise InvalidParameterError(name, getattr(self, name), f"a {cls.__name__}")
        for name in ("hose_damping", "hose_stiffness"):
            value = getattr(self.plant, name)
            if not value > 0.0:
                raise InvalidParameterError("plant." + name, value, "> 0 and finite")
        terms = self.plant_terms
        k2, k3 = terms.stroke_asymmetry, terms.stroke_stiffness
        if k2 * k2 > 3.0 * self.plant.endpoint_stiffness * k3:
            raise InvalidParameterError(
                "plant_terms.stroke_asymmetry", k2,
                f"k_2^2 <= 3 k_e k_3 = {3.0 * self.plant.endpoint_stiffness * k3:.6g} "
                "(N m/rad^2)^2: else the diaphragm force falls somewhere along the stroke, and "
                "the feed-forward would push the finger there")
        self._check_ranges()
        if self.allow_non_passive:
            return
        self._check_feedforward_margin()
        if self.passivity.mode != "active":     # an active guard carries eq. 28
            check_dob_passivity(self.plant, self.dob)
        # impedance mode: ranges verified stable in simulation (Table I, endpoint free and
        # driven); the free endpoint went unstable at K_t ~ 2 k_s and at B_t ~ 25 b_s (V_e_hat
        # amplifies the pressure noise and the hose dynamics by B_t/b_s)
        if self.target.stiffness > self.plant.hose_stiffness:
            raise InvalidParameterError(
                "target.stiffness", self.target.stiffness,
                f"<= k_s = {self.plant.hose_stiffness:.6g} N m/rad (the hose stiffness; "
                "stiffer targets destabilise a free endpoint)", override="allow_non_passive")
        b_max = 10.0 * self.plant.hose_damping
        for name, value in (("target.damping", self.target.damping),
                            ("grasp.contact_damping", self.grasp.contact_damping)):
            if value > b_max:
                raise InvalidParameterError(
                    name, value, f"<= 10 b_s = {b_max:.6g} N m s/rad (the velocity estimate "
                    "amplifies pressure noise by 1/b_s)", override="allow_non_passive")
        gain = self.force_feedback.gain
        if not -1.0 <= gain <= 1.0:
            raise NonPassiveError("force_feedback.gain", gain,
                                  "-1 <= K_f <= 1 (Section III-A, internal force feedback of "
                                  "a series-elastic system)")

    def feedforward_friction(self) -> Tuple[float, float, DahlParams]:
        """What the feed-forward cancels: ``(b_e, k_e, Dahl)`` of the model each times its
        margin's scale (:meth:`FeedforwardParams.scales`), sigma times
        ``feedforward.dahl_stiffness_share`` too (:meth:`FeedforwardParams.dahl`). (The
        feed-forward modes also add ``feedforward.damping_reserve`` on the motor velocity.)"""
        sb, sk, _ = self.feedforward.scales()
        return (sb * self.plant.endpoint_damping, sk * self.plant.endpoint_stiffness,
                self.feedforward.dahl(self.dahl))

    def _check_ranges(self) -> None:
        """The motions of a calibration and of commissioning stay inside the joint range
        (``limits``), and the speeds a grasp or a gripper command asks for below the runaway
        monitor's ``monitor.max_speed``."""
        lim = self.limits
        for group in ("friction", "commissioning"):
            params = getattr(self, group)
            if params.position_min < lim.position_min:
                raise InvalidParameterError(
                    f"{group}.position_min", params.position_min,
                    f">= limits.position_min = {lim.position_min:g} rad (inside the joint "
                    "range)")
            if params.position_max > lim.position_max:
                raise InvalidParameterError(
                    f"{group}.position_max", params.position_max,
                    f"<= limits.position_max = {lim.position_max:g} rad (inside the joint "
                    "range)")
        speed = self.monitor.max_speed
        for name in ("max_closing_velocity", "gripper_velocity"):
            value = getattr(self.grasp, name)
            if not value < speed:
                raise InvalidParameterError(
                    f"grasp.{name}", value, f"< monitor.max_speed = {speed:g} rad/s (the "
                    "runaway monitor would stop the motion)")

    def _check_feedforward_margin(self) -> None:
        """The feed-forward's terms lie at least one uncertainty below the model, and no
        uncertainty claims an exact model: else a free finger whose friction is within the
        model's uncertainty may be active (net negative stiffness, damping or hysteresis)."""
        ff = self.feedforward
        if ff.dahl_stiffness_share > max(0.5, ff.verified_share):
            raise NonPassiveError(
                "feedforward.dahl_stiffness_share", ff.dahl_stiffness_share,
                f"<= {max(0.5, ff.verified_share):g} (cancelling more of the Dahl pre-sliding "
                "stiffness sigma through the loop's lag made a free finger oscillate in 24 of "
                "40 plants 20 % off; a share above 0.5 needs feedforward.verified_share: "
                "commissioning's verification on the gripper)")
        if ff.margin < 1.0:
            raise NonPassiveError(
                "feedforward.margin", ff.margin,
                ">= 1 (the feed-forward's b_e, k_e, sigma, F_c at least one uncertainty "
                "below the model: a free finger within it is not made active)")
        for name in ("damping_uncertainty", "stiffness_uncertainty", "dahl_uncertainty",
                     "stroke_uncertainty"):
            value = getattr(ff, name)
            if value < MIN_UNCERTAINTY:
                raise NonPassiveError(
                    f"feedforward.{name}", value,
                    f">= {MIN_UNCERTAINTY:g} (no identified model is exact; an uncertainty "
                    "below it lets the feed-forward cancel more friction than the finger may "
                    "have)")

    def replace(self, **changes: Any) -> "ControllerConfig":
        """Validated copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    # -- flat ROS-style dictionaries -------------------------------------
    def to_dict(self) -> Dict[str, Any]:
        """Flat ``{key: value}`` (the keys of :data:`PARAMETERS`, relative to
        ``<channel>.``)."""
        out = {}
        for owner, spec in _OWNED:
            value = getattr(getattr(self, owner) if owner else self, spec.attribute)
            out[spec.name] = value if isinstance(value, (str, bool)) or spec.type is int \
                else float(value)
        return out

    @classmethod
    def from_dict(cls, values: Mapping[str, Any],
                  base: Optional["ControllerConfig"] = None) -> "ControllerConfig":
        """A validated config from flat keys, the others from ``base`` (default:
        ``ControllerConfig()``). Keys are those of :data:`PARAMETERS`, optionally prefixed by
        ``<channel>.`` (stripped when the rest is a known key); an unknown key or a bad value
        raises :class:`InvalidParameterError` naming it. Without ``base`` an unset
        ``dob.nominal_inertia`` is the given plant's motor inertia (its documented default);
        with one it keeps the base's value."""
        fresh = base is None
        base = cls() if base is None else base
        nested: Dict[str, Dict[str, Any]] = {name: {} for name, _ in _NESTED}
        if fresh:
            nested["dob"]["nominal_inertia"] = None     # resolved from the plant given
        own: Dict[str, Any] = {}
        for raw_key, value in values.items():
            key = raw_key
            if key not in _BY_KEY and "." in key and key.split(".", 1)[1] in _BY_KEY:
                key = key.split(".", 1)[1]
            if key not in _BY_KEY:
                raise InvalidParameterError(raw_key, value, "a known key: "
                                            + ", ".join(_BY_KEY))
            owner, spec = _BY_KEY[key]
            (nested[owner] if owner else own)[spec.attribute] = spec.coerce(value)
        replaced = {name: dataclasses.replace(getattr(base, name), **nested[name])
                    for name, _ in _NESTED if nested[name]}
        return dataclasses.replace(base, **replaced, **own)



def settable_order(base: ControllerConfig, values: Mapping[str, Any]) -> Optional[List[str]]:
    """An order of ``values``' keys (flat, as :meth:`ControllerConfig.from_dict` takes them)
    in which setting them one at a time from ``base`` passes the channel's checks at every
    step -- what ``ros2 param load`` does: one set per value, each validated as a whole
    configuration (eq. 28 between ``plant.*`` and ``dob.*``) -- or None when there is none
    and only an atomic set of all of them gets there.

    Greedy: at each step the first key (in ``values``' order) whose set is accepted."""
    order: List[str] = []
    left = dict(values)
    current = base
    while left:
        for key, value in left.items():
            try:
                current = ControllerConfig.from_dict({key: value}, base=current)
            except SeaforceError:
                continue
            order.append(key)
            del left[key]
            break
        else:
            return None
    return order

#: ``(attribute, class)`` of ControllerConfig's nested groups, in field order.
_NESTED = tuple((f.name, type(f.default_factory())) for f in dataclasses.fields(ControllerConfig)
                if f.default_factory is not dataclasses.MISSING)
_OWN = {spec.attribute: spec for spec in ControllerConfig.SPECS}
#: ``(owner attribute or '', Spec)`` of every row of a channel, in field order.
_OWNED = tuple(
    pair for f in dataclasses.fields(ControllerConfig)
    for pair in ((("", _OWN[f.name]),) if f.name in _OWN else
                 tuple((f.name, spec) for spec in dict(_NESTED)[f.name].SPECS)))
_ROWS = tuple(spec for _, spec in _OWNED)
_BY_KEY = {spec.name: (owner, spec) for owner, spec in _OWNED}

#: Every per-channel controller parameter: flat key -> :class:`~.schema.Spec`, in the order
#: a node declares them. The ROS descriptors, ranges, the flat-dict conversions and the
#: generated reference all derive from these rows.
PARAMETERS: Dict[str, Spec] = {spec.name: spec for spec in _ROWS}

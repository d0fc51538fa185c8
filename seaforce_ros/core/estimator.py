"""Online contact detection and object impedance estimation, from motor state and pressure only.

The paper's future work (Section VI): estimate the environment impedance continuously -- here
the stiffness and damping of a grasped object -- with nothing but the motor position X, the
hose pressure force F_p and the model.

Signals (motor frame). The controller's hose inversion gives the endpoint position X_e_hat
(eq. 29, :mod:`.controller`) and the Dahl force F_d. The external force follows from the
endpoint model::

    F_e_hat = m_e A_e_hat + b_e V_e_hat + k_e (X_e_hat - rest) + F_d + F_p

Every signal is seen through one second-order state-variable filter
``H(s) = w^2 / (s^2 + 2 zeta w s + w^2)`` (Butterworth, ``w = 2 pi filter_cutoff``, exact
discretisation for an input held over each sample period): its two states are ``H X_e_hat``
and ``s H X_e_hat`` (a filtered position and an exact filtered velocity), ``s^2 H X_e_hat`` is
the mean slope of the second over the last period (half a sample late: nothing at a grasp's
frequencies), so no noisy signal is differentiated; ``H (F_p + F_d)`` is a second filter with
the same coefficients. Filtering both sides of a linear relation with the same ``H`` keeps the
relation and removes the pressure noise and the hose mode (173 rad/s).

Contact detection: the residual ``r = H F_e_hat - bias``, where ``bias`` tracks ``H F_e_hat``
while there is no contact (the model's error in free motion: a 15 % wrong model leaves ~0.01
N m) with a critically damped second-order tracker (bias and drift: the error drifts with the
distance travelled, k_e's error times it, and a steady drift leaves no lag) whose time
constant is ``baseline_time`` or the time to travel ``baseline_distance``, whichever is
shorter (a fast finger's error drifts fast; a contact's force rises with the distance too, so
the distance decides what is absorbed: an object softer than about ``e contact_threshold /
baseline_distance``, ~0.04 N m/rad). The detection sees ``d``, ``r`` smoothed with the time
constant :data:`DETECT_TIME` (3 ms): ``r``'s sample-to-sample noise is the m_e acceleration
term's (``s^2 H`` passes noise up to the Nyquist frequency with the gain ``m_e w^2``, 0.5 mN m
rms with the simulated sensors; ``d``: 0.15-0.3 mN m). The threshold adapts to the noise: in
free motion the mean ``m`` of ``d`` and its rms deviation ``sigma_d`` are tracked (time
constant :data:`SPREAD_TIME`) and a contact starts when ``|d - m| > clamp(SPREAD_FACTOR
sigma_d, FLOOR_FRACTION contact_threshold, contact_threshold)`` or ``|d| > contact_threshold``
(5 sigma_d, at least 1 mN m, at most 3 mN m by default; the first threshold after a reset, a
:meth:`ContactEstimator.rearm` or a :meth:`ContactEstimator.let_go` is the largest: a new
motion's model error is measured anew; :meth:`ContactEstimator.rearm_at_rest` re-arms once a
coasting finger has stopped). A smaller fixed threshold would not do: the rms
grows with the speed and the model's error. A contact ends when ``d`` (in the contact's
direction) stays below half the threshold it started with for :data:`LOSS_TIME` (samples
below it are not fitted). The contact position is where the
filtered endpoint was at the start (the filter delays position and force alike), replaced by
the fit's ``x_c`` once the stiffness is reported. The model's error depends on the direction of
motion (the Dahl force's error flips): a contact is only ended reliably by a residual that
falls below half the threshold, so a grasp :meth:`ContactEstimator.freeze` s the estimator
while it lets go and declares the contact over with :meth:`ContactEstimator.let_go`.

Fit: exponentially weighted least squares (recursive least squares with forgetting, kept in
information form) of the Kelvin-Voigt object ``F_e = -(k_o (X_e - x_c) + b_o V_e)``, plus an
inertia term that absorbs the error of m_e (at a few Hz m_e w^2 is as large as a soft
object's stiffness)::

    -H(F_p + F_d) = (k_o + k_e) H X_e + (b_o + b_e) s H X_e + (m_x + m_e) s^2 H X_e + c

It starts :data:`_SETTLE_DELAYS` filter group delays after the contact starts (the filters
then hold no free-motion samples). A regressor that never varied (a press at constant speed:
no acceleration, no velocity change) leaves its term out rather than the whole fit.

Why least squares with forgetting and not a Kalman filter: the object does not change during a
grasp (there is no process model to give a Kalman filter), the dominant error is the plant
model's bias, not white noise (so a Kalman filter's noise model would be wrong and its
covariance no honest 1-sigma), and the information form costs little per sample -- the samples
are kept and the products of :data:`BLOCK` of them formed in one numpy call -- and solves the
4x4 normal equations only when an estimate is read. Forgetting (time constant
``forgetting_time``) acts only on blocks in which the finger moved: information is never lost
while the finger is still, so a held object keeps its estimate and the information matrix
cannot wind up.

Excitation: the part of the endpoint motion that only the stiffness (the damping) can
explain, as an rms over the forgetting time: ``sqrt(T / (forgetting_time [G^-1]_kk))``. No
stiffness (damping) is reported below ``min_position_excitation`` (``min_velocity_excitation``):
NaN instead, never a guess.

1-sigma: the statistical part (residual variance times ``[G^-1]_ii``, the samples counted per
correlation time of the filter) plus the model part, the sensitivities of the estimates to a
relative error ``model_uncertainty`` (u) of: k_e and b_e (in the regression they shift k_o and
b_o one to one); the hose k_s and b_s (the object hides behind the hose: the estimator sees
``W_hat = W/(1 - W delta(s))``, ``W = k_o + k_e + s (b_o + b_e)``, ``delta`` the error of the
modelled hose compliance; the truth is recovered at the corners k_s (1 +- u), b_s (1 +- u)
and the largest change taken -- one-sided, and unbounded for an object as stiff as the hose:
:func:`_hose_sensitivity`); and the Dahl force (regressed on the fit's regressors).
"""

import math
import struct
from collections import namedtuple

import numpy as np
import scipy.linalg

from .params import EstimatorParams, PlantParams, PlantTermsParams

__all__ = ["ContactEstimator", "ObjectEstimate", "NO_ESTIMATE", "BLOCK", "LOSS_TIME",
           "DETECT_TIME", "SPREAD_FACTOR", "SPREAD_TIME", "FLOOR_FRACTION", "QUIET_GAP",
           "QUIET_TIME", "REST_SPEED", "REST_TIME", "REST_TIMEOUT",
           "svf_coefficients"]

#: A contact ends when the residual stays below half the threshold this long [s].
LOSS_TIME = 0.02
#: Averaging time of the residual a re-captured bias takes [s].
RECENT = 0.02
#: Time constant of the first-order smoothing of the residual the contact detection sees [s]
#: (it removes the sample-to-sample noise of the m_e acceleration term).
DETECT_TIME = 0.003
#: The contact threshold is this many times the detection residual's rms about its mean in
#: free motion ...
SPREAD_FACTOR = 5.0
#: ... both measured with this time constant [s] ...
SPREAD_TIME = 0.25
#: ... and never below this fraction of ``contact_threshold`` (nor above it).
FLOOR_FRACTION = 1.0 / 3.0
#: A gap of more than this many sample periods between two updates (lost states), or a
#: :meth:`ContactEstimator.disturb` (the plant replaced the torque), starts a quiet period:
#: the inputs interpolated over a longer gap, or a torque the model did not see, are no
#: sample of the endpoint's force.
QUIET_GAP = 20
#: The quiet period [s]: the filters settle (about four group delays) -- no contact starts,
#: none ends, nothing is fitted, and the free-motion statistics and bias stay as they were
#: (the smoothed residuals run on: a re-arm after it takes the settled part).
QUIET_TIME = 0.03
#: :meth:`ContactEstimator.rearm_at_rest`: the finger is at rest when the filtered endpoint
#: speed stays below this [rad/s] ...
REST_SPEED = 0.05
#: ... for this long [s] ...
REST_TIME = 0.1
#: ... or, at the latest, this long after the call [s] (a finger that does not come to rest:
#: re-armed on its motion then).
REST_TIMEOUT = 2.0
#: Outside a job a contact that has stood this long [s] with the finger still (filtered
#: endpoint speed below :data:`REST_SPEED`) is the model's error at rest, not an object: the
#: controller re-arms the estimator (:meth:`ChannelController.update
#: <seaforce_ros.core.controller.ChannelController.update>`).
STANDING_TIME = 2.0
#: Samples accumulated per block of the fit (one numpy outer product per block).
BLOCK = 128
_BLOCK_VALUES = 6 * BLOCK
#: A block's values as C doubles in one call: the fold's array is a view of them
#: (``np.fromiter`` converts a list one item at a time through the iterator protocol: twice the
#: time, about 0.04 us more per sample in contact; the doubles, so the products, are the same).
_PACK_BLOCK = struct.Struct(f"{_BLOCK_VALUES}d").pack
_ZETA = math.sqrt(0.5)
#: A filtered signal needs this many group delays after the start of a contact before it
#: holds no free-motion samples; the fit starts then.
_SETTLE_DELAYS = 4.0
_NAN = math.nan

ObjectEstimate = namedtuple(
    "ObjectEstimate", "stiffness stiffness_sigma damping damping_sigma contact_position "
                      "position_excitation velocity_excitation")
ObjectEstimate.__doc__ = """The fit's object (NaN where not excited enough; see module docstring).

stiffness, stiffness_sigma : k_o and its 1-sigma [N m/rad]
damping, damping_sigma : b_o and its 1-sigma [N m s/rad]
contact_position : x_c [rad] (the fit's when the stiffness is reported, else where the
    contact started; NaN before any contact)
position_excitation : rms endpoint motion only k_o explains [rad]
velocity_excitation : rms endpoint velocity only b_o explains [rad/s]
"""

NO_ESTIMATE = ObjectEstimate(_NAN, _NAN, _NAN, _NAN, _NAN, 0.0, 0.0)


def svf_coefficients(cutoff: float, dt: float) -> tuple[float, float, float, float, float, float]:
    """The state-variable filter ``H(s) = w^2/(s^2 + 2 zeta w s + w^2)`` (Butterworth, ``w =
    2 pi cutoff``, ``cutoff`` in Hz) discretised exactly for an input held over ``dt`` [s]:
    ``(a11, a12, b1, a21, a22, b2)`` of ``p' = a11 p + a12 q + b1 u``, ``q' = a21 p + a22 q +
    b2 u``, with ``p = H u`` and ``q = s H u``."""
    w = 2.0 * math.pi * cutoff
    a_c = np.array([[0.0, 1.0, 0.0], [-w * w, -2.0 * _ZETA * w, w * w], [0.0, 0.0, 0.0]])
    e = scipy.linalg.expm(a_c * dt)
    return (float(e[0, 0]), float(e[0, 1]), float(e[0, 2]),
            float(e[1, 0]), float(e[1, 1]), float(e[1, 2]))


class ContactEstimator:
    """Contact detection and object stiffness/damping of one channel (see module docstring).

    Parameters
    ----------
    params : EstimatorParams
    plant : PlantParams
        The model: m_e, b_e, k_e of the endpoint, k_s, b_s of the hose.
    dt : float > 0
        Sample period [s].
    rest_position : float
        Where k_e is relaxed [rad].

    Attributes (updated by every :meth:`update`)
    ----------------------------------------------
    contact : bool
    direction : int
        +1 while something pushes the endpoint towards -X_e (an object at the closing side of
        a positive closing velocity), -1 for the other side, 0 without contact.
    force : float
        The residual ``r`` [N m]: the external force estimate less the free-motion bias.
    position, velocity : float
        Filtered X_e_hat [rad] and V_e_hat [rad/s].
    detection : float
        The residual ``d`` the detection sees: ``force`` smoothed over :data:`DETECT_TIME`
        [N m].
    detection_mean : float
        Its mean in free motion [N m] (held during a contact).
    bias : float
        The free-motion bias of the external force estimate [N m] (the model's error while
        nothing touches; frozen during a contact).
    onset_position : float
        Filtered endpoint position where the latest contact started [rad] (NaN before one).
    contacts : int
        Number of contacts started since the last reset.
    quiet : bool
        This sample was no sample of the force: within :data:`QUIET_TIME` after a gap of
        more than :data:`QUIET_GAP` samples or a :meth:`disturb` (no contact started or
        ended, nothing fitted, the free-motion statistics and bias left as they were).
    """

    # slots: more than 30 attributes would leave the instance's dict unshared (CPython 3.11),
    # every attribute access in update a hashed look-up (about 15 % of its time)
    __slots__ = (
        # configuration (configure)
        "dt", "params", "plant", "_rest", "_stroke", "_coef", "_be", "_ke", "_model", "_rate_time",
        "_rate_distance", "_on", "_settle", "_loss_samples", "_quiet_samples", "_rest_samples",
        "_rest_timeout", "_recent_alpha", "_detect_alpha", "_spread_alpha", "_ceiling2",
        "_factor2", "_floor2", "_block_decay", "_moving", "_kappa",
        # the filters and the residual
        "_first", "_x_in", "_g_in", "position", "velocity", "_f1", "_f2", "force", "bias",
        "_drift", "_recent", "detection", "detection_mean", "_spread2", "_on2", "_release",
        # contact and quiet periods
        "contact", "direction", "_side", "onset_position", "_onset_before", "contacts",
        "_frozen", "_quiet", "quiet", "_settling", "_at_rest", "_skip", "_below",
        # the fit
        "_stats", "_cache", "_S", "_block", "_filled", "_p0")

    def __init__(self, params: EstimatorParams | None = None, plant: PlantParams | None = None,
                 dt: float = 5e-4, rest_position: float = 0.0,
                 terms: PlantTermsParams | None = None) -> None:
        self.dt = float(dt)
        self.configure(EstimatorParams() if params is None else params,
                       PlantParams.table_i() if plant is None else plant, rest_position,
                       terms)
        self.reset()

    def configure(self, params: EstimatorParams, plant: PlantParams,
                  rest_position: float = 0.0, terms: PlantTermsParams | None = None
                  ) -> None:
        """New parameters (validated), effective now; the state is kept. ``terms``: the
        model's nonlinear terms (``plant_terms``), whose stroke force ``k_2 u^2 + k_3 u^3``
        (``u = X_e - rest``) the residual takes off like the linear k_e's (else the stroke's
        ends look like a push)."""
        if not isinstance(params, EstimatorParams) or not isinstance(plant, PlantParams):
            raise TypeError("params must be EstimatorParams and plant PlantParams")
        self.params = params
        self.plant = plant
        self._rest = float(rest_position)
        self._stroke = ((terms.stroke_asymmetry, terms.stroke_stiffness)
                        if terms is not None and terms.stroke else None)
        w = 2.0 * math.pi * params.filter_cutoff
        dt = self.dt
        self._coef = svf_coefficients(params.filter_cutoff, dt)
        self._be, self._ke = plant.endpoint_damping, plant.endpoint_stiffness
        # y = f1 + k_e (p - rest) + b_e q + m_e (q - q_prev)/T, constants folded
        self._model = (self._ke, self._be, plant.endpoint_inertia, self._ke * self._rest,
                       1.0 / dt)
        self._rate_time = dt / params.baseline_time             # per sample
        self._rate_distance = dt / params.baseline_distance     # per rad/s, per sample
        self._on = params.contact_threshold
        self._settle = int(math.ceil(_SETTLE_DELAYS * 2.0 * _ZETA / (w * dt)))
        self._loss_samples = max(1, int(round(LOSS_TIME / dt)))
        self._quiet_samples = max(1, int(round(QUIET_TIME / dt)))
        self._rest_samples = max(1, int(round(REST_TIME / dt)))
        self._rest_timeout = max(1, int(round(REST_TIMEOUT / dt)))
        self._recent_alpha = -math.expm1(-dt / RECENT)
        self._detect_alpha = -math.expm1(-dt / DETECT_TIME)
        self._spread_alpha = -math.expm1(-dt / SPREAD_TIME)
        self._ceiling2 = self._on * self._on
        self._factor2 = SPREAD_FACTOR * SPREAD_FACTOR
        self._floor2 = (FLOOR_FRACTION * self._on) ** 2
        self._block_decay = math.exp(-BLOCK * dt / params.forgetting_time)
        self._moving = params.min_velocity_excitation ** 2
        # samples of the filtered residual per independent sample (its correlation time)
        self._kappa = max(1.0, 1.0 / (2.0 * params.filter_cutoff * dt))

    def reset(self) -> None:
        """Forget everything: no contact, no fit; the next :meth:`update` starts the filters
        from its sample."""
        self._first = True
        self._x_in = self._g_in = 0.0   # the previous X_e_hat and F_p + F_d (lost samples)
        self.contact = False
        self.direction = 0
        self._side = 0.0
        self.force = 0.0
        self.position = 0.0
        self.velocity = 0.0
        self.onset_position = self._onset_before = _NAN
        self.contacts = 0
        self._f1 = self._f2 = 0.0
        self.bias = 0.0
        self._drift = 0.0            # the bias's drift per sample [N m]
        self._recent = 0.0           # the residual averaged over RECENT s
        self.detection = 0.0
        # the detection residual's mean and SPREAD_FACTOR^2 times its mean square deviation
        # in free motion (the first threshold is the largest), the threshold squared, the
        # release level negated (d * side above it is below the level; kept negated, not
        # negated per sample)
        self.detection_mean = 0.0
        self._spread2 = self._ceiling2
        self._on2 = self._ceiling2
        self._release = -(0.5 * self._on)
        self._frozen = False         # between freeze() and let_go()
        self._quiet = 0              # samples still to be skipped (QUIET_TIME's)
        self.quiet = False           # this sample was skipped
        self._settling = False       # rearm_at_rest(): quiet until the finger is at rest
        self._at_rest = 0            # ... samples in a row below REST_SPEED
        self._clear_fit()

    def _clear_fit(self) -> None:
        # (S 6x6, p0, bias) published at each fold: read atomically
        self._stats: tuple[np.ndarray, float, float] | None = None
        # (stats, contacts, ObjectEstimate) of the last estimate()
        self._cache: tuple[tuple | None, int, ObjectEstimate] | None = None
        self._S = np.zeros((6, 6))
        # x - p0, q, a, 1, z, F_d of each sample since the last fold: the first _filled values
        # (the 1 of every sample written here, once)
        self._block = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0] * BLOCK
        self._filled = 0
        self._skip = 0
        self._below = 0              # samples in a row below the release level
        self._p0 = 0.0

    def rearm(self) -> None:
        """Declare the present motion free: the residual of the last :data:`RECENT` s becomes
        the free-motion bias and a contact the residual may have started is dropped with its
        fit (a finger that has just started moving: its model error changes faster than the
        baseline tracks). It ends a :meth:`rearm_at_rest` still waiting for rest: the caller
        says the motion is free now."""
        self.stop_settling()
        if self.contact:
            self.contact = False
            self.direction = 0
            self.contacts -= 1
            self.onset_position = self._onset_before
            self._clear_fit()
        self._take_bias()

    def _take_bias(self) -> None:
        """The residual's recent mean (not one noisy sample) becomes part of the bias; the
        residual's spread is measured anew (the largest threshold first): a new motion's
        model error is not the last one's."""
        recent = self._recent
        self.bias += recent
        self.force -= recent
        self.detection -= recent
        self.detection_mean = 0.0
        self._spread2 = self._on2 = self._ceiling2
        self._recent = 0.0
        self._drift = 0.0

    def freeze(self) -> None:
        """Stop fitting and detecting (the fit stays as it is): a grasp letting go of its
        object. The unloading and the finger's motion after it would be fitted with the bias
        of the approach, which the motion's direction changes (the Dahl model's error)."""
        if not self._frozen:
            self._frozen = True
            if self._filled:
                self._fold()

    def let_go(self) -> None:
        """End a :meth:`freeze`: the contact, if any, is over (its fit is kept) and the recent
        residual is the free-motion bias."""
        self._frozen = False
        if self.contact:
            self.contact = False
            self.direction = 0
        self._take_bias()

    def rearm_at_rest(self) -> None:
        """:meth:`rearm` once the finger has come to rest: a job that moved the finger fast
        ended (canceled mid-chirp, the finger coasts on). A contact the residual started is
        dropped now; until the filtered endpoint speed has stayed below :data:`REST_SPEED` for
        :data:`REST_TIME` (or :data:`REST_TIMEOUT` has passed) the samples are quiet (no
        contact starts); then the residual at rest becomes the bias. A re-arm while the finger
        still moved took the coasting's residual for the bias: when it stopped, the
        difference, the model's error times the deceleration, started a contact that its
        offset at rest then kept (a 0.7x..1.4x model: in 11 of 12 cancels)."""
        self.rearm()
        self._settling = True
        self._at_rest = 0
        self._quiet = max(self._quiet, self._rest_timeout)
        self.quiet = True

    def stop_settling(self) -> None:
        """End a :meth:`rearm_at_rest` still waiting for rest (a new job takes the channel:
        its own arming declares the motion free); the estimator works again at once."""
        if self._settling:
            self._settling = False
            self._quiet = 0

    def disturb(self) -> None:
        """The plant replaced the torque for a while (a command timeout, its fault): the
        residual holds a force the model did not see until the filters have settled -- the
        next :data:`QUIET_TIME` of samples are quiet, as after a gap of lost states."""
        self._quiet = self._quiet_samples
        self.quiet = True

    @property
    def threshold(self) -> float:
        """The contact threshold in force [N m] (adapted in free motion; see module
        docstring)."""
        return math.sqrt(self._on2)

    # --- per sample -----------------------------------------------------------------------
    def update(self, xe: float, fp: float, fd: float, steps: int = 1) -> None:
        """One sample: estimated endpoint position X_e_hat [rad], pressure force F_p [N m],
        Dahl force F_d [N m]; ``steps`` sample periods since the previous one (the inputs
        are interpolated linearly over them, as the hose inversion and the friction fit do: held
        at the new value, a motion's ramp becomes a step that the filter's acceleration and
        the residual see as a force -- a late loop's lost samples made contacts in free
        motion).

        Allocates nothing that outlives the call (a fit's block is a preallocated list, folded
        into the information matrix every :data:`BLOCK` samples)."""
        g = fp + fd
        if self._stroke is not None:
            k2, k3 = self._stroke
            u = xe - self._rest
            g += u * u * (k2 + k3 * u)
        if self._first:
            self._start(xe, g)
        q0 = self.velocity
        ke, be, me, ke_rest, inv_dt = self._model
        if steps == 1:
            a11, a12, b1, a21, a22, b2 = self._coef
            p = self.position
            f1 = self._f1
            f2 = self._f2
            p, q = a11 * p + a12 * q0 + b1 * xe, a21 * p + a22 * q0 + b2 * xe
            f1, f2 = a11 * f1 + a12 * f2 + b1 * g, a21 * f1 + a22 * f2 + b2 * g
            acc = (q - q0) * inv_dt
            recent_alpha = self._recent_alpha
            detect_alpha = self._detect_alpha
        else:
            p, q, f1, f2 = self._filter_steps(xe, g, steps)
            acc = (q - q0) * inv_dt / steps
            recent_alpha = 1.0 - (1.0 - self._recent_alpha) ** steps
            detect_alpha = 1.0 - (1.0 - self._detect_alpha) ** steps
        self._x_in = xe
        self._g_in = g
        self.position = p
        self.velocity = q
        self._f1 = f1
        self._f2 = f2
        r = f1 + ke * p - ke_rest + be * q + me * acc - self.bias
        self.force = r
        recent = self._recent
        self._recent = recent + recent_alpha * (r - recent)
        d = self.detection
        d += detect_alpha * (r - d)
        self.detection = d
        if steps > QUIET_GAP or self._quiet:
            self._go_quiet(steps)
            if self._settling:
                self._settle_step(q, steps)
        elif self._frozen:
            self.quiet = False
        elif self.contact:
            self.quiet = False
            if d * self._side > self._release or self._skip:
                self._in_contact(d, steps)
            else:
                # a sample of the object (the most frequent case in contact: in line)
                if self._below:
                    self._below = 0
                block = self._block
                k = self._filled
                block[k] = p - self._p0
                block[k + 1] = q
                block[k + 2] = acc
                block[k + 4] = -f1
                block[k + 5] = fd
                k += 6
                self._filled = k
                if k == _BLOCK_VALUES:
                    self._fold()
        else:
            self.quiet = False
            # free motion: a contact starts when d leaves its free-motion mean by more than
            # the threshold (or exceeds contact_threshold)
            excess = d - self.detection_mean
            excess2 = excess * excess
            on2 = self._on2
            ceiling2 = self._ceiling2
            if excess2 > on2 or d * d > ceiling2:
                self._start_contact(excess if excess2 > on2 else d, p)
                return
            # else the mean and spread of d follow it (kept as SPREAD_FACTOR^2 times the mean
            # square deviation: the threshold squared before its bounds) ...
            a = self._spread_alpha if steps == 1 else min(1.0, self._spread_alpha * steps)
            self.detection_mean += a * excess
            on2 = self._spread2
            on2 += a * (self._factor2 * excess2 - on2)
            self._spread2 = on2
            floor2 = self._floor2
            self._on2 = floor2 if on2 < floor2 else (ceiling2 if on2 > ceiling2 else on2)
            # ... and so does a critically damped tracker of the bias and its drift (a slowly
            # changing model error, k_e's for one, drifts with the position: no lag on a
            # steady drift), at the rate of baseline_time or of baseline_distance travelled,
            # whichever is faster
            w = self._rate_distance * (q if q > 0.0 else -q)
            rate_time = self._rate_time
            if w < rate_time:
                w = rate_time
            drift = self._drift
            if steps == 1:
                self.bias += drift + 2.0 * w * r
            else:
                w *= steps
                self.bias += drift * steps + 2.0 * w * r
            self._drift = drift + w * w * r

    def _start(self, xe: float, g: float) -> None:
        """The first sample after a reset starts the filters at rest at it."""
        self._first = False
        self.position, self.velocity, self._f1, self._f2 = xe, 0.0, g, 0.0
        self.bias = g + self._ke * (xe - self._rest)
        self._x_in, self._g_in = xe, g

    def _filter_steps(self, xe: float, g: float, steps: int) -> tuple[float, float, float, float]:
        """Both filters over ``steps`` periods, their inputs interpolated linearly from the
        previous sample's to ``xe`` and ``g``: ``(H X_e, s H X_e, H g, s H g)``."""
        a11, a12, b1, a21, a22, b2 = self._coef
        p, q, f1, f2 = self.position, self.velocity, self._f1, self._f2
        x0, g0 = self._x_in, self._g_in
        dx, dg = (xe - x0) / steps, (g - g0) / steps
        for k in range(1, steps + 1):
            xk, gk = x0 + k * dx, g0 + k * dg
            p, q = a11 * p + a12 * q + b1 * xk, a21 * p + a22 * q + b2 * xk
            f1, f2 = a11 * f1 + a12 * f2 + b1 * gk, a21 * f1 + a22 * f2 + b2 * gk
        return p, q, f1, f2

    def _go_quiet(self, steps: int) -> None:
        """A gap or a torque the model did not see: nothing starts, ends, is fitted or
        tracked until the filters have settled (this sample, then QUIET_TIME's)."""
        if steps > QUIET_GAP:
            self._quiet = self._quiet_samples
        else:
            self._quiet = self._quiet - steps if self._quiet > steps else 0
        self.quiet = True
        self._below = 0

    def _settle_step(self, q: float, steps: int) -> None:
        """A quiet sample of :meth:`rearm_at_rest`: the re-arm when the finger has been at
        rest long enough or the time-out has run out."""
        self._at_rest = self._at_rest + steps if -REST_SPEED < q < REST_SPEED else 0
        if self._at_rest >= self._rest_samples or not self._quiet:
            self._settling = False
            self._quiet = 0
            self.rearm()

    def _in_contact(self, d: float, steps: int) -> None:
        """A sample in contact that is no sample of the object (:meth:`update` puts those in
        the fit's block): the contact ends when ``d`` stays below the release level; the first
        samples after its start are skipped (the filters still hold free motion)."""
        if d * self._side > self._release:
            # below the release level: not a sample of the object; the contact ends when
            # that lasts (noise on a light touch must not end it)
            self._below += steps
            if self._below >= self._loss_samples:
                self._end_contact()
        else:
            self._skip -= 1
            self._below = 0

    def _start_contact(self, excess: float, p: float) -> None:
        """A contact starts at the filtered endpoint position ``p``; ``excess`` < 0: something
        pushes towards -X_e."""
        self.contact = True
        self.direction = 1 if excess < 0.0 else -1
        self._side = float(self.direction)      # (d * side: a product of two floats)
        self._release = -(0.5 * math.sqrt(self._on2))
        self._onset_before = self.onset_position
        self.onset_position = p
        self.contacts += 1
        self._clear_fit()
        self._p0 = p
        self._skip = self._settle
        self._below = 0

    def _end_contact(self) -> None:
        if self._filled:
            self._fold()
        self.contact = False
        self.direction = 0

    def _fold(self) -> None:
        """Add the block's cross products to the information matrix (forgetting the old ones
        if the finger moved in the block) and publish a consistent snapshot."""
        filled = self._filled
        n = filled // 6
        x = np.frombuffer(_PACK_BLOCK(*self._block), float, filled).reshape(n, 6)
        self._filled = 0
        block = x.T @ x
        if block[1, 1] > self._moving * n:
            self._S = self._S * self._block_decay ** (n / BLOCK) + block
        else:
            self._S = self._S + block
        self._stats = (self._S, self._p0, self.bias)

    # --- reading ----------------------------------------------------------------------------
    def estimate(self) -> ObjectEstimate:
        """The object's :class:`ObjectEstimate` from the fit so far (the latest contact's, also
        after it ended); NaN where the excitation is too small. Safe to call from another
        thread than :meth:`update`'s (it reads one snapshot); recomputed only when a block has
        been added since the last call."""
        stats, contacts, onset = self._stats, self.contacts, self.onset_position
        cached = self._cache
        if cached is not None and cached[0] is stats and cached[1] == contacts:
            return cached[2]
        result = self._solve(stats, onset)
        self._cache = (stats, contacts, result)
        return result

    def _solve(self, stats: tuple | None, onset: float) -> ObjectEstimate:
        unknown = NO_ESTIMATE._replace(contact_position=onset)
        if stats is None:
            return unknown
        S, p0, bias = stats
        S = S.tolist()
        if S[3][3] <= 8.0:
            return unknown
        # all four regressors; without the acceleration (a press at a constant speed); without
        # the velocity too: a regressor that never varied leaves its term out, not everything
        for used in ((0, 1, 2, 3), (0, 1, 3), (0, 3)):
            small = _spd_inverse([[S[i][j] for j in used] for i in used])
            if small is not None:
                break
        else:
            return unknown
        inverse = [[0.0] * 4 for _ in range(4)]
        for a, i in enumerate(used):
            for c, j in enumerate(used):
                inverse[i][j] = small[a][c]
        weight = S[3][3]
        h = [S[i][4] for i in range(4)]
        hd = [S[i][5] for i in range(4)]
        theta = [sum(inverse[i][j] * h[j] for j in range(4)) for i in range(4)]
        dahl = [sum(inverse[i][j] * hd[j] for j in range(4)) for i in range(2)]
        rss = max(S[4][4] - sum(theta[i] * h[i] for i in range(4)), 0.0)
        variance = self._kappa * rss / max(weight - len(used), 1.0)
        p = self.params
        u = p.model_uncertainty
        ke, be = self._ke, self._be
        ks, bs = self.plant.hose_stiffness, self.plant.hose_damping
        k = theta[0] - ke
        b = theta[1] - be
        samples = p.forgetting_time / self.dt
        exc_k = math.sqrt(1.0 / (samples * inverse[0][0]))
        exc_b = math.sqrt(1.0 / (samples * inverse[1][1])) if inverse[1][1] > 0.0 else 0.0
        hose_k, hose_b = _hose_sensitivity(k + ke, b + be, ks, bs, u)
        stiffness = sigma_k = damping = sigma_b = _NAN
        position = onset
        if exc_k >= p.min_position_excitation:
            stiffness = k
            sigma_k = math.sqrt(variance * inverse[0][0] + (u * ke) ** 2 + hose_k ** 2
                                + (u * dahl[0]) ** 2)
            if k != 0.0:
                position = ((k + ke) * p0 - bias - ke * self._rest - theta[3]) / k
        if exc_b >= p.min_velocity_excitation:
            damping = b
            sigma_b = math.sqrt(variance * inverse[1][1] + (u * be) ** 2 + hose_b ** 2
                                + (u * dahl[1]) ** 2)
        return ObjectEstimate(stiffness, sigma_k, damping, sigma_b, position, exc_k, exc_b)


def _hose_sensitivity(stiffness: float, damping: float, ks: float, bs: float,
                      u: float) -> tuple[float, float]:
    """Largest change of the estimated k_o + k_e and b_o + b_e (``stiffness``, ``damping``)
    when the true hose is k_s (1 +- u), b_s (1 +- u) instead of the model's ``ks``, ``bs``.

    The estimator sees the endpoint through the modelled hose: with the compliance error
    ``delta = 1/ks - 1/k_s`` and ``dtau = bs/ks^2 - b_s/k_s^2`` it reports
    ``K_hat = K/(1 - K delta)`` and ``B_hat = B/(1 - K delta)^2 + K^2 dtau`` for the true
    ``K = k_o + k_e``, ``B = b_o + b_e``; inverted at the four corners. A stiff object whose
    corner has ``1 + K_hat delta <= 0`` cannot be told from a rigid one: inf."""
    worst_k = worst_b = 0.0
    for ks_true in (ks * (1.0 - u), ks * (1.0 + u)):
        delta = 1.0 / ks - 1.0 / ks_true
        denominator = 1.0 + stiffness * delta
        if denominator <= 0.0:
            return math.inf, math.inf
        true_k = stiffness / denominator
        for bs_true in (bs * (1.0 - u), bs * (1.0 + u)):
            dtau = bs / ks ** 2 - bs_true / ks_true ** 2
            true_b = (damping - true_k ** 2 * dtau) * (1.0 - true_k * delta) ** 2
            worst_b = max(worst_b, abs(true_b - damping))
        worst_k = max(worst_k, abs(true_k - stiffness))
    return worst_k, worst_b


def _spd_inverse(a: list[list[float]], rcond: float = 1e-12) -> list[list[float]] | None:
    """Inverse of the symmetric positive definite matrix ``a`` (list of lists), or None when it
    is (numerically) singular: a regressor that never varied independently of the others.
    Scaled to unit diagonal, Cholesky-factored (a pivot below ``rcond`` means singular),
    inverted from the factor."""
    n = len(a)
    scale = []
    for i in range(n):
        if not a[i][i] > 0.0:
            return None
        scale.append(1.0 / math.sqrt(a[i][i]))
    low = [[0.0] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            value = a[i][j] * scale[i] * scale[j] - sum(low[i][m] * low[j][m] for m in range(j))
            if i == j:
                if not value > rcond:
                    return None
                low[i][i] = math.sqrt(value)
            else:
                low[i][j] = value / low[j][j]
    inv_low = [[0.0] * n for _ in range(n)]             # L^-1, lower triangular
    for i in range(n):
        inv_low[i][i] = 1.0 / low[i][i]
        for j in range(i):
            inv_low[i][j] = -sum(low[i][m] * inv_low[m][j] for m in range(j, i)) / low[i][i]
    return [[scale[i] * scale[j] * sum(inv_low[m][i] * inv_low[m][j] for m in range(max(i, j), n))
             for j in range(n)] for i in range(n)]

"""A grasp: close until contact, squeeze to a grip force, probe, hold; release on request.

:class:`Grasp` decides, per sample, the endpoint force ``F_g`` [N m] the channel's controller
renders through the DOB on top of the endpoint friction feed-forward (``F_ref = F_cmp + F_d
+ F_g``: the minimum-impedance mode ``dob_full_ff`` plus a force): ``F_g`` is what the finger
pushes the object with. Plain Python with explicit state, no ROS; the contact and the object
come from :class:`~.estimator.ContactEstimator`. Signs: ``s = sign(closing_velocity)``; the
finger closes towards ``s X_e`` and pushes with the contact force ``f`` (``F_g = s f``), the
object pushes back with ``F_e = -s c`` (``c`` the contact force estimate, > 0).

Phases:

* ``approach`` -- a PI speed servo ``F_g = clamp(B (v_cmd - V_e) + I, +-approach_force)``,
  ``I' = B w_i (v_cmd - V_e)`` (``w_i`` = :data:`APPROACH_INTEGRAL`; ``I`` clamped to the same
  bounds and held while the output is at a bound, so the acceleration does not wind it up):
  the finger moves at the commanded speed in its minimum-impedance mode, the integral
  takes up what the friction model misses, and it never pushes harder than
  ``approach_force`` (it feels the object instead of hitting it). ``B`` sets the loop's
  cross-over ``B/(m_n + m_e)``, well below the DOB's lambda and the estimator's filter. The
  contact detection is armed once the finger moves steadily -- beyond the Dahl transition
  (:data:`ARM_DAHL` F_c/sigma of travel: the hysteresis model's error changes until then) and
  for :data:`ARM_TIME` within 15 % (or :data:`STEADY_SPEED`) of the commanded speed (the
  model's error changes with the speed) -- when the estimator's bias is re-captured. Before
  that, a contact on the closing side while the servo pushes towards it with all of
  ``approach_force`` is the object's when the finger is held up (after :data:`ARM_TIME_MAX`,
  for :data:`ARM_TIME` slower than a quarter of the commanded speed: a finger the friction
  model's error holds up is freed before the servo's integral gets there) or bounces back
  after it closed at half the commanded speed (a finger pushed towards the object cannot
  move away by itself): it started touching the object, or met one nearer than it needs to
  arm (``v_cmd`` x ~0.15 s). A contact on the closing side ends the approach (from the other
  side it aborts). No contact within ``max_travel`` (or
  ``2 max_travel/|v_cmd| + 1 s``): aborted. Goals slower than :data:`MIN_CLOSING_VELOCITY`
  are refused.
* ``contact`` -- ``f = approach_force`` for :data:`CONTACT_TIME` (the touch settles).
* ``squeeze`` -- ``f`` ramps (raised cosine) to ``grip_force`` in ``squeeze_time``.
* ``probe`` (if the goal asks for it) -- ``f = grip_force + A w(t) sin(phi(t))``, a log chirp
  from ``probe_start_frequency`` to ``probe_end_frequency`` in ``probe_duration`` under a
  raised-cosine window w; ``A = min(probe_amplitude grip_force, (max_force - grip_force)/2)``
  (the probe uses at most half of the head-room to ``max_force``).
* ``hold`` -- ``f = grip_force`` until the goal is released.

In every contact phase the finger may travel at most ``give_way_travel`` past the point where
the contact was detected; in ``hold`` the contact force estimate may fall below
:data:`SLIP_FRACTION` of the held grip (its average) for at most :data:`SLIP_TIME` of samples
(those seen: after lost states one sample is one; none while the estimator is quiet; a
creeping soft object's force only rises towards the grip). Beyond either the object gave way -- it
slipped out, was pulled out, broke -- and the grip would drive a free finger: the grasp
aborts and drops the push at once. The estimator's own end of the contact may come late
then: a free finger driven by the grip moves at ``grip_force/contact_damping``, and the
model's error in b_e times that speed looks like a contact force (15 % of b_e: ~6 % of the
grip).

From ``contact`` on, ``F_g = s f - bias - B_c V_e_hat``: the estimator's free-motion bias (the
friction model's error, measured while approaching) is commanded away, so the real contact
force is ``f`` despite the model's error, and ``B_c = contact_damping`` damps the contact (a
pure force source against a stiff object rings, the more so with a wrong model; a soft object
settles with ``(b_o + B_c)/k_o``).

* ``release`` -- ``F_g`` ramps to zero in ``release_time`` (a cancel, or an abort: the
  estimated contact force beyond ``max_force``, no contact found; at once when the object is
  gone: the contact lost, the travel or slip limits above), then
  stays zero, the contact damper still on, until the object has relaxed: the finger is still
  (the filtered V_e below :data:`STILL_SPEED` for :data:`STILL_TIME`) or :data:`RELAX_TIMES`
  time constants ``(b_o + B_c)/k_o`` of the estimated object have passed (a finger at minimum
  impedance creeps at the friction model's error over ``B_c``; :data:`RELAX_TIME` without an
  estimate, :data:`RELAX_TIME_MAX` at most); then the grasp is ``done`` and the controller
  returns to the mode the channel had before, bumplessly from a torque that holds no grip and
  no push-back (a ``hold`` entered straight from the ramp would capture the object's
  push-back as its bias). The estimator's fit is frozen meanwhile (the release is not a
  sample of the object) and the contact declared over at the end.

The commanded contact force ``f`` never leaves ``[0, max_force]`` in any phase (the approach's
push never exceeds ``approach_force``). :meth:`Grasp.abort_now` ends a grasp at once (the
cycle has already zeroed the torque: a fault or a re-initialisation); nothing is commanded
after it.

A grasp is a :class:`~.jobs.Job` (an :data:`~.jobs.ENDPOINT_FORCE` one: ``F_g``), which
gives it its threads: the cycle thread runs :meth:`Grasp.update` (through
:meth:`Grasp.step`), :meth:`~.jobs.Job.claim` (when it takes the grasp over) and
:meth:`Grasp.abort_now`; another thread (the action server) may call
:meth:`Grasp.request_release` (its :meth:`~.jobs.Job.request_cancel`) and
:meth:`~.jobs.Job.request_abort` (taken at the next sample) and :meth:`~.jobs.Job.withdraw`
(effective only if the cycle has not claimed it yet: a grasp whose goal gave up waiting never
starts later) and reads the attributes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .jobs import ENDPOINT_FORCE, InvalidJobGoalError, Job, JobSample
from .params import MIN_CLOSING_VELOCITY, ControllerConfig, EstimatorParams, GraspParams
from .signals import faded_log_chirp

if TYPE_CHECKING:
    from .estimator import ContactEstimator, ObjectEstimate

__all__ = ["GraspGoal", "Grasp", "InvalidGoalError", "check_goal", "PHASES", "ARM_TIME",
           "STEADY_SPEED", "ARM_DAHL", "ARM_TIME_MAX", "CONTACT_TIME", "APPROACH_INTEGRAL",
           "STILL_SPEED", "STILL_TIME", "RELAX_TIMES", "RELAX_TIME", "RELAX_TIME_MAX",
           "SLIP_FRACTION", "SLIP_TIME", "MIN_CLOSING_VELOCITY"]

#: Phases in order; ``done`` after the release.
PHASES = ("approach", "contact", "squeeze", "probe", "hold", "release", "done")

ARM_TIME = 0.05        # s within 15 % of the commanded speed before the detection is armed
STEADY_SPEED = MIN_CLOSING_VELOCITY    # rad/s: ... or within this much of it (a slow one)
ARM_DAHL = 4.0         # F_c/sigma of travel before it is armed (the Dahl transition)
ARM_TIME_MAX = 0.5     # s after which a finger blocked by a contact started touching it
CONTACT_TIME = 0.03    # s the touch force is held before the squeeze
APPROACH_INTEGRAL = 10.0   # rad/s, corner of the approach servo's integral action
STILL_SPEED = 0.02     # rad/s: after the release ramp the finger is still below this ...
STILL_TIME = 0.02      # s ... for this long, or the object's relaxation is over:
RELAX_TIMES = 5.0      # its time constants (b_o + B_c)/k_o ...
RELAX_TIME = 0.5       # s without an estimate of the object,
RELAX_TIME_MAX = 5.0   # s at most
SLIP_FRACTION = 0.3    # in hold, a contact force estimate below this part of the held grip ...
SLIP_TIME = 0.01       # s ... for this long: the object gave way (slipped out, was pulled out)
_HOLD_AVERAGE = 0.1    # s, time constant of the grip force average in hold


class InvalidGoalError(InvalidJobGoalError):
    """A grasp goal that cannot be executed; the message says why."""


class GraspGoal:
    """The fields of a ``seaforce_msgs/action/Grasp`` goal.

    Parameters
    ----------
    channel : str
    closing_velocity : float
        [rad/s]; the finger closes towards +X_e when positive.
    grip_force : float
        Contact force to hold [N m].
    max_force : float
        Abort limit of the contact force [N m].
    probe : bool
        Probe the object (force oscillation) after the squeeze.
    """

    __slots__ = ("channel", "closing_velocity", "grip_force", "max_force", "probe")

    def __init__(self, channel: str, closing_velocity: float, grip_force: float,
                 max_force: float, probe: bool = True) -> None:
        self.channel = channel
        self.closing_velocity = closing_velocity
        self.grip_force = grip_force
        self.max_force = max_force
        self.probe = probe

    def __repr__(self) -> str:
        return (f"GraspGoal(channel={self.channel!r}, closing_velocity="
                f"{self.closing_velocity!r}, grip_force={self.grip_force!r}, "
                f"max_force={self.max_force!r}, probe={self.probe!r})")


def check_goal(goal: GraspGoal, params: GraspParams, estimator: EstimatorParams,
               max_torque: float) -> None:
    """Raise :class:`InvalidGoalError` naming the field and the bound if ``goal`` cannot be
    executed on a channel with these :class:`GraspParams`, :class:`EstimatorParams` and
    ``max_torque`` [N m]."""
    if not isinstance(params, GraspParams) or not isinstance(estimator, EstimatorParams):
        raise TypeError("params must be GraspParams and estimator EstimatorParams")
    for name in ("closing_velocity", "grip_force", "max_force"):
        value = getattr(goal, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise InvalidGoalError(f"{name} = {value!r}: must be a finite number")
    if not isinstance(goal.probe, bool):
        raise InvalidGoalError(f"probe = {goal.probe!r}: must be a bool")
    v = goal.closing_velocity
    if not MIN_CLOSING_VELOCITY <= abs(v) <= params.max_closing_velocity:
        raise InvalidGoalError(
            f"closing_velocity = {v!r} rad/s: |closing_velocity| must be within "
            f"{MIN_CLOSING_VELOCITY:g} (slower, the approach's arming cannot tell the speed "
            f"from the friction model's error) and grasp.max_closing_velocity = "
            f"{params.max_closing_velocity:g} rad/s")
    if not goal.grip_force > estimator.contact_threshold:
        raise InvalidGoalError(
            f"grip_force = {goal.grip_force!r} N m: must be > estimator.contact_threshold = "
            f"{estimator.contact_threshold:g} N m (a lighter grip is no contact)")
    if not goal.max_force >= goal.grip_force:
        raise InvalidGoalError(f"max_force = {goal.max_force!r} N m: must be >= grip_force = "
                               f"{goal.grip_force!r} N m")
    if not goal.max_force > params.approach_force:
        raise InvalidGoalError(f"max_force = {goal.max_force!r} N m: must be > "
                               f"grasp.approach_force = {params.approach_force:g} N m (the "
                               "force of the first touch)")
    if goal.max_force > max_torque:
        raise InvalidGoalError(f"max_force = {goal.max_force!r} N m: must be <= the channel's "
                               f"max_torque = {max_torque:g} N m")


class Grasp(Job):
    """One grasp goal on one channel (see module docstring): a job whose output is the
    endpoint force ``F_g`` [N m].

    Parameters
    ----------
    goal : GraspGoal
        Already checked (:func:`check_goal`).
    config : ControllerConfig
        The channel's: its ``grasp`` parameters and its Dahl model (``dahl``).
    dt : float > 0
        Sample period [s].

    Attributes
    ----------
    phase : str
        One of :data:`PHASES`.
    outcome : str or None
        None until the grasp is ``done``, then ``'canceled'`` (released on request) or
        ``'aborted'`` (with the reason in ``message``).
    message : str
        Why it ended (or what it is doing).
    force_command : float
        The contact force commanded, signed: ``s f`` [N m] (the approach servo's force in
        ``approach``); never beyond ``max_force``.
    contact : bool
        A contact was found (stays True after it).
    contact_time : float
        Time of the contact's detection since the grasp started [s] (NaN before).
    grip_force : float
        Contact force estimate averaged in ``hold`` [N m] (NaN before hold).
    estimate : ObjectEstimate or None
        The object, as the estimator had it when the grasp let go (set when a grasp that
        found a contact ends, by its release or an abort; None otherwise).
    """

    kind = "grasp"
    output = ENDPOINT_FORCE

    def __init__(self, goal: GraspGoal, config: ControllerConfig, dt: float = 5e-4) -> None:
        super().__init__()
        self.goal = goal
        self.params = params = config.grasp
        dahl = config.dahl
        self._arm_travel = (ARM_DAHL * dahl.coulomb_force / dahl.sigma
                            if dahl.sigma > 0.0 else 0.0)
        self.dt = float(dt)
        v = float(goal.closing_velocity)
        self._sign = 1.0 if v > 0.0 else -1.0
        self._v = v
        self._grip = float(goal.grip_force)
        self._max = float(goal.max_force)
        self._touch = min(params.approach_force, self._grip)
        self._amp = (min(params.probe_amplitude * self._grip, 0.5 * (self._max - self._grip))
                     if goal.probe else 0.0)
        self._max_travel = params.max_travel
        self._timeout = 2.0 * params.max_travel / abs(v) + 1.0
        self._damping = params.contact_damping
        self._give_way = params.give_way_travel
        self._hold_command = self._sign * self._grip
        self.phase = "approach"
        self.outcome = None
        self.message = "approaching"
        self.force_command = 0.0
        self._output = 0.0         # the last F_g [N m]
        self._pushed = 0.0         # ... without the contact damper
        self.contact = False
        self.contact_time = math.nan
        self.grip_force = math.nan
        self.estimate: ObjectEstimate | None = None
        self._t = 0.0              # time in the phase [s] (approach: since the start)
        self._armed = False
        self._steady = 0.0         # time within 15 % of the approach speed, or still [s]
        self._slow = 0.0           # time below a quarter of the approach speed [s]
        self._integral = 0.0       # the approach servo's integral action [N m]
        self._at_cap = False       # ... and its output at approach_force towards the object
        self._closed = False       # the finger has moved towards the object at v_cmd/2
        self._start: float | None = None    # filtered endpoint position at the start
        self._contact_at = math.nan    # ... and at the contact's detection
        self._slip = 0.0           # time the hold's contact force has been below the slip level
        self._release_from = 0.0     # F_g and the commanded contact force when the release began
        self._release_contact = 0.0
        self._pending_outcome: str | None = None
        self._release_request: str | None = None
        self._relax: float | None = None    # (release) how long the object may take
        self._estimator: ContactEstimator | None = None   # the channel's, from the contact on
        self._hold_alpha = -math.expm1(-self.dt / _HOLD_AVERAGE)

    # --- requests (the rest is the job's: :class:`~.jobs.Job`) -----------------------------
    def request_release(self, reason: str = "released") -> None:
        """(any thread) Release at the next sample: ramp down, then ``canceled``."""
        self._release_request = reason

    #: A grasp's cancel is its release.
    request_cancel = request_release

    def release(self, reason: str = "released", outcome: str = "canceled",
                drop: bool = False) -> None:
        """Ramp the force to zero (``drop``: at once -- nothing holds the finger back any more),
        then end with ``outcome`` and ``reason`` (no effect once releasing or done)."""
        if self.phase in ("release", "done"):
            return
        self._pending_outcome = outcome
        self.message = reason
        self._release_from = 0.0 if drop else self._pushed
        self._release_contact = 0.0 if drop else self.force_command
        self._steady = 0.0
        self._relax = None          # how long the object may take (at the ramp's end)
        self._enter("release")

    def abort_now(self, reason: str, estimate: ObjectEstimate | None = None) -> None:
        """(cycle thread) End at once, commanding nothing more (the cycle zeroes the torque,
        or re-initialises the controller, right after). A grasp that found a contact keeps
        the object as ``estimate`` has it, or else as the estimator it measured the object
        with has it now (the cycle resets the estimator after this)."""
        if self.phase == "done":
            return
        self.outcome = "aborted"
        self.message = reason
        if self.contact:
            if estimate is None and self._estimator is not None:
                estimate = self._estimator.estimate()
            if estimate is not None:
                self.estimate = estimate
        self.force_command = self._output = self._pushed = 0.0
        self._enter("done")

    def wind_down(self, reason: str) -> bool:
        """(cycle thread) The mode changed: release (ramp down, aborted with ``reason``)."""
        self.release(reason, "aborted")
        return True

    @property
    def free_motion(self) -> bool:
        """The approach: the finger moves free (the friction adaptation may fit it)."""
        return self.phase == "approach"

    @property
    def armed(self) -> bool:
        """The approach's contact detection is armed (the finger moves steadily)."""
        return self._armed

    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        """``phase``, ``endpoint_position`` [rad], ``force`` (the contact force estimate, > 0
        pushing back) [N m], ``object_stiffness`` [N m/rad] and ``object_damping``
        [N m s/rad] (NaN before this grasp's contact: the estimator still has the last
        object's fit)."""
        estimate = estimator.estimate()
        return {"phase": self.phase, "endpoint_position": estimator.position,
                "force": -self._sign * estimator.force,
                "object_stiffness": estimate.stiffness if self.contact else math.nan,
                "object_damping": estimate.damping if self.contact else math.nan}

    def _enter(self, phase: str) -> None:
        self.phase = phase
        self._t = 0.0

    # --- per sample -------------------------------------------------------------------
    def step(self, sample: JobSample) -> float:
        """(cycle thread) :meth:`update` on the channel's sample: ``F_g`` [N m]."""
        return self.update(sample.estimator, sample.endpoint_velocity, sample.steps)

    def update(self, est: ContactEstimator, ve: float, steps: int = 1) -> float:
        """Advance ``steps`` samples; returns ``F_g`` [N m]. ``est`` is the channel's
        :class:`~.estimator.ContactEstimator`, already updated with this sample, ``ve`` the
        controller's endpoint velocity estimate V_e_hat [rad/s] (undelayed).

        Stages: the requests from other threads; the clock; then the phase's stage -- a
        steady hold (the common case, kept short), the release, done, the approach, or a
        contact phase (the object checked, the contact force of the phase, the command). A
        stage that releases the grasp runs the release at once, on this sample (``steps``
        0: no time passes twice)."""
        if self._abort_request is not None or self._release_request is not None:
            self._take_requests(est)
        self._t += self.dt * steps
        phase = self.phase
        if phase == "hold" and est.contact:
            output = self._hold_steady(est, ve, steps)
            if output is not None:
                return output
        if phase == "release":
            return self._release_step(est, ve, steps)
        if phase == "done":
            self.force_command = self._output = self._pushed = 0.0
            return 0.0
        if phase == "approach":
            f = self._approach(est, self._sign, steps)
            if self.phase == "approach":
                self.force_command = self._output = self._pushed = f
                return f
            if self.phase == "release":
                return self.update(est, ve, 0)
            phase = "contact"
        if self._object_gone(est, phase):
            return self.update(est, ve, 0)
        force = self._phase_force(est, phase, steps)
        if force is None:
            return self.update(est, ve, 0)
        return self._command(force, est, ve)

    def _take_requests(self, est: ContactEstimator) -> None:
        """The abort and the release requested from another thread since the last sample."""
        if self._abort_request is not None:
            self.abort_now(self._abort_request, est.estimate() if self.contact else None)
        if self._release_request is not None:
            self.release(self._release_request)
            self._release_request = None

    def _hold_steady(self, est: ContactEstimator, ve: float, steps: int) -> float | None:
        """``hold`` with a contact force within the slip level and ``max_force``, the
        estimator not quiet and the finger within ``give_way_travel``: the grip, its average
        updated; F_g [N m]. None when a check fails (the contact stage decides)."""
        s = self._sign
        c = -s * est.force
        grip = self.grip_force
        if SLIP_FRACTION * grip <= c <= self._max and not est.quiet and \
                s * (est.position - self._contact_at) <= self._give_way:
            self._slip = 0.0
            self.grip_force = grip + self._hold_alpha * steps * (c - grip)
            pushed = self._hold_command - est.bias
            self._pushed = pushed
            self._output = output = pushed - self._damping * ve
            return output
        return None

    def _release_step(self, est: ContactEstimator, ve: float, steps: int) -> float:
        """``release``: F_g ramps to zero in ``release_time`` (at once if the object gave way
        meanwhile), the damper on; then done once the finger is still or the object has
        relaxed. The estimator's fit is frozen meanwhile and the contact declared over at the
        end."""
        est.freeze()
        if (self._release_from or self._release_contact) and self._gave_way(est):
            # the object gave way while the force ramped down: nothing pushes any more
            self._release_from = self._release_contact = 0.0
        ramp = self.params.release_time
        scale = 1.0 - self._t / ramp
        if scale <= 0.0:
            scale = 0.0
            if self._relax is None:
                self._relax = self._relax_time(est)
            if abs(est.velocity) < STILL_SPEED:
                self._steady += self.dt * steps
            else:
                self._steady = 0.0
            if self._steady >= STILL_TIME or self._t >= ramp + self._relax:
                if self.contact:
                    self.estimate = est.estimate()    # the fit, frozen since the release
                est.let_go()
                self.force_command = self._output = 0.0   # released: nothing remains
                self._released(est)
                return 0.0
        self.force_command = self._release_contact * scale
        # the damper stays: the object unloads the finger gently (a finger at minimum
        # impedance let go of a squeezed object would fly open)
        self._output = self._release_from * scale - self._damping * ve
        return self._output

    def _released(self, est: ContactEstimator) -> None:
        """The release is over (the force ramped down, the object relaxed): done, with the
        outcome the release was begun with."""
        self.outcome = self._pending_outcome
        self._enter("done")

    def _object_gone(self, est: ContactEstimator, phase: str) -> bool:
        """A contact phase's checks of the object: the contact lost, the finger past the
        contact by more than ``give_way_travel``, the contact force estimate beyond
        ``max_force``. True when one failed: the grasp is released (aborted)."""
        if not est.contact:
            self.release(f"contact lost at {est.position:.4g} rad in {phase}", "aborted",
                         drop=True)
            return True
        s = self._sign
        if self._gave_way(est):
            # the object gave way (or was taken away) and the contact estimate still sees
            # one: the model's error at the speed the grip drives a free finger to (first:
            # a force estimate this far past the contact is no object to ramp down from)
            travel = s * (est.position - self._contact_at)
            self.release(f"the finger went {travel:.3g} rad past the contact in {phase} "
                         f"(grasp.give_way_travel {self._give_way:g} rad): the object gave "
                         f"way, or is too soft for this grip",
                         "aborted", drop=True)
            return True
        c = -s * est.force                 # contact force estimate, > 0 pushing back
        if c > self._max and not est.quiet:    # (quiet: no sample of it; f stays bounded)
            self.release(f"contact force estimate {c:.4g} N m beyond max_force "
                         f"{self._max:g} N m in {phase}", "aborted")
            return True
        return False

    def _phase_force(self, est: ContactEstimator, phase: str, steps: int) -> float | None:
        """The contact force f [N m] of a contact phase (``contact``, ``squeeze``, ``probe``,
        ``hold``), moving on to the next phase when this one is over. None when the object
        slipped in ``hold`` (the grasp is released, aborted)."""
        c = -self._sign * est.force        # contact force estimate, > 0 pushing back
        t = self._t
        if phase == "contact":
            if t >= CONTACT_TIME:
                self._enter("squeeze")
            return self._touch
        if phase == "squeeze":
            x = min(1.0, t / self.params.squeeze_time)
            f = self._touch + (self._grip - self._touch) * (0.5 - 0.5 * math.cos(math.pi * x))
            if x >= 1.0 and self._amp > 0.0:
                self._enter("probe")
                self.message = "probing"
            elif x >= 1.0:
                self._enter_hold(c, est)
                self.message = "holding"
            return f
        if phase == "probe":
            f = self._grip + self._amp * self._probe(t)
            if t >= self.params.probe_duration:
                self._enter_hold(c, est)
                self.message = "holding"
            return f
        if est.quiet:   # hold, quiet: the force estimate is no sample of the object (lost
            self._slip = 0.0    # states, a plant stop, after which the grip comes back)
            return self._grip
        # hold, when the steady stage did not decide
        grip = self.grip_force
        if c < SLIP_FRACTION * grip:
            # a creeping soft object's force only rises towards the grip; this one fell
            # (counted over the samples seen: one after a gap is one sample of it)
            self._slip += self.dt
            if self._slip >= SLIP_TIME:
                self.release(f"the object gave way in hold: contact force estimate "
                             f"{c:.3g} N m, held {grip:.3g} N m", "aborted", drop=True)
                return None
        else:
            self._slip = 0.0
        self.grip_force = grip + self._hold_alpha * steps * (c - grip)
        return self._grip

    def _command(self, f: float, est: ContactEstimator, ve: float) -> float:
        """F_g [N m] for the contact force ``f`` (bounded to ``[0, max_force]``): the
        estimator's free-motion bias commanded away, the contact damper on."""
        s = self._sign
        f = min(max(f, 0.0), self._max)
        self.force_command = s * f
        # the model's free-motion error (the estimator's bias) shifts the real contact force:
        # command it away; the damper keeps a stiff contact from ringing
        self._pushed = s * f - est.bias
        self._output = self._pushed - self._damping * ve
        return self._output

    def _gave_way(self, est: ContactEstimator) -> bool:
        """The finger is more than give_way_travel past the contact point, towards the
        object (False before a contact: ``_contact_at`` is NaN)."""
        return self._sign * (est.position - self._contact_at) > self._give_way

    def _enter_hold(self, c: float, est: ContactEstimator) -> None:
        self._enter("hold")
        # the average starts from the force estimate, or from the grip commanded when the
        # estimate is no sample of the object (a quiet estimator)
        self.grip_force = self._grip if est.quiet else c
        self._slip = 0.0

    def _approach(self, est: ContactEstimator, s: float, steps: int) -> float:
        """``approach``: the servo's force [N m], or the phase changes (contact, release)."""
        if self._start is None:
            self._start = est.position
        travel = s * (est.position - self._start)
        if est.quiet:
            # lost states or a plant stop: the motion the bias was captured in was
            # interrupted, the servo's push may not have been applied -- arm again once the
            # finger moves steadily (or is held up, or bounces back) after it
            self._armed = self._closed = False
            self._steady = self._slow = 0.0
        elif not self._armed:
            self._arm(est, s, steps, travel)
        if self._armed and est.contact:
            self._touched(est, s)
            return 0.0
        if travel > self._max_travel or self._t > self._timeout:
            self.release(f"no contact within {travel:.3g} rad of travel in {self._t:.2f} s "
                         f"(grasp.max_travel {self._max_travel:g} rad)", "aborted")
            return 0.0
        return self._servo(est, s, steps)

    def _arm(self, est: ContactEstimator, s: float, steps: int, travel: float) -> None:
        """Arm the contact detection once the finger moves steadily past the Dahl transition
        (the estimator's bias re-captured), or when a contact on the closing side holds up or
        bounces back a finger the servo pushes with all it may."""
        elapsed = self.dt * steps
        if abs(est.velocity - self._v) <= max(0.15 * abs(self._v), STEADY_SPEED):
            self._steady += elapsed
        else:
            self._steady = 0.0
        speed = abs(self._v)
        if abs(est.velocity) < 0.25 * speed:
            self._slow += elapsed
        else:
            self._slow = 0.0
        if s * est.velocity >= 0.5 * speed:
            self._closed = True
        if self._steady >= ARM_TIME and travel >= self._arm_travel:
            est.rearm()
            self._armed = True
        elif self._at_cap and est.contact and est.direction * s > 0 and (
                (self._t >= ARM_TIME_MAX and self._slow >= ARM_TIME)
                or (self._closed and s * est.velocity < -max(0.25 * speed, STEADY_SPEED))):
            # a contact on the closing side before the finger could arm, the servo
            # pushing towards it with all it may: the finger is held up (it started
            # touching the object, or met one before it moved steadily), or it bounced
            # back off one (a closing finger pushed on towards the object cannot move
            # away by itself) -- that is the contact
            self._armed = True

    def _touched(self, est: ContactEstimator, s: float) -> None:
        """An armed approach meets a contact: ``contact`` on the closing side, released
        (aborted) from the other."""
        if est.direction * s < 0:
            self.release("pushed from the side away from the object: no grasp", "aborted")
            return
        self.contact = True
        self._estimator = est
        self.contact_time = self._t
        self._contact_at = est.position
        self.message = "contact"
        self._enter("contact")

    def _servo(self, est: ContactEstimator, s: float, steps: int) -> float:
        """The approach's PI speed servo, bounded to +-approach_force [N m] (the integral
        held while the output is at a bound: no wind-up)."""
        p = self.params
        cap = p.approach_force
        error = p.approach_damping * (self._v - est.velocity)
        i = self._integral
        f = error + i
        if -cap < f < cap:          # integrate only while not saturated (no wind-up)
            i += error * APPROACH_INTEGRAL * self.dt * steps
            self._integral = cap if i > cap else (-cap if i < -cap else i)
            f = error + self._integral
        f = cap if f > cap else (-cap if f < -cap else f)
        self._at_cap = s * f >= cap
        return f

    def _relax_time(self, est: ContactEstimator) -> float:
        """How long the object may take to push the finger back after the release ramp:
        RELAX_TIMES time constants ``(b_o + B_c)/k_o`` of the estimated object (RELAX_TIME
        without an estimate), at most RELAX_TIME_MAX. Waiting for a finger at minimum
        impedance to come to rest is not enough: the friction model's error keeps a free one
        creeping at ``error/B_c``."""
        if not self.contact:
            return RELAX_TIME
        e = est.estimate()
        k, b = e.stiffness, e.damping if e.damping == e.damping else 0.0
        if not k > 0.0:
            return RELAX_TIME
        return min(RELAX_TIME_MAX, RELAX_TIMES * (b + self._damping) / k)

    def _probe(self, t: float) -> float:
        p = self.params
        return faded_log_chirp(t, p.probe_start_frequency, p.probe_end_frequency,
                               p.probe_duration, 0.5 * p.probe_duration)

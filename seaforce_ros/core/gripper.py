"""A gripper command: move the finger to a position X_e, or grip what is in the way.

The job behind the control_msgs gripper actions (``GripperCommand``,
``ParallelGripperCommand``): a :class:`~.grasp.Grasp` whose approach has a target. The finger
moves towards ``position`` [rad] in its minimum-impedance mode (the grasp's PI speed servo,
bounded to ``approach_force``) at ``velocity``, the speed command tapered near the target,
``v_cmd = clamp(w_p (x_t - X_e), +-velocity)`` (``w_p`` = :data:`POSITION_GAIN`):

* within ``tolerance`` of the target without a contact: ``at_target`` -- the same servo holds
  the finger there (``reached_goal``); nothing is detected there any more;
* a contact on the way (the grasp's detection, armed the grasp's way): the grasp's ``contact``,
  ``squeeze`` to ``max_effort`` and ``hold`` (no probe) -- ``stalled`` once the finger holds
  still at the grip (|V_e| below :data:`STALL_SPEED` for :data:`STALL_TIME` in ``hold``): the
  effort at the answer is the grip, as a ros2_controllers gripper reports a stall once it has
  stopped at its effort limit (its stall_velocity_threshold and stall_timeout). From the
  contact on the force decides, not the target: the finger may end up past it (a soft object
  squeezed at the cap).

The contact force is commanded exactly as a grasp's with ``grip_force = max_effort``: never
beyond it; an estimate beyond :data:`EFFORT_MARGIN` times it (at most the channel's
``max_torque``) aborts, as a grasp's ``max_force`` does (a grip at the cap itself would abort on
the estimate's noise).

:attr:`GripperMove.answer` says when the command's goal has its answer -- ``reached`` or
``stalled`` -- while the job goes on holding (the position, or the grip) until it is released
(:meth:`~.grasp.Grasp.request_release`: a cancel, a goal of another action) or ended. The
answer is set in the cycle's thread at the sample it happens.
:meth:`GripperMove.request_stop` (a cancel that holds): an approach stops where the finger is
and holds it there; a grip goes on.
:meth:`GripperMove.request_retarget` (a new gripper command on the channel, as a
ros2_controllers gripper takes a new goal's command): from the next sample the job goes on
with the new command -- bumplessly from a motion or a held position (the same servo, its
integral kept; the detection armed again), and from a grip after releasing it (the grasp's
release, then the approach) -- and :attr:`GripperMove.answer` is the new command's. Plain
Python, no ROS.
"""

from __future__ import annotations

import math
import threading
from typing import TYPE_CHECKING

from .grasp import Grasp, GraspGoal, InvalidGoalError
from .jobs import DONE
from .params import MIN_CLOSING_VELOCITY, ControllerConfig

if TYPE_CHECKING:
    from .estimator import ContactEstimator

__all__ = ["free_range", "GripperGoal", "GripperMove", "check_gripper_goal", "POSITION_GAIN",
           "EFFORT_MARGIN", "STALL_SPEED", "STALL_TIME", "REACHED", "STALLED"]

POSITION_GAIN = 10.0   # 1/s: the speed command's taper near the target, v_cmd = w_p (x_t - X_e)
EFFORT_MARGIN = 1.25   # the abort limit of the contact force estimate, times max_effort
STALL_SPEED = 0.05     # rad/s: a finger gripping in hold slower than this ...
STALL_TIME = 0.05      # s ... for this long has stalled (it grips at the cap, still)
REACHED = "reached"    # :attr:`GripperMove.answer` values
STALLED = "stalled"


class GripperGoal:
    """A gripper command on one channel, as the control_msgs actions give it.

    Parameters
    ----------
    channel : str
    position : float
        Target endpoint position X_e [rad].
    velocity : float
        Speed [rad/s] (> 0; the adapter substitutes ``grasp.gripper_velocity`` for a
        GripperCommand and a ParallelGripperCommand without a velocity).
    max_effort : float
        Contact force cap [N m] (> 0; the adapter substitutes ``grasp.gripper_effort`` for a
        ParallelGripperCommand without an effort).
    joint : str
        The joint's name the answers carry (ParallelGripperCommand's ``state.name``).
    """

    __slots__ = ("channel", "position", "velocity", "max_effort", "joint")

    def __init__(self, channel: str, position: float, velocity: float,
                 max_effort: float, joint: str = "") -> None:
        self.channel = channel
        self.position = position
        self.velocity = velocity
        self.max_effort = max_effort
        self.joint = joint or channel

    def __repr__(self) -> str:
        return (f"GripperGoal(channel={self.channel!r}, position={self.position!r}, "
                f"velocity={self.velocity!r}, max_effort={self.max_effort!r})")


def free_range(config: ControllerConfig) -> tuple[float, float]:
    """The joint range between the walls [rad]: ``limits.position_min + wall_band`` to
    ``limits.position_max - wall_band`` -- where a gripper command may send the finger (the
    walls push back beyond it) and the URDF's joint limits (what MoveIt plans with)."""
    lim = config.limits
    return lim.position_min + lim.wall_band, lim.position_max - lim.wall_band


def check_gripper_goal(goal: GripperGoal, config: ControllerConfig) -> None:
    """Raise :class:`~.grasp.InvalidGoalError` naming the field and the bound if ``goal``
    cannot be executed on a channel with ``config``: a finite position within the joint range
    between its walls (:func:`free_range`), a velocity within
    ``[MIN_CLOSING_VELOCITY, grasp.max_closing_velocity]``, a max_effort above
    ``grasp.approach_force`` (the touch) and the contact threshold, at most ``max_torque``."""
    for name in ("position", "velocity", "max_effort"):
        value = getattr(goal, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise InvalidGoalError(f"{name} = {value!r}: must be a finite number")
    low, high = free_range(config)
    if not low <= goal.position <= high:
        raise InvalidGoalError(f"position = {goal.position!r} rad: outside the joint range "
                               f"between its walls [{low:g}, {high:g}] rad "
                               "(limits.position_min + limits.wall_band, "
                               "limits.position_max - limits.wall_band)")
    grasp = config.grasp
    if not MIN_CLOSING_VELOCITY <= goal.velocity <= grasp.max_closing_velocity:
        raise InvalidGoalError(f"velocity = {goal.velocity!r} rad/s: must be within "
                               f"{MIN_CLOSING_VELOCITY:g} and grasp.max_closing_velocity = "
                               f"{grasp.max_closing_velocity:g} rad/s")
    if goal.max_effort < 0.0:
        raise InvalidGoalError(f"max_effort = {goal.max_effort!r} N m: must not be negative")
    if goal.max_effort == 0.0:
        raise InvalidGoalError("max_effort = 0 N m: a command with no force cannot move the "
                               "finger (as ros2_controllers' effort gripper controller, which "
                               "clamps its command to |max_effort|); give an effort cap "
                               "(MoveIt: max_effort in moveit_controllers.yaml)")
    floor = max(grasp.approach_force, config.estimator.contact_threshold)
    if not goal.max_effort > floor:
        raise InvalidGoalError(f"max_effort = {goal.max_effort!r} N m: must be > "
                               f"grasp.approach_force = {floor:g} N m (the force of the first "
                               "touch)")
    if goal.max_effort > config.max_torque:
        raise InvalidGoalError(f"max_effort = {goal.max_effort!r} N m: must be <= the channel's "
                               f"max_torque = {config.max_torque:g} N m")


class GripperMove(Grasp):
    """One gripper command (module docstring): a grasp whose approach stops at ``position``.

    Parameters
    ----------
    goal : GripperGoal
        Already checked (:func:`check_gripper_goal`).
    config : ControllerConfig
        The channel's.
    dt : float > 0
        Sample period [s].
    start : float
        X_e [rad] when the goal arrives (the controller's estimate): sets the direction.

    Attributes
    ----------
    answer : str or None
        None while moving (and while a new command is not yet taken over), then
        :data:`REACHED` or :data:`STALLED` (the job goes on holding).
    target : float
        The position held [rad] (where the finger stopped, after :meth:`request_stop`).
    """

    kind = "gripper command"

    def __init__(self, goal: GripperGoal, config: ControllerConfig, dt: float = 5e-4,
                 start: float = 0.0) -> None:
        effort = float(goal.max_effort)
        super().__init__(GraspGoal(goal.channel, float(goal.velocity), effort,
                                   min(EFFORT_MARGIN * effort, config.max_torque), False),
                         config, dt)
        self.gripper = goal
        self.target = float(goal.position)
        self._speed = float(goal.velocity)
        self._tolerance = config.grasp.gripper_tolerance
        self._aim(start)
        self._answer_value: str | None = None
        self._stop_request = False
        self._stopped = False           # the command was canceled (request_stop)
        self._still = 0.0               # time the finger has been still in hold [s]
        # a new command (request_retarget): handed over under the lock, taken at a sample
        self._lock = threading.Lock()
        self._retarget: GripperMove | None = None
        self._next: GripperMove | None = None      # ... taken, to go on with after a release
        self._requested = 0                        # commands requested (any thread)
        self._serving = 0                          # ... the one the answer is for (cycle)

    def _aim(self, position: float) -> None:
        """Direction, travel limit and time-out towards :attr:`target` from ``position``
        [rad]: the travel is the target's, not grasp.max_travel; the taper adds
        ~4/POSITION_GAIN."""
        sign = 1.0 if self.target >= position else -1.0
        self._sign = sign
        self._v = sign * self._speed
        self._hold_command = sign * self._grip
        self._max_travel = abs(self.target - position) + self._give_way
        self._timeout = 2.0 * self._max_travel / self._speed + 4.0 / POSITION_GAIN + 1.0

    # --- requests ----------------------------------------------------------------------------
    def request_stop(self) -> None:
        """(any thread) A cancel that holds: an approach stops and holds the finger where it
        is (at the next sample); a grip goes on. The command has not reached its goal
        (:attr:`reached_goal` stays False until a new command)."""
        self._stopped = True
        self._stop_request = True

    def request_retarget(self, new: GripperMove) -> bool:
        """(any thread) Go on with ``new``'s command (its position, speed and effort cap)
        from the next sample, instead of running ``new`` itself (module docstring). False when
        this job has ended: start ``new``."""
        with self._lock:
            if self.phase == DONE:
                return False
            self._retarget = new
            self._requested += 1
            return True

    @property
    def answer(self) -> str | None:
        """The answer of the latest command requested (None until it has one)."""
        return self._answer_value if self._serving == self._requested else None

    # --- per sample ----------------------------------------------------------------------------
    def update(self, est: ContactEstimator, ve: float, steps: int = 1) -> float:
        """:meth:`~.grasp.Grasp.update` with the target: ``at_target`` holds the position."""
        if self._stop_request:
            self._stop_request = False
            if self.phase == "approach":
                self.target = est.position
        if self._retarget is not None:
            self._take_retarget(est)
        if self.phase == "approach" and \
                self._sign * (self.target - est.position) <= self._tolerance:
            self._enter("at_target")
            self.message = f"at {est.position:.4g} rad"
            self._answer(REACHED)
        if self.phase == "at_target":
            if self._abort_request is not None or self._release_request is not None:
                self._take_requests(est)
            if self.phase == "at_target":
                self._t += self.dt * steps
                return self._hold_position(est, steps)
        output = super().update(est, ve, steps)
        if self.phase == "hold" and self._answer_value is None:
            self._still = self._still + self.dt * steps if abs(est.velocity) < STALL_SPEED \
                else 0.0
            if self._still >= STALL_TIME:
                self._answer(STALLED)
        return output

    def _take_retarget(self, est: ContactEstimator) -> None:
        """A new command: a motion or a held position goes on towards it now; a grip (or a
        release under way) is released first (:meth:`_released` goes on with it)."""
        with self._lock:
            new = self._claim_retarget()
        if self.phase in ("approach", "at_target"):
            self._follow(new, est)
            return
        self._next = new
        self.release("released for a new gripper command", "canceled")

    def _claim_retarget(self) -> GripperMove:
        """(cycle thread, the lock held) The newest command requested; from now on the
        answer is its."""
        new, self._retarget = self._retarget, None
        assert new is not None
        self._answer_value = None
        self._stopped = False
        self._serving = self._requested
        return new

    def _released(self, est: ContactEstimator) -> None:
        """The release is over: the next command's approach, if one waits (or was requested
        this very sample), else done."""
        with self._lock:
            new = self._claim_retarget() if self._retarget is not None else self._next
            self._next = None
            if new is None:
                super()._released(est)
                return
        self.contact = False
        self.contact_time = self.grip_force = self._contact_at = math.nan
        self._pending_outcome = self._release_request = self._estimator = None
        self._integral = 0.0            # F_g ramped to zero: the servo starts from rest
        self._follow(new, est)

    def _follow(self, new: GripperMove, est: ContactEstimator) -> None:
        """Take ``new``'s command over and approach its target from here: the servo's
        integral is kept (bumpless); the detection arms again unless the finger goes on
        approaching in the same direction."""
        sign, phase = self._sign, self.phase
        self.gripper, self.goal, self.target = new.gripper, new.goal, new.target
        self._speed, self._tolerance = new._speed, new._tolerance
        self._grip, self._max, self._touch = new._grip, new._max, new._touch
        self._aim(est.position)
        if phase != "approach" or self._sign != sign:
            self._start = None
            self._armed = self._closed = self._at_cap = False
            self._steady = self._slow = 0.0
        self._enter("approach")
        self.message = "approaching"

    def _approach(self, est: ContactEstimator, s: float, steps: int) -> float:
        """The grasp's approach with the speed command tapered to the target (:meth:`update`
        has taken a finger within the tolerance to ``at_target``)."""
        remaining = s * (self.target - est.position)
        self._v = s * min(self._speed, max(POSITION_GAIN * remaining, MIN_CLOSING_VELOCITY))
        return super()._approach(est, s, steps)

    def _enter_hold(self, c: float, est: ContactEstimator) -> None:
        """The squeeze is done: the finger grips at the cap (``stalled`` once it is still)."""
        super()._enter_hold(c, est)
        self._still = 0.0

    def _hold_position(self, est: ContactEstimator, steps: int) -> float:
        """``at_target``: the approach's servo at ``clamp(w_p (x_t - X_e), +-velocity)``,
        bounded to ``approach_force`` [N m]."""
        error = POSITION_GAIN * (self.target - est.position)
        speed = self._speed
        self._v = speed if error > speed else (-speed if error < -speed else error)
        f = self._servo(est, self._sign, steps)
        self.force_command = self._output = self._pushed = f
        return f

    def _answer(self, answer: str) -> None:
        if self._answer_value is None:
            self._answer_value = answer

    @property
    def stalled(self) -> bool:
        """A contact stopped the finger before the target: it grips at ``max_effort``."""
        return self.answer == STALLED

    @property
    def reached_goal(self) -> bool:
        """The finger is at the target (``at_target``: within the tolerance when it came),
        and the command was not stopped short of it."""
        return self.answer == REACHED and self.phase == "at_target" and not self._stopped

    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        """``position`` X_e [rad], ``effort`` (the contact force estimate, > 0 pushing back)
        [N m], ``stalled``, ``reached_goal`` and the ``phase``."""
        return {"position": estimator.position, "effort": -self._sign * estimator.force,
                "stalled": self.stalled, "reached_goal": self.reached_goal,
                "phase": self.phase}

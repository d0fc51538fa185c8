"""A gripper command: move the finger to a position X_e, or grip what is in the way.

The job behind the control_msgs gripper actions (``GripperCommand``,
``ParallelGripperCommand``): a :class:`~.grasp.Grasp` whose approach has a target. The finger
moves towards ``position`` [rad] in its minimum-impedance mode (the grasp's PI speed servo,
bounded to ``approach_force``) at ``velocity``, the speed command tapered near the target,
``v_cmd = clamp(w_p (x_t - X_e), +-velocity)`` (``w_p`` = :data:`POSITION_GAIN`):

* within ``tolerance`` of the target without a contact: ``at_target`` -- the same servo holds
  the finger there (``reached_goal``); nothing is detected there any more;
* a contact on the way (the grasp's detection, armed the grasp's way): the grasp's ``contact``,
  ``squeeze`` to ``max_effort`` and ``hold`` (no probe) -- ``stalled``. From the contact on the
  force decides, not the target: the finger may end up past it (a soft object squeezed at the
  cap).

The contact force is commanded exactly as a grasp's with ``grip_force = max_effort``: never
beyond it; an estimate beyond :data:`EFFORT_MARGIN` times it (at most the channel's
``max_torque``) aborts, as a grasp's ``max_force`` does (a grip at the cap itself would abort on
the estimate's noise).

:attr:`GripperMove.answer` says when the command's goal has its answer -- ``reached`` or
``stalled`` -- while the job goes on holding (the position, or the grip) until it is released
(:meth:`~.grasp.Grasp.request_release`: the next goal on the channel, a cancel) or ended. The
answer is set in the cycle's thread at the sample it happens.
:meth:`GripperMove.request_stop` (a cancel that holds): an approach stops where the finger is
and holds it there; a grip goes on. Plain Python, no ROS.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .grasp import Grasp, GraspGoal, InvalidGoalError
from .params import MIN_CLOSING_VELOCITY, ControllerConfig

if TYPE_CHECKING:
    from .estimator import ContactEstimator

__all__ = ["GripperGoal", "GripperMove", "check_gripper_goal", "POSITION_GAIN",
           "EFFORT_MARGIN", "REACHED", "STALLED"]

POSITION_GAIN = 10.0   # 1/s: the speed command's taper near the target, v_cmd = w_p (x_t - X_e)
EFFORT_MARGIN = 1.25   # the abort limit of the contact force estimate, times max_effort
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
        Speed [rad/s] (> 0; the adapter substitutes ``grasp.gripper_velocity`` for 0 or an
        empty one).
    max_effort : float
        Contact force cap [N m] (> 0; the adapter substitutes ``grasp.gripper_effort`` for 0).
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


def check_gripper_goal(goal: GripperGoal, config: ControllerConfig) -> None:
    """Raise :class:`~.grasp.InvalidGoalError` naming the field and the bound if ``goal``
    cannot be executed on a channel with ``config``: a finite position within the joint range
    ``[friction.position_min, friction.position_max]``, a velocity within
    ``[MIN_CLOSING_VELOCITY, grasp.max_closing_velocity]``, a max_effort above
    ``grasp.approach_force`` (the touch) and the contact threshold, at most ``max_torque``."""
    for name in ("position", "velocity", "max_effort"):
        value = getattr(goal, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise InvalidGoalError(f"{name} = {value!r}: must be a finite number")
    low, high = config.friction.position_min, config.friction.position_max
    if not low <= goal.position <= high:
        raise InvalidGoalError(f"position = {goal.position!r} rad: outside the joint range "
                               f"[{low:g}, {high:g}] rad (friction.position_min, "
                               "friction.position_max)")
    grasp = config.grasp
    if not MIN_CLOSING_VELOCITY <= goal.velocity <= grasp.max_closing_velocity:
        raise InvalidGoalError(f"velocity = {goal.velocity!r} rad/s: must be within "
                               f"{MIN_CLOSING_VELOCITY:g} and grasp.max_closing_velocity = "
                               f"{grasp.max_closing_velocity:g} rad/s")
    if goal.max_effort < 0.0:
        raise InvalidGoalError(f"max_effort = {goal.max_effort!r} N m: must not be negative "
                               "(0: the channel's grasp.gripper_effort)")
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
        None while moving, then :data:`REACHED` or :data:`STALLED` (the job goes on holding).
    target : float
        The position held [rad] (where the finger stopped, after :meth:`request_stop`).
    """

    kind = "gripper command"

    def __init__(self, goal: GripperGoal, config: ControllerConfig, dt: float = 5e-4,
                 start: float = 0.0) -> None:
        self.target = float(goal.position)
        sign = 1.0 if self.target >= start else -1.0
        effort = float(goal.max_effort)
        super().__init__(GraspGoal(goal.channel, sign * float(goal.velocity), effort,
                                   min(EFFORT_MARGIN * effort, config.max_torque), False),
                         config, dt)
        self.gripper = goal
        self._speed = float(goal.velocity)
        self._tolerance = config.grasp.gripper_tolerance
        distance = abs(self.target - start)
        # the travel is the target's, not grasp.max_travel; the taper adds ~4/POSITION_GAIN
        self._max_travel = distance + config.grasp.give_way_travel
        self._timeout = 2.0 * self._max_travel / self._speed + 4.0 / POSITION_GAIN + 1.0
        self.answer: str | None = None
        self._stop_request = False

    # --- requests ----------------------------------------------------------------------------
    def request_stop(self) -> None:
        """(any thread) A cancel that holds: an approach stops and holds the finger where it
        is (at the next sample); a grip goes on."""
        self._stop_request = True

    # --- per sample ----------------------------------------------------------------------------
    def update(self, est: ContactEstimator, ve: float, steps: int = 1) -> float:
        """:meth:`~.grasp.Grasp.update` with the target: ``at_target`` holds the position."""
        if self._stop_request:
            self._stop_request = False
            if self.phase == "approach":
                self.target = est.position
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
        return super().update(est, ve, steps)

    def _approach(self, est: ContactEstimator, s: float, steps: int) -> float:
        """The grasp's approach with the speed command tapered to the target (:meth:`update`
        has taken a finger within the tolerance to ``at_target``)."""
        remaining = s * (self.target - est.position)
        self._v = s * min(self._speed, max(POSITION_GAIN * remaining, MIN_CLOSING_VELOCITY))
        return super()._approach(est, s, steps)

    def _touched(self, est: ContactEstimator, s: float) -> None:
        super()._touched(est, s)
        if self.phase == "contact":
            self._answer(STALLED)

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
        if self.answer is None:
            self.answer = answer

    @property
    def stalled(self) -> bool:
        """A contact stopped the finger before the target (it grips at ``max_effort``)."""
        return self.answer == STALLED

    @property
    def reached_goal(self) -> bool:
        """The finger is at the target (``at_target``: within the tolerance when it came)."""
        return self.answer == REACHED and self.phase == "at_target"

    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        """``position`` X_e [rad], ``effort`` (the contact force estimate, > 0 pushing back)
        [N m], ``stalled``, ``reached_goal`` and the ``phase``."""
        return {"position": estimator.position, "effort": -self._sign * estimator.force,
                "stalled": self.stalled, "reached_goal": self.reached_goal,
                "phase": self.phase}

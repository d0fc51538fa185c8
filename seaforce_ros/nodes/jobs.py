"""The controller node's job actions: one adapter from a ROS 2 action to a core job.

An action whose goals run a :class:`~seaforce_ros.core.jobs.Job` on a channel (``~/grasp``,
``~/calibrate_friction``) is one :class:`JobAction` registered with :class:`JobActions`: how a
goal becomes a job (the goal's checks and the job's factory, raising
:class:`~seaforce_ros.core.jobs.InvalidJobGoalError` with the reason), how its result is built,
what its start logs, how a running goal describes its channel to a goal it turns away, the
reason of a client's cancel, and what its end does beyond the result (a calibration stores the
new friction as parameters). The rest is the same for every action:

* One goal per channel, of whatever action. A goal that cannot be executed -- unknown channel,
  bad fields, a channel another goal holds, a faulted channel, one the plant stopped, no states
  arriving -- ends at once ABORTED with ``rejected: <reason>`` in ``result.message`` (ROS 2's
  goal rejection carries no reason); each action's rejections are logged once per reason
  and 10 s, with a count.
* The job is handed to the channel's controller
  (:meth:`~seaforce_ros.core.controller.ChannelController.request_job`), which takes it at the
  start of a cycle; a job the cycle has not taken within :data:`JOB_START_TIMEOUT` is withdrawn
  (the goal ends ABORTED: it never starts later).
* Feedback at :data:`JOB_FEEDBACK_RATE` from the job's
  :meth:`~seaforce_ros.core.jobs.Job.feedback` (named as the action's feedback fields).
* A cancel withdraws a job the cycle has not taken, or asks it to end
  (:meth:`~seaforce_ros.core.jobs.Job.request_cancel`).
* A stall (no state the cycle ran on for the node's stall time): the goal ends ABORTED at once
  with the reason; its job ends in the cycle's thread when the cycle runs again.
* At its end the job's outcome gives the goal's status (``succeeded``, ``canceled``, else
  aborted), the result is built and one line logged.

An action may also declare (the control_msgs gripper actions do):

* ``answered`` -- the goal has its answer while its job goes on holding (a gripper command
  that reached its position, or stalled on an object and grips it): the goal ends with the
  status it names (SUCCEEDED, or ABORTED: a stall where stalling is not allowed) and the job
  stays on the channel, *held*, until the next goal there (of any action), which releases it
  (:meth:`~seaforce_ros.core.jobs.Job.request_cancel`) and starts once it is done; the answers
  are looked for at :data:`ANSWER_RATE` (not only at the feedback rate: the rclpy events
  executor has no guard conditions the cycle's thread could wake it with);
* ``retarget`` -- a new goal of the action on a channel whose job (a running goal's, or a held
  one) can take the new goal over: the job goes on with it, bumplessly, instead of being
  released first, and a running goal of such an action ends CANCELED (preempted) -- as
  ros2_controllers' gripper controllers take a new goal;
* ``on_cancel`` -- how a cancel ends the job: True leaves it holding, False releases it. The
  goal gives its channel up when the cancel is accepted (the next goal may come at once: it
  takes the job over, or waits for the release) and ends CANCELED at the next look, or once
  the release is done;
* ``reject_in_callback`` -- a goal that cannot be executed is rejected by the goal callback
  (its result type has no message field); the reason is logged like every rejection;
* ``follow`` -- work off the control thread after the job succeeded (commissioning's
  identification in a child process, a :class:`FollowUp`). The goal keeps its channel while it
  runs (a goal for that channel is still turned away), feedback and cancels go to it, and its
  outcome gives the goal's status. The channel itself is back in its mode from the job's end.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Optional, Protocol, Sequence

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.task import Future

from ..core.control_cycle import ControlCycle
from ..core.controller import ChannelController
from ..core.episodes import Episode, EventLog
from ..core.jobs import InvalidJobGoalError, Job
from .ros_common import log_events, shutdown_safe, steady_timer

__all__ = ["JobAction", "JobActions", "FollowUp", "JOB_FEEDBACK_RATE", "JOB_START_TIMEOUT",
           "ANSWER_RATE"]

JOB_FEEDBACK_RATE = 50.0     # Hz
ANSWER_RATE = 250.0          # Hz, the look for answered goals (actions that have ``answered``)
JOB_START_TIMEOUT = 1.0      # s a goal waits for the cycle to take its job over
#: Rejection reasons throttled apart (per action and reason text; the oldest forgotten).
REJECTION_KINDS = 64


class FollowUp(Protocol):
    """Work an action goes on with after its job succeeded, off the control thread (polled at
    :data:`JOB_FEEDBACK_RATE` from the node's executor; nothing here may block).

    ``outcome`` is None while it runs, then ``succeeded``, ``canceled`` or ``aborted``;
    ``message`` says what it does or why it ended.
    """

    outcome: str | None
    message: str

    def poll(self) -> bool:
        """Advance (never blocking); True once it has ended."""

    def cancel(self, reason: str) -> None:
        """The client's cancel: end as soon as it safely can, ``canceled``."""

    def feedback(self) -> dict[str, float | str]:
        """Its progress now, named as the action's feedback fields."""


@dataclass(frozen=True)
class JobAction:
    """One action whose goals run a core job (module docstring).

    Attributes
    ----------
    name : str
        The action's name (``~/grasp``).
    action_type : type
        Its type (``seaforce_msgs.action.Grasp``).
    label : str
        What its job is, in logs and messages (the job's ``kind``: ``grasp``).
    make : callable (channel index, goal) -> Job
        The goal's checks and the job's factory; raises ``InvalidJobGoalError`` with the reason
        (prefixed with the channel here).
    result : callable (channel index or None, Job or None, message) -> the action's Result
        ``Job`` None: a goal rejected before it had one; a job still active: a goal ended
        before its job (a stall).
    describe : callable (goal) -> str
        The start's log line, after ``<channel>: ``.
    busy : callable (Job) -> str
        What this action's running goal does to its channel, for a goal turned away
        (``is held by a grasp goal (hold)``).
    cancel_reason : str
        The reason a client's cancel gives the running job.
    finish : callable (channel index, Job) -> str, optional
        The result's message once the job is done (and its follow-up, if any), after what its
        end does in the node (the default: the job's message).
    channel : callable (goal) -> str, optional
        The goal's channel (the default: its ``channel`` field).
    answered : callable (Job) -> str, optional
        The status a goal whose job holds ends with now (``succeeded``, ``aborted``), or ''
        while it has no answer (module docstring).
    retarget : callable (running Job, new Job) -> bool, optional
        Whether the running job took the new goal's job over (module docstring).
    on_cancel, reject_in_callback : optional
        The gripper actions' cancels and rejections (module docstring).
    feedback : callable (channel index, Job) -> the action's Feedback, optional
        The default: the job's :meth:`~seaforce_ros.core.jobs.Job.feedback` fields set on the
        action's Feedback by name.
    follow : callable (channel index, Job) -> FollowUp, optional
        What the goal goes on with once its job has succeeded (module docstring); None (the
        default): the goal ends with its job.
    """

    name: str
    action_type: Any
    label: str
    make: Callable[[int, Any], Job]
    result: Callable[[int | None, Job | None, str], Any]
    describe: Callable[[Any], str]
    busy: Callable[[Job], str]
    cancel_reason: str
    finish: Callable[[int, Job], str] = lambda index, job: job.message
    channel: Callable[[Any], str] = lambda goal: goal.channel
    answered: Optional[Callable[[Job], str]] = None
    retarget: Optional[Callable[[Job, Job], bool]] = None
    on_cancel: Optional[Callable[[Job], bool]] = None
    reject_in_callback: bool = False
    feedback: Optional[Callable[[int, Job], Any]] = None
    follow: Optional[Callable[[int, Job], FollowUp]] = None


@dataclass
class _Goal:
    """A goal whose job is handed to its channel's controller (once ``after``, the job held
    on the channel before it, is done)."""
    action: JobAction
    job: Job
    handle: Any                 # rclpy's ServerGoalHandle
    done: Future                # the execute callback's result
    requested: float            # monotonic time of the request [s] (or of the goal, waiting)
    after: Optional[Job] = None
    follow_up: Optional[FollowUp] = None   # once the job has succeeded (``JobAction.follow``)
    releasing: bool = False                # (a canceled goal) it ends once its job is done


def _preempts(new: Optional[JobAction], running: JobAction) -> bool:
    """A goal of ``new`` preempts a running goal of ``running`` (both take new goals over:
    ``retarget``)."""
    return new is not None and new.retarget is not None and running.retarget is not None


class JobActions:
    """The job actions of a controller node: one goal per channel (module docstring).

    Parameters
    ----------
    node : Node
        Serves the actions, runs the feedback timer, logs.
    channels : sequence of str
    controllers : sequence of ChannelController
        One per channel, the jobs' controllers.
    cycle : ControlCycle
        Its faults and plant stops turn goals away.
    stalled : callable () -> str
        Why the control cycle is not running now (no state for too long), or ''.
    """

    def __init__(self, node: Node, channels: Sequence[str],
                 controllers: Sequence[ChannelController], cycle: ControlCycle,
                 stalled: Callable[[], str]) -> None:
        self._node = node
        self.context = node.context          # (shutdown_safe)
        self._channels = list(channels)
        self._controllers = controllers
        self._cycle = cycle
        self._stalled = stalled
        self._goals: dict[int, _Goal] = {}   # channel index -> its goal
        self._held: dict[int, Job] = {}      # channel index -> a job its answered goal left
        self._canceled: list[tuple[int, _Goal]] = []   # goals that gave their channel up
        self._log = EventLog()
        # one throttle per action and reason (logged once per 10 s, with a count): with one
        # for all, a gripper goal's reason once stood in for a grasp's, and another bad goal
        # within 10 s logged nothing
        self._rejections: dict[str, Episode] = {}
        steady_timer(node, 1.0 / JOB_FEEDBACK_RATE, self._tick)
        self._answer_timer = None

    def add(self, action: JobAction) -> None:
        """Serve ``action``."""
        if action.answered is not None and self._answer_timer is None:
            self._answer_timer = steady_timer(self._node, 1.0 / ANSWER_RATE, self._answers)
        async def execute(handle: Any) -> Any:
            return await self._execute(action, handle)
        def accept(goal: Any) -> GoalResponse:
            if action.reject_in_callback and self._check(action, goal) is None:
                return GoalResponse.REJECT
            return GoalResponse.ACCEPT
        def cancel(handle: Any) -> CancelResponse:
            if action.on_cancel is not None:
                self._give_up(handle)
            return CancelResponse.ACCEPT
        ActionServer(self._node, action.action_type, action.name, execute_callback=execute,
                     goal_callback=accept, cancel_callback=cancel,
                     callback_group=ReentrantCallbackGroup())

    def channel_for(self, channel: str, action: Optional[JobAction] = None) -> int:
        """The index of a goal's ``channel`` if a goal (of ``action``) can run on it now, else
        InvalidJobGoalError with the reason: unknown, busy (a goal another goal of an action
        with ``retarget`` cannot preempt), faulted, stopped by the plant, no states
        arriving."""
        if channel not in self._channels:
            raise InvalidJobGoalError(f'unknown channel {channel!r}; the channels are '
                                      + ', '.join(self._channels))
        index = self._channels.index(channel)
        held = self._goals.get(index)
        if held is not None and not _preempts(action, held.action):
            raise InvalidJobGoalError(f'channel {channel} {held.action.busy(held.job)}; '
                                      'cancel it first')
        cycle = self._cycle
        fault = cycle.fault(index)
        if fault and cycle.latched(index):
            raise InvalidJobGoalError(f'channel {channel} is faulted: {fault}; call ~/reset')
        if fault:
            raise InvalidJobGoalError(f'channel {channel} is {fault} (it re-initialises itself '
                                      'at the next clean state: send the goal again)')
        stopped = cycle.plant_stopped(index)
        if stopped:
            raise InvalidJobGoalError(f'the plant has stopped channel {channel}: {stopped}')
        stalled = self._stalled()
        if stalled:
            raise InvalidJobGoalError(stalled + ': the control cycle is not running')
        return index

    def _check(self, action: JobAction, goal: Any) -> tuple[int, Job] | None:
        """(channel index, job) of a goal that can run now, else None (the reason logged,
        once per 10 s with a count)."""
        channel = action.channel(goal)
        try:
            index = self.channel_for(channel, action)
            try:
                return index, action.make(index, goal)
            except InvalidJobGoalError as exc:
                raise InvalidJobGoalError(f'{channel}: {exc}') from None
        except InvalidJobGoalError as exc:
            text = f'{action.label} goal rejected: {exc}'
            episode = self._rejections.get(text)
            if episode is None:
                if len(self._rejections) >= REJECTION_KINDS:     # bounded: the oldest goes
                    del self._rejections[next(iter(self._rejections))]
                episode = self._rejections[text] = Episode(self._log)
            episode.begin(time.monotonic(), text)
            episode.end(time.monotonic())
            log_events(self._node.get_logger(), self._log.drain())
            self.last_rejection = str(exc)
            return None

    #: The reason of the latest goal turned away (tests and the node's diagnostics).
    last_rejection = ''

    async def _execute(self, action: JobAction, handle: Any) -> Any:
        """One goal: checked, handed to the cycle (after the job held on its channel, if any,
        is released), followed by :meth:`_tick` until answered or done."""
        goal = handle.request
        checked = self._check(action, goal)
        if checked is None:
            handle.abort()
            return action.result(None, None, f'rejected: {self.last_rejection}')
        index, job = checked
        done = Future()
        previous = self._held.pop(index, None)
        running = self._goals.pop(index, None)       # one the new goal preempts (channel_for)
        if running is not None:
            previous = self._preempt(index, running, previous)
        after = None
        if previous is not None and previous.active:
            if action.retarget is not None and action.retarget(previous, job):
                job = previous                       # it goes on with this goal, bumplessly
            else:
                previous.request_cancel(f'released for a new {action.label} goal')
                after = previous
        self._goals[index] = _Goal(action, job, handle, done, time.monotonic(), after)
        if after is None and not job.started:
            self._controllers[index].request_job(job)
        self._node.get_logger().info(f'{action.channel(goal)}: {action.describe(goal)}')
        if action.on_cancel is not None and handle.is_cancel_requested:
            self._give_up(handle)          # canceled before this coroutine ran
        return await done

    def _preempt(self, index: int, goal: _Goal, held: Optional[Job]) -> Optional[Job]:
        """End ``goal``, preempted by a new goal on its channel: CANCELED now (rclpy offers no
        server-side cancel of an executing goal; rcl's EXECUTING -> CANCELING -> CANCELED is
        the way rclcpp's goal handle ends one that is dropped). Returns the job on the channel
        the new goal follows: the goal's (started), or the one it waited for."""
        job = goal.job
        if goal.after is not None or not job.started:
            job.withdraw('preempted before it started', 'canceled')
        previous = goal.after if goal.after is not None else (
            job if job.started else held)
        if not goal.handle.is_cancel_requested:
            goal.handle._update_state(_rclpy.GoalEvent.CANCEL_GOAL)
        self._finish(index, goal, 'canceled', 'preempted by a new goal')
        return previous

    def _give_up(self, handle: Any) -> None:
        """(the cancel callback of an action with ``on_cancel``) The goal of ``handle`` gives
        its channel up now: its job holds (``on_cancel`` True), releases (False) or, not
        started, is withdrawn; the goal ends CANCELED at the next look
        (:meth:`_end_canceled`), a releasing one once its job is done."""
        for index, goal in list(self._goals.items()):
            if goal.handle != handle or goal.follow_up is not None:
                continue
            del self._goals[index]
            job = goal.job
            if job.withdraw('canceled before it started', 'canceled'):
                if goal.after is not None and goal.after.active:
                    self._held[index] = goal.after        # still releasing
            elif goal.action.on_cancel(job):
                self._held[index] = job
            else:
                job.request_cancel(goal.action.cancel_reason)
                self._held[index] = job
                goal.releasing = True
            self._canceled.append((index, goal))

    def _end_canceled(self) -> None:
        """End the goals that gave their channel up, once rclpy has them CANCELING: at once,
        or a releasing one once its job is done or another goal has taken it over."""
        taken = {id(goal.job) for goal in self._goals.values()}
        for entry in list(self._canceled):
            index, goal = entry
            if not goal.handle.is_cancel_requested:
                continue
            if goal.releasing and goal.job.active and id(goal.job) not in taken:
                continue
            self._canceled.remove(entry)
            self._finish(index, goal, 'canceled')

    @shutdown_safe
    def _tick(self) -> None:
        """Feedback, cancel requests, start time-outs, stalls and ends of the running goals."""
        self._end_canceled()
        for index, job in list(self._held.items()):
            if not job.active:
                del self._held[index]
        for index, goal in list(self._goals.items()):
            job, handle, action = goal.job, goal.handle, goal.action
            if goal.follow_up is not None:
                self._tick_follow_up(index, goal, goal.follow_up)
                continue
            if goal.after is not None:
                if handle.is_cancel_requested:
                    job.withdraw('canceled before it started', 'canceled')
                elif goal.after.active:
                    continue                  # the job held on the channel is releasing
                else:
                    goal.after = None
                    goal.requested = time.monotonic()
                    self._controllers[index].request_job(job)
            if handle.is_cancel_requested and job.active:
                if not job.withdraw('canceled before it started', 'canceled'):
                    job.request_cancel(action.cancel_reason)
            answer = self._answer(goal)
            if answer:
                self._end(index, answer)
                continue
            if job.active and not job.started and \
                    time.monotonic() - goal.requested > JOB_START_TIMEOUT:
                job.withdraw(f'the control cycle did not take the {goal.action.label} within '
                             f'{JOB_START_TIMEOUT:g} s (are states arriving?)')
            message = self._stall_message(job)
            if message:
                self._end_stalled(index, message)
            elif job.active:
                handle.publish_feedback(self._feedback(index, goal))
            elif action.follow is not None and job.outcome == 'succeeded':
                goal.follow_up = action.follow(index, job)
                self._tick_follow_up(index, goal, goal.follow_up)
            else:
                self._end(index)

    def _tick_follow_up(self, index: int, goal: _Goal, follow_up: FollowUp) -> None:
        """One tick of a goal's follow-up: its cancel, its feedback, its end."""
        if goal.handle.is_cancel_requested and follow_up.outcome is None:
            follow_up.cancel(goal.action.cancel_reason)
        if follow_up.poll():
            self._end(index)
        else:
            feedback = goal.action.action_type.Feedback()
            for name, value in follow_up.feedback().items():
                setattr(feedback, name, value)
            goal.handle.publish_feedback(feedback)

    @shutdown_safe
    def _answers(self) -> None:
        """End the goals whose job has answered (it goes on holding the channel), and the
        canceled ones that gave their channel up."""
        self._end_canceled()
        for index, goal in list(self._goals.items()):
            answer = self._answer(goal)
            if answer:
                self._end(index, answer)

    @staticmethod
    def _answer(goal: _Goal) -> str:
        """The status a goal whose job has answered ends with (its job goes on holding), or
        ''."""
        answered = goal.action.answered
        if answered is None or not goal.job.active or not goal.job.started or \
                goal.handle.is_cancel_requested:
            return ''
        return answered(goal.job)

    def _feedback(self, index: int, goal: _Goal) -> Any:
        if goal.action.feedback is not None:
            return goal.action.feedback(index, goal.job)
        feedback = goal.action.action_type.Feedback()
        for name, value in goal.job.feedback(self._controllers[index].estimator).items():
            setattr(feedback, name, value)
        return feedback

    def _end(self, index: int, holding: str = '') -> None:
        """The goal of a job that is done (or, ``holding``: the goal's status, of a job that
        goes on holding the channel): its status, result and log line."""
        goal = self._goals.pop(index)
        if holding:
            self._held[index] = goal.job
        self._finish(index, goal, holding or (goal.follow_up.outcome if goal.follow_up is not
                                              None else goal.job.outcome))

    def _finish(self, index: int, goal: _Goal, outcome: Optional[str], why: str = '') -> None:
        """``goal``'s status (``outcome``: succeeded, canceled, else aborted), result and log
        line (``why`` instead of its job's message)."""
        action, job, handle = goal.action, goal.job, goal.handle
        message = why or action.finish(index, job)
        result = action.result(index, job, message)
        if outcome == 'succeeded':
            handle.succeed()
        elif outcome == 'canceled':
            handle.canceled()
        else:
            handle.abort()
        holding = job.active and job.started
        self._node.get_logger().info(f'{self._channels[index]}: {action.label} {outcome}: '
                                     f'{message}' + (' (holding)' if holding else ''))
        goal.done.set_result(result)

    def _stall_message(self, job: Job) -> str:
        """Why a started, running job's goal must end because the cycle does not run (a plant
        that died, a cut link), else ''."""
        stalled = self._stalled() if job.active and job.started else ''
        return stalled + ': the plant stopped, or the link to it' if stalled else ''

    def _end_stalled(self, index: int, message: str) -> None:
        """End the goal on channel ``index`` now; its job ends in the cycle's thread when the
        cycle runs again (re-initialised first: the stall is older than state_timeout)."""
        goal = self._goals.pop(index)
        action, job, handle, done = goal.action, goal.job, goal.handle, goal.done
        job.request_abort(message)
        handle.abort()
        self._node.get_logger().warn(f'{self._channels[index]}: {action.label} aborted: '
                                     f'{message}')
        done.set_result(action.result(index, job, message))

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
  goal rejection carries no reason); rejections are logged once per 10 s, with a count.
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
* An action may go on after its job succeeded with work off the control thread
  (:attr:`JobAction.follow`: commissioning's identification in a child process). The goal
  keeps its channel while it runs (a goal for that channel is still turned away), feedback and
  cancels go to it, and its outcome gives the goal's status. The channel itself is back in its
  mode from the job's end.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Protocol, Sequence

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future

from ..core.control_cycle import ControlCycle
from ..core.controller import ChannelController
from ..core.episodes import Episode, EventLog
from ..core.jobs import InvalidJobGoalError, Job
from .ros_common import log_events, shutdown_safe

__all__ = ["JobAction", "JobActions", "FollowUp", "JOB_FEEDBACK_RATE", "JOB_START_TIMEOUT"]

JOB_FEEDBACK_RATE = 50.0     # Hz
JOB_START_TIMEOUT = 1.0      # s a goal waits for the cycle to take its job over


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
    follow : callable (channel index, Job) -> FollowUp, optional
        What the goal goes on with once its job has succeeded (module docstring); None (the
        default): the goal ends with its job.
    feedback : callable (dict) -> dict, optional
        The action's feedback fields from the job's :meth:`~seaforce_ros.core.jobs.Job.feedback`
        (the default: the job's fields as they are).
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
    follow: Callable[[int, Job], FollowUp] | None = None
    feedback: Callable[[dict[str, float | str]], dict[str, float | str]] = lambda fields: fields


@dataclass
class _Goal:
    """A goal whose job is handed to its channel's controller."""
    action: JobAction
    job: Job
    handle: Any                 # rclpy's ServerGoalHandle
    done: Future                # the execute callback's result
    requested: float            # monotonic time of the request [s]
    after: FollowUp | None = None   # the follow-up, once the job has succeeded


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
        self._log = EventLog()
        self._rejections = Episode(self._log)   # logged once per 10 s, with a count
        node.create_timer(1.0 / JOB_FEEDBACK_RATE, self._tick)

    def add(self, action: JobAction) -> None:
        """Serve ``action``."""
        async def execute(handle: Any) -> Any:
            return await self._execute(action, handle)
        ActionServer(self._node, action.action_type, action.name, execute_callback=execute,
                     goal_callback=lambda goal: GoalResponse.ACCEPT,
                     cancel_callback=lambda handle: CancelResponse.ACCEPT,
                     callback_group=ReentrantCallbackGroup())

    def channel_for(self, channel: str) -> int:
        """The index of a goal's ``channel`` if a goal can run on it now, else
        InvalidJobGoalError with the reason: unknown, busy, faulted, stopped by the plant, no
        states arriving."""
        if channel not in self._channels:
            raise InvalidJobGoalError(f'unknown channel {channel!r}; the channels are '
                                      + ', '.join(self._channels))
        index = self._channels.index(channel)
        held = self._goals.get(index)
        if held is not None:
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

    async def _execute(self, action: JobAction, handle: Any) -> Any:
        """One goal: checked, handed to the cycle, followed by :meth:`_tick` until done."""
        goal = handle.request
        try:
            index = self.channel_for(goal.channel)
            try:
                job = action.make(index, goal)
            except InvalidJobGoalError as exc:
                raise InvalidJobGoalError(f'{goal.channel}: {exc}') from None
        except InvalidJobGoalError as exc:
            self._rejections.begin(time.monotonic(), f'{action.label} goal rejected: {exc}')
            self._rejections.end(time.monotonic())
            log_events(self._node.get_logger(), self._log.drain())
            handle.abort()
            return action.result(None, None, f'rejected: {exc}')
        done = Future()
        self._goals[index] = _Goal(action, job, handle, done, time.monotonic())
        self._controllers[index].request_job(job)
        self._node.get_logger().info(f'{goal.channel}: {action.describe(goal)}')
        return await done

    @shutdown_safe
    def _tick(self) -> None:
        """Feedback, cancel requests, start time-outs, stalls, follow-ups and ends of the
        running goals."""
        for index, goal in list(self._goals.items()):
            if goal.after is not None:
                self._tick_follow_up(index, goal, goal.after)
                continue
            job, handle = goal.job, goal.handle
            if handle.is_cancel_requested and job.active:
                if not job.withdraw('canceled before it started', 'canceled'):
                    job.request_cancel(goal.action.cancel_reason)
            if job.active and not job.started and \
                    time.monotonic() - goal.requested > JOB_START_TIMEOUT:
                job.withdraw(f'the control cycle did not take the {goal.action.label} within '
                             f'{JOB_START_TIMEOUT:g} s (are states arriving?)')
            message = self._stall_message(job)
            if message:
                self._end_stalled(index, message)
            elif job.active:
                handle.publish_feedback(self._feedback(goal.action, goal.action.feedback(
                    job.feedback(self._controllers[index].estimator))))
            elif goal.action.follow is not None and job.outcome == 'succeeded':
                goal.after = goal.action.follow(index, job)
                self._tick_follow_up(index, goal, goal.after)
            else:
                self._end(index, job.outcome)

    def _tick_follow_up(self, index: int, goal: _Goal, after: FollowUp) -> None:
        """One tick of a goal's follow-up: its cancel, its feedback, its end."""
        if goal.handle.is_cancel_requested and after.outcome is None:
            after.cancel(goal.action.cancel_reason)
        if after.poll():
            self._end(index, after.outcome)
        else:
            goal.handle.publish_feedback(self._feedback(goal.action, after.feedback()))

    @staticmethod
    def _feedback(action: JobAction, fields: dict[str, float | str]) -> Any:
        feedback = action.action_type.Feedback()
        for name, value in fields.items():
            setattr(feedback, name, value)
        return feedback

    def _end(self, index: int, outcome: str | None) -> None:
        """The goal of a job (and follow-up) that is done: its status from ``outcome``, its
        result and log line."""
        goal = self._goals.pop(index)
        action, job, handle = goal.action, goal.job, goal.handle
        message = action.finish(index, job)
        result = action.result(index, job, message)
        if outcome == 'succeeded':
            handle.succeed()
        elif outcome == 'canceled':
            handle.canceled()
        else:
            handle.abort()
        self._node.get_logger().info(f'{self._channels[index]}: {action.label} {outcome}: '
                                     f'{message}')
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
        goal.job.request_abort(message)
        goal.handle.abort()
        self._node.get_logger().warn(f'{self._channels[index]}: {goal.action.label} aborted: '
                                     f'{message}')
        goal.done.set_result(goal.action.result(index, goal.job, message))

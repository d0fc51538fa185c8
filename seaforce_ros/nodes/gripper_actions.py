"""The control_msgs gripper actions of controller_node: one GripperCommand and one
ParallelGripperCommand action per channel, as :class:`~.jobs.JobAction` registrations.

Each goal becomes a :class:`~seaforce_ros.core.gripper.GripperMove` (a grasp whose approach
stops at a position X_e [rad]) through the node's :class:`~.jobs.JobActions`, like ``~/grasp``:

* names: ``<ns>/gripper_cmd`` (``control_msgs/action/GripperCommand``) and
  ``<ns>/parallel_gripper_cmd`` (``control_msgs/action/ParallelGripperCommand``), ``<ns>`` the
  channel's ``grasp.gripper_namespace`` or ``<channel>_gripper`` -- relative to the node's
  namespace, the shape MoveIt's simple controller manager expects (``action_ns: gripper_cmd``
  under a controller named ``<channel>_gripper``);
* GripperCommand: ``command.position`` [rad], ``command.max_effort`` [N m] (0 is no force:
  refused, as ros2_controllers' effort gripper controller would not move), the speed
  ``grasp.gripper_velocity``; ParallelGripperCommand: one joint -- ``command.position[0]``,
  the optional ``command.velocity[0]`` and ``command.effort[0]`` (empty: the channel's
  ``grasp.gripper_velocity`` / ``grasp.gripper_effort``, as ros2_controllers'
  parallel_gripper_controller takes its max_velocity / max_effort; MoveIt's handle sends them
  empty unless configured), ``command.name[0]`` (optional) is echoed in ``state.name``;
* a goal that cannot be executed (a bad field, a faulted channel, one a goal of another
  action holds, no states) is rejected by the goal callback -- control_msgs results carry no
  message -- and the reason logged (once per 10 s, with a count);
* a goal on a channel with a gripper command (running, or holding after its answer) takes
  its job over, bumplessly (:meth:`~seaforce_ros.core.gripper.GripperMove.request_retarget`);
  a running goal ends CANCELED (preempted), as with ros2_controllers' gripper controllers;
* the goal ends when the finger is within ``grasp.gripper_tolerance`` of the position
  (``reached_goal``: SUCCEEDED) or a contact stopped it and the finger grips at the effort
  cap (``stalled``: SUCCEEDED with ``grasp.gripper_allow_stalling``, else ABORTED, as
  ros2_controllers' ``allow_stalling``), and the job goes on holding the position or the grip
  until the channel's next goal;
* a cancel: ``grasp.gripper_cancel`` -- ``hold`` (an approach stops and holds where the
  finger is, a grip goes on) or ``release`` (as a grasp's cancel); either way the goal gives
  the channel up when the cancel is accepted (MoveIt sends its next goal right after the
  cancel's answer) and ends CANCELED at the next look (50-250 Hz), a releasing one once the
  release is done.

Feedback at :data:`~.jobs.JOB_FEEDBACK_RATE`: position X_e, effort = the contact force
estimate (from the hose pressure; > 0 pushing back), stalled, reached_goal; the result carries
them at the answer (a stall's effort: the grip at the cap).
"""
from __future__ import annotations

import math
from typing import Any

from control_msgs.action import GripperCommand, ParallelGripperCommand

from ..core.grasp import InvalidGoalError
from ..core.gripper import STALLED, GripperGoal, GripperMove, check_gripper_goal
from .jobs import JobAction

__all__ = ["gripper_job_actions", "action_namespace"]


def action_namespace(channel: str, namespace: str) -> str:
    """The namespace of ``channel``'s gripper actions: ``namespace`` or ``<channel>_gripper``."""
    return namespace or f'{channel}_gripper'


def gripper_job_actions(node: Any) -> list[JobAction]:
    """The two gripper actions of every channel of a controller node (``channels``,
    ``configs``, ``controllers``, ``dt``)."""
    actions = []
    for index, channel in enumerate(node.channels):
        ns = action_namespace(channel, node.configs[index].grasp.gripper_namespace)
        actions.append(_action(node, channel, f'{ns}/gripper_cmd', GripperCommand))
        actions.append(_action(node, channel, f'{ns}/parallel_gripper_cmd',
                               ParallelGripperCommand))
    return actions


def _one(values: Any, field: str, default: float) -> float:
    """The single entry of a JointState field; ``default`` when empty."""
    values = list(values)
    if len(values) > 1:
        raise InvalidGoalError(f'command.{field} has {len(values)} entries: one joint per '
                               'channel')
    return float(values[0]) if values else default


def _request(node: Any, index: int, channel: str, goal: Any, parallel: bool) -> GripperGoal:
    """The GripperGoal of a control_msgs goal (the channel's defaults filled in)."""
    grasp = node.configs[index].grasp
    command = goal.command
    if not parallel:
        return GripperGoal(channel, float(command.position), grasp.gripper_velocity,
                           float(command.max_effort))
    if len(command.position) != 1:
        raise InvalidGoalError(f'command.position has {len(command.position)} entries: one '
                               'joint per channel')
    names = list(command.name)
    if len(names) > 1:
        raise InvalidGoalError(f'command.name has {len(names)} entries: one joint per channel')
    return GripperGoal(channel, float(command.position[0]),
                       _one(command.velocity, 'velocity', grasp.gripper_velocity),
                       _one(command.effort, 'effort', grasp.gripper_effort),
                       names[0] if names else channel)


def _action(node: Any, channel: str, name: str, action_type: Any) -> JobAction:
    parallel = action_type is ParallelGripperCommand

    def make(index: int, goal: Any) -> GripperMove:
        request = _request(node, index, channel, goal, parallel)
        check_gripper_goal(request, node.configs[index])
        return GripperMove(request, node.configs[index], node.dt,
                           node.controllers[index].endpoint_position_estimate)

    def describe(goal: Any) -> str:
        command = goal.command
        if parallel:
            return (f'parallel gripper command to {list(command.position)} rad, velocity '
                    f'{list(command.velocity)}, effort {list(command.effort)}')
        return (f'gripper command to {command.position:g} rad, max_effort '
                f'{command.max_effort:g} N m')

    def figures(index: int, job: GripperMove | None) -> tuple[str, float, float, float]:
        """(joint, X_e [rad], V_e [rad/s], contact force estimate [N m]) now."""
        estimator = node.controllers[index].estimator
        force = 0.0 if not estimator.contact else abs(estimator.force)
        if job is not None:
            force = float(job.feedback(estimator)['effort'])
        return (job.gripper.joint if job is not None else channel, estimator.position,
                estimator.velocity, force)

    def state(index: int, job: GripperMove | None, message: Any) -> Any:
        joint, position, velocity, effort = figures(index, job)
        message.state.name = [joint]
        message.state.position = [position]
        message.state.velocity = [velocity]
        message.state.effort = [effort]
        return message

    def result(index: int | None, job: GripperMove | None, _message: str) -> Any:
        out = action_type.Result()
        if index is None:
            if parallel:
                out.state.name = [channel]
                out.state.position = [math.nan]
            else:
                out.position = math.nan
            return out
        out.stalled = bool(job is not None and job.stalled)
        out.reached_goal = bool(job is not None and job.reached_goal)
        if parallel:
            return state(index, job, out)
        _, out.position, _, out.effort = figures(index, job)
        return out

    def feedback(index: int, job: GripperMove) -> Any:
        out = action_type.Feedback()
        if parallel:
            return state(index, job, out)
        _, out.position, _, out.effort = figures(index, job)
        out.stalled = job.stalled
        out.reached_goal = job.reached_goal
        return out

    def on_cancel(job: GripperMove) -> bool:
        index = node.channels.index(channel)
        if node.configs[index].grasp.gripper_cancel != 'hold':
            return False
        job.request_stop()
        return True

    def answered(job: GripperMove) -> str:
        """The goal's status at the job's answer ('' before it): a stall SUCCEEDS only with
        grasp.gripper_allow_stalling."""
        answer = job.answer
        if answer is None:
            return ''
        grasp = node.configs[node.channels.index(channel)].grasp
        return 'aborted' if answer == STALLED and not grasp.gripper_allow_stalling \
            else 'succeeded'

    def retarget(running: Any, new: Any) -> bool:
        return isinstance(running, GripperMove) and isinstance(new, GripperMove) and \
            running.request_retarget(new)

    return JobAction(name, action_type, GripperMove.kind, make, result, describe,
                     busy=lambda job: f'is held by a {GripperMove.kind} goal ({job.phase})',
                     cancel_reason='released (goal canceled)',
                     channel=lambda goal: channel, answered=answered, retarget=retarget,
                     on_cancel=on_cancel, reject_in_callback=True, feedback=feedback)

"""Goals of the controller's actions (~/grasp, ~/calibrate_friction) from a test probe."""
import time

from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from seaforce_msgs.action import CalibrateFriction


#: s the probe's spin thread may take to run a request (a busy host's backlog of 2 kHz
#: messages in front of it took more than 10 s)
CALL_TIMEOUT = 60.0


def wait_future(future, timeout, what, probe=None):
    """The future's result; AssertionError after ``timeout`` s -- with a ``probe``, s of its
    clock (:meth:`~helpers.probe.Probe.wait_for`: wall time and the loop's time)."""
    if probe is not None:
        probe.wait_for(future.done, timeout, what)
        return future.result()
    deadline = time.monotonic() + timeout
    while not future.done():
        assert time.monotonic() < deadline, f'no {what} within {timeout} s'
        time.sleep(0.01)
    return future.result()


class ActionTestClient:
    """Goals of ``action_type`` to the action ``name`` through the probe's node; subclasses
    build the goal from keyword fields (:meth:`goal`). Every request is sent from the probe's
    spin thread (``BackgroundNode.call``): sent from the test's thread, an answer can arrive
    before rclpy registers the future waiting for it, and is dropped."""

    def __init__(self, probe, action_type, name):
        self.probe = probe
        self.action_type = action_type
        self.client = ActionClient(probe.node, action_type, name)
        assert self.client.wait_for_server(timeout_sec=30.0)

    def goal(self, **fields):
        raise NotImplementedError

    def _call(self, request):
        return self.probe.background.call(request, timeout=CALL_TIMEOUT)

    def send(self, **fields):
        feedback = []
        goal = self.goal(**fields)
        handle = wait_future(self._call(lambda: self.client.send_goal_async(
            goal, feedback_callback=lambda m: feedback.append(m.feedback))),
            30.0, 'goal answer', self.probe)
        assert handle.accepted
        return handle, feedback

    def result(self, handle, timeout=30.0):
        return wait_future(self._call(handle.get_result_async), timeout, 'result', self.probe)

    def cancel(self, handle, timeout=30.0):
        wait_future(self._call(handle.cancel_goal_async), timeout, 'cancel answer', self.probe)
        return self.result(handle, timeout)

    def rejected(self, **fields):
        """A goal that must end at once, ABORTED with ``rejected: <reason>``: the message."""
        handle, _ = self.send(**fields)
        answer = self.result(handle)
        assert answer.status == GoalStatus.STATUS_ABORTED
        assert answer.result.message.startswith('rejected: '), answer.result.message
        return answer.result.message


class CalibrationClient(ActionTestClient):
    """``~/calibrate_friction`` goals (default: the ``pinch`` finger, 0.4 rad at 1 rad/s,
    applied)."""

    def __init__(self, probe):
        super().__init__(probe, CalibrateFriction, '/controller/calibrate_friction')

    def goal(self, channel='pinch', amplitude=0.4, speed=1.0, apply=True):
        return CalibrateFriction.Goal(channel=channel, amplitude=float(amplitude),
                                      speed=float(speed), apply=apply)

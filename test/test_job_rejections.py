"""The job path's goal rejections (``seaforce_ros.nodes.jobs.JobActions``): each reason is
logged when it first comes, throttled per action and reason (10 s, with a count of the ones
in between), so a rejection of one kind never hides another's reason. In-process, on a
stand-in node (no ROS graph): the logger's lines are what is checked."""
import types

from seaforce_ros.nodes.jobs import JobActions


class _Logger:
    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(text)

    error = info = warning


def _actions():
    logger = _Logger()
    node = types.SimpleNamespace(context=None, create_timer=lambda *a, **k: None,
                                 get_logger=lambda: logger)
    jobs = JobActions(node, ['pinch'], [], cycle=None, stalled=lambda: '')
    return jobs, logger


def _goal_for(label, channel):
    return types.SimpleNamespace(label=label, channel=lambda goal: channel)


def test_each_action_and_reason_is_logged_and_throttled_apart():
    jobs, logger = _actions()
    gripper, grasp = _goal_for('gripper command', 'thumb'), _goal_for('grasp', 'wrist')
    for _ in range(11):
        assert jobs._check(gripper, None) is None
    assert jobs._check(grasp, None) is None        # another action, another reason: logged
    assert len(logger.lines) == 2, logger.lines
    assert logger.lines[0].startswith('gripper command goal rejected: unknown channel')
    assert logger.lines[1].startswith("grasp goal rejected: unknown channel 'wrist'")
    assert 'more such episode' not in logger.lines[1]
    assert jobs.last_rejection.startswith("unknown channel 'wrist'")

"""What MoveIt 2 (Jazzy) does with a gripper, as far as the tests need it: the configuration
snippets of docs/gripper-actions.md, the time parameterisation of a one-joint motion and the
execution duration its trajectory execution manager allows."""
import math
import re

import yaml

from helpers.processes import ROOT

#: trajectory_execution.allowed_execution_duration_scaling and
#: allowed_goal_duration_margin [s]: MoveIt's defaults
DURATION_SCALING = 1.1
DURATION_MARGIN = 0.5


def snippets():
    """(moveit_simple_controller_manager section, joint_limits section) of the docs."""
    text = (ROOT / 'docs' / 'gripper-actions.md').read_text()
    blocks = [yaml.safe_load(b) for b in re.findall(r'```yaml\n(.*?)```', text, re.S)]
    (controllers,) = [b['moveit_simple_controller_manager'] for b in blocks
                      if 'moveit_simple_controller_manager' in b]
    (limits,) = [b['joint_limits'] for b in blocks if 'joint_limits' in b]
    return controllers, limits


def planned_duration(distance, velocity, acceleration):
    """Duration [s] of a rest-to-rest motion of ``distance`` [rad] at the limits (rad/s,
    rad/s^2): the trapezoid (or triangle) a time-optimal parameterisation of one joint gives."""
    distance = abs(distance)
    if distance * acceleration >= velocity ** 2:
        return distance / velocity + velocity / acceleration
    return 2.0 * math.sqrt(distance / acceleration)


def allowed_duration(planned):
    """How long MoveIt lets an execution of ``planned`` [s] run before it cancels it."""
    return DURATION_SCALING * planned + DURATION_MARGIN

"""The ``~/commission`` goal's checks and run directory (seaforce_ros.nodes.commissioning),
without a running node: a contact the estimator reports while the finger moves turns the goal
away; one that has stood with the finger still for STANDING_TIME is logged and the goal
accepted (the model's error at rest; the excitation's contact test aborts at a real one); a
band beyond the Nyquist frequency pi/T is refused at goal time; ``commissioning.directory``
and ``commissioning.params_file`` are read at each goal; a run that ends with nothing written
leaves no directory."""
import math
import types

import pytest
from seaforce_msgs.action import Commission

from seaforce_ros.commissioning.excitation import FreeAirExcitation
from seaforce_ros.core.estimator import REST_SPEED
from seaforce_ros.core.jobs import InvalidJobGoalError
from seaforce_ros.core.params import ControllerConfig
from seaforce_ros.nodes.commissioning import RECENT_CONTACT, STANDING_TIME, CommissionAction

DT = 5e-4


class Logger:
    def __init__(self):
        self.warnings = []

    def warning(self, text):
        self.warnings.append(text)


class FakeNode:
    """What CommissionAction reads of a controller node: channels, configs, controllers'
    estimators, dt, the logger, its commissioning.* parameters."""

    def __init__(self, directory=''):
        self.parameters = {'commissioning.directory': directory,
                           'commissioning.params_file': ''}
        self.channels = ['pinch']
        self.configs = [ControllerConfig()]
        self.estimator = types.SimpleNamespace(contact=False, force=0.0, velocity=0.0)
        self.controllers = [types.SimpleNamespace(estimator=self.estimator)]
        self.dt = DT
        self.logger = Logger()

    def get_logger(self):
        return self.logger

    def get_parameter(self, name):
        return types.SimpleNamespace(value=self.parameters[name])


def status_stream(action, velocities, start=0, every=20, contacts=None):
    """The status loop (every 20 cycles: 100 Hz) seeing these endpoint velocities (and
    contact flags: the estimator's own by default)."""
    cycle = start
    for k, v in enumerate(velocities):
        contact = action._node.estimator.contact if contacts is None else contacts[k]
        action.observe(cycle, [v], [contact])
        cycle += every
    return cycle


@pytest.fixture
def setup(tmp_path):
    node = FakeNode(str(tmp_path / 'runs'))
    return node, CommissionAction(node)


def test_a_contact_while_the_finger_moves_is_refused(setup):
    node, action = setup
    node.estimator.contact, node.estimator.force = True, -0.02
    # a finger swinging at 0.4 rad/s amplitude, 0.05 Hz: never still for 2 s
    status_stream(action, [0.4 * math.sin(2 * math.pi * 0.05 * k / 100.0) for k in range(3000)])
    with pytest.raises(InvalidJobGoalError, match='the finger is not free'):
        action._make(0, Commission.Goal(channel='pinch'))
    assert not node.logger.warnings


def test_a_contact_standing_still_is_logged_and_the_goal_accepted(setup):
    node, action = setup
    node.estimator.contact, node.estimator.force = True, -0.005
    n = int(math.ceil(STANDING_TIME / (20 * DT))) + 2
    cycle = status_stream(action, [0.5] * 50)                 # moving, then still
    status_stream(action, [0.5 * REST_SPEED] * (n - 5), start=cycle)
    with pytest.raises(InvalidJobGoalError):                 # still, but not yet long enough
        action._make(0, Commission.Goal(channel='pinch'))
    status_stream(action, [0.5 * REST_SPEED] * n, start=cycle + 20 * (n - 5))
    job = action._make(0, Commission.Goal(channel='pinch'))
    assert isinstance(job, FreeAirExcitation)
    assert node.logger.warnings and 'taken for the model' in node.logger.warnings[0]
    # a motion again restarts the clock
    action.observe(10 ** 6, [2.0 * REST_SPEED], [True])
    with pytest.raises(InvalidJobGoalError):
        action._make(0, Commission.Goal(channel='pinch'))


def test_a_contact_that_flickers_off_at_a_reversal_still_turns_the_goal_away(setup):
    """A finger pushed back and forth drops its contact flag around each reversal of the
    force: a goal there is refused while a contact was reported within RECENT_CONTACT, and
    accepted once none was for longer (and the finger moves on, free)."""
    node, action = setup
    node.estimator.force = 0.0
    n = 300
    cycle = status_stream(action, [0.3] * n, contacts=[k % 100 < 80 for k in range(n - 1)]
                          + [False])                  # off for the last 0.2 s of statuses
    node.estimator.contact = False                       # the flag is off right now
    with pytest.raises(InvalidJobGoalError, match='the finger is not free'):
        action._make(0, Commission.Goal(channel='pinch'))
    quiet = int(math.ceil(RECENT_CONTACT / (20 * DT))) + 1
    status_stream(action, [0.3] * quiet, start=cycle, contacts=[False] * quiet)
    assert isinstance(action._make(0, Commission.Goal(channel='pinch')), FreeAirExcitation)


def test_no_contact_is_accepted_at_once(setup):
    node, action = setup
    assert isinstance(action._make(0, Commission.Goal(channel='pinch')), FreeAirExcitation)
    node.estimator.contact = True                            # no status seen yet: moving
    with pytest.raises(InvalidJobGoalError):
        action._make(0, Commission.Goal(channel='pinch'))


def test_a_non_finite_velocity_counts_as_moving(setup):
    node, action = setup
    node.estimator.contact = True
    status_stream(action, [math.nan] * 1000)
    with pytest.raises(InvalidJobGoalError):
        action._make(0, Commission.Goal(channel='pinch'))


def test_a_band_beyond_the_nyquist_frequency_is_refused_at_goal_time(setup):
    _, action = setup
    with pytest.raises(InvalidJobGoalError, match=r'band_high = 7540 .*pi/T = 6283 rad/s'):
        action._make(0, Commission.Goal(channel='pinch', band_high=7540.0))
    assert isinstance(action._make(0, Commission.Goal(channel='pinch', band_high=6000.0)),
                      FreeAirExcitation)


def test_the_directory_and_params_file_are_read_at_each_goal(setup, tmp_path):
    node, action = setup
    action._make(0, Commission.Goal(channel='pinch'))
    first = action._runs[0]
    assert first.directory.parent == tmp_path / 'runs'
    node.parameters['commissioning.directory'] = str(tmp_path / 'elsewhere')
    node.parameters['commissioning.params_file'] = str(tmp_path / 'setup.yaml')
    action._make(0, Commission.Goal(channel='pinch'))
    run = action._runs[0]
    assert run.directory.parent == tmp_path / 'elsewhere'
    assert run.request['params_file'] == str(tmp_path / 'setup.yaml')


def test_a_run_that_wrote_nothing_leaves_no_directory(setup):
    _, action = setup
    job = action._make(0, Commission.Goal(channel='pinch'))
    directory = action._runs[0].directory
    assert directory.is_dir()
    action._result(0, job, 'canceled')                  # canceled during the excitation
    assert not directory.exists()
    job = action._make(0, Commission.Goal(channel='pinch'))
    directory = action._runs[0].directory
    (directory / 'record.npz').write_bytes(b'')         # the analysis had started
    action._result(0, job, 'canceled')
    assert (directory / 'record.npz').exists()

"""Shared fixtures: isolated ROS graph per test run, rclpy contexts, managed node processes."""
import os
import pathlib
import sys
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'test'))

# Every test run gets its own DDS domain and stays on this host (set before rclpy is imported
# anywhere, and inherited by every process the tests start).
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
# Under pytest-xdist (scripts/test runs two workers) each worker is a test run of its own: its
# domain is the session's moved by 50 per worker, and so are the stacks' own (helpers.nodes)
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
_WORKER_INDEX = int(_WORKER[2:]) if _WORKER.startswith('gw') else 0
if _WORKER:
    os.environ['ROS_DOMAIN_ID'] = str(
        1 + (int(os.environ['ROS_DOMAIN_ID']) - 1 + 50 * _WORKER_INDEX) % 100)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# numpy's BLAS on one thread here and in every process a test starts (scripts/setup.sh says
# why; before numpy is first imported)
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

from helpers.processes import ProcessGroup, stop_leftovers  # noqa: E402
from ethercat.fixtures import _shared_line, ecat_bus, ecat_emulator, soem_master  # noqa: E402,F401


def pytest_addoption(parser):
    parser.addoption('--cpu-hog', action='store_true',
                     help='run the whole session next to one CPU-burning process per core '
                          '(normal priority): the tests must pass on a busy host')


def _start_hogs(group, shared=False):
    """One busy-looping process per core, ended by PID with the group; ``shared``: the
    session's, shared out among the xdist workers (one per core in all)."""
    cores = os.cpu_count() or 1
    count = cores
    if shared:
        workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
        count = cores // workers + (1 if _WORKER_INDEX < cores % workers else 0)
    for _ in range(count):
        # SIGINT ends it even where the shell that started the run ignores SIGINT for its
        # background jobs (a `nohup ... &` run: each hog then took SIGKILL after 5 s)
        group.start([sys.executable, '-c', 'import signal\n'
                     'signal.signal(signal.SIGINT, signal.SIG_DFL)\nwhile True: pass'],
                    name='cpu_hog')


@pytest.fixture(scope='session', autouse=True)
def _session_cpu_hog(request):
    group = ProcessGroup()
    if request.config.getoption('--cpu-hog'):
        _start_hogs(group, shared=True)
    try:
        yield
    finally:
        group.stop_all()


#: How long a real-time test beside the hogs waits for the other xdist worker to pause at its
#: next test boundary [s], and how long a worker pauses for one at most (a bound against a
#: worker that died holding its flag).
PAUSE_ACK, PAUSE_MAX = 30.0, 300.0


def _pause_dir(tmp_path_factory):
    """A directory the xdist workers of this run share (their basetemps' parent)."""
    path = tmp_path_factory.getbasetemp().parent / 'realtime-pause'
    path.mkdir(exist_ok=True)
    return path


@pytest.fixture
def cpu_hog(request, processes, tmp_path_factory):
    """One CPU-burning process per core, at normal priority, for this test (unless the whole
    session already runs next to them: --cpu-hog). Under xdist the other worker pauses at its
    next test boundary first (up to PAUSE_ACK s): the test runs beside the hogs, not beside
    the hogs and another worker's tests."""
    flag = None
    if _WORKER:
        pause = _pause_dir(tmp_path_factory)
        flag = pause / f'hold-{_WORKER}'
        flag.touch()
        deadline = time.monotonic() + PAUSE_ACK    # until no other worker is in a test
        while time.monotonic() < deadline and any(
                p.name != f'busy-{_WORKER}' for p in pause.glob('busy-*')):
            time.sleep(0.1)
    try:
        if not request.config.getoption('--cpu-hog'):
            _start_hogs(processes)
        yield
    finally:
        if flag is not None:
            flag.unlink(missing_ok=True)


@pytest.fixture(autouse=True)
def _pause_for_realtime(tmp_path_factory):
    """(xdist) wait at this test's start while another worker's real-time test holds its
    flag (:func:`cpu_hog`), at most PAUSE_MAX s."""
    if not _WORKER:
        yield
        return
    pause = _pause_dir(tmp_path_factory)
    deadline = time.monotonic() + PAUSE_MAX
    while time.monotonic() < deadline and any(
            p.name != f'hold-{_WORKER}' for p in pause.glob('hold-*')):
        time.sleep(0.1)
    busy = pause / f'busy-{_WORKER}'     # in a test (a worker with none left is not waited for)
    busy.touch()
    try:
        yield
    finally:
        busy.unlink(missing_ok=True)


@pytest.fixture
def processes():
    """Start processes for a test and end every one of them by PID afterwards, pass or fail."""
    group = ProcessGroup()
    try:
        yield group
    finally:
        group.stop_all()


@pytest.fixture
def probe(request):
    """A test-side ROS node (helpers.probe.Probe) on its own context, closed afterwards."""
    from helpers.probe import Probe
    p = Probe(f'probe_{request.module.__name__.rsplit(".", 1)[-1]}')
    try:
        yield p
    finally:
        p.close()


@pytest.fixture
def ros_context():
    """A fresh rclpy Context, shut down after the test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


# --- xdist: which worker runs what ----------------------------------------------------------
#: The test files that start ROS stacks and measure them (nodes, demos, benches, the EtherCAT
#: emulator). Under xdist with ``--dist loadfile`` (scripts/test) they are one unit of work:
#: one worker runs them one file after another while the other takes the rest file by file,
#: so that two stacks never share the 2 cores (two at once failed the commissioning tests;
#: with the three lockstep demos on the other worker at nice 10, a real-time probe beside them
#: lost 21 % of its states, test_friction_calibration_ros, 2026-12-06) and each runs beside at
#: most one single-threaded test (niced: REST_NICENESS). The tests beside the CPU hogs
#: (test_grasp_ros, test_hardware_node) come last, when the other worker's files are short:
#: each waits for it to end its test (up to PAUSE_ACK).
STACKS = ('test_demo.py', 'test_benches_live.py', 'test_commission_ros.py',
          'test_friction_calibration_ros.py', 'test_bag_recorder.py', 'test_safety_ros.py',
          'test_cycle_faults_ros.py', 'test_closed_loop.py', 'test_controller_modes_ros.py',
          'test_passivity_guard_ros.py', 'test_layouts_ros.py', 'test_gripper_actions_ros.py',
          'test_identification_ros.py', 'ethercat/test_backend.py', 'ethercat/test_emulator.py',
          'ethercat/test_harness.py', 'test_grasp_ros.py', 'test_hardware_node.py')
#: The longest other files, longest first, at the head of the queue the scheduler hands out
#: after STACKS (the rest follow in collection order), so that the other worker's last files
#: are short ones.
LONGEST = ('test_benches.py', 'commissioning/test_free_air.py',
           'commissioning/test_nonlinear_compensation.py', 'test_identification_random.py',
           'core/test_per_sample_exact.py', 'test_startup_errors.py',
           'core/test_passivity_guard.py', 'commissioning/test_analyse.py',
           'commissioning/test_report.py', 'core/test_friction_calibration.py',
           'core/test_safety.py', 'commissioning/test_nonlinear_terms.py')


def _test_path(nodeid):
    return nodeid.split('::', 1)[0].removeprefix('test/')


def pytest_collection_modifyitems(items):
    if _WORKER:                    # the stacks in STACKS' order, then LONGEST, then the rest
        rank = {name: i for i, name in enumerate(STACKS + LONGEST)}
        items.sort(key=lambda item: rank.get(_test_path(item.nodeid), len(rank)))


#: The niceness of the worker's main thread (and what it starts) while it runs a test file
#: that is not in STACKS: the stacks' loops wait on each other (a lockstep step is a round
#: trip through three processes), so a CPU-bound test beside them at the same priority slowed
#: one 20 s test to 120 s; niced, it takes the CPU they leave.
REST_NICENESS = 10


@pytest.fixture(scope='module', autouse=True)
def _stacks_first(request):
    """(xdist workers) the module's niceness: 0 for a STACKS file, REST_NICENESS else (set
    before the module's own fixtures start anything: a higher scope's autouse fixture runs
    first). Without the right to lower it again (not root, no CAP_SYS_NICE) a worker stays
    at the higher one, as if nothing were niced."""
    if _WORKER:
        want = 0 if _test_path(request.node.nodeid) in STACKS else REST_NICENESS
        try:
            os.setpriority(os.PRIO_PROCESS, 0, want)
        except PermissionError:
            pass
    yield


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """(xdist controller, ``--dist loadfile``) every file its own unit of work, but the
    STACKS one unit. (xdist's ``loadgroup`` would say the same with marks, but it renames
    the test's node id, which pytest 9 no longer lets it do: its groups are lost.)"""
    if config.getvalue('dist') != 'loadfile':
        return None
    # the units in the workers' collection order (pytest_collection_modifyitems: STACKS,
    # LONGEST, the rest), not by their number of tests
    config.option.loadscopereorder = False
    from xdist.scheduler import LoadFileScheduling

    class StacksTogether(LoadFileScheduling):
        def _split_scope(self, nodeid):
            path = _test_path(nodeid)
            return 'stacks' if path in STACKS else super()._split_scope(nodeid)

    return StacksTogether(config, log)


# --- session end ---------------------------------------------------------------------------
_session = {}


def pytest_terminal_summary(terminalreporter):
    """Process stops that were slow (time every run pays in teardown), grouped."""
    from helpers.processes import SLOW_STOP, slow_stops
    if slow_stops:
        groups = {}
        for name, took, how in slow_stops:
            groups.setdefault((name, how), []).append(took)
        terminalreporter.write_sep('-', f'process stops slower than {SLOW_STOP:g} s')
        for (name, how), took in sorted(groups.items(), key=lambda kv: -sum(kv[1])):
            terminalreporter.write_line(f'{len(took):3d} x {name}: {sum(took):.1f} s in all '
                                        f'(max {max(took):.1f} s), {how}')


def pytest_sessionfinish(session, exitstatus):
    _session['status'] = int(exitstatus)
    workeroutput = getattr(session.config, 'workeroutput', None)
    if workeroutput is not None:          # an xdist worker: its slow stops go to the controller
        from helpers.processes import slow_stops
        workeroutput['slow_stops'] = [list(stop) for stop in slow_stops]


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """(xdist controller) a worker's slow process stops, for the summary above."""
    from helpers.processes import slow_stops
    slow_stops.extend(tuple(stop) for stop in getattr(node, 'workeroutput', {}).get(
        'slow_stops', []))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """End the test process deterministically once pytest has reported.

    Every process a test started is ended by PID first (a safety net behind the fixtures).
    Then the interpreter leaves without running finalizers: the rclpy objects of the PyPI
    wheels (the EventsExecutor above all) can abort or block while the interpreter tears them
    down, which would turn a finished, reported run into a crash or a hang.
    """
    leftovers = stop_leftovers()
    if leftovers:
        print(f'conftest: ended {leftovers} process(es) a test left running', file=sys.stderr)
    if 'status' in _session:
        from ethercat import harness
        harness._stop_leftovers()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_session['status'])



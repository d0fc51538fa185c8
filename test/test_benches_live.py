"""The smoke runs of the benchmarks that start ROS nodes or the EtherCAT emulator and time
their loops (test_benches.LIVE): as test_benches.py, in a file of their own so that they run
on the worker of the ROS stacks (conftest.STACKS), one stack at a time, while the offline
benches' run beside them."""
import pytest

from test_benches import ALL_RUNS, LIVE, check, ids, run_all

RUNS = [run for run in ALL_RUNS if run[0] in LIVE]


@pytest.fixture(scope='module')
def live_runs():
    # DDS domains after the offline benches' (the two files may run at once)
    yield from run_all(RUNS, domain_offset=len(ALL_RUNS))


@pytest.mark.parametrize('index', range(len(RUNS)), ids=ids(RUNS))
def test_live_bench_runs_quick(live_runs, index):
    check(RUNS[index], live_runs[index])

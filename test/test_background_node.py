"""ros_common.BackgroundNode.call: rclpy requests made from the node's spin thread.

Jazzy's ActionClient sends a request before it registers the future that waits for the
answer; from a thread other than the spin thread an early answer is dropped (seen in CI:
"Ignoring unexpected cancel response", a cancel never answered). ``call`` runs the request
where no answer can be taken in between."""
import threading

import pytest

from seaforce_ros.nodes.ros_common import BackgroundNode


@pytest.fixture
def background():
    node = BackgroundNode('test_background_call')
    yield node
    node.close()


def test_call_runs_on_the_spin_thread_and_returns_the_result(background):
    assert threading.current_thread() is threading.main_thread()
    names = [background.call(lambda: threading.current_thread().name) for _ in range(20)]
    assert names == ['test_background_call_spin'] * 20
    assert background.call(lambda: 6 * 7) == 42


def test_call_raises_what_the_function_raised(background):
    def broken():
        raise ValueError('bad request')
    with pytest.raises(ValueError, match='bad request'):
        background.call(broken)
    assert background.call(lambda: 'still spinning') == 'still spinning'


def test_call_times_out_with_a_clear_error_when_the_spin_thread_is_busy(background):
    release = threading.Event()
    background.executor.create_task(lambda: release.wait(10.0))
    try:
        with pytest.raises(TimeoutError, match='did not run a call within 0.2 s'):
            background.call(lambda: None, timeout=0.2)
    finally:
        release.set()

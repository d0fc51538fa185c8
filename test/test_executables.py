"""The installed executables (what `ros2 run seaforce_ros <name>` runs) start and stop cleanly."""
import signal

import pytest

from helpers.nodes import start_node

NODES = [('sim_node', 'sim'), ('controller_node', 'controller'), ('bringup', 'controller')]


@pytest.mark.parametrize('executor', ['events', 'single_threaded'])
@pytest.mark.parametrize('name,node_name', NODES)
def test_node_comes_up_and_exits_cleanly_on_sigint(processes, tmp_path, name, node_name, executor):
    proc = start_node(processes, name, node_name, tmp_path, {'executor': executor})
    assert proc.popen.poll() is None, proc.output()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=5.0)
    assert code == 0, f'exit code {code}\n{proc.output()}'
    out = proc.output()
    assert 'Traceback' not in out and 'FATAL' not in out, out


@pytest.mark.parametrize('name,node_name', NODES)
def test_node_exits_cleanly_on_sigterm(processes, tmp_path, name, node_name):
    proc = start_node(processes, name, node_name, tmp_path)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=5.0) == 0, proc.output()


def test_bad_configuration_is_a_clear_error_not_a_traceback(processes, tmp_path):
    proc = start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'pinch.dob.nominal_inertia': 1e-5}, wait=False)
    code = proc.wait(timeout=60)
    out = proc.output()
    assert code == 2, out
    assert 'cannot start' in out and 'dob.nominal_inertia' in out and 'Traceback' not in out, out

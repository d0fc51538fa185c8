import time
import numpy as np
import pytest
from seaforce_msgs.msg import ActuatorState, ControllerStatus
from helpers.nodes import start_node
from helpers.states import value


@pytest.mark.parametrize('hog', [False, True])
def test_gaps(processes, tmp_path, probe, request, hog):
    if hog:
        request.getfixturevalue('cpu_hog')
    start_node(processes, 'sim_node', 'sim', tmp_path, {})
    start_node(processes, 'controller_node', 'controller', tmp_path, {'status_rate': 2000.0})
    probe.record(ControllerStatus, 'controller_status')
    probe.record(ActuatorState, 'actuator_state')
    probe.wait_messages('controller_status', 5, timeout=60)
    time.sleep(1)
    probe.clear('controller_status'); probe.clear('actuator_state')
    time.sleep(8)
    c = np.array([m.cycle for m in probe.messages('controller_status')])
    st = [value(m, 'pinch', 'status') for m in probe.messages('actuator_state')]
    d = np.diff(c)
    print('\nhog', hog, 'n', len(c), 'span', c[-1]-c[0], 'hist', {k: int(np.sum(d == k)) for k in range(1, 12)}, '>11:', sorted(d[d > 11].tolist())[-30:], 'timeouts', sum(1 for s in st if s & 1), 'of', len(st))

"""Round-trip latencies of the control_msgs gripper actions (GripperCommand on
``/pinch_gripper/gripper_cmd``), sim_node + controller_node as separate processes in real time
(the default layout).

Per goal: *accepted* -- send_goal_async until the goal response (the goal callback's checks
included); *free air* -- the goal sent until its result (reached_goal) for a 0.3 rad move at
the default 0.3 rad/s (the motion's own ~1 s is in it); *contact -> result* -- the first
actuator_state in which the simulated object pushes on the finger (its stamp, the plant's
system time) until the result (stalled) arrived here, in ms and in cycles (the newest state
cycle this process had then; the detection's delay, the squeeze to the cap and the finger
coming to rest at the grip are in it); *rejected* -- a NaN goal until its rejection. The figures are printed (median, max over ``--goals``).

Run:  source scripts/setup.sh && python bench/gripper_actions.py [--goals 5] [--quick]
      (--quick: one goal of each kind, a smoke run)
"""
import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import yaml
from control_msgs.action import GripperCommand
from rclpy.action import ActionClient
from seaforce_msgs.msg import ActuatorState

from seaforce_ros.nodes.ros_common import RECORD_QOS, BackgroundNode

ROOT = pathlib.Path(__file__).resolve().parent.parent
LIB = ROOT / 'install' / 'seaforce_ros' / 'lib' / 'seaforce_ros'


def start(name, node, overrides, directory):
    path = directory / f'{node}.yaml'
    path.write_text(yaml.safe_dump({node: {'ros__parameters': overrides}}))
    return subprocess.Popen([str(LIB / name), '--ros-args', '--params-file',
                             str(ROOT / 'config' / 'gripper.yaml'), '--params-file', str(path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait(future, timeout=30.0):
    deadline = time.monotonic() + timeout
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError('no answer')
        time.sleep(0.0005)
    return future.result()


class Bench:
    def __init__(self):
        self.bg = BackgroundNode('gripper_actions_bench')
        self.node = self.bg.node
        self.lock = threading.Lock()
        self.states = []
        self.node.create_subscription(ActuatorState, 'actuator_state', self._state, RECORD_QOS)
        self.client = ActionClient(self.node, GripperCommand, '/pinch_gripper/gripper_cmd')
        from rcl_interfaces.srv import SetParameters
        self.params = self.node.create_client(SetParameters, '/sim/set_parameters')

    def _state(self, msg):
        pinch = list(msg.name).index('pinch')
        with self.lock:
            self.states.append((msg.cycle, msg.header.stamp.sec * 10**9
                                + msg.header.stamp.nanosec, msg.endpoint_position[pinch],
                                msg.external_force[pinch]))

    def latest(self):
        with self.lock:
            return self.states[-1]

    def set_sim(self, values):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        request = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                    for k, v in values.items()])
        wait(self.bg.call(lambda: self.params.call_async(request)))

    def goal(self, position, effort=0.3):
        """(accepted after [s], handle, result future, {'arrived': (ns, cycle)}); ``effort``:
        the max_effort MoveIt's handle sends (docs/gripper-actions.md's snippet)."""
        goal = GripperCommand.Goal()
        goal.command.position = float(position)
        goal.command.max_effort = float(effort)
        t0 = time.perf_counter()
        handle = wait(self.bg.call(lambda: self.client.send_goal_async(goal)))
        accepted = time.perf_counter() - t0
        arrived = {}
        if not handle.accepted:
            return accepted, handle, None, arrived

        def request():
            future = handle.get_result_async()
            future.add_done_callback(lambda f: arrived.update(
                ns=time.time_ns(), cycle=self.latest()[0]))
            return future
        return accepted, handle, self.bg.call(request), arrived


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--goals', type=int, default=5)
    parser.add_argument('--quick', action='store_true', help='smoke run: one goal of each kind')
    args = parser.parse_args()
    if args.quick:
        args.goals = 1
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        procs = [start('sim_node', 'sim', {'pinch.environment.mode': 'object',
                                           'pinch.environment.position': 10.0}, tmp),
                 start('controller_node', 'controller', {'state_timeout': 0.5}, tmp)]
        bench = Bench()
        try:
            run(bench, args.goals)
        finally:
            bench.bg.close()
            for p in procs:
                p.terminate()
                p.wait(10)


def run(bench, goals):
    if not bench.client.wait_for_server(timeout_sec=60.0):
        sys.exit('the gripper action did not come up')
    assert bench.params.wait_for_service(timeout_sec=30.0)
    # not measured: a goal to where the finger is, until the controller takes goals (a busy
    # host brings the loop up slowly, and a goal before its first states is refused)
    deadline = time.monotonic() + 60.0
    while True:
        with bench.lock:
            here = bench.states[-1][2] if bench.states else None
        handle = future = None
        if here is not None:
            _, handle, future, _ = bench.goal(here)
        if handle is not None and handle.accepted:
            wait(future)
            break
        if time.monotonic() > deadline:
            sys.exit('the gripper action refused every goal for 60 s (see the controller log)')
        time.sleep(0.5)
    figures = {'accepted [ms]': [], 'free air, sent -> result [ms]': [],
               'contact -> result [ms]': [], 'contact -> result [cycles]': [],
               'rejected [ms]': []}
    for n in range(goals):
        home = bench.latest()[2]
        accepted, handle, future, _ = bench.goal(home + 0.3)
        t0 = time.perf_counter()
        answer = wait(future)
        figures['free air, sent -> result [ms]'].append(1e3 * (time.perf_counter() - t0
                                                               + accepted))
        figures['accepted [ms]'].append(1e3 * accepted)
        assert answer.result.reached_goal, answer.result
        # an object 0.1 rad on, the goal beyond it
        surface = bench.latest()[2] + 0.1
        bench.set_sim({'pinch.environment.position': surface,
                       'pinch.environment.stiffness': 3.0, 'pinch.environment.damping': 0.06})
        start_cycle = bench.latest()[0]
        accepted, handle, future, arrived = bench.goal(surface + 0.3, 0.3)
        figures['accepted [ms]'].append(1e3 * accepted)
        answer = wait(future)
        assert answer.result.stalled, answer.result
        with bench.lock:
            touch = next(s for s in bench.states if s[0] > start_cycle and s[3] < 0.0)
        # (the future is done before its done-callback has run: on a busy host the arrival is
        # written a little after wait() returns)
        deadline = time.monotonic() + 10.0
        while 'cycle' not in arrived and time.monotonic() < deadline:
            time.sleep(0.01)
        figures['contact -> result [ms]'].append((arrived['ns'] - touch[1]) / 1e6)
        figures['contact -> result [cycles]'].append(arrived['cycle'] - touch[0])
        bench.set_sim({'pinch.environment.position': 10.0})
        accepted, handle, future, _ = bench.goal(home)        # open: releases, moves back
        wait(future)
        t0 = time.perf_counter()
        accepted, handle, _, _ = bench.goal(float('nan'))
        assert not handle.accepted
        figures['rejected [ms]'].append(1e3 * accepted)
        print(f'goal {n + 1}/{goals} done', file=sys.stderr)
    print(f'{"figure":32s} {"median":>8s} {"max":>8s}   (n)')
    for name, values in figures.items():
        print(f'{name:32s} {statistics.median(values):8.1f} {max(values):8.1f}   '
              f'({len(values)})')


if __name__ == '__main__':
    main()

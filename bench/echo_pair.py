#!/usr/bin/env python3
"""The platform's own limit: a bare rclpy state -> command echo with the project's messages.

`--role source` publishes seaforce_msgs/ActuatorState (two channels) from a thread with
absolute deadlines at `--rate` and listens for ActuatorCommand; `--role echo` answers every
state with a command carrying its cycle and nothing else. The source measures the same
figures the sim node reports (round trip, commands in time before the next cycle) over
`--seconds` from the end of `--warmup` or, later, the first answer, and prints them as one JSON
line. Used by bench/control_loop.py.
"""
import argparse
import json
import pathlib
import sys
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import rclpy  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402
from seaforce_msgs.msg import ActuatorCommand, ActuatorState  # noqa: E402

from seaforce_ros.nodes.ros_common import (control_qos, make_executor, spin_forever,  # noqa: E402
                                     stamp_now)
from seaforce_ros.nodes.timing import Deadline, LoopStats  # noqa: E402


def source(node, args):
    dt = 1.0 / args.rate
    sent = [0.0] * 8192
    rtts = []
    state = {'answered': -1}
    late = [0]

    def on_command(msg):
        now = time.monotonic()
        state['answered'] = msg.cycle
        rtts.append(now - sent[msg.cycle % len(sent)])

    node.create_subscription(ActuatorCommand, 'actuator_command', on_command,
                             control_qos(args.qos, subscriber=True))
    pub = node.create_publisher(ActuatorState, 'actuator_state', control_qos(args.qos))
    msg = ActuatorState()
    msg.name = ['wrist', 'pinch']
    stats = LoopStats(dt)
    result = {}

    def loop():
        deadline = Deadline(dt)
        cycle = 0
        # the measurement starts after the warm-up once the echo answers (a busy host starts
        # it slowly), or 30 s later without it
        t_start = time.monotonic() + args.warmup
        t_end = t_start + 30.0 + args.seconds
        measuring = False
        while time.monotonic() < t_end:
            now = deadline.wait()
            if not measuring and now > t_start and (state['answered'] >= 0
                                                    or now > t_start + 30.0):
                t_end = now + args.seconds
                measuring = True
                rtts.clear()
                late[0] = 0
                stats.summary()
                first = cycle
                cpu0 = (time.process_time(), time.monotonic())
            if measuring:
                stats.tick(now)
                if state['answered'] != cycle:
                    late[0] += 1
            cycle += 1
            stamp_now(msg.header.stamp)
            msg.cycle = cycle
            msg.motor_position = [0.001 * cycle, 0.0]
            msg.motor_velocity = [0.0, 0.0]
            msg.pressure_force = [0.0, 0.0]
            msg.motor_effort = [0.0, 0.0]
            msg.endpoint_position = [0.0, 0.0]
            msg.external_force = [0.0, 0.0]
            msg.status = [0, 0]
            sent[cycle % len(sent)] = time.monotonic()  # before publish: replies can be quick
            pub.publish(msg)
        s = stats.summary()
        cycles = cycle - first
        r = sorted(rtts) or [float('nan')]
        result['cpu_pct'] = 100.0 * ((time.process_time() - cpu0[0])
                                     / max(1e-9, time.monotonic() - cpu0[1]))
        result.update(rate=s.rate_hz, period_p99_ms=s.period_p99_ms,
                      in_time=1.0 - late[0] / max(1, cycles),
                      rtt_p50_ms=1e3 * r[len(r) // 2],
                      rtt_p99_ms=1e3 * r[min(len(r) - 1, int(0.99 * len(r)))])
        print(json.dumps(result), flush=True)
        rclpy.try_shutdown()

    threading.Thread(target=loop, daemon=True).start()


def echo(node, args):
    cmd = ActuatorCommand()
    cmd.name = ['wrist', 'pinch']
    zeros = [0.0, 0.0]
    pub = node.create_publisher(ActuatorCommand, 'actuator_command', control_qos(args.qos))

    def on_state(msg):
        cmd.header.stamp = msg.header.stamp
        cmd.cycle = msg.cycle
        cmd.effort = zeros
        pub.publish(cmd)

    node.create_subscription(ActuatorState, 'actuator_state', on_state,
                             control_qos(args.qos, subscriber=True))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--role', choices=('source', 'echo'), required=True)
    parser.add_argument('--executor', default='events')
    parser.add_argument('--qos', default='reliable')
    parser.add_argument('--rate', type=float, default=2000.0)
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--warmup', type=float, default=3.0)
    args = parser.parse_args()
    sys.setswitchinterval(2e-4)
    rclpy.init()
    node = rclpy.create_node(f'bare_{args.role}')
    (source if args.role == 'source' else echo)(node, args)
    executor = make_executor(args.executor)
    executor.add_node(node)
    try:
        spin_forever(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()

#!/usr/bin/env python3
"""Benchmark the 2 kHz closed loop over ROS 2: executors, QoS, separate vs composed processes.

For each variant it starts sim_node (realtime, 2 kHz) and controller_node (pinch in
dob_full_ff, finger backdriven 0.5 rad at 1 rad/s) — as two processes or composed in one
(`bringup`) — lets them settle, then reads the nodes' own /diagnostics for `--seconds`:

  rate      achieved sim cycle rate [Hz]
  p99 per   p99 of the sim cycle period [ms]
  rtt p50/p99   state published -> its command received by the sim [ms]
  late %    cycles stepped before the answer to the previous state had arrived
  timeouts  command watchdog trips (no command for command_timeout = 10 ms)
  CPU %     CPU time of the node processes / wall time (200 % = both cores)

and prints a table with the round trip relative to the baseline variant of the same run
(separate processes, single_threaded executor, reliable QoS).

Usage: scripts/setup.sh first (or scripts/test does it), then
       python bench/control_loop.py [--seconds 20] [--variants all|quick]
"""
import argparse
import os
import pathlib
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
LIB = ROOT / 'install' / 'seaforce_ros' / 'lib' / 'seaforce_ros'
CONFIG = ROOT / 'config' / 'gripper.yaml'

VARIANTS = [  # (layout, executor, qos)
    ('separate', 'single_threaded', 'reliable'),
    ('separate', 'events', 'reliable'),
    ('separate', 'events', 'best_effort'),
    ('separate', 'single_threaded', 'best_effort'),
    ('composed', 'events', 'reliable'),
    ('composed', 'single_threaded', 'reliable'),
]


def cpu_seconds(pid):
    try:
        fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError):
        return 0.0


class DiagnosticsListener:
    def __init__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        from seaforce_ros.ros_common import BackgroundNode
        self.background = BackgroundNode('bench_control_loop')
        self.lock = threading.Lock()
        self.items = []
        self.background.node.create_subscription(DiagnosticArray, '/diagnostics',
                                                 self._on_diag, 50)

    def _on_diag(self, msg):
        now = time.monotonic()
        with self.lock:
            for status in msg.status:
                self.items.append((now, status.name, {kv.key: kv.value for kv in status.values}))

    def window(self, name, t0, t1):
        with self.lock:
            return [v for t, n, v in self.items if n == name and t0 <= t < t1]

    def close(self):
        self.background.close()


def run_variant(layout, executor, qos, seconds, workdir):
    overrides = workdir / f'{layout}-{executor}-{qos}.yaml'
    common = (f'    executor: {executor}\n    control_qos: {qos}\n')
    overrides.write_text(
        '/**:\n  ros__parameters:\n' + common
        + '    pinch.environment.mode: position_sine\n    pinch.environment.amplitude: 0.5\n'
        + '    pinch.mode: dob_full_ff\n    wrist.mode: dob\n')
    args = ['--ros-args', '--params-file', str(CONFIG), '--params-file', str(overrides)]
    if layout == 'separate':
        argvs = [[str(LIB / 'sim_node')] + args, [str(LIB / 'controller_node')] + args]
    else:
        argvs = [[str(LIB / 'bringup')] + args]
    procs = [subprocess.Popen(a, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              stdin=subprocess.DEVNULL, start_new_session=True) for a in argvs]
    listener = DiagnosticsListener()
    try:
        time.sleep(4.0)  # discovery and settling
        c0 = sum(cpu_seconds(p.pid) for p in procs)
        t0 = time.monotonic()
        time.sleep(seconds)
        t1 = time.monotonic()
        c1 = sum(cpu_seconds(p.pid) for p in procs)
        time.sleep(1.2)
        sim = listener.window('sim: cycle', t0 + 1.0, t1 + 1.2)
        ctl = listener.window('controller: loop', t0 + 1.0, t1 + 1.2)
    finally:
        listener.close()
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    if len(sim) < 2:
        return None
    f = lambda rows, key: [float(r[key]) for r in rows if key in r and r[key] != 'nan']
    cycles = int(sim[-1]['cycle']) - int(sim[0]['cycle'])
    late = int(sim[-1]['late_commands_total']) - int(sim[0]['late_commands_total'])
    return {
        'rate': statistics.mean(f(sim, 'rate_hz')),
        'per_p99': statistics.median(f(sim, 'period_p99_ms')),
        'rtt_p50': statistics.median(f(sim, 'round_trip_p50_ms') or [float('nan')]),
        'rtt_p99': statistics.median(f(sim, 'round_trip_p99_ms') or [float('nan')]),
        'late': 100.0 * late / max(1, cycles),
        'timeouts': int(sim[-1]['command_timeouts']) - int(sim[0]['command_timeouts']),
        'compute_us': statistics.median(f(ctl, 'compute_mean_us') or [float('nan')]),
        'cpu': 100.0 * (c1 - c0) / (t1 - t0),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--variants', choices=('all', 'quick'), default='all')
    args = parser.parse_args()
    if not (LIB / 'bringup').exists():
        sys.exit('install/ is missing: run `source scripts/setup.sh` first')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    variants = VARIANTS if args.variants == 'all' else VARIANTS[:2]
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for variant in variants:
            print(f'[bench] {"/".join(variant)}: {args.seconds:.0f} s ...', flush=True)
            results[variant] = run_variant(*variant, args.seconds, pathlib.Path(tmp))
    base = results.get(VARIANTS[0])
    print(f'\n{"layout":9s}{"executor":16s}{"qos":12s}{"rate Hz":>9s}{"p99 per":>9s}'
          f'{"rtt p50":>9s}{"rtt p99":>9s}{"vs base":>8s}{"late %":>8s}{"timeouts":>9s}'
          f'{"ctl us":>8s}{"CPU %":>7s}')
    for (layout, executor, qos), r in results.items():
        if r is None:
            print(f'{layout:9s}{executor:16s}{qos:12s}  no diagnostics received')
            continue
        ratio = r['rtt_p50'] / base['rtt_p50'] if base else float('nan')
        print(f'{layout:9s}{executor:16s}{qos:12s}{r["rate"]:9.0f}{r["per_p99"]:9.2f}'
              f'{r["rtt_p50"]:9.3f}{r["rtt_p99"]:9.2f}{ratio:8.2f}{r["late"]:8.1f}'
              f'{r["timeouts"]:9d}{r["compute_us"]:8.0f}{r["cpu"]:7.0f}')
    print('\nrtt: sim publishes state k -> sim receives the command for k; '
          '"vs base": rtt p50 / that of the first row')


if __name__ == '__main__':
    main()

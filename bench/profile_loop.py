#!/usr/bin/env python3
"""Where the time of the 2 kHz ROS loop goes: py-spy profiles of sim_node and controller_node.

Starts the same scenario as bench/control_loop.py (sim_node realtime at 2 kHz, controller_node,
EventsExecutor, reliable QoS, pinch in dob_full_ff backdriven 0.5 rad at 1 rad/s), lets it
settle, then samples both processes with py-spy (non-blocking, idle frames included; with
``--native`` also the C/C++ frames below rclpy, at the price of stopping the process for each
sample) for ``--seconds``. For each process it prints:

* how the samples split into: waiting (in the executor's wait or the cycle thread's sleep),
  the project's own Python (seaforce_ros), rclpy's Python layer, and native code (rcl / rmw /
  Fast DDS / CPython) reached from rclpy calls;
* the hottest leaf frames (self time) and the hottest project / rclpy functions (total time).

py-spy is in the project's pinned requirements; it needs ptrace rights (root, or
``kernel.yama.ptrace_scope`` = 0). Usage: ``source scripts/setup.sh; python bench/profile_loop.py
[--seconds 20] [--quick]`` (``--quick``: 1 s after a short settling, a smoke run).
"""
import argparse
import collections
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'bench'))

from control_loop import SETTLE, _stop, start_scenario  # noqa: E402

# Without native frames a sample taken while C/C++ code runs shows the Python line that called
# into it; these leaves name what that C/C++ code is.
LEAF_BUCKETS = (
    ('spin_forever', 'ros_common.py', 'executor, in C++ (EventsExecutor: wait, take, dispatch)'),
    ('spin_until_future_complete', '', 'executor, in C++ (EventsExecutor: wait, take, dispatch)'),
    ('spin_once', '', 'executor (wait, take, dispatch)'),
    ('publish', 'publisher.py', 'rclpy publish, in C (convert, serialise, Fast DDS write)'),
    ('wait', 'timing.py', 'cycle thread sleeping until its next deadline'),
)


def parse_raw(path: pathlib.Path):
    """py-spy's raw (collapsed) format: 'frame;frame;...;leaf count' per line."""
    stacks = []
    for line in path.read_text(errors='replace').splitlines():
        stack, _, count = line.rpartition(' ')
        if stack and count.isdigit():
            stacks.append((stack.split(';'), int(count)))
    return stacks


def classify(frames):
    leaf = frames[-1]
    name, _, where = leaf.partition(' (')
    for func, module, bucket in LEAF_BUCKETS:
        if name == func and module in where:
            return bucket
    # py-spy names files relative to their sys.path entry: 'seaforce_ros/nodes/sim_node.py'
    if where.startswith('seaforce_ros/'):
        return 'project Python (seaforce_ros)'
    if where.split('/')[0] in ('seaforce_msgs', 'std_msgs', 'builtin_interfaces',
                               'sensor_msgs', 'diagnostic_msgs'):
        return 'generated message classes (Python)'
    if where.startswith('rclpy/'):
        return 'rclpy Python (other)'
    return 'other Python'


def short(frame: str) -> str:
    # "function (/long/path/to/module.py:123)" -> "function (module.py:123)"
    if '(' in frame and frame.endswith(')'):
        name, _, where = frame.partition(' (')
        return f'{name} ({pathlib.Path(where[:-1]).name})'
    return frame


def report(name: str, stacks, top: int) -> None:
    threads = collections.Counter()
    by_class = collections.Counter()
    self_time = collections.Counter()
    inclusive = collections.Counter()
    for frames, count in stacks:
        thread = 'process'
        if frames and frames[0].startswith('thread ('):
            thread, frames = frames[0], frames[1:]
        if not frames:
            continue
        threads[thread] += count
        by_class[(thread, classify(frames))] += count
        self_time[short(frames[-1])] += count
        for f in set(frames):
            if 'seaforce_ros' in f or 'rclpy' in f:
                inclusive[short(f)] += count
    total = sum(threads.values())
    if not total:
        print(f'\n== {name}: no samples')
        return
    print(f'\n== {name}: {total} samples over {len(threads)} thread(s)')
    for thread, n in threads.most_common():
        print(f'  {thread}: {100 * n / total:.0f} % of the samples; of its time:')
        for (t, what), count in by_class.most_common():
            if t == thread and count / n >= 0.002:
                print(f'    {100 * count / n:5.1f} %  {what}')
    print('  hottest leaves (self, share of all samples):')
    for frame, count in self_time.most_common(top):
        print(f'    {100 * count / total:5.1f} %  {frame}')
    print('  hottest project / rclpy functions (total):')
    for frame, count in inclusive.most_common(top):
        print(f'    {100 * count / total:5.1f} %  {frame}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--rate', type=float, default=2000.0, help='loop rate [Hz]')
    parser.add_argument('--sample-rate', type=int, default=500, help='py-spy samples per second')
    parser.add_argument('--top', type=int, default=12)
    parser.add_argument('--native', action='store_true',
                        help='also native frames (rcl/rmw/Fast DDS); py-spy must then stop '
                             'the process for each sample, which perturbs the loop')
    parser.add_argument('--quick', action='store_true', help='smoke run: 1 s of samples')
    args = parser.parse_args()
    settle = SETTLE['nodes'] + 1.0
    if args.quick:
        args.seconds, settle = 1.0, 2.0
    pyspy = shutil.which('py-spy') or str(pathlib.Path(sys.executable).parent / 'py-spy')
    if not os.path.exists(pyspy):
        sys.exit('py-spy is missing: run `source scripts/setup.sh` (it is a pinned requirement)')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        procs = start_scenario('separate', 'events', 'reliable', args.rate, tmp)
        procs = {'sim': procs['sim'], 'controller': procs['ctl']}
        spies = {}
        try:
            time.sleep(settle)
            for name, proc in procs.items():
                if proc.poll() is not None:
                    sys.exit(f'{name} exited early (code {proc.returncode})')
            print(f'[profile] sampling sim and controller for {args.seconds:.0f} s at '
                  f'{args.sample_rate} Hz', flush=True)
            for name, proc in procs.items():
                argv = [pyspy, 'record', '--pid', str(proc.pid), '--rate', str(args.sample_rate),
                        '--duration', str(int(args.seconds)), '--format', 'raw', '--idle',
                        '--threads',
                        '--output', str(tmp / f'{name}.txt')]
                argv.append('--native' if args.native else '--nonblocking')
                spies[name] = subprocess.Popen(argv, stdout=subprocess.DEVNULL,
                                               stderr=subprocess.PIPE, text=True)
            for name, spy in spies.items():
                _, err = spy.communicate(timeout=args.seconds + 120)
                if spy.returncode != 0:
                    print(f'[profile] py-spy on {name} failed: {err.strip()[-400:]}')
        finally:
            for spy in spies.values():
                if spy.poll() is None:
                    spy.kill()
                    spy.wait()
            _stop(procs.values())
        for name in procs:
            path = tmp / f'{name}.txt'
            if path.exists():
                report(name, parse_raw(path), args.top)
    print('\nEvery thread is sampled whether it runs or waits (--idle): a thread\'s shares are '
          'of its wall time. The sim has two Python threads (the executor and the 2 kHz cycle '
          'thread); the controller one.')


if __name__ == '__main__':
    main()

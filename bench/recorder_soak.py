#!/usr/bin/env python3
"""bag_recorder soak: sim_node + controller_node (realtime, 2 kHz) + bag_recorder for
``--duration`` seconds (default 600), then ``identify`` on the recorded bag. Prints figures,
asserts nothing.

The pinch finger runs the identification experiment during the soak (sim environment
``torque_chirp`` 0.3 N m, 0.01-1000 Hz over the soak duration, controller mode ``passive``), so the
10-minute bag is a real identification input.

Figures: per topic received / written by the recorder and messages in the bag; actuator_state
cycles missing in the bag (gaps against the sim's own numbering, after the first second of
discovery); splits, bag size, recorder CPU and memory; identify wall time and its table.

    source scripts/setup.sh && python bench/recorder_soak.py [--duration 600] [--keep DIR]
        [--quick]      (3 s in 1 s splits: a smoke run; identify refuses so short a record)
"""
import argparse
import os
import pathlib
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import yaml

ROOT = pathlib.Path(__file__).resolve().parent.parent
LIB = ROOT / 'install' / 'seaforce_ros' / 'lib' / 'seaforce_ros'
CONFIG = ROOT / 'config' / 'gripper.yaml'
sys.path.insert(0, str(ROOT))


def start(argv, log):
    return subprocess.Popen([str(a) for a in argv], stdout=open(log, 'wb'),
                            stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True)


def wait_for(log, text, proc, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in pathlib.Path(log).read_text(errors='replace'):
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.1)
    return False


def cpu_seconds(pid):
    try:
        fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError):
        return float('nan')


def rss_mb(pid):
    try:
        for line in pathlib.Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float('nan')


def stop(proc, sig=signal.SIGINT, timeout=30.0):
    if proc.poll() is None:
        os.kill(proc.pid, sig)
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGKILL)
        return proc.wait(5)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=600.0, help='recording time [s]')
    ap.add_argument('--storage', default='mcap', choices=('mcap', 'sqlite3'))
    ap.add_argument('--split', type=float, default=10.0, help='split_duration [s]')
    ap.add_argument('--keep', help='keep the bag in this directory (default: delete)')
    ap.add_argument('--quick', action='store_true', help='smoke run: 3 s in 1 s splits')
    args = ap.parse_args()
    if args.quick:
        args.duration, args.split = 3.0, 1.0
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 200)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    work = pathlib.Path(tempfile.mkdtemp(prefix='recorder_soak_'))
    bag = pathlib.Path(args.keep).resolve() if args.keep else work / 'bag'
    overrides = work / 'overrides.yaml'
    overrides.write_text(yaml.safe_dump({
        'sim': {'ros__parameters': {
            'pinch.environment.mode': 'torque_chirp', 'pinch.environment.amplitude': 0.3,
            'pinch.environment.start_frequency': 0.01,
            'pinch.environment.end_frequency': 1000.0,
            'pinch.environment.duration': float(args.duration)}},
        'controller': {'ros__parameters': {'state_timeout': 0.5}}}))
    cfg = ['--ros-args', '--params-file', CONFIG, '--params-file', overrides]
    procs = []
    try:
        sim = start([LIB / 'sim_node', *cfg], work / 'sim.log')
        procs.append(sim)
        ctl = start([LIB / 'controller_node', *cfg], work / 'controller.log')
        procs.append(ctl)
        for p, log in ((sim, 'sim.log'), (ctl, 'controller.log')):
            if not wait_for(work / log, 'spinning with', p):
                sys.exit(f'{log}: did not start:\n' + (work / log).read_text()[-2000:])
        rec = start([LIB / 'bag_recorder', '--ros-args', '-p', f'output:={bag}', '-p',
                     f'storage:={args.storage}', '-p', f'split_duration:={args.split}', '-p',
                     'report_period:=30.0'], work / 'recorder.log')
        procs.append(rec)
        if not wait_for(work / 'recorder.log', 'spinning with', rec):
            sys.exit('recorder did not start:\n' + (work / 'recorder.log').read_text())
        t0 = time.monotonic()
        cpu0 = cpu_seconds(rec.pid)
        rss_max = 0.0
        print(f'recording {args.duration:.0f} s into {bag} ...', flush=True)
        next_print = 60.0
        while time.monotonic() - t0 < args.duration:
            time.sleep(1.0)
            rss_max = max(rss_max, rss_mb(rec.pid))
            if rec.poll() is not None:
                sys.exit('recorder died:\n' + (work / 'recorder.log').read_text()[-3000:])
            if time.monotonic() - t0 >= next_print:
                print(f'  {next_print:.0f} s', flush=True)
                next_print += 60.0
        elapsed = time.monotonic() - t0
        cpu = cpu_seconds(rec.pid) - cpu0
        stop(ctl)
        stop(sim)
        time.sleep(1.0)
        code = stop(rec, timeout=120)
        log = (work / 'recorder.log').read_text(errors='replace')
        m = re.search(r'final counts: (.*); splits (\d+)', log)
        print(f'\nrecorder exit code {code}; {m.group(0) if m else "no final counts!"}')
        # what is in the bag
        from rosbags.rosbag2 import Reader
        from seaforce_ros import bags
        counts = {}
        with Reader(bag) as reader:               # the bag directory as one bag
            for c in reader.connections:
                counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
        splits = sorted(p for p in bag.iterdir() if p.suffix in ('.mcap', '.db3'))
        size = sum(f.stat().st_size for f in bag.rglob('*') if f.is_file()) / 1e6
        rec_data = bags.read_channel(bag, 'pinch')
        cyc = rec_data.cycle
        span = int(cyc[-1] - cyc[0] + 1)
        settled = cyc[cyc >= cyc[0] + 2000]
        missing_settled = (int(settled[-1] - settled[0] + 1 - settled.size) if settled.size
                           else 0)       # (a record shorter than the discovery second)
        print(f'recorded for {elapsed:.1f} s wall time; bag: {len(splits)} files, '
              f'{size:.1f} MB ({args.storage})')
        for topic, n in sorted(counts.items()):
            print(f'  {topic}: {n} messages in the bag ({n / elapsed:.0f}/s)')
        print(f'actuator_state: cycles {cyc[0]}..{cyc[-1]} = {span} published while recorded, '
              f'{cyc.size} in the bag, {span - cyc.size} missing '
              f'({missing_settled} after the first second of discovery); sim rate '
              f'{cyc.size / elapsed:.0f} Hz')
        print(f'recorder CPU {100 * cpu / elapsed:.1f} % of one core, max RSS {rss_max:.0f} MB')
        # identify on the 10-minute bag
        t1 = time.perf_counter()
        ident = subprocess.run([str(LIB / 'identify'), str(bag), '--channel', 'pinch', '--out',
                                str(work / 'identified.yaml'), '--quiet'],
                               capture_output=True, text=True)
        t_id = time.perf_counter() - t1
        print(f'\nidentify on the {elapsed / 60:.1f}-minute bag: {t_id:.1f} s wall '
              f'(exit {ident.returncode})')
        print(ident.stdout.strip() or ident.stderr.strip())
    finally:
        for p in procs:
            if p.poll() is None:
                stop(p, signal.SIGINT, 10)
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
        else:
            print(f'logs in {work}')


if __name__ == '__main__':
    main()

#!/usr/bin/env python3
"""Benchmark the 2 kHz closed loop over ROS 2 against the platform's own limit.

Main rows, 60 s each (split into ``--rounds`` interleaved rounds: bare, nodes, nodes, bare, ...,
so that the host's drifts hit both sides of the ratio), with the EventsExecutor and the
SingleThreadedExecutor:

* **nodes** - sim_node (realtime) and controller_node as separate processes, pinch in
  dob_full_ff with the finger backdriven 0.5 rad at 1 rad/s, wrist in dob; figures from the
  sim's own /diagnostics;
* **bare echo** - bench/echo_pair.py: a 2 kHz ActuatorState source and a process that answers
  each with an ActuatorCommand and does nothing else: what rclpy + Fast DDS allow here.

Extra rows (20 s each): best-effort QoS; both nodes composed in one process (bringup); the
"rt" rows, whose processes run under SCHED_FIFO (chrt -f, needs root or CAP_SYS_NICE); and a
sweep of lower rates for the bare echo and the nodes, to find the highest rate at which >= 99 %
of commands arrive in time (printed at the end). Columns:

  rate      achieved cycle rate [Hz]
  in time   commands that arrived before the next cycle started
  rtt       state k published -> its command received [ms], p50 and p99
  vs bare   rtt p50 / the bare echo's with the same executor, same run
  timeouts  command watchdog trips (no command for 10 ms)
  CPU %     per process, CPU time / wall time (one core = 100)

Usage: source scripts/setup.sh; python bench/control_loop.py [--seconds 60] [--no-extras]
       [--quick]   (one direct, one bare echo and one nodes row with the EventsExecutor, 1 s
                    each after a short settling: a smoke run, figures meaningless)
"""
import argparse
import json
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
#: s of discovery and settling before a row's figures are taken (and its bare echo's warm-up);
#: --quick shortens it, and /diagnostics then comes every 0.2 s
SETTLE = {'nodes': 4.0, 'warmup': 4.0, 'diagnostics_period': 1.0}

def start_hogs():
    """One busy-looping process per core (normal priority); end them with _stop()."""
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass'],
                             stdin=subprocess.DEVNULL, start_new_session=True)
            for _ in range(os.cpu_count() or 1)]


def cpu_seconds(pid):
    try:
        fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError):
        return 0.0


class DiagnosticsListener:
    def __init__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        from seaforce_ros.nodes.ros_common import BackgroundNode
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

    def answered(self, name):
        """The newest ``name`` row shows a round trip: commands answer the states."""
        with self.lock:
            rows = [v for _, n, v in self.items if n == name]
        return bool(rows) and rows[-1].get('round_trip_p50_ms', 'nan') != 'nan'

    def window(self, name, t0, t1):
        with self.lock:
            return [v for t, n, v in self.items if n == name and t0 <= t < t1]

    def close(self):
        self.background.close()


def _stop(procs):
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def start_scenario(layout, executor, qos, rate, workdir, prefix=()):
    """Start the benchmark scenario: sim_node (realtime, pinch backdriven 0.5 rad at 1 rad/s)
    and controller_node (pinch dob_full_ff, wrist dob) as separate processes ('sim', 'ctl'),
    or composed in bringup ('both'; layout 'direct': bringup loop:=direct). Returns
    {name: Popen}."""
    overrides = workdir / f'{layout}-{executor}-{qos}-{rate:.0f}-{len(prefix)}.yaml'
    # one section per node (the composed bringup reads both), given after gripper.yaml
    common = (f'    executor: {executor}\n    control_qos: {qos}\n    rate: {rate}\n'
              f'    diagnostics_period: {SETTLE["diagnostics_period"]}\n')
    overrides.write_text(
        'sim:\n  ros__parameters:\n' + common
        + '    pinch.environment.mode: position_sine\n    pinch.environment.amplitude: 0.5\n'
        'controller:\n  ros__parameters:\n' + common
        + '    pinch.mode: dob_full_ff\n    wrist.mode: dob\n    state_timeout: 1.0\n'
        + ('    loop: direct\n' if layout == 'direct' else ''))
    args = ['--ros-args', '--params-file', str(CONFIG), '--params-file', str(overrides)]
    if layout == 'separate':
        argvs = {'sim': [str(LIB / 'sim_node')] + args,
                 'ctl': [str(LIB / 'controller_node')] + args}
    else:
        argvs = {'both': [str(LIB / 'bringup')] + args}
    return {k: subprocess.Popen(list(prefix) + a, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL,
                                stdin=subprocess.DEVNULL, start_new_session=True)
            for k, a in argvs.items()}


def observe(procs, listener, name, settle, seconds, answer_within=30.0):
    """After ``settle`` s (discovery, settling) and once the ``name`` rows show commands
    answering the states (a busy host starts a node slowly; at most ``answer_within`` s more),
    ``seconds`` of the ``name`` diagnostics rows and each process's CPU use over them [% of one
    core]: (rows, {key: percent})."""
    time.sleep(settle)
    deadline = time.monotonic() + answer_within
    while not listener.answered(name) and time.monotonic() < deadline:
        time.sleep(0.1)
    c0 = {k: cpu_seconds(p.pid) for k, p in procs.items()}
    t0 = time.monotonic()
    time.sleep(seconds)
    t1 = time.monotonic()
    c1 = {k: cpu_seconds(p.pid) for k, p in procs.items()}
    first = t0 + SETTLE['diagnostics_period']
    end = t1 + SETTLE['diagnostics_period'] + 0.2      # the row that covers the window's end
    time.sleep(max(0.0, end - time.monotonic()))
    # (a busy host publishes the rows late: until two are in, at most answer_within s more)
    deadline = time.monotonic() + answer_within
    while len(listener.window(name, first, end)) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
        end = time.monotonic()
    return (listener.window(name, first, end),
            {k: 100.0 * (c1[k] - c0[k]) / (t1 - t0) for k in procs})


def run_nodes(layout, executor, qos, rate, seconds, workdir, prefix=()):
    """The project's sim_node + controller_node (or bringup); figures from /diagnostics."""
    procs = start_scenario(layout, executor, qos, rate, workdir, prefix)
    listener = DiagnosticsListener()
    try:
        sim, cpu = observe(procs, listener, 'sim: cycle', SETTLE['nodes'], seconds)
    finally:
        listener.close()
        _stop(procs.values())
    if len(sim) < 2:
        return None
    f = lambda key: [float(r[key]) for r in sim if key in r and r[key] != 'nan']
    cycles = int(sim[-1]['cycle']) - int(sim[0]['cycle'])
    late = int(sim[-1]['late_commands_total']) - int(sim[0]['late_commands_total'])
    return {
        'rate': statistics.mean(f('rate_hz')),
        'in_time': 1.0 - late / max(1, cycles),
        'rtt_p50_ms': statistics.median(f('round_trip_p50_ms') or [float('nan')]),
        'rtt_p99_ms': statistics.median(f('round_trip_p99_ms') or [float('nan')]),
        'timeouts': int(sim[-1]['command_timeouts']) - int(sim[0]['command_timeouts']),
        'period_p99_ms': statistics.median(f('period_p99_ms') or [float('nan')]),
        'period_max_ms': max(f('period_max_ms') or [float('nan')]),
        'cpu': cpu,
    }


def run_bare(executor, qos, rate, seconds, prefix=()):
    """The bare rclpy echo pair (bench/echo_pair.py) with the same message types."""
    common = ['--executor', executor, '--qos', qos, '--rate', str(rate)]
    script = str(ROOT / 'bench' / 'echo_pair.py')
    echo = subprocess.Popen(list(prefix) + [sys.executable, script, '--role', 'echo'] + common,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    time.sleep(1.0)
    src = subprocess.Popen(list(prefix) + [sys.executable, script, '--role', 'source', '--seconds',
                            str(seconds), '--warmup', str(SETTLE['warmup'])] + common,
                           stdout=subprocess.PIPE,
                           stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    procs = {'src': src, 'echo': echo}
    try:
        time.sleep(SETTLE['warmup'])
        c0 = {k: cpu_seconds(p.pid) for k, p in procs.items()}
        t0 = time.monotonic()
        out, _ = src.communicate(timeout=seconds + 60)
        t1 = time.monotonic()
        c1 = {k: cpu_seconds(p.pid) if p.poll() is None else c0[k] for k, p in procs.items()}
    finally:
        _stop(procs.values())
    lines = [line for line in out.splitlines() if line.startswith('{')]
    if not lines:
        return None
    result = json.loads(lines[-1])
    result['timeouts'] = 0
    result['cpu'] = {k: 100.0 * (c1[k] - c0[k]) / max(1e-9, t1 - t0) for k in procs}
    result['cpu']['src'] = result.pop('cpu_pct', float('nan'))  # it has exited: its own figure
    return result


def combine(parts):
    """One row from interleaved rounds: means of rate / in time / CPU, medians of the
    rounds' round-trip percentiles, total watchdog trips."""
    if not parts:
        return None
    cpu = {k: statistics.mean(p['cpu'][k] for p in parts) for k in parts[0]['cpu']}
    return {'rate': statistics.mean(p['rate'] for p in parts),
            'in_time': statistics.mean(p['in_time'] for p in parts),
            'rtt_p50_ms': statistics.median(p['rtt_p50_ms'] for p in parts),
            'rtt_p99_ms': statistics.median(p['rtt_p99_ms'] for p in parts),
            'timeouts': sum(p['timeouts'] for p in parts), 'cpu': cpu,
            'period_p99_ms': statistics.median(p.get('period_p99_ms', float('nan'))
                                               for p in parts),
            'rounds_p50': [p['rtt_p50_ms'] for p in parts]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='measurement per main variant (bare/nodes x executor)')
    parser.add_argument('--extra-seconds', type=float, default=20.0,
                        help='measurement per extra variant (QoS, composition, lower rates)')
    parser.add_argument('--rounds', type=int, default=4,
                        help='interleaved rounds the main rows are split into')
    parser.add_argument('--no-extras', action='store_true')
    parser.add_argument('--sweep', type=lambda v: [float(x) for x in v.split(',') if x],
                        default=[1500.0, 1000.0, 750.0, 500.0, 250.0],
                        help='lower rates [Hz] tried for bare echo and nodes (events)')
    parser.add_argument('--fifo-priority', type=int, default=40,
                        help='SCHED_FIFO priority of the "rt" rows (chrt -f)')
    parser.add_argument('--only-direct', action='store_true',
                        help='only the direct-layout rows (quiet and with a CPU hog per core)')
    parser.add_argument('--quick', action='store_true',
                        help='smoke run: direct, bare echo and nodes (events), 1 s each')
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.rounds, args.no_extras = 1.0, 1, True
        SETTLE.update(nodes=2.0, warmup=1.5, diagnostics_period=0.2)
    if not (LIB / 'bringup').exists():
        sys.exit('install/ is missing: run `source scripts/setup.sh` first')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    runs = []   # (label, executor, qos, rate, result)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        # main rows: each variant's time is split into rounds, run interleaved (bare, nodes,
        # bare, nodes, ...), so that the host's slow drifts hit both sides of the ratio alike
        chunk = args.seconds / args.rounds
        fifo = ['chrt', '-f', str(args.fifo_priority)]
        # the direct layout (bringup loop:=direct): the sim's cycle thread calls the controller
        for hog in (False,) if args.quick else (False, True):
            tag = ', a CPU hog per core' if hog else ''
            print(f'[bench] direct / events / 2000 Hz / SCHED_FIFO{tag}: {args.seconds:.0f} s',
                  flush=True)
            hogs = start_hogs() if hog else []
            try:
                r = run_nodes('direct', 'events', 'reliable', 2000.0, args.seconds, tmp, fifo)
            finally:
                _stop(hogs)
            runs.append(('direct rt' + (' hog' if hog else ''), 'events', 'reliable', 2000.0, r))
        executors = ('events',) if args.quick else ('events', 'single_threaded')
        for executor in (() if args.only_direct else executors):
            parts = {'bare echo': [], 'nodes': []}
            for round_ in range(args.rounds):
                for kind in (('bare echo', 'nodes') if round_ % 2 == 0 else ('nodes', 'bare echo')):
                    print(f'[bench] {kind} / {executor} / 2000 Hz: round {round_ + 1} of '
                          f'{args.rounds}, {chunk:.0f} s', flush=True)
                    r = (run_bare(executor, 'reliable', 2000.0, chunk) if kind == 'bare echo'
                         else run_nodes('separate', executor, 'reliable', 2000.0, chunk, tmp))
                    if r is not None:
                        parts[kind].append(r)
            for kind in ('bare echo', 'nodes'):
                runs.append((kind, executor, 'reliable', 2000.0, combine(parts[kind])))
        if not (args.no_extras or args.only_direct):
            extras = [('nodes', 'events', 'best_effort', 2000.0, 'separate', ()),
                      ('composed', 'events', 'reliable', 2000.0, 'composed', ()),
                      ('nodes', 'events', 'reliable', 2000.0, 'separate', fifo),
                      ('bare echo', 'events', 'reliable', 2000.0, None, fifo),
                      ('composed', 'events', 'reliable', 2000.0, 'composed', fifo)]
            for rate in args.sweep:
                extras += [('bare echo', 'events', 'reliable', rate, None, ()),
                           ('nodes', 'events', 'reliable', rate, 'separate', ())]
                if rate >= 1000.0:
                    extras.append(('composed', 'events', 'reliable', rate, 'composed', fifo))
            for kind, executor, qos, rate, layout, prefix in extras:
                tag = ' / SCHED_FIFO' if prefix else ''
                print(f'[bench] {kind} / {executor} / {qos} / {rate:.0f} Hz{tag}: '
                      f'{args.extra_seconds:.0f} s', flush=True)
                r = (run_bare(executor, qos, rate, args.extra_seconds, prefix) if layout is None
                     else run_nodes(layout, executor, qos, rate, args.extra_seconds, tmp, prefix))
                runs.append((kind + (' rt' if prefix else ''), executor, qos, rate, r))
    bare = {(k.endswith(' rt'), e, q, rt): r
            for k, e, q, rt, r in runs if k.startswith('bare echo') and r}
    print(f'\n{"what":16s}{"executor":16s}{"qos":12s}{"target":>7s}{"rate Hz":>9s}'
          f'{"in time":>9s}{"per p99":>8s}{"rtt p50":>9s}{"rtt p99":>9s}{"vs bare":>8s}'
          f'{"timeouts":>9s}  CPU % per process')
    for kind, executor, qos, rate, r in runs:
        if r is None:
            print(f'{kind:16s}{executor:16s}{qos:12s}{rate:7.0f}  no figures (see logs)')
            continue
        rt = ' rt' in kind
        ref = bare.get((rt, executor, qos, rate)) or bare.get((rt, executor, 'reliable', rate))
        ratio = (r['rtt_p50_ms'] / ref['rtt_p50_ms'] if ref and not kind.startswith('bare')
                 else float('nan'))
        cpu = ' '.join(f'{k}={v:.0f}' for k, v in r['cpu'].items())
        print(f'{kind:16s}{executor:16s}{qos:12s}{rate:7.0f}{r["rate"]:9.0f}'
              f'{100 * r["in_time"]:8.2f}%{r.get("period_p99_ms", float("nan")):8.3f}'
              f'{r["rtt_p50_ms"]:9.3f}{r["rtt_p99_ms"]:9.2f}{ratio:8.2f}{r["timeouts"]:9d}  {cpu}')
    for kind, executor, qos, rate, r in runs:
        if r and 'rounds_p50' in r:
            print(f'rtt p50 per round, {kind} / {executor}: '
                  + ' '.join(f'{v:.3f}' for v in r['rounds_p50']))
    for what in ('bare echo', 'nodes', 'composed rt'):
        held = [rate for kind, executor, qos, rate, r in runs
                if kind == what and executor == 'events' and qos == 'reliable' and r
                and r['in_time'] >= 0.99 and r['rate'] >= 0.98 * rate]
        print(f'highest rate with >= 99 % of commands in time, {what} (events, reliable): '
              + (f'{max(held):.0f} Hz' if held else 'none of those tried'))
    print('\nin time: the command answering state k arrived before cycle k+1 started (direct: '
          'the torque of cycle k+1 was computed from state k); per p99: the plant\'s cycle '
          'period p99 [ms]; rtt: state k published -> its command received [ms] (direct: '
          'cycle start -> command computed); vs bare: rtt p50 / that of the bare echo pair with '
          'the same executor (and priority), measured in this run; timeouts: command watchdog '
          'trips (10 ms); rt: SCHED_FIFO; hog: a CPU-burning process per core, normal '
          'priority.')


if __name__ == '__main__':
    main()

#!/usr/bin/env python3
"""Benchmark hardware_node's EtherCAT cycle next to sim_node, in one run.

Starts the software EtherCAT slave emulator (test/ethercat) on a veth pair in its own network
namespace, then `hardware_node` + `controller_node` (pinch in dob_full_ff, finger backdriven
0.5 rad at 1 rad/s by the emulated plant) for `--seconds`, reading the node's /diagnostics:
cycle rate, period p50/p99, working-counter errors, round trip state -> command, commands in
time. Then the same controller against `sim_node` for the same time. Needs root (veth,
namespaces, raw sockets). `--rt PRIO` runs the hardware node, the sim node and the emulator
with SCHED_FIFO priority PRIO, as a real rig would (README, first power-on checklist).

Usage: source scripts/setup.sh; python bench/hardware_loop.py [--seconds 60] [--rt 40]
"""
import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))
sys.path.insert(0, str(ROOT / 'bench'))

from control_loop import CONFIG, LIB, DiagnosticsListener, _stop, cpu_seconds  # noqa: E402

BUS = ROOT / 'test' / 'data' / 'bus_emulated.yaml'


def measure(argvs, name, seconds, listener):
    procs = {k: subprocess.Popen(a, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
             for k, a in argvs.items()}
    try:
        time.sleep(5.0)
        c0 = {k: cpu_seconds(p.pid) for k, p in procs.items()}
        t0 = time.monotonic()
        time.sleep(seconds)
        t1 = time.monotonic()
        c1 = {k: cpu_seconds(p.pid) for k, p in procs.items()}
        time.sleep(1.2)
        rows = listener.window(name, t0 + 1.0, t1 + 1.2)
    finally:
        _stop(procs.values())
    if len(rows) < 2:
        return None
    f = lambda key: sorted(float(r[key]) for r in rows if key in r and r[key] != 'nan')
    med = lambda key: f(key)[len(f(key)) // 2] if f(key) else float('nan')
    first, last = rows[0], rows[-1]
    cycles = int(last['cycle']) - int(first['cycle'])
    late = int(last['late_commands_total']) - int(first['late_commands_total'])
    wkc = (int(last['wkc_errors_total']) - int(first['wkc_errors_total'])
           if 'wkc_errors_total' in last else 0)
    return {'rate': med('rate_hz'), 'p50': med('period_p50_ms'), 'p99': med('period_p99_ms'),
            'rtt50': med('round_trip_p50_ms'), 'rtt99': med('round_trip_p99_ms'),
            'in_time': 1.0 - late / max(1, cycles), 'wkc': wkc, 'cycles': cycles,
            'cpu': {k: 100.0 * (c1[k] - c0[k]) / (t1 - t0) for k in procs}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--rt', type=int, default=0, help='SCHED_FIFO priority (0: normal)')
    args = parser.parse_args()
    if os.geteuid() != 0:
        sys.exit('needs root: veth pair, network namespace, raw EtherCAT socket')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    from ethercat.emulator.config import default_config
    from ethercat.harness import EmulatorHarness

    prefix = ['chrt', '-f', str(args.rt)] if args.rt else []
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        ctl_file = tmp / 'controller.yaml'
        ctl_file.write_text('controller:\n  ros__parameters:\n    pinch.mode: dob_full_ff\n'
                            '    wrist.mode: dob\n    state_timeout: 1.0\n')
        ctl = [str(LIB / 'controller_node'), '--ros-args', '--params-file', str(CONFIG),
               '--params-file', str(ctl_file)]
        config = default_config()
        config['channels']['pinch']['environment'] = {
            'mode': 'position_sine', 'amplitude': 0.5, 'frequency': 1.0}
        harness = EmulatorHarness(config, workdir=tmp / 'emulator', realtime=args.rt)
        listener = DiagnosticsListener()
        try:
            harness.start()
            hw_file = tmp / 'hardware.yaml'
            hw_file.write_text('hardware:\n  ros__parameters:\n'
                               f'    interface: {harness.master_interface}\n'
                               f'    bus_config: {BUS}\n    max_torque: 5.0\n')
            hw = prefix + [str(LIB / 'hardware_node'), '--ros-args', '--params-file',
                           str(CONFIG), '--params-file', str(hw_file)]
            print(f'[bench] hardware_node over EtherCAT (emulator on {harness.master_interface})'
                  f': {args.seconds:.0f} s', flush=True)
            results['hardware_node'] = measure({'hardware': hw, 'controller': ctl},
                                               'hardware: bus', args.seconds, listener)
        finally:
            harness.stop()
        sim_file = tmp / 'sim.yaml'
        sim_file.write_text('sim:\n  ros__parameters:\n    pinch.environment.mode: position_sine\n'
                            '    pinch.environment.amplitude: 0.5\n')
        sim = prefix + [str(LIB / 'sim_node'), '--ros-args', '--params-file', str(CONFIG),
                        '--params-file', str(sim_file)]
        print(f'[bench] sim_node: {args.seconds:.0f} s', flush=True)
        results['sim_node'] = measure({'sim': sim, 'controller': ctl}, 'sim: cycle',
                                      args.seconds, listener)
        listener.close()
    print(f'\n{"plant node":15s}{"rate Hz":>9s}{"per p50":>9s}{"per p99":>9s}{"wkc err":>9s}'
          f'{"rtt p50":>9s}{"rtt p99":>9s}{"in time":>9s}  CPU % per process')
    for name, r in results.items():
        if r is None:
            print(f'{name:15s}  no diagnostics received')
            continue
        cpu = ' '.join(f'{k}={v:.0f}' for k, v in r['cpu'].items())
        print(f'{name:15s}{r["rate"]:9.0f}{r["p50"]:9.3f}{r["p99"]:9.3f}{r["wkc"]:9d}'
              f'{r["rtt50"]:9.3f}{r["rtt99"]:9.2f}{100 * r["in_time"]:8.1f}%  {cpu}')
    print(f'\nperiods and round trips in ms; wkc err: working-counter errors in '
          f'{args.seconds:.0f} s; in time: the command for cycle k arrived before cycle k+1; '
          f'scheduling: {"SCHED_FIFO " + str(args.rt) if args.rt else "normal"}')


if __name__ == '__main__':
    main()

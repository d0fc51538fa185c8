#!/usr/bin/env python3
"""Benchmark hardware_node's EtherCAT cycle in both layouts, next to sim_node, in one run.

Starts the software EtherCAT slave emulator (test/ethercat) on a veth pair in its own network
namespace, then, for `--seconds` each (pinch in dob_full_ff, finger backdriven 0.5 rad at
1 rad/s by the emulated plant), reading the plant's /diagnostics:

* ``hardware topics``: `hardware_node` + `controller_node` as separate processes;
* ``hardware direct``: `hardware_bringup loop:=direct` (the cycle thread calls the controller);
* ``sim topics`` / ``sim direct``: the same with `sim_node` / `bringup`.

Columns: cycle rate, period p50/p99, working-counter errors, round trip state -> command,
"fresh": cycles whose torque came from the command answering the state just before (the one
modelled frame), CPU per process. Needs root (veth, namespaces, raw sockets). `--rt PRIO` runs
the plant processes and the emulator (at PRIO + 10) under SCHED_FIFO, as a real rig would
(docs/ethercat-hardware.md); the separate controller then runs at PRIO - 10. `--hog` adds a
CPU-burning process per core at normal priority for the whole run.

``--profiles``: instead, ``hardware direct`` once per emulated drive profile (the pinch drive
is one of test/ethercat's profiles: Elmo-like mapping, none, a drive in CSP without
0x6060/0x6061 mapped, one that needs SYNC0 -- run in DC, the cycle locked --, one that needs
0x60C2, one sampling its controlword every 2 ms), each with the bus YAML it needs
(test/ethercat/lines.py NEEDS): whether each reaches OP and keeps the 2 kHz loop fresh.

Usage: source scripts/setup.sh; python bench/hardware_loop.py [--seconds 60] [--rt 40] [--hog]
       [--profiles] [--quick]   (the two hardware rows, 1 s each after a short settling: a
       smoke run)
"""
import argparse
import os
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))
sys.path.insert(0, str(ROOT / 'bench'))

from control_loop import (CONFIG, LIB, SETTLE, DiagnosticsListener, _stop,  # noqa: E402
                          observe, start_hogs)

BUS = ROOT / 'test' / 'data' / 'bus_emulated.yaml'


def measure(argvs, name, seconds, listener, attempts=2, probe=None):
    """The figures of one layout from its ``name`` diagnostics rows; None when none came.
    A run whose rows did not come is run again once (the nodes' stderr tails are printed:
    a smoke run once saw no rows for the topics layout on a quiet host). ``probe()``, if
    given, is called at the end of the window, before the nodes stop (its result in
    ``'probe'``)."""
    seen = None
    for attempt in range(1, attempts + 1):
        with tempfile.TemporaryFile() as err:
            procs = {k: subprocess.Popen(a, stdout=subprocess.DEVNULL, stderr=err,
                                         stdin=subprocess.DEVNULL, start_new_session=True)
                     for k, a in argvs.items()}
            try:
                rows, cpu = observe(procs, listener, name, SETTLE['nodes'] + 1.0, seconds)
                seen = probe() if probe is not None else None
            finally:
                _stop(procs.values())
            if len(rows) >= 2:
                break
            err.seek(0)
            tail = err.read().decode(errors='replace').strip().splitlines()[-8:]
            print(f'[bench] {name}: no diagnostics rows in the window (attempt {attempt}); '
                  'the nodes\' last stderr lines:\n  ' + '\n  '.join(tail or ['(none)']),
                  flush=True)
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
            'busy50': med('busy_p50_ms'), 'busy99': med('busy_p99_ms'),
            'rtt50': med('round_trip_p50_ms'), 'rtt99': med('round_trip_p99_ms'),
            'in_time': 1.0 - late / max(1, cycles), 'wkc': wkc, 'cycles': cycles,
            'cpu': cpu, 'probe': seen}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--rt', type=int, default=0, help='SCHED_FIFO priority (0: normal)')
    parser.add_argument('--only', choices=('hardware', 'sim', 'direct', 'topics'),
                        help='run only these rows')
    parser.add_argument('--hog', action='store_true',
                        help='one CPU-burning process per core (normal priority) meanwhile')
    parser.add_argument('--quick', action='store_true',
                        help='smoke run: the hardware rows, 1 s each')
    parser.add_argument('--profiles', action='store_true',
                        help='hardware direct once per emulated drive profile (the pinch drive)')
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.only = 1.0, args.only or 'hardware'
        SETTLE.update(nodes=2.0, diagnostics_period=0.2)
    hogs = start_hogs() if args.hog else []
    try:
        if args.profiles:
            run_profiles(args)
        else:
            run(args)
    finally:
        _stop(hogs)


PROFILES = ('standard', 'elmo_like', 'ingenia_like', 'csp_start', 'requires_dc',
            'requires_60c2', 'slow_controlword')


def run_profiles(args):
    """``hardware direct`` with the pinch drive of each profile, its bus YAML as it needs."""
    if os.geteuid() != 0:
        sys.exit('needs root: veth pair, network namespace, raw EtherCAT socket')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    import yaml
    from ethercat.emulator.cia402 import PROFILES as EMULATED
    from ethercat.emulator.config import default_config
    from ethercat.harness import EmulatorHarness
    from ethercat.lines import NEEDS

    prefix = ['chrt', '-f', str(args.rt)] if args.rt else []
    listener = DiagnosticsListener()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        for profile in PROFILES:
            config = default_config()
            config['slaves'][1]['profile'] = profile
            config['channels']['pinch']['environment'] = {
                'mode': 'position_sine', 'amplitude': 0.5, 'frequency': 1.0}
            bus = yaml.safe_load(BUS.read_text())
            bus['slaves'][1]['product_code'] = EMULATED[profile].product_code
            bus['slaves'][1].update(NEEDS.get(profile, {}))
            bus_path = tmp / f'bus_{profile}.yaml'
            bus_path.write_text(yaml.safe_dump(bus))
            harness = EmulatorHarness(config, workdir=tmp / profile,
                                      realtime=args.rt + 10 if args.rt else 0)
            try:
                harness.start()
                params = tmp / f'{profile}.yaml'
                params.write_text(
                    '/**:\n  ros__parameters:\n    pinch.mode: dob_full_ff\n    wrist.mode: dob\n'
                    f'    state_timeout: 1.0\n    torque_limit: 5.0\n'
                    f'    diagnostics_period: {SETTLE["diagnostics_period"]}\n'
                    f'    interface: {harness.master_interface}\n    bus_config: {bus_path}\n'
                    '    autostart: active\n    loop: direct\n')
                argv = {'bringup': prefix + [str(LIB / 'hardware_bringup'), '--ros-args',
                                             '--params-file', str(CONFIG), '--params-file',
                                             str(params)]}
                print(f'[bench] hardware direct, pinch drive {profile}: {args.seconds:.0f} s',
                      flush=True)
                result = measure(argvs=argv, name='hardware: bus', seconds=args.seconds,
                                 listener=listener,
                                 probe=lambda: harness.client.slave('pinch_drive'))
                status = (result or {}).get('probe') or harness.client.slave('pinch_drive')
                results[profile] = (result, status)
            finally:
                harness.stop()
    listener.close()
    print(f'\n{"pinch drive":18s}{"rate Hz":>9s}{"per p99":>9s}{"busy99":>8s}{"wkc err":>9s}'
          f'{"fresh":>9s}  {"OP":>3s} {"CST enabled":>11s}  {"unsafe":>6s}  DC  CPU %')
    for profile, (r, st) in results.items():
        if r is None:
            print(f'{profile:18s}  no diagnostics received (AL {st["al_state"]}, code '
                  f'0x{st["al_status_code"]:04X})')
            continue
        cpu = ' '.join(f'{k}={v:.0f}' for k, v in r['cpu'].items())
        dc = 'SYNC0' if st['sync0_active'] else 'free'
        print(f'{profile:18s}{r["rate"]:9.0f}{r["p99"]:9.3f}{r["busy99"]:8.3f}{r["wkc"]:9d}'
              f'{100 * r["in_time"]:8.2f}%  {"yes" if st["al_state"] == 8 else "no":>3s} '
              f'{"yes" if st["torque_enabled"] else "no":>11s}  '
              f'{st["unsafe_torque_frames"] + st["enables_outside_cst"]:6d}  {dc:5s} {cpu}')
    print(f'\nfresh: the command for cycle k arrived before cycle k+1 ({args.seconds:.0f} s per '
          'row); unsafe: frames with torque to a drive not in Operation enabled in CST, and '
          'enables outside CST, counted by the drive')


def run(args):
    if os.geteuid() != 0:
        sys.exit('needs root: veth pair, network namespace, raw EtherCAT socket')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    from ethercat.emulator.config import default_config
    from ethercat.harness import EmulatorHarness

    prefix = ['chrt', '-f', str(args.rt)] if args.rt else []
    ctl_prefix = ['chrt', '-f', str(max(1, args.rt - 10))] if args.rt else []
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        common = ('    pinch.mode: dob_full_ff\n    wrist.mode: dob\n    state_timeout: 1.0\n'
                  '    torque_limit: 5.0\n    pinch.environment.mode: position_sine\n'
                  '    pinch.environment.amplitude: 0.5\n'
                  f'    diagnostics_period: {SETTLE["diagnostics_period"]}\n')
        config = default_config()
        config['channels']['pinch']['environment'] = {
            'mode': 'position_sine', 'amplitude': 0.5, 'frequency': 1.0}
        harness = EmulatorHarness(config, workdir=tmp / 'emulator',
                                  realtime=args.rt + 10 if args.rt else 0)
        listener = DiagnosticsListener()

        def argv(executable, extra, name):
            path = tmp / f'{name}.yaml'
            path.write_text('/**:\n  ros__parameters:\n' + common + extra)
            pre = ctl_prefix if executable == 'controller_node' else prefix
            return pre + [str(LIB / executable), '--ros-args', '--params-file', str(CONFIG),
                          '--params-file', str(path)]

        try:
            harness.start()
            hw = (f'    interface: {harness.master_interface}\n    bus_config: {BUS}\n'
                  '    autostart: active\n')
            for layout in ('topics', 'direct'):
                if args.only in ('sim', 'direct' if layout == 'topics' else 'topics'):
                    continue
                print(f'[bench] hardware {layout} over EtherCAT (emulator on '
                      f'{harness.master_interface}): {args.seconds:.0f} s', flush=True)
                if layout == 'topics':
                    argvs = {'hardware': argv('hardware_node', hw, 'hw'),
                             'controller': argv('controller_node', '', 'ctl')}
                else:
                    argvs = {'bringup': argv('hardware_bringup', hw + '    loop: direct\n',
                                             'hwb')}
                results[f'hardware {layout}'] = measure(argvs, 'hardware: bus', args.seconds,
                                                        listener)
        finally:
            harness.stop()
        for layout in ('topics', 'direct'):
            if args.only in ('hardware', 'direct' if layout == 'topics' else 'topics'):
                continue
            print(f'[bench] sim {layout}: {args.seconds:.0f} s', flush=True)
            if layout == 'topics':
                argvs = {'sim': argv('sim_node', '', 'sim'),
                         'controller': argv('controller_node', '', 'ctl')}
            else:
                argvs = {'bringup': argv('bringup', '    loop: direct\n', 'simb')}
            results[f'sim {layout}'] = measure(argvs, 'sim: cycle', args.seconds, listener)
        listener.close()
    print(f'\n{"plant, layout":18s}{"rate Hz":>9s}{"per p50":>9s}{"per p99":>9s}{"busy50":>8s}'
          f'{"busy99":>8s}{"wkc err":>9s}'
          f'{"rtt p50":>9s}{"rtt p99":>9s}{"fresh":>9s}  CPU % per process')
    for name, r in results.items():
        if r is None:
            print(f'{name:18s}  no diagnostics received')
            continue
        cpu = ' '.join(f'{k}={v:.0f}' for k, v in r['cpu'].items())
        print(f'{name:18s}{r["rate"]:9.0f}{r["p50"]:9.3f}{r["p99"]:9.3f}{r["busy50"]:8.3f}'
              f'{r["busy99"]:8.3f}{r["wkc"]:9d}'
              f'{r["rtt50"]:9.3f}{r["rtt99"]:9.2f}{100 * r["in_time"]:8.2f}%  {cpu}')
    print(f'\nperiods and round trips in ms; wkc err: working-counter errors in '
          f'{args.seconds:.0f} s; fresh: the command for cycle k arrived before cycle k+1; '
          f'scheduling: {"SCHED_FIFO " + str(args.rt) if args.rt else "normal"}'
          f'{", with a CPU hog per core" if args.hog else ""}')


if __name__ == '__main__':
    main()

"""The main job: the simulated gripper under closed-loop control over ROS 2.

Starts ``sim_node`` and ``controller_node`` as separate processes on one parameter file,
backdrives the ``pinch`` finger with the paper's quasi-static position drive (0.5 rad at
1 rad/s, the bonded-finger experiment of Fig. 5A-B), switches ``pinch.mode`` through
``passive, hold, dob, dob_linear_ff, dob_full_ff`` with the controller's parameter service (what
``ros2 param set`` does), and for each mode measures from ``actuator_state``:

* the peak external torque |F_e| over the work loop and within +-0.2 rad,
* |Z(j omega)| = |F_e / V_e| at the drive frequency (dB re 1 N m s/rad),

A window in which the plant went without a fresh command (zero torque: a busy host in real
time) does not measure the mode: it is measured again, up to ``ATTEMPTS`` times, and the table
notes what remained (``--lockstep`` steps the plant only on the controller's answer: exact on
any host). It
prints a table with the impedance range (``hold`` vs the softest mode), writes a PNG of the
work loops (external F_e and internal F_p vs X_e, as Fig. 5A-B), and stops every process it
started, also on Ctrl-C or an error.

Usage: python -m seaforce_ros.demo [--out DIR] [--periods N] [--amplitude RAD]
       [--frequency RAD_S] [--lockstep]
       python -m seaforce_ros.demo grasp [...]   (the grasping demo: seaforce_ros.grasp_demo)
"""
from __future__ import annotations

import argparse
import math
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time
from typing import Dict, List

import numpy as np

from .core.plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_FAULT, STATUS_LIMIT
from .identification.zwidth_lib import DEFAULT_MODES as MODES  # the paper's Fig. 5 modes

CHANNEL = 'pinch'
DT = 5e-4
#: measurements of a mode at most, when the controller's answers came late (real time only)
ATTEMPTS = 3


def _package_paths():
    """(lib dir with the executables, default config file)."""
    try:
        from ament_index_python.packages import (get_package_prefix,
                                                 get_package_share_directory)
        lib = pathlib.Path(get_package_prefix('seaforce_ros')) / 'lib' / 'seaforce_ros'
        config = pathlib.Path(get_package_share_directory('seaforce_ros')) / 'config' / 'gripper.yaml'
        if (lib / 'sim_node').exists() and config.exists():
            return lib, config
    except Exception:
        pass
    root = pathlib.Path(__file__).resolve().parent.parent
    return root / 'install' / 'seaforce_ros' / 'lib' / 'seaforce_ros', root / 'config' / 'gripper.yaml'


class Children:
    """Node processes of the demo; each is ended by its own PID."""

    def __init__(self, log_dir: pathlib.Path):
        self.log_dir = log_dir
        self.procs: List[subprocess.Popen] = []
        self.observers = []              # closed (before the processes stop) by stop_all

    def start(self, argv, name):
        log = open(self.log_dir / f'{name}.log', 'wb')
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        proc.log_path = self.log_dir / f'{name}.log'
        self.procs.append(proc)
        return proc

    def check(self):
        """RuntimeError if a node has exited."""
        for proc in self.procs:
            if proc.poll() is not None:
                raise RuntimeError(f'{proc.args[0]} exited; see {proc.log_path}')

    def stop_all(self):
        for observer in self.observers:
            observer.close()
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for proc in self.procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)


class Observer:
    """In-process ROS node: records actuator_state/controller_status, sets parameters."""

    def __init__(self):
        from seaforce_msgs.msg import ActuatorState, ControllerStatus

        from .ros_common import RECORD_QOS, STATUS_QOS, BackgroundNode

        self.background = BackgroundNode('seaforce_demo')
        self.node = self.background.node
        self.lock = threading.Lock()
        self.states = []
        self.modes: Dict[int, str] = {}
        self.param_client = None
        self.node.create_subscription(ActuatorState, 'actuator_state', self._on_state, RECORD_QOS)
        self.node.create_subscription(ControllerStatus, 'controller_status', self._on_status,
                                      STATUS_QOS)

    def _on_state(self, msg):
        i = list(msg.name).index(CHANNEL)
        with self.lock:
            self.states.append((msg.cycle, msg.motor_position[i], msg.pressure_force[i],
                                msg.motor_effort[i], msg.endpoint_position[i],
                                msg.external_force[i], msg.status[i]))

    def _on_status(self, msg):
        i = list(msg.name).index(CHANNEL)
        with self.lock:
            self.modes[msg.cycle] = msg.mode[i]

    def latest_cycle(self):
        with self.lock:
            return self.states[-1][0] if self.states else None

    def first_cycle_in_mode(self, mode, after):
        with self.lock:
            cycles = [c for c, m in self.modes.items() if m == mode and c > after]
        return min(cycles) if cycles else None

    def set_mode(self, mode, timeout=20.0):
        from rclpy.parameter import Parameter
        from rclpy.parameter_client import AsyncParameterClient

        from .ros_common import request_until_answered
        if self.param_client is None:
            self.param_client = AsyncParameterClient(self.node, '/controller')
            if not self.param_client.wait_for_services(timeout_sec=timeout):
                raise RuntimeError('the controller parameter services did not come up')
        try:
            response = request_until_answered(lambda: self.param_client.set_parameters(
                [Parameter(f'{CHANNEL}.mode', value=mode)]), timeout)
        except TimeoutError:
            raise RuntimeError(f'no answer setting {CHANNEL}.mode') from None
        result = response.results[0]
        if not result.successful:
            raise RuntimeError(f'{CHANNEL}.mode={mode} rejected: {result.reason}')

    def window(self, first, last):
        """Recorded samples with first <= cycle <= last as arrays on a uniform cycle grid."""
        with self.lock:
            rows = [r for r in self.states if first <= r[0] <= last]
        rows = sorted({r[0]: r for r in rows}.values())
        data = np.array(rows, dtype=float)
        grid = np.arange(first, last + 1, dtype=float)
        status = data[:, 6].astype(int)
        out = {'cycle': grid, 'received': len(rows), 'expected': grid.size,
               'status': int(np.bitwise_or.reduce(status)),
               'timeouts': int(np.count_nonzero(status & STATUS_COMMAND_TIMEOUT))}
        for k, name in enumerate(('x', 'f_p', 'f_a', 'x_e', 'f_e'), start=1):
            out[name] = np.interp(grid, data[:, 0], data[:, k])
        return out

    def close(self):
        self.background.close()


def measure(window, omega, amplitude):
    from .core.analysis import impedance_from_position
    z = impedance_from_position(window['f_e'], window['x_e'], omega, DT)
    f_e, x_e = window['f_e'], window['x_e']
    centre = np.abs(x_e) <= 0.2 * amplitude / 0.5
    area = abs(np.trapezoid(window['f_p'], x_e))
    return {'z_db': 20.0 * math.log10(abs(z)), 'peak': float(np.max(np.abs(f_e))),
            'peak_centre': float(np.max(np.abs(f_e[centre]))) if centre.any() else float('nan'),
            'fp_area': area}


def plot(results, path, amplitude):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    colours = {'passive': '#f2b705', 'hold': '#d62728', 'dob': '#17becf',
               'dob_linear_ff': '#c51b8a', 'dob_full_ff': '#1f77b4'}
    fig, (ax_e, ax_p, ax_h) = plt.subplots(1, 3, figsize=(16, 5), sharex=True)
    for mode, (window, m) in results.items():
        kw = dict(color=colours.get(mode), lw=1.2, label=f'{mode}  |Z|={m["z_db"]:.1f} dB')
        if mode == 'hold':
            ax_h.plot(window['x_e'], window['f_e'], **kw)
            ax_h.plot(window['x_e'], window['f_p'], color='0.4', lw=1.0, ls='--',
                      label='hold: internal F_p')
        else:
            ax_e.plot(window['x_e'], window['f_e'], **kw)
            ax_p.plot(window['x_e'], window['f_p'], **kw)
    ax_e.set_title('external torque F_e (what the finger feels)')
    ax_p.set_title('internal pressure torque F_p (what the controller sees)')
    ax_h.set_title('hold: maximum impedance (stiff PD on the motor)')
    for ax in (ax_e, ax_p, ax_h):
        ax.set_xlabel('endpoint position X_e [rad]')
        ax.set_ylabel('torque [N m]')
        ax.axvspan(-0.2 * amplitude / 0.5, 0.2 * amplitude / 0.5, color='0.93', zorder=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f'pinch finger backdriven {amplitude} rad (work loops, cf. paper Fig. 5A-B); '
                 'simulated gripper under ROS 2 closed-loop control')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run_guarded(label, out, work):
    """``work(children)`` -> exit code, with the demos' hygiene: SIGTERM is an interrupt, every
    node started through ``children`` is ended by its PID (observers it lists closed first),
    an error is one line and exit code 1, Ctrl-C 130."""
    children = Children(out)

    def on_signal(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, on_signal)
    print(f'[{label}] ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")}; logs in {out}/',
          flush=True)
    try:
        return work(children)
    except KeyboardInterrupt:
        print(f'[{label}] interrupted; stopping the nodes', file=sys.stderr)
        return 130
    except (RuntimeError, ValueError) as exc:
        print(f'[{label}] failed: {exc}', file=sys.stderr)
        return 1
    finally:
        children.stop_all()


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['grasp']:
        from .grasp_demo import main as grasp_main
        return grasp_main(argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', default='out/demo', help='output directory (PNG, logs)')
    parser.add_argument('--periods', type=int, default=1,
                        help='drive periods measured per mode (after one settling second)')
    parser.add_argument('--amplitude', type=float, default=0.5, help='drive amplitude [rad]')
    parser.add_argument('--frequency', type=float, default=1.0, help='drive frequency [rad/s]')
    parser.add_argument('--lockstep', action='store_true',
                        help='deterministic lockstep simulation instead of real time')
    parser.add_argument('--config', default=None, help='parameter file (default gripper.yaml)')
    args = parser.parse_args(argv)

    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lib, config = _package_paths()
    config = pathlib.Path(args.config) if args.config else config
    overrides = out / 'demo-overrides.yaml'
    overrides.write_text(
        'sim:\n  ros__parameters:\n'
        f'    clock_mode: {"lockstep" if args.lockstep else "realtime"}\n'
        f'    {CHANNEL}.environment.mode: position_sine\n'
        f'    {CHANNEL}.environment.amplitude: {args.amplitude}\n'
        f'    {CHANNEL}.environment.frequency: {args.frequency}\n')
    period_cycles = int(math.ceil(2 * math.pi / args.frequency / DT)) + 1

    def work(children):
        for name in ('sim_node', 'controller_node'):
            argv_node = [str(lib / name), '--ros-args', '--params-file', str(config)]
            if name == 'sim_node':
                argv_node += ['--params-file', str(overrides)]
            children.start(argv_node, name)
        observer = Observer()
        children.observers.append(observer)
        print('[demo] waiting for the closed loop to come up ...', flush=True)
        deadline = time.monotonic() + 60
        while observer.latest_cycle() is None or not observer.modes:
            children.check()
            if time.monotonic() > deadline:
                raise RuntimeError('no actuator_state/controller_status within 60 s')
            time.sleep(0.1)

        observer.set_mode('passive')  # also connects the parameter client before measuring
        results = {}
        settle = int(round(1.0 / DT))
        for mode in MODES:
            before = observer.latest_cycle()
            observer.set_mode(mode)
            deadline = time.monotonic() + 20
            while (start := observer.first_cycle_in_mode(mode, before)) is None:
                if time.monotonic() > deadline:
                    raise RuntimeError(f'controller_status never showed mode {mode}')
                time.sleep(0.05)
            first = start + settle
            for attempt in range(1, ATTEMPTS + 1):
                last = first + args.periods * period_cycles - 1
                print(f'[demo] {mode:14s} measuring cycles {first}..{last} '
                      f'({(last - first + 1) * DT:.1f} s of drive)', flush=True)
                while (observer.latest_cycle() or 0) < last:
                    children.check()
                    time.sleep(0.1)
                window = observer.window(first, last)
                if not window['timeouts'] or attempt == ATTEMPTS:
                    break
                # zero torque while the controller's answers were late: not the mode's impedance
                print(f'[demo]   {window["timeouts"]} cycles without a fresh command (the host '
                      f'was busy); measuring again ({attempt + 1}/{ATTEMPTS})', flush=True)
                first = last + 1 + settle // 2
            results[mode] = (window, measure(window, args.frequency, args.amplitude))
            if window['received'] < 0.9 * window['expected']:
                print(f'[demo]   note: recorded {window["received"]} of {window["expected"]} '
                      'samples (the gaps are interpolated)')
        report(results, args)
        png = out / 'work_loops.png'
        plot(results, png, args.amplitude)
        print(f'\nwork loops: {png}')
        return 0

    return run_guarded('demo', out, work)


def status_note(window):
    """What the plant reported during a measurement window, for the table ('' when nothing)."""
    notes = []
    if window['timeouts']:
        notes.append(f'{window["timeouts"]} cycles without a fresh command (zero torque; '
                     'a busy host: --lockstep measures exactly)')
    if window['status'] & STATUS_LIMIT:
        notes.append('torque limit reached')
    if window['status'] & STATUS_FAULT:
        notes.append('a channel fault')
    return f'  ({"; ".join(notes)}: see the sim log)' if notes else ''


def report(results, args):
    soft = min((m for m in results if m != 'hold'), key=lambda m: results[m][1]['z_db'])
    print(f'\nPinch finger backdriven {args.amplitude} rad at {args.frequency} rad/s; '
          'the controller only measures motor position and hose pressure.\n')
    print(f'{"mode":15s}{"|Z| [dB]":>10s}{"vs passive":>11s}{"peak |F_e|":>13s}'
          f'{"|F_e| in +-0.2":>16s}{"F_p loop area":>15s}')
    print(f'{"":15s}{"re N m s/rad":>10s}{"[dB]":>11s}{"[N m]":>13s}{"rad [N m]":>16s}'
          f'{"[N m rad]":>15s}')
    z_passive = results['passive'][1]['z_db'] if 'passive' in results else float('nan')
    for mode, (window, m) in results.items():
        flag = status_note(window)
        print(f'{mode:15s}{m["z_db"]:10.1f}{m["z_db"] - z_passive:11.1f}{m["peak"]:13.3f}'
              f'{m["peak_centre"]:16.4f}{m["fp_area"]:15.4f}{flag}')
    if 'hold' in results:
        width = results['hold'][1]['z_db'] - results[soft][1]['z_db']
        print(f'\nimpedance range at {args.frequency} rad/s: {width:.1f} dB '
              f'(hold vs {soft}); paper, on hardware: ~50 dB up to 3 rad/s')


if __name__ == '__main__':
    sys.exit(main())

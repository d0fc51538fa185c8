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

The model is not the plant: by default the sim's true plant (``pinch.sim.plant.*``,
``pinch.sim.dahl.*``) is every Table I and Dahl parameter 10-20 % off the controller's model
(signs drawn with ``--seed``, as the grasp demo does), so that the minimum impedance, and with
it the range, is limited by model error as on the paper's hardware (``--ideal``: the sim runs
the model itself). Then the finger is released into free air, ``~/calibrate_friction``
recalibrates b_e, k_e, F_c and sigma (``--calibration-time`` s), and ``dob_full_ff`` is measured
again: the table of what the calibration recovers, against the sim's truth, and the |Z| it
gains (``--no-calibration`` skips it).

Usage: python -m seaforce_ros.demo [--out DIR] [--periods N] [--amplitude RAD]
       [--frequency RAD_S] [--lockstep] [--ideal] [--seed N] [--calibration-time S]
       [--no-calibration]
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


def prepare(out):
    """A demo's start: localhost-only discovery unless set, the output directory made;
    ``(out directory, lib dir with the executables, default config file)``."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return (out, *_package_paths())


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
    parser.add_argument('--ideal', action='store_true',
                        help="the sim's plant is the controller's model (no model error)")
    parser.add_argument('--seed', type=int, default=3,
                        help="signs of the sim's 10-20 %% model error")
    parser.add_argument('--calibration-time', type=float, default=10.0,
                        help='friction calibration length [s]')
    parser.add_argument('--no-calibration', action='store_true',
                        help='skip the friction calibration and the re-measurement')
    args = parser.parse_args(argv)

    out, lib, config = prepare(args.out)
    config = pathlib.Path(args.config) if args.config else config
    overrides = out / 'demo-overrides.yaml'
    overrides.write_text(
        'sim:\n  ros__parameters:\n'
        f'    clock_mode: {"lockstep" if args.lockstep else "realtime"}\n'
        f'    {CHANNEL}.environment.mode: position_sine\n'
        f'    {CHANNEL}.environment.amplitude: {args.amplitude}\n'
        f'    {CHANNEL}.environment.frequency: {args.frequency}\n'
        + ''.join(f'    {key}: {v!r}\n' for key, v in model_error(args).items()))
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
        if not args.no_calibration:
            recalibrate(observer, children, args, results['dob_full_ff'][1]['z_db'])
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


# --- model error, and what the friction calibration recovers (issue 13) -------------------
FRICTION_LABELS = ('b_e [N m s/rad]', 'k_e [N m/rad]', 'F_c [N m]', 'sigma [N m/rad]')
CALIBRATION_ATTEMPTS = 3
CALIBRATION_STATE_TIMEOUT = 0.25   # s, controller state_timeout while calibrating


def model_error(args):
    """``{'pinch.sim.<key>': value}`` of the sim's true plant: none with ``--ideal``."""
    if args.ideal:
        return {}
    from .grasp_demo import true_plant
    return {key: float(v) for key, v in true_plant(args.seed)[0].items()}


def set_parameters(node, target, values, timeout=20.0, atomically=False):
    """Set ``values`` (name -> value) on ``target``'s node, all or none if ``atomically``;
    RuntimeError with the node's reason if it refuses or does not answer."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from .ros_common import request_until_answered
    client = AsyncParameterClient(node, target)
    if not client.wait_for_services(timeout_sec=timeout):
        raise RuntimeError(f'the parameter services of {target} did not come up')
    parameters = [Parameter(k, value=v) for k, v in values.items()]
    request = (client.set_parameters_atomically if atomically else client.set_parameters)
    try:
        response = request_until_answered(lambda: request(parameters), timeout)
    except TimeoutError:
        raise RuntimeError(f'no answer setting {list(values)} on {target}') from None
    results = [response.result] if atomically else response.results
    failed = [r.reason for r in results if not r.successful]
    if failed:
        raise RuntimeError(f'{target} rejected {list(values)}: {failed[0]}')


def get_parameter(node, target, name, timeout=20.0):
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    from .ros_common import request_until_answered
    client = AsyncParameterClient(node, target)
    if not client.wait_for_services(timeout_sec=timeout):
        raise RuntimeError(f'the parameter services of {target} did not come up')
    try:
        response = request_until_answered(lambda: client.get_parameters([name]), timeout)
    except TimeoutError:
        raise RuntimeError(f'no answer reading {name} on {target}') from None
    return parameter_value_to_python(response.values[0])


def run_friction_calibration(observer, children, args):
    """Release the finger into free air and run ~/calibrate_friction; its result. The
    controller's ``state_timeout`` and the channel's mode are left as the calibration set them
    (``hold``): the caller restores them."""
    from rclpy.action import ActionClient
    from seaforce_msgs.action import CalibrateFriction
    node = observer.node
    # held where the drive left it, then released (in dob_full_ff a model that
    # over-compensates k_e lets the free finger creep away, out of the joint range); a
    # longer state_timeout while it runs: a loaded host's real-time loop stalls now and then,
    # and a stall aborts a calibration (zero torque, nothing applied)
    set_parameters(node, '/controller', {
        f'{CHANNEL}.mode': 'hold', 'state_timeout': CALIBRATION_STATE_TIMEOUT,
        f'{CHANNEL}.friction.calibration_duration': float(args.calibration_time)})
    set_parameters(node, '/sim', {f'{CHANNEL}.environment.mode': 'free'})
    client = ActionClient(node, CalibrateFriction, '/controller/calibrate_friction')
    if not client.wait_for_server(timeout_sec=20.0):
        raise RuntimeError('the ~/calibrate_friction action server did not come up')
    time.sleep(0.5)                                  # the released finger settles
    goal = CalibrateFriction.Goal(channel=CHANNEL, amplitude=0.4, speed=1.0, apply=True)
    for attempt in range(1, CALIBRATION_ATTEMPTS + 1):
        print(f'[demo] friction calibration: the finger in free air, '
              f'{args.calibration_time:g} s of motion ...', flush=True)
        deadline = time.monotonic() + 3.0 * args.calibration_time + 60.0
        # (requests from the spin thread: from this one rclpy can drop the answer)
        future = observer.background.call(lambda: client.send_goal_async(goal))
        while not future.done():
            children.check()
            if time.monotonic() > deadline:
                raise RuntimeError('the calibration goal was not answered')
            time.sleep(0.05)
        result_future = observer.background.call(future.result().get_result_async)
        while not result_future.done():
            children.check()
            if time.monotonic() > deadline:
                raise RuntimeError('the friction calibration did not end in time')
            time.sleep(0.1)
        result = result_future.result().result
        if result.applied or attempt == CALIBRATION_ATTEMPTS:
            return result
        # a real-time loop on a loaded host stalls now and then: the stall zeroes the torque
        # and aborts the calibration (nothing applied); try again
        print(f'[demo]   aborted: {result.message}', flush=True)


def print_calibration(result, truth, seconds):
    """The table of what ~/calibrate_friction recovered: model, new value, 1-sigma, the sim's
    truth (``{'<ch>.sim.<key>': value}``; the model where it has none) and the error."""
    print(f'\nFriction calibration (~/calibrate_friction, {seconds:g} s in free air): '
          f'{result.message}')
    print(f'{"parameter":18s}{"model":>11s}{"recalibrated":>14s}{"1-sigma":>10s}'
          f'{"sim truth":>11s}{"error":>9s}')
    for label, key, old, new, sigma in zip(FRICTION_LABELS, result.names, result.old_values,
                                           result.new_values, result.new_values_sigma):
        true = truth.get(f'{CHANNEL}.sim.{key}', old)
        print(f'{label:18s}{old:11.4g}{new:14.4g}{sigma:10.2g}{true:11.4g}'
              f'{100.0 * (new / true - 1.0):+8.1f}%')


def recalibrate(observer, children, args, z_before):
    """Calibrate, drive the finger again, measure dob_full_ff, print what was recovered."""
    state_timeout = get_parameter(observer.node, '/controller', 'state_timeout')
    result = run_friction_calibration(observer, children, args)
    set_parameters(observer.node, '/controller', {'state_timeout': state_timeout,
                                                  f'{CHANNEL}.mode': 'dob_full_ff'})
    if not result.applied:
        print(f'\nfriction calibration: {result.message}')
        return
    before = observer.latest_cycle()
    set_parameters(observer.node, '/sim', {f'{CHANNEL}.environment.mode': 'position_sine'})
    first = before + int(round(1.0 / DT))
    last = first + args.periods * (int(math.ceil(2 * math.pi / args.frequency / DT)) + 1) - 1
    while (observer.latest_cycle() or 0) < last:
        children.check()
        time.sleep(0.1)
    z_after = measure(observer.window(first, last), args.frequency, args.amplitude)['z_db']
    print_calibration(result, model_error(args), args.calibration_time)
    print(f'recalibrated dob_full_ff |Z| at {args.frequency} rad/s: {z_after:.1f} dB '
          f'(was {z_before:.1f} dB with the model)')


if __name__ == '__main__':
    sys.exit(main())

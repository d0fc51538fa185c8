"""The main job: the simulated gripper under closed-loop control over ROS 2.

Starts ``sim_node`` and ``controller_node`` as separate processes on one parameter file,
backdrives the ``pinch`` finger with the paper's quasi-static position drive (0.5 rad at
1 rad/s, the bonded-finger experiment of Fig. 5A-B), switches ``pinch.mode`` through
``passive, hold, dob, dob_linear_ff, dob_full_ff`` with the controller's parameter service (what
``ros2 param set`` does), and for each mode measures from ``actuator_state``:

* |Z(j omega)| = |F_e / V_e| of the fundamentals at the drive frequency (dB re 1 N m s/rad),
  beside the rms impedance rms(F_e)/rms(V_e) and the harmonic distortion of F_e,
* the peak external torque |F_e| over the work loop and within +-0.2 rad,

A window in which the plant went without a fresh command (zero torque: a busy host in real
time) does not measure the mode: it is measured again, up to ``ATTEMPTS`` times, and the table
notes what remained (``--lockstep`` steps the plant only on the controller's answer: exact on
any host). It
prints a table with the impedance range (``hold`` vs the softest mode, on the fundamental and
on the rms), writes a PNG of the
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

Usage: python -m seaforce_ros.demos [--out DIR] [--periods N] [--amplitude RAD]
       [--frequency RAD_S] [--lockstep] [--ideal] [--seed N] [--calibration-time S]
       [--no-calibration]
       python -m seaforce_ros.demos grasp [...]   (the grasping demo: seaforce_ros.demos.grasp)
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys
import threading
import time
from typing import Dict

import numpy as np

from ..core.plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_FAULT, STATUS_LIMIT
from ..identification.zwidth_lib import DEFAULT_MODES as MODES  # the paper's Fig. 5 modes
from .common import (CHANNEL, DT, SERVICE_TIMEOUT, get_parameter, prepare, print_calibration,
                     run_friction_calibration, run_guarded, set_parameters, true_plant,
                     wait_until)

#: measurements of a mode at most, when the controller's answers came late (real time only)
ATTEMPTS = 3
#: A measurement with fewer of its states recorded than this share is taken again.
COMPLETE = 0.98
#: seconds of passive between two modes (the hose's deflection released)
RELEASE = 0.25






class Observer:
    """In-process ROS node: records actuator_state/controller_status, sets parameters."""

    def __init__(self):
        from seaforce_msgs.msg import ActuatorState, ControllerStatus

        from ..nodes.ros_common import RECORD_QOS, STATUS_QOS, BackgroundNode

        self.background = BackgroundNode('seaforce_demo')
        self.node = self.background.node
        self.lock = threading.Lock()
        self.states_lock = threading.Lock()
        self.states = []
        # actuator_state as it arrives, serialized: the callback only keeps the bytes (a
        # lockstep loop publishes faster than 2 kHz, and a busy host's subscriber that
        # builds each message falls behind and loses some: their gaps, interpolated, bent
        # the measured velocity); read on demand (:meth:`_drain`)
        self._raw: list = []
        self._state_type = ActuatorState
        self.modes: Dict[int, str] = {}
        self.fault: Dict[int, str] = {}
        self.param_client = None
        self.node.create_subscription(ActuatorState, 'actuator_state', self._on_state, RECORD_QOS,
                                      raw=True)
        self.node.create_subscription(ControllerStatus, 'controller_status', self._on_status,
                                      STATUS_QOS)

    def _on_state(self, data):
        with self.lock:
            self._raw.append(data)

    def _drain(self):
        """Deserialize what arrived since the last call into ``states`` (the caller holds
        ``states_lock``; the subscription's thread is kept waiting only for the swap)."""
        from rclpy.serialization import deserialize_message
        with self.lock:
            raw, self._raw = self._raw, []
        for data in raw:
            msg = deserialize_message(data, self._state_type)
            i = list(msg.name).index(CHANNEL)
            self.states.append((msg.cycle, msg.motor_position[i], msg.pressure_force[i],
                                msg.motor_effort[i], msg.endpoint_position[i],
                                msg.external_force[i], msg.status[i]))

    def _on_status(self, msg):
        i = list(msg.name).index(CHANNEL)
        with self.lock:
            self.modes[msg.cycle] = msg.mode[i]
            if msg.fault[i]:
                self.fault[msg.cycle] = str(msg.fault[i])

    def fault_in(self, first: int, last: int) -> str:
        """The channel's fault reported in ``first..last`` (a latched fall-back of the runaway
        monitor, a fault); '' when none."""
        with self.lock:
            found = [f for c, f in self.fault.items() if first <= c <= last]
        return found[0] if found else ''

    def latest_fault(self) -> str:
        """The fault of the latest status ('' when none)."""
        with self.lock:
            if not self.modes:
                return ''
            return self.fault.get(max(self.modes), '')

    def wait_until_live(self, children, timeout=60.0):
        """Until both topics arrive; RuntimeError if a node exits or ``timeout`` s pass."""
        wait_until(children, lambda: self.latest_cycle() is not None and bool(self.modes),
                   timeout, 'no actuator_state/controller_status', poll=0.1)

    def wait_cycle(self, children, cycle):
        """Until a state of ``cycle`` or later arrived (RuntimeError if a node exits)."""
        wait_until(children, lambda: (self.latest_cycle() or 0) >= cycle, math.inf,
                   f'no state of cycle {cycle}', poll=0.1)

    def wait_mode(self, mode, after, children, timeout=20.0):
        """The first status cycle after ``after`` in ``mode``, once there is one."""
        wait_until(children, lambda: self.first_cycle_in_mode(mode, after) is not None,
                   timeout, f'controller_status did not show mode {mode}')
        return self.first_cycle_in_mode(mode, after)

    def latest_cycle(self):
        with self.states_lock:
            self._drain()
            return self.states[-1][0] if self.states else None

    def first_cycle_in_mode(self, mode, after):
        with self.lock:
            cycles = [c for c, m in self.modes.items() if m == mode and c > after]
        return min(cycles) if cycles else None

    def enter_mode(self, mode, children, timeout=20.0, centre=None):
        """Set ``mode`` through ``passive`` (RELEASE s of it) and return the first status cycle
        in it: a switch straight from ``hold`` to a DOB mode releases the hose's deflection
        at once, and the runaway monitor takes the motor's slam (30-45 rad/s measured) for
        a finger driven away. With ``centre`` [rad] (a drive's centre), the mode is set as
        the driven finger crosses it (:meth:`wait_crossing`)."""
        before = self.latest_cycle() or 0
        self.set_mode('passive')
        self.wait_cycle(children, self.wait_mode('passive', before, children, timeout)
                        + int(round(RELEASE / DT)))
        if centre is not None:
            self.wait_crossing(children, centre, timeout)
        before = self.latest_cycle()
        self.set_mode(mode)
        return self.wait_mode(mode, before, children, timeout)

    def wait_crossing(self, children, centre, timeout=20.0, rising=False, required=True):
        """Until the finger's endpoint position crosses ``centre`` [rad] (upwards only with
        ``rising``) in the states that arrive from now on; True once it did, False after
        ``timeout`` s when not ``required`` (RuntimeError when it is). ``hold`` captures its
        set point where it is entered: entered at a drive's stroke end instead of its
        centre, its deflection -- and its torque -- reach twice what the drive's amplitude
        gives (the nonlinear commissioning demo's tuned hold hit its 20 N m max_torque so at
        0.5 rad, 1 rad/s, where 9-10 N m was predicted); and a drive installed anew restarts
        its sine at the centre, rising: at a stroke's end that is a step of the set point
        (the sim latched an overspeed fault, -101 rad/s, at the demo's switch to 3 rad/s)."""
        with self.states_lock:
            self._drain()
            seen = [len(self.states)]

        def crossed():
            with self.states_lock:
                self._drain()
                rows = self.states[max(seen[0] - 1, 0):]
                seen[0] = len(self.states)
            sides = [r[4] > centre for r in rows if math.isfinite(r[4])]
            return any((b and not a) if rising else (a != b)
                       for a, b in zip(sides, sides[1:]))
        try:
            wait_until(children, crossed, timeout, f'the finger crossing {centre:g} rad',
                       poll=0.01)
        except RuntimeError:
            children.check()
            if required:
                raise
            return False
        return True

    def set_mode(self, mode, timeout=SERVICE_TIMEOUT):
        from rclpy.parameter import Parameter
        from rclpy.parameter_client import AsyncParameterClient

        from ..nodes.ros_common import request_until_answered
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
        with self.states_lock:
            self._drain()
            rows = [r for r in self.states if first <= r[0] <= last]
        rows = sorted({r[0]: r for r in rows}.values())
        grid = np.arange(first, last + 1, dtype=float)
        if len(rows) < 2:          # nothing recorded there (a lost stretch of messages)
            nan = np.full(grid.size, np.nan)
            return {'cycle': grid, 'received': len(rows), 'expected': grid.size, 'status': 0,
                    'timeouts': 0, 'fault': '',
                    **{name: nan for name in ('x', 'f_p', 'f_a', 'x_e', 'f_e')}}
        data = np.array(rows, dtype=float)
        status = data[:, 6].astype(int)
        out = {'cycle': grid, 'received': len(rows), 'expected': grid.size,
               'status': int(np.bitwise_or.reduce(status)),
               'timeouts': int(np.count_nonzero(status & STATUS_COMMAND_TIMEOUT)),
               'fault': self.fault_in(first, last)}
        for k, name in enumerate(('x', 'f_p', 'f_a', 'x_e', 'f_e'), start=1):
            out[name] = np.interp(grid, data[:, 0], data[:, k])
        return out

    def close(self):
        self.background.close()


def measure(window, omega, amplitude=None):
    """The impedance figures of a measured window (``core.analysis.impedance_figures``: the
    fundamental and the rms |Z|, the distortion, the peaks over the stroke and within
    +-0.2 rad), the area of the F_p loop and the finger's four-bar ratio at the stroke's ends
    (``identification.finger_ratio``: the finger's encoder against the motor and the
    pressure; its line, its ends, NaN where not fitted); ``amplitude`` is not used (the
    figures take the stroke from X_e)."""
    from ..core.analysis import impedance_figures
    from ..identification.finger_ratio import fit_finger_ratio
    fig = impedance_figures(window['f_e'], window['x_e'], omega, DT)
    area = abs(np.trapezoid(window['f_p'], window['x_e']))
    ratio = fit_finger_ratio(window['x_e'], window['x'], window['f_p'], DT)
    return {'figures': fig, 'z_db': fig.z_db, 'z_rms_db': fig.z_rms_db,
            'distortion': fig.distortion, 'peak': fig.peak, 'peak_centre': fig.peak_centre,
            'peak_away': fig.peak_away,
            'fp_area': area, 'finger_ratio': ratio.line(),
            'finger_ratio_ends': list(ratio.ends), 'finger_ratio_resolved': ratio.resolved}


def plot(results, path, amplitude):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    colours = {'passive': '#f2b705', 'hold': '#d62728', 'dob': '#17becf',
               'dob_linear_ff': '#c51b8a', 'dob_full_ff': '#1f77b4'}
    fig, (ax_e, ax_p, ax_h) = plt.subplots(1, 3, figsize=(16, 5), sharex=True)
    for mode, (window, m) in results.items():
        kw = dict(color=colours.get(mode), lw=1.2,
                  label=f'{mode}  |Z| {m["z_db"]:.1f} dB, rms {m["z_rms_db"]:.1f} dB')
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
        ax.axvspan(-0.2, 0.2, color='0.93', zorder=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f'pinch finger backdriven {amplitude} rad (work loops, cf. paper Fig. 5A-B); '
                 'simulated gripper under ROS 2 closed-loop control')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
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
        + ''.join(f'    {key}: {v!r}\n' for key, v in model_error(args).items())
        # lockstep: the stamps are the plant's wall time, and a busy host can hold a state
        # back longer than the real-time loop's 50 ms without the loop losing a step
        + ('controller:\n  ros__parameters:\n    state_timeout: 5.0\n' if args.lockstep
           else ''))
    period_cycles = int(math.ceil(2 * math.pi / args.frequency / DT)) + 1

    def work(children):
        for name in ('sim_node', 'controller_node'):
            argv_node = [str(lib / name), '--ros-args', '--params-file', str(config),
                         '--params-file', str(overrides)]
            children.start(argv_node, name)
        observer = Observer()
        children.observers.append(observer)
        print('[demo] waiting for the closed loop to come up ...', flush=True)
        observer.wait_until_live(children)
        observer.set_mode('passive')  # also connects the parameter client before measuring
        results = {}
        settle = int(round(1.0 / DT))
        for mode in MODES:
            first = observer.enter_mode(mode, children, centre=0.0) + settle
            for attempt in range(1, ATTEMPTS + 1):
                last = first + args.periods * period_cycles - 1
                print(f'[demo] {mode:14s} measuring cycles {first}..{last} '
                      f'({(last - first + 1) * DT:.1f} s of drive)', flush=True)
                observer.wait_cycle(children, last)
                window = observer.window(first, last)
                complete = window['received'] >= COMPLETE * window['expected']
                if (not window['timeouts'] and complete) or attempt == ATTEMPTS:
                    break
                if window['timeouts']:
                    # zero torque while the controller's answers were late: not the mode's
                    # impedance
                    print(f'[demo]   {window["timeouts"]} cycles without a fresh command (the '
                          f'host was busy); measuring again ({attempt + 1}/{ATTEMPTS})',
                          flush=True)
                else:
                    # states this observer lost (a busy host): interpolated, their gaps bend
                    # the harmonics (an rms 3 dB below the fundamental, measured)
                    print(f'[demo]   recorded {window["received"]} of {window["expected"]} '
                          f'states (the host was busy); measuring again '
                          f'({attempt + 1}/{ATTEMPTS})', flush=True)
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
            recalibrate(observer, children, args, results['dob_full_ff'][1])
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
    if window.get('fault'):
        notes.append(f'the controller reported "{window["fault"]}": not the mode\'s figure')
    return f'  ({"; ".join(notes)}: see the sim log)' if notes else ''


def report(results, args):
    soft = min((m for m in results if m != 'hold'), key=lambda m: results[m][1]['z_db'])
    soft_rms = min((m for m in results if m != 'hold'),
                   key=lambda m: results[m][1]['z_rms_db'])
    print(f'\nPinch finger backdriven {args.amplitude} rad at {args.frequency} rad/s; '
          'the controller only measures motor position and hose pressure.\n')
    print(f'{"mode":15s}{"|Z| fund.":>10s}{"vs passive":>11s}{"|Z| rms":>9s}{"distortion":>11s}'
          f'{"peak |F_e|":>12s}{"|F_e| in +-0.2":>16s}{"F_p loop area":>15s}')
    print(f'{"":15s}{"[dB re 1 N m s/rad]":>30s}{"[%]":>11s}{"[N m]":>12s}'
          f'{"rad [N m]":>16s}{"[N m rad]":>15s}')
    z_passive = results['passive'][1]['z_db'] if 'passive' in results else float('nan')
    for mode, (window, m) in results.items():
        flag = status_note(window)
        print(f'{mode:15s}{m["z_db"]:10.1f}{m["z_db"] - z_passive:11.1f}{m["z_rms_db"]:9.1f}'
              f'{100 * m["distortion"]:11.0f}{m["peak"]:12.3f}{m["peak_centre"]:16.4f}'
              f'{m["fp_area"]:15.4f}{flag}')
    if 'hold' in results:
        hold = results['hold'][1]
        print(f'\nimpedance range at {args.frequency} rad/s: '
              f'{hold["z_db"] - results[soft][1]["z_db"]:.1f} dB on the fundamental (hold vs '
              f'{soft}), {hold["z_rms_db"] - results[soft_rms][1]["z_rms_db"]:.1f} dB on the rms '
              f'(hold vs {soft_rms}); paper, on hardware: ~50 dB up to 3 rad/s')


def model_error(args):
    """``{'pinch.sim.<key>': value}`` of the sim's true plant: none with ``--ideal``."""
    if args.ideal:
        return {}
    return {key: float(v) for key, v in true_plant(args.seed)[0].items()}


def recalibrate(observer, children, args, before):
    """Calibrate, then measure dob_full_ff as the sweep did, print what was recovered.

    ``before``: the sweep's figures of dob_full_ff with the model. The drive runs again before
    the mode is entered (through passive) and the window starts a second later, as in the
    sweep: a drive started under dob_full_ff begins with a step in velocity, and its
    transient (0.09 N m decaying over about 1.5 s) would be measured as the mode's impedance.
    """
    state_timeout = get_parameter(observer.node, '/controller', 'state_timeout')
    result = run_friction_calibration(observer, children, args)
    set_parameters(observer.node, '/controller', {'state_timeout': state_timeout})
    if not result.applied:
        print(f'\nfriction calibration: {result.message}')
        return
    set_parameters(observer.node, '/sim', {f'{CHANNEL}.environment.mode': 'position_sine'})
    first = observer.enter_mode('dob_full_ff', children) + int(round(1.0 / DT))
    last = first + args.periods * (int(math.ceil(2 * math.pi / args.frequency / DT)) + 1) - 1
    observer.wait_cycle(children, last)
    window = observer.window(first, last)
    after = measure(window, args.frequency, args.amplitude)
    print_calibration(result, model_error(args), args.calibration_time)
    print(f'recalibrated dob_full_ff |Z| at {args.frequency} rad/s: {after["z_db"]:.1f} dB '
          f'(was {before["z_db"]:.1f} dB with the model); rms {after["z_rms_db"]:.1f} dB '
          f'(was {before["z_rms_db"]:.1f}), distortion {100 * after["distortion"]:.0f} %'
          f'{status_note(window)}')
    stiffness = dict(zip(result.names, zip(result.old_values, result.new_values)))
    k_model, k_new = stiffness.get('plant.endpoint_stiffness', (0.0, 0.0))
    if after['z_rms_db'] > before['z_rms_db'] and k_model > k_new > 0.0:
        print(f'  stiffer than with the model: the model\'s k_e is '
              f'{100 * (k_model / k_new - 1):.0f} % above the calibrated one. That\n'
              '  over-compensation happens to cancel part of the hose and motor errors on the '
              'drive,\n  but for a free finger it is a negative stiffness that pushes it away '
              '(docs/safety-and-layouts.md).')


if __name__ == '__main__':
    sys.exit(main())

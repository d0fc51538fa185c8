"""``scripts/demo commission``: commission a gripper whose plant nobody told the controller.

The sim's true plant is drawn with ``--seed``: every Table I parameter and the Dahl sigma and
F_c log-uniform in [0.5x, 2x] (``pinch.sim.plant.*``, ``pinch.sim.dahl.*``), hidden from the
controller, which starts from the default configuration (``config/gripper.yaml``). Lockstep:
the plant steps on the controller's answers, so every figure is the loop's own on any host.

1. **before**: each mode's |Z(j omega)| = |F_e/V_e| measured with the sim's position drive
   (``position_sine``, amplitude ``min(0.5, 0.5/omega)`` rad: 0.5 rad/s peak) at each
   ``--frequencies`` value, one period after a settling second: the fundamental beside the
   rms impedance rms(F_e)/rms(V_e), the distortion of F_e and the work loop's peaks
   (:func:`~..core.analysis.impedance_figures`);
2. **commission**: the finger released into free air (passive, the drive off), the
   ``~/commission`` action with ``apply`` (excitation, identification, tuning, report; the run
   directory under ``<--out>/runs``);
3. **after**: every mode measured again on the applied parameters;
4. **ideal**: the controller given the sim's true plant and Dahl parameters (the tuned
   settings kept; refused when eq. 28 does not hold for them), ``dob_full_ff`` measured at the
   lowest frequency: what the identification's error costs.

Predictions (:func:`~..commissioning.predictor.predict_modes`, on the *identified* plant from
the run's report, with its loop delay): before with the starting configuration, after with
the applied one; after, also the report's rms prediction (backdrives simulated on the
identified model at 1, 3 and 10 rad/s). Prints measured (fundamental and rms) vs predicted
per mode and frequency, the Z-width (hold less the softest other mode) before and after on
both, ``dob_full_ff`` after vs ideal and the rig time; writes ``zwidth_commission.png`` and
``results.json`` to ``--out``.

With ``--nonlinear`` the drawn plant also has the real gripper's nonlinear effects
(``pinch.sim.nonlinear.*`` and ``pinch.sim.motor_coulomb``: the hose's flow- and
pressure-dependent terms, the stroke-dependent diaphragm force, the four-bar finger ratio,
motor Coulomb friction and cogging; :mod:`~..core.nonlinear_effects`), each drawn within its
plausible range with ``--seed`` (the linear coefficients drawn as without it: the same seed
without ``--nonlinear`` is the same plant's linear class). Last, the goal figures: the
fundamental and the rms |Z| of ``dob_full_ff``, the Z-width on both, its work loop's peak over
the stroke against within +-0.2 rad, the identified b_s and k_e against the sim's linear
coefficients, and the model class's verdict.

Usage: python -m seaforce_ros.demos commission [--seed N] [--nonlinear] [--out DIR]
       [--frequencies 1,3,10] [--modes passive,hold,...] [--controller-params FILE]
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
from typing import Any, Dict, List, Sequence, Tuple

import numpy as np

from ..commissioning.analyse import backdrive_amplitude
from ..commissioning.tuning import contact_damping_within
from ..core.plant_cycle import STATUS_FAULT
from .common import (CHANNEL, DT, drawn_plant, prepare, run_action, run_guarded,
                     set_parameters, wait_until)
from .impedance import COMPLETE, Observer, measure, status_note

MODES = ('passive', 'hold', 'dob', 'dob_linear_ff', 'dob_full_ff', 'impedance')
SETTLE = 1.0            # s of drive before a mode's measured period
ATTEMPTS = 3            # measurements of a mode at most when the recorded states have gaps
RELEASE_TIME = 10.0     # s of the loop's time at most for the released finger to read free
COMMISSION_TIMEOUT = 600.0
#: The drive's amplitude at omega [rad]: min(0.5, 0.5/omega), as the rms predictions'
amplitude = backdrive_amplitude


class CommissionObserver(Observer):
    """The demo's observer, which also keeps the channel's contact flag."""

    def __init__(self):
        super().__init__()
        self.contact: Dict[int, bool] = {}
        #: whether the sim's position drive is running (set by this demo only: the sim
        #: starts with the finger free, :func:`release` sets it free again)
        self.driving = False

    def _on_status(self, msg):
        super()._on_status(msg)
        i = list(msg.name).index(CHANNEL)
        with self.lock:
            self.contact[msg.cycle] = bool(msg.contact[i])

    def free_for(self, cycles: int) -> bool:
        """No contact in the statuses of the last ``cycles`` cycles (and some seen)."""
        with self.lock:
            if not self.contact:
                return False
            last = max(self.contact)
            recent = [c for k, c in self.contact.items() if k > last - cycles]
        return len(recent) > 10 and not any(recent)


#: The figures of a mode that did not hold (the plant latched a fault).
UNSTABLE = {'z_db': math.nan, 'z_rms_db': math.nan, 'distortion': math.nan, 'peak': math.nan,
            'peak_centre': math.nan, 'peak_away': math.nan}


def measure_modes(observer, children, modes: Sequence[str], frequencies: Sequence[float],
                  label: str) -> Dict[Tuple[str, float], Dict[str, float]]:
    """The impedance figures (``impedance.measure``: |Z| of the fundamental and rms [dB],
    distortion, peaks) of each mode at each frequency with the sim's position drive;
    :data:`UNSTABLE` for a mode that latched a fault."""
    node = observer.node
    out: Dict[Tuple[str, float], Dict[str, float]] = {}
    for omega in frequencies:
        a = amplitude(omega)
        observer.set_mode('passive')        # the drive changes under the softest mode
        # ... as the finger passes the centre upwards, where the new sine starts: no step of
        # the set point -- when a drive is running; a free finger rests near its centre and
        # crosses nothing (waiting there cost the timeout, 10 s, before each series)
        if observer.driving:
            observer.wait_crossing(children, 0.0, timeout=10.0, rising=True, required=False)
        # atomically: one set at a time would install the drive three times, each restarting
        # its sine at 0 (a step of the set point) and the first with the old amplitude
        set_parameters(node, '/sim', {f'{CHANNEL}.environment.mode': 'position_sine',
                                      f'{CHANNEL}.environment.amplitude': a,
                                      f'{CHANNEL}.environment.frequency': float(omega)},
                       atomically=True)
        observer.driving = True
        period = int(math.ceil(2.0 * math.pi / omega / DT)) + 1
        for mode in modes:
            for attempt in range(1, ATTEMPTS + 1):
                first = observer.enter_mode(mode, children, 30.0, centre=0.0) \
                    + int(round(SETTLE / DT))
                last = first + period - 1
                observer.wait_cycle(children, last)
                window = observer.window(first, last)
                if window['received'] >= COMPLETE * window['expected']:
                    break
                print(f'[commission] {label:6s} {mode:14s} {omega:5.3g} rad/s: recorded '
                      f'{window["received"]} of {window["expected"]} states (a busy host); '
                      f'measuring again ({attempt}/{ATTEMPTS})', flush=True)
            fault = observer.fault_in(first - int(round(SETTLE / DT)), last)
            if fault and not window['status'] & STATUS_FAULT:
                # the controller fell back (the runaway monitor: a finger driven away on a
                # model this far off): the configured mode did not run; no figure
                out[(mode, omega)] = UNSTABLE
                print(f'[commission] {label:6s} {mode:14s} {omega:5.3g} rad/s ({a:.3g} rad): '
                      f'NOT HELD (the controller reports: {fault}); resetting the controller',
                      flush=True)
                observer.set_mode('passive')
                reset_plant(observer, ('/controller/reset',))
                continue
            if window['status'] & STATUS_FAULT:
                # the mode does not hold on this plant (a 2x model error can make dob_full_ff
                # unstable): no figure; the plant's fault cleared, the next mode measured
                out[(mode, omega)] = UNSTABLE
                print(f'[commission] {label:6s} {mode:14s} {omega:5.3g} rad/s ({a:.3g} rad): '
                      'UNSTABLE (the plant latched a fault; see the sim log); resetting',
                      flush=True)
                observer.set_mode('passive')
                reset_plant(observer)
                continue
            m = measure(window, omega, a)
            out[(mode, omega)] = {k: v for k, v in m.items() if k != 'figures'}
            print(f'[commission] {label:6s} {mode:14s} {omega:5.3g} rad/s ({a:.3g} rad): '
                  f'|Z| {m["z_db"]:6.1f} dB, rms {m["z_rms_db"]:6.1f} dB, distortion '
                  f'{100 * m["distortion"]:4.0f} %{status_note(window)}', flush=True)
    return out


def reset_plant(observer, targets=('/sim/reset', '/controller/reset')) -> None:
    """Clear the sim's latched fault (``/sim/reset``) and the controller's (``/controller/
    reset``: a fault or a fall-back); RuntimeError when the sim refuses or one does not
    answer."""
    from std_srvs.srv import Trigger

    from ..nodes.ros_common import request_until_answered
    for target in targets:
        client = observer.node.create_client(Trigger, target)
        try:
            if not client.wait_for_service(timeout_sec=20.0):
                raise RuntimeError(f'{target} is not offered')
            try:
                answer = request_until_answered(lambda: observer.background.call(
                    lambda: client.call_async(Trigger.Request())), 20.0)
            except TimeoutError:
                raise RuntimeError(f'{target} did not answer') from None
            if target == '/sim/reset' and not answer.success:
                raise RuntimeError(f'{target}: {answer.message}')
        finally:
            observer.node.destroy_client(client)


#: Seconds of the loop's time the drive holds the finger at its rest before the release.
CENTRE_TIME = 0.5


def release(observer, children) -> None:
    """Passive, the finger brought to its rest by the drive (:data:`CENTRE_TIME`), the drive
    off, and wait until the contact estimator has seen 1 s free -- at
    most :data:`RELEASE_TIME` of the loop's time (cycles: a busy host slows a lockstep loop,
    not what it does): with the model this far off, the drive's contact can stand at rest (the
    model's error times the finger's deflection), and ``~/commission`` takes a contact that
    stands with the finger still for its ``STANDING_TIME`` for the model's error (the
    excitation's contact test aborts at a real one); a goal it turns away says why."""
    observer.set_mode('passive')
    # the finger at its rest first: the drive stopped at its centre (amplitude 0: the set point
    # steps to 0 from where the last sine was, at most that sine's amplitude), then let go.
    # Released where the last measurement left it, the finger starts the excitation with the
    # diaphragm's spring loaded and held by the Dahl friction, and its drift as the chirp
    # frees it is motion the excitation did not cause: on the oracle, 0.1 rad from rest took
    # the port fit's misfit from 1.2 % to 2.7 % (the model class flagged on a linear plant)
    # and 0.2 rad aborted the excitation on a false contact
    set_parameters(observer.node, '/sim', {f'{CHANNEL}.environment.mode': 'position_sine',
                                           f'{CHANNEL}.environment.amplitude': 0.0,
                                           f'{CHANNEL}.environment.offset': 0.0},
                   atomically=True)
    centred = (observer.latest_cycle() or 0) + int(round(CENTRE_TIME / DT))
    observer.wait_cycle(children, centred)
    set_parameters(observer.node, '/sim', {f'{CHANNEL}.environment.mode': 'free'})
    observer.driving = False
    if observer.latest_fault():
        # a latched fall-back turns the commissioning goal away: clear it first
        reset_plant(observer, ('/controller/reset',))
    free = int(round(1.0 / DT))
    limit = (observer.latest_cycle() or 0) + int(round(RELEASE_TIME / DT))
    wait_until(children, lambda: observer.free_for(free) or (observer.latest_cycle() or 0)
               >= limit, math.inf, 'the released finger', poll=0.1)
    if not observer.free_for(free):
        print('[commission] the contact estimator still reports a contact with the finger '
              'released (the model\'s error at rest)', flush=True)


def commission(observer, children):
    """The ``~/commission`` goal with apply; its result (progress lines on the way)."""
    from seaforce_msgs.action import Commission
    goal = Commission.Goal(channel=CHANNEL, apply=True)
    shown = {'phase': None, 'at': 0.0}

    def on_feedback(feedback):
        now = time.monotonic()
        if feedback.phase != shown['phase'] or now - shown['at'] > 2.0:
            shown.update(phase=feedback.phase, at=now)
            print(f'[commission]   {feedback.phase:9s} {100.0 * feedback.progress:5.1f} %  '
                  f'{feedback.measuring}', flush=True)
    return run_action(observer, children, Commission, '/controller/commission', goal,
                      COMMISSION_TIMEOUT, on_feedback)


def predictions(run_dir: pathlib.Path, result, modes, frequencies):
    """Predicted |Z| [dB] before and after -- on the identified plant and on the controller's
    model (``plant.*`` as tuned) -- with the run's delay; also the configurations (flat dicts)
    before and after."""
    from ..commissioning.predictor import predict_modes
    from ..commissioning.report import load_report
    from ..core.params import ControllerConfig
    request = json.loads((run_dir / 'request.json').read_text())
    before_values = dict(request['config'])
    applied = {k: float(v) for k, v in zip(result.names, result.new_values)
               if math.isfinite(v)}
    after_values = {**before_values, **applied}
    report = load_report(run_dir / 'report.json')
    # (only its plant and Dahl are used: the starting settings' rules, e.g. the contact
    # damping's 10 b_s, need not hold with them)
    identified = ControllerConfig.from_dict(
        {r.name: r.value for r in report.identification if math.isfinite(r.value)},
        base=ControllerConfig.from_dict(before_values).replace(allow_non_passive=True))
    delay = next((int(f.value) for f in report.loop if f.name.startswith('loop delay p50')), 1)
    out = {}
    for label, values in (('before', before_values), ('after', after_values)):
        config = ControllerConfig.from_dict(values).replace(allow_non_passive=True)
        # after: on the controller's model (the linear fit's, or refitted with the terms the
        # record resolved: commissioning's analysis predicts on it too)
        model = identified if label == 'before' else config
        for omega in frequencies:
            z = predict_modes(model.plant, model.dahl, config, modes, [omega],
                              delay=delay, amplitude=amplitude(omega))
            for mode in modes:
                out[(label, mode, omega)] = 20.0 * math.log10(abs(complex(z[mode][0])))
    return out, before_values, applied, report, delay


def zwidth(z: Dict[Tuple[str, float], Dict[str, float]], omega: float,
           key: str = 'z_db') -> float:
    """hold less the softest other mode [dB] at ``omega``, on ``key`` (``z_db``: the
    fundamental, ``z_rms_db``: the rms)."""
    soft = [v[key] for (m, w), v in z.items() if w == omega and m != 'hold'
            and not math.isnan(v[key])]
    return z[('hold', omega)][key] - min(soft) if ('hold', omega) in z and soft else math.nan


def print_table(measured, predicted, modes, frequencies, predicted_rms=None) -> float:
    """The measured (fundamental and rms) vs predicted table (after: the report's rms
    prediction too, where it has the frequency); returns the largest |difference| [dB] of the
    fundamental."""
    predicted_rms = predicted_rms or {}
    print(f'\n{"mode":15s}{"omega":>7s} | {"before: meas.":>13s}{"rms":>7s}{"pred.":>7s}'
          f'{"diff":>7s} | {"after: meas.":>12s}{"rms":>7s}{"pred.":>7s}{"diff":>7s}'
          f'{"p.rms":>7s}{"diff":>7s}{"dist.":>7s}')
    print(f'{"":15s}{"rad/s":>7s} | {"[dB re 1 N m s/rad]":>34s} | {"[dB]":>47s}{"[%]":>7s}')
    worst = 0.0
    for omega in frequencies:
        for mode in modes:
            cells = []
            for label in ('before', 'after'):
                m = measured[label][(mode, omega)]
                p = predicted[(label, mode, omega)]
                width = 13 if label == 'before' else 12
                if math.isnan(m['z_db']):
                    cells.append(f'{"unstable":>{width}s}{"":7s}{p:7.1f}{"":7s}')
                    continue
                worst = max(worst, abs(m['z_db'] - p))
                cells.append(f'{m["z_db"]:{width}.1f}{m["z_rms_db"]:7.1f}{p:7.1f}'
                             f'{m["z_db"] - p:+7.1f}')
            after = measured['after'][(mode, omega)]
            p_rms = predicted_rms.get((mode, omega), math.nan)
            rms_cells = (f'{p_rms:7.1f}{after["z_rms_db"] - p_rms:+7.1f}'
                         if math.isfinite(p_rms) else f'{"-":>7s}{"":7s}')
            print(f'{mode:15s}{omega:7.3g} | {cells[0]} | {cells[1]}{rms_cells}'
                  f'{100 * after["distortion"]:7.0f}')
    return worst


def rms_predictions(report) -> Dict[Tuple[str, float], float]:
    """The report's predicted rms |Z| [dB] per (mode, omega)."""
    return {(row.mode, float(w)): 20.0 * math.log10(float(v))
            for row in report.impedance for w, v in zip(row.rms_omega, row.rms_abs)
            if math.isfinite(v) and v > 0}


def plot(measured, predicted_curves, modes, path: pathlib.Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(14, 5.5), sharey=True)
    colours = dict(zip(MODES, ('#f2b705', '#d62728', '#17becf', '#c51b8a', '#1f77b4',
                               '#2ca02c')))
    for ax, label in zip(axes, ('before', 'after')):
        for mode in modes:
            w, db = predicted_curves[(label, mode)]
            ax.semilogx(w, db, color=colours.get(mode), lw=1.2, label=f'{mode} predicted')
            pts = sorted((o, v['z_db'], v['z_rms_db']) for (m, o), v in measured[label].items()
                         if m == mode)
            ax.semilogx([p[0] for p in pts], [p[1] for p in pts], 'o',
                        color=colours.get(mode), ms=6)
            ax.semilogx([p[0] for p in pts], [p[2] for p in pts], 's', mfc='none',
                        color=colours.get(mode), ms=8)
        ax.set_title(f'{label} commissioning\n(lines: predicted; dots: measured, squares: '
                     'measured rms)', fontsize=10)
        ax.set_xlabel('omega [rad/s]')
        ax.grid(True, which='both', alpha=0.3)
    axes[0].set_ylabel('|Z| [dB re 1 N m s/rad]')
    axes[1].legend(fontsize=8)
    fig.suptitle('pinch finger: |F_e/V_e| per mode, the plant drawn 0.5x..2x and unknown '
                 'to the controller')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


#: The plot's frequencies [rad/s] (predicted lines).
CURVE_OMEGA = tuple(float(w) for w in np.logspace(-0.3, 1.3, 17))


def curves(predicted, modes) -> Dict[Tuple[str, str], Tuple[Sequence[float], List[float]]]:
    """The predicted |Z| [dB] on :data:`CURVE_OMEGA` per (before/after, mode)."""
    return {(label, mode): (CURVE_OMEGA, [predicted[(label, mode, w)] for w in CURVE_OMEGA])
            for label in ('before', 'after') for mode in modes}


def nonlinear_plant(seed: int):
    """The nonlinear effects drawn with ``seed`` (their own stream: the linear coefficients
    stay the ones :func:`~.common.drawn_plant` draws); ``({'<ch>.sim.<key>': value}, one-line
    description)``."""
    from ..core.nonlinear_effects import draw_effects
    effects, coulomb = draw_effects(np.random.default_rng([seed, 33]))
    values = {**effects.key_values(f'{CHANNEL}.'), f'{CHANNEL}.sim.motor_coulomb': coulomb}
    return values, f'{effects.describe()}; motor Coulomb {1e3 * coulomb:.1f} mN m'


def four_bar(values: Dict[str, Any]) -> Tuple[float, float]:
    """The sim's four-bar ratio r(q)/r(0) at the ends of its stroke, from the drawn effects'
    values (``{'<ch>.sim.nonlinear.<x>': value}``; (1, 1) without a finger ratio)."""
    from ..core.nonlinear_effects import NonlinearEffects, finger_ratio
    effects = NonlinearEffects.from_values({k[len(CHANNEL) + 1:]: v for k, v in values.items()
                                            if '.nonlinear.' in k})
    half = effects.half_stroke
    return finger_ratio(-half, effects), finger_ratio(half, effects)


def goal_figures(measured, report, truth, frequencies, applied=None,
                 finger=None) -> Dict[str, Any]:
    """The goal figures of a run on a nonlinear plant (after commissioning): ``dob_full_ff``
    at the lowest frequency (fundamental and rms |Z| [dB], the work loop's peaks [N m]), the
    Z-width on the fundamental and the rms [dB] at each frequency, the identified b_s and k_e
    against the sim's (linear) values -- the linear fit's and, given the values the tuning
    ``applied`` (``plant.*``, ``plant_terms.*`` keys), the controller's model's -- the model
    class's verdict; the four-bar's ratio the bonded drive of ``dob_full_ff`` showed, beside
    the sim's (``finger``: r/r(0) at the stroke's ends, :func:`four_bar`)."""
    after = measured['after']
    low = frequencies[0]
    ff = after[('dob_full_ff', low)]
    identified = {r.name: r.value for r in report.identification}

    def error(key):
        return identified.get(key, math.nan) / truth[f'{CHANNEL}.sim.{key}'] - 1.0
    model = report.model_class
    applied = applied or {}

    def model_error(key):
        return applied.get(key, math.nan) / truth[f'{CHANNEL}.sim.{key}'] - 1.0
    terms = {k.split('.', 1)[1]: v for k, v in applied.items()
             if k.startswith('plant_terms.') and v}
    return {
        'model_hose_damping_error': model_error('plant.hose_damping'),
        'model_endpoint_stiffness_error': model_error('plant.endpoint_stiffness'),
        'model_terms': terms,
        'omega': low, 'z_db': ff['z_db'], 'z_rms_db': ff['z_rms_db'],
        'distortion': ff['distortion'], 'peak': ff['peak'], 'peak_centre': ff['peak_centre'],
        'peak_away': ff.get('peak_away', math.nan),
        'zwidth_db': {f'{w:g}': zwidth(after, w) for w in frequencies},
        'zwidth_rms_db': {f'{w:g}': zwidth(after, w, 'z_rms_db') for w in frequencies},
        'hose_damping_error': error('plant.hose_damping'),
        'endpoint_stiffness_error': error('plant.endpoint_stiffness'),
        'model_class_fits': None if model is None else model.fits,
        'misfit': {} if model is None else dict(model.misfit),
        'finger_ratio': ff.get('finger_ratio', ''),
        'finger_ratio_truth': None if finger is None else list(finger)}


def goal_lines(goals: Dict[str, Any], nonlinear: bool) -> List[str]:
    """The goal figures as printed lines."""
    low = goals['omega']
    ratio = goals['peak'] / goals['peak_centre'] if goals['peak_centre'] else math.nan
    away = goals.get('peak_away', math.nan) / goals['peak_centre'] if goals['peak_centre'] \
        else math.nan
    widths = '; '.join(
        f'{w} rad/s {goals["zwidth_db"][w]:.1f} dB fundamental, {goals["zwidth_rms_db"][w]:.1f} '
        'dB rms' if math.isfinite(goals['zwidth_db'][w]) else
        f'{w} rad/s none (hold or every softer mode did not hold)' for w in goals['zwidth_db'])
    fits = goals['model_class_fits']
    verdict = ('not given' if fits is None else 'fits' if fits else 'DOES NOT FIT') + (
        ' (misfit ' + ', '.join(f'{k} {100 * v:.2g} %' for k, v in goals['misfit'].items())
        + ')' if goals['misfit'] else '')
    return [f'\ngoal figures after commissioning ({"with" if nonlinear else "without"} the '
            'nonlinear effects):',
            f'  dob_full_ff at {low:g} rad/s: |Z| {goals["z_db"]:.1f} dB fundamental, '
            f'{goals["z_rms_db"]:.1f} dB rms (distortion {100 * goals["distortion"]:.0f} %)',
            f'  Z-width: {widths}',
            f'  work loop of dob_full_ff at {low:g} rad/s: peak {goals["peak"]:.3g} N m over the '
            f'stroke, {goals["peak_centre"]:.3g} N m within +-0.2 rad (ratio {ratio:.2f}); '
            f'{goals.get("peak_away", math.nan):.3g} N m without the stroke\'s ends (within 0.9 '
            f'of the half-stroke: the reversals left out; ratio {away:.2f})',
            f'  identified b_s {100 * goals["hose_damping_error"]:+.1f} %, k_e '
            f'{100 * goals["endpoint_stiffness_error"]:+.1f} % by the linear fit (against the '
            'sim\'s linear coefficients)',
            f'  model class: {verdict}'] + ([
                f'  bonded drive of dob_full_ff at {low:g} rad/s: {goals["finger_ratio"]}'
                + (' (the sim\'s: {:.3f} and {:.3f} at the ends of its +-0.5 rad)'.format(
                    *goals['finger_ratio_truth']) if goals.get('finger_ratio_truth') else '')]
                if goals.get('finger_ratio') else []) + ([
                f'  the controller\'s model: b_s {100 * goals["model_hose_damping_error"]:+.1f} '
                f'%, k_e {100 * goals["model_endpoint_stiffness_error"]:+.1f} %, with '
                + (', '.join(f'{k} {v:.4g}' for k, v in goals['model_terms'].items())
                   or 'no nonlinear term')]
                if math.isfinite(goals.get('model_endpoint_stiffness_error', math.nan)) else [])


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', default='out/demo-commission', help='output directory')
    parser.add_argument('--seed', type=int, default=1, help="the sim's drawn plant")
    parser.add_argument('--nonlinear', action='store_true',
                        help="the sim's plant with the real gripper's nonlinear effects too, "
                             'each drawn within its plausible range with --seed')
    parser.add_argument('--frequencies', default='1,3,10',
                        help='drive frequencies [rad/s], comma-separated')
    parser.add_argument('--modes', default=','.join(MODES), help='modes measured')
    parser.add_argument('--controller-params', default=None,
                        help='a params file for controller_node after the defaults (e.g. a '
                             'shorter commissioning.duration)')
    args = parser.parse_args(argv)
    extra = pathlib.Path(args.controller_params) if args.controller_params else None
    if extra is not None and not extra.is_file():
        parser.error(f'--controller-params {extra}: no such file')
    try:
        frequencies = sorted(float(f) for f in args.frequencies.split(','))
    except ValueError:
        parser.error(f'--frequencies {args.frequencies!r}: numbers separated by commas')
    if not frequencies or not all(0.1 <= f <= 100.0 for f in frequencies):
        parser.error('--frequencies: each within 0.1..100 rad/s')
    modes = tuple(args.modes.split(','))
    if 'hold' not in modes or not set(modes) <= set(MODES) or len(modes) < 2:
        parser.error(f'--modes: hold and at least one other of {", ".join(MODES)}')

    out, lib, config = prepare(args.out)
    truth, factors = drawn_plant(args.seed, 0.5, 2.0)
    nonlinear, effects = nonlinear_plant(args.seed) if args.nonlinear else ({}, '')
    sim_overrides = out / 'sim-overrides.yaml'
    sim_overrides.write_text('sim:\n  ros__parameters:\n    clock_mode: lockstep\n'
                             + ''.join(f'    {k}: {v!r}\n'
                                       for k, v in {**truth, **nonlinear}.items()))
    ctl_overrides = out / 'controller-overrides.yaml'
    runs = (out / 'runs').resolve()
    ctl_overrides.write_text('controller:\n  ros__parameters:\n'
                             f'    commissioning.directory: "{runs}"\n    state_timeout: 5.0\n')

    def work(children):
        started = time.monotonic()
        for name, files in (('sim_node', [sim_overrides]),
                            ('controller_node', [ctl_overrides] + ([extra] if extra else []))):
            children.start([str(lib / name), '--ros-args', '--params-file', str(config)]
                           + [a for f in files for a in ('--params-file', str(f))], name)
        observer = CommissionObserver()
        children.observers.append(observer)
        print(f'[commission] seed {args.seed}: the true plant, x Table I / the Dahl fit: '
              + ', '.join(f'{k} {f:.2f}' for k, f in factors.items()), flush=True)
        if nonlinear:
            print(f'[commission] seed {args.seed}: the nonlinear effects: {effects}\n'
                  + ''.join(f'[commission]   {k} = {v:.6g}\n' for k, v in nonlinear.items()),
                  flush=True)
        observer.wait_until_live(children)
        measured = {'before': measure_modes(observer, children, modes, frequencies, 'before')}
        release(observer, children)
        t0 = time.monotonic()
        result = commission(observer, children)
        commission_wall = time.monotonic() - t0
        print(f'\n{result.summary}\n[commission] {result.message}', flush=True)
        if not result.applied:
            raise RuntimeError(f'the commissioning applied nothing: {result.message}')
        run_dir = pathlib.Path(result.report_path).parent
        measured['after'] = measure_modes(observer, children, modes, frequencies, 'after')
        predicted, _, applied, report, delay = predictions(
            run_dir, result, modes, sorted(set(frequencies) | set(CURVE_OMEGA)))
        # ideal: the tuned settings with the true model (what the identification's error
        # costs); the controller refuses it when eq. 28 does not hold for the true plant
        low = frequencies[0]
        observer.set_mode('passive')
        ideal_values = {k.replace('.sim.', '.', 1): v for k, v in truth.items()}
        # (the contact damping's bound follows the true hose)
        ideal_values[f'{CHANNEL}.grasp.contact_damping'] = contact_damping_within(
            applied.get('grasp.contact_damping', math.inf),
            truth[f'{CHANNEL}.sim.plant.hose_damping'])
        try:
            set_parameters(observer.node, '/controller', ideal_values, atomically=True)
            ideal = measure_modes(observer, children, ('dob_full_ff',), [low], 'ideal')
        except RuntimeError as exc:
            print(f'[commission] ideal model not measured: {exc}', flush=True)
            ideal = {('dob_full_ff', low): UNSTABLE}
        predicted_rms = rms_predictions(report)
        worst = print_table(measured, predicted, modes, frequencies, predicted_rms)
        phases = report.meta.phases
        rig = sum(phases.values())
        lines = [f'\nZ-width (hold vs the softest other mode), predictor delay {delay} '
                 'sample(s):']
        for omega in frequencies:
            lines.append(f'  {omega:5.3g} rad/s: before {zwidth(measured["before"], omega):5.1f}'
                         f' dB, after {zwidth(measured["after"], omega):5.1f} dB; on the rms '
                         f'before {zwidth(measured["before"], omega, "z_rms_db"):5.1f} dB, after '
                         f'{zwidth(measured["after"], omega, "z_rms_db"):5.1f} dB')
        after_ff = measured['after'][('dob_full_ff', low)]
        z_after, z_ideal = after_ff['z_db'], ideal[('dob_full_ff', low)]['z_db']
        lines += [f'dob_full_ff at {low:g} rad/s: '
                  f'{measured["before"][("dob_full_ff", low)]["z_db"]:.1f}'
                  f' dB before, {z_after:.1f} dB after, {z_ideal:.1f} dB with the true model '
                  f'({z_after - z_ideal:+.1f} dB); rms after {after_ff["z_rms_db"]:.1f} dB, '
                  f'{ideal[("dob_full_ff", low)]["z_rms_db"]:.1f} dB with the true model; '
                  f'work loop peak {after_ff["peak"]:.3g} N m over the stroke, '
                  f'{after_ff["peak_centre"]:.3g} within +-0.2 rad',
                  f'predicted vs measured: largest difference {worst:.1f} dB',
                  'rig time: ' + ', '.join(f'{k} {v:.1f} s' for k, v in phases.items())
                  + f' = {rig:.1f} s (goal {commission_wall:.1f} s wall)',
                  f'report: {result.report_path}']
        goals = goal_figures(measured, report, truth, frequencies, applied,
                             four_bar(nonlinear))
        lines += goal_lines(goals, bool(nonlinear))
        print('\n'.join(lines))
        png = out / 'zwidth_commission.png'
        plot(measured, curves(predicted, modes), modes, png)
        results = {'seed': args.seed, 'factors': factors, 'frequencies': frequencies,
                   'nonlinear': nonlinear, 'nonlinear_effects': effects, 'goals': goals,
                   'measured': {label: {f'{m}@{w:g}': v['z_db'] for (m, w), v in z.items()}
                                for label, z in measured.items()},
                   'measured_figures': {label: {f'{m}@{w:g}': v for (m, w), v in z.items()}
                                        for label, z in measured.items()},
                   'predicted': {f'{label}:{m}@{w:g}': v for (label, m, w), v in
                                 predicted.items() if w in frequencies},
                   'predicted_rms_after': {f'{m}@{w:g}': v
                                           for (m, w), v in predicted_rms.items()},
                   'ideal_dob_full_ff_db': z_ideal,
                   'ideal_dob_full_ff': ideal[('dob_full_ff', low)],
                   'zwidth_db': {label: {f'{w:g}': zwidth(measured[label], w)
                                         for w in frequencies} for label in measured},
                   'zwidth_rms_db': {label: {f'{w:g}': zwidth(measured[label], w, 'z_rms_db')
                                             for w in frequencies} for label in measured},
                   'worst_prediction_error_db': worst, 'phases': phases, 'rig_time': rig,
                   'identified': {r.name: r.value for r in report.identification},
                   'truth': truth, 'report': result.report_path,
                   'wall_time': time.monotonic() - started}
        (out / 'results.json').write_text(json.dumps(results, indent=1))
        print(f'plot: {png}\nresults: {out / "results.json"}')
        return 0

    return run_guarded('commission', out, work)


if __name__ == '__main__':
    sys.exit(main())

"""Grasping figures: object estimates, contact detection, forces -- with a wrong model.

The control core on the simulated gripper (no ROS: the ROS tests show the nodes give the same),
the sim's plant off the controller's model by ``--error`` (every Table I and Dahl parameter,
signs at random), objects drawn at random. Prints:

* object stiffness and damping errors 0.5 s after the contact, by stiffness range, with the
  ratio of the error to the 1-sigma the estimator reports (rms: ~1 means honest);
* contact detection delay and peak contact force before the squeeze, by closing speed and
  object stiffness (goal: 10 ms and 0.05 N m up to 0.3 rad/s and 5 N m/rad), next to the
  delay of an ideal detector on the same plants and objects (:func:`ideal_delay`: the best any
  detector on the pressure could do);
* grip force error in a settled hold and the largest contact force relative to max_force;
* free motion (no object) by closing speed: contacts found (goal: none), the contact threshold
  the estimator adapted and the largest excess of its detection residual over its mean, as a
  fraction of the threshold (the margin against a false contact).

``--calibrate``: before each grasp the controller recalibrates the endpoint friction in free air
(:class:`~seaforce_ros.core.friction_calibration.FrictionCalibration`, 0.1 rad at 0.5 rad/s,
``friction.calibration_duration``; objects sit 0.15 rad or more away), as a user would run
``~/calibrate_friction`` before grasping; the rest of the model stays ``--error`` off.

``--commission``: before each grasp the controller's model is the free-air self-identification's
(:mod:`seaforce_ros.commissioning.free_air`, a 12 s chirp 1..400 Hz of the same plant, as
``~/commission`` runs it; the plant, the Dahl sigma and F_c, the DOB's nominal inertia set to
the identified m, the contact damping within 10 b_s; the rest of the configuration is the
default) -- the grasps on a commissioned
model. ``--estimates-only`` prints the object estimates and grip figures only.

Run:  PYTHONPATH=. python bench/grasp_accuracy.py [--draws N] [--error 0.15] [--seed S]
      [--calibrate | --commission] [--estimates-only] [--quick]
      (--quick: two objects, one detection cell, one free-motion plant: a smoke run)
"""
import argparse
import dataclasses
import math
import sys

import numpy as np

from seaforce_ros.core import ChannelController, ChannelSimulator, ControllerConfig, DahlParams
from seaforce_ros.core import PlantParams
from seaforce_ros.core.environment import contact_object, free
from seaforce_ros.core.friction_calibration import CalibrationGoal, FrictionCalibration
from seaforce_ros.core.grasp import Grasp, GraspGoal
from seaforce_ros.core.sensors import SensorParams

DT = 5e-4
PLANT_KEYS = ('motor_inertia', 'motor_damping', 'motor_stiffness', 'endpoint_inertia',
              'endpoint_damping', 'endpoint_stiffness', 'hose_damping', 'hose_stiffness')


def wrong_plant(rng, error):
    sign = lambda: 1.0 + error * rng.choice((-1.0, 1.0))    # noqa: E731
    d = DahlParams()
    return (PlantParams.table_i().scaled(**{k: sign() for k in PLANT_KEYS}),
            DahlParams(sigma=d.sigma * sign(), coulomb_force=d.coulomb_force * sign()))


#: set by ``--calibrate``: a friction calibration before each grasp
CALIBRATE = False
#: set by ``--commission``: the model self-identified in free air before each grasp
COMMISSION = False


def commissioned(plant, dahl, seed):
    """The default configuration with the model the free-air identification gives for
    ``plant``/``dahl`` (module docstring)."""
    from seaforce_ros.commissioning.experiments import run_free_air_excitation
    from seaforce_ros.commissioning.free_air import identify_free_air
    from seaforce_ros.commissioning.tuning import contact_damping_within
    config = ControllerConfig()
    ident = identify_free_air(run_free_air_excitation(plant, dahl, config, seed=seed,
                                                      duration=12.0, band=(1.0, 400.0)))
    model = ident.plant()
    return config.replace(
        plant=model, dahl=ident.dahl(),
        dob=dataclasses.replace(config.dob, nominal_inertia=model.motor_inertia),
        grasp=dataclasses.replace(config.grasp, contact_damping=contact_damping_within(
            config.grasp.contact_damping, model.hose_damping)))


def controller_on(sim, plant=None, dahl=None, seed=0):
    """The controller on ``sim`` and its first measurement, friction recalibrated in free air
    first when ``CALIBRATE`` (it must succeed), its model commissioned on ``plant``/``dahl``
    when ``COMMISSION``: (controller, config, measurement)."""
    config = commissioned(plant, dahl, seed) if COMMISSION else ControllerConfig()
    ctl = ChannelController(config, dt=DT)
    m = sim.measurement()
    if CALIBRATE:
        cal = FrictionCalibration(CalibrationGoal('pinch', 0.1, 0.5, True), config, DT)
        ctl.request_job(cal)
        for _ in range(int((config.friction.calibration_duration + 1.0) / DT)):
            m = sim.step(ctl.update(m.x, m.v, m.f_p))
            if cal.outcome is not None:
                break
        if cal.outcome != 'succeeded' or not cal.applied:
            raise RuntimeError(f'friction calibration: {cal.outcome}: {cal.message}')
        config = ctl.config
    return ctl, config, m


#: The matched signal-to-noise ratio at which :func:`ideal_delay` declares the contact: the
#: estimator's own threshold is 5 rms of its residual too (a Gaussian tail of 3e-7 per look).
IDEAL_SNR = 5.0


def ideal_delay(config, plant, dahl, k, b, position, v):
    """The detection delay [s] of an ideal detector on the pressure: one that knows when the
    contact starts and the exact pressure it will cause -- the difference between the
    noise-free pressure of the grasp with the object and without it, on the same plant under
    the same controller -- and declares the contact when the matched signal-to-noise ratio
    ``sqrt(sum s^2) / sigma`` reaches :data:`IDEAL_SNR`, ``sigma`` the sim's pressure noise
    per sample (Gaussian and ADC quantisation). No causal detector that must also find the
    onset, the amplitude and a wrong model's error does better on the pressure alone (the
    motor encoder is no second force sensor: the motor's own disturbances -- its model's
    error, on hardware cogging and friction -- enter it in full)."""
    sensors = SensorParams()
    sigma = math.hypot(sensors.pressure_noise, sensors.pressure_quantum / math.sqrt(12.0))

    def run(env, samples):
        sim = ChannelSimulator(plant, dahl, seed=0, environment=env,
                               sensors=SensorParams.ideal())
        ctl = ChannelController(config, dt=DT)
        ctl.request_job(Grasp(GraspGoal('pinch', v, 0.3, 0.6, True), config, DT))
        m = sim.measurement()
        fp, touched = [], None
        while len(fp) < samples and (touched is None or len(fp) < touched + int(0.05 / DT)):
            m = sim.step(ctl.update(m.x, m.v, m.f_p))
            fp.append(m.f_p)
            if touched is None and m.f_e < 0.0:
                touched = len(fp) - 1
        return np.array(fp), touched

    contact, touched = run(contact_object(position, k, b), int((position / v + 3.0) / DT))
    if touched is None:
        return math.nan
    signal = contact - run(free(), contact.size)[0]
    snr = np.sqrt(np.cumsum(signal[touched:] ** 2)) / sigma
    return int(np.argmax(snr >= IDEAL_SNR)) * DT if snr[-1] >= IDEAL_SNR else math.nan


def grasp(k, b, position, v, grip, rng, error, hold=True, ideal=False):
    """One grasp; returns the measured figures (None where it did not get there), with the
    :func:`ideal_delay` on the same plant and object if ``ideal``."""
    plant, dahl = wrong_plant(rng, error)
    seed = int(rng.integers(1 << 30))
    sim = ChannelSimulator(plant, dahl, seed=seed, environment=contact_object(position, k, b))
    ctl, config, m = controller_on(sim, plant, dahl, seed)
    max_force = 2.0 * grip
    g = Grasp(GraspGoal('pinch', v, grip, max_force, True), config, DT)
    ctl.request_job(g)
    t = 0.0
    touched = estimate = None
    forces, phases = [], []
    settle = max(0.3, 6.0 * (b + config.grasp.contact_damping) / k) if hold else 0.0
    t_hold = None
    while t < 30.0:
        m = sim.step(ctl.update(m.x, m.v, m.f_p))
        t += DT
        forces.append(-m.f_e)
        phases.append(g.phase)
        if touched is None and m.f_e < 0.0:
            touched = t
        if touched is not None and estimate is None and t >= touched + 0.5:
            estimate = ctl.estimator.estimate()
        if g.phase == 'hold' and t_hold is None:
            t_hold = t
        if not g.active or (t_hold is not None and estimate is not None
                            and t >= t_hold + settle):
            break
    forces = np.array(forces)
    squeeze = phases.index('squeeze') if 'squeeze' in phases else len(phases)
    first = int(round(touched / DT)) if touched else len(forces)
    early = g.contact and (touched is None or g.contact_time < touched)
    return {'k': k, 'b': b, 'v': v, 'estimate': estimate, 'early': early,
            'delay': (g.contact_time - touched) if touched and g.contact else math.nan,
            'peak_approach': float(forces[first - 1:squeeze].max())
            if touched and not early else math.nan,
            'grip_error': (float(np.mean(forces[-int(0.1 / DT):])) - grip) / grip
            if g.phase == 'hold' else math.nan,
            'peak_ratio': float(forces.max()) / max_force, 'ended': g.message,
            'ideal': ideal_delay(config, plant, dahl, k, b, position, v) if ideal else math.nan}


def table_estimates(rows):
    print('\nobject estimates 0.5 s after the contact (errors in % of the truth; err/sigma: '
          'rms of error over reported 1-sigma)')
    print(f'{"k range [N m/rad]":>20s} {"n":>3s} {"k err max":>10s} {"k err rms":>10s} '
          f'{"k err/sig":>10s} {"b err max":>10s} {"b err rms":>10s} {"b err/sig":>10s}')
    for low, high in ((0.2, 1.0), (1.0, 3.0), (3.0, 5.0), (5.0, 10.0), (10.0, 20.0)):
        sel = [r for r in rows if low <= r['k'] < high and r['estimate'] is not None]
        if not sel:
            continue
        ek = np.array([(r['estimate'].stiffness - r['k']) / r['k'] for r in sel])
        rk = np.array([(r['estimate'].stiffness - r['k']) / r['estimate'].stiffness_sigma
                       for r in sel])
        eb = np.array([(r['estimate'].damping - r['b']) / r['b'] for r in sel])
        rb = np.array([(r['estimate'].damping - r['b']) / r['estimate'].damping_sigma
                       for r in sel])
        print(f'{f"{low:g} - {high:g}":>20s} {len(sel):3d} {100 * np.nanmax(abs(ek)):9.1f}% '
              f'{100 * math.sqrt(np.nanmean(ek ** 2)):9.1f}% {math.sqrt(np.nanmean(rk ** 2)):10.2f}'
              f' {100 * np.nanmax(abs(eb)):9.1f}% {100 * math.sqrt(np.nanmean(eb ** 2)):9.1f}% '
              f'{math.sqrt(np.nanmean(rb ** 2)):10.2f}')


def table_contact(rng, error, speeds, stiffnesses, b, n):
    print(f'\ncontact detection delay [ms] (an ideal detector\'s on the same plants) / peak '
          f'contact force before the squeeze [N m] (object damping {b} N m s/rad; worst of {n})')
    print(f'{"speed [rad/s]":>14s}' + ''.join(f'{f"k = {k:g}":>24s}' for k in stiffnesses))
    for v in speeds:
        cells = []
        for k in stiffnesses:
            rows = [grasp(k, b, 0.15 + 0.4 * v, v, 0.3, rng, error, hold=False, ideal=True)
                    for _ in range(n)]
            cells.append(f'{1e3 * max(r["delay"] for r in rows):5.1f} '
                         f'({1e3 * max(r["ideal"] for r in rows):4.1f}) / '
                         f'{max(r["peak_approach"] for r in rows):.3f}'
                         + ('!' if any(r['early'] for r in rows) else ''))
        print(f'{v:14.2f}' + ''.join(f'{c:>24s}' for c in cells), flush=True)


def free_motion(v, rng, error, travel=0.5):
    """A grasp with nothing to find, released after ``travel``: (contact found, lowest and
    highest threshold [N m], largest |d - m| / threshold) while the approach is armed."""
    plant, dahl = wrong_plant(rng, error)
    sim = ChannelSimulator(plant, dahl, seed=int(rng.integers(1 << 30)), environment=free())
    ctl, config, m = controller_on(sim)
    g = Grasp(GraspGoal('pinch', v, 0.3, 0.6, True), config, DT)
    ctl.request_job(g)
    est = ctl.estimator
    start = None
    low, high, worst = math.inf, 0.0, 0.0
    while g.active:
        m = sim.step(ctl.update(m.x, m.v, m.f_p))
        start = est.position if start is None else start
        if g.phase == 'approach' and g.armed:
            low, high = min(low, est.threshold), max(high, est.threshold)
            worst = max(worst, abs(est.detection - est.detection_mean) / est.threshold)
        if abs(est.position - start) >= travel:
            g.request_release('enough')
    return g.contact, low, high, worst


def table_free(rng, error, speeds, n):
    print(f'\nfree motion, {n} plants per speed, released after 0.5 rad: contacts found, the '
          'adapted threshold [mN m], largest |d - m| / threshold')
    for v in speeds:
        rows = [free_motion(v, rng, error) for _ in range(n)]
        print(f'{v:14.2f} {sum(r[0] for r in rows):3d} {1e3 * min(r[1] for r in rows):6.2f} - '
              f'{1e3 * max(r[2] for r in rows):4.2f} {max(r[3] for r in rows):8.2f}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--draws', type=int, default=40, help='random objects')
    parser.add_argument('--error', type=float, default=0.15, help='model error (relative)')
    parser.add_argument('--seed', type=int, default=12)
    parser.add_argument('--worst-of', type=int, default=3, help='grasps per detection cell')
    parser.add_argument('--free', type=int, default=10, help='plants per free-motion speed')
    parser.add_argument('--calibrate', action='store_true',
                        help='recalibrate the endpoint friction before each grasp')
    parser.add_argument('--commission', action='store_true',
                        help='the model self-identified in free air before each grasp')
    parser.add_argument('--estimates-only', action='store_true',
                        help='only the object estimates and grip figures')
    parser.add_argument('--quick', action='store_true',
                        help='smoke run: two objects, one detection cell, one free plant')
    args = parser.parse_args()
    if args.quick:
        args.draws, args.worst_of, args.free = 2, 1, 1
    global CALIBRATE, COMMISSION
    if args.calibrate and args.commission:
        parser.error('--calibrate or --commission, not both')
    if args.commission and not args.estimates_only:
        parser.error('--commission needs --estimates-only (the detection and free-motion '
                     'tables do not commission)')
    CALIBRATE, COMMISSION = args.calibrate, args.commission
    rng = np.random.default_rng(args.seed)
    print(f'the sim\'s plant {100 * args.error:.0f} % off the controller\'s model (each '
          f'parameter, random signs); {args.draws} objects: k log-uniform 0.2..20 N m/rad, '
          'b 0.04..0.1 N m s/rad, at 0.15..0.3 rad, closed at 0.05..0.3 rad/s, grip '
          '0.2..0.5 N m (at most k x 1 rad), max_force 2 grip'
          + ('; friction recalibrated in free air before each grasp' if CALIBRATE else '')
          + ('; the model self-identified in free air before each grasp' if COMMISSION
             else ''))
    rows = []
    for _ in range(args.draws):
        k = float(np.exp(rng.uniform(np.log(0.2), np.log(20.0))))
        b, position, v = (float(rng.uniform(*r)) for r in ((0.04, 0.1), (0.15, 0.3),
                                                            (0.05, 0.3)))
        # a grip the object takes within grasp.give_way_travel (1.5 rad): at most k x 1 rad
        grip = min(float(rng.uniform(0.2, 0.5)), max(0.2, k))
        rows.append(grasp(k, b, position, v, grip, rng, args.error))
    table_estimates(rows)
    grip = np.array([r['grip_error'] for r in rows])
    soft = np.array([r['k'] < 0.3 for r in rows])
    print(f'\ngrip force error in a settled hold: max {100 * np.nanmax(abs(grip[~soft])):.1f} % '
          f'(k >= 0.3 N m/rad), {100 * np.nanmax(abs(grip[soft])) if soft.any() else math.nan:.1f}'
          ' % (k < 0.3: the finger\'s own k_e, wrong by the model error, is a fifth of it)')
    print(f'largest contact force / max_force: {max(r["peak_ratio"] for r in rows):.2f}')
    ended = [r['ended'] for r in rows if r['ended'] not in ('holding', 'probing')]
    print(f'grasps that did not reach a settled hold: {len(ended)} {ended if ended else ""}')
    print(f'contacts detected before the true contact: {sum(r["early"] for r in rows)}')
    if args.estimates_only:
        return 0
    if args.quick:
        table_contact(rng, args.error, (0.3,), (1.0,), 0.04, args.worst_of)
        table_free(rng, args.error, (0.3,), args.free)
        return 0
    for b in (0.04, 0.1):
        table_contact(rng, args.error, (0.05, 0.1, 0.2, 0.3, 0.6, 1.0), (0.2, 1.0, 5.0, 20.0),
                      b, args.worst_of)
    table_free(rng, args.error, (0.05, 0.1, 0.3, 0.6, 1.0), args.free)
    return 0


if __name__ == '__main__':
    sys.exit(main())

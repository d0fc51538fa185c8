"""Endpoint friction recalibration after a drift of the simulated plant.

The sim's true endpoint drifts (default: b_e and F_c +50 %, k_e -30 %: a worn finger)
while the controller keeps the Table I model. Printed:

* the drift table: each friction parameter's truth, the model before recalibration, the
  calibration's value with its 1-sigma, and the error against the truth;
* |Z| of ``dob_full_ff`` (the stiff position drive, 0.5 rad, core/environment.py) with the true
  parameters, with the drifted plant and the old model, and after recalibration, at 0.3, 1 and
  3 rad/s;
* the calibration's cost per sample against the controller's ``dob_full_ff`` update, measured
  in the same run (a ratio; the absolute times depend on the machine).

Run:  PYTHONPATH=. python bench/friction_drift.py [--random N] [--duration S]
          [--amplitude A] [--speed V] [--quick]
      (--quick: the default drift only, a 3 s calibration, |Z| at 3 rad/s, 1000 samples of
      cost: a smoke run)
"""

import argparse
import dataclasses
import math
import time

import numpy as np

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, position_sine, run_closed_loop)
from seaforce_ros.core.analysis import impedance_from_position, magnitude_db
from seaforce_ros.core.friction_calibration import (CalibrationGoal, FrictionCalibration,
                                                    with_friction)

DT = 5e-4
FREQS = (0.3, 1.0, 3.0)
NAMES = ("b_e [N m s/rad]", "k_e [N m/rad]", "F_c [N m]", "sigma [N m/rad]")


def z_db(config, plant, dahl, omega, amp=0.5):
    period = 2.0 * math.pi / omega
    settle = max(3.0, period)
    n = int((settle + 2 * period) / DT) + 1
    sim = ChannelSimulator(plant, dahl, dt=DT, seed=1, environment=position_sine(amp, omega))
    rec = run_closed_loop(sim, ChannelController(config.replace(mode="dob_full_ff"), DT), n)
    return magnitude_db(impedance_from_position(rec["f_e"], rec["x_e"], omega, DT, settle))


def calibrate(config, plant, dahl, amplitude, speed, seed=2):
    sim = ChannelSimulator(plant, dahl, dt=DT, seed=seed)
    ctl = ChannelController(config, DT)
    cal = FrictionCalibration(CalibrationGoal("pinch", amplitude, speed, True), config, DT)
    n0 = 400
    n = n0 + int((config.friction.calibration_duration + 0.2) / DT)
    run_closed_loop(sim, ctl, n, on_switch={n0: lambda s, c: c.request_job(cal)})
    return cal, ctl.config


def per_sample_cost(config, calibrate_too, n=6000):
    """(mean, 99.9th percentile) seconds per controller update: the finger backdriven by the position drive
    (the adaptation, when on, runs there), or a calibration running in free air."""
    env = None if calibrate_too else position_sine(0.5, 1.0)
    sim = ChannelSimulator(config.plant, config.dahl, dt=DT, seed=3, environment=env)
    ctl = ChannelController(config, DT)
    if calibrate_too:
        ctl.request_job(FrictionCalibration(CalibrationGoal("pinch", 0.5, 1.0, True),
                                                    config, DT))
    m = sim.measurement()
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        u = ctl.update(m.x, m.v, m.f_p)
        times.append(time.perf_counter() - t0)
        m = sim.step(u)
    return float(np.mean(times)), float(np.percentile(times, 99.9))


def one_case(base, factors, amplitude, speed, freqs=FREQS):
    fb, fk, ff, fs = factors
    plant = base.plant.scaled(endpoint_damping=fb, endpoint_stiffness=fk)
    dahl = DahlParams(sigma=base.dahl.sigma * fs, coulomb_force=base.dahl.coulomb_force * ff)
    truth = (plant.endpoint_damping, plant.endpoint_stiffness, dahl.coulomb_force, dahl.sigma)
    t0 = time.perf_counter()
    cal, recalibrated = calibrate(base, plant, dahl, amplitude, speed)
    wall = time.perf_counter() - t0
    print(f"\ndrift b_e x{fb:g}, k_e x{fk:g}, F_c x{ff:g}, sigma x{fs:g}: calibration "
          f"{base.friction.calibration_duration:g} s simulated ({wall:.1f} s wall), amplitude "
          f"{amplitude:g} rad, peak speed {speed:g} rad/s: {cal.outcome} ({cal.message})")
    old = (base.plant.endpoint_damping, base.plant.endpoint_stiffness,
           base.dahl.coulomb_force, base.dahl.sigma)
    print(f"{'parameter':18s} {'truth':>10s} {'before':>10s} {'after':>10s} {'1-sigma':>9s} "
          f"{'error':>8s} {'before err':>10s}")
    new = cal.new
    values = (new.endpoint_damping, new.endpoint_stiffness, new.coulomb_force, new.sigma) \
        if new is not None else (math.nan,) * 4
    sigmas = (new.endpoint_damping_sigma, new.endpoint_stiffness_sigma,
              new.coulomb_force_sigma, new.sigma_sigma) if new is not None else (math.nan,) * 4
    for name, t, b, a, s in zip(NAMES, truth, old, values, sigmas):
        print(f"{name:18s} {t:10.5g} {b:10.5g} {a:10.5g} {s:9.2g} {100 * (a / t - 1):+7.2f}% "
              f"{100 * (b / t - 1):+9.1f}%")
    true_cfg = with_friction(base, truth)
    print(f"{'|Z| dob_full_ff [dB]':22s} " + " ".join(f"{w:>8g} r/s" for w in freqs))
    rows = {}
    for label, cfg in (("true parameters", true_cfg), ("drifted (old model)", base),
                       ("recalibrated", recalibrated)):
        rows[label] = [z_db(cfg, plant, dahl, w) for w in freqs]
        print(f"  {label:20s} " + " ".join(f"{z:12.2f}" for z in rows[label]))
    w = 1.0 if 1.0 in freqs else freqs[0]
    i = freqs.index(w)
    true_z = rows["true parameters"][i]
    print(f"  at {w:g} rad/s: the drift costs {rows['drifted (old model)'][i] - true_z:+.1f} dB; "
          f"after recalibration {rows['recalibrated'][i] - true_z:+.2f} dB from the true "
          "parameters")
    return cal


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--random", type=int, default=2, help="random drifts after the default one")
    ap.add_argument("--duration", type=float, default=12.0, help="calibration length [s]")
    ap.add_argument("--amplitude", type=float, default=0.5)
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: the default drift, 3 s, 3 rad/s, 1000 samples of cost")
    args = ap.parse_args()
    if args.quick:
        args.random, args.duration = 0, 3.0
    freqs = (3.0,) if args.quick else FREQS
    base = ControllerConfig(mode="dob_full_ff", plant=PlantParams.table_i(), dahl=DahlParams())
    base = base.replace(friction=dataclasses.replace(base.friction,
                                                     calibration_duration=args.duration))
    print("Endpoint friction recalibration after a drift of the simulated plant "
          "(Table I model, sensors with noise, 2 kHz)")
    cases = [(1.5, 0.7, 1.5, 1.0)]
    rng = np.random.default_rng(args.seed)
    cases += [tuple(float(f) for f in np.round(r, 2)) for r in rng.uniform(
        [0.6, 0.6, 0.6, 0.7], [1.6, 1.4, 1.6, 1.4], size=(args.random, 4))]
    for factors in cases:
        one_case(base, factors, args.amplitude, args.speed, freqs)
    rows = (("dob_full_ff", base, False),
            ("dob_full_ff + adaptation", base.replace(friction=dataclasses.replace(
                base.friction, adaptation=True)), False),
            ("calibration running", base, True))
    print(f"\nper-sample cost of the controller update [us] "
          f"({len(FrictionCalibration(CalibrationGoal('p', 0.5, 1.0), base, DT).fit.ratios)} "
          "candidate sigma/F_c in a calibration, 3 in the adaptation)")
    reference = None
    for label, cfg, calibrating in rows:
        mean, tail = per_sample_cost(cfg, calibrating, n=1000 if args.quick else 6000)
        reference = reference or mean
        print(f"  {label:26s} mean {1e6 * mean:7.1f}  p99.9 {1e6 * tail:7.1f}  "
              f"(x{mean / reference:.2f} of dob_full_ff's mean)")

if __name__ == "__main__":
    main()

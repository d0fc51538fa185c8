"""Predicted vs simulated endpoint impedance per mode, and the hold's delay limit.

Over N random grippers (each Table I parameter and the Dahl sigma, F_c log-uniform in
0.5x-2x of its Table I value) whose controller runs on a model with a random 10-20 % error
in every parameter (sign random), this prints, per mode and frequency, the error of
:func:`seaforce_ros.commissioning.predictor.predict_modes` against the simulated backdrive
measurement (:func:`seaforce_ros.identification.zwidth_lib.simulate_impedance`: the core's
simulator, default sensors, one-sample command delay, the stiff position drive at 0.5 rad):
median, 90th percentile and largest |error| [dB], and the share within 3 dB. Then the hold's
delay limit (largest stable loop delay, endpoint free) predicted by
:func:`~seaforce_ros.commissioning.predictor.hold_delay_limit` against the first delay at
which the simulated hold (an extra command buffer in front of the simulator, a 0.01 rad
initial offset, 1.5 s) grows, and the CPU time of a prediction. Last, :func:`tune` on the
first few plants (identified = true, 1-sigma 5 %, margin 2 sigma, pressure noise 5e-4 N m,
2^20 counts/rev, delay p50 1 / p99 2 samples, budget 5 mN m rms): the settings, which
constraint bound each, the predicted mean Z-width over 0.3-10 rad/s before (defaults on the
identified model) and after, and the CPU time of a tune.

Run (from the repository root, environment sourced)::

    python bench/zwidth_prediction.py [N] [seed] [--quick]

``--quick``: one plant at 10 rad/s and one tune, a smoke run whose figures mean nothing.
"""

import argparse
import math
import pathlib
import sys
import time

import numpy as np

from seaforce_ros.commissioning.predictor import (PLANT_FIELDS, PREDICTED_MODES, LoopModel,
                                                  hold_delay_limit, predict_modes)
from seaforce_ros.commissioning.model import ControllerModel
from seaforce_ros.commissioning.tuning import InfeasibleTuningError, TuningGoals, tune
from seaforce_ros.core import ControllerConfig
from seaforce_ros.core.params import DahlParams, GraspParams, PlantParams, TargetParams
from seaforce_ros.identification.zwidth_lib import simulate_impedance

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "test"))
from helpers.delayed_hold import hold_grows  # noqa: E402

DT = 5e-4
OMEGAS = (1.0, 3.0, 10.0)
AMPLITUDE = 0.5


def random_case(rng):
    """(true plant, true Dahl, controller config on a model 10-20 % off)."""
    table = PlantParams.table_i()
    true = PlantParams(**{n: getattr(table, n) * math.exp(rng.uniform(-math.log(2), math.log(2)))
                          for n in PLANT_FIELDS})
    dahl = DahlParams(sigma=12.8 * math.exp(rng.uniform(-math.log(2), math.log(2))),
                      coulomb_force=0.032 * math.exp(rng.uniform(-math.log(2), math.log(2))))

    def off(v):
        return v * (1.0 + rng.choice((-1.0, 1.0)) * rng.uniform(0.1, 0.2))

    model = PlantParams(**{n: off(getattr(true, n)) for n in PLANT_FIELDS})
    model_dahl = DahlParams(sigma=off(dahl.sigma), coulomb_force=off(dahl.coulomb_force))
    target = TargetParams(stiffness=0.3 * model.hose_stiffness * rng.uniform(0.01, 0.1),
                          damping=model.hose_damping * rng.uniform(0.5, 3.0))
    # the default contact damping (0.08) exceeds 10 b_s for the softest hoses drawn
    grasp = GraspParams(contact_damping=min(0.08, 10.0 * model.hose_damping))
    return true, dahl, ControllerConfig(plant=model, dahl=model_dahl, target=target,
                                        grasp=grasp)


def simulated_delay_limit(plant, dahl, config, max_delay=40):
    """Largest d with the simulated hold stable at every delay 1..d."""
    for d in range(1, max_delay + 1):
        if hold_grows(plant, dahl, config, d):
            return d - 1
    return max_delay


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n", type=int, nargs="?", default=20, help="random plants")
    parser.add_argument("seed", type=int, nargs="?", default=1)
    parser.add_argument("--quick", action="store_true", help="smoke run: one plant, one tune")
    args = parser.parse_args()
    n = 1 if args.quick else args.n
    omegas = (10.0,) if args.quick else OMEGAS
    rng = np.random.default_rng(args.seed)
    errors = {m: {w: [] for w in omegas} for m in PREDICTED_MODES}
    limits = []
    cpu_pred = 0.0
    t0 = time.process_time()
    for case in range(n):
        true, dahl, config = random_case(rng)
        kp, kd = config.hold.stiffness, config.hold.damping
        predicted_limit = hold_delay_limit(true, kp, kd, dt=DT)
        modes = PREDICTED_MODES if predicted_limit >= 1 else tuple(
            m for m in PREDICTED_MODES if m != "hold")
        t = time.process_time()
        pred = predict_modes(true, dahl, config, modes, omegas, amplitude=AMPLITUDE)
        cpu_pred += time.process_time() - t
        meas = simulate_impedance(true, dahl, config, modes, omegas, amplitude=AMPLITUDE)
        for m in modes:
            for i, w in enumerate(omegas):
                errors[m][w].append(20 * math.log10(abs(pred[m][i]) / abs(meas[m][i])))
        limits.append((predicted_limit, simulated_delay_limit(true, dahl, config)))
        print(f"case {case + 1}/{n}: hold delay limit predicted {limits[-1][0]}, "
              f"simulated {limits[-1][1]}", flush=True)
    print(f"\nPredicted - simulated |Z| [dB] over {n} random plants (0.5x-2x Table I, "
          "model 10-20 % off), drive 0.5 rad:")
    print(f"{'mode':16s}{'w':>6s}{'median':>9s}{'p90 |e|':>9s}{'max |e|':>9s}{'<=3 dB':>9s}")
    for m in PREDICTED_MODES:
        for w in omegas:
            e = np.asarray(errors[m][w])
            if e.size == 0:
                continue
            a = np.abs(e)
            print(f"{m:16s}{w:6.1f}{np.median(e):9.2f}{np.percentile(a, 90):9.2f}"
                  f"{a.max():9.2f}{np.mean(a <= 3.0) * 100:8.0f}%")
    diff = [p - s for p, s in limits]
    print(f"\nHold delay limit (endpoint free, default gains 150/0.5): predicted - simulated "
          f"samples: {dict(zip(*np.unique(diff, return_counts=True)))}; within one sample: "
          f"{sum(abs(d) <= 1 for d in diff)}/{len(diff)}")
    print(f"CPU: {cpu_pred / n * 1e3:.0f} ms per prediction of {len(PREDICTED_MODES)} modes "
          f"x {len(omegas)} frequencies; whole run {time.process_time() - t0:.0f} s")
    print_tuning([random_case(np.random.default_rng(100 + i))[:2]
                  for i in range(1 if args.quick else 5)])
    return 0


def print_tuning(plants):
    figures = LoopModel(pressure_noise=5e-4, encoder_resolution=2 * math.pi / 2 ** 20,
                          delay_p50=1, delay_p99=2)
    print("\nTuning (identified = true plant, 1-sigma 5 %, margin 2, budget 5 mN m rms, "
          "delay p50/p99 1/2):")
    for plant, dahl in plants:
        sigma = {n: 0.05 * getattr(plant, n) for n in PLANT_FIELDS}
        t = time.process_time()
        try:
            r = tune(ControllerModel(plant, sigma, dahl), figures,
                     TuningGoals(noise_budget=0.005))
        except InfeasibleTuningError as exc:
            print(f"  refused ({exc.constraint}): {exc}")
            continue
        cpu = time.process_time() - t
        v = r.values
        print(f"  lambda {v['dob.cutoff'] / (2 * math.pi):6.1f} Hz, m_n/m "
              f"{v['dob.nominal_inertia'] / plant.motor_inertia:5.3f}, b_n "
              f"{v['dob.nominal_damping']:+.2e}, hold {v['hold.stiffness']:g}/"
              f"{v['hold.damping']:g} (delay limit {r.hold_delay_limit}), noise "
              f"{r.torque_noise * 1e3:.2f} mN m; Z-width {np.mean(r.zwidth_before_db):.1f} -> "
              f"{np.mean(r.zwidth_after_db):.1f} dB; CPU {cpu:.2f} s")
        print(f"    lambda: {r.bindings['dob.cutoff']}; m_n: "
              f"{r.bindings['dob.nominal_inertia']}; hold: {r.bindings['hold.stiffness']}")


if __name__ == "__main__":
    sys.exit(main())

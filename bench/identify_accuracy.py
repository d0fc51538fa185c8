#!/usr/bin/env python3
"""Identification accuracy on simulated bags: prints figures, asserts nothing.

For each parameter set (Table I; 3x endpoint inertia + half hose stiffness + 2x motor damping)
it simulates the paper's experiment offline -- a 60 s external-torque log chirp (0.3 N m,
0.01-1000 Hz) on the pinch finger with the motor off, Dahl hysteresis (sigma 12.8 N m/rad,
F_c 0.032 N m) and realistic sensors (16-bit pressure ADC with 5e-4 N m noise, quantised
encoders) -- writes it as an mcap bag, runs ``identify`` on it (with and without the Dahl
correction), fits the Dahl model to a 0.5 rad / 1 rad/s work-loop bag, and compares the
Z-width obtained with the identified parameters in the controller with the true-parameter one.

    python bench/identify_accuracy.py [--seeds 3]
"""
import argparse
import pathlib
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from seaforce_ros.core.params import ControllerConfig, DahlParams, PlantParams  # noqa: E402
from seaforce_ros.core.sensors import SensorParams  # noqa: E402
from seaforce_ros import bags as bagio  # noqa: E402
from seaforce_ros.identification.dahl_fit import fit_dahl_loop  # noqa: E402
from seaforce_ros.identification.experiments import (chirp_experiment,  # noqa: E402
                                                     work_loop_experiment)
from seaforce_ros.identification.plant_id import PARAMETERS, identify_plant  # noqa: E402
from seaforce_ros.identification.timeseries import prepare  # noqa: E402
from seaforce_ros.identification.zwidth_lib import (config_from_params,  # noqa: E402
                                                    simulate_impedance, zwidth_rows)

SETS = {
    "Table I": PlantParams.table_i(),
    "3x m_e, k_s/2, 2x b": PlantParams.table_i().scaled(endpoint_inertia=3.0,
                                                         hose_stiffness=0.5,
                                                         motor_damping=2.0),
}


def run_set(name, truth, seed, workdir, zwidth=True):
    print(f"\n=== {name}, seed {seed} ===")
    t0 = time.perf_counter()
    d = chirp_experiment(plant=truth, dahl=DahlParams(), sensors=SensorParams(), seed=seed)
    t_sim = time.perf_counter() - t0
    bag = workdir / f"chirp_{name.replace(' ', '_').replace(',', '').replace('/', '')}_{seed}"
    bagio.write_state_bag(bag, ["pinch"], {"pinch": d}, split_duration=10.0)
    t0 = time.perf_counter()
    record = bagio.read_channel(bag, "pinch")
    series = prepare(record, ("x", "f_p", "x_e"), optional=("f_e", "f_a"))
    res = identify_plant(series)
    t_id = time.perf_counter() - t0
    lin = identify_plant(series, dahl=False)
    print(f"chirp simulated in {t_sim:.1f} s; bag read + identified in {t_id:.1f} s")
    print(f"{'parameter':20s} {'true':>11s} {'identified':>11s} {'1-sigma':>9s} "
          f"{'error':>8s} {'fit err':>8s} {'linear-only error':>18s}")
    for key, (sym, unit, plant) in PARAMETERS.items():
        t = getattr(truth, key)
        v = getattr(res.params, key)
        vl = getattr(lin.params, key)
        print(f"{key:20s} {t:11.5g} {v:11.5g} {res.sigma[key]:9.2g} {100 * (v / t - 1):+7.2f}% "
              f"{100 * res.fit_error[plant]:7.2f}% {100 * (vl / t - 1):+17.2f}%")
    dh = res.dahl
    print(f"Dahl seen in the chirp: sigma {dh['sigma']:.3f} (true 12.8), F_c "
          f"{dh['coulomb_force']:.5f} (true 0.032)")
    if res.rational is not None:
        print("2-zero/4-pole X_e/F_e poles:", np.round(res.rational.poles, 2),
              f"fit error {100 * res.rational.fit_error:.2f} %")
    loop = work_loop_experiment(plant=truth, dahl=DahlParams(), cycles=2.0, seed=seed + 100)
    lbag = workdir / f"loop_{seed}_{abs(hash(name)) % 1000}"
    bagio.write_state_bag(lbag, ["pinch"], {"pinch": loop})
    lseries = prepare(bagio.read_channel(lbag, "pinch"), ("x_e", "f_e", "f_p"))
    fit = fit_dahl_loop(lseries, res.params)
    print(f"Dahl work-loop fit: sigma {fit.sigma:.3f} +- {fit.sigma_1s:.2g} "
          f"({100 * (fit.sigma / 12.8 - 1):+.2f} %), F_c {fit.coulomb_force:.5f} +- "
          f"{fit.coulomb_force_1s:.2g} ({100 * (fit.coulomb_force / 0.032 - 1):+.2f} %)")
    if zwidth:
        true_cfg = ControllerConfig(plant=truth, dahl=DahlParams())
        ident_cfg = config_from_params(
            {k: getattr(res.params, k) for k in PARAMETERS},
            {"sigma": fit.sigma, "coulomb_force": fit.coulomb_force, "exponent": 1.0},
            base=true_cfg)
        omegas = (0.1, 1.0, 3.0, 10.0)
        modes = ("hold", "dob", "dob_linear_ff", "dob_full_ff")
        zt = zwidth_rows(omegas, simulate_impedance(truth, DahlParams(), true_cfg, modes,
                                                    omegas))
        zi = zwidth_rows(omegas, simulate_impedance(truth, DahlParams(), ident_cfg, modes,
                                                    omegas))
        print("Z-width [dB] (hold vs minimum mode):   " + "  ".join(
            f"{w:g} rad/s" for w in omegas))
        print("  true parameters in the controller:   " + "  ".join(
            f"{r.width_db:7.2f}" for r in zt))
        print("  identified parameters:               " + "  ".join(
            f"{r.width_db:7.2f}" for r in zi))
        print("  difference:                          " + "  ".join(
            f"{a.width_db - b.width_db:+7.2f}" for a, b in zip(zi, zt)))
        print("  |Z| dob_full_ff true / identified [dB]: " + ", ".join(
            f"{a.z_db['dob_full_ff']:.1f}/{b.z_db['dob_full_ff']:.1f}" for a, b in zip(zt, zi)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--no-zwidth", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            for name, truth in SETS.items():
                run_set(name, truth, seed, pathlib.Path(tmp), zwidth=not args.no_zwidth)


if __name__ == "__main__":
    main()

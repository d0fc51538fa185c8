"""A friction calibration with an object in reach: refused or aborted, nothing applied?

``~/calibrate_friction`` learns b_e, k_e, F_c and sigma from a free finger. With an object in
the motion's reach the fit would learn the object (measured before: a 0.5 N m/rad object at
0.2 rad was applied as k_e +109 %). The calibration now runs a model-free contact test
(core/sided.py: the two sides' stiffness about the motion's centre) and refuses results
outside ``friction.plausible_ratio``. This bench runs the calibration as the controller runs
it (core only, the default 0.5 rad at 1 rad/s, 12 s) against:

* objects placed in reach -- positions 0.1..0.4 rad x stiffness 0.2..5 N m/rad (damping
  0.05) -- on plants drawn 0.7x..1.4x of the model (seeded): every one must end aborted with
  nothing applied;
* free air on plants drawn 0.5x..2x: how many succeed (a refusal in free air is the price),
  with the contact test's largest level.

Prints one row per run and the totals.

Run:  PYTHONPATH=. python bench/calibration_contact.py [--free 20] [--quick]
"""

import argparse
import math
import time

import numpy as np

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, contact_object, free)
from seaforce_ros.core.friction_calibration import CalibrationGoal, FrictionCalibration

TABLE_I = PlantParams.table_i()
DAHL = DahlParams()
FIELDS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
          "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")


def draw(rng, spread):
    f = np.exp(rng.uniform(-math.log(spread), math.log(spread), size=10))
    return (TABLE_I.scaled(**dict(zip(FIELDS, f[:8]))),
            DahlParams(sigma=DAHL.sigma * f[8], coulomb_force=DAHL.coulomb_force * f[9]))


def calibrate(plant, dahl, environment, seed=0, amplitude=0.5, speed=1.0):
    """(calibration, the controller's config afterwards == before)."""
    config = ControllerConfig()
    sim = ChannelSimulator(plant, dahl, seed=seed, environment=environment)
    ctl = ChannelController(config)
    cal = FrictionCalibration(CalibrationGoal("pinch", amplitude, speed, True), config)
    m = sim.measurement()
    n = int((config.friction.calibration_duration + 0.5) / sim.dt)
    for k in range(n):
        if k == 200:
            ctl.request_job(cal)
        m = sim.step(ctl.update(m.x, m.v, m.f_p))
        if cal.outcome is not None and k > 200 and ctl.job is None:
            break
    return cal, ctl.config == config


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--free", type=int, default=20, help="free-air plants")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--quick", action="store_true", help="4 placements, 2 free (smoke test)")
    args = ap.parse_args()
    t0 = time.monotonic()
    rng = np.random.default_rng(args.seed)
    positions = (0.1, 0.2, 0.3, 0.4)
    stiffnesses = (0.2, 0.5, 1.0, 2.0, 5.0)
    placements = [(p, k) for p in positions for k in stiffnesses]
    if args.quick:
        placements, args.free = placements[::5], 2
    print(f"objects in reach of a 0.5 rad, 1 rad/s calibration (plants 0.7x..1.4x):")
    print(f"{'position':>9}{'k_o':>6}  outcome  applied  why")
    refused = 0
    for i, (position, k) in enumerate(placements):
        plant, dahl = draw(rng, 1.4)
        cal, unchanged = calibrate(plant, dahl, contact_object(position, k, 0.05), seed=i)
        ok = cal.outcome != "succeeded" and not cal.applied and unchanged
        refused += ok
        print(f"{position:>9.2f}{k:>6.1f}  {cal.outcome:<8} {'yes' if cal.applied else 'no':<8} "
              f"{cal.message[:100]}")
    print(f"refused or aborted, nothing applied: {refused}/{len(placements)}")

    print(f"\nfree air (plants 0.5x..2x):")
    ok = levels = 0
    worst = 0.0
    for i in range(args.free):
        plant, dahl = draw(rng, 2.0)
        cal, _ = calibrate(plant, dahl, free(), seed=100 + i)
        worst = max(worst, cal.contact_test.peak)
        ok += cal.outcome == "succeeded"
        levels += 1
        print(f"  plant {i:>2}: {cal.outcome:<9} contact level {cal.contact_test.peak:.3f}  "
              f"{cal.message[:80]}")
    print(f"succeeded {ok}/{levels}; largest contact-test level in free air {worst:.3f} "
          f"(1 = contact)")
    print(f"wall time {time.monotonic() - t0:.0f} s")


if __name__ == "__main__":
    main()

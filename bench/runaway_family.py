"""A free finger in ``dob_full_ff`` on random plants: does it stay in its joint range?

Also, with every parameter off by 20 % (signs drawn), whether the free finger comes to rest
(no limit cycle). The controller has the Table I model (and the paper's Dahl fit) with the shipped defaults --
the feed-forward's margin (``feedforward.margin`` 2 x 10 %), the joint walls (``limits.*``),
the runaway monitor (``monitor.*``). The true plant has every Table I and Dahl parameter drawn
log-uniform in 0.5x..2x of the model (seeded). The finger starts free, with a flick of
``--flick`` rad/s (a hand letting go of it), and runs ``--seconds`` in the whole cycle
(:class:`seaforce_ros.core.rig.CycleRig`: state checks, controller, torque and joint-limit
faults). Printed per run: peak |X_e| and |V_e| (true), whether the finger stayed in the joint
range, the monitor's trips (time from start to the fall-back, peak |X_e| then) and faults;
then the totals. Also the runaways of the measurements that led to the margin (the model's k_e
17 % and 25 % above the finger's, its b_e 1.5x), once with the shipped defaults and once with
the paper's exact feed-forward (no margin), where the monitor and the walls must stop them.

Run:  PYTHONPATH=. python bench/runaway_family.py [--plants 200] [--seconds 60] [--quick]
"""

import argparse
import math
import multiprocessing
import time

import numpy as np

from seaforce_ros.core import ChannelSimulator, ControllerConfig, DahlParams, PlantParams
from seaforce_ros.core.rig import CycleRig

TABLE_I = PlantParams.table_i()
DAHL = DahlParams()
FIELDS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
          "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")


def draw(seed):
    """(plant, dahl) with every parameter log-uniform in 0.5x..2x of the model's."""
    rng = np.random.default_rng(seed)
    f = np.exp(rng.uniform(-math.log(2.0), math.log(2.0), size=len(FIELDS) + 2))
    plant = TABLE_I.scaled(**dict(zip(FIELDS, f[:len(FIELDS)])))
    dahl = DahlParams(sigma=DAHL.sigma * f[-2], coulomb_force=DAHL.coulomb_force * f[-1])
    return plant, dahl


def run(plant, dahl, config, seconds, flick, seed=0):
    """One free finger: a dict of figures."""
    sim = ChannelSimulator(plant, dahl, seed=seed)
    sim.reset(state=(0.0, flick, 0.0, flick))
    rig = CycleRig(sim, config)
    ctl, lim = rig.controller, config.limits
    n = int(round(seconds / sim.dt))
    peak_x = peak_v = 0.0
    trip_at = trip_x = None
    in_range = True
    last = []                       # |V_e| over the last second: at rest, or a limit cycle?
    diagnosed = False               # the settling watch named it at some time
    tail = n - int(round(1.0 / sim.dt))
    for i in range(n):
        rig.step()
        z = sim._z
        xe, ve = abs(z[2]), abs(z[3])
        peak_x = xe if xe > peak_x else peak_x
        peak_v = ve if ve > peak_v else peak_v
        if not lim.position_min <= z[2] <= lim.position_max:
            in_range = False
        if trip_at is None and ctl.fallback:
            trip_at, trip_x = rig.k * sim.dt, peak_x
        if i >= tail:
            last.append(z[3] * z[3])
        diagnosed = diagnosed or ctl.settling.restless or ctl.settling.creeping != 0.0
    return {"peak_x": peak_x, "peak_v": peak_v, "in_range": in_range, "trip_at": trip_at,
            "rest_v": math.sqrt(sum(last) / max(1, len(last))),
            "trip_x": trip_x, "fallback": ctl.fallback, "fault": rig.cycle.latched(0),
            "faults": rig.cycle.faults_latched,
            "diagnosed": diagnosed}


def family_run(args):
    seed, seconds, flick = args
    plant, dahl = draw(seed)
    return seed, run(plant, dahl, ControllerConfig(mode="dob_full_ff"), seconds, flick, seed)


def band_run(args):
    """Every parameter 20 % off the model, signs drawn: inside the default uncertainty."""
    seed, seconds, flick = args
    rng = np.random.default_rng(10_000 + seed)
    f = 1.0 + 0.2 * rng.choice((-1.0, 1.0), size=len(FIELDS) + 2)
    plant = TABLE_I.scaled(**dict(zip(FIELDS, f[:len(FIELDS)])))
    dahl = DahlParams(sigma=DAHL.sigma * f[-2], coulomb_force=DAHL.coulomb_force * f[-1])
    return seed, run(plant, dahl, ControllerConfig(mode="dob_full_ff"), seconds, flick, seed)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plants", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--flick", type=float, default=1.0, help="initial speed [rad/s]")
    ap.add_argument("--seed", type=int, default=1, help="first plant's seed")
    ap.add_argument("--quick", action="store_true", help="8 plants of 5 s (a smoke test)")
    ap.add_argument("--band", type=int, default=40, help="plants 20 % off")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    if args.quick:
        args.plants, args.seconds, args.band = 8, 5.0, 4
    t0 = time.monotonic()

    print("the measured runaways (Table I model, true plant off), free finger, "
          f"{min(args.seconds, 20.0):g} s:")
    print(f"{'case':<24}{'feed-forward':<16}{'peak |X_e|':>11}{'peak |V_e|':>11}"
          f"{'in range':>9}  monitor / fault")
    cases = (("true k_e 0.83x model", TABLE_I.scaled(endpoint_stiffness=0.83)),
             ("true k_e 0.75x model", TABLE_I.scaled(endpoint_stiffness=0.75)),
             ("model b_e 1.5x truth", TABLE_I.scaled(endpoint_damping=1 / 1.5)))
    exact = ControllerConfig(mode="dob_full_ff", allow_non_passive=True)
    exact = exact.replace(feedforward=exact.feedforward.__class__(margin=0.0,
                                                                  dahl_stiffness_share=1.0,
                                                                  damping_reserve=0.0))
    for name, plant in cases:
        for label, config in (("margin (default)", ControllerConfig(mode="dob_full_ff")),
                              ("exact (paper)", exact)):
            r = run(plant, DAHL, config, min(args.seconds, 20.0), args.flick)
            what = (f"fell back to {r['fallback']} at {r['trip_at']:.3f} s, |X_e| "
                    f"{r['trip_x']:.3f} rad then" if r["trip_at"] is not None else "no trip")
            if r["fault"]:
                what += f"; fault: {r['fault']}"
            print(f"{name:<24}{label:<16}{r['peak_x']:>11.3f}{r['peak_v']:>11.3f}"
                  f"{'yes' if r['in_range'] else 'NO':>9}  {what}")

    print(f"\n{args.band} plants with every parameter 20 % off (inside the default band), "
          f"dob_full_ff, free, flick {args.flick:g} rad/s, 6 s each:")
    with multiprocessing.Pool(args.jobs) as pool:
        band = list(pool.imap(band_run, [(i, 6.0, args.flick) for i in range(args.band)]))
    moving = [(s, r) for s, r in band if r["rest_v"] >= 0.01]
    print(f"at rest in the last second: {len(band) - len(moving)}/{len(band)}; largest rms "
          f"|V_e| then {max(r['rest_v'] for _, r in band):.4f} rad/s; peak |X_e| "
          f"{max(r['peak_x'] for _, r in band):.3f} rad; trips "
          f"{sum(r['trip_at'] is not None for _, r in band)}")

    print(f"\n{args.plants} plants 0.5x..2x (seeds {args.seed}..{args.seed + args.plants - 1}), "
          f"dob_full_ff, free, flick {args.flick:g} rad/s, {args.seconds:g} s each:")
    work = [(args.seed + i, args.seconds, args.flick) for i in range(args.plants)]
    with multiprocessing.Pool(args.jobs) as pool:
        results = []
        for i, (seed, r) in enumerate(pool.imap(family_run, work), 1):
            results.append((seed, r))
            if i % max(1, args.plants // 10) == 0:
                print(f"  {i}/{args.plants} done ({time.monotonic() - t0:.0f} s)", flush=True)
    inside = sum(r["in_range"] for _, r in results)
    trips = [(s, r) for s, r in results if r["trip_at"] is not None]
    faults = [(s, r) for s, r in results if r["faults"]]
    peak_v = max(r["peak_v"] for _, r in results)
    peak_x = max(r["peak_x"] for _, r in results)
    print(f"in range: {inside}/{len(results)}; peak |V_e| {peak_v:.3f} rad/s "
          f"(median {np.median([r['peak_v'] for _, r in results]):.3f}); peak |X_e| "
          f"{peak_x:.3f} rad")
    moving = [(s, r) for s, r in results if r["rest_v"] >= 0.01]
    print(f"monitor trips: {len(trips)}; latched faults: {len(faults)}; still moving in the "
          f"last second (rms |V_e| >= 0.01 rad/s): {len(moving)}")
    silent = [(s, r) for s, r in moving if r["trip_at"] is None and not r["diagnosed"]]
    print(f"  of those, with no fall-back and never a settling-watch diagnostic (restless or "
          f"creeping): {len(silent)}")
    # the silent ones first: they are what the monitor and the watch missed
    for s, r in (silent + [m for m in moving if all(m is not q for q in silent)])[:10]:
        named = ("fell back" if r["trip_at"] is not None else
                 "diagnosed" if r["diagnosed"] else "silent")
        print(f"  seed {s}: rms |V_e| {r['rest_v']:.3f} rad/s over the last second ({named})")
    for s, r in trips[:10]:
        print(f"  seed {s}: fell back to {r['fallback']} at {r['trip_at']:.3f} s, "
              f"|X_e| {r['trip_x']:.3f} rad then, peak |V_e| {r['peak_v']:.2f}")
    for s, r in faults[:10]:
        print(f"  seed {s}: fault {r['fault']!r}")
    worst = sorted(results, key=lambda sr: -sr[1]["peak_x"])[:5]
    print("largest |X_e|: " + ", ".join(f"seed {s} {r['peak_x']:.3f} rad" for s, r in worst))
    print(f"wall time {time.monotonic() - t0:.0f} s")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""How well ``identify --external-force auto`` tells a held external torque from a sampled
one, and what it costs: prints figures, asserts nothing.

Records: external-torque log chirps (0.3 N m, 0.01-1000 Hz, motor passive, Dahl hysteresis,
quantised noisy sensors) from the independent simulator of ``test/helpers/second_sim.py``,
with the torque held over each sample (a drive's command) or continuous (what a sampled force
sensor sees), on Table I and on draws of the randomised family, and from the project's core
simulator (held). For each record, duration and top of the fit band: the endpoint misfit
(chi^2/dof of fit B) under each convention, their ratio (wrong/right), whether ``auto`` chose
right, and how far the two conventions' parameters are apart (the largest relative difference
of the eight) -- what a wrong choice would cost. Then the time of ``identify_plant`` with one
convention and with ``auto`` (process time, best of 3).

    python bench/identify_external_force.py [--draws 3] [--durations 30 60 120] [--quick]
        (--quick: Table I only, 30 s, band top 400 rad/s, timings best of 1: a smoke run)
"""
import argparse
import math
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "test"))

from helpers.second_sim import DAHL, KEYS, TABLE_I, draw_family, simulate_chirp  # noqa: E402

from seaforce_ros.core.params import DahlParams, PlantParams  # noqa: E402
from seaforce_ros.core.sensors import SensorParams  # noqa: E402
from seaforce_ros.identification.experiments import chirp_experiment  # noqa: E402
from seaforce_ros.identification.plant_id import identify_plant  # noqa: E402
from seaforce_ros.identification.timeseries import Series  # noqa: E402


def _series(data):
    return Series("pinch", 5e-4, cycle0=0,
                  signals={k: np.asarray(data[k], float) for k in ("x", "f_p", "x_e", "f_e")})


def _records(draws, durations):
    rng = np.random.default_rng(7)
    plants = [("Table I", dict(TABLE_I), dict(DAHL))]
    plants += [(f"draw {i}",) + draw_family(rng) for i in range(draws)]
    for duration in durations:
        for name, plant, dahl in plants:
            for hold in (True, False):
                data = simulate_chirp(plant, dahl, duration=duration, hold=hold, seed=3)
                yield (f"second_sim {name}", duration, "held" if hold else "instant",
                       _series(data))
        data = chirp_experiment(plant=PlantParams.table_i(), dahl=DahlParams(),
                                sensors=SensorParams(), seed=3, duration=duration)
        yield "core sim Table I", duration, "held", _series(data)


def _cpu(fn, repeats=3):
    best = math.inf
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--durations", type=float, nargs="+", default=(30.0, 60.0, 120.0))
    ap.add_argument("--tops", type=float, nargs="+", default=(400.0, 200.0, 100.0, 40.0))
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: Table I only, 30 s, band top 400 rad/s")
    args = ap.parse_args(argv)
    if args.quick:
        args.draws, args.durations, args.tops = 0, (30.0,), (400.0,)
    print(f"{'record':22s} {'T [s]':>6s} {'truth':>7s} {'top':>5s} {'held':>9s} "
          f"{'instant':>9s} {'ratio':>7s} {'auto':>7s} {'max dp':>7s}")
    ratios = {}
    timing = None
    for name, duration, truth, series in _records(args.draws, args.durations):
        for top in args.tops:
            band = (0.5, top)
            r = {c: identify_plant(series, band=band, rational_band=band, external_force=c)
                 for c in ("held", "instant")}
            auto = identify_plant(series, band=band, rational_band=band)
            choice = auto.external_force
            wrong = "instant" if truth == "held" else "held"
            ratio = choice.misfits[wrong] / choice.misfits[truth]
            dp = max(abs(getattr(r["held"].params, k) / getattr(r["instant"].params, k) - 1)
                     for k in KEYS)
            ratios.setdefault(top, []).append(ratio)
            print(f"{name:22s} {duration:6.0f} {truth:>7s} {top:5.0f} "
                  f"{choice.misfits['held']:9.4g} {choice.misfits['instant']:9.4g} "
                  f"{ratio:7.3g} {choice.convention + ('' if choice.clear else '?'):>7s} "
                  f"{100 * dp:6.2f}%", flush=True)
            if timing is None and top == args.tops[0] and duration == max(args.durations):
                repeats = 1 if args.quick else 3
                timing = (duration, _cpu(lambda: identify_plant(series, external_force="held"),
                                         repeats), _cpu(lambda: identify_plant(series), repeats))
    print("\nratio wrong/right misfit per band top: min / median / max")
    for top, rs in ratios.items():
        print(f"  0.5-{top:g} rad/s: {min(rs):.3g} / {float(np.median(rs)):.3g} / "
              f"{max(rs):.3g} over {len(rs)} records")
    if timing:
        d, one, both = timing
        print(f"\nidentify_plant on a {d:.0f} s record: one convention {one:.2f} s, auto "
              f"{both:.2f} s (process time, best of {1 if args.quick else 3}; "
              f"+{100 * (both / one - 1):.0f} %)")


if __name__ == "__main__":
    main()

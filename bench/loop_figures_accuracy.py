#!/usr/bin/env python3
"""Accuracy of commissioning.loop_figures' sensor estimates: prints figures, asserts nothing.

Pressure noise: Gaussian noise of a known std (2e-4, 5e-4, 2e-3 N m) on a smooth signal, on
log chirps (0.1 Hz to 200 Hz, 500 Hz, 1 kHz; 0.3 N m) and on a constant, through the 16-bit
ADC over +-10 N m of the sensors, 10 s at 2 kHz; per difference order k the mean and spread
of the estimate's relative error over the seeds against the std of what was added (measured
minus clean, quantisation included), and the mean reported 1-sigma. Encoder: the quantum
found on positions rounded to 2^20, 2^14 and 40,000 counts/rev and unrounded.

    python bench/loop_figures_accuracy.py [--seeds 5] [--orders 4 6 8] [--quick]
        (--quick: one seed, order 4: a smoke run)
"""
import argparse
import math
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from seaforce_ros.commissioning.loop_figures import (encoder_resolution,  # noqa: E402
                                                     pressure_noise)

DT = 5e-4
N = 20000


def _adc(v, bits=16, full_scale=10.0):
    q = 2 * full_scale / 2 ** bits
    return np.minimum(np.round(np.clip(v, -full_scale, full_scale) / q) * q, full_scale - q)


def _chirp(f0, f1, amp):
    t = np.arange(N) * DT
    rate = math.log(f1 / f0) / t[-1]
    return amp * np.sin(2 * math.pi * f0 * np.expm1(rate * t) / rate)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--orders", type=int, nargs="+", default=(4, 6, 8))
    ap.add_argument("--quick", action="store_true", help="smoke run: one seed, order 4")
    args = ap.parse_args(argv)
    if args.quick:
        args.seeds, args.orders = 1, (4,)
    t = np.arange(N) * DT
    signals = {"smooth 2+13 Hz": 0.5 * np.sin(2 * math.pi * 2 * t)
               + 0.2 * np.sin(2 * math.pi * 13 * t),
               "chirp to 200 Hz": _chirp(0.1, 200.0, 0.3),
               "chirp to 500 Hz": _chirp(0.1, 500.0, 0.3),
               "chirp to 1 kHz": _chirp(0.1, 1000.0, 0.3),
               "constant": np.full(N, 0.02)}
    print("pressure noise: relative error of the estimate (mean, spread over seeds), mean "
          "reported 1-sigma")
    for order in args.orders:
        for name, clean in signals.items():
            for std in (2e-4, 5e-4, 2e-3):
                rows = []
                for seed in range(args.seeds):
                    rng = np.random.default_rng(seed)
                    measured = _adc(clean + std * rng.standard_normal(N))
                    truth = float(np.std(measured - clean))
                    est = pressure_noise(measured, order=order)
                    rows.append((est.std / truth - 1, est.std_1s / truth))
                r = np.array(rows)
                print(f"  k={order} {name:16s} std {std:.0e} N m: error "
                      f"{100 * r[:, 0].mean():+5.2f} % +- {100 * r[:, 0].std():4.2f} %, "
                      f"1-sigma {100 * r[:, 1].mean():4.2f} %")
    print("encoder quantum")
    rng = np.random.default_rng(1)
    motions = {"slow sine": 0.3 * np.sin(2 * math.pi * 0.5 * t) + 1.7,
               "chirp": 0.05 * np.sin(2 * math.pi * 0.8 * np.expm1(t / 4)) - 3.0,
               "random walk": np.cumsum(rng.standard_normal(N)) * 1e-4}
    for counts in (2 ** 20, 2 ** 14, 40000, 0):
        for name, x in motions.items():
            q = 2 * math.pi / counts if counts else 0.0
            est = encoder_resolution(np.round(x / q) * q if q else x)
            err = f"{est.quantum / q - 1:+.1e}" if q else "-"
            print(f"  {counts or 'unquantised':>11} {name:12s}: q {est.quantum:.6g} rad "
                  f"(relative error {err}), {est.counts_per_rev:.8g} counts/rev, "
                  f"{est.steps} steps, worst deviation {est.worst_deviation:.2g} q")


if __name__ == "__main__":
    main()

"""Does the free-air identification see when its model class does not fit?

Over N plants of the commissioning family (each Table I parameter, sigma and F_c log-uniform
in [0.5x, 2x]) the project's excitation job runs in its controller on the nonlinear oracle
(``test/helpers/nonlinear_sim.py``: its own integrator and sensors), once with every
nonlinear effect off (the model class the identification assumes) and once with every effect
drawn within its range (and, with ``--each``, with each effect alone). Printed per draw and
summarised: the misfits of the motor and port fits, the model-class verdict of
:func:`seaforce_ros.commissioning.free_air.model_class` and the identified hose damping b_s
against the truth and against its equivalent linear value at the excitation's hose flow;
last, how many draws the verdict flags per class (the threshold's false alarms and misses).

Run (from the repository root, environment sourced)::

    python bench/model_class.py [N] [seed] [--each] [--quick]

``--quick``: 1 draw, a 20 s chirp (a smoke run: its figures mean little).
"""
import math
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "test"))
from helpers.nonlinear_sim import EFFECTS, STROKE  # noqa: E402
from helpers.oracle_commissioning import draw, excite, identify, relative_errors  # noqa: E402

from seaforce_ros.commissioning.analyse import model_class_stage  # noqa: E402

QUICK_DURATION = 20.0    # s of chirp in --quick (the default: commissioning.duration, 40 s)


def term_truth(plant, e):
    """The oracle's value of each candidate term's coefficient (0: the effect is off)."""
    return {"motor_coulomb": e.motor_coulomb, "cogging": e.cogging,
            "hose_flow": plant["hose_damping"] / e.hose_flow if e.hose_flow else 0.0,
            "hose_pressure": e.hose_pressure * plant["hose_stiffness"] ** 2 / 2.0,
            "stroke_asymmetry": plant["endpoint_stiffness"] * e.stroke_asymmetry / STROKE,
            "stroke_stiffness": plant["endpoint_stiffness"] * e.stroke_stiffness / STROKE ** 2}


def main(argv):
    flags = {a for a in argv if a.startswith("--")}
    args = [a for a in argv if not a.startswith("--")]
    n = 1 if "--quick" in flags else int(args[0]) if args else 20
    seed0 = int(args[1]) if len(args) > 1 else 1
    classes = ["linear", "all effects"] + (list(EFFECTS) if "--each" in flags else [])
    rows = {c: [] for c in classes}
    t0 = time.process_time()
    for i in range(n):
        for label in classes:
            rng = np.random.default_rng(seed0 * 1000 + i)
            plant, dahl, effects = draw(rng, effects=label != "linear")
            if label not in ("linear", "all effects"):
                effects = effects.only(label)
            try:
                record = excite(plant, dahl, effects, seed=i, duration=QUICK_DURATION if "--quick" in flags
                                else None)
            except RuntimeError as exc:
                print(f"draw {i} {label}: {exc}")
                continue
            ident = identify(record)
            verdict, terms = model_class_stage(record, ident)
            err = relative_errors(ident, plant, dahl)
            resolved = sorted(t.key for t in terms.resolved()) if terms else []
            b_s = (terms.equations["port"].linear["hose_damping"][0]
                   if terms and "port" in terms.equations else math.nan)
            b_s_err = b_s / plant["hose_damping"] - 1.0
            flow = terms.term("hose_flow") if terms else None
            c_err = (flow.value / (plant["hose_damping"] / effects.hose_flow) - 1.0
                     if flow is not None and effects.hose_flow else math.nan)
            truth = term_truth(plant, effects)
            term_err = {t.key: t.value / truth[t.key] - 1.0 for t in terms.resolved()
                        if truth.get(t.key)} if terms else {}
            rows[label].append((ident.misfit["motor"], ident.misfit["port"], verdict.fits,
                                err["hose_damping"], b_s_err, c_err, resolved, term_err))
            print(f"draw {i:2d} {label:16s} misfit motor {100 * ident.misfit['motor']:5.2f} %, "
                  f"port {100 * ident.misfit['port']:5.2f} % -> "
                  f"{'fits' if verdict.fits else 'FLAGGED'}; b_s {100 * err['hose_damping']:+6.1f}"
                  f" % (with the terms {100 * b_s_err:+5.1f} %, c {100 * c_err:+5.1f} %); "
                  f"resolved: {', '.join(resolved) or '-'}; {effects.describe()}", flush=True)
    print(f"\nover {n} draws (seed {seed0}); misfit [%] median / max, flagged draws:")
    for label, r in rows.items():
        if not r:
            continue
        a = np.asarray([x[:6] for x in r], float)
        counts = {}
        for x in r:
            for key in x[6]:
                counts[key] = counts.get(key, 0) + 1
        print(f"  {label:16s} motor {100 * np.median(a[:, 0]):5.2f} / {100 * a[:, 0].max():5.2f}"
              f"  port {100 * np.median(a[:, 1]):5.2f} / {100 * a[:, 1].max():5.2f}  flagged "
              f"{int((a[:, 2] == 0).sum())}/{len(r)}  b_s error median "
              f"{100 * np.median(a[:, 3]):+.1f} %, max |{100 * np.abs(a[:, 3]).max():.1f}| %; "
              f"with the terms max |{100 * np.nanmax(np.abs(a[:, 4])):.1f}| %, c max "
              f"|{100 * np.nanmax(np.abs(a[:, 5])) if np.isfinite(a[:, 5]).any() else math.nan:.1f}"
              f"| %; resolved: " + ", ".join(f"{k} {v}/{len(r)}" for k, v in sorted(counts.items())))
        errors = {}
        for x in r:
            for key, e in x[7].items():
                errors.setdefault(key, []).append(e)
        for key, e in sorted(errors.items()):
            e = np.abs(np.asarray(e))
            print(f"      {key:18s} resolved {e.size}/{len(r)}: |error| median "
                  f"{100 * np.median(e):.1f} %, 90th percentile {100 * np.percentile(e, 90):.1f} %,"
                  f" largest {100 * e.max():.1f} %")
    print(f"CPU {time.process_time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""The feed-forward's margin over a family of grippers with real sensors, against its goals.

Each draw: a plant of the commissioning family (Table I, sigma and F_c log-uniform in
[0.5x, 2x]), the linear class (every nonlinear effect off) or the nonlinear one (every effect
of ``test/helpers/nonlinear_sim.py`` drawn in its range), and a rig's sensors drawn apart
(:func:`helpers.nonlinear_sim.draw_sensors`: encoder 2^14..2^20 counts/rev, the drive's
velocity over 1-4 samples, pressure +-10..+-40 N m at 12-16 bit with 0.2-2 mN m of noise and an
offset within +-50 mN m, 0-2 samples of extra delay). On the oracle (its own integrator and
sensors), with the project's controller in lock-step:

* **hand-typed**: the shipped configuration (Table I, its uncertainties) -- ``dob_full_ff``
  and ``hold`` backdriven (0.5 rad, at most 0.5 rad/s, as the commissioning demo) at 1 and
  3 rad/s;
* **commissioned**: the project's excitation job on the oracle, its analysis' proposal, the
  verification job on the same finger, the analysis' finish (as ``~/commission`` runs them),
  the tuned configuration backdriven the same way;
* the margin's cost at 1 rad/s as the tuning predicts it (tuned ``dob_full_ff`` against the
  exact inversion of the identified model);
* a free finger entered into ``dob_full_ff`` at rest (the motor from ``passive``) after
  commissioning: how far it moves in 5 s.

Printed per draw, then per class the median and the range of each figure beside its goal.

Run (from the repository root, environment sourced)::

    python bench/margin_family.py [N per class] [seed] [--linear | --nonlinear] [--unverified]

(``--unverified``: no verification, the model class's candidate, as before it; ``--quick``:
one linear draw, a 20 s chirp, one candidate verified at one point -- a smoke run.)
"""
import dataclasses
import math
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "test"))
from helpers.nonlinear_sim import draw_sensors  # noqa: E402
from helpers.oracle_commissioning import commission, draw, figures, release  # noqa: E402

from seaforce_ros.commissioning.analyse import backdrive_amplitude  # noqa: E402
from seaforce_ros.core.params import ControllerConfig  # noqa: E402

OMEGAS = (1.0, 3.0)
#: The shipped configuration's settings a gripper's own config carries (config/gripper.yaml).
HAND_TYPED = ControllerConfig(max_torque=20.0)


class Unstable:
    """A backdrive whose loop diverged (on the rig the cycle's max_torque latches a fault):
    no figure."""
    z_db = z_rms_db = math.nan


def measure(plant, dahl, effects, sensors, config, seed):
    """{(mode, omega): ImpedanceFigures} of hold and dob_full_ff (:class:`Unstable` where the
    loop diverged)."""
    out = {}
    for m in ("hold", "dob_full_ff"):
        for w in OMEGAS:
            try:
                fig = figures(plant, dahl, effects, config, m, w, backdrive_amplitude(w), seed,
                              sensors=sensors)
                if not fig.z_rms_db < 100.0:           # (|F_e| beyond any max_torque)
                    raise FloatingPointError
                out[(m, w)] = fig
            except (ValueError, FloatingPointError, OverflowError):
                print(f"  {m} at {w:g} rad/s: the loop diverged", flush=True)
                out[(m, w)] = Unstable()
    return out


QUICK = "--quick" in sys.argv


def draw_row(cls, seed0, i):
    rng = np.random.default_rng([seed0, i, 0 if cls == "linear" else 1])
    plant, dahl, effects = draw(rng, effects=cls == "nonlinear")
    sensors = draw_sensors(rng)
    print(f"{cls} {i}: {sensors.describe()}", flush=True)
    before = measure(plant, dahl, effects, sensors, HAND_TYPED, i)
    t0 = time.time()
    config = HAND_TYPED.replace(verification=dataclasses.replace(
        HAND_TYPED.verification, candidates=1, offset=0.0)) if QUICK else HAND_TYPED
    a, rig, cpu = commission(plant, dahl, effects, sensors, config, seed=i,
                             duration=20.0 if QUICK else None,
                             verify="--unverified" not in sys.argv)
    row = {"rig": rig, "cpu": cpu}
    for w in OMEGAS:
        row[f"hand_ff{w:g}"] = before[("dob_full_ff", w)].z_rms_db
        row[f"hand_zw{w:g}"] = before[("hold", w)].z_rms_db - row[f"hand_ff{w:g}"]
    if not a.tuned:
        print(f"  not tuned: {a.message} ({time.time() - t0:.0f} s)", flush=True)
        row["tuned"] = False
        return row
    config = a.tuning.config
    after = measure(plant, dahl, effects, sensors, config, i)
    row["tuned"] = True
    for w in OMEGAS:
        row[f"ff{w:g}"] = after[("dob_full_ff", w)].z_rms_db
        row[f"ff_fund{w:g}"] = after[("dob_full_ff", w)].z_db
        row[f"zw{w:g}"] = after[("hold", w)].z_rms_db - row[f"ff{w:g}"]
    cost = a.tuning.margin_cost_db
    row["cost1"] = float(np.interp(0.0, np.log(a.tuning.omega), cost))
    free = release(plant, dahl, effects, config.replace(mode="dob_full_ff"), 0.0, 5.0, i,
                   sensors=sensors)
    row["moved"] = float(np.max(np.abs(free["x_e"] - free["x_e"][0])))
    row["fallback"] = free["fallback"]
    ff = config.feedforward
    row["verified"] = a.tuning.bindings.get("feedforward.dahl_stiffness_share", "")
    print(f"  feed-forward: {row['verified']}")
    print(f"  dob_full_ff rms at 1 rad/s {row['hand_ff1']:.1f} -> {row['ff1']:.1f} dB "
          f"(fundamental {row['ff_fund1']:.1f}); Z-width on the rms {row['hand_zw1']:.1f} -> "
          f"{row['zw1']:.1f} dB at 1 rad/s, {row['hand_zw3']:.1f} -> {row['zw3']:.1f} at 3; "
          f"margin cost {row['cost1']:.1f} dB; free finger moved {1e3 * row['moved']:.1f} mrad "
          f"in 5 s{' (fell back)' if row['fallback'] else ''}; reserve "
          f"{ff.damping_reserve:.4f}, scales {', '.join(f'{s:.3f}' for s in ff.scales())}, "
          f"share {ff.dahl_stiffness_share:g}; analysis {cpu:.1f} s CPU "
          f"({time.time() - t0:.0f} s)", flush=True)
    return row


GOALS = {
    "linear": (("cost1", "<= 3 dB median, <= 6 worst"), ("zw1", ">= 70 dB median"),
               ("zw3", ">= 50 dB median"), ("hand_zw1", "(hand-typed)"),
               ("ff1", "(dob_full_ff rms at 1 rad/s)"), ("moved", "<= 0.020 rad every draw"),
               ("rig", "<= 90 s"), ("cpu", "<= 20 s")),
    "nonlinear": (("ff_gain", "> 0 every draw (never stiffer), >= 10 dB median"),
                  ("zw1", ">= 60 dB median"), ("zw3", "(at 3 rad/s)"),
                  ("hand_zw1", "(hand-typed)"), ("cost1", "(predicted margin cost)"),
                  ("moved", "<= 0.020 rad every draw"), ("rig", "<= 90 s"),
                  ("cpu", "<= 20 s")),
}


def main(argv):
    args = [a for a in argv if not a.startswith("--")]
    n = 1 if QUICK else int(args[0]) if args else 4
    seed0 = int(args[1]) if len(args) > 1 else 1
    classes = ["linear"] if QUICK else [
        c for c in ("linear", "nonlinear") if f"--{c}" in argv] or ["linear", "nonlinear"]
    for cls in classes:
        rows = [draw_row(cls, seed0, i) for i in range(n)]
        tuned = [r for r in rows if r["tuned"]]
        for r in tuned:
            r["ff_gain"] = r["hand_ff1"] - r["ff1"]
        print(f"\n{cls} class, {len(tuned)} of {len(rows)} draws tuned (seed {seed0}): "
              "median [min .. max]")
        for key, goal in GOALS[cls]:
            v = np.asarray([r[key] for r in tuned], float)
            if v.size:
                print(f"  {key:10s} {np.nanmedian(v):8.3f} [{np.nanmin(v):8.3f} .. "
                      f"{np.nanmax(v):8.3f}]   goal {goal}"
                      + (f" ({np.isnan(v).sum()} diverged)" if np.isnan(v).any() else ""))
        print(f"  fell back in the free-finger test: {sum(bool(r['fallback']) for r in tuned)}",
              flush=True)
        kinds = [r["verified"].split(":")[0] for r in tuned]
        print("  feed-forward: " + ", ".join(f"{k} {kinds.count(k)}" for k in sorted(set(kinds))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

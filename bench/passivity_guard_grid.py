"""The time-domain passivity guard over a grid of aggressive DOB settings.

Grid: lambda in {2 pi 10, 2 pi 20, 2 pi 50} rad/s x m_n in {0.1, 0.25, 0.5, 0.75, 1} m x
b_n in {0, -k/(2 lambda), -2 k/lambda} (the first two inside eq. 28's b_n range, the last
beyond it), ``dob`` mode, Table I, default sensors, one-sample command delay, 2 kHz; the
guard at its defaults (reserve 1 mJ, max_damping 0.5 N m s/rad, release 5 s, no dead band).

Environments, each without and with the guard (``active``):

* free   -- endpoint free, kicked to 0.5 rad/s;
* soft   -- pressed into an object of 1 N m/rad, 0.02 N m s/rad by the finger's own spring
            (surface 0.3 rad away), kicked to 0.2 rad/s;
* stiff  -- the same against 50 N m/rad, 0.005 N m s/rad (little damping);
* drive  -- the bonded position drive of core/environment.py (1000 N m/rad), 0.05 rad at
            10 rad/s.

Verdict: ``DIV`` the torque left max_torque (5 N m: the cycle would latch a fault); ``GROW``
growing (last 0.25 s > 1.25 x the 0.25 s before); ``LC`` a sustained oscillation (at rest:
> 0.01 rad/s rms motor velocity over the last 0.25 s and less than 30 % below its level a
second earlier; in the drive: the velocity does not repeat with the drive within 5 % rms);
else ``ok``. 4 s at rest without the guard, 6 s with it (a weak limit cycle runs until it has
spent half the reserve, and the damping that stopped a transient is released once).

|Z| = F_e/(j w X_e) in the bonded drive at 1, 10, 30 rad/s (0.3, 0.05, 0.017 rad: 0.3-0.5 rad/s
at the endpoint), over whole periods after 3 s (8 s with the guard: it releases damping it
no longer needs over 5 s). Then the gain: |Z| at 10 and 30 rad/s of m_n below the bound with
the guard against the passive ``dob`` (m_n = m, lambda = 2 pi 20), in the bonded drive and
with the endpoint free, driven by a 0.01 N m torque sine, next to the continuous model
(:meth:`PlantModel.dob_impedance`).

Run:  PYTHONPATH=. python bench/passivity_guard_grid.py [--inside] [--quick]
      (--inside: b_n in {0, -k/(2 lambda)} only; --quick: one setting of the grid and one
      of the gain, a smoke run)
"""

import argparse
import math
import sys
import time

import numpy as np

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DobParams, PlantParams, free, position_sine, torque_sine)
from seaforce_ros.core.analysis import frequency_response, impedance_from_position
from seaforce_ros.core.environment import contact_object
from seaforce_ros.core.params import GuardParams
from seaforce_ros.core.plant import PlantModel
from seaforce_ros.core.simulator import run_closed_loop

DT = 5e-4
PLANT = PlantParams.table_i()
M, B, K = PLANT.motor_inertia, PLANT.motor_damping, PLANT.motor_stiffness
MAX_TORQUE = 5.0
LIMIT_CYCLE = 0.01
FREQS = (1.0, 10.0, 30.0)
AMPLITUDE = {1.0: 0.3, 10.0: 0.05, 30.0: 0.017}


def pressed(stiffness, damping, kick, surface=-0.3):
    xe = stiffness * surface / (PLANT.endpoint_stiffness + stiffness)
    return contact_object(surface, stiffness, damping), (xe, 0.0, xe, kick)


REST = {"free": (free(), (0.0, 0.0, 0.0, 0.5)), "soft": pressed(1.0, 0.02, 0.2),
        "stiff": pressed(50.0, 0.005, 0.2)}


def simulate(dob, guard, env, state, seconds):
    """Closed loop, ``dob`` mode, until ``seconds`` or the first torque beyond MAX_TORQUE:
    (completed, motor velocity, X_e, F_e, most damping the guard added)."""
    sim = ChannelSimulator(PLANT, None, dt=DT, seed=3, environment=env)
    sim.reset(state=state, environment=env)
    cfg = ControllerConfig(mode="dob", dob=dob, allow_non_passive=True, max_torque=MAX_TORQUE,
                           passivity=GuardParams(mode=guard))
    n = int(round(seconds / DT))
    r = run_closed_loop(sim, ChannelController(cfg, dt=DT), n, max_torque=MAX_TORQUE)
    damping = r.get("passivity_damping", np.zeros(1))
    alpha = float(damping.max()) if damping.size else 0.0
    return r["u"].size == n, r["v_true"], r["x_e"], r["f_e"], alpha


def rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def at_rest(dob, guard, name):
    env, state = REST[name]
    done, v, _, _, alpha = simulate(dob, guard, env, state, 6.0 if guard == "active" else 4.0)
    if not done:
        return "DIV", alpha
    k = int(0.25 / DT)
    last, before, second_ago = rms(v[-k:]), rms(v[-2 * k:-k]), rms(v[-5 * k:-4 * k])
    if last > 1.25 * before + 1e-3:
        return "GROW", alpha
    if last > LIMIT_CYCLE and last > 0.7 * second_ago:
        return "LC", alpha
    return "ok", alpha


def driven(dob, guard, omega, settle):
    """(verdict, Z or None, most damping the guard added) in the bonded drive."""
    period = 2 * math.pi / omega
    periods = max(2, int(math.ceil(1.0 / period)))
    done, v, xe, fe, alpha = simulate(dob, guard, position_sine(AMPLITUDE[omega], omega),
                                      (0.0, 0.0, 0.0, 0.0), settle + periods * period + DT)
    if not done:
        return "DIV", None, alpha
    p = int(round(period / DT))
    verdict = "ok" if rms(v[-p:] - v[-2 * p:-p]) <= 0.05 * rms(v[-p:]) else "LC"
    return verdict, impedance_from_position(fe, xe, omega, DT, settle), alpha


def torque_driven(dob, guard, omega, settle=3.0):
    """|Z| with the endpoint free, driven by a 0.01 N m torque sine (None if it diverged)."""
    period = 2 * math.pi / omega
    periods = max(2, int(math.ceil(1.0 / period)))
    done, _, xe, fe, _ = simulate(dob, guard, torque_sine(0.01, omega), (0.0,) * 4,
                                  settle + periods * period + DT)
    return impedance_from_position(fe, xe, omega, DT, settle) if done else None


def db(z):
    return 20.0 * math.log10(abs(z)) if z is not None else math.nan


def zcells(values):
    return " ".join("   div " if zw is None else f"{db(zw):6.1f}{'*' if v != 'ok' else ' '}"
                    for v, zw in values)


def setting(fraction, cutoff_hz, damping):
    lam = 2 * math.pi * cutoff_hz
    return DobParams(cutoff=lam, nominal_inertia=fraction * M, nominal_damping=damping * K / lam)


def passive(dob):
    lam = dob.cutoff
    return dob.nominal_inertia >= M - B / lam and 0.0 <= K + lam * dob.nominal_damping


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--inside", action="store_true", help="b_n in {0, -k/(2 lambda)} only")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: 20 Hz, m_n 0.5 m, b_n -k/(2 lambda) only")
    args = parser.parse_args()
    dampings = (0.0, -0.5) if args.inside else (0.0, -0.5, -2.0)
    cutoffs, fractions = (10, 20, 50), (0.1, 0.25, 0.5, 0.75, 1.0)
    if args.quick:
        dampings, cutoffs, fractions = (-0.5,), (20,), (0.5,)
    t0 = time.perf_counter()
    envs = ("free", "soft", "stiff", "drive")
    print("DOB grid without / with the passivity guard (Table I, dob mode; verdicts: ok, LC "
          "limit cycle, GROW, DIV diverged)")
    print("|Z| [dB re 1 N m s/rad] in the bonded position drive at 1 / 10 / 30 rad/s; "
          "alpha = most damping the guard added [N m s/rad]\n")
    head = (f"{'lambda':>6} {'m_n/m':>5} {'b_n':>8} {'eq28':>4} | "
            + " ".join(f"{e:>5}" for e in envs) + " | " + " ".join(f"{e:>5}" for e in envs)
            + " | " + "   no guard [dB]      " + " |      guard [dB]       | alpha")
    print(head)
    print("-" * len(head))
    rows = []
    for cutoff_hz in cutoffs:
        for damping in dampings:
            for fraction in fractions:
                dob = setting(fraction, cutoff_hz, damping)
                verdicts = {}
                for guard in ("disabled", "active"):
                    verdicts[guard] = [at_rest(dob, guard, name)[0] for name in REST]
                z = {}
                alpha = 0.0
                for guard, settle in (("disabled", 3.0), ("active", 8.0)):
                    z[guard] = []
                    for omega in FREQS:
                        verdict, zw, a = driven(dob, guard, omega, settle)
                        z[guard].append((verdict, zw))
                        alpha = max(alpha, a)
                        if omega == 10.0:
                            verdicts[guard].append(verdict)
                rows.append((cutoff_hz, fraction, damping, passive(dob), verdicts, z, alpha))
                print(f"{cutoff_hz:>4}Hz {fraction:>5.2f} {damping:>5.1f}k/l "
                      f"{'yes' if passive(dob) else 'no':>4} | "
                      + " ".join(f"{v:>5}" for v in verdicts["disabled"]) + " | "
                      + " ".join(f"{v:>5}" for v in verdicts["active"]) + " | "
                      + zcells(z["disabled"]) + " | " + zcells(z["active"])
                      + f" | {alpha:.3f}", flush=True)
    print("(* : the response does not repeat with the drive: |Z| of a limit cycle)")
    summary(rows)
    gain(((20,), (0.5,)) if args.quick else ((20, 50), (0.5, 0.25, 0.1)))
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return 0


def summary(rows):
    cells = len(rows) * 4
    bad = sum(v != "ok" for r in rows for v in r[4]["disabled"])
    bad_guarded = sum(v != "ok" for r in rows for v in r[4]["active"])
    settings_bad = sum(any(v != "ok" for v in r[4]["disabled"]) for r in rows)
    per_env = {e: sum(r[4]["active"][i] != "ok" for r in rows)
               for i, e in enumerate(("free", "soft", "stiff", "drive"))}
    print(f"\nwithout the guard: {bad} of {cells} (setting, environment) pairs unstable or "
          f"limit-cycling ({settings_bad} of {len(rows)} settings somewhere); with it: "
          f"{bad_guarded} (" + ", ".join(f"{e} {n}" for e, n in per_env.items()) + ")")
    deltas, passive_deltas = [], []
    for cutoff_hz, fraction, damping, is_passive, verdicts, z, _ in rows:
        for (v0, z0), (v1, z1), omega in zip(z["disabled"], z["active"], FREQS):
            if v0 == "ok" and v1 == "ok":
                d = abs(db(z1) - db(z0))
                (passive_deltas if is_passive else deltas).append(
                    (d, cutoff_hz, fraction, damping, omega))
    for damping in sorted({d[3] for d in deltas}, reverse=True):
        worst = max(d for d in deltas if d[3] == damping)
        print(f"where the unguarded drive is stable, b_n = {damping:g} k/lambda: |Z| with the "
              f"guard within {worst[0]:.2f} dB of it (non-passive settings; worst {worst[1]} Hz, "
              f"m_n {worst[2]} m, {worst[4]:g} rad/s)")
    if passive_deltas:
        print(f"passive settings (eq. 28 holds): within {max(passive_deltas)[0]:.3f} dB")


def gain(settings):
    """``settings``: (cut-offs [Hz], m_n fractions) of the settings compared."""
    model = PlantModel(PLANT)
    reference = DobParams()          # the passive dob: m_n = m, lambda = 2 pi 20
    print("\nthe gain: |Z| [dB] at 10 / 30 rad/s, m_n below the bound with the guard vs the "
          "passive dob (m_n = m, lambda = 2 pi 20 rad/s)")
    print(f"{'setting':28} | {'model':>13} | {'bonded drive':>13} | {'endpoint free':>13} | "
          "gain free / model at 30 rad/s")
    ref = {}
    for name, dob in [("passive dob", reference)] + [
            (f"{cutoff} Hz, m_n {fraction} m", setting(fraction, cutoff, -0.5))
            for cutoff in settings[0] for fraction in settings[1]]:
        zm = frequency_response(model.dob_impedance(dob), [10.0, 30.0])
        guard = "disabled" if name == "passive dob" else "active"
        zb = [driven(dob, guard, w, 8.0)[1] for w in (10.0, 30.0)]
        zf = [torque_driven(dob, guard, w, 8.0) for w in (10.0, 30.0)]
        values = [db(zm[0]), db(zm[1]), db(zb[0]), db(zb[1]), db(zf[0]), db(zf[1])]
        if not ref:
            ref = dict(zip(("m10", "m30", "b10", "b30", "f10", "f30"), values))
            extra = ""
        else:
            extra = f"{values[5] - ref['f30']:+.1f} / {values[1] - ref['m30']:+.1f} dB"
        print(f"{name:28} | {values[0]:6.1f} {values[1]:6.1f} | {values[2]:6.1f} {values[3]:6.1f} "
              f"| {values[4]:6.1f} {values[5]:6.1f} | {extra}", flush=True)


if __name__ == "__main__":
    sys.exit(main())

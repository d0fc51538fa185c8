"""identify on a randomised family of plants, measured with an independent simulator.

Oracles that do not come from the project's own simulator:

* the data come from :mod:`helpers.second_sim` (trapezoidal integration with substeps, a
  continuous Dahl force, its own sensors; checked against scipy's ``solve_ivp`` below);
* each plant is drawn at random: the eight parameters log-uniform in [0.33x, 3x] of Table I,
  Dahl sigma and F_c log-uniform in [0.5x, 2x] of the paper's (n = 1);
* the identified model's X_e/F_e is compared with the true plant's, computed analytically
  from the paper's equations (:func:`helpers.second_sim.transfer_functions`);
* the record goes through a rosbag2 bag with a decoy channel (another plant's data) and
  about 1 % of its cycles lost in bursts, and through the ``identify`` executable.

Seeds: every run draws its own (``SEAFORCE_ID_SEED=<seed>`` replays one); each failure
message carries the seed.

Threshold. The goal is a pass rate >= 95 % over the family (m, m_e, k_s within 5 %, the
other five within 15 %); ``bench/identify_accuracy.py`` measures it over 40 draws. Here
N = 8 draws keep the run time reasonable, and the test allows at most one failing draw: a
method that meets the goal with margin (a failure rate of 1 %) fails this test with
probability 1 - 0.99^8 - 8 (0.01) 0.99^7 = 0.3 %; one at the goal's edge (5 %) with 5.7 %;
one that fails 30 % of the family is caught with probability 74 % per run (and one failing
half of it with 96 %). Independently of the count, no draw may miss a limit by more than
2x (a gross failure is caught in every run).
"""
import concurrent.futures
import math
import multiprocessing
import os
import subprocess

import numpy as np
import pytest
import yaml

from helpers.processes import executable
from helpers.second_sim import (KEYS, TABLE_I, draw_family, drop_mask, simulate_chirp,
                                transfer_functions, write_bag)

TIGHT = ("motor_inertia", "endpoint_inertia", "hose_stiffness")     # within 5 %
N_DRAWS = 8
MAX_FAILING = 1
LOST_FRACTION = 0.01
BAND = (0.5, 400.0)


def _limit(key):
    return 0.05 if key in TIGHT else 0.15


def _seed():
    text = os.environ.get("SEAFORCE_ID_SEED")
    return int(text) if text else int.from_bytes(os.urandom(4), "little")


def _identify_all(bags, outs, tmp_path, parallel=2):
    """Run the identify executable on every bag, ``parallel`` at a time; each process is
    waited for (and, on any error, killed) by its own PID."""
    results = [None] * len(bags)
    running = []
    pending = list(range(len(bags)))
    try:
        while pending or running:
            while pending and len(running) < parallel:
                i = pending.pop(0)
                log = open(tmp_path / f"identify_{i}.log", "w+")
                proc = subprocess.Popen(
                    [str(executable("identify")), str(bags[i]), "--channel", "pinch",
                     "--out", str(outs[i]), "--quiet"],
                    stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
                running.append((i, proc, log))
            i, proc, log = running.pop(0)
            code = proc.wait(timeout=1200)        # generous: a loaded CI host starves it
            log.seek(0)
            results[i] = (code, log.read())
            log.close()
    finally:
        for _, proc, log in running:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            log.close()
    return results


def _plant(path):
    return yaml.safe_load(path.read_text())["/**"]["ros__parameters"]["pinch"]["plant"]


def _draw(seed, i):
    """Draw ``i`` of the family of ``seed``: (plant, dahl, its chirp record, the cycles kept)."""
    rng = np.random.default_rng([seed, i])
    plant, dahl = draw_family(rng)
    data = simulate_chirp(plant, dahl, duration=120.0, seed=int(rng.integers(2 ** 31)))
    return plant, dahl, data, drop_mask(data["x"].size, LOST_FRACTION, rng)


def _bag(path, data, decoy, keep):
    write_bag(path, ["wrist", "pinch"], {"pinch": data, "wrist": decoy}, keep=keep)
    return path


# about a minute on an idle 2-core host (8 simulations, 8 identify runs two at a time); the
# suite's 300 s default is too short on a host starved by other (real-time) processes
@pytest.mark.timeout(900)
def test_random_family_identified_through_bags_with_decoy_and_lost_cycles(tmp_path):
    seed = _seed()
    replay = f"replay with SEAFORCE_ID_SEED={seed}"
    outs = [tmp_path / f"params_{i}.yaml" for i in range(N_DRAWS)]
    # the draws and their bags are independent: one per core (pytest itself runs on one)
    with concurrent.futures.ProcessPoolExecutor(
            max_workers=min(2, os.cpu_count() or 1),
            mp_context=multiprocessing.get_context("forkserver")) as pool:
        draws = list(pool.map(_draw, [seed] * N_DRAWS, range(N_DRAWS)))
        # the decoy: another plant's chirp, the same messages
        bags = list(pool.map(_bag, [tmp_path / f"bag_{i}" for i in range(N_DRAWS)],
                             [d[2] for d in draws], [draws[(i + 1) % N_DRAWS][2]
                                                     for i in range(N_DRAWS)],
                             [d[3] for d in draws]))
    results = _identify_all(bags, outs, tmp_path)

    omega = np.logspace(math.log10(BAND[0]), math.log10(BAND[1]), 60)
    lines, failing, gross = [], [], []
    for i, ((plant, dahl, data, keep), (code, text)) in enumerate(zip(draws, results)):
        assert code == 0, f"draw {i} ({replay}): identify exited {code}:\n{text}"
        lost = int((~keep).sum())
        gaps = int(np.sum(np.diff(keep.astype(int)) == -1))
        assert f"{lost} cycles missing from the record" in text, (replay, text)
        assert f"in {gaps} gaps" in text, (replay, text)
        assert "+- 0 " not in text and "+- 0.0 " not in text, (replay, text)
        got = _plant(outs[i])
        err = {k: got[k] / plant[k] - 1.0 for k in KEYS}
        # the identified model against the true plant's analytic X_e/F_e (paper's model)
        d_true = transfer_functions(plant, omega)["D"]
        d_fit = transfer_functions(got, omega)["D"]
        d_err = float(np.max(np.abs(d_fit / d_true - 1.0)))
        bad = [k for k in KEYS if abs(err[k]) > _limit(k)]
        if bad:
            failing.append(i)
        gross += [(i, k) for k in KEYS if abs(err[k]) > 2 * _limit(k)]
        lines.append(f"draw {i}: " + " ".join(f"{k} {100 * err[k]:+.1f}%" for k in KEYS)
                     + f"; max |D_fit/D_true - 1| {100 * d_err:.1f}%; sigma {dahl['sigma']:.3g}"
                     f" F_c {dahl['coulomb_force']:.3g}" + (f"  FAIL {bad}" if bad else ""))
        if not bad:
            # every parameter within its limit keeps the endpoint response within ~20 %
            assert d_err < 0.2, f"draw {i} ({replay}): {lines[-1]}"
    report = "\n".join(lines)
    # (the seed at both ends of the message: a CI log that keeps only its tail still has it)
    assert not gross, f"{replay}: a limit missed by more than 2x {gross}\n{report}\n{replay}"
    assert len(failing) <= MAX_FAILING, f"{replay}: draws {failing} fail\n{report}\n{replay}"


def test_coulomb_like_hysteresis_is_reported_not_identified(tmp_path):
    """A hysteresis whose pre-sliding displacement F_c/sigma (1 urad) is far below the
    endpoint encoder's step (157 urad): sigma cannot be identified and is reported so (with
    the reason), never as ``value +- 0``; the fit falls back to the Coulomb limit, which keeps
    the linear parameters within their limits and still identifies F_c."""
    plant = dict(TABLE_I)
    dahl = {"sigma": 3.0e4, "coulomb_force": 0.03}
    data = simulate_chirp(plant, dahl, duration=120.0, seed=11)
    write_bag(tmp_path / "bag", ["pinch", "wrist"],
              {"pinch": data, "wrist": {k: np.zeros_like(v) for k, v in data.items()}})
    out = tmp_path / "p.yaml"
    (code, text), = _identify_all([tmp_path / "bag"], [out], tmp_path)
    assert code == 0, text
    assert "sigma: not identified (the search for sigma/F_c ran to its upper bound" in text
    assert "Coulomb limit" in text
    line = next(l for l in text.splitlines() if l.strip().startswith("F_c ="))
    value = float(line.split("=")[1].split("+-")[0])
    assert abs(value / dahl["coulomb_force"] - 1) < 0.1, line
    got = _plant(out)
    err = {k: got[k] / plant[k] - 1.0 for k in KEYS}
    assert all(abs(err[k]) < _limit(k) for k in KEYS), err


def test_second_simulator_agrees_with_solve_ivp():
    """The oracle's integrator against scipy's DOP853 (tight tolerances) on the same ODEs with
    the Dahl force as a fifth state, over a 1 s chirp segment (2-60 Hz, continuous force)
    without sensors."""
    import scipy.integrate
    from helpers.second_sim import DAHL, _matrices

    duration, f0, f1, dt = 1.0, 2.0, 60.0, 5e-4
    plant = dict(TABLE_I, endpoint_inertia=2 * TABLE_I["endpoint_inertia"])
    ours = simulate_chirp(plant, DAHL, duration=duration, start_hz=f0, end_hz=f1, tail=0.0,
                          hold=False, pressure_noise=0.0, pressure_bits=0, motor_counts=0,
                          endpoint_counts=0)
    a, b = _matrices(plant)
    rate = math.log(f1 / f0) / duration
    sigma, fc = DAHL["sigma"], DAHL["coulomb_force"]

    def rhs(t, z):
        fe = 0.3 * math.sin(2 * math.pi * f0 * math.expm1(rate * t) / rate)
        x, fd = z[:4], z[4]
        v = x[3]
        return np.r_[a @ x + b * (fe - fd), sigma * v * (1 - fd / fc * np.sign(v))]

    t = np.arange(ours["x"].size) * dt
    sol = scipy.integrate.solve_ivp(rhs, (0, t[-1]), np.zeros(5), t_eval=t, method="DOP853",
                                    rtol=1e-8, atol=1e-11)
    assert sol.success, sol.message
    scale = np.max(np.abs(sol.y[2]))
    assert np.max(np.abs(sol.y[2] - ours["x_e_true"])) < 2e-4 * scale
    assert np.max(np.abs(sol.y[4] - ours["f_d_true"])) < 0.02 * fc

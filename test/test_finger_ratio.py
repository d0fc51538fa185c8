"""The finger's four-bar ratio from a bonded-finger record
(:mod:`seaforce_ros.identification.finger_ratio`): against the analytic map on synthetic
records, against the nonlinear oracle (its own four-bar, integrator and sensors) on a random
draw of the plausible family, and through ``zwidth`` on a backdrive bag. Each run draws its
own seed (printed; ``SEAFORCE_FINGER_SEED=<seed>`` replays one)."""
import math
import os

import numpy as np
import pytest

from seaforce_ros import bags
from seaforce_ros.core.controller import ChannelController
from seaforce_ros.core.params import ControllerConfig, DahlParams, PlantParams
from seaforce_ros.identification.finger_ratio import (CONSISTENCY, MIN_RISE, MIN_STROKE,
                                                      fit_finger_ratio)
from seaforce_ros.tools import zwidth

from helpers.nonlinear_sim import STROKE, Unpowered, backdrive, linear_counterpart, ratio
from helpers.oracle_commissioning import draw

SEED = int(os.environ.get("SEAFORCE_FINGER_SEED", np.random.SeedSequence().entropy % 100000))
DT = 5e-4


def _synthetic(rng, c1, c2, half=0.5, k_s=10.0, seconds=14.0, noise=2e-5):
    """A bonded drive q = half sin(t) through the four-bar X_e = L (u + c1 u^2/2 + c2 u^3/3),
    u = q/L, the motor X = X_e - F_p/k_s with a pressure force that is not a function of q
    (a soft mode's: damping and the DOB's residual), the sensors' noise on each."""
    t = np.arange(0.0, seconds, DT)
    q = half * np.sin(t)
    u = q / STROKE
    xe = STROKE * (u + c1 * u * u / 2.0 + c2 * u ** 3 / 3.0)
    f_p = 0.05 * np.cos(t) + 0.02 * np.sin(2.3 * t + rng.uniform(0, 6))
    x = xe - f_p / k_s
    return (q + noise * rng.standard_normal(t.size), x + noise * rng.standard_normal(t.size),
            f_p + 5e-4 * rng.standard_normal(t.size))


def test_the_analytic_four_bar_is_recovered():
    """Invariant: on records of the four-bar's model, any c_1, c_2 of the plausible range
    (c_2 0.05-0.15, |c_1| <= c_2/3) and any hose stiffness, the fit gives the ratio at the
    stroke's ends within 0.002 of the map's and within 4 of its 1-sigmas, and calls it
    resolved."""
    rng = np.random.default_rng([SEED, 1])
    print(f"SEAFORCE_FINGER_SEED={SEED}")
    for _ in range(5):
        c2 = rng.uniform(0.05, 0.15)
        c1 = rng.uniform(-1.0, 1.0) * c2 / 3.0
        k_s = math.exp(rng.uniform(math.log(3.0), math.log(30.0)))
        fit = fit_finger_ratio(*_synthetic(rng, c1, c2, k_s=k_s), DT)
        assert fit.resolved, (c1, c2, fit.line())
        # the fit's L is the record's largest |q| (0.5 rad here, to the noise), the ends the
        # stroke's
        assert fit.half_stroke == pytest.approx(0.5, abs=1e-3)
        assert fit.stroke == pytest.approx((-0.5, 0.5), abs=1e-3)
        assert fit.ends[0] == pytest.approx(1.0 - c1 + c2, abs=0.002), fit.line()
        assert fit.ends[1] == pytest.approx(1.0 + c1 + c2, abs=0.002), fit.line()
        assert abs(fit.c_2 - c2) < 4.0 * fit.sigma[1] + 1e-3, fit.line()
        assert fit.hose_stiffness == pytest.approx(k_s, rel=0.05)


def test_what_the_record_cannot_show_is_named():
    rng = np.random.default_rng([SEED, 2])
    # a constant ratio: not resolved, as constant
    fit = fit_finger_ratio(*_synthetic(rng, 0.0, 0.0), DT)
    assert not fit.resolved and "constant ratio" in fit.reason
    assert max(abs(e - 1.0) for e in fit.ends) < MIN_RISE
    # a stroke too short to show it
    fit = fit_finger_ratio(*_synthetic(rng, 0.0, 0.1, half=0.1), DT)
    assert not fit.resolved and f"under {2 * MIN_STROKE:g} rad" in fit.reason
    assert "not resolved" in fit.line()
    # a stiff mode: the motor stays, the hose takes the finger's motion
    q, x, f_p = _synthetic(rng, 0.0, 0.1)
    fit = fit_finger_ratio(q, 0.02 * x, f_p, DT)
    assert not fit.resolved and "soft mode" in fit.reason
    # a stroke that never passes the finger's centre (where r_0 is taken): its other end
    # would be extrapolated
    fit = fit_finger_ratio(0.3 + 0.5 * q, x, f_p, DT)
    assert not fit.resolved and "does not pass the finger's centre" in fit.reason
    # a finger that does not move while the motor does
    fit = fit_finger_ratio(np.full_like(q, 0.3), x, f_p, DT)
    assert not fit.resolved and "too short" in fit.reason
    # bad input: a clear reason, never an exception
    for args in ((q[:100], x[:100], f_p[:100], DT), (q, x[:-1], f_p, DT),
                 (np.where(np.arange(q.size) == 7, np.nan, q), x, f_p, DT), (q, x, f_p, 0.0),
                 (q, x, f_p, math.nan), (q, x, f_p, 0.1), (q, x, f_p, 1), (q, x, f_p, 5.0),
                 (q[:3000:300], x[:3000:300], f_p[:3000:300], 0.15)):
        fit = fit_finger_ratio(*args)
        assert not fit.resolved and fit.reason and math.isnan(fit.c_2), fit.reason


def test_a_motion_that_differs_between_the_strokes_directions_is_turned_away():
    """A deflection error that follows the motion's direction (a hose whose deflection is not
    F_p/k_s: here one rising with the stroke and the speed, its sign the motion's) makes the
    two directions disagree: not resolved, with both directions' ends."""
    rng = np.random.default_rng([SEED, 3])
    q, x, f_p = _synthetic(rng, 0.0, 0.1)
    speed = np.gradient(q, DT) / 0.5                     # -1..1
    fit = fit_finger_ratio(q, x + 0.01 * speed * (q / 0.5) ** 2, f_p, DT)
    assert not fit.resolved and "two directions" in fit.reason, fit.line()
    assert f"beyond {CONSISTENCY:g}" in fit.reason


@pytest.fixture(scope="module")
def oracle_draw():
    plant, dahl, effects = draw(np.random.default_rng([SEED, 4]))
    return plant, dahl, effects


@pytest.mark.parametrize("mode", ["passive", "dob_full_ff"])
def test_the_oracles_four_bar_from_a_bonded_drive(oracle_draw, mode, tmp_path, capsys):
    """The oracle's finger (every effect drawn) backdriven 0.5 rad at 1 rad/s, two periods,
    the motor off or in dob_full_ff on the true model: the ratio at the stroke's ends within
    0.005 of the oracle's r(q); its linear class: a constant ratio. ``zwidth`` prints the
    same from the bag."""
    plant, dahl, effects = oracle_draw
    where = f"SEAFORCE_FINGER_SEED={SEED}: {effects.describe()}"
    config = ControllerConfig(plant=PlantParams(**plant), dahl=DahlParams(**dahl),
                              allow_non_passive=True, mode="dob_full_ff")

    def controller():
        return Unpowered() if mode == "passive" else ChannelController(config, DT)

    rec = backdrive(plant, dahl, effects, controller(), 0.5, 1.0, periods=2, seed=SEED)
    fit = fit_finger_ratio(rec["x_e"], rec["x"], rec["f_p"], rec["dt"])
    truth = (ratio(fit.stroke[0], effects), ratio(fit.stroke[1], effects))
    assert fit.resolved, (fit.line(), where)
    for got, want in zip(fit.ends, truth):
        assert got == pytest.approx(want, abs=0.005), (fit.line(), truth, where)
    assert fit.half_stroke == pytest.approx(STROKE, abs=0.01)
    linear = backdrive(plant, dahl, linear_counterpart(effects), controller(), 0.5, 1.0,
                       periods=2, seed=SEED)
    flat = fit_finger_ratio(linear["x_e"], linear["x"], linear["f_p"], linear["dt"])
    assert not flat.resolved and "constant ratio" in flat.reason, (flat.line(), where)
    # through zwidth: the bag of the drive gives the same line
    path = tmp_path / "bag"
    bags.write_state_bag(path, ["pinch"], {"pinch": {k: rec[k] for k in
                                                     ("x", "v", "f_p", "f_a", "x_e", "f_e")}})
    code = zwidth.main([f"{mode}={path}", "--channel", "pinch", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0, out
    line = next(l for l in out.splitlines() if "finger ratio" in l)
    assert line.endswith("resolved") and "not resolved" not in line, line
    words = line.split()
    ends = (float(words[words.index("at") - 1]), float(words[words.index("rad,") + 1]))
    for got, want in zip(ends, truth):
        assert got == pytest.approx(want, abs=0.005), (line, truth, where)
    # a bag without the motor position still gives the impedance, and says why no ratio
    blind = {k: rec[k] for k in ("x", "v", "f_p", "f_a", "x_e", "f_e")}
    blind["x"] = np.full_like(rec["x"], np.nan)
    bags.write_state_bag(tmp_path / "blind", ["pinch"], {"pinch": blind})
    code = zwidth.main([f"{mode}={tmp_path / 'blind'}", "--channel", "pinch", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0 and "finger ratio: not fitted (x is NaN in every sample" in out, out
    assert "peak |F_e|" in out

"""Compensation on the richer model, judged on the nonlinear oracle (``helpers/nonlinear_sim.py``:
its own integrator and sensors, every effect drawn within its stated range) through the
project's own excitation job and analysis -- the goals of the nonlinear-plant issue on a
random draw of the family (each Table I parameter, sigma and F_c log-uniform in [0.5x, 2x],
every effect drawn). Each run draws its own seed (printed; ``SEAFORCE_COMPENSATION_SEED``
replays one).

On the draw and on the same plant with every effect off (the linear class), each commissioned:

* the nonlinear draw's model class is flagged and the controller's model takes the terms
  the record resolved (``plant_terms``), with the model class's error the margin takes cut to
  what the terms leave;
* ``dob_full_ff``'s rms |Z| at 1 rad/s within 3 dB of the linear class's, plus what the
  tuning predicts its larger margin costs (the richer model's residual misfit, which the
  margin takes, is larger than the linear class's, and the stroke terms have a margin of
  their own: seed 18 of the family, a diaphragm 33 % stiffer at 0.5 rad, its model within
  6 %, 4.4 dB stiffer, predicted 4.8; before the richer model it was 12-29 dB stiffer);
* the rms |Z| the analysis predicts for ``dob_full_ff`` at 1 rad/s (its backdrive simulated on
  the identified model, terms included) within 3 dB of the measured;
* with the tuned settings the free finger released anywhere on the +-0.45 rad stroke neither
  runs away nor oscillates, without tripping the monitor (the margins cover the model's
  errors, the unmodelled finger ratio and cogging included): it stays within its start + 0.1
  rad and in the last second of 6 s it is at rest or slides towards its rest, reversing at
  most once. (The better the compensation, the less there is to bring a free finger home: on
  an accurate model the Dahl hysteresis holds it near its start, it creeps, then breaks away
  and slides back -- on 3 of 10 draws the slide came between 5 and 11.25 s, at up to 0.53
  rad/s, once across rest to +0.15 rad; a limit cycle reverses several times a second.)

The gap's allowance is the tuning's predicted margin cost, the stroke margin's included
(:func:`seaforce_ros.commissioning.tuning._margin_cost`): on 22 draws (seeds 1-11, 16-26,
2026-12-05) the gap was -0.2 to +7.4 dB, within 3 dB on 15, the others within 3 dB of the
predicted extra margin (which was the larger by up to 5.7 dB); the rms prediction -2.8 to
+0.1 dB off.
"""
import math
import os

import numpy as np
import pytest

from helpers.nonlinear_sim import linear_counterpart
from helpers.oracle_commissioning import draw, excite, figures, release
from seaforce_ros.commissioning.analyse import AnalysisRequest, analyse
from seaforce_ros.core.params import ControllerConfig

SEED = int(os.environ.get("SEAFORCE_COMPENSATION_SEED",
                          np.random.SeedSequence().entropy % 100000))


def margin_cost(tuning):
    """What the feed-forward's margin costs ``dob_full_ff`` at 1 rad/s [dB] (the tuning's
    prediction: with the margin against without it)."""
    return float(np.interp(0.0, np.log(tuning.omega), tuning.margin_cost_db))


def _commission(plant, dahl, effects, seed):
    record = excite(plant, dahl, effects, seed=seed)
    return analyse(record, AnalysisRequest("sim", ControllerConfig()), None)


@pytest.fixture(scope="module")
def commissioned():
    print(f"SEAFORCE_COMPENSATION_SEED={SEED}")
    plant, dahl, effects = draw(np.random.default_rng([SEED, 0]))
    nonlinear = _commission(plant, dahl, effects, SEED)
    linear = _commission(plant, dahl, linear_counterpart(effects), SEED + 1)
    return plant, dahl, effects, nonlinear, linear


@pytest.mark.timeout(900)
def test_the_richer_model_brings_dob_full_ff_to_the_linear_class(commissioned):
    plant, dahl, effects, a, lin = commissioned
    where = f"seed {SEED}: {effects.describe()}"
    assert a.tuned and lin.tuned, (where, a.message, lin.message)
    assert not a.model_class.fits, where
    terms = a.tuning.config.plant_terms
    assert terms.hose or terms.stroke_stiffness, (where, a.model.lines)
    assert a.model.class_error < 0.5 * a.identification.misfit["port"], (where, a.model.lines)
    ff = figures(plant, dahl, effects, a.tuning.config, "dob_full_ff", 1.0, 0.5, SEED)
    ff_lin = figures(plant, dahl, linear_counterpart(effects), lin.tuning.config,
                     "dob_full_ff", 1.0, 0.5, SEED)
    gap = ff.z_rms_db - ff_lin.z_rms_db
    excess = margin_cost(a.tuning) - margin_cost(lin.tuning)
    assert gap < 3.0 + max(0.0, excess), (where, ff.z_rms_db, ff_lin.z_rms_db, excess,
                                          a.model.lines)
    predicted = a.backdrives.figures["dob_full_ff"][a.backdrives.omega.index(1.0)]
    assert predicted is not None
    assert abs(20.0 * math.log10(predicted.z_rms) - ff.z_rms_db) < 3.0, (
        where, 20.0 * math.log10(predicted.z_rms), ff.z_rms_db)


@pytest.mark.timeout(900)
@pytest.mark.parametrize("start", [-0.45, 0.45])
def test_the_tuned_free_finger_comes_to_rest_anywhere_on_the_stroke(commissioned, start):
    plant, dahl, effects, a, _ = commissioned
    rec = release(plant, dahl, effects, a.tuning.config.replace(mode="dob_full_ff"), start,
                  seconds=6.0, seed=SEED)
    where = f"seed {SEED}: {effects.describe()}"
    assert not rec["fallback"], (where, rec["fallback"])
    assert np.max(np.abs(rec["x_e"])) < abs(start) + 0.1, where
    n = int(1.0 / rec["dt"])
    last, x = rec["v_e"][-n:], rec["x_e"][-n - 1:]
    at_rest = float(np.sqrt(np.mean(last ** 2))) < 0.01
    sliding_home = _reversals(last, 0.01) <= 1 and abs(x[-1]) < abs(x[0])
    assert at_rest or sliding_home, (where, float(np.sqrt(np.mean(last ** 2))),
                                     _reversals(last, 0.01), x[0], x[-1])


def _reversals(v, floor):
    """How often ``v`` reverses between its half-cycles (the parts between its sign changes)
    whose peak speed exceeds ``floor`` (a slide with a blip of the hysteresis in it: none; a
    slide that overshoots rest and comes back: one; a limit cycle: several a second)."""
    edges = np.flatnonzero(np.diff(np.sign(v)) != 0) + 1
    signs = [np.sign(part[0]) for part in np.split(v, edges)
             if part.size and np.max(np.abs(part)) > floor]
    return sum(1 for a, b in zip(signs, signs[1:]) if a != b)

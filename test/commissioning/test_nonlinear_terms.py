"""The model class's verdict and the candidate nonlinear terms
(:mod:`seaforce_ros.commissioning.nonlinear_terms`, :func:`~seaforce_ros.commissioning.free_air.
model_class`), judged on the nonlinear oracle (``helpers/nonlinear_sim.py``: its own integrator
and sensors, each effect drawn within its stated range) through the project's own excitation
job and identification.

Randomised family: each Table I parameter, sigma and F_c log-uniform in [0.5x, 2x] and every
effect drawn (:func:`helpers.oracle_commissioning.draw`); each run draws its own seed (printed;
``SEAFORCE_TERMS_SEED=<seed>`` replays one). Two draws with the effects and one of the linear
class (the same plant with every effect off), the default 40 s excitation each:

* with the effects the verdict flags the model class (``bench/model_class.py``: 24 of 24
  draws, port misfits 7.4-44 % against at most 1.4 % on the linear class, threshold 2.5 %;
  a draw with the weakest hose losses flagged by the motor's misfit instead);
  the motor's Coulomb friction and cogging (its N too) and the hose's flow term are resolved
  (or, rarely -- the Coulomb friction on 1 draw in 90 -- found within its tolerance but
  turned away by the halves check, with that reason), every term said resolved is within
  its tolerance of the truth (the others -- the pressure and stroke terms where the record
  does not drive them far or another model error imitates them -- give their reason), and
  the linear parts the terms leave (m, b, k, b_s, k_s, m_e, b_e, k_e) are within their
  tolerance (5 %; b_s 15 %), where the linear fit's b_s is up to 300 % off; the finger
  ratio is never resolved, with the reason;
* on the linear class nothing is flagged, no term is resolved, and the port equation's b_s
  is within 5 % (at most 1.5 % over 30 draws of ``default_rng([s, 2])``; up to 6.2 % with
  the friction path at 100 Hz).

Also the selection's statistics on synthetic regressions with correlated noise: the
information criterion picks the term that is there and leaves the one that is not, and the
Newey-West 1-sigma is the spread over repeated draws (within 35 %).
"""
import math
import os

import numpy as np
import pytest

from helpers.nonlinear_sim import STROKE
from helpers.oracle_commissioning import draw, excite, identify
from seaforce_ros.commissioning import nonlinear_terms as nt
from seaforce_ros.commissioning.analyse import model_class_stage

SEED = int(os.environ.get("SEAFORCE_TERMS_SEED", np.random.SeedSequence().entropy % 100000))
def _run(index, effects):
    rng = np.random.default_rng([SEED, index])
    plant, dahl, drawn = draw(rng, effects)
    record = excite(plant, dahl, drawn, seed=index)        # the default 40 s excitation
    ident = identify(record)
    verdict, terms = model_class_stage(record, ident)
    return plant, dahl, drawn, ident, verdict, terms


@pytest.fixture(scope="module")
def family():
    print(f"SEAFORCE_TERMS_SEED={SEED}")
    return [_run(0, True), _run(1, True), _run(2, False)]


def _truth(plant, e):
    return {"motor_coulomb": e.motor_coulomb, "cogging": e.cogging,
            "hose_flow": plant["hose_damping"] / e.hose_flow,
            "hose_pressure": e.hose_pressure * plant["hose_stiffness"] ** 2 / 2.0,
            "stroke_asymmetry": plant["endpoint_stiffness"] * e.stroke_asymmetry / STROKE,
            "stroke_stiffness": plant["endpoint_stiffness"] * e.stroke_stiffness / STROKE ** 2}


#: Tolerances of the resolved terms (relative), from the family itself: over 90 draws with
#: the effects (``default_rng([s, 1])``, s = 1..90, 2026-12-05, the port's search taking
#: the Dahl shape sigma/F_c) every draw was flagged, the motor's Coulomb friction resolved
#: on 89 (the 90th turned away by the halves check, 0.0 % off) and its cogging on all, the
#: hose's flow term on all; the resolved terms' errors were: Coulomb and cogging within
#: 1 %, the flow term within 1 %, the pressure term -14 to +5 % (resolved on 86; the others
#: turned away by the halves), k_2 -9 to +6 % (on 55), k_3 -15 to +8 % (on 90). (Before the
#: search took sigma/F_c -- the linear fit's sigma, -52..+44 % off, held fixed -- the
#: pressure term was -11 to +201 % on 30 of these draws, k_3 -35 to +8 %, and the flow
#: term was once turned away at -87 %: the tolerances were 2-4x wider.) The tolerances are
#: about twice the largest error seen.
TOLERANCE = {"motor_coulomb": 0.1, "cogging": 0.1, "hose_flow": 0.1,
             "hose_pressure": 0.35, "stroke_asymmetry": 0.2, "stroke_stiffness": 0.3}
#: ... and of the linear parts beside them: over the same 90 draws b_s within 7.1 % (the one
#: the flow term trades against), every other within 1.4 %
LINEAR_TOLERANCE = {"motor_inertia": 0.05, "motor_damping": 0.05, "motor_stiffness": 0.05,
                    "hose_damping": 0.15, "hose_stiffness": 0.05, "endpoint_inertia": 0.05,
                    "endpoint_damping": 0.05, "endpoint_stiffness": 0.05}


def test_with_the_effects_the_class_is_flagged_and_the_terms_resolved(family):
    for plant, dahl, e, ident, verdict, terms in family[:2]:
        where = f"seed {SEED}: {e.describe()}\n" + "\n".join(terms.lines())
        assert not verdict.fits and "does not describe this gripper" in verdict.warning, where
        # flagged by an equation's misfit (the port's on all but the weakest hose losses:
        # seed 78340's first draw, its damping doubling only at 2.95 rad/s, had the port at
        # 2.1 % and the motor at 3.3 %, its threshold 3 %)
        assert any(verdict.misfit[k] > verdict.threshold[k] for k in verdict.misfit), where
        assert verdict.terms == terms.lines()
        truth = _truth(plant, e)
        # the terms every draw has in measurable size: resolved, or chosen, their value
        # within the tolerance, and turned away by the halves check with that reason (the
        # motor's Coulomb friction on seed 78340's first draw: 0.00997 and 0.00187 +- 0.0012
        # N m, the second half above the motor equation's 10 Hz band; 1 of the 90 draws)
        for key in ("motor_coulomb", "cogging", "hose_flow"):
            term = terms.term(key)
            if not term.resolved:
                assert "two halves of the record" in term.reason, (key, where)
                tol = TOLERANCE[key]
                low, high = tol if isinstance(tol, tuple) else (-tol, tol)
                assert low < term.value / truth[key] - 1.0 < high, (key, where)
        for term in terms.resolved():
            # how far the halves took it: measured for every resolved term (the stroke
            # terms' margin takes it)
            assert math.isfinite(term.spread) and term.spread >= 0.0, (term, where)
            tol = TOLERANCE[term.key]
            low, high = tol if isinstance(tol, tuple) else (-tol, tol)
            assert low < term.value / truth[term.key] - 1.0 < high, \
                (term.key, term.value, truth[term.key], where)
        assert f"N = {e.cogging_periods} periods/rev" in terms.term("cogging").extra, where
        finger = terms.term("finger_ratio")
        assert not finger.resolved and "bonded-finger" in finger.reason
        for term in terms.terms:
            assert term.resolved or term.reason, term
        # the linear parts with the terms: the small-signal plant
        linear = {k: v for eq in terms.equations.values() for k, (v, _) in eq.linear.items()}
        for key, tol in LINEAR_TOLERANCE.items():
            assert abs(linear[key] / plant[key] - 1.0) < tol, (key, linear[key], where)


def test_on_the_linear_class_nothing_is_flagged_or_resolved(family):
    plant, dahl, e, ident, verdict, terms = family[2]
    where = f"seed {SEED}\n" + "\n".join(terms.lines())
    assert verdict.fits and not verdict.warning, where
    assert terms.resolved() == [], where
    linear = terms.equations["port"].linear
    assert abs(linear["hose_damping"][0] / plant["hose_damping"] - 1.0) < 0.05, where


def _synthetic(rng, n=4000, rho=0.8, with_term=True):
    """y = 2 a + 0.5 b (+ 0.3 c) + AR(1) noise; a candidate d that is not there."""
    cols = {k: rng.standard_normal(n) for k in "abcd"}
    e = np.empty(n)
    e[0] = 0.0
    w = rng.standard_normal(n)
    for i in range(1, n):
        e[i] = rho * e[i - 1] + w[i]
    y = 2.0 * cols["a"] + 0.5 * cols["b"] + (0.3 * cols["c"] if with_term else 0.0) + 0.5 * e
    return y, cols


def test_the_criterion_picks_what_is_there_and_the_sigma_is_the_spread():
    rng = np.random.default_rng(7)
    values, sigmas = [], []
    for _ in range(60):
        y, cols = _synthetic(rng)
        sel = nt._select(y, cols, ["a", "b"], {"c": ["c"], "d": ["d"]})
        assert sel.chosen == ["c"]
        v, s = nt._coef(sel.final, "c")
        values.append(v)
        sigmas.append(s)
        assert sel.bic_change["d"] > 0.0 > sel.bic_change["c"]
    spread = float(np.std(values))
    assert abs(np.mean(values) - 0.3) < 3 * spread / math.sqrt(len(values))
    assert float(np.median(sigmas)) == pytest.approx(spread, rel=0.35)
    # without the term, the criterion does not take it
    y, cols = _synthetic(rng, with_term=False)
    assert nt._select(y, cols, ["a", "b"], {"c": ["c"], "d": ["d"]}).chosen == []


def test_a_term_negative_where_every_grippers_is_positive_is_not_resolved():
    """A chosen term far from zero whose sign no gripper has (a diaphragm that softens
    towards its ends) is not resolved, with that reason; the same term positive is."""
    from seaforce_ros.commissioning.nonlinear_terms import PHYSICAL_SIGN
    rng = np.random.default_rng(5)
    n = 4000
    base = rng.standard_normal(n)
    for sign in (-1.0, 1.0):
        x3 = rng.standard_normal(n)
        y = 2.0 * base + sign * 0.5 * x3 + 0.01 * rng.standard_normal(n)
        cols = {"k_e": base, "x3": x3}
        sel = nt._select(y, cols, ["k_e"], {"stroke_stiffness": ["x3"]})
        term = nt._term("stroke_stiffness", "endpoint", "k_3", "N m/rad^3", sel, y, cols, ["x3"])
        assert term.value == pytest.approx(sign * 0.5, abs=0.01)
        if sign < 0:
            assert not term.resolved and PHYSICAL_SIGN["stroke_stiffness"] in term.reason
            assert "negative" in term.line()
        else:
            assert term.resolved, term.reason
            assert term.spread < 0.05          # both halves give 0.5


def test_a_margined_term_whose_halves_disagree_is_used_with_their_spread(monkeypatch):
    """A stroke term whose halves give 0.3 and 0.7 (beyond the halves check, both positive
    and far from zero) is not resolved but used (the controller's refit has it, and its
    spread is what the margin takes); the same record's term under a key without a margin
    of its own (the hose's) is not used; halves of opposite signs are not used either."""
    # (off by default, MARGINED empty: the mechanism, switched on)
    assert nt.MARGINED == ()
    monkeypatch.setattr(nt, "MARGINED", ("stroke_asymmetry", "stroke_stiffness"))
    rng = np.random.default_rng(7)
    n = 4000
    base = rng.standard_normal(n)
    x3 = rng.standard_normal(n)
    for first, second, key, used in ((0.3, 0.7, "stroke_stiffness", True),
                                     (0.3, 0.7, "hose_pressure", False),
                                     (-0.2, 0.8, "stroke_stiffness", False)):
        c = np.where(np.arange(n) < n // 2, first, second)
        y = 2.0 * base + c * x3 + 0.01 * rng.standard_normal(n)
        cols = {"k_e": base, "x3": x3}
        sel = nt._select(y, cols, ["k_e"], {key: ["x3"]})
        term = nt._term(key, "endpoint", "k_3", "N m/rad^3", sel, y, cols, ["x3"])
        assert not term.resolved and "two halves" in term.reason, term
        assert term.sized_by_spread is used and term.used is used, term
        # (the halves split where the target's energy is half spent, not at n/2)
        assert nt.CONSISTENCY < term.spread < abs(second - first) / abs(term.value), term
        model, _ = nt._resolved_model(y, cols, sel, [term], {"endpoint_stiffness": "k_e"},
                                      {key: "x3"})
        assert (key in model) is used
        if used:
            assert "in its margin" in term.reason
            assert model[key][0] == pytest.approx(term.value, rel=0.01)


def test_a_search_far_off_is_started_again_and_the_best_kept_with_its_jacobian():
    """The port search's restart (:func:`nt._best_restart`, taken when the first search's
    misfit exceeds PORT_RESTART_MISFIT): a stub search whose misfit depends on where m_e
    starts; the lowest misfit of the first and the restarts wins, and the Jacobian and
    residual left for the 1-sigmas are that search's, not the last one run."""
    y = np.ones(10)
    first = np.log([1e-3, 0.03, 0.06, 0.03, 400.0])
    last = {}
    started = []

    def search(start):
        started.append(float(np.exp(start[0])))
        misfit = 0.01 if np.exp(start[0]) < 1e-3 else 0.3
        last["resid"] = misfit * y
        last["jac"] = np.full((10, 5), misfit)
        return start + misfit
    last.update(resid=0.2 * y, jac=np.full((10, 5), 0.2))
    z = nt._best_restart(first + 0.2, first, search, last, y)
    assert started == pytest.approx([1e-3 / 3.0, 3e-3])
    assert nt._misfit_of(last["resid"], y) == pytest.approx(0.01)
    assert np.all(last["jac"] == 0.01)
    start = first.copy()
    start[0] += math.log(1.0 / 3.0)
    assert np.allclose(z, start + 0.01)
    # nothing better: the first search stays, with its own Jacobian
    last.update(resid=0.001 * y, jac=np.full((10, 5), 0.001))
    started.clear()
    z = nt._best_restart(first, first, search, last, y)
    assert len(started) == 2 and np.allclose(z, first) and np.all(last["jac"] == 0.001)
    assert nt._misfit_of(np.zeros(3), np.zeros(3)) == 0.0      # a target of zeros: no crash

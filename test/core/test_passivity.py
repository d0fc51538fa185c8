"""DOB admittance (eq. 25) and passivity (eq. 28): closed form vs numerical."""

import math

import numpy as np
import pytest

from seaforce_ros.core import ControllerConfig, DobParams, NonPassiveError, PlantParams
from seaforce_ros.core.passivity import (dob_admittance, dob_admittance_at,
                                         dob_admittance_coefficients,
                                         dob_passivity_bounds, dob_passivity_closed_form,
                                         numerical_passivity)

TABLE_I = PlantParams.table_i()


def test_m_n_bound_at_20_hz_cutoff():
    bounds = dob_passivity_bounds(TABLE_I, 2 * math.pi * 20)
    assert bounds.min_nominal_inertia == pytest.approx(8.743e-4, abs=5e-8)
    assert bounds.max_nominal_stiffness == pytest.approx(TABLE_I.motor_stiffness)


def test_m_n_bound_negative_at_20_rad_s():
    bounds = dob_passivity_bounds(TABLE_I, 20.0)
    assert bounds.min_nominal_inertia < 0.0
    assert bounds.min_nominal_inertia == pytest.approx(1.1116e-3 - 2.9814e-2 / 20)
    # hence any m_n >= 0 is accepted, including the pure integral controller m_n = 0
    cfg = ControllerConfig(mode="dob", dob=DobParams(cutoff=20.0, nominal_inertia=0.0))
    assert cfg.dob.nominal_inertia == 0.0


def test_default_nominal_inertia_is_motor_inertia_and_passive():
    cfg = ControllerConfig(mode="dob")
    assert cfg.dob.nominal_inertia == TABLE_I.motor_inertia
    assert cfg.dob.cutoff == pytest.approx(2 * math.pi * 20)


def test_admittance_matches_definition():
    """Eq. 25 equals 1/((1-Q) P^-1 + Q P_n^-1) at arbitrary frequencies."""
    dob = DobParams(cutoff=90.0, nominal_inertia=1.3e-3, nominal_damping=0.002,
                    nominal_stiffness=0.05)
    w = np.logspace(-2, 4, 50)
    s = 1j * w
    p = TABLE_I
    q = dob.cutoff / (s + dob.cutoff)
    p_inv = p.motor_inertia * s + p.motor_damping + p.motor_stiffness / s
    pn_inv = dob.nominal_inertia * s + dob.nominal_damping + dob.nominal_stiffness / s
    expected = 1.0 / ((1 - q) * p_inv + q * pn_inv)
    np.testing.assert_allclose(dob_admittance_at(p, dob, w), expected, rtol=1e-10)
    tf = dob_admittance(p, dob)
    np.testing.assert_allclose(np.asarray(tf(s[7])).ravel()[0], expected[7], rtol=1e-9)


def test_table_i_default_dob_numerically_passive():
    p = TABLE_I
    num, den = dob_admittance_coefficients(p.motor_inertia, p.motor_damping,
                                           p.motor_stiffness, 2 * math.pi * 20,
                                           p.motor_inertia, 0.0, 0.0)
    verdict = numerical_passivity(num, den)
    assert verdict.passive, verdict.reason
    assert verdict.min_real_part >= 0.0


def test_integral_force_feedback_is_not_passive_at_20_hz():
    """m_n = 0 (plain integral force feedback) violates eq. 28 at lambda = 2 pi 20."""
    p = TABLE_I
    num, den = dob_admittance_coefficients(p.motor_inertia, p.motor_damping,
                                           p.motor_stiffness, 2 * math.pi * 20, 0.0, 0.0, 0.0)
    verdict = numerical_passivity(num, den)
    assert not verdict.passive
    with pytest.raises(NonPassiveError) as info:
        ControllerConfig(mode="dob", dob=DobParams(nominal_inertia=0.0))
    assert "0.000874" in str(info.value) and "allow_non_passive" in str(info.value)
    assert info.value.name == "dob.nominal_inertia" and info.value.value == 0.0
    assert "0.000874" in info.value.bound


def _random_sets(rng, n):
    """Random plants and DOB settings, a third of them within 1e-6..1e-2
    (relative) of one of the eq. 28 bounds, on either side."""
    sets = []
    for i in range(n):
        m = 10 ** rng.uniform(-4, -2)
        b = 10 ** rng.uniform(-3.5, 0)
        k = 0.0 if rng.random() < 0.1 else 10 ** rng.uniform(-3, 1.5)
        lam = 10 ** rng.uniform(0.5, 3.5)
        m_min = m - b / lam
        b_n = rng.uniform(-1.5, 1.0) * (k / lam + 0.1 * b)
        k_max = k + lam * b_n
        near = i % 3
        side = rng.choice([-1.0, 1.0])
        eps = 10 ** rng.uniform(-6, -2)
        m_n = m_min + rng.uniform(-0.5, 1.0) * m
        k_n = rng.uniform(-0.1, 1.5) * abs(k_max)
        if near == 1:
            m_n = m_min + side * eps * m
        elif near == 2:
            k_n = k_max + side * eps * max(abs(k_max), 1e-3)
            if rng.random() < 0.2:
                k_n = side * eps      # near k_n = 0
        if rng.random() < 0.05:
            k_n = 0.0
        sets.append((m, b, k, lam, m_n, b_n, k_n))
    return sets


def test_closed_form_agrees_with_numerical_verdict_on_random_sets():
    rng = np.random.default_rng(20240603)
    sets = _random_sets(rng, 1200)
    n_passive = 0
    n_near = 0
    for params in sets:
        m, b, k, lam, m_n, b_n, k_n = params
        closed = dob_passivity_closed_form(*params)
        verdict = numerical_passivity(*dob_admittance_coefficients(*params))
        assert closed == verdict.passive, (params, verdict.reason)
        n_passive += closed
        m_min, k_max = m - b / lam, k + lam * b_n
        if abs(m_n - m_min) < 1e-2 * m or abs(k_n - k_max) < 1e-2 * max(abs(k_max), 1e-3):
            n_near += 1
    # both verdicts occur often, and many sets sit near a bound
    assert 200 < n_passive < 1000
    assert n_near >= 300

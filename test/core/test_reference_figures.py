"""The reference figures computed from Table I (passive impedance, poles, low-frequency stiffness, DOB bound)."""

import numpy as np
import pytest

from seaforce_ros.core import PlantParams
from seaforce_ros.core.analysis import (eq22_stiffness, eq23_stiffness, eq24_stiffness,
                                        force_feedback_comparison, frequency_response,
                                        low_frequency_stiffness_external,
                                        low_frequency_stiffness_internal,
                                        low_frequency_stiffness_passive, magnitude_db,
                                        max_passive_external_gain, zwidth_db)
from seaforce_ros.core.passivity import numerical_passivity
from seaforce_ros.core.plant import PlantModel

TABLE_I = PlantParams.table_i()


@pytest.fixture
def model():
    return PlantModel(TABLE_I)


@pytest.mark.parametrize("omega, expected_db", [
    (0.1, 7.08), (1.0, -12.66), (3.0, -20.51), (10.0, -23.92), (100.0, -8.13)])
def test_passive_endpoint_impedance(model, omega, expected_db):
    z = frequency_response(model.passive_impedance(), [omega])[0]
    assert magnitude_db(z) == pytest.approx(expected_db, abs=0.05)


def test_endpoint_poles(model):
    poles = model.endpoint_poles()
    expected = np.sort_complex(np.array([-30.42 + 171.15j, -30.42 - 171.15j, -31.09, -4.04]))
    np.testing.assert_allclose(poles, expected, atol=0.01)
    # the python-control object has the same poles, 2 zeros and 4 poles
    tf = model.endpoint_system()
    np.testing.assert_allclose(np.sort_complex(tf.poles()), expected, atol=0.01)
    assert len(tf.zeros()) == 2


def test_fig4_plants_are_consistent(model):
    """X_e/F_e equals the composition of the three sub-plants of Fig. 4."""
    w = np.logspace(-1, 3, 40)
    s = 1j * w
    xm = frequency_response(model.motor_plant(), w)          # X/F_p
    xe = frequency_response(model.endpoint_plant(), w)       # X_e/(F_e - F_p)
    ks_num, _ = model.hose_plant()
    hose = np.polyval(ks_num.coeffs, s)                      # F_p/(X_e - X)
    # F_p = hose (X_e - xm F_p)  ->  F_p = hose/(1 + hose xm) X_e
    fp_per_xe = hose / (1.0 + hose * xm)
    xe_per_fe = 1.0 / (1.0 / xe + fp_per_xe)
    np.testing.assert_allclose(frequency_response(model.endpoint_system(), w),
                               xe_per_fe, rtol=1e-9)
    # Z = F_e/V_e = 1/(s X_e/F_e)
    np.testing.assert_allclose(frequency_response(model.passive_impedance(), w),
                               1.0 / (s * xe_per_fe), rtol=1e-9)


def test_low_frequency_stiffness(model):
    assert low_frequency_stiffness_passive(TABLE_I) == pytest.approx(0.2259, abs=5e-5)
    assert eq22_stiffness(TABLE_I) == pytest.approx(0.1453, abs=5e-5)
    assert low_frequency_stiffness_internal(TABLE_I, 1.0) == pytest.approx(
        eq22_stiffness(TABLE_I), rel=1e-12)
    # the transfer functions agree: s Z(s) at a very low frequency
    w = 1e-6
    assert abs(1j * w * frequency_response(model.passive_impedance(), [w])[0]) == \
        pytest.approx(0.2259, abs=5e-5)
    assert abs(1j * w * frequency_response(model.internal_force_feedback_impedance(1.0),
                                           [w])[0]) == pytest.approx(0.1453, abs=5e-5)
    k_ext = 0.7
    assert abs(1j * w * frequency_response(model.external_force_feedback_impedance(k_ext),
                                           [w])[0]) == pytest.approx(
        low_frequency_stiffness_external(TABLE_I, k_ext), rel=1e-6)


def test_eq23_eq24_limits():
    """Eq. 22 tends to eq. 23 for k >> k_s, k_e and to eq. 24 for k_s >> k, k_e."""
    stiff_motor = TABLE_I.scaled(motor_stiffness=1e8)
    assert eq22_stiffness(stiff_motor) == pytest.approx(eq23_stiffness(stiff_motor), rel=1e-4)
    stiff_hose = TABLE_I.scaled(hose_stiffness=1e8)
    assert eq22_stiffness(stiff_hose) == pytest.approx(eq24_stiffness(stiff_hose), rel=1e-4)
    # and these differ markedly for Table I itself
    assert eq23_stiffness(TABLE_I) > 10 * eq22_stiffness(TABLE_I)


def test_internal_force_feedback_k1_is_passive(model):
    z = model.internal_force_feedback_impedance(1.0)
    assert numerical_passivity(z.den[0][0], z.num[0][0]).passive


def test_fig7_external_vs_internal_force_feedback():
    w = np.logspace(-1, 1.5, 30)          # low-mid frequencies
    a = force_feedback_comparison(TABLE_I, w)
    b = force_feedback_comparison(TABLE_I.scaled(endpoint_damping=10.0), w)
    c = force_feedback_comparison(TABLE_I.scaled(endpoint_inertia=10.0), w)
    # the maximum passive gain is a true boundary: slightly above it is not passive
    for plant in (TABLE_I, TABLE_I.scaled(endpoint_damping=10.0),
                  TABLE_I.scaled(endpoint_inertia=10.0)):
        k = max_passive_external_gain(plant)
        m = PlantModel(plant)
        ok = m.external_force_feedback_impedance(k)
        bad = m.external_force_feedback_impedance(k * 1.01 + 1e-4)
        assert numerical_passivity(ok.den[0][0], ok.num[0][0]).passive
        assert not numerical_passivity(bad.den[0][0], bad.num[0][0]).passive
    # A: external outperforms internal at low-mid frequencies
    assert np.all(np.abs(a["external"]) < np.abs(a["internal"]))
    # B (10x b_e): internal force feedback is nearly ineffective, external is not
    gain_int_b = magnitude_db(b["passive"]) - magnitude_db(b["internal"])
    gain_ext_b = magnitude_db(b["passive"]) - magnitude_db(b["external"])
    assert np.all(gain_int_b[w > 1.5] < 1.5) and np.all(gain_ext_b[w > 1.5] > 4.0)
    # C (10x m_e): internal outperforms external below the (now low) endpoint
    # resonance; above it the inertia dominates both
    low = w <= 5.0
    assert np.all(np.abs(c["internal"])[low] < np.abs(c["external"])[low])


def test_zwidth_db():
    assert zwidth_db(0.01, 10.0) == pytest.approx(60.0)
    np.testing.assert_allclose(zwidth_db(np.array([1.0, 1j]), np.array([10.0, -100.0])),
                               [20.0, 40.0])

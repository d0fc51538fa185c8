"""Impedance-from-time-series helpers and model impedances."""

import math

import numpy as np
import pytest

from seaforce_ros.core import DobParams, PlantParams
from seaforce_ros.core.analysis import (fourier_coefficient, frequency_response,
                                        impedance_from_position, impedance_from_series,
                                        magnitude_db)
from seaforce_ros.core.passivity import dob_admittance_at
from seaforce_ros.core.plant import PlantModel

TABLE_I = PlantParams.table_i()


def test_fourier_coefficient_of_a_sine_after_transient():
    dt, w = 5e-4, 3.0
    t = np.arange(40000) * dt
    y = 0.7 * np.sin(w * t + 0.4) + 5.0 * np.exp(-t / 0.2) + 0.1 * np.sin(7.3 * w * t)
    c = fourier_coefficient(y, w, dt, settle_time=5.0)
    assert abs(c) == pytest.approx(0.7, rel=2e-3)
    assert np.angle(c) == pytest.approx(0.4 - math.pi / 2, abs=2e-3)
    with pytest.raises(ValueError):
        fourier_coefficient(y[:100], w, dt)


def test_impedance_from_series_recovers_a_known_impedance():
    dt, w = 5e-4, 2.0
    t = np.arange(30000) * dt
    z_true = 0.3 - 0.8j
    v = 0.5 * np.cos(w * t)
    f = 0.5 * np.real(z_true * np.exp(1j * w * t))
    x = 0.5 / w * np.sin(w * t)
    assert impedance_from_series(f, v, w, dt) == pytest.approx(z_true, rel=1e-3)
    assert impedance_from_position(f, x, w, dt) == pytest.approx(z_true, rel=1e-3)


def test_dob_endpoint_impedance_consistent_with_eq25():
    """The motor-port stiffness used for the endpoint impedance is s/Y(s)."""
    dob = DobParams(cutoff=2 * math.pi * 20, nominal_inertia=TABLE_I.motor_inertia)
    model = PlantModel(TABLE_I)
    w = np.logspace(-1, 3, 30)
    num, den = model.port_dob(dob)
    k_port = np.polyval(num.coeffs, 1j * w) / np.polyval(den.coeffs, 1j * w)
    np.testing.assert_allclose(k_port, 1j * w / dob_admittance_at(TABLE_I, dob, w), rtol=1e-9)
    # the DOB lowers |Z| below the passive curve at low frequencies,
    # the linear feed-forward lowers it further
    zp = frequency_response(model.passive_impedance(), w)
    zd = frequency_response(model.dob_impedance(dob), w)
    zl = frequency_response(model.dob_impedance(dob, linear_ff=True), w)
    low = w < 10
    assert np.all(np.abs(zd[low]) < np.abs(zp[low]))
    assert np.all(np.abs(zl[low]) < np.abs(zd[low]))
    # linear ff: DC stiffness fully cancelled (|Z| -> 0 faster than 1/w)
    assert abs(1j * 1e-4 * frequency_response(model.dob_impedance(dob, True), [1e-4])[0]) < 1e-4


def test_motor_port_impedance_hold_is_large():
    model = PlantModel(TABLE_I)
    w = np.array([1.0, 3.0])
    z_port = frequency_response(model.motor_port_impedance(model.port_pd(150.0, 0.5)), w)
    z_end = frequency_response(model.hold_impedance(150.0, 0.5), w)
    # rigid-hose maximum (F_p/V) exceeds the endpoint maximum through the hose
    assert np.all(magnitude_db(z_port) > magnitude_db(z_end) + 10)

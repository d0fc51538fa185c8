"""The impedance figures of a backdrive (:func:`seaforce_ros.core.analysis.impedance_figures`)
against forces whose fundamental, rms, harmonics and peaks are known in closed form.

Each case is drawn at random (amplitude, frequency, phase, magnitudes, the record's length and
a transient before ``settle_time``): a linear impedance (no distortion; rms equals the
fundamental), Coulomb friction F_c sgn(V) (fundamental 4 F_c/pi, k-th odd harmonic
4 F_c/(k pi), rms F_c, distortion sqrt(pi^2/8 - 1)), a quadratic damper c V|V| (harmonics
8/(3 pi), 8/(15 pi), 8/(105 pi) of c V0^2) and a hardening spring k x (1 + a (x/L)^2) whose
peaks over the stroke and within the centre band are the spring's at those positions.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seaforce_ros.core.analysis import (AWAY_SHARE, CENTRE_BAND, HARMONICS, impedance_figures,
                                        impedance_from_position)

DT = 5e-4
DRAWS = 6


def _case(rng, omega=None):
    """(omega, amplitude, phase, t, x, v, settle): a sine path after a decaying transient,
    whole and fractional periods at random."""
    w = float(rng.uniform(0.5, 10.0)) if omega is None else omega
    a = float(rng.uniform(0.1, 0.6))
    phi = float(rng.uniform(0.0, 2.0 * math.pi))
    settle = float(rng.uniform(0.2, 1.0))
    periods = float(rng.uniform(1.0, 3.5))
    n = int((settle + periods * 2.0 * math.pi / w) / DT)
    t = np.arange(n) * DT
    x = a * np.sin(w * t + phi)
    v = a * w * np.cos(w * t + phi)
    transient = np.where(t < settle, np.exp(-t / (0.1 * settle)), 0.0)
    return w, a, phi, t, x, v, settle, transient


@pytest.mark.parametrize("seed", range(DRAWS))
def test_a_linear_impedance_has_no_distortion_and_rms_equals_fundamental(seed):
    rng = np.random.default_rng(seed)
    w, a, _, _, x, v, settle, transient = _case(rng)
    z = complex(rng.uniform(0.01, 1.0), rng.uniform(-1.0, 1.0))
    f = z.real * v - z.imag * w * x + 3.0 * transient + 0.2     # b V + (k/w) ... and a bias
    fig = impedance_figures(f, x, w, DT, settle)
    assert fig.z == pytest.approx(z, rel=1e-6)
    assert fig.z_rms == pytest.approx(abs(z), rel=1e-6)
    assert fig.distortion < 1e-5
    assert fig.amplitude == pytest.approx(a, rel=1e-9)
    # the fundamental agrees with the projection the project measured with so far
    zp = impedance_from_position(f, x, w, DT, settle)
    assert abs(fig.z - zp) < 0.01 * abs(z)


@pytest.mark.parametrize("seed", range(DRAWS))
def test_coulomb_friction(seed):
    rng = np.random.default_rng(100 + seed)
    w, a, _, _, x, v, settle, transient = _case(rng)
    fc = float(rng.uniform(0.005, 0.05))
    f = fc * np.sign(v) - 1.0 * transient
    fig = impedance_figures(f, x, w, DT, settle)
    v_rms = a * w / math.sqrt(2.0)
    # the fundamental: a damper 4 F_c/(pi A w), in phase with V
    assert fig.z.real == pytest.approx(4.0 * fc / (math.pi * a * w), rel=2e-3)
    assert abs(fig.z.imag) < 2e-3 * abs(fig.z)
    assert fig.z_rms == pytest.approx(fc / v_rms, rel=2e-3)
    for k in range(1, HARMONICS + 1):
        expected = 4.0 * fc / (k * math.pi) if k % 2 else 0.0
        assert fig.harmonics[k - 1] == pytest.approx(expected, abs=3e-3 * fc)
    assert fig.distortion == pytest.approx(math.sqrt(math.pi ** 2 / 8.0 - 1.0), rel=5e-3)
    assert fig.peak == pytest.approx(fc) and fig.peak_centre == pytest.approx(fc)
    # the rms impedance is larger than the fundamental's: it counts the harmonics
    assert fig.z_rms > abs(fig.z)


@pytest.mark.parametrize("seed", range(DRAWS))
def test_quadratic_damper(seed):
    rng = np.random.default_rng(200 + seed)
    w, a, _, _, x, v, settle, transient = _case(rng)
    c = float(rng.uniform(0.001, 0.1))
    f = c * v * np.abs(v) + 2.0 * transient
    fig = impedance_figures(f, x, w, DT, settle)
    v0 = a * w
    expected = {1: 8.0 / (3.0 * math.pi), 3: 8.0 / (15.0 * math.pi), 5: 8.0 / (105.0 * math.pi)}
    for k in range(1, HARMONICS + 1):
        assert fig.harmonics[k - 1] == pytest.approx(c * v0 ** 2 * expected.get(k, 0.0),
                                                     rel=1e-4, abs=1e-6 * c * v0 ** 2), k
    # rms of c V0^2 cos|cos| is c V0^2 sqrt(3/8)
    assert fig.z_rms == pytest.approx(c * v0 ** 2 * math.sqrt(3.0 / 8.0) / (v0 / math.sqrt(2)),
                                      rel=1e-4)


@pytest.mark.parametrize("seed", range(DRAWS))
def test_work_loop_peaks_of_a_hardening_spring(seed):
    rng = np.random.default_rng(300 + seed)
    w, a, _, _, x, v, settle, _ = _case(rng, omega=1.0)
    a_big = float(rng.uniform(0.3, 0.6))
    x = x * a_big / a
    k, rise, centre = float(rng.uniform(0.05, 0.5)), float(rng.uniform(0.1, 0.5)), \
        float(rng.uniform(-0.3, 0.3))
    spring = k * x * (1.0 + rise * (x / 0.5) ** 2)
    fig = impedance_figures(spring, x + centre, w, DT, settle)
    # the peak over the stroke at +-A, within the band at +-0.2 rad of the stroke's centre
    # (the samples come within a_big w DT of the band's edge)
    assert fig.peak == pytest.approx(k * a_big * (1 + rise * (a_big / 0.5) ** 2), rel=1e-4)
    edge = k * CENTRE_BAND * (1 + rise * (CENTRE_BAND / 0.5) ** 2)
    assert edge * (1 - 5 * a_big * w * DT / CENTRE_BAND) <= fig.peak_centre <= edge
    assert fig.peak_ratio == pytest.approx(fig.peak / fig.peak_centre)
    # the stroke without its ends: up to AWAY_SHARE of the half-stroke (within a sample)
    reach = AWAY_SHARE * a_big
    away = k * reach * (1 + rise * (reach / 0.5) ** 2)
    assert away * (1 - 5 * a_big * w * DT / reach) <= fig.peak_away <= away
    assert fig.peak_centre <= fig.peak_away <= fig.peak
    assert fig.away_ratio == pytest.approx(fig.peak_away / fig.peak_centre)


@settings(max_examples=300, deadline=None)
@given(omega=st.floats(0.3, 40.0), periods=st.integers(1, 3), settle_periods=st.floats(0.0, 2.0),
       dt=st.sampled_from([5e-4, 1e-3, 2e-3]))
def test_a_record_of_whole_periods_after_its_settle_is_measured_whole(omega, periods,
                                                                      settle_periods, dt):
    """Invariant: a record made as a backdrive makes one -- ``periods`` drive periods after
    ``settle_periods`` of them, the sum rounded to samples -- is measured, on its whole
    periods, for every frequency: no 'shorter than one period', and the fundamental of a
    linear impedance exact. (With the settle's end rounded up, one recorded period came out
    a sample short for about a quarter of the frequencies.)"""
    period = 2.0 * math.pi / omega
    n = int(round((periods + settle_periods) * period / dt))
    t = np.arange(n) * dt
    x = 0.3 * np.sin(omega * t)
    z = complex(0.2, -0.5)
    f = z.real * 0.3 * omega * np.cos(omega * t) - z.imag * omega * x
    fig = impedance_figures(f, x, omega, dt, settle_periods * period)
    assert fig.z == pytest.approx(z, rel=1e-6)


def test_refuses_what_it_cannot_measure():
    x = np.sin(np.arange(1000) * DT)
    with pytest.raises(ValueError, match="shorter than one period"):
        impedance_figures(x, x, 1.0, DT)
    with pytest.raises(ValueError, match="same one-dimensional shape"):
        impedance_figures(x[:-1], x, 1.0, DT)
    with pytest.raises(ValueError, match="> 0"):
        impedance_figures(x, x, -1.0, DT)

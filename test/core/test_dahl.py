"""Dahl hysteresis (eq. 14-15): exact per-step update."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from seaforce_ros.core import DahlParams, DahlState
from seaforce_ros.core.dahl import dahl_step

SIGMA, FC = 12.8, 0.032


def reference(force0, dx, n):
    """Integrate eq. 14 along a monotone path with a tight-tolerance ODE solver."""
    s = np.sign(dx)

    def rhs(_, f):
        u = max(1.0 - f[0] / FC * s, 0.0)
        return [s * SIGMA * u ** n]

    def saturated(_, f):          # u = 0: F_d = s F_c, and it stays there
        return 1.0 - f[0] / FC * s - 1e-13
    saturated.terminal = True
    sol = solve_ivp(rhs, (0.0, abs(dx)), [force0], rtol=1e-11, atol=1e-14,
                    method="LSODA", events=saturated)
    if sol.status == 1:
        return s * FC
    return sol.y[0, -1]


@pytest.mark.parametrize("n", [0.5, 1.0, 2.0, 3.0])
@pytest.mark.parametrize("force0", [-0.03, 0.0, 0.02])
@pytest.mark.parametrize("dx", [1e-4, -1e-3, 2e-3, -0.02])
def test_step_matches_ode_solution(n, force0, dx):
    assert dahl_step(force0, dx, SIGMA, FC, n) == pytest.approx(reference(force0, dx, n),
                                                                abs=1e-9)


def test_n1_matches_eq15_closed_form():
    # dF/dx = sigma (1 - F/F_c) for xdot > 0: F = F_c (1 - exp(-sigma x/F_c))
    x = 0.004
    assert dahl_step(0.0, x, SIGMA, FC, 1.0) == pytest.approx(FC * (1 - np.exp(-SIGMA * x / FC)),
                                                             rel=1e-12)


@pytest.mark.parametrize("n", [0.0, 0.5, 1.0, 2.0])
def test_never_overshoots_for_huge_steps(n):
    state = DahlState(DahlParams(SIGMA, FC, n))
    rng = np.random.default_rng(1)
    x = 0.0
    for dx in rng.normal(0.0, 10.0, 500):   # steps far beyond F_c/sigma = 2.5 mrad
        x += dx
        f = state.update(x)
        assert abs(f) <= FC * (1 + 1e-15)
    # a huge positive step saturates at +F_c (exponentially for n <= 1,
    # algebraically for n > 1)
    f = state.update(x + 100.0)
    assert FC * (1 - 1e-3) < f <= FC


def test_step_size_independence_for_monotone_path():
    """Exact update: one step or 1000 sub-steps of a monotone path give the same force."""
    for n in (0.5, 1.0, 2.5):
        a = DahlState(DahlParams(SIGMA, FC, n))
        b = DahlState(DahlParams(SIGMA, FC, n))
        a.update(-0.01)
        b.update(-0.01)
        a.update(0.003)
        for x in np.linspace(-0.01, 0.003, 1001)[1:]:
            b.update(float(x))
        assert a.force == pytest.approx(b.force, abs=1e-12)


def test_hysteresis_loop_and_slope_at_zero():
    """Quasi-static loop: initial slope sigma, saturation F_c, odd symmetry."""
    state = DahlState(DahlParams(SIGMA, FC, 1.0))
    assert state.update(1e-9) == pytest.approx(SIGMA * 1e-9, rel=1e-6)
    xs = 0.5 * np.sin(np.linspace(0, 4 * np.pi, 8001))
    forces = np.array([state.update(float(x)) for x in xs])
    second = slice(4000, None)
    up = np.diff(xs[second], prepend=xs[3999]) > 0
    # rising branch near x = 0 sits at -F_c + ..., clearly below the falling branch
    mid = np.abs(xs[second]) < 0.1
    assert np.all(forces[second][mid & up] > 0.99 * FC)
    assert np.all(forces[second][mid & ~up] < -0.99 * FC)


def test_zero_sigma_disables():
    state = DahlState(DahlParams(sigma=0.0))
    assert state.update(1.0) == 0.0

"""The controller's parts alone: endpoint observer, DOB, modes (the controller composes them)."""

import math

import pytest

from seaforce_ros.core import (DOB_MODES, MODES, ChannelController, ControllerConfig,
                               DahlParams, PlantParams, TargetParams)
from seaforce_ros.core.dahl import DahlState
from seaforce_ros.core.dob import DisturbanceObserver
from seaforce_ros.core.modes import MODE_TYPES, ReferenceMode, TorqueMode
from seaforce_ros.core.observer import EndpointObserver, hose_coefficients

DT = 5e-4
CONFIG = ControllerConfig(mode="dob_full_ff",
                          target=TargetParams(stiffness=2.0, damping=0.01, force=0.1))
PLANT = PlantParams.table_i()


def test_one_mode_class_per_mode_and_the_dob_modes_give_a_reference():
    assert tuple(MODE_TYPES) == MODES
    assert {n for n, cls in MODE_TYPES.items() if issubclass(cls, ReferenceMode)} \
        == set(DOB_MODES)
    assert all(issubclass(cls, TorqueMode) for n, cls in MODE_TYPES.items()
               if n not in DOB_MODES)
    assert {n for n, cls in MODE_TYPES.items() if cls.uses_feedforward} \
        == {"dob_linear_ff", "dob_full_ff", "impedance"}


@pytest.mark.parametrize("steps", [1, 3])
def test_dob_entry_is_bumpless(steps):
    dob = DisturbanceObserver(CONFIG.dob, DT)
    dob.enter(0.37, 0.05, 0.2, -0.4, 0.11, steps)
    assert dob.update(0.05, 0.2, -0.4, 0.11, steps) == pytest.approx(0.37, abs=1e-15)


@pytest.mark.parametrize("name", [n for n in MODES if n not in DOB_MODES and n != "passive"])
@pytest.mark.parametrize("full", [True, False])
def test_torque_modes_enter_from_the_applied_torque(name, full):
    mode = MODE_TYPES[name](CONFIG.replace(mode=name), DT)
    assert isinstance(mode, TorqueMode)
    if not full:        # a re-entry keeps targets captured at an earlier entry
        mode.enter(0.01, 0.0, 0.0, 1, -0.2, True)
        mode.update(0.03, 0.1, 0.05, 1)
        mode.interrupt()    # the plant replaced the torque (ChannelController.reenter)
    assert mode.enter(0.02, 0.3, -0.1, 1, 0.25, full) == pytest.approx(0.25, abs=1e-15)


def test_a_chirp_interrupted_before_its_clock_moved_re_enters_from_the_applied_torque():
    """Entered and interrupted in the same sample (a plant-side stop right at the entry):
    the re-entry is bumpless from the torque applied, as after any interruption (the
    property test over arbitrary states found the re-entry going on from its clock instead:
    1.6e-9 N m where 0 was applied)."""
    mode = MODE_TYPES["chirp"](CONFIG.replace(mode="chirp"), DT)
    mode.select()
    mode.enter(0.0, 0.0, 0.0, 1, -0.2, True)
    mode.interrupt()
    assert mode.enter(0.0, 0.0, 0.0, 1, 0.25, False) == pytest.approx(0.25, abs=1e-15)


def test_a_chirp_re_entered_without_an_interruption_goes_on():
    """New values set within ``chirp`` while it plays (a re-entry, no interruption): the chirp
    goes on from its clock with its u_0, sample for sample as without the re-entry."""
    cfg = CONFIG.replace(mode="chirp")
    one, other = (MODE_TYPES["chirp"](cfg, DT) for _ in range(2))
    for m in (one, other):
        m.select()
        m.enter(0.0, 0.0, 0.0, 1, -0.2, True)
        for _ in range(50):
            m.update(0.0, 0.0, 0.0, 1)
    assert one.enter(0.0, 0.0, 0.0, 1, 0.7, False) == other.update(0.0, 0.0, 0.0, 1)
    assert [one.update(0.0, 0.0, 0.0, 1) for _ in range(100)] \
        == [other.update(0.0, 0.0, 0.0, 1) for _ in range(100)]


def test_passive_is_zero_at_once():
    mode = MODE_TYPES["passive"](CONFIG, DT)
    assert isinstance(mode, TorqueMode)
    assert mode.enter(0.1, 0.2, 0.3, 1, 0.9, True) == 0.0 == mode.update(0.1, 0.2, 0.3, 1)


def test_observer_at_rest_and_the_reference_modes():
    """A constant F_p: the hose deflects by F_p/k_s, V_e_hat is V; F_cmp is eq. 29 on them,
    each term times its margin's scale ``1 - margin u`` (0.8 at the defaults)."""
    obs = EndpointObserver(PLANT, CONFIG.feedforward, CONFIG.dahl, DT)
    for _ in range(50):
        obs.update(0.1, 0.0, 0.02)
    delta = 0.02 / PLANT.hose_stiffness
    assert obs.position == pytest.approx(0.1 + delta, rel=1e-12)
    assert obs.velocity == pytest.approx(0.0, abs=1e-12)
    s_b, s_k, s_d = CONFIG.feedforward.scales()
    assert (s_b, s_k, s_d) == pytest.approx((0.8, 0.8, 0.8))
    assert obs.compensation == pytest.approx(s_k * PLANT.endpoint_stiffness * (0.1 + delta),
                                             rel=1e-9)
    refs = {}
    for name in DOB_MODES:
        mode = MODE_TYPES[name](CONFIG, DT)
        assert isinstance(mode, ReferenceMode)
        refs[name] = mode.enter(obs)
    # the feed-forward's Dahl force: F_c at the margin, half the model's sigma (a state of its
    # own; the model's F_d is what the estimator sees)
    ff_dahl = CONFIG.feedforward.dahl(CONFIG.dahl)
    assert ff_dahl.coulomb_force == pytest.approx(s_d * CONFIG.dahl.coulomb_force)
    assert ff_dahl.sigma == pytest.approx(0.5 * CONFIG.dahl.sigma)
    ff = obs.compensation + obs.dahl_feedforward
    assert obs.feedforward == pytest.approx(ff, rel=1e-15)
    assert refs == {"dob": 0.0, "dob_linear_ff": obs.compensation, "dob_full_ff": ff,
                    "impedance": ff - 0.01 * obs.velocity, "force": 0.1}


@pytest.mark.parametrize("exponent", [1.0, 1.5])
def test_the_observers_dahl_states_are_dahl_states_driven_by_the_play(exponent):
    """The observer updates its two Dahl states itself for n = 1: exactly (==) what
    DahlState.update gives on the play's output, as it does for another n."""
    dahl = DahlParams(exponent=exponent)
    obs = EndpointObserver(PLANT, CONFIG.feedforward, dahl, DT)
    model, feedforward = DahlState(dahl), DahlState(CONFIG.feedforward.dahl(dahl))
    for k in range(2000):
        t = k * DT
        obs.update(0.3 * math.sin(7.0 * t) + 0.02 * math.sin(300.0 * t), 0.0,
                   0.05 * math.cos(11.0 * t))
        if k == 0:
            model.reset(obs.dahl_input)
            feedforward.reset(obs.dahl_input)
        assert obs.dahl_force == model.update(obs.dahl_input)
        assert obs.dahl_feedforward == feedforward.update(obs.dahl_input)
        assert obs.feedforward == obs.compensation + obs.dahl_feedforward


@pytest.mark.parametrize("mode", ["force", "dob_linear_ff", "dob_full_ff"])
def test_the_controllers_dob_step_is_the_dobs(mode):
    """ChannelController.update writes the DOB's step out (and dob_full_ff's reference): its
    torque is exactly (==) what DisturbanceObserver.update gives on the reference, one sample
    or several at a time (walls clear, no guard: F_ref + 0.0 is the mode's reference)."""
    ctl = ChannelController(CONFIG.replace(mode=mode), DT)
    dob = DisturbanceObserver(CONFIG.dob, DT)
    reference = {"force": lambda: CONFIG.target.force,
                 "dob_linear_ff": lambda: ctl.observer.compensation,
                 "dob_full_ff": lambda: ctl.observer.feedforward}[mode]
    for k in range(3000):
        t = k * DT
        x, v, f_p = 0.3 * math.sin(7.0 * t), 2.1 * math.cos(7.0 * t), 0.05 * math.cos(11.0 * t)
        steps = 3 if k % 500 == 7 else 1
        u = ctl.update(x, v, f_p, steps)
        f_ref = reference() + 0.0
        if k == 0:
            dob.enter(0.0, f_ref, x, v, f_p, steps)
        assert u == dob.update(f_ref, x, v, f_p, steps)
        assert ctl.disturbance == u - f_ref


def test_hose_coefficients_over_n_periods_are_n_single_ones_for_a_ramp():
    """The first-order hold is exact for a linear F_p: one step over 4 T equals four steps."""
    ks, inv_bs = PLANT.hose_stiffness, 1.0 / PLANT.hose_damping
    a1, c01, c11 = hose_coefficients(ks, inv_bs, DT)
    a4, c04, c14 = hose_coefficients(ks, inv_bs, 4 * DT)
    delta, f = 1e-4, [0.0, 0.01, 0.02, 0.03, 0.04]
    d = delta
    for k in range(4):
        d = a1 * d + c01 * f[k] + c11 * f[k + 1]
    assert a4 * delta + c04 * f[0] + c14 * f[4] == pytest.approx(d, rel=1e-12)
    assert a1 == pytest.approx(math.exp(-ks * inv_bs * DT))

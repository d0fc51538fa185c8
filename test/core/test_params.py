"""Parameter validation and the flat ROS-key mapping."""

import math

import pytest

from seaforce_ros.core import (ControllerConfig, DahlParams, DobParams, ForceFeedbackParams,
                               GraspParams, InvalidParameterError, MODES, NonPassiveError,
                               PARAMETERS, PlantParams, SeaforceError, TargetParams)
from seaforce_ros.core.params import settable_order

TABLE_I = PlantParams.table_i()


def test_table_i_values():
    p = TABLE_I
    assert (p.motor_inertia, p.motor_damping, p.motor_stiffness) == (1.1116e-3, 2.9814e-2, 0.1642)
    assert (p.endpoint_inertia, p.endpoint_damping, p.endpoint_stiffness) == \
        (0.7089e-3, 3.3879e-2, 0.0637)
    assert (p.hose_damping, p.hose_stiffness) == (9.2453e-3, 13.0782)
    assert DahlParams() == DahlParams(sigma=12.8, coulomb_force=0.032, exponent=1.0)


@pytest.mark.parametrize("field", ["motor_inertia", "endpoint_inertia"])
@pytest.mark.parametrize("value", [0.0, -1e-3])
def test_non_positive_inertia_rejected(field, value):
    with pytest.raises(InvalidParameterError) as info:
        TABLE_I.scaled()  # copy is fine
        PlantParams(**{**TABLE_I.__dict__, field: value})
    err = info.value
    assert err.name == "plant." + field and err.value == value
    assert err.bound == "> 0 and <= 10"
    assert f"plant.{field}" in str(err) and "> 0" in str(err)


@pytest.mark.parametrize("field", [
    "motor_damping", "motor_stiffness", "endpoint_damping", "endpoint_stiffness",
    "hose_damping", "hose_stiffness"])
def test_negative_stiffness_damping_rejected(field):
    with pytest.raises(InvalidParameterError) as info:
        PlantParams(**{**TABLE_I.__dict__, field: -0.01})
    assert info.value.name == "plant." + field
    assert ">= 0" in str(info.value) and "-0.01" in str(info.value)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("field", ["motor_inertia", "hose_stiffness", "endpoint_damping"])
def test_non_finite_rejected(field, value):
    with pytest.raises(InvalidParameterError) as info:
        PlantParams(**{**TABLE_I.__dict__, field: value})
    assert info.value.name == "plant." + field
    assert "finite" in str(info.value)


def test_invalid_errors_are_value_errors_and_seaforce_errors():
    with pytest.raises(ValueError):
        DahlParams(coulomb_force=0.0)
    with pytest.raises(SeaforceError):
        DobParams(cutoff=-1.0)
    with pytest.raises(InvalidParameterError, match="dob.nominal_stiffness"):
        DobParams(nominal_stiffness=-0.1)
    with pytest.raises(InvalidParameterError, match="dahl.exponent"):
        DahlParams(exponent=math.nan)


def test_non_passive_dob_rejected_unless_allowed():
    m_min = TABLE_I.motor_inertia - TABLE_I.motor_damping / (2 * math.pi * 20)
    bad = DobParams(nominal_inertia=0.9 * m_min)
    with pytest.raises(NonPassiveError) as info:
        ControllerConfig(mode="dob", dob=bad)
    err = info.value
    assert isinstance(err, InvalidParameterError)
    assert err.name == "dob.nominal_inertia" and err.value == pytest.approx(0.9 * m_min)
    assert f"{m_min:.6g}" in err.bound and "allow_non_passive" in str(err)
    ok = ControllerConfig(mode="dob", dob=bad, allow_non_passive=True)
    assert ok.dob.nominal_inertia == pytest.approx(0.9 * m_min)
    # at the bound itself it is accepted
    ControllerConfig(mode="dob", dob=DobParams(nominal_inertia=m_min * (1 + 1e-12)))


def test_non_passive_nominal_stiffness_rejected():
    lam = 2 * math.pi * 20
    b_n = 1e-3
    k_max = TABLE_I.motor_stiffness + lam * b_n
    with pytest.raises(NonPassiveError) as info:
        ControllerConfig(dob=DobParams(nominal_damping=b_n, nominal_stiffness=1.01 * k_max))
    assert info.value.name == "dob.nominal_stiffness"
    assert f"{k_max:.6g}" in info.value.bound
    ControllerConfig(dob=DobParams(nominal_damping=b_n, nominal_stiffness=0.99 * k_max))


def test_force_feedback_gain_passive_range():
    for gain in (-1.0, 0.0, 1.0):
        gains = ForceFeedbackParams(gain=gain)
        assert ControllerConfig(force_feedback=gains).force_feedback.gain == gain
    for gain in (-1.01, 1.5):
        with pytest.raises(NonPassiveError, match="force_feedback.gain"):
            ControllerConfig(force_feedback=ForceFeedbackParams(gain=gain))
    assert ControllerConfig(force_feedback=ForceFeedbackParams(gain=1.5), allow_non_passive=True)


def test_controller_config_other_checks():
    with pytest.raises(InvalidParameterError, match="mode"):
        ControllerConfig(mode="zero")
    with pytest.raises(InvalidParameterError, match="max_torque"):
        ControllerConfig(max_torque=0.0)
    with pytest.raises(InvalidParameterError, match="target.stiffness"):
        ControllerConfig(target=TargetParams(stiffness=-1.0))
    with pytest.raises(InvalidParameterError, match="plant.hose_damping"):
        # the hose inversion of the feed-forward needs b_s > 0
        ControllerConfig(plant=PlantParams(**{**TABLE_I.__dict__, "hose_damping": 0.0}))
    for mode in MODES:
        assert ControllerConfig(mode=mode).mode == mode


def test_flat_dict_round_trip():
    cfg = ControllerConfig(mode="dob_full_ff", target=TargetParams(stiffness=0.5),
                           dob=DobParams(cutoff=20.0, nominal_inertia=5e-4))
    flat = cfg.to_dict()
    assert list(flat) == list(PARAMETERS)
    assert flat["mode"] == "dob_full_ff" and flat["dob.cutoff"] == 20.0
    assert flat["plant.hose_stiffness"] == 13.0782
    assert flat["dahl.coulomb_force"] == 0.032
    assert flat["allow_non_passive"] is False
    assert ControllerConfig.from_dict(flat) == cfg


def test_from_dict_overrides_base_and_strips_channel_prefix():
    cfg = ControllerConfig.from_dict({"pinch.mode": "dob", "pinch.dob.cutoff": 20,
                                      "plant.motor_damping": 0.05, "target.damping": 0.01})
    assert cfg.mode == "dob" and cfg.dob.cutoff == 20.0
    assert isinstance(cfg.dob.cutoff, float)
    assert cfg.plant.motor_damping == 0.05 and cfg.target.damping == 0.01
    assert cfg.plant.motor_inertia == TABLE_I.motor_inertia
    with pytest.raises(InvalidParameterError, match="no_such_key"):
        ControllerConfig.from_dict({"no_such_key": 1.0})
    with pytest.raises(NonPassiveError):
        ControllerConfig.from_dict({"dob.nominal_inertia": 0.0})
    with pytest.raises(InvalidParameterError, match="plant.motor_inertia"):
        ControllerConfig.from_dict({"plant.motor_inertia": math.nan})


def test_an_unset_nominal_inertia_is_the_given_plants_motor_inertia():
    """dob.nominal_inertia's documented default is plant.motor_inertia: from the plant given,
    not Table I's (an identified m of 0.002 was refused for eq. 28 against Table I's m_n);
    given explicitly it is kept, and a base keeps its own."""
    assert ControllerConfig.from_dict({"plant.motor_inertia": 0.002}).dob.nominal_inertia == 0.002
    assert ControllerConfig.from_dict({"plant.motor_inertia": 0.002,
                                       "dob.nominal_inertia": 0.003}).dob.nominal_inertia == 0.003
    base = ControllerConfig()
    assert ControllerConfig.from_dict({"plant.motor_inertia": 0.0012}, base=base) \
        .dob.nominal_inertia == base.dob.nominal_inertia
    assert ControllerConfig.from_dict({}) == ControllerConfig()


def test_every_key_has_a_description_and_a_unit_or_choices():
    for key, spec in PARAMETERS.items():
        assert spec.description, key
        assert spec.unit or spec.choices or spec.type is bool, key


def test_the_table_names_real_fields_and_sane_ranges():
    """Every PARAMETERS row maps to a ControllerConfig field; its range holds the Table I
    default; numeric parameters have a range, mode and the bools have none."""
    config = ControllerConfig(plant=TABLE_I)
    flat = config.to_dict()
    for key, spec in PARAMETERS.items():
        group = key.rpartition(".")[0] if key != "passivity_guard" else "passivity"
        owner = getattr(config, group) if group else config
        assert hasattr(owner, spec.attribute), key
        value = flat[key]
        if isinstance(value, (bool, str)):
            assert spec.low is None and spec.high is None, key
        else:
            assert spec.low is not None and spec.high is not None and spec.low < spec.high, key
            assert spec.problem(value) is None, (key, value)


def test_the_core_and_a_node_accept_the_same_values():
    """One range per parameter: a value the core's dataclass accepts is one a node accepts,
    and the other way round (grasp.give_way_travel = 200 was accepted by the core and
    refused by the node)."""
    with pytest.raises(InvalidParameterError, match="grasp.give_way_travel"):
        GraspParams(give_way_travel=200.0)
    spec = PARAMETERS["grasp.give_way_travel"]
    assert "within (0, 100]" in spec.reason(200.0)
    for key, spec in PARAMETERS.items():
        if spec.type is not float:
            continue
        for value in (spec.low, spec.high, -1e9, 1e9, 0.0, 1e-7, float("nan")):
            if value is None:
                continue
            assert (spec.problem(value) is None) == (spec.reason(value) is None), (key, value)


def test_impedance_target_limits():
    ks, bs = TABLE_I.hose_stiffness, TABLE_I.hose_damping
    assert ControllerConfig(mode="impedance", target=TargetParams(stiffness=ks, damping=10 * bs))
    with pytest.raises(InvalidParameterError) as info:
        ControllerConfig(mode="impedance", target=TargetParams(stiffness=1.5 * ks))
    assert info.value.name == "target.stiffness" and "13.0782" in info.value.bound
    assert "allow_non_passive" in str(info.value)
    with pytest.raises(InvalidParameterError, match="target.damping"):
        ControllerConfig(mode="impedance", target=TargetParams(damping=11 * bs))
    assert ControllerConfig(mode="impedance", target=TargetParams(stiffness=1.5 * ks),
                            allow_non_passive=True).target.stiffness == 1.5 * ks


def test_settable_order_puts_m_n_back_before_m():
    """From a configuration tuned for a plant at 0.6 m (m_n with it) back to the defaults, one
    value at a time: m first is refused (eq. 28 with the tuned m_n), so m_n goes first; a
    value no configuration accepts gives no order."""
    start = ControllerConfig()
    m = start.plant.motor_inertia
    tuned = ControllerConfig.from_dict({'plant.motor_inertia': 0.6 * m,
                                        'dob.nominal_inertia': 0.6 * m}, base=start)
    back = {'plant.motor_inertia': m, 'dob.nominal_inertia': m}
    with pytest.raises(NonPassiveError):
        ControllerConfig.from_dict({'plant.motor_inertia': m}, base=tuned)
    assert settable_order(tuned, back) == ['dob.nominal_inertia', 'plant.motor_inertia']
    assert settable_order(tuned, {**back, 'dob.cutoff': -1.0}) is None
    assert settable_order(tuned, {}) == []

"""The softest modes never make the finger active: the feed-forward's margin, the joint walls
and the joint-limit fault, the runaway monitor and its fall-back (core/safety.py), alone, in the
controller, in the cycle, and as properties over random plants, modes and environments."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, contact_object, free, position_sine,
                               run_closed_loop)
from seaforce_ros.core.control_cycle import JOINT_LIMIT
from seaforce_ros.core.episodes import ERROR
from seaforce_ros.core.errors import InvalidParameterError, NonPassiveError
from seaforce_ros.core.grasp import Grasp, GraspGoal
from seaforce_ros.core.nonlinear_effects import draw_effects, model_terms
from seaforce_ros.core.nonlinear_simulator import NonlinearChannelSimulator
from seaforce_ros.core.params import (FeedforwardParams, ForceFeedbackParams, FrictionParams,
                                      GraspParams, LimitParams, MonitorParams,
                                      PlantTermsParams, TargetParams)
from seaforce_ros.core.rig import CycleRig
from seaforce_ros.core.safety import JointWalls, RunawayMonitor

from helpers.configs import exact_feedforward

DT = 5e-4
TABLE_I = PlantParams.table_i()
DAHL = DahlParams()
LIMITS = LimitParams()
FIELDS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
          "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")
#: The runaways measured on the plant before the margin: (name, true plant) for a Table I model.
RUNAWAYS = [("k_e 17 % high", TABLE_I.scaled(endpoint_stiffness=0.83)),
            ("k_e 25 % high", TABLE_I.scaled(endpoint_stiffness=0.75)),
            ("b_e 1.5x", TABLE_I.scaled(endpoint_damping=1.0 / 1.5))]


# --- the walls alone -------------------------------------------------------------------------
def test_walls_push_back_inside_the_band_only_and_never_pull():
    w = JointWalls(LIMITS, max_torque=5.0)
    hi_wall = LIMITS.position_max - LIMITS.wall_band
    assert w.update(0.0, 3.0, 0.0, 3.0) == 0.0 and w.beyond == ""
    assert w.update(hi_wall - 1e-6, 3.0, hi_wall - 1e-6, 3.0) == 0.0
    # spring plus damping (full from a quarter of the band in), pushing out
    p = 0.1
    f = w.update(hi_wall + p, 0.5, hi_wall + p, 0.5)
    assert f == pytest.approx(-(LIMITS.wall_stiffness * p + LIMITS.wall_damping * 0.5))
    # leaving the wall fast: the damping would pull; the wall only stops pushing
    assert w.update(hi_wall + 0.01, -50.0, hi_wall + 0.01, -50.0) == 0.0
    # the lower wall mirrors it
    lo_wall = LIMITS.position_min + LIMITS.wall_band
    assert w.update(lo_wall - p, -0.5, lo_wall - p, -0.5) == pytest.approx(-f)
    # no step where the finger enters the band: the damping ramps in
    assert abs(w.update(hi_wall + 1e-6, 5.0, hi_wall + 1e-6, 5.0)) < 1e-3


def test_walls_take_the_deeper_of_motor_and_endpoint_are_bounded_and_name_the_limit():
    w = JointWalls(LIMITS, max_torque=0.2)
    hi_wall = LIMITS.position_max - LIMITS.wall_band
    # the endpoint estimate deeper than the motor (a wrong hose model): its penetration counts
    f = w.update(hi_wall, 0.0, hi_wall + 0.02, 0.0)
    assert f == pytest.approx(-LIMITS.wall_stiffness * 0.02)
    assert w.update(10.0, 100.0, 10.0, 100.0) == -0.2            # |F_w| <= max_torque
    assert "beyond the joint range" in w.beyond and "motor at 10 rad" in w.beyond
    w.update(1.0, 0.0, 1.0, 0.0)
    assert w.beyond == ""
    w.update(0.0, 0.0, -1.6, 0.0)                                  # the endpoint alone
    assert "endpoint (estimated) at -1.6" in w.beyond


# --- the monitor alone -----------------------------------------------------------------------
def test_monitor_trips_after_trip_time_once_per_excursion():
    params = MonitorParams(max_speed=10.0, trip_time=0.005)
    m = RunawayMonitor(params, DT)
    beyond = int(round(params.trip_time / DT)) + 1
    assert not any(m.update(0.0, 11.0) for _ in range(beyond - 1))
    assert not m.update(0.0, 9.9)                # a break restarts the count
    assert not any(m.update(50.0, 0.0) for _ in range(100))   # the motor's speed is not judged
    trips = [m.update(0.0, -10.5) for _ in range(beyond)]
    assert trips == [False] * (beyond - 1) + [True]
    assert "endpoint (estimated) speed 10.5 rad/s" in m.reason
    # still fast after the trip: no new trip until the speed was back within max_speed ...
    assert not any(m.update(15.0, 15.0) for _ in range(100))
    # ... or beyond twice max_speed (the fall-back does not stop it)
    assert any(m.update(0.0, 21.0) for _ in range(beyond))
    assert not m.update(0.0, 0.0)
    assert any(m.update(0.0, 12.0) for _ in range(beyond))


def test_monitor_trips_on_the_energy_the_walls_take_out():
    """The walls' dissipated power is counted (forgotten over WALL_MEMORY): a finger that keeps
    coming back into them trips the monitor; power they give (a spring relaxing) is not."""
    from seaforce_ros.core.safety import WALL_MEMORY
    m = RunawayMonitor(MonitorParams(wall_energy=0.02), DT)
    for _ in range(1000):
        m.walls(-5.0)                       # negative: not counted, only forgotten
    assert m.wall_work == 0.0 and not m.update(0.0, 0.0)
    for _ in range(6):
        m.walls(5.0)                        # 15 mJ in 3 ms
    assert not m.update(0.0, 0.0)
    assert m.wall_work == pytest.approx(0.015, rel=0.01)
    for _ in range(int(WALL_MEMORY / DT)):
        m.walls(0.0)                        # forgotten by e
    assert m.wall_work == pytest.approx(0.015 / math.e, rel=0.01)
    for _ in range(8):
        m.walls(5.0)                        # 20 mJ more
    assert m.update(0.0, 0.0) and "joint walls" in m.reason and m.wall_work == 0.0
    # after a trip the walls take the finger's energy out of it: not counted for WALL_MEMORY
    for _ in range(int(WALL_MEMORY / DT) - 1):
        m.walls(5.0)
    assert m.wall_work == 0.0 and not m.update(0.0, 0.0)
    m.walls(5.0)
    m.walls(5.0)
    assert m.wall_work > 0.0


# --- what the controller skips ------------------------------------------------------------------
@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(-1.6, 1.6), st.floats(-20.0, 20.0), st.floats(-1.6, 1.6),
                          st.floats(-20.0, 20.0)), min_size=1, max_size=80),
       st.sampled_from([(4.0, 0.1), (0.0, 0.0)]))
def test_walls_clear_and_between_them_change_nothing(samples, wall):
    """ChannelController.update skips JointWalls.update while ``clear`` with X and X_e_hat
    within ``free_min..free_max``: the update then returns +0.0 and leaves ``force``,
    ``beyond`` and ``clear`` as they were (0.0, '', True). (Walls without stiffness and
    damping give -0.0 in them: not clear.)"""
    walls = JointWalls(LimitParams(position_min=-1.2, position_max=1.4, wall_band=0.3,
                                   wall_stiffness=wall[0], wall_damping=wall[1]), 0.5)
    low, high = walls.free_min, walls.free_max
    for x, v, xe, ve in samples:
        state = (walls.force, walls.beyond, walls.clear)
        if walls.clear:     # +0.0 (the sign counts: -0.0 is no skipped +0.0)
            assert (walls.force, math.copysign(1.0, walls.force), walls.beyond) == (0.0, 1.0, "")
        f = walls.update(x, v, xe, ve)
        if state[2] and low <= x <= high and low <= xe <= high:
            assert (f, math.copysign(1.0, f)) == (0.0, 1.0)
            assert (walls.force, walls.beyond, walls.clear) == state


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(-25.0, 25.0), st.floats(-25.0, 25.0),
                          st.sampled_from([0.0, 0.0, -3.0, 4.0]), st.integers(1, 3)),
                min_size=1, max_size=80))
def test_a_calm_monitor_within_its_limit_changes_nothing(samples):
    """ChannelController.update skips RunawayMonitor.update while ``calm`` with both speeds
    within ``max_speed``: calm is nothing counted (over 0, armed, wall_work 0), and the update
    then returns False and changes nothing."""
    m = RunawayMonitor(MonitorParams(max_speed=10.0, trip_time=0.002, wall_energy=1e-3), DT)
    for v, ve, power, steps in samples:
        if m.calm:
            assert m.over == 0 and m.armed and m.wall_work == 0.0
        state = (m.over, m.reason, m.armed, m.wall_work, m.calm)
        tripped = m.update(v, ve, steps)
        if state[4] and -10.0 <= v <= 10.0 and -10.0 <= ve <= 10.0:
            assert not tripped and (m.over, m.reason, m.armed, m.wall_work, m.calm) == state
        m.walls(power, steps)
        if m.calm:
            assert m.over == 0 and m.armed and m.wall_work == 0.0


# --- the configuration's rules -----------------------------------------------------------------
def test_a_feed_forward_without_its_margin_is_refused_unless_allowed():
    for changes, name in (({"margin": 0.9}, "feedforward.margin"),
                          ({"stiffness_uncertainty": 0.0}, "feedforward.stiffness_uncertainty"),
                          ({"dahl_uncertainty": 0.005}, "feedforward.dahl_uncertainty")):
        ff = FeedforwardParams(**changes)
        with pytest.raises(NonPassiveError, match=name.replace(".", r"\.")) as info:
            ControllerConfig(feedforward=ff)
        assert info.value.override == "allow_non_passive"
        ControllerConfig(feedforward=ff, allow_non_passive=True)
    assert FeedforwardParams(margin=2.0, damping_uncertainty=0.6).scales()[0] == 0.0


def test_motions_stay_inside_the_joint_range_and_grasps_below_the_monitor():
    with pytest.raises(InvalidParameterError, match=r"friction\.position_max"):
        ControllerConfig(limits=LimitParams(position_max=1.0))
    with pytest.raises(InvalidParameterError, match=r"limits\.position_max"):
        LimitParams(position_min=-0.1, position_max=0.1, wall_band=0.15)
    with pytest.raises(InvalidParameterError, match=r"grasp\.max_closing_velocity"):
        ControllerConfig(monitor=MonitorParams(max_speed=1.0))
    narrow = ControllerConfig(limits=LimitParams(position_min=-1.0, position_max=1.0),
                              friction=FrictionParams(position_min=-1.0, position_max=1.0),
                              commissioning=dataclasses.replace(
                                  ControllerConfig().commissioning, position_min=-1.0,
                                  position_max=1.0))
    assert narrow.limits.position_max == 1.0


# --- in the controller --------------------------------------------------------------------------
def free_finger(plant, config, seconds, flick=1.0, dahl=DAHL, seed=1):
    """The whole cycle on a free finger that starts with a flick: (rig, X_e, V_e, fallback)."""
    sim = ChannelSimulator(plant, dahl, seed=seed)
    sim.reset(state=(0.0, flick, 0.0, flick))
    rig = CycleRig(sim, config)
    xe, ve, fb = [], [], []
    for _ in range(int(round(seconds / DT))):
        rig.step()
        xe.append(sim._z[2])
        ve.append(sim._z[3])
        fb.append(rig.controller.fallback)
    return rig, np.array(xe), np.array(ve), fb


@pytest.mark.parametrize("name, plant", RUNAWAYS)
def test_the_measured_runaways_stay_still_with_the_margin(name, plant):
    """The plants that ran away in dob_full_ff (to 10-51 rad): with the default margin (each
    term 20 % below the model) the free finger's net stiffness and damping are positive."""
    rig, xe, ve, fb = free_finger(plant, ControllerConfig(mode="dob_full_ff"), 10.0)
    assert np.max(np.abs(xe)) < 0.1, name
    assert np.max(np.abs(ve[-2000:])) < 0.05, name        # at rest at the end
    assert not any(fb) and not rig.cycle.faults_latched


def assert_comes_to_rest(signs, size, flick, seed, uncertainty=None):
    """Every Table I and Dahl parameter of the true plant ``size`` off the model (``signs``),
    the free finger in dob_full_ff flicked at ``flick`` rad/s: 1 s of it after 5 s is at rest
    and it never left +-0.5 rad. ``uncertainty`` (b_e, k_e, F_c's, the margin 2) defaults to
    the hand-typed 10 %."""
    f = [1.0 + size * sgn for sgn in signs]
    plant = TABLE_I.scaled(**dict(zip(FIELDS, f[:8])))
    dahl = DahlParams(sigma=DAHL.sigma * f[8], coulomb_force=DAHL.coulomb_force * f[9])
    sim = ChannelSimulator(plant, dahl, seed=seed)
    sim.reset(state=(0.0, flick, 0.0, flick))
    config = ControllerConfig(mode="dob_full_ff")
    if uncertainty is not None:
        config = config.replace(feedforward=dataclasses.replace(
            config.feedforward, damping_uncertainty=uncertainty,
            stiffness_uncertainty=uncertainty, dahl_uncertainty=uncertainty))
    rec = run_closed_loop(sim, ChannelController(config), 12000)
    last = rec["v_e_true"][-2000:]
    assert float(np.sqrt(np.mean(last ** 2))) < 0.01
    assert np.max(np.abs(rec["x_e_true"])) < 0.5


@settings(max_examples=16, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(signs=st.lists(st.sampled_from([-1.0, 1.0]), min_size=10, max_size=10),
       size=st.one_of(st.just(0.2), st.floats(0.05, 0.2)), flick=st.floats(-1.0, 1.0),
       seed=st.integers(0, 1000))
def test_a_free_finger_within_the_uncertainty_comes_to_rest(signs, size, flick, seed):
    """Invariant: every Table I and Dahl parameter of the true plant off the model by up to
    the default band (2 x 10 %), its edge included, the free finger in dob_full_ff, flicked:
    it comes to rest -- no limit cycle (the feed-forward's Dahl cancelling the model's whole
    pre-sliding stiffness made 24 of 40 such plants oscillate at 0.14-0.19 rad/s rms)."""
    assert_comes_to_rest(signs, size, flick, seed)


# plants at the band's edge that kept moving before the feed-forward modes had the free
# finger's damping reserve (5 of 100 drawn at the edge; b_e exactly cancelled on all):
# a limit cycle of +-3 mrad at 0.06 rad/s rms, and creeps that accelerated to 1.3 rad in 28 s
EDGE_PLANTS = [("+----+---+", 0.46), ("+--+--+---", 0.44), ("+-+---+---", -0.61)]


@pytest.mark.parametrize("signs, flick", EDGE_PLANTS)
@pytest.mark.parametrize("uncertainty, size", [(None, 0.2), (0.032, 0.064)])
def test_a_free_finger_at_the_margins_edge_comes_to_rest(signs, flick, uncertainty, size):
    """The same invariant on the measured edge plants, with the hand-typed uncertainties and
    with a commissioned model's (3.2 %: the plant 6.4 % off)."""
    assert_comes_to_rest([1.0 if c == "+" else -1.0 for c in signs], size, flick, 2,
                         uncertainty)


@pytest.mark.parametrize("name, plant", RUNAWAYS)
def test_without_the_margin_the_walls_and_the_monitor_keep_them_in_range(name, plant):
    """The paper's exact feed-forward on the same plants: the finger runs away, and the walls
    and the monitor keep it inside the joint range; a trip comes within trip_time and one
    sample of the speed crossing max_speed."""
    config = exact_feedforward(mode="dob_full_ff")
    rig, xe, ve, fb = free_finger(plant, config, 8.0)
    assert np.max(np.abs(xe)) > 1.0, name                 # it does run away
    assert np.max(np.abs(xe)) <= LIMITS.position_max, name
    assert not rig.cycle.faults_latched, rig.cycle.latched(0)
    limit = config.monitor.max_speed
    if any(fb) and "speed" in rig.controller.fallback_reason:
        first = fb.index(next(f for f in fb if f))
        crossed = int(np.argmax(np.abs(ve) > limit))
        assert first - crossed <= round(config.monitor.trip_time / DT) + 2, (first, crossed)
    elif any(fb):       # the walls' energy (it kept coming back into them), or held on one
        assert "joint wall" in rig.controller.fallback_reason


def test_the_fallback_is_latched_refuses_grasps_and_ends_with_clear_fallback():
    """A trip ends a grasp, falls back to dob, enters it bumplessly; resets keep the fall-back;
    a grasp goal is refused; clear_fallback (~/reset) returns to the configured mode."""
    ctl = ChannelController(ControllerConfig(mode="dob_full_ff"))
    for _ in range(10):
        ctl.update(0.0, 0.0, 0.0)
    grasp = Grasp(GraspGoal("pinch", 0.3, 0.2, 0.5, False), ctl.config)
    ctl.request_job(grasp)
    ctl.update(0.0, 0.0, 0.0)
    assert ctl.job is grasp
    u, fell = [], []
    for k in range(20):
        u.append(ctl.update(0.006 * k, 12.0, 0.0))
        fell.append(ctl.fallback)
    assert ctl.fallback == "dob" and "monitor.max_speed" in ctl.fallback_reason
    assert ctl.tripped and ctl.job is None and grasp.outcome == "aborted"
    assert "runaway monitor" in grasp.message
    k = fell.index("dob")                       # the trip's sample: the DOB enters from u
    steps = [abs(a - b) for a, b in zip(u, u[1:])]
    assert abs(u[k] - u[k - 1]) <= max(steps[:k - 1])     # no step beyond the motion's own
    ctl.reset(0.0)
    assert ctl.fallback == "dob"
    refused = Grasp(GraspGoal("pinch", 0.3, 0.2, 0.5, False), ctl.config)
    ctl.request_job(refused)
    ctl.update(0.0, 0.0, 0.0)
    assert refused.outcome == "aborted" and "~/reset" in refused.message
    # a trip in the fall-back goes on to passive: zero torque
    for k in range(20):
        ctl.update(0.0125 * k, 25.0, 0.0)
    assert ctl.fallback == "passive" and ctl.update(0.25, 25.0, 0.0) == 0.0
    assert ctl.mode == "dob_full_ff"            # the configured mode is kept ...
    assert ctl.clear_fallback() and not ctl.fallback
    ctl.update(0.0, 0.0, 0.0)
    assert type(ctl._reference_mode).__name__ == "DobFullFeedforward"   # ... and back
    assert not ctl.clear_fallback()


def test_hold_works_inside_the_walls_and_enters_bumplessly_in_the_band():
    """hold at 1.4 rad (inside the wall band) keeps the finger there against a drive that
    pushes it; entering hold in the band gives the torque the channel had."""
    sim = ChannelSimulator(TABLE_I, DAHL, seed=3,
                           environment=position_sine(0.0, 0.0, offset=1.4,
                                                     stiffness=5.0, damping=0.05))
    sim.reset(state=(1.4, 0.0, 1.4, 0.0))
    ctl = ChannelController(ControllerConfig(mode="dob"))
    rec = run_closed_loop(sim, ctl, 4000, on_switch={
        2000: lambda s, c: c.configure(c.config.replace(mode="hold"))})
    u = rec["u"]
    assert abs(u[2000] - u[1999]) < 1e-3
    assert ctl.walls.force < 0.0                    # in the band: the wall pushes
    assert np.max(np.abs(rec["x_e_true"] - 1.4)) < 0.05 and ctl.beyond == ""


# --- in the cycle ------------------------------------------------------------------------------
def test_beyond_the_range_latches_joint_limit_and_the_trip_is_reported_once():
    """A force that overpowers the walls: the finger reaches the end of the range, the cycle
    latches joint_limit (zero torque), ~/reset clears it. A trip is an error event, once."""
    config = ControllerConfig(mode="force", target=TargetParams(force=1.0),
                              monitor=MonitorParams(max_speed=50.0, wall_energy=100.0))
    sim = ChannelSimulator(TABLE_I, DAHL, seed=2)
    rig = CycleRig(sim, config)
    for _ in range(8000):
        rig.step()
        if rig.cycle.latched(0):
            break
    assert "beyond the joint range" in rig.cycle.latched(0)
    assert rig.cycle.counts[JOINT_LIMIT] >= 1
    assert rig.step() == 0.0 and rig.step() == 0.0
    assert any("FAULT latched" in text for _, text in rig.cycle.events.drain())
    # the finger coasts passively: it stops close to the end of the range
    for _ in range(4000):
        rig.step()
    assert abs(sim._z[2]) < LIMITS.position_max + 0.3

    # the runaway monitor in the cycle: reported once, shown as the fault, cleared by a reset
    config = ControllerConfig(mode="force", target=TargetParams(force=1.0),
                              limits=LimitParams(position_min=-100.0, position_max=100.0))
    rig = CycleRig(ChannelSimulator(TABLE_I, DAHL, seed=2), config)
    for _ in range(4000):
        rig.step()
    assert rig.controller.fallback == "dob"
    events = [text for sev, text in rig.cycle.events.drain() if sev == ERROR]
    assert len(events) == 1 and "runaway monitor" in events[0] and "~/reset" in events[0]
    assert rig.cycle.fault(0).startswith("fallback to dob")
    assert rig.cycle.request_reset() == "cleared faults on pinch"
    rig.step()
    assert not rig.controller.fallback and rig.cycle.fault(0) == ""


def test_no_trip_while_the_channel_is_faulted():
    """Zero torque (a latched fault): the finger moves, but not by this controller's doing; a
    speed beyond max_speed then trips nothing."""
    ctl = ChannelController(ControllerConfig(mode="dob"))
    rig = CycleRig(ChannelSimulator(TABLE_I, None, seed=1), ControllerConfig(mode="dob"))
    ctl = rig.controller
    cc = rig.cycle
    cc._latch(0, "a test fault")
    for k in range(50):
        cc.step(["pinch"], 10 + k, 0, [0.0], [20.0], [0.0], [0.0], [0], 0, 1.0 + k * DT)
    assert ctl.fallback == "" and not ctl.tripped


# --- properties over random plants, modes and environments ------------------------------------
MAX_VELOCITY = 30.0         # rad/s: the plant's speed trip (PlantLimits' default)
#: How far a finger the cycle stopped (joint_limit, zero torque) coasts past the end of the
#: range: from at most 2 max_speed (the monitor stops anything faster) the passive finger
#: (friction and the motor's spring only) stops within this [rad].
OVERTRAVEL = 0.3

modes = st.sampled_from(["passive", "hold", "force_feedback", "dob", "dob_linear_ff",
                         "dob_full_ff", "impedance", "force"])


@st.composite
def segments(draw):
    """A mode with random targets, an environment kind, a duration."""
    mode = draw(modes)
    env = draw(st.sampled_from(["free", "free", "object", "hand"]))
    return (mode, env, draw(st.floats(0.3, 2.0)), draw(st.floats(0.0, 1.0)),
            draw(st.floats(0.0, 1.0)), draw(st.floats(0.0, 1.0)))


def configured(mode, a, b):
    """The default configuration in ``mode``, targets from a, b in 0..1."""
    config = ControllerConfig(mode=mode)
    if mode == "impedance":
        config = config.replace(target=TargetParams(stiffness=a * 2.0, damping=b * 0.09))
    elif mode == "force":
        config = config.replace(target=TargetParams(force=(2 * a - 1) * 0.5))
    elif mode == "force_feedback":
        config = config.replace(force_feedback=ForceFeedbackParams(gain=2 * a - 1))
    return config


def environment(kind, xe, a, b, c):
    """free; an object beyond the finger (0.02..0.8 rad ahead, 0.2..20 N m/rad); a hand that
    takes the finger where it is and moves it within the range (2..50 N m/rad, up to 8 rad/s
    peak)."""
    if kind == "object" and xe < 1.25:
        return contact_object(min(1.3, xe + 0.02 + 0.78 * a), 0.2 * 100.0 ** b,
                              0.02 + 0.08 * c)
    if kind == "hand" and abs(xe) < 1.2:
        amplitude = min(0.5, 1.25 - abs(xe)) * (0.2 + 0.8 * a)
        frequency = min(0.5 + 7.5 * b, 8.0 / amplitude)
        return position_sine(amplitude, frequency, stiffness=2.0 * 25.0 ** c,
                             damping=0.05 + 0.15 * c, offset=xe)
    return free()


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(factors=st.lists(st.floats(-math.log(2.0), math.log(2.0)), min_size=10, max_size=10),
       plan=st.lists(segments(), min_size=1, max_size=4), seed=st.integers(0, 2 ** 16))
def test_no_torque_mode_leaves_the_range_or_outruns_the_limits(factors, plan, seed):
    """Every Table I and Dahl parameter of the true plant 0.5x..2x of the controller's model,
    random mode switches and environments (free; objects of random stiffness and position; a
    backdriving hand as a position drive within the range). Invariants, every sample:

    * no command beyond max_torque;
    * |V| (true motor speed) within the plant's max_velocity;
    * the finger within the joint range, or -- after the cycle latched joint_limit and zeroed
      the torque, or a hand or object pushed it there -- within OVERTRAVEL of it;
    * the monitor's reaction: where the DOB runs and the channel is not faulted, the estimated
      endpoint speed is never beyond max_speed for longer than trip_time plus one sample
      without a fall-back (counted from the sample the monitor is armed).
    """
    f = np.exp(factors)
    plant = TABLE_I.scaled(**dict(zip(FIELDS, f[:8])))
    dahl = DahlParams(sigma=DAHL.sigma * f[8], coulomb_force=DAHL.coulomb_force * f[9])
    sim = ChannelSimulator(plant, dahl, seed=seed, torque_saturation=20.0)
    judge_plan(sim, plan)


def judge_plan(sim, plan, terms=None):
    """Run ``plan`` on ``sim`` through the whole cycle (the model's nonlinear ``terms`` in
    every configuration) and check the invariants of
    :func:`test_no_torque_mode_leaves_the_range_or_outruns_the_limits` at every sample."""
    def config_of(mode, a, b):
        config = configured(mode, a, b)
        return config if terms is None else config.replace(plant_terms=terms)
    first = plan[0]
    rig = CycleRig(sim, config_of(first[0], first[3], first[4]))
    ctl = rig.controller
    config = rig.controller.config
    vmax, limit = config.monitor.max_speed, config.max_torque
    reaction = int(round(config.monitor.trip_time / DT)) + 1
    lo, hi = config.limits.position_min, config.limits.position_max
    for i, (mode, kind, seconds, a, b, c) in enumerate(plan):
        if i:
            rig.configure(config_of(mode, a, b))
        rig.set_environment(environment(kind, sim._z[2], a, b, c))
        pushed = kind != "free"
        over = 0
        for _ in range(int(round(seconds / DT))):
            u = rig.step()
            z = sim._z
            assert abs(u) <= limit, u
            assert abs(z[1]) <= MAX_VELOCITY, (z, ctl.mode, ctl.fallback)
            stopped = bool(rig.cycle.latched(0))
            if not stopped and not pushed:
                assert lo - 0.05 <= z[2] <= hi + 0.05, (z, ctl.mode, rig.cycle.fault(0))
            assert lo - OVERTRAVEL <= z[2] <= hi + OVERTRAVEL, (z, ctl.mode,
                                                                rig.cycle.fault(0))
            runs_dob = ctl._torque_mode is None or ctl.job is not None
            fast = abs(ctl.observer.velocity) > vmax * 1.05
            over = over + 1 if (fast and runs_dob and not stopped and ctl.monitor.armed) \
                else 0
            assert over <= reaction + 1, (z, ctl.mode, ctl.fallback)


# --- the model's nonlinear terms (plant_terms) ------------------------------------------------
@st.composite
def any_terms(draw):
    """Any ``plant_terms`` the config accepts, far beyond a real gripper's: the hose's flow
    term up to 10x and its pressure term up to 6x the plausible ones' top, the stroke terms up
    to 15x (k_3 u^3 at 0.5 rad up to 4x k_e u), k_2 anywhere the rule allows."""
    k3 = draw(st.floats(0.0, 1.0))
    bound = math.sqrt(3.0 * TABLE_I.endpoint_stiffness * k3)
    return PlantTermsParams(hose_flow=draw(st.floats(0.0, 0.1)),
                            hose_pressure=draw(st.floats(0.0, 200.0)),
                            stroke_asymmetry=draw(st.floats(-1.0, 1.0)) * bound,
                            stroke_stiffness=k3)


@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(factors=st.lists(st.floats(-math.log(2.0), math.log(2.0)), min_size=10, max_size=10),
       plan=st.lists(segments(), min_size=1, max_size=3), seed=st.integers(0, 2 ** 16),
       terms=any_terms())
def test_any_model_terms_on_a_nonlinear_plant_keep_the_invariants(factors, plan, seed, terms):
    """The true plant 0.5x..2x of the model with every nonlinear effect drawn within its
    plausible range (the hose's flow and pressure terms, the diaphragm's stroke dependence,
    the four-bar's ratio, cogging, motor Coulomb friction); the controller's model with *any*
    nonlinear terms the config accepts, however wrong; random modes and environments. The
    invariants of :func:`test_no_torque_mode_leaves_the_range_or_outruns_the_limits`, every
    sample: no command beyond max_torque, the motor within the plant's speed limit, the finger
    in the joint range (or within OVERTRAVEL after a latched stop or a push), the monitor's
    reaction within trip_time."""
    f = np.exp(factors)
    plant = TABLE_I.scaled(**dict(zip(FIELDS, f[:8])))
    dahl = DahlParams(sigma=DAHL.sigma * f[8], coulomb_force=DAHL.coulomb_force * f[9])
    effects, coulomb = draw_effects(np.random.default_rng(seed))
    sim = NonlinearChannelSimulator(plant, dahl, effects, seed=seed, torque_saturation=20.0,
                                    motor_coulomb=coulomb)
    judge_plan(sim, plan, terms)


@settings(max_examples=16, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(signs=st.lists(st.sampled_from([-1.0, 1.0]), min_size=10, max_size=10),
       size=st.floats(0.0, 0.05), term_errors=st.lists(st.floats(-1.0, 1.0), min_size=4,
                                                      max_size=4),
       start=st.floats(-0.5, 0.5), flick=st.floats(-1.0, 1.0), seed=st.integers(0, 1000))
def test_a_free_finger_on_the_richer_model_comes_to_rest_over_the_stroke(
        signs, size, term_errors, start, flick, seed):
    """Invariant: a nonlinear plant of the plausible family (every effect drawn), the
    controller's model its linear coefficients within ``size`` (<= 5 %) and its terms within
    what the oracle's family showed (stroke terms -25..+40 %, the hose's +-50 %),
    the feed-forward's uncertainties as commissioning writes them
    (:func:`~seaforce_ros.commissioning.tuning.feedforward_uncertainties`, the class error
    ``size``); the free finger in dob_full_ff released anywhere in the +-0.5 rad stroke with a
    flick: it comes to rest (no limit cycle), runs no further out than where it started
    (plus 0.1 rad of the flick's travel) and never trips the monitor -- the unmodelled finger
    ratio and cogging included."""
    from seaforce_ros.commissioning.tuning import feedforward_uncertainties
    effects, coulomb = draw_effects(np.random.default_rng(seed))
    truth = model_terms(effects, TABLE_I)
    f = [1.0 + size * sgn for sgn in signs]
    model = TABLE_I.scaled(**dict(zip(FIELDS, f[:8])))
    dahl = DahlParams(sigma=DAHL.sigma * f[8], coulomb_force=DAHL.coulomb_force * f[9])
    k3 = truth.stroke_stiffness * (1.075 + 0.325 * term_errors[3])
    k2 = truth.stroke_asymmetry * (1.075 + 0.325 * term_errors[2])
    bound = math.sqrt(3.0 * model.endpoint_stiffness * k3)
    terms = PlantTermsParams(hose_flow=truth.hose_flow * (1.0 + 0.5 * term_errors[0]),
                             hose_pressure=truth.hose_pressure * (1.0 + 0.5 * term_errors[1]),
                             stroke_asymmetry=max(-bound, min(bound, k2)), stroke_stiffness=k3)
    sigmas = {"endpoint_damping": size * model.endpoint_damping,
              "endpoint_stiffness": size * model.endpoint_stiffness,
              "coulomb_force": size * dahl.coulomb_force}
    ff = feedforward_uncertainties(model, sigmas, dahl, size, terms)
    config = ControllerConfig.from_dict(ff, base=ControllerConfig(
        mode="dob_full_ff", plant=model, dahl=dahl, plant_terms=terms))
    sim = NonlinearChannelSimulator(TABLE_I, DAHL, effects, seed=seed, motor_coulomb=coulomb)
    sim.reset(state=(start, flick, start, flick))
    rig = CycleRig(sim, config)
    xe, ve = [], []
    for _ in range(16000):
        rig.step()
        xe.append(sim._z[2])
        ve.append(sim._z[3])
        assert not rig.controller.fallback, (rig.controller.fallback_reason, sim._z)
    last = np.array(ve[-2000:])
    assert float(np.sqrt(np.mean(last ** 2))) < 0.01, ff
    assert np.max(np.abs(xe)) < abs(start) + 0.1, (np.max(np.abs(xe)), ff)
    assert not rig.cycle.faults_latched

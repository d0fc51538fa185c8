"""The per-sample path gives the same floats as the core before its speed-ups.

Two control cycles -- the working tree's core and the core of :data:`BASELINE` (exported with
``git archive``: test/helpers/baseline_core.py) -- run in lock-step on one simulated plant: the
working tree's command drives it, both see the same states, and at every sample the two agree
to the bit (a float's repr: -0.0 is not +0.0) on everything the cycle and its controller give:
the command, the disturbance estimate, the endpoint observer's estimates, the contact
estimator's residual, bias, contacts and object estimate, the runaway monitor and its fall-back,
the walls, the passivity guard, the jobs' phases, outcomes, messages and feedback, the cycle's
faults, counts and reports.

The runs are random (seeded): the true plant and its Dahl friction 0.5x..2x of the model's
(Table I); mode switches (all nine modes, the mode set again or a parameter set within it) with
random targets and options -- the feed-forward without its margin (runaways: monitor trips and
fall-backs), the friction adaptation, the passivity guard (monitor, active), a narrow joint
range (the walls), a slow monitor, a Dahl exponent other than 1, another DOB cutoff;
environments: free, objects, a hand that drives the finger, a torque; jobs: grasps (with
probes, released), gripper commands, friction calibrations that apply their fit, a job refused
as busy, cancels; lost samples (``steps`` > 1), gaps, command time-outs (re-entries), a
non-finite state (a latched fault) and resets.

Skipped where the revision cannot be exported (no git history: a shallow clone).
"""

import dataclasses
import importlib
import math

import numpy as np
import pytest

import seaforce_ros.core as now_core
from helpers.baseline_core import BaselineUnavailable, load_core

#: The core whose behaviour the per-sample path keeps: 8e7ccaf (before the speed-ups of
#: 2026-12-05, which this test proved exact against it) until the walls ran once per sample
#: (2660397: the monitor's wall ledger no longer counts a sample twice), then until parameters
#: set within a mode stopped selecting it anew (72503fc: targets kept, a chirp not replayed;
#: 71c2b09: its re-entry after an interruption in the entry's sample bumpless again), then
#: until the feed-forward modes added the free finger's damping reserve (58f1b49; its band's
#: parameters e2ba8c5), then until the reserve acted through a high-pass (63ca16a), then until
#: a friction calibration applied the pressure offset it identifies (0c4c6e3), then until the
#: monitor's settling watch (fe3fcc2: its two parameters in the config; no float changed
#: where it does not trip), then until the verification's parameters (75f804c: the config's keys
#: only; no float changed).
#: A deliberate change of behaviour moves it; a speed-up never does.
BASELINE = "75f804c"
DT = 5e-4
_T0_NS = 1_700_000_000_000_000_000
FIELDS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
          "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")
STATUS_COMMAND_TIMEOUT = importlib.import_module(
    "seaforce_ros.core.plant_cycle").STATUS_COMMAND_TIMEOUT


@pytest.fixture(scope="module")
def before(tmp_path_factory):
    try:
        return load_core(BASELINE, tmp_path_factory.mktemp("baseline"))
    except BaselineUnavailable as err:
        pytest.skip(f"the baseline core: {err}")


def part(core, name):
    """The module ``name`` of ``core``."""
    return importlib.import_module(f"{core.__name__}.{name}")


# --- the random run, as plain data (each core builds its own objects from it) ------------------
def draw_config(rng):
    """A configuration: the mode and, per parameter group, the fields changed."""
    mode = str(rng.choice(now_core.MODES))
    groups = {
        "target": {"stiffness": rng.uniform(0.0, 2.0), "damping": rng.uniform(0.0, 0.09),
                   "force": rng.uniform(-0.4, 0.4)},
        "force_feedback": {"gain": rng.uniform(-1.0, 1.0)},
        "chirp": {"amplitude": rng.uniform(0.02, 0.2), "start_frequency": 0.5,
                  "end_frequency": rng.uniform(5.0, 200.0), "duration": rng.uniform(0.2, 1.5)},
        "friction": {"calibration_duration": rng.uniform(1.0, 2.5),
                     "adaptation": bool(rng.random() < 0.4),
                     "adaptation_time": rng.uniform(0.5, 5.0)},
        "grasp": {"probe_duration": 0.15, "squeeze_time": 0.05},
    }
    allow = False
    if rng.random() < 0.3:       # the paper's exact feed-forward: runaways on a plant that is off
        groups["feedforward"] = {"margin": 0.0, "dahl_stiffness_share": 1.0}
        allow = True
    if rng.random() < 0.3:
        groups["passivity"] = {"mode": str(rng.choice(["monitor", "active"])),
                               "reserve": rng.uniform(1e-5, 1e-3)}
    if rng.random() < 0.4:       # the walls within reach
        groups["limits"] = {"position_min": -0.9, "position_max": 0.8, "wall_band": 0.1}
        groups["friction"].update(position_min=-0.9, position_max=0.8)
    if rng.random() < 0.3:
        groups["monitor"] = {"max_speed": rng.uniform(2.5, 6.0),
                             "wall_energy": rng.uniform(1e-3, 2e-2),
                             "fallback": str(rng.choice(["dob", "passive"]))}
        groups["grasp"].update(max_closing_velocity=2.0, gripper_velocity=0.3)
    if rng.random() < 0.15:
        groups["dahl"] = {"exponent": float(rng.choice([0.7, 1.5]))}
    if rng.random() < 0.3:       # a small torque is no contact: the adaptation sees free motion
        groups["estimator"] = {"contact_threshold": 0.05}
        groups["friction"].update(adaptation=True, adaptation_time=0.5,
                                  min_velocity_excitation=0.01, min_position_excitation=0.001)
    if rng.random() < 0.3:
        groups["dob"] = {"cutoff": 2.0 * math.pi * rng.uniform(10.0, 40.0)}
    return {"mode": mode, "groups": groups, "allow": allow}


def build_config(core, spec):
    """``spec`` (:func:`draw_config`) as ``core``'s ControllerConfig."""
    config = core.ControllerConfig(mode=spec["mode"])
    changes = {name: dataclasses.replace(getattr(config, name), **fields)
               for name, fields in spec["groups"].items()}
    return config.replace(allow_non_passive=spec["allow"], **changes)


def valid_config(rng):
    """A configuration the working tree's core accepts (a draw it refuses is drawn again)."""
    while True:
        spec = draw_config(rng)
        try:
            build_config(now_core, spec)
        except now_core.SeaforceError:
            continue
        return spec


def draw_environment(rng, xe):
    """free; an object ahead of or behind the finger; a hand that moves the finger about a point
    in the range (into the walls too); a torque, small or strong enough to push the finger
    beyond the range."""
    kind = rng.choice(["free", "object", "hand", "torque", "push"])
    if kind == "object":
        side = 1.0 if rng.random() < 0.5 else -1.0
        return ("contact_object", float(np.clip(xe + side * rng.uniform(0.02, 0.5), -1.3, 1.3)),
                0.2 * 100.0 ** rng.random(), rng.uniform(0.02, 0.1))
    if kind == "hand":
        amplitude = rng.uniform(0.05, 1.0)
        return ("position_sine", amplitude, min(rng.uniform(0.3, 6.0), 6.0 / amplitude),
                2.0 * 25.0 ** rng.random(), 0.05 + 0.15 * rng.random(), rng.uniform(-0.8, 0.8))
    if kind == "torque":
        return ("torque_sine", rng.uniform(0.01, 0.3), rng.uniform(0.2, 5.0))
    if kind == "push":          # slow and strong: through the walls
        return ("torque_sine", rng.uniform(0.5, 1.5), rng.uniform(0.1, 0.5))
    return ("free",)


def make_environment(spec):
    kind, *args = spec
    if kind == "position_sine":
        amplitude, frequency, stiffness, damping, offset = args
        return now_core.position_sine(amplitude, frequency, stiffness=stiffness,
                                      damping=damping, offset=offset)
    return getattr(now_core, kind)(*args)


def draw_job(rng):
    kind = rng.choice(["grasp", "grasp", "gripper", "calibration"])
    if kind == "grasp":
        grip = rng.uniform(0.05, 0.4)
        return ("grasp", float(rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 1.2)), grip,
                grip + rng.uniform(0.05, 0.5), bool(rng.random() < 0.5))
    if kind == "gripper":
        return ("gripper", rng.uniform(-0.7, 0.7), rng.uniform(0.1, 1.0), rng.uniform(0.05, 0.5))
    return ("calibration", rng.uniform(0.1, 0.35), rng.uniform(0.3, 1.5), bool(rng.random() < 0.7))


def draw_plan(rng, samples):
    """``{sample: [action, ...]}``: what happens at which sample."""
    plan = {}
    k = 0
    while k < samples:
        k += int(rng.integers(100, 1500))
        what = rng.choice(["configure", "configure", "environment", "environment", "job",
                           "job", "cancel", "lose", "gap", "timeout", "nan"])
        plan.setdefault(k, []).append(str(what))
        if what == "nan":                           # a latched fault, cleared a while later
            plan.setdefault(k + int(rng.integers(5, 400)), []).append("reset")
        if what == "job" and rng.random() < 0.2:    # a second one: refused, the channel busy
            plan.setdefault(k + int(rng.integers(1, 50)), []).append("job")
    return plan


# --- one side of the lock-step --------------------------------------------------------------
class Side:
    """A ControlCycle over one ChannelController of ``core``."""

    def __init__(self, core, spec):
        self.core = core
        self.ctl = core.ChannelController(build_config(core, spec), DT)
        self.cycle = part(core, "control_cycle").ControlCycle(("pinch",), [self.ctl],
                                                              quiet_period=1e9)
        self.jobs = []

    def configure(self, spec, mode_set):
        self.cycle.configure_channels({0: build_config(self.core, spec)},
                                      (0,) if mode_set else ())

    def request_job(self, spec):
        kind, *args = spec
        config = self.ctl.config
        if kind == "grasp":
            grasp = part(self.core, "grasp")
            job = grasp.Grasp(grasp.GraspGoal("pinch", *args), config, DT)
        elif kind == "gripper":
            gripper = part(self.core, "gripper")
            job = gripper.GripperMove(gripper.GripperGoal("pinch", *args), config, DT,
                                      start=self.ctl.endpoint_position_estimate)
        else:
            calibration = part(self.core, "friction_calibration")
            job = calibration.FrictionCalibration(calibration.CalibrationGoal("pinch", *args),
                                                  config, DT)
        self.jobs.append(job)
        self.ctl.request_job(job)

    def cancel(self):
        if self.jobs and self.jobs[-1].active:
            self.jobs[-1].request_cancel("canceled")

    def step(self, k, x, v, f_p, f_a, status):
        now_ns = _T0_NS + int(round(k * DT * 1e9))
        out = self.cycle.step(["pinch"], k, now_ns, [x], [v], [f_p], [f_a], [status], now_ns,
                              k * DT)
        return out.effort[0] if out.answered else None, out.answered

    def snapshot(self, full):
        """Everything the cycle and the controller give (floats exact)."""
        ctl = self.ctl
        obs, est, mon, walls = ctl.observer, ctl.estimator, ctl.monitor, ctl.walls
        guard = ctl.passivity_guard
        values = [ctl.torque, ctl.disturbance, ctl.mode, ctl.fallback, ctl.fallback_reason,
                  ctl.beyond, obs.position, obs.velocity, obs.dahl_input, obs.dahl_force,
                  obs.compensation, obs.feedforward, obs.dahl_feedforward, est.contact,
                  est.direction, est.contacts, est.force, est.bias, est.detection, est.quiet,
                  est.position, est.velocity, est.onset_position, mon.over, mon.armed,
                  mon.wall_work, mon.reason, walls.force, walls.beyond,
                  None if guard is None else (guard.energy, guard.dissipated, guard.damping,
                                                guard.force, guard.fault),
                  self.cycle.fault(0), tuple(self.cycle.counts.items()),
                  self.cycle.faults_latched, tuple(self.cycle.events.drain()),
                  tuple((job.phase, job.outcome, job.message) for job in self.jobs)]
        if full:
            values.append(tuple(est.estimate()))
            values.append(linear_config(ctl.config))
            values.extend(tuple(sorted(job.feedback(est).items())) for job in self.jobs)
        return exact(values)


def linear_config(config):
    """The config's flat keys and values but those that came after the baseline
    (``plant_terms.*``, ``feedforward.stroke_uncertainty``, ``pressure_offset``) while every
    term and the offset are 0 (the linear model, no offset: at 0 they change no float)."""
    terms = getattr(config, "plant_terms", None)
    if terms is not None and any(getattr(terms, f.name) for f in dataclasses.fields(terms)):
        return config
    if getattr(config, "pressure_offset", 0.0):
        return config
    return tuple(sorted((k, v) for k, v in config.to_dict().items()
                        if not k.startswith("plant_terms.")
                        and k not in ("feedforward.stroke_uncertainty", "pressure_offset",
                                      "monitor.settle_time", "monitor.wall_time")))


def exact(values):
    """Each of ``values`` as text: a float's repr is its shortest exact decimal (NaN equals NaN,
    -0.0 is not +0.0), a dataclass's and a tuple's hold their fields' reprs."""
    return [repr(value) for value in values]


def lockstep(before, seed, seconds, script=None):
    """One random run (module docstring) of ``seconds``, or the run of ``script`` (the first
    configuration and the plan, some actions given as ``(action, what...)``) on a random
    plant: the samples compared and what the run reached (:data:`REACHED`)."""
    rng = np.random.default_rng(seed)
    f = np.exp(rng.uniform(-math.log(2.0), math.log(2.0), 10))
    plant = now_core.PlantParams.table_i().scaled(**dict(zip(FIELDS, f[:8])))
    model = now_core.DahlParams()
    dahl = now_core.DahlParams(sigma=model.sigma * f[8], coulomb_force=model.coulomb_force * f[9])
    sim = now_core.ChannelSimulator(plant, dahl, seed=seed, torque_saturation=20.0)
    spec, plan = (valid_config(rng), None) if script is None else script
    sides = (Side(before, spec), Side(now_core, spec))
    samples = int(round(seconds / DT))
    if plan is None:
        plan = draw_plan(rng, samples)
    k = 0
    u = 0.0
    timeout = 0
    seen = set()
    for i in range(samples):
        status = 0
        lost = 0
        for action in plan.get(i, ()):
            action, *given = (action,) if isinstance(action, str) else action
            seen.add(action)
            if action == "configure":
                same = rng.random() < 0.3     # a parameter set within the mode
                spec = valid_config(rng) if not same else dict(spec, groups=dict(
                    spec["groups"], target={"stiffness": rng.uniform(0.0, 2.0),
                                            "damping": rng.uniform(0.0, 0.09),
                                            "force": rng.uniform(-0.4, 0.4)}))
                mode_set = bool(rng.random() < 0.5)
                if given:
                    spec, mode_set = given
                for side in sides:
                    side.configure(spec, mode_set)
            elif action == "environment":
                environment = given[0] if given else draw_environment(rng, sim.state[2])
                sim.set_environment(make_environment(environment))
            elif action == "job":
                job = draw_job(rng)
                for side in sides:
                    side.request_job(job)
            elif action == "cancel":
                for side in sides:
                    side.cancel()
            elif action == "reset":
                for side in sides:
                    side.cycle.request_reset()
            elif action == "lose":
                lost = int(rng.integers(1, 4))
            elif action == "gap":
                lost = int(rng.integers(45, 90))
            elif action == "timeout":
                timeout = int(rng.integers(1, 60))
        for _ in range(lost):
            sim.step(u)
        k += 1 + lost
        m = sim.measurement()
        x = math.nan if "nan" in plan.get(i, ()) else m.x
        if timeout:
            timeout -= 1
            status = STATUS_COMMAND_TIMEOUT
        answers = [side.step(k, x, m.v, m.f_p, m.f_a, status) for side in sides]
        assert exact(answers[0]) == exact(answers[1]), (seed, i, answers)
        full = i % 97 == 0
        old, new = (side.snapshot(full) for side in sides)
        assert old == new, (seed, i, [(n, a, b) for n, (a, b) in enumerate(zip(old, new))
                                      if a != b])
        command, answered = answers[1]
        if answered:
            u = command
        sim.step(0.0 if status else u)
        seen.update(ctl_events(sides[1]))
    return samples, seen


def ctl_events(side):
    """What this sample showed of the things the runs must reach."""
    ctl = side.ctl
    events = set()
    if ctl.fallback:
        events.add("fallback")
    if ctl.walls.force != 0.0:
        events.add("walls" if ctl.walls.force < 0.0 else "low wall")
    if ctl.beyond:
        events.add("beyond")
    if ctl.adaptation.updates:
        events.add("adapted")
    if ctl._still >= ctl._standing - 1:
        events.add("standing")
    if ctl.estimator.contact:
        events.add("contact")
    if ctl.job is not None:
        events.add(type(ctl.job).__name__)
    if ctl.passivity_guard is not None and ctl.passivity_guard.damping:
        events.add("guard damps")
    if side.cycle.latched(0):
        events.add("latched")
    return events


#: What the runs of each group of seeds reach (a run changed so that one is no longer reached
#: must be drawn anew; :data:`SCRIPT` reaches what they reach seldom).
REACHED = {"configure", "job", "cancel", "lose", "gap", "timeout", "reset", "latched",
           "fallback", "walls", "contact", "guard damps", "Grasp", "GripperMove",
           "FrictionCalibration"}


@pytest.mark.parametrize("seeds", [range(0, 8), range(8, 16), range(16, 24)])
def test_every_float_is_the_baselines(before, seeds):
    """Random closed loops in lock-step with the baseline core (module docstring): at every
    sample the same floats, strings and events."""
    seen = set()
    for seed in seeds:
        _, events = lockstep(before, seed, 6.0)
        seen |= events
    assert REACHED <= seen, REACHED - seen


def configured(mode, **groups):
    """A configuration (as :func:`draw_config` gives it): ``mode`` and the fields changed."""
    return {"mode": mode, "groups": groups, "allow": False}


#: What the random runs reach seldom: the friction adaptation in dob_full_ff on a torque too
#: small to be a contact (its values go to the observer); a contact standing in hold (the
#: estimator re-armed); a hand that takes the finger through the low wall and beyond the range
#: (force_feedback: no monitor), a reset.
SCRIPT = (configured("dob_full_ff", estimator={"contact_threshold": 0.05},
                     friction={"adaptation": True, "adaptation_time": 0.5,
                               "min_velocity_excitation": 0.01,
                               "min_position_excitation": 0.001}),
          {0: [("environment", ("torque_sine", 0.03, 6.0))],
           10000: [("configure", configured("hold"), True),
                   ("environment", ("torque_sine", 0.3, 0.3))],
           16000: [("configure", configured("force_feedback"), True),
                   ("environment", ("position_sine", 0.1, 1.0, 5.0, 0.1, -1.8))],
           20000: ["reset"]})


def test_a_scripted_run_is_the_baselines(before):
    """What the random runs reach seldom (:data:`SCRIPT`), in lock-step: the same floats."""
    _, seen = lockstep(before, 99, 11.0, SCRIPT)
    assert {"adapted", "standing", "low wall", "beyond", "latched"} <= seen, seen

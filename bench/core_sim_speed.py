"""Speed of the control core: controller update, simulator step, closed loop.

Prints, in one run:
* samples/s of the simulator alone and of simulator + controller in every mode;
* mean and p99 time of one controller update in ``dob_full_ff`` (goal <= 10 us)
  and of one simulator step (goal <= 20 us), each next to a naive numpy
  implementation of the same computation (per-sample array construction and
  matrix products) measured in the same run;
* wall time of a 60 s closed-loop simulation at 2 kHz with ``run_closed_loop``
  (goal <= 3 s) next to the same loop built from the naive pieces;
* the contact estimator and the grasp logic per cycle (goal <= 5 us mean), over a recorded
  grasp (approach, contact, squeeze, probe, hold), next to the controller update without the
  estimator measured in the same run, and their ratio;
* the passivity guard per cycle, on a recorded run in which it acts (m_n = 0.1 m,
  lambda = 2 pi 50, stiff object), next to the controller update measured in the same run.

With ``--baseline REV`` it prints instead, in one run, the per-sample rows of a git revision
(exported with ``git archive`` into a temporary directory, its ``core`` imported beside the
working tree's) and of the working tree, timed interleaved in chunks of samples on the same
inputs, with their ratio: the controller update in ``dob_full_ff`` (the estimator's share
split out), the contact estimator alone and the update with a grasp; the simulator step, whose
code neither side changed, shows what the host's noise alone does to a ratio. Per row: the mean
and p99 of the per-call times over every repetition, and the floor: per chunk of samples the
repetition that ran fastest (the least disturbed by other processes), averaged. Then the
memory the update keeps, traced over N and 2N samples (no allocation per sample: it does not
grow).

With ``--stages`` it prints where the time of the ``dob_full_ff`` update goes: its parts alone
on the inputs they had in it (observer, estimator, the DOB step, the walls, the monitor), the
rest, and the update / simulator step ratio.

Timing figures are printed, never asserted.

Run:  PYTHONPATH=. python bench/core_sim_speed.py [--baseline main | --stages] [--quick]
      (--quick: every row on a few thousand samples, the closed loop 3 s: a smoke run)
"""

import argparse
import importlib
import math
import platform
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from seaforce_ros.core import (MODES, ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, position_sine, run_closed_loop)
from seaforce_ros.core.environment import contact_object
from seaforce_ros.core.estimator import ContactEstimator
from seaforce_ros.core.grasp import Grasp, GraspGoal
from seaforce_ros.core.params import DobParams, GuardParams
from seaforce_ros.core.passivity_guard import PassivityGuard
from seaforce_ros.core.simulator import discretise

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
from helpers import baseline_core  # noqa: E402

DT = 5e-4
PLANT = PlantParams.table_i()
DAHL = DahlParams()


class NaiveSimulator:
    """Baseline: the same exact ZOH plant + Dahl, written the obvious numpy way
    (state as an array, ``Phi @ z + Gamma @ u`` with a new input array per step)."""

    def __init__(self, plant, dahl, env):
        self.phi, self.gam = discretise(plant, DT, env.stiffness, env.damping, env.frequency)
        self.z = np.array([0.0, 0.0, 0.0, 0.0, 0.0, env.amplitude])
        self.fd = 0.0
        self.dahl = dahl
        self.ks, self.bs = plant.hose_stiffness, plant.hose_damping
        self.rng = np.random.default_rng(0)

    def step(self, torque):
        u = np.array([torque, -self.fd])
        z_new = self.phi @ self.z + self.gam @ u
        dx = z_new[2] - self.z[2]
        s = np.sign(dx)
        if s != 0:
            self.fd = s * self.dahl.coulomb_force + (self.fd - s * self.dahl.coulomb_force) * \
                np.exp(-self.dahl.sigma * abs(dx) / self.dahl.coulomb_force)
        self.z = z_new
        fp = self.ks * (z_new[2] - z_new[0]) + self.bs * (z_new[3] - z_new[1])
        fp += 5e-4 * self.rng.standard_normal()
        return np.array([z_new[0], z_new[1], fp])


class NaiveController:
    """Baseline dob_full_ff: the same equations with numpy scalars/arrays per sample."""

    def __init__(self, cfg):
        p = cfg.plant
        self.ks, self.bs, self.be, self.ke = (p.hose_stiffness, p.hose_damping,
                                              p.endpoint_damping, p.endpoint_stiffness)
        self.lam, self.mn = cfg.dob.cutoff, cfg.dob.nominal_inertia
        self.a = np.exp(-self.ks / self.bs * DT)
        self.state = np.zeros(4)            # delta, fp_prev, integ, e_prev
        self.fd, self.xd = 0.0, 0.0
        self.dahl = cfg.dahl

    def update(self, x, v, fp):
        st = self.state
        delta = self.a * st[0] + (1 - self.a) * np.mean(np.array([st[1], fp])) / self.ks
        xe = x + delta
        ve = v + (fp - self.ks * delta) / self.bs
        dx = xe - self.xd
        s = np.sign(dx)
        fc = self.dahl.coulomb_force
        self.fd = s * fc + (self.fd - s * fc) * np.exp(-self.dahl.sigma * abs(dx) / fc)
        self.xd = xe
        fref = np.dot(np.array([self.be, self.ke, 1.0]), np.array([ve, xe, self.fd]))
        e = fref + fp
        integ = st[2] + 0.5 * self.lam * DT * (e + st[3])
        u = fref + integ - self.lam * self.mn * v
        self.state = np.array([delta, fp, integ, e])
        return float(np.clip(u, -5.0, 5.0))


def stub_estimator(ctl):
    """Run ``ctl`` without its contact estimator: the estimator's class becomes a subclass
    whose update does nothing (its instance may have slots: no attribute to override)."""
    est = ctl.estimator
    est.__class__ = type("NoUpdate", (type(est),),
                         {"__slots__": (), "update": lambda self, *args: None})


def timed_calls(fn, args_iter, n):
    times = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        a = args_iter(i)
        t0 = clock()
        fn(*a)
        times[i] = clock() - t0
    return times * 1e-3      # us


def fmt(times):
    return f"mean {np.mean(times):6.2f} us   p99 {np.percentile(times, 99):6.2f} us"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", metavar="REV",
                        help="compare the per-sample rows with this git revision (e.g. main)")
    parser.add_argument("--repeats", type=int, default=5,
                        help="repetitions of each compared row (default 5)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: 2000 samples per row, one repetition, a 3 s loop")
    parser.add_argument("--stages", action="store_true",
                        help="time the stages of the dob_full_ff update instead")
    args = parser.parse_args(argv)
    print(f"Python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}")
    n = 2000 if args.quick else 40000
    if args.stages:
        return stage_rows(1 if args.quick else args.repeats)
    if args.baseline:
        return compare_rows(args.baseline, 1 if args.quick else args.repeats,
                            2000 if args.quick else 20000)
    env = position_sine(0.5, 1.0)
    best_of = 1 if args.quick else 3
    loop_seconds = 3.0 if args.quick else 60.0

    # --- throughput --------------------------------------------------------------
    def plant_alone():
        sim = ChannelSimulator(PLANT, DAHL, environment=env)
        step = sim.step
        t0 = time.perf_counter()
        for i in range(n):
            step(0.0)
        return n / (time.perf_counter() - t0)

    def with_controller(mode):
        sim = ChannelSimulator(PLANT, DAHL, environment=env)
        ctl = ChannelController(ControllerConfig(mode=mode))
        m = sim.measurement()
        update, step = ctl.update, sim.step
        t0 = time.perf_counter()
        for _ in range(n):
            m = step(update(m.x, m.v, m.f_p))
        return n / (time.perf_counter() - t0)

    # best of 3 runs of 20 s simulated time each (the machine may be shared)
    plant_rate = max(plant_alone() for _ in range(best_of))
    print(f"\nthroughput, best of {best_of} x {n} samples")
    print(f"simulator alone (position drive, Dahl, sensors): {plant_rate:8.0f} samples/s"
          f"  ({1e6 / plant_rate:5.1f} us/sample)")
    print("simulator + controller, plain loop (no recording):")
    for mode in MODES:
        rate = max(with_controller(mode) for _ in range(best_of))
        print(f"  {mode:15s} {rate:8.0f} samples/s  ({1e6 / rate:5.1f} us/sample)")

    # --- per-call timing: controller update ----------------------------------------
    cfg = ControllerConfig(mode="dob_full_ff")
    sim = ChannelSimulator(PLANT, DAHL, environment=env)
    rec = run_closed_loop(sim, ChannelController(cfg), n)
    xs, vs, fps = rec["x"].tolist(), rec["v"].tolist(), rec["f_p"].tolist()
    ctl = ChannelController(cfg)
    t_ctl = timed_calls(ctl.update, lambda i: (xs[i], vs[i], fps[i]), n)
    naive = NaiveController(cfg)
    t_ctl_naive = timed_calls(naive.update, lambda i: (xs[i], vs[i], fps[i]), n)
    print("\none controller update, dob_full_ff (goal <= 10 us):")
    print(f"  ChannelController.update      {fmt(t_ctl)}")
    print(f"  naive numpy baseline          {fmt(t_ctl_naive)}")

    # --- per-call timing: simulator step --------------------------------------------
    us = rec["u"].tolist()
    sim = ChannelSimulator(PLANT, DAHL, environment=env)
    t_sim = timed_calls(sim.step, lambda i: (us[i],), n)
    nsim = NaiveSimulator(PLANT, DAHL, env)
    t_sim_naive = timed_calls(nsim.step, lambda i: (us[i],), n)
    print("\none simulator step (goal <= 20 us):")
    print(f"  ChannelSimulator.step         {fmt(t_sim)}")
    print(f"  naive numpy baseline          {fmt(t_sim_naive)}")

    # --- 60 s closed loop -------------------------------------------------------------
    n60 = int(round(loop_seconds / DT))
    sim = ChannelSimulator(PLANT, DAHL, environment=env)
    t0 = time.perf_counter()
    run_closed_loop(sim, ChannelController(cfg), n60)
    wall = time.perf_counter() - t0
    nsim, nctl = NaiveSimulator(PLANT, DAHL, env), NaiveController(cfg)
    t0 = time.perf_counter()
    y = np.zeros(3)
    log = np.zeros((n60, 4))
    for i in range(n60):
        u = nctl.update(y[0], y[1], y[2])
        y = nsim.step(u)
        log[i] = (y[0], y[1], y[2], u)
    wall_naive = time.perf_counter() - t0
    print(f"\n{loop_seconds:g} s closed-loop simulation at 2 kHz, dob_full_ff, recording "
          f"(goal <= {loop_seconds / 20.0:g} s):")
    print(f"  run_closed_loop               {wall:6.2f} s  ({loop_seconds / wall:5.1f}x real time)")
    print(f"  naive numpy baseline          {wall_naive:6.2f} s  "
          f"({loop_seconds / wall_naive:5.1f}x real time)")
    grasp_rows()
    guard_rows(n // 2)
    return 0


def record_grasp():
    """A grasp on the simulator (object k = 2 N m/rad at 0.1 rad): per sample the controller's
    inputs (x, v, f_p), its X_e_hat, V_e_hat and F_d, and the grasp's phase."""
    sim = ChannelSimulator(PLANT, DAHL, environment=contact_object(0.1, 2.0, 0.06))
    cfg = ControllerConfig(mode="passive")
    ctl = ChannelController(cfg)
    grasp = Grasp(GraspGoal("pinch", 0.3, 0.4, 0.8, True), cfg)
    ctl.request_job(grasp)
    rows = []
    m = sim.measurement()
    while len(rows) < int(2.5 / DT):
        u = ctl.update(m.x, m.v, m.f_p)
        rows.append((m.x, m.v, m.f_p, ctl.endpoint_position_estimate,
                     ctl.endpoint_velocity_estimate, ctl.dahl_force, grasp.phase))
        m = sim.step(u)
    assert grasp.phase == "hold", grasp.message
    return cfg, rows


def grasp_rows():
    cfg, rows = record_grasp()
    n = len(rows)
    x, v, fp, xe, ve, fd, phase = (list(c) for c in zip(*rows))
    # the controller update as it was before the estimator (stubbed out), dob_full_ff
    plain = ChannelController(ControllerConfig(mode="dob_full_ff"))
    stub_estimator(plain)
    t_plain = timed_calls(plain.update, lambda i: (x[i], v[i], fp[i]), n)
    # the estimator alone, and the estimator + the grasp logic, on the recorded sequence
    est = ContactEstimator(cfg.estimator, cfg.plant)
    t_est = timed_calls(est.update, lambda i: (xe[i], fp[i], fd[i]), n)
    est = ContactEstimator(cfg.estimator, cfg.plant)
    grasp = Grasp(GraspGoal("pinch", 0.3, 0.4, 0.8, True), cfg)
    assert grasp.claim()
    update, g_update = est.update, grasp.update

    def both(i):
        update(xe[i], fp[i], fd[i])
        g_update(est, ve[i])
    t_both = timed_calls(both, lambda i: (i,), n)
    full = ChannelController(ControllerConfig(mode="passive"))
    full.request_job(Grasp(GraspGoal("pinch", 0.3, 0.4, 0.8, True), cfg))
    t_full = timed_calls(full.update, lambda i: (x[i], v[i], fp[i]), n)
    contact = np.array([p != "approach" for p in phase])
    print(f"\ncontact estimator + grasp logic per cycle, over a recorded {n * DT:.1f} s grasp "
          f"({np.mean(contact) * 100:.0f} % of it in contact) (goal <= 5 us mean):")
    print(f"  controller update, dob_full_ff, without estimator  {fmt(t_plain)}")
    print(f"  ContactEstimator.update                           {fmt(t_est)}")
    print(f"    free motion / in contact (mean)                 {np.mean(t_est[~contact]):6.2f} us"
          f" / {np.mean(t_est[contact]):6.2f} us")
    print(f"  estimator + Grasp.update                          {fmt(t_both)}")
    print(f"  controller update with a grasp (everything)       {fmt(t_full)}")
    print(f"  (estimator + grasp) / controller update without estimator: "
          f"{np.mean(t_both) / np.mean(t_plain):.2f}")



# --- passivity guard ---------------------------------------------------------------------------
def guard_rows(n=20000):
    """The guard alone per cycle on the inputs it saw in a run where it acts (``n`` samples),
    vs the controller update (dob, guard disabled) on the same samples, and the whole update
    with it active."""
    light = DobParams(cutoff=2 * math.pi * 50, nominal_inertia=0.1 * PLANT.motor_inertia)
    xe = -0.3 * 50.0 / (PLANT.endpoint_stiffness + 50.0)     # pressed in by k_e, kicked
    env = contact_object(-0.3, 50.0, 0.005)
    sim = ChannelSimulator(PLANT, DAHL, environment=env)
    sim.reset(state=(xe, 0.0, xe, 0.2), environment=env)
    active = ControllerConfig(mode="dob", dob=light, passivity=GuardParams(mode="active"))
    ctl = ChannelController(active)
    rows = []
    m = sim.measurement()
    for _ in range(n):
        u = ctl.update(m.x, m.v, m.f_p)
        rows.append((m.x, m.v, m.f_p))
        m = sim.step(u)
    acting = ctl.passivity_guard.dissipated
    x, v, fp = (list(c) for c in zip(*rows))
    guard = PassivityGuard(active.passivity, DT, light.nominal_inertia, active.max_torque)
    t_guard = timed_calls(guard.update, lambda i: (fp[i], x[i], v[i]), n)
    plain = ChannelController(active.replace(passivity=GuardParams(), allow_non_passive=True))
    t_plain = timed_calls(plain.update, lambda i: (x[i], v[i], fp[i]), n)
    full = ChannelController(active)
    t_full = timed_calls(full.update, lambda i: (x[i], v[i], fp[i]), n)
    print(f"\npassivity guard per cycle, over a recorded {n * DT:.1f} s run in stiff contact with "
          f"m_n = 0.1 m (the guard dissipated {acting * 1e3:.2f} mJ):")
    for name, t in (("controller update, dob, guard disabled           ", t_plain),
                    ("PassivityGuard.update                            ", t_guard),
                    ("controller update, dob, guard active (everything)", t_full)):
        print(f"  {name} {fmt(t)}   median {np.median(t):5.2f} us")
    print(f"  guard / controller update without it (medians): "
          f"{np.median(t_guard) / np.median(t_plain):.2f}")


# --- the stages of the update -------------------------------------------------------------------
def stage_rows(repeats):
    """Where the time of a dob_full_ff update goes: each part alone on the inputs it had in the
    update (the free-motion samples of the compared rows: a hand moves the finger, which the
    estimator sees as a contact), next to the whole update and the simulator step, interleaved
    like the compared rows; every row less a call that does nothing."""
    n = 20000
    sim = ChannelSimulator(PLANT, DAHL, environment=position_sine(0.5, 1.0))
    rec = run_closed_loop(sim, ChannelController(ControllerConfig(mode="dob_full_ff")), n)
    x, v, fp, u = (rec[k].tolist() for k in ("x", "v", "f_p", "u"))
    cfg = ControllerConfig(mode="dob_full_ff")
    ctl = ChannelController(cfg)
    seen = []                           # what the parts saw: X_e_hat, F_d, F_ref, V_e_hat
    for i in range(n):
        ui = ctl.update(x[i], v[i], fp[i])
        obs = ctl.observer
        seen.append((obs.position, obs.dahl_force, ui - ctl.disturbance, obs.velocity))
    xe, fd, f_ref, ve = (list(c) for c in zip(*seen))

    def part(build):
        def make():
            return build(ChannelController(cfg))
        return make

    def nothing(i):
        pass

    def observer(c):
        update = c.observer.update
        return lambda i: update(x[i], v[i], fp[i])

    def estimator(c):
        update = c.estimator.update
        return lambda i: update(xe[i], fp[i], fd[i])

    def dob(c):
        update = c._dob.update
        return lambda i: update(f_ref[i], x[i], v[i], fp[i])

    def walls(c):
        update = c.walls.update
        return lambda i: update(x[i], v[i], xe[i], ve[i])

    def monitor(c):
        update = c.monitor.update
        return lambda i: update(v[i], ve[i])

    def whole(c):
        update = c.update
        return lambda i: update(x[i], v[i], fp[i])

    def simulator(c):
        step = ChannelSimulator(PLANT, DAHL, environment=position_sine(0.5, 1.0)).step
        return lambda i: step(u[i])

    makers = {"a call that does nothing": lambda: nothing,
              "ChannelController.update, dob_full_ff": part(whole),
              "  EndpointObserver.update": part(observer),
              "  ContactEstimator.update": part(estimator),
              "  DisturbanceObserver.update (written out)": part(dob),
              "  JointWalls.update (skipped while clear)": part(walls),
              "  RunawayMonitor.update (skipped while calm)": part(monitor),
              "ChannelSimulator.step": part(simulator)}
    res = interleaved(makers, [(i,) for i in range(n)], repeats)
    empty = res["a call that does nothing"][1]
    floors = {label: floor - empty for label, (_, floor) in res.items()}
    print(f"\nthe stages of a dob_full_ff update, each alone on its inputs in the update "
          f"(floor per call [us], less {empty:.2f} us of a call that does nothing)")
    for label, floor in floors.items():
        if label != "a call that does nothing":
            print(f"  {label:46s} {floor:6.2f}")
    whole_t = floors["ChannelController.update, dob_full_ff"]
    rest = whole_t - floors["  EndpointObserver.update"] - floors["  ContactEstimator.update"]
    print(f"  {'the rest (hand-overs, mode, checks, DOB step)':46s} {rest:6.2f}")
    print(f"  update / simulator step: {whole_t / floors['ChannelSimulator.step']:.2f}")
    return 0


# --- before / after, in one run ----------------------------------------------------------------
def load_core(rev, directory):
    """The ``seaforce_ros.core`` of git revision ``rev``, exported into ``directory``
    (test/helpers/baseline_core.py)."""
    try:
        return baseline_core.load_core(rev, directory)
    except baseline_core.BaselineUnavailable as err:
        raise SystemExit(f"--baseline {err}")


def interleaved(makers, samples, repeats, chunk=500):
    """Per-call times [us] of each ``makers[label]()`` (a fresh callable per repetition) over
    ``samples`` (argument tuples), the labels taking turns chunk by chunk (in a rotating
    order) so that both see the same load. Returns ``{label: (times, floor)}``: ``times`` of
    shape (repeats, n); ``floor`` the mean per call of the fastest repetition of each chunk."""
    n = len(samples)
    labels = list(makers)
    times = {label: np.empty((repeats, n)) for label in labels}
    clock = time.perf_counter_ns
    for r in range(repeats):
        calls = {label: make() for label, make in makers.items()}
        for c, start in enumerate(range(0, n, chunk)):
            k = (c + r) % len(labels)
            for label in labels[k:] + labels[:k]:
                fn, row = calls[label], times[label][r]
                for i in range(start, min(n, start + chunk)):
                    a = samples[i]
                    t0 = clock()
                    fn(*a)
                    row[i] = clock() - t0
    result = {}
    for label, t in times.items():
        t = t * 1e-3
        chunks = [t[:, s:s + chunk].sum(axis=1).min() for s in range(0, n, chunk)]
        result[label] = (t, sum(chunks) / n)
    return result


def kept_memory(update, samples):
    """Traced memory [B] after N updates and after 2N (``samples`` holds 2N + a warm-up)."""
    n = (len(samples) - 1000) // 2
    for a in samples[:1000]:
        update(*a)
    tracemalloc.start()
    try:
        for a in samples[1000:1000 + n]:
            update(*a)
        first = tracemalloc.get_traced_memory()[0]
        for a in samples[1000 + n:1000 + 2 * n]:
            update(*a)
        second = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    return n, first, second


def compare_rows(rev, repeats, n=20000):
    """The per-sample rows of ``rev`` and of the working tree, interleaved (module docstring),
    on ``n`` samples."""
    directory = tempfile.mkdtemp(prefix="seaforce-baseline-")
    try:
        old = load_core(rev, directory)
        sides = (("before", old), ("after", sys.modules["seaforce_ros.core"]))
        env = position_sine(0.5, 1.0)
        sim = ChannelSimulator(PLANT, DAHL, environment=env)
        rec = run_closed_loop(sim, ChannelController(ControllerConfig(mode="dob_full_ff")), n)
        free = list(zip(rec["x"].tolist(), rec["v"].tolist(), rec["f_p"].tolist()))
        torques = [(u,) for u in rec["u"].tolist()]
        cfg, rows = record_grasp()
        grasp_in = [r[:3] for r in rows]
        estimator_in = [(r[3], r[2], r[5]) for r in rows]

        def update(core, without_estimator=False):
            def make():
                ctl = core.ChannelController(core.ControllerConfig(mode="dob_full_ff"))
                if without_estimator:
                    stub_estimator(ctl)
                return ctl.update
            return make

        def estimator(core):
            def make():
                c = core.ControllerConfig(mode="passive")
                module = importlib.import_module(core.__name__ + ".estimator")
                return module.ContactEstimator(c.estimator, c.plant).update
            return make

        def grasping(core):
            def make():
                c = core.ControllerConfig(mode="passive")
                ctl = core.ChannelController(c)
                module = importlib.import_module(core.__name__ + ".grasp")
                request = getattr(ctl, "request_job", None) or ctl.request_grasp   # older
                request(module.Grasp(module.GraspGoal("pinch", 0.3, 0.4, 0.8, True), c))
                return ctl.update
            return make

        def simulator(core):
            def make():
                return core.ChannelSimulator(core.PlantParams.table_i(), core.DahlParams(),
                                             environment=core.position_sine(0.5, 1.0)).step
            return make

        table = (("ChannelController.update, dob_full_ff", update, free),
                 ("  the same, estimator stubbed out", lambda c: update(c, True), free),
                 ("ContactEstimator.update (recorded grasp)", estimator, estimator_in),
                 ("ChannelController.update with a grasp", grasping, grasp_in),
                 ("ChannelSimulator.step (same code: noise)", simulator, torques))
        print(f"\nbefore = {rev}, after = the working tree; per call [us], {repeats} "
              f"repetitions interleaved in chunks of 500 samples")
        print(f"{'':42s} {'mean':>13s} {'ratio':>6s}  {'floor':>13s} {'ratio':>6s}  "
              f"{'p99':>13s}")
        print(f"{'':42s} {'before after':>13s} {'':6s}  {'before after':>13s} {'':6s}  "
              f"{'before after':>13s}")
        for name, maker, samples in table:
            res = interleaved({label: maker(core) for label, core in sides}, samples, repeats)
            (tb, fb), (ta, fa) = res["before"], res["after"]
            print(f"{name:42s} {tb.mean():6.2f} {ta.mean():6.2f} {ta.mean() / tb.mean():6.2f}  "
                  f"{fb:6.2f} {fa:6.2f} {fa / fb:6.2f}  "
                  f"{np.percentile(tb, 99):6.2f} {np.percentile(ta, 99):6.2f}")
        more = list(zip(rec["x"].tolist(), rec["v"].tolist(), rec["f_p"].tolist()))
        print("\nmemory kept by ChannelController.update, dob_full_ff (traced after N and 2N "
              "updates):")
        for label, core in sides:
            ctl = core.ChannelController(core.ControllerConfig(mode="dob_full_ff"))
            k, first, second = kept_memory(ctl.update, more)
            print(f"  {label:6s}  N = {k}: {first} B, 2N: {second} B ({second - first:+d} B)")
    finally:
        shutil.rmtree(directory, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

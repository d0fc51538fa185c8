"""The per-sample path keeps no memory: traced memory after N more updates is what it was after
N (a container built per sample and kept, or a list that grows with the samples, would show in
every stretch of N)."""
import tracemalloc

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig, DahlParams,
                               PlantParams, position_sine, run_closed_loop)
from seaforce_ros.core.environment import contact_object
from seaforce_ros.core.estimator import BLOCK, ContactEstimator
from seaforce_ros.core.grasp import Grasp, GraspGoal

PLANT = PlantParams.table_i()
N = 4 * BLOCK * 6      # several folds of the estimator's block in each half


def memory_growth(update, samples):
    """Traced memory growth [B] per third of ``samples`` after the first tenth (first-sample
    and first-fold set-up): the smaller of the second third's and the last third's. Growth
    that goes with the samples shows in both; a one-off allocation (a contact that starts
    anew builds its fit's state once) in one only."""
    warm = len(samples) // 10
    third = (len(samples) - warm) // 3
    for args in samples[:warm]:
        update(*args)
    tracemalloc.start()
    try:
        marks = []
        for k in range(3):
            for args in samples[warm + k * third:warm + (k + 1) * third]:
                update(*args)
            marks.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    return min(marks[1] - marks[0], marks[2] - marks[1], key=abs)


def recorded(environment, n, mode):
    sim = ChannelSimulator(PLANT, DahlParams(), environment=environment)
    rec = run_closed_loop(sim, ChannelController(ControllerConfig(mode=mode)), n)
    return list(zip(rec["x"].tolist(), rec["v"].tolist(), rec["f_p"].tolist()))


def test_a_dob_full_ff_update_keeps_no_memory():
    samples = recorded(position_sine(0.5, 1.0), 3 * N, "dob_full_ff")
    ctrl = ChannelController(ControllerConfig(mode="dob_full_ff"))
    assert abs(memory_growth(ctrl.update, samples)) < 512


def test_the_estimator_in_contact_keeps_no_memory():
    """A grasp's squeeze and hold: every sample goes to the fit's block, folded every BLOCK
    samples."""
    sim = ChannelSimulator(PLANT, DahlParams(), environment=contact_object(0.1, 2.0, 0.06))
    cfg = ControllerConfig(mode="passive")
    ctrl = ChannelController(cfg)
    ctrl.request_job(Grasp(GraspGoal("pinch", 0.3, 0.4, 0.8, True), cfg))
    inputs = []
    m = sim.measurement()
    while len(inputs) < 3 * N or not ctrl.estimator.contact:
        u = ctrl.update(m.x, m.v, m.f_p)
        if ctrl.estimator.contact:
            inputs.append((ctrl.endpoint_position_estimate, m.f_p, ctrl.dahl_force))
        m = sim.step(u)
    est = ContactEstimator(cfg.estimator, cfg.plant)
    assert abs(memory_growth(est.update, inputs)) < 512
    assert est.contact

"""Commissioning run on the nonlinear oracle (:mod:`helpers.nonlinear_sim`): the project's own
excitation job inside its controller, the oracle as the gripper, then the project's analysis
stages (identification, tuning) and backdrives of the tuned controller on the oracle.

The family: each Table I parameter, sigma and F_c log-uniform in [0.5x, 2x] (as the
commissioning family) and every nonlinear effect drawn within its range
(:func:`helpers.nonlinear_sim.draw_effects`); :func:`draw` gives one draw.
"""
from __future__ import annotations

import math

import numpy as np

from helpers.free_air_records import draw as draw_linear
from helpers.nonlinear_sim import Unpowered, backdrive, draw_effects, free_air_excitation

DT = 5e-4


def draw(rng, effects=True):
    """``(plant dict, dahl dict, Effects)`` of one draw (effects off with ``effects=False``,
    the magnitudes still drawn so that the random stream is the same)."""
    plant, dahl = draw_linear(rng)
    drawn = draw_effects(rng)
    if not effects:
        from helpers.nonlinear_sim import linear_counterpart
        drawn = linear_counterpart(drawn)
    return plant, dahl, drawn


def excite(plant, dahl, effects, config=None, seed=0, duration=None, band=None, start=0.0,
           settle=0.0, sensors=None):
    """The project's free-air excitation job (commissioning) run by its controller on the
    oracle (its ``sensors``: :class:`helpers.nonlinear_sim.Sensors`, default the rig's), the
    finger at rest at ``start`` [rad] left unpowered ``settle`` [s] first; returns the job's
    :class:`ExcitationRecord` (raises if the job did not succeed)."""
    from seaforce_ros.commissioning.excitation import ExcitationGoal, FreeAirExcitation
    from seaforce_ros.core.controller import ChannelController
    from seaforce_ros.core.params import ControllerConfig
    config = (config or ControllerConfig()).replace(mode="passive")
    ctrl = ChannelController(config, DT)
    job = FreeAirExcitation(ExcitationGoal("sim", band, duration), config, DT)
    ctrl.request_job(job)
    free_air_excitation(plant, dahl, effects, ctrl, job, job.capacity, seed=seed, start=start,
                        settle=settle, sensors=sensors)
    if job.outcome != "succeeded":
        raise RuntimeError(f"the excitation ended {job.outcome}: {job.message}")
    return job.record()


def identify(record):
    from seaforce_ros.commissioning.free_air import identify_free_air
    return identify_free_air(record)


def tuned_config(ident, record, config=None, terms=None):
    """The analysis' tuning stage on an identification (and the candidate nonlinear terms,
    if given); the tuned ControllerConfig."""
    from seaforce_ros.commissioning.analyse import (AnalysisRequest, loop_stage, model_stage,
                                                    tune_stage)
    from seaforce_ros.core.params import ControllerConfig
    config = config or ControllerConfig()
    _, loop = loop_stage(record, config)
    return tune_stage(model_stage(ident, terms), loop, AnalysisRequest("sim", config)).config


def figures(plant, dahl, effects, config, mode, omega=1.0, amplitude=0.5, seed=0,
            sensors=None):
    """The impedance figures of a backdrive of ``mode`` on the oracle (with its ``sensors``)."""
    from seaforce_ros.core.analysis import impedance_figures
    from seaforce_ros.core.controller import ChannelController
    ctrl = (Unpowered() if mode == "passive" and config is None
            else ChannelController(config.replace(mode=mode), DT))
    rec = backdrive(plant, dahl, effects, ctrl, amplitude, omega, periods=1,
                    settle=max(1.0, 2.0 * math.pi / omega), seed=seed, sensors=sensors)
    return impedance_figures(rec["f_e"], rec["x_e"], omega, rec["dt"])


def truth(plant, dahl):
    """The oracle's parameters as the identification names them."""
    return dict(plant, **(dahl or {}))


def relative_errors(ident, plant, dahl):
    t = truth(plant, dahl)
    return {k: ident.value(k) / t[k] - 1.0 for k in t if k in ident.parameters}


__all__ = ["draw", "excite", "identify", "tuned_config", "figures", "truth",
           "relative_errors", "np"]


def release(plant, dahl, effects, config, start, seconds=6.0, seed=0, sensors=None):
    """The free finger on the oracle (with its ``sensors``), at rest at ``start`` [rad] (motor
    and endpoint there, the hose relaxed), released under the project's controller with
    ``config``. Returns the true ``x_e``, ``v_e`` per sample, ``dt`` and the controller's
    first ``fallback`` ('' if none)."""
    from helpers.nonlinear_sim import NonlinearGripper
    from seaforce_ros.core.controller import ChannelController
    g = NonlinearGripper(plant, dahl, effects, None, seed=seed, sensors=sensors)
    g.place(start)
    ctrl = ChannelController(config, g.dt)
    n = int(round(seconds / g.dt))
    xe, ve = np.empty(n), np.empty(n)
    fallback = ""
    m = g.measurement()
    for k in range(n):
        ctrl.cycle = k
        ctrl.applied = m.f_a
        u = ctrl.update(m.x, m.v, m.f_p)
        fallback = fallback or ctrl.fallback
        xe[k], ve[k] = g.state[2], g.state[3]
        m = g.step(u)
    return {"x_e": xe, "v_e": ve, "dt": g.dt, "fallback": fallback}


def commission(plant, dahl, effects, sensors=None, config=None, seed=0, duration=None,
               verify=True):
    """A whole commissioning run on the oracle, as ``~/commission`` runs it on a gripper: the
    excitation job, the analysis' proposal, the verification job on the same finger (``verify``
    False: none, the model class's candidate unverified), the analysis' finish. Returns
    ``(Analysis, rig time [s], the analysis' CPU time [s])``."""
    import time
    from helpers.nonlinear_sim import run_loop
    from seaforce_ros.commissioning.analyse import AnalysisRequest, Verified, finish, propose
    from seaforce_ros.commissioning.excitation import ExcitationGoal, FreeAirExcitation
    from seaforce_ros.commissioning.verification import FreeFingerVerification
    from seaforce_ros.core.controller import ChannelController
    from seaforce_ros.core.params import ControllerConfig
    config = (config or ControllerConfig(max_torque=20.0)).replace(mode="passive")
    ctrl = ChannelController(config, DT)
    job = FreeAirExcitation(ExcitationGoal("sim", None, duration), config, DT)
    ctrl.request_job(job)
    rec, gripper = free_air_excitation(plant, dahl, effects, ctrl, job, job.capacity,
                                       seed=seed, sensors=sensors)
    if job.outcome != "succeeded":
        raise RuntimeError(f"the excitation ended {job.outcome}: {job.message}")
    record = job.record()
    rig = len(rec["t"]) * DT
    request = AnalysisRequest("sim", config)
    cpu = time.process_time()
    proposal = propose(record, request)
    cpu = time.process_time() - cpu
    verified = None
    if verify and proposal.candidates:
        check = FreeFingerVerification(proposal.candidates, config, DT)
        ctrl.request_job(check)
        out = run_loop(gripper, ctrl, int(300.0 / DT), job_done=lambda: not check.active)
        rig += len(out["t"]) * DT
        verified = Verified(check.outcomes, check.chosen, len(out["t"]) * DT,
                            "" if check.outcome == "succeeded" else check.message)
    t = time.process_time()
    analysis = finish(proposal, request, verified)
    return analysis, rig, cpu + time.process_time() - t

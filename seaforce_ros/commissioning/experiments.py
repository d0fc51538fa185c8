"""Commissioning's experiments on the core simulator: what a lab would run on its gripper.

:func:`simulate_excitation` runs a :class:`~.excitation.FreeAirExcitation` inside a
:class:`~..core.controller.ChannelController` configured with the *model* (which may be
wrong) on a :class:`~..core.simulator.ChannelSimulator` of the *true* plant and Dahl
hysteresis, with the simulator's sensors (quantised encoders, pressure ADC and noise) and its
one-sample command delay, in the order of the sim node's lockstep mode (measurement ->
controller -> plant step). :func:`run_free_air_excitation` is the same, returning the record
of a successful excitation and raising :class:`ExcitationFailed` otherwise. Deterministic per
``seed`` (the simulator's noise generator); a 40 s record takes a few seconds.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from ..core.controller import ChannelController
from ..core.environment import Environment
from ..core.params import ControllerConfig, DahlParams, PlantParams
from ..core.sensors import SensorParams
from ..core.simulator import ChannelSimulator
from .errors import CommissioningError
from .excitation import ExcitationGoal, FreeAirExcitation
from .record import ExcitationRecord

__all__ = ["ExcitationRun", "ExcitationFailed", "simulate_excitation",
           "run_free_air_excitation"]


@dataclass(frozen=True)
class ExcitationRun:
    """One simulated excitation.

    Attributes
    ----------
    record : ExcitationRecord
        What the controller saw, with the simulator's true endpoint position ``x_e`` [rad]
        and external force ``f_e`` [N m] filled in.
    job : FreeAirExcitation
        The job, done: ``outcome``, ``message``, ``peak_position``, ``peak_speed``, ...
    output : float array
        The controller's torque command at every sample it ran [N m] (the job's samples,
        the one it ended on, then ``settle`` samples of the mode).
    ended : int
        Index in ``output`` of the sample the job ended on.
    contact_after : bool
        The channel's contact estimator sees a contact after the ``settle`` samples.
    """

    record: ExcitationRecord
    job: FreeAirExcitation
    output: np.ndarray
    ended: int
    contact_after: bool = False

    @property
    def outcome(self) -> Optional[str]:
        """The job's outcome."""
        return self.job.outcome


class ExcitationFailed(CommissioningError):
    """The simulated excitation did not succeed (aborted: a contact, a limit); ``run`` holds
    what it recorded."""

    def __init__(self, run: ExcitationRun) -> None:
        super().__init__(f"the free-air excitation ended {run.job.outcome}: {run.job.message}")
        self.run = run


def simulate_excitation(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                        model_config: ControllerConfig, *,
                        sensors: Optional[SensorParams] = None, seed: int = 0,
                        duration: Optional[float] = None,
                        band: Optional[tuple[float, float]] = None,
                        environment: Optional[Environment] = None,
                        start: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
                        mode: str = "passive", settle: int = 0,
                        cancel_after: Optional[int] = None,
                        dt: float = 5e-4) -> ExcitationRun:
    """Run one free-air excitation in closed loop (module docstring).

    Parameters
    ----------
    true_plant, true_dahl : PlantParams, DahlParams or None
        The simulated gripper.
    model_config : ControllerConfig
        The controller's configuration (its model may be wrong; its ``commissioning`` group
        sets the excitation); ``mode`` replaces its mode (the mode before and after the job).
    sensors : SensorParams, optional
        The simulator's sensors (default ``SensorParams()``).
    seed : int
        The simulator's noise seed.
    duration, band : optional
        The goal's chirp duration [s] and band (start, end) [Hz] (None: the config's).
    environment : Environment, optional
        Default free air; an object tests the contact abort.
    start : (X, V, X_e, V_e)
        The simulator's initial state [rad, rad/s].
    settle : int
        Samples to run the mode after the job ends.
    cancel_after : int, optional
        Cancel the job (:meth:`~.excitation.FreeAirExcitation.request_cancel`) after this many
        samples.
    dt : float
        Sample period [s].
    """
    config = model_config.replace(mode=mode)
    sim = ChannelSimulator(true_plant, true_dahl, dt, seed=seed, environment=environment,
                           sensors=sensors)
    sim.reset(start)
    ctrl = ChannelController(config, dt)
    job = FreeAirExcitation(ExcitationGoal("sim", band, duration), config, dt)
    ctrl.request_job(job)
    n = job.capacity
    x_e = np.full(n, np.nan)
    f_e = np.full(n, np.nan)
    output = np.zeros(n + 1 + settle)
    update = ctrl.update
    step = sim.step
    m = sim.measurement()
    k = 0
    recorded = 0
    while job.active and k < n + 1:
        if k == cancel_after:
            job.request_cancel()
        ctrl.cycle = k
        ctrl.applied = m.f_a
        u = update(m.x, m.v, m.f_p)
        output[k] = u
        if len(job) > recorded:
            x_e[recorded] = m.x_e
            f_e[recorded] = m.f_e
            recorded += 1
        m = step(u)
        k += 1
    if job.active:      # cannot happen: the job records every sample and ends in time
        job.abort_now("the simulation ran past the job's capacity")
    ended = k - 1
    for i in range(settle):
        ctrl.cycle = k
        ctrl.applied = m.f_a
        u = update(m.x, m.v, m.f_p)
        output[k] = u
        m = step(u)
        k += 1
    record = replace(job.record(), x_e=x_e[:recorded], f_e=f_e[:recorded])
    return ExcitationRun(record, job, output[:k].copy(), ended, ctrl.estimator.contact)


def run_free_air_excitation(true_plant: PlantParams, true_dahl: Optional[DahlParams],
                            model_config: ControllerConfig, *,
                            sensors: Optional[SensorParams] = None, seed: int = 0,
                            duration: Optional[float] = None,
                            band: Optional[tuple[float, float]] = None,
                            dt: float = 5e-4) -> ExcitationRecord:
    """The record of a successful free-air excitation of ``true_plant``/``true_dahl`` run by a
    controller configured with ``model_config`` (:func:`simulate_excitation`, free air,
    from rest at 0, ``passive`` before and after), ``x_e``/``f_e`` holding the simulator's
    truth.

    Raises
    ------
    ExcitationFailed
        The job did not succeed (its ``run`` has the record so far and the reason).
    """
    run = simulate_excitation(true_plant, true_dahl, model_config, sensors=sensors,
                              seed=seed, duration=duration, band=band, dt=dt)
    if run.outcome != "succeeded":
        raise ExcitationFailed(run)
    return run.record

"""Free-air excitation records for the commissioning tests and benches.

Until ``seaforce_ros.commissioning.experiments.run_free_air_excitation`` (the real excitation
job) is available, these stand in for it: a log chirp of motor torque, 0.3-800 Hz over 40 s,
its amplitude shaped on the *model's* free-air admittance (Table I) to keep |X| < ~0.5 rad and
|V| < ~5 rad/s (half of 1 rad and 10 rad/s), at most 0.5 N m, under a weak centring PD servo
(K_p = 0.1 N m/rad, K_d = 0.002 N m s/rad) on the measured motor state. Two plants:

* :func:`second_sim_record` -- :mod:`helpers.second_sim` (independent of seaforce_ros);
* :func:`core_sim_record` -- the project's :class:`~seaforce_ros.core.simulator.ChannelSimulator`
  in a free environment.
"""
import math

import numpy as np

from helpers.second_sim import DAHL, KEYS, TABLE_I, motor_chirp, simulate_motor_excitation
from seaforce_ros.commissioning.record import ExcitationRecord

SERVO = (0.1, 0.002)
DT = 5e-4


def as_record(data, dt=DT):
    """An :class:`ExcitationRecord` from a dict of arrays (``x v f_p applied command
    excitation``)."""
    n = len(data["x"])
    return ExcitationRecord(dt, np.arange(n, dtype=np.int64), data["x"], data["v"],
                            data["f_p"], data["applied"], data["command"], data["excitation"])


def second_sim_record(plant=None, dahl=None, seed=0, ideal=False, **chirp):
    """A record from the second simulator (``ideal``: no noise, no quantisation, 8 substeps;
    else the rig's sensors, 4 substeps)."""
    plant = dict(TABLE_I) if plant is None else plant
    sensors = (dict(pressure_noise=0.0, pressure_bits=0, motor_counts=0, substeps=8) if ideal
               else dict(substeps=4))
    exc = motor_chirp(TABLE_I, servo=SERVO, **chirp)
    return as_record(simulate_motor_excitation(plant, dahl, excitation=exc, servo=SERVO,
                                               seed=seed, **sensors))


def core_sim_record(plant=None, dahl=None, seed=0, **chirp):
    """A record from the core simulator (its default sensors, free endpoint)."""
    from seaforce_ros.core.params import DahlParams, PlantParams
    from seaforce_ros.core.simulator import ChannelSimulator
    p = PlantParams(**(dict(TABLE_I) if plant is None else plant))
    d = None if dahl is None else DahlParams(**dahl)
    sim = ChannelSimulator(p, d, dt=DT, seed=seed)
    exc = motor_chirp(TABLE_I, servo=SERVO, **chirp)
    n = exc.size
    out = {k: np.empty(n) for k in ("x", "v", "f_p", "applied", "command")}
    kp, kd = SERVO
    m = sim.measurement()
    exc_l = exc.tolist()
    for i in range(n):
        u = exc_l[i] - kp * m.x - kd * m.v
        out["x"][i], out["v"][i], out["f_p"][i], out["applied"][i] = m.x, m.v, m.f_p, m.f_a
        out["command"][i] = u
        m = sim.step(u)
    out["excitation"] = exc
    return as_record(out)


def draw(rng):
    """One draw of the commissioning family: each Table I parameter, sigma and F_c
    log-uniform in [0.5x, 2x]. Returns ``(plant dict, dahl dict)``."""
    lo, hi = math.log(0.5), math.log(2.0)
    plant = {k: TABLE_I[k] * math.exp(rng.uniform(lo, hi)) for k in KEYS}
    dahl = {k: v * math.exp(rng.uniform(lo, hi)) for k, v in DAHL.items()}
    return plant, dahl


#: The goals: parameter -> relative tolerance.
GOALS = {"motor_inertia": 0.05, "endpoint_inertia": 0.05, "hose_stiffness": 0.05,
         "motor_damping": 0.15, "motor_stiffness": 0.15, "endpoint_damping": 0.15,
         "endpoint_stiffness": 0.15, "hose_damping": 0.15, "sigma": 0.25,
         "coulomb_force": 0.25}


def errors(result, plant, dahl):
    """Relative error per parameter of a :class:`FreeAirIdentification` (NaN: not
    identified)."""
    truth = dict(plant, **(dahl or {}))
    return {k: result.value(k) / truth[k] - 1.0 for k in GOALS if k in truth}

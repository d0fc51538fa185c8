"""Offline experiments with the core simulator, recorded the way the sim node publishes them.

* :func:`chirp_experiment` -- the identification experiment: a log torque chirp either on the
  endpoint (``excitation='external'``: the paper's bonded second finger backdriving the
  finger; the sim's ``torque_chirp`` environment; F_e is measured, the motor is off so F_a = 0)
  or on the motor (``excitation='motor'``: the controller's ``chirp`` mode; the endpoint is
  free, F_e = 0).
* :func:`work_loop_experiment` -- the quasi-static position drive (0.5 rad, 1 rad/s) of the
  Dahl fit and the Z-width, in any controller mode.

The result is a dict of arrays with the ``ActuatorState`` field names of one channel
(``x v f_p f_a x_e f_e``) plus the simulator's true states, ready for
:func:`~seaforce_ros.bags.writer.write_state_bag`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Dict, Mapping, Optional, Union

import numpy as np
import numpy.typing as npt

from ..core.controller import ChannelController
from ..core.environment import position_sine, torque_chirp
from ..core.params import ChirpParams, ControllerConfig, DahlParams, PlantParams
from ..core.simulator import ChannelSimulator, run_closed_loop
from ..core.nonlinear_effects import NonlinearEffects
from ..core.nonlinear_simulator import make_simulator

if TYPE_CHECKING:
    from ..core.sensors import SensorParams

__all__ = ["chirp_experiment", "work_loop_experiment", "ZeroTorque"]

_Record = Dict[str, npt.NDArray[np.float64]]
#: A work loop's record: the arrays and ``settle`` [s].
_WorkLoop = Dict[str, Union[npt.NDArray[np.float64], float]]


class ZeroTorque:
    """A 'controller' that commands nothing (motor unpowered)."""

    def update(self, x: float, v: float, f_p: float) -> float:
        """Zero torque [N m], whatever the state."""
        return 0.0


def _fields(rec: Mapping[str, npt.NDArray[np.float64]]) -> _Record:
    out = {k: rec[k] for k in ("x", "v", "f_p", "f_a", "x_e", "f_e")}
    out.update({k: rec[k] for k in ("t", "x_true", "v_true", "x_e_true", "v_e_true",
                                     "f_p_true", "dahl_true")})
    return out


def chirp_experiment(plant: Optional[PlantParams] = None, dahl: Optional[DahlParams] = None,
                     sensors: Optional[SensorParams] = None, amplitude: float = 0.3,
                     start_frequency: float = 0.01, end_frequency: float = 1000.0,
                     duration: float = 60.0, excitation: str = "external", seed: int = 0,
                     dt: float = 5e-4, tail: float = 1.0,
                     motor_coulomb: float = 0.0) -> _Record:
    """Run the identification chirp on one simulated channel.

    Parameters
    ----------
    plant : PlantParams, default Table I
    dahl : DahlParams or None
    sensors : SensorParams or None (default: realistic, ``SensorParams()``)
    amplitude : float >= 0
        Chirp torque [N m].
    start_frequency, end_frequency : float > 0
        [Hz], log chirp.
    duration : float > 0
        [s].
    excitation : 'external' or 'motor'
    tail : float >= 0
        Seconds recorded after the chirp ends.

    Returns
    -------
    dict of numpy arrays (see module docstring).
    """
    plant = PlantParams.table_i() if plant is None else plant
    n = int(round((duration + tail) / dt))
    if excitation == "external":
        env = torque_chirp(amplitude, start_frequency, end_frequency, duration)
        sim = ChannelSimulator(plant, dahl=dahl, dt=dt, seed=seed, environment=env,
                               sensors=sensors, motor_coulomb=motor_coulomb)
        rec = run_closed_loop(sim, ZeroTorque(), n)
    elif excitation == "motor":
        sim = ChannelSimulator(plant, dahl=dahl, dt=dt, seed=seed, sensors=sensors,
                               motor_coulomb=motor_coulomb)
        config = ControllerConfig(mode="chirp", plant=plant, chirp=ChirpParams(
            amplitude=amplitude, start_frequency=start_frequency, end_frequency=end_frequency,
            duration=duration))
        rec = run_closed_loop(sim, ChannelController(config, dt), n)
    else:
        raise ValueError(f"excitation must be 'external' or 'motor', not {excitation!r}")
    return _fields(rec)


def work_loop_experiment(plant: Optional[PlantParams] = None, dahl: Optional[DahlParams] = None,
                         sensors: Optional[SensorParams] = None, amplitude: float = 0.5,
                         frequency: float = 1.0, cycles: float = 3.0, mode: str = "passive",
                         config: Optional[ControllerConfig] = None, seed: int = 0,
                         dt: float = 5e-4,
                         settle_cycles: float = 1.0, motor_coulomb: float = 0.0,
                         effects: Optional[NonlinearEffects] = None) -> _WorkLoop:
    """Backdrive the endpoint with the stiff position drive in controller ``mode``.

    Parameters
    ----------
    plant : PlantParams
        The simulated (true) plant, default Table I.
    dahl : DahlParams or None
        The simulated hysteresis.
    amplitude : float
        [rad].
    frequency : float > 0
        [rad/s].
    cycles : float > 0
        Recorded drive periods after ``settle_cycles``.
    mode : str
        Controller mode; ``config`` (a ControllerConfig, e.g. with identified parameters)
        overrides the default config built from ``plant`` and ``dahl``.
    motor_coulomb : float >= 0
        The simulated motor's Coulomb friction [N m].
    effects : NonlinearEffects, optional
        The simulated plant's nonlinear effects (default none: the linear plant).

    Returns
    -------
    dict of numpy arrays; ``settle`` [s] is the transient to ignore.
    """
    plant = PlantParams.table_i() if plant is None else plant
    period = 2.0 * math.pi / frequency
    n = int(round((cycles + settle_cycles) * period / dt))
    sim = make_simulator(plant, dahl, effects, dt=dt, seed=seed,
                         environment=position_sine(amplitude, frequency), sensors=sensors,
                         motor_coulomb=motor_coulomb)
    ctl: Union[ZeroTorque, ChannelController]
    if mode == "passive" and config is None:
        ctl = ZeroTorque()
    else:
        if config is None:
            kwargs: Dict[str, Any] = {"plant": plant}
            if dahl is not None:
                kwargs["dahl"] = dahl
            config = ControllerConfig(mode=mode, **kwargs)
        else:
            config = config.replace(mode=mode)
        ctl = ChannelController(config, dt)
    rec: _WorkLoop = {**_fields(run_closed_loop(sim, ctl, n))}
    rec["settle"] = settle_cycles * period
    return rec

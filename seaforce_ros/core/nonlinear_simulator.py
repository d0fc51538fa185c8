"""The simulated gripper with the real one's nonlinear effects (:mod:`.nonlinear_effects`).

:class:`NonlinearChannelSimulator` is a :class:`~.simulator.ChannelSimulator` (the same
sensors, command delay, torque saturation, environments, Dahl hysteresis, Coulomb friction and
run-time plant changes) whose plant has the hose's flow- and pressure-dependent terms, the
diaphragm's stroke-dependent force, the four-bar finger ratio and the motor's cogging.
:func:`make_simulator` gives the linear :class:`~.simulator.ChannelSimulator` itself when every
effect is off, so that the linear plant stays the linear simulator, bit for bit.

Integration, per sample of length dt:

* the linear plant's exact zero-order-hold step (the linear simulator's matrices: plant,
  environment spring-damper, position drive) under the held motor torque and the held
  endpoint force (environment offset, torque environment, minus the Dahl force);
* plus the effects' *excess* forces over the linear plant's -- hose ``F_p - k_s d - b_s d'``
  (on the motor +, on the endpoint -), diaphragm ``-(F_k(X_e) - k_e X_e)``, cogging and, with a
  finger ratio, the environment's force at the actuator ``F_q / r(q)`` less the linear step's
  spring-damper on X_e -- by the trapezoidal rule (Heun): the excess at the sample's state and
  at the predicted end, averaged, entering the exact step as a held input. Second order in dt
  for the effects, exact for the linear part;
* Coulomb friction (``motor_coulomb``, ``endpoint_coulomb``) as in the linear simulator: the
  force that would stop the joint at the end of the step, within +-F_c the joint sticks, else
  it slips at F_c (on the predicted and on the corrected end);
* the Dahl force held over the step and updated exactly from the endpoint's increment.

With a finger ratio the environment acts on the finger joint q (X_e = X_e(q)): the position
drive's and an object's spring-damper on q and q' = V_e / r(q), a torque environment's force at
the finger, and the sensors report the finger: the endpoint encoder reads q, ``f_e`` is the
force on the finger F_q (virtual work: F_q = r(q) F_e,act). The drive's spring is stiff (75 k_s
by default), too stiff for its nonlinear part to be a held input: while it is engaged, the
exact step takes it linearised at the step's start, q ~ q_0 + (X_e - X_e,0)/r_0, i.e. the
spring-damper k/r_0^2, b/r_0^2 on X_e and the drive's motion through 1/r_0 (r_0 on a grid of
:data:`RATIO_STEP`, one matrix exponential per grid value, kept), and only what that leaves --
second order in the step's motion, and the grid's rounding -- is an excess force.
"""
from __future__ import annotations

import math
from typing import Any, Dict, NamedTuple, Optional, Tuple

import numpy as np
import numpy.typing as npt

from .errors import NonFiniteInputError, SimulationDivergedError
from .nonlinear_effects import (NonlinearEffects, cogging_torque, diaphragm_force,
                                finger_of_endpoint, finger_ratio, hose_force)
from .params import DahlParams, PlantParams
from .sensors import adc, quantise
from .simulator import ChannelSimulator, Measurement, continuous_matrices, zero_order_hold

__all__ = ["NonlinearChannelSimulator", "make_simulator", "RATIO_STEP"]

#: Grid [-] of the finger ratio at which the engaged drive's exact step is linearised.
RATIO_STEP = 1e-3

_Vector = npt.NDArray[np.float64]
_Step = Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]


def _matrices(coef: Tuple[float, ...]) -> _Step:
    """(Phi 6x6, Gamma 6x2) of the linear simulator's flattened coefficients."""
    rows = np.asarray(coef, dtype=float).reshape(6, 8)
    return rows[:, :6].copy(), rows[:, 6:].copy()


def _clamp(value: float, limit: float) -> float:
    return limit if value > limit else (-limit if value < -limit else value)


class _Link(NamedTuple):
    """The engaged drive's spring-damper on the finger, linearised at the step's start: the
    finger q0 [rad] at the endpoint xe0 [rad], the ratio r [-] (on the grid)."""

    q0: float
    xe0: float
    r: float


class NonlinearChannelSimulator(ChannelSimulator):
    """One channel with the nonlinear effects (module docstring).

    Parameters
    ----------
    plant : PlantParams
        The linear coefficients (m, b, k, m_e, b_e, k_e, b_s, k_s) the effects add to.
    dahl : DahlParams or None
        Endpoint Dahl hysteresis.
    effects : NonlinearEffects
        The effects' magnitudes (0: off).
    **kwargs
        As :class:`~.simulator.ChannelSimulator` (dt, seed, environment, sensors,
        motor_coulomb, endpoint_coulomb, backlash, torque_saturation, command_delay).
    """

    def __init__(self, plant: PlantParams, dahl: Optional[DahlParams] = None,
                 effects: Optional[NonlinearEffects] = None, **kwargs: Any) -> None:
        effects = NonlinearEffects() if effects is None else effects
        if not isinstance(effects, NonlinearEffects):
            raise TypeError("effects must be a NonlinearEffects")
        self.effects = effects
        self._ratio = effects.has_finger_ratio
        self._q_guess = math.nan
        super().__init__(plant, dahl, **kwargs)

    def reset(self, state: Any = (0.0, 0.0, 0.0, 0.0),
              environment: Any = None) -> None:
        """As :meth:`ChannelSimulator.reset` (``state`` is (X, V, X_e, V_e) of the actuator)."""
        self._q_guess = math.nan
        super().reset(state, environment)

    # --- the linear step's matrices, refreshed with the plant or the environment ------------
    def _discretise(self) -> None:
        super()._discretise()
        self._on = _matrices(self._coef_on)
        self._off = _matrices(self._coef_off)
        self._linked: Dict[float, _Step] = {}

    def _linked_step(self, r: float) -> _Step:
        """(Phi, Gamma) with the engaged spring-damper seen through the finger ratio ``r``:
        k/r^2, b/r^2 on X_e, the drive's motion through 1/r (module docstring)."""
        step = self._linked.get(r)
        if step is None:
            A, B = continuous_matrices(self.plant, self._ken / r ** 2, self._ben / r ** 2,
                                       self._w)
            A[3, 4:6] *= r
            step = self._linked[r] = zero_order_hold(A, B, self.dt)
        return step

    def _linear_step(self, engaged: bool, c: float) -> Tuple[_Step, float, Optional[_Link]]:
        """The exact step's matrices, its held environment input [N m] (the spring's set
        point) and, with a finger ratio and the drive engaged, the linearisation it takes."""
        if not engaged:
            return self._off, 0.0, None
        if not self._ratio:
            return self._on, self._ken * (self._anchor - c), None
        xe0 = self._z[2]
        q0, r = self._finger(xe0)
        r = RATIO_STEP * round(r / RATIO_STEP)
        held = self._ken / r * (self._anchor - c - q0 + xe0 / r)
        return self._linked_step(r), held, _Link(q0, xe0, r)

    # --- the finger -----------------------------------------------------------------------
    def _finger(self, xe: float) -> Tuple[float, float]:
        """(q [rad], r(q)) at the actuator endpoint X_e."""
        if not self._ratio:
            return xe, 1.0
        q = self._q_guess = finger_of_endpoint(xe, self.effects, self._q_guess)
        return q, finger_ratio(q, self.effects)

    @property
    def finger_position(self) -> float:
        """True finger joint position q [rad] (X_e without a finger ratio)."""
        return self._finger(self._z[2])[0]

    @property
    def endpoint_velocity(self) -> float:
        """True velocity of the joint the endpoint encoder reads, q' = V_e / r(q) [rad/s]."""
        return self._z[3] / self._finger(self._z[2])[1]

    def _spring_damper(self, z: Any, c: float, position: float, velocity: float) -> float:
        """The drive's or object's spring-damper force on a joint at ``position`` moving at
        ``velocity``, side offset ``c`` [N m]."""
        return (self._ken * (self._anchor + z[4] - c - position)
                + self._ben * (self._w * z[5] - velocity))

    def _engagement(self) -> Tuple[bool, float]:
        """(engaged, side offset c) of the drive or object on the finger joint q."""
        if not (self._ratio and self._drive):
            return super()._engagement()
        z = self._z
        q, r = self._finger(z[2])
        if self._object:
            depth = q - self._anchor
            return depth > 0.0 and self._ken * depth + self._ben * z[3] / r > 0.0, 0.0
        half = 0.5 * self.backlash
        gap = self._anchor + z[4] - q
        if half == 0.0 or abs(gap) > half:
            return True, math.copysign(half, gap)
        return False, 0.0

    def external_force(self) -> float:
        """True force on the finger F_q at the current time [N m] (F_e without a ratio)."""
        if not (self._ratio and self._drive):
            return super().external_force()
        engaged, c = self._engagement()
        if not engaged:
            return 0.0
        q, r = self._finger(self._z[2])
        return self._spring_damper(self._z, c, q, self._z[3] / r)

    # --- forces ---------------------------------------------------------------------------
    @property
    def pressure_force(self) -> float:
        """True F_p [N m] of the nonlinear hose."""
        z = self._z
        return hose_force(z[2] - z[0], z[3] - z[1], self.plant.hose_stiffness,
                          self.plant.hose_damping, self.effects)

    def _excess(self, z: _Vector, link: Optional[_Link], c: float, torque: float) -> _Vector:
        """(motor, endpoint) forces [N m] the effects add to the linear step's at state z,
        under the held torque environment's ``torque``."""
        p, e = self.plant, self.effects
        x, v, xe, ve = float(z[0]), float(z[1]), float(z[2]), float(z[3])
        d, rate = xe - x, ve - v
        hose = (hose_force(d, rate, p.hose_stiffness, p.hose_damping, e)
                - p.hose_stiffness * d - p.hose_damping * rate)
        ke = p.endpoint_stiffness
        endpoint = -hose - (diaphragm_force(xe, ke, e) - ke * xe)
        if self._ratio:
            endpoint += self._finger_excess(z, link, c, torque)
        return np.array((hose + cogging_torque(x, e), endpoint))

    def _finger_excess(self, z: _Vector, link: Optional[_Link], c: float,
                       torque: float) -> float:
        """The environment's force on the actuator, F_q / r(q), less the linear step's."""
        q, r = self._finger(float(z[2]))
        if not self._drive:
            return torque * (1.0 / r - 1.0)
        if link is None:
            return 0.0
        at_finger = self._spring_damper(z, c, q, z[3] / r)
        linear = self._spring_damper(z, c, link.q0 + (z[2] - link.xe0) / link.r, z[3] / link.r)
        return (at_finger / r) - linear / link.r

    def _with_friction(self, z: _Vector, gam: npt.NDArray[np.float64]) -> _Vector:
        """``z`` at the end of the step with the Coulomb frictions: stick or slip."""
        fcm, fce = self.motor_coulomb, self.endpoint_coulomb
        if not (fcm or fce):
            return z
        ffm = ffe = 0.0
        for _ in range(4 if (fcm and fce) else 1):       # projected Gauss-Seidel
            if fcm:
                ffm = _clamp((z[1] - gam[1, 1] * ffe) / gam[1, 0], fcm)
            if fce:
                ffe = _clamp((z[3] - gam[3, 0] * ffm) / gam[3, 1], fce)
        z = z - gam @ np.array((ffm, ffe))
        if fcm and abs(ffm) < fcm:
            z[1] = 0.0
        if fce and abs(ffe) < fce:
            z[3] = 0.0
        self.motor_friction, self.endpoint_friction = ffm, ffe
        return z

    # --- one sample -----------------------------------------------------------------------
    def _command(self, torque: float) -> float:
        """The torque applied over this step [N m]: the last command (delay 1) or this one,
        saturated."""
        torque = float(torque)
        if not math.isfinite(torque):
            raise NonFiniteInputError("torque", torque)
        if self.command_delay:
            applied, self._pending = self._pending, torque
        else:
            applied = torque
        lim = self.torque_saturation
        self.limited = abs(applied) > lim
        self.applied_torque = _clamp(applied, lim)
        return self.applied_torque

    def step(self, torque: float) -> Measurement:
        """Advance one sample with ``torque`` [N m] held (module docstring); return the new
        measurement.

        Raises
        ------
        NonFiniteInputError
            ``torque`` is NaN or inf.
        SimulationDivergedError
            The state left the finite numbers (effects too stiff for the step); the state
            stays the last finite one.
        """
        applied = self._command(torque)
        engaged, c = self._engagement()
        (phi, gam), held, link = self._linear_step(engaged, c)
        env_torque = 0.0 if self._drive else self._env.torque(self.t - self._env_t0)
        z0 = np.array(self._z)
        linear = phi @ z0 + gam @ np.array((applied, held + env_torque - self._dahl.force))
        start = self._excess(z0, link, c, env_torque)
        predicted = self._with_friction(linear + gam @ start, gam)
        end = self._excess(predicted, link, c, env_torque)
        z1 = self._with_friction(linear + gam @ (0.5 * (start + end)), gam)
        if not np.isfinite(z1).all():
            raise SimulationDivergedError(self.t, tuple(self._z[:4]))
        self._z = z1.tolist()
        self._dahl.update(self._z[2])
        self.step_count += 1
        self.t = self.step_count * self.dt
        self._measurement = self._measure()
        return self._measurement

    def _measure(self) -> Measurement:
        z = self._z
        fp = self.pressure_force
        if self._biased:
            fp += self.sensors.pressure_bias(self.t)
        if self._noise_std:
            fp += self._noise_std * self._next_noise()
        xq = quantise(z[0], self._qx)
        if self._vn == 1:
            v = (xq - self._xq_prev) / self.dt
            self._xq_prev = xq
        else:
            v = self._averaged_velocity(xq)
        q = self._finger(z[2])[0]
        return Measurement(xq, v, adc(fp, self._qp, self._prange), self.applied_torque,
                           quantise(q, self._qe), self.external_force())


def make_simulator(plant: PlantParams, dahl: Optional[DahlParams] = None,
                   effects: Optional[NonlinearEffects] = None,
                   **kwargs: Any) -> ChannelSimulator:
    """The channel's simulator: the linear :class:`~.simulator.ChannelSimulator` when no
    effect is on (``effects`` None or all 0), else :class:`NonlinearChannelSimulator`;
    ``kwargs`` as :class:`~.simulator.ChannelSimulator`."""
    if effects is None or not effects.any:
        return ChannelSimulator(plant, dahl, **kwargs)
    return NonlinearChannelSimulator(plant, dahl, effects, **kwargs)

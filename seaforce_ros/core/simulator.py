"""Fast offline simulator of one channel (plant + sensors + environment).

Linear part: the 4-state lumped model (X, V, X_e, V_e) of the paper's Section II-C plus,
for the position drive, the drive oscillator (x_d, y_d) and the
spring-damper to the endpoint -- 6 states, discretised exactly (matrix
exponential, zero-order hold) for the two inputs

* ``u_m`` motor force  = F_a - F_fm  (F_a after delay and saturation, F_fm motor
  Coulomb friction),
* ``u_e`` endpoint force = F_e,ext - F_d - F_fe (+ constant drive offset),

all held over the step. The nonlinear forces are integrated robustly:

* Dahl hysteresis F_d (eq. 14, exponent n): exact per-step update from the
  endpoint increment (:mod:`.dahl`), held over the next step;
* Coulomb friction (motor, optional endpoint): the force that would bring
  the velocity exactly to zero at the end of the step is computed from the
  discrete matrices; if it is within ``+-F_c`` the joint sticks (velocity 0,
  no chatter), otherwise it slips with ``F_c`` opposing the predicted
  velocity (projected Gauss-Seidel when both frictions are on);
* backlash (position drive only): a dead zone of total width ``backlash``
  between the drive and the endpoint; the coupling is switched (two exact
  discretisations) at the start of each step;
* motor torque saturation ``+-torque_saturation`` (the motor and drive's physical
  limit; ``limited`` says it acted this step).

Sensors (:mod:`.sensors`): 16-bit pressure ADC with noise and an offset (drifting
or not), quantised motor and endpoint encoders, drive velocity = the mean of the
last ``velocity_samples`` backward differences of the quantised motor position. ``command_delay=1`` (default) models the EtherCAT frame: the
torque computed from the measurement of cycle k is applied from cycle k+1.

Randomness: one Gaussian draw per step (pressure noise), from the
simulator's own ``numpy.random.Generator(PCG64(seed))``, consumed in blocks
in a fixed order, so a run is reproducible bit for bit and independent of
wall time.
"""

import math
from collections import deque
from typing import (Callable, Dict, List, NamedTuple, Optional, Protocol,
                    Sequence, Tuple, TypeVar, Union)

import numpy as np
import numpy.typing as npt
import scipy.linalg

from .dahl import DahlState
from .environment import Environment, free
from .errors import InvalidParameterError, NonFiniteInputError
from .params import PlantParams, DahlParams
from .sensors import SensorParams

__all__ = ["Measurement", "ChannelSimulator", "run_closed_loop", "discretise",
           "continuous_matrices", "zero_order_hold", "SampleController"]


class Measurement(NamedTuple):
    """One sample as the sensors report it.

x : motor position [rad] (quantised)
v : motor velocity [rad/s] (drive's backward difference)
f_p : pressure force [N m] (ADC, noise)
f_a : motor torque applied during the last step [N m]
x_e : endpoint position [rad] (40,000 counts/rev encoder)
f_e : external force [N m] (environment)
"""

    x: float
    v: float
    f_p: float
    f_a: float
    x_e: float
    f_e: float


class SampleController(Protocol):
    """What :func:`run_closed_loop` drives: a controller with a per-sample update."""

    def update(self, x: float, v: float, f_p: float) -> float:
        """The torque command [N m] for motor position ``x`` [rad], velocity ``v`` [rad/s]
        and pressure force ``f_p`` [N m]."""
        ...


_Controller = TypeVar("_Controller", bound=SampleController)
_Matrix = npt.NDArray[np.float64]

_NOISE_BLOCK = 4096


def continuous_matrices(plant: PlantParams, env_stiffness: float = 0.0, env_damping: float = 0.0,
                        frequency: float = 0.0) -> Tuple[_Matrix, _Matrix]:
    """Continuous A (6x6) and B (6x2) of the channel with the position drive.

    States ``(X, V, X_e, V_e, x_d, y_d)`` with ``x_d' = w y_d``,
    ``y_d' = -w x_d``; inputs ``(u_m, u_e)``.
    """
    p = plant
    m, b, k = p.motor_inertia, p.motor_damping, p.motor_stiffness
    me, be, ke = p.endpoint_inertia, p.endpoint_damping, p.endpoint_stiffness
    bs, ks = p.hose_damping, p.hose_stiffness
    ken, ben, w = env_stiffness, env_damping, frequency
    A = np.zeros((6, 6))
    A[0, 1] = 1.0
    A[1, :4] = [-(k + ks) / m, -(b + bs) / m, ks / m, bs / m]
    A[2, 3] = 1.0
    A[3, :6] = [ks / me, bs / me, -(ke + ks + ken) / me, -(be + bs + ben) / me,
                ken / me, ben * w / me]
    A[4, 5] = w
    A[5, 4] = -w
    B = np.zeros((6, 2))
    B[1, 0] = 1.0 / m
    B[3, 1] = 1.0 / me
    return A, B


def discretise(plant: PlantParams, dt: float, env_stiffness: float = 0.0,
               env_damping: float = 0.0, frequency: float = 0.0) -> Tuple[_Matrix, _Matrix]:
    """Exact zero-order-hold discretisation ``(Phi, Gamma)`` of
    :func:`continuous_matrices` with step ``dt`` [s]."""
    A, B = continuous_matrices(plant, env_stiffness, env_damping, frequency)
    return zero_order_hold(A, B, dt)


def zero_order_hold(A: _Matrix, B: _Matrix, dt: float) -> Tuple[_Matrix, _Matrix]:
    """``(Phi, Gamma)`` of ``x' = A x + B u`` with ``u`` held over a step ``dt`` [s]
    (one matrix exponential)."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    E = scipy.linalg.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def _flatten(phi: _Matrix, gam: _Matrix) -> Tuple[float, ...]:
    return tuple(float(v) for v in np.hstack([phi, gam]).ravel())


class ChannelSimulator:
    """One channel: plant, nonlinear friction, sensors and environment.

    Parameters
    ----------
    plant : PlantParams
        Linear model (Table I by default in the tools).
    dahl : DahlParams or None
        Endpoint Dahl hysteresis (None: none).
    dt : float > 0
        Sample period [s] (2 kHz: 5e-4).
    seed : int
        Seed of the sensor-noise generator.
    environment : Environment, optional
        Default :func:`~.environment.free`.
    sensors : SensorParams, optional
        Default ``SensorParams()`` (16-bit ADC +-10 N m, 5e-4 N m noise,
        2^20 counts/rev motor, 40,000 counts/rev endpoint).
    motor_coulomb : float >= 0
        Motor Coulomb friction [N m].
    endpoint_coulomb : float >= 0
        Endpoint Coulomb friction [N m] (unobservable from pressure).
    backlash : float >= 0
        Total dead-zone width between the position drive and the endpoint [rad].
    torque_saturation : float > 0
        Motor torque saturation [N m] (default inf).
    command_delay : int, 0 or 1
        Samples between a command and its application (default 1).
    """

    def __init__(self, plant: PlantParams, dahl: Optional[DahlParams] = None, dt: float = 5e-4,
                 seed: int = 0, environment: Optional[Environment] = None,
                 sensors: Optional[SensorParams] = None, motor_coulomb: float = 0.0,
                 endpoint_coulomb: float = 0.0, backlash: float = 0.0,
                 torque_saturation: float = math.inf, command_delay: int = 1) -> None:
        if not isinstance(plant, PlantParams):
            raise TypeError("plant must be a PlantParams")
        if dahl is not None and not isinstance(dahl, DahlParams):
            raise TypeError("dahl must be a DahlParams or None")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InvalidParameterError("dt", dt, "> 0 and finite")
        for name, value in (("motor_coulomb", motor_coulomb),
                            ("endpoint_coulomb", endpoint_coulomb),
                            ("backlash", backlash)):
            if not (math.isfinite(value) and value >= 0):
                raise InvalidParameterError(name, value, ">= 0 and finite")
        if not torque_saturation > 0:
            raise InvalidParameterError("torque_saturation", torque_saturation, "> 0")
        if command_delay not in (0, 1):
            raise InvalidParameterError("command_delay", command_delay, "0 or 1")
        self.plant = plant
        self.dahl_params = dahl
        self.dt = float(dt)
        self.seed = seed
        self.sensors = SensorParams() if sensors is None else sensors
        self.motor_coulomb = float(motor_coulomb)
        self.endpoint_coulomb = float(endpoint_coulomb)
        self.backlash = float(backlash)
        self.torque_saturation = float(torque_saturation)
        self.command_delay = int(command_delay)
        self._hose = (plant.hose_stiffness, plant.hose_damping)
        self._qp = self.sensors.pressure_quantum
        self._qx = self.sensors.motor_quantum
        self._qe = self.sensors.endpoint_quantum
        self._prange = float(self.sensors.pressure_range)
        self._noise_std = float(self.sensors.pressure_noise)
        self._biased = bool(self.sensors.pressure_offset or self.sensors.pressure_drift)
        self._vn = int(self.sensors.velocity_samples)
        self._dahl = DahlState(dahl if dahl is not None else DahlParams(sigma=0.0))
        # None only until reset() below installs one
        self._env: Environment = None  # type: ignore[assignment]
        self.reset(environment=environment)

    # --- state management ---------------------------------------------------
    def reset(self, state: Sequence[float] = (0.0, 0.0, 0.0, 0.0),
              environment: Optional[Environment] = None) -> None:
        """Restart at ``t = 0`` with ``state = (X, V, X_e, V_e)`` and a fresh
        noise generator (same seed)."""
        self._rng = np.random.Generator(np.random.PCG64(self.seed))
        self._noise: List[float] = []
        self._noise_i = 0
        self.t = 0.0
        self.step_count = 0
        self._z = [float(s) for s in state] + [0.0, 0.0]
        self._dahl.reset(self._z[2], 0.0)
        self._pending = 0.0
        self.applied_torque = 0.0
        self.limited = False
        self.motor_friction = 0.0
        self.endpoint_friction = 0.0
        self._xq_prev = self._quantise(self._z[0], self._qx)
        self._xq_history = deque([self._xq_prev] * self._vn, maxlen=self._vn)
        if environment is None:
            environment = self._env if self._env is not None else free()
        self.set_environment(environment)
        self._measurement = self._measure()

    def set_environment(self, environment: Environment) -> None:
        """Install an environment now (its time origin is the current time)."""
        if not isinstance(environment, Environment):
            raise TypeError("environment must be an Environment")
        self._env = environment
        self._env_t0 = self.t
        # a spring-damper to a set point: the position drive's moving one, an object's fixed one
        self._drive = environment.is_position_drive or environment.is_object
        self._object = environment.is_object
        self._anchor = environment.position if self._object else environment.offset
        self._discretise()
        if environment.is_position_drive:
            # x_d = offset + A sin(w (t - t0)): oscillator at phase 0
            self._z[4] = 0.0
            self._z[5] = environment.amplitude
        else:
            self._z[4] = self._z[5] = 0.0
        if hasattr(self, "_measurement"):
            # the new environment changes only the reported F_e (no noise draw)
            self._measurement = self._measurement._replace(f_e=self.external_force())

    def set_plant(self, plant: PlantParams, dahl: Optional[DahlParams] = None) -> None:
        """Replace the true plant and Dahl hysteresis now, keeping the state (a drifting
        plant); ``dahl`` None: no hysteresis."""
        if not isinstance(plant, PlantParams):
            raise TypeError("plant must be a PlantParams")
        if dahl is not None and not isinstance(dahl, DahlParams):
            raise TypeError("dahl must be a DahlParams or None")
        self.plant = plant
        self.dahl_params = dahl
        self._hose = (plant.hose_stiffness, plant.hose_damping)
        self._dahl.set_params(dahl if dahl is not None else DahlParams(sigma=0.0))
        self._discretise()

    def _discretise(self) -> None:
        env = self._env
        w = env.frequency if env.is_position_drive else 0.0
        ken = env.stiffness if self._drive else 0.0
        ben = env.damping if self._drive else 0.0
        self._ken, self._ben, self._w = ken, ben, w
        phi, gam = discretise(self.plant, self.dt, ken, ben, w)
        self._coef_on = _flatten(phi, gam)
        phi0, gam0 = discretise(self.plant, self.dt, 0.0, 0.0, w)
        self._coef_off = _flatten(phi0, gam0)

    @property
    def environment(self) -> Environment:
        """The installed environment."""
        return self._env

    @property
    def state(self) -> Tuple[float, float, float, float]:
        """True ``(X, V, X_e, V_e)`` [rad, rad/s]."""
        z = self._z
        return (z[0], z[1], z[2], z[3])

    @property
    def pressure_force(self) -> float:
        """True F_p = k_s (X_e - X) + b_s (V_e - V) [N m]."""
        z = self._z
        ks, bs = self._hose
        return ks * (z[2] - z[0]) + bs * (z[3] - z[1])

    @property
    def endpoint_velocity(self) -> float:
        """True velocity [rad/s] of the joint the endpoint encoder reads (V_e here)."""
        return self._z[3]

    @property
    def dahl_force(self) -> float:
        """True Dahl force F_d [N m]."""
        return self._dahl.force

    @property
    def drive_position(self) -> float:
        """Position drive set-point x_d [rad] (0 when not driving)."""
        return self._env.offset + self._z[4] if self._env.is_position_drive else 0.0

    def _engagement(self) -> Tuple[bool, float]:
        """(engaged, side offset c) of the drive or object coupling at the current state."""
        if not self._drive:
            return False, 0.0
        if self._object:
            # in contact while beyond the surface and pushing into it (an object never pulls)
            z = self._z
            depth = z[2] - self._anchor
            return depth > 0.0 and self._ken * depth + self._ben * z[3] > 0.0, 0.0
        half = 0.5 * self.backlash
        if half == 0.0:
            return True, 0.0
        r = self._anchor + self._z[4] - self._z[2]
        if r > half:
            return True, half
        if r < -half:
            return True, -half
        return False, 0.0

    def external_force(self) -> float:
        """True F_e at the current time [N m]."""
        if self._drive:
            engaged, c = self._engagement()
            if not engaged:
                return 0.0
            z = self._z
            return (self._ken * (self._anchor + z[4] - c - z[2])
                    + self._ben * (self._w * z[5] - z[3]))
        return self._env.torque(self.t - self._env_t0)

    @staticmethod
    def _quantise(value: float, quantum: float) -> float:
        return quantum * round(value / quantum) if quantum else value

    def _next_noise(self) -> float:
        i = self._noise_i
        if i >= len(self._noise):
            self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
            i = 0
        self._noise_i = i + 1
        return self._noise[i]

    def _averaged_velocity(self, xq: float) -> float:
        """The drive's velocity [rad/s] from the quantised position ``xq`` [rad]: the mean of the
        last ``velocity_samples`` backward differences (:mod:`.sensors`)."""
        history = self._xq_history
        v = (xq - history[0]) / (self._vn * self.dt)
        history.append(xq)
        return v

    def _measure(self) -> Measurement:
        z = self._z
        ks, bs = self._hose
        fp = ks * (z[2] - z[0]) + bs * (z[3] - z[1])
        if self._biased:
            fp += self.sensors.pressure_bias(self.t)
        if self._noise_std:
            fp += self._noise_std * self._next_noise()
        r = self._prange
        fp = r if fp > r else (-r if fp < -r else fp)
        qp = self._qp
        if qp:
            fp = qp * round(fp / qp)
            if fp > r - qp:
                fp = r - qp
        qx = self._qx
        xq = qx * round(z[0] / qx) if qx else z[0]
        if self._vn == 1:
            v = (xq - self._xq_prev) / self.dt
            self._xq_prev = xq
        else:
            v = self._averaged_velocity(xq)
        qe = self._qe
        xe = qe * round(z[2] / qe) if qe else z[2]
        return Measurement(xq, v, fp, self.applied_torque, xe, self.external_force())

    def measurement(self) -> Measurement:
        """The current :class:`Measurement` (no side effects)."""
        return self._measurement

    # --- one sample -------------------------------------------------------------
    def step(self, torque: float) -> Measurement:
        """Advance one sample with ``torque`` [N m] held; return the new measurement.

        Raises
        ------
        NonFiniteInputError
            ``torque`` is NaN or inf.
        """
        torque = float(torque)
        if not math.isfinite(torque):
            raise NonFiniteInputError("torque", torque)
        if self.command_delay:
            applied = self._pending
            self._pending = torque
        else:
            applied = torque
        lim = self.torque_saturation
        if applied > lim:
            applied, self.limited = lim, True
        elif applied < -lim:
            applied, self.limited = -lim, True
        else:
            self.limited = False
        self.applied_torque = applied

        z = self._z
        ue = -self._dahl.force
        if self._drive:
            engaged, c = self._engagement()
            coef = self._coef_on if engaged else self._coef_off
            if engaged:
                ue += self._ken * (self._anchor - c)
        else:
            coef = self._coef_off
            ue += self._env.torque(self.t - self._env_t0)
        um = applied
        (a00, a01, a02, a03, a04, a05, g00, g01,
         a10, a11, a12, a13, a14, a15, g10, g11,
         a20, a21, a22, a23, a24, a25, g20, g21,
         a30, a31, a32, a33, a34, a35, g30, g31,
         a40, a41, a42, a43, a44, a45, g40, g41,
         a50, a51, a52, a53, a54, a55, g50, g51) = coef
        z0, z1, z2, z3, z4, z5 = z
        n0 = a00 * z0 + a01 * z1 + a02 * z2 + a03 * z3 + a04 * z4 + a05 * z5 + g00 * um + g01 * ue
        n1 = a10 * z0 + a11 * z1 + a12 * z2 + a13 * z3 + a14 * z4 + a15 * z5 + g10 * um + g11 * ue
        n2 = a20 * z0 + a21 * z1 + a22 * z2 + a23 * z3 + a24 * z4 + a25 * z5 + g20 * um + g21 * ue
        n3 = a30 * z0 + a31 * z1 + a32 * z2 + a33 * z3 + a34 * z4 + a35 * z5 + g30 * um + g31 * ue
        if self._drive:
            n4 = a44 * z4 + a45 * z5
            n5 = a54 * z4 + a55 * z5
        else:
            n4 = n5 = 0.0
        fcm, fce = self.motor_coulomb, self.endpoint_coulomb
        if fcm or fce:
            ffm = ffe = 0.0
            for _ in range(4 if (fcm and fce) else 1):
                if fcm:
                    ffm = (n1 - g11 * ffe) / g10
                    ffm = fcm if ffm > fcm else (-fcm if ffm < -fcm else ffm)
                if fce:
                    ffe = (n3 - g30 * ffm) / g31
                    ffe = fce if ffe > fce else (-fce if ffe < -fce else ffe)
            n0 -= g00 * ffm + g01 * ffe
            n1 -= g10 * ffm + g11 * ffe
            n2 -= g20 * ffm + g21 * ffe
            n3 -= g30 * ffm + g31 * ffe
            # stuck joints: exactly zero velocity (no rounding residue)
            if fcm and -fcm < ffm < fcm:
                n1 = 0.0
            if fce and -fce < ffe < fce:
                n3 = 0.0
            self.motor_friction, self.endpoint_friction = ffm, ffe
        z[0], z[1], z[2], z[3], z[4], z[5] = n0, n1, n2, n3, n4, n5
        self._dahl.update(n2)
        self.step_count += 1
        self.t = self.step_count * self.dt
        m = self._measurement = self._measure()
        return m


def run_closed_loop(
        sim: ChannelSimulator, controller: _Controller, n_steps: int,
        on_switch: Union[None, Callable[[int, ChannelSimulator, _Controller], object],
                         Dict[int, Callable[[ChannelSimulator, _Controller], object]]] = None,
        max_torque: Optional[float] = None) -> Dict[str, npt.NDArray[np.float64]]:
    """Run ``controller`` on ``sim`` for ``n_steps`` samples.

    Exactly::

        m = sim.measurement()
        for i in range(n_steps):
            (on_switch hook)
            u = controller.update(m.x, m.v, m.f_p)
            (record)
            m = sim.step(u)

    which is also what the ROS sim node does in lockstep mode.

    Parameters
    ----------
    sim : ChannelSimulator
    controller : object with ``update(x, v, f_p) -> float``
        (and optionally the status attributes of
        :class:`~.controller.ChannelController`).
    n_steps : int
    on_switch : callable or dict, optional
        ``on_switch(i, sim, controller)`` called before each update, or a
        dict ``{i: callable(sim, controller)}`` of one-off actions (mode or
        environment switches).
    max_torque : float, optional
        Stop at the first command beyond +-``max_torque`` [N m] (or not finite): the record
        ends before that sample, where the cycle would latch a fault (fewer than ``n_steps``
        samples tell the caller so).

    Returns
    -------
    dict of numpy arrays, all aligned to the sample times ``t`` [s]:
    measurement fields ``x v f_p f_a x_e f_e`` (what the controller saw),
    ``u`` (command), true ``x_true v_true x_e_true v_e_true f_p_true
    dahl_true`` (X_e, V_e of the actuator: with a finger ratio the measured ``x_e`` is the
    finger's), the controller's ``disturbance feedforward
    endpoint_velocity_estimate dahl_force`` when it has them, and its passivity guard's
    ``passivity_energy passivity_damping`` when it runs one.
    """
    names = ("t", "x", "v", "f_p", "f_a", "x_e", "f_e", "u", "x_true", "v_true",
             "x_e_true", "v_e_true", "f_p_true", "dahl_true")
    status = ("disturbance", "feedforward", "endpoint_velocity_estimate",
              "dahl_force")
    has_status = all(hasattr(controller, s) for s in status)
    rec: Dict[str, List[float]] = {n: [] for n in names + (status if has_status else ())}
    guard = getattr(controller, "passivity_guard", None)
    if guard is not None:
        r_energy = rec["passivity_energy"] = []
        r_damping = rec["passivity_damping"] = []
    limit = None if max_torque is None else float(max_torque)
    hooks = on_switch if isinstance(on_switch, dict) else None
    each = None if isinstance(on_switch, dict) else on_switch
    update = controller.update
    ks, bs = sim.plant.hose_stiffness, sim.plant.hose_damping
    # a simulator with its own hose (the nonlinear one) gives its F_p; the linear one inline
    own_hose = type(sim).pressure_force is not ChannelSimulator.pressure_force
    r_t, r_x, r_v, r_fp, r_fa, r_xe, r_fe, r_u = (rec[n] for n in names[:8])
    r_X, r_V, r_XE, r_VE, r_FP, r_FD = (rec[n] for n in names[8:])
    m = sim.measurement()
    for i in range(n_steps):
        if hooks is not None:
            action = hooks.get(i)
            if action is not None:
                action(sim, controller)
        elif each is not None:
            each(i, sim, controller)
        u = update(m.x, m.v, m.f_p)
        if limit is not None and not abs(u) <= limit:
            break
        z = sim._z
        r_t.append(sim.t)
        r_x.append(m.x)
        r_v.append(m.v)
        r_fp.append(m.f_p)
        r_fa.append(m.f_a)
        r_xe.append(m.x_e)
        r_fe.append(m.f_e)
        r_u.append(u)
        r_X.append(z[0])
        r_V.append(z[1])
        r_XE.append(z[2])
        r_VE.append(z[3])
        r_FP.append(sim.pressure_force if own_hose
                    else ks * (z[2] - z[0]) + bs * (z[3] - z[1]))
        r_FD.append(sim._dahl.force)
        if has_status:
            for s in status:
                rec[s].append(getattr(controller, s))
        if guard is not None:
            r_energy.append(guard.energy)
            r_damping.append(guard.damping)
        m = sim.step(u)
    return {n: np.asarray(v, dtype=float) for n, v in rec.items()}

"""The oracle with the real gripper's nonlinearities: a third simulator, independent of
``seaforce_ros`` and of :mod:`helpers.second_sim`'s integration (its own equations and
integrator; the rig's sensor steps from :func:`helpers.second_sim.quanta`).

The paper names the effects the linear model leaves out (Section IV: "a linear damper poorly
approximates nonlinear viscous losses" in the hose, "a nonlinear four-bar mechanism gear ratio
in the finger joint", "a slight stroke position dependence on the actuator diaphragm
resistance force"); a real hose also stiffens with pressure and a direct-drive motor has
Coulomb friction and cogging. Each is switchable (:class:`Effects`, magnitude 0 = off) and
:func:`draw_effects` draws its magnitude within the ranges below.

Model (motor frame, rotational SI units; X motor, X_e actuator endpoint, q the finger joint
the bonded finger and the endpoint encoder see, delta = X_e - X the hose deflection)::

    motor     m X''   = F_a + F_p - b X' - k X - F_cm tanh(X'/v_s) - F_cog sin(N X + phi)
    endpoint  m_e X_e'' = F_e,act - F_p - b_e X_e' - F_k(X_e) - F_d
    hose      F_p = k_s delta (1 + kappa |delta|) + b_s delta' (1 + |delta'|/q_2)
    diaphragm F_k(X_e) = k_e X_e (1 + a_1 (X_e/L) + a_2 (X_e/L)^2),    L = 0.5 rad
    finger    dX_e/dq = r(q) = 1 + c_1 (q/L) + c_2 (q/L)^2,  F_q = r(q) F_e,act  (virtual work)
    Dahl      dF_d/dt = sigma X_e' (1 - (F_d/F_c) sgn X_e')              (eq. 14-15, n = 1)

with kappa = s_p k_s/2, so that the tangent stiffness of the hose rises by ``s_p`` at a
pressure force of 1 N m (|delta| ~ 1/k_s there). The endpoint inertia is on the actuator side
(fluid and piston), the finger link is massless: in free air (F_q = 0) the finger ratio does
nothing, and no free-air record can show it.

Ranges drawn (:data:`RANGES`; the torque range is 1 N m, commissioning's ``max_torque``):

==================  =================================================  =====================
effect              magnitude                                          drawn
==================  =================================================  =====================
hose_flow           q_2: hose flow at which the hose damping doubles   1 .. 3 rad/s
hose_pressure       s_p: rise of the hose's tangent stiffness at       0.1 .. 0.4
                    |F_p| = 1 N m
stroke_stiffness    a_2: rise of the diaphragm force at |X_e| = L      0.1 .. 0.3, with
                    (a_1 the asymmetry, up to a third of a_2)          |a_1| <= a_2/3
finger_ratio        c_2: rise of the finger ratio from 1 at the        0.05 .. 0.15, with
                    centre to the ends of the +-L stroke (c_1 the      |c_1| <= c_2/3
                    asymmetry, up to a third of c_2)
motor_coulomb       F_cm (0.5-1 % of the torque range)                 0.005 .. 0.01 N m
cogging             F_cog (0.5-1 % of the torque range), N periods     0.005 .. 0.01 N m,
                    per revolution, phase phi                          N in 24..84, phi any
==================  =================================================  =====================

The motor's Coulomb friction is regularised, ``tanh(V/v_s)`` with v_s = 5 mrad/s (a finger at
rest creeps instead of sticking; a 0.5 rad/s drive passes through the band in 1 % of its
period).

Integration: classical Runge-Kutta (RK4) on (X, V, X_e, V_e, F_d) with ``substeps`` steps per
sample, every force evaluated on the stage's state (nothing held over a step; the project's
simulator is an exact zero-order hold with the nonlinear forces held). The Dahl state is stiff
where the endpoint is fast: it relaxes at the rate ``sigma |X_e'| / F_c``, 15,000 /s at
12 rad/s on a draw with sigma 24 N m/rad and F_c 19 mN m, beyond RK4's stability limit (2.8/h)
at 2 substeps, where the oracle itself diverged (seed 52584 of the compensation test: X_e
24,000 rad in one sample). So a sample takes more substeps where that rate needs them:
``h sigma |X_e'| / F_c <= 1`` with ``|X_e'|`` taken at twice its value at the sample's
start (:data:`DAHL_STEP`). The motor torque is held over each sample and applied one sample
after the sample it answers (the EtherCAT frame): :meth:`NonlinearGripper.step` follows the
project simulator's protocol, so a controller runs on it the way it runs on ``sim_node`` in
lockstep. The finger is either free
(F_q = 0) or driven along a prescribed path q(t) (the bonded second finger, a kinematic drive:
X_e, X_e' and X_e'' follow from q; F_q is the force that takes).

Sensors (:class:`Sensors`; by default the rig's, restated here): pressure force through a
16-bit ADC over +-10 N m with 5e-4 N m Gaussian noise and no offset, motor encoder 2^20
counts/rev, finger encoder 40,000 counts/rev, motor velocity the backward difference of the
quantised position, the torque applied one sample after the sample it answers; the bonded
finger's force F_q exact. :func:`draw_sensors` draws what real rigs have instead: a coarser
encoder, a drive that averages its velocity, a pressure sensor with range, resolution, noise and
an offset of its own, and samples of delay beyond the frame's.
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from helpers.second_sim import quanta

#: Half-stroke L [rad] the stroke ranges refer to.
STROKE = 0.5
#: The torque range [N m] the motor's ranges are a share of (commissioning's max_torque).
TORQUE_RANGE = 1.0
#: Velocity [rad/s] of the motor Coulomb friction's tanh regularisation.
COULOMB_VELOCITY = 5e-3

#: effect -> (low, high) of its magnitude (module docstring)
RANGES = {"hose_flow": (1.0, 3.0), "hose_pressure": (0.1, 0.4),
          "stroke_stiffness": (0.1, 0.3), "finger_ratio": (0.05, 0.15),
          "motor_coulomb": (0.005 * TORQUE_RANGE, 0.01 * TORQUE_RANGE),
          "cogging": (0.005 * TORQUE_RANGE, 0.01 * TORQUE_RANGE)}
#: Largest ``h sigma |X_e'| / F_c`` of an RK4 substep h (module docstring: the Dahl state's
#: stiffness; RK4 is stable to 2.8 on the negative real axis).
DAHL_STEP = 1.0
#: More substeps than this per sample (an endpoint at about 10,000 rad/s): the run diverged.
MAX_SUBSTEPS = 1000
#: Cogging periods per revolution drawn from (slots x poles of common direct-drive motors).
COGGING_PERIODS = (24, 36, 42, 48, 56, 72, 84)
EFFECTS = tuple(RANGES)


@dataclass(frozen=True)
class Sensors:
    """What the gripper's sensors and drive report (module docstring): ``motor_counts`` per
    revolution (0: exact), the drive's velocity the mean of the last ``velocity_samples``
    backward differences, the pressure force over +-``pressure_range`` N m at
    ``pressure_bits`` (0: not quantised) with ``pressure_noise`` N m of white noise and an
    offset ``pressure_offset`` N m changing at ``pressure_drift`` N m/s, the torque applied
    ``1 + extra_delay`` samples after the sample it answers, the finger encoder's
    ``finger_counts``."""

    motor_counts: int = 2 ** 20
    velocity_samples: int = 1
    pressure_range: float = 10.0
    pressure_bits: int = 16
    pressure_noise: float = 5e-4
    pressure_offset: float = 0.0
    pressure_drift: float = 0.0
    extra_delay: int = 0
    finger_counts: int = 40000

    def describe(self):
        """One line."""
        return (f"encoder 2^{round(math.log2(self.motor_counts)) if self.motor_counts else 'inf'}"
                f", velocity over {self.velocity_samples}, pressure +-{self.pressure_range:.0f}"
                f" N m at {self.pressure_bits} bit, noise {1e3 * self.pressure_noise:.2f} mN m, "
                f"offset {1e3 * self.pressure_offset:+.1f} mN m, delay +{self.extra_delay}")


#: The ranges :func:`draw_sensors` draws from.
SENSOR_RANGES = {"motor_bits": (14, 20), "velocity_samples": (1, 4), "pressure_range": (10.0, 40.0),
                 "pressure_bits": (12, 16), "pressure_noise": (2e-4, 2e-3),
                 "pressure_offset": (-0.05, 0.05), "extra_delay": (0, 2)}


def draw_sensors(rng):
    """Sensors of a real rig, each uniform in :data:`SENSOR_RANGES` (the encoder's bits, the
    pressure range and noise log-uniform)."""
    r = SENSOR_RANGES
    return Sensors(
        motor_counts=2 ** int(rng.integers(r["motor_bits"][0], r["motor_bits"][1] + 1)),
        velocity_samples=int(rng.integers(r["velocity_samples"][0],
                                          r["velocity_samples"][1] + 1)),
        pressure_range=float(math.exp(rng.uniform(*np.log(r["pressure_range"])))),
        pressure_bits=int(rng.integers(r["pressure_bits"][0], r["pressure_bits"][1] + 1)),
        pressure_noise=float(math.exp(rng.uniform(*np.log(r["pressure_noise"])))),
        pressure_offset=float(rng.uniform(*r["pressure_offset"])),
        extra_delay=int(rng.integers(r["extra_delay"][0], r["extra_delay"][1] + 1)))


@dataclass(frozen=True)
class Effects:
    """The nonlinear effects' magnitudes (0: off). ``hose_flow`` is q_2 [rad/s] (0: the hose
    damping is linear), ``hose_pressure`` s_p, ``stroke_stiffness`` a_2 and
    ``stroke_asymmetry`` a_1, ``finger_ratio`` c_2 and ``finger_asymmetry`` c_1,
    ``motor_coulomb`` F_cm [N m], ``cogging`` F_cog [N m] with ``cogging_periods`` N and
    ``cogging_phase`` phi [rad] (module docstring)."""

    hose_flow: float = 0.0
    hose_pressure: float = 0.0
    stroke_stiffness: float = 0.0
    stroke_asymmetry: float = 0.0
    finger_ratio: float = 0.0
    finger_asymmetry: float = 0.0
    motor_coulomb: float = 0.0
    cogging: float = 0.0
    cogging_periods: int = 84
    cogging_phase: float = 0.0

    def only(self, *names):
        """These effects as drawn, every other one off."""
        keep = {"hose_flow": ("hose_flow",), "hose_pressure": ("hose_pressure",),
                "stroke_stiffness": ("stroke_stiffness", "stroke_asymmetry"),
                "finger_ratio": ("finger_ratio", "finger_asymmetry"),
                "motor_coulomb": ("motor_coulomb",),
                "cogging": ("cogging", "cogging_periods", "cogging_phase")}
        values = {}
        for name in names:
            values.update({k: getattr(self, k) for k in keep[name]})
        return Effects(**values)

    def describe(self):
        """One line of the effects that are on."""
        parts = []
        if self.hose_flow:
            parts.append(f"hose damping x2 at {self.hose_flow:.2f} rad/s of flow")
        if self.hose_pressure:
            parts.append(f"hose stiffness +{100 * self.hose_pressure:.0f} % at 1 N m")
        if self.stroke_stiffness:
            parts.append(f"diaphragm force +{100 * (self.stroke_stiffness + self.stroke_asymmetry):.0f}"
                         f" / +{100 * (self.stroke_stiffness - self.stroke_asymmetry):.0f} % "
                         f"at +-{STROKE} rad")
        if self.finger_ratio:
            parts.append(f"finger ratio {ratio(STROKE, self):.3f} / {ratio(-STROKE, self):.3f} "
                         f"at +-{STROKE} rad")
        if self.motor_coulomb:
            parts.append(f"motor Coulomb {1e3 * self.motor_coulomb:.1f} mN m")
        if self.cogging:
            parts.append(f"cogging {1e3 * self.cogging:.1f} mN m x {self.cogging_periods}/rev")
        return "; ".join(parts) or "none (the linear model class)"

    def as_dict(self):
        return asdict(self)


def draw_effects(rng, names=EFFECTS):
    """One draw of the effects ``names`` (the others off) within :data:`RANGES`: each magnitude
    uniform in its range, the asymmetries uniform within a third of their effect, the cogging's
    periods from :data:`COGGING_PERIODS` and its phase uniform."""
    values = {}
    for name in names:
        lo, hi = RANGES[name]
        values[name] = float(rng.uniform(lo, hi))
    if "stroke_stiffness" in values:
        values["stroke_asymmetry"] = float(rng.uniform(-1.0, 1.0)) * values["stroke_stiffness"] / 3
    if "finger_ratio" in values:
        values["finger_asymmetry"] = float(rng.uniform(-1.0, 1.0)) * values["finger_ratio"] / 3
    if "cogging" in values:
        values["cogging_periods"] = int(rng.choice(COGGING_PERIODS))
        values["cogging_phase"] = float(rng.uniform(0.0, 2.0 * math.pi))
    return Effects(**values)


def ratio(q, effects):
    """The finger ratio r(q) = dX_e/dq."""
    u = q / STROKE
    return 1.0 + effects.finger_asymmetry * u + effects.finger_ratio * u * u


def actuator_position(q, effects):
    """X_e(q) = the integral of r from 0 to q."""
    u = q / STROKE
    return STROKE * (u + effects.finger_asymmetry * u * u / 2.0
                     + effects.finger_ratio * u * u * u / 3.0)


def finger_position(xe, effects):
    """q(X_e), the inverse of :func:`actuator_position` (Newton)."""
    q = xe
    for _ in range(30):
        step = (actuator_position(q, effects) - xe) / ratio(q, effects)
        q -= step
        if abs(step) < 1e-15:
            break
    return q


def diaphragm_force(xe, plant, effects):
    """F_k(X_e) [N m], the endpoint's (diaphragm's) spring force."""
    u = xe / STROKE
    return plant["endpoint_stiffness"] * xe * (1.0 + effects.stroke_asymmetry * u
                                               + effects.stroke_stiffness * u * u)


def hose_force(delta, rate, plant, effects):
    """F_p [N m] for the hose deflection delta = X_e - X [rad] and its rate [rad/s]."""
    ks, bs = plant["hose_stiffness"], plant["hose_damping"]
    kappa = 0.5 * effects.hose_pressure * ks
    flow = abs(rate) / effects.hose_flow if effects.hose_flow else 0.0
    return ks * delta * (1.0 + kappa * abs(delta)) + bs * rate * (1.0 + flow)


Measurement = namedtuple("Measurement", "x v f_p f_a x_e f_e")


class SinePath:
    """A prescribed finger motion q(t) = offset + A sin(w t) [rad]: ``(q, q', q'')`` at t."""

    def __init__(self, amplitude, omega, offset=0.0):
        self.amplitude, self.omega, self.offset = float(amplitude), float(omega), float(offset)

    def __call__(self, t):
        a, w = self.amplitude, self.omega
        s, c = math.sin(w * t), math.cos(w * t)
        return self.offset + a * s, a * w * c, -a * w * w * s


class NonlinearGripper:
    """One channel of the nonlinear gripper (module docstring), stepped one sample at a time.

    Parameters
    ----------
    plant : dict of the eight Table I parameters (:data:`helpers.second_sim.KEYS`)
    dahl : dict ``{sigma, coulomb_force}`` or None
    effects : Effects (default: none)
    path : callable t -> (q, q', q'') or None (the finger free)
    hand : callable (t, X_e, X_e') -> force [N m] on the actuator's endpoint, or None: a force
        on the free finger (a hand that flicks or moves it; ``path`` None)
    dt : float, s; substeps : int >= 1 (RK4 steps per sample)
    seed : int (pressure noise)
    sensors : Sensors, optional
    **fields : fields of :class:`Sensors` (instead of, or over, ``sensors``)
    """

    def __init__(self, plant, dahl=None, effects=None, path=None, dt=5e-4, substeps=2, seed=0,
                 sensors=None, hand=None, **fields):
        self.plant = dict(plant)
        self.dahl = dict(dahl) if dahl else None
        self.effects = effects or Effects()
        self.path = path
        self.hand = hand
        self.dt = dt
        self.substeps = substeps
        self.sensors = sn = replace(sensors or Sensors(), **fields)
        self._rng = np.random.default_rng(seed)
        self._noise, self._range = sn.pressure_noise, sn.pressure_range
        self._qp, self._qx = quanta(sn.pressure_range, sn.pressure_bits, sn.motor_counts)
        self._qq = quanta(motor_counts=sn.finger_counts)[1]
        self.t = 0.0
        self._path_cache = {}
        self._noise_block = []
        self.state = [0.0, 0.0, 0.0, 0.0, 0.0]      # X, V, X_e, V_e, F_d
        if path is not None:
            q, qd, _ = path(0.0)
            self.state[2] = actuator_position(q, self.effects)
            self.state[3] = ratio(q, self.effects) * qd
        self._pending = [0.0] * (1 + sn.extra_delay)     # commands on their way, oldest first
        self.applied = 0.0
        self._xq = [self._quantise(self.state[0], self._qx)] * (sn.velocity_samples + 1)
        self.dissipated = 0.0       # energy the losses (and the Dahl force) took [J]
        self.work_in = 0.0          # work of the finger's force and the motor's torque [J]
        self.forces = self._make_forces()
        self._measurement = self._measure()

    def place(self, position):
        """Motor and endpoint at rest at ``position`` [rad], the hose relaxed (the sensors
        read anew)."""
        self.state[0] = self.state[2] = float(position)
        self.state[1] = self.state[3] = 0.0
        self._xq = [self._quantise(self.state[0], self._qx)] * len(self._xq)
        self._measurement = self._measure()

    # --- the model ---------------------------------------------------------------------
    @staticmethod
    def _quantise(value, q):
        return q * round(value / q) if q else value

    def _endpoint_from_path(self, t):
        """(X_e, X_e', X_e'') of the prescribed finger path at t (the last two times kept:
        RK4 asks for each stage's time twice)."""
        cache = self._path_cache
        hit = cache.get(t)
        if hit is not None:
            return hit
        e = self.effects
        q, qd, qdd = self.path(t)
        u = q / STROKE
        r = 1.0 + e.finger_asymmetry * u + e.finger_ratio * u * u
        dr = (e.finger_asymmetry + 2.0 * e.finger_ratio * u) / STROKE
        xe = STROKE * (u + e.finger_asymmetry * u * u / 2.0 + e.finger_ratio * u * u * u / 3.0)
        value = (xe, r * qd, dr * qd * qd + r * qdd)
        if len(cache) > 3:
            cache.clear()
        cache[t] = value
        return value

    def _make_forces(self):
        """The right-hand side as a closure over the constants (speed: it runs 8 times a
        sample)."""
        p, e = self.plant, self.effects
        m, b, k = p["motor_inertia"], p["motor_damping"], p["motor_stiffness"]
        me, be, ke = p["endpoint_inertia"], p["endpoint_damping"], p["endpoint_stiffness"]
        ks, bs = p["hose_stiffness"], p["hose_damping"]
        kappa = 0.5 * e.hose_pressure * ks
        inv_q2 = 1.0 / e.hose_flow if e.hose_flow else 0.0
        fcm, cog, n_cog, phi = e.motor_coulomb, e.cogging, e.cogging_periods, e.cogging_phase
        a1, a2 = e.stroke_asymmetry / STROKE, e.stroke_stiffness / STROKE ** 2
        sigma = self.dahl["sigma"] if self.dahl else 0.0
        inv_fc = 1.0 / self.dahl["coulomb_force"] if self.dahl else 0.0
        path = self._endpoint_from_path if self.path is not None else None
        hand = self.hand
        tanh, sin = math.tanh, math.sin
        vs = COULOMB_VELOCITY

        def forces(y, t, torque):
            x, v, xe, ve, fd = y
            if path is not None:
                xe, ve, ae = path(t)
            delta, rate = xe - x, ve - v
            fk_hose = ks * delta * (1.0 + kappa * abs(delta))
            fb_hose = bs * rate * (1.0 + inv_q2 * abs(rate))
            fp = fk_hose + fb_hose
            friction = fcm * tanh(v / vs) if fcm else 0.0
            cogging = cog * sin(n_cog * x + phi) if cog else 0.0
            a = (torque + fp - b * v - k * x - friction - cogging) / m
            fk = ke * xe * (1.0 + a1 * xe + a2 * xe * xe)
            if sigma:
                dfd = sigma * ve * (1.0 - fd * inv_fc) if ve > 0.0 else (
                    sigma * ve * (1.0 + fd * inv_fc) if ve < 0.0 else 0.0)
            else:
                dfd = 0.0
            resist = fp + be * ve + fk + fd
            if path is None:
                fe_act = 0.0 if hand is None else hand(t, xe, ve)
                ae = (fe_act - resist) / me
            else:
                fe_act = me * ae + resist
            loss = fb_hose * rate + be * ve * ve + b * v * v + friction * v + fd * ve
            return v, a, ve, ae, dfd, fp, fe_act, loss, fe_act * ve + torque * v

        return forces

    # --- one sample --------------------------------------------------------------------
    def measurement(self):
        """The current :class:`Measurement` (x, v, f_p, f_a, x_e, f_e): what the sensors
        report at this sample, ``f_a`` the torque applied over the last sample."""
        return self._measurement

    def _measure(self):
        y = self.state
        fp, fe_act = self.forces(y, self.t, self._pending[0])[5:7]
        xq = self._quantise(y[0], self._qx)
        self._xq[-1] = xq                       # (the last sample's positions before it)
        n = self.sensors.velocity_samples
        v = (xq - self._xq[-1 - n]) / (n * self.dt)
        if not self._noise_block:
            self._noise_block = (self._noise * self._rng.standard_normal(4096)).tolist()[::-1]
        f = fp + self._noise_block.pop() + self.sensors.pressure_offset \
            + self.sensors.pressure_drift * self.t
        f = min(self._range, max(-self._range, f))
        if self._qp:
            f = min(self._qp * round(f / self._qp), self._range - self._qp)
        if self.path is None:
            xe_meas, fe = math.nan, math.nan
        else:
            q, _, _ = self.path(self.t)
            xe_meas = self._quantise(q, self._qq)
            fe = ratio(q, self.effects) * fe_act
        self.true_f_p = fp
        return Measurement(xq, v, f, self.applied, xe_meas, fe)

    def step(self, torque):
        """Advance one sample: the torque commanded at the last sample acts over this one
        (held); ``torque`` acts over the next. Returns the new :class:`Measurement`."""
        torque = float(torque)
        if not math.isfinite(torque):
            raise ValueError(f"torque {torque!r} is not finite")
        pending = self._pending
        u = pending.pop(0)
        pending.append(torque)
        self.applied = u
        self._xq.pop(0)
        self._xq.append(self._xq[-1])           # (its slot: the new sample's position)
        y = self.state
        substeps = self.substeps
        if self.dahl:       # the Dahl state's stiffness (module docstring)
            rate = 2.0 * abs(y[3]) * self.dahl["sigma"] / self.dahl["coulomb_force"]
            needed = self.dt * rate / DAHL_STEP
            if not needed <= MAX_SUBSTEPS:
                raise FloatingPointError(
                    f"the oracle's endpoint speed {y[3]!r} rad/s needs more than "
                    f"{MAX_SUBSTEPS} substeps per sample: the simulation diverged")
            substeps = max(substeps, math.ceil(needed))
        h = self.dt / substeps
        t = self.t
        f = self.forces
        lost = put = 0.0
        for _ in range(substeps):
            x, v, xe, ve, fd = y
            k1 = f(y, t, u)
            k2 = f((x + 0.5 * h * k1[0], v + 0.5 * h * k1[1], xe + 0.5 * h * k1[2],
                    ve + 0.5 * h * k1[3], fd + 0.5 * h * k1[4]), t + 0.5 * h, u)
            k3 = f((x + 0.5 * h * k2[0], v + 0.5 * h * k2[1], xe + 0.5 * h * k2[2],
                    ve + 0.5 * h * k2[3], fd + 0.5 * h * k2[4]), t + 0.5 * h, u)
            k4 = f((x + h * k3[0], v + h * k3[1], xe + h * k3[2], ve + h * k3[3],
                    fd + h * k3[4]), t + h, u)
            w = h / 6.0
            y = [x + w * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]),
                 v + w * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]),
                 xe + w * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]),
                 ve + w * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3]),
                 fd + w * (k1[4] + 2.0 * (k2[4] + k3[4]) + k4[4])]
            lost += w * (k1[7] + 2.0 * (k2[7] + k3[7]) + k4[7])
            put += w * (k1[8] + 2.0 * (k2[8] + k3[8]) + k4[8])
            t += h
        if self.path is not None:                  # the kinematic endpoint: on its path
            y[2], y[3], _ = self._endpoint_from_path(t)
        self.state = y
        self.t = t
        self.dissipated += lost
        self.work_in += put
        self._measurement = self._measure()
        return self._measurement


# --- experiments -------------------------------------------------------------------------------
def run_loop(gripper, controller, samples, job_done=None):
    """Run ``controller`` (``update(x, v, f_p)``, optionally with ``cycle`` and ``applied``
    attributes as the project's ChannelController) on ``gripper`` for ``samples`` samples,
    lockstep (measurement -> command -> step). Returns a dict of arrays ``x v f_p f_a x_e
    f_e command`` (the measurement of each sample and the command answering it) and ``t``."""
    out = {k: np.empty(samples) for k in ("t", "x", "v", "f_p", "f_a", "x_e", "f_e",
                                          "command", "x_true", "x_e_true", "f_p_true")}
    m = gripper.measurement()
    has_cycle = hasattr(controller, "cycle")
    for k in range(samples):
        if has_cycle:
            controller.cycle = k
            controller.applied = m.f_a
        u = controller.update(m.x, m.v, m.f_p)
        out["t"][k] = gripper.t
        out["x"][k], out["v"][k], out["f_p"][k], out["f_a"][k] = m.x, m.v, m.f_p, m.f_a
        out["x_e"][k], out["f_e"][k], out["command"][k] = m.x_e, m.f_e, u
        out["x_true"][k], out["x_e_true"][k] = gripper.state[0], gripper.state[2]
        out["f_p_true"][k] = gripper.true_f_p
        m = gripper.step(u)
        if job_done is not None and job_done():
            return {name: a[:k + 1] for name, a in out.items()}
    return out


class Unpowered:
    """The motor off: zero torque."""

    def update(self, x, v, f_p):
        return 0.0


def backdrive(plant, dahl, effects, controller, amplitude=0.5, omega=1.0, periods=1,
              settle=None, seed=0, **sensors):
    """The bonded-finger experiment on the oracle: the finger driven along
    ``amplitude sin(omega t)`` while ``controller`` runs (:class:`Unpowered` for the motor
    off). ``settle`` [s] of drive first (default one period, at least 1 s), then ``periods``
    whole periods recorded. Returns the record of :func:`run_loop` over the recorded periods
    (``x_e`` the finger encoder q, ``f_e`` the force on the finger) and ``settle``."""
    period = 2.0 * math.pi / omega
    settle = max(1.0, period) if settle is None else settle
    g = NonlinearGripper(plant, dahl, effects, SinePath(amplitude, omega),
                         seed=seed, **sensors)
    dt = g.dt
    n_settle = int(round(settle / dt))
    n_rec = int(round(periods * period / dt))
    rec = run_loop(g, controller, n_settle + n_rec)
    out = {k: a[n_settle:] for k, a in rec.items()}
    out["dt"] = dt
    out["gripper"] = g
    return out


#: Samples a job may take beyond its record's capacity (a centring move records nothing) [s].
UNRECORDED = 60.0


def free_air_excitation(plant, dahl, effects, controller, job, capacity, seed=0, start=0.0,
                        settle=0.0, **sensors):
    """A job of the project's controller (e.g. commissioning's FreeAirExcitation, already
    requested on ``controller``) run on the oracle with the finger free, until the job ends
    or ``capacity`` samples (and :data:`UNRECORDED` s more). The finger starts at rest at
    ``start`` [rad] and is left unpowered for ``settle`` [s] first (its friction holds it off
    rest). Returns ``(record of run_loop, gripper)``."""
    g = NonlinearGripper(plant, dahl, effects, None, seed=seed, **sensors)
    if start:
        g.place(start)
    for _ in range(int(round(settle / g.dt))):
        g.step(0.0)
    rec = run_loop(g, controller, capacity + 1 + int(UNRECORDED / g.dt),
                   job_done=lambda: not job.active)
    return rec, g


def linear_counterpart(effects):
    """The same plant with every effect off (the model class the identification assumes)."""
    return replace(effects, **{f.name: 0.0 for f in fields(Effects)
                               if f.name not in ("cogging_periods", "cogging_phase")})

"""A second, independent simulator of the identification experiment, and analytic oracles.

It shares no code with ``seaforce_ros`` (neither its simulator, nor its Dahl model, nor its
sensors): it is the oracle the identification is measured against, so that an error the
project's own simulator and ``identify`` share (an alignment convention, a discretisation, a
Dahl timing) shows up.

The continuous-time model (paper Section II-C; motor passive, F_a = 0)::

    m X'' + b X' + k X          = F_p
    m_e X_e'' + b_e X_e' + k_e X_e = F_e - F_p - F_d
    F_p = b_s (X_e' - X') + k_s (X_e - X)
    dF_d/dt = sigma X_e' (1 - (F_d/F_c) sgn X_e')           (Dahl, eq. 14-15, n = 1)

Discretisation (deliberately not the project's exact zero-order-hold one): ``substeps`` steps
of the trapezoidal rule (bilinear transform) per sample on the four linear states, with the
Dahl force as a continuous input -- predicted, then corrected once from the endpoint's path
over the substep (Heun). The external chirp torque is either held over each sample (``hold``:
a drive's command, the sim node's ``torque_chirp``) or continuous (a sampled force sensor).

Sensors as the rig's (quantised, noisy; the values of ``core/sensors.py`` by default, restated
here): pressure force through a 16-bit ADC over +-10 N m with 5e-4 N m Gaussian noise, motor
encoder 2^20 counts/rev, endpoint encoder 40,000 counts/rev, motor velocity the backward
difference of the quantised position.

:func:`draw_family` draws the randomised family of plants (each parameter log-uniform around
Table I, see there) the identification is measured on; :func:`transfer_functions` gives the
paper's four plants (Fig. 4 A-D) analytically from the eight parameters.
"""
from __future__ import annotations

import math

import numpy as np

#: Table I (paper), the centre of the family
TABLE_I = {"motor_inertia": 1.1116e-3, "motor_damping": 2.9814e-2, "motor_stiffness": 0.1642,
           "endpoint_inertia": 0.7089e-3, "endpoint_damping": 3.3879e-2,
           "endpoint_stiffness": 0.0637, "hose_damping": 9.2453e-3, "hose_stiffness": 13.0782}
#: the paper's Dahl parameters (Section IV)
DAHL = {"sigma": 12.8, "coulomb_force": 0.032}
KEYS = tuple(TABLE_I)


def draw_family(rng):
    """One draw of the family: each plant parameter log-uniform in [0.33x, 3x] of Table I,
    sigma and F_c log-uniform in [0.5x, 2x] of the paper's (n = 1).

    Returns ``(plant dict, dahl dict)``."""
    plant = {k: v * math.exp(rng.uniform(math.log(0.33), math.log(3.0)))
             for k, v in TABLE_I.items()}
    dahl = {k: v * math.exp(rng.uniform(math.log(0.5), math.log(2.0))) for k, v in DAHL.items()}
    return plant, dahl


def quanta(pressure_range=10.0, pressure_bits=16, motor_counts=2 ** 20):
    """The rig's sensor steps: ``(pressure ADC step [N m], motor encoder step [rad])`` (0:
    not quantised)."""
    qp = 2.0 * pressure_range / 2 ** pressure_bits if pressure_bits else 0.0
    qx = 2.0 * math.pi / motor_counts if motor_counts else 0.0
    return qp, qx


def _matrices(p):
    m, b, k = p["motor_inertia"], p["motor_damping"], p["motor_stiffness"]
    me, be, ke = p["endpoint_inertia"], p["endpoint_damping"], p["endpoint_stiffness"]
    bs, ks = p["hose_damping"], p["hose_stiffness"]
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-(k + ks) / m, -(b + bs) / m, ks / m, bs / m],
                  [0.0, 0.0, 0.0, 1.0],
                  [ks / me, bs / me, -(ke + ks) / me, -(be + bs) / me]])
    bvec = np.array([0.0, 0.0, 0.0, 1.0 / me])       # endpoint force input
    return a, bvec


def _dahl_after(fd, dx, sigma, fc):
    """The Dahl force after a monotone path increment ``dx`` (exact solution of eq. 15)."""
    if dx == 0.0 or sigma == 0.0:
        return fd
    if dx > 0.0:
        return fc - (fc - fd) * math.exp(-sigma * dx / fc)
    return -fc + (fc + fd) * math.exp(sigma * dx / fc)


def simulate_chirp(plant, dahl=None, duration=120.0, amplitude=0.3, start_hz=0.01,
                   end_hz=1000.0, dt=5e-4, tail=1.0, substeps=2, hold=True, seed=0,
                   pressure_noise=5e-4, pressure_range=10.0, pressure_bits=16,
                   motor_counts=2 ** 20, endpoint_counts=40000):
    """The external-torque log chirp on the endpoint, motor passive.

    Parameters
    ----------
    plant : dict of the eight parameters (:data:`KEYS`)
    dahl : dict ``{sigma, coulomb_force}`` or None
    duration : float, s (chirp; ``tail`` s of rest follow)
    amplitude : float, N m
    start_hz, end_hz : float, Hz (instantaneous frequency ``f0 (f1/f0)^(t/T)``)
    substeps : int >= 1 (trapezoidal steps per sample)
    hold : bool (F_e held over each sample, else continuous)

    Returns
    -------
    dict of arrays ``x v f_p f_a x_e f_e`` (measured, one per sample) and ``x_e_true``,
    ``f_d_true``.
    """
    n = int(round((duration + tail) / dt))
    h = dt / substeps
    a, bvec = _matrices(plant)
    eye = np.eye(4)
    lhs = np.linalg.inv(eye - 0.5 * h * a)
    ad = lhs @ (eye + 0.5 * h * a)
    bd = lhs @ (h * bvec)
    (a00, a01, a02, a03), (a10, a11, a12, a13), (a20, a21, a22, a23), (a30, a31, a32, a33) = \
        ad.tolist()
    g0, g1, g2, g3 = (0.5 * bd).tolist()          # trapezoid: B (u0 + u1)/2
    ks, bs = plant["hose_stiffness"], plant["hose_damping"]
    sigma = dahl["sigma"] if dahl else 0.0
    fc = dahl["coulomb_force"] if dahl else 1.0
    rate = math.log(end_hz / start_hz) / duration

    def force(t):
        if t >= duration:
            return 0.0
        return amplitude * math.sin(2.0 * math.pi * start_hz * math.expm1(rate * t) / rate)

    def dahl_after(fd, dx):
        # exact solution of eq. 15 along a monotone path increment dx
        if dx == 0.0 or sigma == 0.0:
            return fd
        if dx > 0.0:
            return fc - (fc - fd) * math.exp(-sigma * dx / fc)
        return -fc + (fc + fd) * math.exp(sigma * dx / fc)

    rng = np.random.default_rng(seed)
    noise = (rng.standard_normal(n) * pressure_noise).tolist()
    x0 = x1 = x2 = x3 = 0.0
    fd = 0.0
    out_x = np.empty(n)
    out_fp = np.empty(n)
    out_xe = np.empty(n)
    out_fe = np.empty(n)
    out_fd = np.empty(n)
    fe_now = force(0.0)
    for i in range(n):
        t = i * dt
        fe_sample = force(t)
        out_x[i] = x0
        out_xe[i] = x2
        out_fp[i] = ks * (x2 - x0) + bs * (x3 - x1) + noise[i]
        out_fe[i] = fe_sample
        out_fd[i] = fd
        for j in range(substeps):
            if hold:
                fe0 = fe1 = fe_sample
            else:
                fe0 = fe_now
                fe1 = force(t + (j + 1) * h)
                fe_now = fe1
            u0 = fe0 - fd
            # predictor: F_d constant over the substep
            s = u0 + fe1 - fd
            y2 = a20 * x0 + a21 * x1 + a22 * x2 + a23 * x3 + g2 * s
            fd1 = dahl_after(fd, y2 - x2)
            # corrector: the Dahl force at the end of the substep from the predicted path
            s = u0 + fe1 - fd1
            y0 = a00 * x0 + a01 * x1 + a02 * x2 + a03 * x3 + g0 * s
            y1 = a10 * x0 + a11 * x1 + a12 * x2 + a13 * x3 + g1 * s
            y2 = a20 * x0 + a21 * x1 + a22 * x2 + a23 * x3 + g2 * s
            y3 = a30 * x0 + a31 * x1 + a32 * x2 + a33 * x3 + g3 * s
            fd = dahl_after(fd, y2 - x2)
            x0, x1, x2, x3 = y0, y1, y2, y3
    qx = 2.0 * math.pi / motor_counts if motor_counts else 0.0
    qe = 2.0 * math.pi / endpoint_counts if endpoint_counts else 0.0
    xq = np.round(out_x / qx) * qx if qx else out_x
    xeq = np.round(out_xe / qe) * qe if qe else out_xe
    fp = np.clip(out_fp, -pressure_range, pressure_range)
    if pressure_bits:
        qp = 2.0 * pressure_range / 2 ** pressure_bits
        fp = np.minimum(np.round(fp / qp) * qp, pressure_range - qp)
    v = np.diff(xq, prepend=xq[0]) / dt
    return {"x": xq, "v": v, "f_p": fp, "f_a": np.zeros(n), "x_e": xeq, "f_e": out_fe,
            "x_e_true": out_xe, "f_d_true": out_fd}


def transfer_functions(plant, omega):
    """The four plants of the paper's Fig. 4 at ``omega`` [rad/s], from the model equations
    (motor passive): A = X/F_p, B = X_e/(F_e - F_p), C = F_p/(X_e - X), D = X_e/F_e."""
    s = 1j * np.asarray(omega, float)
    p = plant
    zm = p["motor_inertia"] * s ** 2 + p["motor_damping"] * s + p["motor_stiffness"]
    ze = p["endpoint_inertia"] * s ** 2 + p["endpoint_damping"] * s + p["endpoint_stiffness"]
    zs = p["hose_damping"] * s + p["hose_stiffness"]
    # F_p = zs (X_e - X), X = F_p/zm  ->  F_p = zs zm/(zm + zs) X_e
    hose_series = zs * zm / (zm + zs)
    return {"A": 1.0 / zm, "B": 1.0 / ze, "C": zs, "D": 1.0 / (ze + hose_series)}


def write_bag(path, channels, data, keep=None, dt=5e-4, storage="mcap",
              topic="/actuator_state"):
    """Write ``data`` (channel -> dict of ``x v f_p f_a x_e f_e`` arrays) as ``actuator_state``
    messages into the rosbag2 directory ``path`` with the ``rosbags`` writer; ``keep`` (a
    boolean mask over the samples) leaves the other cycles out of the bag (lost messages:
    gaps in ``cycle``)."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin

    from seaforce_ros.bags import serialize_states, typestore
    rows, stamps = serialize_states(channels, data, dt=dt)
    index = np.arange(rows.shape[0]) if keep is None else np.flatnonzero(keep)
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    writer = Writer(path, version=8, storage_plugin=plugin)
    writer.open()
    conn = writer.add_connection(topic, "seaforce_msgs/msg/ActuatorState",
                                 typestore=typestore())
    for i in index.tolist():
        writer.write(conn, int(stamps[i]), rows[i].tobytes())
    writer.close()
    return path


def drop_mask(n, fraction, rng, longest=40):
    """A mask over ``n`` samples that loses about ``fraction`` of them, in bursts of 1 to
    ``longest`` samples at random places (never the first or last sample)."""
    keep = np.ones(n, bool)
    lost = 0
    while lost < fraction * n:
        length = int(rng.integers(1, longest + 1))
        start = int(rng.integers(1, n - length - 1))
        lost += int(keep[start:start + length].sum())
        keep[start:start + length] = False
    return keep


def _motor_matrices(p):
    """The 4-state model with both inputs: motor torque (column 0), endpoint force (column 1)."""
    a, b_end = _matrices(p)
    b_motor = np.array([0.0, 1.0 / p["motor_inertia"], 0.0, 0.0])
    return a, np.stack([b_motor, b_end], axis=1)


def free_air_admittance(plant, omega, servo=(0.0, 0.0)):
    """X/F_exc of the motor with the endpoint free, under the centring servo
    ``F_a = F_exc - K_p X - K_d V`` (delays neglected), at ``omega`` [rad/s]: the motor sees
    its own impedance, the servo's and the port's ``Z_s Z_e/(Z_s + Z_e)``."""
    s = 1j * np.asarray(omega, float)
    p = plant
    zm = p["motor_inertia"] * s ** 2 + p["motor_damping"] * s + p["motor_stiffness"]
    ze = p["endpoint_inertia"] * s ** 2 + p["endpoint_damping"] * s + p["endpoint_stiffness"]
    zs = p["hose_damping"] * s + p["hose_stiffness"]
    kp, kd = servo
    return 1.0 / (zm + kp + kd * s + zs * ze / (zs + ze))


def chirp_envelope(plant, start_hz, end_hz, servo=(0.0, 0.0), max_position=1.0,
                   max_velocity=10.0, max_torque=0.5, margin=0.5, points=400):
    """Torque amplitude [N m] of a motor log chirp as a function of frequency [Hz]: the
    largest that keeps ``margin`` of ``max_position`` [rad] and ``max_velocity`` [rad/s] on
    ``plant``'s free-air admittance, at most ``max_torque``. Returns ``(hz, amplitude)``
    arrays (interpolate in log frequency)."""
    hz = np.logspace(math.log10(start_hz), math.log10(end_hz), points)
    w = 2.0 * math.pi * hz
    gain = np.abs(free_air_admittance(plant, w, servo))
    amp = np.minimum(max_position / gain, max_velocity / (w * gain))
    return hz, np.minimum(margin * amp, max_torque)


def motor_chirp(plant, duration=40.0, start_hz=0.3, end_hz=800.0, dt=5e-4, tail=0.2,
                servo=(0.1, 0.002), fade=0.5, **envelope):
    """The excitation samples [N m] of a motor-torque log chirp ``start_hz`` -> ``end_hz``
    over ``duration`` s (amplitude :func:`chirp_envelope` on ``plant``, raised-cosine fades
    of ``fade`` s at both ends, ``tail`` s of zero after)."""
    n = int(round((duration + tail) / dt))
    t = np.arange(n) * dt
    rate = math.log(end_hz / start_hz) / duration
    tc = np.minimum(t, duration)
    phase = 2.0 * math.pi * start_hz * np.expm1(rate * tc) / rate
    f_inst = start_hz * np.exp(rate * tc)
    hz, amp = chirp_envelope(plant, start_hz, end_hz, servo, **envelope)
    a = np.interp(np.log(f_inst), np.log(hz), amp)
    e = np.clip(np.minimum(t, duration - t) / fade, 0.0, 1.0)
    e = 0.5 * (1.0 - np.cos(math.pi * e))
    return np.where(t < duration, a * e * np.sin(phase), 0.0)


def simulate_motor_excitation(plant, dahl=None, excitation=None, servo=(0.1, 0.002), dt=5e-4,
                              substeps=2, seed=0, pressure_noise=5e-4, pressure_range=10.0,
                              pressure_bits=16, motor_counts=2 ** 20, **chirp):
    """A motor-torque excitation with the endpoint free (F_e = 0) under a weak centring servo.

    Each sample k: measure (quantised X, backward-difference V, F_p with noise), command
    ``excitation[k] - K_p X - K_d V``; the command is applied one sample later and held over
    that sample (the EtherCAT frame's delay), so the torque acting during ``[k, k+1]`` is the
    command of sample ``k - 1`` and the torque reported at sample k (``applied``) is the one
    that acted during ``[k-1, k]``. No endpoint encoder: ``x_e`` is NaN.

    Parameters
    ----------
    plant : dict of the eight parameters; dahl : dict ``{sigma, coulomb_force}`` or None
    excitation : array [N m] or None (default :func:`motor_chirp` on ``plant`` with ``chirp``)
    servo : (K_p [N m/rad], K_d [N m s/rad])

    Returns
    -------
    dict of arrays ``x v f_p applied command excitation x_e f_e`` and ``x_e_true``,
    ``f_d_true``.
    """
    if excitation is None:
        excitation = motor_chirp(plant, dt=dt, servo=servo, **chirp)
    exc = np.asarray(excitation, float)
    n = exc.size
    h = dt / substeps
    a, bmat = _motor_matrices(plant)
    eye = np.eye(4)
    lhs = np.linalg.inv(eye - 0.5 * h * a)
    ad = (lhs @ (eye + 0.5 * h * a)).tolist()
    bd = (lhs @ (h * bmat)).tolist()
    (a00, a01, a02, a03), (a10, a11, a12, a13), (a20, a21, a22, a23), (a30, a31, a32, a33) = ad
    (m0, e0), (m1, e1), (m2, e2), (m3, e3) = bd
    e0, e1, e2, e3 = 0.5 * e0, 0.5 * e1, 0.5 * e2, 0.5 * e3       # trapezoid: (u0 + u1)/2
    ks, bs = plant["hose_stiffness"], plant["hose_damping"]
    sigma = dahl["sigma"] if dahl else 0.0
    fc = dahl["coulomb_force"] if dahl else 1.0
    kp, kd = servo
    qx = 2.0 * math.pi / motor_counts if motor_counts else 0.0
    qp = 2.0 * pressure_range / 2 ** pressure_bits if pressure_bits else 0.0

    def dahl_after(fd, dx):
        # exact solution of eq. 15 along a monotone path increment dx
        return _dahl_after(fd, dx, sigma, fc)

    rng = np.random.default_rng(seed)
    noise = (rng.standard_normal(n) * pressure_noise).tolist()
    exc_l = exc.tolist()
    out = {k: np.empty(n) for k in ("x", "v", "f_p", "applied", "command", "x_e_true",
                                     "f_d_true")}
    ox, ov, ofp, oap, ocm, oxe, ofd = (out[k] for k in ("x", "v", "f_p", "applied", "command",
                                                        "x_e_true", "f_d_true"))
    x0 = x1 = x2 = x3 = 0.0
    fd = 0.0
    acting = 0.0          # torque held during the coming sample
    pending = 0.0         # the command of this sample, applied from the next
    xq_prev = 0.0
    for i in range(n):
        xq = qx * round(x0 / qx) if qx else x0
        fp = ks * (x2 - x0) + bs * (x3 - x1) + noise[i]
        fp = max(-pressure_range, min(pressure_range, fp))
        if qp:
            fp = min(qp * round(fp / qp), pressure_range - qp)
        v = (xq - xq_prev) / dt
        xq_prev = xq
        cmd = exc_l[i] - kp * xq - kd * v
        ox[i], ov[i], ofp[i], ocm[i], oxe[i], ofd[i] = xq, v, fp, cmd, x2, fd
        oap[i] = acting
        acting, pending = pending, cmd
        u = acting
        for _ in range(substeps):
            c = -fd
            y2 = a20 * x0 + a21 * x1 + a22 * x2 + a23 * x3 + m2 * u + e2 * (c - fd)
            fd1 = dahl_after(fd, y2 - x2)
            c = -fd - fd1
            y0 = a00 * x0 + a01 * x1 + a02 * x2 + a03 * x3 + m0 * u + e0 * c
            y1 = a10 * x0 + a11 * x1 + a12 * x2 + a13 * x3 + m1 * u + e1 * c
            y2 = a20 * x0 + a21 * x1 + a22 * x2 + a23 * x3 + m2 * u + e2 * c
            y3 = a30 * x0 + a31 * x1 + a32 * x2 + a33 * x3 + m3 * u + e3 * c
            fd = dahl_after(fd, y2 - x2)
            x0, x1, x2, x3 = y0, y1, y2, y3
    out["excitation"] = exc.copy()
    out["x_e"] = np.full(n, np.nan)
    out["f_e"] = np.full(n, np.nan)
    return out


class MotorTorqueSim:
    """The same model stepped one sample at a time with a motor torque F_a as the input (the
    endpoint free, F_e = 0): what a closed loop runs on. The command given to :meth:`step` is
    applied over the *next* sample (one sample of delay, as the rig's bus), held; the state is
    integrated by ``substeps`` trapezoidal steps per sample with the Dahl force predicted and
    corrected (Heun), as :func:`simulate_chirp`. :meth:`measure` gives what the sensors report
    (quantised motor position, backward-difference velocity, the pressure ADC with noise) and
    the torque applied over the last sample.

    Parameters: ``plant`` and ``dahl`` dicts as :func:`simulate_chirp`; ``dt`` [s]; ``seed`` of
    the pressure noise; the sensor settings of :func:`simulate_chirp`.
    """

    def __init__(self, plant, dahl=None, dt=5e-4, substeps=2, seed=0, pressure_noise=5e-4,
                 pressure_range=10.0, pressure_bits=16, motor_counts=2 ** 20):
        h = dt / substeps
        a, bvec = _matrices(plant)
        bm = np.array([0.0, 1.0 / plant["motor_inertia"], 0.0, 0.0])
        eye = np.eye(4)
        lhs = np.linalg.inv(eye - 0.5 * h * a)
        self._ad = (lhs @ (eye + 0.5 * h * a)).tolist()
        self._be = (lhs @ (0.5 * h * bvec)).tolist()     # endpoint force, trapezoid
        self._bm = (lhs @ (h * bm)).tolist()             # motor torque, held
        self._ks, self._bs = plant["hose_stiffness"], plant["hose_damping"]
        self._sigma = dahl["sigma"] if dahl else 0.0
        self._fc = dahl["coulomb_force"] if dahl else 1.0
        self._substeps = substeps
        self._dt = dt
        self._rng = np.random.default_rng(seed)
        self._noise = pressure_noise
        self._range = pressure_range
        self._qp, self._qx = quanta(pressure_range, pressure_bits, motor_counts)
        self.state = [0.0, 0.0, 0.0, 0.0]
        self.dahl_force = 0.0
        self._pending = 0.0
        self.applied = 0.0
        self._xq_prev = 0.0

    def _dahl_after(self, fd, dx):
        sigma, fc = self._sigma, self._fc
        if dx == 0.0 or sigma == 0.0:
            return fd
        if dx > 0.0:
            return fc - (fc - fd) * math.exp(-sigma * dx / fc)
        return -fc + (fc + fd) * math.exp(sigma * dx / fc)

    def measure(self):
        """``(x, v, f_p, f_a)``: motor position [rad], velocity [rad/s], pressure force [N m],
        the torque applied over the last sample [N m]."""
        x0, x1, x2, x3 = self.state
        xq = round(x0 / self._qx) * self._qx if self._qx else x0
        v = (xq - self._xq_prev) / self._dt
        fp = self._ks * (x2 - x0) + self._bs * (x3 - x1) + self._noise * self._rng.standard_normal()
        fp = min(self._range, max(-self._range, fp))
        if self._qp:
            fp = min(round(fp / self._qp) * self._qp, self._range - self._qp)
        return xq, v, fp, self.applied

    def step(self, command):
        """Advance one sample: the torque commanded last sample is applied over it."""
        x0, x1, x2, x3 = self.state
        self._xq_prev = round(x0 / self._qx) * self._qx if self._qx else x0
        u = self._pending
        self._pending = float(command)
        self.applied = u
        ad, be, bm = self._ad, self._be, self._bm
        fd = self.dahl_force
        for _ in range(self._substeps):
            def advance(s):
                return [ad[i][0] * x0 + ad[i][1] * x1 + ad[i][2] * x2 + ad[i][3] * x3
                        + be[i] * s + bm[i] * u for i in range(4)]
            predicted = advance(-2.0 * fd)
            fd1 = self._dahl_after(fd, predicted[2] - x2)
            y = advance(-fd - fd1)
            fd = self._dahl_after(fd, y[2] - x2)
            x0, x1, x2, x3 = y
        self.state = [x0, x1, x2, x3]
        self.dahl_force = fd

"""What keeps a finger in its joint range and stops a finger the controller drives away.

Two stages of :meth:`ChannelController.update <seaforce_ros.core.controller.ChannelController
.update>`, each plain Python over explicit state, no allocation per sample:

* :class:`JointWalls` (``limits.*``) -- in every mode that commands torque (all but
  ``passive``; jobs included). Inside each end of the joint range ``position_min..
  position_max`` a soft virtual wall of width ``wall_band`` pushes back: with the penetration
  ``p`` of the motor position X or of the estimated endpoint X_e_hat, whichever is deeper,
  and the velocity ``u`` of that one (V or V_e_hat)::

      F_w = -(K_w p + B_w min(1, 4 p/band) u),  never pulling towards the wall,
      |F_w| <= max_torque

  (a damping that rises over the first quarter of the band: no step in the torque where the
  finger enters it). The wall force is added to the torque of a torque mode or job, and to
  the reference F_ref of a mode that runs the DOB, which renders it on the nominal plant below
  lambda. A spring and a damper that only push: the walls are passive. Beyond the range
  itself (X or X_e_hat outside ``position_min..position_max``) :attr:`JointWalls.beyond`
  says why, and :class:`~.control_cycle.ControlCycle` latches a ``joint_limit`` fault (zero
  torque until ``~/reset``).

* :class:`RunawayMonitor` (``monitor.*``) -- in every mode that runs the DOB (the feed-forward
  modes, ``impedance``, ``force``, ``dob`` and a grasp). The feed-forward cancels the friction
  *of the model*; where the finger has less (a model off by more than the margin of
  ``feedforward.margin``), its net stiffness, damping or hysteresis is negative and a free
  finger accelerates away with a time constant of a fraction of a second. The monitor trips
  when the estimated endpoint speed |V_e_hat| has stayed beyond ``max_speed`` for
  ``trip_time``: a speed no backdriving hand gives the finger in these modes, i.e. a kinetic
  energy ``(m_n + m_e) max_speed^2/2`` the finger does not reach unless something drives it.
  (The finger's speed, not the motor's: the motor snaps when a mode releases the hose's
  compression -- hold to dob against the bonded drive, 0.75 N m in the hose: 5.4 rad/s in the
  simulator, 10.9 over ROS, for a few ms, while the finger moved at 0.8.) The channel then falls back, in the same sample, to
  ``monitor.fallback`` (``dob``: the DOB without feed-forward, passive by eq. 28; a trip in
  ``dob`` itself, or in the fall-back, goes on to ``passive``) and stays there until
  ``~/reset``. Reaction time: ``trip_time`` plus one sample (the command's delay). After a
  trip the finger is still fast: the monitor counts again once the speed has been back within
  ``max_speed`` (a new excursion), or at once while it is beyond twice ``max_speed`` (a
  fall-back that does not stop the finger goes on to ``passive``). It trips too when the
  walls have taken more than ``wall_energy`` out of the finger within about
  :data:`WALL_MEMORY` (the energy their force dissipates, ``-F_w V``, forgotten with that time
  constant): a finger that keeps coming back into the walls is driven by something -- a
  feed-forward with negative net damping bounced a free finger between them at 3.5 rad/s rms,
  below ``max_speed``.

* :class:`SettlingWatch` (``monitor.wall_time``, ``monitor.settle_time``) -- beside the
  monitor, in the modes that run the DOB, outside a job: a finger that never comes to rest.
  Every :data:`SETTLE_CHECK` samples it measures the finger's speed from the path X_e_hat
  travelled (its total variation: an oscillation counts as much as a drift), sampled every
  :data:`WATCH_EVERY` samples and low-passed at :data:`PATH_CUTOFF` (the pressure noise
  alone moves X_e_hat by 40 urad a sample: 0.06 rad/s of path unfiltered at 2 kHz; 0.004
  so); it counts as at rest again after :data:`REST_TIME` below :data:`REST_SPEED`. The
  controller counts the samples down (:attr:`SettlingWatch.due`) and calls it when due: its
  per-sample cost is one subtraction. A free finger
  whose feed-forward is right comes to rest within a few seconds of a flick (its residual
  friction, ``1 - margin x uncertainty`` of the model's, damps it). A finger the walls have
  held still for ``wall_time`` trips the fall-back: the controller pushes it onto them (a
  pressure offset, or an over-compensated stiffness: 4 of 24 fingers 0.5x..2x of the
  hand-typed model stayed pressed there), or a hand holds it against the joint limit, which
  falls back too (the conservative side). A finger that has kept moving faster than
  :data:`REST_SPEED` for ``settle_time`` in a feed-forward mode (:attr:`SettlingWatch.restless`)
  and one that creeps steadily one way (:attr:`SettlingWatch.creeping`) are diagnostics, not
  trips: a hand that backdrives the finger for minutes (the bonded-finger experiments, a
  rehab user) looks the same to every signal the controller has -- the estimated external
  force's power is ``(1 - s)`` times the model friction's whether a hand drives the finger or
  an over-compensating feed-forward does (``s`` the feed-forward's share).

What the monitor cannot see: a finger that drifts slowly (a negative net stiffness or damping
small enough to stay below ``max_speed``) -- the walls keep that one in range, and the watch
ends it; and it cannot tell a hand that moves the finger faster than ``max_speed`` from a
runaway (it falls back then too: the conservative side).
"""

from __future__ import annotations

import math

from .params import LimitParams, MonitorParams

__all__ = ["JointWalls", "RunawayMonitor", "SettlingWatch", "WALL_MEMORY", "SETTLE_CHECK",
           "WATCH_EVERY", "REST_SPEED"]

#: Time constant [s] with which the monitor forgets the energy the walls dissipated.
WALL_MEMORY = 2.0


class JointWalls:
    """The soft walls and the hard limit of one channel's joint range (module docstring).

    Parameters
    ----------
    limits : LimitParams
    max_torque : float > 0
        Bound on |F_w| [N m] (the channel's ``max_torque``).

    Attributes (after every :meth:`update`)
    ----------------------------------------
    force : float
        F_w [N m].
    beyond : str
        Why the finger is beyond the joint range (X or X_e_hat outside it), or ''.
    clear : bool
        Neither X nor X_e_hat was in a wall or beyond the range: ``force`` is 0.0 and
        ``beyond`` ''. While both stay within ``free_min..free_max`` another update changes
        nothing and returns 0.0 (the controller skips it then).

    Attributes (configuration)
    --------------------------
    free_min, free_max : float
        The range between the walls [rad].
    """

    __slots__ = ("_lo", "_hi", "free_min", "free_max", "_k", "_b", "_ramp", "_fmax", "force",
                 "beyond", "clear")

    def __init__(self, limits: LimitParams, max_torque: float) -> None:
        self.configure(limits, max_torque)
        self.force = 0.0
        self.beyond = ""
        self.clear = True

    def configure(self, limits: LimitParams, max_torque: float) -> None:
        """New (validated) settings."""
        self._lo, self._hi = limits.position_min, limits.position_max
        band = limits.wall_band
        self.free_min, self.free_max = self._lo + band, self._hi - band
        self._k, self._b = limits.wall_stiffness, limits.wall_damping
        self._ramp = 4.0 / band
        self._fmax = float(max_torque)

    def update(self, x: float, v: float, xe: float, ve: float) -> float:
        """One sample: X [rad], V [rad/s], X_e_hat [rad], V_e_hat [rad/s]; returns F_w [N m]."""
        f = 0.0
        clear = False
        if x > xe:
            hi, hv, lo, lv = x, v, xe, ve
        else:
            hi, hv, lo, lv = xe, ve, x, v
        if hi > self.free_max:
            p = hi - self.free_max
            r = p * self._ramp
            f = -(self._k * p + self._b * (r if r < 1.0 else 1.0) * hv)
            if f > 0.0:
                f = 0.0
            elif f < -self._fmax:
                f = -self._fmax
        elif lo < self.free_min:
            p = self.free_min - lo
            r = p * self._ramp
            f = self._k * p - self._b * (r if r < 1.0 else 1.0) * lv
            if f < 0.0:
                f = 0.0
            elif f > self._fmax:
                f = self._fmax
        else:
            clear = True
        self.force = f
        if hi > self._hi or lo < self._lo:
            clear = False
            if not self.beyond:             # worded once per excursion
                self.beyond = (f"beyond the joint range limits.position_min..position_max = "
                               f"{self._lo:g}..{self._hi:g} rad: motor at {x:.4g} rad, "
                               f"endpoint (estimated) at {xe:.4g} rad")
        elif self.beyond:
            self.beyond = ""
        self.clear = clear
        return f


class RunawayMonitor:
    """The speed envelope of one channel (module docstring).

    Parameters
    ----------
    monitor : MonitorParams
    dt : float > 0
        Sample period [s].

    Attributes
    ----------
    over : int
        Sample periods the speed has been beyond ``max_speed`` without a break.
    reason : str
        Why it tripped (set on the sample it trips), or ''.
    armed : bool
        False after a trip until the speed was back within ``max_speed``.
    wall_work : float
        The energy the walls took out of the finger, forgotten with :data:`WALL_MEMORY` [J].
    calm : bool
        Nothing is counted: ``over`` 0, armed, ``wall_work`` 0. An update with V_e_hat
        within ``max_speed`` then changes nothing and returns False (the controller skips it).
    max_speed, min_speed : float
        ``monitor.max_speed`` and its negative [rad/s].
    """

    __slots__ = ("dt", "max_speed", "min_speed", "_trip", "over", "reason", "armed", "wall_work",
                 "_budget", "_forget", "_grace", "_memory", "calm")

    def __init__(self, monitor: MonitorParams, dt: float) -> None:
        self.dt = float(dt)
        self.configure(monitor)
        self.reset()

    def configure(self, monitor: MonitorParams) -> None:
        """New (validated) settings; the count goes on."""
        self.max_speed = monitor.max_speed
        self.min_speed = -monitor.max_speed
        self._budget = monitor.wall_energy
        self._forget = math.exp(-self.dt / WALL_MEMORY)
        self._memory = int(round(WALL_MEMORY / self.dt))
        # beyond for more than trip_time: the count reaches this (at least one sample)
        self._trip = max(1, int(round(monitor.trip_time / self.dt)) + 1)

    def reset(self) -> None:
        """Forget the count; armed."""
        self.over = 0
        self.reason = ""
        self.armed = True
        self.wall_work = 0.0
        self._grace = 0
        self.calm = True

    def disarm(self) -> None:
        """After a trip: the finger the fall-back has to stop is still fast. Count again once
        the speed has been within ``max_speed`` (a new excursion), or at once beyond twice it
        (the fall-back does not stop it); the walls' energy after :data:`WALL_MEMORY` (they
        take the finger's energy at the trip out of it meanwhile)."""
        self.over = 0
        self.armed = False
        self.wall_work = 0.0
        self._grace = self._memory       # the walls stop the finger the fall-back released
        self.calm = False

    def walls(self, power: float, steps: int = 1) -> None:
        """The power the walls take out of the finger this sample, ``-F_w V`` [W] (counted
        when positive), into the ledger :attr:`wall_work` [J]."""
        if self._grace > 0:
            self._grace -= steps
            return
        w = self.wall_work * (self._forget if steps == 1 else self._forget ** steps)
        if power > 0.0:
            w += power * self.dt * steps
        self.wall_work = w
        if w:
            self.calm = False

    def update(self, v: float, ve: float, steps: int = 1) -> bool:
        """One sample: V (not judged), V_e_hat [rad/s], ``steps`` periods since the previous;
        True on the sample the monitor trips (then :attr:`reason` says why)."""
        vmax = self.max_speed
        if -vmax <= ve <= vmax:
            if self.over:
                self.over = 0
            if not self.armed:
                self.armed = True
            if self.wall_work > self._budget:
                self.reason = (f"finger driven into the joint walls: they took "
                               f"{1e3 * self.wall_work:.3g} mJ out of it within about "
                               f"{WALL_MEMORY:g} s, beyond monitor.wall_energy = "
                               f"{1e3 * self._budget:g} mJ")
                self.disarm()
                return True
            self.calm = not self.wall_work
            return False
        if not self.armed:
            twice = vmax + vmax
            if -twice <= ve <= twice:
                return False
        self.over += steps
        self.calm = False
        if self.over < self._trip:
            return False
        self.reason = (f"finger driven away: endpoint (estimated) speed {abs(ve):.3g} rad/s "
                       f"beyond monitor.max_speed = {vmax:g} rad/s for "
                       f"{1e3 * (self.over - 1) * self.dt:.3g} ms")
        self.disarm()
        return True


#: Samples between the settling watch's looks (50 ms at 2 kHz), and between its samples of
#: X_e_hat (5 ms).
SETTLE_CHECK, WATCH_EVERY = 100, 10
#: The speed [rad/s] below which the finger counts as at rest (the contact estimator's).
REST_SPEED = 0.05
#: A creep: the finger has moved one way, at least this share of its path, for 1 s.
CREEP_SHARE = 0.8
#: The path's low-pass [Hz] and how long [s] the finger must stay below REST_SPEED to count as
#: at rest (a slow oscillation passes through rest twice a period).
PATH_CUTOFF, REST_TIME = 20.0, 0.5


class SettlingWatch:
    """The finger that never comes to rest (module docstring).

    Parameters
    ----------
    monitor : MonitorParams
        ``settle_time`` and ``wall_time`` [s].
    dt : float > 0
        Sample period [s].

    Attributes
    ----------
    moving, walled : float
        How long the finger has kept moving [s]; how long the walls have held it still [s].
    restless : bool
        It has kept moving for ``settle_time`` in a feed-forward mode (a diagnostic).
    creeping : float
        The speed [rad/s] of a finger creeping one way over the last second (0: none).
    reason : str
        Why it trips (set on the look it trips), or ''.
    """

    __slots__ = ("dt", "_settle", "_wall_time", "_count", "_travel", "_last", "_start",
                 "_window", "_window_travel", "moving", "walled", "creeping", "reason", "_a",
                 "_still", "restless", "due")

    def __init__(self, monitor: MonitorParams, dt: float) -> None:
        self.dt = float(dt)
        self._a = 1.0 - math.exp(-2.0 * math.pi * PATH_CUTOFF * WATCH_EVERY * self.dt)
        self.configure(monitor)
        self.reset()

    def configure(self, monitor: MonitorParams) -> None:
        """New (validated) settings; the times go on."""
        self._settle = monitor.settle_time
        self._wall_time = monitor.wall_time

    def reset(self) -> None:
        """Forget everything (a mode entry, a job's end, a fall-back)."""
        self._count = SETTLE_CHECK
        self._travel = 0.0
        self._last = math.nan
        self._start = math.nan             # X_e_hat at the start of the creep window
        self._window = 0
        self._window_travel = 0.0
        self.moving = self.walled = self.creeping = self._still = 0.0
        self.restless = False
        self.reason = ""
        self.due = WATCH_EVERY

    def update(self, xe: float, walls: float, feedforward: bool) -> bool:
        """When :attr:`due` has counted down to 0 (or below: samples skipped): X_e_hat [rad],
        the walls' force [N m] now, whether the mode cancels the finger's friction; True on
        the look that trips (:attr:`reason`)."""
        steps = WATCH_EVERY - self.due
        self.due = WATCH_EVERY
        last = self._last
        if last == last:
            a = self._a if steps == WATCH_EVERY else \
                1.0 - math.exp(-2.0 * math.pi * PATH_CUTOFF * steps * self.dt)
            y = last + a * (xe - last)
            self._travel += abs(y - last)
        else:
            y = self._start = xe
        self._last = y
        self._count -= steps
        if self._count > 0:
            return False
        span = (SETTLE_CHECK - self._count) * self.dt
        self._count = SETTLE_CHECK
        speed = self._travel / span
        self._travel = 0.0
        moving = speed > REST_SPEED
        self._still = 0.0 if moving else self._still + span
        if moving:
            self.moving += span
        elif self._still >= REST_TIME:
            self.moving = 0.0
        self.walled = self.walled + span if (walls != 0.0 and not moving) else 0.0
        self._creep(y, speed * span, moving)
        self.restless = feedforward and self.moving >= self._settle
        if self.walled >= self._wall_time:
            self.reason = (f"finger held on the joint wall for {self.walled:.3g} s (beyond "
                           f"monitor.wall_time = {self._wall_time:g} s, the wall pushing with "
                           f"{abs(walls):.3g} N m): the controller pushes it there -- a "
                           "pressure offset (~/tare) or an over-compensated stiffness -- or "
                           "something holds it")
            return True
        return False

    def _creep(self, xe: float, path: float, moving: bool) -> None:
        """Over windows of about 1 s: the finger moved one way (its net displacement at least
        :data:`CREEP_SHARE` of its path) while moving: :attr:`creeping` its speed."""
        self._window += SETTLE_CHECK
        self._window_travel += path
        if self._window * self.dt < 1.0:
            return
        net = xe - self._start
        seconds = self._window * self.dt
        self.creeping = (net / seconds if moving and self._window_travel > 0.0
                         and abs(net) >= CREEP_SHARE * self._window_travel else 0.0)
        self._start = xe
        self._window = 0
        self._window_travel = 0.0

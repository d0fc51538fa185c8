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

What the monitor cannot see: a finger that drifts slowly (a negative net stiffness or damping
small enough to stay below ``max_speed``) -- the walls keep that one in range; and it cannot
tell a hand that moves the finger faster than ``max_speed`` from a runaway (it falls back
then too: the conservative side).
"""

from __future__ import annotations

import math

from .params import LimitParams, MonitorParams

__all__ = ["JointWalls", "RunawayMonitor", "WALL_MEMORY"]

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

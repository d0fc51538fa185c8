"""Time-domain passivity guard on the DOB's motor port.

The passivity bound of eq. 28 (``m_n >= m - b/lambda``) is sufficient for coupled stability
with *any* passive environment, and conservative for the environments a finger meets. This
guard lets a lighter nominal inertia run: a **passivity observer** (PO) counts the energy that
enters the motor port, and a **passivity controller** (PC) adds damping only when the port has
given back more than it took in -- Ryu and Hannaford's time-domain passivity approach
(B. Hannaford, J.-H. Ryu, "Time-domain passivity control of haptic interfaces", IEEE T-RA
18(1), 2002; J.-H. Ryu, D.-S. Kwon, B. Hannaford, "Stability guaranteed control: time domain
passivity approach", IEEE T-CST 12(6), 2004).

Port and sign
-------------
The port is the DOB loop's input: effort ``F_p + F_ref`` (the hose force plus the mode's
reference, which enters eq. 19 exactly where F_p does; in ``dob`` mode it is F_p alone), flow
the motor velocity V. Positive power flows from the hose into motor + controller. The guard's
force is added to F_ref, so the DOB renders it on its nominal plant: a damping alpha adds
exactly alpha to the port impedance ``Z = F_p/V`` at every frequency (eq. 25 with
``b -> b + alpha``, ``b_n -> b_n + alpha``). A DOB below the bound is the passive DOB with
``m_n* = m - b/lambda`` plus the negative damper ``lambda (m_n* - m_n) V`` (the ramp term of
eq. 19): below lambda it only lightens the finger, above it it is active. In the continuous
model ``alpha >= lambda (m - m_n) - b`` passivates it at every frequency (for
``b_n >= -k/lambda``; beyond, ``alpha >= -(k + lambda b_n)/lambda`` too).

Observer (per sample, no window)
--------------------------------
::

    E_k = min(R, E_{k-1} + (F_k + F_{k-1})/2 (X_k - X_{k-1}) - (S_k - S_{k-1})),  E_0 = R
    S_k = m_n V_k^2 / 2

* the work is the trapezoidal sum over the *position* increment (exact for piecewise-linear
  effort, independent of how the drive estimates V, and right over skipped samples);
* ``S`` is the kinetic energy of the port's apparent inertia (m_n below lambda). Without it a
  passive port's ledger dips below its cap by the kinetic energy it stores and returns (up to
  0.6 mJ in position drives of 0.3-0.5 rad/s, Table I), more than a useful reserve; with it
  by at most 0.2 mJ (at the bound with lambda = 2 pi 10 rad/s; under 0.1 mJ elsewhere). Any
  ``S >= 0`` keeps the observer sound;
* ``R`` (``passivity.reserve``) is the bounded initial reserve and the cap: the ledger never
  credits more than R, so energy absorbed long ago cannot fund a later instability (the
  "reserve problem" of an unbounded PO, cf. Ryu, Preusche, Hannaford, Hirzinger, "Time domain
  passivity control with reference energy following", IEEE T-CST 13(5), 2005, and the bounded
  energy tank of Franken et al., IEEE T-RO 27(4), 2011).

Capping only lowers E, so ``E_k >= 0`` for all k certifies
``sum F dX >= -(R + S_0)``: the guarded port is passive with the bounded initial energy R.

Controller: damping that is held, learned against a source, and released slowly
-------------------------------------------------------------------------------
::

    alpha_demand = alpha_max clip((R/2 - E)/(R/2), 0, 1)
    D_k          = D_{k-1} exp(-T/tau_r) + alpha_{k-1} dz(V_{k-1}) V_{k-1} T   (the guard's flow)
    floor_k      = the peak alpha_demand of the last burst once the ledger is back at R;
                   released (x exp(-T/tau_r)) only while D_k < R/2; dropped by a slow drain
    held_k       = alpha_{k-1} exp(-T/tau_r) while E >= R/2, alpha_{k-1} while a deficit lasts
    alpha_k      = max(alpha_demand, floor_k, held_k)                (0 below 1e-3 alpha_max)
    F_guard      = -alpha_k dz(V)                                    |F_guard| <= max_torque

``dz`` is the dead zone ``passivity.velocity_deadband``. The top half of the reserve is
left for the reactive swing of a passive port and sensor noise; below it the damping rises
with the deficit and reaches ``alpha_max`` (``passivity.max_damping``) at E = 0.

Why not the other variants (all measured on the simulated grid, bench/passivity_guard_grid.py):

* **Per-sample deficit law** ``alpha = -E/(T V^2)`` (Hannaford-Ryu): through the motor's
  inertia and the command delay the damping cannot dissipate a deficit within one sample, so
  the law saturates at every activation: bang-bang damping that chatters (at a few hundred Hz
  in the simulator) and itself drains the ledger (the port's stored energy moves with it).
* **Memoryless damping** (any law of E alone): once it has stopped an oscillation the ledger
  refills -- under the bonded position drive, through the damping of the drive's own motion
  -- the damping drops to zero and the oscillation grows back: a limit cycle fed by one reserve
  per drive cycle (residual 30-170 % of the drive's velocity). Holding the damping and
  releasing it with ``tau_r`` (``passivity.release_time``, 5 s) keeps "just enough" damping
  instead of re-learning it every cycle. It is released only while the ledger is above R/2:
  against a passive object the ledger stays below R/2 after an instability, the demand alone
  settles just short of what the port needs, and the released damping let the oscillation
  grow once more, 2-10 s later, to up to 0.09 rad/s rms (stiff contact, bench grid).
* **Hold and release alone**: against a position source the released damping falls below what
  the port needs, and the source has refilled the ledger meanwhile (through the held damping),
  so the instability returns as a burst worth R/2 every ~``tau_r ln(alpha_peak/alpha_needed)``
  (5-10 s in the bench for 7 of the 45 settings). Hence the **learned floor**. An episode
  (demand > 0) is a *burst* when it starts within 0.2 s of a full ledger: an oscillation that
  spends R/2 that fast grows at a rate no drive cycle has (measured: 0.01-0.12 s from full to
  R/2 for the first instability of the bench's settings, 0.3-7 s for the b_n = -2 k/lambda
  ports, which give energy back at the drive frequency itself). A burst that ends with the
  ledger full again has met a source; its peak demand -- the damping at which the port
  stopped giving energy back -- becomes the floor, kept while the guard's own flow ``D`` (the
  energy its damping took out over the last ~tau_r) shows the source still working against
  it, released with tau_r once that flow is below R/2 (a passive object comes to rest; the
  person lets go). The floor's own damping is such work: any motion faster than
  ``sqrt(R/(2 floor tau_r))`` rms (0.016-0.05 rad/s for floors of 0.4-0.04 at the defaults),
  the finger's commanded motion included, keeps it. A slow drain drops the floor (the held
  damping then follows the demand once the ledger is back above R/2): a floor there cost 1-3
  dB of |Z| where the unguarded drive is stable.
  Over 120 s of the bonded drive at 10 rad/s no burst returns (was: one every 5-10 s); a
  floor of 1.5x the peak gained nothing more there. An ever-held peak was the alternative: it
  never gives the finger its lightness back after one transient.
* **A narrow ramp** (full damping just below E = 0) chatters; **a wide ramp without hold**
  lets the damping follow the reactive swing of the oscillation it should damp.
* **Windowed PO** (energy over the last N samples): no passivity certificate beyond the
  window, and a window short enough to forget the drive's credit is shorter than the reactive
  swing of a passive port at low frequency. The capped ledger forgets credit without a window.
* **Observing the DOB without the guard** (the port's energy less the guard's own
  dissipation, so that the damping cannot refill the ledger): sound too, but wherever the DOB
  delivers energy at the frequency it is driven at (b_n beyond eq. 28), nothing ever pays the
  debt back and the damping ends at ``alpha_max`` (+12 to +24 dB of |Z| in the bonded drive).
* **Velocity dead band**: implemented, default 0. A band stops the guard from damping anything
  slower than it, and in stiff contact (the 126 rad/s motor-hose mode) that left a limit cycle
  of a few times the band's width (0.01 rad/s: 0.02 rad/s rms); quantisation noise of the
  motor velocity costs at most ``alpha`` times one count per sample, and only while the guard
  is active.

Limits. Passivity of the port buys stability against *passive* environments. A position
source refills the ledger through the guard's own damping; the learned floor holds the
damping while it does. A source too slow to keep ``D`` above R/2 (the bonded drive at
0.5 rad/s, 0.05 rad: 0.025 rad/s) leaves the ledger near R/2 with the demand hovering around
what the port needs: a weak oscillation whose energy stays bounded by the reserve (residual
up to ~0.2 rad/s in the bench's settings that diverge without the guard). The first
instability of a setting also spends R/2 before the damping starts. ``S`` counts the inertia
only: with ``k_n > 0`` the nominal spring's swing (``k_n dX^2/2``) needs room in the reserve.

Modes: ``monitor`` observes and computes the damping it would add, and adds nothing;
``active`` adds it. The class is plain Python with explicit state; the hot path uses floats
only. A NaN/inf input, ``steps`` not >= 1, or an overflowing ledger or force gives zero force
for that sample and sets :attr:`fault`, which stays set until :meth:`reset` (the ledger is left
as it was, but for an overflowing force; later finite samples are used again).
"""

import math
from typing import Optional

from .params import GuardParams

__all__ = ["PassivityGuard"]

#: Held damping below this fraction of ``max_damping`` is released to zero.
_RELEASE_TO_ZERO = 1e-3
#: An episode that starts within this time [s] of a full ledger is a burst (module docstring).
_BURST_WINDOW = 0.2


class PassivityGuard:
    """Passivity observer and controller of one motor port (see module docstring).

    Parameters
    ----------
    params : GuardParams
        ``mode``, ``reserve`` R [J], ``max_damping`` alpha_max [N m s/rad],
        ``velocity_deadband`` [rad/s], ``release_time`` tau_r [s].
    dt : float > 0
        Sample period T [s].
    inertia : float >= 0
        Apparent inertia of the port whose kinetic energy the ledger does not count as credit:
        m_n under the DOB [N m s^2/rad].
    max_force : float > 0
        Bound on |F_guard| [N m] (the channel's ``max_torque``).

    Attributes (after every :meth:`update`)
    ----------------------------------------
    energy : float
        Ledger E [J]: the energy the port may still give back before alpha reaches its
        maximum (<= R; negative only when alpha_max is too small for the port).
    dissipated : float
        Energy the guard's damping has taken out since :meth:`reset` [J] (0 in ``monitor``).
    damping : float
        alpha [N m s/rad]; in ``monitor`` the damping it would add.
    floor : float
        The learned floor of alpha [N m s/rad] (0 until an episode ended with a full ledger).
    flow : float
        D: the energy the guard's damping took out, forgotten with tau_r [J] (in ``monitor``
        what it would have taken out).
    force : float
        ``-alpha dz(V)`` [N m] (what :meth:`update` returns in ``active``).
    active : bool
        alpha > 0.
    saturated : bool
        alpha_max or the force bound limits the damping this sample.
    fault : str
        Why the last input was refused (non-finite), or ''.
    """

    def __init__(self, params: Optional[GuardParams] = None, dt: float = 5e-4,
                 inertia: float = 0.0, max_force: float = math.inf) -> None:
        if params is None:
            params = GuardParams()
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt = {dt!r} must be > 0 and finite")
        self.dt = float(dt)
        self.damping = self.floor = 0.0
        self.configure(params, inertia, max_force)
        self.reset()

    def configure(self, params: GuardParams, inertia: float = 0.0,
                  max_force: float = math.inf) -> None:
        """New settings (validated :class:`GuardParams`); the state is kept, its damping and
        floor within the new ``max_damping`` (held damping is not released while a deficit
        lasts: a lowered maximum must bind at once)."""
        if not isinstance(params, GuardParams):
            raise TypeError("params must be a GuardParams")
        if not (math.isfinite(inertia) and inertia >= 0.0):
            raise ValueError(f"inertia = {inertia!r} must be >= 0 and finite")
        if not max_force > 0.0:
            raise ValueError(f"max_force = {max_force!r} must be > 0")
        self.params = params
        self._apply = params.mode == "active"
        self._reserve = params.reserve
        self._half_band = 0.5 * params.reserve
        self._alpha_max = params.max_damping
        self._zero_below = _RELEASE_TO_ZERO * params.max_damping
        self._deadband = params.velocity_deadband
        self._decay = math.exp(-self.dt / params.release_time)
        self._half_m = 0.5 * inertia
        self._f_max = float(max_force)
        self.damping = min(self.damping, params.max_damping)
        self.floor = min(self.floor, self.damping)

    def reset(self) -> None:
        """Full reserve, no damping, no history."""
        self.energy = self._reserve
        self.dissipated = 0.0
        self.damping = 0.0
        self.floor = 0.0
        self.flow = 0.0
        self.force = 0.0
        self.active = False
        self.saturated = False
        self.fault = ""
        self._first = True
        self._x = 0.0
        self._f = 0.0
        self._storage = 0.0
        self._peak = 0.0
        self._burst = False
        self._since_full = 0.0

    def update(self, effort: float, x: float, v: float, steps: int = 1) -> float:
        """One sample: port effort ``F_p + F_ref`` [N m], motor position X [rad], velocity
        V [rad/s], ``steps`` sample periods since the previous one. Returns the force to add
        to F_ref [N m] (0.0 unless ``active``)."""
        if not (math.isfinite(effort) and math.isfinite(x) and math.isfinite(v)
                and 1 <= steps < 1e9):
            return self._refuse(effort, x, v, steps)
        storage = self._half_m * v * v
        if self._first:
            self._first = False
            self._x, self._f, self._storage = x, effort, storage
        e = (self.energy + 0.5 * (effort + self._f) * (x - self._x)
             - (storage - self._storage))
        if not math.isfinite(e):
            return self._refuse(effort, x, v, steps)
        self._x, self._f, self._storage = x, effort, storage
        reserve = self._reserve
        full = e >= reserve
        if full:
            e = reserve
        self.energy = e
        # the damping: what the deficit asks for, or the held damping if that is more
        amax = self._alpha_max
        saturated = False
        demand = 0.0
        half = self._half_band
        if e < half:
            demand = amax * (half - e) / half
            if demand >= amax:
                demand, saturated = amax, True
        decay = self._decay if steps == 1 else self._decay ** steps
        flow = self.flow * decay
        floor = self.floor
        if full:
            self._since_full = 0.0
        else:
            self._since_full += self.dt * steps
        if demand > 0.0 and self._peak == 0.0:  # an episode starts
            self._burst = self._since_full < _BURST_WINDOW
            if not self._burst:
                floor = 0.0                     # a slow drain: the floor is not what it needs
        if demand > self._peak:
            self._peak = demand                 # the most the episode asked for
        elif full and self._peak > 0.0:         # ended with the ledger refilled: a source
            if self._burst and self._peak > floor:
                floor = self._peak
            self._peak = 0.0
        if flow < half:
            floor *= decay                      # nothing works against the damping: release
        if floor < self._zero_below:
            floor = 0.0
        held = self.damping * decay if e >= half else self.damping
        if held < floor:
            held = floor
        if held < self._zero_below:
            held = 0.0
        alpha = demand if demand >= held else held
        db = self._deadband
        vd = v - db if v > db else (v + db if v < -db else 0.0)
        f = -alpha * vd
        if not math.isfinite(f):
            return self._refuse(effort, x, v, steps)
        fmax = self._f_max
        if f > fmax:
            f, saturated = fmax, True
        elif f < -fmax:
            f, saturated = -fmax, True
        self.damping = alpha
        self.floor = floor
        self.flow = flow - f * v * self.dt * steps
        self.active = alpha > 0.0
        self.saturated = saturated
        self.force = f
        if self._apply:
            self.dissipated -= f * v * self.dt * steps
            return f
        return 0.0

    def _refuse(self, effort: float, x: float, v: float, steps: int) -> float:
        self.fault = (f"non-finite input, energy or force, or steps not >= 1 (effort "
                      f"{effort!r}, x {x!r}, v {v!r}, steps {steps!r}): no damping added")
        self.force = 0.0
        self.active = self.saturated = False
        return 0.0

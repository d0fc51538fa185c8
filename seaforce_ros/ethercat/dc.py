"""The host's cycle locked to the bus's reference clock (distributed clocks; no ROS).

With DC, a drive takes its outputs at SYNC0, which the slaves' clocks -- kept on the first DC
slave's, the reference clock -- fire every cycle at ``k * cycle + shift`` of system time. The
master's frame must reach them in between, well before each SYNC0: if the host's cycle ran on
its own clock, the frames would slide against SYNC0 (two oscillators differ by tens of ppm)
until one SYNC0 passes without new outputs (a drive counts it in 0x1C32:0B, and faults past
its limit). So the host follows the reference clock: every frame carries SOEM's read of the
reference clock's system time (the FRMW of 0x0910) as the frame passed it, and
:class:`DcLock`, a PI controller, shifts the host's next deadlines until that time sits at
phase 0 of the cycle -- the shift later SYNC0 fires. SOEM's own DC example does the same with
its ``ec_sync``; this is the project's, with a limit on each step.
"""
from __future__ import annotations

__all__ = ["DcLock"]


class DcLock:
    """PI lock of the frame's passage (the reference clock's time in it) to phase 0.

    Parameters
    ----------
    cycle_ns : int > 0
        The cycle, SYNC0's [ns].
    kp, ki : float
        Proportional and integral gains (per cycle; the correction is
        ``-(kp e + ki sum e)``, e the phase error).
    max_step_ns : float > 0
        Largest shift of the deadlines per cycle [ns] (a first big phase error is taken out
        over many cycles, not at once).

    Attributes
    ----------
    error_ns : float
        The newest phase error [ns] (the frame passed the reference clock this much after
        phase 0; wrapped into +-cycle/2).
    mean_ns, jitter_ns : float
        Running mean of the phase error and of its distance from that mean [ns] (the frame's
        send time varies with the cycle's work: the lock centres it, the jitter remains).
    locked : bool
        The mean phase error has stayed within :attr:`LOCK_BAND` of the cycle for
        :attr:`LOCK_CYCLES` cycles.
    """

    #: Fraction of the cycle the mean phase error must stay within to count as locked.
    LOCK_BAND = 0.05
    #: Cycles it must stay there.
    LOCK_CYCLES = 200
    #: Weight of the newest error in the running mean and jitter.
    AVERAGING = 0.02

    def __init__(self, cycle_ns: int, kp: float = 0.1, ki: float = 0.002,
                 max_step_ns: float = 20000.0) -> None:
        if cycle_ns <= 0:
            raise ValueError(f'cycle_ns must be > 0, got {cycle_ns}')
        self.cycle_ns = int(cycle_ns)
        self.kp, self.ki = float(kp), float(ki)
        self.max_step_ns = float(max_step_ns)
        self._half = self.cycle_ns // 2
        self._band = self.LOCK_BAND * self.cycle_ns
        self._limit = self.max_step_ns / max(self.ki, 1e-12)   # the integral's, anti-windup
        self.reset()

    def reset(self) -> None:
        self.error_ns = self.mean_ns = self.jitter_ns = 0.0
        self._integral = 0.0
        self._inside = 0

    @property
    def locked(self) -> bool:
        return self._inside >= self.LOCK_CYCLES

    def update(self, dc_time_ns: int) -> float:
        """The reference clock's time in the newest frame [ns] -> the shift of the host's
        next deadlines [s] (negative: earlier). (Once per cycle: kept to plain arithmetic.)"""
        cycle = self.cycle_ns
        e = dc_time_ns % cycle
        if e > self._half:
            e -= cycle
        self.error_ns = e
        mean = self.mean_ns + self.AVERAGING * (e - self.mean_ns)
        self.mean_ns = mean
        self.jitter_ns += self.AVERAGING * (abs(e - mean) - self.jitter_ns)
        self._inside = self._inside + 1 if -self._band < mean < self._band else 0
        integral = self._integral + e
        if integral > self._limit:
            integral = self._limit
        elif integral < -self._limit:
            integral = -self._limit
        self._integral = integral
        step = -(self.kp * e + self.ki * integral)
        if step > self.max_step_ns:
            step = self.max_step_ns
        elif step < -self.max_step_ns:
            step = -self.max_step_ns
        return step * 1e-9

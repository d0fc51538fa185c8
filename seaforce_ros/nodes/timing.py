"""Loop timing statistics for the 2 kHz cycles (no ROS imports).

:class:`LoopStats` records cycle start times into a preallocated ring (no allocation per
sample) and summarises rate, period jitter and missed deadlines on demand, for
``/diagnostics`` and the benchmarks.
"""
from __future__ import annotations

import array
import time
from dataclasses import dataclass


@dataclass(frozen=True)
class LoopSummary:
    """Timing of the cycles recorded since the previous summary.

    rate_hz : achieved cycle rate [Hz]
    period_p50_ms, period_p99_ms, period_max_ms : cycle period percentiles [ms]
    jitter_p99_ms : p99 of |period - nominal| [ms]
    missed : cycles whose start was more than one nominal period late
    cycles : cycles in the window
    """

    rate_hz: float
    period_p50_ms: float
    period_p99_ms: float
    period_max_ms: float
    jitter_p99_ms: float
    missed: int
    cycles: int


class LoopStats:
    """Ring buffer of cycle periods.

    Parameters
    ----------
    nominal_period : float > 0
        Target period [s] (5e-4 at 2 kHz).
    capacity : int > 0
        Periods kept between summaries (older ones are overwritten).
    """

    def __init__(self, nominal_period: float, capacity: int = 8192):
        if not nominal_period > 0:
            raise ValueError(f'nominal_period must be > 0 s, got {nominal_period}')
        self.nominal_period = float(nominal_period)
        self._periods = array.array('d', bytes(8 * capacity))
        self._capacity = capacity
        self._count = 0
        self._missed = 0
        self._last = None
        self._window_start = None

    def tick(self, now: float = None) -> None:
        """Record the start of a cycle at monotonic time ``now`` [s]."""
        if now is None:
            now = time.monotonic()
        last = self._last
        self._last = now
        if last is None:
            self._window_start = now
            return
        period = now - last
        self._periods[self._count % self._capacity] = period
        self._count += 1
        if period > 2.0 * self.nominal_period:
            self._missed += 1

    def summary(self, reset: bool = True) -> LoopSummary:
        """Statistics of the window since the last reset."""
        n = min(self._count, self._capacity)
        if n == 0:
            result = LoopSummary(0.0, float('nan'), float('nan'), float('nan'), float('nan'), 0, 0)
        else:
            periods = sorted(self._periods[:n])
            elapsed = (self._last - self._window_start) if self._window_start is not None else 0.0
            jitter = sorted(abs(p - self.nominal_period) for p in periods)
            result = LoopSummary(
                rate_hz=self._count / elapsed if elapsed > 0 else 0.0,
                period_p50_ms=1e3 * periods[n // 2],
                period_p99_ms=1e3 * periods[min(n - 1, int(0.99 * n))],
                period_max_ms=1e3 * periods[-1],
                jitter_p99_ms=1e3 * jitter[min(n - 1, int(0.99 * n))],
                missed=self._missed,
                cycles=self._count)
        if reset:
            self._count = 0
            self._missed = 0
            self._window_start = self._last
        return result


class Deadline:
    """Absolute-deadline pacing of a periodic loop (no drift: deadlines are k * period).

    ``wait()`` sleeps until the next deadline; if the loop is more than ``max_lag`` periods
    behind, it skips ahead instead of bursting to catch up, and counts the skipped cycles.
    """

    def __init__(self, period: float, max_lag: int = 10):
        self.period = float(period)
        self.max_lag = max_lag
        self.start = time.monotonic()
        self.index = 0
        self.skipped = 0

    def wait(self) -> float:
        """Sleep until the next deadline; return the monotonic time at wake-up."""
        self.index += 1
        deadline = self.start + self.index * self.period
        now = time.monotonic()
        if now - deadline > self.max_lag * self.period:
            behind = int((now - deadline) / self.period)
            self.index += behind
            self.skipped += behind
            return now
        remaining = deadline - now
        if remaining > 0:
            time.sleep(remaining)
            return time.monotonic()
        return now


class CommandTiming:
    """Round trip of a state -> command loop, kept by the side that publishes the states.

    ``on_publish(cycle, now)`` just before a state goes out, ``on_command(cycle, now)`` when the
    command answering it arrives, ``on_tick(cycle)`` at the start of the next cycle (counts the
    cycle as late if the answer to ``cycle`` has not arrived yet). No allocation per sample.
    """

    def __init__(self, ring: int = 4096, capacity: int = 8192):
        self._sent = array.array('d', bytes(8 * ring))
        self._rtt = array.array('d', bytes(8 * capacity))
        self._n = 0
        self.answered = -1
        self.late = 0
        self.cycles = 0

    def on_publish(self, cycle: int, now: float) -> None:
        self._sent[cycle % len(self._sent)] = now

    def on_command(self, cycle: int, latest_cycle: int, now: float) -> None:
        self.answered = cycle
        if 0 <= latest_cycle - cycle < len(self._sent):
            self._rtt[self._n % len(self._rtt)] = now - self._sent[cycle % len(self._sent)]
            self._n += 1

    def on_tick(self, previous_cycle: int) -> None:
        self.cycles += 1
        if self.answered != previous_cycle:
            self.late += 1

    def round_trip_ms(self, reset: bool = True):
        """(p50, p99) of the round trips since the last reset [ms] (NaN if none)."""
        values = _ring_values(self._rtt, self._n)
        if reset:
            self._n = 0
        return _percentiles_ms(values)[:2]


def _ring_values(ring, count):
    """The values a ring of ``len(ring)`` slots holds after ``count`` writes."""
    return ring[:min(count, len(ring))]


def _percentiles_ms(values):
    """(p50, p99, max) of ``values`` [s] in ms (NaN if none)."""
    n = len(values)
    if n == 0:
        return float('nan'), float('nan'), float('nan')
    values = sorted(values)
    return (1e3 * values[n // 2], 1e3 * values[min(n - 1, int(0.99 * n))], 1e3 * values[-1])


class BusyTime:
    """Ring of per-cycle busy times (wake-up to end of the cycle's work), for diagnostics:
    how much of the period the cycle uses, and how close its tail comes to the deadline."""

    def __init__(self, capacity: int = 8192):
        self._values = array.array('d', bytes(8 * capacity))
        self._n = 0

    def add(self, seconds: float) -> None:
        self._values[self._n % len(self._values)] = seconds
        self._n += 1

    def percentiles_ms(self, reset: bool = True):
        """(p50, p99, max) since the last reset [ms] (NaN if none)."""
        values = _ring_values(self._values, self._n)
        if reset:
            self._n = 0
        return _percentiles_ms(values)

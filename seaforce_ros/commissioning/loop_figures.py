"""Sensor and loop figures of one channel from its excitation record: the pressure sensor's
noise, the motor encoder's resolution, and the control loop's delay.

Three estimates, each from the record alone (no model of the plant):

* **Pressure noise** sigma_p [N m] of F_p. The k-th backward difference
  ``d_k[i] = sum_j (-1)^j C(k, j) F_p[i - j]`` of white noise of std sigma has the variance
  ``C(2k, k) sigma^2``; a signal at omega is scaled by ``(2 sin(omega T/2))^k``, so relative to
  the noise by ``sin(omega T/2)^k (pi k)^(1/4)``: with k = 6, a component at 100 Hz (2 kHz
  sampling) is suppressed by 4e-7 against the noise, one at 300 Hz by 1e-3. Per block of
  ``block`` samples the robust std ``1.4826 MAD(d_k)/sqrt(C(2k, k))``; the estimate is the
  median over the blocks, which stays unbiased while less than half of the record holds
  content fast enough to pass the difference (a log chirp to 1 kHz spends 13 % of its time
  above 300 Hz). Its 1-sigma is the blocks' spread (robust) over sqrt(blocks), at least the
  MAD's own (1.166 sigma over the root of the n/k independent differences). The result is
  the noise as sampled, ADC quantisation included (a 16-bit ADC over +-10 N m adds
  ``q/sqrt(12)`` = 8.8e-5 N m in quadrature). Measured (bench/loop_figures_accuracy.py, 10 s,
  k = 6): within +-1.6 % of the injected noise (std 5e-4 and 2e-3 N m, smooth signals and
  chirps to 500 Hz), +2.3-2.7 % with a 0.3 N m chirp to 1 kHz, +2.5 % for noise below the
  ADC step (2e-4 N m), with a reported 1-sigma of 2 %. The rest phase at the start, where the
  excitation is zero, gives a second estimate (the same estimator over it alone).
* **Encoder resolution** q [rad] of X: the largest q of which every nonzero position
  difference is an integer multiple (within :data:`QUANTUM_TOLERANCE` of q); the candidates are
  the smallest difference divided by 1..:data:`MAX_QUANTUM_DIVISOR`. A record whose differences
  fit no candidate is not quantised as far as it shows (q = 0, with the smallest step seen).
* **Loop delay** in samples. A command answers state cycle c (its ``cycle``); it is applied
  from the first sample c' > c whose reported ``applied`` torque (``motor_effort``) equals
  the command clamped to the torque limit, within half a drive unit (:func:`command_applied`):
  delay = c' - c. A command
  that no sample within ``max_delay`` applied is missed. A command whose value another command
  within ``max_delay`` cycles shares (within a drive unit) cannot be told from it (a constant
  command): it is ambiguous and counted apart. A state missing from the record between c and
  the sample that applied it (or in a window without one: a gap, the record's end) leaves
  the delay bounded only: censored, counted apart. Reported: p50 and p99 of the delays with
  a distribution-free 95 % interval of p99 (order statistics), the histogram, the missed
  fraction with its 95 % upper bound (Clopper-Pearson), and the states the controller skipped
  (cycles between the first and last command that no command answers).

Inputs: :func:`loop_figures` (an :class:`~.record.ExcitationRecord`),
:func:`loop_figures_from_arrays` (the state and command streams as arrays, e.g. from a bag)
and :func:`read_loop_arrays` (those arrays from a rosbag2 bag's ``actuator_state`` and
``actuator_command``). Malformed input raises :class:`LoopFiguresError` with the reason.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

from .errors import CommissioningError
from .record import ExcitationRecord

__all__ = ["LoopFiguresError", "PressureNoise", "EncoderResolution", "LoopDelay",
           "LoopFigures", "LoopArrays", "pressure_noise", "encoder_resolution", "loop_delay",
           "command_applied", "loop_figures", "loop_figures_from_arrays", "read_loop_arrays",
           "DIFFERENCE_ORDER", "QUANTUM_TOLERANCE", "MAX_QUANTUM_DIVISOR", "MAX_DELAY"]

_Array = npt.NDArray[np.float64]
_Ints = npt.NDArray[np.int64]

#: order k of the backward difference the pressure noise is estimated from
DIFFERENCE_ORDER = 6
#: samples per block of the pressure-noise estimate (0.25 s at 2 kHz)
NOISE_BLOCK = 500
#: a position difference is a multiple of q when within this fraction of q of one
QUANTUM_TOLERANCE = 0.01
#: the encoder quantum is searched among the smallest difference / 1 .. this
MAX_QUANTUM_DIVISOR = 16
#: commands not applied within this many samples are missed
MAX_DELAY = 20
#: fewest rest samples (excitation zero at the start) for the rest-phase noise estimate
MIN_REST = 200
#: MAD -> std of a Gaussian
_MAD_TO_STD = 1.482602218505602


class LoopFiguresError(CommissioningError):
    """A record the loop figures cannot be taken from (lengths, NaN, empty, cycles that do not
    increase); the message says which array and what is wrong."""


@dataclass(frozen=True)
class PressureNoise:
    """Std of the pressure sensor's noise, as sampled (quantisation included).

    Attributes
    ----------
    std : float >= 0
        sigma_p [N m] from the whole record (median over blocks).
    std_1s : float >= 0
        Its 1-sigma [N m] (the blocks' robust spread over sqrt(blocks)).
    blocks : int
        Blocks the median is taken over.
    rest_std : float
        The same estimator over the rest phase at the start alone [N m]; NaN without a rest
        phase of at least :data:`MIN_REST` samples.
    order : int
        The difference order k.
    """

    std: float
    std_1s: float
    blocks: int
    rest_std: float
    order: int


@dataclass(frozen=True)
class EncoderResolution:
    """The quantum of the motor position X.

    Attributes
    ----------
    quantum : float >= 0
        q [rad]; 0 when the record shows no quantisation.
    counts_per_rev : float
        2 pi / q (inf when not quantised).
    steps : int
        Nonzero position differences the figure rests on.
    worst_deviation : float
        Largest distance of a difference from a multiple of q, in q (<= QUANTUM_TOLERANCE
        when quantised; the confidence statement: every one of ``steps`` differences is a
        multiple of q within it).
    smallest_step : float
        The smallest nonzero |difference| [rad] (an upper bound of the resolution when not
        quantised).
    """

    quantum: float
    counts_per_rev: float
    steps: int
    worst_deviation: float
    smallest_step: float

    @property
    def quantised(self) -> bool:
        """The record shows a quantum."""
        return self.quantum > 0.0


@dataclass(frozen=True)
class LoopDelay:
    """When the commands were applied, in samples after the state they answer.

    Attributes
    ----------
    commands : int
        Commands in the record.
    delays : int array
        c' - c of each command whose application was seen (not ambiguous, not censored).
    p50, p99 : float
        Median and 99th percentile of ``delays`` [samples] (NaN when none).
    p99_interval : (float, float)
        Distribution-free 95 % interval of the 99th percentile (order statistics; the upper
        end is inf when fewer than ~300 delays cannot bound it).
    histogram : dict int -> int
        Delay [samples] -> commands.
    missed : int
        Commands no sample within ``max_delay`` applied.
    missed_fraction, missed_upper : float
        missed / (commands - ambiguous) and its 95 % upper bound (Clopper-Pearson).
    ambiguous : int
        Commands whose value a command within ``max_delay`` cycles shares.
    censored : int
        Commands first seen applied after a gap in the state record (delay bounded only).
    skipped : int
        States between the first and last command that no command answers.
    skip_runs, longest_skip : int
        Runs of consecutive skipped states, and the longest one.
    max_delay : int
        The search window [samples].
    """

    commands: int
    delays: _Ints
    p50: float
    p99: float
    p99_interval: Tuple[float, float]
    histogram: Dict[int, int]
    missed: int
    missed_fraction: float
    missed_upper: float
    ambiguous: int
    censored: int
    skipped: int
    skip_runs: int
    longest_skip: int
    max_delay: int


@dataclass(frozen=True)
class LoopFigures:
    """The sensor and loop figures of one channel (:func:`loop_figures`)."""

    pressure: PressureNoise
    encoder: EncoderResolution
    delay: LoopDelay
    notes: List[str] = field(default_factory=list)

    def lines(self) -> List[str]:
        """The figures as report lines."""
        p, e, d = self.pressure, self.encoder, self.delay
        rest = (f"; rest phase alone {p.rest_std:.3g} N m" if math.isfinite(p.rest_std)
                else "")
        out = [f"pressure noise: {p.std:.3g} +- {p.std_1s:.2g} N m (1-sigma; {p.order}th "
               f"differences over {p.blocks} blocks{rest})"]
        if e.quantised:
            out.append(f"motor encoder: {e.quantum:.4g} rad ({e.counts_per_rev:.6g} counts/rev):"
                       f" all {e.steps} steps are multiples within {e.worst_deviation:.2g} q")
        else:
            out.append(f"motor encoder: no quantum seen in {e.steps} steps (smallest step "
                       f"{e.smallest_step:.3g} rad)")
        hist = ", ".join(f"{k}: {v}" for k, v in sorted(d.histogram.items()))
        out.append(f"loop delay: p50 {d.p50:g}, p99 {d.p99:g} samples (95 % interval of p99 "
                   f"{d.p99_interval[0]:g}-{d.p99_interval[1]:g}); histogram {{{hist}}}")
        out.append(f"commands: {d.commands}, missed {d.missed} ({100 * d.missed_fraction:.3g} %,"
                   f" at most {100 * d.missed_upper:.3g} % at 95 %), ambiguous {d.ambiguous}, "
                   f"censored {d.censored}; states skipped {d.skipped} in {d.skip_runs} runs "
                   f"(longest {d.longest_skip})")
        return out + [f"note: {n}" for n in self.notes]


@dataclass(frozen=True)
class LoopArrays:
    """The state and command streams of one channel (one entry per message).

    Attributes
    ----------
    dt : float > 0
        Sample period [s].
    state_cycle : int64 array, strictly increasing
        ``ActuatorState.cycle``.
    x, f_p, applied : float arrays
        ``motor_position`` [rad], ``pressure_force`` [N m], ``motor_effort`` [N m] per state.
    command_cycle : int64 array, strictly increasing
        ``ActuatorCommand.cycle``: the state each command answers.
    command : float array
        ``effort`` [N m] per command.
    excitation : float array, optional
        The excitation per state (for the rest phase; empty: no rest-phase estimate).
    """

    dt: float
    state_cycle: _Ints
    x: _Array
    f_p: _Array
    applied: _Array
    command_cycle: _Ints
    command: _Array
    excitation: _Array = field(default_factory=lambda: np.zeros(0))


# --- input checks ----------------------------------------------------------------------------
def _finite(name: str, a: npt.ArrayLike, n: Optional[int] = None) -> _Array:
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 1:
        raise LoopFiguresError(f"loop figures: {name} must be one-dimensional, has shape "
                               f"{arr.shape}")
    if n is not None and arr.size != n:
        raise LoopFiguresError(f"loop figures: {name} has {arr.size} samples, its cycles "
                               f"{n}: record every array on the same samples")
    bad = ~np.isfinite(arr)
    if bad.any():
        raise LoopFiguresError(f"loop figures: {name} has {int(bad.sum())} non-finite "
                               f"samples (first at index {int(np.argmax(bad))}); drop those "
                               "samples (and their cycles) before taking the figures")
    return arr


def _cycles(name: str, c: npt.ArrayLike, least: int) -> _Ints:
    arr = np.asarray(c)
    if arr.ndim != 1:
        raise LoopFiguresError(f"loop figures: {name} must be one-dimensional")
    if arr.size < least:
        raise LoopFiguresError(f"loop figures: {name} has {arr.size} entries, at least "
                               f"{least} are needed: record a longer excitation")
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise LoopFiguresError(f"loop figures: {name} holds values that are not whole "
                                   "cycle numbers")
    elif arr.dtype.kind not in "iu":
        raise LoopFiguresError(f"loop figures: {name} must hold integers, not {arr.dtype}")
    out = arr.astype(np.int64)
    step = np.diff(out)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0))
        raise LoopFiguresError(
            f"loop figures: {name} does not increase at index {i + 1} ({int(out[i])} -> "
            f"{int(out[i + 1])}): sort the messages by cycle and drop repeats")
    return out


# --- pressure noise --------------------------------------------------------------------------
def _block_noise(f_p: _Array, order: int, block: int) -> _Array:
    """Robust std of the noise per block of the ``order``-th difference."""
    d = np.diff(f_p, n=order)
    gain = math.sqrt(math.comb(2 * order, order))
    n_blocks = max(1, d.size // block)
    used = d[:n_blocks * block].reshape(n_blocks, -1) if d.size >= block else d[None, :]
    med = np.median(used, axis=1, keepdims=True)
    mad = np.median(np.abs(used - med), axis=1)
    return np.asarray(_MAD_TO_STD * mad / gain, dtype=float)


def pressure_noise(f_p: npt.ArrayLike, rest: int = 0, order: int = DIFFERENCE_ORDER,
                   block: int = NOISE_BLOCK) -> PressureNoise:
    """Std of the noise on F_p (module docstring).

    Parameters
    ----------
    f_p : float array
        Measured pressure force F_p [N m], at least ``order + 50`` samples (fewer than
        ``block`` + ``order``: one block).
    rest : int >= 0
        Samples of rest at the start (excitation zero); fewer than :data:`MIN_REST`: no
        rest-phase estimate.
    order : int in 2..12
        Difference order k.
    block : int >= 50
        Samples per block.
    """
    if not 2 <= order <= 12:
        raise LoopFiguresError(f"loop figures: difference order {order} outside 2..12")
    if block < 50:
        raise LoopFiguresError(f"loop figures: noise block of {block} samples, at least 50")
    f = _finite("f_p", f_p)
    if f.size < order + 50:
        raise LoopFiguresError(f"loop figures: {f.size} pressure samples, at least "
                               f"{order + 50} are needed for the noise estimate")
    with np.errstate(over="ignore", invalid="ignore"):
        per_block = _block_noise(f, order, block)
    std = float(np.median(per_block))
    if not math.isfinite(std):
        raise LoopFiguresError(f"loop figures: the pressure samples (up to "
                               f"{float(np.max(np.abs(f))):.3g} N m) overflow their "
                               f"{order}th differences: not a pressure force in N m")
    # the statistical floor: the MAD's std 1.166 sigma/sqrt(n) over the n/k independent
    # differences there are (neighbouring k-th differences share k samples); quantised noise
    # can make every block's MAD the same value, and the spread alone would then say 0
    one = 1.166 * std * math.sqrt(order / max(f.size - order, 1))
    if per_block.size > 1:
        spread = _MAD_TO_STD * float(np.median(np.abs(per_block - std)))
        one = max(one, 1.2533 * spread / math.sqrt(per_block.size))  # std of a median
    rest_std = math.nan
    if rest >= MIN_REST:
        rest_std = float(np.median(_block_noise(f[:rest], order, block)))
    return PressureNoise(std, one, int(per_block.size), rest_std, order)


# --- encoder resolution ----------------------------------------------------------------------
def encoder_resolution(x: npt.ArrayLike, tolerance: float = QUANTUM_TOLERANCE,
                       max_divisor: int = MAX_QUANTUM_DIVISOR) -> EncoderResolution:
    """The quantum of the motor position X (module docstring).

    Parameters
    ----------
    x : float array
        Measured motor position X [rad].
    tolerance : float in (0, 0.25]
        Distance from a multiple, in quanta, still counted as one.
    max_divisor : int >= 1
    """
    pos = _finite("x", x)
    if not 0.0 < tolerance <= 0.25:
        raise LoopFiguresError(f"loop figures: quantum tolerance {tolerance:g} outside (0, 0.25]")
    dx = np.abs(np.diff(pos))
    # float rounding of positions of this size: far below any encoder's step
    floor = 64.0 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(pos))) if pos.size else 1.0)
    steps = dx[dx > floor]
    if steps.size == 0:
        raise LoopFiguresError("loop figures: the motor position never changes: the record "
                               "shows no encoder step (excite the motor)")
    smallest = float(steps.min())
    for m in range(1, max_divisor + 1):
        q = smallest / m
        if q <= floor / tolerance:
            break
        r = steps / q
        worst = float(np.max(np.abs(r - np.round(r))))
        if worst <= tolerance:
            # refine q over all steps: least squares of steps = n q
            n = np.round(r)
            q = float(np.sum(n * steps) / np.sum(n * n))
            r = steps / q
            worst = float(np.max(np.abs(r - np.round(r))))
            return EncoderResolution(q, 2.0 * math.pi / q, int(steps.size), worst, smallest)
    return EncoderResolution(0.0, math.inf, int(steps.size), math.nan, smallest)


# --- loop delay ------------------------------------------------------------------------------
def _as_applied(command: _Array, torque_limit: float,
                effort_quantum: float) -> Tuple[_Array, _Array]:
    """(target, tolerance) [N m] per command: clamped to +-``torque_limit``; an applied torque
    within half the drive's ``effort_quantum`` plus 1e-9 relative (float round trips) of the
    target is that command."""
    target = np.clip(command, -torque_limit, torque_limit)
    return target, 0.5 * effort_quantum + 1e-9 * np.maximum(1.0, np.abs(target))


def command_applied(applied: npt.ArrayLike, command: float, torque_limit: float,
                    effort_quantum: float = 0.0) -> npt.NDArray[np.bool_]:
    """Which ``applied`` torques are ``command`` as the plant applies it: clamped to
    +-``torque_limit`` and rounded to the drive's ``effort_quantum`` (0: none), equal within
    half that quantum plus 1e-9 relative (float round trips).

    Parameters
    ----------
    applied : float array [N m]
    command : float [N m]
    torque_limit : float > 0 [N m]
    effort_quantum : float >= 0 [N m]
    """
    target, tol = _as_applied(np.array([command], dtype=float), torque_limit, effort_quantum)
    return np.asarray(np.abs(np.asarray(applied, float) - target[0]) <= tol[0])


def _quantile_interval(n: int, q: float, level: float = 0.95) -> Tuple[int, int]:
    """0-based order-statistic indices (lo, hi) covering the q-quantile with probability
    >= level (hi = n when the sample cannot bound it from above)."""
    from scipy.stats import binom
    alpha = 1.0 - level
    lo = int(binom.ppf(alpha / 2, n, q)) - 1
    hi = int(binom.ppf(1 - alpha / 2, n, q))
    return max(lo, -1), min(hi, n)


def _upper_bound(k: int, n: int, level: float = 0.95) -> float:
    """Clopper-Pearson one-sided upper bound of a proportion k/n."""
    if n == 0:
        return 1.0
    if k >= n:
        return 1.0
    from scipy.stats import beta
    return float(beta.ppf(level, k + 1, n - k))


def loop_delay(state_cycle: npt.ArrayLike, applied: npt.ArrayLike,
               command_cycle: npt.ArrayLike, command: npt.ArrayLike,
               torque_limit: Optional[float] = None, effort_quantum: float = 0.0,
               max_delay: int = MAX_DELAY) -> LoopDelay:
    """The loop delay (module docstring).

    Parameters
    ----------
    state_cycle : int array, strictly increasing
        Cycles of the states whose ``applied`` torque was recorded.
    applied : float array [N m]
        ``motor_effort`` per state.
    command_cycle : int array, strictly increasing
        The state cycle each command answers.
    command : float array [N m]
    torque_limit : float > 0, optional
        The plant's clamp [N m]; default: the largest |applied| in the record (a command
        beyond it counts as applied where the plant reports that limit with its sign).
    effort_quantum : float >= 0
        Drive torque unit [N m] the plant rounds to (0: none).
    max_delay : int in 1..1000
        Search window [samples].
    """
    sc = _cycles("state cycle", state_cycle, 2)
    ap = _finite("applied", applied, sc.size)
    cc = _cycles("command cycle", command_cycle, 1)
    cmd = _finite("command", command, cc.size)
    if not 1 <= max_delay <= 1000:
        raise LoopFiguresError(f"loop figures: max_delay {max_delay} outside 1..1000 samples")
    if not (math.isfinite(effort_quantum) and effort_quantum >= 0.0):
        raise LoopFiguresError(f"loop figures: effort quantum {effort_quantum!r} must be >= 0")
    limit = float(np.max(np.abs(ap))) if torque_limit is None else float(torque_limit)
    if not (math.isfinite(limit) and limit > 0.0):
        if torque_limit is not None:
            raise LoopFiguresError(f"loop figures: torque limit {torque_limit!r} must be > 0")
        limit = math.inf                     # nothing was ever applied: no clamp seen
    targets, tol = _as_applied(cmd, limit, effort_quantum)
    n = cc.size
    # ambiguous: a command within max_delay cycles (so within max_delay entries) could be
    # applied as the same value (within both tolerances: one drive unit)
    shared = np.zeros(n, bool)
    for k in range(1, min(max_delay, n - 1) + 1):
        same = ((cc[k:] - cc[:-k] <= max_delay)
                & (np.abs(targets[k:] - targets[:-k]) <= tol[k:] + tol[:-k]))
        shared[k:] |= same
        shared[:-k] |= same
    # per command and lag k = 1..max_delay: is state c + k recorded, and does it apply it
    first = np.full(n, -1, dtype=np.int64)      # first lag that applied it
    gap_before = np.zeros(n, bool)              # a state missing before that lag (or at all)
    for k in range(1, max_delay + 1):
        want = cc + k
        idx = np.minimum(np.searchsorted(sc, want), sc.size - 1)
        here = sc[idx] == want
        hit = here & (np.abs(ap[idx] - targets) <= tol) & (first < 0)
        first[hit] = k
        gap_before |= (~here) & (first < 0)
    # the unambiguous commands split into: a state missing before the application (or in
    # a window without one: the record's gaps or its end) -> censored; else applied -> a
    # delay, or not applied within the window -> missed
    clear = ~shared & ~gap_before
    ambiguous = int(shared.sum())
    censored = int((~shared & gap_before).sum())
    missed = int((clear & (first < 0)).sum())
    delays = first[clear & (first > 0)]
    d = np.asarray(delays, dtype=np.int64)
    decided = cc.size - ambiguous - censored
    if d.size:
        p50 = float(np.percentile(d, 50, method="inverted_cdf"))
        p99 = float(np.percentile(d, 99, method="inverted_cdf"))
        srt = np.sort(d)
        i_lo, i_hi = _quantile_interval(int(d.size), 0.99)
        interval = (float(srt[i_lo]) if i_lo >= 0 else -math.inf,
                    float(srt[i_hi]) if i_hi < d.size else math.inf)
    else:
        p50 = p99 = math.nan
        interval = (math.nan, math.nan)
    values, counts = np.unique(d, return_counts=True)
    cycles_span = np.arange(int(cc[0]), int(cc[-1]) + 1)
    answered = np.zeros(cycles_span.size, bool)
    answered[cc - cc[0]] = True
    gaps = np.flatnonzero(~answered)
    runs = int(np.sum(np.diff(gaps) != 1)) + 1 if gaps.size else 0
    longest = 0
    if gaps.size:
        breaks = np.flatnonzero(np.diff(gaps) != 1)
        starts = np.r_[0, breaks + 1]
        ends = np.r_[breaks, gaps.size - 1]
        longest = int(np.max(ends - starts + 1))
    return LoopDelay(int(cc.size), d, p50, p99, interval,
                     {int(k): int(v) for k, v in zip(values, counts)}, missed,
                     missed / decided if decided else math.nan,
                     _upper_bound(missed, decided), ambiguous, censored, int(gaps.size),
                     runs, longest, max_delay)


# --- the whole set ---------------------------------------------------------------------------
def _rest_samples(excitation: _Array) -> int:
    nonzero = np.flatnonzero(excitation != 0.0)
    return int(nonzero[0]) if nonzero.size else int(excitation.size)


def loop_figures_from_arrays(arrays: LoopArrays, torque_limit: Optional[float] = None,
                             effort_quantum: float = 0.0,
                             max_delay: int = MAX_DELAY) -> LoopFigures:
    """The figures from the state and command streams (:class:`LoopArrays`); the keywords
    as in :func:`loop_delay`."""
    if not (arrays.dt > 0.0 and math.isfinite(arrays.dt)):
        raise LoopFiguresError(f"loop figures: dt = {arrays.dt!r} s, must be > 0 and finite")
    sc = _cycles("state cycle", arrays.state_cycle, 2)
    x = _finite("x", arrays.x, sc.size)
    f_p = _finite("f_p", arrays.f_p, sc.size)
    ex = np.zeros(0)
    if len(arrays.excitation):
        ex = _finite("excitation", arrays.excitation, sc.size)
    notes: List[str] = []
    lost = int(sc[-1] - sc[0] + 1 - sc.size)
    if lost:
        notes.append(f"{lost} state cycles missing from the record: the noise estimate "
                     "differences across those gaps (a few blocks at most)")
    rest = _rest_samples(ex) if ex.size else 0
    pressure = pressure_noise(f_p, rest=rest)
    encoder = encoder_resolution(x)
    delay = loop_delay(sc, arrays.applied, arrays.command_cycle, arrays.command,
                       torque_limit=torque_limit, effort_quantum=effort_quantum,
                       max_delay=max_delay)
    if delay.ambiguous > 0.25 * delay.commands:
        notes.append(f"{delay.ambiguous} of {delay.commands} commands share their value with a "
                     "neighbour: the delay rests on the others only (excite with a signal "
                     "that changes every sample)")
    return LoopFigures(pressure, encoder, delay, notes)


def loop_figures(record: ExcitationRecord, torque_limit: Optional[float] = None,
                 effort_quantum: float = 0.0, max_delay: int = MAX_DELAY) -> LoopFigures:
    """The figures from an :class:`~.record.ExcitationRecord`: its states are the samples the
    controller ran on and each answers with one command (``record.command``); the keywords
    as in :func:`loop_delay`."""
    if len(record) == 0:
        raise LoopFiguresError("loop figures: the record is empty")
    return loop_figures_from_arrays(
        LoopArrays(record.dt, record.cycle, record.x, record.f_p, record.applied,
                   record.cycle, record.command, record.excitation),
        torque_limit=torque_limit, effort_quantum=effort_quantum, max_delay=max_delay)


def read_loop_arrays(path: Union[str, "os.PathLike[str]"], channel: str,
                     state_topic: str = "actuator_state",
                     command_topic: str = "actuator_command",
                     dt: Optional[float] = None) -> LoopArrays:
    """The state and command streams of ``channel`` from a rosbag2 bag (mcap or sqlite3): the
    states through :func:`~seaforce_ros.bags.read_channel`, the commands from
    ``seaforce_msgs/msg/ActuatorCommand`` messages (sorted by cycle, repeats of a cycle
    dropped); ``dt`` [s] defaults to the states' stamps (median step over cycles).

    Raises
    ------
    LoopFiguresError
        No commands for the channel in the bag, or no usable sample period.
    seaforce_ros.bags.BagError
        The bag cannot be read, has no states, or not this channel.
    """
    from ..bags import Bag, read_channel, topic_matches, typestore

    rec = read_channel(path, channel, state_topic)
    command_type = "seaforce_msgs/msg/ActuatorCommand"
    store = typestore()
    cycles: List[int] = []
    efforts: List[float] = []
    bag = Bag(path)
    for _t, _m, _ts, data in bag.messages(
            lambda name, msgtype: msgtype == command_type and topic_matches(name, command_topic)):
        msg: Any = store.deserialize_cdr(data, command_type)   # a generated message class
        names = list(msg.name)
        if channel in names:
            cycles.append(int(msg.cycle))
            efforts.append(float(msg.effort[names.index(channel)]))
    if not cycles:
        raise LoopFiguresError(f"loop figures: {path}: no {command_topic} messages for "
                               f"channel {channel!r}; record the controller's commands too")
    order = np.argsort(np.asarray(cycles, dtype=np.int64), kind="stable")
    cc = np.asarray(cycles, dtype=np.int64)[order]
    eff = np.asarray(efforts, dtype=float)[order]
    keep = np.ones(cc.size, bool)
    keep[1:] = cc[1:] != cc[:-1]
    if dt is None:
        steps = np.diff(rec.stamp) / np.maximum(np.diff(rec.cycle), 1)
        dt = float(np.median(steps)) if steps.size else math.nan
        if not (math.isfinite(dt) and dt > 0.0):
            raise LoopFiguresError(f"loop figures: {path}: the state stamps give no sample "
                                   "period; give dt")
    return LoopArrays(dt, rec.cycle, rec.x, rec.f_p, rec.f_a, cc[keep], eff[keep])

"""commissioning.loop_figures on synthetic records whose figures are known by construction.

Oracles (none uses the estimators' own code):

* pressure noise: Gaussian noise of a known std added to a smooth signal, to chirps up to
  200 Hz and 1 kHz and to a rest phase, through the 16-bit ADC over +-10 N m of the sensors;
  the truth is the std of what was added (measured minus clean, quantisation included);
* encoder: positions rounded to 2^20 and 2^14 counts/rev (and 40,000, the endpoint
  encoder's), or not rounded;
* loop delay: a plant model of its own -- command j (answering state c_j) reaches the plant
  in sample a_j = c_j + d_j with d_j drawn (1; 1-3; lost); each sample applies the newest
  command that has arrived (a command overtaken by a newer one is never applied: missed),
  clamped to the torque limit and rounded to the drive's unit. Delays, misses, skips and the
  censoring by gaps are counted from that model's event list.
"""
import math

import numpy as np
import pytest

from seaforce_ros.commissioning.errors import CommissioningError
from seaforce_ros.commissioning.loop_figures import (
    MAX_DELAY, LoopArrays, LoopFiguresError, command_applied, encoder_resolution, loop_delay,
    loop_figures, loop_figures_from_arrays, pressure_noise, read_loop_arrays)
from seaforce_ros.commissioning.record import ExcitationRecord

DT = 5e-4
N = 20000                      # 10 s at 2 kHz
FULL_SCALE = 10.0
ADC_QUANTUM = 2 * FULL_SCALE / 2 ** 16


def _adc(v):
    return np.minimum(np.round(np.clip(v, -FULL_SCALE, FULL_SCALE) / ADC_QUANTUM)
                      * ADC_QUANTUM, FULL_SCALE - ADC_QUANTUM)


def _chirp(n, f0, f1, amp):
    t = np.arange(n) * DT
    rate = math.log(f1 / f0) / t[-1]
    return amp * np.sin(2 * math.pi * f0 * np.expm1(rate * t) / rate)


def _smooth(n):
    t = np.arange(n) * DT
    return 0.5 * np.sin(2 * math.pi * 2 * t) + 0.2 * np.sin(2 * math.pi * 13 * t)


# --- pressure noise ------------------------------------------------------------------------

@pytest.mark.parametrize("shape", ["smooth", "chirp to 200 Hz", "chirp to 1 kHz", "rest"])
@pytest.mark.parametrize("std", [2e-4, 5e-4, 2e-3])
def test_pressure_noise_against_injected_noise(shape, std):
    clean = {"smooth": _smooth(N), "chirp to 200 Hz": _chirp(N, 0.1, 200.0, 0.3),
             "chirp to 1 kHz": _chirp(N, 0.1, 1000.0, 0.3), "rest": np.full(N, 0.02)}[shape]
    rng = np.random.default_rng(int(std * 1e6) + len(shape))
    measured = _adc(clean + std * rng.standard_normal(N))
    truth = float(np.std(measured - clean))
    est = pressure_noise(measured)
    # measured over 5 seeds x these shapes: within +-3 % (k = 6), 1-sigma 1.1-1.5 %
    assert abs(est.std / truth - 1) < 0.06, (est, truth)
    assert 0.005 * truth < est.std_1s < 0.05 * truth, est
    assert abs(est.std - truth) < 5 * est.std_1s, (est, truth)
    assert math.isnan(est.rest_std)


def test_pressure_noise_of_the_rest_phase_too():
    rest = 2000
    clean = np.r_[np.zeros(rest), _chirp(N - rest, 0.5, 200.0, 0.3)]
    rng = np.random.default_rng(5)
    measured = _adc(clean + 5e-4 * rng.standard_normal(N))
    truth = float(np.std(measured - clean))
    est = pressure_noise(measured, rest=rest)
    assert abs(est.std / truth - 1) < 0.06
    assert abs(est.rest_std / truth - 1) < 0.15        # 2000 samples: ~7 % 1-sigma


def test_pressure_noise_sees_no_noise_in_a_smooth_signal():
    est = pressure_noise(_smooth(N))
    assert est.std < 1e-6, est            # a 13 Hz sine passes a 6th difference as ~1e-9


# --- encoder resolution --------------------------------------------------------------------

@pytest.mark.parametrize("counts", [2 ** 20, 2 ** 14, 40000])
@pytest.mark.parametrize("motion", ["slow sine", "chirp", "random walk"])
def test_encoder_quantum_of_quantised_positions(counts, motion):
    x = _motion(motion)
    q = 2 * math.pi / counts
    est = encoder_resolution(np.round(x / q) * q)
    assert est.quantised
    assert est.quantum == pytest.approx(q, rel=1e-9)
    assert round(est.counts_per_rev) == counts
    assert est.worst_deviation < 1e-6 and est.steps > 1000


@pytest.mark.parametrize("motion", ["slow sine", "chirp", "random walk"])
def test_unquantised_positions_show_no_quantum(motion):
    est = encoder_resolution(_motion(motion))
    assert not est.quantised and est.counts_per_rev == math.inf
    assert est.smallest_step > 0


def test_a_motion_that_never_moves_one_count_still_gives_the_count():
    """Steps of 2 and 3 counts only: the quantum is their common divisor, not the smallest."""
    q = 2 * math.pi / 2 ** 14
    rng = np.random.default_rng(3)
    counts = np.cumsum(rng.choice([2, 3, -2, -3], size=5000))
    est = encoder_resolution(counts * q + 0.123)         # an offset that is not a count
    assert est.quantum == pytest.approx(q, rel=1e-9)


def _motion(kind):
    t = np.arange(N) * DT
    if kind == "slow sine":
        return 0.3 * np.sin(2 * math.pi * 0.5 * t) + 1.7
    if kind == "chirp":
        return 0.05 * np.sin(2 * math.pi * 0.8 * np.expm1(t / 4)) - 3.0
    return np.cumsum(np.random.default_rng(1).standard_normal(N)) * 1e-4


# --- loop delay ----------------------------------------------------------------------------

class _Plant:
    """The loop as events: command j answers state cycle c_j, reaches the plant in sample
    a_j = c_j + d_j (d_j = None: lost); sample k applies the newest command arrived by k."""

    def __init__(self, cycles, commands, delays, limit=math.inf, unit=0.0):
        self.cycles = np.asarray(cycles)
        self.commands = np.asarray(commands, float)
        self.arrival = [None if d is None else int(c) + d for c, d in zip(cycles, delays)]
        self.limit, self.unit = limit, unit

    def applied(self, state_cycles):
        order = sorted((a, int(c), j) for j, (a, c) in
                       enumerate(zip(self.arrival, self.cycles)) if a is not None)
        out = np.empty(len(state_cycles))
        newest, value, i = -1, 0.0, 0
        first = {}
        for n, k in enumerate(state_cycles):
            while i < len(order) and order[i][0] <= k:
                _, c, j = order[i]
                if c > newest:
                    newest, value = c, self._as_applied(self.commands[j])
                    first.setdefault(j, None)
                i += 1
            out[n] = value
        return out

    def _as_applied(self, u):
        u = min(max(u, -self.limit), self.limit)
        return round(u / self.unit) * self.unit if self.unit else u

    def truth(self, state_cycles, max_delay=MAX_DELAY):
        """Per command: 'delay' d, 'missed' or 'censored' (a state it needs is not recorded),
        from the event list (a command overtaken by a newer one before its arrival is never
        applied)."""
        recorded = set(int(c) for c in state_cycles)
        out = []
        for j, (c, a) in enumerate(zip(self.cycles, self.arrival)):
            c = int(c)
            overtaken = a is None or any(
                b is not None and b <= a and int(c2) > c
                for c2, b in zip(self.cycles[j + 1:j + 2 * max_delay], self.arrival[j + 1:]))
            end = c + max_delay if overtaken or a - c > max_delay else a
            if any(k not in recorded for k in range(c + 1, end + 1)):
                out.append("censored")
            elif overtaken or a - c > max_delay:
                out.append("missed")
            else:
                out.append(a - c)
        return out


def _record(cycles, commands, applied, seed=0):
    """An ExcitationRecord on ``cycles`` (quantised smooth motion, noisy pressure)."""
    n = len(cycles)
    rng = np.random.default_rng(seed)
    t = np.asarray(cycles, float) * DT
    q = 2 * math.pi / 2 ** 20
    x = np.round(0.2 * np.sin(2 * math.pi * 1.5 * t) / q) * q
    f_p = _adc(0.3 * np.sin(2 * math.pi * 3 * t) + 5e-4 * rng.standard_normal(n))
    return ExcitationRecord(DT, np.asarray(cycles, np.int64), x, np.gradient(x, DT), f_p,
                            np.asarray(applied, float), np.asarray(commands, float),
                            np.asarray(commands, float))


def _check(figures_delay, truth):
    delays = [d for d in truth if isinstance(d, int)]
    assert figures_delay.missed == truth.count("missed")
    assert figures_delay.censored == truth.count("censored")
    assert figures_delay.ambiguous == 0
    assert sorted(figures_delay.delays.tolist()) == sorted(delays)
    hist = {d: delays.count(d) for d in set(delays)}
    assert figures_delay.histogram == hist
    assert figures_delay.p50 == float(np.percentile(delays, 50, method="inverted_cdf"))
    assert figures_delay.p99 == float(np.percentile(delays, 99, method="inverted_cdf"))
    lo, hi = figures_delay.p99_interval
    assert lo <= figures_delay.p99 <= hi


def test_one_sample_delay():
    rng = np.random.default_rng(1)
    cycles = np.arange(100, 100 + N)
    commands = rng.normal(0, 0.5, N)
    plant = _Plant(cycles, commands, [1] * N)
    rec = _record(cycles, commands, plant.applied(cycles))
    fig = loop_figures(rec)
    _check(fig.delay, plant.truth(cycles))
    assert fig.delay.p50 == 1 and fig.delay.p99 == 1 and fig.delay.histogram == {1: N - 1}
    assert fig.delay.missed == 0 and fig.delay.missed_upper < 3.0 / N    # rule of three
    assert fig.delay.skipped == 0 and fig.delay.censored == 1            # the last command
    assert fig.encoder.counts_per_rev == pytest.approx(2 ** 20)
    assert abs(fig.pressure.std / 5.08e-4 - 1) < 0.06     # sqrt(5e-4^2 + q^2/12)
    assert any("loop delay: p50 1, p99 1" in line for line in fig.lines())


def test_a_mix_of_one_to_three_samples_with_drops_and_skipped_states():
    rng = np.random.default_rng(2)
    span = np.arange(N)
    skipped = np.zeros(N, bool)
    for start in rng.choice(np.arange(50, N - 50), size=40, replace=False):
        skipped[start:start + int(rng.integers(1, 4))] = True
    cycles = span[~skipped]
    commands = rng.normal(0, 0.5, cycles.size)
    delays = [None if rng.random() < 0.01 else int(rng.choice([1, 2, 3], p=[.7, .2, .1]))
              for _ in cycles]
    plant = _Plant(cycles, commands, delays)
    rec = _record(cycles, commands, plant.applied(cycles), seed=2)
    fig = loop_figures(rec)
    truth = plant.truth(cycles)
    _check(fig.delay, truth)
    assert fig.delay.skipped == int(skipped.sum())
    runs = int(np.sum(np.diff(np.r_[0, skipped.astype(int)]) == 1))
    assert fig.delay.skip_runs == runs
    assert set(fig.delay.histogram) == {1, 2, 3}
    assert fig.delay.p50 == 1
    # lost (1 %) and overtaken commands (a 3-sample delay followed by a shorter one: the
    # plant takes the newer; about a fifth here) are missed; the fraction's bound covers it
    decided = len(truth) - truth.count("censored")
    assert fig.delay.missed_fraction == pytest.approx(truth.count("missed") / decided)
    assert fig.delay.missed_fraction < fig.delay.missed_upper < fig.delay.missed_fraction + 0.01


def test_clamped_and_rounded_commands_count_as_applied():
    rng = np.random.default_rng(4)
    cycles = np.arange(N)
    commands = rng.uniform(-0.9, 0.9, N)
    commands[::97] = np.sign(commands[::97]) * rng.uniform(1.5, 3.0, commands[::97].size)
    unit = 1e-3
    plant = _Plant(cycles, commands, [2] * N, limit=1.0, unit=unit)
    rec = _record(cycles, commands, plant.applied(cycles))
    for limit in (1.0, None):                     # given, or the largest applied torque
        fig = loop_figures(rec, torque_limit=limit, effort_quantum=unit)
        d = fig.delay
        assert d.missed == 0 and set(d.histogram) == {2}, d.histogram
        # the drive unit makes nearby commands indistinguishable: counted apart, not as
        # delays (about 40 neighbours x 2e-3 N m / 1.8 N m of spread: ~5 %)
        assert 0 < d.ambiguous < 0.1 * N
        assert sum(d.histogram.values()) + d.ambiguous + d.censored == N
    strict = loop_figures(rec, torque_limit=1.0).delay          # no drive unit: misses all
    assert strict.missed > 0.8 * N


def test_command_applied_is_the_clamped_command_within_half_a_drive_unit():
    applied = [1.0, 0.9995, 0.9994, -1.0, 0.5]
    assert command_applied(applied, 2.5, 1.0, 1e-3).tolist() == [True, True, False, False,
                                                                  False]
    assert command_applied(applied, 0.5, 1.0).tolist() == [False] * 4 + [True]


def test_a_constant_command_is_ambiguous_not_a_delay():
    cycles = np.arange(2000)
    commands = np.zeros(2000)
    commands[1000:] = np.random.default_rng(5).normal(0, 0.5, 1000)
    plant = _Plant(cycles, commands, [1] * 2000)
    fig = loop_figures(_record(cycles, commands, plant.applied(cycles)))
    assert fig.delay.ambiguous >= 1000
    assert set(fig.delay.histogram) == {1}
    assert any("share their value" in n for n in fig.notes)


# --- from a bag ----------------------------------------------------------------------------

def test_from_a_bag_with_states_and_commands(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from seaforce_ros.bags import serialize_states, typestore

    rng = np.random.default_rng(6)
    n = 6000
    cycles = np.arange(n)
    commands = rng.normal(0, 0.5, n)
    answered = np.ones(n, bool)
    answered[rng.choice(np.arange(10, n - 10), 30, replace=False)] = False   # skipped
    delays = [int(rng.choice([1, 2], p=[.9, .1])) for _ in range(n)]
    plant = _Plant(cycles[answered], commands[answered],
                   [d for d, a in zip(delays, answered) if a])
    applied = plant.applied(cycles)
    rec = _record(cycles, commands, applied)
    data = {"pinch": {"x": rec.x, "v": rec.v, "f_p": rec.f_p, "f_a": applied,
                      "x_e": np.full(n, np.nan), "f_e": np.full(n, np.nan)},
            "wrist": {k: np.zeros(n) for k in ("x", "v", "f_p", "f_a", "x_e", "f_e")}}
    rows, stamps = serialize_states(["wrist", "pinch"], data, dt=DT)
    store = typestore()
    cmd_type = "seaforce_msgs/msg/ActuatorCommand"
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    writer = Writer(tmp_path / "bag", version=8, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    s_conn = writer.add_connection("/actuator_state", "seaforce_msgs/msg/ActuatorState",
                                   typestore=store)
    c_conn = writer.add_connection("/actuator_command", cmd_type, typestore=store)
    for i in range(n):
        writer.write(s_conn, int(stamps[i]), rows[i].tobytes())
        if answered[i]:
            stamp = int(stamps[i]) + 100_000
            msg = store.types[cmd_type](
                header=header_t(stamp=time_t(sec=stamp // 10 ** 9, nanosec=stamp % 10 ** 9),
                                frame_id=""),
                cycle=int(cycles[i]), name=["wrist", "pinch"],
                effort=np.array([0.0, commands[i]]))
            writer.write(c_conn, stamp, store.serialize_cdr(msg, cmd_type))
    writer.close()

    arrays = read_loop_arrays(tmp_path / "bag", "pinch")
    assert arrays.dt == pytest.approx(DT)
    assert arrays.command_cycle.tolist() == cycles[answered].tolist()
    fig = loop_figures_from_arrays(arrays)
    _check(fig.delay, plant.truth(cycles))
    assert fig.delay.skipped == 30
    assert fig.encoder.counts_per_rev == pytest.approx(2 ** 20)
    with pytest.raises(LoopFiguresError, match="no other_command messages for channel"):
        read_loop_arrays(tmp_path / "bag", "pinch", command_topic="other_command")


# --- malformed input -----------------------------------------------------------------------

def _arrays(**change):
    n = 1000
    base = dict(dt=DT, state_cycle=np.arange(n), x=np.arange(n) * 1e-3,
                f_p=np.random.default_rng(0).normal(0, 1e-3, n), applied=np.zeros(n),
                command_cycle=np.arange(n), command=np.zeros(n))
    base.update(change)
    return LoopArrays(**base)


@pytest.mark.parametrize("change, reason", [
    (dict(f_p=np.zeros(999)), "f_p has 999 samples, its cycles 1000"),
    (dict(command=np.zeros(10)), "command has 10 samples, its cycles 1000"),
    (dict(x=np.r_[np.zeros(500), np.nan, np.zeros(499)]), "x has 1 non-finite samples"),
    (dict(applied=np.r_[np.inf, np.zeros(999)]), "applied has 1 non-finite"),
    (dict(state_cycle=np.r_[np.arange(500), np.arange(499, 999)]),
     "state cycle does not increase at index 500"),
    (dict(command_cycle=np.arange(1000)[::-1]), "command cycle does not increase"),
    (dict(state_cycle=np.zeros(0, np.int64), x=np.zeros(0), f_p=np.zeros(0),
          applied=np.zeros(0)), "state cycle has 0 entries"),
    (dict(command_cycle=np.zeros(0, np.int64), command=np.zeros(0)),
     "command cycle has 0 entries"),
    (dict(dt=0.0), "dt = 0.0 s"),
    (dict(state_cycle=np.arange(1000) + 0.5), "not whole cycle numbers"),
])
def test_malformed_arrays_are_refused_with_the_reason(change, reason):
    with pytest.raises(LoopFiguresError, match=reason) as info:
        loop_figures_from_arrays(_arrays(**change))
    assert isinstance(info.value, CommissioningError)


def test_malformed_records_are_refused():
    rec = _record(np.arange(1000), np.zeros(1000), np.zeros(1000))
    empty = ExcitationRecord(DT, np.zeros(0, np.int64), *([np.zeros(0)] * 6))
    with pytest.raises(LoopFiguresError, match="the record is empty"):
        loop_figures(empty)
    with pytest.raises(CommissioningError, match="f_p has 3 samples"):
        ExcitationRecord(DT, rec.cycle, rec.x, rec.v, rec.f_p[:3], rec.applied, rec.command,
                         rec.excitation)
    with pytest.raises(LoopFiguresError, match="never changes"):
        encoder_resolution(np.ones(100))
    with pytest.raises(LoopFiguresError, match="max_delay 0"):
        loop_delay(np.arange(10), np.zeros(10), np.arange(10), np.zeros(10), max_delay=0)
    with pytest.raises(LoopFiguresError, match="at least 56"):
        pressure_noise(np.zeros(10))
    with pytest.raises(LoopFiguresError, match="overflow"):
        pressure_noise(1e307 * (-1.0) ** np.arange(1000))
    # a few huge samples are outliers the median over blocks ignores
    spikes = pressure_noise(np.r_[np.zeros(500), 1e307, -1e307, np.zeros(1500)])
    assert spikes.std == 0.0

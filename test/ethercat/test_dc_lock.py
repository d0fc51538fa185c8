"""The cycle's lock to the reference clock (seaforce_ros/ethercat/dc.py), in simulated time:
a host whose clock runs 50 ppm off the bus's, its frame sent a varying time after each
deadline and seen by the reference clock then; the lock must centre the frames at phase 0
of the cycle (SYNC0 fires ``shift`` later) and hold them there."""
import random

import pytest

from seaforce_ros.ethercat.dc import DcLock

CYCLE = 500_000


def run(lock, cycles, start_phase_ns, drift_ppm, busy_ns=(100_000, 250_000), seed=1):
    """Deadlines on the host's clock moved by the lock's corrections; returns the phase
    errors the lock saw (the reference clock's time at each frame, mod the cycle)."""
    rng = random.Random(seed)
    deadline_host = 0.0
    errors = []
    rate = 1.0 + drift_ppm * 1e-6           # reference-clock ns per host ns
    for _ in range(cycles):
        send_host = deadline_host + rng.uniform(*busy_ns)
        dc_time = int(start_phase_ns + send_host * rate) + 10**15
        correction_s = lock.update(dc_time)
        errors.append(lock.error_ns)
        deadline_host += CYCLE + correction_s * 1e9
    return errors


@pytest.mark.parametrize('start', [-240_000, 0, 90_000, 249_000])
@pytest.mark.parametrize('drift', [-50.0, 0.0, 50.0])
def test_the_lock_centres_the_frames_and_tracks_the_drift(start, drift):
    lock = DcLock(CYCLE)
    errors = run(lock, 4000, start, drift)
    late = errors[-1000:]
    mean = sum(late) / len(late)
    assert abs(mean) < 10_000                      # centred within 10 us of phase 0
    assert max(abs(e) for e in late) < 120_000     # the busy time's spread, no slide
    assert lock.locked


def test_without_the_lock_a_drift_slides_the_frames_through_the_cycle():
    class Free(DcLock):
        def update(self, dc_time_ns):
            super().update(dc_time_ns)
            return 0.0

    errors = run(Free(CYCLE), 4000, 0, 50.0, busy_ns=(0, 1))
    assert max(errors) - min(errors) > 90_000      # 50 ppm of 2 s: 100 us of slide


def test_a_correction_step_is_limited():
    lock = DcLock(CYCLE, max_step_ns=20_000)
    assert abs(lock.update(10**15 + 200_000)) <= 20e-6 + 1e-12

"""The pressure sensor's offset, measured on a free finger: the tare (``~/tare``).

In a DOB mode the controller makes the measured F_p what it should be, so the sensor's offset
o becomes a force on the finger; where the feed-forward cancels most of the finger's stiffness,
20 mN m moves a free finger over its stroke. At rest in free air the endpoint's balance (paper
Section II-C, motor frame) is ``F_p = -(k_e (X_e - rest) + F_d)``: the Dahl force F_d, anywhere
in ``[-F_c, F_c]`` after the finger stopped, hides the offset as well as any offset would. So
the tare moves the finger: a position servo on the motor (the ``hold`` gains) takes it to its
rest (``feedforward.rest_position``: a raised-cosine path at most :data:`MOVE_SPEED` fast, from
wherever the finger's friction held it; it starts from the channel's torque, that step fading
in :data:`~.modes.TRANSFER_TIME`, so that no torque of the mode it interrupted stays on as an
offset of the servo) and there tracks ``X_ref = rest + A e(t) sin(w t)``
(``A`` = :data:`AMPLITUDE`, ``w`` = 2 pi :data:`FREQUENCY`, raised-cosine fades of one period
at both ends, :data:`CYCLES` whole periods between them). At rest the model's k_e hardly
matters below (tared 0.24 rad from rest on a nonlinear oracle plant, the spring's error there
read as 3.4 mN m of offset, which then pushed the free finger 0.7 rad in dob_full_ff).
Over a whole period of a motion symmetric about its centre the hysteresis' force averages out,
and so do the inertia and damping forces: per measured period ``j``::

    o_j = mean(F_p) + k_e (mean(X_e_hat) - rest)

(``F_p`` as the controller sees it: less the offset in force, so ``o_j`` is what is left of
it). The offset found is their mean, its 1-sigma their spread over sqrt(n); the channel goes on
with ``pressure_offset`` plus it (bumplessly: the hose inversion's state moves with it).

It refuses (aborted, nothing applied) what it cannot tare: a finger that the model-free test
of :mod:`.sided` finds one-sided over the dither (an object on one side), or whose pressure
force's apparent stiffness over it is beyond :data:`STIFFNESS_RATIO` times what the model's
free finger shows (``k_e + 4 F_c/(pi A)``: its friction slides; an object in the way on both
sides); a finger that does not follow the servo (held:
``friction.max_tracking_error``); a motion that would leave ``friction.position_min..max``;
an offset beyond the parameter's range. A finger pressed by an object on both sides with a
steady force, or held still by a hand, reads as an offset: tare a free finger.

Output: the motor torque (:data:`~.jobs.TORQUE`), within ``min(friction.torque_limit,
max_torque)``. Nothing here imports ROS.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .jobs import TORQUE, Job, JobSample
from .servo import MotorServo
from .params import ControllerConfig
from .sided import SidedStiffness
from .signals import faded_sine

if TYPE_CHECKING:
    from .estimator import ContactEstimator

__all__ = ["PressureTare", "AMPLITUDE", "FREQUENCY", "CYCLES", "MOVE_SPEED", "TARE_PHASES"]

#: Largest speed [rad/s] of the move to rest, and the distance [rad] below which it is skipped.
MOVE_SPEED, MOVE_TOLERANCE = 0.2, 0.005
#: The dither's amplitude [rad]: many times the pre-sliding displacement F_c/sigma (2.5 mrad on
#: Table I), so that the hysteresis slides and its loop is symmetric.
AMPLITUDE = 0.02
#: Its frequency [Hz] (0.38 rad/s at the peak: well within any finger's speed).
FREQUENCY = 3.0
#: Whole periods measured (between the fades).
CYCLES = 4
#: The model-free contact test's thresholds (:mod:`.sided`) at this amplitude [N m/rad, -]
#: (the same 30 draws: the sides within 0.2 N m/rad of each other; an object of 5 N m/rad at
#: 0.01 rad: 1.8 apart).
CONTACT_STIFFNESS, CONTACT_RATIO = 0.5, 0.2
#: ... and the rms motion [rad] each side it needs.
CONTACT_MOTION = 0.005
#: How many times the model's free finger's apparent stiffness over the dither the tare accepts
#: (on 30 oracle draws 0.5x..2x of the hand-typed model, with a rig's sensors: 0.17-1.3 times
#: it; an object of 5 N m/rad pressing the finger from 0.1 rad in: 2.2 times).
STIFFNESS_RATIO = 2.0
#: The phases: ``move`` to rest, ``dither`` there, ``done`` at the end.
TARE_PHASES = ("move", "dither", "done")


class PressureTare(Job):
    """The tare of one channel's pressure offset (module docstring).

    Parameters
    ----------
    config : ControllerConfig
        The channel's: the model's k_e and rest, the offset in force, the hold gains,
        ``friction.*`` (torque limit, tracking error, range), ``max_torque``.
    dt : float > 0
        Sample period [s].

    Attributes
    ----------
    old, offset, offset_sigma : float
        The offset in force when it started, the one it found (NaN until done or when not
        found) and its 1-sigma [N m].
    applied : bool
        The channel took the new offset.
    """

    kind = "tare"
    output = TORQUE

    def __init__(self, config: ControllerConfig, dt: float = 5e-4) -> None:
        super().__init__()
        self.config = config
        self.dt = float(dt)
        self.phase = "move"
        self.message = "waiting for the control cycle"
        self.progress = 0.0
        self.old = config.pressure_offset
        self.offset = self.offset_sigma = math.nan
        self.applied = False
        fp = config.friction
        self._limit = min(fp.torque_limit, config.max_torque)
        self._motor = MotorServo(config.hold.stiffness, config.hold.damping, self.dt)
        self._ke = config.plant.endpoint_stiffness
        self._rest = config.feedforward.rest_position
        self._w = 2.0 * math.pi * FREQUENCY
        self._period = 1.0 / FREQUENCY
        self._duration = (CYCLES + 2) * self._period
        self.contact_test = SidedStiffness(CONTACT_STIFFNESS, CONTACT_RATIO, CONTACT_MOTION)
        self._x0: float | None = None
        self._move = 0.0                   # the move's length [rad] and duration [s]
        self._move_time = 0.0
        self._t = 0.0
        self._sums = [0.0, 0.0, 0]         # F_p, X_e_hat, samples of the period being measured
        self._per_period: list[float] = []
        self._cancel: str | None = None

    # --- requests ------------------------------------------------------------------------
    def request_cancel(self, reason: str = "canceled") -> None:
        """(any thread) End at the next sample, canceled; nothing is applied."""
        self._cancel = reason

    def abort_now(self, reason: str) -> None:
        if self.phase != "done":
            self._finish("aborted", reason + ", nothing applied")

    def final_config(self, config: ControllerConfig) -> ControllerConfig | None:
        """``config`` with the new offset when the tare succeeded."""
        if self.outcome != "succeeded":
            return None
        self.applied = True
        return config.replace(pressure_offset=self.offset)

    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        return {"phase": self.phase, "progress": self.progress}

    # --- per sample ------------------------------------------------------------------------
    def step(self, sample: JobSample) -> float:
        """(cycle thread) F_a [N m] of the servo; 0.0 once done."""
        if self.phase == "done":
            return 0.0
        x, v, xe, fp = sample.x, sample.v, sample.endpoint_position, sample.f_p
        if not all(math.isfinite(a) for a in (x, v, xe, fp, sample.torque)):
            self._finish("aborted", "non-finite input: zero torque, nothing applied")
            return 0.0
        if self._x0 is None:
            reason = self._cannot_start(sample)
            if reason:
                self._finish("aborted", reason + ", nothing applied")
                return 0.0
            self._x0 = x
            self._motor.start(max(-self._limit, min(self._limit, sample.torque)), v)
            move = self._rest - xe
            if abs(move) > MOVE_TOLERANCE:
                self._move = move
                self._move_time = max(self._period, 0.5 * math.pi * abs(move) / MOVE_SPEED)
            self.contact_test.reset(x + self._move)
            self.message = "moving to rest" if self._move else "dithering"
        t = self._t
        r, rd = self._reference(t)
        error = self._x0 + r - x
        friction = self.config.friction
        if abs(error) > friction.max_tracking_error:
            self._finish("aborted", f"tracking error {error:.3g} rad beyond "
                                    f"friction.max_tracking_error = "
                                    f"{friction.max_tracking_error:g} rad: the finger is held "
                                    "(not free), nothing applied")
            return 0.0
        u = self._motor.output(error, rd - v, sample.steps)
        u = max(-self._limit, min(self._limit, u))
        if self._abort_request is not None:
            self._finish("aborted", self._abort_request + ", nothing applied")
            return u
        if self._cancel is not None:
            self._finish("canceled", self._cancel + ", nothing applied")
            return u
        if t >= self._move_time:
            self.phase, self.message = "dither", "dithering"
            self._measure(t - self._move_time, x, xe, fp)
        self._t = t + self.dt * sample.steps
        total = self._move_time + self._duration
        self.progress = min(1.0, self._t / total)
        if self._t >= total:
            self._conclude()
        return u

    def _reference(self, t: float) -> tuple[float, float]:
        """(X_ref - x_0 [rad], its rate [rad/s]): the raised-cosine move to rest, then the
        dither about it."""
        move, tm = self._move, self._move_time
        if t < tm:
            c = math.pi / tm
            return 0.5 * move * (1.0 - math.cos(c * t)), 0.5 * move * c * math.sin(c * t)
        r, rd = faded_sine(t - tm, AMPLITUDE, self._w, self._period, self._duration)
        return move + r, rd

    def _cannot_start(self, sample: JobSample) -> str:
        """Why the tare cannot start on this sample, or ''. (Not the contact estimator's
        verdict: its residual holds the very offset the tare is for, and 45 mN m of it read
        as a contact on a free finger.)"""
        friction = self.config.friction
        lo, hi = friction.position_min, friction.position_max
        if not (lo + AMPLITUDE <= self._rest <= hi - AMPLITUDE
                and lo <= sample.endpoint_position <= hi):
            return (f"the endpoint at {sample.endpoint_position:.4g} rad, or the dither "
                    f"(+-{AMPLITUDE:g} rad) about its rest {self._rest:g} rad, is not within "
                    f"friction.position_min..max {lo:g}..{hi:g} rad")
        return ""

    def _measure(self, t: float, x: float, xe: float, fp: float) -> None:
        """Sum F_p and X_e_hat over each whole period between the fades; judge the sides'
        stiffness at each period's end."""
        p = self._period
        if not p <= t < self._duration - p:
            return
        self.contact_test.update(x, fp)
        sums = self._sums
        sums[0] += fp
        sums[1] += xe
        sums[2] += 1
        if t + self.dt >= p * (len(self._per_period) + 2) - 0.5 * self.dt:
            n = sums[2]
            self._per_period.append(sums[0] / n + self._ke * (sums[1] / n - self._rest))
            self._sums = [0.0, 0.0, 0]

    def _conclude(self) -> None:
        test = self.contact_test
        if test.judge() > 1.0:
            side = "above" if test.upper > test.lower else "below"
            self._finish("aborted", f"contact {side} the dither's centre: the pressure force's "
                                    f"apparent stiffness is {test.upper:.3g} N m/rad above it "
                                    f"and {test.lower:.3g} below (a free finger's is the same "
                                    "both sides): tare a free finger, nothing applied")
            return
        dahl = self.config.dahl
        free = self._ke + 4.0 * dahl.coulomb_force / (math.pi * AMPLITUDE)
        apparent = 0.5 * (test.upper + test.lower)
        if not apparent <= STIFFNESS_RATIO * free:
            self._finish("aborted", f"the pressure force's apparent stiffness over the dither is "
                                    f"{apparent:.3g} N m/rad, beyond {STIFFNESS_RATIO:g} times "
                                    f"the model's free finger ({free:.3g}): something holds "
                                    "the finger; tare a free finger, nothing applied")
            return
        found = self._per_period
        if len(found) < 2:
            self._finish("aborted", "fewer than two whole periods measured, nothing applied")
            return
        n = len(found)
        mean = sum(found) / n
        spread = math.sqrt(sum((o - mean) ** 2 for o in found) / (n - 1))
        offset = self.old + mean
        limit = ControllerConfig.spec("pressure_offset").high or 0.0
        if not abs(offset) <= limit:
            self._finish("aborted", f"the offset found, {offset:.4g} N m, is beyond the "
                                    f"parameter's range +-{limit:g} N m: is the sensor wired "
                                    "and scaled right? Nothing applied")
            return
        self.offset, self.offset_sigma = offset, spread / math.sqrt(n)
        self._finish("succeeded", f"pressure offset {1e3 * offset:+.2f} +- "
                                  f"{1e3 * self.offset_sigma:.2f} mN m (was "
                                  f"{1e3 * self.old:+.2f})")


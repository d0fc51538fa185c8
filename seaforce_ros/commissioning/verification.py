"""The feed-forward's margin measured on the free finger: commissioning's verification.

The tuning (:mod:`.tuning`) proposes candidate feed-forwards, from the most compensation the
identification's statistical band allows to the most cautious the model class's band asks for
(:class:`Candidate`). The model cannot say which of them a real finger rests under: its Dahl
friction is a spring stiffer than the hose at small motions, and cancelling it through the
loop's lag, on sensors no model has exactly (an ADC step, an offset left, a drive's velocity
filter), makes limit cycles and creeps the linearised loop does not show. So the gripper says:
:class:`FreeFingerVerification`, a :class:`~seaforce_ros.core.jobs.Job` in the control cycle,
tries each candidate in turn, most compensation first, on the free finger:

1. at each of two points -- the rest (``feedforward.rest_position``) and
   ``verification.offset`` from it, on the side with more room -- a position servo on the motor
   (the ``hold`` gains) takes the finger there along a raised-cosine path (at most
   :data:`MOVE_SPEED`) and dithers it about the point (``20 mrad`` falling to 0 over
   :data:`DITHER_CYCLES` cycles at :data:`DITHER_FREQUENCY`: the hysteresis cycled down to
   nothing) and holds it still for :data:`STILL_TIME` (the torque at the start of the job
   fading in :data:`~seaforce_ros.core.modes.TRANSFER_TIME`);
2. then the candidate runs the channel as ``dob_full_ff`` would (a controller of its own, with
   its walls and its runaway monitor armed, entered from the servo's mean torque over the
   still's second half, the finger's static load): the
   finger, released there, is pulsed on the DOB's reference for :data:`PULSE_TIME` -- a force
   that would take the model's motor and endpoint inertia to ``verification.speed`` -- and
   watched for ``verification.settle_time`` and :data:`DRIFT_TIME`, then pulsed the other way;
   the end
   of each window is the finger at rest under the candidate, where a pre-sliding limit cycle
   or a creep shows;
3. each window's figures (:class:`Window`): the finger's speed -- X_e_hat's path over
   :data:`CHUNK` samples, low-passed at 20 Hz (the pressure noise alone is 0.06 rad/s of raw
   path) -- its peak, the time after which it stays below
   :data:`~seaforce_ros.core.safety.REST_SPEED` (the settling time), the decay rate
   ``ln(peak/REST_SPEED) / settling time`` [1/s], and the drift, X_e_hat's range over the
   window's last :data:`DRIFT_TIME`.

A candidate passes when in every window the finger came to rest within
``verification.settle_time`` and then moved less than ``verification.band`` (the stated
margin), its monitor did not trip and the finger stayed clear of the walls. The first to pass
is the one taken; a window that fails ends its candidate at once (the servo takes the finger
over bumplessly from its torque) and nothing of it is applied. None passing: the caller keeps
the starting settings of the feed-forward modes.

The same job on the identified model (:func:`predict`, the core's simulator with the measured
loop) gives each window's figures as predicted: the report shows them beside the measured.

Torque: the servo's and the candidate's are bounded by ``min(commissioning.max_torque,
max_torque)`` and by the candidate's ``max_torque``; a non-finite input aborts with zero
torque; a cancel ends it with the channel's mode, nothing applied. Nothing here imports ROS.
"""
from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Dict, List, Optional, Sequence

from ..core.controller import ChannelController
from ..core.jobs import TORQUE, InvalidJobGoalError, Job, JobSample
from ..core.params import ControllerConfig, DahlParams, PlantParams, PlantTermsParams
from ..core.servo import MotorServo
from ..core.safety import REST_SPEED
from ..core.sensors import SensorParams
from ..core.signals import faded_sine

if TYPE_CHECKING:
    from ..core.estimator import ContactEstimator

__all__ = ["Candidate", "Window", "CandidateOutcome", "FreeFingerVerification", "predict",
           "PULSE_TIME", "DRIFT_TIME", "STILL_TIME", "CHUNK", "KINDS"]

#: Largest speed [rad/s] of the servo's moves between points.
MOVE_SPEED = 0.3
#: The dither before a candidate takes over: amplitude [rad], cycles, frequency [Hz].
DITHER_AMPLITUDE, DITHER_CYCLES, DITHER_FREQUENCY = 0.02, 3, 3.0
#: The servo holds the finger still this long [s] after the dither before the candidate takes
#: over: its torque is then the finger's static load, not the dither's tracking error (at the
#: tuned hold gains 0.3 N m, which the candidate's DOB took over as a push: a flick of 3-4
#: rad/s that carried a finger the candidate held to the walls).
STILL_TIME = 0.15
#: The pulse's length [s]: the finger slides a few tenths of a radian, as a flick does (a
#: pulse of 20 ms moved it a few hundredths, and a candidate whose finger rested after those
#: swung across +-0.3 rad after a hand's flick of 4 mN m s).
PULSE_TIME = 0.08
#: The drift is X_e_hat's range over the window's last this [s] (a window lasts
#: ``verification.settle_time`` and this).
DRIFT_TIME = 0.5
#: Samples per speed measurement, and the path's low-pass [Hz].
CHUNK, PATH_CUTOFF = 10, 20.0
#: The windows at each point, in order.
KINDS = ("pulse +", "pulse -")


@dataclass(frozen=True)
class Candidate:
    """One feed-forward the verification tries.

    name : str
        What it is, in words (``share 0.75, margin 1 x the statistical 1-sigma``).
    config : ControllerConfig
        The channel's configuration with it (the mode is set to ``dob_full_ff`` when it runs).
    """
    name: str
    config: ControllerConfig


@dataclass
class Window:
    """One window's figures: ``point`` [rad] and ``kind`` (:data:`KINDS`); the finger's peak
    speed [rad/s], its settling time [s] (inf: it did not rest), the decay rate [1/s] (NaN
    when it never moved faster than REST_SPEED), the drift [rad]; ``failed``: why the window
    failed the candidate ('' when it passed)."""
    point: float
    kind: str
    peak_speed: float = 0.0
    settle: float = 0.0
    decay: float = math.nan
    drift: float = 0.0
    failed: str = ""


@dataclass
class CandidateOutcome:
    """A candidate's windows and verdict (``passed``; ``reason``: why not)."""
    name: str
    windows: List[Window] = field(default_factory=list)
    passed: bool = False
    reason: str = "not tried"


class FreeFingerVerification(Job):
    """The verification of ``candidates`` on the free finger (module docstring).

    Parameters
    ----------
    candidates : sequence of Candidate
        Most compensation first.
    config : ControllerConfig
        The channel's (``verification.*``, ``commissioning.max_torque``, ``max_torque``,
        ``feedforward.rest_position``, ``limits``); the servo between the candidates takes the
        last candidate's ``hold`` gains.
    dt : float > 0
        Sample period [s].

    Attributes
    ----------
    outcomes : list of CandidateOutcome
        One per candidate tried, in order.
    chosen : int or None
        The index of the candidate taken, once done (None: none passed).
    """

    kind = "free-finger verification"
    output = TORQUE

    def __init__(self, candidates: Sequence[Candidate], config: ControllerConfig,
                 dt: float = 5e-4) -> None:
        super().__init__()
        if not candidates:
            raise InvalidJobGoalError("no candidate feed-forward to verify")
        self.candidates = list(candidates)
        self.config = config
        self.dt = float(dt)
        v = config.verification
        p = config.plant
        self._settle, self._band = v.settle_time, v.band
        self._pulse = v.speed * (p.motor_inertia + p.endpoint_inertia) / PULSE_TIME
        self._window = v.settle_time + DRIFT_TIME
        self._limit = min(config.commissioning.max_torque, config.max_torque)
        # (the servo's gains: the last candidate's, tuned for the loop measured -- the
        # channel's may be a hand-typed hold that a rig's delay makes unstable)
        servo = self.candidates[-1].config.hold
        self._motor = MotorServo(servo.stiffness, servo.damping, self.dt)
        rest = config.feedforward.rest_position
        lim = config.limits
        room = lim.wall_band + DITHER_AMPLITUDE + 0.05
        up = rest + v.offset <= lim.position_max - room
        second = rest + v.offset if up else rest - v.offset
        self.points = [rest] if v.offset == 0.0 else [rest, second]
        if not all(lim.position_min + room <= p <= lim.position_max - room
                   for p in self.points):
            raise InvalidJobGoalError(
                f"the verification's points {self.points} rad are not within the joint range "
                f"less its walls and the dither ({lim.position_min:g}..{lim.position_max:g} "
                "rad): set feedforward.rest_position or verification.offset")
        self.outcomes: List[CandidateOutcome] = []
        self.chosen: Optional[int] = None
        self.phase = "move"
        self.message = "waiting for the control cycle"
        self.progress = 0.0
        self._cancel: Optional[str] = None
        # the state machine: candidate index, point index, the step within the point
        self._c = 0
        self._p = 0
        self._private: Optional[ChannelController] = None
        self._t = 0.0                  # time in the present step [s]
        self._x0 = math.nan            # the servo's start and the torque it entered with
        self._still = [0.0, 0]         # the servo's torque summed over the still, samples
        self._move = 0.0
        self._move_time = 0.0
        self._kind = 0                 # which window of KINDS
        self._speeds = array("d")      # this window's chunk speeds [rad/s]
        self._positions = array("d")   # ... and the low-passed X_e_hat at each chunk [rad]
        self._y = math.nan             # the low-passed X_e_hat
        self._path = 0.0
        self._chunk = 0
        self._a = 1.0 - math.exp(-2.0 * math.pi * PATH_CUTOFF * self.dt)
        self._steps_total = 0.0
        self._duration = self._estimated_duration()

    # --- requests ------------------------------------------------------------------------
    def request_cancel(self, reason: str = "canceled") -> None:
        self._cancel = reason

    def abort_now(self, reason: str) -> None:
        if self.phase != "done":
            self._finish("aborted", reason + ", nothing applied")

    def feedback(self, estimator: ContactEstimator) -> Dict[str, float | str]:
        return {"phase": self.phase, "progress": self.progress}

    def _estimated_duration(self) -> float:
        """Rig time [s] for every candidate (the moves as if from rest)."""
        per_point = (2.0 + DITHER_CYCLES / DITHER_FREQUENCY + STILL_TIME
                     + len(KINDS) * self._window)
        return len(self.candidates) * len(self.points) * per_point

    # --- per sample ------------------------------------------------------------------------
    def step(self, sample: JobSample) -> float:
        if self.phase == "done":
            return 0.0
        x, v, xe, fp, torque = (sample.x, sample.v, sample.endpoint_position, sample.f_p,
                                sample.torque)
        if not all(math.isfinite(a) for a in (x, v, xe, fp, torque)):
            self._finish("aborted", "non-finite input: zero torque, nothing applied")
            return 0.0
        if self._abort_request is not None:
            self._finish("aborted", self._abort_request + ", nothing applied")
            return 0.0
        if self._cancel is not None:
            self._finish("canceled", self._cancel + ", nothing applied")
            return max(-self._limit, min(self._limit, torque))
        steps = sample.steps
        self._steps_total += steps * self.dt
        self.progress = min(0.99, self._steps_total / self._duration)
        if self._private is None:
            u = self._servo(x, v, xe, torque, steps)
        else:
            u = self._candidate(x, v, fp, steps)
        return max(-self._limit, min(self._limit, u))

    def _servo(self, x: float, v: float, xe: float, torque: float, steps: int) -> float:
        """The move to the next point and the dither there; then the candidate takes over."""
        if self._x0 != self._x0:
            self._x0 = x
            self._motor.start(max(-self._limit, min(self._limit, torque)), v)
            self._move = self.points[self._p] - xe
            self._move_time = max(0.2, 0.5 * math.pi * abs(self._move) / MOVE_SPEED)
            self._t = 0.0
            self._still = [0.0, 0]
            self.phase = "move"
            self.message = (f"candidate {self._c + 1} of {len(self.candidates)}: moving to "
                            f"{self.points[self._p]:.3g} rad")
        t, tm = self._t, self._move_time
        if t < tm:
            c = math.pi / tm
            r = 0.5 * self._move * (1.0 - math.cos(c * t))
            rd = 0.5 * self._move * c * math.sin(c * t)
        else:
            self.phase = "dither"
            dither = DITHER_CYCLES / DITHER_FREQUENCY
            fade = 0.5 * dither
            w = 2.0 * math.pi * DITHER_FREQUENCY
            r, rd = faded_sine(t - tm, DITHER_AMPLITUDE, w, fade, dither) \
                if t - tm < dither else (0.0, 0.0)
            r += self._move
            if t - tm >= dither + STILL_TIME:
                # from the servo's mean torque over the still's second half: the finger's
                # static load (a coarse encoder's count is kp x 0.4 mrad of torque)
                u = self._still[0] / max(self._still[1], 1)
                self._enter(u)
                return u
        self._t = t + self.dt * steps
        u = self._motor.output(self._x0 + r - x, rd - v, steps)
        if t >= tm and t - tm >= DITHER_CYCLES / DITHER_FREQUENCY + 0.5 * STILL_TIME:
            self._still[0] += max(-self._limit, min(self._limit, u)) * steps
            self._still[1] += steps
        return u

    def _enter(self, torque: float) -> None:
        """The candidate takes the channel over from ``torque`` [N m], bumplessly."""
        candidate = self.candidates[self._c]
        # (the samples' F_p is already less the channel's pressure offset: the candidate's
        # controller takes off what its own adds to it)
        offset = candidate.config.pressure_offset - self.config.pressure_offset
        private = ChannelController(candidate.config.replace(mode="dob_full_ff",
                                                            pressure_offset=offset), self.dt)
        private.reset(torque)
        self._private = private
        self._kind = 0
        self._open_window()
        if self._p == 0:
            self.outcomes.append(CandidateOutcome(candidate.name, reason="running"))
        self.phase = "observe"
        self.message = f"candidate {self._c + 1} of {len(self.candidates)}: {candidate.name}"

    def _open_window(self) -> None:
        self._t = 0.0
        del self._speeds[:]
        del self._positions[:]
        self._y = math.nan
        self._path = 0.0
        self._chunk = 0

    def _candidate(self, x: float, v: float, fp: float, steps: int) -> float:
        """One sample of the candidate: its torque, the window's figures."""
        private = self._private
        assert private is not None
        kind = KINDS[self._kind]
        pulse = (self._pulse if kind == "pulse +" else -self._pulse if kind == "pulse -"
                 else 0.0)
        private.reference_offset = pulse if self._t < PULSE_TIME else 0.0
        u = private.update(x, v, fp, steps)
        self._track(private.endpoint_position_estimate, steps)
        self._t += self.dt * steps
        outcome = self.outcomes[-1]
        failed = ""
        if private.fallback:
            failed = f"its runaway monitor tripped: {private.fallback_reason}"
        elif private.walls.force != 0.0 or private.beyond:
            failed = "the finger reached the joint walls"
        if failed or self._t >= self._window:
            window = self._judge(failed)
            outcome.windows.append(window)
            if window.failed:
                self._next_candidate(outcome, f"{window.kind} at {window.point:.3g} rad: "
                                              f"{window.failed}", u)
                return u
            self._kind += 1
            if self._kind < len(KINDS):
                self._open_window()
            else:
                self._next_point(outcome, u)
        return u

    def _track(self, xe: float, steps: int) -> None:
        """X_e_hat low-passed and its path over each chunk of :data:`CHUNK` samples."""
        y = self._y
        if y != y:
            self._y = xe
            return
        new = y + self._a * (xe - y) if steps == 1 else xe
        self._path += abs(new - y)
        self._y = new
        self._chunk += steps
        if self._chunk >= CHUNK:
            self._speeds.append(self._path / (self._chunk * self.dt))
            self._positions.append(new)
            self._path = 0.0
            self._chunk = 0

    def _judge(self, failed: str) -> Window:
        """The window's figures and verdict."""
        point = self.points[self._p]
        window = Window(point, KINDS[self._kind], failed=failed)
        speeds, positions = self._speeds, self._positions
        if not speeds:
            return window
        chunk = CHUNK * self.dt
        window.peak_speed = max(speeds)
        moving = [i for i, s in enumerate(speeds) if s > REST_SPEED]
        last = moving[-1] if moving else -1
        window.settle = math.inf if last == len(speeds) - 1 else (last + 1) * chunk
        if window.peak_speed > REST_SPEED and math.isfinite(window.settle) \
                and window.settle > 0.0:
            window.decay = math.log(window.peak_speed / REST_SPEED) / window.settle
        tail = positions[-max(1, int(round(DRIFT_TIME / chunk))):]
        window.drift = max(tail) - min(tail)
        if not failed:
            if window.settle > self._settle:
                window.failed = (f"the finger did not come to rest within "
                                 f"verification.settle_time = {self._settle:g} s")
            elif window.drift > self._band:
                window.failed = (f"it moved {1e3 * window.drift:.3g} mrad over the last "
                                 f"{DRIFT_TIME:g} s, beyond verification.band = "
                                 f"{1e3 * self._band:g} mrad (a creep or a ring)")
        return window

    def _next_point(self, outcome: CandidateOutcome, torque: float) -> None:
        self._p += 1
        if self._p < len(self.points):
            self._leave(torque)
            return
        outcome.passed, outcome.reason = True, "passed"
        self.chosen = self._c
        self._finish("succeeded", f"{outcome.name}: the finger came to rest in every window")

    def _next_candidate(self, outcome: CandidateOutcome, reason: str, torque: float) -> None:
        outcome.passed, outcome.reason = False, reason
        self._c += 1
        self._p = 0
        if self._c < len(self.candidates):
            self._leave(torque)
            return
        self._finish("succeeded", "no candidate passed: the feed-forward modes keep their "
                                  "starting settings")

    def _leave(self, torque: float) -> None:  # noqa: ARG002 -- (the sample's torque is it)
        """The servo takes the finger over from the candidate's ``torque``, bumplessly."""
        self._private = None
        self._x0 = math.nan                 # (the servo starts from the sample's torque)
        self.phase = "move"


def predict(plant: PlantParams, dahl: Optional[DahlParams], candidates: Sequence[Candidate],
            config: ControllerConfig, delay: int = 1, dt: float = 5e-4, seed: int = 0,
            terms: Optional[PlantTermsParams] = None, motor_coulomb: float = 0.0,
            sensors: Optional[SensorParams] = None) -> List[CandidateOutcome]:
    """Every candidate's windows on the identified model (the core's simulator: ``plant``,
    ``dahl``, the nonlinear ``terms`` the record showed and the motor's Coulomb friction, the
    ``sensors`` measured (default the sim's), the torque applied ``delay`` samples after its
    sample): what the
    verification should measure. Each candidate is verified alone, the finger placed at rest
    at each point in turn (the gripper's move there leaves it so: the dither cycles the
    hysteresis down), the job stepped on the simulator's samples directly."""
    from ..core.jobs import JobSample
    from ..core.nonlinear_effects import effects_of_terms
    from ..core.nonlinear_simulator import make_simulator
    effects = None if terms is None else effects_of_terms(terms, plant)
    config = config.replace(pressure_offset=0.0)     # (the simulated sensor has none)
    estimator = ChannelController(config, dt).estimator       # (a JobSample needs one)
    out = []
    for candidate in candidates:
        outcome = CandidateOutcome(candidate.name, reason="passed", passed=True)
        for point in FreeFingerVerification([candidate], config, dt).points:
            job = FreeFingerVerification([Candidate(candidate.name, candidate.config.replace(
                pressure_offset=0.0))], config, dt)
            job.points = [point]
            sim = make_simulator(plant, dahl, effects, dt=dt, seed=seed,
                                 motor_coulomb=motor_coulomb, sensors=sensors)
            sim.reset((point, 0.0, point, 0.0))
            sample = JobSample(estimator)
            pending = [0.0] * max(0, delay - 1)
            m = sim.measurement()
            u = 0.0
            assert job.claim()
            for _ in range(int(job._duration / dt) + int(10.0 / dt)):
                sample.x, sample.v, sample.f_p, sample.torque = m.x, m.v, m.f_p, u
                sample.endpoint_position = m.x + m.f_p / plant.hose_stiffness
                u = job.step(sample)
                pending.append(u)
                m = sim.step(pending.pop(0))
                if not job.active:
                    break
            tried = job.outcomes[0] if job.outcomes else CandidateOutcome(
                candidate.name, reason=f"not run: {job.message}")
            outcome.windows.extend(tried.windows)
            if not tried.passed:
                outcome.passed, outcome.reason = False, tried.reason
                break
        out.append(outcome)
    return out

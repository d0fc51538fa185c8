"""The free-air excitation of commissioning: a motor-torque log chirp with the endpoint free.

Commissioning identifies a gripper from what its own sensors see while the motor shakes the
finger with nothing in the way: motor position X, velocity V, pressure force F_p and the
applied torque F_a (no endpoint encoder, no external force). The identification wants the
motor plant ``X/(F_a + F_p)`` and the endpoint seen through the hose ``F_p/X`` from about
0.3 Hz to several hundred Hz; :class:`FreeAirExcitation` is the :class:`~..core.jobs.Job`
(output :data:`~..core.jobs.TORQUE`) that produces that record safely, sample by sample::

    F_a = F_0 + a(t) e(t) - K_p (X - x_0) - K_d V

with ``x_0`` the motor position and ``F_0`` the torque at the start (a bumpless entry),
``K_p, K_d`` a weak centring servo (``commissioning.stiffness``, ``damping``: far below the
finger's own impedance, so it moves freely, yet enough to keep the Dahl hysteresis and
offsets from walking it away), ``e(t)`` a unit log chirp and ``a(t)`` its amplitude [N m].

The signal
    After ``commissioning.rest_duration`` of servo only (the pressure noise is measured there),
    a log chirp from ``start_frequency`` (0.2 Hz) to ``end_frequency`` (800 Hz) over
    ``duration`` (40 s), ``f(t) = f_0 (f_1/f_0)^(t/T)``. A log chirp spends the same time on
    every decade (40 s / 3.6 decades = 11 s per decade) and has as many cycles per decade as
    its frequency: the low decade, whose periods are long, is the thin one, which is why the
    record should not be much shorter than 40 s. Raised-cosine fades each span a factor 1.5 in
    frequency (0.2..0.3 Hz and 533..800 Hz), so the band 0.3..533 Hz is excited at full
    amplitude. 800 Hz is 0.8 of the Nyquist frequency at 2 kHz: 2.5 samples per period, the
    zero-order hold's gain still 0.76; above it the hold's images and the one-sample delay
    leave nothing worth identifying.

The amplitude law
    ``a = min(max_torque', g a_0(f))``: ``a_0(f)`` is the torque for which the channel's model
    (its ``plant``, the servo included) would move the finger by 60 % of the room it has
    (``min(x_0 - position_min, position_max - x_0)``) and at 60 % of ``max_speed``, taking the
    model's largest motion over a factor 2 of frequency either side and with the endpoint both
    free and stuck in its Dahl hysteresis (sigma as a stiffness): a model wrong by 0.5x..2x
    has its resonances in that window. So the torque is small at low frequency (the springs,
    where the position limit rules), low around the hose resonance, and rises with frequency
    above it (the inertia makes the motion tiny) up to ``max_torque' = min(commissioning.
    max_torque, max_torque)``. ``g`` (1 at the start, 0.1..4) corrects the model online: the
    envelopes of ``|X - x_0|`` and ``|V|`` (peak-hold, decaying over 1.5 periods of the present
    frequency) are kept between 45 % and 60 % of their limits by moving ``ln g`` at most
    :data:`DOWN_RATE` per second down and :data:`UP_RATE` per period up: a slow, smooth scaling (the
    excitation stays quasi-stationary) that the record does not need to know about, since
    ``excitation`` holds the scaled torque ``a e`` the cross spectra are taken against.

Contact test
    The channel's contact estimator is not used: it is made for a grasp's slow approach (its
    threshold is a few mN m above the free-motion residual it tracks), and under this
    excitation its residual -- the model's error times accelerations of hundreds of rad/s^2
    -- crossed it within 2 s even with the exact model (measured: Table I, 0.2 Hz, 1 rad).
    The job's own test is one that a model wrong by 0.5x..2x does not upset, because it uses
    no model: a free finger is (nearly) linear about the centre of its motion, so the
    pressure force's apparent stiffness ``k = -sum (F_p - c_F)(X - c_X) / sum (X - c_X)^2``
    is the same over the samples above the centre ``c_X`` as over those below (the damping and
    the Dahl hysteresis's quadrature part cancel over each lobe, inertia and springs are
    symmetric); an object in the way acts on one side only. Over the last
    :data:`CONTACT_PERIODS` periods of the chirp (``c_X``, ``c_F``: the position and force
    tracked over a period), contact is declared when ``|k_+ - k_-| > CONTACT_STIFFNESS +
    CONTACT_RATIO |Z|``, ``|Z| = rms(F_p - c_F)/rms(X - c_X)`` (the window's cut lobes leave
    a part of ``|Z|``). Measured: free air over random plants 0.5x..2x of Table I reached
    0.36..0.49 of the threshold; a stiff object (20..100 N m/rad) 0.2..0.3 rad into the
    motion 1.5..2.2; a soft one (5 N m/rad at 0.5 rad) 0.96, one of 1 N m/rad (15 times k_e:
    physically a spring like the finger's own) 0.6. Costs: the test waits until the chirp has
    run four periods (about 6 s at the default 0.2 Hz start, while the torque is below
    0.3 N m and the hard limits hold), and it stops where the motion is below
    :data:`CONTACT_MOTION` each side (above about 100 Hz: an object the finger cannot reach
    there).

The centring move
    A finger left away from its rest (``feedforward.rest_position``, where the diaphragm's
    spring is relaxed) is held there by its Dahl friction -- up to F_c/k_e, about 0.3 rad on
    these plants -- and the chirp would free it: it drifts home during the record, which the
    excitation did not cause (measured on the oracle's linear class: 0.1 rad off doubled the
    port misfit and flagged the model class; 0.2 rad off aborted on a false contact). So a
    start more than :data:`CENTRE_TOLERANCE` from rest first moves the motor there: a
    raised-cosine path at most :data:`CENTRE_SPEED` fast, tracked by a servo of
    :data:`CENTRE_STIFFNESS` and :data:`CENTRE_DAMPING` (stiff enough to carry the finger
    through its friction within a few 10 mrad, far below any finger's own impedance). At rest
    the move leaves the Dahl force at F_c against its direction, which the servo's torque
    holds; handed to the weak servo as its F_0, that torque would push the finger off rest
    as soon as the chirp relaxes the friction (measured: 0.1 rad off, moved to rest, the port
    misfit as high as not moved). So the move ends with a dither about rest whose amplitude
    falls from :data:`CENTRE_DITHER` to 0 over :data:`CENTRE_DITHER_CYCLES` cycles at
    :data:`CENTRE_DITHER_FREQUENCY` -- a hysteresis cycled down to nothing keeps nothing --
    then :data:`CENTRE_SETTLE` at rest; the weak servo takes over bumplessly (its x_0 and F_0
    where the move ended) and the rest phase and the chirp follow as above. Nothing of the
    move is recorded. It aborts when the finger falls :data:`CENTRE_ERROR` behind its path (an
    object or a hand in the way) or rest lies outside ``position_min..position_max``.

Aborts (zero torque from that sample on, ``aborted`` with the reason): a contact (above); X
leaves ``position_min..position_max`` or ``|V|`` exceeds ``max_speed`` (the amplitude law
keeps them near 60 %: beyond is a blocked, loose or misidentified finger); the start outside
the range or under a load above half the torque bound; a non-finite input (X, V, F_p, the
applied torque or the last torque); the record's capacity reached (cannot happen with
``steps >= 1``); :meth:`~FreeAirExcitation.abort_now` (a fault, a mode change) and
:meth:`~..core.jobs.Job.request_abort`. A cancel (:meth:`FreeAirExcitation.request_cancel`)
zeroes the torque at once too, ``canceled``. The job applies nothing: its product is
:meth:`FreeAirExcitation.record`.

Per sample: no allocation beyond float boxing; the record's arrays are allocated at
construction for the whole excitation.
"""
from __future__ import annotations

import math
from array import array
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ..core.jobs import TORQUE, InvalidJobGoalError, Job, JobSample
from ..core.params import CommissioningParams, ControllerConfig, PlantParams
from .record import ExcitationRecord

if TYPE_CHECKING:
    from ..core.estimator import ContactEstimator

__all__ = ["ExcitationGoal", "FreeAirExcitation", "check_excitation_goal",
           "nominal_amplitude", "EXCITATION_PHASES", "TARGET", "LOW_TARGET", "FADE_RATIO",
           "MIN_FADE", "CONTACT_PERIODS", "CONTACT_STIFFNESS", "CONTACT_RATIO",
           "CONTACT_MOTION",
           "UP_RATE", "DOWN_RATE", "GAIN_RANGE", "CENTRE_TOLERANCE", "CENTRE_SPEED",
           "CENTRE_STIFFNESS", "CENTRE_DAMPING", "CENTRE_DITHER", "CENTRE_DITHER_FREQUENCY",
           "CENTRE_DITHER_CYCLES", "CENTRE_SETTLE", "CENTRE_ERROR"]

#: Phases of an excitation, in order.
EXCITATION_PHASES = ("rest", "excite", "done")
#: The amplitude law aims the envelopes of |X - x_0| and |V| at this fraction of their limits.
TARGET = 0.6
#: ... and raises the amplitude while both are below this fraction.
LOW_TARGET = 0.45
#: Each raised-cosine fade spans this factor of frequency.
FADE_RATIO = 1.5
#: Shortest fade [s].
MIN_FADE = 0.05
#: The contact test's window, in periods of the chirp's frequency.
CONTACT_PERIODS = 4.0
#: The contact test's threshold on ``|k_+ - k_-|``: this stiffness [N m/rad] ...
CONTACT_STIFFNESS = 0.02
#: ... plus this fraction of the magnitude ``|Z| = rms(F_p - c_F) / rms(X - c_X)``.
CONTACT_RATIO = 0.45
#: The rms motion [rad] on each side of x_0 over the window below which the test waits.
CONTACT_MOTION = 2e-3
#: Above this share of commands applied later than the loop's usual delay in its window, a
#: tripped contact test names the loop's timing instead of a contact (a free finger driven
#: with 20 % of the commands a cycle late crossed the threshold; separate sim_node and
#: controller_node processes answer 62 % of the cycles in time: bench/control_loop.py).
LATE_SHARE = 0.05
#: Fastest rise of ln g per period of the chirp (and at most 1/s): the amplitude stays
#: nearly constant over the contact test's window.
UP_RATE = 0.05
#: Fastest fall of ln g [1/s] (a factor 2 in 70 ms: a resonance the model misplaced builds up
#: over tens of ms).
DOWN_RATE = 10.0
#: Bounds of the online correction g of the model's amplitude law.
GAIN_RANGE = (0.1, 4.0)
#: A start farther than this from ``feedforward.rest_position`` [rad] is moved there first
#: (module docstring: the centring move).
CENTRE_TOLERANCE = 0.02
#: The centring move's peak speed [rad/s].
CENTRE_SPEED = 0.2
#: ... its servo's stiffness [N m/rad] and damping [N m s/rad] (a 10 Hz motor loop on Table
#: I's m; the friction it carries, up to about 0.15 N m, leaves 30 mrad of lag) ...
CENTRE_STIFFNESS = 5.0
CENTRE_DAMPING = 0.08
#: ... the dither that ends it: its first amplitude [rad] (beyond every finger's
#: pre-sliding range F_c/sigma, 0.6-10 mrad), its frequency [Hz] and its cycles ...
CENTRE_DITHER = 0.02
CENTRE_DITHER_FREQUENCY = 3.0
CENTRE_DITHER_CYCLES = 8
#: ... the time it then holds the finger at rest [s] ...
CENTRE_SETTLE = 0.3
#: ... and the lag behind its path [rad] at which it aborts (something holds the finger).
CENTRE_ERROR = 0.1
_DITHER_TIME = CENTRE_DITHER_CYCLES / CENTRE_DITHER_FREQUENCY      # s
_DITHER_OMEGA = 2.0 * math.pi * CENTRE_DITHER_FREQUENCY            # rad/s
#: Points per decade of the amplitude law's table.
_TABLE_DENSITY = 50
#: Frequency window either side over which the model's largest motion is taken.
_WINDOW = 2.0

_Array = npt.NDArray[np.float64]


class ExcitationGoal:
    """What a free-air excitation is asked to do (the job applies nothing).

    Parameters
    ----------
    channel : str
    band : (float, float) or None
        Chirp start and end frequency [Hz], ``0 < lo < hi``; None: the channel's
        ``commissioning.start_frequency`` and ``end_frequency``.
    duration : float or None
        Chirp duration [s], fades included; None: ``commissioning.duration``. The contact test
        assumes a slow sweep (``ln(f_1/f_0)/duration`` up to about 0.5 per second: 20 s over
        the default band, 8 s over 5..200 Hz); a faster one may see contacts in free air (the
        job then aborts: safe, but no record).
    """

    __slots__ = ("channel", "band", "duration")

    def __init__(self, channel: str, band: tuple[float, float] | None = None,
                 duration: float | None = None) -> None:
        self.channel = channel
        self.band = band
        self.duration = duration

    def __repr__(self) -> str:
        return (f"ExcitationGoal(channel={self.channel!r}, band={self.band!r}, "
                f"duration={self.duration!r})")


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not (math.isfinite(value) and value > 0.0):
        raise InvalidJobGoalError(f"{name} = {value!r}: must be a finite number > 0")
    return float(value)


def check_excitation_goal(goal: ExcitationGoal, params: CommissioningParams,
                          dt: float = 5e-4) -> tuple[float, float, float]:
    """``(start_frequency [Hz], end_frequency [Hz], duration [s])`` of ``goal`` with the
    channel's defaults filled in; :class:`~..core.jobs.InvalidJobGoalError` naming the field
    and its bound when it cannot run (a band beyond 0.9 of the Nyquist frequency
    ``1/(2 dt)``, fades shorter than :data:`MIN_FADE` or leaving no band between them)."""
    if not isinstance(goal, ExcitationGoal):
        raise TypeError("goal must be an ExcitationGoal")
    if goal.band is None:
        lo, hi = params.start_frequency, params.end_frequency
    else:
        try:
            lo_raw, hi_raw = goal.band
        except (TypeError, ValueError):
            raise InvalidJobGoalError(f"band = {goal.band!r}: must be (start, end) in Hz, "
                                      "or None for commissioning.start_frequency/"
                                      "end_frequency") from None
        lo, hi = _number("band start", lo_raw), _number("band end", hi_raw)
    duration = params.duration if goal.duration is None else _number("duration",
                                                                      goal.duration)
    nyquist = 0.5 / dt
    if not lo < hi:
        raise InvalidJobGoalError(f"band = ({lo!r}, {hi!r}) Hz: the start must be below the "
                                  "end")
    if hi > 0.9 * nyquist:
        raise InvalidJobGoalError(f"band end = {hi!r} Hz: must be <= 0.9 of the Nyquist "
                                  f"frequency {nyquist:g} Hz")
    if duration > 600.0:
        raise InvalidJobGoalError(f"duration = {duration!r} s: must be <= 600 s")
    fade = duration * math.log(FADE_RATIO) / math.log(hi / lo)
    if hi / lo <= FADE_RATIO ** 2 or fade < MIN_FADE:
        raise InvalidJobGoalError(
            f"duration = {duration!r} s over the band {lo:g}..{hi:g} Hz: the fades (a factor "
            f"{FADE_RATIO:g} of frequency each) must leave a band between them and last "
            f"{MIN_FADE:g} s or more each ({fade:.3g} s): a longer duration or a wider band")
    return lo, hi, duration


def _free_air_admittance(plant: PlantParams, stiffness: float, damping: float,
                         endpoint_stiffness: float, w: _Array) -> npt.NDArray[np.complex128]:
    """X/F_a(jw) [rad/(N m)] of the model with the servo ``K_p + K_d s`` and the endpoint's
    stiffness raised by ``endpoint_stiffness``: ``1/(Z_m + Z_s Z_e/(Z_s + Z_e))``."""
    s = 1j * w
    zm = plant.motor_inertia * s * s + (plant.motor_damping + damping) * s \
        + plant.motor_stiffness + stiffness
    zs = plant.hose_damping * s + plant.hose_stiffness
    ze = plant.endpoint_inertia * s * s + plant.endpoint_damping * s \
        + plant.endpoint_stiffness + endpoint_stiffness
    result: npt.NDArray[np.complex128] = 1.0 / (zm + zs * ze / (zs + ze))
    return result


def _motion_per_torque(config: ControllerConfig,
                       frequency: _Array) -> tuple[_Array, _Array]:
    """The model's largest ``|X/F_a|`` [rad/(N m)] and ``|V/F_a|`` [rad/(s N m)] over
    ``f/2..2f`` for each ``frequency`` [Hz], the endpoint free or held by its Dahl stiffness
    sigma, the centring servo included."""
    c = config.commissioning
    f = np.asarray(frequency, dtype=float)
    offsets = np.exp(np.linspace(-math.log(_WINDOW), math.log(_WINDOW), 41))
    w = 2.0 * math.pi * f[:, None] * offsets[None, :]
    worst_x = np.zeros_like(f)
    worst_v = np.zeros_like(f)
    for held in (0.0, config.dahl.sigma):
        h = np.abs(_free_air_admittance(config.plant, c.stiffness, c.damping, held, w))
        worst_x = np.maximum(worst_x, h.max(axis=1))
        worst_v = np.maximum(worst_v, (h * w).max(axis=1))
    return worst_x, worst_v


def nominal_amplitude(config: ControllerConfig, frequency: _Array, room: float,
                      limit: float) -> _Array:
    """The amplitude law's model part ``a_0(f)`` [N m] at ``frequency`` [Hz] (module
    docstring): the torque for which the model's largest motion over ``f/2..2f`` (endpoint
    free or held by its Dahl stiffness sigma) reaches :data:`TARGET` of ``room`` [rad] in
    position and of ``commissioning.max_speed`` in speed, at most ``limit`` [N m]."""
    worst_x, worst_v = _motion_per_torque(config, frequency)
    speed = TARGET * config.commissioning.max_speed
    amplitude: _Array = np.minimum(np.minimum(TARGET * room / worst_x, speed / worst_v),
                                   limit)
    return amplitude


class FreeAirExcitation(Job):
    """One free-air excitation on one channel (module docstring): a job whose output is the
    motor torque F_a [N m].

    Parameters
    ----------
    goal : ExcitationGoal
    config : ControllerConfig
        The channel's: ``commissioning`` settings, ``max_torque``, and the model (``plant``,
        ``dahl.sigma``) the amplitude law starts from.
    dt : float > 0
        Sample period [s].

    Raises
    ------
    InvalidJobGoalError
        The goal cannot run (:func:`check_excitation_goal`).

    Attributes
    ----------
    phase : str
        One of :data:`EXCITATION_PHASES`.
    outcome : str or None
        None until done, then ``'succeeded'``, ``'canceled'`` or ``'aborted'``.
    message : str
    progress : float
        0..1.
    frequency : float
        The chirp's frequency now [Hz] (0 in the rest phase).
    amplitude : float
        The excitation's amplitude now ``a`` [N m].
    gain : float
        The online correction g of the model's law [-].
    peak_position, peak_speed : float
        Largest ``|X - x_0|`` [rad] and ``|V|`` [rad/s] so far.
    contact_level : float
        Largest ratio of the contact test's mean pressure force to its threshold so far (the
        job aborts above 1).
    capacity : int
        Samples the record holds at most.
    """

    kind = "free-air excitation"
    output = TORQUE

    def __init__(self, goal: ExcitationGoal, config: ControllerConfig,
                 dt: float = 5e-4) -> None:
        super().__init__()
        if not isinstance(config, ControllerConfig):
            raise TypeError("config must be a ControllerConfig")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt = {dt!r} must be > 0 and finite")
        self.dt = dt = float(dt)
        self.goal = goal
        self.config = config
        c = self.params = config.commissioning
        f0, f1, duration = check_excitation_goal(goal, c, dt)
        self.start_frequency, self.end_frequency, self.duration = f0, f1, duration
        self._limit = min(c.max_torque, config.max_torque)
        self._kp, self._kd = c.stiffness, c.damping
        self._rest = c.rest_duration
        self._rest_position = config.feedforward.rest_position
        self._rate = math.log(f1 / f0) / duration
        self._fade = math.log(FADE_RATIO) / self._rate
        self._end = self._rest + duration
        self._speed_limit = c.max_speed
        # the amplitude law's model part, per unit room (scaled when x_0 is known)
        self._table_step = math.log(10.0) / _TABLE_DENSITY
        n_table = int(math.ceil(math.log(f1 / f0) / self._table_step)) + 2
        worst_x, worst_v = _motion_per_torque(
            config, f0 * np.exp(self._table_step * np.arange(n_table)))
        self._per_room = [float(a) for a in TARGET / worst_x]
        self._for_speed = [float(a) for a in TARGET * c.max_speed / worst_v]
        self._table: list[float] = []
        # the record, for the whole excitation
        self.capacity = n = int(math.ceil(self._end / dt)) + 2
        # (``array``: element access in Python floats, tens of ns, where a numpy element's is
        # a numpy scalar and costs several times that)
        self._cycle = array("q", bytes(8 * n))
        self._x, self._v, self._fp = _zeros(n), _zeros(n), _zeros(n)
        self._applied, self._command, self._exc = _zeros(n), _zeros(n), _zeros(n)
        # running sums of the contact test, each side of the motion's centre: (F_p - c_F)
        # (X - c_X), (X - c_X)^2; and (F_p - c_F)^2 both sides; [i]: over the first i samples
        self._cum_fp, self._cum_qp = _zeros(n + 1), _zeros(n + 1)
        self._cum_fn, self._cum_qn = _zeros(n + 1), _zeros(n + 1)
        self._cum_ff = _zeros(n + 1)
        self._sums = [0.0, 0.0, 0.0, 0.0, 0.0]     # their latest values: fp, qp, fn, qn, ff
        self._n = 0
        # the state
        self.phase = "rest"
        self.message = "waiting for the control cycle"
        self.progress = 0.0
        self.frequency = 0.0
        self.amplitude = 0.0
        self.gain = 1.0
        self.peak_position = 0.0
        self.peak_speed = 0.0
        self.touched = False         # the contact test ended it: something is in the way
        self._rearmed = False
        self._t = 0.0
        self._x0 = math.nan
        self._bias = 0.0
        self._room = 0.0
        self._env_x = 0.0
        self._env_v = 0.0
        self._centre_x = math.nan
        self._centre_f = 0.0
        self._rest_samples = 0
        self.contact_level = 0.0
        self._log_gain = 0.0
        self._cancel: str | None = None
        # the centring move (module docstring): its path from, to, its duration and clock [s]
        self.centring = False
        self._move = (0.0, 0.0, 0.0)
        self._move_t = 0.0

    # --- requests and the end (the rest is the job's: :class:`~..core.jobs.Job`) ------------
    def request_cancel(self, reason: str = "canceled") -> None:
        """(any thread) End at the next sample, canceled, with zero torque from it on."""
        self._cancel = reason

    def abort_now(self, reason: str) -> None:
        """End at once, commanding nothing more (the cycle zeroed the torque)."""
        if self.phase != "done":
            self._finish("aborted", reason)

    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        """``phase``, ``progress`` (0..1), ``frequency`` [Hz], ``amplitude`` [N m],
        ``peak_position`` (largest |X - x_0|) [rad], ``peak_speed`` (largest |V|) [rad/s]."""
        return {"phase": self.phase, "progress": self.progress,
                "frequency": self.frequency, "amplitude": self.amplitude,
                "peak_position": self.peak_position, "peak_speed": self.peak_speed}

    def record(self) -> ExcitationRecord:
        """The samples so far, as an :class:`~.record.ExcitationRecord` (copies, trimmed)."""
        n = self._n
        return ExcitationRecord(
            dt=self.dt, cycle=np.frombuffer(self._cycle, np.int64, n).copy(),
            x=_trimmed(self._x, n), v=_trimmed(self._v, n), f_p=_trimmed(self._fp, n),
            applied=_trimmed(self._applied, n), command=_trimmed(self._command, n),
            excitation=_trimmed(self._exc, n))

    def __len__(self) -> int:
        """Samples recorded so far."""
        return self._n

    def _abort(self, reason: str) -> float:
        self._finish("aborted", reason + ": zero torque")
        return 0.0

    # --- per sample --------------------------------------------------------------------------
    def step(self, sample: JobSample) -> float:
        """(cycle thread) :meth:`update` on the channel's sample: F_a [N m]. On the sample it
        ends on -- unless its contact test ended it -- the channel's contact estimator is
        re-armed once the finger is at rest
        (:meth:`~..core.estimator.ContactEstimator.rearm_at_rest`): under the chirp that
        estimator's residual (the model's error times large accelerations) starts contacts
        that are none, and one left standing at the end would stay (its residual's offset at
        rest keeps it from ending) and turn the next grasp or commissioning away; re-armed at
        once, a canceled chirp's coasting finger started one as it stopped."""
        u = self.update(sample.x, sample.v, sample.f_p, sample.torque, sample.applied,
                        sample.cycle, sample.steps)
        if self.phase == "done" and not self._rearmed:
            self._rearmed = True
            if not self.touched:
                sample.estimator.rearm_at_rest()
        return u

    def update(self, x: float, v: float, f_p: float, u_prev: float, applied: float,
               cycle: int = -1, steps: int = 1) -> float:
        """One sample: motor X [rad], V [rad/s], F_p [N m], the channel's last torque and the
        torque the plant reports applied [N m], the state's cycle, the sample periods since
        the last; returns F_a [N m],
        ``|F_a| <= min(commissioning.max_torque, max_torque)``, exactly 0.0 from the sample
        the job ends without success on, and 0.0 once done."""
        if self.phase == "done":
            return 0.0
        if not (_finite(x) and _finite(v) and _finite(f_p) and _finite(applied)
                and _finite(u_prev)):
            return self._abort("non-finite input (X, V, F_p or the applied torque)")
        if self._abort_request is not None:
            return self._abort(self._abort_request)
        if self._cancel is not None:
            self._finish("canceled", self._cancel + ": zero torque")
            return 0.0
        if self._x0 != self._x0 and not self.centring:      # NaN: the first sample
            reason = self._start(x, u_prev)
            if reason:
                return self._abort(reason)
        reason = self._check(x, v)
        if reason:
            return self._abort(reason)
        if self.centring:
            return self._centre(x, v, u_prev, steps)
        excitation = self._excitation(x, v, f_p, steps)
        u = self._bias + excitation - self._kp * (x - self._x0) - self._kd * v
        limit = self._limit
        u = limit if u > limit else (-limit if u < -limit else u)
        n = self._n
        if n >= self.capacity:
            return self._abort("the record is full")
        self._cycle[n] = cycle
        self._x[n] = x
        self._v[n] = v
        self._fp[n] = f_p
        self._applied[n] = applied
        self._command[n] = u
        self._exc[n] = excitation
        # the contact test's sums about the motion's centre (both tracked over a period)
        a = self.dt * steps * self.frequency
        a = a if a < 1.0 else 1.0
        cx = self._centre_x
        cf = self._centre_f
        cx += a * (x - cx)
        cf += a * (f_p - cf)
        self._centre_x = cx
        self._centre_f = cf
        d = x - cx
        g = f_p - cf
        sums = self._sums
        k = n + 1
        if d > 0.0:
            sums[0] += g * d
            sums[1] += d * d
        else:
            sums[2] += g * d
            sums[3] += d * d
        sums[4] += g * g
        self._cum_fp[k] = sums[0]
        self._cum_qp[k] = sums[1]
        self._cum_fn[k] = sums[2]
        self._cum_qn[k] = sums[3]
        self._cum_ff[k] = sums[4]
        self._n = n + 1
        reason = self._contact(n + 1)
        if reason:
            self.touched = True
            return self._abort(reason)
        if self._t >= self._end:
            self.progress = 1.0
            self._finish("succeeded", f"excited {self.start_frequency:g}..{self.end_frequency:g}"
                                      f" Hz in {self.duration:g} s: peak |X - x_0| "
                                      f"{self.peak_position:.3g} rad, |V| "
                                      f"{self.peak_speed:.3g} rad/s")
        return u

    def _start(self, x: float, u_prev: float) -> str:
        """The first sample: the centring move if the finger is away from rest, else
        :meth:`_begin`; the reason not to start, or ''."""
        c = self.params
        lo, hi = c.position_min, c.position_max
        if not lo < x < hi:
            return (f"the motor at {x:.4g} rad is outside the joint range "
                    f"commissioning.position_min..position_max = {lo:g}..{hi:g} rad")
        rest = self._rest_position
        if abs(x - rest) <= CENTRE_TOLERANCE:
            return self._begin(x, u_prev)
        reason = self._loaded(u_prev, "start from passive or a lighter hold")
        if reason:
            return reason
        if not lo < rest < hi:
            return (f"the finger's rest feedforward.rest_position = {rest:g} rad is outside "
                    f"the joint range {lo:g}..{hi:g} rad: set the rest where the finger's "
                    "spring is relaxed")
        self.centring = True
        self._bias = u_prev
        self._move = (x, rest, 0.5 * math.pi * abs(rest - x) / CENTRE_SPEED)
        self._move_t = 0.0
        self.message = f"centring: moving the finger from {x:.3g} rad to its rest {rest:g} rad"
        return ""

    def _begin(self, x: float, u_prev: float,
               advice: str = "start from passive or a lighter hold") -> str:
        """x_0, the entry torque and the amplitude law's table, at ``x`` [rad] with the
        channel's last torque ``u_prev`` [N m]; the reason not to go on (``advice`` what to
        do about a load), or ''."""
        c = self.params
        lo, hi = c.position_min, c.position_max
        limit = self._limit
        reason = self._loaded(u_prev, advice)
        if reason:
            return reason
        self._x0 = self._centre_x = x
        self._bias = u_prev
        self._room = min(x - lo, hi - x)
        # the table of a_0 for this room and bound (pure Python: no numpy in the cycle)
        room, cap = self._room, limit - abs(u_prev)
        self._table = [min(room * p, s, cap) for p, s in zip(self._per_room, self._for_speed)]
        self.message = "resting"
        return ""

    def _loaded(self, u: float, advice: str) -> str:
        """The reason not to excite from a torque ``u`` [N m] above half the bound, or ''."""
        if abs(u) <= 0.5 * self._limit:
            return ""
        return (f"the channel holds {u:.3g} N m, more than half the excitation's bound "
                f"{self._limit:g} N m: {advice}")

    def _centre(self, x: float, v: float, u_prev: float, steps: int) -> float:
        """One sample of the centring move (module docstring): F_a [N m], nothing recorded."""
        start, rest, duration = self._move
        t = self._move_t
        self._move_t = t + self.dt * steps
        dither = _DITHER_TIME
        if t < duration:
            phase = math.pi * t / duration
            ref = start + (rest - start) * 0.5 * (1.0 - math.cos(phase))
            speed = (rest - start) * 0.5 * math.pi / duration * math.sin(phase)
        elif t < duration + dither:
            tau = t - duration
            w = _DITHER_OMEGA
            a = CENTRE_DITHER * (1.0 - tau / dither)
            ref = rest + a * math.sin(w * tau)
            speed = a * w * math.cos(w * tau) - CENTRE_DITHER / dither * math.sin(w * tau)
        else:
            ref, speed = rest, 0.0
        if abs(x - ref) > CENTRE_ERROR:
            return self._abort(
                f"centring: the finger at {x:.4g} rad fell {abs(x - ref):.3g} rad behind its "
                f"path to rest ({rest:g} rad): something holds it; free the finger")
        u = self._bias - CENTRE_STIFFNESS * (x - ref) - CENTRE_DAMPING * (v - speed)
        limit = self._limit
        u = limit if u > limit else (-limit if u < -limit else u)
        if t >= duration + dither + CENTRE_SETTLE:
            self.centring = False       # the weak servo takes over where the move ended
            reason = self._begin(x, u, "the motor's spring is loaded at rest (is "
                                 "feedforward.rest_position the finger's rest?)")
            if reason:
                return self._abort(reason)
        return u

    def _check(self, x: float, v: float) -> str:
        """The hard limits: the reason to abort, or ''."""
        c = self.params
        if not c.position_min <= x <= c.position_max:
            return (f"the motor at {x:.4g} rad left the joint range "
                    f"{c.position_min:g}..{c.position_max:g} rad")
        if not -self._speed_limit <= v <= self._speed_limit:
            return (f"|V| = {abs(v):.4g} rad/s beyond commissioning.max_speed = "
                    f"{self._speed_limit:g} rad/s")
        return ""

    def _contact(self, n: int) -> str:
        """The contact test on the ``n`` samples recorded (module docstring): the apparent
        stiffness ``k = -sum (F_p - c_F)(X - c_X) / sum (X - c_X)^2`` over the last
        :data:`CONTACT_PERIODS` periods of the chirp, on each side of the motion's centre
        ``c_X`` (``c_F``: the pressure force's; both tracked over a period); the reason to
        abort, or ''."""
        f = self.frequency
        if f <= 0.0:
            return ""
        window = int(CONTACT_PERIODS / (f * self.dt))
        if window > n - self._rest_samples:
            return ""                   # the chirp has not run that long yet
        m = n - window
        fp, qp, fn, qn, ff = self._sums
        qp -= self._cum_qp[m]
        qn -= self._cum_qn[m]
        least = window * CONTACT_MOTION * CONTACT_MOTION
        if qp < least or qn < least:
            return ""                   # one side hardly moved (see the module docstring)
        kp = (self._cum_fp[m] - fp) / qp
        kn = (self._cum_fn[m] - fn) / qn
        magnitude = math.sqrt((ff - self._cum_ff[m]) / (qp + qn))
        threshold = CONTACT_STIFFNESS + CONTACT_RATIO * magnitude
        level = abs(kp - kn) / threshold
        if level > self.contact_level:
            self.contact_level = level
        if level <= 1.0:
            return ""
        side = "above" if kp > kn else "below"
        late = self._late_share(m, n)
        if late > LATE_SHARE:
            return (f"over the last {window * self.dt:.3g} s the plant applied {100 * late:.0f} % "
                    "of the commands later than the others (a controller in another process "
                    "than the plant, over topics); the contact test cannot tell such a drive "
                    f"from a contact (apparent stiffness {kp:.3g} N m/rad above the centre, "
                    f"{kn:.3g} below): commission in the direct layout (bringup or "
                    "hardware_bringup with loop:=direct) or with the sim in lockstep")
        return (f"contact {side} X = {self._centre_x:.4g} rad: over the last {window * self.dt:.3g} s "
                f"the pressure force's apparent stiffness is {kp:.3g} N m/rad above and "
                f"{kn:.3g} below (a free finger's is the same both sides): the finger is not "
                "free")

    def _late_share(self, m: int, n: int) -> float:
        """Over the samples ``m..n-1``: the share whose applied torque is not the command of
        the loop's usual delay (the most common d = 1..4 with ``applied[k] == command[k -
        d]``, exact: a plant that reports the torque it applied). 0 where under half of the
        samples match any of the last four commands (a plant that reports a measured
        torque: no claim)."""
        m = max(m, 4)
        if n - m < 8:
            return 0.0
        applied = np.frombuffer(self._applied, dtype=float, count=n)[m:n]
        command = np.frombuffer(self._command, dtype=float, count=n)
        unmatched = np.ones(n - m, dtype=bool)
        counts = []
        for d in range(1, 5):
            hit = unmatched & (applied == command[m - d:n - d])
            counts.append(int(np.count_nonzero(hit)))
            unmatched &= ~hit
        if sum(counts) < 0.5 * (n - m):
            return 0.0
        return 1.0 - max(counts) / (n - m)

    def _excitation(self, x: float, v: float, f_p: float, steps: int) -> float:
        """The excitation torque ``a e`` of this sample [N m], the envelopes and the
        amplitude's correction, the clock and the progress."""
        dx = abs(x - self._x0)
        av = abs(v)
        if dx > self.peak_position:
            self.peak_position = dx
        if av > self.peak_speed:
            self.peak_speed = av
        dt = self.dt * steps
        t = self._t
        self._t = t + dt
        tc = t - self._rest
        if tc < 0.0:                    # the rest: the free-air pressure force
            k = self._rest_samples + 1
            self._rest_samples = k
            self._centre_f += (f_p - self._centre_f) / k
        if tc < 0.0 or tc >= self.duration:
            self.frequency = self.amplitude = 0.0
            self.progress = min(1.0, max(0.0, t / self._end))
            return 0.0
        if self.phase == "rest":
            self.phase = "excite"
            self.message = "exciting"
        self.progress = t / self._end
        rate = self._rate
        f0 = self.start_frequency
        f = f0 * math.exp(rate * tc)
        self.frequency = f
        # envelopes: peak-hold, decaying over 1.5 periods
        decay = dt * f / 1.5
        decay = 1.0 - (decay if decay < 1.0 else 1.0)
        ex = self._env_x * decay
        ev = self._env_v * decay
        ex = dx if dx > ex else ex
        ev = av if av > ev else ev
        self._env_x, self._env_v = ex, ev
        # the amplitude law: the model's table (linear in ln f) times the correction
        table = self._table
        pos = rate * tc / self._table_step       # (ln f - ln f_0) / step
        i = int(pos)
        if i >= len(table) - 1:
            i = len(table) - 2
        frac = pos - i
        a0 = table[i] + frac * (table[i + 1] - table[i])
        limit = self._limit - abs(self._bias)
        if self.gain * a0 > limit:      # the bound rules: g no higher than it lets act
            self._log_gain = math.log(limit / a0)
            self.gain = limit / a0
        self._adapt(ex, ev, dt)
        a = self.gain * a0
        a = limit if a > limit else a
        edge = min(tc, self.duration - tc)
        if edge < self._fade:
            a *= 0.5 - 0.5 * math.cos(math.pi * edge / self._fade)
        self.amplitude = a
        phase = 2.0 * math.pi * f0 * math.expm1(rate * tc) / rate
        return a * math.sin(phase)

    def _adapt(self, env_x: float, env_v: float, dt: float) -> None:
        """Move ln g towards envelopes between :data:`LOW_TARGET` and :data:`TARGET` of the
        limits, rate-limited (where the torque bound rules, g has been held at what it lets
        act: no wind-up)."""
        ratio = max(env_x / self._room if self._room > 0.0 else 1.0,
                    env_v / self._speed_limit)
        lg = self._log_gain
        if ratio > TARGET:
            step = math.log(ratio / TARGET) if ratio < math.e * TARGET else 1.0
            lg -= DOWN_RATE * dt * step
        elif ratio < LOW_TARGET:
            up = UP_RATE * self.frequency
            lg += (up if up < 1.0 else 1.0) * dt
        else:
            return
        lo, hi = _LOG_GAIN_RANGE
        lg = lo if lg < lo else (hi if lg > hi else lg)
        self._log_gain = lg
        self.gain = math.exp(lg)


_LOG_GAIN_RANGE = (math.log(GAIN_RANGE[0]), math.log(GAIN_RANGE[1]))


def _zeros(n: int) -> array[float]:
    """``n`` zeros in an ``array('d')``."""
    return array("d", bytes(8 * n))


def _trimmed(values: array[float], n: int) -> _Array:
    """The first ``n`` values, copied into a numpy array."""
    return np.frombuffer(values, np.float64, n).copy()
_finite = math.isfinite

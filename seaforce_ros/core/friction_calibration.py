"""Endpoint friction that recalibrates itself: a calibration action and an online adaptation.

The friction feed-forward (eq. 29 and the Dahl force, eq. 14) uses b_e, k_e, F_c and sigma
identified once; they drift. In free air the external force is zero, so the endpoint's balance
(paper Section II-C, motor frame) gives the friction from pressure and motor state alone::

    -F_p - m_e A_e = b_e V_e + k_e (X_e - rest) + F_c f(X_e; a),     a = sigma/F_c

with X_e, V_e, A_e the hose model's endpoint estimate (the controller's X_e_hat, eq. 29) and
``f = F_d/F_c`` the normalised Dahl force, which depends on sigma and F_c only through their
ratio ``a`` (:class:`~seaforce_ros.identification.dahl_model.DahlPath` uses the same
property). The relation is linear in (b_e, k_e, F_c, an offset) for a given ``a``: a
*variable projection* fit, as identification's ``fit_endpoint_with_dahl`` does on spectra,
here sample by sample. :class:`FrictionFit` runs one normalised Dahl state per candidate
ratio on a log grid (exact per-sample update, :func:`~.dahl.dahl_step`), driven by the
controller's Dahl input (X_e_hat through its play operator, so that the fit describes the
force the feed-forward will compute), and sees every signal through the contact estimator's
state-variable filter (:func:`~.estimator.svf_coefficients`: filtering both sides of a linear
relation alike keeps it exact, removes the pressure noise and the hose mode, and gives V_e and
A_e without differentiating a noisy signal). The cross products of :data:`BLOCK` samples are
formed in one numpy call; each candidate's 4x4 normal equations give its misfit, and the
misfit's minimum over log ``a`` (a parabola through the best grid point and its neighbours)
gives sigma = a F_c.

1-sigma: the residual variance (samples counted per correlation time of the filter) times the
inverse normal matrix for b_e, k_e, F_c; for log ``a`` the profiled misfit's curvature
(``var = s^2 / c`` for ``rss(l) = rss_min + c (l - l*)^2``); sigma's adds F_c's.

:class:`FrictionCalibration` (action ``~/calibrate_friction``): a :class:`~.jobs.Job` whose
output is the motor torque (:data:`~.jobs.TORQUE`): it overrides the channel's mode while it
runs, like a grasp. A position servo on the motor (the ``hold`` gains) tracks ``X_ref
= x_0 + A e(t) sin(w t)``, ``w = speed/A``, ``e`` a raised-cosine fade over one period at both
ends, for ``friction.calibration_duration``; its torque never exceeds
``min(friction.torque_limit, max_torque)``; while the plant applies something else (a command
timeout) the reference waits. The fit takes the samples after the fade-in (the Dahl states have
forgotten their start by then), and ramps its inputs over samples it never saw. Then it holds
``x_0`` while it solves one candidate per sample, reports the new values with their 1-sigma and
the change, and the controller applies them (bumplessly, at the start of the next sample) if
the goal asked for it and they are plausible: within ``friction.plausible_ratio`` of the
present values. Before it learns, it makes sure the finger is free: the model-free contact test
of :mod:`.sided` (the two sides' stiffness about the motion's centre, judged at every whole
period between the fades) aborts it when something is in reach, nothing applied. It aborts with the reason, commanding zero torque from then on, on a
non-finite input, a tracking error beyond ``friction.max_tracking_error`` (the finger is
blocked: not free) or an endpoint outside the joint range; a fit that cannot tell the
parameters apart is reported, not applied.

:class:`FrictionAdaptation` (``friction.adaptation``): the same fit with three candidate ratios
around the present one and forgetting (``friction.adaptation_time``, only while the finger
moves), fed only while the contact estimator reports no contact. (The calibration's
model-free contact test needs a motion about a known centre, judged at whole periods; over
windows of the adaptation's unstructured motion it took a free endpoint moved at two
frequencies, not symmetric about its mean, for a contact four times in 12 s. The adaptation
relies on the estimator, its bounds and the runaway monitor.) At each block it moves b_e,
k_e, F_c, sigma a step ``BLOCK dt / adaptation_time`` towards the fit (solving one candidate
per sample after it), clipped to ``[v/(1+r), v(1+r)]`` of the configured ``v`` (``r =
friction.adaptation_bound``), and only when the motion excites every term: the velocity only
b_e explains above ``min_velocity_excitation``, the motion only k_e explains above
``min_position_excitation``, and the Dahl force's part only F_c explains above
:data:`MIN_DAHL_EXCITATION` (reversals). Below that it stops (``adapting`` False, ``reason``
says why).

Threads (those of every :class:`~.jobs.Job`): the cycle thread runs ``update`` (through
``step``), ``claim`` and ``abort_now``; the action server may call
:meth:`FrictionCalibration.request_cancel`, ``request_abort``, ``withdraw`` and read the
attributes.
"""

from __future__ import annotations

import dataclasses
import math
from collections import namedtuple
from collections.abc import Sequence
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from .dahl import dahl_step
from .estimator import BLOCK, svf_coefficients
from .jobs import TORQUE, InvalidJobGoalError, Job, JobSample
from .params import ControllerConfig, FrictionParams, PlantParams
from .sided import SidedStiffness
from .signals import faded_sine

if TYPE_CHECKING:
    from .estimator import ContactEstimator

#: One candidate's solution: (theta, rss, inverse normal matrix), or None (singular).
Solution: TypeAlias = "tuple[np.ndarray, float, np.ndarray] | None"

__all__ = ["FrictionFit", "FrictionEstimate", "FrictionCalibration", "CalibrationGoal",
           "InvalidCalibrationError", "check_calibration_goal", "FrictionAdaptation",
           "with_friction", "ratio_grid",
           "CALIBRATION_PHASES", "RATIO_SPAN", "RATIOS_PER_DECADE", "ADAPTATION_STEP",
           "MIN_DAHL_EXCITATION", "FLAT_MISFIT", "SETTLE_SAMPLES", "CONTACT_STIFFNESS",
           "CONTACT_RATIO", "CONTACT_MOTION"]

#: Phases of a calibration, in order.
CALIBRATION_PHASES = ("move", "solve", "done")
#: The calibration's grid of sigma/F_c spans this factor either side of the model's [-].
RATIO_SPAN = 10.0 ** 0.75
#: Grid points per decade of sigma/F_c (a step of 10^0.1 = 26 %).
RATIOS_PER_DECADE = 10
#: Spacing of the adaptation's three candidate ratios (factor) [-].
ADAPTATION_STEP = 10.0 ** 0.1
#: The Dahl regressor's part only F_c explains (rms of the normalised force, 0..1) below which
#: adaptation stops: too few reversals to tell hysteresis from damping.
MIN_DAHL_EXCITATION = 0.2
#: ``sigma_reason`` of a misfit without curvature in sigma/F_c.
FLAT_MISFIT = "the misfit is flat in sigma/F_c: sigma not identified"
#: Samples after a contact ends before the adaptation fits again (the filter's memory).
SETTLE_SAMPLES = 64
#: The calibration's contact test (:mod:`.sided`): ``|k_+ - k_-|`` beyond this stiffness
#: [N m/rad] ...
CONTACT_STIFFNESS = 0.005
#: ... plus this fraction of ``|Z|`` (a real finger's stroke-dependent stiffness is not quite
#: symmetric) is contact. Measured (Table I model, 0.5 rad at 1 rad/s, 0.3 at 1.5, 0.2 at 0.5):
#: free air over plants 0.5x..2x at most 0.0018 N m/rad; an object 0.2..5 N m/rad reached by
#: 0.05..0.4 rad 0.018..1.6.
CONTACT_RATIO = 0.05
#: The rms motion [rad] each side of the centre needs before the test judges.
CONTACT_MOTION = 0.01

FrictionEstimate = namedtuple(
    "FrictionEstimate", "endpoint_damping endpoint_stiffness coulomb_force sigma "
                        "endpoint_damping_sigma endpoint_stiffness_sigma coulomb_force_sigma "
                        "sigma_sigma velocity_excitation position_excitation dahl_excitation "
                        "samples reason sigma_reason pressure_offset pressure_offset_sigma",
    defaults=(math.nan, math.nan))
#: The largest pressure offset [N m] a calibration applies (the parameter's range).
OFFSET_LIMIT = float(ControllerConfig.spec("pressure_offset").high or 0.0)

FrictionEstimate.__doc__ = """A fit of the free endpoint's friction.

endpoint_damping, endpoint_stiffness, coulomb_force, sigma : b_e [N m s/rad], k_e [N m/rad],
    F_c [N m], sigma [N m/rad]
*_sigma : their 1-sigma
velocity_excitation, position_excitation, dahl_excitation : rms endpoint velocity [rad/s],
    motion [rad] and normalised Dahl force [-] only b_e, k_e, F_c explain
samples : samples fitted (after forgetting)
reason : '' when b_e, k_e, F_c are identified, else why not (no value is then to be used)
sigma_reason : '' when sigma is identified too, else why not (the best ratio on the edge of the
    searched range: sigma is then that edge's; or a flat misfit)
pressure_offset, pressure_offset_sigma : what the pressure force read beyond the endpoint's
    friction [N m] -- the sensor's offset, with the spring relaxed at the fit's ``rest`` (a
    rest elsewhere reads as ``k_e`` times the difference) -- and its 1-sigma
"""


class InvalidCalibrationError(InvalidJobGoalError):
    """A calibration goal that cannot be executed; the message says why."""


def stroke_terms(config: ControllerConfig) -> tuple[float, float, float] | None:
    """``(rest, k_2, k_3)`` of the model's stroke terms (:class:`FrictionFit`'s ``stroke``),
    None without them."""
    t = config.plant_terms
    return ((config.feedforward.rest_position, t.stroke_asymmetry, t.stroke_stiffness)
            if t.stroke else None)


class FrictionFit:
    """Variable-projection fit of the free endpoint's friction over candidate ratios.

    Parameters
    ----------
    plant : PlantParams
        m_e (known), the rest position's k_e is fitted.
    exponent : float >= 0
        Dahl exponent n (fixed).
    ratios : sequence of float > 0
        Candidate sigma/F_c [1/rad], increasing, equally spaced in log.
    dt : float > 0
        Sample period [s].
    filter_cutoff : float > 0
        Cut-off of the state-variable filter [Hz].
    forgetting_time : float > 0 or None
        Memory while the finger moves [s] (None: none).
    stroke : (rest, k_2, k_3) or None
        The model's stroke terms (``plant_terms``): their force ``k_2 u^2 + k_3 u^3``, ``u =
        X_e - rest``, is known and taken off the pressure force before the fit, which then
        fits the linear b_e, k_e beside them (else k_e would take the stroke stiffening in
        and the feed-forward count it twice). None: the linear model.
    rest : float
        Where the endpoint's spring is relaxed [rad] (``feedforward.rest_position``): the
        fit's constant is the pressure force's offset less ``k_e`` times the first sample's
        distance from it (:attr:`FrictionEstimate.pressure_offset`).
    """

    def __init__(self, plant: PlantParams, exponent: float, ratios: Sequence[float], dt: float,
                 filter_cutoff: float, forgetting_time: float | None = None,
                 stroke: tuple[float, float, float] | None = None, rest: float = 0.0) -> None:
        self._stroke = stroke
        self._rest = float(rest)
        self.dt = float(dt)
        self.ratios = [float(r) for r in ratios]
        self.exponent = float(exponent)
        self._me = plant.endpoint_inertia
        self._coef = svf_coefficients(filter_cutoff, self.dt)
        self._kappa = max(1.0, 1.0 / (2.0 * filter_cutoff * self.dt))
        self._decay = 1.0 if forgetting_time is None else math.exp(-BLOCK * self.dt
                                                                    / forgetting_time)
        self._width = 4 + len(self.ratios)
        self.reset()

    def reset(self, force: float = 0.0) -> None:
        """Forget everything; the Dahl states start from the normalised force ``force``."""
        self._first = True
        self._f = [max(-1.0, min(1.0, float(force)))] * len(self.ratios)
        self._clear()

    def _clear(self) -> None:
        self.S = np.zeros((self._width, self._width))
        self._block: list[float] = []
        self.folds = 0

    def update(self, xe: float, xd: float, fp: float, record: bool = True,
               steps: int = 1) -> None:
        """One sample: X_e_hat [rad], the Dahl input [rad], F_p [N m]; the filters and Dahl
        states always run, the sample is fitted only if ``record``."""
        if self._stroke is not None:
            rest, k2, k3 = self._stroke
            u = xe - rest
            fp = fp + u * u * (k2 + k3 * u)
        if self._first:
            self._first = False
            self._p, self._q, self._xd, self._g1, self._g2 = xe, 0.0, xd, fp, 0.0
            self._xe, self._fp = xe, fp
            self._p0 = xe
            self._h = [[f, 0.0] for f in self._f]
        q0 = self._q
        if steps == 1:
            self._advance(xe, xd, fp)
        else:
            # samples the plant produced but this controller never saw: the inputs ramp
            # linearly over the gap (holding the newest would lead every signal by the gap,
            # which the filters' derivatives turn into a velocity-proportional error: b_e
            # +2 % at 10 % lost samples)
            x0, d0, f0 = self._xe, self._xd, self._fp
            for j in range(1, steps + 1):
                c = j / steps
                self._advance(x0 + c * (xe - x0), d0 + c * (xd - d0), f0 + c * (fp - f0))
        acc = (self._q - q0) / (self.dt * steps)
        if record:
            block = self._block
            block.extend((self._q, self._p - self._p0, 1.0, -self._g1 - self._me * acc))
            block.extend([hk[0] for hk in self._h])
            if len(block) >= self._width * BLOCK:
                self.fold()

    def _advance(self, xe: float, xd: float, fp: float) -> None:
        """One sample period of the Dahl states and the filters with these inputs."""
        a11, a12, b1, a21, a22, b2 = self._coef
        dx = xd - self._xd
        self._xd, self._xe, self._fp = xd, xe, fp
        f = self._f
        if dx != 0.0:
            n = self.exponent
            for k, a in enumerate(self.ratios):
                f[k] = dahl_step(f[k], dx, a, 1.0, n)        # F_d/F_c: F_c = 1
        p, q = self._p, self._q
        self._p, self._q = a11 * p + a12 * q + b1 * xe, a21 * p + a22 * q + b2 * xe
        g1, g2 = self._g1, self._g2
        self._g1, self._g2 = a11 * g1 + a12 * g2 + b1 * fp, a21 * g1 + a22 * g2 + b2 * fp
        for k, hk in enumerate(self._h):
            u, w = hk
            hk[0], hk[1] = a11 * u + a12 * w + b1 * f[k], a21 * u + a22 * w + b2 * f[k]

    @property
    def started(self) -> bool:
        """The filters hold a sample."""
        return not self._first

    @property
    def dahl_states(self) -> tuple[float, ...]:
        """The candidates' normalised Dahl forces F_d/F_c."""
        return tuple(self._f)

    def fold(self) -> None:
        """Add the samples since the last fold to the normal matrix (forgetting the old ones
        when the finger moved)."""
        block = self._block
        if not block:
            return
        n = len(block) // self._width
        x = np.fromiter(block, float, len(block)).reshape(n, self._width)
        self._block = []
        prod = x.T @ x
        self.folds += 1
        if self._decay < 1.0 and prod[0, 0] > 1e-4 * n:
            self.S = self.S * self._decay ** (n / BLOCK) + prod
        else:
            self.S = self.S + prod

    @property
    def samples(self) -> float:
        """Samples in the normal matrix (after forgetting)."""
        return float(self.S[2, 2])

    def solve_candidate(self, k: int) -> Solution:
        """``(theta, rss, inverse)`` of candidate ``k``: theta = (b_e, k_e, offset, F_c),
        or None when the normal matrix is singular (a regressor that never varied)."""
        idx = [0, 1, 2, 4 + k]
        S = self.S
        g = S[np.ix_(idx, idx)]
        h = S[idx, 3]
        d = np.sqrt(np.diag(g))
        if not np.all(d > 0.0):
            return None
        gn = g / np.outer(d, d)
        try:
            pivots = np.diag(np.linalg.cholesky(gn))
        except np.linalg.LinAlgError:
            return None
        if pivots.min() ** 2 < 1e-10:       # a regressor (almost) explained by the others
            return None
        inv = np.linalg.inv(gn) / np.outer(d, d)
        theta = inv @ h
        rss = max(float(S[3, 3] - theta @ h), 0.0)
        return theta, rss, inv

    def estimate(self, solutions: Sequence[Solution]) -> FrictionEstimate:
        """The :class:`FrictionEstimate` from ``solutions`` (one :meth:`solve_candidate`
        result per ratio)."""
        if len(solutions) != len(self.ratios):
            raise ValueError(f"{len(solutions)} solutions for {len(self.ratios)} ratios")
        n = self.samples
        costs = [s[1] if s is not None else math.inf for s in solutions]
        best = int(np.argmin(costs))
        nan = math.nan
        solution = solutions[best]
        if solution is None or not math.isfinite(costs[best]) or n < 8.0:
            return FrictionEstimate(nan, nan, nan, nan, nan, nan, nan, nan, 0.0, 0.0, 0.0, n,
                                    "too few samples, or a term that never varied", "")
        theta, rss, inv = solution
        reason = sigma_reason = ""
        logs = [math.log(r) for r in self.ratios]
        log_a = logs[best]
        var_log_a = nan
        variance = self._kappa * rss / max(n - 4.0, 1.0)
        lower, upper = ((solutions[best - 1], solutions[best + 1])
                        if 0 < best < len(self.ratios) - 1 else (None, None))
        if lower is not None and upper is not None:
            c0, c1, c2 = costs[best - 1], costs[best], costs[best + 1]
            step = logs[best + 1] - logs[best]
            # rss(l) = c1 + B (l - l_best) + curv (l - l_best)^2 through the three points
            curv = (c0 - 2.0 * c1 + c2) / (2.0 * step * step)
            if curv > 0.0:
                shift = max(-step, min(step, (c0 - c2) / (4.0 * curv * step)))
                log_a += shift
                var_log_a = variance / curv
                # the linear parameters at the interpolated ratio (quadratic in log a)
                t0, t2 = lower[0], upper[0]
                u = shift / step
                theta = theta + 0.5 * u * (t2 - t0) + 0.5 * u * u * (t2 - 2.0 * theta + t0)
            else:
                sigma_reason = FLAT_MISFIT
        else:
            sigma_reason = (f"the best sigma/F_c is on the edge of the searched range "
                            f"{self.ratios[0]:.4g}..{self.ratios[-1]:.4g} /rad: sigma not "
                            "identified")
        sd = np.sqrt(np.abs(np.diag(inv)) * variance)
        be, ke, fc = float(theta[0]), float(theta[1]), float(theta[3])
        # -F_p,read = ... + k_e (X_e - p0) + c with F_p,read = F_p + o: o = k_e (p0 - rest) - c
        lever = self._p0 - self._rest
        offset = ke * lever - float(theta[2])
        weights = np.array([0.0, lever, -1.0, 0.0])
        offset_sd = math.sqrt(max(float(weights @ inv @ weights), 0.0) * variance)
        exc = [math.sqrt(1.0 / (n * inv[i, i])) if inv[i, i] > 0.0 else 0.0 for i in (0, 1, 3)]
        if not fc > 3.0 * sd[3]:
            reason = (f"the fitted F_c = {fc:.3g} +- {sd[3]:.2g} N m is not positive by 3 "
                      "sigma: no hysteresis seen")
        elif not (be >= 0.0 and ke >= 0.0):
            reason = (f"the fit gives b_e = {be:.3g}, k_e = {ke:.3g}: negative friction, the "
                      "motion does not tell the terms apart")
        sigma = math.exp(log_a) * fc
        sigma_sd = (sigma * math.sqrt(var_log_a + (sd[3] / fc) ** 2)
                    if math.isfinite(var_log_a) and fc > 0.0 else nan)
        return FrictionEstimate(be, ke, fc, sigma, float(sd[0]), float(sd[1]), float(sd[3]),
                                sigma_sd, exc[0], exc[1], exc[2], n, reason, sigma_reason,
                                offset, offset_sd)


def ratio_grid(center: float, span: float = RATIO_SPAN,
               per_decade: int = RATIOS_PER_DECADE) -> list[float]:
    """Log-spaced sigma/F_c candidates [1/rad] from ``center/span`` to ``center*span``."""
    half = int(round(per_decade * math.log10(span)))
    return [center * 10.0 ** (i / per_decade) for i in range(-half, half + 1)]


# --- the calibration (action) ----------------------------------------------------------------
class CalibrationGoal:
    """The fields of a ``seaforce_msgs/action/CalibrateFriction`` goal.

    Parameters
    ----------
    channel : str
    amplitude : float > 0
        A of the motion [rad].
    speed : float > 0
        Peak speed A w [rad/s].
    apply : bool
        Apply the new values when the fit identifies them.
    """

    __slots__ = ("channel", "amplitude", "speed", "apply")

    def __init__(self, channel: str, amplitude: float, speed: float, apply: bool = True) -> None:
        self.channel = channel
        self.amplitude = amplitude
        self.speed = speed
        self.apply = apply

    def __repr__(self) -> str:
        return (f"CalibrationGoal(channel={self.channel!r}, amplitude={self.amplitude!r}, "
                f"speed={self.speed!r}, apply={self.apply!r})")


def check_calibration_goal(goal: CalibrationGoal, params: FrictionParams,
                           position: float | None = None) -> None:
    """Raise :class:`InvalidCalibrationError` naming the field and bound if ``goal`` cannot run
    with these :class:`FrictionParams` from the endpoint ``position`` [rad] (None: not
    known yet; the calibration re-checks it when it starts)."""
    if not isinstance(params, FrictionParams):
        raise TypeError("params must be FrictionParams")
    for name in ("amplitude", "speed"):
        value = getattr(goal, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not (math.isfinite(value) and value > 0.0):
            raise InvalidCalibrationError(f"{name} = {value!r}: must be a finite number > 0")
    if not isinstance(goal.apply, bool):
        raise InvalidCalibrationError(f"apply = {goal.apply!r}: must be a bool")
    if goal.speed > params.max_speed:
        raise InvalidCalibrationError(f"speed = {goal.speed!r} rad/s: must be <= "
                                      f"friction.max_speed = {params.max_speed:g} rad/s")
    half = 0.5 * (params.position_max - params.position_min)
    if goal.amplitude > half:
        raise InvalidCalibrationError(
            f"amplitude = {goal.amplitude!r} rad: the joint range friction.position_min.."
            f"position_max = {params.position_min:g}..{params.position_max:g} rad allows "
            f"at most {half:g} rad")
    if position is not None:
        _check_range(goal.amplitude, position, params)
    period = 2.0 * math.pi * goal.amplitude / goal.speed
    if params.calibration_duration < 3.0 * period:
        raise InvalidCalibrationError(
            f"speed = {goal.speed!r} rad/s with amplitude = {goal.amplitude!r} rad: a period of "
            f"{period:.3g} s, more than a third of friction.calibration_duration = "
            f"{params.calibration_duration:g} s (the contact test needs a whole period at "
            "full amplitude between the fades)")


def _check_range(amplitude: float, position: float, params: FrictionParams) -> None:
    if not math.isfinite(position) or position - amplitude < params.position_min \
            or position + amplitude > params.position_max:
        raise InvalidCalibrationError(
            f"the motion {position:.4g} +- {amplitude:.4g} rad leaves the joint range "
            f"friction.position_min..position_max = {params.position_min:g}.."
            f"{params.position_max:g} rad")


class FrictionCalibration(Job):
    """One calibration goal on one channel (see module docstring): a job whose output is the
    motor torque F_a [N m].

    Parameters
    ----------
    goal : CalibrationGoal
        Already checked (:func:`check_calibration_goal`).
    config : ControllerConfig
        The channel's: model, hold gains, ``friction`` and ``estimator.filter_cutoff``.
    dt : float > 0
        Sample period [s].

    Attributes
    ----------
    phase : str
        One of :data:`CALIBRATION_PHASES`.
    outcome : str or None
        None until done, then ``'succeeded'``, ``'canceled'`` or ``'aborted'``.
    message : str
    progress : float
        0..1.
    old : FrictionEstimate
        The model's values when the goal was made (1-sigma NaN).
    new : FrictionEstimate or None
        The fit, when done.
    applied : bool
        The controller applied ``new``.
    """

    kind = "friction calibration"
    output = TORQUE

    def __init__(self, goal: CalibrationGoal, config: ControllerConfig,
                 dt: float = 5e-4) -> None:
        super().__init__()
        self.goal = goal
        self.config = config
        self.dt = float(dt)
        fp = config.friction
        self.params = fp
        p, d = config.plant, config.dahl
        nan = math.nan
        self.old = FrictionEstimate(p.endpoint_damping, p.endpoint_stiffness, d.coulomb_force,
                                    d.sigma, nan, nan, nan, nan, 0.0, 0.0, 0.0, 0.0, "", "",
                                    config.pressure_offset)
        center = d.sigma / d.coulomb_force if d.sigma > 0.0 else 400.0
        self.fit = FrictionFit(p, d.exponent, ratio_grid(center), self.dt,
                               config.estimator.filter_cutoff, stroke=stroke_terms(config),
                               rest=config.feedforward.rest_position)
        self._limit = min(fp.torque_limit, config.max_torque)
        self._kp, self._kd = config.hold.stiffness, config.hold.damping
        self._amp = float(goal.amplitude)
        self._w = goal.speed / goal.amplitude
        self._duration = fp.calibration_duration
        self._period = 2.0 * math.pi / self._w
        self._fade = min(self._period, self._duration / 3.0)
        self.contact_test = SidedStiffness(CONTACT_STIFFNESS, CONTACT_RATIO, CONTACT_MOTION)
        self._judge_at = math.inf
        self.phase = "move"
        self.outcome = None
        self.message = "waiting for the control cycle"
        self.progress = 0.0
        self.new: FrictionEstimate | None = None
        self.applied = False
        self._t = 0.0
        self._x0: float | None = None
        self._bias = 0.0
        self._solutions: list[Solution] = []
        self._hold = False
        self._cancel: str | None = None

    # --- requests (the rest is the job's: :class:`~.jobs.Job`) -----------------------------
    def request_cancel(self, reason: str = "canceled") -> None:
        """(any thread) End at the next sample, canceled; nothing is applied. (A
        ``request_abort`` ends it aborted the same way.)"""
        self._cancel = reason

    def reenter(self) -> None:
        """(cycle thread) The plant applies something else than our torque this sample (a
        command timeout): the reference does not advance at the next update, so that the
        finger the plant let coast is not left behind by a moving reference."""
        self._hold = True

    def abort_now(self, reason: str) -> None:
        """End at once, commanding nothing more (the cycle zeroed the torque)."""
        if self.phase != "done":
            self._finish("aborted", reason)

    def final_config(self, config: ControllerConfig) -> ControllerConfig | None:
        """``config`` with the new values when the calibration succeeded and the goal asks to
        apply them (then :attr:`applied`), else None."""
        if self.outcome != "succeeded" or not self.goal.apply or self.new is None:
            return None
        applied = with_friction(config, self.new)
        self.applied = True
        return applied

    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        """``phase`` and ``progress`` (0..1)."""
        return {"phase": self.phase, "progress": self.progress}

    # --- per sample --------------------------------------------------------------------------
    def reference(self, t: float) -> tuple[float, float]:
        """(X_ref - x_0 [rad], dX_ref/dt [rad/s]) at ``t`` [s] since the start."""
        return faded_sine(t, self._amp, self._w, self._fade, self._duration)

    def step(self, sample: JobSample) -> float:
        """(cycle thread) :meth:`update` on the channel's sample: F_a [N m]."""
        return self.update(sample.x, sample.v, sample.endpoint_position, sample.dahl_input,
                           sample.f_p, sample.torque, sample.steps)

    def update(self, x: float, v: float, xe: float, xd: float, fp: float, u_prev: float,
               steps: int = 1) -> float:
        """One sample: motor X [rad], V [rad/s], X_e_hat [rad], the Dahl input [rad], F_p [N m],
        the last torque [N m]; returns F_a [N m], ``|F_a| <= min(friction.torque_limit,
        max_torque)`` (0.0 once done)."""
        if self.phase == "done":
            return 0.0
        if not all(isinstance(a, (int, float)) and math.isfinite(a)
                   for a in (x, v, xe, xd, fp, u_prev)):
            self._finish("aborted", "non-finite input: zero torque")
            return 0.0
        kp, kd = self._kp, self._kd
        if self._x0 is None:
            try:
                _check_range(self._amp, xe, self.params)
            except InvalidCalibrationError as exc:
                self._finish("aborted", str(exc))
                return 0.0
            self._x0 = x
            self._bias = max(-self._limit, min(self._limit, u_prev)) + kd * v
            self.message = "moving"
            self.fit.reset()
            self.contact_test.reset(x)
            self._judge_at = self._fade + self._period
        t = self._t
        r, rd = self.reference(t) if self.phase == "move" else (0.0, 0.0)
        error = self._x0 + r - x
        if abs(error) > self.params.max_tracking_error:
            self._finish("aborted", f"tracking error {error:.3g} rad beyond "
                                    f"friction.max_tracking_error = "
                                    f"{self.params.max_tracking_error:g} rad: the finger is "
                                    "blocked (not free), nothing applied")
            return 0.0
        lo, hi = self.params.position_min, self.params.position_max
        if not lo <= xe <= hi:
            self._finish("aborted", f"the endpoint at {xe:.4g} rad left the joint range "
                                    f"{lo:g}..{hi:g} rad, nothing applied")
            return 0.0
        u = self._bias + kp * error + kd * (rd - v)
        u = max(-self._limit, min(self._limit, u))
        if self._abort_request is not None:
            self._finish("aborted", self._abort_request + ", nothing applied")
            return u
        if self._cancel is not None:
            self._finish("canceled", self._cancel + ", nothing applied")
            return u
        if self.phase == "move":
            if self._fade <= t <= self._duration - self._fade:
                reason = self._contact(x, fp, t)
                if reason:
                    self._finish("aborted", reason)
                    return 0.0
            self.fit.update(xe, xd, fp, record=t >= self._fade, steps=steps)
            if self._hold:
                self._hold = False
            else:
                self._t = t + self.dt * steps
            self.progress = 0.9 * min(1.0, self._t / self._duration)
            if self._t >= self._duration:
                self.fit.fold()
                self.phase = "solve"
                self.message = "solving"
        else:
            k = len(self._solutions)
            self._solutions.append(self.fit.solve_candidate(k))
            self.progress = 0.9 + 0.1 * len(self._solutions) / len(self.fit.ratios)
            if len(self._solutions) == len(self.fit.ratios):
                self._conclude()
        return u

    def _contact(self, x: float, fp: float, t: float) -> str:
        """The model-free contact test (:mod:`.sided`) at full amplitude, judged at every whole
        period: the reason to abort, or ''."""
        test = self.contact_test
        test.update(x, fp)
        if t < self._judge_at:
            return ""
        self._judge_at += self._period
        if test.judge() <= 1.0:
            return ""
        side = "above" if test.upper > test.lower else "below"
        return (f"contact {side} the motion's centre {test.x0:.4g} rad: the pressure force's "
                f"apparent stiffness is {test.upper:.3g} N m/rad above it and "
                f"{test.lower:.3g} below (a free finger's is the same both sides): something "
                "is in reach of the finger, nothing applied")

    def _conclude(self) -> None:
        new = self.fit.estimate(self._solutions)
        # the fit saw F_p less the offset in force: what it finds of an offset adds to it
        offset = self.old.pressure_offset + new.pressure_offset
        if not abs(offset) <= OFFSET_LIMIT:        # (NaN too: then not identified)
            offset = new_sigma = math.nan
        else:
            new_sigma = new.pressure_offset_sigma
        new = self.new = new._replace(pressure_offset=offset, pressure_offset_sigma=new_sigma)
        self.progress = 1.0
        implausible = _implausible(new, self.old, self.params.plausible_ratio)
        if new.reason or new.sigma_reason:
            self._finish("aborted", f"not identified: {new.reason or new.sigma_reason}; "
                                    "nothing applied")
        elif implausible:
            self._finish("aborted", f"implausible: {implausible} (friction.plausible_ratio = "
                                    f"{self.params.plausible_ratio:g}): was the finger free? "
                                    "Nothing applied")
        else:
            self._finish("succeeded", "identified" + ("" if self.goal.apply else
                                                      " (not applied: apply is false)"))


def _implausible(new: FrictionEstimate, old: FrictionEstimate, ratio: float) -> str:
    """Which of b_e, k_e, F_c, sigma left ``[old/ratio, old ratio]``, in words, or ''."""
    out = []
    for name, a, b in (("b_e", new.endpoint_damping, old.endpoint_damping),
                       ("k_e", new.endpoint_stiffness, old.endpoint_stiffness),
                       ("F_c", new.coulomb_force, old.coulomb_force),
                       ("sigma", new.sigma, old.sigma)):
        if b > 0.0 and not b / ratio <= a <= b * ratio:
            out.append(f"{name} {a:.4g} against {b:.4g} ({100.0 * (a / b - 1.0):+.0f} %)")
    return ", ".join(out)


def with_friction(config: ControllerConfig,
                  values: FrictionEstimate | Sequence[float]) -> ControllerConfig:
    """``config`` with b_e, k_e, F_c, sigma replaced by ``values`` (a
    :class:`FrictionEstimate` -- its pressure offset too, where identified -- or a ``(b_e,
    k_e, F_c, sigma)`` tuple), validated."""
    be, ke, fc, sigma = tuple(values)[:4]
    if isinstance(values, FrictionEstimate) and math.isfinite(values.pressure_offset):
        config = config.replace(pressure_offset=float(values.pressure_offset))
    return config.replace(
        plant=dataclasses.replace(config.plant, endpoint_damping=float(be),
                                  endpoint_stiffness=float(ke)),
        dahl=dataclasses.replace(config.dahl, coulomb_force=float(fc), sigma=float(sigma)))


# --- online adaptation ---------------------------------------------------------------------
class FrictionAdaptation:
    """Slow online adaptation of b_e, k_e, F_c, sigma while the finger is free (module
    docstring).

    Parameters
    ----------
    config : ControllerConfig
        The configured values (centre of the bounds) and ``friction`` settings.
    dt : float > 0

    Attributes
    ----------
    values : (b_e, k_e, F_c, sigma)
        The adapted values (start: the configured ones), always within :attr:`bounds`.
    bounds : tuple of (low, high)
    adapting : bool
        The last block moved the values.
    reason : str
        Why not, when it did not.
    updates : int
        Blocks that moved the values.
    """

    def __init__(self, config: ControllerConfig, dt: float = 5e-4) -> None:
        self.dt = float(dt)
        self.configure(config)

    def configure(self, config: ControllerConfig) -> None:
        """New configured values and settings: the adaptation restarts from them."""
        fp = config.friction
        self.params = fp
        p, d = config.plant, config.dahl
        self._plant, self._exponent = p, d.exponent
        self._stroke = stroke_terms(config)
        self._cutoff = config.estimator.filter_cutoff
        r = 1.0 + fp.adaptation_bound
        nominal = (p.endpoint_damping, p.endpoint_stiffness, d.coulomb_force, d.sigma)
        self.bounds = tuple((v / r, v * r) for v in nominal)
        self.values = nominal
        self._rate = min(1.0, BLOCK * self.dt / fp.adaptation_time)
        self._center = d.sigma / d.coulomb_force if d.sigma > 0.0 else 0.0
        self.adapting = False
        self.reason = "no free motion yet"
        self.updates = 0
        self._new_fit(0.0)

    def _new_fit(self, force: float) -> None:
        c = self._center
        ratios = [c / ADAPTATION_STEP, c, c * ADAPTATION_STEP] if c > 0.0 else [1.0]
        self.fit = FrictionFit(self._plant, self._exponent, ratios, self.dt, self._cutoff,
                               self.params.adaptation_time, self._stroke)
        self.fit.reset(force)
        self._settle = 0
        self._solving: list[Solution] | None = None   # candidates solved since the last fold

    def update(self, xe: float, xd: float, fp: float, free: bool, dahl_force: float,
               steps: int = 1) -> bool:
        """One sample (X_e_hat, the Dahl input, F_p; ``free``: the contact estimator sees no
        contact; ``dahl_force``: the feed-forward's F_d). Returns True when the values moved."""
        fit = self.fit
        self._settle = self._settle + steps if free else 0
        if not fit.started:
            fc = self.values[2]
            fit.reset(dahl_force / fc if fc > 0.0 else 0.0)
        folds = fit.folds
        fit.update(xe, xd, fp, record=free and self._settle > SETTLE_SAMPLES, steps=steps)
        solving = self._solving
        if solving is not None:
            # one candidate's normal equations per sample (bounded cost per cycle)
            solving.append(fit.solve_candidate(len(solving)))
            if len(solving) < len(fit.ratios):
                return False
            self._solving = None
            return self._step(solving)
        if fit.folds != folds:
            if len(fit.ratios) < 3:
                self.reason = "sigma = 0: no hysteresis model to adapt"
            else:
                self._solving = []
        return False

    def _step(self, solutions: Sequence[Solution]) -> bool:
        fit = self.fit
        est = fit.estimate(solutions)
        fp = self.params
        low = []
        if not est.velocity_excitation >= fp.min_velocity_excitation:
            low.append(f"velocity {est.velocity_excitation:.3g} < "
                       f"{fp.min_velocity_excitation:g} rad/s")
        if not est.position_excitation >= fp.min_position_excitation:
            low.append(f"motion {est.position_excitation:.3g} < "
                       f"{fp.min_position_excitation:g} rad")
        if not est.dahl_excitation >= MIN_DAHL_EXCITATION:
            low.append(f"reversals {est.dahl_excitation:.3g} < {MIN_DAHL_EXCITATION:g}")
        if low:
            self.adapting = False
            self.reason = "excitation too low: " + ", ".join(low)
            return False
        if est.reason or not all(math.isfinite(v) for v in est[:4]):
            self.adapting = False
            self.reason = est.reason or "no estimate"
            return False
        # a ratio on the edge of the three moves the centre that way (the step is bounded by
        # the rate); a flat misfit leaves sigma
        target = (est.endpoint_damping, est.endpoint_stiffness, est.coulomb_force,
                  self.values[3] if est.sigma_reason == FLAT_MISFIT else est.sigma)
        rate = self._rate
        moved = []
        for v, t, (lo, hi) in zip(self.values, target, self.bounds):
            nv = v + rate * (t - v)
            moved.append(min(hi, max(lo, nv)))
        self.values = tuple(moved)
        self.adapting = True
        self.reason = ""
        self.updates += 1
        ratio = self.values[3] / self.values[2]
        if abs(math.log(ratio / self._center)) > 0.5 * math.log(ADAPTATION_STEP):
            self._center = ratio
            self._new_fit(fit.dahl_states[1])
        return True

"""Per-channel controller: DOB + endpoint friction feed-forward (paper III-IV).

Inputs per sample: motor position X [rad], motor velocity V [rad/s], pressure force F_p
[N m]. Output: motor torque F_a [N m].

:class:`ChannelController` composes small parts with explicit state and runs them in named
stages per sample (:meth:`ChannelController.update`):

1. **hand-overs** -- a new configuration (:meth:`~ChannelController.configure`) and the jobs
   requested (:meth:`~ChannelController.request_job`) are taken at the start of a sample,
   never within one;
2. **observe** -- the endpoint observer (:mod:`.observer`): the hose inversion gives X_e_hat
   and V_e_hat (eq. 29), the Dahl play and state F_d (eq. 14), the feed-forward F_cmp (eq. 29);
3. **estimate** -- the contact estimator (:mod:`.estimator`) runs in every mode on X_e_hat,
   F_p and F_d; outside a job a contact that stands with the finger still for
   :data:`~.estimator.STANDING_TIME` is the model's error at rest (re-armed);
4. **job or adaptation** -- a job (:mod:`.jobs`, one at a time per channel, a second one is
   refused as busy) overrides the mode while it runs. A :data:`~.jobs.TORQUE` job (a friction
   calibration, :mod:`.friction_calibration`) commands F_a itself and the stages below pause;
   an :data:`~.jobs.ENDPOINT_FORCE` job (a grasp, :mod:`.grasp`: ``F_j = F_g``) runs the DOB
   with ``F_ref = F_cmp + F_d + F_j`` (minimum impedance plus the job's endpoint force; the
   model's friction in full: a grasp closes its own loop around the endpoint). When a
   job is done the channel enters its mode again, bumplessly from the torque then, with the
   configuration the job leaves (a calibration's new friction; a grasp's release has ramped
   F_g to zero, the grip is not carried over into ``hold``). Selecting ``passive`` ends a job
   at once; selecting another mode ends it too, gently where the job can
   (:meth:`~.jobs.Job.wind_down`) -- and so does selecting the mode the channel has (a
   ``configure`` with ``mode_set``: the job overrides the mode, so setting the mode asks for
   it). With ``friction.adaptation`` the feed-forward's b_e, k_e,
   F_c, sigma follow the friction fit slowly while the estimator sees no contact
   (``dob_linear_ff``, ``dob_full_ff``, ``impedance``, and a grasp's approach);
5. **monitor** -- wherever the DOB runs (the reference modes, a grasp) the runaway monitor
   (:mod:`.safety`) watches the finger's speed and the energy the walls take out of it, and
   outside a job the settling watch a finger that never comes to rest (kept moving in a
   feed-forward mode, or held on a wall); a trip ends a job and falls back, in this sample,
   to ``monitor.fallback`` until :meth:`~ChannelController.clear_fallback` (``~/reset``);
6. **mode and walls** -- the mode (:mod:`.modes`, keyed by name) commands F_a itself
   (passive, hold, force_feedback, chirp) or gives the DOB's reference F_ref (dob,
   dob_linear_ff, dob_full_ff, impedance, force); the joint walls' force (:mod:`.safety`) is
   added to either in every mode but ``passive`` (and to a job's), and :attr:`beyond` says
   when the finger is beyond the joint range (the cycle latches ``joint_limit``);
7. **guard** -- the passivity guard (:mod:`.passivity_guard`, ``passivity_guard`` not
   ``disabled``) watches the DOB's port ``(F_p + F_ref, V)`` whenever the DOB runs; when
   ``active`` its damping force is added to F_ref (the port impedance becomes Z + alpha). It
   restarts (full reserve, no damping) at every mode entry, so entries stay bumpless; a
   parameter set within the mode keeps its ledger;
8. **DOB** -- the disturbance observer (:mod:`.dob`, eq. 19, bumpless entry): F_a and the
   disturbance estimate ``d_hat = F_a - F_ref``;
9. **output** -- ``torque`` and ``disturbance`` are set and F_a returned.

Bumpless transfer: every mode entry (or ``configure``) initialises the new mode's state from
the last output so that the first output equals it; :meth:`ChannelController.reset` and
:meth:`ChannelController.reenter` start from a torque the plant reports as applied.

The controller computes; it does not judge. Input validation (finite, plausible, fresh), the
``max_torque`` fault limit and fault latching live in :class:`~.control_cycle.ControlCycle`,
which calls :meth:`~ChannelController.update` only with checked inputs. A non-finite input
still raises :class:`~.errors.NonFiniteInputError` (nothing is latched).

The hot path uses Python floats only (no numpy, no allocation beyond float boxing, no
logging); a disabled guard or adaptation costs one test per sample, and so do the walls clear
of the finger and a calm runaway monitor (their updates, which would change nothing, are
skipped, in every mode). Its classes have slots: an instance with more than 30 attributes in a
dict would make every attribute access a hashed look-up (CPython 3.11). :meth:`update` writes
the DOB's step and dob_full_ff's reference out (a Python call costs about 0.45k of the 24k
machine instructions of a dob_full_ff update, counted with valgrind), and decides with
comparisons in an ``if``: a float comparison whose result goes to a variable is not
specialised (the walls' skip cost 0.45k more that way). ``bench/core_sim_speed.py --stages``
says where the time goes; test/core/test_per_sample_exact.py holds every float to the code
before these speed-ups.
"""

from __future__ import annotations

import math

from .dob import DisturbanceObserver
from .errors import NonFiniteInputError
from .estimator import REST_SPEED, STANDING_TIME, ContactEstimator
from .friction_calibration import FrictionAdaptation
from .grasp import Grasp
from .handover import Mailbox
from .jobs import TORQUE, Job, JobSample, busy_reason
from .modes import (MODE_TYPES, Dob, DobFullFeedforward, Mode, Passive, ReferenceMode,
                    TorqueMode)
from .observer import EndpointObserver
from .params import ControllerConfig, DahlParams
from .passivity_guard import PassivityGuard
from .safety import JointWalls, RunawayMonitor, SettlingWatch

__all__ = ["ChannelController"]

_ENTER, _REENTER = 2, 1   # pending entry into the mode: full (targets captured) / re-entry
_STILL_LOW = -REST_SPEED  # (a constant: negated per sample it would be a new float)
_NAN = math.nan
_isfinite = math.isfinite


def _non_finite(x: float, v: float, f_p: float) -> NonFiniteInputError:
    """The error naming the first non-finite input."""
    name, value = next((n, val) for n, val in (("x", x), ("v", v), ("f_p", f_p))
                       if not _isfinite(val))
    return NonFiniteInputError(name, value)


class ChannelController:
    """Controller of one channel (module docstring).

    Parameters
    ----------
    config : ControllerConfig
    dt : float > 0
        Sample period [s] (default 5e-4, 2 kHz).

    Attributes (updated by every :meth:`update`)
    ----------------------------------------------
    mode : str
        Active mode.
    torque : float
        Last output F_a [N m].
    disturbance : float
        DOB disturbance estimate ``d_hat = F_a - F_ref`` [N m] (NaN outside the DOB modes).
    pressure_offset : float
        The pressure sensor's offset [N m] subtracted from every F_p (``pressure_offset``).
    feedforward : float
        ``F_cmp + F_d`` [N m] (computed in every mode).
    endpoint_velocity_estimate : float
        V_e_hat [rad/s].
    endpoint_position_estimate : float
        X_e_hat [rad].
    dahl_force : float
        F_d [N m].
    observer : EndpointObserver
        The hose inversion, Dahl state and feed-forward behind the four above.
    estimator : ContactEstimator
        Contact and object estimates (updated in every mode).
    adaptation : FrictionAdaptation
        The online friction adaptation (runs with ``friction.adaptation``).
    job : Job or None
        The job that overrides the mode (a grasp, a friction calibration), while it runs.
    passivity_guard : PassivityGuard or None
        The time-domain passivity guard of the DOB's motor port (None when disabled); it runs
        while the DOB does (the DOB modes and a grasp) and restarts at every mode entry.
    walls : JointWalls
        The joint walls (their ``force`` this sample).
    monitor : RunawayMonitor
        The runaway monitor.
    settling : SettlingWatch
        The watch for a finger that never comes to rest (in the DOB modes, outside a job).
    fallback : str
        The mode the monitor fell back to ('' when none), latched until
        :meth:`clear_fallback`; ``fallback_reason`` says why.
    tripped : str
        Set on the sample the monitor trips (the cycle reports and clears it).
    beyond : str
        Why the finger is beyond the joint range in a mode that commands torque, or ''.

    Attributes the caller sets before :meth:`update` (passed on to a job's
    :class:`~.jobs.JobSample`; :class:`~.control_cycle.ControlCycle` sets them)
    ----------------------------------------------------------------------------------------
    cycle : int
        The state's cycle number (-1: not given).
    applied : float
        The torque the plant reports it applied in this sample [N m] (NaN: not given).
    reference_offset : float
        A force [N m] added to the DOB's reference F_ref in the modes that run it (0: none;
        commissioning's verification pulses a free finger with it).
    """

    # slots (module docstring)
    __slots__ = (
        "dt", "cycle", "applied", "mode", "torque", "disturbance", "pressure_offset",
        "reference_offset",
        # hand-overs and the job
        "_pending", "_mode_sets", "_jobs", "job", "_job_sample",
        # the parts
        "observer", "estimator", "adaptation", "walls", "monitor", "settling", "passivity_guard",
        "_dob",
        "_modes", "_config",
        # the mode in force and its entry
        "_torque_mode", "_reference_mode", "_reads_feedforward", "_uses_feedforward", "_walled",
        "_adapting", "_entry",
        # the walls, the monitor's fall-back, a standing contact
        "_wall", "beyond", "fallback", "fallback_reason", "tripped", "_still", "_standing")

    def __init__(self, config: ControllerConfig | None = None, dt: float = 5e-4) -> None:
        if config is None:
            config = ControllerConfig()
        if not isinstance(config, ControllerConfig):
            raise TypeError("config must be a ControllerConfig")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt = {dt!r} must be > 0 and finite")
        self.dt = float(dt)
        self.cycle = -1
        self.applied = _NAN
        self.reference_offset = 0.0
        self._pending: Mailbox[ControllerConfig] = Mailbox()
        self._mode_sets: Mailbox[bool] = Mailbox()        # ... the mode was set with it
        self._jobs: Mailbox[Job] = Mailbox(size=None)     # every job requested, in order
        self.job: Job | None = None
        self.passivity_guard: PassivityGuard | None = None
        self.mode = config.mode
        self.observer = EndpointObserver(config.plant, config.feedforward, config.dahl,
                                         self.dt, config.plant_terms)
        self._dob = DisturbanceObserver(config.dob, self.dt)
        self._modes: dict[str, Mode] = {name: cls(config, self.dt)
                                        for name, cls in MODE_TYPES.items()}
        self.estimator = ContactEstimator(config.estimator, config.plant, self.dt,
                                          config.feedforward.rest_position,
                                          config.plant_terms)
        self._job_sample = JobSample(self.estimator)
        self.adaptation = FrictionAdaptation(config, self.dt)
        self.walls = JointWalls(config.limits, config.max_torque)
        self.monitor = RunawayMonitor(config.monitor, self.dt)
        self.settling = SettlingWatch(config.monitor, self.dt)
        self.fallback = self.fallback_reason = self.tripped = self.beyond = ""
        self._wall = 0.0
        self._still = 0                 # samples a contact has stood with the finger still
        self._standing = max(1, int(round(STANDING_TIME / self.dt)))
        self._apply_config(config)
        self.reset()

    # --- configuration ----------------------------------------------------------------------
    def configure(self, config: ControllerConfig, mode_set: bool = False) -> None:
        """Queue a new (already validated) config; it takes effect at the start of the next
        :meth:`update`, bumplessly. ``mode_set``: its mode was set (``<channel>.mode``), even
        to the one in force -- a running job ends as at a change of mode."""
        if not isinstance(config, ControllerConfig):
            raise TypeError("config must be a ControllerConfig")
        config.validate()
        if mode_set:
            self._mode_sets.put(True)       # before the config: taken with it, or earlier
        self._pending.put(config)

    @property
    def config(self) -> ControllerConfig:
        """The active configuration."""
        return self._config

    def _apply_config(self, c: ControllerConfig, mode_set: bool = False) -> None:
        job = self.job
        if job is not None and (c.mode != self.mode or mode_set):
            # passive: off at once; another mode: a job that can end gently does
            reason = f"mode set to {c.mode}"
            if c.mode == "passive" or not job.wind_down(reason):
                self._end_job(reason)
        self.adaptation.configure(c)
        self._set_offset(c.pressure_offset)
        self._config = c
        self.mode = c.mode
        for m in self._modes.values():
            m.configure(c)
        self.walls.configure(c.limits, c.max_torque)
        self.monitor.configure(c.monitor)
        self.settling.configure(c.monitor)
        self._use_mode(c.mode)
        self._adapting = c.friction.adaptation
        self.observer.configure(c.plant, c.feedforward, c.dahl, c.plant_terms)
        self._dob.configure(c.dob)
        self.estimator.configure(c.estimator, c.plant, c.feedforward.rest_position,
                                 c.plant_terms)
        self._configure_guard(c)

    def _set_offset(self, offset: float) -> None:
        """The pressure sensor's offset [N m] from the next sample on, bumplessly: the hose
        inversion and the contact estimator take the force they had seen as corrected already
        (a step in F_p would be a velocity spike of ``step / b_s`` in V_e_hat)."""
        change = offset - getattr(self, "pressure_offset", offset)
        self.pressure_offset = offset
        if change:
            self.observer.shift_pressure(-change)
            self.estimator.rearm()

    def _use_mode(self, name: str) -> None:
        """Run the mode ``name`` from now on -- or, while the runaway monitor's fall-back is
        latched and ``name`` runs the DOB, the fall-back (``dob`` or ``passive``)."""
        mode = self._modes[name]
        if self.fallback and isinstance(mode, ReferenceMode):
            mode = self._modes[self.fallback]
        self._torque_mode = mode if isinstance(mode, TorqueMode) else None
        self._reference_mode = mode if isinstance(mode, ReferenceMode) else None
        self._uses_feedforward = mode.uses_feedforward
        self._walled = not isinstance(mode, Passive)
        self._reads_feedforward = type(mode) is DobFullFeedforward     # F_ref = obs.feedforward

    def _select(self, c: ControllerConfig) -> bool:
        """Apply a configuration handed to :meth:`configure`. Its mode is selected anew -- a
        chirp plays again, the targets are captured at the next sample -- when the mode
        changes or was set (``mode_set``, even to the one in force); True then. Otherwise the
        mode goes on with the new values: its targets (``hold``'s set point, ``impedance``'s
        rest position, the chirp's clock and offset) are kept. (Until 2026-12-06 every
        parameter set selected the mode anew: a set of ``hold.stiffness`` in ``chirp`` replayed
        a finished chirp, or restarted a running one from its torque of that instant, which
        stayed on after it; in ``impedance`` it moved the spring's rest to where the finger
        was pushed.)"""
        mode_set = bool(self._mode_sets.take())
        anew = mode_set or c.mode != self.mode
        self._apply_config(c, mode_set)
        if anew:
            self._modes[c.mode].select()
        return anew

    def _configure_guard(self, c: ControllerConfig) -> None:
        """The guard of ``c.passivity`` (None when disabled) on the DOB's port, whose apparent
        inertia is m_n; its force is bounded by ``max_torque``. A running guard is configured,
        not replaced: :meth:`update` restarts its ledger on a mode entry only (a restart on
        every parameter set would refill the reserve, and parameters set again and again
        would disarm it)."""
        guard = self.passivity_guard
        inertia = c.dob.nominal_inertia
        assert inertia is not None      # a ControllerConfig fills in the motor's
        if c.passivity.mode == "disabled":
            self.passivity_guard = None
        elif guard is None:
            self.passivity_guard = PassivityGuard(c.passivity, self.dt, inertia, c.max_torque)
        else:
            guard.configure(c.passivity, inertia, c.max_torque)

    def reset(self, applied_torque: float = 0.0,
              reason: str = "the controller was re-initialised") -> None:
        """Clear all state (filters, integrator, estimates); the next :meth:`update` starts
        afresh from that sample and enters the mode bumplessly from ``applied_torque``
        [N m], the torque the plant reports it applies (its first output equals it). A
        running job ends (aborted, with ``reason``)."""
        self._end_job(reason)
        pending = self._pending.take()
        if pending is not None:
            self._select(pending)
        self._modes[self.mode].interrupt()
        self.estimator.reset()
        if self.passivity_guard is not None:
            self.passivity_guard.reset()
        self.torque = float(applied_torque)
        self._wall = 0.0
        self.disturbance = _NAN
        self.monitor.reset()
        self.observer.reset()
        self._dob.reset()
        for m in self._modes.values():
            m.reset()
        self._entry = _ENTER

    def reenter(self, applied_torque: float) -> None:
        """Continue the mode at the next :meth:`update` from ``applied_torque`` [N m]: the
        plant zeroed or replaced the torque for a moment (a command timeout). The estimators
        (hose inversion, Dahl state) and the mode's targets are kept (the contact estimator
        goes quiet: :meth:`~.estimator.ContactEstimator.disturb`); the next output equals
        ``applied_torque``. The DOB integrator starts from it (no windup) and returns to its
        equilibrium within ~1/lambda; ``hold`` returns to its target through a transfer
        offset that decays in 50 ms: no step, and a finger under load is not pushed away a
        little more at every blip. After a longer interruption use :meth:`reset`, which
        re-captures the targets where the finger is. A running job is told
        (:meth:`~.jobs.Job.reenter`: a friction calibration's reference waits for that
        sample)."""
        self._modes[self.mode].interrupt()
        self.estimator.disturb()        # a torque its model did not see
        self.torque = float(applied_torque)
        if self._entry != _ENTER:
            self._entry = _REENTER
        if self.job is not None:
            self.job.reenter()

    # --- status read from outside -------------------------------------------------------------
    @property
    def endpoint_position_estimate(self) -> float:
        """X_e_hat [rad]."""
        return self.observer.position

    @property
    def endpoint_velocity_estimate(self) -> float:
        """V_e_hat [rad/s]."""
        return self.observer.velocity

    @property
    def dahl_force(self) -> float:
        """F_d [N m]."""
        return self.observer.dahl_force

    @property
    def feedforward(self) -> float:
        """``F_cmp + F_d`` [N m], with the margin (what the feed-forward modes add)."""
        return self.observer.feedforward

    @property
    def grasp_phase(self) -> str:
        """The running grasp's phase, or '' (``controller_status.grasp_phase``)."""
        job = self.job
        return job.phase if isinstance(job, Grasp) else ""

    # --- jobs (a grasp, a friction calibration: :mod:`.jobs`) -------------------------------
    def request_job(self, job: Job) -> None:
        """Start ``job`` (its goal already checked) at the start of the next :meth:`update`
        (any thread) unless it has been withdrawn by then; it enters bumplessly from the
        torque then. A job that arrives while another runs is refused: it ends aborted,
        "the channel is busy with ...". Cancel it with ``job.request_cancel``."""
        if not isinstance(job, Job):
            raise TypeError("job must be a Job (a Grasp, a FrictionCalibration)")
        self._jobs.put(job)

    def abort_job(self, reason: str) -> None:
        """End the running job now, commanding nothing more (the caller zeroes the torque: a
        fault, a stall). Same thread as :meth:`update`."""
        self._end_job(reason)

    # --- the runaway monitor's fall-back (:mod:`.safety`) ----------------------------------
    def _trip(self, reason: str) -> None:
        """The monitor tripped: end a running job, fall back (``monitor.fallback``; from the
        DOB without feed-forward on to ``passive``) and enter it in this sample."""
        target = self._config.monitor.fallback
        if self.job is not None:
            self._end_job("runaway monitor: " + reason)
        elif isinstance(self._reference_mode, Dob):
            target = "passive"
        self.fallback = target
        self.fallback_reason = reason
        self.tripped = f"{reason}: fell back to {target}"
        self._use_mode(self.mode)
        self._entry = _ENTER

    def clear_fallback(self) -> bool:
        """(cycle thread, ``~/reset``) Leave the fall-back: the configured mode is entered again,
        bumplessly, at the next :meth:`update`. Returns whether one was latched."""
        if not self.fallback:
            return False
        self.restore_fallback("", "")
        return True

    def restore_fallback(self, fallback: str, reason: str) -> None:
        """(cycle thread) Set the fall-back to ``fallback`` ('' for none) with ``reason``, as it
        was before a trip that does not count (the plant did not apply this controller's
        torque: :class:`~.control_cycle.ControlCycle` while the channel is faulted)."""
        self.fallback, self.fallback_reason, self.tripped = fallback, reason, ""
        self.monitor.reset()
        self._use_mode(self.mode)
        self._entry = _ENTER

    def _end_job(self, reason: str) -> None:
        job = self.job
        if job is not None:
            job.abort_now(reason)   # (a grasp keeps the object it measured: reset after this)
            self.job = None
            self._entry = _ENTER

    def _take_jobs(self) -> None:
        """Start the first job requested that was not withdrawn, if the channel is free;
        refuse the others."""
        while self._jobs:
            job = self._jobs.take()
            if job is None or not job.claim():
                continue                    # withdrawn before it started
            if self.job is not None:
                job.abort_now(busy_reason(job, self.job))
                continue
            if self.fallback and job.output != TORQUE:
                job.abort_now(f"the runaway monitor keeps the channel in {self.fallback} "
                              f"({self.fallback_reason}): call ~/reset first")
                continue
            self._modes[self.mode].interrupt()
            self.job = job
            self._entry = _ENTER
            self.estimator.stop_settling()      # (after a grasp's release)

    def _run_job(self, job: Job, x: float, v: float, f_p: float, steps: int) -> float:
        """One sample of the running ``job`` (X, V, F_p, steps): its output, which is the
        channel's torque for a :data:`~.jobs.TORQUE` job. A job that ends hands the channel
        back to its mode, from this torque, with the configuration it leaves
        (:meth:`~.jobs.Job.final_config`: a calibration's new friction)."""
        obs = self.observer
        sample = self._job_sample          # filled in place: no allocation per sample
        sample.x = x
        sample.v = v
        sample.f_p = f_p
        sample.dahl_input = obs.dahl_input
        sample.endpoint_position = obs.position
        sample.endpoint_velocity = obs.velocity
        sample.torque = self.torque - self._wall     # the job's own last output
        sample.steps = steps
        sample.cycle = self.cycle
        sample.applied = self.applied
        out = job.step(sample)
        if not job.active:
            self.job = None
            if job.output != TORQUE:
                # a grasp let go: once the finger rests, the residual there (the model's error
                # where it stopped) becomes the bias
                self.estimator.rearm_at_rest()
            config = job.final_config(self._config)
            if config is not None:
                self._apply_config(config)
            self._entry = _ENTER            # back to the mode, from this torque
        if job.output == TORQUE:
            self.disturbance = _NAN
            self.torque = out
        return out

    # --- friction adaptation ------------------------------------------------------------------
    def _adapt(self, f_p: float, steps: int) -> None:
        """One sample of the adaptation; new values go to the feed-forward from the next
        sample on."""
        obs = self.observer
        job = self.job
        estimator = self.estimator
        free = not (estimator.contact or estimator.quiet) and (
            job is None or job.free_motion)
        adaptation = self.adaptation
        if adaptation.update(obs.position, obs.dahl_input, f_p, free, obs.dahl_force, steps):
            be, ke, fc, sigma = adaptation.values
            obs.set_friction(be, ke, DahlParams(sigma=sigma, coulomb_force=fc,
                                                exponent=self._config.dahl.exponent))

    def _take_handovers(self) -> bool:
        """Stage 1: the newest configuration and the jobs requested. Returns whether the
        guard's ledger goes on (a parameter set within the mode, no job starting)."""
        keep_ledger = False
        pending = self._pending.take()
        if pending is not None:
            keep_ledger = pending.mode == self.mode and self._entry != _ENTER and \
                not (self.job is not None and self._mode_sets)
            if self._select(pending):
                self._entry = _ENTER
            elif self._entry != _ENTER:
                self._entry = _REENTER      # the new values taken up bumplessly, targets kept
        if self._jobs:
            keep_ledger = False
            self._take_jobs()
        return keep_ledger

    # --- per sample ---------------------------------------------------------------------------
    def update(self, x: float, v: float, f_p: float, steps: int = 1) -> float:
        """One sample: ``(X [rad], V [rad/s], F_p [N m]) -> F_a [N m]``.

        ``steps`` (int >= 1) is the number of sample periods since the previous update: a
        plant that lost or skipped samples (a late loop answers only the newest state) is
        integrated over the real elapsed time -- the hose inversion (first-order hold over
        ``steps * dt``), the DOB integrator, the force-feedback transfer decay and the chirp
        clock -- instead of one ``dt``, which would turn a pressure change over many samples
        into a huge velocity estimate and, repeated, destabilise the DOB.

        Raises
        ------
        NonFiniteInputError
            An input is NaN/inf (nothing changes; the caller decides).
        """
        if not (_isfinite(x) and _isfinite(v) and _isfinite(f_p)):
            raise _non_finite(x, v, f_p)
        # the hand-overs, then observe and estimate
        keep_ledger = False
        if self._pending or self._jobs:
            keep_ledger = self._take_handovers()
        f_p -= self.pressure_offset         # the force in the hose, as far as the sensor's known
        obs = self.observer
        obs.update(x, v, f_p, steps)
        est = self.estimator
        est.update(obs.position, f_p, obs.dahl_force, steps)

        # the job, or the friction adaptation
        job = self.job
        if job is None:
            if est.contact:
                if _STILL_LOW < est.velocity < REST_SPEED:
                    self._standing_contact(est, steps)
                else:
                    self._still = 0     # a contact that moves is no model error at rest
            if self._adapting and self._uses_feedforward:
                self._adapt(f_p, steps)
            mode = self._torque_mode        # (None: the DOB runs)
        elif job.output == TORQUE:
            u = self._run_job(job, x, v, f_p, steps)     # (sees the last sample's walls)
            u += self._walls(x, v, obs)
            self.torque = u
            return u
        else:
            if self._adapting:
                self._adapt(f_p, steps)
            mode = None

        # the runaway monitor, wherever the DOB runs: a trip falls back in this sample (calm
        # and V_e_hat within its limit, its update would change nothing: skipped)
        monitor = self.monitor
        if mode is None:
            ve = obs.velocity
            if not (monitor.calm and monitor.min_speed <= ve <= monitor.max_speed) and \
                    monitor.update(v, ve, steps):
                self._trip(monitor.reason)
                job = None
                mode = self._torque_mode
            elif job is None:
                watch = self.settling
                watch.due -= steps
                if watch.due <= 0 and watch.update(obs.position, self._wall,
                                                   self._uses_feedforward):
                    # (the walls' force of the last sample: this one's comes with the mode)
                    self._trip(watch.reason)
                    mode = self._torque_mode

        # the mode: F_a itself, or the DOB's reference; the walls add to either
        entry = self._entry
        guard = self.passivity_guard
        if entry:
            self._entry = 0
            if entry == _ENTER:
                self.settling.reset()
                if guard is not None and not keep_ledger:
                    guard.reset()   # a new port: the full reserve, no damping (bumpless)
        if job is not None:
            # the job's endpoint force on minimum impedance: a grasp closes its own loop
            # around the endpoint (a speed servo, then the object and the contact damping), so
            # it takes the model's friction in full, without the margin; the walls after it
            # (the job may have changed the configuration)
            f_ref = obs.model_feedforward() + self._run_job(job, x, v, f_p, steps)
            f_ref += self._walls(x, v, obs)
        else:
            walls = self.walls
            if walls.clear and not monitor.wall_work and walls.free_min <= x <= walls.free_max \
                    and walls.free_min <= obs.position <= walls.free_max:
                # clear of the walls at the last sample and now, the monitor's wall ledger
                # empty: _walls would find no force and change nothing, nor would _no_walls
                w = 0.0
            else:
                w = self._walls(x, v, obs) if self._walled else self._no_walls()
            if mode is not None:
                self.disturbance = _NAN
                # the mode's own part of the last torque: entries stay bumpless in the walls
                u = (mode.enter(x, v, f_p, steps, self.torque - w, entry == _ENTER) if entry
                     else mode.update(x, v, f_p, steps)) + w
                self.torque = u
                return u
            if entry != _ENTER and self._reads_feedforward:
                f_ref = obs.feedforward     # DobFullFeedforward.update without the call (0.4k)
            else:
                ref = self._reference_mode
                assert ref is not None
                f_ref = ref.enter(obs) if entry == _ENTER else ref.update(obs)
            # the walls once per sample (until 2026-12-05 a sample in them ran their update a
            # second time here: counted twice in the monitor's wall ledger, its grace after a
            # trip spent twice as fast)
            f_ref += w
            if self.reference_offset:
                f_ref += self.reference_offset      # (commissioning's verification pulses)

        # the guard: damping on the DOB's port (F_p + F_ref, V), Z -> Z + alpha
        if guard is not None:
            f_ref += guard.update(f_p + f_ref, x, v, steps)

        # the DOB, then the output
        dob = self._dob
        if entry:
            dob.enter(self.torque, f_ref, x, v, f_p, steps)
        if steps == 1:
            # DisturbanceObserver.update written out for one step: the same arithmetic without
            # the call (0.6k of the 25k instructions of a dob_full_ff update)
            e = f_ref + f_p - dob.kn * x
            ramp = dob.lam_mn * v + dob.lam_bn * x
            integ = dob.integral + dob.lam_half_dt * (e + dob.error)
            dob.error = e
            dob.integral = integ
            u = f_ref + integ - ramp
        else:
            u = dob.update(f_ref, x, v, f_p, steps)
        self.disturbance = u - f_ref
        self.torque = u
        return u

    def _standing_contact(self, est: ContactEstimator, steps: int) -> None:
        """Outside a job, a contact that stands with the finger still (:meth:`update` calls
        this while it is) for :data:`~.estimator.STANDING_TIME` is the model's error at rest:
        re-arm (a model 20 % off left a contact standing 3 s after 7 of 12 grasp releases in
        dob_full_ff, which the next grasp would see; with this 4 of 12 after 6 s, each a finger
        still touching or bouncing on the object)."""
        self._still += steps
        if self._still >= self._standing:
            self._still = 0
            est.rearm()

    def _walls(self, x: float, v: float, obs: EndpointObserver) -> float:
        """The walls' force this sample [N m] (:class:`~.safety.JointWalls`) and whether the
        finger is beyond the range (:attr:`beyond`)."""
        walls = self.walls
        w = self._wall = walls.update(x, v, obs.position, obs.velocity)
        self.beyond = walls.beyond
        monitor = self.monitor
        if w != 0.0 or monitor.wall_work != 0.0:
            monitor.walls(-w * v)
        return w

    def _no_walls(self) -> float:
        """``passive``: no torque, no walls, no limit to judge."""
        self._wall = 0.0
        self.beyond = ""
        return 0.0

"""Per-channel controller: DOB + endpoint friction feed-forward (paper III-IV).

Inputs per sample: motor position X [rad], motor velocity V [rad/s],
pressure force F_p [N m]. Output: motor torque F_a [N m].

Discretisation (sample period T = ``dt``):

* Hose inversion (eq. 29): ``delta = F_p/(b_s s + k_s)`` (the hose
  deflection X_e - X), pole ``k_s/b_s`` (1414 rad/s for Table I), discretised
  exactly for a piecewise-*linear* F_p (first-order hold: no lag at the
  sample instants). Then ``X_e_hat = X + delta`` and
  ``V_e_hat = V + (F_p - k_s delta)/b_s`` (= V + d(delta)/dt exactly).
* Feed-forward: ``F_cmp = b_e V_e_hat + k_e (X_e_hat - rest_position)``
  (eq. 29) and the Dahl force ``F_d`` (eq. 14, exact per-sample update,
  :mod:`.dahl`) driven by X_e_hat through a play operator (dead zone) of
  width ``dahl_deadband`` (default 1e-4 rad, about 3-4 sigma of the X_e_hat
  noise from the pressure sensor): without it, sample-to-sample noise on
  X_e_hat makes the Dahl state relax at every spurious reversal, which at
  slow speeds (0.3 rad/s) biased F_d by ~5 mN m rms in simulation (0.15 mN m
  with the play).
* DOB (eq. 19) rewritten without differentiation::

      F_a = F_ref + I - lambda m_n V - lambda b_n X,
      I'  = lambda (F_ref + F_p - k_n X)

  The integrator uses the trapezoidal rule (no phase error at low
  frequency); ``d_hat = F_a - F_ref`` is the disturbance estimate.
* hold: ``F_a = bias - K_p (X - X_0) - K_d V`` with X_0 and the bias captured
  at mode entry.
* force_feedback: ``F_a = K_f F_p + beta`` with a transfer offset beta that
  decays with a 50 ms time constant (bumpless entry).
* impedance: the DOB with ``F_ref = F_cmp + F_d - K_t (X_e_hat - X_e0) -
  B_t V_e_hat``, X_e0 captured at mode entry: the endpoint renders the target
  stiffness/damping (plus the endpoint inertia).
* force: the DOB with ``F_ref = target.force`` (eq. 19 with a reference): at rest
  the hose pushes the motor with ``F_p = -F_ref``.
* a job (:mod:`.jobs`, requested with :meth:`ChannelController.request_job`; one at a time
  per channel, a second one is refused as busy) overrides the mode while it runs. A
  :data:`~.jobs.ENDPOINT_FORCE` job runs the DOB with ``F_ref = F_cmp + F_d + F_j`` (minimum
  impedance plus the job's endpoint force); a :data:`~.jobs.TORQUE` job commands F_a itself.
  When it is done the channel enters its mode again, bumplessly from the torque then, with
  the configuration the job leaves. Selecting ``passive`` ends a job at once; selecting
  another mode ends it too, gently where the job can (:meth:`~.jobs.Job.wind_down`).
* a grasp (:mod:`.grasp`) is an endpoint-force job, ``F_j = F_g``; when it is done the release
  has ramped F_g to zero (the grip is not carried over into ``hold``); another mode releases
  it first.
* the contact estimator (:mod:`.estimator`) runs in every mode on X_e_hat, F_p
  and F_d.
* a friction calibration (:mod:`.friction_calibration`) is a torque job: a position
  servo moves the free finger and fits b_e, k_e, F_c, sigma; when it ends the mode resumes
  bumplessly from the torque then, with the new values if it applied them. Any mode change
  aborts it. With ``friction.adaptation`` the feed-forward's values follow the same fit slowly
  while the estimator sees no contact (``dob_linear_ff``, ``dob_full_ff``, ``impedance``, and
  a grasp's approach).
* the passivity guard (:mod:`.passivity_guard`, ``passivity_guard`` not ``disabled``)
  watches the DOB's port ``(F_p + F_ref, V)`` whenever the DOB runs; when ``active`` its
  damping force is added to F_ref (the port impedance becomes Z + alpha). It restarts
  (full reserve, no damping) at every mode entry, so entries stay bumpless; a parameter set
  within the mode keeps its ledger.
* chirp: ``F_a = u_0 + A w(t) sin(phi(t))``, log chirp, u_0 the torque at
  entry, w a 50 ms raised-cosine fade-in/out. It plays once per selection of
  the mode (``configure``): a chirp that finished, or that the plant
  interrupted, never plays again by itself after a reset or re-entry.
* passive: zero torque, immediately (the safe state; the one deliberate
  non-bumpless transition).

Bumpless transfer: every mode entry (or ``configure``) initialises the new
mode's state from the last output so that the first output equals it;
:meth:`ChannelController.reset` and :meth:`ChannelController.reenter` start
from a torque the plant reports as applied.

The controller computes; it does not judge. Input validation (finite,
plausible, fresh), the ``max_torque`` fault limit and fault latching live in
:class:`~.control_cycle.ControlCycle`, which calls :meth:`update` only with
checked inputs. A non-finite input still raises
:class:`~.errors.NonFiniteInputError` (nothing is latched).

The hot path uses Python floats only (no numpy, no allocation beyond
float boxing, no logging).
"""

from __future__ import annotations

import math

from .dahl import DahlState
from .estimator import ContactEstimator
from .friction_calibration import FrictionAdaptation
from .grasp import Grasp
from .handover import Mailbox
from .jobs import TORQUE, Job, JobSample, busy_reason
from .passivity_guard import PassivityGuard
from .errors import NonFiniteInputError
from .params import ControllerConfig, DahlParams, DOB_MODES
from .signals import faded_log_chirp

__all__ = ["ChannelController"]

_BUMP_TAU = 0.05      # s, decay of the force-feedback and hold transfer offsets
_ENTER, _REENTER = 2, 1   # pending entry into the mode: full (targets captured) / re-entry
_CHIRP_FADE = 0.05    # s, raised-cosine fade of the chirp envelope


class ChannelController:
    """Controller of one channel.

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
        DOB disturbance estimate ``d_hat = F_a - F_ref`` [N m] (NaN outside
        the DOB modes).
    feedforward : float
        ``F_cmp + F_d`` [N m] (computed in every mode).
    endpoint_velocity_estimate : float
        V_e_hat [rad/s].
    endpoint_position_estimate : float
        X_e_hat [rad].
    dahl_force : float
        F_d [N m].
    estimator : ContactEstimator
        Contact and object estimates (updated in every mode).
    job : Job or None
        The job that overrides the mode (a grasp, a friction calibration), while it runs.
    passivity_guard : PassivityGuard or None
        The time-domain passivity guard of the DOB's motor port (None when disabled); it runs
        while the DOB does (the DOB modes and a grasp) and restarts at every mode entry.
    """

    def __init__(self, config=None, dt=5e-4):
        if config is None:
            config = ControllerConfig()
        if not isinstance(config, ControllerConfig):
            raise TypeError("config must be a ControllerConfig")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt = {dt!r} must be > 0 and finite")
        self.dt = float(dt)
        self._pending = Mailbox()
        self._jobs = Mailbox(size=None)     # every job requested, in order
        self.job: Job | None = None
        self.estimator = ContactEstimator(config.estimator, config.plant, self.dt,
                                          config.feedforward.rest_position)
        self._chirp_played = False
        self._t_mode = 0.0
        self.mode = config.mode
        self._dahl = DahlState(config.dahl)
        self._job_sample = JobSample(self.estimator)
        self.adaptation = FrictionAdaptation(config, self.dt)
        self._apply_config(config)
        self.reset()

    # --- configuration ----------------------------------------------------------
    def configure(self, config):
        """Queue a new (already validated) config; it takes effect at the
        start of the next :meth:`update`, bumplessly."""
        if not isinstance(config, ControllerConfig):
            raise TypeError("config must be a ControllerConfig")
        config.validate()
        self._pending.put(config)

    @property
    def config(self):
        """The active configuration."""
        return self._config

    def _apply_config(self, c):
        job = self.job
        if job is not None and c.mode != self.mode:
            # passive: off at once; another mode: a job that can end gently does
            reason = f"mode set to {c.mode}"
            if c.mode == "passive" or not job.wind_down(reason):
                self._end_job(reason)
        self.adaptation.configure(c)
        self._config = c
        dt = self.dt
        p = c.plant
        self.mode = c.mode
        self._dob_mode = c.mode in DOB_MODES
        ks, bs = p.hose_stiffness, p.hose_damping
        self._ks, self._inv_bs = ks, 1.0 / bs
        self._h_a, self._h_c0, self._h_c1 = self._hose_coefficients(dt)
        self._be, self._ke = p.endpoint_damping, p.endpoint_stiffness
        self._rest = c.feedforward.rest_position
        self._dahl_hw = 0.5 * c.feedforward.dahl_deadband
        self._dahl.set_params(c.dahl)
        lam = c.dob.cutoff
        self._lam_half_dt = 0.5 * lam * dt
        self._lam_mn = lam * c.dob.nominal_inertia
        self._lam_bn = lam * c.dob.nominal_damping
        self._kn = c.dob.nominal_stiffness
        self._kp, self._kd = c.hold.stiffness, c.hold.damping
        self._kf = c.force_feedback.gain
        self._bump_decay = math.exp(-dt / _BUMP_TAU)
        self._kt, self._bt = c.target.stiffness, c.target.damping
        self._f_target = c.target.force
        self.estimator.configure(c.estimator, p, c.feedforward.rest_position)
        self._use_ff = c.mode in ("dob_linear_ff", "dob_full_ff", "impedance")
        self._configure_guard(c)

    # --- time-domain passivity guard ------------------------------------------------------
    def _configure_guard(self, c):
        """The guard of ``c.passivity`` (None when disabled) on the DOB's port, whose apparent
        inertia is m_n; its force is bounded by ``max_torque``. A running guard is configured,
        not replaced: :meth:`update` restarts its ledger on a mode entry only (a restart on
        every parameter set would refill the reserve, and parameters set again and again
        would disarm it)."""
        guard = getattr(self, "passivity_guard", None)
        if c.passivity.mode == "disabled":
            self.passivity_guard = None
        elif guard is None:
            self.passivity_guard = PassivityGuard(c.passivity, self.dt, c.dob.nominal_inertia,
                                                  c.max_torque)
        else:
            guard.configure(c.passivity, c.dob.nominal_inertia, c.max_torque)

    def _hose_coefficients(self, period):
        """Exact first-order-hold discretisation of ``delta' = (F_p - k_s delta)/b_s`` over
        ``period`` [s]: ``delta_k = a delta_{k-1} + c0 F_p,{k-1} + c1 F_p,k``."""
        ks = self._ks
        pT = ks * self._inv_bs * period
        a = math.exp(-pT)
        i1 = (1.0 - a) - (1.0 - a - pT * a) / pT
        return a, (1.0 - a - i1) / ks, i1 / ks

    def reset(self, applied_torque=0.0, reason="the controller was re-initialised"):
        """Clear all state (filters, integrator, estimates); the next :meth:`update` starts
        afresh from that sample and enters the mode bumplessly from ``applied_torque``
        [N m], the torque the plant reports it applies (its first output equals it). A
        running job ends (aborted, with ``reason``)."""
        self._end_job(reason)
        pending = self._pending.take()
        if pending is not None:
            self._apply_config(pending)
            self._chirp_played = False
        self._interrupt_chirp()
        self.estimator.reset()
        if self.passivity_guard is not None:
            self.passivity_guard.reset()
        self.torque = float(applied_torque)
        self.disturbance = math.nan
        self.feedforward = 0.0
        self.endpoint_velocity_estimate = 0.0
        self.endpoint_position_estimate = 0.0
        self.dahl_force = 0.0
        self._first = True
        self._delta = 0.0
        self._fp_prev = 0.0
        self._dahl.reset(0.0, 0.0)
        self._dahl_in = 0.0
        self._integ = 0.0
        self._e_prev = 0.0
        self._x0 = 0.0
        self._bias = 0.0
        self._transfer = 0.0
        self._t_mode = 0.0
        self._enter = _ENTER

    def reenter(self, applied_torque):
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
        self._interrupt_chirp()
        self.estimator.disturb()        # a torque its model did not see
        self.torque = float(applied_torque)
        if self._enter != _ENTER:
            self._enter = _REENTER
        if self.job is not None:
            self.job.reenter()

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

    def _end_job(self, reason: str) -> None:
        job = self.job
        if job is not None:
            job.abort_now(reason)   # (a grasp keeps the object it measured: reset after this)
            self.job = None
            self._enter = _ENTER

    def _take_jobs(self) -> None:
        """Start the first job requested that was not withdrawn, if the channel is free;
        refuse the others."""
        while self._jobs:
            job = self._jobs.take()
            if not job.claim():
                continue                    # withdrawn before it started
            if self.job is not None:
                job.abort_now(busy_reason(job, self.job))
                continue
            self._interrupt_chirp()
            self.job = job
            self._enter = _ENTER

    def _run_job(self, job: Job, x: float, v: float, f_p: float, xd: float,
                 steps: int) -> float:
        """One sample of the running ``job`` (X, V, F_p, the Dahl input, steps): its output,
        which is the channel's torque for a :data:`~.jobs.TORQUE` job. A job that ends hands
        the channel back to its mode, from this torque, with the configuration it leaves
        (:meth:`~.jobs.Job.final_config`: a calibration's new friction)."""
        sample = self._job_sample          # filled in place: no allocation per sample
        sample.x = x
        sample.v = v
        sample.f_p = f_p
        sample.dahl_input = xd
        sample.endpoint_position = self.endpoint_position_estimate
        sample.endpoint_velocity = self.endpoint_velocity_estimate
        sample.torque = self.torque
        sample.steps = steps
        out = job.step(sample)
        if not job.active:
            self.job = None
            config = job.final_config(self._config)
            if config is not None:
                self._apply_config(config)
            self._enter = _ENTER            # back to the mode, from this torque
        if job.output == TORQUE:
            self.disturbance = math.nan
            self.torque = out
        return out

    @property
    def grasp_phase(self) -> str:
        """The running grasp's phase, or '' (``controller_status.grasp_phase``)."""
        job = self.job
        return job.phase if isinstance(job, Grasp) else ""

    def _interrupt_chirp(self):
        """A chirp under way when the plant interrupts it is over: it never replays by itself
        (a new ``configure`` into ``chirp`` plays it again)."""
        if self.mode == "chirp" and self._t_mode > 0.0:
            self._chirp_played = True

    # --- friction adaptation ------------------------------------------------------------
    def _adapt(self, xe_hat, xd, f_p, fd, steps):
        adaptation = self.adaptation
        job = self.job
        estimator = self.estimator
        free = not (estimator.contact or estimator.quiet) and (
            job is None or job.free_motion)
        if adaptation.update(xe_hat, xd, f_p, free, fd, steps):
            be, ke, fc, sigma = adaptation.values
            self._be, self._ke = be, ke
            self._dahl.set_params(DahlParams(
                sigma=sigma, coulomb_force=fc, exponent=self._config.dahl.exponent))

    # --- per sample -------------------------------------------------------------
    def update(self, x, v, f_p, steps=1):
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
        if not (math.isfinite(x) and math.isfinite(v) and math.isfinite(f_p)):
            bad = [(n, val) for n, val in (("x", x), ("v", v), ("f_p", f_p))
                   if not math.isfinite(val)][0]
            raise NonFiniteInputError(*bad)
        pending = self._pending.take()
        keep_ledger = False     # the guard's ledger goes on through a same-mode parameter set
        if pending is not None:
            keep_ledger = pending.mode == self.mode and self._enter != _ENTER
            self._apply_config(pending)
            self._chirp_played = False
            self._enter = _ENTER
        if self._jobs:
            keep_ledger = False
            self._take_jobs()

        # hose inversion: delta = F_p/(b_s s + k_s), exact FOH
        if self._first:
            self._first = False
            delta = f_p / self._ks
            self._dahl_in = x + delta
            self._dahl.reset(x + delta, 0.0)
        elif steps == 1:
            delta = self._h_a * self._delta + self._h_c0 * self._fp_prev + self._h_c1 * f_p
        else:
            a, c0, c1 = self._hose_coefficients(steps * self.dt)
            delta = a * self._delta + c0 * self._fp_prev + c1 * f_p
        self._delta = delta
        self._fp_prev = f_p
        xe_hat = x + delta
        ve_hat = v + (f_p - self._ks * delta) * self._inv_bs
        # play operator (dead zone of width w) on the Dahl input: sensor noise
        # on X_e_hat must not drive spurious Dahl reversals
        xd = self._dahl_in
        hw = self._dahl_hw
        if xe_hat > xd + hw:
            xd = self._dahl_in = xe_hat - hw
        elif xe_hat < xd - hw:
            xd = self._dahl_in = xe_hat + hw
        fd = self._dahl.update(xd)
        fcmp = self._be * ve_hat + self._ke * (xe_hat - self._rest)
        self.endpoint_position_estimate = xe_hat
        self.endpoint_velocity_estimate = ve_hat
        self.dahl_force = fd
        self.feedforward = fcmp + fd
        self.estimator.update(xe_hat, f_p, fd, steps)
        job = self.job
        if job is not None and job.output == TORQUE:
            return self._run_job(job, x, v, f_p, xd, steps)
        if self._config.friction.adaptation and (self._use_ff or job is not None):
            self._adapt(xe_hat, xd, f_p, fd, steps)

        mode = self.mode
        enter = self._enter == _ENTER
        reenter = self._enter == _REENTER
        self._enter = 0
        u_prev = self.torque
        guard = self.passivity_guard
        if guard is not None and enter and not keep_ledger:
            guard.reset()           # a new port: the full reserve, no damping (bumpless)
        if job is not None or self._dob_mode:
            if job is not None:     # the job's endpoint force on minimum impedance
                f_ref = fcmp + fd + self._run_job(job, x, v, f_p, xd, steps)
            elif mode == "dob":
                f_ref = 0.0
            elif mode == "dob_linear_ff":
                f_ref = fcmp
            elif mode == "dob_full_ff":
                f_ref = fcmp + fd
            elif mode == "force":
                f_ref = self._f_target
            else:   # impedance
                if enter:
                    self._x0 = xe_hat
                f_ref = fcmp + fd - self._kt * (xe_hat - self._x0) - self._bt * ve_hat
            if guard is not None:   # damping on the DOB's port (F_p + F_ref, V): Z -> Z + alpha
                f_ref += guard.update(f_p + f_ref, x, v, steps)
            e = f_ref + f_p - self._kn * x
            lam_h = self._lam_half_dt * steps
            ramp = self._lam_mn * v + self._lam_bn * x
            if enter or reenter:
                # bumpless: choose I_{k-1} so that this output equals u_prev
                self._integ = u_prev - f_ref + ramp - 2.0 * lam_h * e
                self._e_prev = e
            integ = self._integ + lam_h * (e + self._e_prev)
            self._e_prev = e
            u = f_ref + integ - ramp
            self._integ = integ
            self.disturbance = u - f_ref
            self.torque = u
            return u

        self.disturbance = math.nan
        if mode == "passive":
            u = 0.0
        elif mode == "hold":
            if enter:
                self._x0 = x
                self._bias = u_prev + self._kd * v
                self._transfer = 0.0
            u = self._bias - self._kp * (x - self._x0) - self._kd * v
            if reenter:
                self._transfer = u_prev - u
            elif self._transfer:
                self._transfer *= self._bump_decay if steps == 1 else self._bump_decay ** steps
            u += self._transfer
        elif mode == "force_feedback":
            if enter or reenter:
                self._bias = u_prev - self._kf * f_p
            else:
                self._bias *= self._bump_decay if steps == 1 else self._bump_decay ** steps
            u = self._kf * f_p + self._bias
        else:   # chirp
            if enter or reenter:
                self._bias = u_prev
                self._t_mode = self._config.chirp.duration if self._chirp_played else 0.0
            else:
                self._t_mode += self.dt * steps
            if self._t_mode >= self._config.chirp.duration:
                self._chirp_played = True
            u = self._bias + self._chirp(self._t_mode)
        self.torque = u
        return u

    def _chirp(self, t):
        c = self._config.chirp
        T = c.duration
        return c.amplitude * faded_log_chirp(t, c.start_frequency, c.end_frequency, T,
                                             min(_CHIRP_FADE, 0.1 * T))

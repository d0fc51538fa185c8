"""Jobs: what overrides a channel's mode for a while (a grasp, a friction calibration).

A job is requested from any thread (:meth:`~.controller.ChannelController.request_job`), taken
over by the control cycle at the start of its next sample, runs one :meth:`Job.step` per sample
in the cycle's thread until it is done, and then hands the channel back to its mode, bumplessly
from the torque then. A channel runs one job at a time: a job that arrives while another runs
is refused (aborted, "the channel is busy with ...").

What every job shares lives here, in :class:`Job`:

* the hand-over: :meth:`Job.claim` (cycle thread) and :meth:`Job.withdraw` (any thread) decide,
  once, whether the job starts or is withdrawn (:class:`~.handover.Claim`): a goal that gave
  up waiting never starts later;
* the requests from another thread, taken at the next sample: :meth:`Job.request_cancel`
  (the client's cancel: the job ends the way it safely can, ``canceled``) and
  :meth:`Job.request_abort` (the caller has already ended the goal: the cycle did not run);
* the end from the cycle's thread: :meth:`Job.abort_now` (the cycle zeroes the torque right
  after: a fault, a stall, a re-initialisation; nothing is commanded after it) and
  :meth:`Job.wind_down` (a mode change: a job that can end gently does);
* the record: ``phase`` (``'done'`` at the end), ``outcome`` (None until done, then
  ``'succeeded'``, ``'canceled'`` or ``'aborted'``), ``message`` (why), :meth:`Job.feedback`.

How the output enters the channel is the job's :attr:`Job.output`:

* :data:`TORQUE` -- the job's output is the motor torque F_a [N m] itself (the friction
  calibration's position servo): the mode, the DOB, the passivity guard and the friction
  adaptation pause while it runs;
* :data:`ENDPOINT_FORCE` -- the output is an endpoint force added to the minimum-impedance
  DOB's reference, ``F_ref = F_cmp + F_d + output`` (eq. 19 and 29; the grasp's F_g): the
  passivity guard watches the DOB's port, and the friction adaptation fits the samples the job
  reports as free motion (:attr:`Job.free_motion`).

A job reads the channel through one :class:`JobSample` the controller fills in place at every
sample (no allocation). Nothing here imports ROS.
"""

from __future__ import annotations

import abc
import math
from typing import TYPE_CHECKING, ClassVar

from .errors import SeaforceError
from .handover import Claim

if TYPE_CHECKING:
    from .estimator import ContactEstimator
    from .params import ControllerConfig

__all__ = ["Job", "JobSample", "InvalidJobGoalError", "busy_reason", "TORQUE",
           "ENDPOINT_FORCE", "DONE", "OUTCOMES"]

#: :attr:`Job.output`: the job commands the motor torque F_a [N m].
TORQUE = "torque"
#: :attr:`Job.output`: the job adds an endpoint force [N m] to the minimum-impedance DOB's
#: reference.
ENDPOINT_FORCE = "endpoint_force"
#: The phase of every job once it has ended.
DONE = "done"
#: The outcomes a job ends with.
OUTCOMES = ("succeeded", "canceled", "aborted")


class InvalidJobGoalError(SeaforceError, ValueError):
    """A job's goal that cannot be executed (bad field, busy or faulted channel); the message
    says why."""


class JobSample:
    """The channel at one sample, as a job sees it (filled in place by the controller).

    Attributes
    ----------
    estimator : ContactEstimator
        The channel's contact estimator, already updated with this sample.
    x, v : float
        Motor position X [rad] and velocity V [rad/s].
    f_p : float
        Pressure force F_p [N m].
    endpoint_position, endpoint_velocity : float
        X_e_hat [rad] and V_e_hat [rad/s] (eq. 29).
    dahl_input : float
        X_e_hat through the feed-forward's play operator [rad] (what drives F_d, eq. 14).
    torque : float
        The channel's last torque F_a [N m] (the one the plant applies now).
    steps : int
        Sample periods since the previous sample (>= 1; 0 never).
    cycle : int
        The state's cycle number (``ActuatorState.cycle``; -1 when the caller gave none).
    applied : float
        The torque the plant reports it applied in this sample (``motor_effort``) [N m]; NaN
        when the caller gave none.
    """

    __slots__ = ("estimator", "x", "v", "f_p", "endpoint_position", "endpoint_velocity",
                 "dahl_input", "torque", "steps", "cycle", "applied")

    def __init__(self, estimator: ContactEstimator) -> None:
        self.estimator = estimator
        self.x = self.v = self.f_p = 0.0
        self.endpoint_position = self.endpoint_velocity = self.dahl_input = 0.0
        self.torque = 0.0
        self.steps = 1
        self.cycle = -1
        self.applied = math.nan


class Job(abc.ABC):
    """One job on one channel (module docstring). Subclasses set :attr:`kind`,
    :attr:`output`, the ``phase`` they start in, and implement :meth:`step`,
    :meth:`abort_now`, :meth:`request_cancel` and :meth:`feedback`.

    Threads: the cycle thread calls :meth:`claim`, :meth:`step`, :meth:`abort_now`,
    :meth:`wind_down`, :meth:`reenter` and :meth:`final_config`; any thread may call
    :meth:`withdraw`, :meth:`request_cancel`, :meth:`request_abort` and read the attributes.

    Attributes
    ----------
    phase : str
        The job's phase; :data:`DONE` once it has ended.
    outcome : str or None
        None until done, then one of :data:`OUTCOMES`.
    message : str
        What it is doing, or why it ended.
    """

    #: What the job is, in messages ("the channel is busy with a grasp").
    kind: ClassVar[str] = "job"
    #: :data:`TORQUE` or :data:`ENDPOINT_FORCE`.
    output: ClassVar[str] = TORQUE

    def __init__(self) -> None:
        self.phase = ""
        self.outcome: str | None = None
        self.message = ""
        self._claim = Claim()
        self._abort_request: str | None = None

    # --- hand-over and requests ----------------------------------------------------------
    def claim(self) -> bool:
        """(cycle thread) Take the job over: False if it was withdrawn first."""
        return self._claim.claim()

    def withdraw(self, reason: str, outcome: str = "aborted") -> bool:
        """(any thread) End a job the cycle has not claimed yet: True if it is ended (it will
        never start), False if it runs (then :meth:`request_cancel` or :meth:`request_abort`
        it)."""
        if not self._claim.withdraw():
            return False
        self._finish(outcome, reason)
        return True

    def request_abort(self, reason: str) -> None:
        """(any thread) End at the next sample, aborted with ``reason``, in the cycle's thread:
        a goal the caller has already ended because the cycle stopped running."""
        self._abort_request = reason

    @abc.abstractmethod
    def request_cancel(self, reason: str) -> None:
        """(any thread) The client's cancel: end from the next sample on, the way the job
        safely can, ``canceled``."""

    @property
    def started(self) -> bool:
        """The cycle has claimed it (it runs, or ran)."""
        return self._claim.claimed

    @property
    def active(self) -> bool:
        """True until done."""
        return self.phase != DONE

    def _finish(self, outcome: str, message: str) -> None:
        self.outcome = outcome
        self.message = message
        self.phase = DONE

    # --- the cycle's side ------------------------------------------------------------------
    @abc.abstractmethod
    def step(self, sample: JobSample) -> float:
        """(cycle thread) One sample: the output (:attr:`output`), zero once done."""

    @abc.abstractmethod
    def abort_now(self, reason: str) -> None:
        """(cycle thread) End at once, aborted with ``reason``, commanding nothing more (the
        cycle zeroes the torque, or re-initialises the controller, right after); no effect
        once done."""

    def wind_down(self, reason: str) -> bool:
        """(cycle thread) The channel's mode changed: True if the job ends over the next
        samples by itself (aborted with ``reason``), False if it must end now (the default:
        the controller then calls :meth:`abort_now`)."""
        return False

    def reenter(self) -> None:
        """(cycle thread) The plant applies another torque than the job's this sample (a
        command timeout); the next sample starts from it. Default: nothing to do."""

    @property
    def free_motion(self) -> bool:
        """(cycle thread, an :data:`ENDPOINT_FORCE` job) The finger moves free of any object
        under the job: the friction adaptation may fit this sample. Default False."""
        return False

    def final_config(self, config: ControllerConfig) -> ControllerConfig | None:
        """(cycle thread, once, when the job is done) The configuration the channel continues
        with, or None to keep ``config`` (the default)."""
        return None

    @abc.abstractmethod
    def feedback(self, estimator: ContactEstimator) -> dict[str, float | str]:
        """The job's progress now, named as its action's feedback fields; ``estimator`` is
        its channel's."""


def busy_reason(job: Job, running: Job) -> str:
    """Why ``job`` cannot start while ``running`` holds the channel."""
    article = "another" if type(job) is type(running) else "a"
    return f"the channel is busy with {article} {running.kind}"

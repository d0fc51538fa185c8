"""controller_node's ``~/commission`` action (``seaforce_msgs/action/Commission``).

One goal commissions one channel, through the node's one job path (:mod:`.jobs`):

1. the goal's checks: its fields (a band with 0 < low < high < pi/T, the Nyquist frequency
   of the sample period T; budgets >= 0 and finite), the
   channel (known, not faulted, not held by another goal, not stopped by the plant) and a
   free finger (no contact on the channel's contact estimator while the finger moves; one
   standing with the finger still for :data:`STANDING_TIME` is logged and taken for the
   model's error at rest -- the excitation's contact test aborts at a real one); a goal that
   fails one ends at
   once, ABORTED, ``rejected: <reason>``;
2. the excitation, a core job (:class:`~seaforce_ros.commissioning.excitation.FreeAirExcitation`)
   in the control cycle: a contact, a tracking error, a fault, a stall or a cancel ends it
   with zero torque, and the goal with it;
3. the analysis, a follow-up off the control thread (:class:`_FollowUp`): the record and the
   request are written to the run's directory; a child process
   (:class:`~seaforce_ros.commissioning.worker.AnalysisProcess`: the identification's CPU does
   not compete with the 2 kHz loop for the interpreter) identifies, tunes and proposes the
   feed-forward's candidates (``analyse --propose``); the verification, a core job again
   (:class:`~seaforce_ros.commissioning.verification.FreeFingerVerification`, unless
   ``verification.enabled`` is false), tries them on the free finger and writes
   ``verification.json``; a second child takes its verdict into the tuning, predicts, writes
   the report, the params file and the rollback file (none on ``dry_run``; ``analyse
   --finish``);
4. the end: with ``apply`` (and not ``dry_run``) the tuned values are set as the channel's
   parameters -- validated like any parameter change and taken at the start of a cycle,
   bumplessly; the result carries the summary, the paths, the values old and new.

The run's directory is ``<commissioning.directory>/<channel>-<UTC time>``; the newest earlier
run of the channel there is what the drift is reported against. ``commissioning.directory``
and ``commissioning.params_file`` are read at each goal (a set at run time takes effect with
the next goal). A run that ends before anything was written to its directory (a cancel, an
abort during the excitation) removes it.
"""
from __future__ import annotations

import datetime
import json
import math
import pathlib
import sys
import time
from dataclasses import dataclass, field
from typing import Any

from rclpy.parameter import Parameter
from seaforce_msgs.action import Commission

from ..commissioning.analyse import (CANDIDATES_FILE, VERIFICATION_FILE, Verified,
                                     save_verified)
from ..commissioning.excitation import ExcitationGoal, FreeAirExcitation
from ..commissioning.record import save_record
from ..commissioning.verification import Candidate, FreeFingerVerification
from ..commissioning.worker import AnalysisProcess
from ..core.params import ControllerConfig
from ..core.estimator import REST_SPEED, STANDING_TIME
from ..core.jobs import InvalidJobGoalError, Job
from .jobs import JobAction

__all__ = ["CommissionAction", "DEFAULT_DIRECTORY", "run_directory", "previous_run"]

#: Where runs go when ``commissioning.directory`` is empty (relative to the working directory).
DEFAULT_DIRECTORY = "seaforce_commissioning"

#: The shares of the goal's progress the excitation, the proposal and the verification take
#: (the finish takes the rest).
EXCITATION_SHARE, PROPOSAL_SHARE, VERIFICATION_SHARE = 0.55, 0.15, 0.2
#: A contact reported this long ago [s] still counts at a goal: a finger pushed back and forth
#: drops its contact flag around each reversal of the force (and the estimator re-arms after
#: STANDING_TIME still), and a goal must not slip through there.
RECENT_CONTACT = 0.5


def run_directory(base: str, channel: str, now: datetime.datetime | None = None
                  ) -> pathlib.Path:
    """A new directory for a run of ``channel`` under ``base`` (created; a suffix when two
    runs start in the same second)."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    root = pathlib.Path(base or DEFAULT_DIRECTORY).expanduser()
    stem = f"{channel}-{now.strftime('%Y%m%dT%H%M%SZ')}"
    for n in range(100):
        path = root / (stem if n == 0 else f"{stem}-{n}")
        try:
            path.mkdir(parents=True)
            return path
        except FileExistsError:
            continue
    raise OSError(f"{root}: 100 runs of {channel} in one second?")


def previous_run(base: str, channel: str, exclude: pathlib.Path | None = None
                 ) -> pathlib.Path | None:
    """The newest earlier run of ``channel`` under ``base`` that has a ``report.json``."""
    root = pathlib.Path(base or DEFAULT_DIRECTORY).expanduser()
    runs = sorted((p for p in root.glob(f"{channel}-*") if (p / "report.json").is_file()
                   and p != exclude), key=lambda p: p.name)
    return runs[-1] if runs else None


def _checked(goal: Any, defaults: dict[str, float], dt: float) -> dict[str, Any]:
    """The goal's numbers with the channel's defaults for zeros; InvalidJobGoalError with the
    field's name for a bad one (a band beyond the Nyquist frequency pi/T of the sample period
    ``dt`` [s] among them: nothing there can be identified or tuned)."""
    values: dict[str, Any] = {}
    for name in ("band_low", "band_high", "noise_budget", "passivity_margin"):
        value = float(getattr(goal, name))
        if not math.isfinite(value) or value < 0.0:
            raise InvalidJobGoalError(f"{name} = {value!r}: must be >= 0 and finite (0: the "
                                      f"channel's commissioning.{name})")
        values[name] = value if value > 0.0 else defaults[name]
    if not values["band_low"] < values["band_high"]:
        raise InvalidJobGoalError(f"band {values['band_low']:g}..{values['band_high']:g} "
                                  "rad/s: band_low must be below band_high")
    nyquist = math.pi / dt
    if not values["band_high"] < nyquist:
        raise InvalidJobGoalError(f"band_high = {values['band_high']:g} rad/s: must be below "
                                  f"the Nyquist frequency pi/T = {nyquist:.0f} rad/s (T = "
                                  f"{dt:g} s, the controller's sample period)")
    if values["passivity_margin"] > 10.0:
        raise InvalidJobGoalError(f"passivity_margin = {values['passivity_margin']:g}: at most "
                                  "10 (1-sigmas of m, b, k)")
    values.update(allow_guard=bool(goal.allow_guard), apply=bool(goal.apply) and not
                  goal.dry_run, dry_run=bool(goal.dry_run))
    return values


def _number(value: Any) -> float:
    """A result value (JSON null: not identified) as a float, NaN for none."""
    try:
        return math.nan if value is None else float(value)
    except (TypeError, ValueError):
        return math.nan


@dataclass
class _Run:
    """One goal's run: its request, directory, follow-up and outcome."""
    request: dict[str, Any]
    directory: pathlib.Path
    analysis: "_FollowUp | None" = None
    applied: bool = False
    result: dict[str, Any] = field(default_factory=dict)


class _FollowUp:
    """What follows the excitation (module docstring, step 3), polled by the node's job
    actions (:class:`~.jobs.FollowUp`): the proposal's child, the verification job on the
    channel, the finish's child. ``outcome``, ``message`` and ``result`` are the finish's (or
    the stage's that ended the run)."""

    def __init__(self, node: Any, index: int, directory: pathlib.Path,
                 prepare: Any) -> None:
        self._node, self._index, self._directory = node, index, directory
        self.outcome: str | None = None
        self.message = "starting the analysis"
        self.result: dict[str, Any] | None = None
        self._canceled = ""
        self._job: FreeFingerVerification | None = None
        self._started = 0.0
        self._finishing = False
        self._child = self._analysis("--propose", "identify",
                                     (EXCITATION_SHARE, EXCITATION_SHARE + PROPOSAL_SHARE),
                                     prepare)

    def _analysis(self, stage: str, phase: str, span: tuple[float, float],
                  prepare: Any = None) -> AnalysisProcess:
        # (-P: the node's working directory is not on the child's import path)
        return AnalysisProcess([sys.executable, "-P", "-m", "seaforce_ros.commissioning.analyse",
                                str(self._directory), stage],
                               self._directory / "analysis.log", phase=phase,
                               progress_span=span, prepare=prepare)

    @property
    def pid(self) -> int | None:
        return self._child.pid if self._child is not None else None

    def poll(self) -> bool:
        """Advance (never blocking); True once the run has ended."""
        if self.outcome is not None:
            return True
        if self._job is not None:
            return self._poll_job(self._job)
        if not self._child.poll():
            return False
        child = self._child
        if child.outcome == "canceled" or self._canceled:
            return self._end("canceled", self._canceled or child.message)
        if self._finishing:
            self.result = child.result
            return self._end(child.outcome or "aborted", child.message)
        # the proposal's end: an untuned run (no candidate) is finished too, for its report
        names = (child.result or {}).get("candidates", [])
        if not (self._directory / "proposal.pkl").exists():
            self.result = child.result
            return self._end("aborted", child.message)
        config = self._node.controllers[self._index].config
        if names and config.verification.enabled:
            return self._verify(config)
        return self._finish_stage()

    def _verify(self, config: ControllerConfig) -> bool:
        try:
            data = json.loads((self._directory / CANDIDATES_FILE).read_text())
            candidates = [Candidate(str(c["name"]), ControllerConfig.from_dict(c["config"]))
                          for c in data]
            job = FreeFingerVerification(candidates, config, self._node.dt)
        except Exception as exc:        # noqa: BLE001 -- any failure: unverified, said so
            self._save(Verified([], None, 0.0, f"the verification could not start: {exc}"))
            return self._finish_stage()
        self._job = job
        self._started = time.monotonic()
        self.message = "verifying the feed-forward's candidates on the free finger"
        self._node.controllers[self._index].request_job(job)
        return False

    def _poll_job(self, job: FreeFingerVerification) -> bool:
        if self._canceled and job.active:
            if not job.withdraw(self._canceled, "canceled"):
                job.request_cancel(self._canceled)
        stalled = self._node._stalled()
        if job.active and job.started and stalled:
            job.request_abort(stalled + ": the plant stopped, or the link to it")
        if job.active and not job.started and time.monotonic() - self._started > 1.0:
            job.withdraw("the control cycle did not take the verification within 1 s")
        if job.active:
            return False
        self._job = None
        if job.outcome == "canceled" or self._canceled:
            return self._end("canceled", self._canceled or job.message)
        self._save(Verified(job.outcomes, job.chosen, time.monotonic() - self._started,
                            "" if job.outcome == "succeeded" else job.message))
        return self._finish_stage()

    def _save(self, verified: Verified) -> None:
        try:
            save_verified(self._directory / VERIFICATION_FILE, verified)
        except OSError as exc:
            self.message = f"verification.json not written: {exc}"

    def _finish_stage(self) -> bool:
        self._finishing = True
        self._child = self._analysis(
            "--finish", "predict",
            (EXCITATION_SHARE + PROPOSAL_SHARE + VERIFICATION_SHARE, 1.0))
        return False

    def _end(self, outcome: str, message: str) -> bool:
        self.outcome, self.message = outcome, message
        return True

    def cancel(self, reason: str) -> None:
        self._canceled = reason
        if self._job is None:
            self._child.cancel(reason)

    def close(self) -> None:
        if self._job is not None and self._job.active:
            self._job.request_abort("the node is going down")
        self._child.close()

    def feedback(self) -> dict[str, float | str]:
        job = self._job
        if job is None:
            return self._child.feedback()
        lo = EXCITATION_SHARE + PROPOSAL_SHARE
        return {"phase": "verify", "progress": lo + VERIFICATION_SHARE * job.progress,
                "measuring": job.message}


class CommissionAction:
    """The ``~/commission`` action of a controller node (module docstring).

    Parameters
    ----------
    node : ControllerNode
        Its channels, configs, controllers, dt, logger, ``get_parameter`` (its
        ``commissioning.directory`` and ``commissioning.params_file``, read at each goal) and
        ``set_parameters_atomically``.
    """

    def __init__(self, node: Any) -> None:
        self._node = node
        self._runs: dict[int, _Run] = {}
        # per channel: the status cycle since which the endpoint has been still (or None),
        # the latest status cycle with a contact, and the latest status cycle
        self._still_since: dict[int, int | None] = {}
        self._contact_at: dict[int, int] = {}
        self._cycle = 0

    def observe(self, cycle: int, velocities: list[float], contacts: list[bool]) -> None:
        """(at the status rate) Whether each channel's filtered endpoint speed is below
        :data:`~..core.estimator.REST_SPEED` -- since when; when it last had a contact."""
        self._cycle = cycle
        for i, v in enumerate(velocities):
            if not -REST_SPEED < v < REST_SPEED:
                self._still_since[i] = None
            elif self._still_since.get(i) is None:
                self._still_since[i] = cycle
        for i, contact in enumerate(contacts):
            if contact:
                self._contact_at[i] = cycle

    def _contact_within(self, index: int, seconds: float) -> bool:
        """A status of the last ``seconds`` reported a contact on the channel."""
        at = self._contact_at.get(index)
        return at is not None and (self._cycle - at) * self._node.dt <= seconds

    def _still_for(self, index: int) -> float:
        """How long the channel's endpoint has been still [s] (0 if it moves)."""
        since = self._still_since.get(index)
        return 0.0 if since is None else (self._cycle - since) * self._node.dt

    def action(self) -> JobAction:
        """The JobAction to register with the node's JobActions."""
        return JobAction("~/commission", Commission, FreeAirExcitation.kind, self._make,
                         self._result, self._describe,
                         busy=lambda job: f"is being commissioned ({job.phase})",
                         cancel_reason="canceled", finish=self._finish, follow=self._follow,
                         feedback=self._feedback)

    def _feedback(self, index: int, job: Job) -> Any:
        """The goal's feedback while the excitation runs (its share of the progress)."""
        fields = job.feedback(self._node.controllers[index].estimator)
        feedback = Commission.Feedback()
        feedback.phase = str(fields["phase"])
        feedback.progress = EXCITATION_SHARE * float(fields["progress"])
        frequency = float(fields["frequency"])
        feedback.frequency = frequency if feedback.phase == "excite" else 0.0
        feedback.amplitude = float(fields["amplitude"])
        feedback.measuring = (
            f"motor port response at {frequency:.3g} Hz (peak |X - x0| "
            f"{float(fields['peak_position']):.3g} rad, |V| {float(fields['peak_speed']):.3g} "
            "rad/s)" if feedback.phase == "excite" else
            "pressure noise and the free-air pressure force, servo only")
        return feedback

    # --- goal -> job -------------------------------------------------------------------------
    def _make(self, index: int, goal: Any) -> Job:
        node = self._node
        config = node.configs[index]
        c = config.commissioning
        request = _checked(goal, {"band_low": c.band_low, "band_high": c.band_high,
                                  "noise_budget": c.noise_budget,
                                  "passivity_margin": c.passivity_margin}, node.dt)
        estimator = node.controllers[index].estimator
        still = self._still_for(index)
        if (estimator.contact or self._contact_within(index, RECENT_CONTACT)) \
                and still < STANDING_TIME:
            raise InvalidJobGoalError("the finger is not free: the contact estimator reports "
                                      f"a contact ({estimator.force:.3g} N m now) and the "
                                      "finger moves; release it into free air first")
        if estimator.contact:
            # a contact standing with the finger still: an object at rest, or the model's
            # error at rest (a model 2x off left one in the demo): the excitation's own
            # contact test aborts it with zero torque if something is there
            node.get_logger().warning(
                f"{goal.channel}: the contact estimator reports a contact "
                f"({estimator.force:.3g} N m) with the finger still for {still:.1f} s: taken "
                "for the model's error at rest; the excitation aborts at a real contact")
        job = FreeAirExcitation(ExcitationGoal(goal.channel), config, node.dt)
        base = str(node.get_parameter("commissioning.directory").value)
        params_file = str(node.get_parameter("commissioning.params_file").value)
        try:
            directory = run_directory(base, goal.channel)
        except OSError as exc:
            raise InvalidJobGoalError(f"cannot create the run's directory: {exc} (set "
                                      "commissioning.directory)") from None
        previous = previous_run(base, goal.channel, exclude=directory)
        request.update(channel=goal.channel, config=config.to_dict(),
                       params_file=params_file or str(directory / "params.yaml"),
                       previous=str(previous / "report.json") if previous else "",
                       started=datetime.datetime.now(datetime.timezone.utc).isoformat())
        self._runs[index] = _Run(request, directory)
        return job

    def _describe(self, goal: Any) -> str:
        flags = [f for f, on in (("dry run", goal.dry_run), ("applying", goal.apply and not
                                                            goal.dry_run)) if on]
        return "commissioning in free air" + (f" ({', '.join(flags)})" if flags else "")

    # --- the job's end -> the analysis -------------------------------------------------------
    def _follow(self, index: int, job: Job) -> "_FollowUp":
        run = self._runs[index]
        assert isinstance(job, FreeAirExcitation)
        record = job.record()
        run.request["excitation"] = {"message": job.message, "samples": len(record),
                                     "duration": record.duration}

        def prepare() -> None:
            save_record(record, run.directory / "record.npz")
            (run.directory / "request.json").write_text(json.dumps(run.request, indent=1))

        run.analysis = _FollowUp(self._node, index, run.directory, prepare)
        return run.analysis

    def _finish(self, index: int, job: Job) -> str:
        """The result's message; sets the tuned values as parameters when asked."""
        run = self._runs.get(index)
        if run is None or run.analysis is None:
            return job.message
        run.result = run.analysis.result or {}       # an untuned run still has its report
        if run.analysis.outcome != "succeeded":
            return run.analysis.message
        message = str(run.result.get("message", "done"))
        if not run.request.get("apply"):
            return message
        values = run.result.get("apply", {})
        channel = self._node.channels[index]
        params = [Parameter(f"{channel}.{key}",
                            value=value if isinstance(value, str) else float(value))
                  for key, value in values.items()]
        outcomes = self._node.set_parameters_atomically(params)
        if not outcomes.successful:
            return f"{message}; not applied: {outcomes.reason}"
        run.applied = True
        return f"{message}; applied"

    def _result(self, index: int | None, job: Job | None, message: str) -> Any:
        result = Commission.Result()
        result.message = message
        run = self._runs.pop(index, None) if index is not None else None
        if run is None:
            return result
        if run.analysis is not None and run.analysis.outcome is None:
            run.analysis.close()                    # a goal ended while the child ran
        try:
            run.directory.rmdir()                   # only if nothing was written to it
        except OSError:
            pass
        r = run.result
        result.summary = str(r.get("summary", ""))
        result.report_path = str(r.get("report_path", ""))
        result.params_file = str(r.get("params_file", ""))
        result.rollback_file = str(r.get("rollback_file", ""))
        result.names = [str(n) for n in r.get("names", [])]
        result.old_values = [_number(v) for v in r.get("old_values", [])]
        result.new_values = [_number(v) for v in r.get("new_values", [])]
        result.applied = run.applied
        return result

    def close(self) -> None:
        """End every analysis still running (the node is going down)."""
        for run in self._runs.values():
            if run.analysis is not None:
                run.analysis.close()

"""commission: run ``~/commission`` on a running controller and show its progress.

::

    commission --channel pinch                       # measure, tune, write params + report
    commission --channel pinch --apply               # ... and apply the tuned settings
    commission --channel pinch --dry-run             # measure and report only
    commission --channel pinch --band 0.3 10 --noise-budget 0.002 --passivity-margin 0.1
    commission --rollback seaforce_commissioning/pinch-20261204T101500Z   # undo a run's tuning

The finger must be free in the air. A progress bar (phase, what is measured, percent) goes to
stderr; the summary table, the report's path and the params files to stdout. Ctrl-C or
SIGTERM cancels the goal (the controller zeroes the excitation's torque) and waits for it to
end.
``--rollback RUN_DIR`` (or the path of a ``rollback.yaml``) sets the values a run's tuning
replaced back on the controller in one atomic set (``rollback.yaml``, as rclpy's parameter
client loads a params file): validated as a whole configuration, all of them or none.
Exit status: 0 succeeded, 1 the goal (or the rollback) was refused, aborted or canceled, 2
bad arguments or no controller answering, 130 interrupted twice.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import signal
import sys
import time

__all__ = ["main", "build_parser"]

#: s to wait for the action server to appear
SERVER_TIMEOUT = 20.0


def build_parser() -> argparse.ArgumentParser:
    from ..identification.output import positive_float
    p = argparse.ArgumentParser(
        prog="commission", description="Commission one channel of a running controller: "
        "excite the free finger, identify the plant from motor state and pressure, predict "
        "the Z-width, tune the DOB and the hold, write a report.")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--channel", help="the channel to commission")
    what.add_argument("--rollback", metavar="RUN_DIR",
                      help="set the values a run's tuning replaced back, atomically (its "
                           "rollback.yaml)")
    p.add_argument("--controller", default="/controller",
                   help="the controller node's name (default /controller)")
    p.add_argument("--band", nargs=2, type=positive_float, metavar=("LOW", "HIGH"),
                   help="band the tuning maximises the Z-width over [rad/s] (default: the "
                        "channel's commissioning.band_low/band_high)")
    p.add_argument("--noise-budget", type=positive_float,
                   help="RMS motor torque the DOB may add from sensor noise [N m]")
    p.add_argument("--passivity-margin", type=positive_float,
                   help="1-sigmas of the identified m, b, k against which the tuned DOB must "
                        "still satisfy eq. 28")
    p.add_argument("--allow-guard", action="store_true",
                   help="allow settings outside eq. 28 that the passivity guard carries")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--apply", action="store_true",
                      help="apply the tuned settings bumplessly when done")
    mode.add_argument("--dry-run", action="store_true",
                      help="measure and report only: no params file, nothing applied")
    p.add_argument("--timeout", type=positive_float, default=600.0,
                   help="give up after this many seconds [s] (default 600)")
    return p


class ProgressBar:
    """One updating line on a terminal (``[commission] excite  42% |#####     | 12.5 Hz``),
    else a line per phase and per 10 %."""

    def __init__(self, stream=None) -> None:
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last: tuple[str, int] = ("", -1)
        self._drawn = False
        self.t0 = time.monotonic()

    def show(self, phase: str, progress: float, measuring: str) -> None:
        fraction = min(max(progress if math.isfinite(progress) else 0.0, 0.0), 1.0)
        width = 24
        filled = int(round(fraction * width))
        line = (f"[commission] {phase:9s}{100 * fraction:4.0f}% |{'#' * filled}"
                f"{' ' * (width - filled)}| {measuring} ({time.monotonic() - self.t0:.0f} s)")
        if self.tty:
            self.stream.write("\r" + line[:120].ljust(120))
            self.stream.flush()
            self._drawn = True
            return
        key = (phase, int(10 * fraction))
        if key != self._last:
            self._last = key
            print(line, file=self.stream, flush=True)

    def close(self) -> None:
        """End the updating line (once; nothing when none was drawn)."""
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


def _goal(args, action_type):
    goal = action_type.Goal()
    goal.channel = args.channel
    if args.band:
        goal.band_low, goal.band_high = (float(v) for v in args.band)
    goal.noise_budget = float(args.noise_budget or 0.0)
    goal.passivity_margin = float(args.passivity_margin or 0.0)
    goal.allow_guard = bool(args.allow_guard)
    goal.apply = bool(args.apply)
    goal.dry_run = bool(args.dry_run)
    return goal


def _name_problem(controller: str) -> str:
    """Why ``controller`` names no node whose ``<controller>/commission`` action a client can
    reach (rcl's own words, one line), or ''."""
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name
    try:
        validate_full_topic_name(expand_topic_name(controller.rstrip("/") + "/commission",
                                                   "commission_cli", "/"))
    except (InvalidTopicNameException, ValueError) as exc:
        reason = str(exc).split(", at /")[0].splitlines()[0]
        return f"not a ROS node name ({reason.split(': ', 1)[-1].rstrip(':')})"
    return ""


def _spin_until(executor, future, deadline) -> bool:
    while not future.done():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def _rollback_file(where: str) -> tuple[pathlib.Path | None, str]:
    """(the rollback file of a run directory or the file itself, '') or (None, why not)."""
    from ..commissioning.analyse import ROLLBACK_FILE
    from ..nodes.ros_common import params_file_problem
    path = pathlib.Path(where)
    if path.is_dir():
        path = path / ROLLBACK_FILE
        if not path.exists():
            return None, f"no {ROLLBACK_FILE} in {where} (a dry run or an untuned run writes none)"
    problem = params_file_problem(str(path))
    return (None, f"{path}: {problem}") if problem else (path, "")


def _answer(executor, send, deadline, resend_after: float = 2.0):
    """The result of the request ``send()`` makes (a Future), re-sent every ``resend_after``
    s while unanswered (a server that has not yet discovered this client drops its answer;
    only for idempotent requests); None at ``deadline``."""
    while time.monotonic() < deadline:
        future = send()
        if _spin_until(executor, future, min(deadline, time.monotonic() + resend_after)):
            return future.result()
    return None


def rollback(args, path: pathlib.Path, node, executor) -> int:
    """``--rollback``: the rollback file ``path`` set on the controller atomically (rclpy's
    parameter client loads it, as ``ros2 param load`` does, but in one set)."""
    from rclpy.parameter import parameter_dict_from_yaml_file, parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    values = parameter_dict_from_yaml_file(str(path), use_wildcard=True)
    client = AsyncParameterClient(node, args.controller)
    deadline = time.monotonic() + args.timeout
    before = None
    if client.wait_for_services(timeout_sec=SERVER_TIMEOUT):
        before = _answer(executor, lambda: client.get_parameters(list(values)), deadline)
    if before is None:
        print(f"commission: error: no answer from the parameter services of "
              f"{args.controller} (is controller_node running, and in this ROS_DOMAIN_ID?)",
              file=sys.stderr)
        return 2
    loaded = _answer(executor, lambda: client.load_parameter_file_atomically(
        str(path), use_wildcard=True), deadline)
    if loaded is None:
        print("commission: error: the controller did not answer the rollback", file=sys.stderr)
        return 2
    if not loaded.result.successful:
        print(f"[commission] rollback refused, nothing changed: {loaded.result.reason}",
              file=sys.stderr)
        return 1
    for (name, new), old in zip(values.items(), before.values):
        print(f"{name}: {parameter_value_to_python(old)} -> "
              f"{parameter_value_to_python(new.value)}")
    print(f"[commission] rolled back {len(values)} values on {args.controller} ({path})")
    return 0


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run(args) -> int:
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor
    from seaforce_msgs.action import Commission

    if args.band and not args.band[0] < args.band[1]:
        print(f"commission: error: --band {args.band[0]:g} {args.band[1]:g}: LOW must be "
              "below HIGH", file=sys.stderr)
        return 2
    problem = _name_problem(args.controller)
    if problem:
        print(f"commission: error: --controller {args.controller}: {problem}", file=sys.stderr)
        return 2
    path, problem = _rollback_file(args.rollback) if args.rollback else (None, "")
    if problem:
        print(f"commission: error: --rollback {problem}", file=sys.stderr)
        return 2
    # rclpy's own SIGINT/SIGTERM handlers would shut its context down before the cancel
    # below could be sent (a traceback, and the excitation went on with nobody watching):
    # both signals raise KeyboardInterrupt here instead, so the goal is canceled
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupt)
    node = rclpy.create_node("commission_cli")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    bar = ProgressBar()
    try:
        if path is not None:
            return rollback(args, path, node, executor)
        name = args.controller.rstrip("/") + "/commission"
        client = ActionClient(node, Commission, name)
        if not client.wait_for_server(timeout_sec=SERVER_TIMEOUT):
            print(f"commission: error: no action server {name} within {SERVER_TIMEOUT:g} s "
                  "(is controller_node running, and in this ROS_DOMAIN_ID?)", file=sys.stderr)
            return 2

        def on_feedback(msg) -> None:
            f = msg.feedback
            what = f.measuring
            if f.phase == "excite":
                what += f" {f.frequency:.2f} Hz, {f.amplitude:.3g} N m"
            bar.show(f.phase, f.progress, what)

        deadline = time.monotonic() + args.timeout
        sent = client.send_goal_async(_goal(args, Commission), feedback_callback=on_feedback)
        result_future = None
        try:
            if not _spin_until(executor, sent, deadline):
                print("commission: error: the goal was not answered", file=sys.stderr)
                return 2
            handle = sent.result()
            result_future = handle.get_result_async()
            finished = _spin_until(executor, result_future, deadline)
        except KeyboardInterrupt:
            # from the goal's sending on (a goal accepted after the tool left would excite the
            # finger with nobody watching); further signals wait for the cancel
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, signal.SIG_IGN)
            bar.close()
            print("[commission] canceling (the excitation's torque is zeroed; further "
                  "Ctrl-C wait for it, up to 50 s) ...", file=sys.stderr, flush=True)
            if not _spin_until(executor, sent, time.monotonic() + 10.0):
                print("commission: error: the goal was not answered within 10 s; should the "
                      f"controller take it later, cancel it on {name}", file=sys.stderr)
                return 1
            handle = sent.result()
            if not handle.accepted:
                print("[commission] the goal was refused: nothing runs", file=sys.stderr)
                return 1
            if result_future is None:
                result_future = handle.get_result_async()
            cancel = handle.cancel_goal_async()
            _spin_until(executor, cancel, time.monotonic() + 10.0)
            finished = _spin_until(executor, result_future, time.monotonic() + 30.0)
        bar.close()
        if not finished:
            print(f"commission: error: no result within {args.timeout:g} s; canceling",
                  file=sys.stderr)
            cancel = handle.cancel_goal_async()
            _spin_until(executor, cancel, time.monotonic() + 10.0)
            return 1
        wrapped = result_future.result()
        result = wrapped.result
        from action_msgs.msg import GoalStatus
        ok = wrapped.status == GoalStatus.STATUS_SUCCEEDED
        if result.summary:
            print(result.summary)
        for label, path in (("report", result.report_path), ("params file", result.params_file),
                            ("rollback file", result.rollback_file)):
            if path:
                print(f"{label}: {path}")
        status = {GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_CANCELED:
                  "canceled"}.get(wrapped.status, "aborted")
        print(f"[commission] {args.channel}: {status}: {result.message}"
              + (" (applied)" if result.applied else ""),
              file=sys.stdout if ok else sys.stderr)
        return 0 if ok else 1
    finally:
        bar.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except KeyboardInterrupt:
        print("commission: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

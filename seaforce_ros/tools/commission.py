"""commission: run ``~/commission`` on a running controller and show its progress.

::

    commission --channel pinch                       # measure, tune, write params + report
    commission --channel pinch --apply               # ... and apply the tuned settings
    commission --channel pinch --dry-run             # measure and report only
    commission --channel pinch --band 0.3 10 --noise-budget 0.002 --passivity-margin 0.1

The finger must be free in the air. A progress bar (phase, what is measured, percent) goes to
stderr; the summary table, the report's path and the params files to stdout. Ctrl-C cancels
the goal (the controller zeroes the excitation's torque) and waits for it to end.
Exit status: 0 succeeded, 1 the goal was refused, aborted or canceled, 2 bad arguments or no
controller answering, 130 interrupted twice.
"""
from __future__ import annotations

import argparse
import math
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
    p.add_argument("--channel", required=True, help="the channel to commission")
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
    rclpy.init()
    node = rclpy.create_node("commission_cli")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    bar = ProgressBar()
    try:
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
        if not _spin_until(executor, sent, deadline):
            print("commission: error: the goal was not answered", file=sys.stderr)
            return 2
        handle = sent.result()
        result_future = handle.get_result_async()
        try:
            finished = _spin_until(executor, result_future, deadline)
        except KeyboardInterrupt:
            bar.close()
            print("[commission] canceling (the excitation's torque is zeroed) ...",
                  file=sys.stderr, flush=True)
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

"""Outputs of the offline tools: ROS params file, tables, progress, output-path checks."""

from __future__ import annotations

import datetime
import os
import pathlib
import sys
import time

import yaml

from .errors import IdentificationError

__all__ = ["check_output_file", "check_output_dir", "write_params_file", "format_table",
           "Progress", "read_params_file"]


def check_output_file(path):
    """Fail early (before long work) if ``path`` cannot be written."""
    p = pathlib.Path(path)
    if p.is_dir():
        raise IdentificationError(f"cannot write {p}: it is a directory")
    parent = p.parent if str(p.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise IdentificationError(f"cannot write {p}: directory {parent} does not exist")
    if p.exists() and not os.access(p, os.W_OK):
        raise IdentificationError(f"cannot write {p}: permission denied")
    if not p.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise IdentificationError(f"cannot write {p}: directory {parent} is not writable")
    return p


def check_output_dir(path):
    """Create ``path`` (parents too) or fail with a clear message."""
    p = pathlib.Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise IdentificationError(f"cannot create the directory {p}: {exc.strerror}") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise IdentificationError(f"cannot write into {p}: permission denied")
    return p


def _float(v):
    return float(f"{float(v):.6g}")


def write_params_file(path, channel, plant=None, dahl=None, comments=(), merge=True):
    """Write ``/**: ros__parameters: <channel>: {plant: ..., dahl: ...}``.

    ``plant`` is a PlantParams (or None), ``dahl`` a dict ``{sigma, coulomb_force,
    exponent}`` (or None). With ``merge``, values already in an existing file (other channels,
    other keys) are kept and only the given groups are replaced.
    """
    p = check_output_file(path)
    data = {}
    if merge and p.exists():
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except (OSError, yaml.YAMLError):
            data = {}
        if not isinstance(data, dict):
            data = {}
    node = data.setdefault("/**", {}).setdefault("ros__parameters", {})
    ch = node.setdefault(channel, {})
    if plant is not None:
        ch["plant"] = {k: _float(getattr(plant, k)) for k in (
            "motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
            "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")}
    if dahl is not None:
        ch["dahl"] = {k: _float(dahl[k]) for k in ("sigma", "coulomb_force", "exponent")}
    header = [f"# seaforce_ros parameters identified {datetime.datetime.now():%Y-%m-%d %H:%M}",
              "# load with: --ros-args --params-file " + p.name]
    header += [f"# {c}" for c in comments]
    text = "\n".join(header) + "\n" + yaml.safe_dump(data, sort_keys=False)
    try:
        p.write_text(text)
    except OSError as exc:
        raise IdentificationError(f"cannot write {p}: {exc.strerror}") from None
    return p


def read_params_file(path, channel):
    """``(plant dict, dahl dict)`` of ``channel`` from a params file (any node section)."""
    p = pathlib.Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise IdentificationError(f"cannot read {p}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise IdentificationError(f"{p} is not valid YAML: {exc}") from None
    plant, dahl = {}, {}
    for section in (data or {}).values():
        params = (section or {}).get("ros__parameters", {}) if isinstance(section, dict) else {}
        ch = params.get(channel, {}) if isinstance(params, dict) else {}
        if isinstance(ch, dict):
            plant.update(ch.get("plant", {}) or {})
            dahl.update(ch.get("dahl", {}) or {})
        for key, value in (params.items() if isinstance(params, dict) else ()):
            if key.startswith(channel + ".plant."):
                plant[key.split(".", 2)[2]] = value
            elif key.startswith(channel + ".dahl."):
                dahl[key.split(".", 2)[2]] = value
    return plant, dahl


def format_table(headers, rows, formats):
    """Plain-text table; ``formats`` per column (format spec or None for str)."""
    cells = [[(format(v, f) if f else str(v)) for v, f in zip(row, formats)] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(headers)]
    line = "  ".join(h.ljust(w) for h, w in zip(headers, widths))
    out = [line, "-" * len(line)]
    out += ["  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in
                      enumerate(zip(r, widths))) for r in cells]
    return "\n".join(out)


class Progress:
    """Progress lines on stderr (``[tool] 42% message (3.1 s)``), at most every 0.5 s."""

    def __init__(self, tool, stream=None, quiet=False):
        self.tool = tool
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.t0 = time.monotonic()
        self._last = -1.0

    def __call__(self, message, fraction=None):
        if self.quiet:
            return
        now = time.monotonic()
        if fraction is not None and fraction < 1.0 and now - self._last < 0.5:
            return
        self._last = now
        pct = "" if fraction is None else f"{100 * min(max(fraction, 0), 1):3.0f}% "
        print(f"[{self.tool}] {pct}{message} ({now - self.t0:.1f} s)", file=self.stream,
              flush=True)

    def stage(self, lo, hi):
        """A callback mapping a sub-task's 0..1 onto lo..hi."""
        def cb(message, fraction=None):
            self(message, None if fraction is None else lo + (hi - lo) * fraction)
        return cb


def run_cli(prog, run, args):
    """Run an offline tool's ``run(args)``: a bad input is one ``prog: error: ...`` line and exit
    code 2 (never a stack trace), Ctrl-C exit code 130."""
    from ..core.errors import SeaforceError

    try:
        return run(args)
    except (IdentificationError, SeaforceError, ValueError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130

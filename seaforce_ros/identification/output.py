"""Outputs of the offline tools: ROS params file, tables, progress, output-path checks."""

from __future__ import annotations

import argparse
import datetime
import math
import os
import pathlib
import sys
import time
from typing import (Any, Callable, Dict, Iterable, Mapping, Optional, Sequence, TextIO, Tuple,
                    TypeVar, Union)

import yaml

from ..core.params import DahlParams, PlantParams
from .errors import IdentificationError
from .params_file import (ALL_NODES, HEADER_MARK, PathLike, channel_groups, load, plant_params,
                          read_text, update_text, where)

__all__ = ["check_output_file", "check_output_dir", "check_params_update", "write_params_file",
           "write_values_file",
           "format_table", "Progress", "read_params_file", "read_plant", "positive_float",
           "run_cli"]

_Args = TypeVar("_Args")


def check_output_file(path: PathLike) -> pathlib.Path:
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


def check_output_dir(path: PathLike) -> pathlib.Path:
    """Create ``path`` (parents too) or fail with a clear message."""
    p = pathlib.Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise IdentificationError(f"cannot create the directory {p}: {exc.strerror}") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise IdentificationError(f"cannot write into {p}: permission denied")
    return p


def _float(v: float) -> float:
    return float(f"{float(v):.6g}")


def _values(channel: str, plant: Optional[PlantParams] = None,
            dahl: Optional[Mapping[str, float]] = None) -> Dict[str, float]:
    """``{dotted parameter name: value}`` of the groups to write (6 significant digits)."""
    values: Dict[str, float] = {}
    if plant is not None:
        values.update({f"{channel}.{spec.name}": _float(getattr(plant, spec.attribute))
                       for spec in PlantParams.SPECS})
    if dahl is not None:
        values.update({f"{channel}.{spec.name}": _float(dahl[spec.attribute])
                       for spec in DahlParams.SPECS})
    return values


def _existing_text(p: pathlib.Path, option: Optional[str]) -> Optional[str]:
    """The text of an existing, non-blank output file (None: write a new file)."""
    if not p.exists():
        return None
    text = read_text(p, option)
    return text if text.strip() else None


def check_params_update(path: PathLike, channel: str, plant: bool = False, dahl: bool = False,
                        option: Optional[str] = None) -> pathlib.Path:
    """Fail early (before long work) if the params file ``path`` cannot be written, or exists
    with a layout :func:`write_params_file` cannot update in place."""
    p = check_output_file(path)
    text = _existing_text(p, option)
    if text is not None:
        values: Dict[str, float] = {}
        for wanted, group in ((plant, PlantParams), (dahl, DahlParams)):
            if wanted:
                values.update({f"{channel}.{spec.name}": 1.0 for spec in group.SPECS})
        update_text(text, values, where(p, option))
    return p


def write_params_file(path: PathLike, channel: str, plant: Optional[PlantParams] = None,
                      dahl: Optional[Mapping[str, float]] = None, comments: Iterable[str] = (),
                      merge: bool = True, option: Optional[str] = None) -> pathlib.Path:
    """Write ``<channel>.plant.*`` (``plant``: a PlantParams) and ``<channel>.dahl.*``
    (``dahl``: a dict ``{sigma, coulomb_force, exponent}``) for ``--ros-args --params-file``
    (:func:`write_values_file`)."""
    return write_values_file(path, _values(channel, plant, dahl), comments, merge, option)


def write_values_file(path: PathLike, values: Mapping[str, Union[float, str]],
                      comments: Iterable[str] = (), merge: bool = True,
                      option: Optional[str] = None, flat: bool = False) -> pathlib.Path:
    """Write ``values`` (``{dotted name: float or str}``, e.g. ``pinch.dob.cutoff``) as a
    params file for ``--ros-args --params-file``.

    A new file (or, without ``merge``, any file) becomes ``/**: ros__parameters: ...`` under a
    header of ``comments``; ``flat``: one dotted key per value, in ``values``' order (the
    order ``ros2 param load`` sets them in), else nested by the dots. An existing file is updated in place
    (:func:`~.params_file.update_text`): only these values change; every comment, other
    parameter and the layout stay. A file whose layout cannot be updated safely is refused
    (ParamsFileError, naming ``option`` and the file) and left as it is. The file is written
    under a temporary name and renamed: it is never half-written (a full disk).
    """
    p = check_output_file(path)
    w = where(p, option)
    header = [f"{HEADER_MARK} {datetime.datetime.now():%Y-%m-%d %H:%M}",
              "# load with: --ros-args --params-file " + p.name]
    header += [f"# {c}" for c in comments]
    text = _existing_text(p, option) if merge else None
    if text is None:
        data: Dict[str, Any] = {}
        for name, value in values.items():
            node = data.setdefault(ALL_NODES, {}).setdefault("ros__parameters", {})
            parts = [name] if flat else name.split(".")
            for part in parts[:-1]:
                node = node.setdefault(part, {})
            node[parts[-1]] = value
        text = "\n".join(header) + "\n" + yaml.safe_dump(data, sort_keys=False)
    else:
        text = update_text(text, values, w, header=header)
    tmp = p.with_name(p.name + ".part")
    try:
        tmp.write_text(text)
        os.replace(tmp, p)
    except OSError as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise IdentificationError(f"{w}: cannot write it ({exc.strerror})") from None
    return p


def read_params_file(path: PathLike, channel: str,
                     option: Optional[str] = None) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """``(plant dict, dahl dict)`` of ``channel`` from a params file (every node section).

    Errors (ParamsFileError, naming ``option`` and the file): missing file, a directory, not
    YAML, not a ROS params file, no parameters of ``channel`` (the message lists the channels
    the file has)."""
    return channel_groups(load(path, option), channel, where(path, option))


def read_plant(path: PathLike, channel: str, option: Optional[str] = None) -> PlantParams:
    """PlantParams of ``channel`` in a params file (all eight of Table I)."""
    plant, _ = read_params_file(path, channel, option)
    return plant_params(plant, where(path, option), channel)


def format_table(headers: Sequence[str], rows: Iterable[Sequence[Any]],
                 formats: Sequence[Optional[str]]) -> str:
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

    def __init__(self, tool: str, stream: Optional[TextIO] = None, quiet: bool = False) -> None:
        self.tool = tool
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.t0 = time.monotonic()
        self._last = -1.0

    def __call__(self, message: str, fraction: Optional[float] = None) -> None:
        if self.quiet:
            return
        now = time.monotonic()
        if fraction is not None and fraction < 1.0 and now - self._last < 0.5:
            return
        self._last = now
        pct = "" if fraction is None else f"{100 * min(max(fraction, 0), 1):3.0f}% "
        print(f"[{self.tool}] {pct}{message} ({now - self.t0:.1f} s)", file=self.stream,
              flush=True)

    def stage(self, lo: float, hi: float) -> Callable[[str, Optional[float]], None]:
        """A callback mapping a sub-task's 0..1 onto lo..hi."""
        def cb(message: str, fraction: Optional[float] = None) -> None:
            self(message, None if fraction is None else lo + (hi - lo) * fraction)
        return cb


def positive_float(text: str) -> float:
    """argparse ``type``: a finite number > 0 (argparse then reports ``argument --x: ...``
    and exits 2)."""
    value: Optional[float]
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is None or not math.isfinite(value) or not value > 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def run_cli(prog: str, run: Callable[[_Args], int], args: _Args) -> int:
    """Run an offline tool's ``run(args)``: a bad input is one ``prog: error: ...`` line and exit
    code 2 (never a stack trace), Ctrl-C exit code 130."""
    from ..bags.errors import BagError
    from ..core.errors import SeaforceError

    try:
        return run(args)
    except (IdentificationError, BagError, SeaforceError, ValueError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130

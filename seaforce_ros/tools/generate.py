"""Files generated from the parameter schema (:mod:`seaforce_ros.core.schema`).

* ``docs/parameters.md``: the parameter reference, one table per node, every row with its
  type, default, unit, range or allowed values, read-only flag and description; then the
  bus YAML's keys (:data:`seaforce_ros.ethercat.bus_config.KEYS`);
* the ``<choice>`` lists of the launch files' arguments that set a parameter with allowed
  values (``wrist_mode`` -> ``<channel>.mode``, ``loop``, ...): rewritten in place, the rest
  of each file untouched.

``python -m seaforce_ros.tools.generate`` writes them; ``--check`` only says which are stale
(exit 1), as the test suite does. Run it after adding or changing a row.
"""
from __future__ import annotations

import argparse
import pathlib
import re
import sys
from typing import Dict, List, Optional, Sequence, Tuple

from ..core import schema
from ..core.schema import Spec

__all__ = ["ROOT", "parameters_markdown", "launch_choices", "outputs", "main"]

#: The source tree (this file is seaforce_ros/tools/generate.py).
ROOT = pathlib.Path(__file__).resolve().parents[2]

_NODE_TITLES = (
    (schema.CONTROLLER, "controller_node (node `controller`)"),
    (schema.SIM, "sim_node (node `sim`)"),
    (schema.HARDWARE, "hardware_node (node `hardware`)"),
    (schema.RECORDER, "bag_recorder (node `bag_recorder`)"),
    (schema.BRINGUP, "bringup and hardware_bringup (added to the controller)"),
)

_HEAD = """# Parameter reference

Generated from the parameter schema (`seaforce_ros/core/schema.py` and the groups it lists) by
`python -m seaforce_ros.tools.generate`; a test fails when this file is stale. Do not edit it:
change the row.

Every value is checked against its row when a node starts and on every later set (type,
finiteness, range, allowed values); a refused value is answered with the reason. Rules
*between* parameters -- the DOB's passivity (eq. 28), the impedance targets against the hose,
`friction.position_max > friction.position_min` -- are checked on the whole channel
configuration, which is applied at the start of the next control cycle or not at all.

Per-channel keys are written `<channel>.<key>` (`channels` names the channels: `pinch.mode`).
Ranges are intervals: `[a, b]` closed, `(a, b]` open at a. *ro*: read-only, set at start
(`--params-file`, `-p`), refused afterwards.
"""


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _default(spec: Spec) -> str:
    if spec.default is None:
        return "*" + (spec.default_note or "resolved at start") + "*"
    value = spec.default
    if spec.type is list:
        return "`[" + ", ".join(value) + "]`"
    if spec.type is bool:
        return "`true`" if value else "`false`"
    if spec.type is str:
        return f"`{value}`" if value else ("*" + spec.default_note + "*" if spec.default_note
                                           else "`''`")
    if spec.type is float:
        return f"`{value:.6g}`"
    return f"`{value}`"


def _allowed(spec: Spec) -> str:
    if spec.choices:
        return ", ".join(f"`{c}`" for c in spec.choices)
    return spec.range_text()


def _table(specs: Sequence[Spec], prefix: str) -> List[str]:
    lines = ["| key | type | default | unit | range / values | ro | description |",
             "|---|---|---|---|---|---|---|"]
    for spec in specs:
        kind = {float: "double", int: "integer", bool: "bool", str: "string",
                list: "string[]"}[spec.type]
        symbol = f"{spec.symbol}: " if spec.symbol else ""
        lines.append(f"| `{prefix}{spec.name}` | {kind} | {_default(spec)} | "
                     f"{_cell(spec.unit)} | {_allowed(spec)} | {'ro' if spec.read_only else ''} "
                     f"| {_cell(symbol + spec.description)} |")
    return lines


def parameters_markdown() -> str:
    """The text of ``docs/parameters.md``."""
    # the sim's model and true-plant rows are the controller's, declared again (see settings)
    from ..core.settings import SIM_MODEL_GROUPS, SIM_PREFIX
    out = [_HEAD]
    for node, title in _NODE_TITLES:
        own = schema.node_rows(node, per_channel=False)
        per_channel = schema.node_rows(node, per_channel=True)
        out.append(f"## {title}\n")
        if own:
            out.append("Its own parameters:\n")
            out += _table(own, "")
            out.append("")
        if per_channel:
            out.append("Per channel:\n")
            out += _table(per_channel, "<channel>.")
            out.append("")
        if node == schema.SIM:
            keys = ", ".join(f"`{g.PREFIX}.*`" for g in SIM_MODEL_GROUPS)
            out.append(f"The sim also declares the controller's model ({keys}, read-only, the "
                       "controller's rows above) and the plant it simulates under "
                       f"`<channel>.{SIM_PREFIX}` (`<channel>.{SIM_PREFIX}plant.hose_stiffness`"
                       ", ...): the same rows, default the model's value, changeable at run "
                       "time (a plant that drifts, or a controller on a wrong model).\n")
    out += _bus_yaml()
    return "\n".join(out).rstrip() + "\n"


def _bus_yaml() -> List[str]:
    """The bus YAML's keys (hardware_node's ``bus_config``): its rows in
    :data:`seaforce_ros.ethercat.bus_config.KEYS`."""
    from ..ethercat.bus_config import keys_markdown
    return ["## Bus YAML (hardware_node's `bus_config`)\n",
            "The EtherCAT bus, read at configure: each slave is checked, and configured at "
            "PRE-OP over CoE (start-up SDOs, the PDO mapping written and read back entry by "
            "entry, distributed clocks), before any drive is enabled. A misspelt or unknown key "
            "is refused with the known ones. How to write one for a new rig: "
            "[ethercat-hardware.md](ethercat-hardware.md). Generated from "
            "`seaforce_ros/ethercat/bus_config.py` (`KEYS`).\n"] + keys_markdown()


# --- launch files ------------------------------------------------------------------------------
_PARAM = re.compile(r'<param\s+name="([^"]+)"\s+value="\$\(var\s+([\w-]+)\)"')
_ARG = re.compile(r'(?P<open>^(?P<indent>[ \t]*)<arg\s+name="(?P<name>[\w-]+)"[^>]*?(?<!/)>)'
                  r'(?P<body>.*?)(?P<close>^[ \t]*</arg>)', re.S | re.M)
_CHOICE = re.compile(r'^[ \t]*<choice\s+value="[^"]*"\s*/>[ \t]*\n', re.M)


def _spec_for(name: str, channels: Sequence[str], rows: Dict[str, Spec]) -> Optional[Spec]:
    if name in rows:
        return rows[name]
    head, _, rest = name.partition(".")
    return rows.get(rest) if head in channels and rest in rows else None


def launch_choices(text: str, channels: Sequence[str] = ("wrist", "pinch")) -> str:
    """``text`` (a launch XML file) with the ``<choice>`` list of every argument that sets a
    parameter with allowed values replaced by those values, in the schema's order."""
    wanted: Dict[str, Tuple[str, ...]] = {}
    rows = schema.by_key()          # built once per file, not once per <param>
    for key, arg in _PARAM.findall(text):
        spec = _spec_for(key, channels, rows)
        if spec is not None and spec.choices:
            wanted[arg] = spec.choices

    def fix(match: "re.Match[str]") -> str:
        choices = wanted.get(match.group("name"))
        if choices is None:
            return match.group(0)
        body = match.group("body")
        indent = match.group("indent") + "  "
        kept = _CHOICE.sub("", body)
        lines = "".join(f'{indent}<choice value="{c}"/>\n' for c in choices)
        if not kept.strip():
            kept = "\n"
        return match.group("open") + kept + lines + match.group("close")

    return _ARG.sub(fix, text)


def outputs(root: pathlib.Path = ROOT) -> Dict[pathlib.Path, str]:
    """``{path: the text it should have}`` of every generated file under ``root``."""
    files = {root / "docs" / "parameters.md": parameters_markdown()}
    for path in sorted((root / "launch").glob("*.launch.xml")):
        files[path] = launch_choices(path.read_text())
    return files


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m seaforce_ros.tools.generate",
        description="Write the files generated from the parameter schema (docs/parameters.md, "
                    "the launch files' <choice> lists).")
    parser.add_argument("--check", action="store_true",
                        help="write nothing; list the stale files and exit 1 if there are any")
    parser.add_argument("--root", type=pathlib.Path, default=ROOT,
                        help="source tree (default: this checkout)")
    args = parser.parse_args(argv)
    stale = []
    for path, text in outputs(args.root).items():
        current = path.read_text() if path.exists() else None
        if current == text:
            continue
        stale.append(path)
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    for path in stale:
        print(f"{'stale' if args.check else 'wrote'}: {path.relative_to(args.root)}")
    if args.check and stale:
        print("run: python -m seaforce_ros.tools.generate", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

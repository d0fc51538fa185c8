"""ROS 2 params files for the offline tools: read a channel's plant and Dahl parameters, and
update values in a user's file without losing what the user wrote.

Reading (:func:`load`, :func:`channel_groups`, :func:`plant_params`, :func:`dahl_params`): a
file that is missing, a directory, not YAML, not a mapping of node sections with
``ros__parameters``, without the channel asked for, or with a parameter that is unknown,
missing or not a number is a :class:`~.errors.ParamsFileError` naming the file (and the
command-line option that gave it) -- never a stack trace, never a silent fall-back to
defaults.

Updating (:func:`update_text`): values are changed in place, line by line, keeping every
comment, blank line, key order, quoting and indentation. It follows the block-mapping
``key: value`` layout of ``config/gripper.yaml`` (nested or dotted keys, trailing comments,
several node sections); a parameter that is absent is added to its group (or a new ``/**``
section). Where the value to change is written in another style (flow mapping ``{...}``,
over several lines, behind an anchor or alias) it refuses with the reason and the file stays
as it is. Every result is checked by parsing it: it must read back as the old file with
exactly the new values, else it is refused too.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import re
from typing import Any, Dict, List, Mapping, Optional, Sequence, Set, Tuple, Union

import yaml

from ..core.errors import SeaforceError
from ..core.params import DahlParams, PlantParams
from .errors import ParamsFileError

__all__ = ["PLANT_KEYS", "DAHL_KEYS", "where", "read_text", "parse", "load", "sections",
           "flatten", "channel_groups", "controller_view", "ControllerView", "plant_params",
           "dahl_params", "format_value", "update_text"]

#: The fields of the groups identify writes (their keys: ``plant.<field>``, ``dahl.<field>``).
PLANT_KEYS = tuple(spec.attribute for spec in PlantParams.SPECS)
DAHL_KEYS = tuple(spec.attribute for spec in DahlParams.SPECS)
#: the section identify writes to (every node reads it)
ALL_NODES = "/**"
_EXAMPLE = "e.g. '/**:' with 'ros__parameters:' under it"

#: A path as the functions here take it.
PathLike = Union[str, "os.PathLike[str]"]
#: A parsed YAML mapping (keys and values as the file has them: dynamic).
YamlMapping = Dict[Any, Any]
#: A key path from the top of a YAML document.
KeyPath = Tuple[Any, ...]


def where(path: PathLike, option: Optional[str] = None) -> str:
    """How a message names the file: ``--truth t.yaml`` or ``t.yaml``."""
    return f"{option} {path}" if option else str(path)


def _kind(value: Any) -> str:
    if value is None:
        return "empty"
    if isinstance(value, bool):
        return f"a boolean ({value})"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    return type(value).__name__


def read_text(path: PathLike, option: Optional[str] = None) -> str:
    """The text of a params file, or a ParamsFileError saying why not."""
    w = where(path, option)
    p = pathlib.Path(path)
    if p.is_dir():
        raise ParamsFileError(f"{w}: is a directory, not a params file")
    try:
        return p.read_text()
    except FileNotFoundError:
        raise ParamsFileError(f"{w}: no such file") from None
    except UnicodeDecodeError:
        raise ParamsFileError(f"{w}: not a text file") from None
    except OSError as exc:
        raise ParamsFileError(f"{w}: cannot read it ({exc.strerror})") from None


def _yaml_reason(exc: yaml.YAMLError) -> str:
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if mark is not None and problem:
        return f"{problem} at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(exc).split())


def _safe_load(text: str, w: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ParamsFileError(f"{w}: not valid YAML ({_yaml_reason(exc)})") from None


def parse(text: str, w: str) -> YamlMapping:
    """The parsed params file (a dict with at least one ``ros__parameters`` mapping)."""
    data = _safe_load(text, w)
    if data is None:
        raise ParamsFileError(f"{w}: the file is empty; a ROS params file maps node names to "
                              f"ros__parameters ({_EXAMPLE})")
    if not isinstance(data, dict):
        raise ParamsFileError(f"{w}: not a ROS params file: the top level is {_kind(data)}, "
                              f"not a mapping of node names to ros__parameters ({_EXAMPLE})")
    sections(data, w)
    return data


def load(path: PathLike, option: Optional[str] = None) -> YamlMapping:
    """:func:`parse` of the file at ``path``; messages name ``option`` and ``path``."""
    return parse(read_text(path, option), where(path, option))


def sections(data: Mapping[Any, Any], w: str) -> List[Tuple[KeyPath, YamlMapping]]:
    """``[(node path, ros__parameters mapping)]`` of a parsed params file, in file order
    (node sections may nest namespaces: ``ns: node: ros__parameters: ...``)."""
    out: List[Tuple[KeyPath, YamlMapping]] = []

    def walk(node: Mapping[Any, Any], names: List[Any]) -> None:
        for key, value in node.items():
            if key == "ros__parameters":
                if value is None:
                    value = {}
                if not isinstance(value, dict):
                    label = "/".join(map(str, names)) or "the top level"
                    raise ParamsFileError(f"{w}: ros__parameters of {label} is {_kind(value)}, "
                                          "not a mapping of parameter names to values")
                out.append((tuple(names), value))
            elif isinstance(value, dict):
                walk(value, names + [key])

    walk(data, [])
    if not out:
        raise ParamsFileError(f"{w}: not a ROS params file: no 'ros__parameters' mapping under "
                              f"a node name ({_EXAMPLE})")
    return out


def flatten(mapping: Mapping[Any, Any], prefix: str = "") -> Dict[str, Any]:
    """``{dotted parameter name: value}`` of a ros__parameters mapping (nested keys and dotted
    keys give the same names, as ROS reads them)."""
    out: Dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def channel_groups(data: Mapping[Any, Any], channel: str,
                   w: str) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """``(plant, dahl)``: the ``<channel>.plant.*`` and ``<channel>.dahl.*`` values of a parsed
    params file (every node section; a later one overrides an earlier one). A channel with
    neither is an error that lists the channels the file has."""
    plant: Dict[str, Any] = {}
    dahl: Dict[str, Any] = {}
    known: List[str] = []
    named = False
    for _names, params in sections(data, w):
        for name, value in flatten(params).items():
            parts = name.split(".")
            if parts[0] == channel:
                named = True
            if parts == ["channels"] and isinstance(value, list):
                known += [str(v) for v in value]
            if len(parts) < 2 or parts[1] not in ("plant", "dahl"):
                continue
            known.append(parts[0])
            if parts[0] != channel:
                continue
            if len(parts) == 2:
                if value in (None, {}):
                    continue
                raise ParamsFileError(f"{w}: {name} is {_kind(value)}; it must be a mapping "
                                      f"of parameters ({name}.<name>: <value>)")
            (plant if parts[1] == "plant" else dahl)[".".join(parts[2:])] = value
    if not plant and not dahl:
        known = list(dict.fromkeys(known))
        if channel in known or named:
            raise ParamsFileError(f"{w}: channel {channel!r} has no plant.* or dahl.* "
                                  "parameters in this file")
        listed = (f"the file has parameters of {', '.join(known)}" if known else
                  "the file has no <channel>.plant.* or <channel>.dahl.* parameters at all")
        raise ParamsFileError(f"{w}: unknown channel {channel!r}: {listed}")
    return plant, dahl


def _node_pattern(names: KeyPath) -> "re.Pattern[str]":
    """The fully qualified node names a section's path matches, as rcl reads params files:
    ``/**`` any namespace and node (also none), ``*`` one name."""
    path = "/" + "/".join(str(n).strip("/") for n in names if str(n).strip("/"))
    out = ""
    for part in re.split(r"(/\*\*|\*)", path):
        out += {"/**": "(?:/.*)?", "*": "[^/]*"}.get(part, re.escape(part))
    return re.compile(out)


@dataclasses.dataclass
class ControllerView:
    """What ``controller_node`` (node ``/controller``) reads of one channel from a params file:
    its controller parameters (``{key relative to <channel>.: value}``), the node's ``rate``
    and ``loop`` when the file gives them, and the names in its sections a typo away from a
    parameter of the channel (``[(name, meant)]``: the node refuses to start on them)."""

    values: Dict[str, Any]
    node: Dict[str, Any]
    misspelt: List[Tuple[str, str]]


def controller_view(data: Mapping[Any, Any], channel: str, w: str, keys: Sequence[str],
                    node: str = "/controller") -> ControllerView:
    """:class:`ControllerView` of ``channel`` for the node ``node`` in a parsed params file:
    only the sections whose node path matches it (``/**``, ``controller``, ``/**/controller``
    ...), a later value overriding an earlier one; ``keys`` the controller parameters
    (relative to ``<channel>.``)."""
    import difflib
    known = set(keys)
    out = ControllerView({}, {}, [])
    for names, params in sections(data, w):
        if not _node_pattern(names).fullmatch(node):
            continue
        for name, value in flatten(params).items():
            head, _, rest = name.partition(".")
            if head == channel and rest:
                if rest in known:
                    out.values[rest] = value
                else:
                    close = difflib.get_close_matches(rest, keys, n=1, cutoff=0.8)
                    if close:
                        out.misspelt.append((name, f"{channel}.{close[0]}"))
            elif name in ("rate", "loop"):
                out.node[name] = value
    return out


def _number(value: Any, w: str, name: str) -> float:
    number: Optional[float]
    if isinstance(value, str):
        try:
            number = float(value)       # '1e-3': a string to PyYAML, a double to ROS
        except ValueError:
            number = None
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        number = float(value)
    else:
        number = None
    if number is None:
        raise ParamsFileError(f"{w}: {name} must be a number, got {_kind(value)}")
    if not math.isfinite(number):
        raise ParamsFileError(f"{w}: {name} must be a finite number, got {value!r}")
    return number


def _check_keys(values: Mapping[str, Any], keys: Sequence[str], w: str, group: str) -> None:
    unknown = [k for k in values if k not in keys]
    if unknown:
        raise ParamsFileError(f"{w}: unknown parameter {group}.{unknown[0]} (the parameters of "
                              f"{group} are {', '.join(keys)})")


def plant_params(values: Mapping[str, Any], w: str, channel: str) -> PlantParams:
    """PlantParams from a ``<channel>.plant`` group: all eight of Table I, numbers."""
    group = f"{channel}.plant"
    _check_keys(values, PLANT_KEYS, w, group)
    missing = [k for k in PLANT_KEYS if k not in values]
    if missing:
        raise ParamsFileError(f"{w}: {group} is incomplete: {', '.join(missing)} missing (all "
                              "eight parameters of Table I are needed)")
    numbers = {k: _number(values[k], w, f"{group}.{k}") for k in PLANT_KEYS}
    try:
        return PlantParams(**numbers)
    except SeaforceError as exc:
        raise ParamsFileError(f"{w}: channel {channel}: {exc}") from None


def dahl_params(values: Mapping[str, Any], w: str, channel: str,
                base: Optional[DahlParams] = None) -> DahlParams:
    """DahlParams from a ``<channel>.dahl`` group; keys it does not give come from ``base``
    (default: DahlParams())."""
    group = f"{channel}.dahl"
    _check_keys(values, DAHL_KEYS, w, group)
    numbers = {k: _number(v, w, f"{group}.{k}") for k, v in values.items()}
    try:
        return dataclasses.replace(base or DahlParams(), **numbers)
    except SeaforceError as exc:
        raise ParamsFileError(f"{w}: channel {channel}: {exc}") from None


def format_value(value: Union[float, str]) -> str:
    """A float as YAML writes it (always read back as a float, by PyYAML as by ROS); a string
    double-quoted (read back as that string, never as a number or a bool)."""
    if isinstance(value, str):
        return json.dumps(value)
    return yaml.representer.SafeRepresenter().represent_float(float(value)).value


def _scalar(value: Union[float, str]) -> Union[float, str]:
    return value if isinstance(value, str) else float(value)


# --- in-place update ---------------------------------------------------------------------
# A mapping line: indentation, key (plain or quoted), ':' followed by a blank or the end.
_KEY = re.compile(r"""(?P<indent>[ ]*)(?P<key>"(?:[^"\\]|\\.)*"|'(?:[^']|'')*'"""
                  r"""|[^\s#'"\[\]{}&*!|>%@`,?:-][^#]*?|[?:-][^\s#][^#]*?)[ \t]*:(?=[ \t]|$)""")


@dataclasses.dataclass
class _KeyLine:
    index: int          # line number (0-based)
    indent: int
    path: KeyPath       # keys from the top of the document
    value: str          # the value text on this line ('' for a block start)
    start: int          # column of the value (or of the end of the key for a block start)
    end: int            # column after the value


def _key_value(text: str) -> Any:
    try:
        key = yaml.safe_load(text)
    except yaml.YAMLError:
        key = text
    return key if key is not None else text


def _split_value(rest: str) -> Optional[Tuple[str, int, int]]:
    """``(value, offset of its start, offset of its end)`` in the text after ``key:``; the
    value is '' for a block start. None when the line has more than one value (not ours)."""
    stripped = rest.lstrip(" \t")
    start = len(rest) - len(stripped)
    if not stripped or stripped.startswith("#"):
        return "", start, start
    if stripped[0] in "\"'":
        quote = stripped[0]
        i = 1
        while i < len(stripped):
            if quote == '"' and stripped[i] == "\\":
                i += 2
                continue
            if stripped[i] == quote:
                if quote == "'" and stripped[i + 1:i + 2] == "'":
                    i += 2
                    continue
                break
            i += 1
        end = min(i + 1, len(stripped))
    else:
        m = re.search(r"[ \t]#", stripped)
        end = m.start() if m else len(stripped.rstrip(" \t"))
        end = len(stripped[:end].rstrip(" \t"))
    tail = stripped[end:]
    if tail.strip() and not tail.lstrip(" \t").startswith("#"):
        return None
    return stripped[:end], start, start + end


def _scan(lines: Sequence[str], w: str) -> List[_KeyLine]:
    """The mapping lines of a block-style YAML document with their key paths. Lines that
    continue a value (sequences, block scalars, wrapped scalars, multi-line flow collections)
    are skipped; anchors, aliases, tags and merge keys make the layout one this does not
    follow."""
    out: List[_KeyLine] = []
    stack: List[Tuple[int, Any]] = []   # (indent, key) of the open block mappings
    skip_deeper: Optional[int] = None         # lines indented deeper than this continue a value
    for i, line in enumerate(lines):
        body = line.lstrip(" ")
        indent = len(line) - len(body)
        if not body.strip() or body.startswith("#"):
            continue
        if skip_deeper is not None and indent > skip_deeper:
            continue
        skip_deeper = None
        if indent == 0 and (body.startswith("---") or body.startswith("...")
                            or body.startswith("%")):
            stack = []
            continue
        m = _KEY.match(line)
        if m is None:
            # a sequence item, or a line this does not follow: whatever is deeper belongs to it
            skip_deeper = indent
            continue
        key_text = m.group("key")
        if key_text == "<<":
            raise ParamsFileError(f"{w}: line {i + 1} uses a merge key (<<)")
        split = _split_value(line[m.end():])
        if split is None:
            skip_deeper = indent
            continue
        value, start, end = split
        if value[:1] in ("&", "*", "!"):
            raise ParamsFileError(f"{w}: line {i + 1} uses an anchor, alias or tag "
                                  f"({value.split()[0]})")
        while stack and stack[-1][0] >= indent:
            stack.pop()
        key = _key_value(key_text)
        path = tuple(k for _, k in stack) + (key,)
        out.append(_KeyLine(i, indent, path, value, m.end() + start, m.end() + end))
        if value:
            skip_deeper = indent    # a value wrapped onto the next lines, a block scalar
        else:
            stack.append((indent, key))
    return out


def _param_name(path: KeyPath) -> Optional[Tuple[KeyPath, str]]:
    """``(section path, dotted parameter name)`` of a key path inside ros__parameters, or
    None."""
    if "ros__parameters" not in path:
        return None
    k = path.index("ros__parameters")
    if k == len(path) - 1:
        return None
    return path[:k + 1], ".".join(str(p) for p in path[k + 1:])


def _normal(data: Any) -> Dict[Tuple[KeyPath, Any], Any]:
    """``{(section path, dotted name): value}`` for the parameters and ``{(path, key): value}``
    for anything else: the file's meaning, independent of nested vs dotted keys."""
    out: Dict[Tuple[KeyPath, Any], Any] = {}

    def walk(node: Mapping[Any, Any], path: KeyPath) -> None:
        for key, value in node.items():
            if key == "ros__parameters" and isinstance(value, dict):
                for name, v in flatten(value).items():
                    out[(path + (key,), name)] = v
            elif isinstance(value, dict) and value:
                walk(value, path + (key,))
            else:
                out[(path, key)] = value
    if isinstance(data, dict):
        walk(data, ())
    return out


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


def _replace_value(line: str, k: _KeyLine, new: str) -> str:
    """``line`` with the value of key line ``k`` replaced, a trailing comment kept in its
    column where the new value leaves room."""
    head, old, tail = line[:k.start], line[k.start:k.end], line[k.end:]
    if tail.strip():
        gap = len(tail) - len(tail.lstrip(" \t"))
        tail = " " * max(1, gap + len(old) - len(new)) + tail.lstrip(" \t")
    else:
        tail = ""
    return head + new + tail


def _render(tree: Mapping[Any, Any], indent: int, step: int) -> List[str]:
    lines: List[str] = []
    for key, value in tree.items():
        if isinstance(value, dict):
            lines.append(" " * indent + f"{key}:")
            lines += _render(value, indent + step, step)
        else:
            lines.append(" " * indent + f"{key}: {format_value(value)}")
    return lines


def _block_end(lines: Sequence[str], k: _KeyLine) -> int:
    """Index after the last line inside block key line ``k`` (its children, and comments
    indented under it)."""
    last = k.index
    for j in range(k.index + 1, len(lines)):
        body = lines[j].lstrip(" ")
        indent = len(lines[j]) - len(body)
        if not body.strip():
            continue
        if indent <= k.indent:
            if body.startswith("#"):
                continue
            break
        last = j
    return last + 1


def _child_indent(lines: Sequence[str], k: _KeyLine) -> Optional[int]:
    for j in range(k.index + 1, len(lines)):
        body = lines[j].lstrip(" ")
        if not body.strip() or body.startswith("#"):
            continue
        indent = len(lines[j]) - len(body)
        return indent if indent > k.indent else None
    return None


def update_text(text: str, values: Mapping[str, Union[float, str]], w: str,
                header: Optional[Sequence[str]] = None) -> str:
    """``text`` (a params file) with the parameters ``values`` (``{dotted name: float}``, e.g.
    ``pinch.plant.motor_inertia``) set, everything else as it was.

    A parameter is changed wherever a node section of the file sets it; one that no section
    sets is added to the ``/**`` section (created at the end if there is none). ``header``
    (lines, optional) replaces the lines of the same ``# key:`` in the file's leading comment
    block when that block was written by identify (first line
    ``# seaforce_ros parameters identified ...``). Raises ParamsFileError (the reason, the
    file untouched) when the layout is not one this can change safely.
    """
    try:
        return _update(text, values, w, header)
    except ParamsFileError as exc:
        raise ParamsFileError(f"{exc}; the file is left as it is: write the parameters to a "
                              "new file (--out NEW.yaml) and copy them over by hand") from None


def _update(text: str, values: Mapping[str, Union[float, str]], w: str,
            header: Optional[Sequence[str]]) -> str:
    data = _safe_load(text, w)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ParamsFileError(f"{w}: not a ROS params file (the top level is {_kind(data)})"
                             )
    if data:
        sections(data, w)
    newline = "\r\n" if "\r\n" in text else "\n"
    lines = text.splitlines()
    try:
        keys = _scan(lines, w)
    except ParamsFileError as exc:
        raise ParamsFileError(f"{exc}, which this tool does not update line by line") from None
    old = _normal(data)
    expected = dict(old)
    found: Set[str] = set()
    edits: Dict[int, str] = {}
    for k in keys:
        where_name = _param_name(k.path)
        if where_name is None or where_name[1] not in values:
            continue
        section, name = where_name
        if not k.value or k.value[:1] in "[{|>":
            raise ParamsFileError(f"{w}: line {k.index + 1}: {name} is not written as "
                                  "'key: value' on one line")
        try:
            current = yaml.safe_load(k.value)
        except yaml.YAMLError:
            current = None
        if (section, name) not in old or not _same(current, old[(section, name)]):
            raise ParamsFileError(f"{w}: line {k.index + 1}: could not follow the file's layout "
                                  f"there ({name}; a key given twice?)")
        edits[k.index] = _replace_value(lines[k.index], k, format_value(values[name]))
        expected[(section, name)] = _scalar(values[name])
        found.add(name)
    out = [edits.get(i, line) for i, line in enumerate(lines)]

    # parameters no section sets: into /** (the deepest block of their path that exists)
    missing = [n for n in values if n not in found]
    inserts: Dict[int, List[str]] = {}     # line index -> lines to insert before it
    if missing:
        blocks: Dict[KeyPath, _KeyLine] = {}
        leaves: Dict[KeyPath, _KeyLine] = {}
        for k in keys:
            if k.path[:1] != (ALL_NODES,):
                continue
            (leaves if k.value else blocks)[k.path] = k     # the last one wins, as in YAML
        groups: Dict[KeyPath, List[Tuple[KeyPath, Union[float, str]]]] = {}
        for name in missing:
            full = (ALL_NODES, "ros__parameters") + tuple(name.split("."))
            depth = max((d for d in range(1, len(full)) if full[:d] in blocks), default=0)
            for d in range(depth + 1, len(full)):
                if full[:d] in leaves:
                    label = ".".join(map(str, full[2:d])) or "/".join(map(str, full[:d]))
                    raise ParamsFileError(
                        f"{w}: line {leaves[full[:d]].index + 1}: {label} is written on one "
                        f"line; cannot set {name} in it")
            groups.setdefault(full[:depth], []).append((full[depth:], values[name]))
            expected[((ALL_NODES, "ros__parameters"), name)] = _scalar(values[name])
            for d in range(1, len(full)):       # an empty block becomes a mapping
                prefix = full[:d]
                key: Tuple[KeyPath, Any]
                if len(prefix) > 2:
                    key = ((ALL_NODES, "ros__parameters"), ".".join(map(str, prefix[2:])))
                else:
                    key = (prefix[:-1], prefix[-1])
                if key in expected and expected[key] in (None, {}):
                    del expected[key]
        # deeper groups first: an inner block that ends where its parent ends gets its lines
        # before the parent's new keys
        for prefix, items in sorted(groups.items(), key=lambda g: -len(g[0])):
            tree: YamlMapping = {}
            for rest, value in items:
                node = tree
                for part in rest[:-1]:
                    node = node.setdefault(part, {})
                node[rest[-1]] = value
            if prefix:
                k = blocks[prefix]
                indent = _child_indent(lines, k)
                step = 2 if indent is None else indent - k.indent
                at = _block_end(lines, k)
                inserts.setdefault(at, []).extend(_render(tree, k.indent + step, step))
            else:
                at = len(lines)
                block = ([""] if lines and lines[-1].strip() else []) + _render(tree, 0, 2)
                inserts.setdefault(at, []).extend(block)
    result: List[str] = []
    for i, line in enumerate([*out, None]):
        result.extend(inserts.get(i, []))
        if line is not None:
            result.append(line)
    if header:
        result = _update_header(result, header)
    new_text = newline.join(result) + newline
    try:
        new = _normal(yaml.safe_load(new_text))
    except yaml.YAMLError:
        new = {((), "(the result is not valid YAML)"): None}
    diff = sorted(set(new) ^ set(expected), key=str)
    diff += sorted((k for k in set(new) & set(expected) if not _same(new[k], expected[k])),
                   key=str)
    if diff:
        section, name = diff[0]
        label = f"{'/'.join(map(str, section))}: {name}"
        raise ParamsFileError(f"{w}: the line-by-line update would not read back as intended "
                              f"({label}); its layout is more than this tool edits")
    return new_text


HEADER_MARK = "# seaforce_ros parameters identified"


def _update_header(lines: List[str], header: Sequence[str]) -> List[str]:
    """Replace identify's own header lines (same ``# key:``) in the leading comment block of a
    file identify wrote; a user's comments are not touched."""
    if not lines or not lines[0].startswith(HEADER_MARK):
        return lines
    end = 0
    while end < len(lines) and lines[end].startswith("#"):
        end += 1
    top = list(lines[:end])
    for new in header:
        if new.startswith(HEADER_MARK):
            top[0] = new
            continue
        key = new.split(":", 1)[0] + ":"
        same = [i for i, line in enumerate(top) if line.startswith(key)]
        if same:
            top[same[0]] = new
        else:
            top.append(new)
    return top + lines[end:]

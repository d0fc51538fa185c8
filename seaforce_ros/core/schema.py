"""The parameter schema: one row per parameter, everything else derived from it.

A row is a field of a frozen dataclass, declared with :func:`param`::

    @group("grasp")
    class GraspParams(ParameterGroup):
        give_way_travel: float = param(
            1.5, "rad", "travel past the contact point after which the object counts as "
            "given way and the grasp drops it", gt=0.0, le=100.0)

The row holds the default, the unit, the description (the paper's symbol and equation where
there is one), the range (``gt``/``ge``/``lt``/``le``) or the allowed strings (``choices``),
whether it is read-only and which nodes declare it. From it derive: the dataclass field and
its numpydoc entry (appended to the class docstring), the check in ``validate()`` (type,
finiteness, range, choices; one message format), the ROS parameter descriptor
(:func:`seaforce_ros.nodes.ros_common.descriptor`), the declaration by each node
(:func:`node_rows`), the launch files' ``<choice>`` lists and ``docs/parameters.md``
(:mod:`seaforce_ros.tools.generate`), and the keys ``identify --out`` writes. Rules between
parameters (the DOB's passivity, eq. 28, and the other limits that depend on the plant) stay
explicit functions: a group's :meth:`ParameterGroup.check_rules`.

A group has a key prefix (``grasp`` -> ``grasp.give_way_travel``; ``key=`` overrides one key),
the nodes that declare it (a row may name others) and whether its keys are per channel
(``<channel>.grasp.give_way_travel``) or the node's own (``state_timeout``). No ROS here.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
from dataclasses import dataclass, field
from typing import (TYPE_CHECKING, Any, Callable, ClassVar, Dict, Iterator, List, Mapping,
                    Optional, Self, Tuple, Type, TypeVar, dataclass_transform)

from .errors import InvalidParameterError

__all__ = ["Spec", "param", "group", "ParameterGroup", "groups", "rows", "node_rows", "by_key",
           "CONTROLLER", "SIM", "HARDWARE", "RECORDER", "BRINGUP", "PLANTS", "NODES"]

#: The nodes that declare parameters (their node names).
CONTROLLER, SIM, HARDWARE, RECORDER = "controller", "sim", "hardware", "bag_recorder"
#: The composed executables (``bringup``, ``hardware_bringup``) declare ``loop`` on the
#: controller: a row for them names this.
BRINGUP = "bringup"
PLANTS = (SIM, HARDWARE)
NODES = (CONTROLLER, SIM, HARDWARE, RECORDER)

_ROW = "seaforce_row"


@dataclass(frozen=True)
class Spec:
    """One parameter: what a node declares and a check enforces.

    Attributes
    ----------
    name : str
        The key: relative to ``<channel>.`` for per-channel rows (``grasp.max_travel``), the
        node's own otherwise (``state_timeout``); :meth:`qualified` prefixes it.
    type : type
        ``float``, ``int``, ``bool``, ``str`` or ``list`` (of strings).
    default : object
        The default (None: ``optional``, resolved by the group; see ``default_note``).
    unit : str
        SI unit as the paper writes it (``N m s/rad``), ``-`` for dimensionless, '' for none.
    symbol : str
        The paper's symbol (``k_s``), '' where it has none.
    description : str
        Meaning, with the paper's symbol and equation where there is one.
    low, high : float or None
        The range; ``low_open``/``high_open`` make a bound strict.
    choices : tuple of str
        Allowed strings (of a string, or of every entry of a list).
    read_only : bool
        Set once at start (structural: ``channels``, rates, files).
    nodes : tuple of str
        Which nodes declare it (:data:`NODES`, :data:`BRINGUP`).
    per_channel : bool
        The key is per channel.
    hint : str
        Why the bound exists (appended to a rejection).
    default_note : str
        What an optional default resolves to, for the docs.
    attribute : str
        The dataclass field that holds the value.
    node_defaults : tuple of (node, value)
        A node that declares it with another default (``torque_limit`` of the sim).
    """

    name: str
    type: type
    default: Any
    unit: str
    description: str
    symbol: str = ""
    low: Optional[float] = None
    high: Optional[float] = None
    low_open: bool = False
    high_open: bool = False
    choices: Tuple[str, ...] = ()
    read_only: bool = False
    nodes: Tuple[str, ...] = (CONTROLLER,)
    per_channel: bool = True
    hint: str = ""
    default_note: str = ""
    attribute: str = ""
    node_defaults: Tuple[Tuple[str, Any], ...] = ()

    # --- derived ---------------------------------------------------------------------------
    def qualified(self, prefix: str) -> "Spec":
        """The same row under ``prefix + name`` (``pinch.`` for a channel)."""
        return dataclasses.replace(self, name=prefix + self.name)

    def default_for(self, node: str) -> Any:
        """The default ``node`` declares it with."""
        for who, value in self.node_defaults:
            if who == node:
                return value
        return self.default

    def kind(self) -> str:
        """The type in words, as a message names it."""
        return {float: "a number", int: "an integer", bool: "a boolean (true/false)",
                str: "a string", list: "a list of strings"}[self.type]

    def range_text(self) -> str:
        """The range in interval notation (``(0, 100]``), '' without one."""
        if self.low is None and self.high is None:
            return ""
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None else f"{self.high:g}"
        return (("(" if self.low_open or self.low is None else "[") + f"{low}, {high}"
                + (")" if self.high_open or self.high is None else "]"))

    def bound(self) -> str:
        """What a value must be, in words (the core's rejection: ``must be <bound>``)."""
        if self.type is bool:
            return "a bool"
        if self.choices:
            head = "one of " if self.type is str else "a list of: "
            return head + ", ".join(self.choices)
        if self.type is str:
            return "a string"
        if self.type is list:
            return "a list of strings"
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '>='} {self.low:g}")
        if self.high is not None:
            parts.append(f"{'<' if self.high_open else '<='} {self.high:g}")
        if self.type is int:
            return "an integer" + (" " + " and ".join(parts) if parts else "")
        if len(parts) == 1:
            parts.append("finite")
        return " and ".join(parts) if parts else "finite"

    def coerce(self, value: Any) -> Any:
        """``value`` as this parameter's type where nothing is lost: an integer for a float
        (a user writes ``max_torque: 20``), a tuple for a list; anything else unchanged."""
        if self.type is float and type(value) is int:
            return float(value)
        return value

    def _type_ok(self, value: Any) -> bool:
        t = self.type
        if t is bool:
            return isinstance(value, bool)
        if t is float:
            return isinstance(value, (int, float)) and not isinstance(value, bool)
        if t is int:
            return isinstance(value, int) and not isinstance(value, bool)
        if t is list:
            return isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)
        return isinstance(value, str)

    def _in_range(self, value: Any) -> bool:
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return not (self.high is not None and (value >= self.high if self.high_open
                                               else value > self.high))

    def _bad_choices(self, value: Any) -> List[str]:
        items = value if self.type is list else [value]
        return [item for item in items if item not in self.choices] if self.choices else []

    def problem(self, value: Any) -> Optional[str]:
        """What is wrong with ``value`` (already :meth:`coerce`-d), in the core's words (what
        it must be), or None: type, finiteness, range, allowed strings."""
        if value is None and self.default is None:
            return None                          # optional: resolved by its group
        if not self._type_ok(value):
            return "a real number" if self.type is float else self.kind()
        if self.type is float and not math.isfinite(value):
            bound = self.bound().replace(" and finite", "")
            return "finite" if bound == "finite" else "a finite number " + bound
        if self.type in (float, int) and not self._in_range(value):
            return self.bound()
        if self._bad_choices(value):
            return self.bound()
        return None

    def reason(self, value: Any, name: Optional[str] = None) -> Optional[str]:
        """Why a node refuses ``value`` (already :meth:`coerce`-d) for the parameter ``name``
        (default this key), in the words of a ROS parameter: its type, finiteness, range
        and allowed strings; None if it is fine. The same check runs when a node starts and
        on every later set."""
        name = name or self.name
        hint = f" ({self.hint})" if self.hint else ""
        if not self._type_ok(value):
            yaml = (" (YAML 1.1 reads an unquoted yes/no/on/off/true/false as a boolean: "
                    "quote the string)") if isinstance(value, bool) and self.type is str else ""
            return f"{name} must be {self.kind()}, got {value!r}{yaml}"
        if isinstance(value, float) and not math.isfinite(value):
            return f"{name} must be finite, got {value}"
        if self.type in (float, int) and not self._in_range(value):
            return f"{name} must be within {self.range_text()}, got {value!r}"
        bad = self._bad_choices(value)
        if bad:
            if self.type is list:
                return (f"{name}: every entry must be one of {', '.join(self.choices)}; "
                        f"got {bad!r}")
            return f"{name} must be one of {', '.join(self.choices)}; got {value!r}{hint}"
        return None

    def check(self, value: Any, name: Optional[str] = None) -> Any:
        """``value`` coerced, or :class:`InvalidParameterError` naming ``name`` (default this
        key) and the bound."""
        value = self.coerce(value)
        reason = self.problem(value)
        if reason is not None:
            raise InvalidParameterError(name or self.name, value, reason, hint=self.hint)
        return value

    def text(self) -> str:
        """The description a ROS descriptor (and the reference) shows: symbol, meaning, unit."""
        unit = f" [{self.unit}]" if self.unit else ""
        return (f"{self.symbol}, " if self.symbol else "") + self.description + unit

    def numpydoc(self) -> str:
        """The entry of the group's ``Parameters`` section."""
        kind = {float: "float", int: "int", bool: "bool", str: "str", list: "list of str"}[
            self.type]
        where = self.range_text() or (("one of " + ", ".join(self.choices)) if self.choices
                                      else "")
        unit = f" [{self.unit}]" if self.unit and self.unit != "-" else ""
        text = (f"{self.symbol}, " if self.symbol else "") + self.description + unit + "."
        return f"{self.attribute} : {kind}{', ' + where if where else ''}\n    {text}"


class _Row:
    """What :func:`param` records on a field until :func:`group` completes it."""

    __slots__ = ("unit", "description", "symbol", "low", "high", "low_open", "high_open", "choices",
                 "read_only", "nodes", "key", "hint", "default_note", "type", "node_defaults")

    def __init__(self, **kw: Any) -> None:
        for name in self.__slots__:
            setattr(self, name, kw[name])


def param(default: Any, unit: str, description: str, *, symbol: str = "",
          gt: Optional[float] = None,
          ge: Optional[float] = None, lt: Optional[float] = None, le: Optional[float] = None,
          choices: Tuple[str, ...] = (), read_only: bool = False,
          nodes: Optional[Tuple[str, ...]] = None, key: Optional[str] = None, hint: str = "",
          default_note: str = "", type: Optional[type] = None,
          node_defaults: Optional[Mapping[str, Any]] = None) -> Any:
    """A parameter row: a dataclass field with its schema (see the module docstring).

    ``gt``/``ge`` and ``lt``/``le`` give the strict or closed bounds; ``nodes`` overrides the
    group's; ``key`` the key (default ``<prefix>.<field>``); ``type`` is needed only when the
    default is None (an optional value its group resolves).
    """
    if gt is not None and ge is not None or lt is not None and le is not None:
        raise ValueError("give one lower and one upper bound")
    kind = type if type is not None else (list if isinstance(default, (list, tuple))
                                          else builtins_type(default))
    row = _Row(unit=unit, description=description, symbol=symbol, low=gt if gt is not None else ge,
               high=lt if lt is not None else le, low_open=gt is not None,
               high_open=lt is not None, choices=tuple(choices), read_only=read_only,
               nodes=nodes, key=key, hint=hint, default_note=default_note, type=kind,
               node_defaults=tuple(dict(node_defaults or {}).items()))
    if isinstance(default, list):
        default = tuple(default)
    return field(default=default, metadata={_ROW: row})


def builtins_type(value: Any) -> type:
    """The row type of a default value."""
    for t in (bool, int, float, str):
        if isinstance(value, t):
            return t
    raise TypeError(f"no parameter type for the default {value!r}")


#: The core modules that define parameter groups.
_GROUP_MODULES = ("params", "environment", "sensors", "plant_cycle", "control_cycle",
                  "settings", "nonlinear_effects")
#: Every group made by :func:`group`, in definition order.
_GROUPS: List[Type[ParameterGroup]] = []


class ParameterGroup:
    """Base of a group of rows: ``__post_init__`` validates every row, then the group's
    :meth:`check_rules`; integers given for floats are stored as floats."""

    PREFIX: ClassVar[str] = ""
    SPECS: ClassVar[Tuple[Spec, ...]] = ()
    if TYPE_CHECKING:                       # every group is a dataclass (made by group())
        __dataclass_fields__: ClassVar[Dict[str, dataclasses.Field[Any]]]

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`InvalidParameterError` on the first bad value, then check the rules
        between values (:meth:`check_rules`)."""
        for spec in self.SPECS:
            value = getattr(self, spec.attribute)
            checked = spec.check(value)
            if spec.type is list and not isinstance(checked, tuple):
                checked = tuple(checked)         # frozen: a list row is held as a tuple
            if checked is not value:
                object.__setattr__(self, spec.attribute, checked)
        self.check_rules()

    def check_rules(self) -> None:
        """Rules between this group's values (none by default)."""

    def values(self) -> Dict[str, Any]:
        """``{key: value}`` of the rows (lists as lists)."""
        out = {}
        for spec in self.SPECS:
            value = getattr(self, spec.attribute)
            out[spec.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def spec(cls, attribute: str) -> Spec:
        """The row of ``attribute``."""
        for spec in cls.SPECS:
            if spec.attribute == attribute:
                return spec
        raise KeyError(attribute)

    @classmethod
    def from_values(cls, values: Mapping[str, Any], base: Optional[Self] = None) -> Self:
        """A validated group from ``{key: value}`` (keys of :attr:`SPECS`; others are an
        error), the rest from ``base`` (default: the defaults)."""
        by_key = {spec.name: spec for spec in cls.SPECS}
        changes = {}
        for key, value in values.items():
            spec = by_key.get(key)
            if spec is None:
                raise InvalidParameterError(key, value, "a known key: " + ", ".join(by_key))
            changes[spec.attribute] = spec.coerce(value)
        if base is None:
            return cls(**changes)
        return dataclasses.replace(base, **changes)


_Group = TypeVar("_Group", bound="ParameterGroup")


# A type checker sees the decorated class as the frozen dataclass it is. A param() field is a
# field with a default to it (param is no field specifier: its default is positional).
@dataclass_transform(frozen_default=True, field_specifiers=(field,))
def group(prefix: str, *, nodes: Tuple[str, ...] = (CONTROLLER,),
          per_channel: bool = True) -> Callable[[Type[_Group]], Type[_Group]]:
    """Make ``cls`` a frozen dataclass whose :func:`param` fields are rows under ``prefix``
    (see the module docstring); its docstring gets the generated ``Parameters`` section."""
    def make(cls: Type[_Group]) -> Type[_Group]:
        cls = dataclass(frozen=True)(cls)
        specs = []
        for f in dataclasses.fields(cls):
            row = f.metadata.get(_ROW)
            if row is None:
                continue
            key = row.key or (f"{prefix}.{f.name}" if prefix else f.name)
            specs.append(Spec(
                name=key, type=row.type, default=f.default, unit=row.unit,
                description=row.description, symbol=row.symbol, low=row.low, high=row.high,
                low_open=row.low_open, high_open=row.high_open, choices=row.choices,
                read_only=row.read_only,
                nodes=tuple(nodes if row.nodes is None else row.nodes),
                per_channel=per_channel, hint=row.hint, default_note=row.default_note,
                attribute=f.name, node_defaults=row.node_defaults))
        cls.PREFIX = prefix
        cls.SPECS = tuple(specs)
        if specs:
            doc = (cls.__doc__ or "").rstrip()
            cls.__doc__ = (doc + "\n\n    Parameters\n    ----------\n" + "\n".join(
                "    " + s.numpydoc().replace("\n", "\n    ") for s in specs) + "\n")
        _GROUPS.append(cls)
        return cls
    return make


def groups() -> Tuple[Type[ParameterGroup], ...]:
    """Every parameter group: by module (the order of ``_GROUP_MODULES``), then in definition
    order -- whatever imported them first."""
    for module in _GROUP_MODULES:           # importing a module registers its groups
        importlib.import_module(f"{__package__}.{module}")
    order = {f"{__package__}.{m}": i for i, m in enumerate(_GROUP_MODULES)}
    return tuple(sorted(_GROUPS, key=lambda cls: order.get(cls.__module__, len(order))))


def rows() -> Iterator[Spec]:
    """Every row of every group."""
    for cls in groups():
        yield from cls.SPECS


def node_rows(node: str, *, per_channel: Optional[bool] = None) -> List[Spec]:
    """The rows ``node`` declares (optionally only the per-channel ones, or only its own),
    with that node's defaults; in schema order."""
    out = []
    for spec in rows():
        if node in spec.nodes and (per_channel is None or spec.per_channel == per_channel):
            default = spec.default_for(node)
            out.append(spec if default is spec.default else
                       dataclasses.replace(spec, default=default))
    return out


def by_key() -> Dict[str, Spec]:
    """``{key: Spec}`` of every row (a key two groups share would be a schema error)."""
    out: Dict[str, Spec] = {}
    for spec in rows():
        if spec.name in out and out[spec.name] != spec:
            raise RuntimeError(f"two rows for {spec.name}")
        out.setdefault(spec.name, spec)
    return out

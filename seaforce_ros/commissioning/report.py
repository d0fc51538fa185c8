"""The commissioning report: one directory per run, opened by a person from disk.

Commissioning a gripper (self-identification in free air, the sensor and loop figures, the
predicted Z-width, the automatic tuning) ends here. :class:`CommissioningReport` holds what a
run found, every figure with its 1-sigma where it has one; :func:`write_report` turns it into
a directory::

    report.json          every number (NaN as null, +-inf as "inf"/"-inf"), with ``schema``
    port_responses.png   (a) measured port responses, coherence, the fitted model
    impedance.png        (b) predicted |Z| per controller mode with bands, measured points
    zwidth.png           (c) the Z-width, predicted vs measured; the virtual wall's K_max(B)
    torque_noise.png     (d) DOB torque noise vs lambda, the budget, the chosen lambda
    work_loops.png       (e) work loops F_e(X_e) of a backdrive per mode, with the fundamental
                         and the rms |Z|, the distortion and the peaks within +-0.2 rad and
                         over the stroke
    report.html          self-contained: inline CSS, the figures as data URIs, the tables

A figure whose section is empty is not drawn (the page says so). :func:`load_report` reads
``report.json`` back into the same data; :func:`summary_table` is the plain-text table a
command-line tool prints.

Each figure carries its marker colour (:data:`FIGURE_MARKERS`): a lettered badge in its top
left corner and a small square in its bottom right corner, in a colour no plot line, band or
text of the report uses (one channel 0, one 255: no blend of the plot colours with white,
grey or black reaches it). Whoever looks at a rendering of the page (a person, or the render
test on a screenshot) sees from the two marks of each colour that the whole image is there.
"""
from __future__ import annotations

import base64
import dataclasses
import errno
import html
import io
import json
import math
import os
import pathlib
import typing
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from ..identification.plots import _db as _plot_db
from ..identification.plots import _plt
from .errors import CommissioningError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["SCHEMA", "MODES", "FIGURE_MARKERS", "ReportError", "ParameterRow", "PortResponse",
           "LoopFigure", "ModeImpedance", "WallBoundary", "ZWidthChart", "NoiseSweep",
           "WorkLoop", "ModelClass", "TuningRow", "Tuning", "ReportMeta", "CommissioningReport", "RenderedFigure",
           "write_report", "load_report", "report_json", "summary_table", "render_html",
           "render_figures"]

SCHEMA = 1
"""Version of ``report.json``'s layout; :func:`load_report` refuses any other."""

MODES = ("passive", "hold", "force_feedback", "dob", "dob_linear_ff", "dob_full_ff",
         "impedance")
"""Controller modes in the order the |Z| figure and tables list them."""

FIGURE_MARKERS: Dict[str, Tuple[str, Tuple[int, int, int]]] = {
    "a": ("port_responses.png", (255, 0, 255)),
    "b": ("impedance.png", (0, 128, 255)),
    "c": ("zwidth.png", (255, 0, 128)),
    "d": ("torque_noise.png", (0, 255, 128)),
    "e": ("work_loops.png", (128, 0, 255)),
}
"""Figure letter -> (file name, marker colour RGB)."""

_Array = npt.NDArray[np.float64]
_CArray = npt.NDArray[np.complex128]
_PathLike = Union[str, "os.PathLike[str]"]
_NAN = float("nan")
_DPI = 100


class ReportError(CommissioningError):
    """A report that cannot be written or read (the directory, the disk, the file); the
    message says what to do."""


def _empty() -> _Array:
    return np.zeros(0)


def _floats(obj: object, name: str, *fields_: str) -> int:
    """Turn ``fields_`` of ``obj`` into 1-D float arrays of one length, returned."""
    return _arrays(obj, name, fields_, np.float64)


def _arrays(obj: object, name: str, fields_: Sequence[str], dtype: type) -> int:
    """Turn ``fields_`` of ``obj`` into 1-D arrays of ``dtype`` of one length, returned."""
    n = -1
    for f in fields_:
        raw = getattr(obj, f)
        try:
            if dtype is np.float64 and np.iscomplexobj(raw):
                raise TypeError("complex values where real ones belong")
            a: npt.NDArray[Any] = np.asarray(raw, dtype=dtype)
        except (TypeError, ValueError) as exc:
            raise ReportError(f"{name}: {f} must be a list of numbers ({exc})") from None
        if a.ndim != 1:
            raise ReportError(f"{name}: {f} must be one-dimensional, it has shape {a.shape}")
        object.__setattr__(obj, f, a)
        if n >= 0 and len(a) != n:
            raise ReportError(f"{name}: {f} has {len(a)} values, {fields_[0]} has {n}: "
                              "give one value per frequency")
        n = len(a)
    return n


def _scalars(obj: object, name: str, *fields_: str) -> None:
    """Turn ``fields_`` of ``obj`` into floats."""
    for f in fields_:
        try:
            object.__setattr__(obj, f, float(getattr(obj, f)))
        except (TypeError, ValueError):
            raise ReportError(f"{name}: {f} must be a number, got "
                              f"{getattr(obj, f)!r}") from None


def _check_omega(omega: _Array, name: str, key: str = "omega") -> None:
    if not np.all(np.isfinite(omega) & (omega > 0)):
        raise ReportError(f"{name}: {key} must be finite and > 0 rad/s (the axis is "
                          "logarithmic)")


# --- the data model -----------------------------------------------------------------------


@dataclass
class ParameterRow:
    """One identified parameter.

    Attributes
    ----------
    name : str
        Flat ROS key, e.g. ``plant.hose_stiffness``.
    symbol : str
        The paper's symbol (``k_s``).
    unit : str
        Unit of ``value`` (``N m/rad``).
    value, sigma : float
        Estimate and its 1-sigma (NaN: none).
    status : str
        ``"identified"`` or ``"not identified (<reason>)"``.
    previous : float
        The value of the last commissioning (NaN: none): the drift.
    true : float
        The simulated plant's value (NaN outside simulation).
    """

    name: str
    symbol: str
    unit: str
    value: float
    sigma: float
    status: str = "identified"
    previous: float = _NAN
    true: float = _NAN

    def __post_init__(self) -> None:
        _scalars(self, self.name, "value", "sigma", "previous", "true")

    @property
    def identified(self) -> bool:
        """Whether the parameter was identified."""
        return self.status == "identified"

    @property
    def drift_sigmas(self) -> float:
        """(value - previous) / sigma [-]; NaN without previous value or sigma."""
        if not (self.sigma > 0 and math.isfinite(self.previous)):
            return _NAN
        return (self.value - self.previous) / self.sigma


@dataclass
class PortResponse:
    """One measured frequency response at the motor port.

    Attributes
    ----------
    name : str
        E.g. ``"X/(F_a+F_p)"`` or ``"F_p/X"``.
    unit : str
        Unit of H (``rad/(N m)``).
    omega : float array > 0
        Frequencies w [rad/s].
    measured : complex array
        Measured H(jw).
    sigma : float array >= 0
        1-sigma of ``measured`` (absolute, in H's unit).
    coherence : float array in [0, 1]
        Magnitude-squared coherence of the estimate.
    model : complex array
        The fitted model's H(jw).
    """

    name: str
    unit: str
    omega: _Array
    measured: _CArray
    sigma: _Array
    coherence: _Array
    model: _CArray

    def __post_init__(self) -> None:
        n = _floats(self, self.name, "omega", "sigma", "coherence")
        if _arrays(self, self.name, ("measured", "model"), np.complex128) != n:
            raise ReportError(f"{self.name}: measured and model need one value per frequency "
                              f"({n})")
        _check_omega(self.omega, self.name)


@dataclass
class LoopFigure:
    """A sensor or loop figure (pressure noise, encoder resolution, loop delay p50/p99 in
    samples, missed commands): value, 1-sigma (NaN: none) and unit."""

    name: str
    value: float
    sigma: float
    unit: str

    def __post_init__(self) -> None:
        _scalars(self, self.name, "value", "sigma")


@dataclass
class ModeImpedance:
    """Predicted endpoint impedance Z(jw) = F_e/V_e of one controller mode.

    Attributes
    ----------
    mode : str
        One of :data:`MODES`.
    omega : float array > 0
        Frequencies w [rad/s].
    z : complex array
        Predicted Z(jw) [N m s/rad].
    lower, upper : float arrays
        The 1-sigma band of |Z| [N m s/rad].
    measured_omega, measured_abs : float arrays
        Measured |Z| points (w [rad/s], |Z| [N m s/rad]); empty: none.
    rms_omega, rms_abs : float arrays
        Predicted rms impedance rms(F_e)/rms(V_e) (w [rad/s], [N m s/rad]) from backdrives
        simulated on the identified model; empty: none.
    """

    mode: str
    omega: _Array
    z: _CArray
    lower: _Array
    upper: _Array
    measured_omega: _Array = field(default_factory=_empty)
    measured_abs: _Array = field(default_factory=_empty)
    rms_omega: _Array = field(default_factory=_empty)
    rms_abs: _Array = field(default_factory=_empty)

    def __post_init__(self) -> None:
        n = _floats(self, self.mode, "omega", "lower", "upper")
        if _arrays(self, self.mode, ("z",), np.complex128) != n:
            raise ReportError(f"{self.mode}: z needs one value per frequency ({n})")
        _floats(self, self.mode, "measured_omega", "measured_abs")
        _floats(self, self.mode, "rms_omega", "rms_abs")
        _check_omega(self.omega, self.mode)
        _check_omega(self.measured_omega, self.mode, "measured_omega")
        _check_omega(self.rms_omega, self.mode, "rms_omega")


@dataclass
class WallBoundary:
    """Stable virtual wall of ``impedance`` mode: the largest stiffness K_max(B) per damping.

    Attributes
    ----------
    damping : float array >= 0
        Virtual damping B [N m s/rad].
    k_passivity : float array
        K_max from passivity with the loop delay [N m/rad].
    k_quantisation : float array
        K_max from the encoder quantisation (limit cycle) [N m/rad]; inf: no limit.
    chosen_damping, chosen_stiffness : float
        The tuned (B, K) (NaN: none).
    """

    damping: _Array
    k_passivity: _Array
    k_quantisation: _Array
    chosen_damping: float = _NAN
    chosen_stiffness: float = _NAN

    def __post_init__(self) -> None:
        _floats(self, "wall", "damping", "k_passivity", "k_quantisation")
        _scalars(self, "wall", "chosen_damping", "chosen_stiffness")

    @property
    def k_max(self) -> _Array:
        """The binding K_max(B) = min(passivity, quantisation) [N m/rad]."""
        return np.fmin(self.k_passivity, self.k_quantisation)

    @property
    def binding(self) -> List[str]:
        """Per damping, which limit binds: ``"passivity"`` or ``"quantisation"``."""
        return ["passivity" if p <= q else "quantisation"
                for p, q in zip(self.k_passivity, self.k_quantisation)]

    def at_chosen(self) -> Optional[Tuple[float, str]]:
        """(K_max [N m/rad], the limit that binds) at the chosen damping, each limit
        interpolated linearly in B; None without a chosen damping or curve."""
        b = self.chosen_damping
        if not (math.isfinite(b) and len(self.damping)):
            return None
        order = np.argsort(self.damping)
        p, q = (float(np.interp(b, self.damping[order], k[order]))
                for k in (self.k_passivity, self.k_quantisation))
        if math.isnan(q) or p <= q:
            return p, "passivity"
        return q, "quantisation"

    def describe(self) -> str:
        """One line: the chosen (B, K) against K_max(B) and what binds."""
        at = self.at_chosen()
        if at is None:
            return "virtual wall: no chosen damping"
        k, which = at
        return (f"virtual wall: at B = {self.chosen_damping:.4g} N m s/rad, K_max = {k:.4g} "
                f"N m/rad ({which} binds), chosen K = {_num(self.chosen_stiffness)} N m/rad")


@dataclass
class ZWidthChart:
    """The Z-width 20 log10(|Z_hold| / |Z_min|) [dB] against frequency.

    Attributes
    ----------
    omega : float array > 0
        Frequencies w [rad/s].
    predicted_db, lower_db, upper_db : float arrays
        Predicted Z-width and its 1-sigma band [dB].
    measured_omega, measured_db, measured_sigma_db : float arrays
        Measured points, their 1-sigma [dB] (NaN: none); empty: none.
    wall : WallBoundary or None
        K_max(B) of ``impedance`` mode.
    rms_omega, rms_db : float arrays
        The Z-width on the predicted rms impedances [dB] (backdrives simulated on the
        identified model); empty: none.
    """

    omega: _Array
    predicted_db: _Array
    lower_db: _Array
    upper_db: _Array
    measured_omega: _Array = field(default_factory=_empty)
    measured_db: _Array = field(default_factory=_empty)
    measured_sigma_db: _Array = field(default_factory=_empty)
    wall: Optional[WallBoundary] = None
    rms_omega: _Array = field(default_factory=_empty)
    rms_db: _Array = field(default_factory=_empty)

    def __post_init__(self) -> None:
        _floats(self, "zwidth", "omega", "predicted_db", "lower_db", "upper_db")
        _floats(self, "zwidth", "rms_omega", "rms_db")
        _check_omega(self.rms_omega, "zwidth", "rms_omega")
        n = len(np.asarray(self.measured_omega).reshape(-1))
        if len(np.asarray(self.measured_sigma_db).reshape(-1)) == 0:
            self.measured_sigma_db = np.full(n, np.nan)
        _floats(self, "zwidth", "measured_omega", "measured_db", "measured_sigma_db")
        _check_omega(self.omega, "zwidth")
        _check_omega(self.measured_omega, "zwidth", "measured_omega")

    def peak(self) -> Tuple[float, float, float, float]:
        """(w [rad/s], Z-width, lower, upper [dB]) where the predicted Z-width is largest;
        NaNs when it has no finite value."""
        finite = np.isfinite(self.predicted_db)
        if not finite.any():
            return (_NAN,) * 4
        i = int(np.argmax(np.where(finite, self.predicted_db, -np.inf)))
        return (float(self.omega[i]), float(self.predicted_db[i]), float(self.lower_db[i]),
                float(self.upper_db[i]))


@dataclass
class NoiseSweep:
    """RMS of the DOB's torque command from sensor noise against the cut-off lambda.

    Attributes
    ----------
    lam : float array > 0
        DOB cut-off lambda [rad/s] (eq. 22's Q = lambda/(s + lambda)).
    rms, rms_sigma : float arrays
        RMS torque noise and its 1-sigma [N m].
    budget : float
        The allowed RMS torque noise [N m].
    chosen : float
        The chosen lambda [rad/s].
    """

    lam: _Array
    rms: _Array
    rms_sigma: _Array
    budget: float
    chosen: float

    def __post_init__(self) -> None:
        _floats(self, "torque noise", "lam", "rms", "rms_sigma")
        _check_omega(self.lam, "torque noise", "lam")
        _scalars(self, "torque noise", "budget", "chosen")


@dataclass
class WorkLoop:
    """A backdrive of one mode at one frequency: its work loop and impedance figures
    (:func:`~seaforce_ros.core.analysis.impedance_figures`).

    Attributes
    ----------
    mode : str
        The controller mode.
    omega, amplitude : float
        Drive frequency [rad/s] and amplitude [rad].
    x_e, f_e : float arrays
        One period of the loop: endpoint position [rad] and external force [N m].
    z_db, z_rms_db : float
        |Z| of the fundamental and rms(F_e)/rms(V_e) [dB re 1 N m s/rad].
    distortion : float
        Harmonic distortion of F_e (0.4: 40 %).
    peak, peak_centre : float
        Peak |F_e| over the stroke and within +-``centre_band`` [N m].
    centre_band : float
        [rad].
    source : str
        What it comes from, e.g. ``"simulated on the identified model"``.
    """

    mode: str
    omega: float
    amplitude: float
    x_e: _Array
    f_e: _Array
    z_db: float
    z_rms_db: float
    distortion: float
    peak: float
    peak_centre: float
    centre_band: float = 0.2
    source: str = ""

    def __post_init__(self) -> None:
        if _floats(self, self.mode, "x_e") != _floats(self, self.mode, "f_e"):
            raise ReportError(f"work loop {self.mode}: x_e and f_e need the same length")
        _scalars(self, self.mode, "omega", "amplitude", "z_db", "z_rms_db", "distortion",
                 "peak", "peak_centre", "centre_band")

    def describe(self) -> str:
        """One line of its figures."""
        return (f"{self.mode} at {self.omega:g} rad/s, {self.amplitude:g} rad: |Z| "
                f"{self.z_db:.1f} dB fundamental, {self.z_rms_db:.1f} dB rms, distortion "
                f"{100 * self.distortion:.0f} %, peak |F_e| {_num(self.peak, 3)} N m over the "
                f"stroke, {_num(self.peak_centre, 3)} within +-{self.centre_band:g} rad")


@dataclass
class ModelClass:
    """Whether the identified model class describes the gripper: the fits' misfits against
    the thresholds that separate a linear plant's records from nonlinear ones.

    Attributes
    ----------
    misfit, threshold : dict str -> float
        rms relative misfit of each fitted response and its threshold (0.02: 2 %).
    warning : str
        '' when every misfit is below its threshold, else what that means.
    terms : list of str
        Candidate nonlinear terms the record resolved or could not resolve, one line each.
    """

    misfit: Dict[str, float]
    threshold: Dict[str, float]
    warning: str = ""
    terms: List[str] = field(default_factory=list)

    @property
    def fits(self) -> bool:
        """No misfit beyond its threshold."""
        return not self.warning


@dataclass
class TuningRow:
    """One parameter the tuning set: key (flat ROS key), old and new value, unit, and what
    bound it (e.g. ``"passivity m_n >= m - b/lambda (eq. 28)"``)."""

    key: str
    old: float
    new: float
    unit: str
    bound_by: str

    def __post_init__(self) -> None:
        _scalars(self, self.key, "old", "new")

    @property
    def changed(self) -> bool:
        """Whether the tuning changed the value (NaN counts as a value)."""
        return not (self.old == self.new or (math.isnan(self.old) and math.isnan(self.new)))


@dataclass
class Tuning:
    """The tuning's parameter rows and the constraint that binds the whole set."""

    rows: List[TuningRow]
    binding: str


@dataclass
class ReportMeta:
    """What run this is.

    Attributes
    ----------
    channel : str
        The channel commissioned.
    date : str
        When (ISO 8601, UTC).
    phases : dict str -> float
        Duration of each phase [s], in order.
    applied : bool
        Whether the tuned parameters were applied (False: a dry run).
    seed : int or None
        Seed of a simulated run (None on hardware).
    """

    channel: str
    date: str
    phases: Dict[str, float]
    applied: bool
    seed: Optional[int] = None

    def __post_init__(self) -> None:
        try:
            self.phases = {str(k): float(v) for k, v in self.phases.items()}
        except (TypeError, ValueError, AttributeError):
            raise ReportError(f"meta: phases must map phase names to durations [s], got "
                              f"{self.phases!r}") from None

    @property
    def dry_run(self) -> bool:
        """Whether nothing was applied."""
        return not self.applied


@dataclass
class VerificationRow:
    """One window of one candidate feed-forward's verification on the free finger
    (:mod:`.verification`): the ``candidate`` (its name) and ``verdict``, the window's
    ``point`` [rad] and ``kind``, its settling time [s], decay rate [1/s] and drift [rad],
    measured on the gripper (NaN: not tried) and predicted on the identified model."""

    candidate: str
    verdict: str
    point: float
    kind: str
    settle: float
    settle_predicted: float
    decay: float
    decay_predicted: float
    drift: float
    drift_predicted: float


@dataclass
class CommissioningReport:
    """Everything one commissioning run reports. A section it did not reach is empty (a
    list) or None; its figure is then not drawn."""

    meta: ReportMeta
    identification: List[ParameterRow] = field(default_factory=list)
    responses: List[PortResponse] = field(default_factory=list)
    loop: List[LoopFigure] = field(default_factory=list)
    impedance: List[ModeImpedance] = field(default_factory=list)
    zwidth: Optional[ZWidthChart] = None
    noise: Optional[NoiseSweep] = None
    tuning: Optional[Tuning] = None
    summary: List[str] = field(default_factory=list)
    work_loops: List[WorkLoop] = field(default_factory=list)
    model_class: Optional[ModelClass] = None
    verification: List[VerificationRow] = field(default_factory=list)


# --- report.json --------------------------------------------------------------------------


def _enc_float(v: float) -> Union[float, str, None]:
    if math.isnan(v):
        return None
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return v


def _encode(obj: Any) -> Any:
    """JSON value of report data. The virtual wall also gets its derived ``k_max`` and
    ``binding`` (for readers other than :func:`load_report`, which recomputes them)."""
    if isinstance(obj, WallBoundary):
        return {**{f.name: _encode(getattr(obj, f.name)) for f in dataclasses.fields(obj)},
                "k_max": _encode(obj.k_max), "binding": obj.binding}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _encode(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.ndarray):
        if np.iscomplexobj(obj):
            return {"re": _encode(obj.real), "im": _encode(obj.imag)}
        return [_enc_float(v) for v in obj.astype(float).tolist()]
    if isinstance(obj, float):
        return _enc_float(obj)
    if isinstance(obj, dict):
        return {str(k): _encode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_encode(v) for v in obj]
    return obj


def _dec_float(raw: Any, where: str) -> float:
    if raw is None:
        return _NAN
    if raw in ("inf", "-inf"):
        return float(raw)
    if isinstance(raw, (int, float)) and not isinstance(raw, bool):
        return float(raw)
    raise ValueError(f"{where}: {raw!r} is not a number")


def _decode(hint: Any, raw: Any, where: str) -> Any:
    if hint == _CArray:
        if not isinstance(raw, dict):
            raise ValueError(f"{where}: expected {{re, im}}")
        return (_decode(_Array, raw.get("re"), where + ".re")
                + 1j * _decode(_Array, raw.get("im"), where + ".im"))
    if hint == _Array:
        if not isinstance(raw, list):
            raise ValueError(f"{where}: expected a list of numbers")
        return np.array([_dec_float(v, where) for v in raw], dtype=np.float64)
    if hint is float:
        return _dec_float(raw, where)
    if hint in (str, bool, int):
        if not isinstance(raw, hint) or (hint is int and isinstance(raw, bool)):
            raise ValueError(f"{where}: expected {hint.__name__}, got {raw!r}")
        return raw
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Union:
        if raw is None:
            return None
        return _decode(next(a for a in args if a is not type(None)), raw, where)
    if origin is list:
        if not isinstance(raw, list):
            raise ValueError(f"{where}: expected a list")
        return [_decode(args[0], v, f"{where}[{i}]") for i, v in enumerate(raw)]
    if origin is dict:
        if not isinstance(raw, dict):
            raise ValueError(f"{where}: expected an object")
        return {k: _decode(args[1], v, f"{where}.{k}") for k, v in raw.items()}
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        if not isinstance(raw, dict):
            raise ValueError(f"{where}: expected an object")
        hints = typing.get_type_hints(hint)
        kwargs = {f.name: _decode(hints[f.name], raw[f.name], f"{where}.{f.name}")
                  for f in dataclasses.fields(hint) if f.name in raw}
        return hint(**kwargs)
    raise TypeError(f"{where}: no decoder for {hint!r}")  # a field type this module lacks


def report_json(data: CommissioningReport) -> str:
    """``report.json``'s text: ``{"schema": SCHEMA, ...the report's fields}``."""
    return json.dumps({"schema": SCHEMA, **_encode(data)}, indent=1, allow_nan=False) + "\n"


def load_report(path: _PathLike) -> CommissioningReport:
    """Read a report written by :func:`write_report`.

    Parameters
    ----------
    path : path
        The report's directory, or its ``report.json``.

    Raises
    ------
    ReportError
        No such file, not JSON, another schema version, a field of the wrong kind.
    """
    p = pathlib.Path(path)
    if p.is_dir():
        p = p / "report.json"
    try:
        raw = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ReportError(f"cannot read {p}: {exc.strerror}; give a report directory "
                          "written by write_report") from None
    except ValueError as exc:
        raise ReportError(f"{p} is not JSON ({exc}); write the report again") from None
    if not isinstance(raw, dict) or raw.get("schema") != SCHEMA:
        found = raw.get("schema") if isinstance(raw, dict) else None
        raise ReportError(f"{p}: report schema {found!r}, this version reads {SCHEMA}; "
                          "write the report again with this version")
    try:
        report: CommissioningReport = _decode(CommissioningReport, raw, "report")
    except (ValueError, TypeError, KeyError, CommissioningError) as exc:
        raise ReportError(f"{p}: {exc}; write the report again") from None
    return report


# --- the figures --------------------------------------------------------------------------


def _hex(rgb: Tuple[int, int, int]) -> str:
    return "#%02x%02x%02x" % rgb


def _mark(fig: Figure, letter: str) -> None:
    """The figure's marker colour: a lettered badge top left, a square bottom right."""
    from matplotlib.patches import Rectangle

    colour = _hex(FIGURE_MARKERS[letter][1])
    w, h = fig.get_size_inches() * _DPI
    bw, bh, sq = 30.0 / w, 30.0 / h, 12.0
    fig.patches.append(Rectangle((0.0, 1.0 - bh), bw, bh, transform=fig.transFigure,
                                 facecolor=colour, edgecolor="none", antialiased=False))
    fig.patches.append(Rectangle((1.0 - sq / w, 0.0), sq / w, sq / h,
                                 transform=fig.transFigure, facecolor=colour,
                                 edgecolor="none", antialiased=False))
    fig.text(bw / 2, 1.0 - bh / 2, letter, transform=fig.transFigure, ha="center",
             va="center", color="white", fontsize=13, fontweight="bold")


def _png(fig: Figure, letter: str, title: str) -> bytes:
    """Marker, title, layout; the PNG's bytes. The figure is closed."""
    plt = _plt()
    _mark(fig, letter)
    w, h = fig.get_size_inches() * _DPI
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 34.0 / h))
    fig.text(40.0 / w, 1.0 - 15.0 / h, title, ha="left", va="center", fontsize=12)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI)
    plt.close(fig)
    return buf.getvalue()


def _db(h: npt.ArrayLike) -> _Array:
    """20 log10 |h|, with -inf (not a warning) where h is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return _plot_db(h)


def _grid(ax: Axes) -> None:
    ax.grid(True, which="both", alpha=0.3)


def _fig_responses(responses: Sequence[PortResponse]) -> Figure:
    plt = _plt()
    fig, axes = plt.subplots(3, len(responses), figsize=(11, 7.6), sharex="col",
                               squeeze=False,
                               gridspec_kw={"height_ratios": (3, 2, 1.3)})
    for col, r in enumerate(responses):
        mag, ph, coh = axes[:, col]
        mh = np.abs(r.measured)
        rel = np.minimum(r.sigma / np.where(mh > 0, mh, np.nan), 0.9)
        mag.semilogx(r.omega, _db(r.measured), color="tab:blue", label="measured")
        mag.fill_between(r.omega, _db(mh * (1 - rel)), _db(mh * (1 + rel)),
                         color="tab:blue", alpha=0.25, linewidth=0, label="1-sigma")
        mag.semilogx(r.omega, _db(r.model), "--", color="tab:red", label="fitted model")
        phase = np.degrees(np.unwrap(np.angle(r.measured)))
        ph.semilogx(r.omega, phase, color="tab:blue")
        ph.fill_between(r.omega, phase - np.degrees(rel), phase + np.degrees(rel),
                        color="tab:blue", alpha=0.25, linewidth=0)
        ph.semilogx(r.omega, np.degrees(np.unwrap(np.angle(r.model))), "--", color="tab:red")
        coh.semilogx(r.omega, r.coherence, color="tab:green")
        coh.set_ylim(0.0, 1.05)
        mag.set_title(f"{r.name} [{r.unit}]" if r.unit else r.name, fontsize=11)
        coh.set_xlabel("frequency w [rad/s]")
        for ax in (mag, ph, coh):
            _grid(ax)
        if col == 0:
            mag.set_ylabel("magnitude [dB]")
            ph.set_ylabel("phase [deg]")
            coh.set_ylabel("coherence")
            mag.legend(fontsize=8, loc="best")
    return fig


_MODE_COLOURS = dict(zip(MODES, ("tab:gray", "tab:brown", "tab:purple", "tab:blue",
                                 "tab:orange", "tab:green", "tab:red")))


def _fig_impedance(modes: Sequence[ModeImpedance]) -> Figure:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(11, 5.4))
    extra = iter(("tab:olive", "tab:cyan", "tab:pink", "black"))
    for m in modes:
        colour = _MODE_COLOURS.get(m.mode) or next(extra, "black")
        ax.semilogx(m.omega, _db(m.z), color=colour, lw=1.8, label=m.mode)
        ax.fill_between(m.omega, _db(m.lower), _db(m.upper), color=colour, alpha=0.15,
                        linewidth=0)
        if len(m.measured_omega):
            ax.semilogx(m.measured_omega, _db(m.measured_abs), "o", color=colour, ms=6,
                        mfc="white", mew=1.6)
        if len(m.rms_omega):
            ax.semilogx(m.rms_omega, _db(m.rms_abs), "s", color=colour, ms=7, mfc="none",
                        mew=1.4)
    ax.plot([], [], "o", color="0.3", mfc="white", mew=1.6, label="measured")
    if any(len(m.rms_omega) for m in modes):
        ax.plot([], [], "s", color="0.3", mfc="none", mew=1.4, label="rms (simulated)")
    ax.set_xlabel("frequency w [rad/s]")
    ax.set_ylabel("|Z| = |F_e/V_e| [dB re 1 N m s/rad]")
    _grid(ax)
    ax.legend(fontsize=9, loc="center left", bbox_to_anchor=(1.01, 0.5))
    return fig


def _fig_zwidth(chart: ZWidthChart) -> Figure:
    plt = _plt()
    panels = 2 if chart.wall is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(11, 4.8), squeeze=False,
                               gridspec_kw={"width_ratios": (3, 2)[:panels]})
    ax = axes[0, 0]
    ax.semilogx(chart.omega, chart.predicted_db, color="tab:blue", lw=2, label="predicted")
    ax.fill_between(chart.omega, chart.lower_db, chart.upper_db, color="tab:blue", alpha=0.2,
                    linewidth=0, label="1-sigma band")
    if len(chart.measured_omega):
        err = np.where(np.isfinite(chart.measured_sigma_db), chart.measured_sigma_db, 0.0)
        ax.errorbar(chart.measured_omega, chart.measured_db, yerr=err, fmt="o",
                    color="tab:red", ms=6, capsize=3, label="measured")
    if len(chart.rms_omega):
        ax.plot(chart.rms_omega, chart.rms_db, "s", color="tab:purple", ms=8, mfc="none",
                mew=1.6, label="on the rms (simulated)")
    ax.set_xscale("log")
    ax.set_xlabel("frequency w [rad/s]")
    ax.set_ylabel("Z-width 20 log10(|Z_hold|/|Z_min|) [dB]")
    _grid(ax)
    ax.legend(fontsize=9, loc="best")
    if chart.wall is not None:
        _wall_panel(axes[0, 1], chart.wall)
    return fig


def _wall_panel(ax: Axes, wall: WallBoundary) -> None:
    b, kmax = wall.damping, wall.k_max
    ax.plot(b, wall.k_passivity, color="tab:blue", lw=1.2, label="passivity with delay")
    if np.isfinite(wall.k_quantisation).any():
        ax.plot(b, wall.k_quantisation, color="tab:orange", lw=1.2,
                label="encoder quantisation")
    finite = np.isfinite(kmax)
    ax.fill_between(b, 0.0, np.where(finite, kmax, np.nan), color="tab:green", alpha=0.15,
                    linewidth=0, label="stable walls")
    binds = np.array(wall.binding)
    for which, colour in (("passivity", "tab:blue"), ("quantisation", "tab:orange")):
        ax.plot(b, np.where(binds == which, kmax, np.nan), color=colour, lw=3.5)
    if math.isfinite(wall.chosen_damping) and math.isfinite(wall.chosen_stiffness):
        ax.plot([wall.chosen_damping], [wall.chosen_stiffness], "*", color="black", ms=13,
                label="chosen (B, K)")
    ax.set_xlabel("virtual damping B [N m s/rad]")
    ax.set_ylabel("K_max [N m/rad]")
    ax.set_title("stable virtual wall (thick: the limit that binds)", fontsize=10)
    ax.set_ylim(bottom=0.0)
    _grid(ax)
    ax.legend(fontsize=8, loc="upper left")


def _fig_noise(noise: NoiseSweep) -> Figure:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(11, 4.4))
    ax.loglog(noise.lam, noise.rms, "o-", color="tab:blue", ms=4, label="RMS torque noise")
    ax.fill_between(noise.lam, np.maximum(noise.rms - noise.rms_sigma, noise.rms * 1e-3),
                    noise.rms + noise.rms_sigma, color="tab:blue", alpha=0.2, linewidth=0,
                    label="1-sigma")
    ax.axhline(noise.budget, color="tab:red", ls="--", lw=1.5,
               label=f"budget {noise.budget:.3g} N m")
    if math.isfinite(noise.chosen):
        ax.axvline(noise.chosen, color="black", lw=1.5,
                   label=f"chosen lambda = {noise.chosen:.4g} rad/s")
    ax.set_xlabel("DOB cut-off lambda [rad/s]")
    ax.set_ylabel("RMS torque command noise [N m]")
    _grid(ax)
    ax.legend(fontsize=9, loc="lower right")
    return fig


def _fig_work_loops(loops: Sequence[WorkLoop]) -> Figure:
    plt = _plt()
    stiff = [w for w in loops if w.mode == "hold"]
    soft = [w for w in loops if w.mode != "hold"]
    panels = [p for p in (soft, stiff) if p]
    fig, axes = plt.subplots(1, len(panels), figsize=(11, 4.8), squeeze=False)
    extra = iter(("tab:olive", "tab:cyan", "tab:pink", "black"))
    for ax, group in zip(axes[0], panels):
        for w in group:
            colour = _MODE_COLOURS.get(w.mode) or next(extra, "black")
            ax.plot(w.x_e, w.f_e, color=colour, lw=1.5,
                    label=f"{w.mode}: |Z| {w.z_db:.1f} dB, rms {w.z_rms_db:.1f} dB, "
                          f"dist. {100 * w.distortion:.0f} %")
            ax.axvspan(-w.centre_band, w.centre_band, color="0.93", zorder=0)
        ax.set_xlabel("endpoint position X_e [rad]")
        ax.set_ylabel("external torque F_e [N m]")
        _grid(ax)
        ax.legend(fontsize=8, loc="best")
    return fig


@dataclass(frozen=True)
class RenderedFigure:
    """One drawn figure: letter (a-d), file name, title, caption, the PNG's bytes."""

    letter: str
    file: str
    title: str
    caption: str
    png: bytes


def _captions(data: CommissioningReport) -> List[Tuple[str, str, Callable[[], Figure], str]]:
    """(letter, title, draw, caption) of each figure whose section has data."""
    out: List[Tuple[str, str, Callable[[], Figure], str]] = []
    if data.responses:
        names = ", ".join(r.name for r in data.responses)
        out.append(("a", "Measured port responses", lambda: _fig_responses(data.responses),
                    f"Port responses measured in free air ({names}): magnitude with the "
                    "1-sigma band (blue), the fitted model (red, dashed), phase and the "
                    "coherence of the estimate. Low coherence marks frequencies the fit "
                    "should not trust."))
    if data.impedance:
        out.append(("b", "Predicted endpoint impedance per mode",
                    lambda: _fig_impedance(data.impedance),
                    "Predicted |Z(jw)| = |F_e/V_e| of each controller mode with its 1-sigma "
                    "band; open circles: measured points, where a backdrive measured them; "
                    "open squares: the rms impedance rms(F_e)/rms(V_e) of backdrives "
                    "simulated on the identified model (0.5 rad, at most 0.5 rad/s), which "
                    "counts the harmonics of its nonlinear terms."))
    if data.zwidth is not None:
        chart = data.zwidth
        wall = ""
        if chart.wall is not None:
            wall = (" Right: the stable virtual walls of impedance mode, K_max(B) the lower of "
                    "the passivity-with-delay and the quantisation limits (thick where it "
                    f"binds), and the chosen (B, K); {chart.wall.describe()}.")
        out.append(("c", "Z-width: predicted vs measured", lambda: _fig_zwidth(chart),
                    "Z-width, the range between the stiff hold and the lowest-impedance mode, "
                    "predicted with its 1-sigma band and measured (red); squares: on the rms "
                    "impedances of the simulated backdrives." + wall))
    if data.noise is not None:
        noise = data.noise
        out.append(("d", "DOB torque noise vs lambda", lambda: _fig_noise(noise),
                    "RMS of the DOB's torque command from the measured sensor noise against "
                    "the cut-off lambda, with its 1-sigma band, the budget (red) and the "
                    "lambda the tuning chose (black)."))
    if data.work_loops:
        loops = data.work_loops
        source = loops[0].source or "a backdrive"
        out.append(("e", "Work loops", lambda: _fig_work_loops(loops),
                    f"External torque against endpoint position, the finger backdriven at "
                    f"{loops[0].omega:g} rad/s, {loops[0].amplitude:g} rad ({source}); grey: "
                    f"+-{loops[0].centre_band:g} rad about the centre, where the paper's "
                    "compensation holds. The legend gives |Z| of the fundamental beside the "
                    "rms impedance rms(F_e)/rms(V_e) and the distortion of F_e: where the "
                    "fundamental nearly cancels, the rms is what the finger feels. "
                    + " ".join(w.describe() + "." for w in loops)))
    return out


def render_figures(data: CommissioningReport) -> List[RenderedFigure]:
    """The report's figures, one per section that has data, in the order (a)-(e)."""
    figs = []
    with warnings.catch_warnings():
        # Data with nothing to draw on a log axis (all NaN, zero) leaves its panel empty,
        # which the figure shows; matplotlib's warning about it would say nothing more.
        warnings.simplefilter("ignore", UserWarning)
        for letter, title, draw, caption in _captions(data):
            png = _png(draw(), letter, f"({letter}) {title}")
            figs.append(RenderedFigure(letter, FIGURE_MARKERS[letter][0], title, caption, png))
    return figs


# --- text: numbers, the plain-text table, the page ----------------------------------------


def _num(v: float, digits: int = 4) -> str:
    if math.isnan(v):
        return "-"
    return f"{v:.{digits}g}"


def _pm(value: float, sigma: float) -> str:
    """``value +- sigma`` (sigma to 2 significant digits; none when NaN)."""
    if math.isnan(sigma):
        return _num(value)
    return f"{_num(value)} \u00b1 {_num(sigma, 2)}"


def _drift(row: ParameterRow) -> str:
    """``previous (+x.x %, +y.y sigma)``: the value of the last commissioning and the drift
    since, relative and in units of this run's 1-sigma (either left out when undefined)."""
    if math.isnan(row.previous):
        return "-"
    rel = (row.value - row.previous) / row.previous if row.previous else _NAN
    parts = [f"{100 * rel:+.1f} %"] if math.isfinite(rel) else []
    if math.isfinite(row.drift_sigmas):
        parts.append(f"{row.drift_sigmas:+.1f} sigma")
    return _num(row.previous) + (f" ({', '.join(parts)})" if parts else "")


def _zwidth_headline(chart: ZWidthChart) -> str:
    w, db, lo, hi = chart.peak()
    if math.isnan(w):
        return "Z-width: no finite prediction"
    return f"Z-width (predicted): {db:.1f} dB ({lo:.1f} .. {hi:.1f}) at w = {w:.3g} rad/s"


def _plain(headers: Sequence[str], rows: Sequence[Sequence[str]], numeric: str) -> str:
    """A plain-text table; ``numeric``: one letter per column, ``n`` right-aligned, any other
    left-aligned."""
    from ..identification.output import format_table

    cells = [list(r) for r in rows]
    for i, kind in enumerate(numeric):
        if kind != "n":
            width = max([len(headers[i])] + [len(r[i]) for r in cells])
            for r in cells:
                r[i] = r[i].ljust(width)
    return format_table(headers, cells, (None,) * len(headers))


def _both(measured: float, predicted: float, digits: int) -> str:
    """``measured / predicted`` (``-`` where there is none)."""
    m = "-" if math.isnan(measured) else f"{measured:.{digits}f}"
    p = "-" if math.isnan(predicted) else f"{predicted:.{digits}f}"
    return f"{m} / {p}"


def _model_class_lines(model: Optional[ModelClass]) -> List[str]:
    """The model class's verdict: the misfits against their thresholds, the warning, the
    candidate terms."""
    if model is None:
        return []
    fits = ", ".join(f"{k} {100 * v:.2g} % (threshold {100 * model.threshold.get(k, _NAN):.2g} %)"
                     for k, v in model.misfit.items())
    head = (f"model class: {'fits' if model.fits else 'DOES NOT FIT'} -- misfit {fits}")
    out = [head]
    if model.warning:
        out.append(f"WARNING: {model.warning}")
    out += [f"  {t}" for t in model.terms]
    return out


def summary_table(data: CommissioningReport) -> str:
    """The plain-text summary a command-line tool prints: meta, summary lines, the
    identification, the loop figures, the tuning (a changed value marked ``*``)."""
    m = data.meta
    lines = [f"commissioning of {m.channel} on {m.date}: "
             + ("applied" if m.applied else "dry run (nothing applied)")
             + ("" if m.seed is None else f", simulated (seed {m.seed})"),
             "phases: " + (", ".join(f"{k} {v:.1f} s" for k, v in m.phases.items()) or "-")]
    lines += [f"  {s}" for s in data.summary]
    lines += [f"  {s}" for s in _model_class_lines(data.model_class)]
    for w in data.work_loops:
        lines.append(f"  work loop ({w.source or 'backdrive'}): {w.describe()}")
    if data.zwidth is not None:
        lines.append("  " + _zwidth_headline(data.zwidth))
        if data.zwidth.wall is not None:
            lines.append("  " + data.zwidth.wall.describe())
    if data.identification:
        lines += ["", _plain(
            ("parameter", "symbol", "value +- 1-sigma", "unit", "previous (drift)", "status"),
            [(r.name, r.symbol, _pm(r.value, r.sigma), r.unit, _drift(r), r.status)
             for r in data.identification], "ttntnt")]
    if data.loop:
        lines += ["", _plain(("sensor / loop figure", "value +- 1-sigma", "unit"),
                             [(f.name, _pm(f.value, f.sigma), f.unit) for f in data.loop],
                             "tnt")]
    if data.verification:
        lines += ["", _plain(("candidate feed-forward", "verdict", "window", "settling [s]",
                              "decay [1/s]", "drift [mrad]"),
                             [(r.candidate, r.verdict, f"{r.kind} at {r.point:.3g} rad",
                               _both(r.settle, r.settle_predicted, 2),
                               _both(r.decay, r.decay_predicted, 1),
                               _both(1e3 * r.drift, 1e3 * r.drift_predicted, 2))
                              for r in data.verification], "tttnnn"),
                  "  (measured on the gripper / predicted on the identified model)"]
    if data.tuning is not None:
        if data.tuning.rows:
            lines += ["", _plain(("tuned parameter", "old", "new", "unit", "bound by"),
                                 [(r.key, _num(r.old), ("* " if r.changed else "")
                                   + _num(r.new), r.unit, r.bound_by)
                                  for r in data.tuning.rows], "tnntt")]
        lines.append(f"binding constraint: {data.tuning.binding or '-'}")
    return "\n".join(lines)


_CSS = """
body{font-family:"DejaVu Sans",Arial,sans-serif;margin:0;background:#f4f5f7;color:#1d2330;
font-size:14px;line-height:1.4}
main{max-width:1180px;margin:0 auto;padding:18px 20px 40px}
h1{font-size:22px;margin:0 0 4px}h2{font-size:17px;margin:26px 0 8px;border-bottom:2px solid
#c9ced8;padding-bottom:3px}
.meta{color:#4a5262;font-size:13px}
.badge{display:inline-block;padding:1px 8px;border-radius:9px;font-size:12px;font-weight:bold;
margin-left:8px;vertical-align:middle}
.applied{background:#d7f0dc;color:#1d5e2b}.dry{background:#fdebc8;color:#7a4b00}
.cards{display:flex;gap:12px;flex-wrap:wrap;margin-top:14px}
.card{background:#fff;border:1px solid #d5d9e0;border-radius:6px;padding:10px 14px;
flex:1 1 300px}
.card h3{margin:0 0 6px;font-size:13px;text-transform:uppercase;letter-spacing:.04em;
color:#5a6272}
.big{font-size:24px;font-weight:bold}
ul.summary{margin:4px 0 0;padding-left:18px}
table{border-collapse:collapse;background:#fff;width:100%;font-size:13px}
th,td{border:1px solid #d5d9e0;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#e8ebf0}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
td.u{white-space:nowrap}
tr.bad td{background:#fbe3e3}tr.changed td{background:#e6f2e0}
.drift{color:#9c1c1c;font-weight:bold}
code{font-size:12px}
figure{background:#fff;border:1px solid #d5d9e0;border-radius:6px;margin:14px 0;padding:8px}
figure img{display:block;max-width:100%;height:auto}
figcaption{font-size:13px;color:#333a48;padding:6px 4px 0}
.missing{color:#7a4b00;font-style:italic}
"""


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _table(headers: Sequence[str], rows: Sequence[Tuple[str, Sequence[Tuple[str, str]]]]
           ) -> str:
    """``rows``: (row class, [(escaped cell html, cell class: "n" a number, "u" a unit, ""
    text)])."""
    head = "".join(f"<th>{_e(h)}</th>" for h in headers)
    body = "".join(
        f'<tr class="{cls}">' + "".join(f'<td class="{k}">{c}</td>' if k else f"<td>{c}</td>"
                                        for c, k in cells) + "</tr>"
        for cls, cells in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _identification_html(rows: Sequence[ParameterRow]) -> str:
    body = []
    for r in rows:
        drift = _e(_drift(r))
        if abs(r.drift_sigmas) > 3.0:
            drift = f'<span class="drift">{drift}</span>'
        cells = [(f"<code>{_e(r.name)}</code>", ""), (_e(r.symbol), ""),
                 (_e(_pm(r.value, r.sigma)), "n"), (_e(r.unit), "u"), (drift, "n")]
        if any(math.isfinite(x.true) for x in rows):
            cells.append((_e(_num(r.true)), "n"))
        cells.append((_e(r.status), ""))
        body.append(("" if r.identified else "bad", cells))
    headers = ["parameter", "symbol", "value \u00b1 1-sigma", "unit", "previous (drift)"]
    if any(math.isfinite(x.true) for x in rows):
        headers.append("true (sim)")
    return _table(headers + ["status"], body)


def _tuning_html(tuning: Tuning) -> str:
    body = [("changed" if r.changed else "",
             [(f"<code>{_e(r.key)}</code>", ""), (_e(_num(r.old)), "n"),
              ((f"<b>{_e(_num(r.new))}</b>" if r.changed else _e(_num(r.new))), "n"),
              (_e(r.unit), "u"), (_e(r.bound_by), "")]) for r in tuning.rows]
    return (_table(["parameter", "old", "new", "unit", "bound by"], body)
            + f"<p><b>Binding constraint:</b> {_e(tuning.binding)}</p>")


def _cards(data: CommissioningReport) -> str:
    ident = data.identification
    n_ok = sum(r.identified for r in ident)
    cards = [f'<div class="card"><h3>Identification</h3><div class="big">{n_ok} / {len(ident)}'
             '</div>parameters identified'
             + "".join(f"<br>{_e(r.symbol or r.name)}: {_e(r.status)}" for r in ident
                       if not r.identified) + "</div>"]
    if data.zwidth is not None:
        w, db, lo, hi = data.zwidth.peak()
        cards.append('<div class="card"><h3>Predicted Z-width</h3>'
                     + (f'<div class="big">{db:.1f} dB</div>1-sigma band {lo:.1f} .. '
                        f'{hi:.1f} dB, at w = {w:.3g} rad/s' if math.isfinite(w)
                        else "no finite prediction")
                     + ("" if data.zwidth.wall is None
                        else f"<br>{_e(data.zwidth.wall.describe())}") + "</div>")
    if data.tuning is not None:
        changed = [r for r in data.tuning.rows if r.changed]
        cards.append(f'<div class="card"><h3>Tuning</h3><div class="big">{len(changed)} '
                     'changed</div>'
                     + "".join(f"<code>{_e(r.key)}</code> {_e(_num(r.old))} \u2192 "
                               f"<b>{_e(_num(r.new))}</b> {_e(r.unit)}<br>"
                               for r in changed)
                     + f"bound by: {_e(data.tuning.binding)}</div>")
    if data.model_class is not None:
        mc = data.model_class
        lines = _model_class_lines(mc)
        verdict = "fits" if mc.fits else "does not fit"
        cards.append(f'<div class="card"><h3>Model class</h3><div class="big'
                     + ('' if mc.fits else ' drift') + f'">{verdict}</div>'
                     + "<br>".join(_e(x) for x in lines) + "</div>")
    summary = "".join(f"<li>{_e(s)}</li>" for s in data.summary)
    if summary:
        cards.append(f'<div class="card"><h3>Summary</h3><ul class="summary">{summary}</ul>'
                     "</div>")
    return '<div class="cards">' + "".join(cards) + "</div>"


def render_html(data: CommissioningReport, figures: Sequence[RenderedFigure]) -> str:
    """``report.html``'s text: self-contained (inline CSS, ``figures`` as base64 data URIs,
    nothing fetched); every text of ``data`` escaped."""
    m = data.meta
    status = ('<span class="badge applied">applied</span>' if m.applied
              else '<span class="badge dry">dry run: nothing applied</span>')
    sim = "" if m.seed is None else f" &middot; simulated, seed {m.seed}"
    phases = " &middot; ".join(f"{_e(k)} {v:.1f} s" for k, v in m.phases.items())
    parts = [f"<h1>Commissioning report: {_e(m.channel)}{status}</h1>",
             f'<div class="meta">{_e(m.date)}{sim}<br>phases: {phases or "-"}</div>',
             _cards(data)]
    if data.tuning is not None:
        parts += ["<h2>Tuning: what changed</h2>", _tuning_html(data.tuning)]
    if data.verification:
        parts += ["<h2>The feed-forward verified on the free finger</h2>", _table(
            ["candidate", "verdict", "window", "settling [s] measured / predicted",
             "decay [1/s]", "drift [mrad]"],
            [("bad" if r.verdict.startswith("failed") else
              "changed" if r.verdict == "passed" else "",
              [(_e(r.candidate), ""), (_e(r.verdict), ""),
               (_e(f"{r.kind} at {r.point:.3g} rad"), ""),
               (_e(_both(r.settle, r.settle_predicted, 2)), "n"),
               (_e(_both(r.decay, r.decay_predicted, 1)), "n"),
               (_e(_both(1e3 * r.drift, 1e3 * r.drift_predicted, 2)), "n")])
             for r in data.verification])]
    parts.append("<h2>Identified parameters</h2>")
    parts.append(_identification_html(data.identification) if data.identification
                 else '<p class="missing">No identification in this run.</p>')
    if data.loop:
        parts += ["<h2>Sensor and loop figures</h2>", _table(
            ["figure", "value \u00b1 1-sigma", "unit"],
            [("", [(_e(f.name), ""), (_e(_pm(f.value, f.sigma)), "n"),
                   (_e(f.unit), "u")]) for f in data.loop])]
    if data.work_loops:
        parts += ["<h2>Work loops</h2>", _table(
            ["mode", "omega [rad/s]", "|Z| fundamental [dB]", "|Z| rms [dB]", "distortion",
             "peak |F_e| [N m]", "peak within the centre band [N m]", "source"],
            [("", [(_e(w.mode), ""), (_e(_num(w.omega)), "n"), (_e(f"{w.z_db:.1f}"), "n"),
                   (_e(f"{w.z_rms_db:.1f}"), "n"), (_e(f"{100 * w.distortion:.0f} %"), "n"),
                   (_e(_num(w.peak, 3)), "n"), (_e(_num(w.peak_centre, 3)), "n"),
                   (_e(w.source), "")]) for w in data.work_loops])]
    parts.append("<h2>Figures</h2>")
    drawn = {f.letter for f in figures}
    for f in figures:
        uri = "data:image/png;base64," + base64.b64encode(f.png).decode("ascii")
        parts.append(f'<figure id="fig-{f.letter}"><img src="{uri}" alt="({f.letter}) '
                     f'{_e(f.title)}"><figcaption><b>({f.letter}) {_e(f.title)}.</b> '
                     f"{_e(f.caption)} <i>({_e(f.file)})</i></figcaption></figure>")
    for letter in FIGURE_MARKERS:
        if letter not in drawn:
            parts.append(f'<p class="missing">({letter}) {_e(FIGURE_MARKERS[letter][0])}: '
                         "not drawn, this run has no data for it.</p>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>Commissioning {_e(m.channel)} {_e(m.date)}</title>"
            f"<style>{_CSS}</style></head><body><main>\n" + "\n".join(parts)
            + "\n</main></body></html>\n")


# --- the directory ------------------------------------------------------------------------


def _os_error(exc: OSError, what: str) -> ReportError:
    hint = {errno.ENOSPC: "the disk is full: free some space or give a directory on another "
                          "disk",
            errno.EDQUOT: "the disk quota is used up: free some space or give another "
                          "directory",
            errno.EACCES: "permission denied: give a directory you can write, or change its "
                          "permissions",
            errno.EPERM: "not permitted: give a directory you can write",
            errno.EROFS: "the file system is read-only: give a directory on a writable disk",
            errno.ENOTDIR: "a part of the path is a file, not a directory: give another path",
            }.get(exc.errno or 0, f"{exc.strerror or exc}: give another directory")
    return ReportError(f"cannot {what}: {hint}")


def _prepare(directory: pathlib.Path) -> List[pathlib.Path]:
    """Create ``directory`` (parents too); the directories created, innermost first."""
    if directory.exists() and not directory.is_dir():
        raise ReportError(f"cannot write the report into {directory}: it is a file; remove it "
                          "or give another directory")
    created = [p for p in (directory, *directory.parents) if not p.exists()]
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _os_error(exc, f"create the directory {directory}") from None
    if not os.access(directory, os.W_OK | os.X_OK):
        raise ReportError(f"cannot write the report into {directory}: permission denied; "
                          "give a directory you can write, or change its permissions")
    return created


def _write_all(directory: pathlib.Path, files: Sequence[Tuple[str, bytes]]) -> None:
    """Write every file under a temporary name, then rename them into place in order, the
    last one (report.html) last of all, after removing the earlier one: a failure while
    writing leaves the previous files as they were and no temporary file; one while renaming
    leaves no report.html."""
    temps: List[pathlib.Path] = []
    try:
        for name, content in files:
            tmp = directory / f".{name}.{os.getpid()}.tmp"
            temps.append(tmp)
            with open(tmp, "wb") as fh:
                fh.write(content)
                fh.flush()
                os.fsync(fh.fileno())
        # From here on an earlier report's page would no longer match its files: it goes
        # first, the new one comes last.
        (directory / files[-1][0]).unlink(missing_ok=True)
        for (name, _), tmp in zip(files, temps):
            os.replace(tmp, directory / name)
    except OSError as exc:
        for tmp in temps:
            try:
                tmp.unlink()
            except OSError:
                pass
        raise _os_error(exc, f"write the report into {directory}") from None


def write_report(directory: _PathLike, data: CommissioningReport) -> pathlib.Path:
    """Write the report directory (see the module's docstring for the files).

    Parameters
    ----------
    directory : path
        Created with its parents if missing; files of an earlier report in it are replaced.
    data : CommissioningReport
        What to report.

    Returns
    -------
    pathlib.Path
        The path of ``report.html``.

    Raises
    ------
    ReportError
        ``directory`` is a file, cannot be created or written, or the disk is full. Nothing
        is left half-written: every file is written under a temporary name first and renamed
        when all are complete, ``report.html`` last; the directories this call created are
        removed again.
    """
    try:   # checked again as a whole: the data classes can be changed after construction
        data = _decode(CommissioningReport, _encode(data), "report")
    except (ValueError, TypeError, KeyError, CommissioningError) as exc:
        raise ReportError(f"nothing written: {exc}") from None
    d = pathlib.Path(directory)
    created = _prepare(d)
    try:
        figures = render_figures(data)
        files = [(f.file, f.png) for f in figures]
        files.append(("report.json", report_json(data).encode("utf-8")))
        files.append(("report.html", render_html(data, figures).encode("utf-8")))
        _write_all(d, files)
    except BaseException:
        for p in created:
            try:
                p.rmdir()
            except OSError:
                break
        raise
    return d / "report.html"


"""From a :class:`~seaforce_ros.bags.reader.ChannelRecord` to uniformly sampled, finite arrays.

* Sample period: from the header stamps per cycle (median), snapped to a whole rate in Hz
  when within 1 % of one (a realtime node's stamps jitter; its cycle does not), or given.
* Samples with a NaN/inf in a needed field are dropped and counted; dropped samples and cycles
  missing from the record (lost messages) are filled by linear interpolation on the cycle grid
  so that the spectral estimates see a uniform grid. Both counts are reported; more than
  ``max_gap_fraction`` of filled samples is an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Dict, Iterable, List, Optional, Sequence

import numpy as np
import numpy.typing as npt

from .errors import IdentificationError

if TYPE_CHECKING:
    from ..bags.reader import ChannelRecord

__all__ = ["Series", "prepare", "sample_period"]


@dataclass
class Series:
    """Uniformly sampled finite data of one channel.

    ``signals`` maps ``x v f_p f_a x_e f_e`` to arrays of equal length (fields that were NaN
    everywhere are absent); ``dt`` [s]; ``nan_dropped`` samples dropped for a non-finite value
    per field; ``missing`` cycles absent from the record; ``filled`` samples interpolated.
    """

    channel: str
    dt: float
    signals: Dict[str, npt.NDArray[np.float64]]
    cycle0: int
    nan_dropped: Dict[str, int] = field(default_factory=dict)
    missing: int = 0
    filled: int = 0
    absent: Sequence[str] = ()
    gaps: int = 0
    longest_gap: int = 0

    @property
    def n(self) -> int:
        """Samples per signal."""
        return int(next(iter(self.signals.values())).size)

    @property
    def duration(self) -> float:
        """n dt [s]."""
        return self.n * self.dt

    def notes(self) -> List[str]:
        """Human-readable lines about dropped / missing data."""
        out = []
        dropped = {k: v for k, v in self.nan_dropped.items() if v}
        if dropped:
            out.append("non-finite samples dropped: " + ", ".join(
                f"{k} {v}" for k, v in dropped.items()) + " (filled by interpolation)")
        if self.missing:
            out.append(f"{self.missing} cycles missing from the record "
                       f"({100 * self.missing / max(self.n, 1):.2f} %, in {self.gaps} gaps, "
                       f"the longest {self.longest_gap} cycles = "
                       f"{1e3 * self.longest_gap * self.dt:.3g} ms; filled by interpolation)")
        if self.absent:
            out.append("not measured (NaN in every sample): " + ", ".join(self.absent))
        return out


def sample_period(record: ChannelRecord, dt: Optional[float] = None) -> float:
    """Sample period [s] of a record (see module docstring)."""
    if dt is not None:
        if not dt > 0:
            raise IdentificationError("the sample period must be > 0")
        return float(dt)
    if len(record) < 2:
        raise IdentificationError("too little data: fewer than 2 samples")
    dc = np.diff(record.cycle).astype(float)
    ds = np.diff(record.stamp)
    ok = (dc > 0) & np.isfinite(ds) & (ds > 0)
    if ok.sum() < 1:
        raise IdentificationError("cannot tell the sample period from the header stamps; "
                                  "pass --rate HZ")
    est = float(np.median(ds[ok] / dc[ok]))
    rate = round(1.0 / est)
    if rate > 0 and abs(1.0 / rate - est) < 0.01 * est:
        return 1.0 / rate
    return est


def prepare(record: ChannelRecord, fields: Sequence[str], dt: Optional[float] = None,
            max_gap_fraction: float = 0.2, optional: Iterable[str] = ()) -> Series:
    """Uniform, finite arrays of ``fields`` (+ ``optional`` ones when measured).

    Raises
    ------
    IdentificationError
        A required field is NaN everywhere, too much data missing, too few samples.
    """
    period = sample_period(record, dt)
    cycle = record.cycle.astype(np.int64)
    n_total = int(cycle[-1] - cycle[0] + 1)
    signals: Dict[str, npt.NDArray[np.float64]] = {}
    dropped: Dict[str, int] = {}
    absent: List[str] = []
    grid = np.arange(n_total, dtype=float)
    pos = (cycle - cycle[0]).astype(float)
    filled_mask = np.ones(n_total, bool)
    filled_mask[(cycle - cycle[0])] = False
    for name in list(fields) + [f for f in optional if f not in fields]:
        values = np.asarray(getattr(record, name), float)
        finite = np.isfinite(values)
        if not finite.any():
            if name in fields:
                raise IdentificationError(
                    f"{name} is NaN in every sample of channel {record.channel!r}: "
                    + _WHY.get(name, "this field is needed"))
            absent.append(name)
            continue
        dropped[name] = int((~finite).sum())
        if finite.sum() < 2:
            raise IdentificationError(f"too little data: {name} has fewer than 2 finite samples")
        signals[name] = np.interp(grid, pos[finite], values[finite])
        lost = np.ones(n_total, bool)
        lost[(cycle - cycle[0])[finite]] = False
        filled_mask |= lost
    missing = int(n_total - cycle.size)
    steps = np.diff(cycle)
    holes = steps[steps > 1] - 1
    filled = int(filled_mask.sum())
    if filled > max_gap_fraction * n_total:
        raise IdentificationError(
            f"too much data missing: {filled} of {n_total} samples are NaN or lost "
            f"(more than {100 * max_gap_fraction:.0f} %)")
    return Series(record.channel, period, signals, int(cycle[0]), dropped, missing, filled,
                  tuple(absent), int(holes.size), int(holes.max()) if holes.size else 0)


_WHY = {
    "x_e": ("the endpoint encoder is needed for plants B-D (the paper's temporary optical "
            "encoder on the backdriven finger); record with it fitted"),
    "f_e": "the external force is needed (the chirp torque on the endpoint)",
    "x": "the motor position is needed",
    "f_p": "the pressure force is needed",
    "f_a": "the motor effort is needed",
}

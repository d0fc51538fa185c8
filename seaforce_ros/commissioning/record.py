"""One free-air excitation of one channel, on the samples the controller ran.

Motor frame, rotational SI units. Every array has one entry per sample the controller ran on
(a sample it skipped, a late loop answering only the newest state, leaves a gap in ``cycle``).
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .errors import CommissioningError

__all__ = ["ExcitationRecord", "save_record", "load_record"]

#: The arrays of a record, in the order of its fields.
_ARRAYS = ("cycle", "x", "v", "f_p", "applied", "command", "excitation", "x_e", "f_e")

_Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ExcitationRecord:
    """A motor-torque excitation with the endpoint free.

    Attributes
    ----------
    dt : float > 0
        Sample period T [s] (5e-4 at 2 kHz).
    cycle : int64 array
        ``ActuatorState.cycle`` of each sample.
    x, v : float arrays
        Measured motor position X [rad] and velocity V [rad/s].
    f_p : float array
        Measured pressure force F_p [N m].
    applied : float array
        The torque the plant reports it applied in that sample (``motor_effort``) F_a [N m].
    command : float array
        The torque commanded in answer to that sample [N m] (applied from a later sample on:
        the loop delay).
    excitation : float array
        The excitation part of ``command`` [N m] (without the centring servo): the reference
        the cross spectra are taken against.
    x_e, f_e : float arrays
        Endpoint position X_e [rad] and external force F_e [N m]; NaN where not measured (a
        gripper without an endpoint encoder: always, outside tests).
    """

    dt: float
    cycle: npt.NDArray[np.int64]
    x: _Array
    v: _Array
    f_p: _Array
    applied: _Array
    command: _Array
    excitation: _Array
    x_e: _Array = field(default_factory=lambda: np.zeros(0))
    f_e: _Array = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if not (self.dt > 0.0 and np.isfinite(self.dt)):
            raise CommissioningError(f"record: dt = {self.dt!r} s, must be > 0 and finite")
        n = len(self.cycle)
        for name in ("x", "v", "f_p", "applied", "command", "excitation"):
            if len(getattr(self, name)) != n:
                raise CommissioningError(
                    f"record: {name} has {len(getattr(self, name))} samples, cycle has {n}")
        for name in ("x_e", "f_e"):
            a = getattr(self, name)
            if len(a) == 0:
                object.__setattr__(self, name, np.full(n, np.nan))
            elif len(a) != n:
                raise CommissioningError(f"record: {name} has {len(a)} samples, cycle has {n}")

    def __len__(self) -> int:
        return len(self.cycle)

    @property
    def duration(self) -> float:
        """Time the record spans [s]."""
        return float(len(self.cycle)) * self.dt


def save_record(record: ExcitationRecord, path: str | os.PathLike[str]) -> pathlib.Path:
    """Write ``record`` to ``path`` (numpy ``.npz``; written under a temporary name and renamed,
    so a file of that name is always whole). Raises ``OSError`` (a full disk, say)."""
    target = pathlib.Path(path)
    tmp = target.with_name(target.name + ".part")
    with open(tmp, "wb") as f:
        np.savez(f, dt=np.float64(record.dt), **{k: getattr(record, k) for k in _ARRAYS})
    os.replace(tmp, target)
    return target


def load_record(path: str | os.PathLike[str]) -> ExcitationRecord:
    """The record :func:`save_record` wrote; ``CommissioningError`` naming the file if it is
    not one."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k]) for k in _ARRAYS}
            dt = float(data["dt"])
    except (OSError, KeyError, ValueError) as exc:
        raise CommissioningError(f"{path}: not a commissioning record ({exc})") from None
    return ExcitationRecord(dt=dt, **arrays)

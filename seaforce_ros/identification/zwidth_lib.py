"""Endpoint impedance Z(jw) = F_e/V_e per controller mode and the Z-width (paper Fig. 5C).

Measured the way the paper did: the endpoint is backdriven by a stiff position drive
(``position_sine``, the bonded second finger) at one frequency at a time; over whole periods
after the transient, :func:`seaforce_ros.core.analysis.impedance_figures` gives Z, the ratio
of the fundamentals of F_e and V_e = j w X_e, beside the rms impedance rms(F_e)/rms(V_e), the
harmonic distortion of F_e and the work loop's peak force within +-0.2 rad and over the
whole stroke. On a nonlinear plant the fundamental can nearly cancel while the harmonics
stay: the rms is what a hand feels, and a Z-width is given on both.

* :func:`simulate_figures` runs that experiment offline with the core (simulated plant =
  the "true" one, controller configured with any -- e.g. identified -- parameters);
  :func:`simulate_impedance` is its fundamental alone;
* :func:`figures_from_record` measures it on a recorded backdrive bag (the drive frequency
  is found from the endpoint motion); :func:`impedance_from_record` its fundamental;
* :func:`zwidth` is 20 log10(|Z_hold|/|Z_min|) with Z_min the lowest-impedance mode at each
  frequency (the "MaxZ" reference is the stiff PD ``hold``); :func:`zwidth_rows` gives it on
  the fundamental and, given the rms figures, on the rms.

The DC limit is represented by a measurement at ``DC_OMEGA`` = 0.1 rad/s, where every mode's
|Z| is within 0.1 dB of its stiffness asymptote |K|/w for the Table I plant (the slowest pole
of the passive endpoint is at 4 rad/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import (TYPE_CHECKING, Any, Callable, Dict, List, Mapping, Optional, Sequence,
                    Tuple)

import numpy as np
import numpy.typing as npt

from ..core.analysis import AWAY_SHARE, ImpedanceFigures, impedance_figures
from ..core.params import ControllerConfig
from .errors import IdentificationError
from .experiments import work_loop_experiment

if TYPE_CHECKING:
    from ..core.params import DahlParams, PlantParams
    from ..core.sensors import SensorParams
    from .timeseries import Series

__all__ = ["DC_OMEGA", "DEFAULT_MODES", "simulate_impedance", "simulate_figures",
           "impedance_from_record", "figures_from_record", "zwidth", "ZWidthRow",
           "zwidth_rows", "drive_frequency", "config_from_params", "figure_lines"]

DC_OMEGA = 0.1
DEFAULT_MODES = ("passive", "hold", "dob", "dob_linear_ff", "dob_full_ff")


def simulate_figures(plant: PlantParams, dahl: Optional[DahlParams], config: ControllerConfig,
                     modes: Sequence[str] = DEFAULT_MODES,
                     omegas: Sequence[float] = (DC_OMEGA, 1, 3, 10), amplitude: float = 0.2,
                     cycles: float = 2.0, sensors: Optional[SensorParams] = None,
                     seed: int = 0, progress: Optional[Callable[[str, float], object]] = None
                     ) -> Dict[str, List[ImpedanceFigures]]:
    """The impedance figures per mode and frequency from the offline backdrive experiment.

    Parameters
    ----------
    plant, dahl : PlantParams, DahlParams or None
        The simulated (true) gripper.
    config : ControllerConfig
        Controller settings (its plant/dahl are what the controller *believes*, e.g. the
        identified parameters); ``mode`` is replaced per run.
    modes : sequence of str
    omegas : sequence of float > 0 [rad/s]
    amplitude : float
        Drive amplitude [rad].

    Returns
    -------
    dict mode -> list of :class:`~seaforce_ros.core.analysis.ImpedanceFigures` on ``omegas``.
    """
    out: Dict[str, List[ImpedanceFigures]] = {}
    total = len(modes) * len(omegas)
    k = 0
    for mode in modes:
        figs: List[ImpedanceFigures] = []
        for w in omegas:
            if progress is not None:
                progress(f"backdrive {mode} at {w:g} rad/s", k / total)
            k += 1
            settle = max(1.0, 3.0 / w) if w >= 1.0 else 0.25
            rec = work_loop_experiment(plant=plant, dahl=dahl, sensors=sensors,
                                       amplitude=amplitude, frequency=w,
                                       cycles=cycles if w >= 1.0 else 1.0, mode=mode,
                                       config=config, seed=seed, settle_cycles=settle)
            dt: Any = rec["t"][1] - rec["t"][0]  # type: ignore[index]  # arrays but settle
            figs.append(impedance_figures(rec["f_e"], rec["x_e"], w, dt,
                                          rec["settle"]))  # type: ignore[arg-type]
        out[mode] = figs
    return out


def simulate_impedance(plant: PlantParams, dahl: Optional[DahlParams], config: ControllerConfig,
                       modes: Sequence[str] = DEFAULT_MODES,
                       omegas: Sequence[float] = (DC_OMEGA, 1, 3, 10), amplitude: float = 0.2,
                       cycles: float = 2.0, sensors: Optional[SensorParams] = None,
                       seed: int = 0, progress: Optional[Callable[[str, float], object]] = None
                       ) -> Dict[str, npt.NDArray[np.complex128]]:
    """The fundamental Z(j w) [N m s/rad] per mode on ``omegas`` (complex arrays) of
    :func:`simulate_figures` (same parameters)."""
    figs = simulate_figures(plant, dahl, config, modes, omegas, amplitude, cycles, sensors,
                            seed, progress)
    return {m: np.asarray([f.z for f in fs]) for m, fs in figs.items()}


def drive_frequency(x: npt.NDArray[np.floating], dt: float) -> float:
    """Frequency [rad/s] of the dominant sinusoid in ``x`` (FFT peak, refined by nonlinear
    least squares: the frequency whose sine/cosine (+ offset and trend) explain most of x)."""
    x = np.asarray(x, float) - np.mean(x)
    n = x.size
    spec = np.abs(np.fft.rfft(x * np.hanning(n)))
    spec[0] = 0.0
    k = int(np.argmax(spec))
    if k == 0 or spec[k] == 0:
        raise IdentificationError("no periodic endpoint motion found in the bag")
    df = 2 * math.pi / (n * dt)
    lo, hi = max((k - 1) * df, 0.5 * df), (k + 1) * df
    # golden-section on the variance explained by a sinusoid at w
    g = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    t = np.arange(n) * dt
    trend = t - t.mean()

    def f(w: float) -> float:
        basis = np.stack([np.sin(w * t), np.cos(w * t), np.ones(n), trend], axis=1)
        coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
        fitted = basis @ coef
        return float(fitted @ fitted)

    c, d = b - g * (b - a), a + g * (b - a)
    for _ in range(40):
        if f(c) > f(d):
            b = d
        else:
            a = c
        c, d = b - g * (b - a), a + g * (b - a)
    return 0.5 * (a + b)


def figures_from_record(series: Series, omega: Optional[float] = None,
                        settle: Optional[float] = None) -> ImpedanceFigures:
    """The impedance figures of a backdrive record (Series with x_e, f_e); the drive
    frequency is found from the endpoint motion unless given (``figures.omega``)."""
    s = series.signals
    if "x_e" not in s or "f_e" not in s:
        raise IdentificationError("a backdrive bag needs endpoint_position and external_force")
    w = drive_frequency(s["x_e"], series.dt) if omega is None else float(omega)
    period = 2 * math.pi / w
    if settle is None:
        settle = min(period, 0.25 * series.duration)
    if series.duration - settle < period:
        raise IdentificationError(
            f"too little data: the drive at {w:.3g} rad/s needs at least one full period "
            f"({period:.1f} s) after {settle:.1f} s of transient; the record is "
            f"{series.duration:.1f} s")
    return impedance_figures(s["f_e"], s["x_e"], w, series.dt, settle)


def impedance_from_record(series: Series, omega: Optional[float] = None,
                          settle: Optional[float] = None) -> Tuple[float, complex]:
    """Z(j w) of a backdrive record (Series with x_e, f_e); returns ``(omega, Z)``."""
    fig = figures_from_record(series, omega, settle)
    return fig.omega, fig.z


def figure_lines(label: str, fig: ImpedanceFigures) -> str:
    """One line of a backdrive's figures: |Z| of the fundamental and rms, the distortion, the
    harmonics, the work loop's peaks."""
    harm = ", ".join(f"{1e3 * a:.3g}" for a in fig.harmonics)
    return (f"{label}: |Z| {fig.z_db:.2f} dB fundamental, {fig.z_rms_db:.2f} dB rms "
            f"(distortion {100 * fig.distortion:.0f} %; harmonics 1-{len(fig.harmonics)} of "
            f"F_e {harm} mN m); peak |F_e| {fig.peak:.4g} N m over the stroke, "
            f"{fig.peak_centre:.4g} within +-{fig.centre_band:g} rad ({fig.peak_ratio:.2f}x)"
            + (f", {fig.peak_away:.4g} without the stroke's ends ({fig.away_ratio:.2f}x)"
               if fig.amplitude > fig.centre_band / AWAY_SHARE else ""))


def zwidth(z_hold: npt.ArrayLike, z_min: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """20 log10(|Z_hold|/|Z_min|) [dB]."""
    return 20.0 * np.log10(np.abs(z_hold) / np.abs(z_min))


@dataclass
class ZWidthRow:
    """One frequency [rad/s]: |Z| [dB] per mode, the lowest-impedance mode and the Z-width
    [dB] against the reference (None without one); the same on the rms impedance (empty /
    None without rms figures)."""

    omega: float
    z_db: Dict[str, float]
    min_mode: Optional[str]
    width_db: Optional[float]
    z_rms_db: Dict[str, float] = field(default_factory=dict)
    min_mode_rms: Optional[str] = None
    width_rms_db: Optional[float] = None


def _widest(z_db: Mapping[str, float], reference: str, min_modes: Optional[Sequence[str]]
            ) -> Tuple[Optional[str], Optional[float]]:
    cands = [m for m in (min_modes or z_db) if m != reference and m in z_db]
    min_mode = min(cands, key=lambda m: z_db[m]) if cands else None
    width = (z_db[reference] - z_db[min_mode]) if (min_mode and reference in z_db) else None
    return min_mode, width


def zwidth_rows(omegas: Sequence[float], z_by_mode: Mapping[str, npt.NDArray[np.complex128]],
                reference: str = "hold", min_modes: Optional[Sequence[str]] = None,
                rms_by_mode: Optional[Mapping[str, npt.ArrayLike]] = None
                ) -> List[ZWidthRow]:
    """Per frequency: |Z| [dB] per mode, the minimum-impedance mode (among ``min_modes``,
    default every mode but the reference) and the Z-width against ``reference``; with
    ``rms_by_mode`` (mode -> rms impedance [N m s/rad] on ``omegas``) the same on the rms."""
    rows: List[ZWidthRow] = []
    for i, w in enumerate(omegas):
        z_db = {m: float(20 * np.log10(abs(z[i]))) for m, z in z_by_mode.items()
                if i < len(z) and np.isfinite(z[i])}
        min_mode, width = _widest(z_db, reference, min_modes)
        row = ZWidthRow(float(w), z_db, min_mode, width)
        if rms_by_mode is not None:
            row.z_rms_db = {m: float(20 * np.log10(float(np.asarray(r)[i])))
                            for m, r in rms_by_mode.items()
                            if i < len(np.asarray(r)) and np.isfinite(np.asarray(r)[i])
                            and float(np.asarray(r)[i]) > 0.0}
            row.min_mode_rms, row.width_rms_db = _widest(row.z_rms_db, reference, min_modes)
        rows.append(row)
    return rows


def config_from_params(plant_dict: Optional[Mapping[str, Any]],
                       dahl_dict: Optional[Mapping[str, Any]],
                       base: Optional[ControllerConfig] = None) -> ControllerConfig:
    """ControllerConfig with the plant/dahl of a params file on top of ``base``."""
    from ..core.params import DahlParams, PlantParams
    base = base or ControllerConfig()
    plant = PlantParams(**{k: float(v) for k, v in plant_dict.items()}) if plant_dict \
        else base.plant
    dahl = DahlParams(**{k: float(v) for k, v in dahl_dict.items()}) if dahl_dict \
        else base.dahl
    from dataclasses import replace
    dob = replace(base.dob, nominal_inertia=plant.motor_inertia)
    return base.replace(plant=plant, dahl=dahl, dob=dob)

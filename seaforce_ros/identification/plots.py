"""Figures of the offline tools (matplotlib, Agg backend, PNG files)."""

from __future__ import annotations

import os
import pathlib
from types import ModuleType
from typing import TYPE_CHECKING, Dict, Mapping, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from .dahl_fit import DahlFit
    from .plant_id import PlantIdentification

__all__ = ["bode_fig4", "dahl_fig6", "zwidth_fig5c"]

_Path = Union[str, "os.PathLike[str]"]


def _plt() -> ModuleType:
    """matplotlib.pyplot on the Agg backend (imported here: slow to import)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(plt: ModuleType, fig: Figure, path: _Path, title: str = "") -> pathlib.Path:
    """Title (a figure-wide one), layout, PNG at ``path``; the figure is closed. Returns the
    path."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = pathlib.Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _db(h: npt.ArrayLike) -> npt.NDArray[np.float64]:
    return 20.0 * np.log10(np.abs(h))


def bode_fig4(result: PlantIdentification, path: _Path, title: str = "") -> pathlib.Path:
    """Fig. 4-style Bode plots: measured (blue, shaded 1-sigma band), identified linear model
    (red); for B and D also the estimate with the fitted Dahl force removed (green)."""
    plt = _plt()
    letters = [k for k in ("A", "B", "C", "D") if k in result.responses]
    model = result.model_responses()
    fig, axes = plt.subplots(2, len(letters), figsize=(4.2 * len(letters), 6.5),
                             sharex="col", squeeze=False)
    w = result.omega
    for col, letter in enumerate(letters):
        resp = result.responses[letter]
        mag, ph = axes[0, col], axes[1, col]
        rel = np.minimum(resp.rel_sigma, 0.9)
        mag.semilogx(w, _db(resp.h), color="tab:blue", label="measured (BT)")
        mag.fill_between(w, _db(resp.h) + 20 * np.log10(1 - rel),
                         _db(resp.h) + 20 * np.log10(1 + rel), color="tab:blue", alpha=0.25,
                         linewidth=0, label="1-sigma")
        phase = np.unwrap(np.angle(resp.h))
        ph.semilogx(w, np.degrees(phase), color="tab:blue")
        ph.fill_between(w, np.degrees(phase - rel), np.degrees(phase + rel), color="tab:blue",
                        alpha=0.25, linewidth=0)
        corrected = result.responses.get(letter + "_corrected")
        if corrected is not None:
            mag.semilogx(w, _db(corrected.h), color="tab:green", lw=1,
                         label="Dahl force removed")
            ph.semilogx(w, np.degrees(np.unwrap(np.angle(corrected.h))), color="tab:green",
                        lw=1)
        mag.semilogx(w, _db(model[letter]), "--", color="tab:red", label="linear model")
        ph.semilogx(w, np.degrees(np.unwrap(np.angle(model[letter]))), "--", color="tab:red")
        if letter == "D" and result.rational is not None:
            mag.semilogx(w, _db(result.rational(w)), ":", color="k", lw=1,
                         label="2-zero/4-pole fit")
        mag.set_title(f"({letter}) {resp.name}")
        mag.grid(True, which="both", alpha=0.3)
        ph.grid(True, which="both", alpha=0.3)
        ph.set_xlabel("frequency [rad/s]")
        lo, hi = result.band
        for ax in (mag, ph):
            ax.axvspan(w[0], lo, color="0.9")
            ax.axvspan(hi, w[-1], color="0.9")
        if col == 0:
            mag.set_ylabel("magnitude [dB]")
            ph.set_ylabel("phase [deg]")
        mag.legend(fontsize=7, loc="best")
    return _save(plt, fig, path, title)


def dahl_fig6(fit: DahlFit, path: _Path, title: str = "") -> pathlib.Path:
    """Fig. 6-style: external hysteresis loop (linear endpoint terms removed) vs X_e with the
    fitted Dahl model, and a close-up of a turnaround."""
    plt = _plt()
    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(11, 4.5))
    for a in (ax, zoom):
        a.plot(fit.x_e, fit.residual_force, ".", ms=1, color="tab:blue",
               label="measured F_e - F_p - linear endpoint terms")
        a.plot(fit.x_e, fit.model_force, color="tab:red", lw=1.2,
               label=f"Dahl: sigma={fit.sigma:.3g} N m/rad, F_c={fit.coulomb_force:.3g} N m, "
                     f"n={fit.exponent:.2g}")
        a.set_xlabel("endpoint position X_e [rad]")
        a.grid(True, alpha=0.3)
    ax.set_ylabel("hysteresis force [N m]")
    ax.legend(fontsize=7, loc="upper left")
    k = int(np.argmax(fit.x_e))
    x0 = fit.x_e[k]
    span = max(10 * fit.coulomb_force / max(fit.sigma, 1e-9), 1e-3)
    zoom.set_xlim(x0 - span, x0 + 0.1 * span)
    zoom.set_ylim(-1.5 * fit.coulomb_force, 1.5 * fit.coulomb_force)
    zoom.set_title("close-up at the turnaround")
    return _save(plt, fig, path, title)


def zwidth_fig5c(omega: npt.ArrayLike, curves: Mapping[str, npt.NDArray[np.complex128]],
                 path: _Path, title: str = "",
                 markers: Optional[Mapping[str, Tuple[npt.ArrayLike,
                                                      npt.NDArray[np.complex128]]]] = None,
                 rms: Optional[Mapping[str, Tuple[npt.ArrayLike, npt.ArrayLike]]] = None
                 ) -> pathlib.Path:
    """Fig. 5C-style |Z(jw)| per mode. ``curves``: label -> complex array on ``omega``;
    ``markers``: label -> (omega points, complex Z) measured points (filled: the
    fundamental); ``rms``: label -> (omega points, rms |Z| [N m s/rad]) (open squares)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.8))
    colors: Dict[str, str] = {}
    for label, z in curves.items():
        line, = ax.semilogx(omega, _db(z), label=label)
        colors[label] = line.get_color()
    for label, (w, z) in (markers or {}).items():
        ax.semilogx(w, _db(z), "o", color=colors.get(label), ms=5,
                    label=None if label in colors else label)
    for label, (w, r) in (rms or {}).items():
        ax.semilogx(w, _db(r), "s", mfc="none", color=colors.get(label), ms=7,
                    label=f"{label} rms")
    ax.set_xlabel("frequency [rad/s]")
    ax.set_ylabel("|Z| = |F_e/V_e| [dB re 1 N m s/rad]" + ("; squares: rms(F_e)/rms(V_e)"
                                                           if rms else ""))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return _save(plt, fig, path)

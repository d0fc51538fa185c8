"""Plant identification from a chirp record (paper Section II-C, Fig. 4, Table I).

Which experiment identifies what
--------------------------------
* ``external`` excitation (the paper's bonded finger, the sim's ``torque_chirp``; motor off,
  F_a = 0): F_e drives the endpoint, the hose drives the motor. All four plants of Fig. 4 are
  measurable: A = X/(F_p + F_a) -> m, b, k; B = X_e/(F_e - F_p) -> m_e, b_e, k_e;
  C = F_p/(X_e - X) -> b_s, k_s; D = X_e/F_e (the 2-zero/4-pole model; its 7 free
  coefficients alone cannot give 8 parameters, so D is the cross-check of A-C).
* ``motor`` excitation (the controller's ``chirp`` mode, endpoint free, F_e = 0): A, B and C are
  measurable (B's input is -F_p), D is not (no external force).

The reference of every cross-spectrum is the excitation (F_e or F_a), see
:mod:`.spectral`. The endpoint plant is fitted with the Dahl hysteresis removed
(:func:`.fit.fit_endpoint_with_dahl`); the raw B and D (hysteresis lumped in, what the
paper's linear fit saw) are kept for the plots and the 2-zero/4-pole fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

from ..core.params import PlantParams
from ..core.plant import PlantModel
from ..core.analysis import frequency_response
from .errors import IdentificationError
from .fit import (HysteresisEstimate, ParameterFit, RationalFit, fit_endpoint_with_dahl,
                  fit_hose, fit_mass_spring_damper, fit_rational)
from .dahl_model import DahlPath
from .spectral import BlackmanTukey, FrequencyResponse, Spectra

if TYPE_CHECKING:
    from .timeseries import Series

__all__ = ["PlantIdentification", "identify_plant", "PARAMETERS", "required_fields",
           "ExternalForceChoice", "EXTERNAL_FORCE_DELAYS", "CLEAR_MISFIT_RATIO"]

#: The Fig. 4 plant each parameter is identified from: A the motor (X/F_p), B the endpoint
#: (X_e/(F_e - F_p)), C the hose (F_p/(X_e - X)).
_PLANT_OF = {"motor": "A", "endpoint": "B", "hose": "C"}
#: key -> (symbol, unit, plant letter), from the schema's rows of PlantParams.
PARAMETERS = {spec.attribute: (spec.symbol, spec.unit, _PLANT_OF[spec.attribute.split("_")[0]])
              for spec in PlantParams.SPECS}

#: prewhitening (backward differences) of position signals per band, see spectral.py
POSITION_ORDERS = ((0, 5.0), (1, 60.0), (2, math.inf))
#: relative power (of omega S_rr, flat for a log chirp) below which there is no excitation
MIN_RELATIVE_POWER = 1e-3


def required_fields(excitation: str) -> Tuple[str, ...]:
    """The signals the ``external`` or ``motor`` chirp needs."""
    return ("x", "f_p", "x_e", "f_e") if excitation == "external" else ("x", "f_p", "x_e", "f_a")


@dataclass
class PlantIdentification:
    """Everything :func:`identify_plant` found (see the attributes; ``external_force`` is the
    external-force convention used and why, None for a motor chirp)."""

    params: PlantParams
    sigma: Dict[str, float]
    fit_error: Dict[str, float]
    fits: Dict[str, ParameterFit]
    responses: Dict[str, FrequencyResponse]
    rational: Optional[RationalFit]
    excitation: str
    band: Tuple[float, float]
    hysteresis: Optional[HysteresisEstimate]
    omega: npt.NDArray[np.float64]
    excited_band: Tuple[float, float]
    notes: List[str] = field(default_factory=list)
    external_force: Optional["ExternalForceChoice"] = None

    def model_responses(self) -> Dict[str, npt.NDArray[np.complexfloating]]:
        """Identified linear model on the grid, per plant letter (A-D)."""
        m = PlantModel(self.params)
        p = self.params
        w = self.omega
        return {"A": frequency_response(m.motor_plant(), w),
                "B": frequency_response(m.endpoint_plant(), w),
                "C": p.hose_stiffness + 1j * w * p.hose_damping,
                "D": frequency_response(m.endpoint_system(), w)}

    def rows(self, truth: Optional[PlantParams] = None) -> List[Tuple[Union[str, float], ...]]:
        """Table rows: (key, symbol, unit, value, sigma, fit error, plant[, truth, error %])."""
        out = []
        for key, (sym, unit, plant) in PARAMETERS.items():
            row: List[Union[str, float]] = [key, sym, unit, getattr(self.params, key),
                                            self.sigma[key], self.fit_error[plant], plant]
            if truth is not None:
                t = getattr(truth, key)
                row += [t, 100.0 * (row[3] / t - 1.0)]
            out.append(tuple(row))
        return out


def excited_band(ref: npt.NDArray[np.float64], dt: float,
                 relative: float = MIN_RELATIVE_POWER) -> Tuple[float, float]:
    """Band [rad/s] where ``omega P_rr`` (Welch, flat for a log chirp) is within ``relative``
    of its maximum: the frequencies the excitation reaches."""
    import scipy.signal
    nper = int(min(2 ** 14, max(256, ref.size // 4)))
    f, p = scipy.signal.welch(ref - np.mean(ref), fs=1.0 / dt, nperseg=nper)
    w = 2.0 * np.pi * f[1:]
    wp = w * p[1:]
    if not np.any(wp > 0):
        return math.inf, 0.0
    ok = w[wp >= relative * wp.max()]
    return float(ok.min()), float(ok.max())


def _excitation(series: Series, excitation: str) -> str:
    s = series.signals
    if excitation == "auto":
        fe = np.std(s["f_e"]) if "f_e" in s else 0.0
        fa = np.std(s["f_a"]) if "f_a" in s else 0.0
        if fe == 0.0 and fa == 0.0:
            raise IdentificationError(
                "too little frequency content: neither the external force nor the motor "
                "effort varies (record a torque chirp: the sim's torque_chirp environment or "
                "the controller's chirp mode)")
        excitation = "external" if fe >= fa else "motor"
    if excitation not in ("external", "motor"):
        raise IdentificationError(f"excitation must be auto, external or motor, not "
                                  f"{excitation!r}")
    return excitation


#: External-force conventions: the delay [samples] of the recorded F_e relative to the force
#: that acted. ``held``: the torque was held over the interval after its sample (a drive's
#: command, the simulator's environment torque), which acts like the sample delayed by half a
#: sample; ``instant``: a sampled force sensor (the force at the sample's instant).
EXTERNAL_FORCE_DELAYS = {"held": 0.5, "instant": 0.0}
#: Misfit ratio (worse/better convention) from which ``auto`` calls its choice clear.
#: Measured (bench/identify_external_force.py: Table I and three family draws from the
#: independent simulator, held and continuous torque, and the core simulator; 30, 60 and 120 s;
#: fit bands up to 400, 200, 100 and 40 rad/s; 108 fits): on the paper's band the wrong
#: convention's misfit was 2.6-970x the right one's (median 76; at least 18 from 60 s on);
#: the ratio falls with the band's top, since half a sample is ``omega T/2`` of phase, and
#: at band tops of 100 and 40 rad/s ``auto`` took the wrong convention 10 times, each with a
#: ratio under 1.8.
#: No ratio of 1.8 or more picked wrong; 3 leaves a margin of 1.7 over that. The two
#: conventions' parameters differ by 2.7-16 %, so a ratio below it is reported as too close to
#: tell (force the convention when the sensor is known).
CLEAR_MISFIT_RATIO = 3.0


@dataclass(frozen=True)
class ExternalForceChoice:
    """Which external-force convention the endpoint fit used, and why.

    Attributes
    ----------
    requested : 'auto', 'held' or 'instant'
    convention : 'held' or 'instant'
        The one used (auto: the one with the smaller misfit).
    misfits : dict
        Weighted misfit per degree of freedom (chi^2/dof) of the endpoint fit B, per
        convention fitted (both for auto, one otherwise).
    """

    requested: str
    convention: str
    misfits: Dict[str, float]

    @property
    def ratio(self) -> float:
        """Worse over better misfit (>= 1; NaN when one convention was fitted)."""
        if len(self.misfits) < 2:
            return math.nan
        lo, hi = sorted(self.misfits.values())
        return hi / lo if lo > 0 else math.inf

    @property
    def clear(self) -> bool:
        """The misfits differ by at least :data:`CLEAR_MISFIT_RATIO`."""
        return self.ratio >= CLEAR_MISFIT_RATIO

    def summary(self) -> str:
        """One line: the convention, how it was chosen, the misfits."""
        fits = ", ".join(f"{k} {v:.4g}" for k, v in self.misfits.items())
        if self.requested != "auto":
            return (f"external force: {self.convention} (as requested; endpoint misfit "
                    f"chi2/dof {fits})")
        verdict = (f"ratio {self.ratio:.3g}" if self.clear else
                   f"ratio {self.ratio:.3g}, below {CLEAR_MISFIT_RATIO:g}: too close to tell, "
                   "took the smaller; force it with --external-force if the sensor is known")
        return (f"external force: {self.convention} (auto: endpoint misfit chi2/dof {fits}; "
                f"{verdict})")


@dataclass
class _Endpoint:
    """The endpoint (B, D) part of an identification under one external-force alignment."""

    fit: ParameterFit
    hysteresis: Optional[HysteresisEstimate]
    responses: Dict[str, FrequencyResponse]


def _conventions(external_force: str, excitation: str) -> Tuple[str, ...]:
    if external_force not in ("auto",) + tuple(EXTERNAL_FORCE_DELAYS):
        raise IdentificationError(f"external_force must be auto, held or instant, not "
                                  f"{external_force!r}")
    if excitation != "external":
        return ("instant",)           # no external force: the alignment does not enter
    return tuple(EXTERNAL_FORCE_DELAYS) if external_force == "auto" else (external_force,)


def identify_plant(series: Series, band: Tuple[float, float] = (0.5, 400.0),
                   rational_band: Tuple[float, float] = (0.5, 400.0), excitation: str = "auto",
                   external_force: str = "auto", motor_effort_delay: float = -0.5,
                   periods: float = 20.0, n_freq: int = 80, dahl: bool = True,
                   dahl_delay: float = 0.0,
                   progress: Optional[Callable[[str, float], object]] = None
                   ) -> PlantIdentification:
    """Identify the eight linear parameters from a chirp :class:`~.timeseries.Series`.

    Parameters
    ----------
    series : Series
        Needs x, f_p, x_e and the excitation (f_e or f_a).
    band : (lo, hi) [rad/s]
        Band of the plant fits A-C.
    rational_band : (lo, hi) [rad/s]
        Band of the 2-zero/4-pole fit of D (paper: 0-400 rad/s).
    excitation : 'auto', 'external' or 'motor'
    external_force : 'auto', 'held' or 'instant'
        How the recorded F_e relates to its sample (:data:`EXTERNAL_FORCE_DELAYS`). 'auto'
        fits the endpoint (B, D) under both and keeps the one with the smaller misfit; what
        does not depend on the alignment (the spectra, A, C, the Dahl force's spectra) is
        computed once. The choice is in ``PlantIdentification.external_force``.
    motor_effort_delay : float
        Delay [samples] of the recorded F_a relative to the force that acted (-0.5: the
        recorded motor effort was applied during the previous interval).
    periods : float
        Blackman-Tukey resolution (periods per lag window).
    dahl : bool
        Fit the endpoint with Dahl hysteresis (else purely linear, like the paper).
    dahl_delay : float
        Delay [samples] of the Dahl force relative to the X_e samples: 0 for a friction force
        that follows the position continuously (hardware; the default); the core simulator
        holds it over each step (0.5), see :func:`.fit.fit_endpoint_with_dahl`.
    progress : callable(str, float), optional
    """
    def report(msg: str, frac: float) -> None:
        if progress is not None:
            progress(msg, frac)

    lo, hi = band
    if not (0 < lo < hi):
        raise IdentificationError(f"band must satisfy 0 < lo < hi, got {lo:g}-{hi:g} rad/s")
    excitation = _excitation(series, excitation)
    conventions = _conventions(external_force, excitation)
    s = series.signals
    missing = [f for f in required_fields(excitation) if f not in s]
    if missing:
        raise IdentificationError(
            f"{', '.join(missing)} not measured (NaN in every sample): the {excitation} "
            "chirp needs " + ", ".join(required_fields(excitation)))
    dt = series.dt
    nyq = math.pi / dt
    top = max(hi, rational_band[1])
    if top >= 0.9 * nyq:
        raise IdentificationError(f"band up to {top:g} rad/s is above 0.9x the Nyquist "
                                  f"frequency {nyq:.0f} rad/s of this record")
    need_t = 2.0 * 2.0 * math.pi / min(lo, rational_band[0])
    if series.duration < need_t:
        raise IdentificationError(
            f"too little data: {series.duration:.1f} s recorded, the band starting at "
            f"{min(lo, rational_band[0]):g} rad/s needs at least {need_t:.0f} s (two periods);"
            " record longer or raise the band's lower edge with --band")
    w_lo = min(lo, rational_band[0])
    w_hi = max(hi, rational_band[1])
    omega = np.logspace(math.log10(w_lo), math.log10(w_hi), n_freq)
    # the external force's alignment is applied to its own spectrum (bt.delayed), so the
    # estimator and every other spectrum serve both conventions
    if excitation == "external":
        ref, ref_delay = s["f_e"], 0.0
    else:
        ref, ref_delay = s["f_a"], motor_effort_delay
    report("Blackman-Tukey spectra", 0.05)
    bt = BlackmanTukey(ref, dt, omega, periods=periods, reference_delay=ref_delay,
                       decimate="auto")
    ex_lo, ex_hi = excited_band(ref, dt)
    check_lo = max(w_lo, 4.0 * math.pi / min(series.duration, 2 ** 14 * dt))
    if ex_lo > check_lo * 1.05 or ex_hi < w_hi / 1.05:
        raise IdentificationError(
            f"too little frequency content for the band {w_lo:g}-{w_hi:g} rad/s: the "
            f"{excitation} excitation covers about {ex_lo:.3g}-{ex_hi:.3g} rad/s. Record a "
            "chirp that spans the band (e.g. 0.01-1000 Hz) or narrow it with --band")
    zero = np.zeros(series.n)
    f_a = s.get("f_a", zero)
    f_e = s.get("f_e", zero) if excitation == "external" else zero
    sx = bt.signal("x", s["x"], orders=POSITION_ORDERS)
    sxe = bt.signal("x_e", s["x_e"], orders=POSITION_ORDERS)
    sfp = bt.signal("f_p", s["f_p"])
    sfa = bt.signal("f_a", f_a, delay=motor_effort_delay) if excitation == "motor" else None
    sfe = bt.signal("f_e", f_e) if excitation == "external" else None
    shose = bt.signal("hose", s["x_e"] - s["x"], orders=POSITION_ORDERS)
    report("frequency responses", 0.2)
    # A: X / (F_p + F_a)
    motor_in: Spectra
    if sfa is not None:
        motor_in = (sfp[0] + sfa[0], bt.auto(s["f_p"] + f_a))
    else:
        motor_in = sfp
    responses = {
        "A": bt.response(sx, motor_in, "X/F_p"),
        "C": bt.response(sfp, shose, "F_p/(X_e-X)"),
    }
    fits: Dict[str, ParameterFit] = {}
    notes: List[str] = []
    report("fitting the motor plant (A) and the hose (C)", 0.3)
    fits["A"] = fit_mass_spring_damper(responses["A"], lo, hi,
                                       ("motor_inertia", "motor_damping", "motor_stiffness"))
    fits["C"] = fit_hose(responses["C"], lo, hi)
    path = DahlPath(s["x_e"])
    # B: X_e / (F_e - F_p); its input's auto-spectrum and the Dahl force's spectra do not
    # depend on the alignment of F_e
    auto_in = bt.auto(f_e - s["f_p"]) if sfe is not None else sfp[1]
    dahl_spectra: Dict[float, npt.NDArray[np.complex128]] = {}
    endpoints: Dict[str, _Endpoint] = {}
    share = 0.5 / len(conventions)
    for i, name in enumerate(conventions):
        def sub(msg: str, frac: float, base: float = 0.35 + i * share) -> None:
            report(msg if len(conventions) == 1 else f"{name} external force: {msg}",
                   base + share * frac)
        s_fe: Optional[Spectra] = None
        if sfe is not None:
            s_fe = (bt.delayed(sfe[0], EXTERNAL_FORCE_DELAYS[name]), sfe[1])
        endpoints[name] = _fit_endpoint(bt, sxe, sfp, s_fe, auto_in, path, lo, hi, dahl,
                                        dahl_delay, dahl_spectra, sub)
    chosen = min(conventions, key=lambda k: endpoints[k].fit.chi2_dof)
    choice = None
    if excitation == "external":
        choice = ExternalForceChoice(external_force, chosen,
                                     {k: endpoints[k].fit.chi2_dof for k in conventions})
    endpoint = endpoints[chosen]
    fits["B"] = endpoint.fit
    hysteresis = endpoint.hysteresis
    responses.update(endpoint.responses)
    values: Dict[str, float] = {}
    sigma: Dict[str, float] = {}
    for letter in ("A", "B", "C"):
        f = fits[letter]
        for key, v, sg in zip(f.names, f.values, f.sigma):
            values[key] = float(v)
            sigma[key] = float(sg)
    for k, sg in sigma.items():
        if not (math.isfinite(sg) and sg > 0):
            notes.append(f"{k}: not identified (degenerate covariance: its 1-sigma is "
                         f"{sg:.3g}); the value written is the least-squares solution")
    bad = [k for k, v in values.items() if not (math.isfinite(v) and v > 0)]
    for k in bad:
        notes.append(f"{k} fitted as {values[k]:.4g} (not positive; clipped to 0): not "
                     "identifiable from this record")
        values[k] = max(values[k], 0.0) if math.isfinite(values[k]) else 0.0
    if values["motor_inertia"] <= 0 or values["endpoint_inertia"] <= 0:
        raise IdentificationError("the fit gave a non-positive inertia: the record does not "
                                  "excite the band well enough (check the chirp and --band)")
    params = PlantParams(**values)
    rational = None
    if "D" in responses:
        report("2-zero/4-pole fit of X_e/F_e", 0.9)
        rlo, rhi = rational_band
        rational = fit_rational(responses["D"], rlo, rhi)
    fit_err = {k: fits[k].fit_error for k in fits}
    if "D" in responses:
        model_d = frequency_response(PlantModel(params).endpoint_system(), omega)
        key = "D_corrected" if "D_corrected" in responses else "D"
        sel = (omega >= rational_band[0]) & (omega <= rational_band[1])
        h = responses[key].h[sel]
        fit_err["D"] = float(np.sqrt(np.mean(np.abs(model_d[sel] - h) ** 2 / np.abs(h) ** 2)))
    report("done", 1.0)
    return PlantIdentification(params, sigma, fit_err, fits, responses, rational, excitation,
                               (lo, hi), hysteresis, omega, (ex_lo, ex_hi), notes, choice)


def _fit_endpoint(bt: BlackmanTukey, sxe: Spectra, sfp: Spectra, s_fe: Optional[Spectra],
                  auto_in: npt.NDArray[np.float64],
                  path: DahlPath, lo: float, hi: float, dahl: bool, dahl_delay: float,
                  dahl_spectra: Dict[float, npt.NDArray[np.complex128]],
                  report: Callable[[str, float], None]) -> _Endpoint:
    """The endpoint plant B (and D = X_e/F_e when there is an external force ``s_fe``: its
    spectra, the cross-spectrum aligned), the Dahl hysteresis removed unless ``dahl`` is
    False."""
    end_in: Spectra = (-sfp[0] if s_fe is None else s_fe[0] - sfp[0], auto_in)
    responses = {"B": bt.response(sxe, end_in, "X_e/(F_e-F_p)")}
    if s_fe is not None:
        responses["D"] = bt.response(sxe, s_fe, "X_e/F_e")
    report("fitting the endpoint plant (B) with Dahl hysteresis" if dahl
           else "fitting the endpoint plant (B)", 0.0)
    hysteresis = None
    if dahl:
        fb = fit_endpoint_with_dahl(bt, sxe[0], end_in[0], path, lo, hi,
                                    responses["B"].rel_sigma, progress=report,
                                    dahl_delay=dahl_delay, dahl_spectra=dahl_spectra)
        hysteresis = fb.hysteresis
    else:
        fb = fit_mass_spring_damper(responses["B"], lo, hi,
                                    ("endpoint_inertia", "endpoint_damping",
                                     "endpoint_stiffness"))
    if hysteresis is not None and hysteresis.model in ("dahl", "coulomb"):
        fd = hysteresis.coulomb_force * path.normalized(hysteresis.ratio)
        sfd = bt.cross(fd, delay=dahl_delay)
        rel = responses["B"].rel_sigma
        responses["B_corrected"] = FrequencyResponse(
            bt.omega, sxe[0] / (end_in[0] - sfd), rel, "X_e/(F_e-F_p-F_d)")
        if s_fe is not None:
            responses["D_corrected"] = FrequencyResponse(
                bt.omega, sxe[0] / (s_fe[0] - sfd), responses["D"].rel_sigma, "X_e/(F_e-F_d)")
    return _Endpoint(fb, hysteresis, responses)

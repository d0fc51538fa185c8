"""One commissioning run's analysis: from the record of a free-air excitation to the tuned
parameters, the predicted Z-width, the report and the params files.

Stages (each a function over explicit inputs; :func:`analyse` runs them in order and times
them):

1. :func:`identify_stage` -- the eight Table I parameters and the Dahl hysteresis with their
   1-sigmas (:func:`~.free_air.identify_free_air`); then the model class: the fits' misfits
   against :data:`~.free_air.MODEL_CLASS_THRESHOLD` and the candidate nonlinear terms the
   record resolves (:func:`~.nonlinear_terms.identify_nonlinear_terms`), in the report's
   summary;
2. :func:`loop_stage` -- the pressure noise, the encoder's quantum and the loop delay
   (:func:`~.loop_figures.loop_figures`), as the predictor's :class:`~.predictor.LoopModel`.
   The record's delay counts from a state to the first state whose ``applied`` torque is the
   command answering it; the torque acted for one sample before it was reported, so the
   predictor's delay (samples between a state and the sample its command acts from) is one
   less;
3. :func:`model_stage` -- the model the controller gets: the linear fit's, or, where the
   record resolves the hose's or the diaphragm's nonlinear terms, the equations refitted with
   them (``plant_terms``: the observer inverts the nonlinear hose, the feed-forward takes the
   stroke terms); :func:`tune_stage` -- lambda, the nominal plant and the hold gains
   (:func:`~.tuning.tune`) on it;
4. :func:`predict_stage` -- |Z| of every mode with the tuned settings and its 1-sigma band,
   the Z-width chart with impedance mode's virtual-wall boundary, the DOB's torque noise
   against lambda (:mod:`.predictor`); :func:`work_loop_stage` -- the work loops of a
   backdrive at 1 rad/s, 0.5 rad simulated on the identified model with the tuned settings,
   with their figures (the fundamental and the rms |Z|, the distortion, the peaks);
5. :func:`report_stage` -- the :class:`~.report.CommissioningReport` with the drift against the
   previous run's ``report.json``;
6. :func:`write_stage` -- the report directory, the params file (an existing one is updated in
   place, its comments kept) and ``rollback.yaml`` with the values the tuning replaces (none
   of the files but the report on a dry run).

A stage that cannot finish (nothing identified, no feasible tuning) ends the analysis with its
reason; the report still shows what the earlier stages found.

Run as a program (``python -m seaforce_ros.commissioning.analyse RUN_DIR``) it reads
``RUN_DIR/request.json`` and ``RUN_DIR/record.npz`` (what the ``~/commission`` action writes)
and speaks :mod:`.worker`'s protocol: progress lines, then ``{"result": {...}}``; it exits 0
when the run was tuned, 1 (after the result and an ``{"error": ...}`` line) when not.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import pathlib
import pickle
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

from ..core.analysis import ImpedanceFigures, impedance_figures
from ..core.errors import SeaforceError
from ..core.nonlinear_effects import effects_of_terms
from ..core.params import (ControllerConfig, DahlParams, PlantParams, PlantTermsParams,
                           settable_order)
from ..core.schema import by_key
from ..core.sensors import SensorParams
from ..identification.errors import IdentificationError
from ..identification.output import write_values_file
from .errors import CommissioningError
from .free_air import (DAHL_KEYS, PLANT_KEYS, FreeAirIdentification, identify_free_air,
                       model_class)
from .nonlinear_terms import NonlinearTerms, identify_nonlinear_terms
from .loop_figures import LoopFigures, loop_figures
from .predictor import (PREDICTED_MODES, ImpedanceBand, LoopModel, predict_band,
                        torque_noise, wall_limits)
from .record import ExcitationRecord, load_record
from .report import (CommissioningReport, LoopFigure, ModeImpedance, ModelClass, NoiseSweep,
                     ParameterRow,
                     PortResponse, ReportMeta, Tuning, TuningRow, VerificationRow,
                     WallBoundary, WorkLoop, ZWidthChart, load_report, summary_table,
                     write_report)
from .candidates import FEEDFORWARD_KEYS, chosen_values
from .candidates import propose as propose_candidates
from .model import ControllerModel, model_stage
from .tuning import TUNED_KEYS, InfeasibleTuningError, TuningResult, margin_cost_db, tune
from .verification import Candidate, CandidateOutcome, Window
from .verification import predict as predict_verification

__all__ = ["AnalysisRequest", "Analysis", "AnalysisError", "Prediction", "analyse", "propose",
           "finish", "Proposal", "Verified", "verification_rows", "save_verified",
           "load_verified", "propose_directory", "finish_directory", "PROPOSAL_FILE",
           "CANDIDATES_FILE", "VERIFICATION_FILE",
           "analyse_directory", "zwidth_at", "identification_rows",
           "identify_stage", "model_class_stage", "loop_stage", "model_stage", "ControllerModel",
           "tune_stage", "predict_stage", "work_loop_stage", "torque_lines", "TORQUE_WARNING",
           "prediction_model",
           "report_stage", "write_stage", "WORK_LOOP_MODES", "WORK_LOOP_OMEGA",
           "WORK_LOOP_AMPLITUDE", "BACKDRIVE_SPEED", "backdrive_amplitude", "Backdrives", "REQUEST_FILE", "RECORD_FILE", "ROLLBACK_FILE", "HEADLINE_OMEGA",
           "main"]

REQUEST_FILE = "request.json"
RECORD_FILE = "record.npz"
ROLLBACK_FILE = "rollback.yaml"
#: Frequencies [rad/s] the summary gives the Z-width at.
HEADLINE_OMEGA = (1.0, 3.0, 10.0)
#: Plants drawn for the 1-sigma bands of |Z|.
BAND_DRAWS = 24
#: Frequencies of the |Z| figure: 0.1 rad/s to a tenth of the Nyquist frequency.
IMPEDANCE_POINTS = 36
#: Cut-offs of the torque-noise sweep.
NOISE_POINTS = 14

Progress = Callable[[str, float, str], None]      # (phase, fraction 0..1, measuring)


class AnalysisError(CommissioningError):
    """A run's files cannot be analysed (a missing or malformed request, a bad record)."""


@dataclass(frozen=True)
class AnalysisRequest:
    """What the goal asked for (``request.json``).

    Attributes
    ----------
    channel : str
    config : ControllerConfig
        The channel's settings when the goal started (the tuning starts from them).
    band : (float, float)
        Where the tuning widens the Z-width [rad/s].
    noise_budget : float
        Largest RMS torque noise of the tuned DOB [N m].
    passivity_margin : float
        1-sigmas of m, b, k against which eq. 28 must hold.
    allow_guard, apply, dry_run : bool
    params_file : str
        Where the tuned parameters go.
    previous : str
        The previous run's ``report.json`` ('' for none): the drift.
    started : str
        When the goal started (ISO 8601, UTC).
    excitation : dict
        The excitation's end message, samples and duration [s].
    seed : int or None
        A simulated run's seed (the demo); None on hardware.
    truth : dict
        A simulated plant's true values by flat key (the demo; empty on hardware).
    """

    channel: str
    config: ControllerConfig
    band: Tuple[float, float] = (0.3, 10.0)
    noise_budget: float = 0.01
    passivity_margin: float = 2.0
    allow_guard: bool = False
    apply: bool = False
    dry_run: bool = False
    params_file: str = ""
    previous: str = ""
    started: str = ""
    excitation: Dict[str, Any] = field(default_factory=dict)
    seed: Optional[int] = None
    truth: Dict[str, float] = field(default_factory=dict)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> "AnalysisRequest":
        """From ``request.json``'s object; AnalysisError naming the field that is wrong."""
        if not isinstance(data, Mapping):
            raise AnalysisError("request: expected a JSON object")
        try:
            config = ControllerConfig.from_dict(data.get("config", {}))
        except (SeaforceError, ValueError, TypeError, AttributeError) as exc:
            raise AnalysisError(f"request: config: {exc}") from None
        try:
            band = (float(data.get("band_low", 0.3)), float(data.get("band_high", 10.0)))
            seed = data.get("seed")
            return cls(channel=str(data["channel"]), config=config, band=band,
                       noise_budget=float(data.get("noise_budget", 0.01)),
                       passivity_margin=float(data.get("passivity_margin", 2.0)),
                       allow_guard=bool(data.get("allow_guard", False)),
                       apply=bool(data.get("apply", False)),
                       dry_run=bool(data.get("dry_run", False)),
                       params_file=str(data.get("params_file", "")),
                       previous=str(data.get("previous", "")),
                       started=str(data.get("started", "")),
                       excitation=dict(data.get("excitation", {})),
                       seed=None if seed is None else int(seed),
                       truth={str(k): float(v) for k, v in dict(data.get("truth", {})).items()})
        except KeyError as exc:
            raise AnalysisError(f"request: {exc.args[0]} is missing") from None
        except (TypeError, ValueError) as exc:
            raise AnalysisError(f"request: {exc}") from None


@dataclass
class Analysis:
    """What :func:`analyse` found and wrote.

    Attributes
    ----------
    report : CommissioningReport
    message : str
        How it ended, in one line.
    tuned : bool
        The tuning succeeded (``apply`` holds the values).
    identification : FreeAirIdentification or None
    loop : LoopModel or None
    tuning : TuningResult or None
    band : ImpedanceBand or None
        The tuned settings' |Z| per mode on the identified plant.
    before_db : dict float -> float
        Predicted Z-width [dB] at :data:`HEADLINE_OMEGA` with the starting settings
        (after: ``after_db``).
    apply : dict key -> float or str
        The values to set (flat keys relative to ``<channel>.``); empty when not tuned.
    old_values : dict key -> float or str
        The channel's values of those keys when the goal started.
    report_path, params_file, rollback_file : str
        '' when not written.
    work_loops : list of WorkLoop
        The backdrive work loops simulated on the identified model (:func:`work_loop_stage`).
    model_class : ModelClass or None
        Whether the model class fits, with the candidate nonlinear terms' lines.
    terms : NonlinearTerms or None
        The candidate nonlinear terms (:mod:`.nonlinear_terms`).
    backdrives : Backdrives or None
        The backdrives simulated on the identified model: the rms prediction.
    model : ControllerModel or None
    verification : list of VerificationRow
        The feed-forward's candidates' windows, measured on the gripper beside predicted.
    """

    report: CommissioningReport
    message: str
    tuned: bool = False
    identification: Optional[FreeAirIdentification] = None
    loop: Optional[LoopModel] = None
    tuning: Optional[TuningResult] = None
    band: Optional[ImpedanceBand] = None
    before_db: Dict[float, float] = field(default_factory=dict)
    after_db: Dict[float, float] = field(default_factory=dict)
    apply: Dict[str, Any] = field(default_factory=dict)
    old_values: Dict[str, Any] = field(default_factory=dict)
    report_path: str = ""
    params_file: str = ""
    rollback_file: str = ""
    work_loops: List[WorkLoop] = field(default_factory=list)
    model_class: Optional[ModelClass] = None
    terms: Optional[NonlinearTerms] = None
    backdrives: Optional["Backdrives"] = None
    model: Optional[ControllerModel] = None
    verification: List[VerificationRow] = field(default_factory=list)

    def result(self) -> Dict[str, Any]:
        """The JSON result the action's client gets (numeric keys only in the value arrays;
        NaN where a parameter is not identified)."""
        names = [k for k in TUNED_KEYS if not isinstance(self.old_values.get(k, 0.0), str)]
        new = {r.name: r.value for r in self.report.identification}
        new.update({k: v for k, v in self.apply.items() if not isinstance(v, str)})
        return {"message": self.message, "summary": summary_table(self.report),
                "report_path": self.report_path, "params_file": self.params_file,
                "rollback_file": self.rollback_file, "names": names,
                "old_values": [_json_float(self.old_values.get(k, math.nan)) for k in names],
                "new_values": [_json_float(new.get(k, math.nan)) for k in names],
                "apply": self.apply, "tuned": self.tuned}


def _json_float(v: Any) -> Optional[float]:
    v = float(v)
    return v if math.isfinite(v) else None


# --- 1. identification ----------------------------------------------------------------------
def identify_stage(record: ExcitationRecord, progress: Optional[Progress] = None,
                   rest: float = 0.0) -> FreeAirIdentification:
    """The free-air identification (the finger's spring relaxed at ``rest`` [rad]), its
    progress mapped onto ``progress('identify', ...)``."""
    def step(message: str, fraction: float) -> None:
        if progress is not None:
            progress("identify", 0.6 * fraction, message)
    return identify_free_air(record, progress=step, rest=rest)


def model_class_stage(record: ExcitationRecord, ident: FreeAirIdentification,
                      progress: Optional[Progress] = None
                      ) -> Tuple[ModelClass, Optional[NonlinearTerms]]:
    """The model class's verdict with the candidate nonlinear terms (None, and a line saying
    why, when they cannot be fitted)."""
    def step(message: str, fraction: float) -> None:
        if progress is not None:
            progress("identify", 0.6 + 0.4 * fraction, message)
    try:
        terms: Optional[NonlinearTerms] = identify_nonlinear_terms(record, ident, step)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return model_class(ident, terms=[f"candidate nonlinear terms not fitted: {exc}"]), None
    assert terms is not None
    return model_class(ident, terms=terms.lines(),
                       resolved=[t.key.replace("_", " ") for t in terms.resolved()]), terms


def loop_stage(record: ExcitationRecord, config: ControllerConfig
               ) -> Tuple[LoopFigures, LoopModel]:
    """The measured figures and the predictor's loop model from them (module docstring: the
    delay is one less than the record's)."""
    figures = loop_figures(record, torque_limit=config.max_torque)
    d = figures.delay
    p50 = 1 if not math.isfinite(d.p50) else max(0, int(round(d.p50)) - 1)
    p99 = p50 if not math.isfinite(d.p99) else max(p50, int(math.ceil(d.p99)) - 1)
    model = LoopModel(pressure_noise=figures.pressure.std,
                      encoder_resolution=figures.encoder.quantum,
                      delay_p50=p50, delay_p99=p99, dt=record.dt)
    return figures, model


# --- 3. tuning ------------------------------------------------------------------------------
def tune_stage(model: ControllerModel, loop: LoopModel, request: AnalysisRequest
               ) -> TuningResult:
    """:func:`~.tuning.tune` on the controller's model from the channel's settings; raises
    InfeasibleTuningError."""
    config = request.config
    offset, offset_sd = model.pressure_offset
    if math.isfinite(offset):
        config = config.replace(pressure_offset=config.pressure_offset + offset)
    result = tune(model.plant, model.sigma, model.dahl, loop, band=request.band,
                  noise_budget=request.noise_budget,
                  passivity_margin=request.passivity_margin, allow_guard=request.allow_guard,
                  config=config, class_error=model.class_error, terms=model.terms)
    if math.isfinite(offset):
        result.bindings["pressure_offset"] = (
            f"identified: the record read {1e3 * offset:+.2f} +- {1e3 * offset_sd:.2f} mN m "
            "beyond the free finger's forces")
    return result


# --- 4. prediction --------------------------------------------------------------------------
@dataclass
class Prediction:
    """What :func:`predict_stage` predicts for one configuration."""
    band: ImpedanceBand
    wall: WallBoundary
    noise: NoiseSweep
    zwidth: ZWidthChart


def _impedance_grid(dt: float) -> np.ndarray:
    top = min(300.0, 0.1 * math.pi / dt)
    return np.logspace(-1.0, math.log10(top), IMPEDANCE_POINTS)


def zwidth_at(band: ImpedanceBand, omega: Sequence[float]) -> Dict[float, float]:
    """The band's nominal Z-width [dB] interpolated (in log w) at ``omega`` [rad/s]."""
    w = np.log(band.omega)
    return {float(o): float(np.interp(math.log(o), w, band.zwidth_db)) for o in omega}


def predict_stage(plant: PlantParams, plant_sigma: Mapping[str, float],
                  dahl: Optional[DahlParams], config: ControllerConfig, loop: LoopModel,
                  noise_budget: float, draws: int = BAND_DRAWS, noise_rel_sigma: float = 0.0,
                  progress: Optional[Progress] = None) -> Prediction:
    """|Z| per mode with its band, the Z-width chart and wall, the torque noise vs lambda
    (``noise_rel_sigma``: the pressure noise's relative 1-sigma)."""
    omega = _impedance_grid(loop.dt)
    if progress is not None:
        progress("predict", 0.0, f"|Z| of {len(PREDICTED_MODES)} modes over {draws} plants "
                 "drawn from the 1-sigmas")
    band = predict_band(plant, plant_sigma, dahl, config, omega, PREDICTED_MODES, draws=draws,
                        delay=loop.delay_p50, dt=loop.dt)
    if progress is not None:
        progress("predict", 0.7, "virtual-wall boundary and torque noise against lambda")
    b_phys = wall_limits(plant, dahl, config, loop, [0.0]).physical_damping
    damping = np.linspace(0.0, 1.25 * max(b_phys, 1e-4), 26)
    lim = wall_limits(plant, dahl, config, loop, damping)
    wall = WallBoundary(damping, lim.passivity, np.full(damping.size, lim.quantisation),
                        chosen_damping=config.target.damping,
                        chosen_stiffness=config.target.stiffness)
    zwidth = ZWidthChart(omega, band.zwidth_db, band.zwidth_lower_db, band.zwidth_upper_db,
                         wall=wall)
    return Prediction(band, wall, _noise_sweep(plant, dahl, config, loop, noise_budget,
                                               noise_rel_sigma), zwidth)


def _noise_sweep(plant: PlantParams, dahl: Optional[DahlParams], config: ControllerConfig,
                 loop: LoopModel, budget: float, rel_sigma: float) -> NoiseSweep:
    """RMS torque noise of ``dob`` (what ``noise_budget`` bounds) against lambda, the rest of
    the DOB as tuned (the sweep is a prediction: eq. 28 is not enforced along it). Its 1-sigma
    is the pressure share's relative 1-sigma (the quantum is exact)."""
    top = min(2.0 * math.pi * 300.0, 0.5 * math.pi / loop.dt)
    lam = np.logspace(math.log10(2.0 * math.pi), math.log10(top), NOISE_POINTS)
    lam = np.unique(np.append(lam, config.dob.cutoff))
    rms = np.full(lam.size, np.nan)
    pressure = np.full(lam.size, np.nan)
    for i, cutoff in enumerate(lam):
        try:
            trial = config.replace(dob=dataclasses.replace(config.dob, cutoff=float(cutoff)),
                                   allow_non_passive=True)
            p, q = torque_noise(plant, dahl, trial, loop, "dob")
        except (CommissioningError, SeaforceError):   # a cut-off the core refuses
            continue
        rms[i], pressure[i] = math.hypot(p, q), p
    return NoiseSweep(lam, rms, pressure * rel_sigma, budget, config.dob.cutoff)


#: The modes, frequency [rad/s] and amplitude [rad] of the report's work loops (the paper's
#: bonded-finger experiment, Fig. 5A-B).
WORK_LOOP_MODES = ("passive", "hold", "dob", "dob_full_ff")
WORK_LOOP_OMEGA = 1.0
WORK_LOOP_AMPLITUDE = 0.5
#: Peak drive speed [rad/s] of the rms predictions' backdrives (and the commissioning demo's):
#: amplitude min(0.5 rad, BACKDRIVE_SPEED/omega).
BACKDRIVE_SPEED = 0.5
#: Settling before a backdrive's measured period [s] (one period where that is shorter): the
#: closed loops' transients last well under a second and the Dahl state forgets its start at
#: the first reversal. A whole period at 1 rad/s (6.3 s) was a quarter of the analysis' CPU;
#: with 2 s the rms predictions of 8 draws (4 nonlinear, 4 linear class) moved by at most
#: 0.084 dB (dob_full_ff at 1 rad/s), every other mode and frequency by at most 0.014 dB
#: (the commissioning demo settles 1 s).
BACKDRIVE_SETTLE = 2.0
#: Points kept of a work loop's period.
_LOOP_POINTS = 400
#: The summary warns where a simulated backdrive's peak motor torque exceeds this share of
#: ``max_torque`` (the model lacks the finger ratio, free air cannot show it: up to 15 % more
#: torque at the stroke's ends).
TORQUE_WARNING = 0.8


def backdrive_amplitude(omega: float) -> float:
    """The backdrive's amplitude [rad] at ``omega`` [rad/s]: 0.5 rad, at most
    :data:`BACKDRIVE_SPEED` of peak speed."""
    return min(WORK_LOOP_AMPLITUDE, BACKDRIVE_SPEED / omega)


@dataclass
class Backdrives:
    """What :func:`work_loop_stage` simulated: the work loops, and the impedance figures
    (:class:`~..core.analysis.ImpedanceFigures`) per mode at each frequency (None where the
    mode's configuration was refused)."""

    work_loops: List[WorkLoop]
    omega: Tuple[float, ...]
    figures: Dict[str, List[Optional[ImpedanceFigures]]]
    #: per mode, the peak |F_a| [N m] (the torque the simulated motor applied) over the
    #: recorded period at each frequency (None as above)
    peak_torque: Dict[str, List[Optional[float]]] = field(default_factory=dict)
    #: the nonlinear terms of the simulated gripper (None: the linear model)
    terms: Optional[PlantTermsParams] = None

    def rms(self, mode: str) -> npt.NDArray[np.float64]:
        """The predicted rms |Z| [N m s/rad] of ``mode`` on :attr:`omega` (NaN: none)."""
        return np.array([f.z_rms if f is not None else math.nan
                         for f in self.figures.get(mode, [None] * len(self.omega))])


def work_loop_stage(plant: PlantParams, dahl: Optional[DahlParams], config: ControllerConfig,
                    modes: Sequence[str] = PREDICTED_MODES,
                    omegas: Sequence[float] = HEADLINE_OMEGA, motor_coulomb: float = 0.0,
                    progress: Optional[Progress] = None,
                    terms: Optional[PlantTermsParams] = None) -> Backdrives:
    """Backdrives simulated on the identified model (the core's simulator: ``plant``,
    ``dahl`` and the motor's ``motor_coulomb`` as the gripper, the tuned ``config`` as the
    controller, the simulator's sensors and one sample of delay), each mode at each of
    ``omegas`` with :func:`backdrive_amplitude`, one period after :data:`BACKDRIVE_SETTLE`
    of settling (a period at most): the impedance figures -- the rms prediction, which
    counts the harmonics the Dahl hysteresis and the Coulomb friction give --, the peak
    motor torque, and the work loops of :data:`WORK_LOOP_MODES` at
    :data:`WORK_LOOP_OMEGA`. With the model's nonlinear ``terms`` the simulated gripper has
    them too (:func:`~seaforce_ros.core.nonlinear_effects.effects_of_terms`). A mode the
    simulation cannot run (its configuration refused) is left out."""
    effects = None if terms is None else effects_of_terms(terms, plant)
    from ..identification.experiments import work_loop_experiment
    loops: List[WorkLoop] = []
    figures: Dict[str, List[Optional[ImpedanceFigures]]] = {}
    torque: Dict[str, List[Optional[float]]] = {}
    total = len(modes) * len(omegas)
    for i, mode in enumerate(modes):
        figures[mode] = []
        torque[mode] = []
        for j, omega in enumerate(omegas):
            if progress is not None:
                progress("predict", 0.8 + 0.2 * (i * len(omegas) + j) / total,
                         f"backdrive of {mode} at {omega:g} rad/s on the identified model")
            amplitude = backdrive_amplitude(omega)
            same = _same_backdrive(mode, config)
            if same in figures and len(figures[same]) > j:
                # the same controller, sample for sample: its figures (no second simulation)
                figures[mode].append(figures[same][j])
                torque[mode].append(torque[same][j])
                if mode in WORK_LOOP_MODES:
                    loops.extend([dataclasses.replace(w, mode=mode) for w in loops
                                  if w.mode == same and w.omega == omega])
                continue
            settle = min(1.0, BACKDRIVE_SETTLE * omega / (2.0 * math.pi))   # [periods]
            try:
                rec = work_loop_experiment(plant=plant, dahl=dahl, amplitude=amplitude,
                                           frequency=omega, cycles=1.0, mode=mode,
                                           config=config, settle_cycles=settle,
                                           motor_coulomb=motor_coulomb, effects=effects)
            except SeaforceError:
                figures[mode].append(None)
                torque[mode].append(None)
                continue
            dt = float(rec["t"][1] - rec["t"][0])  # type: ignore[index]
            fig = impedance_figures(rec["f_e"], rec["x_e"], omega, dt,
                                    float(rec["settle"]))
            figures[mode].append(fig)
            settled = int(round(float(rec["settle"]) / dt))
            torque[mode].append(float(np.max(np.abs(np.asarray(rec["f_a"])[settled:]))))
            if mode in WORK_LOOP_MODES and omega == WORK_LOOP_OMEGA:
                n = int(round(2.0 * math.pi / omega / dt))
                x = np.asarray(rec["x_e"])[-n:]
                f = np.asarray(rec["f_e"])[-n:]
                keep = np.linspace(0, n - 1, min(n, _LOOP_POINTS)).astype(int)
                loops.append(WorkLoop(mode, omega, amplitude, x[keep], f[keep], fig.z_db,
                                      fig.z_rms_db, fig.distortion, fig.peak, fig.peak_centre,
                                      fig.centre_band,
                                      "simulated on the identified model, tuned settings"))
    return Backdrives(loops, tuple(float(w) for w in omegas), figures, torque, terms)


def _same_backdrive(mode: str, config: ControllerConfig) -> str:
    """The mode whose backdrive ``mode``'s is, sample for sample (``impedance`` with a zero
    target is ``dob_full_ff``: ``F_ref = F_cmp + F_d - 0 - 0``); else ``mode`` itself."""
    if mode == "impedance" and config.target.stiffness == 0.0 and config.target.damping == 0.0:
        return "dob_full_ff"
    return mode


def _unsized(terms: NonlinearTerms, equation: str, keys: Sequence[str],
             model: PlantTermsParams) -> Optional[Dict[str, float]]:
    """The values of ``keys`` the ``equation``'s criterion chose (its whole-record fit) when
    one of them the record did not size (not resolved) is missing from ``model``; None when
    there is none or the fit's values are not usable."""
    eq = terms.equations.get(equation)
    if eq is None:
        return None
    found = {t.key: t for t in terms.terms}
    chosen = {k: found[k].value for k in keys
              if k in eq.chosen and k in found and math.isfinite(found[k].value)}
    unsized = [k for k in chosen if not found[k].resolved and getattr(model, k) == 0.0]
    return chosen if unsized else None


def prediction_model(plant: PlantParams, model: PlantTermsParams,
                     terms: Optional[NonlinearTerms]) -> Tuple[PlantParams, PlantTermsParams]:
    """The gripper the rms backdrives simulate: the controller's model (``plant``,
    ``model``), unless an equation's criterion chose a term the record did not size well
    enough for the controller (not resolved: e.g. its halves disagree). Then that equation's
    fit with every term it chose stands for its part of the gripper, that term at its
    whole-record value: the port's k_s, b_s and hose terms (flow, pressure), the endpoint's
    b_e, k_e and stroke terms (k_3 > 0, k_2 within ``k_2^2 <= 3 k_e k_3`` as the controller's
    model has them) -- one fit each: a term beside another fit's coefficients would count
    twice what they took up. The controller leaves such a term out (it would compensate a
    force that may not be there); without it the predictions miss: a backdrive that reaches
    far beyond the excitation's forces -- hold's, 10 N m against the chirp's 1 -- misses the
    hose's stiffening (2 of 14 draws of the oracle's bench: hold's rms |Z| at 1 rad/s 4.1 and
    4.3 dB stiffer than predicted, 1.4 and 1.7 dB with the term), and ``dob_full_ff`` the
    stroke stiffening its feed-forward lacks (seed 2 of the nonlinear commission demo: 4.5
    dB)."""
    if terms is None:
        return plant, model
    hose = _unsized(terms, "port", ("hose_flow", "hose_pressure"), model)
    if hose is not None:
        port = terms.equations["port"]
        ks = port.linear.get("hose_stiffness", (math.nan, 0.0))[0]
        bs = port.linear.get("hose_damping", (math.nan, 0.0))[0]
        if ks > 0.0 and bs > 0.0 and all(v > 0.0 for v in hose.values()):
            plant = dataclasses.replace(plant, hose_stiffness=ks, hose_damping=bs)
            model = dataclasses.replace(model, hose_flow=hose.get("hose_flow", 0.0),
                                        hose_pressure=hose.get("hose_pressure", 0.0))
    stroke = _unsized(terms, "endpoint", ("stroke_asymmetry", "stroke_stiffness"), model)
    if stroke is not None and stroke.get("stroke_stiffness", 0.0) > 0.0:
        end = terms.equations["endpoint"]
        be = end.linear.get("endpoint_damping", (math.nan, 0.0))[0]
        ke = end.linear.get("endpoint_stiffness", (math.nan, 0.0))[0]
        if be > 0.0 and ke > 0.0:
            k3 = stroke["stroke_stiffness"]
            k2 = stroke.get("stroke_asymmetry", 0.0)
            k2 = math.copysign(min(abs(k2), math.sqrt(3.0 * ke * k3)), k2)
            plant = dataclasses.replace(plant, endpoint_damping=be, endpoint_stiffness=ke)
            model = dataclasses.replace(model, stroke_asymmetry=k2, stroke_stiffness=k3)
    return plant, model


def torque_lines(backdrives: Backdrives, max_torque: float) -> List[str]:
    """The summary's lines on the motor torque the simulated backdrives took: one with each
    mode's peak |F_a| (the largest over the frequencies), and a warning per mode and frequency
    whose peak exceeds :data:`TORQUE_WARNING` of ``max_torque`` [N m] (there, a backdrive of
    the gripper latches the torque fault: zero torque, no measurement)."""
    peaks = {m: [(p, w) for p, w in zip(v, backdrives.omega) if p is not None]
             for m, v in backdrives.peak_torque.items()}
    peaks = {m: v for m, v in peaks.items() if v}
    if not peaks:
        return []
    top = {m: max(v) for m, v in peaks.items()}         # (peak, its omega)
    lines = ["predicted peak motor torque in these backdrives (max_torque "
             f"{max_torque:g} N m): " + ", ".join(
                 f"{m} {p:.3g} N m" + (f" (at {w:g} rad/s)" if len(peaks[m]) > 1 and p > 0.0
                                       else "")
                 for m, (p, w) in top.items())]
    for m, v in peaks.items():
        for p, w in v:
            if p > TORQUE_WARNING * max_torque:
                lines.append(
                    f"WARNING: {m}'s backdrive at {w:g} rad/s ({backdrive_amplitude(w):g} rad) "
                    f"is predicted to take {p:.3g} N m, {100 * p / max_torque:.0f} % of "
                    f"max_torque ({max_torque:g} N m; the finger ratio the model lacks adds up "
                    "to 15 %): on the gripper that backdrive may latch the torque fault (zero "
                    f"torque) and measure nothing; measure {m} there with a smaller amplitude, "
                    "or raise max_torque if the hardware allows it")
    return lines


# --- 5. the report --------------------------------------------------------------------------
def _spec(key: str) -> Tuple[str, str]:
    spec = by_key().get(key)
    return (spec.symbol or key.split(".")[-1], spec.unit) if spec else (key, "")


def _ident_key(name: str) -> str:
    return f"plant.{name}" if name in PLANT_KEYS else f"dahl.{name}"


def _previous_rows(path: str) -> Tuple[Dict[str, float], str]:
    """The previous run's identified values by key, and a note when it cannot be read."""
    if not path:
        return {}, ""
    try:
        previous = load_report(path)
    except CommissioningError as exc:
        return {}, f"drift: the previous report could not be read ({exc})"
    return ({r.name: r.value for r in previous.identification},
            f"drift against the commissioning of {previous.meta.date}")


def identification_rows(ident: FreeAirIdentification, previous: Mapping[str, float],
                        truth: Mapping[str, float]) -> List[ParameterRow]:
    """One report row per identified (or not) parameter, Table I order then sigma, F_c."""
    rows = []
    for name in PLANT_KEYS + DAHL_KEYS:
        key = _ident_key(name)
        e = ident.parameters[name]
        symbol, unit = _spec(key)
        rows.append(ParameterRow(key, symbol, unit, e.value, e.sigma,
                                 "identified" if e.identified else
                                 f"not identified ({e.reason})",
                                 previous=previous.get(key, math.nan),
                                 true=truth.get(key, math.nan)))
    return rows


def _responses(ident: FreeAirIdentification) -> List[PortResponse]:
    out = []
    for r, unit in ((ident.motor, "rad/(N m)"), (ident.port, "N m/rad")):
        out.append(PortResponse(r.name, unit, r.omega, r.h, r.sigma, r.coherence, r.model))
    return out


def _loop_rows(figures: LoopFigures, loop: LoopModel) -> List[LoopFigure]:
    p, e, d = figures.pressure, figures.encoder, figures.delay
    nan = math.nan
    return [LoopFigure("pressure noise", p.std, p.std_1s, "N m"),
            LoopFigure("motor encoder quantum", e.quantum, nan, "rad"),
            LoopFigure("loop delay p50 (state to command acting)", float(loop.delay_p50), nan,
                       "samples"),
            LoopFigure("loop delay p99 (state to command acting)", float(loop.delay_p99), nan,
                       "samples"),
            LoopFigure("missed commands", float(d.missed), nan, "commands"),
            LoopFigure("missed fraction (95 % upper bound)", d.missed_upper, nan, "-")]


def _tuning_rows(tuning: TuningResult, old: Mapping[str, Any]) -> Tuning:
    rows = []
    for key, new in tuning.values.items():
        if isinstance(new, str) or isinstance(old.get(key), str):
            continue
        rows.append(TuningRow(key, float(old.get(key, math.nan)), float(new), _spec(key)[1],
                              tuning.bindings.get(key, "")))
    binding = tuning.bindings.get("dob.cutoff", "")
    if tuning.guard:
        binding += f"; passivity guard: {tuning.guard}"
    return Tuning(rows, binding)


def _mode_rows(band: ImpedanceBand, backdrives: Optional[Backdrives] = None
               ) -> List[ModeImpedance]:
    rows = []
    for m in PREDICTED_MODES:
        if m not in band.nominal:
            continue
        row = ModeImpedance(m, band.omega, band.nominal[m], band.lower[m], band.upper[m])
        if backdrives is not None and m in backdrives.figures:
            row.rms_omega = np.asarray(backdrives.omega)
            row.rms_abs = backdrives.rms(m)
        rows.append(row)
    return rows


def _rms_zwidth(backdrives: Backdrives) -> npt.NDArray[np.float64]:
    """The Z-width on the predicted rms [dB]: hold over the softest other mode."""
    hold = backdrives.rms("hold")
    soft = np.nanmin(np.stack([backdrives.rms(m) for m in backdrives.figures if m != "hold"]),
                     axis=0)
    return np.asarray(20.0 * np.log10(hold / soft), dtype=float)


def report_stage(request: AnalysisRequest, phases: Mapping[str, float], *,
                 ident: Optional[FreeAirIdentification] = None,
                 loop: Optional[Tuple[LoopFigures, LoopModel]] = None,
                 tuning: Optional[TuningResult] = None,
                 prediction: Optional[Prediction] = None,
                 summary: Sequence[str] = (),
                 backdrives: Optional[Backdrives] = None,
                 model: Optional[ModelClass] = None,
                 verification: Sequence[VerificationRow] = ()) -> CommissioningReport:
    """The report of what the stages reached (None: not reached)."""
    previous, note = _previous_rows(request.previous)
    meta = ReportMeta(request.channel, request.started or _now(), dict(phases),
                      applied=request.apply and not request.dry_run and tuning is not None,
                      seed=request.seed)
    data = CommissioningReport(meta, summary=list(summary) + ([note] if note else []))
    if ident is not None:
        data.identification = identification_rows(ident, previous, request.truth)
        data.responses = _responses(ident)
    if loop is not None:
        data.loop = _loop_rows(*loop)
    if tuning is not None:
        data.tuning = _tuning_rows(tuning, request.config.to_dict())
    if prediction is not None:
        data.impedance = _mode_rows(prediction.band, backdrives)
        data.zwidth = prediction.zwidth
        data.noise = prediction.noise
        if backdrives is not None:
            data.zwidth.rms_omega = np.asarray(backdrives.omega)
            data.zwidth.rms_db = _rms_zwidth(backdrives)
    if backdrives is not None:
        data.work_loops = list(backdrives.work_loops)
    data.model_class = model
    data.verification = list(verification)
    return data


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


# --- 6. files -------------------------------------------------------------------------------
def write_stage(directory: pathlib.Path, analysis: Analysis, request: AnalysisRequest) -> None:
    """Write the report, and unless a dry run (or untuned) the params and rollback files;
    fills the paths in ``analysis``. A file that cannot be written adds its reason to the
    message (what was written stays)."""
    try:
        analysis.report_path = str(write_report(directory, analysis.report))
    except CommissioningError as exc:
        analysis.message += f"; the report was not written: {exc}"
    if request.dry_run or not analysis.tuned:
        return
    channel = request.channel
    stamp = f"commissioning of {channel}, run {directory.name}"
    try:
        analysis.params_file = str(write_values_file(
            request.params_file or directory / "params.yaml",
            {f"{channel}.{k}": v for k, v in analysis.apply.items()},
            comments=[stamp, "tuned: " + ", ".join(analysis.apply)],
            option="commissioning.params_file"))
        order = settable_order(analysis.tuning.config, analysis.old_values) \
            if analysis.tuning is not None else None
        how = ("in this order (eq. 28 holds after each one)" if order is not None else
               "not one at a time: eq. 28 fails in between whatever the order")
        analysis.rollback_file = str(write_values_file(
            directory / ROLLBACK_FILE,
            {f"{channel}.{k}": analysis.old_values[k] for k in order or analysis.old_values},
            comments=[f"the values {stamp} replaced: load it to roll back",
                      f"atomically: commission --rollback {directory}",
                      f"or with ros2 param load /controller {ROLLBACK_FILE}, which sets the "
                      f"values one at a time: {how}"],
            merge=False, flat=True))
    except IdentificationError as exc:
        analysis.message += f"; params files not written: {exc}"


# --- the whole run --------------------------------------------------------------------------
def _summary(analysis: Analysis, request: AnalysisRequest) -> List[str]:
    lines = []
    ident = analysis.identification
    if ident is not None:
        missing = ident.not_identified()
        lines.append(f"identified {len(ident.parameters) - len(missing)} of "
                     f"{len(ident.parameters)} parameters (misfit motor "
                     f"{100 * ident.misfit.get('motor', math.nan):.2g} %, port "
                     f"{100 * ident.misfit.get('port', math.nan):.2g} %)")
    if analysis.loop is not None:
        loop = analysis.loop
        lines.append(f"loop delay {loop.delay_p50} samples (p99 {loop.delay_p99}); pressure "
                     f"noise {loop.pressure_noise:.3g} N m; encoder {loop.encoder_resolution:.3g}"
                     " rad")
    if analysis.before_db and analysis.after_db:
        lines.append("predicted Z-width at " + ", ".join(f"{w:g}" for w in HEADLINE_OMEGA)
                     + " rad/s: before " + " / ".join(
                         f"{analysis.before_db[w]:.1f}" for w in HEADLINE_OMEGA)
                     + " dB, after " + " / ".join(
                         f"{analysis.after_db[w]:.1f}" for w in HEADLINE_OMEGA) + " dB")
    b = analysis.backdrives
    if b is not None and "dob_full_ff" in b.figures:
        figs = b.figures["dob_full_ff"]
        lines.append("predicted dob_full_ff at " + ", ".join(f"{w:g}" for w in b.omega)
                     + " rad/s: |Z| " + " / ".join(
                         f"{f.z_db:.1f}" if f else "-" for f in figs) + " dB fundamental, "
                     + " / ".join(f"{f.z_rms_db:.1f}" if f else "-" for f in figs)
                     + " dB rms; Z-width on the rms " + " / ".join(
                         f"{v:.1f}" for v in _rms_zwidth(b)) + " dB (a simulation of the "
                     "identified model: the harmonics of its Dahl hysteresis"
                     + (" and motor Coulomb friction" if analysis.terms is not None
                        and analysis.terms.term("motor_coulomb").resolved else "")
                     + (", and the terms of the controller's model" if analysis.model is not None
                        and (analysis.model.terms.hose or analysis.model.terms.stroke) else "")
                     + _unsized_words(analysis)
                     + "; not those of terms the record does not show)")
    if b is not None and analysis.tuning is not None:
        lines.extend(torque_lines(b, analysis.tuning.config.max_torque))
    if analysis.model is not None:
        lines.extend(analysis.model.lines)
    t = analysis.tuning
    if t is not None:
        lines.append(f"tuned DOB torque noise {1e3 * t.torque_noise:.3g} mN m rms (budget "
                     f"{1e3 * request.noise_budget:.3g}; in dob_full_ff, with the "
                     f"feed-forward's, {1e3 * t.feedforward_noise:.3g}); hold stable up to "
                     f"{t.hold_delay_limit} samples of delay")
        lines.append(_margin_line(t))
    return lines


def _unsized_words(analysis: Analysis) -> str:
    """Words on the terms the backdrives simulate beyond the controller's model
    (:func:`prediction_model`)."""
    b = analysis.backdrives
    if analysis.model is None or b is None or b.terms is None:
        return ""
    model, terms = analysis.model.terms, b.terms
    words = [f"{label} {getattr(terms, key):.4g} {unit}" for key, label, unit in (
        ("hose_flow", "the hose's flow term", "N m s^2/rad^2"),
        ("hose_pressure", "the hose's pressure term", "N m/rad^2"),
        ("stroke_asymmetry", "the diaphragm's k_2", "N m/rad^2"),
        ("stroke_stiffness", "the diaphragm's k_3", "N m/rad^3"))
        if getattr(terms, key) != getattr(model, key)]
    return ((", and " + ", ".join(words) + " (the record showed these terms without sizing "
             "them: the controller's model leaves them out; each with its equation's fit of "
             "every chosen term)") if words else "")


def _margin_line(t: TuningResult) -> str:
    """What the feed-forward's margin costs, in words: its scales and the predicted |Z| of
    dob_full_ff with it less without it at the headline frequencies."""
    ff = t.config.feedforward
    sb, sk, sd = ff.scales()
    stroke = t.config.plant_terms.stroke
    cost = [float(np.interp(math.log(w), np.log(t.omega), t.margin_cost_db))
            for w in HEADLINE_OMEGA]
    return (f"feed-forward margin: b_e x{sb:.3g}, k_e x{sk:.3g}, Dahl F_c x{sd:.3g}, sigma "
            f"x{ff.dahl_stiffness_share:g}"
            + (f", stroke terms x{ff.stroke_scale():.3g}" if stroke else "")
            + f" (margin {ff.margin:g} x the uncertainties "
            f"{100 * ff.damping_uncertainty:.2g} / {100 * ff.stiffness_uncertainty:.2g} / "
            f"{100 * ff.dahl_uncertainty:.2g}"
            + (f" / {100 * ff.stroke_uncertainty:.2g}" if stroke else "") + " %); it "
            "costs " + " / ".join(f"{c:+.1f}" for c in cost) + " dB of dob_full_ff |Z| at "
            + ", ".join(f"{w:g}" for w in HEADLINE_OMEGA) + " rad/s (predicted, against the "
            "exact inversion of the identified model; with the free finger's damping reserve "
            f"{ff.damping_reserve:.2g} N m s/rad)")


@dataclass
class Proposal:
    """The analysis up to the verification (:func:`propose`): the stages that identify and
    tune, and the feed-forward candidates with their windows as the model predicts them.

    Attributes
    ----------
    analysis : Analysis
        Its identification, model class, terms, loop, model and tuning (not the predictions,
        the report or the files: :func:`finish`'s).
    figures : LoopFigures or None
    phases : dict str -> float
        The stages' times [s].
    candidates : list of Candidate
        Most compensation first (:func:`~.candidates.propose`); empty when not tuned.
    predicted : list of CandidateOutcome
        Each candidate's windows on the identified model.
    rejected : list of (Candidate, CandidateOutcome)
        The candidates the model predicted to fail, with their windows: not tried.
    """

    analysis: Analysis
    figures: Optional[LoopFigures]
    phases: Dict[str, float]
    candidates: List[Candidate] = field(default_factory=list)
    predicted: List[CandidateOutcome] = field(default_factory=list)
    rejected: List[Tuple[Candidate, CandidateOutcome]] = field(default_factory=list)


@dataclass
class Verified:
    """What the verification on the gripper found: ``outcomes`` per candidate tried, the index
    of the one ``chosen`` (None: none passed), its rig time [s]; ``message`` when it could
    not run (then nothing of it counts)."""

    outcomes: List[CandidateOutcome]
    chosen: Optional[int]
    duration: float = 0.0
    message: str = ""


Verify = Callable[[List[Candidate]], Verified]


class _Clock:
    """The stages' times and the progress mapped onto the phases' spans."""

    SPANS = {"identify": (0.0, 0.45), "loop": (0.45, 0.5), "tune": (0.5, 0.6),
             "verify": (0.6, 0.65), "predict": (0.65, 0.95), "report": (0.95, 1.0)}

    def __init__(self, phases: Dict[str, float], progress: Optional[Progress]) -> None:
        self.phases, self._progress = phases, progress
        self._t = time.monotonic()

    def lap(self, name: str) -> None:
        now = time.monotonic()
        self.phases[name] = self.phases.get(name, 0.0) + now - self._t
        self._t = now

    def say(self, phase: str, fraction: float, what: str) -> None:
        if self._progress is not None:
            lo, hi = self.SPANS[phase]
            self._progress(phase, lo + (hi - lo) * min(1.0, max(0.0, fraction)), what)


def propose(record: ExcitationRecord, request: AnalysisRequest,
            progress: Optional[Progress] = None) -> Proposal:
    """Identify, tune and propose the feed-forward's candidates (stages 1-3)."""
    phases: Dict[str, float] = {}
    if request.excitation.get("duration"):
        phases["excitation"] = float(request.excitation["duration"])
    clock = _Clock(phases, progress)
    say = clock.say
    analysis = Analysis(CommissioningReport(ReportMeta(request.channel, _now(), {}, False)),
                        "")
    proposal = Proposal(analysis, None, phases)
    try:
        say("identify", 0.0, "the motor plant and the port from the record")
        rest = request.config.feedforward.rest_position
        ident = analysis.identification = identify_stage(record, say, rest)
        analysis.model_class, analysis.terms = model_class_stage(record, ident, say)
        clock.lap("identify")
        say("loop", 0.0, "pressure noise, encoder quantum, loop delay")
        proposal.figures, analysis.loop = loop_stage(record, request.config)
        clock.lap("loop")
        say("tune", 0.0, "lambda, the nominal plant and the hold gains")
        model = analysis.model = model_stage(ident, analysis.terms, rest)
        tuning = analysis.tuning = tune_stage(model, analysis.loop, request)
        say("tune", 0.7, "the feed-forward's candidates and their damping reserves")
        simulated, simulated_terms = prediction_model(model.plant, model.terms,
                                                      analysis.terms)
        loop = analysis.loop
        sensors, coulomb = _sensors(loop), _motor_coulomb(analysis.terms)

        def predict_one(candidate: Candidate) -> CandidateOutcome:
            return predict_verification(
                simulated, model.dahl, [candidate], request.config, delay=loop.delay_p50,
                dt=loop.dt, terms=simulated_terms, motor_coulomb=coulomb, sensors=sensors)[0]

        offered = propose_candidates(tuning.config, model, analysis.loop,
                                     request.passivity_margin,
                                     request.config.verification.candidates, predict_one)
        proposal.candidates, proposal.predicted = offered.candidates, offered.predicted
        proposal.rejected = offered.rejected
        clock.lap("tune")
    except InfeasibleTuningError as exc:
        analysis.message = f"not tuned ({exc.constraint}): {exc}"
    except CommissioningError as exc:
        analysis.message = f"not tuned: {exc}"
    return proposal


def finish(proposal: Proposal, request: AnalysisRequest, verified: Optional[Verified],
           directory: Optional[pathlib.Path] = None,
           progress: Optional[Progress] = None) -> Analysis:
    """Take the verification's verdict into the tuning (:func:`~.candidates.chosen_values`),
    predict, report and, given a ``directory``, write the files (stages 4-6)."""
    analysis, figures = proposal.analysis, proposal.figures
    clock = _Clock(proposal.phases, progress)
    say = clock.say
    if verified is not None and verified.duration:
        proposal.phases["verification"] = verified.duration
    old = request.config.to_dict()
    tuning, prediction, model = analysis.tuning, None, analysis.model
    try:
        if tuning is not None and model is not None and analysis.loop is not None:
            tuning = analysis.tuning = _verified_tuning(proposal, request, verified)
            say("predict", 0.0, "|Z| of every mode, the Z-width, the torque noise")
            prediction = predict_stage(model.plant, model.sigma, model.dahl,
                                       tuning.config, analysis.loop, request.noise_budget,
                                       noise_rel_sigma=(figures.pressure.std_1s / max(
                                           figures.pressure.std, 1e-300)) if figures else 0.0,
                                       progress=say)
            simulated, simulated_terms = prediction_model(model.plant, model.terms,
                                                          analysis.terms)
            analysis.backdrives = work_loop_stage(simulated, model.dahl, tuning.config,
                                                  motor_coulomb=_motor_coulomb(analysis.terms),
                                                  progress=say, terms=simulated_terms)
            analysis.work_loops = analysis.backdrives.work_loops
            clock.lap("predict")
            analysis.band = prediction.band
            analysis.before_db = {w: float(np.interp(math.log(w), np.log(tuning.omega),
                                                     tuning.zwidth_before_db))
                                  for w in HEADLINE_OMEGA}
            analysis.after_db = zwidth_at(prediction.band, HEADLINE_OMEGA)
            analysis.apply = dict(tuning.values)
            analysis.old_values = {k: old[k] for k in tuning.values if k in old}
            analysis.tuned = True
            analysis.message = (f"tuned: {tuning.bindings.get('dob.cutoff', '')}; predicted "
                                f"Z-width at 1 rad/s {analysis.after_db[1.0]:.1f} dB (was "
                                f"{analysis.before_db[1.0]:.1f})")
    except CommissioningError as exc:
        analysis.message = f"not tuned: {exc}"
    analysis.verification = verification_rows(proposal, verified)
    say("report", 0.0, "report, params and rollback files")
    loop_pair = None if figures is None or analysis.loop is None else (figures, analysis.loop)
    analysis.report = report_stage(request, proposal.phases, ident=analysis.identification,
                                   loop=loop_pair, tuning=tuning, prediction=prediction,
                                   summary=_summary(analysis, request),
                                   backdrives=analysis.backdrives,
                                   model=analysis.model_class,
                                   verification=analysis.verification)
    if directory is not None:
        write_stage(directory, analysis, request)
    clock.lap("report")
    return analysis


def _verified_tuning(proposal: Proposal, request: AnalysisRequest,
                     verified: Optional[Verified]) -> TuningResult:
    """The tuning with the feed-forward the verification chose (module docstring of
    :mod:`.candidates`), its bindings saying so, its margin's cost for it."""
    tuning, model, loop = proposal.analysis.tuning, proposal.analysis.model, \
        proposal.analysis.loop
    assert tuning is not None and model is not None and loop is not None
    candidates = proposal.candidates
    ran = verified is not None and not verified.message and bool(candidates)
    values = dict(tuning.values)
    chosen = verified.chosen if verified is not None and ran else None
    values.update(chosen_values(candidates, chosen, request.config, ran) if candidates
                  else {})
    if not ran:
        why = ("unverified (" + (verified.message if verified is not None and verified.message
                                 else "no verification on the gripper") + "): the model "
               "class's band, the most cautious candidate")
    elif chosen is None:
        why = ("verification: no candidate's free finger came to rest: the starting "
               "settings kept")
    else:
        why = f"verified on the gripper: {candidates[chosen].name}"
    bindings = dict(tuning.bindings)
    for key in FEEDFORWARD_KEYS:
        bindings[key] = why if key != "feedforward.damping_reserve" or chosen is None \
            else f"{why} (the least its band needs)"
    config = ControllerConfig.from_dict(values, base=tuning.config)
    cost = margin_cost_db(model.plant, model.dahl, config, model.terms, tuning.omega,
                          loop.delay_p50, loop.dt, 0.5)
    return dataclasses.replace(tuning, values=values, config=config, bindings=bindings,
                               margin_cost_db=cost)


def _sensors(loop: LoopModel) -> SensorParams:
    """The sensors the record showed: the pressure noise (its ADC's steps in it) and the motor
    encoder's quantum."""
    counts = (int(round(2.0 * math.pi / loop.encoder_resolution))
              if loop.encoder_resolution > 0.0 else 0)
    return SensorParams(pressure_range=1e9, pressure_bits=0,
                        pressure_noise=float(loop.pressure_noise),
                        motor_counts_per_rev=counts)


def _motor_coulomb(terms: Optional[NonlinearTerms]) -> float:
    """The motor's Coulomb friction [N m] where the record resolved it (else 0)."""
    if terms is not None and terms.term("motor_coulomb").resolved:
        return terms.term("motor_coulomb").value
    return 0.0


def verification_rows(proposal: Proposal, verified: Optional[Verified]
                      ) -> List[VerificationRow]:
    """Each candidate's windows, measured beside predicted (predicted only where it was not
    tried)."""
    rows = []
    measured = {o.name: o for o in (verified.outcomes if verified is not None else [])}
    pairs = list(zip(proposal.candidates, proposal.predicted))
    rejected = {c.name for c, _ in proposal.rejected}
    for candidate, predicted in proposal.rejected + pairs:
        outcome = measured.get(candidate.name)
        verdict = ("passed" if outcome.passed else f"failed: {outcome.reason}") \
            if outcome is not None else (
                f"predicted to fail ({predicted.reason}): not tried"
                if candidate.name in rejected else "not tried")
        measured_windows = outcome.windows if outcome is not None else []
        for i in range(max(len(predicted.windows), len(measured_windows))):
            p = predicted.windows[i] if i < len(predicted.windows) else None
            m = measured_windows[i] if i < len(measured_windows) else None
            w = m or p
            assert w is not None
            rows.append(VerificationRow(
                candidate.name, verdict, w.point, w.kind,
                m.settle if m else math.nan, p.settle if p else math.nan,
                m.decay if m else math.nan, p.decay if p else math.nan,
                m.drift if m else math.nan, p.drift if p else math.nan))
    return rows


def analyse(record: ExcitationRecord, request: AnalysisRequest,
            directory: Optional[pathlib.Path] = None, progress: Optional[Progress] = None,
            verify: Optional[Verify] = None) -> Analysis:
    """Run the stages (module docstring): :func:`propose`, the verification (``verify``: the
    candidates on the gripper; None: unverified, the model class's candidate) and
    :func:`finish`, which, given a ``directory``, writes the files."""
    proposal = propose(record, request, progress)
    verified = verify(proposal.candidates) if verify is not None and proposal.candidates \
        else None
    return finish(proposal, request, verified, directory, progress)


PROPOSAL_FILE = "proposal.pkl"
CANDIDATES_FILE = "candidates.json"
VERIFICATION_FILE = "verification.json"


def _request_and_record(directory: pathlib.Path) -> Tuple[AnalysisRequest, ExcitationRecord]:
    try:
        data = json.loads((directory / REQUEST_FILE).read_text())
    except OSError as exc:
        raise AnalysisError(f"{directory / REQUEST_FILE}: {exc.strerror}") from None
    except ValueError as exc:
        raise AnalysisError(f"{directory / REQUEST_FILE}: not JSON ({exc})") from None
    return AnalysisRequest.from_json(data), load_record(directory / RECORD_FILE)


def save_verified(path: pathlib.Path, verified: Verified) -> None:
    """``verification.json``: what the verification found (:class:`Verified`)."""
    data = {"outcomes": [dataclasses.asdict(o) for o in verified.outcomes],
            "chosen": verified.chosen, "duration": verified.duration,
            "message": verified.message}
    path.write_text(json.dumps(data, indent=1, default=lambda v: None))


def load_verified(path: pathlib.Path) -> Optional[Verified]:
    """``verification.json`` back (None: there is none); AnalysisError when it is unreadable."""
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
        outcomes = [CandidateOutcome(str(o["name"]), [_window(w) for w in o["windows"]],
                                     bool(o["passed"]), str(o["reason"]))
                    for o in data["outcomes"]]
        chosen = data.get("chosen")
        return Verified(outcomes, None if chosen is None else int(chosen),
                        float(data.get("duration", 0.0)), str(data.get("message", "")))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise AnalysisError(f"{path}: {exc}") from None


def _window(w: Mapping[str, Any]) -> Window:
    """A :class:`Window` from JSON (null: a settling time never reached, other figures NaN)."""
    def number(key: str, none: float) -> float:
        v = w.get(key)
        return none if v is None else float(v)
    return Window(float(w["point"]), str(w["kind"]), number("peak_speed", math.nan),
                  number("settle", math.inf), number("decay", math.nan),
                  number("drift", math.nan), str(w.get("failed", "")))


def analyse_directory(directory: pathlib.Path, progress: Optional[Progress] = None
                      ) -> Analysis:
    """:func:`analyse` on a run directory's ``request.json`` and ``record.npz`` (with its
    ``verification.json``, where the gripper verified the candidates)."""
    directory = pathlib.Path(directory)
    request, record = _request_and_record(directory)
    verified = load_verified(directory / VERIFICATION_FILE)
    proposal = propose(record, request, progress)
    return finish(proposal, request, verified, directory, progress)


def propose_directory(directory: pathlib.Path, progress: Optional[Progress] = None
                      ) -> Proposal:
    """:func:`propose` on a run directory; writes ``proposal.pkl`` (for :func:`finish`) and
    ``candidates.json`` (each candidate's name and configuration, for the verification)."""
    directory = pathlib.Path(directory)
    request, record = _request_and_record(directory)
    proposal = propose(record, request, progress)
    try:
        with open(directory / PROPOSAL_FILE, "wb") as fh:
            pickle.dump(proposal, fh)
        (directory / CANDIDATES_FILE).write_text(json.dumps(
            [{"name": c.name, "config": c.config.to_dict()} for c in proposal.candidates],
            indent=1))
    except OSError as exc:
        raise AnalysisError(f"cannot write the proposal into {directory}: {exc}") from None
    return proposal


def finish_directory(directory: pathlib.Path, progress: Optional[Progress] = None
                     ) -> Analysis:
    """:func:`finish` on a run directory's ``proposal.pkl`` and ``verification.json``."""
    directory = pathlib.Path(directory)
    request, _ = _request_and_record(directory)
    try:
        with open(directory / PROPOSAL_FILE, "rb") as fh:
            proposal = pickle.load(fh)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError) as exc:
        raise AnalysisError(f"{directory / PROPOSAL_FILE}: {exc} (run the analysis again "
                            "without --finish)") from None
    if not isinstance(proposal, Proposal):
        raise AnalysisError(f"{directory / PROPOSAL_FILE}: not a proposal")
    return finish(proposal, request, load_verified(directory / VERIFICATION_FILE), directory,
                  progress)


def _emit(obj: Mapping[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The child's entry point (:mod:`.worker`'s protocol)."""
    parser = argparse.ArgumentParser(
        prog="python -m seaforce_ros.commissioning.analyse",
        description="Analyse one commissioning run directory (request.json, record.npz; "
                    "verification.json where the gripper verified the candidates).")
    parser.add_argument("directory", type=pathlib.Path)
    stage = parser.add_mutually_exclusive_group()
    stage.add_argument("--propose", action="store_true",
                       help="identify, tune and write the feed-forward's candidates only")
    stage.add_argument("--finish", action="store_true",
                       help="take the verification into the tuning, predict and report")
    args = parser.parse_args(argv)

    def progress(phase: str, fraction: float, measuring: str) -> None:
        _emit({"phase": phase, "progress": fraction, "measuring": measuring})

    try:
        if args.propose:
            proposal = propose_directory(args.directory, progress)
            _emit({"result": {"candidates": [c.name for c in proposal.candidates],
                              "message": proposal.analysis.message}})
            if not proposal.candidates:
                _emit({"error": proposal.analysis.message or "no candidate"})
                return 1
            return 0
        analysis = (finish_directory if args.finish else analyse_directory)(
            args.directory, progress)
    except CommissioningError as exc:
        _emit({"error": str(exc)})
        return 1
    _emit({"result": analysis.result()})
    if not analysis.tuned:
        _emit({"error": analysis.message})
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

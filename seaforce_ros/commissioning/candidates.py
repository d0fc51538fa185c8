"""The feed-forward's candidates for the verification, and the choice after it.

The model gives two bands for the finger's friction: the statistical one (the identification's
1-sigmas: a few tenths of a per cent on a linear plant) and the model class's (those with the
fit's misfit: a few per cent even where the class is right, from the sensors and the spectra).
Today's rule takes the model class's band and cancels half of the Dahl pre-sliding stiffness:
safe for every plant within it, and it costs most of the Z-width the identification won. The
statistical band bounds the other end. :func:`propose` lays candidates between them, most
compensation first -- the feed-forward's uncertainties at their statistical 1-sigmas (at least
:data:`~seaforce_ros.core.params.MIN_UNCERTAINTY`) with a Dahl share of each of
:data:`SHARES`, then the tuned model-class one and the same with twice its margin -- each with the damping reserve its own band
needs (:func:`~.free_finger.size_reserve`; a candidate no reserve holds is not one), ordered by
the predicted |Z| of ``dob_full_ff`` at 1 rad/s; the verification on the gripper
(:mod:`.verification`) takes the first the free finger rests under. :func:`chosen_values`
turns its verdict into the values the tuning writes; none passing, the feed-forward keeps the
starting settings.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

from ..core.params import ControllerConfig
from .errors import CommissioningError
from .free_finger import band_spreads, size_reserve, with_reserve
from .model import ControllerModel
from .predictor import LoopModel
from .tuning import band_uncertainties, feedforward_uncertainties
from .verification import Candidate, CandidateOutcome

__all__ = ["propose", "Proposed", "chosen_values", "SHARES", "FEEDFORWARD_KEYS"]

#: The Dahl shares the statistical candidates take, most compensation first (1 was never
#: held by any reserve on the oracle's draws: the linearised loop is unstable).
SHARES = (0.9, 0.75, 0.6, 0.5)
#: The keys a candidate sets (its feed-forward; the rest is the tuning's).
FEEDFORWARD_KEYS = ("feedforward.damping_uncertainty", "feedforward.stiffness_uncertainty",
                    "feedforward.dahl_uncertainty", "feedforward.stroke_uncertainty",
                    "feedforward.plant_uncertainty", "feedforward.motor_uncertainty",
                    "feedforward.dahl_stiffness_share", "feedforward.verified_share",
                    "feedforward.damping_reserve")


def _statistical(tuned: ControllerConfig, model: ControllerModel, share: float,
                 passivity_margin: float) -> ControllerConfig:
    """``tuned`` with the feed-forward's uncertainties at the statistical band and ``share``."""
    values: Dict[str, Any] = dict(feedforward_uncertainties(
        model.plant, model.sigma, model.dahl, 0.0, model.terms))
    values.update(band_uncertainties(model.plant, model.sigma, model.dahl, 0.0,
                                     passivity_margin, tuned.feedforward.margin))
    values["feedforward.dahl_stiffness_share"] = share
    values["feedforward.verified_share"] = share if share > 0.5 else 0.0
    return ControllerConfig.from_dict(values, base=tuned.replace(allow_non_passive=True))


@dataclass
class Proposed:
    """What :func:`propose` offers the verification: the ``candidates`` to try, in order,
    with their windows as ``predicted`` on the identified model, and the ones ``rejected``
    (predicted to fail: not tried)."""

    candidates: List[Candidate] = field(default_factory=list)
    predicted: List[CandidateOutcome] = field(default_factory=list)
    rejected: List[Tuple[Candidate, CandidateOutcome]] = field(default_factory=list)


def propose(tuned: ControllerConfig, model: ControllerModel, loop: LoopModel,
            passivity_margin: float, count: int,
            predict: Callable[[Candidate], CandidateOutcome]) -> Proposed:
    """The candidates the verification tries, most compensation first (module docstring):
    the statistical band's shares in turn, each predicted (``predict``: its windows on the
    identified model), until ``count - 2`` are predicted to pass (the model bounds the
    search: one it predicts to fail is not tried, and the ones after the last tried are not
    even predicted); then the model class's candidate and the one with twice its margin,
    always (none but those where ``count`` is at most 2)."""
    out = Proposed()
    for share in SHARES:
        if len(out.candidates) >= count - 2:
            break
        config = _statistical(tuned, model, share, passivity_margin)
        try:
            reserve, _, _ = size_reserve(config, band_spreads(config), delay=loop.delay_p99,
                                         dt=loop.dt)
        except CommissioningError:
            continue                        # no reserve holds its band: not a candidate
        config = with_reserve(config, reserve).replace(allow_non_passive=False)
        if _feedforward(config) == _feedforward(tuned):
            continue
        candidate = Candidate(_name(config, "the statistical 1-sigmas"), config)
        outcome = predict(candidate)
        if outcome.passed:
            out.candidates.append(candidate)
            out.predicted.append(outcome)
        else:
            out.rejected.append((candidate, outcome))
    for candidate in _cautious(tuned, loop)[:max(1, count - len(out.candidates))]:
        out.candidates.append(candidate)
        out.predicted.append(predict(candidate))
    return out


def _name(config: ControllerConfig, what: str) -> str:
    ff = config.feedforward
    return (f"share {ff.dahl_stiffness_share:g}, {what} (b_e, k_e, F_c x"
            + "/".join(f"{s:.3g}" for s in ff.scales())
            + f"), reserve {ff.damping_reserve:.3g} N m s/rad")


def _cautious(tuned: ControllerConfig, loop: LoopModel) -> List[Candidate]:
    """The model class's candidate (the tuning's), and the same with twice its margin (where
    a reserve holds that band: the last resort before the starting settings)."""
    out = [Candidate(_name(tuned, "the model class's band"), tuned)]
    wider = tuned.replace(feedforward=dataclasses.replace(
        tuned.feedforward, margin=2.0 * tuned.feedforward.margin))
    try:
        reserve, _, _ = size_reserve(wider, band_spreads(wider), delay=loop.delay_p99,
                                     dt=loop.dt)
    except CommissioningError:
        return out
    wider = with_reserve(wider, reserve)
    out.append(Candidate(_name(wider, "twice the model class's margin"), wider))
    return out


def _feedforward(config: ControllerConfig) -> Dict[str, Any]:
    d = config.to_dict()
    return {k: d[k] for k in FEEDFORWARD_KEYS}


def chosen_values(candidates: Sequence[Candidate], chosen: Optional[int],
                  start: ControllerConfig, verified: bool) -> Mapping[str, Any]:
    """The feed-forward values the tuning writes: the chosen candidate's (``verified``: by the
    gripper; unverified, the last, the model class's), or none passing, the starting
    settings'."""
    if not verified:
        return _feedforward(candidates[-1].config)
    if chosen is None:
        return _feedforward(start)
    return _feedforward(candidates[chosen].config)


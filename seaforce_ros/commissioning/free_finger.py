"""A free finger in the feed-forward modes: small-signal stable over the model's uncertainty?

The feed-forward of ``dob_linear_ff`` / ``dob_full_ff`` / ``impedance`` cancels the model's
endpoint friction less its margin. For a finger whose b_e and k_e lie at the margin's edge it
cancels all of them, and what is left to damp the free finger is the sampled loop itself: the
DOB on a motor whose m, b are off the model, the hose inversion on a hose whose b_s, k_s are,
the delay. That can be negative: on Table I's band (every parameter 20 % off) 5 of 100 free
fingers drawn at its edge kept moving in simulation -- a limit cycle of +-3 mrad at 29 rad/s,
creeps that accelerated -- and the linearised loop below put the same mode at 29 rad/s just
outside the unit circle. ``feedforward.damping_reserve`` (a damping on the motor velocity
in those modes, which the DOB renders as nominal damping) is what restores it.

:func:`corner_radius` linearises the free finger about rest: the plant's Dahl hysteresis as
its initial stiffness sigma, the feed-forward's either still in its play or as the
feed-forward's sigma on X_e_hat (beyond it: while the finger moves), the loop sampled exactly
(:func:`~.predictor.closed_loop_radius`), and takes the largest spectral radius over the
corners of the band -- each uncertain parameter at the model's value times ``1 +- spread``.
Below 1 at a plant: the finger at rest is asymptotically stable there (within the
linearisation; the Dahl hysteresis' own dissipation adds to it). The radius need not be
largest at a corner: :func:`size_reserve` finds the least reserve that keeps every corner,
and the points along each axis through the worst one, below :data:`RADIUS_TARGET` (on Table
I's band an interior sigma came out 1.4e-5 above the worst corner, within that margin).
"""
from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from ..core.params import ControllerConfig, DahlParams, FeedforwardParams, PlantParams
from .errors import CommissioningError
from .predictor import PLANT_FIELDS, closed_loop_matrix, controller_polynomials

__all__ = ["BAND_KEYS", "corner_radius", "radius_at", "size_reserve", "band_spreads",
           "reserve_verdict", "with_reserve", "RESERVE_LIMIT", "RADIUS_TARGET", "SPREAD_LIMIT"]

#: The uncertain parameters of a band: Table I's eight and the Dahl sigma (F_c and the
#: exponent do not enter the linearisation).
BAND_KEYS = PLANT_FIELDS + ("sigma",)
_MODES = ("dob_linear_ff", "dob_full_ff", "impedance")
#: The largest reserve :func:`size_reserve` tries [N m s/rad]: the parameter's own limit (3
#: times Table I's b_e; on Table I the nominal loop is stable with it at 1-4 samples of delay,
#: free and held, where 1 N m s/rad was not at 2).
def _reserve_limit() -> float:
    high = FeedforwardParams.spec("damping_reserve").high
    if high is None:  # the row has a range; this keeps the limit a float for the checker
        raise RuntimeError("feedforward.damping_reserve has no upper limit in the schema")
    return float(high)


RESERVE_LIMIT = _reserve_limit()
#: The largest relative half-width of a band (the corners stay positive, the linearisation
#: about the model meaningful).
SPREAD_LIMIT = 0.45
#: The spectral radius every corner must stay below (a margin against rounding and the
#: bisection's last step: 2e-5 per sample is a time constant of 25 s at 2 kHz).
RADIUS_TARGET = 1.0 - 2e-5


def band_spreads(config: ControllerConfig) -> Dict[str, float]:
    """The band a free finger must be held over, as relative half-widths: the feed-forward's
    margin times b_e's and k_e's uncertainties (``feedforward.damping_uncertainty``,
    ``stiffness_uncertainty``: where the feed-forward cancels all of them) and times
    ``feedforward.motor_uncertainty`` for m, b, k and ``plant_uncertainty`` for m_e, b_s, k_s
    and sigma; each at most :data:`SPREAD_LIMIT`.
    Commissioning sizes the reserve over this band of the config it writes, and
    ``controller_node`` checks it at start-up, so both take the same one."""
    ff = config.feedforward
    out = {k: ff.margin * ff.plant_uncertainty for k in BAND_KEYS}
    for k in ("motor_inertia", "motor_damping", "motor_stiffness"):
        out[k] = ff.margin * ff.motor_uncertainty
    out["endpoint_damping"] = ff.margin * ff.damping_uncertainty
    out["endpoint_stiffness"] = ff.margin * ff.stiffness_uncertainty
    return {k: min(SPREAD_LIMIT, v) for k, v in out.items()}


def with_reserve(config: ControllerConfig, reserve: float) -> ControllerConfig:
    """``config`` with ``feedforward.damping_reserve = reserve`` [N m s/rad]."""
    return config.replace(feedforward=dataclasses.replace(config.feedforward,
                                                          damping_reserve=reserve))


def _describe(corner: Mapping[str, float]) -> str:
    """``motor_inertia x1.2, ...``: the parameters a corner moves off the model."""
    return ", ".join(f"{k} x{v:.3g}" for k, v in corner.items() if v != 1.0)


def corner_radius(config: ControllerConfig, spreads: Mapping[str, float], *,
                  mode: str = "dob_full_ff", delay: int = 1, dt: float = 5e-4
                  ) -> Tuple[float, Dict[str, float]]:
    """The largest spectral radius of ``mode``'s sampled closed loop with the endpoint free
    over the corners of the band around ``config``'s model, and that corner.

    Parameters
    ----------
    config : ControllerConfig
        The controller (its ``plant`` and ``dahl`` are the model the band is around).
    spreads : mapping str -> float in [0, 1)
        Relative half-width per :data:`BAND_KEYS` entry (missing: 0).
    mode : str
        ``dob_linear_ff``, ``dob_full_ff`` or ``impedance``.
    delay : int >= 0
        Samples from a state to the sample its command acts from.
    dt : float > 0
        Sample period [s].

    Returns
    -------
    (radius, {key: factor}) : the worst corner's radius and its parameter factors.
    """
    return _worst(config, _corners(spreads), mode, delay, dt)


def radius_at(config: ControllerConfig, corner: Mapping[str, float], *,
              mode: str = "dob_full_ff", delay: int = 1, dt: float = 5e-4) -> float:
    """The radius (as :func:`corner_radius`) of one plant: ``corner`` the factors on
    ``config``'s model per :data:`BAND_KEYS` entry (missing: 1)."""
    return _worst(config, [{k: float(corner.get(k, 1.0)) for k in BAND_KEYS}], mode, delay,
                  dt)[0]


def _corners(spreads: Mapping[str, float]) -> List[Dict[str, float]]:
    """Every corner of the band: {key: factor} (the keys without a spread at 1)."""
    bad = {k: v for k, v in spreads.items()
           if k not in BAND_KEYS or not 0.0 <= float(v) < 1.0}
    if bad:
        raise CommissioningError(f"band spreads: keys of {BAND_KEYS}, values in [0, 1); "
                                 f"got {bad}")
    varied = [k for k in BAND_KEYS if spreads.get(k, 0.0) > 0.0]
    out = []
    for picks in itertools.product((-1.0, 1.0), repeat=len(varied)):
        chosen = dict(zip(varied, picks))
        out.append({k: 1.0 + chosen.get(k, 0.0) * spreads.get(k, 0.0) for k in BAND_KEYS})
    return out


def _axes(corner: Mapping[str, float], spreads: Mapping[str, float],
          steps: Sequence[float] = (-0.5, 0.0, 0.5)) -> List[Dict[str, float]]:
    """The points along each axis through ``corner``: one parameter at ``1 + s x spread`` for
    each ``s`` of ``steps`` (between the band's edges), the others at the corner."""
    out = []
    for k in BAND_KEYS:
        if spreads.get(k, 0.0) > 0.0:
            for s in steps:
                point = dict(corner)
                point[k] = 1.0 + s * spreads[k]
                out.append(point)
    return out


def _worst(config: ControllerConfig, corners: Sequence[Mapping[str, float]], mode: str,
           delay: int, dt: float) -> Tuple[float, Dict[str, float]]:
    """The largest radius over ``corners`` (the feed-forward's Dahl in its play and beyond
    it) and its corner; the controller's polynomials computed once."""
    if mode not in _MODES:
        raise CommissioningError(f"mode {mode!r}: one of " + ", ".join(_MODES))
    sigma_ff = config.feedforward.dahl(config.dahl).sigma if mode != "dob_linear_ff" else 0.0
    polys = [controller_polynomials(config, mode, dt, g + 0j) for g in sorted({0.0, sigma_ff})]
    matrices, actuals = [], []
    for corner in corners:
        plant, dahl, actual = _corner_plant(config.plant, config.dahl,
                                            tuple(corner[k] for k in BAND_KEYS))
        actuals.append(dict(actual))
        matrices.append([closed_loop_matrix(plant, dahl, config, mode, delay=delay, dt=dt,
                                            polynomials=p) for p in polys])
    # one eigenvalue call per controller polynomial over every corner (a tuning asks for
    # tens of thousands of small matrices: the calls' overhead was most of its time)
    radii = np.max([np.max(np.abs(np.linalg.eigvals(np.stack([m[i] for m in matrices]))),
                           axis=1) for i in range(len(polys))], axis=0)
    i = int(np.argmax(radii))
    return float(radii[i]), actuals[i]


@functools.lru_cache(maxsize=4096)
def _corner_plant(plant: PlantParams, dahl: DahlParams, factors: Tuple[float, ...]
                  ) -> Tuple[PlantParams, DahlParams, Dict[str, float]]:
    """The plant and Dahl model at a corner (the factors in :data:`BAND_KEYS`' order), each
    within its range, and the factors taken (a factor the range cut: the one taken); remembered,
    as a reserve's bisection visits the same corners of one model many times (never write into
    the dict)."""
    corner = dict(zip(BAND_KEYS, factors))
    at = dataclasses.replace(plant, **{
        k: _in_range(PlantParams, k, getattr(plant, k) * corner[k]) for k in PLANT_FIELDS})
    at_dahl = dataclasses.replace(dahl, sigma=_in_range(DahlParams, "sigma",
                                                        dahl.sigma * corner["sigma"]))
    actual = dict(corner)
    for k in PLANT_FIELDS:
        if getattr(at, k) != getattr(plant, k) * corner[k]:
            actual[k] = getattr(at, k) / getattr(plant, k)
    if at_dahl.sigma != dahl.sigma * corner["sigma"]:
        actual["sigma"] = at_dahl.sigma / dahl.sigma
    return at, at_dahl, actual


def _in_range(group: type, name: str, value: float) -> float:
    """``value`` of the parameter ``name`` of ``group`` within the parameter's range (a band
    around a model near its range's top reaches past it; the corners are the plants the
    range admits)."""
    spec = group.spec(name)          # type: ignore[attr-defined]
    if spec.high is not None and value >= spec.high:
        return math.nextafter(spec.high, -math.inf) if spec.high_open else float(spec.high)
    return value


def size_reserve(config: ControllerConfig, spreads: Mapping[str, float], *,
                 mode: str = "dob_full_ff", delay: int = 1, dt: float = 5e-4,
                 steps: int = 12, hint: Optional[Mapping[str, float]] = None
                 ) -> Tuple[float, float, Dict[str, float]]:
    """The least ``feedforward.damping_reserve`` (to 1/2^``steps`` of the bracket) for which
    every corner's radius is below :data:`RADIUS_TARGET`: (reserve [N m s/rad], the worst
    radius with it, its corner). ``hint``: a corner likely to be the worst (the previous
    result's, for a similar controller), bisected on first. Raises CommissioningError when
    :data:`RESERVE_LIMIT` does not do it (then no damping on the motor velocity steadies the
    finger: the feed-forward's sigma, or the band, is too large for this loop)."""
    def worst(reserve: float, points: Sequence[Mapping[str, float]]
              ) -> Tuple[float, Dict[str, float]]:
        return _worst(with_reserve(config, reserve), points, mode, delay, dt)

    every = _corners(spreads)
    if hint is not None and set(hint) == set(BAND_KEYS):
        active = [dict(hint)]
    else:
        r0, c0 = worst(0.0, every)
        if r0 < RADIUS_TARGET:
            return 0.0, r0, c0
        active = [c0]
    # bisect on the corners that were worst so far; then check every corner, and again with
    # the one that is worst there, until every corner holds
    lo, hi = 0.0, 0.004
    if worst(0.0, active)[0] < RADIUS_TARGET:
        hi = 0.0
    while True:
        while worst(hi, active)[0] >= RADIUS_TARGET:
            if hi >= RESERVE_LIMIT:
                r, c = worst(hi, every)
                raise CommissioningError(
                    f"no damping reserve up to {RESERVE_LIMIT:g} N m s/rad steadies a free "
                    f"finger in {mode} at every corner of the band (worst radius {r:.6f} at "
                    f"{_describe(c)}): narrow the band (commission the gripper) or lower "
                    "feedforward.dahl_stiffness_share")
            lo, hi = hi, min(RESERVE_LIMIT, 2.0 * hi)
        for _ in range(steps if hi > 0.0 else 0):
            mid = 0.5 * (lo + hi)
            if worst(mid, active)[0] < RADIUS_TARGET:
                hi = mid
            else:
                lo = mid
        r, c = worst(hi, every)
        if r < RADIUS_TARGET:
            # (the radius need not be largest at a corner: along each axis through the worst
            # corner too -- on Table I's band an interior sigma came out above the corners)
            r2, c2 = worst(hi, _axes(c, spreads))
            if r2 < RADIUS_TARGET:
                return hi, max(r, r2), (c if r >= r2 else c2)
            r, c = r2, c2
        active.append(c)
        lo, hi = hi, max(hi, 0.004)


def reserve_verdict(config: ControllerConfig, *, delay: int = 1, dt: float = 5e-4
                    ) -> Optional[str]:
    """What is wrong with ``config``'s ``feedforward.damping_reserve`` for its own model and
    band (:func:`band_spreads`), in words, or None when every corner is stable. About 0.1 s
    of CPU on a quiet host, 1-2 s when it sizes the reserve (only when it warns)."""
    spreads = band_spreads(config)
    radius, corner = corner_radius(config, spreads, delay=delay, dt=dt)
    if radius < RADIUS_TARGET:
        return None
    where = _describe(corner)
    head = (f"feedforward.damping_reserve = {config.feedforward.damping_reserve:.3g} N m s/rad "
            f"leaves a free finger in dob_full_ff small-signal unstable on a plant "
            f"within the model's band (+-{100 * max(spreads.values()):.0f} %; spectral radius "
            f"{radius:.6f} at {where}): it may oscillate or creep")
    try:
        least, _, _ = size_reserve(config, spreads, delay=delay, dt=dt)
    except CommissioningError:
        return head + ("; no reserve holds that band: commission the gripper (a narrower "
                       "band) or lower feedforward.dahl_stiffness_share")
    if least <= 0.0:                    # (the loop is not monotonic in the reserve here)
        return head + "; a reserve of 0 holds it: set feedforward.damping_reserve to 0"
    step = 10.0 ** (math.floor(math.log10(least)) - 2)         # 3 digits, rounded up
    return head + (f"; {math.ceil(least / step) * step:.3g} N m s/rad holds it (set "
                   "feedforward.damping_reserve), or commission the gripper")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m seaforce_ros.commissioning.free_finger REQUEST_JSON``: the verdict of
    :func:`reserve_verdict` for a running controller's changed configuration, in a child
    process (``controller_node``: the check's CPU would otherwise hold the interpreter lock
    against the 2 kHz loop). ``REQUEST_JSON`` is ``{"config": ControllerConfig.to_dict(),
    "delay": int, "dt": float}``; the answer is one line ``{"result": {"verdict": str}}``
    (empty: the reserve holds the band), or ``{"error": str}`` and exit status 1."""
    import json
    import sys
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        if len(args) != 1:
            raise ValueError("usage: python -m seaforce_ros.commissioning.free_finger "
                             "REQUEST_JSON")
        request = json.loads(args[0])
        config = ControllerConfig.from_dict(request["config"])
        text = reserve_verdict(config, delay=int(request["delay"]), dt=float(request["dt"]))
    except Exception as exc:         # noqa: BLE001 -- any failure is the answer, in one line
        print(json.dumps({"error": f"free-finger check: {exc}"}), flush=True)
        return 1
    print(json.dumps({"result": {"verdict": text or "", "message": "checked"}}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

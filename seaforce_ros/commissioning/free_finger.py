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
Below 1 at every corner: the finger at rest is asymptotically stable for every such plant
(within the linearisation; the Dahl hysteresis' own dissipation adds to it).
:func:`size_reserve` finds the least reserve that makes it so.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

from ..core.params import ControllerConfig
from .errors import CommissioningError
from .predictor import PLANT_FIELDS, closed_loop_radius, controller_polynomials

__all__ = ["BAND_KEYS", "corner_radius", "radius_at", "size_reserve", "band_spreads",
           "reserve_verdict", "RESERVE_LIMIT", "RADIUS_TARGET"]

#: The uncertain parameters of a band: Table I's eight and the Dahl sigma (F_c and the
#: exponent do not enter the linearisation).
BAND_KEYS = PLANT_FIELDS + ("sigma",)
_MODES = ("dob_linear_ff", "dob_full_ff", "impedance")
#: The largest reserve :func:`size_reserve` tries [N m s/rad] (30 times Table I's b_e: the
#: feed-forward modes would then be stiffer than ``dob``).
RESERVE_LIMIT = 1.0
#: The spectral radius every corner must stay below (a margin against rounding and the
#: bisection's last step: 2e-5 per sample is a time constant of 25 s at 2 kHz).
RADIUS_TARGET = 1.0 - 2e-5


def band_spreads(config: ControllerConfig, relative: Optional[Mapping[str, float]] = None
                 ) -> Dict[str, float]:
    """The band's relative half-widths: ``feedforward.margin`` times each parameter's
    relative uncertainty -- b_e's and k_e's are the feed-forward's own
    (``feedforward.damping_uncertainty``, ``stiffness_uncertainty``), the others' from
    ``relative`` (default: the larger of the two, as for a hand-typed model)."""
    ff = config.feedforward
    default = max(ff.damping_uncertainty, ff.stiffness_uncertainty)
    relative = {} if relative is None else relative
    out = {k: ff.margin * float(relative.get(k, default)) for k in BAND_KEYS}
    out["endpoint_damping"] = ff.margin * ff.damping_uncertainty
    out["endpoint_stiffness"] = ff.margin * ff.stiffness_uncertainty
    return out


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


def _worst(config: ControllerConfig, corners: Sequence[Mapping[str, float]], mode: str,
           delay: int, dt: float) -> Tuple[float, Dict[str, float]]:
    """The largest radius over ``corners`` (the feed-forward's Dahl in its play and beyond
    it) and its corner; the controller's polynomials computed once."""
    if mode not in _MODES:
        raise CommissioningError(f"mode {mode!r}: one of " + ", ".join(_MODES))
    sigma_ff = config.feedforward.dahl(config.dahl).sigma if mode != "dob_linear_ff" else 0.0
    polys = [controller_polynomials(config, mode, dt, g + 0j) for g in sorted({0.0, sigma_ff})]
    worst, at = -1.0, dict(corners[0])
    for corner in corners:
        plant = config.plant.scaled(**{k: corner[k] for k in PLANT_FIELDS})
        dahl = dataclasses.replace(config.dahl, sigma=config.dahl.sigma * corner["sigma"])
        for p in polys:
            r = closed_loop_radius(plant, dahl, config, mode, delay=delay, dt=dt,
                                   polynomials=p)
            if r > worst:
                worst, at = r, dict(corner)
    return worst, at


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
    def with_reserve(r: float) -> ControllerConfig:
        return config.replace(feedforward=dataclasses.replace(config.feedforward,
                                                              damping_reserve=r))

    every = _corners(spreads)
    if hint is not None and set(hint) == set(BAND_KEYS):
        active = [dict(hint)]
    else:
        r0, c0 = _worst(with_reserve(0.0), every, mode, delay, dt)
        if r0 < RADIUS_TARGET:
            return 0.0, r0, c0
        active = [c0]
    # bisect on the corners that were worst so far; then check every corner, and again with
    # the one that is worst there, until every corner holds
    lo, hi = 0.0, 0.004
    if _worst(with_reserve(0.0), active, mode, delay, dt)[0] < RADIUS_TARGET:
        hi = 0.0
    while True:
        while _worst(with_reserve(hi), active, mode, delay, dt)[0] >= RADIUS_TARGET:
            if hi >= RESERVE_LIMIT:
                r, c = _worst(with_reserve(hi), every, mode, delay, dt)
                raise CommissioningError(
                    f"no damping reserve up to {RESERVE_LIMIT:g} N m s/rad steadies a free "
                    f"finger in {mode} at every corner of the band (worst radius {r:.6f} at "
                    + ", ".join(f"{k} x{v:.3g}" for k, v in c.items() if v != 1.0)
                    + "): narrow the band (commission the gripper) or lower "
                      "feedforward.dahl_stiffness_share")
            lo, hi = hi, min(RESERVE_LIMIT, 2.0 * hi)
        for _ in range(steps if hi > 0.0 else 0):
            mid = 0.5 * (lo + hi)
            if _worst(with_reserve(mid), active, mode, delay, dt)[0] < RADIUS_TARGET:
                hi = mid
            else:
                lo = mid
        r, c = _worst(with_reserve(hi), every, mode, delay, dt)
        if r < RADIUS_TARGET:
            return hi, r, c
        active.append(c)
        lo, hi = hi, max(hi, 0.004)


def reserve_verdict(config: ControllerConfig, *, delay: int = 1, dt: float = 5e-4
                    ) -> Optional[str]:
    """What is wrong with ``config``'s ``feedforward.damping_reserve`` for its own model and
    band (:func:`band_spreads`: the margin times the feed-forward's uncertainties, the larger
    of them for the other parameters, as for a hand-typed model), in words, or None when
    every corner is stable. About 0.1 s of CPU (0.3 s when it sizes the reserve)."""
    spreads = band_spreads(config)
    radius, corner = corner_radius(config, spreads, delay=delay, dt=dt)
    if radius < RADIUS_TARGET:
        return None
    where = ", ".join(f"{k} x{v:.3g}" for k, v in corner.items() if v != 1.0)
    head = (f"feedforward.damping_reserve = {config.feedforward.damping_reserve:.3g} N m s/rad "
            f"leaves a free finger in the feed-forward modes small-signal unstable on a plant "
            f"within the model's band (+-{100 * max(spreads.values()):.0f} %; spectral radius "
            f"{radius:.6f} at {where}): it may oscillate or creep")
    try:
        least, _, _ = size_reserve(config, spreads, delay=delay, dt=dt)
    except CommissioningError:
        return head + ("; no reserve holds that band: commission the gripper (a narrower "
                       "band) or lower feedforward.dahl_stiffness_share")
    if least <= 0.0:                    # (the loop is not monotonic in the reserve here)
        return head + "; no reserve at all holds it: set feedforward.damping_reserve to 0"
    step = 10.0 ** (math.floor(math.log10(least)) - 2)         # 3 digits, rounded up
    return head + (f"; {math.ceil(least / step) * step:.3g} N m s/rad holds it (set "
                   "feedforward.damping_reserve), or commission the gripper")

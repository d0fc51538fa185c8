"""The real gripper's nonlinear effects the linear model leaves out, as sim parameters.

The paper names them (Section IV: "a linear damper poorly approximates nonlinear viscous
losses" in the hose, "a nonlinear four-bar mechanism gear ratio in the finger joint", "a
slight stroke position dependence on the actuator diaphragm resistance force"); a real hose
also stiffens with pressure and a direct-drive motor cogs (its Coulomb friction is the sim's
``sim.motor_coulomb``). Each effect is a parameter of ``<channel>.sim.nonlinear.*``; 0 is off,
and with every effect off the sim is the linear plant. Motor frame, rotational SI units; X
motor, X_e actuator endpoint, q the finger joint the endpoint encoder and an external force
see, d = X_e - X the hose deflection, L the half-stroke::

    hose       F_p = k_s d (1 + kappa |d|) + b_s d' (1 + c_q |d'|),    kappa = s_p k_s / 2
    diaphragm  F_k(X_e) = k_e X_e (1 + a_1 u + a_2 u^2),               u = X_e / L
    finger     dX_e/dq = r(q) = 1 + c_1 v + c_2 v^2,                   v = q / L
               F_q = r(q) F_e,act        (virtual work: F_q dq = F_e,act dX_e)
    cogging    F_cog(X) = -T_cog sin(N X + phi)   (acts on the motor)

The hose's tangent stiffness is k_s (1 + s_p k_s |d|), about k_s (1 + s_p |F_p|): it rises by
s_p per N m of pressure force; its damping doubles at a flow |d'| = 1/c_q. The finger link
is massless: with no force at the finger (free air) the ratio changes nothing but what the
endpoint encoder reads.

:func:`draw_effects` draws every effect within :data:`PLAUSIBLE` (the ranges the project
states for a real gripper, its test oracle's too): the hose damping doubling at 1-3 rad/s of
flow, the hose stiffening 10-40 % per N m, the diaphragm force +10..30 % at the stroke's ends
(asymmetry within a third of that), the finger ratio rising 5-15 % from the centre to the
stroke's ends (asymmetry within a third), cogging and motor Coulomb friction of 0.5-1 % of a
1 N m torque range, the cogging's periods from common direct-drive slot/pole counts and its
phase uniform. The hose's stiffening is linear in |F_p|: at the 10 N m of a stiff hold it is
2-5 times the hose's small-signal stiffness.
"""
from __future__ import annotations

import math
from typing import Dict, Tuple

import numpy as np

from .errors import InvalidParameterError
from .params import PlantParams, PlantTermsParams
from .schema import SIM, ParameterGroup, group, param

__all__ = ["NonlinearEffects", "PLAUSIBLE", "COGGING_PERIODS", "TORQUE_RANGE", "draw_effects",
           "hose_force", "hose_energy", "diaphragm_force", "diaphragm_energy", "finger_ratio",
           "endpoint_of_finger", "finger_of_endpoint", "cogging_torque", "cogging_energy",
           "model_terms", "effects_of_terms"]

@group("sim.nonlinear", nodes=(SIM,))
class NonlinearEffects(ParameterGroup):
    """The simulated plant's nonlinear effects (module docstring); every one 0: the linear
    plant."""

    hose_damping_rise: float = param(
        0.0, "s/rad", "rise of the hose damping with hose flow: b_s d' (1 + c_q |d'|), "
        "d' = V_e - V; the damping doubles at a flow of 1/c_q (plausible 0.33-1: doubling at "
        "1-3 rad/s); 0: linear", symbol="c_q", ge=0.0, le=2.0,
        hint="beyond, the hose's flow term is too stiff for the 2 kHz step", read_only=True)
    hose_stiffening: float = param(
        0.0, "1/(N m)", "rise of the hose's tangent stiffness per N m of pressure force: "
        "F_p = k_s d (1 + s_p k_s |d|/2) (plausible 0.1-0.4); 0: linear", symbol="s_p",
        ge=0.0, le=1.0, read_only=True)
    stroke_stiffening: float = param(
        0.0, "-", "rise of the diaphragm force at the stroke's ends: k_e X_e (1 + a_1 u + "
        "a_2 u^2), u = X_e/L (plausible 0.1-0.3); 0: linear", symbol="a_2", ge=0.0, le=1.0,
        read_only=True)
    stroke_asymmetry: float = param(
        0.0, "-", "asymmetry of the diaphragm force's stroke dependence (a_1^2 < 3 a_2: the "
        "force rises over the whole stroke)", symbol="a_1", ge=-1.0, le=1.0, read_only=True)
    finger_ratio: float = param(
        0.0, "-", "rise of the four-bar's ratio dX_e/dq = 1 + c_1 v + c_2 v^2 (v = q/L) from "
        "the centre to the stroke's ends; the endpoint encoder and an external force are on "
        "the finger joint q (plausible 0.05-0.15); 0: a ratio of 1", symbol="c_2", ge=0.0,
        le=1.0, read_only=True)
    finger_asymmetry: float = param(
        0.0, "-", "asymmetry of the four-bar's ratio (c_1^2 < 4 c_2: the ratio stays "
        "positive)", symbol="c_1", ge=-1.0, le=1.0, read_only=True)
    half_stroke: float = param(
        0.5, "rad", "half-stroke the diaphragm's and the finger's terms refer to", symbol="L",
        gt=0.0, le=10.0, read_only=True)
    cogging: float = param(
        0.0, "N m", "motor cogging amplitude, F_cog = -T_cog sin(N X + phi) (plausible 0.5-1 "
        "% of the torque range); 0: none", symbol="T_cog", ge=0.0, le=10.0, read_only=True)
    cogging_periods: int = param(
        84, "", "cogging periods per motor revolution", symbol="N", ge=1, le=1000, read_only=True)
    cogging_phase: float = param(
        0.0, "rad", "cogging phase at X = 0", symbol="phi", ge=0.0, le=2.0 * math.pi,
        read_only=True)

    def check_rules(self) -> None:
        """The diaphragm force rises and the finger ratio stays positive everywhere."""
        _check_asymmetry("stroke_asymmetry", self.stroke_asymmetry, 3.0 * self.stroke_stiffening,
                         "sqrt(3 sim.nonlinear.stroke_stiffening)",
                         "else the diaphragm force falls somewhere along the stroke")
        _check_asymmetry("finger_asymmetry", self.finger_asymmetry, 4.0 * self.finger_ratio,
                         "2 sqrt(sim.nonlinear.finger_ratio)",
                         "else the finger ratio reaches zero: a four-bar at a dead point")

    @property
    def any(self) -> bool:
        """Some effect is on (else the plant is linear)."""
        return bool(self.hose_damping_rise or self.hose_stiffening or self.stroke_stiffening
                    or self.finger_ratio or self.finger_asymmetry or self.cogging)

    @property
    def has_finger_ratio(self) -> bool:
        """The finger ratio is not 1 somewhere."""
        return bool(self.finger_ratio or self.finger_asymmetry)

    def describe(self) -> str:
        """One line of the effects that are on."""
        L = self.half_stroke
        parts = []
        if self.hose_damping_rise:
            parts.append(f"hose damping x2 at {1.0 / self.hose_damping_rise:.2f} rad/s of flow")
        if self.hose_stiffening:
            parts.append(f"hose stiffness +{100 * self.hose_stiffening:.0f} % per N m")
        if self.stroke_stiffening:
            up = self.stroke_stiffening + self.stroke_asymmetry
            down = self.stroke_stiffening - self.stroke_asymmetry
            parts.append(f"diaphragm force +{100 * up:.0f} / +{100 * down:.0f} % at +-{L:g} rad")
        if self.has_finger_ratio:
            parts.append(f"finger ratio {finger_ratio(L, self):.3f} / "
                         f"{finger_ratio(-L, self):.3f} at +-{L:g} rad")
        if self.cogging:
            parts.append(f"cogging {1e3 * self.cogging:.1f} mN m x {self.cogging_periods}/rev")
        return "; ".join(parts) or "none (the linear plant)"

    def key_values(self, prefix: str = "") -> Dict[str, object]:
        """``{prefix + 'sim.nonlinear.<x>': value}`` (a params file's keys)."""
        return {prefix + spec.name: getattr(self, spec.attribute) for spec in self.SPECS}


def _check_asymmetry(key: str, value: float, square: float, bound: str, hint: str) -> None:
    """An asymmetry must be 0 or within +-sqrt(``square``) (``bound`` in words)."""
    if value and not value * value < square:
        raise InvalidParameterError(f"sim.nonlinear.{key}", value,
                                    f"within +-{bound} = +-{math.sqrt(square):.3g}", hint=hint)


# --- the forces and their energies (closed forms the simulator and the tests share) ----------
def hose_force(delta: float, rate: float, stiffness: float, damping: float,
               effects: NonlinearEffects) -> float:
    """F_p [N m] for the hose deflection ``delta`` = X_e - X [rad] and its rate [rad/s], with
    the hose's k_s = ``stiffness`` and b_s = ``damping``."""
    kappa = 0.5 * effects.hose_stiffening * stiffness
    return (stiffness * delta * (1.0 + kappa * abs(delta))
            + damping * rate * (1.0 + effects.hose_damping_rise * abs(rate)))


def hose_energy(delta: float, stiffness: float, effects: NonlinearEffects) -> float:
    """Energy [J] stored in the hose at deflection ``delta`` (the integral of its elastic
    force)."""
    kappa = 0.5 * effects.hose_stiffening * stiffness
    return stiffness * (0.5 * delta * delta + kappa * abs(delta) ** 3 / 3.0)


def diaphragm_force(xe: float, stiffness: float, effects: NonlinearEffects) -> float:
    """F_k(X_e) [N m], the diaphragm's spring force with k_e = ``stiffness``."""
    u = xe / effects.half_stroke
    return stiffness * xe * (1.0 + effects.stroke_asymmetry * u
                             + effects.stroke_stiffening * u * u)


def diaphragm_energy(xe: float, stiffness: float, effects: NonlinearEffects) -> float:
    """Energy [J] stored in the diaphragm at X_e (the integral of :func:`diaphragm_force`)."""
    u = xe / effects.half_stroke
    return stiffness * xe * xe * (0.5 + effects.stroke_asymmetry * u / 3.0
                                  + effects.stroke_stiffening * u * u / 4.0)


def finger_ratio(q: float, effects: NonlinearEffects) -> float:
    """r(q) = dX_e/dq of the four-bar at the finger position q [rad]."""
    v = q / effects.half_stroke
    return 1.0 + effects.finger_asymmetry * v + effects.finger_ratio * v * v


def endpoint_of_finger(q: float, effects: NonlinearEffects) -> float:
    """X_e(q) [rad], the integral of r from 0 to q."""
    L = effects.half_stroke
    v = q / L
    return L * v * (1.0 + effects.finger_asymmetry * v / 2.0 + effects.finger_ratio * v * v / 3.0)


def finger_of_endpoint(xe: float, effects: NonlinearEffects, guess: float = math.nan) -> float:
    """q(X_e) [rad], the inverse of :func:`endpoint_of_finger` (Newton from ``guess``, default
    X_e; the map rises everywhere, :meth:`NonlinearEffects.check_rules`)."""
    q = xe if math.isnan(guess) else guess
    for _ in range(50):
        step = (endpoint_of_finger(q, effects) - xe) / finger_ratio(q, effects)
        q -= step
        if abs(step) <= 1e-15 * (1.0 + abs(q)):
            break
    return q


def cogging_torque(x: float, effects: NonlinearEffects) -> float:
    """The cogging torque on the motor at X [N m]."""
    return -effects.cogging * math.sin(effects.cogging_periods * x + effects.cogging_phase)


def cogging_energy(x: float, effects: NonlinearEffects) -> float:
    """The cogging's potential energy at X [J] (its force is minus its derivative)."""
    n = effects.cogging_periods
    return -effects.cogging * math.cos(n * x + effects.cogging_phase) / n


def model_terms(effects: NonlinearEffects, plant: PlantParams) -> PlantTermsParams:
    """The controller's model terms (``plant_terms``) that describe these effects exactly on
    the plant ``plant`` (its k_s, b_s, k_e): the hose's ``c = b_s c_q``, ``kappa = k_s^2 s_p /
    2``; the diaphragm's ``k_2 = k_e a_1/L``, ``k_3 = k_e a_2/L^2`` (rest at X_e = 0). The
    finger ratio and the cogging have no model term."""
    ks, L = plant.hose_stiffness, effects.half_stroke
    return PlantTermsParams(
        hose_flow=plant.hose_damping * effects.hose_damping_rise,
        hose_pressure=0.5 * effects.hose_stiffening * ks * ks,
        stroke_asymmetry=plant.endpoint_stiffness * effects.stroke_asymmetry / L,
        stroke_stiffness=plant.endpoint_stiffness * effects.stroke_stiffening / (L * L))


def effects_of_terms(terms: PlantTermsParams, plant: PlantParams,
                     half_stroke: float = 0.5) -> NonlinearEffects:
    """The inverse of :func:`model_terms`: the sim's effects that are the model's terms on
    ``plant`` (to simulate an identified model), each within its parameter's range (an
    identified term beyond it is clipped: the sim's 2 kHz step does not take a stiffer one)."""
    L = half_stroke
    ks, bs, ke = plant.hose_stiffness, plant.hose_damping, plant.endpoint_stiffness

    def within(name: str, value: float) -> float:
        spec = next(s for s in NonlinearEffects.SPECS if s.attribute == name)
        low = -math.inf if spec.low is None else spec.low
        high = math.inf if spec.high is None else spec.high
        return float(min(max(value, low), high))
    a2 = within("stroke_stiffening", terms.stroke_stiffness * L * L / ke if ke > 0 else 0.0)
    a1 = terms.stroke_asymmetry * L / ke if ke > 0 else 0.0
    a1 = math.copysign(min(abs(a1), 0.999 * math.sqrt(3.0 * a2)), a1) if a2 > 0 else 0.0
    return NonlinearEffects(
        hose_damping_rise=within("hose_damping_rise", terms.hose_flow / bs if bs > 0 else 0.0),
        hose_stiffening=within("hose_stiffening", 2.0 * terms.hose_pressure / (ks * ks)
                               if ks > 0 else 0.0),
        stroke_stiffening=a2, stroke_asymmetry=a1, half_stroke=L)


# --- plausible magnitudes ----------------------------------------------------------------------
#: The torque range [N m] the motor's magnitudes are a share of (commissioning's max_torque).
TORQUE_RANGE = 1.0
#: Effect -> (low, high) of its magnitude as a user states it (module docstring): the flow
#: [rad/s] at which the hose damping doubles, the rest as :class:`NonlinearEffects` has them.
PLAUSIBLE: Dict[str, Tuple[float, float]] = {
    "hose_doubling_flow": (1.0, 3.0), "hose_stiffening": (0.1, 0.4),
    "stroke_stiffening": (0.1, 0.3), "finger_ratio": (0.05, 0.15),
    "cogging": (0.005 * TORQUE_RANGE, 0.01 * TORQUE_RANGE),
    "motor_coulomb": (0.005 * TORQUE_RANGE, 0.01 * TORQUE_RANGE)}
#: Cogging periods per revolution of common direct-drive motors (slots x poles).
COGGING_PERIODS = (24, 36, 42, 48, 56, 72, 84)


def draw_effects(rng: np.random.Generator) -> Tuple[NonlinearEffects, float]:
    """Every effect drawn within :data:`PLAUSIBLE`: each magnitude uniform in its range, the
    asymmetries uniform within a third of their effect, the cogging's periods from
    :data:`COGGING_PERIODS`, its phase uniform. Returns the effects and the motor's Coulomb
    friction [N m] (the sim's ``sim.motor_coulomb``)."""
    def uniform(name: str) -> float:
        return float(rng.uniform(*PLAUSIBLE[name]))
    flow = uniform("hose_doubling_flow")
    stroke, finger = uniform("stroke_stiffening"), uniform("finger_ratio")
    effects = NonlinearEffects(
        hose_damping_rise=1.0 / flow, hose_stiffening=uniform("hose_stiffening"),
        stroke_stiffening=stroke, stroke_asymmetry=float(rng.uniform(-1, 1)) * stroke / 3.0,
        finger_ratio=finger, finger_asymmetry=float(rng.uniform(-1, 1)) * finger / 3.0,
        cogging=uniform("cogging"), cogging_periods=int(rng.choice(COGGING_PERIODS)),
        cogging_phase=float(rng.uniform(0.0, 2.0 * math.pi)))
    return effects, uniform("motor_coulomb")

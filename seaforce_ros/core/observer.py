"""Endpoint observer of one channel: hose inversion, Dahl play and the friction feed-forward.

Inputs per sample: motor position X [rad], motor velocity V [rad/s], pressure force F_p
[N m]. Outputs: the endpoint estimates X_e_hat [rad] and V_e_hat [rad/s], the Dahl input
[rad] and force F_d [N m], and the linear feed-forward F_cmp [N m] (paper eq. 29 and 14).

* Hose inversion (eq. 29): ``delta = F_p/(b_s s + k_s)`` (the hose deflection X_e - X),
  pole ``k_s/b_s`` (1414 rad/s for Table I), discretised exactly for a piecewise-*linear* F_p
  (first-order hold: no lag at the sample instants). Then ``X_e_hat = X + delta`` and
  ``V_e_hat = V + (F_p - k_s delta)/b_s`` (= V + d(delta)/dt exactly).
* Feed-forward: ``F_cmp = s_b b_e V_e_hat + s_k k_e (X_e_hat - rest_position)`` (eq. 29) and
  ``s_d F_d``, the Dahl force ``F_d`` (eq. 14, exact per-sample update, :mod:`.dahl`) driven
  by X_e_hat through a play operator (dead zone) of width ``dahl_deadband`` (default 1e-4 rad,
  about 3-4 sigma of the X_e_hat noise from the pressure sensor): without it,
  sample-to-sample noise on X_e_hat makes the Dahl state relax at every spurious reversal,
  which at slow speeds (0.3 rad/s) biased F_d by ~5 mN m rms in simulation (0.15 mN m with
  the play).
* The margin: ``s = 1 - margin u`` per term (:meth:`~.params.FeedforwardParams.scales`) puts
  the feed-forward's b_e, k_e and Dahl F_c at the low edge of the model's uncertainty, so that
  it never cancels more friction than the finger may have (a finger whose friction is
  over-compensated has negative net stiffness, damping or hysteresis and runs away). The Dahl
  feed-forward's sigma is also only ``dahl_stiffness_share`` (0.5) of the model's: sigma is the
  finger's pre-sliding stiffness, about 200 times k_e, and cancelling it through the loop's
  lag (the DOB, the hose) is negative damping -- at the low edge of a 20 % band it made a free
  finger oscillate (0.14-0.19 rad/s rms limit cycles in 24 of 40 plants 20 % off; none at half
  the stiffness). So the feed-forward's Dahl force has its own state (:attr:`dahl_feedforward`);
  F_d itself (what the contact estimator and the friction adaptation see) is the model's.
* The reserve: ``F_cmp`` also has ``- r HP(V)``, ``r = damping_reserve`` on the motor velocity
  through a first-order high-pass of corner ``reserve_cutoff`` (the DOB renders it as
  damping, in the feed-forward modes only): the feed-forward cancels the finger's b_e, which
  was what damped the motor and finger swinging together on the finger's pre-sliding
  friction (sigma, a spring stiffer than the hose: 25-130 rad/s), and the sampled loop's own
  damping of that mode can be negative -- without a reserve 5 of 100 free fingers drawn at
  the edge of Table I's 20 % band oscillated or crept away. Applied on every frequency the
  reserve was also a damping floor in the Z-width's band (0.017 N m s/rad is -35 dB); the
  high-pass leaves it there only as an inertia ``r/cutoff``. Discretised
  ``y_k = a (y_{k-1} + V_k - V_{k-1})``, ``a = exp(-cutoff T)`` (cutoff 0: ``y = V``).

The identified model's nonlinear terms (``plant_terms``, :class:`~.params.PlantTermsParams`),
when some are set: the hose ``F_p = k_s d + b_s d' + c |d'| d' + kappa |d| d`` is inverted
linearised -- the elastic force about a deflection (its tangent stiffness ``k_s + 2 kappa
|d|``), the damping at a flow (``b_s + c |d'|``) -- and stepped exactly in the same
first-order hold, first about the previous sample, then about the step's midpoint (predictor
and corrector: stable for any deflection; at a steady force the fixed point is the true
deflection), the flow ``d'`` solved from the hose equation at the new deflection; the feed-forward adds ``s_s (k_2 u^2 + k_3 u^3)``, ``u = X_e_hat - rest``,
``s_s`` the stroke terms' own margin scale (:meth:`~.params.FeedforwardParams.stroke_scale`).
With every term 0 the arithmetic is the linear one's, to the bit.

A plant that skipped samples (``steps`` > 1) is integrated over the real elapsed time: the
first-order hold spans ``steps * dt``. Plain Python floats, no allocation per sample.
"""

from __future__ import annotations

import math

from .dahl import DahlState
from .params import DahlParams, FeedforwardParams, PlantParams, PlantTermsParams

__all__ = ["EndpointObserver", "hose_coefficients", "hose_deflection", "hose_flow"]

_exp = math.exp
_sqrt = math.sqrt
_NO_TERMS = PlantTermsParams()


def hose_deflection(force: float, stiffness: float, pressure: float) -> float:
    """The static deflection d [rad] of ``force = k_s d + kappa |d| d`` [N m] (``pressure`` =
    kappa >= 0, ``stiffness`` = k_s > 0)."""
    a = abs(force)
    d = 2.0 * a / (stiffness + _sqrt(stiffness * stiffness + 4.0 * pressure * a))
    return d if force >= 0.0 else -d


def hose_flow(residual: float, damping: float, flow: float) -> float:
    """The flow d' [rad/s] of ``residual = b_s d' + c |d'| d'`` [N m] (``flow`` = c >= 0,
    ``damping`` = b_s > 0)."""
    return hose_deflection(residual, damping, flow)


def hose_coefficients(stiffness: float, inverse_damping: float,
                      period: float) -> tuple[float, float, float]:
    """Exact first-order-hold discretisation of ``delta' = (F_p - k_s delta)/b_s`` over
    ``period`` [s]: ``delta_k = a delta_{k-1} + c0 F_p,{k-1} + c1 F_p,k``.

    Parameters
    ----------
    stiffness : float > 0
        k_s [N m/rad].
    inverse_damping : float > 0
        1/b_s [rad/(N m s)].
    period : float > 0
        [s].

    Returns
    -------
    (a, c0, c1) : tuple of float
    """
    ks = stiffness
    pT = ks * inverse_damping * period
    a = math.exp(-pT)
    i1 = (1.0 - a) - (1.0 - a - pT * a) / pT
    return a, (1.0 - a - i1) / ks, i1 / ks


class EndpointObserver:
    """``(X, V, F_p) -> X_e_hat, V_e_hat``, the Dahl input and F_d, and F_cmp (module
    docstring).

    Parameters
    ----------
    plant : PlantParams
        k_s, b_s of the hose; b_e, k_e of the endpoint.
    feedforward : FeedforwardParams
        ``rest_position`` [rad] (where k_e is relaxed) and ``dahl_deadband`` [rad].
    dahl : DahlParams
        sigma, F_c, n of the Dahl force (eq. 14).
    dt : float > 0
        Sample period T [s].

    Attributes (after every :meth:`update`)
    ----------------------------------------
    position : float
        X_e_hat [rad].
    velocity : float
        V_e_hat [rad/s].
    dahl_input : float
        X_e_hat through the play operator [rad] (what drives F_d).
    dahl_force : float
        F_d [N m].
    compensation : float
        F_cmp [N m] (eq. 29, with the margin), less the damping reserve's ``r V``.
    dahl_feedforward : float
        The feed-forward's Dahl force [N m] (the margin's F_c, a share of sigma).
    feedforward : float
        ``F_cmp + dahl_feedforward`` [N m]: the full feed-forward, with the margin.
    damping, stiffness : float
        The model's b_e [N m s/rad] and k_e [N m/rad] (the friction adaptation moves them);
        F_cmp takes them times the margin's scales.
    dahl : DahlState
        The Dahl state behind F_d.
    """

    __slots__ = ("_bs", "_flow_c", "_kappa", "_hose", "_k2", "_k3", "_stroke", "_dflow",
                 "_k2_model", "_k3_model",
                 "dt", "_ks", "_inv_bs", "_a", "_c0", "_c1", "damping", "stiffness", "_rest",
                 "_half_width", "dahl", "_first", "_delta", "_fp_prev", "dahl_input",
                 "position", "velocity", "dahl_force", "compensation", "feedforward",
                 "_scales", "_reserve", "_kb", "_kk", "_ff", "dahl_ff", "dahl_feedforward",
                 "_hp_a", "_hp_cutoff", "_hp", "_v_prev",
                 "_relax", "_coulomb", "_minus_coulomb", "_sigma", "_minus_sigma")

    def __init__(self, plant: PlantParams, feedforward: FeedforwardParams, dahl: DahlParams,
                 dt: float = 5e-4, terms: PlantTermsParams = _NO_TERMS) -> None:
        self.dt = float(dt)
        self.dahl = DahlState(dahl)
        self.dahl_ff = DahlState(dahl)
        self.configure(plant, feedforward, dahl, terms)
        self.reset()

    def configure(self, plant: PlantParams, feedforward: FeedforwardParams,
                  dahl: DahlParams, terms: PlantTermsParams = _NO_TERMS) -> None:
        """New (validated) parameters, effective at the next :meth:`update`; the state (hose
        deflection, Dahl state) is kept."""
        ks = plant.hose_stiffness
        self._ks, self._inv_bs = ks, 1.0 / plant.hose_damping
        self._bs = plant.hose_damping
        self._a, self._c0, self._c1 = hose_coefficients(ks, self._inv_bs, self.dt)
        self._flow_c, self._kappa = terms.hose_flow, terms.hose_pressure
        self._hose = terms.hose
        self._k2_model, self._k3_model = terms.stroke_asymmetry, terms.stroke_stiffness
        self._rest = feedforward.rest_position
        self._half_width = 0.5 * feedforward.dahl_deadband
        self._scales = feedforward.scales()
        self._reserve = feedforward.damping_reserve
        self._hp_cutoff = feedforward.reserve_cutoff
        self._hp_a = _exp(-self._hp_cutoff * self.dt) if self._hp_cutoff else 0.0
        self._ff = feedforward
        self.set_friction(plant.endpoint_damping, plant.endpoint_stiffness, dahl)

    def set_friction(self, damping: float, stiffness: float, dahl: DahlParams) -> None:
        """b_e [N m s/rad], k_e [N m/rad] and the Dahl parameters of the feed-forward (the
        friction adaptation's values); the Dahl state is kept (its force within the new
        F_c)."""
        self.damping, self.stiffness = damping, stiffness
        sb, sk, _ = self._scales
        self._kb, self._kk = sb * damping, sk * stiffness
        ss = self._ff.stroke_scale()
        self._k2, self._k3 = ss * self._k2_model, ss * self._k3_model
        self._stroke = bool(self._k2 or self._k3)      # (0 with a zero stroke scale too)
        self.dahl.set_params(dahl)
        self.dahl_ff.set_params(self._ff.dahl(dahl))
        # both Dahl states relax exponentially (n = 1, eq. 15; sigma > 0): update updates them
        # itself (DahlState.update's arithmetic), otherwise it calls DahlState.update
        states = (self.dahl, self.dahl_ff)
        self._relax = all(d.exponent == 1.0 and d.sigma != 0.0 for d in states)
        # (negated here, not per sample: the same floats, -sigma dx being (-sigma) dx)
        self._coulomb = tuple(d.coulomb_force for d in states)
        self._minus_coulomb = tuple(-d.coulomb_force for d in states)
        self._sigma = tuple(d.sigma for d in states)
        self._minus_sigma = tuple(-d.sigma for d in states)

    def model_feedforward(self) -> float:
        """``b_e V_e_hat + k_e (X_e_hat - rest) + F_d`` [N m]: the model's friction in full,
        without the margin (what a grasp, which closes its own loop around the endpoint, adds
        to its force)."""
        u = self.position - self._rest
        return (self.damping * self.velocity + u * (self.stiffness + u * (
            self._k2_model + u * self._k3_model)) + self.dahl_force)

    def reset(self) -> None:
        """Forget the state: the next :meth:`update` starts the hose inversion at rest (``delta
        = F_p/k_s``) and the Dahl state at F_d = 0 where X_e_hat is."""
        self._first = True
        self._hp = 0.0
        self._v_prev = math.nan         # (the first update starts the high-pass at rest)
        self._delta = 0.0
        self._dflow = 0.0
        self._fp_prev = 0.0
        self.dahl.reset(0.0, 0.0)
        self.dahl_ff.reset(0.0, 0.0)
        self.dahl_input = 0.0
        self.position = self.velocity = 0.0
        self.dahl_force = self.compensation = self.feedforward = self.dahl_feedforward = 0.0

    def shift_pressure(self, change: float) -> None:
        """The pressure force reads ``change`` [N m] more from now on for the same hose (a new
        sensor offset): the hose inversion's state is moved with it, so that the change is no
        flow through the hose (no spike of V_e_hat)."""
        if not self._first:
            self._fp_prev += change
            if self._hose:          # the elastic force g(d) moves by the change
                d = self._delta
                elastic = (self._ks + self._kappa * abs(d)) * d + change
                self._delta = hose_deflection(elastic, self._ks, self._kappa)
            else:
                self._delta += change / self._ks

    def update(self, x: float, v: float, f_p: float, steps: int = 1) -> None:
        """One sample: X [rad], V [rad/s], F_p [N m]; ``steps`` sample periods since the
        previous one. The results are the attributes."""
        if self._hose:
            delta, ve = self._nonlinear_hose(x, v, f_p, steps)
        else:
            if self._first:
                self._first = False
                delta = f_p / self._ks
                self.dahl_input = x + delta
                self.dahl.reset(x + delta, 0.0)
                self.dahl_ff.reset(x + delta, 0.0)
            elif steps == 1:
                delta = self._a * self._delta + self._c0 * self._fp_prev + self._c1 * f_p
            else:
                a, c0, c1 = hose_coefficients(self._ks, self._inv_bs, steps * self.dt)
                delta = a * self._delta + c0 * self._fp_prev + c1 * f_p
            ve = v + (f_p - self._ks * delta) * self._inv_bs
        self._delta = delta
        self._fp_prev = f_p
        xe = x + delta
        self.position = xe
        self.velocity = ve
        # the play operator: sensor noise on X_e_hat must not drive spurious Dahl reversals;
        # both Dahl states are at its output, dahl_input, since the last sample
        xd = self.dahl_input
        hw = self._half_width
        dahl = self.dahl
        dahl_ff = self.dahl_ff
        moved = True
        if xe > xd + hw:
            xd = self.dahl_input = xe - hw
        elif xe < xd - hw:
            xd = self.dahl_input = xe + hw
        else:
            moved = False
        if not moved:               # nor did the Dahl states
            fd = dahl.force
            fdf = dahl_ff.force
        elif self._relax:
            # DahlState.update (n = 1) written out for the model's state and the
            # feed-forward's, with one increment and their parameters cached by set_friction:
            # the same arithmetic without two calls (a fifth of this update)
            dx = xd - dahl.position
            dahl.position = dahl_ff.position = xd
            fd = dahl.force
            fdf = dahl_ff.force
            if dx != 0.0:
                f_c, f_c_ff = self._coulomb
                if dx > 0.0:
                    sigma, sigma_ff = self._minus_sigma
                    fd = dahl.force = f_c - (f_c - fd) * _exp(sigma * dx / f_c)
                    fdf = dahl_ff.force = f_c_ff - (f_c_ff - fdf) * _exp(sigma_ff * dx / f_c_ff)
                else:
                    sigma, sigma_ff = self._sigma
                    low, low_ff = self._minus_coulomb
                    fd = dahl.force = low + (f_c + fd) * _exp(sigma * dx / f_c)
                    fdf = dahl_ff.force = low_ff + (f_c_ff + fdf) * _exp(sigma_ff * dx / f_c_ff)
        else:
            fd = dahl.update(xd)
            fdf = dahl_ff.update(xd)
        self.dahl_force = fd
        self.dahl_feedforward = fdf
        damped = self._kb * ve - self._reserve * self._high_passed(v, steps)
        if self._stroke:
            u = xe - self._rest
            fc = self.compensation = damped + u * (self._kk + u * (self._k2 + u * self._k3))
        else:
            fc = self.compensation = damped + self._kk * (xe - self._rest)
        self.feedforward = fc + fdf

    def _high_passed(self, v: float, steps: int) -> float:
        """The motor velocity the reserve acts on [rad/s]: ``v`` through the high-pass."""
        if not self._hp_cutoff:
            return v
        a = self._hp_a if steps == 1 else _exp(-self._hp_cutoff * self.dt * steps)
        prev = self._v_prev
        y = self._hp = a * (self._hp + v - prev) if prev == prev else 0.0
        self._v_prev = v
        return y

    def _nonlinear_hose(self, x: float, v: float, f_p: float, steps: int
                        ) -> tuple[float, float]:
        """The hose deflection and X_e_hat's velocity through the nonlinear hose (module
        docstring)."""
        ks, kappa = self._ks, self._kappa
        if self._first:
            self._first = False
            delta = hose_deflection(f_p, ks, kappa)
            self.dahl_input = x + delta
            self.dahl.reset(x + delta, 0.0)
            self.dahl_ff.reset(x + delta, 0.0)
            flow = 0.0
        else:
            # the hose's elastic force g(d) = k_s d + kappa |d| d linearised about a point
            # (its tangent stiffness k_t there), the flow's damping b_s + c |d'| at a flow;
            # the resulting linear equation stepped exactly (first-order hold): first about
            # the previous sample, then again about the step's midpoint (predictor and
            # corrector). (Secant coefficients, or a linearisation at the step's end, left
            # the deflection 1e-4 rad off at 10 N m on a stiffened hose, which the flow's
            # residual amplified by k_t/b_s to 12-20 % of V_e.)
            d0, q0 = self._delta, abs(self._dflow)
            period = steps * self.dt
            bs, c = self._bs, self._flow_c
            fp0 = self._fp_prev
            about, q = d0, q0
            for _ in range(2):
                kt = ks + 2.0 * kappa * abs(about)
                shift = (ks + kappa * abs(about)) * about / kt - about      # g/k_t - about
                a, c0, c1 = hose_coefficients(kt, 1.0 / (bs + c * q), period)
                delta = a * (d0 + shift) + c0 * fp0 + c1 * f_p - shift
                flow = hose_flow(f_p - (ks + kappa * abs(delta)) * delta, bs, c)
                about, q = 0.5 * (d0 + delta), 0.5 * (q0 + abs(flow))
        self._dflow = flow
        return delta, v + flow

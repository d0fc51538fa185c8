"""Disturbance observer on the motor plant (paper eq. 17-19), without differentiation.

With the nominal inverse plant ``P_n^-1 = m_n s + b_n + k_n/s`` and the low-pass ``Q =
lambda/(s + lambda)``, eq. 19 is written as::

    F_a = F_ref + I - lambda m_n V - lambda b_n X,
    I'  = lambda (F_ref + F_p - k_n X)

The integrator uses the trapezoidal rule (no phase error at low frequency); ``d_hat = F_a -
F_ref`` is the disturbance estimate. Entry is bumpless: :meth:`DisturbanceObserver.enter`
chooses the integrator's previous value so that the next output equals the torque the plant
applies. Plain Python floats, no allocation per sample.
"""

from __future__ import annotations

from .params import DobParams

__all__ = ["DisturbanceObserver"]


class DisturbanceObserver:
    """The DOB of one channel (module docstring).

    Parameters
    ----------
    params : DobParams
        lambda [rad/s], m_n [N m s^2/rad] (not None: a :class:`~.params.ControllerConfig`'s),
        b_n [N m s/rad], k_n [N m/rad].
    dt : float > 0
        Sample period T [s].

    Attributes
    ----------
    integral : float
        The integrator I [N m].
    error : float
        ``F_ref + F_p - k_n X`` of the last sample [N m] (the trapezoid's other end).
    lam_half_dt, lam_mn, lam_bn, kn : float
        ``lambda T/2``, ``lambda m_n``, ``lambda b_n``, ``k_n`` (set by :meth:`configure`).

    :class:`~.controller.ChannelController` writes :meth:`update` out for one step on its own
    per-sample path (the same arithmetic, without the call).
    """

    __slots__ = ("dt", "lam_half_dt", "lam_mn", "lam_bn", "kn", "integral", "error")

    def __init__(self, params: DobParams, dt: float = 5e-4) -> None:
        self.dt = float(dt)
        self.configure(params)
        self.reset()

    def configure(self, params: DobParams) -> None:
        """New (validated) parameters; the integrator is kept."""
        lam = params.cutoff
        mn = params.nominal_inertia
        if mn is None:
            raise ValueError("dob.nominal_inertia is None: take the DobParams of a "
                             "ControllerConfig (it fills in the plant's motor inertia)")
        self.lam_half_dt = 0.5 * lam * self.dt
        self.lam_mn = lam * mn
        self.lam_bn = lam * params.nominal_damping
        self.kn = params.nominal_stiffness

    def reset(self) -> None:
        """Integrator at zero (an :meth:`enter` sets it before it is used)."""
        self.integral = 0.0
        self.error = 0.0

    def enter(self, torque: float, f_ref: float, x: float, v: float, f_p: float,
              steps: int = 1) -> None:
        """Bumpless entry: the next :meth:`update` with the same arguments returns ``torque``
        [N m] (the one the plant applies now) up to rounding; F_ref [N m], X [rad], V [rad/s],
        F_p [N m]."""
        e = f_ref + f_p - self.kn * x
        lam_h = self.lam_half_dt * steps
        ramp = self.lam_mn * v + self.lam_bn * x
        self.integral = torque - f_ref + ramp - 2.0 * lam_h * e
        self.error = e

    def update(self, f_ref: float, x: float, v: float, f_p: float, steps: int = 1) -> float:
        """One sample (``steps`` sample periods since the previous one): F_a [N m]."""
        e = f_ref + f_p - self.kn * x
        ramp = self.lam_mn * v + self.lam_bn * x
        # (times 1 is exact: one sample skips the product of a float and an int)
        lam_h = self.lam_half_dt if steps == 1 else self.lam_half_dt * steps
        integ = self.integral + lam_h * (e + self.error)
        self.error = e
        self.integral = integ
        return f_ref + integ - ramp

"""Continuous-time LTI model of one channel (paper Section II-C, Fig. 4).

Equations (motor frame, rotational SI units)::

    motor     (m s^2 + b s + k) X      = F_a + F_p
    endpoint  (m_e s^2 + b_e s + k_e) X_e = F_e - F_p
    hose      F_p = (b_s s + k_s)(X_e - X)

Everything is built from exact polynomial products (numpy ``poly1d``) and
returned as :class:`control.TransferFunction` objects.

A controller acting on the motor port is described by its *motor-port
dynamic stiffness* ``K_m(s) = F_p / X`` (the force the hose must apply to the
motor per unit motor displacement), a ratio of polynomials ``(num, den)``:
unpowered ``K_m = P_m = m s^2 + b s + k``; internal force feedback
``F_a = K_f F_p`` gives ``P_m/(1+K_f)``; the DOB gives ``s/Y(s)`` with Y
from eq. 25. The endpoint impedance then is::

    Z(s) = F_e/V_e = [P_e (K_s + K_m) + K_s K_m] / [s (K_s + K_m)]
"""

from typing import TYPE_CHECKING, Optional, Tuple

import numpy as np
import numpy.typing as npt

from .params import DobParams, PlantParams

if TYPE_CHECKING:                       # imported where used (slow to import)
    import control

__all__ = ["PlantModel", "poly_tf", "Ratio"]

#: A ratio of polynomials in s, ``(numerator, denominator)``: a motor-port dynamic stiffness
#: ``K_m = F_p/X`` or an improper transfer function.
Ratio = Tuple[np.poly1d, np.poly1d]

_S = np.poly1d([1.0, 0.0])


def poly_tf(num: npt.ArrayLike, den: npt.ArrayLike) -> "control.TransferFunction":
    """``control.tf`` from two ``numpy.poly1d`` (leading zeros trimmed)."""
    # imported here: python-control takes about a second to import, and every executable
    # that reaches this module (through core.analysis) would pay it before checking its
    # arguments
    import control
    num = np.atleast_1d(np.trim_zeros(np.asarray(np.poly1d(num).coeffs, float), "f"))
    den = np.atleast_1d(np.trim_zeros(np.asarray(np.poly1d(den).coeffs, float), "f"))
    if num.size == 0:
        num = np.array([0.0])
    return control.tf(num, den)


class PlantModel:
    """Analysis model of one channel.

    Parameters
    ----------
    params : PlantParams
        m, b, k, m_e, b_e, k_e, b_s, k_s.
    """

    def __init__(self, params: PlantParams) -> None:
        if not isinstance(params, PlantParams):
            raise TypeError("params must be a PlantParams")
        self.params = params
        p = params
        #: P_m = m s^2 + b s + k (motor dynamic stiffness, polynomial)
        self.Pm = np.poly1d([p.motor_inertia, p.motor_damping, p.motor_stiffness])
        #: P_e = m_e s^2 + b_e s + k_e
        self.Pe = np.poly1d([p.endpoint_inertia, p.endpoint_damping, p.endpoint_stiffness])
        #: K_s = b_s s + k_s
        self.Ks = np.poly1d([p.hose_damping, p.hose_stiffness])

    # --- the four plants of Fig. 4 ----------------------------------------
    def motor_plant(self) -> "control.TransferFunction":
        """X/F_p with F_a = 0: ``1/(m s^2 + b s + k)`` (Fig. 4A)."""
        return poly_tf([1.0], self.Pm)

    def endpoint_plant(self) -> "control.TransferFunction":
        """X_e/(F_e - F_p): ``1/(m_e s^2 + b_e s + k_e)`` (Fig. 4B)."""
        return poly_tf([1.0], self.Pe)

    def hose_plant(self) -> Ratio:
        """F_p/(X_e - X): ``b_s s + k_s`` (Fig. 4C); improper, returned as
        numerator/denominator polynomials ``(b_s s + k_s, 1)``."""
        return self.Ks, np.poly1d([1.0])

    def endpoint_system(self) -> "control.TransferFunction":
        """X_e/F_e, motor unpowered (Fig. 4D): 2 zeros, 4 poles."""
        return poly_tf(self.Pm + self.Ks, self.Pe * (self.Pm + self.Ks) + self.Ks * self.Pm)

    def endpoint_poles(self) -> npt.NDArray[np.complex128]:
        """Poles of X_e/F_e [rad/s], sorted by imaginary part then real part."""
        den = self.Pe * (self.Pm + self.Ks) + self.Ks * self.Pm
        # numpy types sort_complex for complex input; np.roots returns real roots as floats
        return np.sort_complex(np.roots(den.coeffs))  # type: ignore[arg-type]

    # --- motor-port dynamic stiffnesses K_m = F_p/X ------------------------
    def port_passive(self) -> Ratio:
        """Unpowered motor: ``K_m = P_m``."""
        return self.Pm, np.poly1d([1.0])

    def port_internal_force_feedback(self, gain: float) -> Ratio:
        """``F_a = K_f F_p`` (eq. 20): ``K_m = P_m/(1 + K_f)``."""
        return self.Pm, np.poly1d([1.0 + gain])

    def port_pd(self, stiffness: float, damping: float) -> Ratio:
        """PD hold ``F_a = -K_p X - K_d V`` (continuous, no delay):
        ``K_m = P_m + K_d s + K_p``."""
        return self.Pm + np.poly1d([damping, stiffness]), np.poly1d([1.0])

    def port_dob(self, dob: DobParams, linear_ff: bool = False) -> Ratio:
        """DOB (eq. 19, F_ref = 0 or the linear feed-forward of eq. 29).

        ``F_a = (s+lambda)/s F_ref + (lambda/s)(F_p - P_n^-1 V)`` with
        ``F_ref = c_V V + c_p F_p``, ``c_V = b_e + k_e/s``,
        ``c_p = (b_e s + k_e)/(b_s s + k_s)``. Solving the motor equation::

            K_m = s [P_m - (s+lam) c_V + lam P_n^-1] / [(s+lam)(1 + c_p)]

        Parameters
        ----------
        dob : DobParams
            lambda, m_n (None -> m), b_n, k_n.
        linear_ff : bool
            Include the linear endpoint friction feed-forward (eq. 29).
        """
        p = self.params
        lam = dob.cutoff
        m_n = p.motor_inertia if dob.nominal_inertia is None else dob.nominal_inertia
        # s * P_n^-1 = m_n s^2 + b_n s + k_n
        sPn = np.poly1d([m_n, dob.nominal_damping, dob.nominal_stiffness])
        s_lam = np.poly1d([1.0, lam])
        if not linear_ff:
            # K_m = s (P_m + lam P_n^-1)/(s+lam) = (s P_m + lam sPn)/(s+lam)
            return _S * self.Pm + lam * sPn, s_lam
        be, ke = p.endpoint_damping, p.endpoint_stiffness
        Ce = np.poly1d([be, ke])                 # s c_V = b_e s + k_e
        # numerator: s P_m - (s+lam)(b_e s + k_e) + lam sPn, times (b_s s+k_s)
        num = (_S * self.Pm - s_lam * Ce + lam * sPn) * self.Ks
        den = s_lam * (self.Ks + Ce)
        return num, den

    # --- impedances ----------------------------------------------------------
    def endpoint_impedance(self, port: Optional[Ratio] = None) -> "control.TransferFunction":
        """Endpoint impedance ``Z = F_e/V_e`` [N m s/rad] as a transfer function.

        Parameters
        ----------
        port : (poly1d, poly1d), optional
            Motor-port dynamic stiffness ``K_m = num/den`` (default: unpowered).
        """
        kn, kd = self.port_passive() if port is None else port
        num = self.Pe * (self.Ks * kd + kn) + self.Ks * kn
        den = _S * (self.Ks * kd + kn)
        return poly_tf(num, den)

    def passive_impedance(self) -> "control.TransferFunction":
        """Z with the motor unpowered."""
        return self.endpoint_impedance()

    def internal_force_feedback_impedance(self, gain: float) -> "control.TransferFunction":
        """Z with ``F_a = K_f F_p`` (internal force feedback, eq. 20-22)."""
        return self.endpoint_impedance(self.port_internal_force_feedback(gain))

    def external_force_feedback_impedance(self, gain: float) -> "control.TransferFunction":
        """Z with ``F_a = K_f F_e`` (external force feedback)::

            Z = [P_e (P_m + K_s) + K_s P_m] / [s (P_m + (1 + K_f) K_s)]
        """
        num = self.Pe * (self.Pm + self.Ks) + self.Ks * self.Pm
        den = _S * (self.Pm + (1.0 + gain) * self.Ks)
        return poly_tf(num, den)

    def dob_impedance(self, dob: DobParams,
                      linear_ff: bool = False) -> "control.TransferFunction":
        """Z with the continuous DOB (optionally + linear feed-forward)."""
        return self.endpoint_impedance(self.port_dob(dob, linear_ff))

    def hold_impedance(self, stiffness: float, damping: float) -> "control.TransferFunction":
        """Z with a continuous PD hold on the motor position."""
        return self.endpoint_impedance(self.port_pd(stiffness, damping))

    def motor_port_impedance(self,
                             port: Optional[Ratio] = None) -> "control.TransferFunction":
        """Motor-port impedance ``F_p/V = K_m/s`` (the "MaxZ motor only" curve
        for a rigid hose when ``port`` is the PD hold)."""
        kn, kd = self.port_passive() if port is None else port
        return poly_tf(kn, _S * kd)

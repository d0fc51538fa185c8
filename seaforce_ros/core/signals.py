"""Excitation signals shared by the controller (``chirp`` mode, the grasp's probe) and the
simulated environment (``torque_chirp``)."""

import math

__all__ = ["log_chirp_phase", "faded_log_chirp"]


def log_chirp_phase(t: float, start_frequency: float, end_frequency: float,
                    duration: float) -> float:
    """Phase [rad] at ``t`` [s] of a log chirp whose instantaneous frequency goes from
    ``start_frequency`` to ``end_frequency`` [Hz] in ``duration`` [s]:
    ``f(t) = f0 (f1/f0)^(t/T)``, ``phi(t) = 2 pi f0 T (exp(t ln(f1/f0)/T) - 1) / ln(f1/f0)``."""
    f0, f1 = start_frequency, end_frequency
    if f1 == f0:
        return 2.0 * math.pi * f0 * t
    rate = math.log(f1 / f0) / duration
    return 2.0 * math.pi * f0 * math.expm1(rate * t) / rate


def faded_log_chirp(t: float, start_frequency: float, end_frequency: float, duration: float,
                    fade: float) -> float:
    """Unit log chirp (:func:`log_chirp_phase`) with raised-cosine fades of ``fade`` [s] at both
    ends (``fade = duration/2``: a raised-cosine window over the whole chirp); 0 outside
    ``[0, duration)``."""
    if t < 0.0 or t >= duration:
        return 0.0
    edge = min(t, duration - t)
    w = 1.0 if edge >= fade else 0.5 - 0.5 * math.cos(math.pi * edge / fade)
    return w * math.sin(log_chirp_phase(t, start_frequency, end_frequency, duration))

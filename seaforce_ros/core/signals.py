"""Excitation signals shared by the controller (``chirp`` mode, the grasp's probe, the
friction calibration's and the tare's motions) and the simulated environment
(``torque_chirp``)."""

import math

__all__ = ["log_chirp_phase", "faded_log_chirp", "faded_sine"]


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


def faded_sine(t: float, amplitude: float, omega: float, fade: float,
               duration: float) -> tuple[float, float]:
    """``(y, dy/dt)`` at ``t`` [s] of ``amplitude e(t) sin(omega t)`` with raised-cosine fades
    ``e`` of ``fade`` [s] at both ends of ``[0, duration]`` (0 outside it)."""
    if t <= 0.0 or t >= duration:
        return 0.0, 0.0
    if t < fade:
        e = 0.5 * (1.0 - math.cos(math.pi * t / fade))
        de = 0.5 * math.pi / fade * math.sin(math.pi * t / fade)
    elif t > duration - fade:
        e = 0.5 * (1.0 - math.cos(math.pi * (duration - t) / fade))
        de = -0.5 * math.pi / fade * math.sin(math.pi * (duration - t) / fade)
    else:
        e, de = 1.0, 0.0
    s, c = math.sin(omega * t), math.cos(omega * t)
    return amplitude * e * s, amplitude * (de * s + e * omega * c)

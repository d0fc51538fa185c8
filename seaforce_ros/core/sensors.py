"""Sensor models of one channel, as the EtherCAT loop sees them.

* Pressure force F_p: a 16-bit ADC over a symmetric range ``[-R, R]`` N m
  (torque-equivalent) with additive Gaussian noise before quantisation.
* Motor encoder: position quantised to ``motor_counts_per_rev`` (rounded to
  the nearest count). The drive's velocity is the backward difference of the
  quantised position over one loop period, ``(x_q[k] - x_q[k-1])/dt`` (the
  mean velocity over the last sample: half a sample of lag, one count/dt of
  resolution).
* Endpoint encoder: 40,000 counts/rev (10,000-line quadrature, paper II-B),
  used for identification and impedance measurement only.

A count of 0 (or ``bits=0``) disables the quantisation.
"""

import math
from dataclasses import dataclass

from .errors import InvalidParameterError

__all__ = ["SensorParams", "quantise", "adc"]

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class SensorParams:
    """Sensor resolution and noise.

    Parameters
    ----------
    pressure_range : float > 0
        ADC full scale R, the range is ``[-R, R]`` [N m].
    pressure_bits : int >= 0
        ADC resolution (16 on the paper's EtherCAT terminal; 0: none).
    pressure_noise : float >= 0
        Standard deviation of the Gaussian pressure noise [N m].
    motor_counts_per_rev : int >= 0
        Motor encoder counts per revolution (0: no quantisation).
    endpoint_counts_per_rev : int >= 0
        Endpoint encoder counts per revolution (40,000; 0: none).
    """

    pressure_range: float = 10.0
    pressure_bits: int = 16
    pressure_noise: float = 5e-4
    motor_counts_per_rev: int = 2 ** 20
    endpoint_counts_per_rev: int = 40000

    def __post_init__(self):
        if not (math.isfinite(self.pressure_range) and self.pressure_range > 0):
            raise InvalidParameterError("sensors.pressure_range", self.pressure_range,
                                        "> 0 and finite")
        if not (math.isfinite(self.pressure_noise) and self.pressure_noise >= 0):
            raise InvalidParameterError("sensors.pressure_noise", self.pressure_noise,
                                        ">= 0 and finite")
        for name in ("pressure_bits", "motor_counts_per_rev", "endpoint_counts_per_rev"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise InvalidParameterError("sensors." + name, value, "an integer >= 0")

    @classmethod
    def ideal(cls):
        """No noise, no quantisation (ADC range still clips at 1e9 N m)."""
        return cls(pressure_range=1e9, pressure_bits=0, pressure_noise=0.0,
                   motor_counts_per_rev=0, endpoint_counts_per_rev=0)

    @property
    def pressure_quantum(self):
        """ADC step [N m] (0 when not quantised)."""
        if self.pressure_bits == 0:
            return 0.0
        return 2.0 * self.pressure_range / (2 ** self.pressure_bits)

    @property
    def motor_quantum(self):
        """Motor encoder step [rad] (0 when not quantised)."""
        return TWO_PI / self.motor_counts_per_rev if self.motor_counts_per_rev else 0.0

    @property
    def endpoint_quantum(self):
        """Endpoint encoder step [rad] (0 when not quantised)."""
        return TWO_PI / self.endpoint_counts_per_rev if self.endpoint_counts_per_rev else 0.0


def quantise(value, quantum):
    """Round ``value`` to the nearest multiple of ``quantum`` (0: unchanged)."""
    if quantum == 0.0:
        return value
    return quantum * round(value / quantum)


def adc(value, quantum, full_scale):
    """Quantise and clip to ``[-full_scale, full_scale - quantum]``."""
    if value > full_scale:
        value = full_scale
    elif value < -full_scale:
        value = -full_scale
    if quantum == 0.0:
        return value
    q = quantum * round(value / quantum)
    top = full_scale - quantum
    return top if q > top else q

"""Sensor models of one channel, as the EtherCAT loop sees them.

* Pressure force F_p: a 16-bit ADC over a symmetric range ``[-R, R]`` N m
  (torque-equivalent) with additive Gaussian noise before quantisation.
  An offset ``pressure_offset`` (what the sensor reads with no force in the
  hose), changing at ``pressure_drift`` per second, is added before the ADC.
* Motor encoder: position quantised to ``motor_counts_per_rev`` (rounded to
  the nearest count). The drive's velocity is the mean of the last
  ``velocity_samples`` backward differences of the quantised position,
  ``(x_q[k] - x_q[k-n])/(n dt)`` (n = 1: the mean velocity over the last
  sample, half a sample of lag, one count/dt of resolution; a drive that
  averages n of them has (n - 1)/2 samples more lag and n times the
  resolution).
* Endpoint encoder: 40,000 counts/rev (10,000-line quadrature, paper II-B),
  used for identification and impedance measurement only.

A count of 0 (or ``bits=0``) disables the quantisation.
"""

import math

from .schema import SIM, ParameterGroup, group, param

__all__ = ["SensorParams", "quantise", "adc"]

TWO_PI = 2.0 * math.pi


@group("sensors", nodes=(SIM,))
class SensorParams(ParameterGroup):
    """Sensor resolution and noise of the simulated gripper (per channel)."""

    pressure_range: float = param(10.0, "N m", "pressure ADC full scale R: the range is "
                                  "[-R, R] as F_p", gt=0.0, le=1e9, read_only=True)
    pressure_bits: int = param(16, "", "pressure ADC resolution (16 on the paper's EtherCAT "
                               "terminal; 0: none)", ge=0, le=64, nodes=())
    pressure_noise: float = param(5e-4, "N m", "standard deviation of the Gaussian pressure "
                                  "noise", ge=0.0, le=100.0, read_only=True)
    motor_counts_per_rev: int = param(2 ** 20, "", "motor encoder counts per revolution (0: "
                                      "ideal)", ge=0, le=2 ** 40, read_only=True)
    endpoint_counts_per_rev: int = param(40000, "", "endpoint encoder counts per revolution "
                                         "(10,000-line quadrature, paper II-B; 0: ideal)",
                                         ge=0, le=2 ** 40, read_only=True)
    pressure_offset: float = param(0.0, "N m", "what the pressure sensor reads with no force in "
                                   "the hose (its offset at start)", ge=-100.0, le=100.0,
                                   read_only=True)
    pressure_drift: float = param(0.0, "N m/s", "rate at which the pressure sensor's offset "
                                  "changes (a thermal drift)", ge=-1.0, le=1.0, read_only=True)
    velocity_samples: int = param(1, "", "the drive's velocity is the mean of the last this many "
                                  "backward differences of the motor position (1: the backward "
                                  "difference)", ge=1, le=64, read_only=True)

    @classmethod
    def ideal(cls) -> "SensorParams":
        """No noise, no quantisation (ADC range still clips at 1e9 N m)."""
        return cls(pressure_range=1e9, pressure_bits=0, pressure_noise=0.0,
                   motor_counts_per_rev=0, endpoint_counts_per_rev=0)

    def pressure_bias(self, t: float) -> float:
        """The sensor's offset [N m] at time ``t`` [s] (no noise)."""
        return self.pressure_offset + self.pressure_drift * t

    @property
    def pressure_quantum(self) -> float:
        """ADC step [N m] (0 when not quantised)."""
        if self.pressure_bits == 0:
            return 0.0
        return 2.0 * self.pressure_range / (2 ** self.pressure_bits)

    @property
    def motor_quantum(self) -> float:
        """Motor encoder step [rad] (0 when not quantised)."""
        return TWO_PI / self.motor_counts_per_rev if self.motor_counts_per_rev else 0.0

    @property
    def endpoint_quantum(self) -> float:
        """Endpoint encoder step [rad] (0 when not quantised)."""
        return TWO_PI / self.endpoint_counts_per_rev if self.endpoint_counts_per_rev else 0.0


def quantise(value: float, quantum: float) -> float:
    """Round ``value`` to the nearest multiple of ``quantum`` (0: unchanged)."""
    if quantum == 0.0:
        return value
    return quantum * round(value / quantum)


def adc(value: float, quantum: float, full_scale: float) -> float:
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

"""Physics behind the emulated bus: one ``seaforce_ros.core.simulator.ChannelSimulator``
per channel, stepped once per process-data frame, and the scalings between physical
quantities and what travels in the PDOs.

Time base: the plant advances ``cycle_time`` (default 0.5 ms = 2 kHz) per process-data
frame (LRD/LWR/LRW) that reaches the slaves, whatever the wall-clock period: simulated
time stands still while the master is silent or the cable is pulled.  The torque written
in a frame is applied during the step that follows that frame; the inputs read by a frame
are the measurement taken after the previous step (so a command computed from the inputs
of frame k acts one step after the state it was computed from, like the simulator's
``command_delay=1``).

Scalings (also in ``test/ethercat/README.md``):

* motor position 0x6064 [counts] = round(X / (2 pi) * counts_per_rev)
  (default 2**20 counts/rev, direct drive: gear ratio 1), i32 wraps;
* motor velocity 0x606C [counts/s] = round(V / (2 pi) * counts_per_rev), V being the
  simulator's backward difference of the quantised position;
* torque 0x6071 / 0x6077 [per-mille of rated torque 0x6076]: F_a [N m] = value / 1000 *
  rated_torque (default rated torque 0.5 N m, so 1 unit = 0.5 mN m; i16 -> +-16.38 N m);
* hose pressure, analog input: see :class:`PressureChain` and :class:`AnalogSource`.
"""

import math
from dataclasses import dataclass, asdict

from seaforce_ros.core.environment import environment_from_dict, free
from seaforce_ros.core.params import DahlParams, PlantParams
from seaforce_ros.core.sensors import SensorParams
from seaforce_ros.core.simulator import ChannelSimulator

TWO_PI = 2.0 * math.pi

#: ADC of the analog input terminal: +-10 V <-> +-32767 counts (EL3102 signed format).
ADC_FULL_SCALE_VOLTS = 10.0
ADC_FULL_SCALE_COUNTS = 32767
COUNTS_PER_VOLT = ADC_FULL_SCALE_COUNTS / ADC_FULL_SCALE_VOLTS


@dataclass(frozen=True)
class PressureChain:
    """Hose pressure from F_p, and the transducer's voltage.

    F_p [N m] = (p - preload) * area * arm     (rolling diaphragm area, lever arm)
    volts     = p * volts_per_pascal + volts_offset   (0-10 V transducer over 0-2.5 MPa)
    counts    = round(volts * 32767 / 10), clipped to +-32767

    Defaults: area 5e-4 m^2 (25 mm diaphragm), arm 0.02 m (area * arm = 1e-5 m^3),
    preload 0.5 MPa (p at F_p = 0), 4e-6 V/Pa.  So F_p = 0 reads 2.0 V = 6553 counts, and
    the measurable range 0..10 V is F_p = -5 .. +20 N m; 1 count = 76.3 Pa = 0.763 mN m.
    The inverse chain (what a master applies):
    volts = counts * 10/32767; p = (volts - volts_offset) / volts_per_pascal;
    F_p = (p - preload) * area * arm.
    """

    area_m2: float = 5.0e-4
    arm_m: float = 0.02
    preload_pa: float = 0.5e6
    volts_per_pascal: float = 4.0e-6
    volts_offset: float = 0.0

    def pressure(self, f_p):
        """Hose pressure [Pa] for pressure force ``f_p`` [N m]."""
        return self.preload_pa + f_p / (self.area_m2 * self.arm_m)

    def volts(self, f_p):
        return self.pressure(f_p) * self.volts_per_pascal + self.volts_offset

    def force_from_volts(self, volts):
        p = (volts - self.volts_offset) / self.volts_per_pascal
        return (p - self.preload_pa) * self.area_m2 * self.arm_m


#: quantities an analog input channel can carry
ANALOG_QUANTITIES = ("pressure", "external_force", "endpoint_position", "motor_position",
                     "zero")


@dataclass(frozen=True)
class AnalogSource:
    """What one analog input channel measures.

    quantity ``pressure``: volts from :class:`PressureChain` (``pressure`` field);
    other quantities: volts = value * volts_per_unit + volts_offset with the value in SI
    (external_force F_e [N m], default 2 V/(N m) -> +-5 N m; endpoint_position X_e [rad],
    motor_position X [rad], default 10/pi V/rad -> +-pi rad); ``zero``: 0 V.
    """

    channel: str = ""
    quantity: str = "pressure"
    volts_per_unit: float = 2.0
    volts_offset: float = 0.0
    pressure: PressureChain = PressureChain()

    def __post_init__(self):
        if self.quantity not in ANALOG_QUANTITIES:
            raise ValueError("analog quantity %r is not one of %s"
                             % (self.quantity, ", ".join(ANALOG_QUANTITIES)))

    def volts(self, physics):
        if self.quantity == "zero":
            return self.volts_offset
        ch = physics.channel(self.channel)
        m = ch.measurement
        if self.quantity == "pressure":
            return self.pressure.volts(m.f_p)
        value = {"external_force": m.f_e, "endpoint_position": m.x_e,
                 "motor_position": m.x}[self.quantity]
        return value * self.volts_per_unit + self.volts_offset


@dataclass(frozen=True)
class ChannelConfig:
    """Plant of one channel (defaults: Table I, Dahl sigma 12.8 / F_c 0.032, free)."""

    plant: PlantParams = PlantParams.table_i()
    dahl: DahlParams = DahlParams()
    environment: dict = None
    seed: int = 0
    pressure_noise: float = 5e-4       # [N m] std, before the analog terminal's ADC
    motor_coulomb: float = 0.0
    endpoint_coulomb: float = 0.0
    endpoint_counts_per_rev: int = 40000
    max_torque: float = math.inf


class Channel:
    """One channel's simulator and its latest measurement."""

    def __init__(self, name, config, cycle_time, motor_counts_per_rev):
        self.name = name
        self.config = config
        sensors = SensorParams(pressure_range=1e9, pressure_bits=0,
                               pressure_noise=config.pressure_noise,
                               motor_counts_per_rev=int(motor_counts_per_rev),
                               endpoint_counts_per_rev=config.endpoint_counts_per_rev)
        env = environment_from_dict(config.environment) if config.environment else free()
        self.sim = ChannelSimulator(config.plant, config.dahl, dt=cycle_time,
                                    seed=config.seed, environment=env, sensors=sensors,
                                    motor_coulomb=config.motor_coulomb,
                                    endpoint_coulomb=config.endpoint_coulomb,
                                    torque_saturation=config.max_torque, command_delay=0)
        self.measurement = self.sim.measurement()
        self.torque = 0.0

    def step(self, torque):
        self.torque = torque
        self.measurement = self.sim.step(torque)

    def set_environment(self, values):
        env = environment_from_dict(values) if values else free()
        self.sim.set_environment(env)
        self.measurement = self.sim.measurement()

    def status(self):
        m = self.measurement
        x, v, xe, ve = self.sim.state
        return {
            "time": self.sim.t, "steps": self.sim.step_count,
            "torque": self.torque,
            "motor_position": x, "motor_velocity": v,
            "endpoint_position": xe, "endpoint_velocity": ve,
            "pressure_force": self.sim.pressure_force,
            "external_force": m.f_e,
            "dahl_force": self.sim.dahl_force,
            "drive_position": self.sim.drive_position,
            "measured": dict(m._asdict()),
            "environment": asdict(self.sim.environment),
        }


class Physics:
    """All channels; :meth:`step` advances each by one ``cycle_time``."""

    def __init__(self, channels, cycle_time=5e-4):
        """``channels``: dict name -> (ChannelConfig, motor counts/rev)."""
        self.cycle_time = float(cycle_time)
        self.channels = {name: Channel(name, cfg, self.cycle_time, cpr)
                         for name, (cfg, cpr) in channels.items()}
        self.steps = 0
        self._trace = None            # (decimation, max_samples, {name: list of rows})

    # --- trace ------------------------------------------------------------------------------
    TRACE_FIELDS = ("time", "torque", "motor_position", "motor_velocity", "endpoint_position",
                    "endpoint_velocity", "pressure_force", "external_force")

    def start_trace(self, decimation=1, max_samples=100000):
        """Record every ``decimation``-th step of every channel (true states, SI units,
        :data:`TRACE_FIELDS`), at most ``max_samples`` rows per channel."""
        if int(decimation) < 1 or int(max_samples) < 1:
            raise ValueError("decimation and max_samples must be >= 1")
        self._trace = (int(decimation), int(max_samples), {n: [] for n in self.channels})

    def trace(self, stop=False):
        """``{channel: {field: [values]}}`` recorded so far (``stop``: end recording)."""
        if self._trace is None:
            return {}
        rows = self._trace[2]
        if stop:
            self._trace = None
        return {name: {f: [r[i] for r in data] for i, f in enumerate(self.TRACE_FIELDS)}
                for name, data in rows.items()}

    def _record(self):
        decimation, max_samples, rows = self._trace
        if self.steps % decimation:
            return
        for name, ch in self.channels.items():
            data = rows[name]
            if len(data) < max_samples:
                sim = ch.sim
                x, v, xe, ve = sim.state
                data.append((sim.t, ch.torque, x, v, xe, ve, sim.pressure_force,
                             ch.measurement.f_e))

    def channel(self, name):
        try:
            return self.channels[name]
        except KeyError:
            raise KeyError("no channel %r (channels: %s)"
                           % (name, ", ".join(self.channels))) from None

    def step(self, torques):
        """Advance every channel one step with ``torques`` [N m] (dict; missing = 0)."""
        for name, ch in self.channels.items():
            ch.step(torques.get(name, 0.0))
        self.steps += 1
        if self._trace is not None:
            self._record()

    def status(self):
        return {name: ch.status() for name, ch in self.channels.items()}

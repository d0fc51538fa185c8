"""``first_power_on``: the first check of a rig with the drives powered, before any controller.

    ros2 run seaforce_ros first_power_on --interface enp3s0 --bus-config bus.yaml \\
        [--params-file gripper.yaml] [--channels wrist,pinch] [--torque 0.1] \\
        [--output offsets.yaml]

With the hardware node stopped (the bus is this tool's), each channel in turn, the others at
zero torque, the motor and its finger free and at rest:

1. **rest** (0.3 s, zero torque, repeated while the finger still settles, up to 1.5 s): the
   motor must not move (a finger moved by something else, a drive that is not holding zero,
   is refused);
2. **pulses**: ``+torque`` for 0.2 s, zero for 0.5 s, ``-torque`` for 0.2 s, zero for 0.5 s.
   The drive itself is held to the pulse (its max torque 0x6072 lowered to it for the check,
   restored after), and the node's safety rules run as in the node (torque_limit at the pulse,
   a velocity trip at 10 rad/s). Checked, from the samples (:func:`judge`):

   * **direction**: the motor turns the commanded way (X rises with +torque, falls with -);
   * **position against velocity**: the motion integrated from 0x606C matches the one read
     from 0x6064 (the two scalings agree);
   * **torque scale**: the first milliseconds' acceleration against the model's motor
     inertia m (eq. of the motor): their ratio is the torque scale's error (a wrong rated
     torque or position scaling shows here);
   * **pressure sign**: F_p opposes the torque (it falls with +torque: the hose is compressed
     ahead of the endpoint, F_p = k_s (X_e - X));
   * **free finger**: it moves at least a quarter of what the model's free finger would,
     ``(torque - F_c)/(k + k_e)``, and F_p's apparent stiffness over the motion stays below
     what a held one shows -- else it is refused: *the finger is not free*;

3. **tare**, when those passed: the pressure sensor's offset at rest, measured as
   ``controller_node``'s ``~/tare`` measures it (:class:`~seaforce_ros.core.tare.PressureTare`,
   the same job: the finger taken to its rest by a position servo and dithered there, so that
   the endpoint's friction averages out over whole periods; it refuses a finger that is held
   or has an object on one side), with ``X_e_hat = X + F_p/k_s``.

It prints what it found per channel and, when every check passed, writes
``<channel>.pressure_offset`` (the controller's row, checked against its range) into
``--output`` under ``/**: ros__parameters:`` (an existing file is updated in place, its comments
kept), to be loaded with the setup's params file.

:class:`PowerOnCheck` runs the sequence on an :class:`~.backend.EthercatBackend`; :func:`judge`
is the analysis, pure.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple, cast

from ..core.backend import PlantSample
from ..core.jobs import JobSample
from ..core.params import ControllerConfig, DahlParams, PlantParams
from ..core.plant_cycle import PlantCycle, PlantLimits
from ..core.schema import InvalidParameterError
from ..core.tare import PressureTare            # (imported here: not in the middle of the cycles)
from .backend import EthercatBackend
from .bus_config import BusConfig
from .coe import CoeError
from .errors import EthercatError

REST, PULSE, SETTLE = 0.3, 0.2, 0.5          # s
#: speed above which the check's own trip removes the torque [rad/s]
MAX_VELOCITY = 10.0
#: a motion of less than this [rad] is no motion
MIN_MOTION = 0.005
#: at rest the motor moves less than this [rad] in a rest window
REST_MOTION = 0.002
#: rest windows waited for a finger that still settles
REST_TRIES = 5
#: the finger counts as free when it moves at least this share of the model's free finger
FREE_SHARE = 0.25
#: and F_p's apparent stiffness over the motion stays below this many times the model's free
#: finger's (k_e + 2 F_c / motion), and below a held finger's hose (k_s) share
STIFFNESS_RATIO = 3.0
#: window of the torque-scale fit after a pulse starts [s]
ACCEL_WINDOW = 0.004


@dataclass
class Record:
    """One channel's samples through the check (per cycle)."""

    t: List[float] = field(default_factory=list)
    x: List[float] = field(default_factory=list)
    v: List[float] = field(default_factory=list)
    fp: List[float] = field(default_factory=list)
    torque: List[float] = field(default_factory=list)     # applied [N m]
    phase: List[str] = field(default_factory=list)


@dataclass
class Finding:
    """What the check found on one channel."""

    channel: str
    passed: bool = False
    refused: str = ''                     # why the finger/motor could not be checked
    problems: List[str] = field(default_factory=list)
    lines: List[str] = field(default_factory=list)
    motion: Tuple[float, float] = (math.nan, math.nan)          # X change +/- [rad]
    pressure_change: Tuple[float, float] = (math.nan, math.nan)  # F_p change +/- [N m]
    velocity_ratio: float = math.nan
    torque_scale: float = math.nan
    stiffness: float = math.nan
    offset: float = math.nan

    def report(self) -> str:
        head = (f'{self.channel}: ' + ('passed' if self.passed else
                                       'REFUSED: ' + self.refused if self.refused else 'FAILED'))
        return '\n'.join([head] + [f'  {line}' for line in self.lines]
                         + [f'  FIX: {p}' for p in self.problems])


def _window(rec: Record, phase: str, last: Optional[float] = None) -> List[int]:
    idx = [k for k, p in enumerate(rec.phase) if p == phase]
    if last is not None and idx:
        end = rec.t[idx[-1]]
        idx = [k for k in idx if rec.t[k] >= end - last]
    return idx


def _mean(values: Sequence[float]) -> float:
    return sum(values) / len(values) if values else math.nan


def _slope(ts: Sequence[float], ys: Sequence[float]) -> float:
    n = len(ts)
    if n < 2:
        return math.nan
    mt, my = _mean(ts), _mean(ys)
    den = sum((t - mt) ** 2 for t in ts)
    return sum((t - mt) * (y - my) for t, y in zip(ts, ys)) / den if den else math.nan


def judge(rec: Record, channel: str, torque: float, plant: PlantParams,
          dahl: DahlParams) -> Finding:
    """The checks of one channel's record (module docstring)."""
    f = Finding(channel)
    rest = _window(rec, 'rest')
    if not rest:
        f.refused = 'no sample at rest (the bus lost the frames?)'
        return f
    xs = [rec.x[k] for k in rest]
    if max(xs) - min(xs) > REST_MOTION:
        f.refused = (f'the motor moved {1e3 * (max(xs) - min(xs)):.1f} mrad at zero torque: '
                     'something drives the finger, or the drive does not hold zero; leave it '
                     'free and at rest')
        return f
    noise = math.sqrt(_mean([(rec.fp[k] - _mean([rec.fp[j] for j in rest])) ** 2
                             for k in rest]))
    m, k_spring, k_e, k_s = (plant.motor_inertia, plant.motor_stiffness,
                             plant.endpoint_stiffness, plant.hose_stiffness)
    f_c = dahl.coulomb_force
    free_motion = max(torque - f_c, 0.0) / (k_spring + k_e)
    motion, pressure = [], []
    for sign, pulse, settle in ((1, 'plus', 'after_plus'), (-1, 'minus', 'after_minus')):
        p = _window(rec, pulse)
        before = _window(rec, 'rest' if sign > 0 else 'after_plus', last=0.1)
        if not p or not before:
            f.refused = f'no samples of the {pulse} pulse'
            return f
        x0, fp0 = _mean([rec.x[k] for k in before]), _mean([rec.fp[k] for k in before])
        end = p[-5:]
        motion.append(_mean([rec.x[k] for k in end]) - x0)
        pressure.append(_mean([rec.fp[k] for k in end]) - fp0)
    f.motion = (motion[0], motion[1])
    f.pressure_change = (pressure[0], pressure[1])
    f.lines.append(f'pulses +-{torque:g} N m: motor {1e3 * motion[0]:+.1f} / '
                   f'{1e3 * motion[1]:+.1f} mrad (the model\'s free finger: '
                   f'+-{1e3 * free_motion:.0f}), F_p {1e3 * pressure[0]:+.1f} / '
                   f'{1e3 * pressure[1]:+.1f} mN m (noise {1e3 * noise:.2f} mN m rms)')
    if max(abs(motion[0]), abs(motion[1])) < MIN_MOTION:
        f.refused = ('the motor does not move under the pulses: drive not powered or not '
                     'enabled? torque too small for the friction? the finger blocked? (free it)')
        return f
    direction = motion[0] > 0 and motion[1] < 0
    if not direction:
        if motion[0] < 0 and motion[1] > 0:
            f.problems.append('the motor turns against the command: negate the position and '
                              'velocity factors of the channel in the bus YAML (or the '
                              'drive\'s polarity 0x607E)')
        else:
            f.problems.append('the motor moved the same way under both pulses: something '
                              'pushes the finger; check it is free')
    span = min(abs(motion[0]), abs(motion[1]))
    stiffness = max(abs(pressure[0]), abs(pressure[1])) / max(span, 1e-9)
    f.stiffness = stiffness
    limit = max(1.0, STIFFNESS_RATIO * (k_e + 2.0 * f_c / max(free_motion, MIN_MOTION)))
    if span < FREE_SHARE * free_motion or stiffness > min(limit, 0.3 * k_s):
        f.refused = (f'the finger is not free: it moved {1e3 * span:.1f} mrad (the model\'s free '
                     f'finger {1e3 * free_motion:.0f}), its pressure force rose '
                     f'{stiffness:.3g} N m/rad with the motor (free: below {limit:.3g}); remove '
                     'what holds or presses it and run the check again')
        return f
    if direction:
        f.lines.append('direction: the motor turns the commanded way')
    # position against velocity: over each pulse and its settling
    ratios = []
    for pulse, settle in (('plus', 'after_plus'), ('minus', 'after_minus')):
        idx = _window(rec, pulse) + _window(rec, settle)
        if len(idx) > 2:
            integral = sum(rec.v[k] * (rec.t[k] - rec.t[k - 1]) for k in idx[1:])
            moved = rec.x[idx[-1]] - rec.x[idx[0]]
            peak = max(abs(rec.x[k] - rec.x[idx[0]]) for k in idx)
            if peak > MIN_MOTION:
                # the excursion out and back: compare the way out, the larger share
                out = max(idx, key=lambda k: abs(rec.x[k] - rec.x[idx[0]]))
                integral = sum(rec.v[k] * (rec.t[k] - rec.t[k - 1])
                               for k in idx[1:] if k <= out)
                moved = rec.x[out] - rec.x[idx[0]]
                ratios.append(integral / moved if moved else math.nan)
    f.velocity_ratio = _mean(ratios)
    if not 0.8 <= f.velocity_ratio <= 1.25:
        f.problems.append(f'0x606C integrated gives {f.velocity_ratio:.3g} times the motion '
                          '0x6064 gives: fix the velocity factor (counts/s -> rad/s)')
    else:
        f.lines.append(f'velocity scaling: {f.velocity_ratio:.3f} x the position\'s')
    # torque scale: the acceleration in the first milliseconds of each pulse (its size: the
    # direction is judged above)
    scales = []
    for pulse in ('plus', 'minus'):
        idx = _window(rec, pulse)
        if idx:
            t0 = rec.t[idx[0]]
            early = [k for k in idx if rec.t[k] - t0 <= ACCEL_WINDOW]
            a = _slope([rec.t[k] for k in early], [rec.v[k] for k in early])
            scales.append(abs(a) * m / torque)
    f.torque_scale = _mean(scales)
    if not 0.5 <= f.torque_scale <= 2.0:
        f.problems.append(f'the motor accelerates {f.torque_scale:.3g} times what the model\'s '
                          f'inertia m = {m:g} N m s^2/rad gives for the torque: check the rated '
                          'torque (0x6076) and the position scaling (or the model)')
    else:
        f.lines.append(f'torque scale: {f.torque_scale:.2f} (acceleration x m / torque)')
    if not (pressure[0] < 0 < pressure[1]):
        if pressure[0] > 0 > pressure[1]:
            f.problems.append('the pressure force follows the torque: negate the pressure '
                              'chain\'s factor in the bus YAML (F_p = k_s (X_e - X) falls when '
                              'the motor pushes)')
        else:
            f.problems.append('the pressure force hardly follows the pulses: is the sensor '
                              'wired to the configured input and its chain right?')
    elif min(abs(pressure[0]), abs(pressure[1])) < 3 * noise:
        f.problems.append(f'the pressure force changes little against its noise '
                          f'({1e3 * noise:.2f} mN m): check the sensor and its chain')
    else:
        f.lines.append('pressure sign: F_p opposes the torque')
    f.passed = not f.problems and not f.refused
    return f


def tared(f: Finding, offset: float, sigma: float, message: str, ok: bool) -> Finding:
    """``f`` with the tare's result: the offset checked against the controller's row."""
    if not ok:
        f.refused = f'the tare: {message}'
        f.passed = False
        return f
    try:
        f.offset = ControllerConfig.spec('pressure_offset').check(
            offset, f'{f.channel}.pressure_offset')
        f.lines.append(f'pressure offset {1e3 * offset:+.2f} +- {1e3 * sigma:.2f} mN m (tared '
                       'at rest, dithered)')
    except InvalidParameterError as exc:
        f.problems.append(f'{exc}: is the sensor scaled right?')
        f.passed = False
    return f


class PowerOnCheck:
    """Runs the check's sequence on a configured-and-activated backend (module docstring).

    Parameters
    ----------
    backend : EthercatBackend
        Active (the caller activates and closes it).
    torque : float > 0
        Pulse amplitude [N m].
    pace : bool
        Keep the cycle at ``backend.dt`` (a real bus); False runs the cycles back to back
        (an emulator in this process).
    """

    def __init__(self, backend: EthercatBackend, torque: float, pace: bool = True) -> None:
        self.backend = backend
        self.torque = float(torque)
        self.pace = pace
        self.dt = backend.dt
        self.channels = backend.channels
        limits = PlantLimits(command_timeout=0.05, torque_limit=1.05 * self.torque,
                             max_velocity=MAX_VELOCITY)
        self.plant = PlantCycle(self.channels, self.dt, limits,
                                units_per_nm=backend.units_per_nm)
        self._t = 0.0
        self._next = time.monotonic()
        self._tare_step: Any = None

    def _cycle(self, efforts: Sequence[float], rec: Optional[Record], channel: int,
               phase: str) -> None:
        backend, plant = self.backend, self.plant
        if self.pace:
            now = time.monotonic()
            if self._next > now:
                time.sleep(self._next - now)
            self._next = max(self._next + self.dt, time.monotonic() - self.dt)
        self._t += self.dt
        sample = PlantSample(len(self.channels))
        link = backend.read(sample)
        if link.received and plant.exchange(link.counter, link.expected):
            k = plant.state_published()
            if self._tare_step is not None:     # the tare's servo answers this sample
                i, step = self._tare_step
                efforts = list(efforts)
                efforts[i] = step(sample.position[i], sample.velocity[i],
                                  sample.pressure_force[i])
            plant.command(list(self.channels), list(efforts), k)
            if rec is not None:
                rec.t.append(self._t)
                rec.x.append(sample.position[channel])
                rec.v.append(sample.velocity[channel])
                rec.fp.append(sample.pressure_force[channel])
                rec.torque.append(sample.effort[channel])
                rec.phase.append(phase)
        backend.write(plant.step(self._t, sample.velocity, backend.drives()))
        if self.pace:
            self._next += backend.clock_correction()

    def enable(self, seconds: float = 1.0) -> None:
        """Cycles at zero torque until every drive allows torque (or ``seconds``)."""
        zero = [0.0] * len(self.channels)
        for _ in range(int(seconds / self.dt)):
            self._cycle(zero, None, 0, '')
            if all(r[0] for r in self.backend._reports):
                return
        faults = self.plant.latched_faults()
        raise EthercatError('the drives did not reach Operation enabled in CST'
                            + (': ' + '; '.join(faults) if faults else ''))

    def tare(self, channel: int, config: ControllerConfig,
             timeout: float = 20.0) -> Tuple[float, float, str, bool]:
        """The pressure offset of channel ``channel`` by ``~/tare``'s job on ``config``:
        ``(offset, 1-sigma, message, succeeded)`` [N m]."""
        job = PressureTare(config, self.dt)
        sample = JobSample(cast(Any, None))    # (the tare reads no contact estimator)
        k_s = config.plant.hose_stiffness
        efforts = [0.0] * len(self.channels)
        state: Dict[str, float] = {'torque': 0.0}

        def step(rec_x: float, rec_v: float, rec_fp: float) -> float:
            sample.x, sample.v, sample.f_p = rec_x, rec_v, rec_fp - config.pressure_offset
            sample.endpoint_position = rec_x + sample.f_p / k_s
            sample.torque = state['torque']
            state['torque'] = job.step(sample)
            return state['torque']

        self._tare_step = (channel, step)
        try:
            for _ in range(int(timeout / self.dt)):
                efforts[channel] = state['torque']
                self._cycle(efforts, None, channel, 'tare')
                if job.phase == 'done':
                    break
            else:
                return math.nan, math.nan, 'did not end in time', False
        finally:
            self._tare_step = None
        return job.offset, job.offset_sigma, job.message, job.outcome == 'succeeded'

    def run(self, channel: int) -> Record:
        """The sequence on channel ``channel`` (the others at zero torque). The rest lasts
        until the motor is still (a finger that settles after a motion: up to
        :data:`REST_TRIES` windows); the record keeps the last rest window."""
        rec = Record()
        efforts = [0.0] * len(self.channels)
        for _ in range(REST_TRIES):
            rest = Record()
            for _ in range(int(round(REST / self.dt))):
                self._cycle(efforts, rest, channel, 'rest')
            if rest.x and max(rest.x) - min(rest.x) <= REST_MOTION:
                break
        rec.t, rec.x, rec.v, rec.fp = rest.t, rest.x, rest.v, rest.fp
        rec.torque, rec.phase = rest.torque, rest.phase
        for phase, seconds, torque in (('plus', PULSE, self.torque),
                                       ('after_plus', SETTLE, 0.0),
                                       ('minus', PULSE, -self.torque),
                                       ('after_minus', SETTLE, 0.0)):
            efforts[channel] = torque
            for _ in range(int(round(seconds / self.dt))):
                self._cycle(efforts, rec, channel, phase)
            faults = self.plant.latched_faults()
            if faults:
                raise EthercatError('the check stopped: ' + '; '.join(faults))
        return rec


def model(params_file: Optional[str], channel: str) -> ControllerConfig:
    """The channel's controller configuration as controller_node reads it from the setup's
    params file (its model: m, k, k_e, k_s, F_c, the rest, the hold gains), else the
    defaults (Table I)."""
    if not params_file:
        return ControllerConfig()
    from ..core.errors import SeaforceError
    from ..identification import params_file as pf
    from ..identification.errors import IdentificationError
    keys = [spec.name for spec in ControllerConfig.rows()]
    try:
        view = pf.controller_view(pf.load(params_file, '--params-file'), channel,
                                  pf.where(params_file, '--params-file'), keys)
        return ControllerConfig.from_dict(view.values)
    except (SeaforceError, IdentificationError) as exc:
        raise EthercatError(f'--params-file {params_file}: {channel}: {exc}') from None


def check_bus(backend: EthercatBackend, channels: Sequence[str], torque: Optional[float],
              params_file: Optional[str] = None, pace: bool = True,
              out: Any = None) -> List[Finding]:
    """Open, configure and activate ``backend``, run the check on ``channels``, close it; the
    drives' max torque (0x6072) is lowered to the pulse for the check and restored after."""
    out = out if out is not None else sys.stdout
    models = {c: model(params_file, c) for c in channels}
    findings: List[Finding] = []
    backend.open()
    saved: Dict[int, bytes] = {}
    try:
        backend.configure()
        amplitude = torque if torque else max(3.0 * models[c].dahl.coulomb_force
                                              for c in channels)
        for c in backend.ch:
            if backend.bus.coe[c.drive] and c.rated_torque:
                permille = min(0xFFFF, int(math.ceil(1.1e3 * amplitude / c.rated_torque)))
                port = backend.bus.port(c.drive)
                try:
                    saved[c.drive] = port.read(0x6072, 0)
                    port.write(0x6072, 0, permille.to_bytes(2, 'little'))
                    print(f'{c.cfg.name}: drive max torque 0x6072 = {permille} per mille '
                          f'({100 * amplitude / c.rated_torque:.1f} % of the rated '
                          f'{c.rated_torque:g} N m) during the check', file=out)
                except CoeError as exc:
                    print(f'{c.cfg.name}: drive max torque not lowered ({exc})', file=out)
        backend.activate()
        check = PowerOnCheck(backend, amplitude, pace)
        check.enable()
        for name in channels:
            i = backend.channels.index(name)
            rec = check.run(i)
            config = models[name]
            finding = judge(rec, name, amplitude, config.plant, config.dahl)
            if finding.passed:
                finding = tared(finding, *check.tare(i, config))
            findings.append(finding)
            check.enable(0.1)
    finally:
        try:
            if backend.state == 'active':
                backend.deactivate()
            for position, value in saved.items():
                try:
                    backend.bus.port(position).write(0x6072, 0, value)
                except CoeError:
                    pass
        finally:
            backend.close()
    return findings


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='first_power_on', description='First power-on check of each channel: sign and '
        'scale of motor and pressure, the pressure offset tared (docs/ethercat-hardware.md). '
        'Stop hardware_node first; the motors must be free.')
    parser.add_argument('--interface', required=True)
    parser.add_argument('--bus-config', required=True, help='the bus YAML')
    parser.add_argument('--params-file', help='the setup\'s params file (the model: m, k, '
                        'k_e, k_s, F_c, rest_position; default Table I)')
    parser.add_argument('--channels', default='', help='channels to check (default: every '
                        'channel of the bus YAML)')
    parser.add_argument('--torque', type=float, default=None, help='pulse amplitude [N m] '
                        '(default 3 F_c: enough to slide the endpoint\'s friction)')
    parser.add_argument('--output', default='pressure_offsets.yaml', help='params file the '
                        'offsets are written to (updated in place if it exists)')
    parser.add_argument('--drive-watchdog', type=float, default=0.1, help="the drives' "
                        "process-data watchdog [s], as hardware_node's drive_watchdog (run "
                        "the tool under chrt -f 40, as the node)")
    args = parser.parse_args(argv)
    try:
        config = BusConfig.load(args.bus_config)
        channels = [c for c in args.channels.split(',') if c] or [c.name for c in
                                                                  config.channels]
        backend = EthercatBackend(config, channels, args.interface, 5e-4,
                                  drive_watchdog=args.drive_watchdog)
        findings = check_bus(backend, channels, args.torque, args.params_file)
    except (EthercatError, ValueError) as exc:
        print(f'first_power_on: {exc}', file=sys.stderr)
        return 2
    for f in findings:
        print(f.report())
    if not all(f.passed for f in findings):
        print('first_power_on: not every channel passed: nothing written', file=sys.stderr)
        return 1
    try:
        path = write_offsets(args.output, findings)
    except EthercatError as exc:
        print(f'first_power_on: {exc}', file=sys.stderr)
        return 2
    print(f'pressure offsets written to {path}')
    return 0


def write_offsets(path: str, findings: Sequence[Finding]) -> Any:
    """``<channel>.pressure_offset`` of the channels that passed into the params file
    ``path`` (``/**: ros__parameters:``; an existing file updated in place)."""
    from ..core.errors import SeaforceError
    from ..identification.errors import IdentificationError
    from ..identification.output import write_values_file
    values = {}
    for f in findings:
        if f.passed:
            name = f'{f.channel}.pressure_offset'
            values[name] = ControllerConfig.spec('pressure_offset').check(round(f.offset, 6),
                                                                           name)
    try:
        return write_values_file(path, values, comments=[
            'pressure offsets from first_power_on (tared at rest, dithered)'], option='--output')
    except (SeaforceError, IdentificationError) as exc:
        raise EthercatError(str(exc)) from None


if __name__ == '__main__':
    sys.exit(main())

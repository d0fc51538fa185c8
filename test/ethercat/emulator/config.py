"""Emulator configuration: a dict (from JSON or YAML) -> :class:`~.bus.Bus`.

Format (every key optional except ``slaves``; integers may be written as ``"0x..."``)::

    cycle_time: 0.0005              # plant step per process-data frame [s]
    channels:                        # physics channels (created on demand with defaults)
      wrist: {seed: 1}
      pinch:
        environment: {mode: position_sine, amplitude: 0.5, frequency: 1.0}
        plant: {endpoint_damping: 0.03}     # overrides of Table I
        dahl: {sigma: 12.8, coulomb_force: 0.032, exponent: 1.0}   # null: no hysteresis
        pressure_noise: 5.0e-4             # [N m] std
        motor_coulomb: 0.0
        endpoint_coulomb: 0.0
        max_torque: .inf
    slaves:                          # bus order
      - {type: cia402_drive, name: wrist_drive, channel: wrist,
         vendor_id: 0x5EA0, product_code: 0x402, revision: 0x10000, serial: 1,
         rated_torque: 0.5, counts_per_rev: 1048576, max_torque_permille: 32767,
         profile: standard}          # cia402.PROFILES; these keys override a profile's:
      - {type: cia402_drive, name: pinch_drive, channel: pinch, serial: 2,
         profile: elmo_like, requires_dc: true, sync0_cycle_ns: 500000,
         required: [[0x60C2, 1, 5], [0x60C2, 2, -4]], controlword_period: 0.002,
         initial_mode: 8, mailbox_size: 128, complete_access: true, sync_error_limit: 4,
         dc: true}
      - {type: coupler, name: coupler, serial: 0}      # EK1100-like: no process data
      - type: analog_input
        name: pressure_terminal
        vendor_id: 2
        product_code: 0x0C1E3052
        revision: 0x00100000
        serial: 3
        block_lrw: false             # SII blockLRW flag (any slave): SOEM uses LWR + LRD
        inputs:                      # exactly 2; null = 0 V
          - {channel: wrist, quantity: pressure}
          - {channel: pinch, quantity: pressure,
             pressure: {area_m2: 5.0e-4, arm_m: 0.02, preload_pa: 5.0e5,
                        volts_per_pascal: 4.0e-6, volts_offset: 0.0}}
"""

import copy
import dataclasses
import json
import math
import pathlib

from seaforce_ros.core.params import DahlParams, PlantParams

from .analog import AnalogInputTerminal, DEFAULT_IDENTITY as ANALOG_IDENTITY
from .bus import Bus
from .cia402 import Cia402Drive, DEFAULT_IDENTITY as DRIVE_IDENTITY, PROFILES
from .coupler import Coupler, DEFAULT_IDENTITY as COUPLER_IDENTITY
from .physics import AnalogSource, ChannelConfig, Physics, PressureChain
from .sii import Identity


class ConfigError(ValueError):
    """The emulator configuration is invalid; the message names the key."""


DEFAULT_CONFIG = {
    "cycle_time": 0.0005,
    "channels": {"wrist": {"seed": 1}, "pinch": {"seed": 2}},
    "slaves": [
        {"type": "cia402_drive", "name": "wrist_drive", "channel": "wrist", "serial": 1},
        {"type": "cia402_drive", "name": "pinch_drive", "channel": "pinch", "serial": 2},
        {"type": "analog_input", "name": "pressure_terminal", "serial": 3,
         "inputs": [{"channel": "wrist", "quantity": "pressure"},
                    {"channel": "pinch", "quantity": "pressure"}]},
    ],
}


def default_config():
    """A fresh copy of the default bus: wrist drive, pinch drive, pressure terminal."""
    return copy.deepcopy(DEFAULT_CONFIG)


def load(path):
    """Read a JSON (``.json``) or YAML (anything else) configuration file."""
    path = pathlib.Path(path)
    text = path.read_text()
    if path.suffix == ".json":
        return json.loads(text)
    import yaml
    return yaml.safe_load(text)


def _int(value, key):
    if isinstance(value, bool):
        raise ConfigError("%s must be an integer, got %r" % (key, value))
    if isinstance(value, int):
        return value
    if isinstance(value, str):
        try:
            return int(value, 0)
        except ValueError:
            pass
    raise ConfigError("%s must be an integer (or '0x...'), got %r" % (key, value))


def _float(value, key):
    if isinstance(value, str):        # YAML 1.1 reads 5.0e5 (no exponent sign) as a string
        text = value.strip().lower()
        if text in (".inf", "+.inf"):
            return math.inf
        try:
            return float(text)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError("%s must be a number, got %r" % (key, value))
    return float(value)


def _identity(spec, default, key):
    return Identity(
        vendor_id=_int(spec.get("vendor_id", default.vendor_id), key + ".vendor_id"),
        product_code=_int(spec.get("product_code", default.product_code), key + ".product_code"),
        revision=_int(spec.get("revision", default.revision), key + ".revision"),
        serial=_int(spec.get("serial", default.serial), key + ".serial"))


def _dataclass_from(cls, values, key):
    if values is None:
        return None
    if not isinstance(values, dict):
        raise ConfigError("%s must be a mapping, got %r" % (key, values))
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(values) - names
    if unknown:
        raise ConfigError("%s: unknown keys %s (known: %s)"
                          % (key, ", ".join(sorted(unknown)), ", ".join(sorted(names))))
    return {k: _float(v, key + "." + k) for k, v in values.items()}


def _channel_config(values, key):
    values = dict(values or {})
    kwargs = {}
    plant = _dataclass_from(PlantParams, values.pop("plant", {}), key + ".plant")
    kwargs["plant"] = dataclasses.replace(PlantParams.table_i(), **plant)
    if "dahl" in values:
        dahl = _dataclass_from(DahlParams, values.pop("dahl"), key + ".dahl")
        kwargs["dahl"] = DahlParams(sigma=0.0) if dahl is None else DahlParams(**dahl)
    if "environment" in values:
        env = values.pop("environment")
        if env is not None and not isinstance(env, dict):
            raise ConfigError("%s.environment must be a mapping" % key)
        kwargs["environment"] = env
    for name in ("pressure_noise", "motor_coulomb", "endpoint_coulomb", "max_torque"):
        if name in values:
            kwargs[name] = _float(values.pop(name), key + "." + name)
    for name in ("seed", "endpoint_counts_per_rev"):
        if name in values:
            kwargs[name] = _int(values.pop(name), key + "." + name)
    if values:
        raise ConfigError("%s: unknown keys %s" % (key, ", ".join(sorted(values))))
    return ChannelConfig(**kwargs)


def _analog_source(spec, key):
    if spec is None:
        return None
    if not isinstance(spec, dict):
        raise ConfigError("%s must be a mapping or null" % key)
    spec = dict(spec)
    kwargs = {"channel": str(spec.pop("channel", "")),
              "quantity": str(spec.pop("quantity", "pressure"))}
    for name in ("volts_per_unit", "volts_offset"):
        if name in spec:
            kwargs[name] = _float(spec.pop(name), key + "." + name)
    if "pressure" in spec:
        p = _dataclass_from(PressureChain, spec.pop("pressure"), key + ".pressure")
        kwargs["pressure"] = PressureChain(**(p or {}))
    if spec:
        raise ConfigError("%s: unknown keys %s" % (key, ", ".join(sorted(spec))))
    if kwargs["quantity"] not in ("zero",) and not kwargs["channel"]:
        raise ConfigError("%s.channel is required for quantity %s" % (key, kwargs["quantity"]))
    try:
        return AnalogSource(**kwargs)
    except ValueError as exc:
        raise ConfigError("%s: %s" % (key, exc)) from None


#: drive keys that override the profile's fields (DriveProfile)
_PROFILE_INTS = ("initial_mode", "mailbox_size", "sync0_cycle_ns", "sync_error_limit")
_PROFILE_BOOLS = ("complete_access", "requires_dc", "dc", "sii_pdos")


def _profile(spec, key):
    """The drive's :class:`~.cia402.DriveProfile`: ``profile`` (a name) with the keys that
    override its fields."""
    name = spec.get("profile", "standard")
    if name not in PROFILES:
        raise ConfigError("%s.profile %r is not one of %s" % (key, name, ", ".join(PROFILES)))
    changes = {}
    for field_name in _PROFILE_INTS:
        if field_name in spec:
            changes[field_name] = _int(spec[field_name], key + "." + field_name)
    for field_name in _PROFILE_BOOLS:
        if field_name in spec:
            changes[field_name] = bool(spec[field_name])
    if "controlword_period" in spec:
        changes["controlword_period"] = _float(spec["controlword_period"],
                                               key + ".controlword_period")
    if "required" in spec:
        try:
            changes["required"] = {(_int(i, key + ".required"), _int(s, key + ".required")):
                                   _int(v, key + ".required") for i, s, v in spec["required"]}
        except (TypeError, ValueError):
            raise ConfigError("%s.required is a list of [index, subindex, value]" % key) from None
    if "mailbox_size" in changes and changes["mailbox_size"] not in (0,) and not (
            32 <= changes["mailbox_size"] <= 128):
        raise ConfigError("%s.mailbox_size must be 0 (none) or 32..128 bytes" % key)
    return dataclasses.replace(PROFILES[name], **changes)


def build(config, clock=None):
    """Build the :class:`~.bus.Bus` described by ``config`` (a dict).

    Raises
    ------
    ConfigError
        With the offending key in the message.
    """
    if not isinstance(config, dict) or not isinstance(config.get("slaves"), list) \
            or not config["slaves"]:
        raise ConfigError("the configuration needs a non-empty 'slaves' list")
    base_extra = {} if clock is None else {"clock": clock}
    cycle_time = _float(config.get("cycle_time", 0.0005), "cycle_time")
    if not cycle_time > 0:
        raise ConfigError("cycle_time must be > 0 s, got %r" % cycle_time)
    channel_specs = dict(config.get("channels") or {})
    slaves = []
    counts = {}
    names = set()
    for i, spec in enumerate(config["slaves"]):
        key = "slaves[%d]" % i
        if not isinstance(spec, dict):
            raise ConfigError("%s must be a mapping" % key)
        kind = spec.get("type")
        name = str(spec.get("name", "%s_%d" % (kind, i)))
        if name in names:
            raise ConfigError("%s.name %r is used twice" % (key, name))
        names.add(name)
        extra = dict(base_extra)
        if spec.get("block_lrw"):
            extra["block_lrw"] = True
        if kind == "cia402_drive":
            channel = spec.get("channel")
            if not channel:
                raise ConfigError("%s.channel is required for a cia402_drive" % key)
            cpr = _int(spec.get("counts_per_rev", 2 ** 20), key + ".counts_per_rev")
            counts[channel] = cpr
            channel_specs.setdefault(channel, {})
            profile = _profile(spec, key)
            default = dataclasses.replace(DRIVE_IDENTITY, product_code=profile.product_code)
            try:
                slave = Cia402Drive(
                    name, channel, identity=_identity(spec, default, key),
                    profile=profile,
                    rated_torque=(_float(spec["rated_torque"], key + ".rated_torque")
                                  if "rated_torque" in spec else None),
                    counts_per_rev=cpr,
                    max_torque_permille=(_int(spec["max_torque_permille"],
                                              key + ".max_torque_permille")
                                         if "max_torque_permille" in spec else None),
                    cycle_time=cycle_time, **extra)
            except ValueError as exc:
                raise ConfigError("%s: %s" % (key, exc)) from None
        elif kind == "coupler":
            slave = Coupler(name, identity=_identity(spec, COUPLER_IDENTITY, key), **extra)
        elif kind == "analog_input":
            inputs = spec.get("inputs", [None, None])
            if not isinstance(inputs, list) or len(inputs) != 2:
                raise ConfigError("%s.inputs must list exactly 2 channels" % key)
            sources = [_analog_source(s, "%s.inputs[%d]" % (key, j)) for j, s in enumerate(inputs)]
            for src in sources:
                if src is not None and src.channel:
                    channel_specs.setdefault(src.channel, {})
            slave = AnalogInputTerminal(name, sources,
                                        identity=_identity(spec, ANALOG_IDENTITY, key), **extra)
        else:
            raise ConfigError("%s.type must be cia402_drive, analog_input or coupler, got %r"
                              % (key, kind))
        slaves.append(slave)
    channels = {}
    for name, values in channel_specs.items():
        channels[name] = (_channel_config(values, "channels." + name), counts.get(name, 2 ** 20))
    physics = Physics(channels, cycle_time)
    if clock is None:
        return Bus(slaves, physics)
    return Bus(slaves, physics, clock=clock)

"""Emulator internals without a network: frames go straight into ``Bus.handle``.

A fake clock drives the watchdog, so no test depends on wall time.
"""

import math
import struct

import pytest

from ethercat.emulator import config as cfg
from ethercat.emulator import frames as F
from ethercat.emulator.analog import volts_to_counts
from ethercat.emulator.cia402 import (Cia402StateMachine, FAULT, OPERATION_ENABLED,
                                      QUICK_STOP_ACTIVE, READY_TO_SWITCH_ON, SWITCHED_ON,
                                      SWITCH_ON_DISABLED, FAULT_REACTION_ACTIVE)
from ethercat.emulator.physics import PressureChain
from ethercat.emulator.sii import CAT_GENERAL, CAT_RXPDO, CAT_SM, CAT_STRINGS, CAT_TXPDO, \
    parse_categories


class FakeClock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def legacy_config():
    """The default line with drives without a mailbox (their mapping fixed in the SII): the
    ESC-level tests below program SMs and FMMUs by hand, as SOEM does for such slaves."""
    config = cfg.default_config()
    for spec in config["slaves"]:
        if spec["type"] == "cia402_drive":
            spec["profile"] = "no_mailbox"
    return config


def make_bus(config=None):
    clock = FakeClock()
    return cfg.build(config or legacy_config(), clock=clock), clock


def send(bus, datagrams, index=3):
    """Serve one frame; returns ``[(data, wkc, adp)]`` per datagram of the reply."""
    payload = F.build_frame(datagrams, index)
    frame = bytearray(b"\xff" * 6 + b"\x01" * 6 + b"\x88\xa4") + payload
    n = bus.handle(frame, len(frame))
    assert n == len(frame)
    bus.after_frame()
    out = []
    for off, cmd, dlen in F.iter_datagrams(frame, 16, len(frame)):
        data = bytes(frame[off + 10: off + 10 + dlen])
        wkc = struct.unpack_from("<H", frame, off + 10 + dlen)[0]
        adp = struct.unpack_from("<H", frame, off + 2)[0]
        assert frame[off + 1] == index
        out.append((data, wkc, adp))
    return out


def u16(v):
    return struct.pack("<H", v)


def configure_addresses(bus):
    for i in range(len(bus.slaves)):
        send(bus, [(F.APWR, (-i) & 0xFFFF, 0x0010, u16(0x1001 + i))])


def program_default_map(bus):
    """What SOEM's config_map programs for the default bus (its SM and FMMU writes)."""
    log = 0
    for i in (0, 1):                                     # drive outputs
        send(bus, [(F.FPWR, 0x1001 + i, 0x0810, struct.pack("<HHBBBB", 0x1100, 5, 0x64, 0, 1, 0)),
                   (F.FPWR, 0x1001 + i, 0x0600, struct.pack("<IHBBHBBB3x", log, 5, 0, 7, 0x1100, 0, 2, 1))])
        log += 5
    for i, n in ((0, 13), (1, 13), (2, 8)):               # inputs
        send(bus, [(F.FPWR, 0x1001 + i, 0x0818, struct.pack("<HHBBBB", 0x1180, n, 0x20, 0, 1, 0)),
                   (F.FPWR, 0x1001 + i, 0x0610 if i < 2 else 0x0600,
                    struct.pack("<IHBBHBBB3x", log, n, 0, 7, 0x1180, 0, 1, 1))])
        log += n
    return log


def al_request(bus, value, station=None):
    if station is None:
        return send(bus, [(F.BWR, 0, 0x0120, u16(value))])
    return send(bus, [(F.FPWR, station, 0x0120, u16(value))])


def al_status(bus, station):
    (data, wkc, _), = send(bus, [(F.FPRD, station, 0x0130, bytes(6))])
    status, _, code = struct.unpack("<HHH", data)
    return status, code


# --- SII -------------------------------------------------------------------------------------

def test_sii_image_has_identity_and_categories():
    bus, _ = make_bus()
    drive, term = bus.slaves[0], bus.slaves[2]
    img = drive.sii
    assert len(img) < 4096 and len(img) % 2 == 0
    assert struct.unpack_from("<IIII", img, 0x08 * 2) == (0x5EA0, 0x402, 0x10000, 1)
    assert struct.unpack_from("<5H", img, 0x18 * 2) == (0, 0, 0, 0, 0)   # no mailbox
    cats = parse_categories(img)
    assert set(cats) >= {CAT_STRINGS, CAT_GENERAL, CAT_SM, CAT_RXPDO, CAT_TXPDO}
    assert len(cats[CAT_GENERAL]) == 32
    strings = cats[CAT_STRINGS]
    assert strings[2:2 + strings[1]].decode() == drive.sii_spec.name
    sm = [struct.unpack_from("<HHBBBB", cats[CAT_SM], 8 * i) for i in range(4)]
    assert sm[2] == (0x1100, 0, 0x64, 0, 1, 3) and sm[3] == (0x1180, 0, 0x20, 0, 1, 4)

    def pdo_bits(cat):
        bits, off = {}, 0
        while off < len(cat):
            index, n, smn = struct.unpack_from("<HBB", cat, off)
            off += 8
            total = sum(cat[off + 8 * k + 5] for k in range(n))
            off += 8 * n
            bits[smn] = bits.get(smn, 0) + total
        return bits

    assert pdo_bits(cats[CAT_RXPDO]) == {2: 40}
    assert pdo_bits(cats[CAT_TXPDO]) == {3: 104}
    assert pdo_bits(parse_categories(term.sii)[CAT_TXPDO]) == {3: 64}
    assert CAT_RXPDO not in parse_categories(term.sii)


def test_eeprom_reads_through_registers_and_identity_change():
    bus, _ = make_bus()
    configure_addresses(bus)
    send(bus, [(F.FPWR, 0x1002, 0x0502, bytes((0x00, 0x01, 0x0A, 0x00, 0, 0)))])
    (data, wkc, _), = send(bus, [(F.FPRD, 0x1002, 0x0508, bytes(8))])
    assert wkc == 1 and struct.unpack("<II", data) == (0x402, 0x10000)
    (status, wkc, _), = send(bus, [(F.FPRD, 0x1002, 0x0502, bytes(2))])
    assert struct.unpack("<H", status)[0] & 0xF800 == 0          # not busy, no error
    bus.slave("pinch_drive").set_identity(product_code=0xBAD)
    send(bus, [(F.FPWR, 0x1002, 0x0502, bytes((0x00, 0x01, 0x0A, 0x00, 0, 0)))])
    (data, _, _), = send(bus, [(F.FPRD, 0x1002, 0x0508, bytes(4))])
    assert struct.unpack("<I", data)[0] == 0xBAD
    # past the end of the image: 0xFF
    send(bus, [(F.FPWR, 0x1002, 0x0502, bytes((0x00, 0x01, 0xF0, 0x07, 0, 0)))])
    (data, _, _), = send(bus, [(F.FPRD, 0x1002, 0x0508, bytes(4))])
    assert data == b"\xff" * 4


# --- addressing and working counters ---------------------------------------------------------

def test_working_counters_and_addressing():
    bus, _ = make_bus()
    (data, wkc, adp), = send(bus, [(F.BRD, 0, 0x0000, bytes(2))])
    assert wkc == 3 and adp == 3                                # slave count, ADP + 1 each
    configure_addresses(bus)
    assert [s.station_address for s in bus.slaves] == [0x1001, 0x1002, 0x1003]
    (data, wkc, adp), = send(bus, [(F.APRD, 0xFFFE, 0x0010, bytes(2))])
    assert wkc == 1 and struct.unpack("<H", data)[0] == 0x1003 and adp == 1
    (data, wkc, _), = send(bus, [(F.FPRD, 0x1002, 0x0010, bytes(2))])
    assert wkc == 1 and struct.unpack("<H", data)[0] == 0x1002
    (_, wkc, _), = send(bus, [(F.FPRD, 0x7777, 0x0010, bytes(2))])
    assert wkc == 0
    (_, wkc, _), = send(bus, [(F.FPRW, 0x1001, 0x0012, u16(5))])
    assert wkc == 3
    # BRD ORs the slaves' registers: DL status port 1 communicating on all but the last
    (data, _, _), = send(bus, [(F.BRD, 0, 0x0110, bytes(2))])
    dl = [struct.unpack("<H", send(bus, [(F.FPRD, 0x1001 + i, 0x0110, bytes(2))])[0][0])[0]
          for i in range(3)]
    assert [d & 0x0300 for d in dl] == [0x0200] * 3
    assert [d & 0x0C00 for d in dl] == [0x0800, 0x0800, 0x0400]
    assert struct.unpack("<H", data)[0] == dl[0] | dl[1] | dl[2]
    # read-only registers ignore writes
    send(bus, [(F.FPWR, 0x1001, 0x0130, u16(8))])
    assert al_status(bus, 0x1001)[0] == 1
    # several datagrams in one frame, each with its own WKC
    replies = send(bus, [(F.FPRD, 0x1001 + i, 0x0130, bytes(6)) for i in range(3)])
    assert [r[1] for r in replies] == [1, 1, 1]


def test_process_data_wkc_and_fmmu_copy():
    bus, _ = make_bus()
    configure_addresses(bus)
    iomap = program_default_map(bus)
    assert iomap == 44
    # PRE-OP: process data SMs are not served -> WKC 0
    al_request(bus, 0x12)
    (_, wkc, _), = send(bus, [(F.LRW, 0, None, bytes(iomap))])
    assert wkc == 0
    al_request(bus, 0x04)
    assert [al_status(bus, 0x1001 + i) for i in range(3)] == [(4, 0)] * 3
    out = struct.pack("<Hhb", 0x1234, -5, 10) + struct.pack("<Hhb", 0x0006, 7, 9)
    # SAFE-OP: inputs served, outputs not taken (the output SM stays deactivated)
    (data, wkc, _), = send(bus, [(F.LRW, 0, None, out + bytes(iomap - 10))])
    assert wkc == 3                                             # 2 drives + terminal, reads
    assert bytes(bus.slaves[0].mem[0x1100:0x1105]) == bytes(5)
    al_request(bus, 0x08)
    (data, wkc, _), = send(bus, [(F.LRW, 0, None, out + bytes(iomap - 10))])
    assert wkc == 7                                             # 2 x 3 + 1
    assert data[:10] == out                                     # outputs pass unchanged
    d0 = bus.slaves[0].mem[0x1100:0x1105]
    assert bytes(d0) == out[:5]
    sw, pos, vel, torque, mode = struct.unpack_from("<Hiihb", data, 10)
    assert sw & 0x4F == 0x40                                    # switch on disabled
    # LRD / LWR count 1 per slave
    (_, wkc, _), = send(bus, [(F.LRD, 10, None, bytes(34))])
    assert wkc == 3
    (_, wkc, _), = send(bus, [(F.LWR, 0, None, bytes(10))])
    assert wkc == 2
    # a window over only the terminal's inputs (what it holds before the frame's step)
    before = bus.slaves[2].values[0]
    (data, wkc, _), = send(bus, [(F.LRW, 36, None, bytes(8))])
    assert wkc == 1
    status, value = struct.unpack_from("<Hh", data, 0)
    assert value == before


def test_physics_steps_once_per_process_frame():
    bus, _ = make_bus()
    configure_addresses(bus)
    program_default_map(bus)
    al_request(bus, 0x12)
    al_request(bus, 0x04)
    for _ in range(5):
        send(bus, [(F.LRW, 0, None, bytes(44))])
    send(bus, [(F.FPRD, 0x1001, 0x0130, bytes(2))])            # not process data
    assert bus.physics.steps == 5
    assert bus.physics.channel("wrist").sim.step_count == 5


# --- AL state machine ------------------------------------------------------------------------

def test_al_state_machine_policy():
    bus, _ = make_bus()
    configure_addresses(bus)
    al_request(bus, 0x08, 0x1001)                               # INIT -> OP: invalid
    assert al_status(bus, 0x1001) == (0x11, 0x0011)
    al_request(bus, 0x02, 0x1001)                               # no ack: higher state ignored
    assert al_status(bus, 0x1001) == (0x11, 0x0011)
    al_request(bus, 0x11, 0x1001)                               # ack clears error
    assert al_status(bus, 0x1001) == (0x01, 0)
    al_request(bus, 0x03, 0x1001)                               # BOOT unsupported
    assert al_status(bus, 0x1001) == (0x11, 0x0013)
    al_request(bus, 0x12, 0x1001)
    assert al_status(bus, 0x1001) == (0x02, 0)
    al_request(bus, 0x07, 0x1001)                               # unknown state
    assert al_status(bus, 0x1001) == (0x12, 0x0012)
    al_request(bus, 0x01, 0x1001)                               # down without ack: allowed
    assert al_status(bus, 0x1001) == (0x11, 0x0012)
    hist = [h["value"] for h in bus.al_history if h["slave"] == "wrist_drive"]
    assert hist == [0x08, 0x02, 0x11, 0x03, 0x12, 0x07, 0x01]
    assert bus.slaves[0].last_al_request == 0x01


@pytest.mark.parametrize("sm, bad, code", [
    (2, struct.pack("<HHBBBB", 0x1100, 4, 0x64, 0, 1, 0), 0x001D),    # wrong output length
    (2, struct.pack("<HHBBBB", 0x1100, 5, 0x64, 0, 0, 0), 0x001D),    # outputs disabled
    (3, struct.pack("<HHBBBB", 0x1200, 13, 0x20, 0, 1, 0), 0x001E),   # wrong input start
])
def test_safeop_rejects_bad_sync_manager(sm, bad, code):
    bus, _ = make_bus()
    configure_addresses(bus)
    program_default_map(bus)
    al_request(bus, 0x12)
    send(bus, [(F.FPWR, 0x1001, 0x0800 + 8 * sm, bad)])
    al_request(bus, 0x04)
    assert al_status(bus, 0x1001) == (0x12, code)
    assert al_status(bus, 0x1002) == (0x04, 0)


# --- watchdog ---------------------------------------------------------------------------------

def _bus_in_op():
    bus, clock = make_bus()
    configure_addresses(bus)
    program_default_map(bus)
    for v in (0x12, 0x04, 0x08):
        al_request(bus, v)
    return bus, clock


def _pd(bus, cw=0, torque=0, mode=10):
    out = struct.pack("<Hhb", cw, torque, mode) * 2
    (data, wkc, _), = send(bus, [(F.LRW, 0, None, out + bytes(34))])
    return struct.unpack_from("<Hiihb", data, 10), wkc


def test_watchdog_expires_after_100_ms_without_process_data():
    bus, clock = _bus_in_op()
    for cw in (6, 7, 15, 15):
        _pd(bus, cw, 400)
    drive = bus.slaves[0]
    assert drive.sm402.state == OPERATION_ENABLED and drive.torque_command() == pytest.approx(0.2)
    assert drive.watchdog_time() == pytest.approx(0.1)
    clock.t += 0.0999
    bus.poll()
    assert drive.al_state == 8 and drive.watchdog_expiries == 0
    _pd(bus, 15, 400)                                           # feeds the watchdog
    clock.t += 0.0999
    bus.poll()
    assert drive.watchdog_expiries == 0
    clock.t += 0.0002
    bus.poll()
    assert drive.watchdog_expiries == 1
    assert (drive.al_state, drive.al_error, drive.al_code) == (4, True, 0x001B)
    assert drive.torque_command() == 0.0
    assert drive.sm402.state == FAULT
    # the terminal has no watchdog-triggered SM: stays in OP
    assert bus.slaves[2].al_state == 8
    (sw, _, _, torque, _), wkc = _pd(bus, 15, 400)
    assert sw & 0x4F == 0x08 and torque == 0
    # pysoem-style recovery: SAFE-OP + ack, OP, fault reset, enable
    al_request(bus, 0x14, 0x1001)
    al_request(bus, 0x08, 0x1001)
    assert al_status(bus, 0x1001) == (8, 0)
    for cw in (0x80, 6, 7, 15, 15):
        (sw, _, _, torque, _), _ = _pd(bus, cw, 400)
    assert sw & 0x6F == 0x27 and torque == 400


def test_watchdog_time_follows_registers():
    bus, clock = _bus_in_op()
    send(bus, [(F.FPWR, 0x1001, 0x0420, u16(250))])              # 25 ms
    drive = bus.slaves[0]
    assert drive.watchdog_time() == pytest.approx(0.025)
    clock.t += 0.0251
    bus.poll()
    assert drive.watchdog_expiries == 1
    send(bus, [(F.FPWR, 0x1002, 0x0420, u16(0))])                # 0 disables it
    clock.t += 10.0
    bus.poll()
    assert bus.slaves[1].watchdog_expiries == 0


# --- CiA 402 -----------------------------------------------------------------------------------

@pytest.mark.parametrize("start, commands, end", [
    (SWITCH_ON_DISABLED, [0x06], READY_TO_SWITCH_ON),
    (SWITCH_ON_DISABLED, [0x07], SWITCH_ON_DISABLED),           # switch on needs shutdown first
    (SWITCH_ON_DISABLED, [0x0F], SWITCH_ON_DISABLED),
    (SWITCH_ON_DISABLED, [0x06, 0x07], SWITCHED_ON),
    (SWITCH_ON_DISABLED, [0x06, 0x0F], OPERATION_ENABLED),      # 3 + 4
    (SWITCH_ON_DISABLED, [0x06, 0x07, 0x0F], OPERATION_ENABLED),
    (OPERATION_ENABLED, [0x07], SWITCHED_ON),                   # 5
    (OPERATION_ENABLED, [0x06], READY_TO_SWITCH_ON),            # 8
    (OPERATION_ENABLED, [0x00], SWITCH_ON_DISABLED),            # 9
    (OPERATION_ENABLED, [0x02], QUICK_STOP_ACTIVE),             # 11
    (OPERATION_ENABLED, [0x02, 0x0F], OPERATION_ENABLED),       # 16
    (OPERATION_ENABLED, [0x02, 0x00], SWITCH_ON_DISABLED),      # 12
    (OPERATION_ENABLED, [0x02, 0x06], QUICK_STOP_ACTIVE),
    (SWITCHED_ON, [0x06], READY_TO_SWITCH_ON),                  # 6
    (SWITCHED_ON, [0x02], SWITCH_ON_DISABLED),                  # 10
    (READY_TO_SWITCH_ON, [0x00], SWITCH_ON_DISABLED),           # 7
    (OPERATION_ENABLED, [0x8F], OPERATION_ENABLED),             # bit 7 outside fault: no command
])
def test_cia402_transitions(start, commands, end):
    sm = Cia402StateMachine()
    path = {SWITCH_ON_DISABLED: [], READY_TO_SWITCH_ON: [6], SWITCHED_ON: [6, 7],
            OPERATION_ENABLED: [6, 7, 15]}[start]
    for cw in path + commands:
        sm.update(cw)
    assert sm.state == end


def test_cia402_fault_and_reset():
    sm = Cia402StateMachine()
    for cw in (6, 7, 15):
        sm.update(cw)
    sm.fault(0x5400, "test", latched=True)
    assert sm.state == FAULT_REACTION_ACTIVE and sm.statusword() & 0x4F == 0x0F
    sm.update(15)
    assert sm.state == FAULT and sm.statusword() & 0x4F == 0x08
    sm.update(0x80)                                             # latched: refused
    assert sm.state == FAULT
    sm.clear_latch()
    sm.update(0x80)                                             # still high: no edge
    assert sm.state == FAULT
    sm.update(0x00)
    sm.update(0x80)
    assert sm.state == SWITCH_ON_DISABLED and sm.fault_code == 0
    assert sm.statusword() == 0x0250


def test_cia402_statusword_examples():
    sm = Cia402StateMachine()
    assert sm.statusword() == 0x0250
    sm.update(6)
    assert sm.statusword() == 0x0231
    sm.update(7)
    assert sm.statusword() == 0x0233
    sm.update(15)
    assert sm.statusword() == 0x0237
    sm.update(2)
    assert sm.statusword() == 0x0217


def test_torque_only_in_operation_enabled_cst_and_op():
    bus, _ = _bus_in_op()
    drive = bus.slaves[0]
    _pd(bus, 6, 500)
    _pd(bus, 7, 500)
    assert drive.torque_command() == 0.0
    _pd(bus, 15, 500, mode=8)                                   # CSP: no torque
    assert drive.sm402.state == OPERATION_ENABLED and drive.torque_command() == 0.0
    (sw, _, _, torque, mode), _ = _pd(bus, 15, 500, mode=10)
    assert drive.torque_command() == pytest.approx(0.25)
    (sw, _, _, torque, mode), _ = _pd(bus, 15, 500, mode=10)
    assert torque == 500 and mode == 10 and sw & 0x1000
    al_request(bus, 0x04, 0x1001)                               # leaving OP while enabled
    assert drive.torque_command() == 0.0 and drive.sm402.state in (FAULT_REACTION_ACTIVE, FAULT)


# --- scalings ---------------------------------------------------------------------------------

def test_pressure_chain_and_adc():
    chain = PressureChain()
    assert chain.pressure(0.0) == pytest.approx(0.5e6)
    assert chain.volts(0.0) == pytest.approx(2.0)
    assert chain.volts(1.0) == pytest.approx(2.4)              # 1 N m = 0.1 MPa = 0.4 V
    for f in (-4.0, -0.3, 0.0, 0.7, 12.0):
        assert chain.force_from_volts(chain.volts(f)) == pytest.approx(f)
    assert volts_to_counts(2.0) == (6553, 0)
    assert volts_to_counts(10.0) == (32767, 0)
    assert volts_to_counts(10.1) == (32767, 0x0042)            # overrange + error
    assert volts_to_counts(-10.1) == (-32767, 0x0041)


def test_drive_inputs_scale_plant_state():
    config = legacy_config()
    config["channels"]["wrist"]["pressure_noise"] = 0.0
    bus, _ = make_bus(config)
    configure_addresses(bus)
    program_default_map(bus)
    for v in (0x12, 0x04, 0x08):
        al_request(bus, v)
    for cw in (6, 7, 15):
        _pd(bus, cw, 1000)
    for _ in range(200):
        (sw, pos, vel, torque, mode), _ = _pd(bus, 15, 1000)
    ch = bus.physics.channel("wrist")
    m = ch.measurement
    # the inputs read by a frame are those of the previous step: compare with the drive's
    # latest image instead
    sw, pos, vel, torque, mode = struct.unpack_from("<Hiihb", bus.slaves[0].mem, 0x1180)
    assert pos == round(m.x / (2 * math.pi) * 2 ** 20) and pos > 0
    assert vel == round(m.v / (2 * math.pi) * 2 ** 20)
    assert torque == 1000 and ch.torque == pytest.approx(0.5)
    status, value = struct.unpack_from("<Hh", bus.slaves[2].mem, 0x1180)
    assert value == round(PressureChain().volts(m.f_p) * 3276.7)
    assert m.f_p < 0                                            # motor pushed ahead of the endpoint


def test_config_errors_name_the_key():
    bad = cfg.default_config()
    bad["slaves"][0]["product_code"] = "zero"
    with pytest.raises(cfg.ConfigError, match=r"slaves\[0\]\.product_code"):
        cfg.build(bad)
    bad = cfg.default_config()
    bad["slaves"][2]["inputs"][1]["quantity"] = "temperature"
    with pytest.raises(cfg.ConfigError, match=r"slaves\[2\]\.inputs\[1\]"):
        cfg.build(bad)
    bad = cfg.default_config()
    bad["channels"]["wrist"]["plant"] = {"motor_mass": 1.0}
    with pytest.raises(cfg.ConfigError, match="channels.wrist.plant"):
        cfg.build(bad)


def test_documented_yaml_example_builds(tmp_path):
    text = cfg.__doc__.split("Format")[1].split("::", 1)[1]
    path = tmp_path / "bus.yaml"
    path.write_text(text)
    bus = cfg.build(cfg.load(path))
    assert [s.name for s in bus.slaves] == ["wrist_drive", "pinch_drive", "coupler",
                                            "pressure_terminal"]
    assert bus.physics.channel("pinch").sim.environment.mode == "position_sine"
    assert bus.slaves[3].identity.product_code == 0x0C1E3052
    pinch = bus.slaves[1]
    assert pinch.profile.name == "elmo_like" and pinch.profile.requires_dc
    assert pinch.profile.required == {(0x60C2, 1): 5, (0x60C2, 2): -4}
    assert bus.slaves[2].kind == "coupler"

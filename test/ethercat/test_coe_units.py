"""The emulator's CoE, drive profiles and distributed clocks without a network: requests built
byte by byte as ETG.1000.6 / CiA 301 write them (the oracle), answered by the emulator's SDO
server, mailbox and ESC. SOEM's own client is the judge in test_coe_soem.py."""

import struct

import pytest

from ethercat.emulator import config as cfg
from ethercat.emulator import frames as F
from ethercat.emulator import coe as C
from ethercat.emulator.cia402 import (FAULT, OPERATION_ENABLED, PROFILES, SWITCH_ON_DISABLED,
                                      mapping_of, od_value)
from ethercat.emulator.esc import (AL_CODE_INVALID_DC_SYNC_CONFIG, AL_CODE_INVALID_MAILBOX_CONFIG,
                                   AL_CODE_INVALID_SYNC_CYCLE_TIME, AL_CODE_SYNC_ERROR)
from ethercat.emulator.sii import CAT_SM, parse_categories

from .test_emulator_units import FakeClock, send, u16


def line(*profiles, clock=None, **drive_keys):
    """A line of one drive per profile (channel c0, c1, ...) plus a coupler."""
    config = {"cycle_time": 0.0005, "slaves": [
        dict({"type": "cia402_drive", "name": "d%d" % i, "channel": "c%d" % i,
              "profile": p, "serial": i + 1}, **drive_keys) for i, p in enumerate(profiles)]}
    config["slaves"].append({"type": "coupler", "name": "coupler"})
    clock = clock or FakeClock()
    return cfg.build(config, clock=clock), clock


def preop(bus):
    """Addresses, the mailbox SMs from each SII, PRE-OP (what SOEM's config_init does)."""
    for i, s in enumerate(bus.slaves):
        send(bus, [(F.APWR, (-i) & 0xFFFF, 0x0010, u16(0x1001 + i))])
        if s.sii_spec.mailbox:
            rx, rx_n, tx, tx_n = s.sii_spec.mailbox
            send(bus, [(F.FPWR, 0x1001 + i, 0x0800, struct.pack(
                "<HHBBBBHHBBBB", rx, rx_n, 0x26, 0, 1, 0, tx, tx_n, 0x22, 0, 1, 0))])
        send(bus, [(F.FPWR, 0x1001 + i, 0x0120, u16(0x12))])
    assert [s.al_state for s in bus.slaves] == [2] * len(bus.slaves)


def request(cmd, index, sub, data=b"\0\0\0\0"):
    """A CoE SDO request (CoE header: service 2 = SDO request)."""
    return struct.pack("<HBHB", 0x2000, cmd, index, sub) + data


def reply(body):
    """(CoE service, command, index, subindex, data) of a reply."""
    service = struct.unpack_from("<H", body)[0] >> 12
    if len(body) < 6:
        return service, body[2], None, None, b""
    cmd, index, sub = struct.unpack_from("<BHB", body, 2)
    return service, cmd, index, sub, bytes(body[6:])


# --- SDO services ----------------------------------------------------------------------------------

def test_expedited_upload_gives_the_size_in_the_command():
    bus, _ = line("standard")
    preop(bus)
    d = bus.slaves[0]
    for index, cmd, value in ((0x6061, 0x4F, b"\x00"), (0x6041, 0x4B, None),
                              (0x6076, 0x43, struct.pack("<I", 500))):
        service, got, i, s, data = reply(d.sdo.handle(request(0x40, index, 0)))
        assert (service, got, i, s) == (3, cmd, index, 0)
        if value is not None:
            assert data[:len(value)] == value


def test_normal_and_segmented_upload_of_a_long_object():
    bus, _ = line("ingenia_like")               # 48-byte mailbox: 32 data bytes per reply
    preop(bus)
    d = bus.slaves[0]
    name = PROFILES["ingenia_like"].device_name.encode()
    service, cmd, index, sub, data = reply(d.sdo.handle(request(0x40, 0x1008, 0)))
    assert (service, cmd, index) == (3, 0x41, 0x1008)           # normal, size indicated
    size = struct.unpack_from("<I", data)[0]
    assert size == len(name) and data[4:] == name[:32]
    got, toggle = bytearray(data[4:]), 0
    while True:
        body = d.sdo.handle(struct.pack("<HB", 0x2000, 0x60 | toggle) + bytes(7))
        cmd = body[2]
        assert cmd & 0xE0 == 0x00 and cmd & 0x10 == toggle        # the toggle echoed
        chunk = body[3:]
        if cmd & 0x01:
            got += chunk[:7 - ((cmd >> 1) & 7)] if len(chunk) == 7 else chunk
            break
        got += chunk
        toggle ^= 0x10
    assert bytes(got) == name


def test_a_segment_with_the_wrong_toggle_is_aborted():
    bus, _ = line("ingenia_like")
    preop(bus)
    d = bus.slaves[0]
    d.sdo.handle(request(0x40, 0x1008, 0))
    service, cmd, _, _, data = reply(d.sdo.handle(struct.pack("<HB", 0x2000, 0x70) + bytes(7)))
    assert (service, cmd) == (2, 0x80)                 # abort: CoE service "SDO request"
    assert struct.unpack_from("<I", data)[0] == C.ABORT_TOGGLE


@pytest.mark.parametrize("index,sub,cmd,data,code", [
    (0x6060, 0, 0x2F, b"\x05\0\0\0", C.ABORT_VALUE_RANGE),     # mode 5: not supported
    (0x6041, 0, 0x2B, b"\x00\0\0\0", C.ABORT_READ_ONLY),
    (0x2000, 0, 0x2B, b"\x00\0\0\0", C.ABORT_NO_OBJECT),
    (0x1018, 9, 0x40, b"\0\0\0\0", C.ABORT_NO_SUBINDEX),
    (0x60C2, 2, 0x2F, b"\x05\0\0\0", C.ABORT_VALUE_HIGH),       # index > 0
    (0x6076, 0, 0x2B, b"\x00\0\0\0", C.ABORT_TOO_SHORT),        # 2 bytes into a u32
])
def test_downloads_and_uploads_refused_with_their_abort_code(index, sub, cmd, data, code):
    bus, _ = line("standard")
    preop(bus)
    service, got, i, s, payload = reply(bus.slaves[0].sdo.handle(request(cmd, index, sub, data)))
    assert (service, got, i, s) == (2, 0x80, index, sub)
    assert struct.unpack_from("<I", payload)[0] == code


def test_complete_access_upload_and_segmented_download_of_a_mapping():
    bus, _ = line("ingenia_like")
    preop(bus)
    d = bus.slaves[0]
    entries = [0x60410010, 0x60640020, 0x606C0020, 0x60770010, 0x60610008, 0x603F0010]
    # a normal initiate with complete access (0x31) carries the size and up to 48 - 16 = 32
    # bytes: six entries (26 bytes) fit, eight (34) need a segment
    data = struct.pack("<Bx6I", 6, *entries)
    service, cmd, *_ = reply(d.sdo.handle(request(0x31, 0x1A00, 0,
                                                  struct.pack("<I", len(data)) + data)))
    assert (service, cmd) == (3, 0x70)
    assert [e for _, e in mapping_of(d, "tx")] == []            # nothing assigned yet
    assert d.od.mapping(0x1A00) == [(0x6041, 0, 16), (0x6064, 0, 32), (0x606C, 0, 32),
                                    (0x6077, 0, 16), (0x6061, 0, 8), (0x603F, 0, 16)]
    # eight entries: 34 bytes, more than one 48-byte mailbox carries after the initiate
    eight = entries + [0x60FD0020, 0x10010008]
    data = struct.pack("<Bx8I", 8, *eight)
    first = data[:32]
    service, cmd, *_ = reply(d.sdo.handle(request(0x31, 0x1A01, 0,
                                                  struct.pack("<I", len(data)) + first)))
    assert (service, cmd) == (3, 0x70)
    rest = data[32:]                                             # 2 bytes: a short last segment
    body = d.sdo.handle(struct.pack("<HB", 0x2000, 0x01 | ((7 - len(rest)) << 1))
                        + rest + bytes(7 - len(rest)))
    assert body[2] == 0x20                                       # download segment response
    assert [v for _, _, v in d.od.mapping(0x1A01)] == [16, 32, 32, 16, 8, 16, 32, 8]
    service, cmd, _, _, up = reply(d.sdo.handle(request(0x50, 0x1A01, 0)))
    assert (service, cmd & 0xF0) == (3, 0x50)                    # normal, complete access
    assert struct.unpack_from("<I", up)[0] == len(data) and up[4:] == data[:32]


def test_mapping_rules_of_coe():
    bus, _ = line("standard")
    preop(bus)
    d = bus.slaves[0]

    def code(cmd, index, sub, value):
        service, got, *_, payload = reply(d.sdo.handle(request(cmd, index, sub, value)))
        return struct.unpack_from("<I", payload)[0] if got == 0x80 else 0

    assert code(0x2F, 0x1600, 0, b"\0\0\0\0") == C.ABORT_DEVICE_STATE  # assigned: no change
    assert code(0x2F, 0x1C12, 0, b"\0\0\0\0") == 0                  # unassigned
    assert code(0x23, 0x1600, 1, struct.pack("<I", 0x60400010)) == C.ABORT_SI0_NOT_ZERO
    assert code(0x2F, 0x1600, 0, b"\0\0\0\0") == 0                  # now it may change
    assert code(0x23, 0x1600, 1, struct.pack("<I", 0x60410010)) == 0
    assert code(0x2F, 0x1600, 0, b"\1\0\0\0") == C.ABORT_NOT_MAPPABLE   # statusword: a TxPDO's
    assert code(0x23, 0x1600, 1, struct.pack("<I", 0x60710020)) == 0
    assert code(0x2F, 0x1600, 0, b"\1\0\0\0") == C.ABORT_INCOMPATIBLE   # 0x6071 is 16 bits
    assert code(0x2B, 0x1C12, 1, struct.pack("<HH", 0x1A00, 0)) == C.ABORT_VALUE_RANGE
    bus, _ = line("standard")                           # mapping objects in SAFE-OP
    preop(bus)
    _to_safeop(bus)
    d = bus.slaves[0]
    assert d.al_state == 4
    assert code(0x2F, 0x1C12, 0, b"\0\0\0\0") == C.ABORT_DEVICE_STATE


def test_mailbox_handshake_retry_and_repeat_over_frames():
    bus, _ = line("standard")
    preop(bus)
    d = bus.slaves[0]
    rx, size, tx, _ = d.sii_spec.mailbox

    def put(message):
        send(bus, [(F.FPWR, 0x1001, rx, message.ljust(size, b"\0"))])

    def status():
        return send(bus, [(F.FPRD, 0x1001, 0x080D, bytes(2))])[0][0]

    counter = 3
    message = struct.pack("<HHBB", 10, 0, 0, 0x03 | counter << 4) + request(0x40, 0x6076, 0)
    put(message)
    assert status()[0] & 0x08                                   # SM1 full
    (data, wkc, _), = send(bus, [(F.FPRD, 0x1001, tx, bytes(size))])
    assert wkc == 1 and data[5] & 0x0F == 0x03
    assert struct.unpack_from("<I", data, 6 + 6)[0] == 500
    assert not status()[0] & 0x08                               # read: empty again
    requests = d.sdo.requests
    put(message)                                                # the same counter: a retry
    assert d.sdo.requests == requests                           # answered, not executed again
    (again, _, _), = send(bus, [(F.FPRD, 0x1001, tx, bytes(size))])
    assert again[6:] == data[6:]
    # the master lost that read: it toggles the repeat bit, the slave puts it back and acks
    send(bus, [(F.FPWR, 0x1001, 0x080E, bytes([status()[1] ^ 0x02]))])
    assert status()[0] & 0x08
    pdi = send(bus, [(F.FPRD, 0x1001, 0x080F, bytes(1))])[0][0][0]
    assert pdi & 0x02 == d.mem[0x080E] & 0x02 == 0x02


def test_mailbox_refused_when_sm0_is_not_the_sii_s():
    bus, _ = line("standard")
    send(bus, [(F.APWR, 0, 0x0010, u16(0x1001))])
    send(bus, [(F.FPWR, 0x1001, 0x0800, struct.pack("<HHBBBB", 0x1000, 64, 0x26, 0, 1, 0))])
    send(bus, [(F.FPWR, 0x1001, 0x0120, u16(0x12))])
    assert bus.slaves[0].al_state == 1 and bus.slaves[0].al_code == AL_CODE_INVALID_MAILBOX_CONFIG


# --- drives ---------------------------------------------------------------------------------------

def test_profiles_power_up_as_the_drives_they_stand_for():
    bus, _ = line("standard", "elmo_like", "ingenia_like", "csp_start")
    std, elmo, ingenia, csp = bus.slaves[:4]
    assert mapping_of(std, "rx")[0][1] == [(0x6040, 0, 16), (0x6071, 0, 16), (0x6060, 0, 8)]
    rx = [e for _, entries in mapping_of(elmo, "rx") for e in entries]
    assert (0x607A, 0, 32) in rx and not any(i == 0x6071 for i, _, _ in rx)
    assert od_value(elmo, 0x6061) == 8
    assert mapping_of(ingenia, "rx") == [] and mapping_of(ingenia, "tx") == []
    assert ingenia.sii_spec.rx_pdos == [] and ingenia.sii_spec.mailbox[1] == 48
    tx = [i for _, entries in mapping_of(csp, "tx") for i, _, _ in entries]
    assert od_value(csp, 0x6061) == 8 and 0x6061 not in tx
    assert len({s.identity.product_code for s in bus.slaves[:4]}) == 4
    coupler = bus.slaves[4]
    assert coupler.kind == "coupler" and CAT_SM not in parse_categories(coupler.sii)


def _to_safeop(bus):
    """SM2/SM3 as the assignment says, then SAFE-OP."""
    for k, d in enumerate(bus.slaves):
        if d.kind != "cia402_drive":
            continue
        for sm, (start, n, out) in d.expected_sync_managers().items():
            send(bus, [(F.FPWR, 0x1001 + k, 0x0800 + 8 * sm, struct.pack(
                "<HHBBBB", start, n, 0x64 if out else 0x20, 0, 1 if n else 0, 0))])
        d.al_control(0x04)


def test_requires_dc_refuses_op_without_sync0_then_takes_it():
    bus, clock = line("requires_dc")
    preop(bus)
    _to_safeop(bus)
    d = bus.slaves[0]
    assert d.mem[0x0008] & 0x04                                     # DC supported
    d.al_control(0x08)
    assert (d.al_state, d.al_error, d.al_code) == (4, True, AL_CODE_INVALID_DC_SYNC_CONFIG)
    # what SOEM's config_dc and dc_sync write: the latch, the offset, SYNC0 at 0.5 ms
    send(bus, [(F.BWR, 0, 0x0900, bytes(4))])
    port0 = struct.unpack_from("<I", d.mem, 0x0900)[0]
    assert port0 == d.local_time_ns() & 0xFFFFFFFF
    send(bus, [(F.FPWR, 0x1001, 0x0920, struct.pack("<q", 10**12 - d.local_time_ns()))])
    (t,), = [struct.unpack("<Q", send(bus, [(F.FPRD, 0x1001, 0x0910, bytes(8))])[0][0])]
    assert t == 10**12
    send(bus, [(F.FPWR, 0x1001, 0x0990, struct.pack("<Q", 10**12 + 250000)),
               (F.FPWR, 0x1001, 0x09A0, struct.pack("<I", 400000)),
               (F.FPWR, 0x1001, 0x0981, b"\x03")])
    d.al_control(0x14)
    d.al_control(0x08)
    assert d.al_code == AL_CODE_INVALID_DC_SYNC_CONFIG              # 0.4 ms: not its cycle
    send(bus, [(F.FPWR, 0x1001, 0x09A0, struct.pack("<I", 500000))])
    d.al_control(0x14)
    d.al_control(0x08)
    assert (d.al_state, d.al_error) == (8, False)


def test_sync0_without_outputs_is_counted_and_past_the_limit_is_a_sync_error():
    bus, clock = line("requires_dc")
    preop(bus)
    _to_safeop(bus)
    d = bus.slaves[0]
    d.write(0x0990, struct.pack("<Q", d.system_time_ns() + 250000))
    d.write(0x09A0, struct.pack("<I", 500000))
    d.write(0x0981, b"\x03")
    d.al_control(0x08)
    assert d.al_state == 8

    def frame():                         # outputs arriving now (what logical() records)
        d.outputs_fresh, d._wd_last = True, clock.t
        d.process_outputs()

    for _ in range(10):                  # one frame per cycle: nothing missed
        clock.t += 0.0005
        frame()
    assert od_value(d, 0x1C32, 0x0B) == 0 and d.al_state == 8
    clock.t += 0.0015                    # two SYNC0 without outputs: +3 each, limit 4
    frame()
    assert od_value(d, 0x1C32, 0x0B) == 2
    assert (d.al_state, d.al_code) == (4, AL_CODE_SYNC_ERROR)
    assert od_value(d, 0x1C32, 0x20) == 1


def test_requires_60c2_refuses_op_until_the_interpolation_period_is_the_cycle():
    bus, _ = line("requires_60c2")
    preop(bus)
    _to_safeop(bus)
    d = bus.slaves[0]
    d.al_control(0x08)
    assert d.al_code == AL_CODE_INVALID_SYNC_CYCLE_TIME
    d.al_control(0x12)
    d.sdo.handle(request(0x2F, 0x60C2, 1, b"\x05\0\0\0"))
    d.sdo.handle(request(0x2F, 0x60C2, 2, b"\xfc\0\0\0"))           # -4: 5 x 10^-4 s
    _to_safeop(bus)
    d.al_control(0x08)
    assert (d.al_state, d.al_error) == (8, False)


def _op_drive(profile, **keys):
    bus, clock = line(profile, **keys)
    preop(bus)
    d = bus.slaves[0]
    d.sdo.handle(request(0x2F, 0x6060, 0, b"\x0a\0\0\0"))
    _to_safeop(bus)
    d.al_control(0x08)
    assert d.al_state == 8
    return bus, d


def _frame(bus, d, controlword, torque=0, mode=10):
    """One frame of the standard mapping's outputs (controlword, target torque, mode) as it
    reaches the drive, then the drive's step."""
    struct.pack_into("<Hhb", d.mem, 0x1100, controlword, torque, mode)
    d.outputs_fresh = True
    d.process_outputs()
    d.update_inputs(bus.physics)


@pytest.mark.parametrize("frames_high,resets", [(1, 1), (4, 4)])
def test_a_drive_sampling_the_controlword_every_2_ms_sees_only_a_held_reset_edge(frames_high,
                                                                                  resets):
    """Bit 7 high for one 0.5 ms frame reaches the state machine in one phase of the drive's
    2 ms sampling out of four; held four frames (2 ms) in every phase."""
    seen = 0
    for phase in range(4):
        bus, d = _op_drive("slow_controlword")
        for cw in (6,) * 4 + (7,) * 4 + (15,) * 4:
            _frame(bus, d, cw)
        assert d.sm402.state == OPERATION_ENABLED
        d.inject_fault(0x2310, "over current")
        for _ in range(4 + phase):
            _frame(bus, d, 0)
        assert d.sm402.state == FAULT
        for _ in range(frames_high):
            _frame(bus, d, 0x80)
        for _ in range(4):
            _frame(bus, d, 0)
        seen += d.sm402.state == SWITCH_ON_DISABLED
    assert seen == resets


def test_a_fault_sets_0x603f_and_sends_emergencies_on_entry_and_reset():
    bus, d = _op_drive("standard")
    d.inject_fault(0x2310, "over current")
    assert od_value(d, 0x603F) == 0x2310 and od_value(d, 0x1001) & 0x03 == 0x03
    message = d.mailbox.take()
    assert message[5] & 0x0F == 3                                   # CoE
    service, code, register = struct.unpack_from("<HHB", message, 6)
    assert (service >> 12, code, register) == (1, 0x2310, 0x03)     # emergency
    d.mailbox.read_done()
    _frame(bus, d, 0)
    _frame(bus, d, 0x80)
    assert d.sm402.state == SWITCH_ON_DISABLED and od_value(d, 0x603F) == 0
    service, code = struct.unpack_from("<HH", d.mailbox.take(), 6)
    assert (service >> 12, code) == (1, 0x0000)                     # error reset


def test_csp_servos_to_the_target_position_whatever_torque_is_sent():
    bus, d = _op_drive("standard")
    for cw in (6, 7, 15):                                          # 0x6060 = 8 in the PDO
        _frame(bus, d, cw, torque=200, mode=8)
    d._x = 0.3                        # the motor measured at 0.3 rad before the next frame
    _frame(bus, d, 15, torque=200, mode=8)
    assert d.mode_display == 8 and d.applied_permille < 0           # back to 0x607A = 0
    assert d.enables_outside_cst == 1 and d.frames_outside_cst == 2

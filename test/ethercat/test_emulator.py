"""The emulator proven against SOEM: pysoem 1.1.13 is the master, on a veth pair whose
slave end lives in a network namespace with the emulator process.

The tests on the default line share one emulator, reset to power-up before each (fixture
``ecat_bus``); those with another line get their own (``ecat_emulator``); each test has its own
pysoem master (``soem_master``); teardown removes processes, links and namespaces.
"""

import math
import os
import signal
import subprocess
import sys
import time

import pysoem
import pytest

from ethercat.emulator.config import default_config
from ethercat.harness import TEST_DIR
from ethercat.soem_bus import (CW_DISABLE_VOLTAGE, CW_ENABLE_OPERATION, CW_FAULT_RESET,
                               CW_QUICK_STOP, CW_SHUTDOWN, CW_SWITCH_ON, SoemBus, cia402_state)

DRIVE_ID = (0x5EA0, 0x402, 0x10000)
TERMINAL_ID = (0x2, 0x0C1E3052, 0x00100000)
COUNTS_PER_RAD = 2 ** 20 / (2 * math.pi)
EXPECTED_WKC = 7            # 2 drives x (LRW read + write = 3) + terminal (read = 1)
SAFEOP_WKC = 3              # in SAFE-OP the drives take no outputs: their reads only


def wait_until(predicate, what, timeout=10.0, step=None):
    """Poll ``predicate`` (optionally running ``step`` between polls) until it is true."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting for " + what)
        if step is not None:
            step()
        else:
            time.sleep(0.005)


# Tests in OP would fail spuriously if a loaded host stalled the master for more than the
# drives' 100 ms watchdog, so this fixture lengthens it to 2 s; the watchdog tests set
# 100 ms themselves (its exact timing is tested with a fake clock in test_emulator_units).
SAFE_WATCHDOG_MS = 2000.0


@pytest.fixture
def bus_in_op(ecat_bus, soem_master):
    bus = SoemBus(soem_master(ecat_bus.master_interface))
    assert bus.bring_up() == pysoem.OP_STATE
    for i in bus.drives:
        bus.slaves[i].set_watchdog("processdata", SAFE_WATCHDOG_MS)
    return ecat_bus, bus


def test_config_init_finds_slaves_with_identities(ecat_bus, soem_master):
    master = soem_master(ecat_bus.master_interface)
    assert master.config_init() == 3
    ids = [(s.man, s.id, s.rev) for s in master.slaves]
    assert ids == [DRIVE_ID, DRIVE_ID, TERMINAL_ID]
    assert [s.name for s in master.slaves] == ["SEAforce CiA402 drive (emulated)"] * 2 + [
        "EL3102 2Ch. Ana. Input +/-10V (emulated)"]
    serials = [int.from_bytes(s.eeprom_read(0x0E), "little") for s in master.slaves]
    assert serials == [1, 2, 3]
    status = ecat_bus.client.status()
    assert [s["station_address"] for s in status["slaves"]] == [0x1001, 0x1002, 0x1003]
    assert [s["al_state"] for s in status["slaves"]] == [pysoem.PREOP_STATE] * 3
    assert master.read_state() == pysoem.PREOP_STATE


def test_config_map_layout_and_expected_wkc(ecat_bus, soem_master):
    master = soem_master(ecat_bus.master_interface)
    bus = SoemBus(master)
    assert bus.configure() == (3, 44)
    assert master.expected_wkc == EXPECTED_WKC
    assert [len(s.output) for s in master.slaves] == [5, 5, 0]
    assert [len(s.input) for s in master.slaves] == [13, 13, 8]
    assert master.state_check(pysoem.SAFEOP_STATE, 500000) == pysoem.SAFEOP_STATE
    drive = master.slaves[0]
    assert drive._fprd(0x0810, 8) == bytes.fromhex("0011050064000100")      # SM2
    assert drive._fprd(0x0818, 8) == bytes.fromhex("80110d0020000100")      # SM3
    st = ecat_bus.client.status()["slaves"]
    # FMMUs: all outputs first, then all inputs, in slave order
    assert st[0]["fmmus"] == [[0, 5, 0x1100, 2], [10, 13, 0x1180, 1]]
    assert st[1]["fmmus"] == [[5, 5, 0x1100, 2], [23, 13, 0x1180, 1]]
    assert st[2]["fmmus"] == [[36, 8, 0x1180, 1]]
    assert st[2]["sync_managers"][2][1] == 0 and st[2]["sync_managers"][2][3] & 1 == 0


def test_op_and_cyclic_working_counter(ecat_bus, soem_master):
    master = soem_master(ecat_bus.master_interface)
    bus = SoemBus(master)
    bus.configure()
    assert master.state_check(pysoem.SAFEOP_STATE, 500000) == pysoem.SAFEOP_STATE
    # the drives' process-data watchdog (tested on its own below) must not expire while this
    # busy test process reads the emulator's status after the cycles
    for i in bus.drives:
        bus.slaves[i].set_watchdog("processdata", SAFE_WATCHDOG_MS)
    assert bus.cycle() == [SAFEOP_WKC]
    assert bus.request_state(pysoem.OP_STATE) == pysoem.OP_STATE
    steps0 = ecat_bus.client.status()["physics_steps"]
    wkcs = bus.cycle(2000)
    assert wkcs == [EXPECTED_WKC] * 2000
    st = ecat_bus.client.status()
    assert st["physics_steps"] - steps0 == 2000
    assert [s["al_state"] for s in st["slaves"]] == [pysoem.OP_STATE] * 3
    assert [s["last_al_request"] for s in st["slaves"]] == [pysoem.OP_STATE] * 3
    assert st["counters"]["malformed"] == 0 and st["counters"]["ignored"] == 0


def test_block_lrw_makes_soem_use_lwr_and_lrd(ecat_emulator, soem_master):
    config = default_config()
    # on the terminal: SOEM copies the SII data of a slave identical to an earlier one
    # (the pinch drive gets the wrist drive's), so the flag would be missed there
    config["slaves"][2]["block_lrw"] = True
    emu = ecat_emulator(config, evidence=False)
    bus = SoemBus(soem_master(emu.master_interface))
    assert bus.bring_up() == pysoem.OP_STATE
    frames0 = emu.client.status()["counters"]["datagrams"]
    wkcs = bus.cycle(50)
    assert wkcs == [bus.master.expected_wkc] * 50
    st = emu.client.status()
    assert st["counters"]["datagrams"] - frames0 == 100          # LWR + LRD per cycle
    bus.enable(1, 100)
    d = bus.command(1, CW_ENABLE_OPERATION, 100, cycles=50)
    assert cia402_state(d.statusword) == "operation_enabled" and d.torque == 100
    assert emu.client.torque_applied("pinch_drive")


def test_cia402_enable_applies_torque_and_moves_the_plant(bus_in_op):
    emu, bus = bus_in_op
    bus.cycle(5)
    d0 = bus.drive(0)
    p0 = bus.analog(2)[0][1]
    assert cia402_state(d0.statusword) == "switch_on_disabled"
    assert d0.statusword == 0x0250
    # switched on: torque commanded but not applied
    assert cia402_state(bus.command(0, CW_SHUTDOWN, 300).statusword) == "ready_to_switch_on"
    assert cia402_state(bus.command(0, CW_SWITCH_ON, 300).statusword) == "switched_on"
    d = bus.command(0, CW_SWITCH_ON, 300, cycles=20)
    assert d.torque == 0 and abs(d.position - d0.position) < 50
    assert not emu.client.torque_applied("wrist_drive")
    # operation enabled in CST: 300 per-mille of 0.5 N m
    d = bus.command(0, CW_ENABLE_OPERATION, 300, cycles=400)
    assert cia402_state(d.statusword) == "operation_enabled"
    assert d.mode == 10 and d.torque == 300 and d.statusword & 0x1000
    wrist = emu.client.slave("wrist_drive")
    assert wrist["torque_applied"] and wrist["applied_torque"] == pytest.approx(0.15)
    assert d.position - d0.position > 0.05 * COUNTS_PER_RAD      # moved > 0.05 rad
    assert d.velocity != 0
    ch = emu.client.channel("wrist")
    assert ch["torque"] == pytest.approx(0.15)
    assert abs(d.position - ch["motor_position"] * COUNTS_PER_RAD) < 0.01 * COUNTS_PER_RAD
    # hose compressed the other way: pressure ADC fell by many counts (noise ~1 count)
    p1 = bus.analog(2)[0][1]
    assert p0 - p1 > 50
    # the pinch drive never enabled: no torque there
    assert bus.drive(1).torque == 0 and not emu.client.torque_applied("pinch_drive")
    # quick stop: zero torque, then disable voltage -> switch on disabled
    d = bus.command(0, CW_QUICK_STOP, 300)
    assert cia402_state(d.statusword) == "quick_stop_active" and d.torque == 0
    assert not emu.client.torque_applied("wrist_drive")
    assert cia402_state(bus.command(0, CW_DISABLE_VOLTAGE).statusword) == "switch_on_disabled"


def test_the_drive_follows_the_mode_it_is_in(bus_in_op):
    """CST applies the target torque; CSP (mode 8) servos to the target position, here the
    unmapped 0x607A = 0, whatever torque is sent -- the accident of a drive enabled in the
    wrong mode -- and the emulator counts every such frame as evidence."""
    emu, bus = bus_in_op
    bus.enable(1, 0)
    d = bus.command(1, CW_ENABLE_OPERATION, 200, mode=10, cycles=200)
    assert d.mode == 10 and d.torque == 200 and d.statusword & 0x1000
    assert d.position > 0                              # pushed ahead by 0.1 N m
    assert emu.client.slave("pinch_drive")["enables_outside_cst"] == 0
    d = bus.command(1, CW_ENABLE_OPERATION, 200, mode=8, cycles=5)
    assert cia402_state(d.statusword) == "operation_enabled"
    assert d.mode == 8 and d.torque < 0              # back towards position 0, not +200
    assert emu.client.slave("pinch_drive")["frames_outside_cst"] >= 5
    bus.command(1, CW_SWITCH_ON, 0, mode=8, cycles=3)          # disable operation, then
    bus.command(1, CW_ENABLE_OPERATION, 0, mode=8, cycles=3)   # enabled in CSP: counted
    assert emu.client.slave("pinch_drive")["enables_outside_cst"] == 1


def test_position_drive_backdrives_the_finger(ecat_emulator, soem_master):
    config = default_config()
    config["channels"]["pinch"]["environment"] = {
        "mode": "position_sine", "amplitude": 0.5, "frequency": 20.0}
    config["slaves"].append({
        "type": "analog_input", "name": "pinch_endpoint", "serial": 4,
        "inputs": [{"channel": "pinch", "quantity": "endpoint_position",
                    "volts_per_unit": 10 / math.pi},
                   {"channel": "pinch", "quantity": "external_force", "volts_per_unit": 2.0}]})
    emu = ecat_emulator(config, evidence=False)
    master = soem_master(emu.master_interface)
    bus = SoemBus(master)
    assert bus.bring_up() == pysoem.OP_STATE
    assert master.expected_wkc == EXPECTED_WKC + 1
    positions, pressures, endpoint = [], [], []
    for _ in range(300):                       # 0.15 s of plant time, ~half a period
        assert bus.cycle() == [EXPECTED_WKC + 1]
        positions.append(bus.drive(1).position)
        pressures.append(bus.analog(2)[1][1])
        endpoint.append(bus.analog(3)[0][1])
    ch = emu.client.channel("pinch")
    assert ch["environment"]["mode"] == "position_sine"
    # the endpoint follows the drive (x_d = 0.5 sin(20 t)), the hose backdrives the motor
    assert max(endpoint) > 0.9 * 0.5 * 3276.7 * 10 / math.pi      # X_e reaches ~0.5 rad
    assert max(positions) - min(positions) > 0.05 * COUNTS_PER_RAD
    assert max(pressures) - min(pressures) > 200
    # the side-channel truth matches the PDO within one step of motion
    x_e = ch["measured"]["x_e"]
    f_e = ch["measured"]["f_e"]
    assert bus.analog(3)[0][1] == pytest.approx(x_e * 10 / math.pi * 3276.7, abs=400)
    assert bus.analog(3)[1][1] == pytest.approx(f_e * 2.0 * 3276.7, abs=400)
    # the wrist channel is free and unpowered: it stays put
    assert abs(bus.drive(0).position) < 0.001 * COUNTS_PER_RAD


def test_plant_trace_over_the_side_channel(bus_in_op):
    emu, bus = bus_in_op
    emu.client.set_environment("pinch", {"mode": "torque_sine", "amplitude": 0.2,
                                         "frequency": 30.0})
    emu.client.start_trace(decimation=2)
    wkcs = bus.cycle(100)
    bus.enable(0, 100)                                          # 9 cycles
    wkcs += bus.cycle(291)
    trace = emu.client.trace()
    assert wkcs == [EXPECTED_WKC] * 391
    wrist, pinch = trace["wrist"], trace["pinch"]
    assert len(wrist["time"]) == len(pinch["time"]) == 200
    dt = [b - a for a, b in zip(wrist["time"], wrist["time"][1:])]
    assert all(d == pytest.approx(0.001) for d in dt)          # 2 steps of 0.5 ms
    assert wrist["torque"][-1] == pytest.approx(0.05)           # 100 per-mille of 0.5 N m
    assert wrist["torque"][0] == 0.0                            # before Operation enabled
    f_e = pinch["external_force"]
    assert max(f_e) == pytest.approx(0.2, abs=0.01) and min(f_e) < -0.19
    assert emu.client.trace() == {}                             # stopped


def test_cable_pull_gives_wkc_errors_and_watchdog_removes_torque(bus_in_op):
    emu, bus = bus_in_op
    for i in bus.drives:
        bus.slaves[i].set_watchdog("processdata", 100.0)
    bus.enable(0, 200)
    assert bus.command(0, CW_ENABLE_OPERATION, 200).torque == 200
    assert emu.client.torque_applied("wrist_drive")
    emu.client.silent(True)
    lost = []
    wait_until(lambda: not emu.client.torque_applied("wrist_drive"),
               "the drive's watchdog to remove torque", step=lambda: lost.extend(bus.cycle(10)))
    assert lost and all(w != EXPECTED_WKC for w in lost) and all(w <= 0 for w in lost)
    wrist = emu.client.slave("wrist_drive")
    assert wrist["watchdog_expiries"] == 1 and wrist["last_watchdog_gap"] >= 0.1
    assert (wrist["al_state"], wrist["al_error"], wrist["al_status_code"]) == (4, True, 0x1B)
    assert wrist["cia402_state"] == "fault"
    emu.client.silent(False)
    # back on the wire: process data flows again (SAFE-OP still serves the inputs, not the
    # outputs: the WKC shows the drives out of OP), the master sees the drive in SAFE-OP +
    # error with code 0x1B and the fault bit
    assert bus.cycle(3)[-1] == SAFEOP_WKC
    bus.master.read_state()
    assert bus.slaves[0].state == pysoem.SAFEOP_STATE | pysoem.STATE_ERROR
    assert bus.slaves[0].al_status == 0x1B
    d = bus.drive(0)
    assert d.statusword & 0x0008 and d.torque == 0
    # both drives' watchdogs expired (the terminal has none): acknowledge on the whole
    # bus, back to OP, fault reset, enable
    assert [s["al_status_code"] for s in emu.client.status()["slaves"]] == [0x1B, 0x1B, 0]
    assert bus.request_state(pysoem.SAFEOP_STATE | pysoem.STATE_ACK) == pysoem.SAFEOP_STATE
    bus.cycle(2)
    assert bus.request_state(pysoem.OP_STATE) == pysoem.OP_STATE
    bus.command(0, CW_FAULT_RESET)
    assert cia402_state(bus.command(0, 0).statusword) == "switch_on_disabled"
    bus.enable(0, 200)
    assert bus.command(0, CW_ENABLE_OPERATION, 200).torque == 200


def test_watchdog_drops_torque_when_process_data_stop(bus_in_op):
    emu, bus = bus_in_op
    for i in bus.drives:
        bus.slaves[i].set_watchdog("processdata", 100.0)
    assert emu.client.slave("pinch_drive")["watchdog_time"] == pytest.approx(0.1)
    bus.enable(1, -150)
    assert bus.command(1, CW_ENABLE_OPERATION, -150, cycles=300).torque == -150
    # the master stops sending process data (but keeps the link)
    pinch = wait_until(lambda: (lambda s: s if s["watchdog_expiries"] else None)(
        emu.client.slave("pinch_drive")), "the watchdog to expire")
    assert pinch["last_watchdog_gap"] >= 0.1
    assert not pinch["torque_applied"] and pinch["applied_torque"] == 0.0
    assert pinch["cia402_state"] == "fault" and pinch["al_status_code"] == 0x1B
    assert emu.client.slave("wrist_drive")["watchdog_expiries"] == 1    # not enabled, also expired
    assert emu.client.slave("pressure_terminal")["al_state"] == pysoem.OP_STATE
    assert bus.cycle() == [SAFEOP_WKC]
    d = bus.drive(1)
    assert cia402_state(d.statusword) == "fault" and d.torque == 0
    assert emu.client.channel("pinch")["torque"] == 0.0
    bus.master.read_state()
    assert [s.state for s in bus.slaves] == [0x14, 0x14, pysoem.OP_STATE]
    assert [s.al_status for s in bus.slaves] == [0x1B, 0x1B, 0]


def test_a_shorter_watchdog_set_by_the_master_is_honoured(bus_in_op):
    emu, bus = bus_in_op
    bus.slaves[0].set_watchdog("processdata", 20.0)
    assert bus.slaves[0].get_watchdog("processdata") == pytest.approx(20.0)
    assert emu.client.slave("wrist_drive")["watchdog_time"] == pytest.approx(0.02)
    wait_until(lambda: emu.client.slave("wrist_drive")["watchdog_expiries"],
               "the 20 ms watchdog to expire")
    assert emu.client.slave("wrist_drive")["last_watchdog_gap"] >= 0.02


@pytest.mark.parametrize("direction", ["request", "reply"])
def test_dropped_frames_are_lost_cycles(bus_in_op, direction):
    emu, bus = bus_in_op
    bus.cycle(5)
    steps0 = emu.client.status()["physics_steps"]
    emu.client.drop(7, direction=direction)
    wkcs = bus.cycle(40)
    assert sum(w != EXPECTED_WKC for w in wkcs) == 7
    assert all(w == -1 for w in wkcs[:7]) and wkcs[7:] == [EXPECTED_WKC] * 33
    # a request lost before the slaves: the plant did not step; a lost reply: it did
    steps = emu.client.status()["physics_steps"] - steps0
    assert steps == (33 if direction == "request" else 40)


def test_corrupted_replies(bus_in_op):
    emu, bus = bus_in_op
    bus.enable(0)
    bus.cycle(3)
    good = bus.drive(0)
    emu.client.corrupt(3, how="wkc")
    assert bus.cycle(5) == [0, 0, 0, EXPECTED_WKC, EXPECTED_WKC]
    emu.client.corrupt(2, how="index")
    assert bus.cycle(4) == [-1, -1, EXPECTED_WKC, EXPECTED_WKC]
    emu.client.corrupt(1, how="data")
    assert bus.cycle() == [EXPECTED_WKC]                # undetectable by the WKC ...
    assert bus.drive(0).statusword == good.statusword ^ 0xFFFF   # ... but the data is garbage
    bus.cycle()
    assert bus.drive(0).statusword == good.statusword


def test_wrong_identity_is_visible_to_the_master(ecat_bus, soem_master):
    ecat_bus.client.set_identity("pinch_drive", product_code=0xBADC0DE)
    master = soem_master(ecat_bus.master_interface)
    assert master.config_init() == 3
    assert [(s.man, s.id, s.rev) for s in master.slaves] == [
        DRIVE_ID, (DRIVE_ID[0], 0xBADC0DE, DRIVE_ID[2]), TERMINAL_ID]


def test_wrong_identity_from_the_configuration(ecat_emulator, soem_master):
    config = default_config()
    config["slaves"][2]["product_code"] = "0x0C1E3053"
    emu = ecat_emulator(config, evidence=False)
    master = soem_master(emu.master_interface)
    assert master.config_init() == 3
    assert master.slaves[2].id == 0x0C1E3053 and master.slaves[0].id == DRIVE_ID[1]


def test_drive_fault_bit_and_fault_reset(bus_in_op):
    emu, bus = bus_in_op
    bus.enable(0, 250)
    assert bus.command(0, CW_ENABLE_OPERATION, 250).torque == 250
    emu.client.drive_fault("wrist_drive", code=0x2310, latched=True)
    d = bus.command(0, CW_ENABLE_OPERATION, 250)
    assert d.statusword & 0x0008 and cia402_state(d.statusword) == "fault"
    assert d.torque == 0 and not emu.client.torque_applied("wrist_drive")
    assert emu.client.slave("wrist_drive")["fault_code"] == 0x2310
    # latched: a fault reset is refused until the cause is cleared
    bus.command(0, CW_FAULT_RESET)
    assert cia402_state(bus.command(0, 0).statusword) == "fault"
    emu.client.clear_fault("wrist_drive")
    bus.command(0, CW_FAULT_RESET)
    assert cia402_state(bus.command(0, 0).statusword) == "switch_on_disabled"
    assert bus.enable(0, 250) == ["ready_to_switch_on", "switched_on", "operation_enabled"]
    assert bus.command(0, CW_ENABLE_OPERATION, 250).torque == 250


def test_al_errors_are_reported_and_acknowledged(ecat_bus, soem_master):
    master = soem_master(ecat_bus.master_interface)
    assert master.config_init() == 3
    master.state = pysoem.OP_STATE                  # PRE-OP -> OP is not allowed
    master.write_state()
    assert master.state_check(pysoem.OP_STATE, 20000) != pysoem.OP_STATE
    master.read_state()
    assert [s.state for s in master.slaves] == [pysoem.PREOP_STATE | pysoem.STATE_ERROR] * 3
    assert [s.al_status for s in master.slaves] == [0x11] * 3
    master.state = pysoem.PREOP_STATE | pysoem.STATE_ACK
    master.write_state()
    assert master.state_check(pysoem.PREOP_STATE, 200000) == pysoem.PREOP_STATE
    # a bad SM2 set-up is refused at PRE-OP -> SAFE-OP with 0x001D
    master.manual_state_change = True
    assert master.config_map() == 44
    master.slaves[0]._fpwr(0x0812, (4).to_bytes(2, "little"))
    master.state = pysoem.SAFEOP_STATE
    master.write_state()
    master.state_check(pysoem.SAFEOP_STATE, 50000)
    master.read_state()
    assert master.slaves[0].state == pysoem.PREOP_STATE | pysoem.STATE_ERROR
    assert master.slaves[0].al_status == 0x1D
    assert [s.state for s in master.slaves[1:]] == [pysoem.SAFEOP_STATE] * 2


def test_back_to_init_is_recorded(bus_in_op):
    emu, bus = bus_in_op
    emu.client.clear_history()
    bus.cycle(10)
    assert bus.request_state(pysoem.INIT_STATE) == pysoem.INIT_STATE
    st = emu.client.status()["slaves"]
    assert [s["al_state"] for s in st] == [pysoem.INIT_STATE] * 3
    assert [s["last_al_request"] for s in st] == [pysoem.INIT_STATE] * 3
    assert [(h["slave"], h["state"]) for h in emu.client.al_history()] == [
        ("wrist_drive", 1), ("pinch_drive", 1), ("pressure_terminal", 1)]


def test_sigint_to_a_master_process_leaves_drives_disabled_and_bus_in_init(ecat_bus):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(TEST_DIR)] + ([env["PYTHONPATH"]]
                                                           if env.get("PYTHONPATH") else []))
    proc = subprocess.Popen([sys.executable, "-m", "ethercat.example_master",
                             ecat_bus.master_interface, str(SAFE_WATCHDOG_MS)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)
    try:
        assert proc.stdout.readline().strip() == "READY"
        wait_until(lambda: all(ecat_bus.client.torque_applied(d)
                               for d in ("wrist_drive", "pinch_drive")), "torque on both drives")
        os.kill(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, out
    assert out.strip().endswith("STOPPED 1")
    st = ecat_bus.client.status()["slaves"]
    assert [s["al_state"] for s in st] == [pysoem.INIT_STATE] * 3
    assert [s["last_al_request"] for s in st] == [pysoem.INIT_STATE] * 3
    assert [s["cia402_state"] for s in st[:2]] == ["switch_on_disabled"] * 2
    assert not any(s["torque_applied"] for s in st[:2])

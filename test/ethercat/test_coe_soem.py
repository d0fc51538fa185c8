"""The project's CoE path through SOEM itself (pysoem on a veth pair, the emulator as the
slaves), on one line shared by the module: a drive with an Elmo-like default mapping (complete
access), one with none and a 48-byte mailbox (segmented transfers), an EK1100-like coupler and
the EL3102-like terminal behind it.

ethercat_scan lists it and writes a bus YAML that configures unchanged (SOEM's config_func
hook writes the mappings over CoE, SOEM reads them back over CoE with and without complete
access), the loop then closes on it; an SDO abort comes back through pysoem as one line."""
import time

import pysoem
import pytest
import yaml

from ethercat.fixtures import EMULATOR_PRIORITY, realtime_allowed, torque_evidence
from ethercat.harness import EmulatorHarness
from ethercat.lines import line
from seaforce_ros.core.backend import PlantSample
from seaforce_ros.core.plant_cycle import PlantCycle, PlantLimits
from seaforce_ros.ethercat import scan
from seaforce_ros.ethercat.backend import EthercatBackend
from seaforce_ros.ethercat.bus_config import BusConfig
from seaforce_ros.ethercat.errors import BusError

DT = 5e-4
CHANNELS = ('wrist', 'pinch')


@pytest.fixture(scope='module')
def emulator(tmp_path_factory):
    priority = EMULATOR_PRIORITY if realtime_allowed() else 0
    harness = EmulatorHarness(line('elmo_like', 'ingenia_like', cycle_time=DT),
                              workdir=tmp_path_factory.mktemp('coe_soem'), realtime=priority)
    harness.start()
    try:
        yield harness
        assert not torque_evidence(harness.client)
    finally:
        print(harness.log())
        harness.stop()


def test_scan_writes_a_bus_yaml_that_configures_unchanged(emulator, tmp_path, capsys):
    out = tmp_path / 'bus.yaml'
    code = scan.main(['--interface', emulator.master_interface, '--output', str(out),
                      '--channels', ','.join(CHANNELS)])
    printed = capsys.readouterr()
    assert code == 0, printed
    rows = [ln for ln in printed.out.splitlines()
            if ln.split()[:1] and ln.split()[0].isdigit() and ' 0x' in ln]
    assert [r.split()[1] for r in rows] == ['drive1', 'drive2', 'coupler1', 'analog1']
    assert '0x00001402' in rows[0] and 'cia402_drive, CoE, DC, rated torque 500 mN m' in rows[0]
    assert 'coupler, no mailbox' in rows[2] and 'analog_input' in rows[3]
    text = out.read_text()
    # the Elmo-like drive's own mapping, read over CoE (complete access), as a comment
    assert '# at power-up 0x1600 maps 0x607A:00/32, 0x60FE:01/32, 0x6040:00/16' in text
    # the drive without a default mapping answered its 56-byte name in segments (48-byte
    # mailbox)
    assert 'SEAforce CiA402 drive with no default mapping (emulated)' in text
    config = BusConfig.load(out)
    assert [s.kind for s in config.slaves] == ['cia402_drive', 'cia402_drive', 'coupler',
                                               'analog_input']
    backend = EthercatBackend(config, CHANNELS, emulator.master_interface, DT,
                              receive_timeout=2e-3, drive_watchdog=2.0)
    client = emulator.client
    try:
        backend.open()
        done = backend.configure()
        assert 'mapping written and read back on drive1, drive2' in done, done
        for name in ('drive0', 'drive1'):
            st = client.slave(name)
            assert [e for _, entries in st['rx_mapping'] for e in entries] == [
                [0x6040, 0, 16], [0x6071, 0, 16], [0x6060, 0, 8]]
            assert st['image_bytes'] == [5, 15] and st['mode_display'] == 10
        plant = PlantCycle(CHANNELS, DT, PlantLimits(command_timeout=0.5),
                           units_per_nm=backend.units_per_nm)
        backend.activate()
        end = time.monotonic() + 0.6
        while time.monotonic() < end:
            sample = PlantSample(2)
            link = backend.read(sample)
            if link.received and plant.exchange(link.counter, link.expected):
                plant.command(list(CHANNELS), [0.05, -0.05], plant.state_published())
            backend.write(plant.step(time.monotonic(), sample.velocity, backend.drives()))
            time.sleep(DT)
        assert client.slave('drive0')['target_torque'] == 100        # 0.05 N m at 0.5 N m
        assert client.slave('drive1')['applied_torque'] == pytest.approx(-0.05)
        assert plant.latched_faults() == []
    finally:
        backend.close()
    assert {s['al_state'] for s in client.status()['slaves']} == {1}


def test_an_sdo_abort_through_soem_is_one_line_naming_object_and_code(emulator, tmp_path):
    out = tmp_path / 'bus.yaml'
    assert scan.main(['--interface', emulator.master_interface, '--output', str(out),
                      '--channels', ','.join(CHANNELS)]) == 0
    data = yaml.safe_load(out.read_text())
    data['slaves'][1]['sdo'] = [[0x60C2, 2, 'i8', 5]]               # index > 0: too high
    config = BusConfig.from_dict(data)
    backend = EthercatBackend(config, CHANNELS, emulator.master_interface, DT)
    enabled = emulator.client.slave('drive1')['cycles_enabled']
    try:
        backend.open()
        with pytest.raises(BusError) as info:
            backend.configure()
    finally:
        backend.close()
    message = str(info.value)
    assert '\n' not in message
    assert message.startswith('slave 2 (drive2): start-up SDO 1 0x60C2:02 = 5 (i8) refused: '
                              'SDO abort 0x06090031 (value of parameter written too high)')
    assert emulator.client.slave('drive1')['cycles_enabled'] == enabled     # never enabled
    assert pysoem.INIT_STATE == emulator.client.slave('drive1')['al_state']


def test_first_power_on_over_soem(emulator, tmp_path, capsys):
    """first_power_on itself on this line (one channel, paced at 2 kHz through SOEM): it
    lowers the drive's 0x6072 over CoE for the check and gives it back, finds the channel
    right, tares a +15 mN m sensor offset and writes it as the controller's parameter."""
    from ethercat.lines import bus_yaml
    from seaforce_ros.ethercat import power_on
    config = bus_yaml(line('elmo_like', 'ingenia_like', cycle_time=DT))
    config['channels']['c0']['pressure']['steps'][2]['offset'] += 0.015
    bus = tmp_path / 'bus.yaml'
    bus.write_text(yaml.safe_dump(config))
    out = tmp_path / 'offsets.yaml'
    # (a 0.5 s drive watchdog, as the node tests': this test process is not real-time)
    code = power_on.main(['--interface', emulator.master_interface, '--bus-config', str(bus),
                          '--channels', 'c0', '--output', str(out), '--drive-watchdog', '0.5'])
    printed = capsys.readouterr()
    assert code == 0, printed
    assert 'c0: drive max torque 0x6072 = 212 per mille' in printed.out
    assert 'c0: passed' in printed.out, printed.out
    offset = yaml.safe_load(out.read_text())['/**']['ros__parameters']['c0']['pressure_offset']
    assert offset == pytest.approx(0.015, abs=3e-3)
    assert emulator.client.slave('drive0')['max_torque_permille'] == 32767    # given back


def test_an_emergency_in_the_mailbox_through_soem(emulator, tmp_path):
    """SOEM's own mailbox: a drive that faulted while the bus sat in SAFE-OP has its emergency
    waiting; the mode read over CoE at activate (0x6061 unmapped here) still gets its answer
    (pysoem raises an emergency out of a transfer when no callback takes it, the answer lost)
    and the emergency reaches the fault the channel reports, with the 0x603F code."""
    out = tmp_path / 'bus.yaml'
    assert scan.main(['--interface', emulator.master_interface, '--output', str(out),
                      '--channels', ','.join(CHANNELS)]) == 0
    data = yaml.safe_load(out.read_text())
    for slave in data['slaves'][:2]:
        slave['inputs'] = [e for e in slave['inputs'] if e[0] not in ('mode_display',
                                                                       'error_code')]
    config = BusConfig.from_dict(data)
    backend = EthercatBackend(config, CHANNELS, emulator.master_interface, DT,
                              receive_timeout=2e-3, drive_watchdog=2.0)
    client = emulator.client
    try:
        backend.open()
        backend.configure()
        client.drive_fault('drive0', code=0x2310, latched=True)
        assert 'wrist: 0x6061 = 10 read over CoE' in backend.activate()
        plant = PlantCycle(CHANNELS, DT, PlantLimits(command_timeout=0.5),
                           units_per_nm=backend.units_per_nm)
        whole = 'wrist: drive fault 0x2310 (continuous over current), emergency 0x2310'
        end = time.monotonic() + 30.0          # the 0x603F reading runs off the cycle thread
        while time.monotonic() < end and not any(whole in f for f in plant.latched_faults()):
            sample = PlantSample(2)
            link = backend.read(sample)
            if link.received and plant.exchange(link.counter, link.expected):
                plant.command(list(CHANNELS), [0.0, 0.0], plant.state_published())
            backend.write(plant.step(time.monotonic(), sample.velocity, backend.drives()))
            time.sleep(DT)
        assert any(whole in f for f in plant.latched_faults()), plant.latched_faults()
        assert client.cia402_state('drive0') == 'fault'
    finally:
        client.clear_fault('drive0')
        backend.close()
    assert {s['al_state'] for s in client.status()['slaves']} == {1}

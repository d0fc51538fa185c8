"""EthercatBackend (the hardware node's plant, no ROS) through its lifecycle over the emulated
bus, with PlantCycle deciding the torque as in the node: open + configure leave the bus in
SAFE-OP with no drive enabled, activate lets a command reach the drive, deactivate takes the
torque and the power stage away and the bus back to SAFE-OP, close leaves it in INIT with the
interface as it was; a wrong identity fails configure before anything is written to a drive."""

import pathlib
import time

import pytest
import yaml

from ethercat.emulator.config import default_config
from seaforce_ros.core.backend import PlantSample
from seaforce_ros.core.plant_cycle import PlantCycle, PlantLimits
from seaforce_ros.ethercat.backend import EthercatBackend
from seaforce_ros.ethercat.bus_config import BusConfig
from seaforce_ros.ethercat.errors import IdentityError
from seaforce_ros.ethercat.master import IFF_PROMISC, interface_flags

BUS = pathlib.Path(__file__).resolve().parents[1] / 'data' / 'bus_emulated.yaml'
CHANNELS = ('wrist', 'pinch')
DRIVES = ('wrist_drive', 'pinch_drive')
SLAVES = DRIVES + ('pressure_terminal',)
DT = 5e-4


def make_backend(harness, config=None):
    return EthercatBackend(config or BusConfig.load(BUS), CHANNELS, harness.master_interface,
                           DT, receive_timeout=2e-3, drive_watchdog=2.0)


def run_cycles(backend, plant, seconds, effort=(0.0, 0.2)):
    """The node's cycle: read, PlantCycle (a fresh command answering every state), write."""
    end = time.monotonic() + seconds
    velocity = [0.0, 0.0]
    while time.monotonic() < end:
        sample = PlantSample(len(CHANNELS))
        link = backend.read(sample)
        if link.received and plant.exchange(link.counter, link.expected):
            velocity = sample.velocity
            plant.command(list(CHANNELS), list(effort), plant.state_published())
        backend.write(plant.step(time.monotonic(), velocity, backend.drives()))
        time.sleep(DT)


def no_torque(client):
    return all(client.slave(d)['target_torque'] == 0 and not client.torque_applied(d)
               and client.cia402_state(d) != 'operation_enabled' for d in DRIVES)


def test_lifecycle_over_the_bus(ecat_emulator):
    config = default_config()
    config['cycle_time'] = DT
    harness = ecat_emulator(config)
    client = harness.client
    promiscuous = bool(interface_flags(harness.master_interface) & IFF_PROMISC)
    backend = make_backend(harness)
    try:
        backend.open()
        assert 'identities checked' in backend.configure()
        assert {client.al_state(s) for s in SLAVES} == {4}
        assert no_torque(client)
        plant = PlantCycle(CHANNELS, DT, PlantLimits(command_timeout=0.5),
                           units_per_nm=backend.units_per_nm)
        backend.activate()
        assert {client.al_state(s) for s in SLAVES} == {8}
        run_cycles(backend, plant, 0.5)
        assert client.cia402_state('pinch_drive') == 'operation_enabled'
        assert client.slave('pinch_drive')['target_torque'] == round(
            0.2 * backend.units_per_nm[1])
        assert client.torque_applied('pinch_drive')
        assert not client.torque_applied('wrist_drive')      # commanded 0
        assert plant.out.status == [0, 0]

        assert 'bus in SAFE-OP' in backend.deactivate()
        assert no_torque(client)
        assert {client.cia402_state(d) for d in DRIVES} == {'switch_on_disabled'}
        assert {client.al_state(s) for s in SLAVES} == {4}
        time.sleep(0.3)
        assert no_torque(client)
        assert not any('watchdog' in e['text'].lower() for e in client.events())
    finally:
        done = backend.close()
    assert done == 'bus in INIT'
    assert {client.al_state(s) for s in SLAVES} == {1}
    assert bool(interface_flags(harness.master_interface) & IFF_PROMISC) == promiscuous
    assert backend.close() == ''           # idempotent


def test_close_from_active_disables_the_drives_first(ecat_emulator):
    config = default_config()
    config['cycle_time'] = DT
    harness = ecat_emulator(config)
    backend = make_backend(harness)
    backend.open()
    backend.configure()
    plant = PlantCycle(CHANNELS, DT, PlantLimits(command_timeout=0.5),
                       units_per_nm=backend.units_per_nm)
    backend.activate()
    run_cycles(backend, plant, 0.5)
    assert harness.client.torque_applied('pinch_drive')
    assert backend.close() == 'drives disabled, bus in INIT'
    assert {harness.client.cia402_state(d) for d in DRIVES} == {'switch_on_disabled'}
    assert {harness.client.al_state(s) for s in SLAVES} == {1}


def test_wrong_identity_fails_configure_before_any_output(ecat_emulator, tmp_path):
    harness = ecat_emulator()
    data = yaml.safe_load(BUS.read_text())
    data['slaves'][1]['product_code'] = 0x0403
    backend = make_backend(harness, BusConfig.from_dict(data))
    backend.open()
    with pytest.raises(IdentityError, match=r'slave 2 \(pinch_drive.*0x00000403'):
        backend.configure()
    assert backend.close() == 'bus in INIT'
    assert {harness.client.al_state(s) for s in SLAVES} == {1}
    assert not any(e['value'] & 0x0F in (4, 8) for e in harness.client.al_history())

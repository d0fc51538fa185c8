"""Bus YAML parsing, scaling chains and the CiA 402 sequencer (no bus needed)."""
import copy
import math
import pathlib
import struct

import pytest
import yaml

from seaforce_ros.ethercat.bus_config import BusConfig, BusConfigError, Scaling, Affine
from seaforce_ros.ethercat.cia402 import (CW_DISABLE_VOLTAGE, CW_ENABLE_OPERATION,
                                          CW_FAULT_RESET, CW_SHUTDOWN, CW_SWITCH_ON, MODE_CST,
                                          DriveSequencer, DriveState, state_of)

ROOT = pathlib.Path(__file__).resolve().parent.parent
TEMPLATE = yaml.safe_load((ROOT / 'config' / 'ethercat_bus.yaml').read_text())


def test_template_loads_with_layouts_and_scalings():
    bus = BusConfig.load(ROOT / 'config' / 'ethercat_bus.yaml')
    assert [s.name for s in bus.slaves] == ['wrist_drive', 'pinch_drive', 'coupler',
                                            'pressure_adc']
    assert [s.kind for s in bus.slaves][2] == 'coupler' and bus.slaves[2].passive
    drive = bus.slaves[0]
    assert (drive.outputs.size, drive.inputs.size) == (5, 15)
    assert (drive.pdo_mapping, drive.rx_pdo, drive.tx_pdo, drive.sdo, drive.dc) == (
        'auto', 0x1600, 0x1A00, (), None)
    assert bus.channel('wrist').rated_torque is None         # the drive's 0x6076
    assert drive.inputs.offsets()['position'] == (2, '<i')
    assert drive.inputs.offsets()['torque'] == (10, '<h')
    pinch = bus.channel('pinch')
    assert pinch.pressure.source.entry == 'value2'
    # 2^20 counts = one revolution
    assert math.isclose(pinch.position.forward(2**20), 2 * math.pi, rel_tol=1e-12)
    assert pinch.external_from_channel == 'wrist' and pinch.external_sign == -1.0


def test_scaling_chain_compiles_and_inverts():
    chain = Scaling((Affine(2.0, 1.0), Affine(-3.0, 0.5), Affine(0.25)))
    gain, offset = chain.compiled()
    for x in (-7.0, 0.0, 3.5):
        assert math.isclose(chain.forward(x), gain * x + offset)
        assert math.isclose(chain.inverse(chain.forward(x)), x)


@pytest.mark.parametrize('mutate,words', [
    (lambda d: d['slaves'][0].update(kind='servo'), ['kind', 'servo']),
    (lambda d: d['slaves'][0].pop('product_code'), ['product_code']),
    (lambda d: d['slaves'][0].update(inputs=[['statusword', 0x6041, 0, 'u16']]),
     ['position', 'velocity']),
    (lambda d: d['slaves'][3]['inputs'][1].__setitem__(3, 'f32'), ['f32']),
    (lambda d: d['channels']['pinch']['pressure']['source'].update(entry='value9'),
     ['value9', 'value1']),
    (lambda d: d['channels']['pinch'].update(drive='pressure_adc'), ['cia402_drive']),
    (lambda d: d['channels']['pinch']['position'][0].update(factor=0), ['factor']),
    (lambda d: d['channels']['pinch'].update(external_force={'from_channel': 'elbow'}),
     ['elbow']),
    (lambda d: d['channels']['pinch'].pop('pressure'), ['pressure']),
    # the keys of CoE, DC and the kinds: each mistake named with what to write
    (lambda d: d['slaves'][0].update(pdo_maping='write'), ['pdo_maping', 'pdo_mapping']),
    (lambda d: d['slaves'][0].update(pdo_mapping='always'), ['always', 'auto, write, check']),
    (lambda d: d['slaves'][0].update(rx_pdo=0x1A00), ['rx_pdo', '0x1600..0x17FF']),
    (lambda d: d['slaves'][0].update(sdo=[[0x60C2, 1, 'u8', 300]]), ['300', 'u8']),
    (lambda d: d['slaves'][0].update(sdo=[[0x60C2, 1, 'u9', 3]]), ['u9', 'u64']),
    (lambda d: d['slaves'][0].update(sdo=[{'index': 0x60C2, 'value': 3}]), ['subindex', 'type']),
    (lambda d: d['slaves'][0].update(dc={'sync0_shift_ns': 100}), ['assign_activate']),
    (lambda d: d['slaves'][0].update(dc={'assign_activate': 0x0300, 'sync1_cycle_ns': 5}),
     ['sync1_cycle_ns', '0x0700']),
    (lambda d: d['slaves'][2].update(inputs=[['x', 0x6000, 1, 'u8']]), ['coupler', 'passive']),
    (lambda d: d['slaves'][0]['inputs'].__setitem__(4, ['mode_display', 0x6060, 0, 'i8']),
     ['mode_display', '0x6061']),
    (lambda d: d['channels']['pinch'].update(rated_torque=-1), ['rated_torque', 'omitted']),
    (lambda d: d['channels']['pinch'].update(drive='wrist_drive'), ['same drive']),
])
def test_configuration_mistakes_name_the_item(mutate, words):
    data = copy.deepcopy(TEMPLATE)
    mutate(data)
    with pytest.raises(BusConfigError) as info:
        BusConfig.from_dict(data, where='bus.yaml')
    for word in words:
        assert word in str(info.value), str(info.value)


@pytest.mark.parametrize('word,state', [
    (0x0250, DriveState.SWITCH_ON_DISABLED), (0x0231, DriveState.READY_TO_SWITCH_ON),
    (0x0233, DriveState.SWITCHED_ON), (0x0237, DriveState.OPERATION_ENABLED),
    (0x0217, DriveState.QUICK_STOP_ACTIVE), (0x0218, DriveState.FAULT),
    (0x021F, DriveState.FAULT_REACTION_ACTIVE), (0x0200, DriveState.NOT_READY)])
def test_statusword_decoding(word, state):
    assert state_of(word) is state


def test_enable_sequence_fault_and_reset():
    seq = DriveSequencer()
    assert seq.controlword(0x0250, MODE_CST) == CW_DISABLE_VOLTAGE  # not enabled yet
    seq.enable = True
    assert seq.controlword(0x0250, MODE_CST) == CW_SHUTDOWN
    assert seq.controlword(0x0231, MODE_CST) == CW_SWITCH_ON
    assert seq.controlword(0x0233, MODE_CST) == CW_ENABLE_OPERATION
    assert seq.controlword(0x0237, MODE_CST) == CW_ENABLE_OPERATION
    assert seq.torque_allowed
    seq.controlword(0x0237, 8)        # wrong mode displayed: no torque
    assert not seq.torque_allowed
    # fault: no torque, no automatic reset
    for _ in range(3):
        assert seq.controlword(0x0218, MODE_CST) == CW_DISABLE_VOLTAGE
    assert seq.faulted and not seq.torque_allowed
    seq.request_fault_reset()
    words = [seq.controlword(0x0218, MODE_CST) for _ in range(3)]
    assert words == [CW_DISABLE_VOLTAGE, CW_FAULT_RESET, CW_DISABLE_VOLTAGE]  # one rising edge
    assert seq.controlword(0x0250, MODE_CST) == CW_SHUTDOWN      # and up again
    seq.enable = False
    assert seq.controlword(0x0237, MODE_CST) == CW_SWITCH_ON     # disable operation
    assert seq.controlword(0x0233, MODE_CST) == CW_DISABLE_VOLTAGE


def test_the_fault_reset_pulse_is_held_reset_cycles_each_half():
    seq = DriveSequencer(reset_cycles=4)
    seq.enable = True
    seq.request_fault_reset()
    words = [seq.controlword(0x0218, MODE_CST) for _ in range(10)]
    assert words == [CW_DISABLE_VOLTAGE] * 4 + [CW_FAULT_RESET] * 4 + [CW_DISABLE_VOLTAGE] * 2


def test_enable_operation_is_sent_only_while_the_drive_shows_mode_10():
    seq = DriveSequencer()
    seq.enable = True
    assert seq.controlword(0x0233, 8) == CW_SWITCH_ON        # switched on, CSP: held there
    assert seq.held_for_mode and not seq.torque_allowed
    assert seq.controlword(0x0233, MODE_CST) == CW_ENABLE_OPERATION
    assert seq.controlword(0x0237, MODE_CST) == CW_ENABLE_OPERATION and seq.torque_allowed
    assert seq.controlword(0x0237, 9) == CW_SWITCH_ON        # the mode changed: disable it
    assert not seq.torque_allowed


def test_sdo_and_dc_entries_parse_to_what_is_written():
    data = copy.deepcopy(TEMPLATE)
    data['slaves'][0].update(
        sdo=[[0x60C2, 1, 'u8', 5], [0x60C2, 2, 'i8', -4],
             {'index': 0x1010, 'subindex': 1, 'type': 'str', 'value': 'save', 'verify': False},
             [0x2000, 0, 'f32', 1.5]],
        dc={'assign_activate': 0x0300}, pdo_mapping='check', complete_access=True)
    slave = BusConfig.from_dict(data).slaves[0]
    assert [s.encode() for s in slave.sdo] == [b'\x05', b'\xfc', b'save',
                                              struct.pack('<f', 1.5)]
    assert [s.verify for s in slave.sdo] == [True, True, False, True]
    assert slave.sdo[1].decode(b'\xfc') == -4
    assert slave.dc.shift_ns(500000) == 250000                # half the cycle by default
    assert (slave.pdo_mapping, slave.complete_access) == ('check', True)
    assert slave.outputs.entry('target_torque').mapping == 0x60710010


def test_the_bus_yaml_reference_lists_every_key():
    from seaforce_ros.ethercat.bus_config import KEYS, keys_markdown
    text = '\n'.join(keys_markdown())
    for key in KEYS:
        assert f'| `{key.name}` |' in text
    assert (ROOT / 'docs' / 'parameters.md').read_text().count('| `assign_activate` |') == 1

"""Bus YAML parsing, scaling chains and the CiA 402 sequencer (no bus needed)."""
import copy
import math
import pathlib

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
    assert [s.name for s in bus.slaves] == ['wrist_drive', 'pinch_drive', 'pressure_adc']
    drive = bus.slaves[0]
    assert (drive.outputs.size, drive.inputs.size) == (5, 12)
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
    (lambda d: d['slaves'][2]['inputs'][1].__setitem__(3, 'f32'), ['f32']),
    (lambda d: d['channels']['pinch']['pressure']['source'].update(entry='value9'),
     ['value9', 'value1']),
    (lambda d: d['channels']['pinch'].update(drive='pressure_adc'), ['cia402_drive']),
    (lambda d: d['channels']['pinch']['position'][0].update(factor=0), ['factor']),
    (lambda d: d['channels']['pinch'].update(external_force={'from_channel': 'elbow'}),
     ['elbow']),
    (lambda d: d['channels']['pinch'].pop('pressure'), ['pressure']),
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

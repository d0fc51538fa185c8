"""first_power_on (seaforce_ros/ethercat/power_on.py) on emulated drives whose fingers are the
project's plant model, in this process: it finds a wrongly signed or scaled channel and says
which factor to fix, refuses a finger that is not free or not at rest, tares a sensor offset,
keeps the drive at the pulse's torque meanwhile, and writes the offsets as the controller's
``<channel>.pressure_offset`` rows."""
import copy

import pytest
import yaml

from ethercat.inprocess import FakePysoem
from ethercat.lines import bus_yaml, line
from seaforce_ros.core.params import ControllerConfig
from seaforce_ros.ethercat.backend import EthercatBackend
from seaforce_ros.ethercat.bus_config import BusConfig
from seaforce_ros.ethercat.master import EthercatBus
from seaforce_ros.ethercat.power_on import check_bus, main, write_offsets
from seaforce_ros.identification import params_file as pf

HELD = {'mode': 'object', 'position': 0.0, 'stiffness': 50.0, 'damping': 0.5}
MOVING = {'mode': 'position_sine', 'amplitude': 0.3, 'frequency': 6.0}


def run(channels=None, environments=None, tweak=None, **emulator_keys):
    """The check on two emulated channels (c0, c1); ``tweak(yaml)`` changes the bus YAML."""
    emu = line('standard', 'standard', **emulator_keys)
    for name, env in (environments or {}).items():
        emu['channels'][name]['environment'] = env
    y = bus_yaml(emu)
    if tweak:
        tweak(y)
    fake = FakePysoem(emu)
    config = BusConfig.from_dict(y)
    backend = EthercatBackend(config, ('c0', 'c1'), 'inprocess', 5e-4,
                              bus=EthercatBus(config, 'inprocess', pysoem=fake))
    lines = []

    class Out:
        def write(self, text):
            lines.append(text)

    findings = check_bus(backend, channels or ['c0', 'c1'], None, pace=False, out=Out())
    return {f.channel: f for f in findings}, fake, ''.join(lines)


def steps(y, channel, key):
    return y['channels'][channel][key] if key != 'pressure' else \
        y['channels'][channel]['pressure']['steps']


@pytest.fixture(scope='module')
def free():
    """Both fingers free; c0's sensor reads +20 mN m at no force, c1's -10."""
    def offset(y):
        steps(y, 'c0', 'pressure')[2]['offset'] += 0.020
        steps(y, 'c1', 'pressure')[2]['offset'] -= 0.010
    return run(tweak=offset)


def test_free_fingers_pass_and_their_offsets_are_tared(free):
    found, fake, out = free
    for name, true in (('c0', 0.020), ('c1', -0.010)):
        f = found[name]
        assert f.passed, f.report()
        assert f.offset == pytest.approx(true, abs=2e-3), f.report()
        assert f.motion[0] > 0.05 and f.motion[1] < -0.05
        assert f.pressure_change[0] < 0 < f.pressure_change[1]
        assert f.velocity_ratio == pytest.approx(1.0, abs=0.05)
        assert 0.6 < f.torque_scale < 1.4
    # the drives were held to the pulse (0x6072 lowered) and given their max torque back
    assert '0x6072 = 212 per mille (19.2 % of the rated 0.5 N m)' in out
    assert all(fake.bus.slave(d).od.value(0x6072) == 32767 for d in ('drive0', 'drive1'))
    assert {fake.bus.slave(d).status()['al_state'] for d in ('drive0', 'drive1')} == {1}


def test_a_finger_that_is_not_free_or_not_at_rest_is_refused():
    found, _, _ = run(environments={'c0': HELD, 'c1': MOVING})
    assert found['c0'].refused.startswith('the finger is not free'), found['c0'].report()
    assert 'remove what holds or presses it' in found['c0'].refused
    assert found['c1'].refused.startswith('the motor moved'), found['c1'].report()
    assert not found['c0'].passed and not found['c1'].passed


def _mistake(y, mistake, channel):
    if mistake == 'position_sign':
        for key in ('position', 'velocity'):
            steps(y, channel, key)[0]['factor'] *= -1
    elif mistake == 'pressure_sign':
        chain = steps(y, channel, 'pressure')
        chain[2]['factor'] *= -1
        chain[2]['offset'] *= -1
    elif mistake == 'velocity_scale':
        steps(y, channel, 'velocity')[0]['factor'] *= 2
    else:                                          # 2^18 counts per turn taken for 2^20
        for key in ('position', 'velocity'):
            steps(y, channel, key)[0]['factor'] *= 4


@pytest.mark.parametrize('mistakes', [(('position_sign', 'negate the position and velocity '
                                        'factors'),
                                       ('pressure_sign', 'negate the pressure chain\'s factor')),
                                      (('velocity_scale', 'fix the velocity factor'),
                                       ('counts_per_turn', 'check the rated torque (0x6076) and '
                                        'the position scaling'))])
def test_a_wrongly_signed_or_scaled_channel_is_named_with_its_fix(mistakes):
    """One mistake per channel (c0, c1), each found and named with its fix, nothing else."""
    def tweak(y):
        for (mistake, _), channel in zip(mistakes, ('c0', 'c1')):
            _mistake(y, mistake, channel)
    found, _, _ = run(tweak=tweak)
    for (mistake, words), channel in zip(mistakes, ('c0', 'c1')):
        f = found[channel]
        assert not f.passed and not f.refused, f.report()
        assert len(f.problems) == 1 and words in f.problems[0], f.report()


def test_the_offsets_go_into_a_params_file_as_the_controller_reads_them(free, tmp_path):
    found, _, _ = free
    path = tmp_path / 'setup.yaml'
    path.write_text('# the setup\n/**:\n  ros__parameters:\n    c0:\n      mode: passive  # kept\n')
    write_offsets(str(path), list(found.values()))
    text = path.read_text()
    assert '# the setup' in text and 'mode: passive  # kept' in text
    keys = [spec.name for spec in ControllerConfig.rows()]
    for name, true in (('c0', 0.020), ('c1', -0.010)):
        view = pf.controller_view(pf.load(path), name, str(path), keys)
        config = ControllerConfig.from_dict(view.values)
        assert config.pressure_offset == pytest.approx(true, abs=2e-3)
    data = yaml.safe_load(text)
    assert set(data) == {'/**'}


def test_the_tool_says_what_is_wrong_in_one_line(tmp_path, capsys):
    bus = tmp_path / 'bus.yaml'
    bus.write_text(yaml.safe_dump(bus_yaml(line('standard', 'standard'))))
    code = main(['--interface', 'seaforce-no-such-if', '--bus-config', str(bus),
                 '--output', str(tmp_path / 'o.yaml')])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1 and 'seaforce-no-such-if' in err, err
    assert not (tmp_path / 'o.yaml').exists()
    bad = copy.deepcopy(bus_yaml(line('standard', 'standard')))
    bad['slaves'][0]['dc'] = {'assign_activate': 0x0100}
    bus.write_text(yaml.safe_dump(bad))
    assert main(['--interface', 'lo', '--bus-config', str(bus)]) == 2
    assert '0x0100 is not one of 0x0300, 0x0700' in capsys.readouterr().err

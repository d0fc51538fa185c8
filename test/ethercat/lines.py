"""Lines for the master's tests: an emulator configuration and the bus YAML that goes with it.

``line(profiles)`` builds drives of the given emulator profiles (channels c0, c1, ...), then a
coupler and, behind it, an EL3102-like terminal whose two inputs carry the first two
channels' pressure -- the rig's bus -- and ``bus_yaml(line)`` the bus YAML a user would write
for it: identities, the CST mapping (written at PRE-OP), the pressure chain, and per drive the
additions its profile needs (``needs``: SYNC0 for ``requires_dc``, 0x60C2 for
``requires_60c2``, the mode read over CoE for ``csp_start``'s YAML without 0x6060/0x6061).
"""

import copy

from ethercat.emulator.cia402 import DEFAULT_IDENTITY, PROFILES

CST_OUTPUTS = [['controlword', 0x6040, 0, 'u16'], ['target_torque', 0x6071, 0, 'i16'],
               ['mode_of_operation', 0x6060, 0, 'i8']]
CST_INPUTS = [['statusword', 0x6041, 0, 'u16'], ['position', 0x6064, 0, 'i32'],
              ['velocity', 0x606C, 0, 'i32'], ['torque', 0x6077, 0, 'i16'],
              ['mode_display', 0x6061, 0, 'i8'], ['error_code', 0x603F, 0, 'u16']]
#: what each profile needs in the YAML beyond the CST mapping
NEEDS = {
    'requires_dc': {'dc': {'assign_activate': 0x0300, 'sync0_shift_ns': 250000},
                    # a noisy test host: a generous sync error limit (a rig keeps the default)
                    'sdo': [[0x10F1, 2, 'u16', 1000]]},
    'requires_60c2': {'sdo': [[0x60C2, 1, 'u8', 5], [0x60C2, 2, 'i8', -4]]},
    'csp_start': {'outputs': CST_OUTPUTS[:2], 'inputs': CST_INPUTS[:4] + CST_INPUTS[5:]},
    'no_mailbox': {'inputs': CST_INPUTS[:5]},
}
PRESSURE = [{'factor': 3.0518509475997192e-04}, {'factor': 2.5e+5},
            {'factor': 1.0e-5, 'offset': -5.0}]
COUNTS = [{'factor': 5.992112452678286e-06}]
TERMINAL_ID = (0x00000002, 0x0C1E3052, 0x00100000)
COUPLER_ID = (0x00000002, 0x044C2C52, 0x00120000)


def line(*profiles, cycle_time=0.0005, **drive_keys):
    """Emulator configuration: a drive per profile, a coupler, the pressure terminal."""
    slaves = [dict({'type': 'cia402_drive', 'name': f'drive{i}', 'channel': f'c{i}',
                    'profile': p, 'serial': i + 1}, **drive_keys)
              for i, p in enumerate(profiles)]
    inputs = [{'channel': f'c{i}', 'quantity': 'pressure'} for i in range(min(2, len(profiles)))]
    slaves += [{'type': 'coupler', 'name': 'coupler'},
               {'type': 'analog_input', 'name': 'pressure_terminal', 'serial': 99,
                'inputs': inputs + [None] * (2 - len(inputs))}]
    return {'cycle_time': cycle_time, 'slaves': slaves,
            'channels': {f'c{i}': {'seed': i + 1} for i in range(len(profiles))}}


def bus_yaml(emulator, needs=True, **per_drive):
    """The bus YAML (a dict) of an emulator line from :func:`line`; ``per_drive`` maps a
    drive name to keys that replace (or, None, remove) its entry's."""
    slaves, channels = [], {}
    for spec in emulator['slaves']:
        if spec['type'] == 'cia402_drive':
            profile = spec.get('profile', 'standard')
            entry = {'name': spec['name'], 'kind': 'cia402_drive',
                     'vendor_id': DEFAULT_IDENTITY.vendor_id,
                     'product_code': spec.get('product_code', PROFILES[profile].product_code),
                     'revision': DEFAULT_IDENTITY.revision,
                     'outputs': copy.deepcopy(CST_OUTPUTS),
                     'inputs': copy.deepcopy(CST_INPUTS)}
            if needs:
                entry.update(copy.deepcopy(NEEDS.get(profile, {})))
            for key, value in per_drive.get(spec['name'], {}).items():
                if value is None:
                    entry.pop(key, None)
                else:
                    entry[key] = value
            slaves.append(entry)
            n = len(channels)
            channels[spec['channel']] = {
                'drive': spec['name'], 'rated_torque': 0.5, 'position': copy.deepcopy(COUNTS),
                'velocity': copy.deepcopy(COUNTS),
                'pressure': {'source': {'slave': 'pressure_terminal',
                                        'entry': f'value{n % 2 + 1}'},
                             'steps': copy.deepcopy(PRESSURE)}}
        elif spec['type'] == 'coupler':
            slaves.append({'name': spec['name'], 'kind': 'coupler', 'vendor_id': COUPLER_ID[0],
                           'product_code': COUPLER_ID[1], 'revision': COUPLER_ID[2]})
        else:
            slaves.append({'name': spec['name'], 'kind': 'analog_input',
                           'vendor_id': TERMINAL_ID[0], 'product_code': TERMINAL_ID[1],
                           'revision': TERMINAL_ID[2], 'outputs': [],
                           'inputs': [['status1', 0x6000, 0x01, 'u16'],
                                      ['value1', 0x6000, 0x11, 'i16'],
                                      ['status2', 0x6010, 0x01, 'u16'],
                                      ['value2', 0x6010, 0x11, 'i16']]})
    for name, keys in per_drive.get('channels', {}).items():
        for key, value in keys.items():
            if value is None:
                channels[name].pop(key, None)
            else:
                channels[name][key] = value
    return {'slaves': slaves, 'channels': channels}

"""Start-up validation and the ROS user's parameter path.

Every bad configuration of a node ends in ``[<executable>] cannot start: <parameter>: <reason>``,
exit code 2 and no traceback; a value is checked at declaration exactly as a later set would
check it; an integer for a float parameter is accepted; mode names are strings in YAML
(``passive``, never the YAML boolean ``off``), so a params file with every mode written
unquoted loads, and a ``ros2 param dump`` of the controller loads back (``ros2 param load``)
and starts a new controller; rejections name the whole parameter (``pinch.dob...``).
The processes are started as a user starts them: the installed executables with
``--ros-args``.
"""
import re
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
import yaml

from helpers.nodes import CONFIG, params_file, start_node
from helpers.processes import executable, run_until_exit

from seaforce_ros.nodes import bag_recorder, controller_node, hardware_node, param_specs, sim_node
from seaforce_ros.core.environment import ENVIRONMENT_MODES
from seaforce_ros.core.params import MODES
from seaforce_ros.ethercat.master import IFF_PROMISC, interface_flags

#: YAML 1.1 reads these (any capitalisation) as booleans: no string value the package uses
#: or suggests may be one of them.
YAML_BOOLEAN_WORDS = {'y', 'n', 'yes', 'no', 'on', 'off', 'true', 'false'}


def assert_refused(code, out, *names):
    assert code == 2, f'exit code {code}, expected 2:\n{out}'
    assert 'Traceback' not in out, out
    assert 'cannot start:' in out, out
    for name in names:
        assert name in out, f'{name!r} not named in:\n{out}'


# --- one bad value per case: (executable, node name, overrides, words the message names) ---
BAD_VALUES = [
    # a misspelt name: no node of the package declares it, and it is a typo away from one
    # this node declares (it once started with torque_limit at 20 N m, pinch.mode passive)
    ('sim_node', 'sim', {'torque_limt': 2.0}, ['torque_limt', 'did you mean torque_limit']),
    ('controller_node', 'controller', {'pinch.mod': 'hold'}, ['pinch.mod',
                                                                'did you mean pinch.mode']),
    ('bag_recorder', 'bag_recorder', {'topic': ['/joint_states']}, ['did you mean topics']),
    ('hardware_node', 'hardware', {'interfac': 'lo'}, ['did you mean interface']),
    # ... and a misspelt channel (it once left pinch's torque limit as it was)
    ('controller_node', 'controller', {'pnich.max_torque': 2.0},
     ['did you mean pinch.max_torque']),
    ('sim_node', 'sim', {'clock_mode': 'lockstepp'}, ['clock_mode', 'lockstep']),
    ('bag_recorder', 'bag_recorder', {'reliability': 'fast'}, ['reliability', 'best_effort']),
    ('controller_node', 'controller', {'executor': 'multi'}, ['executor', 'single_threaded']),
    ('controller_node', 'controller', {'control_qos': 'fast'}, ['control_qos']),
    ('sim_node', 'sim', {'control_qos': 'fast'}, ['control_qos']),
    ('controller_node', 'controller', {'channels': []}, ['channels']),
    ('sim_node', 'sim', {'channels': ['pinch', 'pinch']}, ['channel', 'unique']),
    ('controller_node', 'controller', {'pinch.max_torque': 2000}, ['pinch.max_torque', '1000']),
    ('controller_node', 'controller', {'pinch.max_torque': 'big'}, ['pinch.max_torque',
                                                                     'a number']),
    ('controller_node', 'controller', {'pinch.hold.stiffness': float('nan')},
     ['pinch.hold.stiffness', 'finite']),
    ('sim_node', 'sim', {'rate': True}, ['rate', 'a number']),
    ('sim_node', 'sim', {'seed': 1.5}, ['seed', 'integer']),
    ('sim_node', 'sim', {'pinch.environment.mode': 'wobble'}, ['pinch.environment.mode',
                                                                'position_sine']),
    # the nonlinear plant's rows: a range, and the rule between two of them
    ('sim_node', 'sim', {'pinch.sim.nonlinear.hose_stiffening': 5.0},
     ['pinch.sim.nonlinear.hose_stiffening', '[0, 1]']),
    ('sim_node', 'sim', {'pinch.sim.nonlinear.finger_ratio': 0.01,
                         'pinch.sim.nonlinear.finger_asymmetry': 0.5},
     ['pinch.sim.nonlinear.finger_asymmetry', 'dead point']),
    ('controller_node', 'controller', {'latched_faults': ['stale_state', 'gremlins']},
     ['latched_faults', 'gremlins']),
    ('controller_node', 'controller', {'status_rate': -1.0}, ['status_rate']),
    # an unquoted `off` is the YAML boolean false
    ('controller_node', 'controller', {'pinch.mode': False}, ['pinch.mode', 'quote']),
    # the old name, quoted: says what it is called now
    ('controller_node', 'controller', {'pinch.mode': 'off'}, ['pinch.mode', 'passive']),
    # the core's whole-configuration rejection, naming both parameters in full
    ('controller_node', 'controller', {'pinch.dob.nominal_inertia': 0.0},
     ['pinch.dob.nominal_inertia', 'set pinch.allow_non_passive to true']),
    ('bringup', 'controller', {'loop': 'dma'}, ['loop', 'direct']),
    ('hardware_node', 'hardware', {'command_timeout': 0.0}, ['command_timeout']),
]


BAD_VALUE_IDS = [f'{exe}-{"-".join(f"{k}={v}" for k, v in o.items())}'
                 for exe, _, o, _ in BAD_VALUES]


@pytest.fixture(scope='module')
def bad_value_runs(tmp_path_factory):
    """Every BAD_VALUES case run to its end, four at a time (each is a Python start-up)."""
    # the directories from this thread: the factory's first mktemp creates its base directory,
    # and from four threads at once that races (this file run alone: "bad1 is not a
    # normalized and relative path")
    directories = [tmp_path_factory.mktemp(f'bad{index}') for index in range(len(BAD_VALUES))]

    def run(case):
        index, (exe, node, overrides, _) = case
        directory = directories[index]
        argv = [str(executable(exe)), '--ros-args', '--params-file', str(CONFIG),
                '--params-file', str(params_file(node, overrides, directory))]
        if exe == 'hardware_node':
            argv += ['-p', 'interface:=lo']     # refused before the bus is touched
        return run_until_exit(argv)
    with ThreadPoolExecutor(max_workers=4) as pool:
        return list(pool.map(run, enumerate(BAD_VALUES)))


@pytest.mark.parametrize('case,names', [(i, c[3]) for i, c in enumerate(BAD_VALUES)],
                         ids=BAD_VALUE_IDS)
def test_bad_value_is_refused_at_start(bad_value_runs, case, names):
    code, out = bad_value_runs[case]
    assert_refused(code, out, *names)


# --- params files that are not params files ---------------------------------------------
PARAMS_FILES = {
    'missing': None,
    'directory': 'DIR',
    'empty': '',
    'comment_only': '# nothing here\n',
    'a_list': '- controller\n- sim\n',
    'a_scalar': 'controller\n',
    'not_yaml': 'controller: [\n',
    'no_ros__parameters': 'controller:\n  channels: [pinch]\n',
    'ros__parameters_a_list': 'controller:\n  ros__parameters: [1, 2]\n',
    'binary': b'\xff\xfe\x00garbage',
}


@pytest.fixture(scope='module')
def params_file_runs(tmp_path_factory):
    """controller_node started on each PARAMS_FILES case, four at a time: {case: (path,
    exit code, output)}."""
    directory = tmp_path_factory.mktemp('params_files')

    def run(case):
        content = PARAMS_FILES[case]
        path = directory / f'{case}.yaml'
        if content == 'DIR':
            path.mkdir()
        elif isinstance(content, bytes):
            path.write_bytes(content)
        elif content is not None:
            path.write_text(content)
        return (path, *run_until_exit([str(executable('controller_node')), '--ros-args',
                                       '--params-file', str(path)]))
    with ThreadPoolExecutor(max_workers=4) as pool:
        return dict(zip(sorted(PARAMS_FILES), pool.map(run, sorted(PARAMS_FILES))))


@pytest.mark.parametrize('case', sorted(PARAMS_FILES))
def test_unusable_params_file_is_refused(params_file_runs, case):
    path, code, out = params_file_runs[case]
    assert_refused(code, out, '--params-file', str(path))


def test_missing_interface_is_refused(tmp_path):
    code, out = run_until_exit([str(executable('hardware_node')), '--ros-args',
                                '--params-file', str(CONFIG)])
    assert_refused(code, out, 'interface')


@pytest.mark.parametrize('promiscuous_before', [False, True])
def test_failed_hardware_start_restores_the_interface(promiscuous_before):
    """SOEM switches the interface to promiscuous mode; a start that fails (no slave answers
    on loopback) must leave the flag as it was."""
    subprocess.run(['ip', 'link', 'set', 'lo', 'promisc', 'on' if promiscuous_before else 'off'],
                   check=True)
    try:
        code, out = run_until_exit([str(executable('hardware_node')), '--ros-args',
                                    '--params-file', str(CONFIG), '-p', 'interface:=lo'])
        assert_refused(code, out, 'no EtherCAT slave answered on lo')
        assert bool(interface_flags('lo') & IFF_PROMISC) == promiscuous_before
    finally:
        subprocess.run(['ip', 'link', 'set', 'lo', 'promisc', 'off'], check=True)


def test_unknown_interface_is_refused():
    code, out = run_until_exit([str(executable('hardware_node')), '--ros-args',
                                '--params-file', str(CONFIG), '-p', 'interface:=nosuch7'])
    assert_refused(code, out, "no network interface 'nosuch7'")


# --- arguments a node does not take -----------------------------------------------------
UNKNOWN_ARGUMENTS = [
    ('bag_recorder', ['--bogus']),
    ('bag_recorder', ['run1']),                          # a stray positional
    ('bag_recorder', ['--output', 'run1']),              # a parameter without -p
    ('sim_node', ['--bogus']),
    ('controller_node', ['--ros-args', '-p', 'status_rate:=50.0', '--', '--bogus']),
    ('bringup', ['--bogus']),
    ('hardware_node', ['--bogus']),
]


@pytest.fixture(scope='module')
def unknown_argument_runs(tmp_path_factory):
    """Every UNKNOWN_ARGUMENTS case run to its end in a directory of its own, four at a time:
    [(directory, exit code, output)]."""
    directories = [tmp_path_factory.mktemp(f'args{i}') for i in range(len(UNKNOWN_ARGUMENTS))]

    def run(case):
        directory, (exe, args) = case
        argv = [str(executable(exe)), *args]
        if '--ros-args' not in args:
            argv += ['--ros-args', '--params-file', str(CONFIG)]
        return (directory, *run_until_exit(argv, cwd=directory))
    with ThreadPoolExecutor(max_workers=4) as pool:
        return list(pool.map(run, zip(directories, UNKNOWN_ARGUMENTS)))


@pytest.mark.parametrize('case', range(len(UNKNOWN_ARGUMENTS)),
                         ids=[f'{e}-{"_".join(a)}' for e, a in UNKNOWN_ARGUMENTS])
def test_unknown_arguments_are_refused(unknown_argument_runs, case):
    """A node takes ROS arguments only: anything else is named in one line, exit 2, before
    the node does anything (bag_recorder records nothing)."""
    directory, code, out = unknown_argument_runs[case]
    exe, args = UNKNOWN_ARGUMENTS[case]
    assert_refused(code, out, 'unknown argument', exe)
    extra = args[args.index('--') + 1:] if '--' in args else args
    assert f'unknown argument(s) {" ".join(extra)}:' in out, out
    assert len(out.strip().splitlines()) == 1, out
    assert not list(directory.iterdir()), list(directory.iterdir())


def test_help_is_no_unknown_argument():
    code, out = run_until_exit([str(executable('sim_node')), '--help'])
    assert code == 0 and out.startswith('usage: sim_node [--ros-args'), out


# --- the free finger's damping reserve ----------------------------------------------------
def test_a_model_whose_band_the_reserve_does_not_hold_is_warned_about(processes, tmp_path,
                                                                       probe):
    """A hand-typed pinch model (softer hose, more b_e) whose +-20 % band the shipped reserve
    leaves small-signal unstable: one warning at start-up, naming the reserve that holds it;
    the wrist (Table I) is not warned about; the node runs. At run time (a child process
    checks each accepted change of the model, the feed-forward or the DOB): the reserve the
    warning named is said to hold the band again; the wrist's reserve set to 0 is warned
    about; a set of the limits only starts no check."""
    proc = start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'pinch.plant.hose_stiffness': 13.0782 * 0.6,
                       'pinch.plant.endpoint_damping': 3.3879e-2 * 1.5})
    out = proc.output()
    assert out.count('may oscillate or creep') == 1, out
    assert 'pinch: feedforward.damping_reserve = 0.01 ' in out and 'holds it' in out, out
    assert 'wrist: feedforward.damping_reserve' not in out, out
    named = float(re.search(r'; ([0-9.e-]+) N m s/rad holds it', out).group(1))
    assert 0.01 < named <= 0.1

    ok, reason = probe.set_parameters('/controller', {'pinch.feedforward.damping_reserve': named})
    assert ok, reason
    assert proc.wait_for_output('pinch: after the parameter change the damping reserve holds',
                                timeout=60), proc.output()
    ok, reason = probe.set_parameters('/controller', {'wrist.max_torque': 10.0,
                                                      'wrist.feedforward.damping_reserve': 0.0})
    assert ok, reason
    assert proc.wait_for_output('wrist: after the parameter change: feedforward.damping_reserve'
                                ' = 0 N m s/rad leaves a free finger', timeout=60), proc.output()
    ok, reason = probe.set_parameters('/controller', {'pinch.max_torque': 10.0})
    assert ok, reason
    time.sleep(2.0)     # (a check would have answered by now: 1 s of a child's CPU)
    out = proc.output()
    assert out.count('after the parameter change') == 2, out
    assert 'did not run' not in out and 'Traceback' not in out, out


def test_the_nominal_inertia_follows_the_given_motor_inertia(processes, tmp_path, probe):
    """dob.nominal_inertia unset (the shipped file leaves it to its default, the plant's m):
    an identified m of 0.002 -- above what Table I's m_n passes in eq. 28 -- starts the node
    with m_n = 0.002 (before: 'cannot start', eq. 28 against Table I's m_n)."""
    proc = start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'pinch.plant.motor_inertia': 0.002})
    assert 'cannot start' not in proc.output()
    got = probe.get_parameters('/controller', ['pinch.dob.nominal_inertia',
                                               'wrist.dob.nominal_inertia'])
    assert got == {'pinch.dob.nominal_inertia': 0.002, 'wrist.dob.nominal_inertia': 1.1116e-3}


# --- integers for float parameters -----------------------------------------------------
def test_integer_for_a_float_parameter_is_accepted(processes, tmp_path, probe):
    proc = start_node(processes, 'controller_node', 'controller', tmp_path,
                      {'pinch.max_torque': 20, 'state_timeout': 1})
    assert 'Traceback' not in proc.output()
    # its housekeeping timers on a steady clock of their own: rclpy's EventsExecutor printed
    # a warning for each timer from the eighth on the node's clock (four at every start)
    assert 'number of timers associated with this clock' not in proc.output(), proc.output()
    got = probe.get_parameters('/controller', ['pinch.max_torque', 'state_timeout'])
    assert got == {'pinch.max_torque': 20.0, 'state_timeout': 1.0}
    assert all(type(v) is float for v in got.values())
    # what `ros2 param set /controller pinch.max_torque 15` sends: an INTEGER parameter
    ok, reason = probe.set_parameters('/controller', {'pinch.max_torque': 15}, atomic=False)
    assert ok, reason
    assert probe.get_parameters('/controller', ['pinch.max_torque']) == {'pinch.max_torque': 15.0}
    # and the checks still hold for integers
    ok, reason = probe.set_parameters('/controller', {'pinch.max_torque': 5000}, atomic=False)
    assert not ok


def test_set_rejection_names_the_whole_parameter(processes, tmp_path, probe):
    start_node(processes, 'controller_node', 'controller', tmp_path)
    ok, reason = probe.set_parameters('/controller', {'pinch.dob.nominal_inertia': 1e-5},
                                      atomic=False)
    assert not ok
    assert 'pinch.dob.nominal_inertia' in reason, reason
    assert 'set pinch.allow_non_passive to true' in reason, reason
    ok, reason = probe.set_parameters('/controller', {'wrist.target.stiffness': 1e3},
                                      atomic=False)
    assert not ok and 'wrist.target.stiffness' in reason and 'wrist.allow_non_passive' in reason


# --- mode names that survive YAML, dump and load ----------------------------------------
def _all_specs():
    specs = (controller_node.node_specs() + sim_node.node_specs() + bag_recorder.node_specs()
             + hardware_node.node_specs())
    for channel in ('pinch',):
        specs += param_specs.controller_channel_specs(channel)
        specs += param_specs.sim_channel_specs(channel)
    return specs


def test_no_string_value_is_a_yaml_boolean():
    """Every string default and choice of every parameter, every mode and environment name,
    read back from YAML unquoted, stays the same string."""
    words = set(MODES) | set(ENVIRONMENT_MODES)
    for spec in _all_specs():
        words |= set(spec.choices)
        if isinstance(spec.default, str) and spec.default:
            words.add(spec.default)
        if spec.type is list:
            words |= set(spec.default)
    assert 'passive' in words and len(words) > 20
    for word in sorted(words):
        assert word.lower() not in YAML_BOOLEAN_WORDS, word
        assert yaml.safe_load(f'key: {word}') == {'key': word}, word


#: One channel per mode, named after it: one controller holds every mode word at once.
MODE_CHANNELS = {f'm_{mode}': mode for mode in MODES}


def _dump(probe, node):
    """What `ros2 param dump <node>` writes: every parameter, nested at the dots, under
    ``<node>: ros__parameters:``."""
    from rclpy.parameter import parameter_value_to_python
    client = probe._param_client(node)
    names = probe._request(lambda: client.list_parameters(), 10, 'list').result.names
    values = probe._request(lambda: client.get_parameters(names), 10, 'get').values
    tree = {}
    for name, value in sorted(zip(names, values)):
        *heads, leaf = name.split('.')
        branch = tree
        for head in heads:
            branch = branch.setdefault(head, {})
        branch[leaf] = parameter_value_to_python(value)
    return yaml.dump({node: {'ros__parameters': tree}}, default_flow_style=False)


def test_unquoted_modes_load_and_dump_load_round_trip(processes, tmp_path, probe):
    """Every mode word, unquoted in a params file, loads as that string; `ros2 param dump`
    writes it unquoted and `ros2 param load` / a restart from the dump read it back (one
    controller with a channel per mode: every word in one start)."""
    unquoted = tmp_path / 'modes.yaml'
    unquoted.write_text('controller:\n  ros__parameters:\n'
                        f'    channels: [{", ".join(MODE_CHANNELS)}]\n'
                        + ''.join(f'    {channel}:\n      mode: {mode}\n'
                                  for channel, mode in MODE_CHANNELS.items()))
    proc = start_node(processes, 'controller_node', 'controller', tmp_path,
                      ros_args=('--params-file', str(unquoted)))
    modes = {f'{channel}.mode': mode for channel, mode in MODE_CHANNELS.items()}
    assert probe.get_parameters('/controller', list(modes)) == modes
    dumped = tmp_path / 'dump.yaml'
    dumped.write_text(_dump(probe, '/controller'))
    for mode in MODES:
        assert f'mode: {mode}\n' in dumped.read_text(), mode      # written unquoted

    # `ros2 param load /controller dump.yaml`: every parameter that may change at run time
    # is set from the file; the read-only ones are refused as read-only, nothing else
    client = probe._param_client('/controller')
    results = probe._request(lambda: client.load_parameter_file(str(dumped)), 10,
                             'load').results
    loaded = yaml.safe_load(dumped.read_text())
    assert len(results) > 50 * len(MODES)
    for result in results:
        assert result.successful or 'read-only' in result.reason, result.reason
    assert sum(r.successful for r in results) > 40 * len(MODES)

    # and a new controller starts from the dump with the same modes
    proc.stop()
    start_node(processes, 'controller_node', 'controller', tmp_path,
               ros_args=('--params-file', str(dumped)))
    assert probe.get_parameters('/controller', list(modes)) == modes
    for channel, mode in MODE_CHANNELS.items():
        assert loaded['/controller']['ros__parameters'][channel]['mode'] == mode


# --- -p after the shipped params file ----------------------------------------------------
#: Keys the shipped file set in node sections before (its `/**/sim:` and `/**/controller:`)
#: and the safety limits a user types: each must be the value `-p` gives after the file.
COMMAND_LINE_KEYS = ('torque_limit', 'max_velocity', 'command_timeout', 'clock_mode', 'rate',
                     'joint_state_rate', 'state_timeout', 'status_rate')


def _other_value(spec):
    """A valid value of ``spec`` other than its default (what a user would type)."""
    default = spec.default
    if spec.type is bool:
        return not default
    if spec.name == 'channels':
        return list(reversed(default))
    if spec.type is list:
        return list(spec.choices[:1]) if spec.choices else ['actuator_state']
    if spec.choices:
        return next(c for c in spec.choices if c != default)
    if spec.type is str:
        return 'eth7' if spec.name == 'interface' else 'run1'
    step = 1 if spec.type is int else 0.5 * abs(default or 1.0)
    for value in (default + step, default - step, default + 2 * step):
        value = spec.type(value)
        if spec.reason(value) is None and value != default:
            return value
    raise AssertionError(f'no other value for {spec.name}')


def _yaml(value):
    """``value`` as `-p NAME:=VALUE` writes it."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, list):
        return '[' + ', '.join(value) + ']'
    return repr(value) if isinstance(value, float) else str(value)


def _node_specs(node, channels):
    if node == 'sim':
        return sim_node.node_specs() + [s for c in channels
                                        for s in param_specs.sim_channel_specs(c)]
    if node == 'controller':
        return controller_node.node_specs() + [s for c in channels
                                               for s in param_specs.controller_channel_specs(c)]
    return {'hardware': hardware_node.node_specs, 'bag_recorder': bag_recorder.node_specs}[node]()


@pytest.mark.parametrize('node', ['sim', 'controller', 'hardware', 'bag_recorder'])
def test_command_line_wins_over_the_shipped_params_file(node):
    """Every read-only key of every node, and the limits and modes a user types, set with
    ``-p`` after ``--params-file config/gripper.yaml`` (the README's command lines) are the
    values the node declares: rcl applies a node's own section of a file after the ``/**``
    one the ``-p`` values join, so the shipped file has none."""
    import rclpy
    from rclpy.context import Context
    from seaforce_ros.nodes.ros_common import declare

    channels = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']['channels']
    specs = _node_specs(node, channels)
    wanted = {s.name: _other_value(s) for s in specs
              if s.read_only or s.name in COMMAND_LINE_KEYS}
    assert len(wanted) > 3, wanted
    argv = ['node', '--ros-args', '--params-file', str(CONFIG)]
    for name, value in wanted.items():
        argv += ['-p', f'{name}:={_yaml(value)}']
    context = Context()
    rclpy.init(args=argv, context=context)
    try:
        ros_node = rclpy.create_node(node, context=context)
        try:
            values = declare(ros_node, specs)
        finally:
            ros_node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    assert {name: values[name] for name in wanted} == wanted


def test_names_no_node_declares():
    """:func:`check_undeclared` on a node given these names (in-process, its own context): a
    typo of one it declares is refused naming both; another package's name passes with a
    warning; a name another node of this package declares (the shipped file holds them all),
    a per-channel one of any channel and rclpy's own pass silently."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from seaforce_ros.nodes.ros_common import StartupError, check_undeclared

    def node_with(**given):
        node = rclpy.create_node(
            'check_undeclared_probe', context=context,
            parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])
        node.declare_parameter('torque_limit', 20.0)
        node.declare_parameter('pinch.mode', 'passive')
        return node

    context = Context()
    rclpy.init(context=context)
    warnings = []
    try:
        for given, refused in (({'torque_limt': 2.0}, 'did you mean torque_limit'),
                               ({'pinch.mod': 'hold'}, 'did you mean pinch.mode')):
            node = node_with(**given)
            with pytest.raises(StartupError, match=refused):
                check_undeclared(node)
            node.destroy_node()
        quiet = node_with(**{'interface': 'eth9', 'pinch.dob.cutoff': 100.0,
                             'thumb.sim.plant.motor_inertia': 1e-3, 'use_sim_time': False,
                             'qos_overrides./x.publisher.depth': 5})
        quiet.get_logger().warning = warnings.append
        check_undeclared(quiet)
        assert warnings == []
        foreign = node_with(other_pkg_gain=1.0)
        foreign.get_logger().warning = warnings.append
        check_undeclared(foreign)
        assert len(warnings) == 1 and 'ignored: other_pkg_gain' in warnings[0], warnings
    finally:
        rclpy.shutdown(context=context)

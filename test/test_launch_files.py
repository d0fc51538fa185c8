"""The launch files in launch/ (installed to share/seaforce_ros/launch), checked without the
launch package (not on PyPI): every <node> names an installed executable of this package,
every $(find-pkg-share seaforce_ros)/... file is installed, every $(var X) is a declared
<arg>, every <include> exists and gets only arguments it declares, every parameter a node is
given is one that node declares, with the declared type and allowed values (the schema
tables of the node modules), the hardware files require `interface`, and the installed
copies are the sources. Nodes of other packages (robot_state_publisher, from a ROS
installation) must be exec_depends of package.xml; a $(command 'xacro FILE name:=value ...')
must name an installed xacro file and only arguments it declares.

Each check is a function returning a list of problems; the tests expect none for the shipped
files and, on small broken samples, the problem each check exists for.
"""
import ast
import pathlib
import re
import xml.etree.ElementTree as ET

import pytest
import yaml

from helpers.processes import INSTALL_LIB, ROOT

from seaforce_ros.nodes import bag_recorder, controller_node, hardware_node, param_specs, sim_node
from seaforce_ros.core.params import MODES

PACKAGE = 'seaforce_ros'
LAUNCH_DIR = ROOT / 'launch'
SHARE = ROOT / 'install' / PACKAGE / 'share' / PACKAGE
SOURCES = sorted(LAUNCH_DIR.glob('*.launch.xml'))
EXPECTED = {'sim', 'bringup', 'hardware', 'hardware_bringup', 'record', 'display'}
DEFAULT_PARAMS = '$(find-pkg-share seaforce_ros)/config/gripper.yaml'
#: YAML 1.1 reads these as booleans (launch_ros reads untyped <param> values as YAML).
YAML11_BOOLS = {'y', 'yes', 'n', 'no', 'true', 'false', 'on', 'off'}
SUBST = re.compile(r'\$\(([\w-]+)((?:\s+[^)\s]+)*)\s*\)')
#: $(command 'xacro ...'): the whole substitution and the command line inside it.
XACRO_COMMAND = re.compile(r"\$\(command '(xacro\s[^']*)'\)")
#: one word of a command line, a $(...) inside it kept whole
COMMAND_WORD = re.compile(r'(?:\$\([^)]*\)|[^\s$])+')

# --- what each executable runs -------------------------------------------------------------
#: executable -> nodes it creates (the composed ones have two: no `name` remap allowed).
NODES = {'sim_node': ('sim',), 'controller_node': ('controller',),
         'hardware_node': ('hardware',), 'bag_recorder': ('bag_recorder',),
         'bringup': ('controller', 'sim'), 'hardware_bringup': ('controller', 'hardware')}
PLANT_EXECS = {'sim_node', 'hardware_node', 'bringup', 'hardware_bringup'}
CONTROLLER_EXECS = {'controller_node', 'bringup', 'hardware_bringup'}
HARDWARE_EXECS = {'hardware_node', 'hardware_bringup'}
COMPOSED_EXECS = {'bringup', 'hardware_bringup'}
#: nodes of other packages, from the ROS installation: (pkg, exec) -> node name.
FOREIGN_NODES = {('robot_state_publisher', 'robot_state_publisher'): 'robot_state_publisher'}


def exec_depends():
    """The <exec_depend> packages of package.xml."""
    root = ET.parse(ROOT / 'package.xml').getroot()
    return {e.text.strip() for e in root.iter('exec_depend')}


def default_channels():
    data = yaml.safe_load((ROOT / 'config' / 'gripper.yaml').read_text())
    return list(data['/**']['ros__parameters']['channels'])


def node_specs(node, channels):
    """name -> Spec of everything ``node`` declares (the schema's rows, as the node declares
    them)."""
    if node == 'controller':
        specs = list(controller_node.node_specs())
        for channel in channels:
            specs += param_specs.controller_channel_specs(channel)
    elif node == 'sim':
        specs = list(sim_node.node_specs())
        for channel in channels:
            specs += param_specs.sim_channel_specs(channel)
    elif node == 'hardware':
        specs = list(hardware_node.node_specs())
    elif node == 'bag_recorder':
        specs = list(bag_recorder.node_specs())
    else:
        raise KeyError(node)
    return {s.name: s for s in specs}


def exec_specs(executable, channels):
    """Parameters the process of ``executable`` declares, over all its nodes."""
    specs = {}
    for node in NODES[executable]:
        specs.update(node_specs(node, channels))
    if executable in COMPOSED_EXECS:   # ControllerNode(composed=True) adds it
        specs.update({s.name: s for s in param_specs.node_specs('bringup')})
    return specs


def console_scripts():
    """Executable names from setup.py's CONSOLE_SCRIPTS (read, not run)."""
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == 'CONSOLE_SCRIPTS' for t in node.targets):
            return {entry.split('=')[0].strip() for entry in ast.literal_eval(node.value)}
    raise AssertionError('CONSOLE_SCRIPTS not found in setup.py')


# --- parsing -------------------------------------------------------------------------------
def parse(source):
    """Root <launch> element of a path or of XML text."""
    root = (ET.parse(source).getroot() if isinstance(source, pathlib.Path)
            else ET.fromstring(source))
    assert root.tag == 'launch', root.tag
    return root


def parent_map(root):
    return {child: parent for parent in root.iter() for child in parent}


def declared_args(root):
    """name -> <arg> element of the file's declared arguments (direct children of <launch>)."""
    return {a.get('name'): a for a in root.findall('arg')}


def substitutions(text):
    """[(kind, [arguments])] of every $(...) in ``text``."""
    return [(m.group(1), m.group(2).split()) for m in SUBST.finditer(text or '')]


def resolve_share(path_text):
    """'$(find-pkg-share seaforce_ros)/x/y' -> SHARE/x/y, else None."""
    prefix = f'$(find-pkg-share {PACKAGE})/'
    if path_text and path_text.startswith(prefix) and '$(' not in path_text[len(prefix):]:
        return SHARE / path_text[len(prefix):]
    return None


def all_attribute_values(root):
    for element in root.iter():
        for key, value in element.attrib.items():
            yield element, key, value


# --- checks (each returns a list of problems) ----------------------------------------------
def check_nodes(root, installed=INSTALL_LIB, scripts=None):
    scripts = console_scripts() if scripts is None else scripts
    problems = []
    nodes = root.iter('node')
    for node in nodes:
        pkg, exe = node.get('pkg'), node.get('exec')
        if (pkg, exe) in FOREIGN_NODES:
            if pkg not in exec_depends():
                problems.append(f'node pkg={pkg!r}: not an exec_depend of package.xml')
            if node.get('name') not in (None, FOREIGN_NODES[pkg, exe]):
                problems.append(f'{exe}: name={node.get("name")!r}, the node calls itself '
                                f'{FOREIGN_NODES[pkg, exe]!r}')
            continue
        if pkg != PACKAGE:
            problems.append(f'node pkg={pkg!r}: not {PACKAGE}')
        if exe not in scripts:
            problems.append(f'node exec={exe!r}: not in setup.py CONSOLE_SCRIPTS')
        path = installed / str(exe)
        if not path.is_file():
            problems.append(f'node exec={exe!r}: {path} is not installed')
        if exe not in NODES:
            problems.append(f'node exec={exe!r}: this test does not know its nodes')
            continue
        name = node.get('name')
        if name is not None and len(NODES[exe]) > 1:
            problems.append(f'{exe}: name={name!r} would rename every node of the process')
        elif name is not None and name != NODES[exe][0]:
            problems.append(f'{exe}: name={name!r}, the node calls itself {NODES[exe][0]!r}')
    return problems


def xacro_args(path):
    """Names of the <xacro:arg>s a xacro file declares."""
    namespace = '{http://www.ros.org/wiki/xacro}'
    return {a.get('name') for a in ET.parse(path).getroot().iter(namespace + 'arg')}


def check_xacro_command(command, args):
    """``xacro FILE name:=value ...``: FILE installed, each name a <xacro:arg> of it, each
    value a plain word or a $(var X) of a declared launch argument."""
    words = COMMAND_WORD.findall(command)
    path = resolve_share(words[1]) if len(words) > 1 else None
    if path is None or not path.is_file():
        return [f'$(command {command!r}): not an installed $(find-pkg-share {PACKAGE}) file']
    problems = []
    declared = xacro_args(path)
    for word in words[2:]:
        name, sep, value = word.partition(':=')
        if not sep or name not in declared:
            problems.append(f'$(command ...): {word!r} is no argument of {path.name} '
                            f'({sorted(declared)})')
        for kind, arguments in substitutions(value):
            if kind != 'var' or arguments[0] not in args:
                problems.append(f'$(command ...): {value!r} is not a $(var X) of a declared '
                                '<arg>')
    return problems


def check_substitutions(root):
    """Only $(var X) of declared args, $(find-pkg-share seaforce_ros) of existing files and
    $(command 'xacro ...') of an installed xacro file (:func:`check_xacro_command`)."""
    problems = []
    args = declared_args(root)
    for element, key, value in all_attribute_values(root):
        for command in XACRO_COMMAND.findall(value):
            problems += check_xacro_command(command, args)
        value = XACRO_COMMAND.sub('', value)
        for kind, arguments in substitutions(value):
            if kind == 'var':
                if arguments[0] not in args:
                    problems.append(f'$(var {arguments[0]}) in <{element.tag} {key}=...> is '
                                    'not a declared <arg>')
            elif kind == 'find-pkg-share':
                if arguments != [PACKAGE]:
                    problems.append(f'$(find-pkg-share {" ".join(arguments)}): not {PACKAGE}')
            else:
                problems.append(f'$({kind} ...) in <{element.tag} {key}=...>: this test '
                                'cannot check it')
        if '$(find-pkg-share' in value:
            path = resolve_share(value)
            if path is None:
                problems.append(f'{value!r}: not a plain $(find-pkg-share {PACKAGE})/path')
            elif not path.is_file():
                problems.append(f'{value!r}: {path} is not installed')
    # arguments come first, so every $(var) reads an argument declared before it
    seen_other = False
    for child in root:
        if child.tag == 'arg' and seen_other:
            problems.append(f'<arg name={child.get("name")!r}> after other actions')
        seen_other = seen_other or child.tag != 'arg'
    return problems


def check_includes(root):
    problems = []
    for include in root.iter('include'):
        path = resolve_share(include.get('file'))
        if path is None or not path.is_file():
            problems.append(f'<include file={include.get("file")!r}>: not an installed file')
            continue
        included_args = declared_args(parse(path))
        for arg in include.findall('arg'):
            if arg.get('name') not in included_args:
                problems.append(f'<include> passes {arg.get("name")!r}, which '
                                f'{path.name} does not declare')
        for name, arg in included_args.items():
            if arg.get('default') is None and name not in {
                    a.get('name') for a in include.findall('arg')}:
                problems.append(f'<include> of {path.name} misses its required {name!r}')
    return problems


def _typed(text, type_name):
    return {'str': str, 'float': float, 'int': int}[type_name](text) if type_name != 'bool' \
        else {'true': True, 'false': False}[text.lower()]


def check_parameters(root, channels):
    """Every <param name=...> is declared by the node, with its type and allowed values."""
    problems = []
    args = declared_args(root)
    type_names = {str: 'str', float: 'float', int: 'int', bool: 'bool', list: 'list_of_str'}
    for node in root.iter('node'):
        exe = node.get('exec')
        if exe not in NODES:
            continue
        specs = exec_specs(exe, channels)
        files = [p.get('from') for p in node.findall('param') if p.get('from')]
        if files != ['$(var params_file)']:
            problems.append(f'{exe}: parameter files {files}, expected $(var params_file) once')
        for param in node.findall('param'):
            name = param.get('name')
            if name is None:
                continue
            spec = specs.get(name)
            if spec is None:
                problems.append(f'{exe}: parameter {name!r} is not declared by '
                                f'{"/".join(NODES[exe])}')
                continue
            expected_type = type_names[spec.type]
            if param.get('type') != expected_type:
                problems.append(f'{exe}: <param name={name!r}> needs type="{expected_type}" '
                                f'(declared {expected_type}; untyped values are read as YAML)')
            value = param.get('value', '')
            whole_var = re.fullmatch(r'\$\(var (\w+)\)', value)
            if whole_var:
                arg = args.get(whole_var.group(1))
                if arg is None:
                    continue    # check_substitutions reports it
                choices = [c.get('value') for c in arg.findall('choice')]
                if spec.choices and set(choices) != set(spec.choices):
                    problems.append(f'{exe}: arg {arg.get("name")!r} offers {choices}, '
                                    f'{name} accepts {list(spec.choices)}')
                candidates = choices + ([arg.get('default')] if arg.get('default') else [])
            elif '$(' in value:
                problems.append(f'{exe}: <param name={name!r}> value {value!r} is not a '
                                'single $(var X)')
                continue
            else:
                candidates = [value]
            for candidate in candidates:
                if candidate.startswith('$('):
                    continue
                if expected_type == 'str' and candidate.lower() in YAML11_BOOLS:
                    problems.append(f'{exe}: {name} may be set to {candidate!r}, a YAML 1.1 '
                                    'boolean')
                try:
                    typed = _typed(candidate, expected_type)
                except (ValueError, KeyError):
                    problems.append(f'{exe}: {name}={candidate!r} is not a {expected_type}')
                    continue
                reason = spec.reason(typed, name)
                if reason is None and spec.low is not None and typed < spec.low:
                    reason = f'{name} below {spec.low}: {typed}'
                if reason is None and spec.high is not None and typed > spec.high:
                    reason = f'{name} above {spec.high}: {typed}'
                if reason:
                    problems.append(f'{exe}: {reason}')
    return problems


def check_namespace(root):
    """Every node sits in a <group> that first pushes $(var namespace)."""
    problems = []
    parents = parent_map(root)
    for node in root.iter('node'):
        group = parents.get(node)
        push = group.find('push-ros-namespace') if group is not None else None
        if group is None or group.tag != 'group' or push is None \
                or push.get('namespace') != '$(var namespace)' or list(group)[0] is not push:
            problems.append(f'{node.get("exec")}: not in a group that first pushes '
                            '$(var namespace)')
    return problems


def check_gripper_arguments(root, channels):
    """params_file, namespace, a starting mode per channel, interface/loop where they apply."""
    problems = []
    args = declared_args(root)
    execs = {n.get('exec') for n in root.iter('node')}
    params = {(n.get('exec'), p.get('name')): p.get('value')
              for n in root.iter('node') for p in n.findall('param') if p.get('name')}
    if args.get('params_file') is None or args['params_file'].get('default') != DEFAULT_PARAMS:
        problems.append(f'arg params_file must default to {DEFAULT_PARAMS}')
    if args.get('namespace') is None or args['namespace'].get('default') != '':
        problems.append('arg namespace must exist with default ""')
    for exe in execs & CONTROLLER_EXECS:
        for channel in channels:
            arg = args.get(f'{channel}_mode')
            if arg is None or arg.get('default') != 'passive':
                problems.append(f'arg {channel}_mode must exist with default passive')
            if params.get((exe, f'{channel}.mode')) != f'$(var {channel}_mode)':
                problems.append(f'{exe}: {channel}.mode is not set from $(var {channel}_mode)')
    for exe in execs & HARDWARE_EXECS:
        arg = args.get('interface')
        if arg is None or 'default' in arg.attrib:
            problems.append('arg interface must be declared with no default (required)')
        if params.get((exe, 'interface')) != '$(var interface)':
            problems.append(f'{exe}: interface is not set from $(var interface)')
    for exe in execs & COMPOSED_EXECS:
        arg = args.get('loop')
        if arg is None or arg.get('default') != 'topics':
            problems.append('arg loop must exist with default topics')
        if params.get((exe, 'loop')) != '$(var loop)':
            problems.append(f'{exe}: loop is not set from $(var loop)')
    return problems


def check_words(text):
    """The mode formerly named for "motors off" is gone, and the word with it (YAML boolean)."""
    return [f'the word {m.group(0)!r} at offset {m.start()}'
            for m in re.finditer(r'\boff\b', text, re.IGNORECASE)]


# --- the shipped files ---------------------------------------------------------------------
@pytest.fixture(scope='module')
def channels():
    return default_channels()


def test_the_expected_launch_files_exist_and_parse():
    assert {p.name[:-len('.launch.xml')] for p in SOURCES} >= EXPECTED, SOURCES
    for path in SOURCES:
        parse(path)


def test_installed_launch_files_are_the_sources():
    installed = sorted((SHARE / 'launch').glob('*.launch.xml'))
    assert [p.name for p in installed] == [p.name for p in SOURCES], \
        'rebuild: source scripts/setup.sh'
    for source in SOURCES:
        assert (SHARE / 'launch' / source.name).read_bytes() == source.read_bytes(), source.name


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_nodes_name_installed_executables_of_this_package(path):
    root = parse(path)
    assert list(root.iter('node')), 'a launch file that starts nothing'
    assert check_nodes(root) == []


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_substitutions_name_declared_args_and_installed_files(path):
    assert check_substitutions(parse(path)) == []


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_includes_exist_and_get_only_declared_args(path):
    assert check_includes(parse(path)) == []


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_parameters_are_declared_by_the_node_with_type_and_allowed_values(path, channels):
    assert check_parameters(parse(path), channels) == []


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_nodes_run_in_the_namespace_argument(path):
    assert check_namespace(parse(path)) == []


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_arguments_params_file_namespace_modes_interface_loop(path, channels):
    assert check_gripper_arguments(parse(path), channels) == []


@pytest.mark.parametrize('path', SOURCES, ids=lambda p: p.name)
def test_no_yaml_boolean_mode_word(path):
    assert check_words(path.read_text()) == []


def test_mode_choices_are_the_controller_modes():
    """Every gripper file offers exactly the core's modes, passive first-class and default."""
    assert 'passive' in MODES
    for path in SOURCES:
        root = parse(path)
        if not {n.get('exec') for n in root.iter('node')} & CONTROLLER_EXECS:
            continue
        for channel in default_channels():
            arg = declared_args(root)[f'{channel}_mode']
            assert [c.get('value') for c in arg.findall('choice')] == list(MODES), path.name


def test_real_gripper_files_require_interface_and_sim_files_do_not():
    seen = set()
    for path in SOURCES:
        root = parse(path)
        execs = {n.get('exec') for n in root.iter('node')}
        interface = declared_args(root).get('interface')
        if execs & HARDWARE_EXECS:
            seen |= execs & HARDWARE_EXECS
            assert interface is not None and 'default' not in interface.attrib, path.name
        else:
            assert interface is None, path.name
    assert seen == HARDWARE_EXECS, 'hardware_node and hardware_bringup each need a launch file'


def test_every_gripper_file_can_record_next_to_it():
    """record:=true includes record.launch.xml (bag_recorder) in the same namespace."""
    for path in SOURCES:
        root = parse(path)
        if not {n.get('exec') for n in root.iter('node')} & PLANT_EXECS:
            continue
        includes = root.findall('include')
        assert [i.get('file') for i in includes] == \
            [f'$(find-pkg-share {PACKAGE})/launch/record.launch.xml'], path.name
        assert includes[0].get('if') == '$(var record)', path.name
        assert declared_args(root)['record'].get('default') == 'false', path.name
        passed = {a.get('name'): a.get('value') for a in includes[0].findall('arg')}
        assert passed['namespace'] == '$(var namespace)', path.name
        assert passed['params_file'] == '$(var params_file)', path.name
    record = parse(LAUNCH_DIR / 'record.launch.xml')
    assert [n.get('exec') for n in record.iter('node')] == ['bag_recorder']


# --- the checks find what they are for -----------------------------------------------------
def _sample(body, args=''):
    return parse(f'<launch>{args}<group><push-ros-namespace namespace="$(var namespace)"/>'
                 f'{body}</group></launch>')


_ARGS = ('<arg name="namespace" default=""/>'
         f'<arg name="params_file" default="{DEFAULT_PARAMS}"/>')


def test_checks_catch_a_missing_executable_and_a_foreign_package(tmp_path):
    root = _sample('<node pkg="seaforce_ros" exec="sim_node"/>'
                   '<node pkg="seaforce_ros" exec="simnode"/>'
                   '<node pkg="demo_nodes_py" exec="talker"/>', _ARGS)
    problems = check_nodes(root)
    assert any("'simnode': not in setup.py" in p for p in problems), problems
    assert any("'simnode'" in p and 'is not installed' in p for p in problems), problems
    assert any("pkg='demo_nodes_py'" in p for p in problems), problems
    assert not any("'sim_node'" in p for p in problems), problems
    # an executable in setup.py but not (yet) installed
    problems = check_nodes(_sample('<node pkg="seaforce_ros" exec="sim_node"/>'),
                           installed=tmp_path)
    assert any('is not installed' in p for p in problems), problems


def test_checks_catch_a_name_remap_on_a_composed_process():
    problems = check_nodes(_sample('<node pkg="seaforce_ros" exec="bringup" name="sim"/>'
                                   '<node pkg="seaforce_ros" exec="sim_node" name="plant"/>'))
    assert len(problems) == 2 and 'rename every node' in problems[0], problems


def test_checks_catch_undeclared_vars_and_missing_files():
    root = _sample('<node pkg="seaforce_ros" exec="sim_node">'
                   '<param from="$(find-pkg-share seaforce_ros)/config/grippr.yaml"/>'
                   '<param name="rate" value="$(var rate)" type="float"/></node>', _ARGS)
    problems = check_substitutions(root)
    assert any('$(var rate)' in p for p in problems), problems
    assert any('grippr.yaml' in p and 'not installed' in p for p in problems), problems


def test_checks_catch_an_include_of_a_missing_file_or_an_unknown_argument():
    root = _sample('', _ARGS + '<include file="$(find-pkg-share seaforce_ros)/launch/'
                   'nothing.launch.xml"/><include file="$(find-pkg-share seaforce_ros)/'
                   'launch/record.launch.xml"><arg name="output" value="x"/></include>')
    problems = check_includes(root)
    assert any('nothing.launch.xml' in p for p in problems), problems
    assert any("passes 'output'" in p for p in problems), problems


def test_checks_catch_undeclared_untyped_and_invalid_parameters(channels):
    mode_args = ('<arg name="pinch_mode" default="passive">'
                 + ''.join(f'<choice value="{m}"/>' for m in MODES) + '</arg>')
    root = _sample('<node pkg="seaforce_ros" exec="controller_node">'
                   '<param from="$(var params_file)"/>'
                   '<param name="pinch.mode" value="$(var pinch_mode)"/>'           # untyped
                   '<param name="pinch.dob.nominal_inertia" value="1e-3" type="float"/>'
                   '<param name="pinch.dob.nominal_inertias" value="1e-3" type="float"/>'
                   '<param name="loop" value="direct" type="str"/>'   # only composed
                   '<param name="state_timeout" value="-1.0" type="float"/>'
                   '<param name="wrist.mode" value="Off" type="str"/>'
                   '</node>', _ARGS + mode_args)
    problems = check_parameters(root, channels)
    assert any('pinch.mode' in p and 'type="str"' in p for p in problems), problems
    assert any("'pinch.dob.nominal_inertias' is not declared" in p for p in problems), problems
    assert any("'loop' is not declared" in p for p in problems), problems
    assert any('state_timeout' in p and '-1.0' in p for p in problems), problems
    assert any("'Off', a YAML 1.1 boolean" in p for p in problems), problems
    assert not any("'pinch.dob.nominal_inertia'" in p for p in problems), problems
    # an argument whose choices differ from the parameter's
    root = _sample('<node pkg="seaforce_ros" exec="controller_node">'
                   '<param from="$(var params_file)"/>'
                   '<param name="pinch.mode" value="$(var pinch_mode)" type="str"/></node>',
                   _ARGS + '<arg name="pinch_mode" default="hold"><choice value="hold"/>'
                   '<choice value="turbo"/></arg>')
    problems = check_parameters(root, channels)
    assert any("offers ['hold', 'turbo']" in p for p in problems), problems


def test_checks_catch_a_defaulted_interface_and_a_node_outside_the_namespace(channels):
    root = parse('<launch><arg name="interface" default="eth0"/>' + _ARGS
                 + '<node pkg="seaforce_ros" exec="hardware_node">'
                 '<param name="interface" value="$(var interface)" type="str"/></node></launch>')
    assert any('interface must be declared with no default' in p
               for p in check_gripper_arguments(root, channels))
    assert check_namespace(root) == ['hardware_node: not in a group that first pushes '
                                     '$(var namespace)']


def test_word_check_finds_the_old_mode_name():
    assert check_words('<arg name="pinch_mode" default="OFF"/>') != []
    assert check_words('<node on_exit="shutdown" offset="1"/>') == []


def test_display_publishes_the_xacro_urdf_with_the_gripper_parameters():
    """robot_state_publisher gets robot_description from the installed xacro, with the
    launch file's params_file and plant; plant offers the plant nodes (sim, hardware)."""
    root = parse(LAUNCH_DIR / 'display.launch.xml')
    (node,) = root.iter('node')
    assert (node.get('pkg'), node.get('exec')) in FOREIGN_NODES
    (param,) = node.findall('param')
    assert param.get('name') == 'robot_description' and param.get('type') == 'str'
    (command,) = XACRO_COMMAND.findall(param.get('value'))
    words = COMMAND_WORD.findall(command)
    assert words[1] == (f'$(find-pkg-share {PACKAGE})/config/urdf/'
                        'seaforce_gripper.urdf.xacro'), words
    assert set(words[2:]) == {'params_file:=$(var params_file)', 'plant:=$(var plant)'}
    assert {c.get('value') for c in declared_args(root)['plant'].findall('choice')} == \
        {n for e in PLANT_EXECS - COMPOSED_EXECS for n in NODES[e]}
    includes = root.findall('include')
    assert [i.get('file') for i in includes] == \
        [f'$(find-pkg-share {PACKAGE})/launch/sim.launch.xml']
    assert includes[0].get('if') == '$(var sim)'


def test_checks_catch_a_foreign_node_not_depended_on_and_a_bad_xacro_command():
    root = _sample('<node pkg="robot_state_publisher" exec="robot_state_publisher" name="rsp">'
                   '<param name="robot_description" type="str" value="$(command \'xacro '
                   f'$(find-pkg-share {PACKAGE})/config/urdf/seaforce_gripper.urdf.xacro '
                   'params_file:=$(var params_file) plants:=sim\')"/></node>'
                   '<node pkg="rviz2" exec="rviz2"/>', _ARGS)
    problems = check_nodes(root)
    assert any("name='rsp'" in p for p in problems), problems
    assert any("pkg='rviz2'" in p for p in problems), problems
    problems = check_substitutions(root)
    assert len(problems) == 1 and "'plants:=sim' is no argument" in problems[0], problems
    missing = _sample('<node pkg="robot_state_publisher" exec="robot_state_publisher">'
                      '<param name="robot_description" type="str" value="$(command \'xacro '
                      f'$(find-pkg-share {PACKAGE})/config/urdf/gripper.urdf.xacro '
                      'plant:=$(var plants)\')"/></node>', _ARGS)
    problems = check_substitutions(missing)
    assert any('not an installed' in p for p in problems), problems

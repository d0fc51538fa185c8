"""config/foxglove_layout.json and config/plotjuggler_layout.xml against the message
definitions and one running sim_node + controller_node (module-scoped).

Every topic a layout names is a topic of the running stack, with the type the layout's panel
needs; every field path resolves in that type's definition (the generated classes of
msg_defs/ and of the standard messages), to a number where it is plotted (a string only in
Foxglove's state transitions) and, for a per-channel index, to an element the live message
has. PlotJuggler's /diagnostics series (``/diagnostics/<hardware_id>/<status>/<key>``, its
DiagnosticArray parser) are series the live /diagnostics gives, with numbers. Both layouts
show X_e against F_p (an XY plot) for every channel of config/gripper.yaml; every Foxglove
panel configured is placed, every placed one configured; the installed copies are the sources.
"""
import importlib
import json
import re
import xml.etree.ElementTree as ET

import pytest
import yaml

from helpers.nodes import CONFIG
from helpers.processes import ROOT
from helpers.sim_stack import SimStack

FOXGLOVE = ROOT / 'config' / 'foxglove_layout.json'
PLOTJUGGLER = ROOT / 'config' / 'plotjuggler_layout.xml'
INSTALLED = ROOT / 'install' / 'seaforce_ros' / 'share' / 'seaforce_ros' / 'config'
CHANNELS = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']['channels']
NUMERIC = {'double', 'float', 'boolean', 'octet', 'uint8', 'int8', 'uint16', 'int16', 'uint32',
           'int32', 'uint64', 'int64'}
DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'
#: /topic.field[i] (Foxglove) or /topic/field[i] (PlotJuggler)
FIELD_PATH = re.compile(r'^(/\w+)[./](\w+(?:[./]\w+)*)(?:\[(\d+)\])?$')


def message_class(type_name):
    package, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def field_type(type_name, fields):
    """The rosidl type of a dotted field path in a message type, e.g. 'sequence<double>'."""
    cls = message_class(type_name)
    for i, name in enumerate(fields):
        types = cls.get_fields_and_field_types()
        assert name in types, f'{type_name} has no field {name!r} ({sorted(types)})'
        kind = types[name]
        if i + 1 < len(fields):
            cls = message_class(kind.replace('/', '/msg/', 1))
    return kind


@pytest.fixture(scope='module')
def live(tmp_path_factory):
    """(topic -> type, topic -> latest message, diagnostics statuses) of a running stack."""
    stack = SimStack(tmp_path_factory.mktemp('layouts'), 'layouts')
    try:
        expected = {'sim: cycle', 'controller: loop', *(f'{p}: {c}' for c in CHANNELS
                                                        for p in ('sim', 'controller'))}
        statuses = list(stack.diagnostics(expected).values())
        topics = {}
        stack.probe.wait_for(lambda: {'/actuator_state', '/actuator_command',
                                      '/controller_status'} <= set(stack.topics()), 20,
                             'the stack\'s topics in the graph')
        for topic, types in stack.topics().items():
            topics[topic] = types[0]
        latest = {}
        for topic in ('/actuator_state', '/actuator_command', '/controller_status'):
            stack.probe.record(message_class(topics[topic]), topic)
            latest[topic] = stack.probe.wait_messages(topic, 1, timeout=20)[-1]
    finally:
        stack.close()
    return topics, latest, statuses


def check_field(path, live, numeric):
    """Problems of one /topic.field[i] reference."""
    topics, latest, _ = live
    match = FIELD_PATH.match(path)
    if not match:
        return [f'{path!r}: not /topic.field[index]']
    topic, fields, index = match.group(1), re.split(r'[./]', match.group(2)), match.group(3)
    if topic not in topics:
        return [f'{path!r}: {topic} is no topic of the running stack']
    kind = field_type(topics[topic], fields)
    problems = []
    element = kind
    if index is not None:
        if not kind.startswith('sequence<'):
            return [f'{path!r}: {kind} is not an array']
        element = kind[len('sequence<'):-1]
        value = latest.get(topic)
        if value is not None:
            for name in fields:
                value = getattr(value, name)
            if int(index) >= len(value):
                problems.append(f'{path!r}: the live message has {len(value)} elements')
    if numeric and element not in NUMERIC:
        problems.append(f'{path!r}: {element} is not a number to plot')
    if not numeric and element not in NUMERIC | {'string'}:
        problems.append(f'{path!r}: {element} is not a value')
    return problems


# --- Foxglove -------------------------------------------------------------------------------
def foxglove():
    return json.loads(FOXGLOVE.read_text())


def placed(layout):
    """Panel ids placed in a mosaic layout (a Tab's tabs included)."""
    if isinstance(layout, str):
        return [layout]
    if layout is None:
        return []
    return placed(layout['first']) + placed(layout['second'])


def foxglove_paths(config):
    """(panel id, path, numeric) of every message path of the layout."""
    for pid, panel in config['configById'].items():
        kind = pid.split('!')[0]
        if kind == 'Plot':
            for p in panel['paths']:
                yield pid, p['value'], True
            if panel.get('xAxisVal') == 'custom':
                yield pid, panel['xAxisPath']['value'], True
        elif kind == 'StateTransitions':
            for p in panel['paths']:
                yield pid, p['value'], False


def test_foxglove_panels_are_placed_and_configured():
    config = foxglove()
    ids = set(config['configById'])
    tabs = [p for p in ids if p.startswith('Tab!')]
    assert placed(config['layout']) == tabs
    inside = [pid for t in tabs for tab in config['configById'][t]['tabs']
              for pid in placed(tab['layout'])]
    assert sorted(inside + tabs) == sorted(ids)
    assert {pid.split('!')[0] for pid in ids} <= {'Tab', 'Plot', 'StateTransitions',
                                                  'DiagnosticSummary', 'DiagnosticStatusPanel'}


def test_foxglove_fields_exist_in_the_definitions_and_the_running_stack(live):
    problems = [f'{pid}: {p}' for pid, path, numeric in foxglove_paths(foxglove())
                for p in check_field(path, live, numeric)]
    assert problems == []


def test_foxglove_diagnostics_panels_show_the_live_diagnostics(live):
    topics, _, statuses = live
    for pid, panel in foxglove()['configById'].items():
        if pid.startswith('Diagnostic'):
            assert topics.get(panel['topicToRender']) == DIAGNOSTICS, pid
            if 'selectedName' in panel:
                assert (panel['selectedHardwareId'], panel['selectedName']) in {
                    (s.hardware_id, s.name) for s in statuses}, pid


def test_foxglove_shows_xe_against_fp_for_every_channel():
    xy = {(p['xAxisPath']['value'], q['value']) for p in foxglove()['configById'].values()
          if p.get('xAxisVal') == 'custom' for q in p['paths']}
    assert xy >= {(f'/actuator_state.endpoint_position[{i}]', f'/actuator_state.pressure_force[{i}]')
                  for i in range(len(CHANNELS))}


# --- PlotJuggler ----------------------------------------------------------------------------
def plotjuggler():
    return ET.parse(PLOTJUGGLER).getroot()


def plotjuggler_series(root):
    """Every series name a curve plots (an XY curve's x and y)."""
    for curve in root.iter('curve'):
        if curve.get('curve_x'):
            yield curve.get('curve_x')
            yield curve.get('curve_y')
        else:
            yield curve.get('name')


def diagnostics_series(statuses):
    """What PlotJuggler's DiagnosticArray parser makes of them: name -> a number or None."""
    series = {}
    for s in statuses:
        prefix = f'/diagnostics/{s.hardware_id}/{s.name}' if s.hardware_id else \
            f'/diagnostics/{s.name}'
        series[f'{prefix}/level'] = float(ord(s.level) if isinstance(s.level, bytes) else s.level)
        for kv in s.values:
            try:
                series[f'{prefix}/{kv.key}'] = float(kv.value)
            except ValueError:
                series[f'{prefix}/{kv.key}'] = None      # a string series: not plotted
    return series


def test_plotjuggler_series_exist_in_the_definitions_and_the_running_stack(live):
    diagnostics = diagnostics_series(live[2])
    problems = []
    for name in plotjuggler_series(plotjuggler()):
        if name.startswith('/diagnostics/'):
            if name not in diagnostics:
                problems.append(f'{name!r}: no such /diagnostics series live')
            elif diagnostics[name] is None:          # (NaN is a number: guard disabled)
                problems.append(f'{name!r}: not a number live')
        else:
            problems += check_field(name, live, numeric=True)
    assert problems == []


def test_plotjuggler_topics_are_live_topics(live):
    topics = live[0]
    for plugin in plotjuggler().iter('plugin'):
        selected = plugin.find('selected_topics')
        assert selected is not None, plugin.get('ID')
        for topic in selected.get('value').split(';'):
            assert topic in topics, (plugin.get('ID'), topic)


def test_plotjuggler_shows_xe_against_fp_for_every_channel():
    xy = {(c.get('curve_x'), c.get('curve_y')) for c in plotjuggler().iter('curve')}
    assert xy >= {(f'/actuator_state/endpoint_position[{i}]', f'/actuator_state/pressure_force[{i}]')
                  for i in range(len(CHANNELS))}


def test_installed_copies_are_the_sources():
    for path in (FOXGLOVE, PLOTJUGGLER):
        assert (INSTALLED / path.name).read_bytes() == path.read_bytes(), \
            'rebuild: source scripts/setup.sh'


def test_the_checks_catch_bad_references(live):
    """A misspelt field, an index past the channels, a string plotted, a topic the stack does
    not have, a diagnostics series nobody publishes."""
    for path, numeric, expected in (
            ('/actuator_state.endpoint_positon[0]', True, 'has no field'),
            ('/actuator_state.endpoint_position[7]', True, 'the live message has 2'),
            ('/controller_status.mode[0]', True, 'not a number'),
            ('/actuator_state.cycle[0]', True, 'not an array'),
            ('/joint_state.position[0]', True, 'no topic')):
        try:
            problems = check_field(path, live, numeric)
        except AssertionError as error:
            problems = [str(error)]
        assert any(expected in p for p in problems), (path, problems)
    assert check_field('/controller_status.mode[0]', live, numeric=False) == []
    assert '/diagnostics/seaforce_controller/controller: hand/level' not in \
        diagnostics_series(live[2])

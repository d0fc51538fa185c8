"""config/diagnostics_analyzers.yaml against the /diagnostics status names the nodes publish.

One sim_node + controller_node + bag_recorder stack (module-scoped) gives the live names; the
EtherCAT node's names come from the class that makes them (EthercatBackend: the bus status and
the per-channel prefix), as hardware_node needs a bus. The analyzers are matched the way the
aggregator's GenericAnalyzer matches (``name``: the whole name, ``startswith``: its beginning,
``contains``: anywhere):

* every published status is matched by exactly one analyzer (nothing falls into the
  aggregator's "Other", no status shows in two groups);
* every ``name`` / ``startswith`` / ``contains`` entry matches some published name (no entry
  for a name that no node publishes, e.g. after a rename);
* the groups are Plant, EtherCAT, Controller, Passivity, Grasp, Recorder.
"""
import pytest
import yaml

from seaforce_ros.ethercat.backend import EthercatBackend
from seaforce_ros.core.sim_backend import SimBackend

from helpers.nodes import CONFIG
from helpers.processes import ROOT
from helpers.sim_stack import SimStack

ANALYZERS = ROOT / 'config' / 'diagnostics_analyzers.yaml'
GROUPS = {'Plant', 'EtherCAT', 'Controller', 'Passivity', 'Grasp', 'Recorder'}
MATCHERS = ('name', 'startswith', 'contains')
CHANNELS = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']['channels']


def analyzers():
    params = yaml.safe_load(ANALYZERS.read_text())['analyzers']['ros__parameters']
    return {key: value for key, value in params.items() if isinstance(value, dict)}


def matches(analyzer, name):
    """GenericAnalyzer's match on one status name."""
    return (name in analyzer.get('name', ())
            or any(name.startswith(p) for p in analyzer.get('startswith', ()))
            or any(c in name for c in analyzer.get('contains', ())))


@pytest.fixture(scope='module')
def published(tmp_path_factory):
    """Every status name the nodes publish: live (sim, controller, recorder), and the
    EtherCAT node's from EthercatBackend."""
    stack = SimStack(tmp_path_factory.mktemp('diagnostics'), 'diagnostics', recorder=True)
    try:
        expected = {SimBackend.status_name, 'controller: loop', 'bag_recorder',
                    *(f'{p}: {c}' for c in CHANNELS
                      for p in (SimBackend.channel_prefix, 'controller', 'passivity', 'grasp'))}
        live = set(stack.diagnostics(expected))
    finally:
        stack.close()
    ethercat = {EthercatBackend.status_name,
                *(f'{EthercatBackend.channel_prefix}: {c}' for c in CHANNELS)}
    return live | ethercat


def test_the_groups():
    found = analyzers()
    assert {a['path'] for a in found.values()} == GROUPS
    for key, analyzer in found.items():
        assert analyzer['type'] == 'diagnostic_aggregator/GenericAnalyzer', key
        assert set(analyzer) - {'type', 'path'} <= set(MATCHERS), key
        assert any(analyzer.get(m) for m in MATCHERS), f'{key} matches nothing'


def test_every_published_status_is_in_exactly_one_group(published):
    found = analyzers()
    for name in sorted(published):
        groups = [a['path'] for a in found.values() if matches(a, name)]
        assert len(groups) == 1, (name, groups)


def test_every_entry_matches_a_published_name(published):
    for key, analyzer in analyzers().items():
        for kind in MATCHERS:
            for entry in analyzer.get(kind, ()):
                hits = [n for n in published if matches({kind: [entry]}, n)]
                assert hits, f'{key}.{kind} {entry!r} matches none of {sorted(published)}'
    # and the live stack did publish every group but EtherCAT's
    paths = {a['path'] for a in analyzers().values() for n in published if matches(a, n)}
    assert paths == GROUPS

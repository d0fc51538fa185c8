"""Every benchmark in ``bench/`` runs in its ``--quick`` form and prints its figures.

The benchmarks pass or fail nothing (their figures are in the docs); this only proves each one
still runs end to end -- imports, command line, the nodes or the emulator it starts, its tables
-- in a few seconds: a short run of every row it prints, the figures meaningless (three run at
once, each in its own DDS domain; the ones that start nodes or the emulator in
test_benches_live.py). Per script:
exit 0, no traceback, and the lines that carry its figures, with numbers in them. A script
added to ``bench/`` without an entry here fails :func:`test_every_bench_has_a_smoke_run`.
"""
import os
import re
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest

from helpers.nodes import domain_env, own_domain
from helpers.processes import ROOT, ProcessGroup

BENCH = ROOT / 'bench'
NUM = r'-?\d+\.?\d*'
#: (arguments after the script, regular expressions its output must match (multiline))
SMOKE = {
    'calibration_contact.py': [
        ((), [r'^refused or aborted, nothing applied: \d+/\d+$',
              rf'^succeeded \d+/\d+; largest contact-test level in free air {NUM}'])],
    'commissioning_excitation.py': [
        ((), [rf'^\s+0\s+(succeeded|aborted)\s+{NUM}\s+{NUM}',
              rf'^FreeAirExcitation\.update per sample \[us\]: mean {NUM}'])],
    'control_loop.py': [
        ((), [rf'^{row}\s+events\s+reliable\s+2000\s+\d+\s+{NUM}%\s+{NUM}\s+{NUM}\s+{NUM}'
              for row in ('direct rt', 'bare echo', 'nodes')])],
    'core_impedance_table.py': [
        ((), [rf'^dob_full_ff\s+{NUM}$', rf'^\s+3\.0 rad/s:\s+{NUM} dB\s+\(with \+20% model '
              rf'error:\s+{NUM} dB\)'])],
    'core_sim_speed.py': [
        ((), [rf'ChannelController\.update\s+mean\s+{NUM} us',
              rf'run_closed_loop\s+{NUM} s', rf'ContactEstimator\.update\s+mean\s+{NUM} us',
              rf'PassivityGuard\.update\s+mean\s+{NUM} us']),
        (('--stages',), [rf'^\s+ContactEstimator\.update\s+{NUM}$',
                         rf'^\s+update / simulator step: {NUM}$']),
        (('--baseline', 'HEAD'), [
            rf'^ChannelSimulator\.step \(same code: noise\)\s+{NUM}\s+{NUM}',
            r'^\s+after\s+N = [1-9]\d*: \d+ B'])],
    'ethercat_cycle.py': [
        ((), [rf'achieved rate\s+{NUM} Hz', r'emulator\s+[1-9]\d* process frames served',
              rf'INIT -> OP\s+{NUM} ms', rf'cycle CPU DC\s+{NUM} us median.*ratio {NUM}'])],
    'free_air_identification.py': [
        ((), [r'^all ten within their goals: \d/2', rf'fit CPU time per record: median {NUM} s'])],
    'friction_drift.py': [
        ((), [rf'^\s+recalibrated\s+{NUM}$', rf'^\s+calibration running\s+mean\s+{NUM}'])],
    'grasp_accuracy.py': [
        ((), [r'^grip force error in a settled hold: max',
              rf'^\s+0\.30\s+{NUM} \(\s*{NUM}\) / {NUM}',
              rf'^\s+0\.30\s+\d+\s+{NUM} - {NUM}\s+{NUM}$'])],
    'gripper_actions.py': [
        ((), [rf'^contact -> result \[cycles\]\s+{NUM}\s+{NUM}', rf'^rejected \[ms\]\s+{NUM}'])],
    'hardware_loop.py': [
        ((), [rf'^hardware {layout}\s+\d+\s+{NUM}\s+{NUM}' for layout in ('topics', 'direct')])],
    'hold_gains.py': [
        ((), [r'^Conclusion$', rf'designed {NUM}/{NUM}:\s+3 rad/s\s+{NUM}'])],
    'identify_accuracy.py': [
        ((), [rf'^\s+0\s+[-+]{NUM}%', rf'identify on the 0\.5-minute bag: {NUM} s wall'])],
    'identify_external_force.py': [
        ((), [rf'^core sim Table I\s+30\s+held\s+400\s+{NUM}',
              rf'identify_plant on a 30 s record: one convention {NUM} s'])],
    'loop_figures_accuracy.py': [
        ((), [rf'k=4 chirp to 1 kHz\s+std 5e-04 N m: error [-+]{NUM} %',
              rf'^\s+1048576 chirp\s+: q {NUM}'])],
    'margin_family.py': [
        ((), [r'^linear class, 1 of 1 draws tuned', rf'^\s+zw1\s+{NUM}',
              r'^\s+feed-forward: (verified|verification)'])],
    'model_class.py': [
        ((), [r'^over 1 draws \(seed 1\); misfit', rf'^\s+all effects\s+motor\s+{NUM} /\s+{NUM}',
              r'^CPU \d+ s'])],
    'nonlinear_commissioning.py': [
        ((), [rf'^\s+rms_vs_linear\s+{NUM}', rf'^\s+zw3\s+{NUM}',
              r'^\s+model class flagged in \d/1'])],
    'passivity_guard_grid.py': [
        ((), [r'^\s+20Hz\s+0\.50\s+-0\.5k/l', rf'^20 Hz, m_n 0\.5 m\s+\|\s+{NUM}'])],
    'profile_loop.py': [
        ((), [r'^== sim: [1-9]\d* samples', r'^== controller: [1-9]\d* samples'])],
    'recorder_soak.py': [
        ((), [r'^recorder exit code 0; final counts',
              r'/actuator_state: [1-9]\d* messages in the bag'])],
    'report_render.py': [
        ((), [rf'^write_report \(4 figures, json, html\): median {NUM} s',
              rf'^chromium screenshot \S+:\s+median {NUM} s'])],
    'runaway_family.py': [
        ((), [rf'^in range: \d+/\d+; peak \|V_e\| {NUM}',
              r'^at rest in the last second: \d+/\d+'])],
    'zwidth_prediction.py': [
        ((), [r'^Hold delay limit', rf'^\s+lambda\s+{NUM} Hz, m_n/m'])],
}
#: scripts that are parts of another benchmark (run by it, covered by its smoke run)
PARTS = {'echo_pair.py': 'control_loop.py'}
#: a bench that outlives this is hung (each takes 1-20 s on a quiet 2-core host)
TIMEOUT = 300.0
#: benches run at once (each its own DDS domain: their nodes do not meet): most wait on
#: processes, sleeps and their loops, and the figures of a smoke run mean nothing
AT_ONCE = 3
#: the benches that start ROS nodes or the EtherCAT emulator and time their loops: run by
#: test_benches_live.py, on the stacks' worker (conftest.STACKS); the others here, beside them
LIVE = {'control_loop.py', 'ethercat_cycle.py', 'gripper_actions.py', 'hardware_loop.py',
        'profile_loop.py', 'recorder_soak.py'}
ALL_RUNS = [(script, args, patterns) for script, runs in SMOKE.items()
            for args, patterns in runs]
RUNS = [run for run in ALL_RUNS if run[0] not in LIVE]


def test_every_bench_has_a_smoke_run():
    scripts = {p.name for p in BENCH.glob('*.py')}
    assert scripts == set(SMOKE) | set(PARTS), (
        f'without a smoke run: {sorted(scripts - set(SMOKE) - set(PARTS))}; '
        f'gone: {sorted((set(SMOKE) | set(PARTS)) - scripts)}')
    assert LIVE <= set(SMOKE), sorted(LIVE - set(SMOKE))
    for script in SMOKE:
        assert '--quick' in (BENCH / script).read_text(), script


def run_all(runs, domain_offset=0):
    """Generator for a module fixture: every smoke run of ``runs`` to its end,
    :data:`AT_ONCE` at a time: [(exit code, output)] in their order; each process ended by its
    PID whatever happens."""
    group = ProcessGroup()

    def run(index):
        script, args, _ = runs[index]
        env = domain_env(own_domain(domain_offset + index), PYTHONPATH=os.pathsep.join(
            p for p in (str(ROOT), os.environ.get('PYTHONPATH')) if p))
        proc = group.start([sys.executable, str(BENCH / script), '--quick', *args],
                           name=f'bench_{script[:-3]}', env=env)
        return proc.wait(TIMEOUT), proc.output()
    try:
        with ThreadPoolExecutor(max_workers=AT_ONCE) as pool:
            yield list(pool.map(run, range(len(runs))))
    finally:
        group.stop_all()


def check(run, result):
    """Exit 0, no traceback, every pattern of the run in its output."""
    script, _, patterns = run
    code, out = result
    assert code == 0, f'{script} exited {code}:\n{out[-4000:]}'
    assert 'Traceback' not in out, out[-4000:]
    for pattern in patterns:
        assert re.search(pattern, out, re.M), f'{pattern!r} not in the output:\n{out[-4000:]}'


def ids(runs):
    return [' '.join((script,) + args) for script, args, _ in runs]


@pytest.fixture(scope='module')
def quick_runs():
    yield from run_all(RUNS)


@pytest.mark.parametrize('index', range(len(RUNS)), ids=ids(RUNS))
def test_bench_runs_quick(quick_runs, index):
    check(RUNS[index], quick_runs[index])

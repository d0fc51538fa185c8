"""The demos (`scripts/demo`, `... grasp`, `... commission`): short runs end to end, as a
user starts them, the three at once (lockstep: what each measures is its own loop's)."""
import collections
import json
import math
import os
import pathlib
import re
import uuid

import pytest
from seaforce_msgs.msg import ControllerStatus

from helpers.nodes import domain_env, own_domain
from helpers.probe import Probe
from helpers.processes import ROOT, ProcessGroup

PNG = b'\x89PNG\r\n\x1a\n'


def _processes_with_marker(marker: str):
    found = []
    for entry in pathlib.Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if marker.encode() in (entry / 'environ').read_bytes():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


#: The demos the tests judge, all in lockstep (each loop's figures are its own however busy
#: the host): scripts/demo's arguments (``--out`` added) and the time each may take [s, of the
#: wall clock and of its loop's].
SEED = int(os.environ.get('SEAFORCE_DEMO_SEED', '1'))
COMMISSION_MODES = ('hold', 'dob_full_ff')
DEMOS = {
    # the README's main job, one period of a 3 rad/s drive per mode (short), and its
    # friction calibration
    'impedance': (['--periods', '1', '--frequency', '3', '--lockstep'], 240.0),
    'grasp': (['grasp', '--lockstep'], 300.0),
    # the two modes of the Z-width (the predictor's figures for the others, passive among
    # them, against the simulated backdrive: test/commissioning/test_predictor.py)
    # a 20 s chirp (test/data/commission_20s.yaml): the 40 s default is most of the loop
    # time of the suite's longest fixture
    'commission': (['commission', '--seed', str(SEED), '--frequencies', '1,3', '--modes',
                    ','.join(COMMISSION_MODES), '--controller-params',
                    str(ROOT / 'test' / 'data' / 'commission_20s.yaml')], 400.0),
}
Demo = collections.namedtuple('Demo', 'code text out marker')
# the first test waits for the three demos (about 2 min together on a quiet 2-core host, 5 at a
# load average of 15): the suite's 300 s guard per test is too short for that
pytestmark = pytest.mark.timeout(1200)


@pytest.fixture(scope='module')
def demos(tmp_path_factory):
    """The three demos run at once, to their ends: ``{name: Demo}``. Each in a DDS domain of
    its own (their nodes do not meet), followed there by a probe on its controller_status
    (its loop's clock for the wait); every process started here ended by its PID, pass or
    fail. The demos' own processes carry a marker in their environment."""
    group = ProcessGroup()
    probes = []
    try:
        running = {}
        for index, (name, (args, timeout)) in enumerate(DEMOS.items()):
            domain = own_domain(index)
            marker = uuid.uuid4().hex
            out = tmp_path_factory.mktemp(name)
            probe = Probe(f'probe_demo_{name}', domain)
            probes.append(probe)
            probe.record(ControllerStatus, 'controller_status')
            proc = group.start([str(ROOT / 'scripts' / 'demo'), *args, '--out', str(out)],
                               name=f'demo_{name}',
                               env=domain_env(domain, SEAFORCE_DEMO_TEST=marker))
            running[name] = (proc, probe, out, marker, timeout)
        results = {}
        for name, (proc, probe, out, marker, timeout) in running.items():
            probe.wait_for(lambda: proc.popen.poll() is not None, timeout, f'the {name} demo')
            results[name] = Demo(proc.popen.returncode, proc.output(), out,
                                 f'SEAFORCE_DEMO_TEST={marker}')
        yield results
    finally:
        for probe in probes:
            probe.close()
        group.stop_all()


def _demo(demos, name):
    """The demo's output: exit 0, and every process it started ended, asserted."""
    demo = demos[name]
    assert demo.code == 0, demo.text
    assert _processes_with_marker(demo.marker) == []
    return demo.text, demo.out


def _impedance_table(text, out):
    """-> (table rows {mode: |Z| dB}, impedance range dB) of the main job's output; its PNG."""
    rows = {}
    # modes whose last window the demo's observer recorded with gaps (a busy host, three
    # tries): the demo says so, and the interpolated gaps bend the harmonics
    degraded, current = set(), None
    for line in text.splitlines():
        started = re.match(r'\[demo\] (\w+)\s+measuring cycles', line)
        if started:
            current = started.group(1)
        elif 'note: recorded' in line and 'the gaps are interpolated' in line:
            degraded.add(current)
    for mode in ('passive', 'hold', 'dob', 'dob_linear_ff', 'dob_full_ff'):
        # |Z| of the fundamental, vs passive, |Z| rms, distortion [%], peak |F_e|
        match = re.search(rf'^{mode}\s+(-?\d+\.\d)\s+(-?\d+\.\d)\s+(-?\d+\.\d)\s+(\d+)\s+'
                          r'(\d+\.\d+)', text, re.M)
        assert match, f'no table row for {mode}:\n{text}'
        rows[mode] = float(match.group(1))
        # the rms counts every harmonic: never below the fundamental (of a whole record)
        if mode not in degraded:
            assert float(match.group(3)) >= rows[mode] - 0.05, text
    width = float(re.search(r'impedance range at 3\.0 rad/s: (\d+\.\d) dB on the fundamental',
                            text).group(1))
    assert re.search(r'dB on the fundamental .*, (\d+\.\d) dB on the rms', text), text
    png = out / 'work_loops.png'
    assert png.is_file() and png.read_bytes()[:8] == PNG
    assert png.stat().st_size > 20_000
    return rows, width


def test_demo_orders_the_modes_recalibrates_and_stops_its_nodes(demos):
    """The README's main job with ``--lockstep`` (the plant steps only on the controller's
    answer, so the figures are the loop's own on any host, busy or not): the table with the
    paper's ordering hold >> passive > dob > dob_linear_ff > dob_full_ff, about 50 dB of
    range at 3 rad/s and no cycle without a command; the PNG; then the friction calibration
    (the sim's plant 10-20 % off the model): b_e, k_e, F_c within 15 % of the sim's truth
    (the hose and motor errors remain), and the recalibrated dob_full_ff lighter than the
    DOB alone (one period at 3 rad/s does not resolve the few dB the calibration gains there:
    -41.4 to -47.2 dB against -39.7 with the model in four runs; the core sim: -39.7 -> -44.0
    dB; test/core/test_friction_calibration.py asserts the recovery); every process ended. (Real time is the loop tests' subject:
    test_closed_loop, test_layouts_ros, the watchdogs in test_cycle_faults_ros.)"""
    text, out = _demo(demos, 'impedance')
    rows, width = _impedance_table(text, out)
    assert rows['hold'] > rows['passive'] + 10, rows
    assert rows['passive'] > rows['dob'] > rows['dob_linear_ff'] > rows['dob_full_ff'], rows
    assert width > 40.0, text
    assert 'without a fresh command' not in text, text
    assert re.search(r'^Friction calibration .*: identified', text, re.M), text
    for label in ('b_e', 'k_e', 'F_c'):
        row = re.search(rf'^{label} \[.*?\]\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+([-+]\d+\.\d)%$',
                        text, re.M)
        assert row and abs(float(row.group(5))) < 15.0, text
    after = re.search(r'^recalibrated dob_full_ff \|Z\| at 3\.0 rad/s: (-?\d+\.\d) dB .*; '
                      r'rms (-?\d+\.\d) dB', text, re.M)
    assert after, text
    assert float(after.group(1)) < rows['dob'] - 3.0, text
    # and on the rms, which a transient in the window would spoil (it did: measured while the
    # drive's start still rang, the rms was the DOB's alone)
    dob_rms = float(re.search(r'^dob\s+\S+\s+\S+\s+(-?\d+\.\d)', text, re.M).group(1))
    assert float(after.group(2)) < dob_rms - 3.0, text


def test_grasp_demo_measures_three_objects_and_stops_its_nodes(demos):
    """`scripts/demo grasp --lockstep`: the friction recalibrated first, then three simulated
    objects (soft, medium, stiff; the plant 10-20 % off the model) grasped over ROS; a table
    row each (estimates within 2.5 of their 1-sigma), a plot each, every process ended. (The
    grasp in real time, in both layouts: test_grasp_ros.py.)"""
    text, out = _demo(demos, 'grasp')
    for name in ('soft', 'medium', 'stiff'):
        row = re.search(rf'^{name}\s+(\d+\.\d+)\s+(\d+\.\d+)\s+(\d+\.\d+)\s+(\d+\.\d+)'
                        rf'\s+(-?\d+\.\d+)\s+(\d+\.\d+)\s+(\d+\.\d)\s+(\d+\.\d+)\s+(\d+\.\d+)$',
                        text, re.M)
        assert row, f'no table row for {name}:\n{text}'
        k, k_hat, k_sigma, b, b_hat, b_sigma = (float(row.group(i)) for i in range(1, 7))
        assert abs(k_hat - k) <= 2.5 * k_sigma, row.group(0)
        assert abs(b_hat - b) <= 2.5 * b_sigma, row.group(0)
        png = out / f'grasp_{name}.png'
        assert png.is_file() and png.read_bytes()[:8] == PNG
    assert re.search(r'grip held within \d+\.\d %', text), text
    assert re.search(r'^Friction calibration \(~/calibrate_friction, 10 s in free air\): '
                     r'identified$', text, re.M), text


def test_commission_demo_identifies_tunes_and_predicts_what_it_measures(demos):
    """`scripts/demo commission` on a plant drawn 0.5x..2x (seed 1), with a 20 s chirp
    (sigma -1.8 %, the others within 1.5 %; a 12 s chirp had sigma 134 % off), two
    frequencies and the two modes of the Z-width (short): exit 0; the table and the files; the
    identified plant within twice the family's goals (m, m_e, k_s 5 %, the other five 15 %,
    sigma and F_c 25 %); every mode's predicted |Z| within 3 dB of the measured, before (where
    the mode held) and after (every one); the Z-width after at least the goals (65 dB at
    1 rad/s, 45 at 3) and wider than before; dob_full_ff within 3 dB of the true model's
    figure (the tuned settings with the true plant) or below it; every process ended."""
    # a fixed draw (the random plants are the family, predictor and tuning tests';
    # SEAFORCE_DEMO_SEED runs another: seed 86275's dob_full_ff, unstable before, measured
    # 4.2 dB below the prediction after)
    text, out = _demo(demos, 'commission')
    where = f'seed {SEED}:\n{text}'
    for mode in COMMISSION_MODES:
        assert re.search(rf'^{mode}\s+[13] \|', text, re.M), where
    # every mode held at every frequency: each entered as the drive passes its centre (hold's
    # set point there), each new drive installed as the finger passes it upwards (no step)
    assert 'UNSTABLE' not in text and 'NOT HELD' not in text, where
    assert (out / 'zwidth_commission.png').read_bytes()[:8] == PNG
    results = json.loads((out / 'results.json').read_text())
    goals = {'motor_inertia': 0.05, 'endpoint_inertia': 0.05, 'hose_stiffness': 0.05,
             'sigma': 0.25, 'coulomb_force': 0.25}
    for key, true in results['truth'].items():
        name = key.split('.sim.', 1)[1]
        found = results['identified'][name]
        goal = goals.get(name.split('.')[-1], 0.15)
        # one draw: within twice the goal (as every draw of the family test; the >= 95 %
        # within the goal is that test's)
        assert abs(found / true - 1.0) <= 2.0 * goal, (name, found, true, where)
    for label, measured in results['measured'].items():
        for point, z in measured.items():
            # before, a mode may be unstable on a plant this far off (NaN: the demo says so);
            # after commissioning every mode holds
            if label == 'after' or label == 'before' and not math.isnan(z):
                predicted = results['predicted'][f'{label}:{point}']
                assert abs(z - predicted) <= 3.0, (label, point, z, predicted, where)
    width = results['zwidth_db']
    assert width['after']['1'] > width['before']['1'], where
    assert width['after']['1'] >= 65.0 and width['after']['3'] >= 45.0, where     # the goals
    after, ideal = results['measured']['after']['dob_full_ff@1'], results['ideal_dob_full_ff_db']
    # (NaN: the controller refused the true model with the tuned settings, eq. 28 -- the
    # output says so)
    assert ideal is None or math.isnan(ideal) and 'ideal model not measured' in text \
        or after <= ideal + 3.0, where
    assert pathlib.Path(results['report']).is_file()
    # the bonded drive's four-bar: the linear sim has none (r constant), and the goal lines
    # say so
    assert 'constant ratio' in results['goals']['finger_ratio'], where
    assert 'bonded drive of dob_full_ff at 1 rad/s: finger ratio' in text, where


def test_commission_demo_draws_a_nonlinear_plant_the_sim_takes_and_reports_its_goals():
    """``commission --nonlinear`` without a run (the run is the docs' output): the drawn
    effects are the seed's, in their ranges, the rows the sim declares, and make the sim's
    nonlinear plant; the goal figures come from the measurements and the report."""
    from types import SimpleNamespace

    from seaforce_ros.core.nonlinear_effects import PLAUSIBLE, NonlinearEffects
    from seaforce_ros.core.nonlinear_simulator import NonlinearChannelSimulator, make_simulator
    from seaforce_ros.core.params import PlantParams
    from seaforce_ros.demos.commission import goal_figures, goal_lines, nonlinear_plant
    from seaforce_ros.demos.common import CHANNEL, drawn_plant
    values, described = nonlinear_plant(SEED)
    assert nonlinear_plant(SEED) == (values, described)
    assert nonlinear_plant(SEED + 1)[0] != values
    effects = NonlinearEffects.from_values({k[len(CHANNEL) + 1:]: v for k, v in values.items()
                                            if '.nonlinear.' in k})
    coulomb = values[f'{CHANNEL}.sim.motor_coulomb']
    assert PLAUSIBLE['motor_coulomb'][0] <= coulomb <= PLAUSIBLE['motor_coulomb'][1]
    assert effects.any and 'motor Coulomb' in described
    assert isinstance(make_simulator(PlantParams.table_i(), None, effects),
                      NonlinearChannelSimulator)

    truth, _ = drawn_plant(SEED, 0.5, 2.0)
    figures = {'z_db': -40.0, 'z_rms_db': -37.0, 'distortion': 0.8, 'peak': 0.02,
               'peak_centre': 0.01, 'peak_away': 0.012}
    measured = {'after': {('hold', 1.0): dict(figures, z_db=30.0, z_rms_db=30.0),
                          ('dob_full_ff', 1.0): figures,
                          ('hold', 3.0): dict(figures, z_db=math.nan, z_rms_db=math.nan),
                          ('dob_full_ff', 3.0): figures}}
    identified = [SimpleNamespace(name=f'plant.{key}',
                                  value=1.5 * truth[f'{CHANNEL}.sim.plant.{key}'])
                  for key in ('hose_damping', 'endpoint_stiffness')]
    report = SimpleNamespace(identification=identified, model_class=SimpleNamespace(
        fits=False, misfit={'port': 0.22}))
    goals = goal_figures(measured, report, truth, [1.0, 3.0])
    assert goals['zwidth_db']['1'] == 70.0 and goals['zwidth_rms_db']['1'] == 67.0
    assert math.isnan(goals['zwidth_db']['3'])
    assert goals['hose_damping_error'] == pytest.approx(0.5)
    text = '\n'.join(goal_lines(goals, True))
    assert 'ratio 2.00' in text and 'DOES NOT FIT' in text and '3 rad/s none' in text
    assert 'ratio 1.20)' in text
    # the four-bar the bonded drive showed, beside the sim's: the effects' own map
    from seaforce_ros.core.nonlinear_effects import finger_ratio
    from seaforce_ros.demos.commission import four_bar
    ends = four_bar(values)
    assert ends == (finger_ratio(-effects.half_stroke, effects),
                    finger_ratio(effects.half_stroke, effects))
    assert min(ends) >= 1.0 and max(ends) > 1.0 and four_bar({}) == (1.0, 1.0)
    line = 'finger ratio r(q)/r(0) of the four-bar: 1.100 at q = -0.5 rad, ...'
    measured['after'][('dob_full_ff', 1.0)] = dict(figures, finger_ratio=line)
    goals = goal_figures(measured, report, truth, [1.0, 3.0], finger=ends)
    text = '\n'.join(goal_lines(goals, True))
    assert f'bonded drive of dob_full_ff at 1 rad/s: {line}' in text
    assert f"(the sim's: {ends[0]:.3f} and {ends[1]:.3f} at the ends" in text

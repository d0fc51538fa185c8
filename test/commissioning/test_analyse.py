"""One commissioning run's analysis (commissioning/analyse.py), as the action's child runs it:
a record of the core simulator's free-air excitation of a plant off the controller's model.

A run tunes, writes the report, a params file that keeps an existing file's comments and a
rollback file holding exactly the values it replaces; the result is JSON with names, old and
new values in step; a dry run writes no params; the second run reports the drift against the
first; a run directory with a missing, malformed or wrong request ends with one error line and
exit status 1, never a traceback."""
import dataclasses
import io
import json
import math
import types
from contextlib import redirect_stdout

import numpy as np
import pytest
import yaml

from seaforce_ros.commissioning.analyse import (RECORD_FILE, REQUEST_FILE, TORQUE_WARNING,
                                                Analysis, AnalysisError, AnalysisRequest,
                                                analyse, analyse_directory, main,
                                                torque_lines, write_stage)
from seaforce_ros.commissioning.experiments import run_free_air_excitation
from seaforce_ros.commissioning.record import save_record
from seaforce_ros.commissioning.report import CommissioningReport, ReportMeta, load_report
from seaforce_ros.commissioning.tuning import TUNED_KEYS
from seaforce_ros.core.params import ControllerConfig, DahlParams, PlantParams

CHANNEL = 'pinch'
TRUE = PlantParams.table_i().scaled(motor_inertia=1.3, hose_stiffness=0.8, endpoint_damping=1.4)
TRUE_DAHL = DahlParams(sigma=16.0, coulomb_force=0.025)


@pytest.fixture(scope='module')
def record():
    """12 s of excitation, 1..400 Hz (the band the fit needs)."""
    return run_free_air_excitation(TRUE, TRUE_DAHL, ControllerConfig(), seed=4, duration=12.0,
                                   band=(1.0, 400.0))


def flatten(node, prefix=''):
    out = {}
    for key, value in node.items():
        if isinstance(value, dict):
            out.update(flatten(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


def test_a_run_tunes_and_writes_its_files(record, tmp_path):
    params = tmp_path / 'setup.yaml'
    params.write_text('# my gripper\n/**:\n  ros__parameters:\n    pinch:\n      dob:\n'
                      '        cutoff: 125.0  # the old lambda\n    other: 3\n')
    run = tmp_path / 'run1'
    run.mkdir()
    config = ControllerConfig()
    steps = []
    a = analyse(record, AnalysisRequest(CHANNEL, config, params_file=str(params), apply=True),
                run, progress=lambda *step: steps.append(step))
    assert a.tuned, a.message
    # progress: known phases, fractions rising within 0..1
    assert [s[0] for s in steps][0] == 'identify' and steps[-1][0] == 'report'
    fractions = [s[1] for s in steps]
    assert all(0.0 <= f <= 1.0 for f in fractions) and fractions == sorted(fractions)
    # the identified plant is the truth (within the family goals)
    for row in a.report.identification:
        if row.name.startswith('plant.'):
            true = getattr(TRUE, row.name.split('.')[1])
            assert abs(row.value / true - 1.0) < 0.15, (row.name, row.value, true)
    # the params file: updated in place, its comments and other keys kept
    text = params.read_text()
    assert '# my gripper' in text and 'other: 3' in text
    written = flatten(yaml.safe_load(text)['/**']['ros__parameters'])
    for key, value in a.apply.items():
        assert written[f'{CHANNEL}.{key}'] == value, key
    # the rollback file: exactly the values replaced
    rollback = flatten(yaml.safe_load((run / 'rollback.yaml').read_text())['/**']
                       ['ros__parameters'])
    old = config.to_dict()
    assert rollback == {f'{CHANNEL}.{k}': old[k] for k in a.apply}
    # the result: JSON, names / old / new in step, NaN as null
    result = json.loads(json.dumps(a.result()))
    assert len(result['names']) == len(result['old_values']) == len(result['new_values'])
    for name, o, n in zip(result['names'], result['old_values'], result['new_values']):
        assert o == old[name]
        assert n == a.apply[name]
    assert result['report_path'] == str(run / 'report.html')
    loaded = load_report(run / 'report.json')
    assert loaded.tuning is not None and loaded.zwidth is not None
    assert {m.mode for m in loaded.impedance} >= {'hold', 'dob_full_ff', 'impedance'}
    # the work loops of a backdrive at 1 rad/s on the identified model, with the rms and the
    # peaks beside the fundamental, and the figure (e) of them
    loops = {w.mode: w for w in loaded.work_loops}
    assert set(loops) == {'passive', 'hold', 'dob', 'dob_full_ff'}
    for w in loops.values():
        assert w.z_rms_db >= w.z_db - 0.1 and w.peak >= w.peak_centre > 0.0
        assert len(w.x_e) == len(w.f_e) > 100 and np.ptp(w.x_e) == pytest.approx(1.0, rel=0.02)
    assert loops['hold'].z_db > loops['dob_full_ff'].z_db + 40.0
    assert (run / 'work_loops.png').stat().st_size > 10_000
    # the rms predicted at 1, 3 and 10 rad/s for every mode (the same backdrives), never below
    # the fundamental there, and the Z-width on it
    rows = {m.mode: m for m in loaded.impedance}
    for m in ('passive', 'hold', 'dob', 'dob_full_ff'):
        assert list(rows[m].rms_omega) == [1.0, 3.0, 10.0]
        fund = np.interp(np.log(rows[m].rms_omega), np.log(rows[m].omega), np.abs(rows[m].z))
        assert np.all(rows[m].rms_abs > 0.7 * fund), m
    assert len(loaded.zwidth.rms_db) == 3 and np.all(loaded.zwidth.rms_db > 20.0)
    assert 'dB rms; Z-width on the rms' in a.result()['summary']
    assert 'work loop (simulated on the identified model' in a.result()['summary']
    # the motor torque those backdrives took: the hold's at 1 rad/s is the quasi-static one
    # (the motor servo K_p + k in series with the hose k_s, the finger at 0.5 rad), within
    # what its Dahl friction and inertia add; the summary says it, and warns where a backdrive
    # would take more than TORQUE_WARNING of max_torque
    plant, hold = a.model.plant, a.tuning.config.hold.stiffness
    static = hold * plant.hose_stiffness * 0.5 / (hold + plant.motor_stiffness
                                                  + plant.hose_stiffness)
    peak = a.backdrives.peak_torque['hold'][a.backdrives.omega.index(1.0)]
    assert peak == pytest.approx(static, rel=0.1)
    assert a.backdrives.peak_torque['passive'] == [0.0, 0.0, 0.0]
    line = next(x for x in a.report.summary if x.startswith('predicted peak motor torque'))
    assert f'hold {peak:.3g} N m (at 1 rad/s)' in line, line
    # (the default max_torque, 5 N m, is what this 0.8x-k_s plant's hold takes at 0.5 rad)
    over = [(m, w) for m, peaks in a.backdrives.peak_torque.items()
            for w, p in zip(a.backdrives.omega, peaks) if p > TORQUE_WARNING * 5.0]
    assert over == [('hold', 1.0)]
    warnings = [x for x in a.report.summary if x.startswith('WARNING')]
    assert len(warnings) == 1 and warnings[0].startswith(
        "WARNING: hold's backdrive at 1 rad/s (0.5 rad) is predicted to take"), warnings
    assert torque_lines(a.backdrives, 100.0)[1:] == []
    # the tuned settings are a valid whole configuration
    assert ControllerConfig.from_dict(a.apply, base=config) == a.tuning.config
    assert a.after_db[1.0] >= a.before_db[1.0] - 3.0
    # the feed-forward's uncertainties from the identification (1-sigma and misfit, >= 1 %),
    # tighter than the hand-typed 10 %, and what their margin costs, in the summary
    ff = a.tuning.config.feedforward
    for name in ('damping_uncertainty', 'stiffness_uncertainty', 'dahl_uncertainty'):
        assert 0.01 <= getattr(ff, name) < 0.1, (name, getattr(ff, name))
        assert a.apply[f'feedforward.{name}'] == getattr(ff, name)
    assert any(line.startswith('feed-forward margin: b_e x') and 'dB of dob_full_ff' in line
               for line in a.report.summary), a.report.summary


def test_a_dry_run_writes_no_params_and_the_next_run_reports_drift(record, tmp_path):
    first, second = tmp_path / 'a', tmp_path / 'b'
    first.mkdir()
    second.mkdir()
    dry = analyse(record, AnalysisRequest(CHANNEL, ControllerConfig(), dry_run=True), first)
    assert dry.tuned and dry.params_file == '' and dry.rollback_file == ''
    assert sorted(p.name for p in first.iterdir() if p.suffix == '.yaml') == []
    again = analyse(record, AnalysisRequest(CHANNEL, ControllerConfig(), dry_run=True,
                                            previous=str(first / 'report.json')), second)
    rows = {r.name: r for r in again.report.identification}
    assert rows['plant.hose_stiffness'].previous == rows['plant.hose_stiffness'].value
    assert any('drift against the commissioning of' in line for line in again.report.summary)


def _main(directory):
    out = io.StringIO()
    with redirect_stdout(out):
        code = main([str(directory)])
    return code, [json.loads(line) for line in out.getvalue().splitlines()]


def test_bad_run_directories_end_with_one_error_line(record, tmp_path):
    code, lines = _main(tmp_path / 'missing')
    assert code == 1 and 'request.json' in lines[-1]['error']
    bad = tmp_path / 'bad'
    bad.mkdir()
    (bad / REQUEST_FILE).write_text('{not json')
    code, lines = _main(bad)
    assert code == 1 and 'not JSON' in lines[-1]['error']
    (bad / REQUEST_FILE).write_text(json.dumps({'channel': 'pinch',
                                                'config': {'dob.cutoff': 'fast'}}))
    with pytest.raises(AnalysisError, match='config'):
        analyse_directory(bad)
    (bad / REQUEST_FILE).write_text(json.dumps({'config': {}}))
    with pytest.raises(AnalysisError, match='channel'):
        analyse_directory(bad)
    (bad / REQUEST_FILE).write_text(json.dumps({'channel': 'pinch', 'config': {}}))
    (bad / RECORD_FILE).write_bytes(b'garbage')
    code, lines = _main(bad)
    assert code == 1 and 'not a commissioning record' in lines[-1]['error']


def test_a_record_that_identifies_nothing_still_reports(tmp_path):
    """A finger that did not move (no excitation): no tuning, the reason, exit status 1 after
    the result; the report says what it could."""
    n = 24000
    quiet = run_free_air_excitation(TRUE, TRUE_DAHL, ControllerConfig(), seed=4, duration=12.0,
                                    band=(1.0, 400.0))
    from seaforce_ros.commissioning.record import ExcitationRecord
    flat = ExcitationRecord(dt=quiet.dt, cycle=quiet.cycle[:n], x=np.zeros(n), v=np.zeros(n),
                            f_p=np.zeros(n), applied=np.zeros(n), command=np.zeros(n),
                            excitation=np.zeros(n))
    run = tmp_path / 'run'
    run.mkdir()
    save_record(flat, run / RECORD_FILE)
    (run / REQUEST_FILE).write_text(json.dumps({'channel': 'pinch', 'config': {}}))
    code, lines = _main(run)
    assert code == 1
    result = next(line['result'] for line in lines if 'result' in line)
    assert 'not tuned' in result['message'] and not result['tuned']
    assert result['params_file'] == '' and result['apply'] == {}
    assert 'error' in lines[-1]
    assert all(v is None or math.isfinite(v) for v in result['new_values'])


def test_params_files_keep_strings_strings(tmp_path):
    """An existing file updated in place, and a new one: strings that look like numbers or
    bools read back as the strings, floats as floats."""
    from seaforce_ros.identification.output import write_values_file
    values = {'pinch.passivity_guard': 'active', 'pinch.a': 'true', 'pinch.b': '1.5',
              'pinch.dob.cutoff': 300.0}
    existing = tmp_path / 'old.yaml'
    existing.write_text('# kept\n/**:\n  ros__parameters:\n    pinch:\n'
                        '      passivity_guard: disabled  # was\n      a: x\n')
    for path in (existing, tmp_path / 'new.yaml'):
        write_values_file(path, values)
        back = flatten(yaml.safe_load(path.read_text())['/**']['ros__parameters'])
        assert {k: back[k] for k in values} == values
        assert all(type(back[k]) is type(v) for k, v in values.items())
    assert '# kept' in existing.read_text() and '# was' in existing.read_text()


def test_the_rollback_file_loads_one_value_at_a_time(tmp_path):
    """A tuning that lowered the motor inertia (a plant at 0.6x) and m_n and raised lambda
    with it: its rollback file is ordered so that ``ros2 param load``, which sets the values
    one at a time in file order, passes eq. 28 after each one (m_n back before m), and it
    holds exactly the replaced values."""
    start = ControllerConfig()
    m = start.plant.motor_inertia
    tuned = ControllerConfig.from_dict({'plant.motor_inertia': 0.6 * m, 'plant.hose_damping':
                                        0.011, 'dob.nominal_inertia': 0.6 * m,
                                        'dob.cutoff': 200.0}, base=start)
    new, old = tuned.to_dict(), start.to_dict()
    apply = {k: new[k] for k in TUNED_KEYS if k in new}
    analysis = Analysis(CommissioningReport(ReportMeta(CHANNEL, '', {}, False)), 'tuned',
                        tuned=True, tuning=types.SimpleNamespace(config=tuned), apply=apply,
                        old_values={k: old[k] for k in apply})
    write_stage(tmp_path, analysis, AnalysisRequest(CHANNEL, start))
    assert analysis.rollback_file == str(tmp_path / 'rollback.yaml'), analysis.message
    text = (tmp_path / 'rollback.yaml').read_text()
    assert f'commission --rollback {tmp_path}' in text
    loaded = yaml.safe_load(text)['/**']['ros__parameters']
    assert flatten(loaded) == {f'{CHANNEL}.{k}': old[k] for k in apply}
    config = tuned
    for key, value in loaded.items():          # file order: ros2 param load's sets
        config = ControllerConfig.from_dict({key: value}, base=config)
    assert config == start


def test_the_backdrives_simulate_the_hose_terms_the_record_showed_but_did_not_size():
    from seaforce_ros.commissioning.analyse import prediction_model
    from seaforce_ros.commissioning.nonlinear_terms import EquationFit, NonlinearTerms, Term
    from seaforce_ros.core.params import PlantTermsParams

    def term(key, value, resolved):
        return Term(key, 'port', key, 'N m/rad^2', value, 0.1 * value, resolved,
                    '' if resolved else 'chosen, but the two halves of the record disagree')

    def terms(chosen, *rows):
        # each equation's fit with every chosen term: its own k_s, b_s; b_e, k_e
        port = EquationFit('port', {'hose_stiffness': (12.0, 0.1), 'hose_damping': (0.006, 1e-5)},
                           0.1, 0.05, [k for k in chosen if k.startswith('hose')], 1000, 100)
        end = EquationFit('endpoint', {'endpoint_damping': (0.05, 1e-3),
                                       'endpoint_stiffness': (0.07, 1e-3)},
                          0.1, 0.05, [k for k in chosen if k.startswith('stroke')], 1000, 100)
        return NonlinearTerms(list(rows), {'port': port, 'endpoint': end})

    plant = TRUE
    model = PlantTermsParams(hose_flow=0.004)
    # chosen and not resolved: the whole fit's hose (k_s, b_s and every chosen hose term at
    # its whole-record value), not a term beside the other fit's k_s
    got_plant, got = prediction_model(plant, model, terms(
        ['hose_flow', 'hose_pressure'], term('hose_flow', 0.0041, True),
        term('hose_pressure', 15.3, False)))
    assert got == PlantTermsParams(hose_flow=0.0041, hose_pressure=15.3)
    assert got_plant == dataclasses.replace(plant, hose_stiffness=12.0, hose_damping=0.006)
    # nothing unsized (not chosen by the criterion, negative, not finite, or resolved and in
    # the controller's model already): the controller's model as it is
    for rows, chosen in (((term('hose_pressure', 15.3, False),), ['hose_flow']),
                         ((term('hose_pressure', -2.0, False),), ['hose_pressure']),
                         ((term('hose_pressure', math.nan, False),), ['hose_pressure']),
                         ((), ['hose_flow'])):
        assert prediction_model(plant, model, terms(chosen, term('hose_flow', 0.0041, True),
                                                    *rows)) == (plant, model)
    # no terms at all (the model class stage did not run)
    assert prediction_model(plant, model, None) == (plant, model)
    # the diaphragm's stroke stiffening chosen, not sized: the endpoint equation's whole fit
    # (b_e, k_e, k_3 and k_2 within k_2^2 <= 3 k_e k_3); a k_2 alone is left out
    got_plant, got = prediction_model(plant, model, terms(
        ['stroke_asymmetry', 'stroke_stiffness'], term('stroke_asymmetry', 0.5, False),
        term('stroke_stiffness', 0.05, False)))
    assert got == PlantTermsParams(hose_flow=0.004, stroke_asymmetry=math.sqrt(3 * 0.07 * 0.05),
                                   stroke_stiffness=0.05)
    assert got_plant == dataclasses.replace(plant, endpoint_damping=0.05,
                                            endpoint_stiffness=0.07)
    assert prediction_model(plant, model, terms(['stroke_asymmetry'],
                                                term('stroke_asymmetry', 0.01, False))) \
        == (plant, model)


def test_the_stroke_floor_leaves_a_term_up_to_40_percent_high_under_compensated():
    """A resolved stroke term whose 1-sigma is small gets the floor (TERM_UNCERTAINTY): its
    margin leaves a term up to 40 % high -- the range the free-finger property test of
    test_safety draws -- under-compensated; a larger 1-sigma takes a larger margin."""
    from seaforce_ros.commissioning.tuning import TERM_UNCERTAINTY, feedforward_uncertainties
    from seaforce_ros.core.params import FeedforwardParams, PlantTermsParams

    model_terms = PlantTermsParams(stroke_stiffness=0.06)

    def stroke_scale(sd):
        sigma = {'endpoint_damping': 1e-4, 'endpoint_stiffness': 1e-4, 'stroke_stiffness': sd}
        u = feedforward_uncertainties(TRUE, sigma, DahlParams(), 0.01, model_terms)
        return dataclasses.replace(FeedforwardParams(), **{
            k.split('.')[1]: v for k, v in u.items()}).stroke_scale()

    assert stroke_scale(0.0012) == pytest.approx(1.0 - 2.0 * math.hypot(TERM_UNCERTAINTY, 0.01))
    assert stroke_scale(0.0012) * 1.4 <= 1.0               # a term 40 % high: still below
    assert stroke_scale(0.018) == pytest.approx(1.0 - 2.0 * math.hypot(0.3, 0.01))


def test_a_plant_the_linear_fit_leaves_unidentified_takes_the_terms_equations_values(record):
    """Where the linear fit leaves the endpoint and the Dahl friction unidentified (a hose
    loss doubling at 1 rad/s of flow: m_e 120x, b_e and k_e near zero, their 1-sigmas above
    them) and the terms' equations give them, the controller's model takes those (m_e with
    the port search's 1-sigma, sigma from F_c and the search's sigma/F_c) and says so;
    where the equations do not give one, the run is refused naming it."""
    from seaforce_ros.commissioning.model import model_stage
    from seaforce_ros.commissioning.errors import CommissioningError
    from seaforce_ros.commissioning.free_air import Estimate, identify_free_air
    from seaforce_ros.commissioning.nonlinear_terms import EquationFit, NonlinearTerms

    ident = identify_free_air(record)
    lost = ('endpoint_inertia', 'endpoint_damping', 'endpoint_stiffness', 'sigma',
            'coulomb_force')
    params = dict(ident.parameters)
    for key in lost:
        params[key] = Estimate(math.nan, math.nan, 'the record does not tell it apart')
    blind = dataclasses.replace(ident, parameters=params)
    with pytest.raises(CommissioningError, match='endpoint_inertia'):
        model_stage(blind, None)

    def terms(port_linear):
        port = EquationFit('port', port_linear, 0.14, 0.004, ['hose_flow'], 1000, 100,
                           {'hose_stiffness': (9.6, 0.01), 'hose_damping': (0.0126, 1e-5),
                            'hose_flow': (0.012, 1e-5)}, 0.004)
        end = EquationFit('endpoint', {'endpoint_damping': (0.047, 1e-4),
                                       'endpoint_stiffness': (0.045, 1e-4),
                                       'coulomb_force': (0.054, 1e-4)}, 0.01, 0.001, [],
                          1000, 100, {'endpoint_damping': (0.047, 1e-4),
                                      'endpoint_stiffness': (0.045, 1e-4),
                                      'coulomb_force': (0.054, 1e-4)}, 0.001)
        return NonlinearTerms([], {'port': port, 'endpoint': end})

    searched = {'hose_stiffness': (9.6, 0.01), 'hose_damping': (0.0126, 1e-5),
                'endpoint_inertia': (5.3e-4, 1e-7), 'dahl_ratio': (240.0, 0.5)}
    model = model_stage(blind, terms(searched))
    assert model.plant.endpoint_inertia == 5.3e-4 and model.sigma['endpoint_inertia'] == 1e-7
    assert (model.plant.endpoint_damping, model.plant.endpoint_stiffness) == (0.047, 0.045)
    assert model.dahl.coulomb_force == 0.054
    assert model.dahl.sigma == pytest.approx(0.054 * 240.0)
    assert 0.0 < model.sigma['sigma'] < 0.01 * model.dahl.sigma
    assert any('did not identify' in line for line in model.lines), model.lines
    # the search gave no 1-sigma for m_e and no Dahl shape: refused, naming what is missing
    for missing, key in (('endpoint_inertia', 'endpoint_inertia'), ('dahl_ratio', 'Dahl')):
        partial = dict(searched)
        partial[missing] = (partial[missing][0], math.nan)
        with pytest.raises(CommissioningError, match=key):
            model_stage(blind, terms(partial))


def test_impedance_with_a_zero_target_is_dob_full_ffs_backdrive_not_simulated_twice(monkeypatch):
    """``impedance`` with a zero target renders ``F_cmp + F_d - 0 - 0``: its simulated
    backdrive is ``dob_full_ff``'s sample for sample, so the prediction stage takes those
    figures instead of simulating it again -- the same figures as simulating it; with a
    target it is simulated (and differs)."""
    from seaforce_ros.commissioning import analyse as an
    config = ControllerConfig()
    modes, omegas = ('dob_full_ff', 'impedance'), (3.0,)
    shared = an.work_loop_stage(TRUE, TRUE_DAHL, config, modes, omegas)
    monkeypatch.setattr(an, '_same_backdrive', lambda mode, config: mode)
    simulated = an.work_loop_stage(TRUE, TRUE_DAHL, config, modes, omegas)
    assert shared.figures['impedance'] == simulated.figures['impedance']
    assert shared.peak_torque['impedance'] == simulated.peak_torque['impedance']
    monkeypatch.undo()
    stiff = an.work_loop_stage(TRUE, TRUE_DAHL,
                               ControllerConfig.from_dict({'target.stiffness': 0.5}, config),
                               modes, omegas)
    assert stiff.figures['impedance'][0].z_rms > 2 * stiff.figures['dob_full_ff'][0].z_rms


@pytest.mark.parametrize("fitted, fitted_sigma, used", [
    (39.94, 5.02, "search"),      # a record over ROS: 3x the sim's 12.8, 6 1-sigmas off
    (22.88, 1.65, "search"),
    (13.26, 0.47, "fit"),         # within 50 % of the search (11.52): as identified
    (16.41, 0.51, "fit"),
    (10.0, 0.3, "fit"),           # below the search: the lower already
    (32.46, 9.5, "search"),       # within 3 of its 1-sigmas of the search, 2.5x the plant's
    (17.0, 3.0, "fit"),           # under 1.5x
])
def test_the_lower_dahl_sigma_of_fit_and_search_is_the_controllers(fitted, fitted_sigma, used):
    """The linear fit's Dahl sigma against F_c times the port equation's search's sigma/F_c:
    where the fit's lies more than 50 % above, whatever its 1-sigma, the controller
    gets the search's (with its 1-sigma, and a line saying so): a sigma above the finger's,
    of which the feed-forward cancels a share, leaves the finger's pre-sliding stiffness
    net negative; otherwise the fit's, untouched."""
    from seaforce_ros.commissioning.model import _lower_sigma
    port = types.SimpleNamespace(linear={"dahl_ratio": (372.4, 0.87)})
    dahl = DahlParams(sigma=fitted, coulomb_force=0.0309387)
    sigma = {"sigma": fitted_sigma, "coulomb_force": 0.000695}
    lines = []
    out = _lower_sigma(dahl, sigma, port, lines)
    searched = 0.0309387 * 372.4
    if used == "search":
        assert out.sigma == pytest.approx(searched) and out.coulomb_force == dahl.coulomb_force
        assert sigma["sigma"] == pytest.approx(searched * math.hypot(0.87 / 372.4,
                                                                     0.000695 / 0.0309387))
        assert len(lines) == 1 and "the lower is used" in lines[0]
    else:
        assert out == dahl and sigma["sigma"] == fitted_sigma and lines == []
    assert _lower_sigma(dahl, dict(sigma), None, []) == dahl
    nan_port = types.SimpleNamespace(linear={"dahl_ratio": (372.4, math.nan)})
    assert _lower_sigma(dahl, dict(sigma), nan_port, []) == dahl

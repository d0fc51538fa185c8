"""identify: chirp bags from the offline simulator (Table I and a second parameter set, Dahl
hysteresis, realistic sensor noise) -> Table I parameters; Dahl fit from a work loop; the bag
reader's formats; clear errors for bad input."""
import math
import subprocess

import numpy as np
import pytest
import yaml

from helpers.processes import executable

from seaforce_ros.tools import identify
from seaforce_ros.core.params import DahlParams, PlantParams
from seaforce_ros.core.sensors import SensorParams
from seaforce_ros import bags as bagio
from seaforce_ros.identification.dahl_model import dahl_force
from seaforce_ros.identification.experiments import chirp_experiment, work_loop_experiment
from seaforce_ros.identification.spectral import BlackmanTukey

TABLE_I = PlantParams.table_i()
#: clearly different: 3x endpoint inertia, half the hose stiffness, 2x motor damping
OTHER = TABLE_I.scaled(endpoint_inertia=3.0, hose_stiffness=0.5, motor_damping=2.0)
TIGHT = ("motor_inertia", "endpoint_inertia", "hose_stiffness")          # within 5 %
LOOSE = ("motor_damping", "motor_stiffness", "endpoint_damping", "endpoint_stiffness",
         "hose_damping")                                                 # within 15 %
FIELDS = ("x", "v", "f_p", "f_a", "x_e", "f_e")


def _free(n):
    return {k: np.zeros(n) for k in FIELDS}


def _chirp_bag(path, plant, storage="mcap", split=10.0, **kwargs):
    """A 60 s external-torque chirp (0.3 N m, 0.01-1000 Hz) on the pinch finger, motor off,
    Dahl hysteresis (F_c 0.032 N m, sigma 12.8 N m/rad), default sensors (16-bit pressure
    ADC with 5e-4 N m noise, quantised encoders); wrist idle in the same messages."""
    d = chirp_experiment(plant=plant, dahl=DahlParams(), sensors=SensorParams(), seed=3,
                         **kwargs)
    bagio.write_state_bag(path, ["wrist", "pinch"], {"pinch": d, "wrist": _free(d["x"].size)},
                          storage=storage, split_duration=split)
    return d


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("idbags")
    _chirp_bag(root / "table_i", TABLE_I)                       # directory of mcap splits
    _chirp_bag(root / "other", OTHER, storage="sqlite3", split=None)  # one sqlite3 bag
    loop = work_loop_experiment(dahl=DahlParams(), cycles=2.0, seed=5)
    bagio.write_state_bag(root / "loop", ["pinch"], {"pinch": loop})
    return root


def _identify(capsys, *argv):
    code = identify.main([str(a) for a in argv] + ["--quiet"])
    out = capsys.readouterr()
    return code, out.out, out.err


def _plant_from(path, channel="pinch"):
    data = yaml.safe_load(path.read_text())
    return data["/**"]["ros__parameters"][channel]


def _errors(identified, truth):
    return {k: identified[k] / getattr(truth, k) - 1.0 for k in TIGHT + LOOSE}


@pytest.fixture(scope="module")
def table_i_run(bags, tmp_path_factory):
    """identify on the Table I chirp bag with the work-loop bag and plots (run once)."""
    out = tmp_path_factory.mktemp("table_i_run")
    params = out / "params.yaml"
    proc = subprocess.run([str(executable("identify")), str(bags / "table_i"), "--channel",
                           "pinch", "--out", str(params), "--plots", str(out / "plots"),
                           "--dahl-bag", str(bags / "loop")],
                          capture_output=True, text=True, timeout=300)
    return proc, params, out / "plots"


def _check_recovery(plant, truth):
    errors = _errors(plant, truth)
    for key in TIGHT:
        assert abs(errors[key]) < 0.05, (key, errors)
    for key in LOOSE:
        assert abs(errors[key]) < 0.15, (key, errors)


def _check_table(stdout):
    """The printed table has every parameter with a value, a 1-sigma and a fit error."""
    for key in TIGHT + LOOSE:
        line = next(l for l in stdout.splitlines() if l.startswith(key))
        fields = line.split()
        assert len(fields) >= 7, line
        value, sigma, fit_err, plant = fields[-4:]
        assert float(value) > 0 and float(sigma) >= 0, line
        assert fit_err.endswith("%") and plant in "ABC", line


def test_table_i_chirp_bag_recovers_the_eight_parameters(table_i_run):
    proc, params, plots = table_i_run
    assert proc.returncode == 0, proc.stderr
    _check_recovery(_plant_from(params)["plant"], TABLE_I)
    _check_table(proc.stdout)
    assert "2-zero/4-pole fit of X_e/F_e" in proc.stdout
    assert "%" in proc.stderr and "done" in proc.stderr          # progress lines
    assert (plots / "pinch_fig4_bode.png").stat().st_size > 10000


def test_second_parameter_set_recovered_too(bags, tmp_path, capsys):
    """3x endpoint inertia, half the hose stiffness, twice the motor damping (sqlite3 bag)."""
    out = tmp_path / "params.yaml"
    code, stdout, err = _identify(capsys, bags / "other", "--channel", "pinch", "--out", out)
    assert code == 0, err
    _check_recovery(_plant_from(out)["plant"], OTHER)
    _check_table(stdout)


def test_params_file_keys_and_dahl_fit_from_work_loop(table_i_run):
    proc, params, plots = table_i_run
    assert proc.returncode == 0, proc.stderr
    data = _plant_from(params)
    assert set(data["plant"]) == set(TIGHT + LOOSE)
    assert abs(data["dahl"]["sigma"] / 12.8 - 1) < 0.15, data["dahl"]
    assert abs(data["dahl"]["coulomb_force"] / 0.032 - 1) < 0.15, data["dahl"]
    assert data["dahl"]["exponent"] == 1.0
    assert "Dahl fit (work loop" in proc.stdout
    assert (plots / "pinch_fig6_dahl.png").stat().st_size > 10000


def test_dahl_only_on_top_of_existing_params(bags, table_i_run, tmp_path, capsys):
    proc, params, _ = table_i_run
    copy = tmp_path / "params.yaml"
    copy.write_text(params.read_text())
    before = _plant_from(copy)
    code, _, err = _identify(capsys, "--plant-params", copy, "--dahl-bag", bags / "loop",
                             "--channel", "pinch", "--out", copy, "--fit-exponent")
    assert code == 0, err
    again = _plant_from(copy)
    assert again["plant"] == before["plant"]
    assert abs(again["dahl"]["exponent"] - 1.0) < 0.15
    assert abs(again["dahl"]["sigma"] / 12.8 - 1) < 0.15


def test_the_written_model_is_checked_for_a_free_finger(bags, table_i_run, tmp_path, capsys):
    """After writing, identify says whether the file's damping reserve holds a free finger
    over the written model's band (what controller_node checks at start-up): held with the
    default; warned about with the reserve set to 0 in the --out file, naming what holds it."""
    proc, params, _ = table_i_run
    assert proc.returncode == 0, proc.stderr
    assert "free finger: feedforward.damping_reserve = 0.01 N m s/rad holds a free finger " \
        "in dob_full_ff over this model's band (+-20 %)" in proc.stdout, proc.stdout
    data = yaml.safe_load(params.read_text())
    data["/**"]["ros__parameters"]["pinch"]["feedforward"] = {"damping_reserve": 0.0}
    copy = tmp_path / "params.yaml"
    copy.write_text(yaml.safe_dump(data, default_flow_style=False))
    code, out, err = _identify(capsys, "--plant-params", copy, "--dahl-bag", bags / "loop",
                               "--channel", "pinch", "--out", copy)
    assert code == 0, err
    assert "warning: free finger: feedforward.damping_reserve = 0 N m s/rad leaves a free " \
        "finger in dob_full_ff small-signal unstable" in out and "holds it" in out, out


def test_the_check_reads_the_file_as_controller_node_does():
    """controller_view: only the sections the node /controller reads (``/**``, ``controller``,
    ``/**/controller``; not ``sim`` nor ``controller_spare``), the later overriding; the node's
    rate and loop; a name a typo away from a parameter (the node refuses to start on it)."""
    from seaforce_ros.core.params import ControllerConfig
    from seaforce_ros.identification.params_file import controller_view
    keys = [spec.name for spec in ControllerConfig.rows()]
    data = {
        "/**": {"ros__parameters": {"rate": 2000.0, "pinch": {
            "plant": {"motor_inertia": 0.002}, "feedforward": {"damping_reserve": 0.0}}}},
        "sim": {"ros__parameters": {"pinch": {"plant": {"motor_inertia": 0.003}}}},
        "controller_spare": {"ros__parameters": {"pinch": {
            "feedforward": {"damping_reserve": 0.05}}}},
        "controller": {"ros__parameters": {"rate": 1000.0, "loop": "direct"}},
        "/**/controller": {"ros__parameters": {"pinch.feedforward.margin": 3.0,
                                               "pinch.feedforward.damping_reserv": 0.1,
                                               "pinch.environment.mode": "free"}},
    }
    view = controller_view(data, "pinch", "f.yaml", keys)
    assert view.values == {"plant.motor_inertia": 0.002, "feedforward.damping_reserve": 0.0,
                           "feedforward.margin": 3.0}
    assert view.node == {"rate": 1000.0, "loop": "direct"}
    assert view.misspelt == [("pinch.feedforward.damping_reserv",
                              "pinch.feedforward.damping_reserve")]
    assert controller_view(data, "wrist", "f.yaml", keys).values == {}


def test_the_check_says_when_controller_node_would_not_start(bags, table_i_run, tmp_path,
                                                              capsys):
    """identify's line after writing: the file's rate in it; a misspelt name or a value the
    node refuses named as what keeps controller_node from starting (not a traceback, not a
    verdict on another file); an m_n left to its default follows the identified m."""
    proc, params, _ = table_i_run
    data = yaml.safe_load(params.read_text())
    copy = tmp_path / "params.yaml"
    argv = ("--plant-params", copy, "--dahl-bag", bags / "loop", "--channel", "pinch", "--out",
            copy)
    data["controller"] = {"ros__parameters": {"rate": 4000.0}}
    copy.write_text(yaml.safe_dump(data, default_flow_style=False))
    code, out, err = _identify(capsys, *argv)
    assert code == 0 and "at 4000 Hz in the topics layout" in out, out + err
    data["controller"] = {"ros__parameters": {"pinch.feedforward.damping_reserv": 0.1}}
    copy.write_text(yaml.safe_dump(data, default_flow_style=False))
    code, out, err = _identify(capsys, *argv)
    assert code == 0 and "warning: controller_node would not start on this file: pinch: " \
        "pinch.feedforward.damping_reserv: no such parameter (did you mean " \
        "pinch.feedforward.damping_reserve?)" in out, out + err
    data["controller"] = {"ros__parameters": {"pinch.dob.nominal_inertia": 1e-5}}
    copy.write_text(yaml.safe_dump(data, default_flow_style=False))
    code, out, err = _identify(capsys, *argv)
    assert code == 0 and "would not start" in out and "eq. 28" in out, out + err
    del data["controller"]
    data["/**"]["ros__parameters"]["pinch"]["plant"]["motor_inertia"] = 0.002
    copy.write_text(yaml.safe_dump(data, default_flow_style=False))
    code, out, err = _identify(capsys, *argv)
    assert code == 0 and "would not start" not in out and "free finger" in out, out + err


def test_linear_only_fit_is_biased_by_hysteresis(bags, table_i_run, tmp_path, capsys):
    """The paper's purely linear endpoint fit lumps the Dahl force into m_e, b_e, k_e: with
    the hysteresis in the data the linear-only b_e is far off (the default fit, which removes
    the fitted Dahl force, is within 5 %: previous tests)."""
    lin = tmp_path / "lin.yaml"
    assert _identify(capsys, bags / "table_i", "--channel", "pinch", "--out", lin,
                     "--no-dahl")[0] == 0
    e_lin = _errors(_plant_from(lin)["plant"], TABLE_I)
    e_dahl = _errors(_plant_from(table_i_run[1])["plant"], TABLE_I)
    assert abs(e_lin["endpoint_damping"]) > 0.2
    assert abs(e_dahl["endpoint_damping"]) < 0.05
    assert "endpoint hysteresis seen in the chirp" in table_i_run[0].stdout


def test_motor_chirp_identifies_motor_endpoint_and_hose(tmp_path, capsys):
    """The controller's chirp mode (torque on the motor, endpoint free): plants A-C, no D."""
    d = chirp_experiment(plant=TABLE_I, dahl=None, excitation="motor", duration=20.0,
                         amplitude=0.3, start_frequency=0.2)
    bagio.write_state_bag(tmp_path / "bag", ["pinch"], {"pinch": d})
    out = tmp_path / "p.yaml"
    code, stdout, err = _identify(capsys, tmp_path / "bag", "--channel", "pinch", "--out", out,
                                  "--band", "2", "400")
    assert code == 0, err
    assert "motor excitation" in stdout and "2-zero/4-pole" not in stdout
    errors = _errors(_plant_from(out)["plant"], TABLE_I)
    for key in ("motor_inertia", "endpoint_inertia", "hose_stiffness", "motor_damping"):
        assert abs(errors[key]) < 0.05, (key, errors)


# --- building blocks -------------------------------------------------------------------------
def test_blackman_tukey_recovers_a_known_filter():
    """Noise-free first-order lag y = r/(1 + s/50) driven by white noise: BT H within 2 %."""
    import scipy.signal
    rng = np.random.default_rng(0)
    dt = 5e-4
    r = rng.standard_normal(200000)
    b, a = scipy.signal.cont2discrete(([50.0], [1.0, 50.0]), dt, method="bilinear")[:2]
    y = scipy.signal.lfilter(np.ravel(b), a, r)
    omega = np.logspace(0, 3, 20)
    bt = BlackmanTukey(r, dt, omega, periods=20)
    h = bt.response(bt.signal("y", y), bt.signal("r", r)).h
    z = np.exp(1j * omega * dt)
    exact = np.polyval(np.ravel(b), z) / np.polyval(a, z)
    assert np.max(np.abs(h / exact - 1)) < 0.02


def test_vectorised_dahl_matches_core_step_by_step():
    from seaforce_ros.core.dahl import dahl_step
    t = np.arange(20000) * 5e-4
    x = 0.4 * np.sin(t) + 0.002 * np.sin(60 * t)
    for n in (1.0, 0.5, 2.0):
        ref = [0.0]
        for k in range(1, x.size):
            ref.append(dahl_step(ref[-1], x[k] - x[k - 1], 12.8, 0.032, n))
        np.testing.assert_allclose(dahl_force(x, 12.8, 0.032, n), ref, atol=1e-12)


def test_reader_formats_and_mixed_layouts(tmp_path):
    """mcap dir, sqlite3 dir, bare .mcap file, directory of splits, a killed split without
    metadata, and messages whose layout differs (decoded one by one) all read the same."""
    n = 3000
    rng = np.random.default_rng(1)
    data = {c: {k: rng.standard_normal(n) for k in FIELDS} for c in ("wrist", "pinch")}
    bagio.write_state_bag(tmp_path / "m", ["wrist", "pinch"], data)
    bagio.write_state_bag(tmp_path / "s", ["wrist", "pinch"], data, storage="sqlite3",
                          split_duration=0.4)
    for src in (tmp_path / "m", tmp_path / "s", next((tmp_path / "m").glob("*.mcap"))):
        rec = bagio.read_channel(src, "pinch")
        np.testing.assert_array_equal(rec.f_p, data["pinch"]["f_p"])
        np.testing.assert_array_equal(rec.cycle, np.arange(n))
    # a bag directory without metadata.yaml (ros2 bag record killed before writing it)
    (tmp_path / "s" / "metadata.yaml").unlink()
    rec = bagio.read_channel(tmp_path / "s", "wrist")
    np.testing.assert_array_equal(rec.x, data["wrist"]["x"])
    # different channel order and frame_id in some messages -> generic decoder for those
    store = bagio.typestore()
    rows, stamps = bagio.serialize_states(["pinch", "wrist"], {
        "pinch": {k: np.full(2, 7.0) for k in FIELDS},
        "wrist": {k: np.full(2, 9.0) for k in FIELDS}}, cycle0=n)
    from rosbags.rosbag2 import Writer
    w = Writer(tmp_path / "mixed", version=8)
    w.open()
    conn = w.add_connection("/actuator_state", bagio.ACTUATOR_STATE, typestore=store)
    mrows, mstamps = bagio.serialize_states(["wrist", "pinch"], data)
    for i in range(n):
        w.write(conn, int(mstamps[i]), mrows[i].tobytes())
    for i in range(2):
        w.write(conn, int(stamps[i]) + 10**9, rows[i].tobytes())
    w.close()
    rec = bagio.read_channel(tmp_path / "mixed", "pinch")
    assert len(rec) == n + 2
    assert np.all(rec.f_p[n:] == 7.0)
    np.testing.assert_array_equal(rec.f_p[:n], data["pinch"]["f_p"])


# --- errors: one clear line, exit status 2, never a stack trace ------------------------------
def _cli(*argv):
    proc = subprocess.run([str(executable("identify")), *map(str, argv), "--quiet"],
                          capture_output=True, text=True, timeout=120)
    return proc.returncode, proc.stdout, proc.stderr


def test_error_bag_without_actuator_state(tmp_path):
    from rosbags.rosbag2 import Writer
    store = bagio.typestore()
    w = Writer(tmp_path / "bag", version=8)
    w.open()
    conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
    msg = store.types["std_msgs/msg/String"](data="hello")
    w.write(conn, 1, store.serialize_cdr(msg, "std_msgs/msg/String"))
    w.close()
    code, _, err = _cli(tmp_path / "bag", "--channel", "pinch", "--out", tmp_path / "p.yaml")
    assert code == 2
    assert "no actuator_state messages" in err and "/chatter" in err
    assert "Traceback" not in err
    assert not (tmp_path / "p.yaml").exists()


def test_error_unknown_channel_and_missing_bag(bags, tmp_path, capsys):
    code, _, err = _identify(capsys, bags / "table_i", "--channel", "thumb", "--out",
                             tmp_path / "p.yaml")
    assert code == 2 and "unknown channel 'thumb'" in err and "wrist, pinch" in err
    code, _, err = _identify(capsys, tmp_path / "nope", "--channel", "pinch", "--out",
                             tmp_path / "p.yaml")
    assert code == 2 and "no such bag" in err


def test_error_unwritable_output_checked_before_work(bags, tmp_path, capsys):
    code, _, err = _identify(capsys, bags / "table_i", "--channel", "pinch", "--out",
                             tmp_path / "missing_dir" / "p.yaml")
    assert code == 2 and "does not exist" in err
    code, _, err = _identify(capsys, bags / "table_i", "--channel", "pinch", "--out", tmp_path)
    assert code == 2 and "is a directory" in err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = _identify(capsys, bags / "table_i", "--channel", "pinch", "--out",
                             tmp_path / "p.yaml", "--plots", blocker / "plots")
    assert code == 2 and "cannot create the directory" in err


def test_error_too_little_data_and_frequency_content(tmp_path, capsys):
    short = chirp_experiment(duration=3.0, tail=0.0)
    bagio.write_state_bag(tmp_path / "short", ["pinch"], {"pinch": short})
    code, _, err = _identify(capsys, tmp_path / "short", "--channel", "pinch", "--out",
                             tmp_path / "p.yaml")
    assert code == 2 and "too little data" in err
    slow = chirp_experiment(duration=30.0, start_frequency=0.05, end_frequency=5.0)
    bagio.write_state_bag(tmp_path / "slow", ["pinch"], {"pinch": slow})
    code, _, err = _identify(capsys, tmp_path / "slow", "--channel", "pinch", "--out",
                             tmp_path / "p.yaml")
    assert code == 2 and "too little frequency content" in err and "--band" in err
    # no endpoint encoder: X_e NaN everywhere
    nan = dict(slow, x_e=np.full(slow["x"].size, math.nan))
    bagio.write_state_bag(tmp_path / "noenc", ["pinch"], {"pinch": nan})
    code, _, err = _identify(capsys, tmp_path / "noenc", "--channel", "pinch", "--out",
                             tmp_path / "p.yaml")
    assert code == 2 and "x_e is NaN in every sample" in err


def test_nan_samples_are_dropped_and_counted(tmp_path, capsys):
    d = chirp_experiment(plant=TABLE_I, dahl=None, duration=20.0, start_frequency=0.2)
    rng = np.random.default_rng(2)
    bad = rng.choice(d["x"].size, 37, replace=False)
    d = dict(d, f_p=d["f_p"].copy())
    d["f_p"][bad] = math.nan
    bagio.write_state_bag(tmp_path / "bag", ["pinch"], {"pinch": d})
    out = tmp_path / "p.yaml"
    code, stdout, err = _identify(capsys, tmp_path / "bag", "--channel", "pinch", "--out", out,
                                  "--band", "2", "400")
    assert code == 0, err
    assert "non-finite samples dropped: f_p 37" in stdout
    plant = _plant_from(out)["plant"]
    assert abs(plant["hose_stiffness"] / TABLE_I.hose_stiffness - 1) < 0.05

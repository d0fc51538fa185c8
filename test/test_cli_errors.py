"""Command-line tools given bad input: one clear message naming the option, parameter or file,
exit status 2, never a traceback. The offline tools' cases (identify, zwidth, commission) run
the function their installed executable runs (its console-script entry point, loaded from the
installed package's metadata) in this process with the user's arguments; a Python start-up
each (numpy, scipy: 0.7 s quiet, 2-5 s beside the suite's other worker) made 100 cases 184 s
of the suite. That the executables themselves exit 2 on a bad argument without a traceback:
one case per tool, started as a user starts it. bag_recorder (a ROS node, --ros-args) is
always started as a process; every process is ended by its PID (the ``processes`` fixture),
pass or fail.

Also: ``identify --out`` onto an existing, commented params file (a copy of
config/gripper.yaml) changes the identified values in place and keeps every comment line."""
import contextlib
import functools
import importlib.metadata
import io
import re

import pytest
import yaml

from helpers.nodes import CONFIG
from helpers.processes import executable

from seaforce_ros.core.params import MODES, DahlParams, PlantParams
from seaforce_ros.bags import write_state_bag
from seaforce_ros.identification.experiments import chirp_experiment, work_loop_experiment
from seaforce_ros.identification.output import read_params_file
from seaforce_ros.identification.params_file import flatten

PLANT_KEYS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
              "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")


def _run(processes, name, *args, timeout=60.0):
    """Run an installed executable to its end: (exit code, stdout+stderr)."""
    proc = processes.start([str(executable(name)), *map(str, args)], name=name)
    code = proc.wait(timeout)
    out = proc.output()
    assert code is not None, f"{name} still running after {timeout} s:\n{out}"
    return code, out


#: the offline tools run in this process (bag_recorder, a ROS node, never)
IN_PROCESS = ("identify", "zwidth", "commission")


@functools.cache
def _entry_point(name):
    """The function the installed executable ``name`` runs (its console-script entry point)."""
    found = importlib.metadata.entry_points(group="console_scripts", name=name)
    assert len(found) == 1, (name, found)
    return next(iter(found)).load()


def _call(name, *args):
    """The tool's entry point with ``args`` in this process, as its executable calls it:
    (exit code, stdout+stderr). An exception it lets out fails the test (the executable would
    print a traceback)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            code = _entry_point(name)([str(a) for a in args])
        except SystemExit as exc:          # argparse's errors
            code = exc.code
    return code, out.getvalue()


def _rejected(processes, name, *args, naming=()):
    """The tool exits 2 with no traceback and a message that contains every ``naming``."""
    code, out = _call(name, *args) if name in IN_PROCESS else _run(processes, name, *args)
    assert code == 2, out
    assert "Traceback" not in out, out
    for text in naming:
        assert str(text) in out, f"{text!r} not in:\n{out}"
    return out


# --- bad params files: --plant-params, --truth (identify), --params & co. (zwidth) ----------
BAD_FILES = {
    "list": "- wrist\n- pinch\n",
    "scalar": "42\n",
    "empty": "",
    "comments_only": "# nothing here\n",
    "invalid_yaml": "/**:\n  ros__parameters: [\n",
    "no_ros__parameters": "pinch:\n  plant:\n    motor_inertia: 1.0\n",
    "ros__parameters_not_a_mapping": "/**:\n  ros__parameters: 5\n",
    "plant_not_a_mapping": "/**:\n  ros__parameters:\n    pinch:\n      plant: [1, 2]\n",
    "unknown_key": ("/**:\n  ros__parameters:\n    pinch:\n      plant:\n"
                    "        motor_inerta: 1.0\n"),
    "not_a_number": "/**:\n  ros__parameters:\n    pinch:\n      dahl:\n        sigma: abc\n",
}


def _bad_file(tmp_path, kind):
    """Path of a file of ``kind`` (a BAD_FILES key, or missing / directory)."""
    path = tmp_path / f"{kind}.yaml"
    if kind == "directory":
        path.mkdir()
    elif kind != "missing":
        path.write_text(BAD_FILES[kind])
    return path


FILE_KINDS = [*BAD_FILES, "missing", "directory"]
#: (tool, option, arguments around it); the other arguments are fine or never reached
FILE_OPTIONS = [
    ("identify", "--plant-params", ["--dahl-bag", "no_such_bag", "--channel", "pinch",
                                    "--out", "{tmp}/out.yaml"]),
    ("identify", "--truth", ["no_such_bag", "--channel", "pinch", "--out", "{tmp}/out.yaml"]),
    ("zwidth", "--params", ["--simulate", "--channel", "pinch"]),
    ("zwidth", "--true-params", ["--simulate", "--channel", "pinch"]),
    ("zwidth", "--reference-params", ["--simulate", "--channel", "pinch"]),
]
#: every kind of bad file for the three options that read a channel's parameters, a few for
#: the other two (the same reader)
FILE_CASES = [(*option, kind) for option in FILE_OPTIONS for kind in (
    FILE_KINDS if option[1] in ("--plant-params", "--truth", "--params")
    else ("list", "invalid_yaml", "missing"))]


@pytest.fixture(scope="module")
def file_case_runs(tmp_path_factory):
    """Every FILE_CASES case run to its end: [(directory, path, exit code, output)]."""
    def run(index):
        tool, option, args, kind = FILE_CASES[index]
        directory = tmp_path_factory.mktemp(f"file{index}")
        path = _bad_file(directory, kind)
        return (directory, path, *_call(tool, option, path,
                                        *(a.format(tmp=directory) for a in args), "--quiet"))
    return [run(index) for index in range(len(FILE_CASES))]


@pytest.mark.parametrize("case", range(len(FILE_CASES)),
                         ids=[f"{t}{o}-{k}" for t, o, _, k in FILE_CASES])
def test_params_file_option_that_is_not_a_params_file(file_case_runs, case):
    directory, path, code, out = file_case_runs[case]
    option = FILE_CASES[case][1]
    assert code == 2, out
    assert "Traceback" not in out, out
    assert f"{option} {path}" in out, out
    assert not (directory / "out.yaml").exists()


@pytest.mark.parametrize("tool,option,args", FILE_OPTIONS,
                         ids=[f"{t}{o}" for t, o, _ in FILE_OPTIONS])
def test_params_file_without_the_channel_names_the_channels_it_has(processes, tmp_path, tool,
                                                                   option, args):
    args = [a.format(tmp=tmp_path) for a in args]
    args[args.index("pinch")] = "thumb"
    out = _rejected(processes, tool, option, CONFIG, *args, "--quiet",
                    naming=[f"{option} {CONFIG}", "'thumb'", "wrist, pinch"])
    assert "unknown channel" in out


@pytest.mark.parametrize("name,args,naming", [
    ("identify", ["no_such_bag", "--channel", "pinch", "--out", "p.yaml", "--rate", "fast"],
     "--rate"),
    ("zwidth", ["--simulate", "--channel", "pinch", "--modes", "turbo"], "'turbo'"),
    ("commission", ["--channel", "pinch", "--controller", "bad//name"], "repeated '/'"),
])
def test_the_installed_executable_exits_2_without_a_traceback(processes, tmp_path, name, args,
                                                               naming):
    """As a user starts it (the cases above call the same entry point in-process)."""
    args = [str(tmp_path / a) if a == "p.yaml" else a for a in args]
    code, out = _run(processes, name, *args)
    assert code == 2 and "Traceback" not in out and naming in out, out
    assert out.strip().splitlines()[-1].startswith(f"{name}: error: "), out


# --- identify: numeric options ------------------------------------------------------------
@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "fast"])
def test_identify_rate_must_be_a_positive_number(processes, tmp_path, value):
    _rejected(processes, "identify", "no_such_bag", "--channel", "pinch", "--out",
              tmp_path / "p.yaml", "--rate", value, naming=["--rate", repr(value)])


@pytest.mark.parametrize("option", ["--band", "--rational-band"])
@pytest.mark.parametrize("lo,hi", [("0", "400"), ("-1", "400"), ("nan", "400"),
                                   ("0.5", "inf"), ("400", "0.5"), ("10", "10")])
def test_identify_band_must_be_positive_and_increasing(processes, tmp_path, option, lo, hi):
    _rejected(processes, "identify", "no_such_bag", "--channel", "pinch", "--out",
              tmp_path / "p.yaml", option, lo, hi, naming=[option])


def test_identify_chirp_bag_and_plant_params_together(processes, tmp_path):
    _rejected(processes, "identify", "no_such_bag", "--plant-params", CONFIG, "--channel",
              "pinch", "--out", tmp_path / "p.yaml", naming=["--plant-params"])


# --- zwidth: numeric options, modes, MODE=BAG labels -----------------------------------------
@pytest.mark.parametrize("value", ["0", "-0.2", "nan", "inf"])
def test_zwidth_amplitude_must_be_a_positive_number(processes, value):
    """--amplitude 0 used to print a table of '-' and exit 0."""
    _rejected(processes, "zwidth", "--simulate", "--channel", "pinch", "--amplitude", value,
              naming=["--amplitude", repr(value)])


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "1e6", "", "1,,3", "fast"])
def test_zwidth_frequencies_must_be_usable(processes, value):
    _rejected(processes, "zwidth", "--simulate", "--channel", "pinch", "--frequencies", value,
              naming=["--frequencies"])


@pytest.mark.parametrize("value", ["turbo", "hold,turbo", "", "hold"])
def test_zwidth_modes_must_be_controller_modes(processes, value):
    out = _rejected(processes, "zwidth", "--simulate", "--channel", "pinch", "--modes", value,
                    naming=["--modes"])
    if "turbo" in value:
        assert "'turbo'" in out and ", ".join(MODES) in out


def test_zwidth_label_of_a_bag_must_be_a_mode(processes, tmp_path):
    """``turbo=BAG`` used to be read as a mode called turbo; the valid ones come from
    core.params.MODES."""
    out = _rejected(processes, "zwidth", f"turbo={tmp_path / 'bag'}", "--channel", "pinch",
                    naming=["turbo=", "'turbo'", ", ".join(MODES)])
    assert "unknown mode" in out
    _rejected(processes, "zwidth", f"={tmp_path / 'bag'}", "--channel", "pinch",
              naming=["mode before '='"])


def test_zwidth_simulation_options_without_simulate(processes, tmp_path):
    _rejected(processes, "zwidth", tmp_path / "bag", "--channel", "pinch", "--params", CONFIG,
              naming=["--params", "--simulate"])


# --- commission ----------------------------------------------------------------------------
@pytest.mark.parametrize("name, reason", [("bad//name", "repeated '/'"),
                                          ("/1ctl", "must not start with a number")])
def test_commission_controller_must_be_a_node_name(processes, name, reason):
    out = _rejected(processes, "commission", "--channel", "pinch", "--controller", name,
                    naming=("--controller", name, reason))
    assert len(out.strip().splitlines()) == 1, out


def test_commission_rollback_needs_a_rollback_file(processes, tmp_path):
    out = _rejected(processes, "commission", "--rollback", tmp_path,
                    naming=("--rollback", "no rollback.yaml in", "dry run"))
    assert len(out.strip().splitlines()) == 1, out
    _rejected(processes, "commission", "--rollback", tmp_path, "--channel", "pinch",
              naming=("not allowed with argument",))


# --- bag_recorder: start-up parameters ------------------------------------------------------
def _recorder(tmp_path, *params, params_file=None):
    """bag_recorder arguments: ``--ros-args [--params-file FILE] -p NAME:=VALUE ...``."""
    args = ["--ros-args"]
    if params_file is not None:
        path = tmp_path / "recorder.yaml"
        path.write_text(yaml.safe_dump({"bag_recorder": {"ros__parameters": params_file}}))
        args += ["--params-file", path]
    for p in params:
        args += ["-p", p]
    return args


def test_bag_recorder_output_is_an_existing_file(processes, tmp_path):
    target = tmp_path / "taken"
    target.write_text("not a directory\n")
    out = _rejected(processes, "bag_recorder",
                    *_recorder(tmp_path, f"output:={target}"),
                    naming=["[bag_recorder] cannot start: output:", str(target)])
    assert target.read_text() == "not a directory\n"
    # and below a file: cannot be created
    _rejected(processes, "bag_recorder",
              *_recorder(tmp_path, f"output:={target / 'bag'}"),
              naming=["cannot start: output:", str(target)])
    assert "exists and is not a directory" in out


@pytest.mark.parametrize("param,value", [
    ("split_duration", 0.0), ("split_duration", -1.0), ("split_duration", 0),
    ("split_duration", float("nan")), ("report_period", 0.0), ("report_period", -5.0),
    ("topics", []), ("topics", [""]), ("storage", "rosbag"), ("reliability", "fast"),
])
def test_bag_recorder_rejects_a_bad_parameter(processes, tmp_path, param, value):
    """Given in a params file, as a user writes it (``split_duration: 0`` is a YAML int)."""
    out = tmp_path / "bag"
    _rejected(processes, "bag_recorder",
              *_recorder(tmp_path, params_file={"output": str(out), param: value}),
              naming=["[bag_recorder] cannot start:", param])
    assert not out.exists()


@pytest.mark.parametrize("value", ["0.0", "-1.0"])
def test_bag_recorder_split_duration_on_the_command_line(processes, tmp_path, value):
    _rejected(processes, "bag_recorder",
              *_recorder(tmp_path, f"output:={tmp_path / 'bag'}",
                         f"split_duration:={value}"),
              naming=["cannot start: split_duration"])


# --- identify --out onto an existing params file -------------------------------------------
@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """A short chirp (plant 1.5x endpoint inertia: values differ from the gripper file's) and
    a one-cycle work loop."""
    root = tmp_path_factory.mktemp("cli_bags")
    chirp = chirp_experiment(plant=PlantParams.table_i().scaled(endpoint_inertia=1.5),
                             dahl=DahlParams(), duration=20.0, start_frequency=0.2, seed=4)
    write_state_bag(root / "chirp", ["pinch"], {"pinch": chirp})
    loop = work_loop_experiment(dahl=DahlParams(), cycles=1.0, seed=5)
    write_state_bag(root / "loop", ["pinch"], {"pinch": loop})
    return root


def _identify(processes, bags, out, *extra):
    code, output = _run(processes, "identify", bags / "chirp", "--dahl-bag", bags / "loop",
                        "--band", "2", "400", "--channel", "pinch", "--out", out, "--quiet",
                        *extra, timeout=120.0)
    assert code == 0, output
    return output


def _comment(line):
    """The comment of a line ('' if none): from a '#' at its start or after a blank."""
    m = re.search(r"(^|[ \t])(#.*)$", line)
    return m.group(2) if m else ""


def test_identify_out_onto_commented_gripper_file_keeps_every_comment(processes, tmp_path,
                                                                      bags):
    """Used to merge the values but cut the file's comments (75 lines with one) to 3."""
    fresh = tmp_path / "fresh.yaml"
    _identify(processes, bags, fresh)
    identified = read_params_file(fresh, "pinch")
    original = CONFIG.read_text()
    copy = tmp_path / "gripper.yaml"
    copy.write_text(original)
    _identify(processes, bags, copy)
    updated = copy.read_text()

    # the identified values read back, by the tools' reader and as YAML
    assert read_params_file(copy, "pinch") == identified
    data = yaml.safe_load(updated)["/**"]["ros__parameters"]["pinch"]
    assert data["plant"] == identified[0] and data["dahl"] == identified[1]
    assert set(identified[0]) == set(PLANT_KEYS)
    # every other parameter as it was
    before = {s: flatten(v["ros__parameters"]) for s, v in yaml.safe_load(original).items()}
    after = {s: flatten(v["ros__parameters"]) for s, v in yaml.safe_load(updated).items()}
    changed = {f"pinch.plant.{k}" for k in PLANT_KEYS} | {f"pinch.dahl.{k}" for k in (
        "sigma", "coulomb_force", "exponent")}
    for section in before:
        for name in before[section]:
            if not (section == "/**" and name in changed):
                assert after[section][name] == before[section][name], (section, name)
    assert set(after["/**"]) == set(before["/**"])
    # every comment line survives, in place; only the identified values' lines change
    old_lines, new_lines = original.splitlines(), updated.splitlines()
    assert len(new_lines) == len(old_lines)
    comments = [line for line in old_lines if _comment(line)]
    assert len(comments) > 70
    for old, new in zip(old_lines, new_lines):
        assert _comment(new) == _comment(old), (old, new)
        if old != new:
            key = old.split(":")[0].strip()
            assert key == new.split(":")[0].strip() and key in PLANT_KEYS + (
                "sigma", "coulomb_force", "exponent"), (old, new)
            assert new.index("#") >= old.index("#"), (old, new)     # never moved left


def test_identify_out_dahl_only_onto_its_own_params_file(processes, tmp_path, bags):
    """--plant-params X --dahl-bag --out X: the plant stays, the Dahl values change."""
    copy = tmp_path / "gripper.yaml"
    copy.write_text(CONFIG.read_text())
    plant_before, _ = read_params_file(copy, "pinch")
    code, out = _run(processes, "identify", "--plant-params", copy, "--dahl-bag",
                     bags / "loop", "--channel", "pinch", "--out", copy, "--quiet")
    assert code == 0, out
    plant, dahl = read_params_file(copy, "pinch")
    assert plant == plant_before
    assert dahl["sigma"] != 12.8
    comments = [_comment(line) for line in CONFIG.read_text().splitlines() if _comment(line)]
    assert [_comment(line) for line in copy.read_text().splitlines()
            if _comment(line)] == comments


@pytest.mark.parametrize("text,reason", [
    ("/**:\n  ros__parameters:\n    pinch:\n      plant: {motor_inertia: 1.0}  # mine\n",
     "written on one line"),
    ("/**:\n  ros__parameters:\n    pinch: &p\n      plant:\n        motor_inertia: 1.0\n",
     "anchor"),
    ("# mine\n/**:\n  ros__parameters: [\n", "not valid YAML"),
    ("- a list\n", "not a ROS params file"),
])
def test_identify_out_refuses_a_layout_it_cannot_update(processes, tmp_path, text, reason):
    """Checked before any work (the bag is never read), and the file stays as it was (an
    invalid file used to be overwritten silently)."""
    out = tmp_path / "mine.yaml"
    out.write_text(text)
    _rejected(processes, "identify", tmp_path / "no_such_bag", "--channel", "pinch", "--out",
              out, naming=[f"--out {out}", reason, "left as it is"])
    assert out.read_text() == text

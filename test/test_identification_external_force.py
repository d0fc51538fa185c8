"""identify --external-force auto: the convention of the recorded F_e is told from the record.

Oracles: a continuous external torque (what a sampled force sensor sees) from the independent
simulator :mod:`helpers.second_sim` must come out ``instant``, with exactly the parameters of
``--external-force instant``; the project's simulator holds its torque over the sample and
must come out ``held``. The records are 40 s (the paper's band from 0.5 rad/s needs 25 s);
the wrong convention's misfit on the paper's band was measured 4.6-6.9x the right one's on
30 s Table I records and 9.4x on this 40 s one, 2.6-145x over 30 s family draws and 19-411x
from 60 s on (bench ``identify_external_force.py``; auto picked right on all 27 records).
One 60 s draw of the randomised family (``SEAFORCE_ID_SEED`` replays it) checks the pick away
from Table I.
"""
import math
import os

import numpy as np
import pytest
import yaml

from helpers.second_sim import DAHL, KEYS, TABLE_I, draw_family, simulate_chirp, write_bag

from seaforce_ros import bags as bagio
from seaforce_ros.core.params import DahlParams, PlantParams
from seaforce_ros.core.sensors import SensorParams
from seaforce_ros.identification.experiments import chirp_experiment
from seaforce_ros.identification.plant_id import CLEAR_MISFIT_RATIO, ExternalForceChoice
from seaforce_ros.tools import identify

DURATION = 40.0


def _run(capsys, bag, out, *extra):
    code = identify.main([str(bag), "--channel", "pinch", "--out", str(out), *extra])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return captured.out, captured.err


def _plant(path):
    return yaml.safe_load(path.read_text())["/**"]["ros__parameters"]["pinch"]["plant"]


def _choice_line(stdout):
    return next(line for line in stdout.splitlines() if line.startswith("external force:"))


def _misfits(line):
    """``{convention: chi2/dof}`` from the printed choice line."""
    inner = line.split("chi2/dof ")[1].split(";")[0].rstrip(")")
    return {name: float(value) for name, value in
            (part.split() for part in inner.split(", "))}


@pytest.fixture(scope="module")
def sensor_bag(tmp_path_factory):
    """A continuous external torque (sampled force sensor) on Table I with Dahl hysteresis."""
    path = tmp_path_factory.mktemp("ef") / "sensor"
    data = simulate_chirp(TABLE_I, DAHL, duration=DURATION, hold=False, seed=1)
    write_bag(path, ["pinch"], {"pinch": data})
    return path


def test_auto_takes_instant_for_a_sampled_force_sensor(sensor_bag, tmp_path, capsys):
    auto_out, progress = _run(capsys, sensor_bag, tmp_path / "auto.yaml")
    line = _choice_line(auto_out)
    assert line.startswith("external force: instant (auto:"), line
    misfits = _misfits(line)
    assert set(misfits) == {"held", "instant"}
    assert misfits["held"] > CLEAR_MISFIT_RATIO * misfits["instant"], line
    assert "too close" not in line
    assert "external force: instant (auto:" in progress          # the progress lines say it
    header = (tmp_path / "auto.yaml").read_text().split("/**")[0]
    assert "pinch.plant: external force: instant (auto: endpoint misfit" in header, header
    # the same parameters as the forced convention, and within the goal of the true ones
    forced_out, _ = _run(capsys, sensor_bag, tmp_path / "instant.yaml",
                         "--external-force", "instant", "--quiet")
    assert "external force: instant (as requested" in forced_out
    auto, forced = _plant(tmp_path / "auto.yaml"), _plant(tmp_path / "instant.yaml")
    for key in KEYS:
        assert auto[key] == pytest.approx(forced[key], rel=1e-9), key
        assert abs(auto[key] / TABLE_I[key] - 1) < 0.05, (key, auto[key], TABLE_I[key])
    # forcing the wrong convention reproduces the bias auto avoids
    _run(capsys, sensor_bag, tmp_path / "held.yaml", "--external-force", "held", "--quiet")
    # (m_e, which half a sample of phase moves most: measured -0.3 % vs -3.1 % on this record)
    held = _plant(tmp_path / "held.yaml")
    key = "endpoint_inertia"
    assert abs(auto[key] / TABLE_I[key] - 1) < 0.01, auto[key]
    assert abs(held[key] / TABLE_I[key] - 1) > 0.02, held[key]


def test_auto_takes_held_for_the_projects_simulator(tmp_path, capsys):
    d = chirp_experiment(plant=PlantParams.table_i(), dahl=DahlParams(),
                         sensors=SensorParams(), seed=3, duration=DURATION)
    bagio.write_state_bag(tmp_path / "bag", ["pinch"], {"pinch": d})
    out, _ = _run(capsys, tmp_path / "bag", tmp_path / "p.yaml", "--quiet")
    line = _choice_line(out)
    assert line.startswith("external force: held (auto:"), line
    misfits = _misfits(line)
    assert misfits["instant"] > CLEAR_MISFIT_RATIO * misfits["held"], line


def test_auto_on_a_random_plant_with_a_force_sensor(tmp_path, capsys):
    text = os.environ.get("SEAFORCE_ID_SEED")
    seed = int(text) if text else int.from_bytes(os.urandom(4), "little")
    plant, dahl = draw_family(np.random.default_rng(seed))
    data = simulate_chirp(plant, dahl, duration=60.0, hold=False, seed=seed % 1000)
    write_bag(tmp_path / "bag", ["pinch"], {"pinch": data})
    out, _ = _run(capsys, tmp_path / "bag", tmp_path / "p.yaml", "--quiet")
    line = _choice_line(out)
    assert line.startswith("external force: instant (auto:"), \
        f"replay with SEAFORCE_ID_SEED={seed}: {line}"


def test_help_shows_auto_as_the_default(capsys):
    text = identify.build_parser().format_help()
    flat = " ".join(text.split())
    assert "--external-force {auto,held,instant}" in flat
    assert "(default: auto)" in flat
    assert identify.build_parser().parse_args(["b", "--channel", "c", "--out", "o"]) \
        .external_force == "auto"


def test_the_choice_says_when_the_misfits_are_too_close():
    close = ExternalForceChoice("auto", "held", {"held": 1.0, "instant": 1.5})
    assert not close.clear and close.ratio == pytest.approx(1.5)
    assert "too close to tell, took the smaller" in close.summary()
    clear = ExternalForceChoice("auto", "instant", {"held": 30.0, "instant": 1.0})
    assert clear.clear and "too close" not in clear.summary()
    forced = ExternalForceChoice("held", "held", {"held": 1.0})
    assert math.isnan(forced.ratio) and "as requested" in forced.summary()

"""The params file written by identify loads into the real nodes with --params-file."""
import pytest

from helpers.nodes import CONFIG
from helpers.processes import executable

from seaforce_ros.core.params import PlantParams
from seaforce_ros.identification.output import write_params_file

KEYS = ("motor_inertia", "motor_damping", "motor_stiffness", "endpoint_inertia",
        "endpoint_damping", "endpoint_stiffness", "hose_damping", "hose_stiffness")


def test_identified_params_file_loads_into_controller_and_sim(processes, tmp_path, probe):
    plant = PlantParams.table_i().scaled(endpoint_inertia=1.07, hose_stiffness=0.93,
                                         motor_damping=1.11)
    dahl = {"sigma": 11.5, "coulomb_force": 0.029, "exponent": 1.0}
    params = write_params_file(tmp_path / "identified.yaml", "pinch", plant, dahl,
                               comments=["test"])
    names = [f"pinch.plant.{k}" for k in KEYS] + ["pinch.dahl.sigma",
                                                    "pinch.dahl.coulomb_force"]
    for exe, node in (("controller_node", "/controller"), ("sim_node", "/sim")):
        proc = processes.start([str(executable(exe)), "--ros-args", "--params-file",
                                str(CONFIG), "--params-file", str(params)], name=exe)
        assert proc.wait_for_output("spinning with", timeout=60), proc.output()
        values = probe.get_parameters(node, names)
        for k in KEYS:
            assert values[f"pinch.plant.{k}"] == pytest.approx(getattr(plant, k), rel=1e-5)
        assert values["pinch.dahl.sigma"] == pytest.approx(11.5)
        assert values["pinch.dahl.coulomb_force"] == pytest.approx(0.029)
        # the other channel keeps the gripper defaults
        other = probe.get_parameters(node, ["wrist.plant.hose_stiffness"])
        assert other["wrist.plant.hose_stiffness"] == pytest.approx(13.0782)

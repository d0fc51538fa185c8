"""One running sim_node + controller_node (+ bag_recorder) and a probe, for the test modules
that check files against what the nodes really publish (analyzers, URDF, layouts): each
module starts one and shares it among its tests."""
import pathlib
from typing import Dict, List, Set

from diagnostic_msgs.msg import DiagnosticArray

from helpers.nodes import start_node
from helpers.probe import Probe
from helpers.processes import ProcessGroup, executable

#: /diagnostics every 0.2 s (the default 1 s would make a test wait)
FAST_DIAGNOSTICS = {'diagnostics_period': 0.2}


class SimStack:
    """sim_node and controller_node on config/gripper.yaml, optionally bag_recorder; a probe."""

    def __init__(self, tmp_path: pathlib.Path, name: str, recorder: bool = False):
        self.processes = ProcessGroup()
        self.probe = Probe(f'probe_{name}')
        try:
            start_node(self.processes, 'sim_node', 'sim', tmp_path, FAST_DIAGNOSTICS)
            start_node(self.processes, 'controller_node', 'controller', tmp_path,
                       {**FAST_DIAGNOSTICS, 'state_timeout': 0.5})
            if recorder:
                proc = self.processes.start(
                    [str(executable('bag_recorder')), '--ros-args', '-p',
                     f'output:={tmp_path / "bag"}', '-p', 'report_period:=0.2'],
                    name='bag_recorder')
                assert proc.wait_for_output('spinning with', timeout=60), proc.output()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self.probe.close()
        self.processes.stop_all()

    def diagnostics(self, expected: Set[str], timeout: float = 30.0) -> Dict[str, object]:
        """Every /diagnostics status seen (name -> the latest status) once ``expected`` names
        have all been seen, and for at least two more periods after that."""
        self.probe.record(DiagnosticArray, '/diagnostics')

        def names() -> Set[str]:
            return {s.name for m in self.probe.messages('/diagnostics') for s in m.status}
        self.probe.wait_for(lambda: expected <= names(), timeout,
                            f'/diagnostics names {sorted(expected)}')
        seen = len(self.probe.messages('/diagnostics'))
        self.probe.wait_messages('/diagnostics', seen + 6, timeout)
        return {s.name: s for m in self.probe.messages('/diagnostics') for s in m.status}

    def topics(self) -> Dict[str, List[str]]:
        """Topic name -> types, from the graph."""
        return dict(self.probe.node.get_topic_names_and_types())

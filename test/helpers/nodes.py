"""Start the installed seaforce_ros executables with a parameter file for a test."""
import os
import pathlib
from typing import Any, Dict, Optional

import yaml

from helpers.processes import ROOT, ProcessGroup, executable

CONFIG = ROOT / 'config' / 'gripper.yaml'


def params_file(node_name: str, values: Dict[str, Any], directory: pathlib.Path) -> pathlib.Path:
    """A --params-file with ``values`` (flat dotted keys) for ``node_name``."""
    path = directory / f'{node_name}-overrides.yaml'
    path.write_text(yaml.safe_dump({node_name: {'ros__parameters': dict(values)}}))
    return path


def own_domain(index: int) -> int:
    """A DDS domain for a stack that runs beside the session's own: 101..200, the
    ``index``-th after the session's ``ROS_DOMAIN_ID`` (scripts/setup.sh and conftest draw
    theirs from 1..100), so that its nodes and the session's never meet."""
    return 101 + (int(os.environ.get('ROS_DOMAIN_ID', '0')) + index) % 100


def domain_env(domain: int, **extra: str) -> Dict[str, str]:
    """This process's environment with ``ROS_DOMAIN_ID=domain`` (and ``extra``)."""
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), **extra)


def start_node(processes: ProcessGroup, name: str, node_name: str, tmp_path: pathlib.Path,
               overrides: Optional[Dict[str, Any]] = None, config: pathlib.Path = CONFIG,
               wait: bool = True, prefix=(), ros_args=(), domain: Optional[int] = None):
    """Start an installed executable with config + overrides; ``prefix`` goes before it
    (e.g. ``('chrt', '-f', '40')``: chrt execs, so the PID stays the node's); ``ros_args``
    go after them (e.g. ``('-r', '__node:=controller_b')``; the overrides then go to that
    node name); ``domain``: a DDS domain of its own (:func:`own_domain`)."""
    argv = [*prefix, str(executable(name)), '--ros-args', '--params-file', str(config)]
    if overrides:
        argv += ['--params-file', str(params_file(node_name, overrides, tmp_path))]
    argv += list(ros_args)
    proc = processes.start(argv, name=name,
                           env=None if domain is None else domain_env(domain))
    if wait:
        assert proc.wait_for_output('spinning with', timeout=60), proc.output()
    return proc

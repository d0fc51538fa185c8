"""The stand-in ``compat/control_msgs`` (the gripper actions' interfaces where no ROS
distribution provides control_msgs): the same RIHS01 type hashes as the ROS 2 Jazzy
distribution's package, and never built by a colcon crawl of a workspace.

The expected hashes below were obtained once by hand, outside the repository: the Jazzy line's
(5.x, release 5.8.0) ``msg/GripperCommand.msg``, ``action/GripperCommand.action`` and
``action/ParallelGripperCommand.action`` of ros-controls' control_msgs, built with this
environment's rosidl (``colcon build`` of an interface package holding those three files, in a
temporary directory, against the venv's Jazzy sensor_msgs); the hashes read from the generated
``share/control_msgs/{msg,action}/*.json`` (``type_hashes``). A type hash covers the field
names, types and order of the type and of every type it refers to -- not the comments -- so a
client built against the distribution's package and a node using the stand-in (or the other way
round) agree on the wire."""
import json
import os
import pathlib
import subprocess

import pytest
from ament_index_python.packages import get_package_share_directory

ROOT = pathlib.Path(__file__).resolve().parent.parent
COLCON = pathlib.Path(os.environ.get('VIRTUAL_ENV', ROOT / '.venv')) / 'bin' / 'colcon'

#: Jazzy control_msgs 5.8.0, built by hand as the module docstring says.
JAZZY_HASHES = {
    'control_msgs/msg/GripperCommand':
        'RIHS01_57eb8f326c9889ca8bb34ead82cc94cc09bf6bc5c3b6c09546dca3a00b589890',
    'control_msgs/action/GripperCommand':
        'RIHS01_e17c0e644eccf14bea84a0a93e0977182872c2eb7873ca6694900059b46dbc84',
    'control_msgs/action/GripperCommand_Goal':
        'RIHS01_607d9f41eb241e1922e90f02125e87ae6bfb78f7f64a71dc92630263d01f8b6d',
    'control_msgs/action/GripperCommand_Result':
        'RIHS01_bf512d5aa6a0e4fe4d8be22b2ec4a1973c3d250fa1f65e47450322c25c45c0a0',
    'control_msgs/action/GripperCommand_Feedback':
        'RIHS01_8f7c520077bab528bb9161ee3b83c81eee1f8aecadb8922ce82c79d667a819c4',
    'control_msgs/action/ParallelGripperCommand':
        'RIHS01_adfd3c1ebe8abc38ebcc0e454b6423d291d4010dd5697d14eca5b9be4726ae18',
    'control_msgs/action/ParallelGripperCommand_Goal':
        'RIHS01_412807b6b6acf2bf406fb0cf3b5c8f84286cd4e4d425734155aa1ff41caa0063',
    'control_msgs/action/ParallelGripperCommand_Result':
        'RIHS01_51acbcd62aa44097d3877c506eab1146856fa8768628ffbe102c1699152d2afa',
    'control_msgs/action/ParallelGripperCommand_Feedback':
        'RIHS01_ed6f7c4e5aea7f960432663c0e762e001a0a1f5cc0130d126e60041412d0543c',
}
FILES = ('msg/GripperCommand', 'action/GripperCommand', 'action/ParallelGripperCommand')


def built_hashes():
    """type name -> RIHS01 hash of every type in the installed control_msgs' descriptions."""
    share = pathlib.Path(get_package_share_directory('control_msgs'))
    hashes = {}
    for name in FILES:
        for entry in json.loads((share / f'{name}.json').read_text())['type_hashes']:
            hashes[entry['type_name']] = entry['hash_string']
    return hashes


def test_the_installed_control_msgs_has_jazzys_type_hashes():
    hashes = built_hashes()
    wrong = {name: (hashes.get(name), expected) for name, expected in JAZZY_HASHES.items()
             if hashes.get(name) != expected}
    assert not wrong, wrong


def test_the_installed_control_msgs_is_the_stand_in_here():
    """Without a distribution (this environment) the package setup.sh built is the stand-in:
    the hashes above are those of compat/control_msgs, not of something else on the path."""
    share = pathlib.Path(get_package_share_directory('control_msgs'))
    assert share.resolve().is_relative_to((ROOT / 'install').resolve()), share
    for name in FILES:
        source = ROOT / 'compat' / 'control_msgs' / f'{name}.{name.split("/")[0]}'
        assert source.exists(), source


@pytest.mark.parametrize('layout', ['repository', 'workspace'])
def test_a_colcon_crawl_never_finds_the_stand_in(tmp_path, layout):
    """``colcon list`` from the repository (setup.sh's own base paths) or from a ROS workspace
    holding it under src/ lists no control_msgs; only an explicit --paths does."""
    if layout == 'workspace':
        (tmp_path / 'src').mkdir()
        (tmp_path / 'src' / 'seaforce_ros').symlink_to(ROOT)
        argv, cwd = [str(COLCON), 'list', '--names-only'], tmp_path
    else:
        argv, cwd = [str(COLCON), 'list', '--names-only', '--base-paths', '.', 'msg_defs',
                     'compat'], ROOT
    names = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, check=True,
                           timeout=60).stdout.split()
    assert 'seaforce_ros' in names and 'control_msgs' not in names, names
    explicit = subprocess.run([str(COLCON), 'list', '--names-only', '--paths',
                               'compat/control_msgs'], cwd=ROOT, capture_output=True,
                              text=True, check=True, timeout=60).stdout.split()
    assert explicit == ['control_msgs'], explicit

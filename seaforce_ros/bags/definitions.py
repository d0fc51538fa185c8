"""The ``seaforce_msgs`` message definitions as seen by the ``rosbags`` library.

Bags are written and read with ``rosbags`` (no rosbag2 on PyPI). For a bag written here to be
interchangeable with one from ``ros2 bag record``, rosbags must know the exact ``.msg``
definitions of ``seaforce_msgs``: this module finds them (installed share directory through the
ament index, else ``msg_defs/msg`` of a source checkout) and registers them, on top of the
standard ROS 2 Jazzy types, in a typestore. The actions' (Grasp, CalibrateFriction) goal,
result and feedback, and the feedback topic's message (``Grasp_FeedbackMessage``, what ``ros2
bag record`` of the action's hidden topics stores), are registered too, from
``action/<Name>.action``.

No rclpy import here: offline tools (identification, Z-width) use it without ROS running.
"""
from __future__ import annotations

import pathlib
from typing import TYPE_CHECKING, Dict, List, Optional

if TYPE_CHECKING:
    from rosbags.interfaces.typing import Typesdict
    from rosbags.typesys.store import Typestore

MSG_PACKAGE = 'seaforce_msgs'
MESSAGE_NAMES = ('ActuatorState', 'ActuatorCommand', 'ControllerStatus')
ACTION_NAMES = ('Grasp', 'CalibrateFriction')


class InterfaceDefinitionError(RuntimeError):
    """The ``seaforce_msgs`` definitions could not be found or parsed."""


def msg_directory() -> pathlib.Path:
    """Directory holding ``ActuatorState.msg`` and the other ``seaforce_msgs`` definitions
    (``action/`` is beside it).

    Looks in the installed package share (``share/seaforce_msgs/msg`` via ament_index) first,
    then in ``msg_defs/msg`` beside this package in a source checkout.
    """
    candidates: List[pathlib.Path] = []
    try:
        from ament_index_python.packages import get_package_share_directory, PackageNotFoundError
        try:
            candidates.append(pathlib.Path(get_package_share_directory(MSG_PACKAGE)) / 'msg')
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    candidates.append(pathlib.Path(__file__).resolve().parents[2] / 'msg_defs' / 'msg')
    for directory in candidates:
        if all((directory / f'{name}.msg').is_file() for name in MESSAGE_NAMES) and all(
                (directory.parent / 'action' / f'{name}.action').is_file()
                for name in ACTION_NAMES):
            return directory
    raise InterfaceDefinitionError(
        f'cannot find the {MSG_PACKAGE} .msg files (looked in: '
        + ', '.join(str(c) for c in candidates)
        + '); build the workspace (scripts/setup.sh) or source its install/setup.bash.')


def message_definitions(directory: Optional[pathlib.Path] = None) -> Dict[str, str]:
    """Map ``seaforce_msgs/msg/<Name>`` to the text of its ``.msg`` file."""
    directory = directory or msg_directory()
    return {f'{MSG_PACKAGE}/msg/{name}': (directory / f'{name}.msg').read_text()
            for name in MESSAGE_NAMES}


def action_definitions(directory: Optional[pathlib.Path] = None) -> Dict[str, str]:
    """Map ``seaforce_msgs/action/<Name>_{Goal,Result,Feedback,FeedbackMessage}`` to its
    message text: the three sections of ``<Name>.action`` (split at ``---``, as rosidl does)
    and the feedback topic's message, ``goal_id`` + ``feedback``."""
    directory = (directory or msg_directory()).parent / 'action'
    out: Dict[str, str] = {}
    for name in ACTION_NAMES:
        text = (directory / f'{name}.action').read_text()
        sections = text.split('\n---\n')
        if len(sections) != 3:
            raise InterfaceDefinitionError(f'{name}.action: expected goal, result and feedback '
                                           f'separated by ---, found {len(sections)} sections')
        prefix = f'{MSG_PACKAGE}/action/{name}'
        for part, section in zip(('Goal', 'Result', 'Feedback'), sections):
            out[f'{prefix}_{part}'] = section
        out[f'{prefix}_FeedbackMessage'] = (f'unique_identifier_msgs/UUID goal_id\n'
                                            f'{prefix}_Feedback feedback\n')
    return out


def make_typestore(directory: Optional[pathlib.Path] = None) -> Typestore:
    """A rosbags typestore with the ROS 2 Jazzy standard types plus ``seaforce_msgs``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: Typesdict = {}
    definitions = {**message_definitions(directory), **action_definitions(directory)}
    for name, text in definitions.items():
        try:
            types.update(get_types_from_msg(text, name))
        except Exception as exc:  # rosbags raises its own parser errors
            raise InterfaceDefinitionError(f'cannot parse {name}: {exc}') from exc
    store.register(types)
    return store

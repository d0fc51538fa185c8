"""The ROS parameters of each node, from the core's schema (:mod:`seaforce_ros.core.schema`).

Per-channel keys are ``<channel>.<key>``. A value is checked against its row (type,
finiteness, range, allowed strings) at declaration and on every set; rules between
parameters (the DOB's passivity, eq. 28) are checked by the core in the nodes' on-set
callbacks. Nothing about a parameter is written here: which node declares which row, with
which default, is in the rows.
"""
from __future__ import annotations

import dataclasses
from typing import Dict, List

from ..core.errors import InvalidParameterError
from ..core.params import ControllerConfig, DahlParams, PlantParams
from ..core.schema import SIM, Spec, node_rows
from ..core.settings import SIM_MODEL_GROUPS, SIM_PREFIX
from .ros_common import StartupError

#: The model keys the sim mirrors: ``plant.*`` and ``dahl.*``.
PLANT_KEYS = tuple(spec.name for spec in PlantParams.SPECS)
DAHL_KEYS = tuple(spec.name for spec in DahlParams.SPECS)
MODEL_KEYS = tuple(spec.name for group in SIM_MODEL_GROUPS for spec in group.SPECS)


def node_specs(node: str) -> List[Spec]:
    """The node's own parameters (not per channel), with its defaults."""
    return node_rows(node, per_channel=False)


def controller_channel_specs(channel: str) -> List[Spec]:
    """Every controller parameter of one channel; defaults: the default configuration (the
    DOB's nominal inertia resolved to the plant's)."""
    defaults = ControllerConfig().to_dict()
    return [dataclasses.replace(spec, name=f'{channel}.{spec.name}', default=defaults[spec.name])
            for spec in ControllerConfig.rows()]


def sim_channel_specs(channel: str) -> List[Spec]:
    """The simulated plant's parameters of one channel: the controller's model (``plant.*``,
    ``dahl.*``, read-only), the sim's own settings and the environment. The true plant
    ``sim.plant.*`` / ``sim.dahl.*`` follows from the model: :func:`sim_plant_specs`."""
    model = [dataclasses.replace(spec, name=f'{channel}.{spec.name}', read_only=True,
                                 description=spec.description + ' (the model; the simulated '
                                 f'plant is {channel}.{SIM_PREFIX}{spec.name})')
             for group in SIM_MODEL_GROUPS for spec in group.SPECS]
    return model + [spec.qualified(f'{channel}.') for spec in node_rows(SIM, per_channel=True)]


def sim_plant_specs(channel: str, model: Dict[str, object]) -> List[Spec]:
    """The simulated gripper's true plant and Dahl hysteresis, ``<channel>.sim.plant.*`` /
    ``<channel>.sim.dahl.*``, each defaulting to the model's value in ``model``
    (``{'<channel>.plant.<x>': value}``): set them to run the controller on a wrong model;
    they change at run time (a drifting plant)."""
    return [dataclasses.replace(spec, name=f'{channel}.{SIM_PREFIX}{spec.name}',
                                default=float(model[f'{channel}.{spec.name}']),
                                description=spec.description + ' (the simulated plant, '
                                'default the model)')
            for group in SIM_MODEL_GROUPS for spec in group.SPECS]


def channel_values(values: Dict[str, object], channel: str, prefix: str = '') -> Dict[str, object]:
    """``{'<channel>.<prefix>x': v}`` -> ``{'<prefix>x': v}`` for one channel."""
    head = f'{channel}.{prefix}'
    return {k[len(channel) + 1:]: v for k, v in values.items() if k.startswith(head)}


def channels_from(values: Dict[str, object]) -> List[str]:
    """The validated ``channels`` parameter: unique, non-empty ROS-name-safe tokens.

    Raises :class:`~seaforce_ros.nodes.ros_common.StartupError` saying what to write instead.
    """
    channels = list(values['channels'])
    if not channels:
        raise StartupError('channels is empty: name at least one channel, e.g. [wrist, pinch]')
    for name in channels:
        if not name or not name.replace('_', 'a').isalnum() or name[0].isdigit():
            raise StartupError(f'channel name {name!r} must be letters, digits and _, '
                               'not starting with a digit')
    if len(set(channels)) != len(channels):
        raise StartupError(f'channel names must be unique: {channels}')
    return channels


def channel_error(exc: Exception, channel: str) -> str:
    """The core's rejection of one channel's setting, naming every parameter in full
    (``pinch.dob.nominal_inertia``, ``pinch.allow_non_passive``) as a ROS user sets it."""
    if isinstance(exc, InvalidParameterError):
        return str(exc.in_channel(channel))
    return f'channel {channel}: {exc}'

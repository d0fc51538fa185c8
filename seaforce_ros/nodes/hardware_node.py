"""hardware_node (node ``hardware``): the gripper over EtherCAT, a drop-in for ``sim_node``.

A :class:`~seaforce_ros.nodes.plant_node.PlantNode` composing an
:class:`~seaforce_ros.ethercat.backend.EthercatBackend` built from the parameters
(``interface``, ``bus_config``, ``receive_timeout``, ``drive_watchdog``,
``fault_reset_time``). A ``torque_limit`` above a drive's max torque (0x6072, read at
configure) is reported, at configure and when it is set. The bus is driven
through pysoem (SOEM); the cycle thread runs at ``rate`` with absolute deadlines: one
process-data frame per cycle, sent at the end of a cycle and received at the start of the
next, scaled to SI units, an ``actuator_state`` sample with the same semantics as the sim's,
and the torques :class:`~seaforce_ros.core.plant_cycle.PlantCycle` allows applied as CiA 402
target torque (object 0x6071, per mille of the rated torque, int16) -- only in *Operation
enabled*.

It is a managed (lifecycle) node, like a ros2_control hardware component::

    ros2 lifecycle set /hardware configure    # bus to SAFE-OP, every identity checked, no torque
    ros2 lifecycle set /hardware activate     # bus to OP, drives enabled: torque follows commands
    ros2 lifecycle set /hardware deactivate   # zero torque, drives disabled, bus in SAFE-OP
    ros2 lifecycle set /hardware cleanup      # bus to INIT

``autostart`` (default ``inactive``) is the state it goes to by itself at start: the bus is
checked at once (a missing slave or a wrong vendor/product/revision ends the process with the
reason, before any drive is enabled), and no drive takes torque until someone activates it.
``autostart:=active`` starts with the drives enabled, as before the node was managed.

Safety: the rules of :mod:`seaforce_ros.core.plant_cycle`, shared with the sim (per-channel
command watchdog, fresh commands only, one command source, ``torque_limit`` clamp, velocity
trip, drive faults, ``wkc_error_limit`` consecutive working-counter errors -> bus fault with
the drives disabled, ``~/reset``), each with a status bit, a ``/diagnostics`` entry and a
log line; plus the drives' own process-data watchdog (``drive_watchdog``), which drops torque
if the master stops, and SIGINT/SIGTERM -> zero torque, drives disabled, bus back to INIT
before exit, whatever the lifecycle state.
"""
from __future__ import annotations

import dataclasses
import pathlib
import sys
from typing import Any, List, Optional

from ..core.schema import HARDWARE, Spec
from ..ethercat.backend import EthercatBackend
from ..ethercat.bus_config import BusConfig
from ..ethercat.errors import BusConfigError
from .plant_node import PlantNode, plant_specs, prepare_process
from .ros_common import StartupError, check_undeclared, run


def _default_bus_config() -> str:
    try:
        from ament_index_python.packages import get_package_share_directory
        return str(pathlib.Path(get_package_share_directory('seaforce_ros')) / 'config'
                   / 'ethercat_bus.yaml')
    except Exception:
        return str(pathlib.Path(__file__).resolve().parents[2] / 'config' / 'ethercat_bus.yaml')


def node_specs() -> List[Spec]:
    """hardware_node's own parameters (the plant's common ones among them); ``bus_config``
    defaults to the installed config/ethercat_bus.yaml."""
    return [dataclasses.replace(spec, default=_default_bus_config())
            if spec.name == 'bus_config' else spec for spec in plant_specs(HARDWARE)]


class HardwareNode(PlantNode):
    """The EtherCAT gripper (see module docstring): the plant node with an EthercatBackend.

    Parameters
    ----------
    direct : controller_node.DirectPort, optional
        The direct layout (``hardware_bringup loop:=direct``): the cycle thread calls the
        controller between two exchanges.
    """

    def __init__(self, direct: Any = None, **kwargs: Any) -> None:
        super().__init__('hardware', node_specs(), direct=direct, **kwargs)
        check_undeclared(self)          # a misspelt name first (-p interfac:=...), no bus yet
        values = self.values
        if not values['interface']:
            raise StartupError('interface is not set: pass the EtherCAT network interface, '
                               'e.g. --ros-args -p interface:=enp3s0 (ip link lists them)')
        try:
            backend = EthercatBackend(
                BusConfig.load(values['bus_config']), self.channels, values['interface'],
                self.dt, receive_timeout=values['receive_timeout'],
                drive_watchdog=values['drive_watchdog'],
                fault_reset_time=values['fault_reset_time'])
        except (ValueError, BusConfigError) as exc:
            raise StartupError(str(exc)) from exc
        self._ethercat = backend
        self.add_post_set_parameters_callback(self._torque_limit_changed)
        self.attach(backend, description=backend.describe())

    def _configure(self) -> str:
        """Configure, then say whether ``torque_limit`` is above a drive's max torque."""
        done = super()._configure()
        note = self._ethercat.torque_limit_note(self.get_parameter('torque_limit').value)
        if note:
            self.get_logger().warning(note)
            done += f'; {note}'
        return done

    def _torque_limit_changed(self, params: List[Any]) -> None:
        for p in params:
            if p.name == 'torque_limit':
                note = self._ethercat.torque_limit_note(p.value)
                if note:
                    self.get_logger().warning(note)


def main(args: Optional[List[str]] = None) -> None:
    prepare_process()
    sys.exit(run(HardwareNode, args=args, name='hardware_node'))


if __name__ == '__main__':
    main()

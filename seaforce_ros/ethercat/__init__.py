"""EtherCAT side of the hardware node: bus description, CiA 402 sequencing, pysoem master,
and the plant backend built on them.

``bus_config`` and ``cia402`` import neither ROS nor pysoem; ``master`` imports pysoem only
when a bus is opened; ``backend`` (:class:`~.backend.EthercatBackend`, the hardware node's
:class:`~seaforce_ros.core.backend.PlantBackend`) imports no ROS.
"""
from .errors import BusConfigError, BusError, EthercatError, IdentityError
from .bus_config import (Affine, BusConfig, ChannelConfig, PdoEntry, PdoLayout, Scaling,
                         SignalConfig, SlaveConfig, Source)
from .cia402 import DriveSequencer, DriveState, state_of
from .master import EthercatBus
from .backend import EthercatBackend

__all__ = ["EthercatError", "BusConfigError", "BusError", "IdentityError", "BusConfig",
           "SlaveConfig", "PdoEntry", "PdoLayout", "ChannelConfig", "SignalConfig", "Source",
           "Scaling", "Affine", "DriveState", "DriveSequencer", "state_of", "EthercatBus",
           "EthercatBackend"]

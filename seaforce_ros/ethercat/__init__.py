"""EtherCAT side of the hardware node: bus description, CoE configuration, CiA 402
sequencing, distributed clocks, pysoem master, and the plant backend built on them.

``bus_config``, ``sii``, ``coe``, ``cia402`` and ``dc`` import neither ROS nor pysoem;
``master`` imports pysoem only when a bus is opened; ``backend``
(:class:`~.backend.EthercatBackend`, the hardware node's
:class:`~seaforce_ros.core.backend.PlantBackend`) imports no ROS. The tools ``ethercat_scan``
(:mod:`.scan`) and ``first_power_on`` (:mod:`.power_on`) work on a bus directly.
"""
from .errors import BusConfigError, BusError, EthercatError, IdentityError
from .bus_config import (Affine, BusConfig, ChannelConfig, DcConfig, PdoEntry, PdoLayout,
                         Scaling, SignalConfig, SlaveConfig, Source, StartupSdo)
from .cia402 import DriveSequencer, DriveState, error_text, state_of
from .coe import CoeError, SdoAbortError
from .master import EthercatBus
from .backend import EthercatBackend

__all__ = ["EthercatError", "BusConfigError", "BusError", "IdentityError", "CoeError",
           "SdoAbortError", "BusConfig", "SlaveConfig", "PdoEntry", "PdoLayout", "StartupSdo",
           "DcConfig", "ChannelConfig", "SignalConfig", "Source", "Scaling", "Affine",
           "DriveState", "DriveSequencer", "state_of", "error_text", "EthercatBus",
           "EthercatBackend"]

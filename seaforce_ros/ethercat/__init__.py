"""EtherCAT side of the hardware node: bus description, CiA 402 sequencing, pysoem master,
and the plant backend built on them.

``bus_config`` and ``cia402`` import neither ROS nor pysoem; ``master`` imports pysoem only
when a bus is opened; ``backend`` (:class:`~.backend.EthercatBackend`, the hardware node's
:class:`~seaforce_ros.core.backend.PlantBackend`) imports no ROS.
"""

"""EtherCAT side of the hardware node: bus description, CiA 402 sequencing, pysoem master.

``bus_config`` and ``cia402`` import neither ROS nor pysoem; ``master`` imports pysoem only
when a bus is opened.
"""

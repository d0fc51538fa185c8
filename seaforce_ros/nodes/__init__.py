"""The ROS 2 nodes (``ros2 run seaforce_ros <executable>``) and their plumbing.

Nodes: :mod:`.sim_node` (the simulated gripper), :mod:`.hardware_node` (the gripper over
EtherCAT), :mod:`.controller_node` (DOB + friction feed-forward at 2 kHz, the grasp and
friction-calibration actions, the control_msgs gripper actions: :mod:`.gripper_actions`), :mod:`.bag_recorder` (rosbag2 recording), :mod:`.bringup`
(a plant and the controller in one process). Shared: :mod:`.plant_node` (the one plant node: the
ROS side of the loop and the lifecycle around a plant backend and
:class:`~seaforce_ros.core.plant_cycle.PlantCycle`), :mod:`.ros_common` (parameter
declaration, QoS, diagnostics, the shutdown idiom), :mod:`.param_specs` (the nodes' parameters,
from the core's schema) and :mod:`.timing` (loop statistics, no ROS).
"""
__all__ = ["sim_node", "hardware_node", "controller_node", "bag_recorder", "bringup",
           "plant_node", "ros_common", "param_specs", "timing", "gripper_actions"]

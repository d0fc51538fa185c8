"""seaforce_ros: wide-range endpoint impedance for a fluid-actuated series-elastic gripper.

The control core (:mod:`seaforce_ros.core`) is plain Python + numpy; the node
modules wrap it with ROS 2 I/O.
"""

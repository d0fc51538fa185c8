"""seaforce_ros: wide-range endpoint impedance for a fluid-actuated series-elastic gripper.

The control core (:mod:`seaforce_ros.core`) is plain Python + numpy; :mod:`~.bags`,
:mod:`~.identification` and :mod:`~.ethercat` are ROS-free too; :mod:`~.nodes` wraps them with
ROS 2 I/O, :mod:`~.tools` holds the offline command lines and :mod:`~.demos` the demos. The
package imports none of them: ``import seaforce_ros.core`` loads no ROS.
"""
__all__ = ["core", "bags", "identification", "ethercat", "nodes", "tools", "demos"]

"""bringup: sim_node and controller_node composed in one process on one executor.

In rclpy, composition still goes through the RMW (the nodes talk over DDS, with intra-process
shortcuts left to Fast DDS), but it saves the cross-process hop and one scheduler wake-up per
message; bench/control_loop.py measures what that buys for the 2 kHz loop. Separate processes
(``ros2 run seaforce_ros sim_node`` / ``controller_node``) stay the default.

Usage: bringup --ros-args --params-file config/gripper.yaml
The executor is the controller's ``executor`` parameter.
"""
import sys

from .controller_node import ControllerNode
from .ros_common import run
from .sim_node import SimNode


def main(args=None):
    sys.setswitchinterval(2e-4)  # the sim's cycle thread shares the GIL with the executor
    sys.exit(run(lambda: [ControllerNode(), SimNode()], args=args, name='bringup'))


if __name__ == '__main__':
    main()

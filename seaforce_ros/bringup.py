"""bringup: sim_node and controller_node composed in one process on one executor.

In rclpy, composition still goes through the RMW (the nodes talk over DDS, with intra-process
shortcuts left to Fast DDS), but it saves the cross-process hop and one scheduler wake-up per
message; bench/control_loop.py measures what that buys for the 2 kHz loop. Separate processes
(``ros2 run seaforce_ros sim_node`` / ``controller_node``) stay the default.

Usage: bringup --ros-args --params-file config/gripper.yaml
The executor is the controller's ``executor`` parameter.
"""
import sys

import rclpy
from rclpy.executors import ExternalShutdownException

from .controller_node import ControllerNode
from .ros_common import StartupError, make_executor, spin_forever
from .sim_node import SimNode


def main(args=None):
    sys.setswitchinterval(2e-4)  # the sim's cycle thread shares the GIL with the executor
    rclpy.init(args=args)
    nodes = []
    code = 0
    try:
        nodes.append(ControllerNode())
        nodes.append(SimNode())
        kind = nodes[0].get_parameter('executor').value
        executor = make_executor(kind)
        for node in nodes:
            executor.add_node(node)
        nodes[0].get_logger().info(f'spinning with the {kind} executor (sim + controller)')
        spin_forever(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except StartupError as exc:
        print(f'[bringup] cannot start: {exc}', file=sys.stderr)
        code = 2
    finally:
        for node in reversed(nodes):
            if hasattr(node, 'shutdown'):
                node.shutdown()
            node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(code)


if __name__ == '__main__':
    main()

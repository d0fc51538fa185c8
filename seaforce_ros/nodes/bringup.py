"""bringup / hardware_bringup: the controller and a plant composed in one process.

``bringup`` composes sim_node + controller_node, ``hardware_bringup`` hardware_node +
controller_node, on one executor. The read-only parameter ``loop`` chooses how they talk:

* ``topics`` (default): through the RMW as separate processes do (rclpy composition still
  goes through DDS; it saves the cross-process hop and one scheduler wake-up per message);
* ``direct`` (ros2_control's pattern): the plant's cycle thread calls the controller's
  cycle itself, between reading the plant and writing it: no DDS and no executor in the
  2 kHz path, exactly one sample of delay. Every state and command is still published on
  ``actuator_state`` / ``actuator_command`` (and ``controller_status``) for recorders and
  observers; the controller's parameters and ``~/reset`` work from the executor as usual
  and reach the cycle at the start of a cycle.

Separate processes (``ros2 run seaforce_ros sim_node`` / ``controller_node``) stay the
default. The executor is the controller's ``executor`` parameter.

Usage: bringup --ros-args --params-file config/gripper.yaml -p loop:=direct
       hardware_bringup --ros-args --params-file ... -p interface:=enp3s0 -p loop:=direct
"""
import sys

from .controller_node import ControllerNode
from .plant_node import prepare_process
from .ros_common import run


def _compose(plant_class):
    def make():
        controller = ControllerNode(composed=True)
        direct = controller.direct_port() if controller.loop == 'direct' else None
        try:
            plant = plant_class(direct=direct)
        except BaseException:
            controller.destroy_node()
            raise
        return [controller, plant]
    return make


def main(args=None):
    from .sim_node import SimNode
    prepare_process()
    sys.exit(run(_compose(SimNode), args=args, name='bringup'))


def hardware_main(args=None):
    from .hardware_node import HardwareNode
    prepare_process()
    sys.exit(run(_compose(HardwareNode), args=args, name='hardware_bringup'))


if __name__ == '__main__':
    main()

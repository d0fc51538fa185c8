"""Subscribe to seaforce_msgs topics and print every message received as one JSON line.

Usage: echo_json.py TOPIC:Type [TOPIC:Type ...]   (Type: ActuatorState, ActuatorCommand, ...)
Prints READY once subscribed; exits on SIGINT.
"""
import json
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
import seaforce_msgs.msg

from msgdict import to_plain


def main():
    rclpy.init()
    node = rclpy.create_node('echo_json')
    for spec in sys.argv[1:]:
        topic, type_name = spec.split(':')
        msg_type = getattr(seaforce_msgs.msg, type_name)

        def callback(msg, topic=topic):
            print(json.dumps({'topic': topic, 'msg': to_plain(msg)}), flush=True)

        node.create_subscription(msg_type, topic, callback, 10)
    print('READY', flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()

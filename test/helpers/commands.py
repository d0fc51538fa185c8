"""The test plays a controller that commands only some channels."""
import time

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from seaforce_msgs.msg import ActuatorCommand, ActuatorState

from helpers.states import stamp_ns, value

#: Only the newest state: what a controller answers.
LATEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                        reliability=ReliabilityPolicy.BEST_EFFORT)


def command_only(probe, efforts, after_ns=0, want=20, timeout=60.0):
    """Publish ``actuator_command`` naming only the channels of ``efforts`` ({name: N m}),
    each answering the newest state seen (never an older one: the plant would take that for a
    second source), until ``want`` states stamped after ``after_ns`` (system time) show every
    one of these efforts applied; returns those states. A Python test process answers late
    on a busy host: an answer to a state older than command_timeout is ignored, so only some
    take effect.

    ``actuator_state`` is recorded afresh with a queue of one: a deep queue makes a starved
    probe see states as late as its depth (a second at 2 kHz), and every answer stale."""
    start_ns = time.time_ns()
    probe.stop_recording('actuator_state')
    probe.record(ActuatorState, 'actuator_state', LATEST_QOS)
    # the first answer must be newer than any the previous controller gave (an older one is
    # out of order: the plant takes it for a second source): a state stamped after this call
    first = probe.wait_messages('actuator_state', 1, timeout=timeout,
                                where=lambda m: stamp_ns(m) > start_ns)[0]
    pub = probe.publisher(ActuatorCommand, 'actuator_command')
    cmd = ActuatorCommand()
    cmd.name = list(efforts)
    cmd.effort = list(efforts.values())
    cmd.cycle = first.cycle
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline and len(seen) < want:
        for _ in range(200):
            cmd.cycle = max(cmd.cycle, probe.messages('actuator_state')[-1].cycle)
            pub.publish(cmd)
            time.sleep(0.001)
        seen = [m for m in probe.messages('actuator_state') if stamp_ns(m) > after_ns and all(
            abs(value(m, name, 'motor_effort') - effort) < 1e-9
            for name, effort in efforts.items())]
    assert len(seen) >= want, f'the commands {efforts} never took effect'
    return seen

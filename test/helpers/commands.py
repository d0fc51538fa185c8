"""The test plays a controller that commands only some channels."""
import time

from seaforce_msgs.msg import ActuatorCommand

from helpers.states import value


def command_only(probe, efforts, after_cycle=0, want=20, timeout=60.0):
    """Publish ``actuator_command`` naming only the channels of ``efforts`` ({name: N m}),
    each answering the newest state seen (never an older one: the plant would take that for a
    second source), until ``want`` states after ``after_cycle`` show every one of these
    efforts applied; returns those states. A Python test process answers late on a busy host:
    an answer to a state older than command_timeout is ignored, so only some take effect."""
    pub = probe.publisher(ActuatorCommand, 'actuator_command')
    cmd = ActuatorCommand()
    cmd.name = list(efforts)
    cmd.effort = list(efforts.values())
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline and len(seen) < want:
        for _ in range(200):
            cmd.cycle = max(cmd.cycle, probe.messages('actuator_state')[-1].cycle)
            pub.publish(cmd)
            time.sleep(0.001)
        seen = [m for m in probe.messages('actuator_state') if m.cycle > after_cycle and all(
            abs(value(m, name, 'motor_effort') - effort) < 1e-9
            for name, effort in efforts.items())]
    assert len(seen) >= want, f'the commands {efforts} never took effect'
    return seen

"""A test-side ROS node: records topics, sets parameters (what `ros2 param set` does), calls
services. It spins its own executor in a background thread on its own Context."""
import threading
import time
from typing import Any, Callable, Dict, List, Optional

from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message

from helpers.states import has_cycle, serialized_cycle

from seaforce_ros.nodes.ros_common import (RECORD_QOS, CONTROL_QOS, BackgroundNode,
                                     request_until_answered)


#: The probe's subscriptions: RECORD_QOS with 10 s of a 2 kHz topic queued (a test process
#: starved for more than RECORD_QOS's second lost samples; only bytes are queued)
PROBE_QOS = QoSProfile(history=RECORD_QOS.history, depth=20000,
                       reliability=RECORD_QOS.reliability, durability=RECORD_QOS.durability)
#: s of the loop's time per plant cycle (2 kHz: config/gripper.yaml's rate)
CYCLE = 5e-4
#: s without a new cycle after which a wait whose time is not up in the loop's clock still
#: ends (a loop that stopped)
STALL = 30.0


class Probe:
    """Records topics as their serialized bytes on the spin thread (cheap: a 2 kHz topic
    taken in as messages fell behind on a busy host, and its subscription queue dropped
    samples), turned into messages on the test's thread when it asks for them."""

    def __init__(self, name: str = 'test_probe', domain_id: Optional[int] = None):
        self.background = BackgroundNode(name, domain_id)
        self.node = self.background.node
        self._lock = threading.Lock()           # the records: spin thread and test thread
        self._taking = threading.Lock()         # one deserialization at a time
        self.records: Dict[str, List[Any]] = {}
        self._raw: Dict[str, List[bytes]] = {}  # topic -> taken in, not yet deserialized
        self._types: Dict[str, Any] = {}
        self._subscriptions: Dict[str, Any] = {}
        self._cycles: Dict[str, int] = {}       # topic -> the newest cycle recorded on it
        self._advanced = time.monotonic()       # when one of them last grew
        self._cleared: Dict[str, int] = {}      # topic -> clear() calls

    def close(self):
        # subscriptions first: a 2 kHz topic from a node that still runs (the processes
        # fixture ends after this one) can keep a CPU-starved spin thread from returning
        for topic in list(self._subscriptions):
            self.stop_recording(topic)
        self.background.close()

    # --- topics ------------------------------------------------------------------------
    def record(self, msg_type, topic: str, qos=PROBE_QOS):
        with self._lock:
            self.records[topic] = []
            self._raw[topic] = []
            self._types[topic] = msg_type
            self._cleared[topic] = self._cleared.get(topic, 0) + 1

        counted = has_cycle(msg_type)

        def callback(data, topic=topic):
            cycle = serialized_cycle(data) if counted else -1
            with self._lock:
                self._raw[topic].append(data)
                if cycle > self._cycles.get(topic, -1):
                    self._cycles[topic] = cycle
                    self._advanced = time.monotonic()

        self._subscriptions[topic] = self.node.create_subscription(msg_type, topic, callback,
                                                                   qos, raw=True)

    def _take(self, topics=None) -> None:
        """Deserialize what the spin thread took in, into ``records`` (and the loop's clock)."""
        with self._taking:
            for topic in list(self._raw) if topics is None else topics:
                with self._lock:
                    raw, self._raw[topic] = self._raw[topic], []
                    msg_type, cleared = self._types[topic], self._cleared[topic]
                if not raw:
                    continue
                msgs = [deserialize_message(data, msg_type) for data in raw]
                with self._lock:
                    if self._cleared[topic] == cleared:     # else: they came before a clear()
                        self.records[topic].extend(msgs)

    def stop_recording(self, topic: str) -> None:
        """Stop taking messages of ``topic`` (what was recorded stays): a 2 kHz topic costs a
        CPU-starved test process the time it needs to answer its own service calls."""
        subscription = self._subscriptions.pop(topic, None)
        if subscription is not None:
            self.node.destroy_subscription(subscription)

    def messages(self, topic: str) -> List[Any]:
        self._take([topic])
        with self._lock:
            return list(self.records[topic])

    def clear(self, topic: str) -> None:
        with self._lock:
            self.records[topic].clear()
            self._raw[topic].clear()
            self._cleared[topic] = self._cleared.get(topic, 0) + 1

    def loop_time(self, since: Dict[str, int]) -> float:
        """s of the loop's time since ``since`` (a copy of the recorded topics' newest cycles):
        the most any topic advanced, in plant cycles x :data:`CYCLE`."""
        with self._lock:
            return CYCLE * max((c - since.get(t, c) for t, c in self._cycles.items()),
                               default=0)

    def wait_for(self, predicate: Callable[[], bool], timeout: float = 20.0,
                 what: str = 'condition') -> None:
        """Until ``predicate()``; AssertionError once ``timeout`` s have passed both in wall
        time and in the time of the loop whose cycles this probe records (a lockstep loop on
        a busy host runs slower than the wall clock, not differently), or after ``timeout``
        s of wall time when that loop has not advanced for :data:`STALL` s."""
        start = time.monotonic()
        with self._lock:
            since = dict(self._cycles)
        while True:
            if predicate():
                return
            now = time.monotonic()
            if now - start >= timeout:
                with self._lock:
                    stalled = not self._cycles or now - self._advanced >= STALL
                looped = self.loop_time(since)
                if stalled or looped >= timeout:
                    raise AssertionError(
                        f'timed out after {now - start:.1f} s ({looped:.1f} s of the loop) '
                        f'waiting for {what}')
            time.sleep(0.02)

    def newest_cycle(self, topic: str) -> int:
        """The newest cycle taken in on ``topic`` (-1: none yet), without building messages."""
        with self._lock:
            return self._cycles.get(topic, -1)

    def wait_cycle(self, topic: str, cycle: int, timeout: float = 20.0) -> None:
        """Until a message of ``cycle`` or later came on ``topic`` (no message built while
        waiting: the thread that takes them in keeps the interpreter lock to itself)."""
        self.wait_for(lambda: self.newest_cycle(topic) >= cycle, timeout,
                      f'cycle {cycle} on {topic}')

    def wait_messages(self, topic: str, count: int = 1, timeout: float = 20.0,
                      where: Optional[Callable[[Any], bool]] = None) -> List[Any]:
        # scanned as they come (a 2 kHz record rescanned at every poll takes the interpreter
        # lock from the thread that takes the messages in: it fell behind and lost samples)
        found: List[Any] = []
        scanned = [0, self._cleared.get(topic, 0)]       # messages looked at, clear()s seen

        def matching() -> List[Any]:
            self._take([topic])
            with self._lock:
                if self._cleared.get(topic, 0) != scanned[1]:
                    found.clear()
                    scanned[:] = [0, self._cleared.get(topic, 0)]
                new = self.records[topic][scanned[0]:]
                scanned[0] += len(new)
            found.extend(m for m in new if where is None or where(m))
            return found
        self.wait_for(lambda: len(matching()) >= count, timeout,
                      f'{count} message(s) on {topic}')
        return list(matching())

    def publisher(self, msg_type, topic: str, qos=CONTROL_QOS):
        return self.node.create_publisher(msg_type, topic, qos)

    # --- parameters (the calls `ros2 param set/get` make) -----------------------------------
    def _param_client(self, node_name: str) -> AsyncParameterClient:
        client = AsyncParameterClient(self.node, node_name)
        if not client.wait_for_services(timeout_sec=20.0):
            raise AssertionError(f'parameter services of {node_name} not available')
        return client

    def set_parameters(self, node_name: str, values: Dict[str, Any], timeout: float = 10.0,
                       atomic: bool = True):
        """Set parameters; returns (successful, reason).

        ``atomic=False`` uses the SetParameters service one parameter at a time, which is what
        ``ros2 param set`` does; the reasons of the rejected ones are joined with '; '.
        """
        client = self._param_client(node_name)
        params = [Parameter(name, value=value) for name, value in values.items()]
        if atomic:
            result = self._request(lambda: client.set_parameters_atomically(params), timeout,
                                   f'set_parameters_atomically on {node_name}')
            return result.result.successful, result.result.reason
        result = self._request(lambda: client.set_parameters(params), timeout,
                               f'set_parameters on {node_name}')
        failed = [r.reason for r in result.results if not r.successful]
        return not failed, '; '.join(failed)

    def get_parameters(self, node_name: str, names: List[str], timeout: float = 10.0):
        client = self._param_client(node_name)
        result = self._request(lambda: client.get_parameters(names), timeout,
                               f'get_parameters on {node_name}')
        from rclpy.parameter import parameter_value_to_python
        return {name: parameter_value_to_python(v) for name, v in zip(names, result.values)}

    def call(self, srv_type, name: str, request=None, timeout: float = 10.0):
        client = self.node.create_client(srv_type, name)
        if not client.wait_for_service(timeout_sec=20.0):
            raise AssertionError(f'service {name} not available')
        return self._request(lambda: client.call_async(request or srv_type.Request()),
                             timeout, f'call {name}')

    @staticmethod
    def _request(send, timeout, what):
        """Send and wait, re-sending while unanswered (see ros_common.request_until_answered:
        every request made here is idempotent)."""
        try:
            return request_until_answered(send, timeout, resend_after=timeout / 4)
        except TimeoutError:
            raise AssertionError(f'no answer to {what} within {timeout} s') from None

"""The controller node's ``~/tare`` service: the pressure sensor's offset, measured on every free
finger (:mod:`seaforce_ros.core.tare`).

``ros2 service call /controller/tare std_srvs/srv/Trigger`` starts a tare on every channel a
job can run on now (not busy with a goal, not faulted, states arriving) and answers at once
which it started and which it could not (``success`` when it started one): a tare moves the
finger for about 2.5 s, longer than a service call should wait (and the events executor
serves no coroutine service callbacks). Each tare then ends by itself: its outcome is logged
(one line per channel), the new offset is set as ``<channel>.pressure_offset`` (so that
``ros2 param get`` and a ``ros2 param dump`` have it), and ``/diagnostics`` carries the last
tare's line per channel (``pressure_tare``) beside the offset in force. A tare the cycle does
not take within :data:`~.jobs.JOB_START_TIMEOUT` is withdrawn; one whose states stop is
aborted.
"""
from __future__ import annotations

import time
from typing import Callable, Dict, Sequence, Tuple

from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from ..core.controller import ChannelController
from ..core.jobs import InvalidJobGoalError
from ..core.tare import PressureTare
from .jobs import JOB_START_TIMEOUT, JobActions
from .ros_common import shutdown_safe, steady_timer

__all__ = ["TareService", "TARE_POLL"]

#: s between looks at the running tares.
TARE_POLL = 0.05


class TareService:
    """``~/tare`` (module docstring).

    Parameters
    ----------
    node : Node
        Serves it, sets the parameters, logs.
    channels : sequence of str
    controllers : sequence of ChannelController
    jobs : JobActions
        Which channels a job can run on now (:meth:`JobActions.channel_for`).
    stalled : callable () -> str
        Why the control cycle is not running now, or ''.
    """

    def __init__(self, node: Node, channels: Sequence[str],
                 controllers: Sequence[ChannelController], jobs: JobActions,
                 stalled: Callable[[], str]) -> None:
        self._node = node
        self.context = node.context             # (shutdown_safe)
        self._channels = list(channels)
        self._controllers = controllers
        self._jobs = jobs
        self._stalled = stalled
        self._running: Dict[int, Tuple[PressureTare, float]] = {}
        #: channel index -> the last tare's line
        self.results: Dict[int, str] = {}
        node.create_service(Trigger, '~/tare', self._on_tare)
        steady_timer(node, TARE_POLL, self._poll)

    def _on_tare(self, request: Trigger.Request, response: Trigger.Response
                 ) -> Trigger.Response:
        started, refused = [], []
        for index, channel in enumerate(self._channels):
            if index in self._running:
                refused.append(f'{channel}: a tare runs already')
                continue
            try:
                self._jobs.channel_for(channel)
            except InvalidJobGoalError as exc:
                refused.append(str(exc))
                continue
            tare = PressureTare(self._controllers[index].config, self._controllers[index].dt)
            self._controllers[index].request_job(tare)
            self._running[index] = (tare, time.monotonic())
            started.append(channel)
        response.success = bool(started)
        parts = []
        if started:
            parts.append(f'taring {", ".join(started)} (about 2.5 s: the finger goes to its '
                         'rest and is dithered there; the offsets go to <channel>.'
                         'pressure_offset, the log and /diagnostics)')
        if refused:
            parts.append('not tared: ' + '; '.join(refused))
        response.message = '; '.join(parts)
        self._node.get_logger().info(f'tare: {response.message}')
        return response

    @shutdown_safe
    def _poll(self) -> None:
        """Withdraw a tare the cycle did not take, abort one whose states stopped, and report
        the ended ones."""
        stalled = self._stalled()
        for index, (tare, requested) in list(self._running.items()):
            if tare.active and not tare.started and \
                    time.monotonic() - requested > JOB_START_TIMEOUT:
                tare.withdraw(f'the control cycle did not take the tare within '
                              f'{JOB_START_TIMEOUT:g} s (are states arriving?)')
            elif tare.active and tare.started and stalled:
                tare.request_abort(stalled + ': the plant stopped, or the link to it')
            if tare.active:
                continue
            del self._running[index]
            self._report(index, tare)

    def _report(self, index: int, tare: PressureTare) -> None:
        channel = self._channels[index]
        logger = self._node.get_logger()
        line = f'{tare.outcome}: {tare.message}'
        if tare.outcome == 'succeeded':
            result = self._node.set_parameters([Parameter(f'{channel}.pressure_offset',
                                                          value=float(tare.offset))])[0]
            if not result.successful:
                line += f'; parameter not updated: {result.reason}'
            logger.info(f'{channel}: tare {line}')
        else:
            logger.warning(f'{channel}: tare {line}')
        self.results[index] = line

    def diagnostics(self, index: int) -> Dict[str, str]:
        """The channel's last tare, for its /diagnostics status."""
        running = index in self._running
        return {'pressure_tare': 'running' if running else self.results.get(index, 'none')}

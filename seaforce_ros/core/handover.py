"""Hand-over of a value from one thread to another, taken at a safe point.

A node's executor thread sets parameters and serves ``~/reset`` while the plant's cycle thread
runs the cycle (the direct layout). ``x = self._pending; self._pending = None`` in the cycle
would lose a value the other thread stores between the two statements; :class:`Mailbox`
uses a one-slot deque, whose ``append`` and ``popleft`` are single atomic operations: the
newest value put is the one taken, and none is taken twice. :class:`Claim` decides, once,
whether a request handed to the cycle (a grasp, a friction calibration) starts there or is
withdrawn by the thread that made it.
"""

import threading
from collections import deque
from typing import Any

__all__ = ["Mailbox", "Claim"]


class Mailbox(deque):
    """One slot: :meth:`put` replaces what is waiting, :meth:`take` empties it; true while a
    value waits.

    A one-slot deque itself (not a wrapper): the cycle asks every sample whether something
    waits, and a deque answers that, and an empty :meth:`take`, without a Python call or an
    exception.
    """

    def __init__(self) -> None:
        super().__init__(maxlen=1)

    #: Put ``value`` (any thread), replacing one that waits.
    put = deque.append

    def take(self) -> Any:
        """The newest value put since the last take, or None."""
        if not self:
            return None
        try:
            return self.popleft()
        except IndexError:      # another thread took it in between
            return None


class Claim:
    """Either the cycle claims a request or another thread withdraws it first, never both."""

    def __init__(self):
        self._lock = threading.Lock()
        self._claimed = False
        self._withdrawn = False

    def claim(self):
        """(cycle thread) True if the request is now the cycle's, False if it was withdrawn."""
        with self._lock:
            if self._withdrawn:
                return False
            self._claimed = True
            return True

    def withdraw(self):
        """(any thread) True if withdrawn (it will never start), False if the cycle has it."""
        with self._lock:
            if self._claimed:
                return False
            self._withdrawn = True
            return True

    @property
    def claimed(self):
        return self._claimed

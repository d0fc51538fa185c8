"""Hand-over of a value from one thread to another, taken at a safe point.

A node's executor thread sets parameters and serves ``~/reset`` while the plant's cycle thread
runs the cycle (the direct layout). ``x = self._pending; self._pending = None`` in the cycle
would lose a value the other thread stores between the two statements; :class:`Mailbox`
uses a deque, whose ``append`` and ``popleft`` are single atomic operations: with one slot
(a new configuration) the newest value put is the one taken; without a bound (the jobs a
channel is asked to run) every value put is taken once, in order, so that a request is never
lost by another arriving in the same sample. :class:`Claim` decides, once, whether a request
handed to the cycle (a job: :mod:`.jobs`) starts there or is withdrawn by the thread that made
it.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Deque, Optional, TypeVar

__all__ = ["Mailbox", "Claim"]

_T = TypeVar("_T")


class Mailbox(Deque[_T]):
    """A hand-over: :meth:`put` (any thread), :meth:`take` (the one thread that takes), of
    values of one type (``Mailbox[ControllerConfig]``); true while a value waits.

    Parameters
    ----------
    size : int or None
        How many values wait at most: 1 (the default) keeps only the newest put; None keeps
        every one, taken oldest first.

    Notes
    -----
    A deque itself, not a wrapper: the cycle asks every sample whether something waits, and a
    deque answers that, and an empty :meth:`take`, without a Python call or a caught
    exception.
    """

    def __init__(self, size: Optional[int] = 1) -> None:
        super().__init__(maxlen=size)

    def put(self, value: _T) -> None:
        """Hand ``value`` over (any thread); with one slot it replaces a value waiting."""
        self.append(value)

    def take(self) -> Optional[_T]:
        """The oldest value waiting (with one slot: the newest put since the last take), or
        None."""
        if not self:
            return None
        try:
            return self.popleft()
        except IndexError:      # another thread took it in between
            return None


class Claim:
    """Either the cycle claims a request or another thread withdraws it first, never both."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._claimed = False
        self._withdrawn = False

    def claim(self) -> bool:
        """(cycle thread) True if the request is now the cycle's, False if it was withdrawn."""
        with self._lock:
            if self._withdrawn:
                return False
            self._claimed = True
            return True

    def withdraw(self) -> bool:
        """(any thread) True if withdrawn (it will never start), False if the cycle has it."""
        with self._lock:
            if self._claimed:
                return False
            self._withdrawn = True
            return True

    @property
    def claimed(self) -> bool:
        """True once the cycle has claimed the request."""
        return self._claimed

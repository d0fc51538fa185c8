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
from typing import Deque, Generic, Optional, TypeVar

__all__ = ["Mailbox", "Claim"]

_T = TypeVar("_T")


class Mailbox(Generic[_T]):
    """One slot: :meth:`put` replaces what is waiting, :meth:`take` empties it (of values of
    one type, ``Mailbox[ControllerConfig]``)."""

    def __init__(self) -> None:
        self._slot: Deque[_T] = deque(maxlen=1)

    def put(self, value: _T) -> None:
        self._slot.append(value)

    def take(self) -> Optional[_T]:
        """The newest value put since the last take, or None."""
        try:
            return self._slot.popleft()
        except IndexError:
            return None

    def __bool__(self) -> bool:
        return bool(self._slot)


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

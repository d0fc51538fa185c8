"""Hand-over of a value from one thread to another, taken at a safe point.

A node's executor thread sets parameters and serves ``~/reset`` while the plant's cycle thread
runs the cycle (the direct layout). ``x = self._pending; self._pending = None`` in the cycle
would lose a value the other thread stores between the two statements; :class:`Mailbox`
uses a one-slot deque, whose ``append`` and ``popleft`` are single atomic operations: the
newest value put is the one taken, and none is taken twice.
"""

from collections import deque

__all__ = ["Mailbox"]


class Mailbox:
    """One slot: :meth:`put` replaces what is waiting, :meth:`take` empties it."""

    def __init__(self):
        self._slot = deque(maxlen=1)

    def put(self, value):
        self._slot.append(value)

    def take(self):
        """The newest value put since the last take, or None."""
        try:
            return self._slot.popleft()
        except IndexError:
            return None

    def __bool__(self):
        return bool(self._slot)

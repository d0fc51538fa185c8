"""Errors of commissioning: every one carries a message meant for the user (what is wrong and
what to do). One root, :class:`CommissioningError`, which is a core
:class:`~seaforce_ros.core.errors.SeaforceError` and a ``ValueError``."""
from ..core.errors import SeaforceError

__all__ = ["CommissioningError"]


class CommissioningError(SeaforceError, ValueError):
    """Commissioning input that cannot be used (a record too short or not excited enough, a
    band outside what the record holds, budgets that no setting meets); the message says why."""

"""Exception types of :mod:`seaforce_ros.ethercat`: one root, :class:`EthercatError`, so the
hardware node catches one type and reports the message (it names what to check or fix). The
root is a :class:`~seaforce_ros.core.backend.BackendError`: a plant node handles a failed
transition of its EtherCAT backend like that of any other backend."""

from ..core.backend import BackendError

__all__ = ['EthercatError', 'BusConfigError', 'BusError', 'IdentityError']


class EthercatError(BackendError):
    """Base class of every error :mod:`seaforce_ros.ethercat` raises for bad input or a bus
    that cannot work."""


class BusConfigError(EthercatError, ValueError):
    """The bus YAML is inconsistent; the message names the item and the fix."""


class BusError(EthercatError, RuntimeError):
    """The bus cannot be brought up or has failed; the message says what to check."""


class IdentityError(BusError):
    """A slave on the bus is not the one the configuration expects."""

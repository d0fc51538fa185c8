"""Errors of the offline tools: every one carries a message meant for the user (what is wrong
and what to do), and the CLIs print it instead of a stack trace (``<tool>: error: ...``, exit
status 2: :func:`seaforce_ros.identification.output.run_cli`).

One root, :class:`IdentificationError`; the subclasses say where the bad input came from."""

__all__ = ["IdentificationError", "UsageError", "ParamsFileError"]


class IdentificationError(RuntimeError):
    """Bad input to an offline tool (bag, channel, data, output path)."""


class UsageError(IdentificationError):
    """A command-line argument that cannot be used; the message names the option."""


class ParamsFileError(IdentificationError):
    """A ROS params file that cannot be read, or cannot be updated without losing what the
    user wrote; the message names the file (and the option that gave it)."""

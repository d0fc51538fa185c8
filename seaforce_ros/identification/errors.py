"""Errors of the offline tools: every one carries a message meant for the user (what is wrong
and what to do), and the CLIs print it instead of a stack trace."""

__all__ = ["IdentificationError"]


class IdentificationError(RuntimeError):
    """Bad input to an offline tool (bag, channel, data, output path)."""

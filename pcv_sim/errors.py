"""Errors raised by pcv_sim. Each role has its own class, which also inherits the matching builtin."""


class PcvSimError(Exception):
    """Base of every error pcv_sim raises on purpose."""


class ParameterError(PcvSimError, ValueError):
    """A parameter is missing, unknown, of the wrong type or non-physical."""


class BagError(PcvSimError, ValueError):
    """A bag cannot be read or written as asked."""


class CommandError(PcvSimError, ValueError):
    """An input command is out of range or not finite."""


class UsageError(PcvSimError, ValueError):
    """Command-line options that cannot go together or are out of range (exit status 2)."""

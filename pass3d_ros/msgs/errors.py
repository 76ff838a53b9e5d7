"""The project's error classes, in the lowest package (the codec's, which imports nothing of the project's) so every
layer can raise them: `Pass3dError` is
the base of every error this package raises on purpose, `UserError` the bad input, argument, file or output that the
tools print as one line (exit 2), and `DatasetError` the data layer's own (every reader raises it)."""

from __future__ import annotations


class Pass3dError(Exception):
    """Base of the errors this package raises on purpose; anything else escaping a tool is a bug."""


class UserError(Pass3dError, ValueError):
    """Bad input, argument, file or output: the user's to fix; the tools print one line and exit 2."""


class DatasetError(UserError):
    """A dataset spec or a file it names is unusable; the message names the spec or file and the problem."""

"""The data layer's error: a dataset spec or a file it names is unusable (every reader raises it)."""

from __future__ import annotations


class DatasetError(ValueError):
    """A dataset spec or a file it names is unusable; the message names the spec or file and the problem."""

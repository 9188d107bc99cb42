"""Named exceptions of pearl_ros. Bad caller input raises; degenerate data never does."""

from __future__ import annotations


class PearlError(Exception):
    """Base class of every pearl_ros error."""


class InputError(PearlError, ValueError):
    """An argument is malformed: wrong shape, non-finite values, out of its bounds."""


class BagError(PearlError):
    """A bag cannot be read or written: missing, corrupt, unknown topic or type."""

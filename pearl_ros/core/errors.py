"""Named exceptions of pearl_ros, and the one-line form every front end prints them in.

Bad caller input raises; degenerate data never does.
"""

from __future__ import annotations

import argparse
import typing


class PearlError(Exception):
    """Base class of every pearl_ros error."""


class InputError(PearlError, ValueError):
    """An argument is malformed: wrong shape, non-finite values, out of its bounds."""


class BagError(PearlError):
    """A bag cannot be read or written: missing, corrupt, unknown topic or type."""


def one_line(err: BaseException | str, limit: int | None = 300) -> str:
    """``err`` as one line (white space folded: YAML and rcl errors span several), cut to
    ``limit`` characters with ``...`` (None: not cut); an empty message gives the type's name."""
    text = ' '.join(str(err).split())
    if not text and isinstance(err, BaseException):
        text = type(err).__name__
    return text if limit is None or len(text) <= limit else text[: limit - 3] + '...'


class UsageParser(argparse.ArgumentParser):
    """An argument parser whose usage errors raise :class:`InputError`, so that a command's
    ``main`` prints them as its one ``error:`` line and returns 1 (argparse would exit 2)."""

    def error(self, message: str) -> typing.NoReturn:
        raise InputError(message)

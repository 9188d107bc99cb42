"""Finding a data set's files."""

from __future__ import annotations

from pathlib import Path

from pearl_ros.core.errors import InputError


def data_files(root: str | Path, pattern: str, dataset: str, what: str) -> list[Path]:
    """The paths under ``root`` that match the glob ``pattern``, sorted.

    Raises
    ------
    InputError
        ``root`` is not a folder (``'<dataset> folder not found: ...'``), or nothing in it
        matches (``'no <pattern> <what> in ...'``).
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f'{dataset} folder not found: {root}')
    paths = sorted(root.glob(pattern))
    if not paths:
        raise InputError(f'no {pattern} {what} in {root}')
    return paths

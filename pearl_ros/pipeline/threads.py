"""One BLAS thread for the segmenter's process.

The segmenter's linear algebra is many small matrices (8 x 8 patch Gram matrices, 3-D fits to a
few hundred points): OpenBLAS runs them on the calling thread, and its second thread, started
for the matrices it would split, waits for work by spinning. On a 2-core machine a 500-feature
stream then takes 32-37 ms of CPU per frame for 16-19 ms of wall time, and the same wall time
with one thread (BENCHMARKS.md, "Node latency and replay throughput"): a core that the tracker,
the estimator and the node's own executor need. numpy and scipy each load their own OpenBLAS;
both are set at runtime, after import, through OpenBLAS's own ``set_num_threads``.

Every program that segments sets one thread: the live ones (``pearl_node``, ``pearl_tracker``),
the offline ones (``pearl_replay``, ``pearl_video``, ``pearl_segment_bag``) and the
benchmarks. Offline, alone on the machine, the spinning thread takes the core that the
segmenter's own second thread (:mod:`pearl_ros.core.parallel`) would use: with it,
``bags/cars2`` replayed at 72-81 frames/s against 91-93 with one thread (BENCHMARKS.md, "Node
latency and replay throughput").
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

# Variables with which a user chooses the thread count; where one is set, it is left alone.
THREAD_VARIABLES = (
    'OMP_NUM_THREADS',
    'OPENBLAS_NUM_THREADS',
    'MKL_NUM_THREADS',
    'BLIS_NUM_THREADS',
    'VECLIB_MAXIMUM_THREADS',
    'NUMEXPR_NUM_THREADS',
)
# OpenBLAS's setter and getter as numpy's and scipy's wheels (scipy-openblas, 64- and 32-bit
# integers) and a system OpenBLAS name them.
_SYMBOLS = (
    ('scipy_openblas_set_num_threads64_', 'scipy_openblas_get_num_threads64_'),
    ('scipy_openblas_set_num_threads', 'scipy_openblas_get_num_threads'),
    ('openblas_set_num_threads64_', 'openblas_get_num_threads64_'),
    ('openblas_set_num_threads', 'openblas_get_num_threads'),
)


def openblas_libraries() -> list[Path]:
    """The OpenBLAS libraries loaded into this process (numpy's, scipy's), by path; none where
    the process's memory map cannot be read (not Linux)."""
    try:
        lines = Path('/proc/self/maps').read_text().splitlines()
    except OSError:
        return []
    paths = {line.split(maxsplit=5)[-1] for line in lines if line.count(' ') >= 5}
    return sorted(Path(p) for p in paths if 'openblas' in Path(p).name.lower())


def blas_threads() -> dict[Path, int]:
    """Each loaded OpenBLAS library's thread count."""
    counts = {}
    for path in openblas_libraries():
        symbols = _symbols(path)
        if symbols is not None:
            counts[path] = int(symbols[1]())
    return counts


def limit_blas_threads(count: int = 1) -> int:
    """Run every loaded OpenBLAS library on ``count`` threads, unless the user chose a number
    through one of :data:`THREAD_VARIABLES`; returns how many libraries were set. numpy and
    scipy must be imported first (their libraries load with them)."""
    if count < 1:
        raise ValueError(f'count must be >= 1, got {count}')
    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return 0
    done = 0
    for path in openblas_libraries():
        symbols = _symbols(path)
        if symbols is not None:
            symbols[0](ctypes.c_int(count))
            done += 1
    return done


def _symbols(path: Path) -> tuple[Callable[..., Any], Callable[..., Any]] | None:
    """The library's thread-count setter and getter, or None if it has neither."""
    try:
        library = ctypes.CDLL(str(path))  # already loaded: the same handle, no second copy
    except OSError:
        return None
    for setter, getter in _SYMBOLS:
        if hasattr(library, setter) and hasattr(library, getter):
            set_threads, get_threads = getattr(library, setter), getattr(library, getter)
            set_threads.restype, set_threads.argtypes = None, [ctypes.c_int]
            get_threads.restype, get_threads.argtypes = ctypes.c_int, []
            return set_threads, get_threads
    return None

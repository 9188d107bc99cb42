"""One BLAS thread: OpenBLAS's own getter says how many threads each loaded library runs."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from pearl_ros.pipeline.threads import THREAD_VARIABLES, limit_blas_threads

PROBE = """
import json, numpy, scipy.linalg
from pearl_ros.pipeline.threads import blas_threads, limit_blas_threads
before = {str(k): v for k, v in blas_threads().items()}
done = limit_blas_threads()
after = {str(k): v for k, v in blas_threads().items()}
print(json.dumps({'before': before, 'done': done, 'after': after}))
"""


def _probe(**env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    out = subprocess.run([sys.executable, '-c', PROBE], env={**clean, **env}, check=True,
                         capture_output=True, text=True, timeout=120).stdout
    result: dict = json.loads(out)
    return result


def test_every_openblas_of_numpy_and_scipy_runs_one_thread_once_limited():
    probe = _probe()
    names = ' '.join(probe['after'])
    # The pinned wheels bundle their own OpenBLAS each: numpy's with 64-bit integers.
    assert 'openblas64' in names and len(probe['after']) == 2
    assert probe['done'] == 2
    assert set(probe['after'].values()) == {1}
    assert set(probe['before']) == set(probe['after'])


def test_a_thread_count_the_user_chose_is_left_alone():
    probe = _probe(OPENBLAS_NUM_THREADS='2')
    assert probe['done'] == 0
    assert probe['after'] == probe['before']
    alone = _probe(OMP_NUM_THREADS='1')
    assert alone['done'] == 0 and alone['after'] == alone['before']


def test_no_thread_at_all_is_refused():
    with pytest.raises(ValueError, match='count must be >= 1'):
        limit_blas_threads(0)

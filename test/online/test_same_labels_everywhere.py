"""Without a budget, the same frames and seed give the same labels on any machine: whatever
its BLAS thread count (the programs run one, a user may choose one a core)
and whether the frame's neighbourhood went to a second thread (a core idle or not)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from pearl_ros.core import parallel
from pearl_ros.evaluation.latency import make_stream
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.pipeline.threads import THREAD_VARIABLES

# A robot-like stream without a budget (its labels frame by frame), then batch fits of its last
# window: an affine one and a fundamental matrix between the window's ends.
PROBE = """
import hashlib, json
import numpy as np
from pearl_ros.core.config import PearlConfig
from pearl_ros.core.pearl import fit
from pearl_ros.evaluation.latency import make_stream
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.pipeline.threads import blas_threads
digest = hashlib.sha256()
segmenter = OnlineSegmenter(online=OnlineConfig(budget_ms=0))
frames = make_stream('robot', 1000, 24, 3)
for frame in frames:
    digest.update(segmenter.process(frame.stamp_ns, frame.ids, frame.uv).labels.tobytes())
last = frames[-10:]
common = last[0].ids
for frame in last[1:]:
    common = np.intersect1d(common, frame.ids)
def at(frame, ids):
    order = np.argsort(frame.ids)
    return frame.uv[order][np.searchsorted(frame.ids[order], ids)]
tracks = np.stack([at(frame, common) for frame in last])
for model, window in (('affine', tracks), ('fundamental', tracks[[0, -1]])):
    digest.update(fit(window, PearlConfig(model=model), rng=5).labels.tobytes())
print(json.dumps({'labels': digest.hexdigest(), 'threads': sorted(blas_threads().values())}))
"""


def _probe(threads: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env['OPENBLAS_NUM_THREADS'] = threads
    out = subprocess.run([sys.executable, '-c', PROBE], env=env, check=True,
                         capture_output=True, text=True, timeout=300).stdout
    result: dict = json.loads(out)
    return result


def test_labels_do_not_depend_on_the_blas_thread_count():
    cores = os.cpu_count() or 1
    if cores < 2:
        pytest.skip('OpenBLAS runs at most one thread a core: one core allows no second')
    one, many = _probe('1'), _probe(str(cores))
    # Each ran with the threads asked for (numpy's and scipy's OpenBLAS alike).
    assert one['threads'] == [1, 1] and many['threads'] == [cores, cores]
    assert one['labels'] == many['labels']


def _stream_labels() -> list[np.ndarray]:
    segmenter = OnlineSegmenter(online=OnlineConfig(budget_ms=0))
    return [segmenter.process(f.stamp_ns, f.ids, f.uv).labels
            for f in make_stream('robot', 400, 30, 4)]


def test_a_stream_labels_the_same_with_or_without_the_second_thread(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parallel, 'PARALLEL_MIN_POINTS', 10**9)
    alone = _stream_labels()
    handed = []
    real = parallel.in_background

    def counted(*args: object) -> object:
        handed.append(args[0])
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(parallel, 'PARALLEL_MIN_POINTS', 1)
    monkeypatch.setattr(parallel, 'idle_core', lambda: True)
    monkeypatch.setattr(parallel, 'in_background', counted)
    shared = _stream_labels()
    assert handed  # the second thread did take pieces of the work
    assert len(alone) == len(shared) == 30
    for a, b in zip(alone, shared, strict=True):
        assert np.array_equal(a, b)
    assert any(np.unique(labels[labels >= 0]).size >= 2 for labels in alone)

"""One BLAS thread: OpenBLAS's own getter says how many threads each loaded library runs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

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


# A program's entry point run in a fresh interpreter, then each OpenBLAS's thread count.
PROGRAM = """
import json, sys, numpy, scipy.linalg
from pearl_ros.pipeline.threads import blas_threads
before = sorted(blas_threads().values())
if sys.argv[1] == 'replay':
    from pearl_ros.cli.replay import main
    status = main([sys.argv[2], '-o', sys.argv[3], '--set', 'budget_ms=0'])
elif sys.argv[1] == 'segment_bag':
    from pearl_ros.cli.segment_bag import main
    status = main([sys.argv[2]])
else:
    import cv2
    from pearl_ros.tracking.render import render_scene
    scene = render_scene(0, frames=8, size=(240, 320))
    clip = sys.argv[3] + '.avi'
    writer = cv2.VideoWriter(clip, cv2.VideoWriter.fourcc(*'MJPG'), 30.0, (320, 240))
    for frame in scene.frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    from pearl_ros.cli.video import main
    status = main([clip, '--output-bag', sys.argv[3]])
print(json.dumps({'status': status, 'before': before,
                  'after': sorted(blas_threads().values())}))
"""


def _program(name: str, folder: Path, **env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    bag = Path(__file__).resolve().parents[2] / 'bags' / '1R2RCR_g12'
    out = subprocess.run([sys.executable, '-c', PROGRAM, name, str(bag), str(folder / 'out')],
                         env={**clean, **env}, check=True, capture_output=True, text=True,
                         timeout=300).stdout
    result: dict = json.loads(out.strip().splitlines()[-1])
    return result


@pytest.mark.parametrize('name', ['replay', 'segment_bag', 'video'])
def test_the_offline_programs_run_blas_on_one_thread_as_the_node_does(
        name: str, tmp_path: Path) -> None:
    if (os.cpu_count() or 1) < 2:
        pytest.skip('OpenBLAS starts one thread on a one-core machine: nothing to limit')
    probe = _program(name, tmp_path)
    assert probe['status'] == 0
    # numpy's and scipy's OpenBLAS (and OpenCV's, once it is loaded), each on one thread.
    assert len(probe['after']) >= 2 and max(probe['before']) > 1
    assert set(probe['after']) == {1}
    (tmp_path / 'chosen').mkdir()
    chosen = _program(name, tmp_path / 'chosen', OPENBLAS_NUM_THREADS='2')
    assert chosen['status'] == 0 and set(chosen['after']) == {2}

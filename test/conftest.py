"""Scene factories shared by the tests, and the datasets that the ``data`` tests need.

The default suite (``make test``, ``-m "not data"``) runs on a bare clone: synthetic scenes and the
bundled bags only. Tests marked ``data`` need whole datasets, found under ``$PEARL_DATA`` or else
``../shared/data`` beside the repository; ``make test-data`` runs them, and a session that selects
one whose dataset is missing stops with one line saying where the data is expected and where it
comes from (a failure, never a skip).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pearl_ros.core.labels import OUTLIER

REPO = Path(__file__).resolve().parents[1]
DATA_ENV = 'PEARL_DATA'

# Where each dataset comes from (../shared/data/README.md has their layout and citations).
DATASET_SOURCES = {
    'hopkins155': 'Hopkins155 ground-truth files (Tron & Vidal, CVPR 2007), '
                  'http://www.vision.jhu.edu/data/hopkins155/',
    'kt3dmoseg_dev': 'KT3DMoSeg clips (Xu, Cheong & Li, CVPR 2018; KITTI, CC BY-NC-SA 3.0), '
                     'the 11 development clips',
    'adelaidermf_f_dev': 'AdelaideRMF "F" pairs (Wong et al., ICCV 2011), '
                         'the 10 development pairs',
}
# What a bare ``@pytest.mark.data`` needs; ``@pytest.mark.data('kt3dmoseg_dev')`` names another.
DEFAULT_DATASET = 'hopkins155'


def data_root() -> Path:
    """``$PEARL_DATA`` when set, else ``../shared/data`` beside the repository."""
    env = os.environ.get(DATA_ENV)
    return Path(env).expanduser() if env else REPO.parent / 'shared' / 'data'


def missing_dataset(name: str) -> str | None:
    """None when dataset ``name`` is present, else the one-line message saying what to do."""
    path = data_root() / name
    if path.is_dir():
        return None
    return (f'{name} not found at {path} (set {DATA_ENV} to the folder that holds {name}/); '
            f'it is {DATASET_SOURCES[name]}')


def dataset(name: str) -> Path:
    """The folder of dataset ``name``; fails the test with one line when it is missing."""
    message = missing_dataset(name)
    if message is not None:
        pytest.fail(message, pytrace=False)
    return data_root() / name


@pytest.hookimpl(tryfirst=True)  # before ``-m`` selects on the markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that asks for a dataset fixture is a ``data`` test even without the marker."""
    for item in items:
        for fixture in getattr(item, 'fixturenames', ()):
            if fixture in DATA_FIXTURES:
                item.add_marker(pytest.mark.data(DATA_FIXTURES[fixture]))


def pytest_collection_finish(session: pytest.Session) -> None:
    """Stop before the first test when a selected data test's dataset is missing."""
    needed = set()
    for item in session.items:
        for mark in item.iter_markers('data'):
            needed.update(mark.args or (DEFAULT_DATASET,))
    unknown = sorted(needed - DATASET_SOURCES.keys())
    if unknown:
        raise pytest.UsageError(f'unknown dataset(s) in a data marker: {unknown}; '
                                f'known: {sorted(DATASET_SOURCES)}')
    missing = [m for m in map(missing_dataset, sorted(needed)) if m is not None]
    if missing:
        hint = 'run `make test` (-m "not data") for the suite that needs no dataset'
        pytest.exit('; '.join(missing) + f'; {hint}', returncode=pytest.ExitCode.TESTS_FAILED)


def _rotation(rng: np.random.Generator, angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def make_affine_scene(
    sizes: tuple[int, ...] = (120, 80),
    frames: int = 12,
    noise: float = 0.5,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid bodies seen by an affine camera: tracks (F, N, 2) px and labels (N,).

    Body k is a cloud of 3-D points in its own image region; each frame it turns and shifts by
    its own random motion; an orthographic camera with a zoom projects it. Gaussian pixel noise.
    The regions stay apart, as opaque objects' do (no body's features show through another).
    """
    rng = np.random.default_rng(seed)
    tracks, labels = [], []
    for k, size in enumerate(sizes):
        centre = np.array([120.0 + 320.0 * k, 240.0 + 60.0 * (k % 2), 0.0])
        cloud = rng.uniform(-60, 60, (size, 3))
        rot, shift = np.eye(3), np.zeros(3)
        step_rot = _rotation(rng, 0.06)
        step_shift = rng.normal(0, 4.0, 3)
        body = []
        for _ in range(frames):
            world = cloud @ rot.T + centre + shift
            body.append(world[:, :2] * 1.0)
            rot, shift = step_rot @ rot, shift + step_shift
        tracks.append(np.stack(body))
        labels.append(np.full(size, k))
    tracks_arr = np.concatenate(tracks, axis=1) + rng.normal(0, noise, (frames, sum(sizes), 2))
    return tracks_arr, np.concatenate(labels)


def make_gap_scene(same_body: bool, frames: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Two 60-point clusters 300 px apart with nothing between; tracks (F, N, 2) and the
    cluster of each point. Both clusters are one rigid body (one motion of the pair), or each
    turns and shifts by its own motion, as the bodies of ``make_affine_scene`` do (0.06 rad a
    frame about a random axis). Orthographic views, noise 0.3 px."""
    rng = np.random.default_rng(7)
    centres = np.array([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0]])
    clouds = [rng.uniform(-60, 60, (60, 3)) + centre for centre in centres]
    motions = []
    for _ in range(2):
        step = _rotation(rng, 0.06)
        motions.append((step, rng.normal(0, 4.0, 3)))
    if same_body:
        motions[1] = motions[0]
    tracks = []
    for f in range(frames):
        views = []
        for cloud, (step, shift) in zip(clouds, motions, strict=True):
            rot = np.linalg.matrix_power(step, f)
            views.append((cloud - [150.0, 0, 0]) @ rot.T + f * shift)
        tracks.append(np.concatenate(views)[:, :2])
    tracks = np.stack(tracks) + rng.normal(0, 0.3, (frames, 120, 2))
    return tracks, np.repeat([0, 1], 60)


def make_two_view_scene(seed: int, mismatches: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Two views (the first and last frames of ``make_affine_scene``'s two bodies of 120 and 90
    points, 0.3 px noise) with a share ``mismatches`` of the points moved anywhere in the second
    view; tracks (2, N, 2) px and labels (N,), ``OUTLIER`` for the moved points."""
    tracks, truth = make_affine_scene(sizes=(120, 90), noise=0.3, seed=seed)
    tracks = tracks[[0, -1]].copy()
    rng = np.random.default_rng(seed)
    bad = rng.random(truth.size) < mismatches
    low, high = tracks.reshape(-1, 2).min(axis=0), tracks.reshape(-1, 2).max(axis=0)
    tracks[1, bad] = rng.uniform(low, high, (int(bad.sum()), 2))
    return tracks, np.where(bad, OUTLIER, truth)


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether labellings ``a`` and ``b`` group the points alike, whatever their numbers, and
    label the same points outliers."""
    if not np.array_equal(np.asarray(a) == OUTLIER, np.asarray(b) == OUTLIER):
        return False
    pairs = np.unique(np.stack([a, b]), axis=1).shape[1]
    return bool(pairs == np.unique(a).size == np.unique(b).size)


def kept_by_sets(tracks: np.ndarray, k: int) -> np.ndarray:
    """By brute force, how many of each point's k nearest others in the first frame of
    ``tracks`` (F, N, 2) are among its k nearest in the last: sets of sorted distances, (N,)."""
    kept = np.zeros(tracks.shape[1], dtype=np.int64)
    for p in range(tracks.shape[1]):
        near = []
        for view in (tracks[0], tracks[-1]):
            d = np.linalg.norm(view - view[p], axis=1)
            d[p] = np.inf
            near.append(set(np.argsort(d, kind='stable')[:k].tolist()))
        kept[p] = len(near[0] & near[1])
    return kept


@pytest.fixture
def affine_scene():
    return make_affine_scene


@pytest.fixture
def two_view_scene():
    return make_two_view_scene


@pytest.fixture(name='same_partition')
def same_partition_fixture():
    return same_partition


@pytest.fixture(name='kept_by_sets')
def kept_by_sets_fixture():
    return kept_by_sets


@pytest.fixture
def gap_scene():
    return make_gap_scene


def write_hopkins_mat(
    path: Path, tracks: np.ndarray, labels: np.ndarray, focal: float = 500.0
) -> Path:
    """Write tracks (F, P, 2) px and labels (P,) as a Hopkins155 ``*_truth.mat`` file.

    The fields as in the dataset (see ../shared/data/README.md): ``y`` (3, P, F) homogeneous
    pixels, ``x`` the same normalised by ``K``, ``s`` (P, 1) groups 1..k, ``K``, ``width``,
    ``height``, ``points``, ``frames``. Returns ``path``.
    """
    num_frames, num_points, _ = tracks.shape
    k = np.array([[focal, 0.0, 320.0], [0.0, focal, 240.0], [0.0, 0.0, 1.0]])
    y = np.concatenate((np.transpose(tracks, (2, 1, 0)), np.ones((1, num_points, num_frames))))
    x = np.einsum('ij,jpf->ipf', np.linalg.inv(k), y)
    groups = np.unique(labels, return_inverse=True)[1].reshape(-1, 1) + 1
    path.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(str(path), {
        'y': y, 'x': x, 's': groups.astype(np.float64), 'K': k,
        'width': np.array([[640]]), 'height': np.array([[480]]),
        'points': np.array([[num_points]]), 'frames': np.array([[num_frames]]),
    })
    return path


@pytest.fixture
def hopkins_like(tmp_path: Path):
    """Factory: a Hopkins155-format folder in ``tmp_path`` that needs no dataset.

    ``hopkins_like(name, sizes=(40, 30), frames=10, seed=0)`` writes
    ``<tmp>/hopkins155/<name>/<name>_truth.mat`` from ``make_affine_scene`` and returns the
    file; the folder (``path.parents[1]``) is then a Hopkins155 root for ``pearl_bench``.
    The name sets the category as in the dataset (``cars...`` traffic, ``two_cranes...``
    articulated, else checkerboard).
    """

    def make(name: str, sizes: tuple[int, ...] = (40, 30), frames: int = 10,
             seed: int = 0) -> Path:
        tracks, labels = make_affine_scene(sizes, frames, noise=0.3, seed=seed)
        return write_hopkins_mat(tmp_path / 'hopkins155' / name / f'{name}_truth.mat',
                                 tracks, labels)

    return make


@pytest.fixture
def hopkins_root() -> Path:
    """The Hopkins155 folder (``$PEARL_DATA/hopkins155``, default ../shared/data/hopkins155)."""
    return dataset('hopkins155')


@pytest.fixture
def kt3dmoseg_root() -> Path:
    """The KT3DMoSeg development clips (``$PEARL_DATA/kt3dmoseg_dev``)."""
    return dataset('kt3dmoseg_dev')


@pytest.fixture
def adelaidermf_root() -> Path:
    """The AdelaideRMF F development pairs (``$PEARL_DATA/adelaidermf_f_dev``)."""
    return dataset('adelaidermf_f_dev')


# Fixture -> the dataset it needs: a test that uses one is marked ``data`` at collection.
DATA_FIXTURES = {
    'hopkins_root': 'hopkins155',
    'kt3dmoseg_root': 'kt3dmoseg_dev',
    'adelaidermf_root': 'adelaidermf_f_dev',
}

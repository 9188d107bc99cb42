"""What a robot-like stream's last window holds to separate its motions, from its true geometry.

The robot-like streams (:mod:`pearl_ros.datasets.robot`) know their camera poses. A point of the
static world, triangulated from its track with those poses, reprojects within the tracking
noise; a point of a moving object usually does not. Where it does as well as it does for the
static world's own tracks, the object's motion over the window is one a static point at some
depth would show (an object driving along the camera's line of sight, say): no segmentation
from image motion alone can tell it from the background, whatever its energy. A looser reading
(residual under a fixed 2 px, four times the tracking noise) counts also the tracks that a
static point explains only roughly: from these the cameras set the object apart, over enough
frames, though a model of the image motion alone (an affine subspace) may not. And the motion
model matters: under perspective, the static world's trajectories over a window fill a 4-D
affine subspace, which a 3-D one (the affine camera's) fits only at two to three times the
noise. Over 15 frames objects lie about 1-8 px off the 3-D subspace and 0.8-2 px off the 4-D
one (on the streams of `pearl_bench synthetic`).

``pearl_bench synthetic --oracle`` prints these readings beside the segmenter's scores.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pearl_ros.core.errors import InputError
from pearl_ros.core.models.ego import static_residuals
from pearl_ros.datasets.robot import robot_scene, robot_stream
from pearl_ros.online.window import SlidingWindow


@dataclass(frozen=True)
class GroupReading:
    """One true group of the features that span a stream's last window.

    Attributes
    ----------
    seed : int, the stream's seed
    group : int, -1 outlier tracks, 0 static world, k object k
    points : int, features of the group that span the window
    static_px : float, median RMS reprojection residual (px) of the group's tracks each
        triangulated as one static point with the true camera poses
    static_share : float, share of them a static point explains: residual under the
        threshold and in front of every camera of the window
    within_share : float, share of them a static point explains as well as it explains the
        static world's own tracks: residual at most the static world's 99% quantile on the
        window, and in front (what a test at the static world's own spread cannot tell apart;
        the fixed threshold above is looser)
    affine3_px, affine4_px : float, median RMS distance per frame (px) of the group's
        trajectories to the static world's own best 3-D / 4-D affine subspace (for the static
        world itself: its RMS residual to that subspace)
    """

    seed: int
    group: int
    points: int
    static_px: float
    static_share: float
    within_share: float
    affine3_px: float
    affine4_px: float


def final_window(seed: int, window: int = 10, frames: int = 300, static_px: float = 2.0
                 ) -> list[GroupReading]:
    """Readings of the features spanning the last ``window`` frames of ``robot_stream(seed=seed,
    frames=frames)`` (default arguments otherwise, as ``pearl_bench synthetic``), per true
    group; ``static_px`` is the residual under which a static point explains a track (default
    2 px: four times the stream's 0.5 px tracking noise)."""
    if not 2 <= window <= frames:
        raise InputError(f'window must be in [2, frames], got {window}')
    scene = robot_scene(frames, seed)
    # The tracks as the node keys them (a tracker's reused id is a new track).
    tracked = SlidingWindow(window)
    for frame in list(robot_stream(seed=seed, frames=frames))[-window:]:
        keys = tracked.push(frame.stamp_ns, frame.ids, frame.uv)
    coords, age = tracked.history(keys)
    spanning = age == window
    uv, truth = coords[:, spanning], frame.truth[spanning]
    span = range(frames - window, frames)
    cameras = np.stack([scene.camera(t) for t in span])
    residual, in_front = static_residuals(cameras, uv)
    trajectories = np.transpose(uv, (1, 0, 2)).reshape(uv.shape[1], -1)
    static = trajectories[truth == 0]
    explained = in_front & (residual <= np.quantile(residual[truth == 0], 0.99))
    readings = []
    for group in np.unique(truth):
        member = truth == group
        affine = [float(np.median(_distance(trajectories[member], static, dim))) for dim in (3, 4)]
        readings.append(GroupReading(
            seed, int(group), int(member.sum()), float(np.median(residual[member])),
            float(np.mean((residual[member] < static_px) & in_front[member])),
            float(np.mean(explained[member])), *affine))
    return readings


def _distance(trajectories: np.ndarray, reference: np.ndarray, dim: int) -> np.ndarray:
    """RMS distance per frame of ``trajectories`` (N, 2F) to the best ``dim``-D affine subspace
    of ``reference`` (M, 2F) (nan if ``reference`` holds too few points to fit one)."""
    if reference.shape[0] <= dim:
        return np.full(trajectories.shape[0], np.nan)
    mean = reference.mean(axis=0)
    _, _, vt = np.linalg.svd(reference - mean, full_matrices=False)
    offset = trajectories - mean
    along = offset @ vt[:dim].T
    sq = np.sum(np.square(offset), axis=1) - np.sum(np.square(along), axis=1)
    frames = trajectories.shape[1] // 2
    distance: np.ndarray = np.sqrt(np.maximum(sq, 0.0) / frames)
    return distance


def format_readings(readings: list[GroupReading]) -> str:
    """A markdown table of ``readings``, and per seed the share of the spanning points that are
    on a moving object yet explained by a static point."""
    lines = ['| seed | group | points | static residual px | static share | within static '
             '99% | to 3-D affine px | to 4-D affine px |',
             '| --- | --- | --- | --- | --- | --- | --- | --- |']
    for r in readings:
        name = {-1: 'outliers', 0: 'static world'}.get(r.group, f'object {r.group}')
        lines.append(f'| {r.seed} | {name} | {r.points} | {r.static_px:.2f} | '
                     f'{r.static_share:.2f} | {r.within_share:.2f} | {r.affine3_px:.2f} | '
                     f'{r.affine4_px:.2f} |')
    for seed in dict.fromkeys(r.seed for r in readings):
        rows = [r for r in readings if r.seed == seed]
        total = max(sum(r.points for r in rows), 1)
        hidden = sum(r.points * r.static_share for r in rows if r.group > 0)
        within = sum(r.points * r.within_share for r in rows if r.group > 0)
        lines.append(f'seed {seed}: {100 * hidden / total:.1f}% of the spanning points move with '
                     'an object yet as a static point would (static share); '
                     f'{100 * within / total:.1f}% within the static world\'s own spread')
    return '\n'.join(lines)

"""A synthetic feature stream shaped like a robot's: a perspective camera driving through a scene.

A pinhole camera (focal length 500 px, 640 x 480 px, principal point at the centre) 1.2 m above
flat ground moves forward at 1.5-3 m/s and turns (a yaw rate that varies smoothly, up to
0.3 rad/s, with a small pitch and roll jitter), 30 frames a second. The static world is the
ground and boxes standing on it (buildings, walls, parked things) at 3-40 m and more; the
background therefore shows real perspective parallax, which no homography explains. Moving
objects are boxes on the ground that drive or walk (speed and heading vary smoothly): a car is
4 x 1.5 x 1.8 m and moves at 3-10 m/s, turning at most 0.08 rad/s; a person is 0.5 x 1.7 x
0.4 m and walks at about 1.4 m/s. Their paths are drawn among random candidates so that each
object is in view on a good share of the frames, leaves it and comes back, and the first object
is in view in the last frame.

The features are a tracker's view. A feature is a point on a surface seen by the camera: it is
born where a random pixel's ray first meets a surface (the ground, a static box or an object),
preferring pixels far from the features already tracked, as a corner detector with a minimum
distance does, so the static world gets features in proportion to its visible image area.
Objects carry more texture than roads and walls: each object in view is topped up to
``object_density`` times its visible area's share of the features (at least a handful), at once
when it comes into view. A feature dies when its point leaves the image, goes behind the camera
or beyond 50 m, is hidden by a nearer surface (exact ray casting against every box; a box also
hides its own far faces), or at random. Dead features are replaced so that each frame keeps
about ``num_features``; a new feature sometimes takes an id that died at least three frames
before, as trackers reuse ids. Each frame lists its features in a new random order.

Gross outliers: a share ``outlier_share`` of each frame's features are outlier tracks, random
walks in the image that no rigid motion explains (they start anywhere in the image, step by a
Gaussian of ``outlier_step`` px per axis each frame, and live for a random number of frames,
5-90, or until they leave the image). Their truth is -1. Truth of the others: 0 for the static
world (ground and static boxes), k for the k-th moving object.

Coordinates: world and camera frames have x right, y down, z forward (the ground is the plane
y = 1.2 m of the world); a pose (R, c) maps a point's body coordinates X to R X + c.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from pearl_ros.core.errors import InputError
from pearl_ros.datasets.synthetic import FRAME_NS, StreamFrame

FOCAL_PX = 500.0
WIDTH_PX, HEIGHT_PX = 640, 480
INTRINSICS = np.array([[FOCAL_PX, 0.0, WIDTH_PX / 2], [0.0, FOCAL_PX, HEIGHT_PX / 2],
                       [0.0, 0.0, 1.0]])
CAMERA_HEIGHT_M = 1.2
OBJECT_KINDS = ('car', 'person')
_DT = FRAME_NS * 1e-9  # s per frame
_MIN_DEPTH, _MAX_DEPTH = 0.5, 50.0  # m, depth range in which a point is tracked
# Per kind: half extents (m) across, up and along the object (a car is 4 m long, 1.5 m high,
# 1.8 m wide); speed range (m/s); largest yaw rate (rad/s); range (m) at which it is put in view.
_KINDS = {
    'car': ((0.9, 0.75, 2.0), (3.0, 10.0), 0.08, (6.0, 18.0)),
    'person': ((0.25, 0.85, 0.2), (1.2, 1.6), 0.25, (3.0, 8.0)),
}
_CANDIDATES = 256  # random paths drawn per object, the best kept
_STATIC_BOXES = 60
_HANDFUL = 6  # features an object in view gets at least (fewer if num_features < 120)
_REUSE = 0.2  # probability that a new feature takes an id dead for >= 3 frames
_SPACING_PX = 40.0  # distance to the nearest feature at which a birth pixel stops being favoured


@dataclass(frozen=True)
class RobotScene:
    """The geometry behind a robot stream: poses per frame and the boxes of the world.

    Attributes
    ----------
    camera_rotation : (T, 3, 3) float64, world from camera
    camera_position : (T, 3) float64, m, camera centre in the world
    object_rotation : (T, K, 3, 3) float64, world from object k + 1's box frame
    object_position : (T, K, 3) float64, m, centre of object k + 1's box
    object_half_extents : (K, 3) float64, m, half sizes across, up and along the object
    kinds : tuple of str, 'car' or 'person' per object
    static_rotation : (S, 3, 3) float64, world from static box frame
    static_position : (S, 3) float64, m, static box centres
    static_half_extents : (S, 3) float64, m
    """

    camera_rotation: np.ndarray
    camera_position: np.ndarray
    object_rotation: np.ndarray
    object_position: np.ndarray
    object_half_extents: np.ndarray
    kinds: tuple[str, ...]
    static_rotation: np.ndarray
    static_position: np.ndarray
    static_half_extents: np.ndarray

    def camera(self, t: int) -> np.ndarray:
        """The projection matrix (3, 4) of frame t: pixels from world points."""
        to_camera = self.camera_rotation[t].T
        return INTRINSICS @ np.hstack([to_camera, -to_camera @ self.camera_position[t][:, None]])

    def project(self, t: int, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths (N,) in m of world points (N, 3) seen from frame t."""
        cam = (world - self.camera_position[t]) @ self.camera_rotation[t]
        depth = cam[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            uv = FOCAL_PX * cam[:, :2] / depth[:, None] + INTRINSICS[:2, 2]
        return uv, depth


def _yaw(angle: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) about the (downward) y axis that turn +z towards +x."""
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1),
                     np.stack([-s, zero, c], -1)], -2)


def _smooth(rng: np.random.Generator, frames: int, count: int, periods: tuple[float, float]
            ) -> np.ndarray:
    """(count, frames) smooth random signals with peak |value| 1: three sines of random periods
    (s) in ``periods``."""
    seconds = np.arange(frames) * _DT
    period = rng.uniform(*periods, (count, 3, 1))
    phase = rng.uniform(0.0, 2 * np.pi, (count, 3, 1))
    weight = rng.uniform(0.5, 1.0, (count, 3, 1))
    signal = np.sum(weight * np.sin(2 * np.pi * seconds / period + phase), axis=1)
    return signal / np.maximum(np.abs(signal).max(axis=1, keepdims=True), 1e-9)


class _Camera(NamedTuple):
    """A camera's path: world-from-camera rotations (T, 3, 3), centres (T, 3) in m and headings
    (T,) in rad."""

    rotation: np.ndarray
    position: np.ndarray
    heading: np.ndarray


def _camera_path(rng: np.random.Generator, frames: int) -> _Camera:
    """The path of a camera driving forward and turning."""
    speed = np.clip(rng.uniform(1.5, 3.0) + 0.3 * _smooth(rng, frames, 1, (3.0, 10.0))[0],
                    1.5, 3.0)
    yaw_rate = rng.uniform(0.2, 0.3) * _smooth(rng, frames, 1, (4.0, 16.0))[0]
    heading = np.concatenate([[0.0], np.cumsum(yaw_rate[:-1]) * _DT])
    step = speed[:, None] * np.stack([np.sin(heading), np.zeros(frames), np.cos(heading)], 1)
    position = np.concatenate([np.zeros((1, 3)), np.cumsum(step[:-1] * _DT, axis=0)])
    pitch, roll = 0.01 * _smooth(rng, frames, 2, (0.5, 2.0))
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    zero, one = np.zeros(frames), np.ones(frames)
    rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cp, -sp], -1),
                   np.stack([zero, sp, cp], -1)], -2)
    rz = np.stack([np.stack([cr, -sr, zero], -1), np.stack([sr, cr, zero], -1),
                   np.stack([zero, zero, one], -1)], -2)
    return _Camera(_yaw(heading) @ rx @ rz, position, heading)


def _object_paths(rng: np.random.Generator, kind: str, anchor: np.ndarray, camera: _Camera
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Candidate paths of one object: box centres (C, T, 3) and headings (C, T).

    Candidate c is in view at frame ``anchor[c]`` (at a random range and bearing) and moves
    from there, forwards and backwards in time, with a smoothly varying speed and yaw rate.
    """
    half, (slow, fast), turn, (near, far) = _KINDS[kind]
    centre, heading = camera.position, camera.heading
    count, frames = anchor.size, heading.size
    bearing = heading[anchor] + rng.uniform(-0.45, 0.45, count)
    distance = rng.uniform(near, far, count)
    start = centre[anchor] + distance[:, None] * np.stack(
        [np.sin(bearing), np.zeros(count), np.cos(bearing)], 1)
    mid = rng.uniform(slow, fast, (count, 1))
    swing = np.minimum(mid - slow, fast - mid) * rng.uniform(0.3, 1.0, (count, 1))
    speed = mid + swing * _smooth(rng, frames, count, (3.0, 12.0))
    rate = turn * rng.uniform(0.2, 1.0, (count, 1)) * _smooth(rng, frames, count, (4.0, 20.0))
    rows = np.arange(count)
    # Integrals from frame 0, then shifted so that they vanish at each candidate's anchor.
    angle = np.concatenate([np.zeros((count, 1)), np.cumsum(rate[:, :-1], 1) * _DT], 1)
    angle += rng.uniform(-np.pi, np.pi, (count, 1)) + heading[anchor, None] - angle[rows, anchor,
                                                                                     None]
    step = speed[..., None] * np.stack([np.sin(angle), np.zeros_like(angle), np.cos(angle)], -1)
    path = np.concatenate([np.zeros((count, 1, 3)), np.cumsum(step[:, :-1] * _DT, 1)], 1)
    path += start[:, None] - path[rows, anchor, None]
    path[..., 1] = CAMERA_HEIGHT_M - half[1]
    return path, angle


def _runs(visible: np.ndarray) -> int:
    """Runs of at least 10 visible frames, after gaps of less than 10 frames are closed."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], visible.astype(np.int8), [0]])))
    starts, stops = edges[::2], edges[1::2]
    if starts.size == 0:
        return 0
    keep = np.concatenate([[True], starts[1:] - stops[:-1] >= 10])
    merged_starts = starts[keep]
    merged_stops = np.concatenate([stops[np.flatnonzero(keep)[1:] - 1], stops[-1:]])
    return int(np.sum(merged_stops - merged_starts >= 10))


def _choose_path(rng: np.random.Generator, kind: str, last: bool, camera: _Camera,
                 taken: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The candidate path whose object is in view on about half the frames, leaves the view and
    comes back, stays clear of the camera and of the objects ``taken`` (paths (T, 3)); in view
    in the last frame if ``last``."""
    frames = camera.heading.size
    anchor = np.full(_CANDIDATES, frames - 1) if last else rng.integers(0, frames, _CANDIDATES)
    path, angle = _object_paths(rng, kind, anchor, camera)
    half = np.asarray(_KINDS[kind][0])
    offset = path - camera.position
    cam = sum(offset[..., j, None] * camera.rotation[:, j] for j in range(3))  # (C, T, 3)
    uv = FOCAL_PX * cam[..., :2] / np.maximum(cam[..., 2:], 1e-9) + INTRINSICS[:2, 2]
    visible = ((cam[..., 2] > 1.0) & (cam[..., 2] < _MAX_DEPTH) & (uv[..., 0] >= 0)
               & (uv[..., 0] <= WIDTH_PX - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= HEIGHT_PX - 1))
    share = visible.mean(axis=1)
    runs = np.array([_runs(v) if v.any() else 0 for v in visible])
    radius = np.hypot(half[0], half[2])
    gap = np.linalg.norm(offset[..., ::2], axis=-1).min(axis=1) - radius - 2.0
    for other in taken:
        gap = np.minimum(gap, np.linalg.norm((path - other)[..., ::2], axis=-1).min(axis=1)
                         - radius - 3.0)
    score = -np.abs(share - 0.6) + 0.5 * (runs >= 2) - 0.1 * np.maximum(runs - 3, 0) \
        - 10.0 * (gap < 0)
    best = int(np.argmax(score))
    return path[best], angle[best]


def _static_boxes(rng: np.random.Generator, camera: _Camera, clear: np.ndarray,
                  margin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes standing on the ground around the camera's path, none within ``margin`` (m) of
    the ground-plane points ``clear`` (P, 3): rotations, centres, half extents."""
    centre, heading = camera.position, camera.heading
    count = 20 * _STATIC_BOXES
    at = rng.integers(0, heading.size, count)
    ahead, aside = rng.uniform(2.0, 45.0, count), rng.uniform(-30.0, 30.0, count)
    yaw = heading[at] + rng.uniform(-0.3, 0.3, count)
    half = np.stack([rng.uniform(0.5, 5.0, count), rng.uniform(1.0, 5.0, count),
                     rng.uniform(0.5, 3.0, count)], 1)
    forward = np.stack([np.sin(heading[at]), np.zeros(count), np.cos(heading[at])], 1)
    across = np.stack([np.cos(heading[at]), np.zeros(count), -np.sin(heading[at])], 1)
    position = centre[at] + ahead[:, None] * forward + aside[:, None] * across
    position[:, 1] = CAMERA_HEIGHT_M - half[:, 1]
    distance = np.linalg.norm(position[:, None, ::2] - clear[None, :, ::2], axis=-1)
    free = np.all(distance > np.hypot(half[:, :1], half[:, 2:]) + margin, axis=1)
    keep = np.flatnonzero(free)[:_STATIC_BOXES]
    return _yaw(yaw[keep]), position[keep], half[keep]


def robot_scene(frames: int = 300, seed: int = 0,
                objects: Sequence[str] = ('car', 'person', 'car')) -> RobotScene:
    """The scene that :func:`robot_stream` with the same arguments shows.

    Parameters
    ----------
    frames : int, frames (30 Hz)
    seed : int
    objects : 'car' or 'person' per moving object; object k is ``objects[k - 1]``
    """
    _check_scene(frames, objects)
    return _build_scene(np.random.default_rng(seed), frames, tuple(objects))


def _check_scene(frames: int, objects: Sequence[str]) -> None:
    """InputError on a bad frame count or object kind."""
    if frames < 1:
        raise InputError(f'frames must be >= 1, got {frames}')
    unknown = [kind for kind in objects if kind not in OBJECT_KINDS]
    if unknown:
        raise InputError(f'objects must be among {OBJECT_KINDS}, got {unknown[0]!r}')


def _build_scene(rng: np.random.Generator, frames: int, objects: tuple[str, ...]) -> RobotScene:
    camera = _camera_path(rng, frames)
    paths: list[np.ndarray] = []
    angles: list[np.ndarray] = []
    for k, kind in enumerate(objects):
        path, angle = _choose_path(rng, kind, k == 0, camera, paths)
        paths.append(path)
        angles.append(angle)
    half = np.array([_KINDS[kind][0] for kind in objects]).reshape(-1, 3)
    # Keep boxes off the camera's path and the objects' paths (every third frame, at most 1 m
    # apart, so the margins are 0.5 m wider), and off the line of sight to the first object in
    # the last frame.
    clear = [camera.position[::3]] + [path[::3] for path in paths]
    steps = clear[0].shape[0]
    margin = [np.full(steps, 2.5)] + [np.full(steps, np.hypot(h[0], h[2]) + 1.5) for h in half]
    if paths:
        sight = np.linspace(0.0, 1.0, 12)[:, None]
        clear.append(camera.position[-1] + sight * (paths[0][-1] - camera.position[-1]))
        margin.append(np.full(12, 1.0))
    static = _static_boxes(rng, camera, np.concatenate(clear), np.concatenate(margin))
    rotation = np.stack([_yaw(a) for a in angles], 1) if paths else np.zeros((frames, 0, 3, 3))
    position = np.stack(paths, 1) if paths else np.zeros((frames, 0, 3))
    return RobotScene(camera.rotation, camera.position, rotation, position, half, objects,
                      *static)


def _corners(rotation: np.ndarray, centre: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(B, 8, 3) world corners of boxes."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return (signs * half[:, None, :]) @ np.swapaxes(rotation, 1, 2) + centre[:, None, :]


def _box_entry(origin: np.ndarray, rays: np.ndarray, rotation: np.ndarray, centre: np.ndarray,
               half: np.ndarray) -> np.ndarray:
    """(M, B) ray parameter s at which origin + s * ray enters box b (slab method); inf where
    the ray misses it or starts inside it."""
    boxes = rotation.shape[0]
    start = np.sum((origin - centre)[:, :, None] * rotation, axis=1)  # (B, 3), box frame
    # Every ray in every box's frame with one matrix product: (M, 3) @ (3, B * 3).
    heading = (rays @ rotation.transpose(1, 0, 2).reshape(3, 3 * boxes)).reshape(-1, boxes, 3)
    with np.errstate(divide='ignore', invalid='ignore'):
        low = (-half - start) / heading
        high = (half - start) / heading
        first, last = np.minimum(low, high), np.maximum(low, high)
        near = np.maximum(np.maximum(first[..., 0], first[..., 1]), first[..., 2])
        far = np.minimum(np.minimum(last[..., 0], last[..., 1]), last[..., 2])
    return np.where((near <= far) & (near > 0), near, np.inf)


class _World:
    """The boxes of one frame (objects first, then the static boxes near enough to matter) and
    the body each belongs to."""

    def __init__(self, scene: RobotScene, t: int, corners: np.ndarray) -> None:
        """``corners`` : (S * 8, 3) float64, m, the static boxes' corners."""
        self.origin = scene.camera_position[t]
        self.rotation = scene.camera_rotation[t]
        objects = scene.object_position.shape[1]
        moving = _corners(scene.object_rotation[t], scene.object_position[t],
                          scene.object_half_extents).reshape(-1, 3)
        uv, depth = scene.project(t, np.concatenate([moving, corners]))
        uv, depth = uv.reshape(-1, 8, 2), depth.reshape(-1, 8)
        # Static boxes that may be seen: a corner in front, within range, and an image bounding
        # box that overlaps the image (or a corner behind the camera, where no bounding box
        # holds).
        front = np.all(depth > 0, axis=1)
        low = np.where(front[:, None], uv.min(axis=1), -np.inf)
        high = np.where(front[:, None], uv.max(axis=1), np.inf)
        near = ((depth > 0).any(axis=1) & (depth.min(axis=1) < _MAX_DEPTH)
                & np.all((high >= 0) & (low <= [WIDTH_PX - 1, HEIGHT_PX - 1]), axis=1))
        near[:objects] = True
        self.box_rotation = np.concatenate([scene.object_rotation[t], scene.static_rotation])[near]
        self.box_centre = np.concatenate([scene.object_position[t], scene.static_position])[near]
        self.box_half = np.concatenate([scene.object_half_extents,
                                        scene.static_half_extents])[near]
        self.box_low, self.box_high = low[near], high[near]
        self.box_body = np.concatenate([np.arange(1, objects + 1),
                                        np.zeros(near.size - objects, int)])[near]

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """World directions (N, 3) of pixels, scaled to unit depth."""
        cam = np.column_stack([(uv - INTRINSICS[:2, 2]) / FOCAL_PX, np.ones(len(uv))])
        return cam @ self.rotation.T

    def entry(self, rays: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """(N, B) parameters at which rays (N, 3) through pixels (N, 2) enter each box, inf
        where they miss it (only pixels in a box's image bounding box are tested)."""
        u, v = uv[:, :1], uv[:, 1:]
        low, high = self.box_low, self.box_high
        candidate = (u >= low[:, 0]) & (u <= high[:, 0]) & (v >= low[:, 1]) & (v <= high[:, 1])
        rows = np.flatnonzero(candidate.any(axis=1))
        cols = np.flatnonzero(candidate.any(axis=0))
        entry = np.full(candidate.shape, np.inf)
        if rows.size:
            entry[np.ix_(rows, cols)] = _box_entry(
                self.origin, rays[rows], self.box_rotation[cols],
                self.box_centre[cols], self.box_half[cols])
        return entry

    def hidden(self, world: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Points (N, 3) seen at pixels (N, 2) that a box hides (their own box's far faces
        included)."""
        return np.any(self.entry(world - self.origin, uv) < 1.0 - 1e-6, axis=1)

    def cast(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first surface each pixel's ray meets: world points (N, 3), depths (N,) in m (inf
        for none within range) and bodies (N,) (0 = ground or static, k = object k)."""
        rays = self.rays(uv)
        entry = self.entry(rays, uv)
        with np.errstate(divide='ignore'):
            ground = np.where(rays[:, 1] > 0, (CAMERA_HEIGHT_M - self.origin[1]) / rays[:, 1],
                              np.inf)
        first = np.argmin(entry, axis=1) if entry.shape[1] else np.zeros(len(uv), int)
        box = entry[np.arange(len(uv)), first] if entry.shape[1] else np.full(len(uv), np.inf)
        depth = np.minimum(box, ground)
        body = np.where(box < ground, self.box_body[first] if entry.shape[1] else 0, 0)
        depth = np.where(depth <= _MAX_DEPTH, depth, np.inf)
        return self.origin + depth[:, None] * rays, depth, body


def _inside(uv: np.ndarray) -> np.ndarray:
    """Whether pixels (N, 2) are in the image (NaN is not)."""
    with np.errstate(invalid='ignore'):
        return ((uv[:, 0] >= 0) & (uv[:, 0] <= WIDTH_PX - 1) & (uv[:, 1] >= 0)
                & (uv[:, 1] <= HEIGHT_PX - 1))


class _Tracker:
    """What a tracker holds: live features (points fixed on bodies), outlier walks, and ids."""

    def __init__(self, rng: np.random.Generator, scene: RobotScene, true_count: int,
                 outlier_count: int, death_rate: float, outlier_step: float,
                 object_density: float) -> None:
        self.rng, self.scene = rng, scene
        self.object_density = object_density
        self.corners = _corners(scene.static_rotation, scene.static_position,
                                scene.static_half_extents).reshape(-1, 3)
        self.true_count, self.outlier_count = true_count, outlier_count
        self.death_rate, self.outlier_step = death_rate, outlier_step
        self.ids = np.empty(0, np.int64)
        self.body = np.empty(0, np.int64)
        self.local = np.empty((0, 3))  # body coordinates (world coordinates for body 0)
        self.walk_ids = np.empty(0, np.int64)
        self.walk_uv = np.empty((0, 2))
        self.walk_life = np.empty(0, np.int64)  # frames left
        self.next_id = 0
        self.pool = np.empty(0, np.int64)  # dead ids
        self.died = np.empty(0, np.int64)  # frame each pool id died

    def frame(self, t: int, noise: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ids (N,), pixels (N, 2) and truth (N,) of frame t, in a new random order."""
        world = _World(self.scene, t, self.corners)
        uv = self._survivors(world, t)
        self._walk(t)
        uv = self._births(world, t, uv)
        uv = uv + self.rng.normal(0.0, noise, uv.shape)
        inside = _inside(uv)  # noise may push a feature by the border out of the image
        self._retire(self.ids[~inside], t)
        self.ids, self.body, self.local = self.ids[inside], self.body[inside], self.local[inside]
        ids = np.concatenate([self.ids, self.walk_ids])
        order = self.rng.permutation(ids.size)
        truth = np.concatenate([self.body, np.full(self.walk_ids.size, -1, np.int64)])
        return ids[order], np.concatenate([uv[inside], self.walk_uv])[order], truth[order]

    def _points(self, t: int) -> np.ndarray:
        """World points (N, 3) of the live features in frame t."""
        rotation = np.concatenate([np.eye(3)[None], self.scene.object_rotation[t]])[self.body]
        centre = np.concatenate([np.zeros((1, 3)), self.scene.object_position[t]])[self.body]
        return np.einsum('nij,nj->ni', rotation, self.local) + centre

    def _survivors(self, world: _World, t: int) -> np.ndarray:
        """Drop the features lost in frame t; the clean pixels (N, 2) of the others."""
        points = self._points(t)
        uv, depth = self.scene.project(t, points)
        alive = (depth > _MIN_DEPTH) & (depth < _MAX_DEPTH) & _inside(uv)
        alive[alive] = ~world.hidden(points[alive], uv[alive])
        if t:
            alive &= self.rng.random(alive.size) >= self.death_rate
        self._retire(self.ids[~alive], t)
        self.ids, self.body, self.local = self.ids[alive], self.body[alive], self.local[alive]
        return uv[alive]

    def _walk(self, t: int) -> None:
        """Move the outlier walks one step, end those that expire or leave, start new ones."""
        if t:
            self.walk_uv = self.walk_uv + self.rng.normal(0.0, self.outlier_step,
                                                          self.walk_uv.shape)
            self.walk_life = self.walk_life - 1
        alive = (self.walk_life > 0) & _inside(self.walk_uv)
        self._retire(self.walk_ids[~alive], t)
        count = self.outlier_count - int(alive.sum())
        self.walk_ids = np.concatenate([self.walk_ids[alive], self._take(count, t)])
        self.walk_uv = np.concatenate([self.walk_uv[alive], self._pixels(count)])
        self.walk_life = np.concatenate([self.walk_life[alive],
                                         self.rng.integers(5, 91, count)])

    def _births(self, world: _World, t: int, uv: np.ndarray) -> np.ndarray:
        """Add features up to the true count: first on the objects in view that have fewer than
        their share, then on pixels spread away from the tracked ones. Clean pixels of all."""
        uv = self._object_births(world, t, uv)
        count = self.true_count - self.ids.size
        if count <= 0:
            return uv
        pixels = self._pixels(4 * count + 40)
        points, depth, body = world.cast(pixels)
        ok = np.flatnonzero(np.isfinite(depth) & (depth >= _MIN_DEPTH))
        tracked = np.concatenate([uv, self.walk_uv])
        # A corner detector with a minimum distance: favour pixels far from tracked features.
        spacing = np.full(ok.size, _SPACING_PX)
        if tracked.size and ok.size:
            gaps = cKDTree(tracked).query(pixels[ok])[0]
            spacing = np.minimum(gaps, _SPACING_PX) + 1e-3
        # Weighted sampling without replacement (Efraimidis & Spirakis 2006): smallest keys.
        keys = self.rng.exponential(size=ok.size) / spacing**2
        pick = ok[np.argsort(keys)[:count]]
        return self._add(t, uv, pixels[pick], points[pick], body[pick])

    def _object_births(self, world: _World, t: int, uv: np.ndarray) -> np.ndarray:
        """Top up each object in view to its share: ``object_density`` times its visible image
        area's share of the true features (at least a handful; all objects at most 60%)."""
        pixels, points, body, area = self._on_objects(world, t, 64)
        target = self.object_density * self.true_count * area / (WIDTH_PX * HEIGHT_PX)
        target *= min(1.0, 0.6 * self.true_count / max(target.sum(), 1e-9))
        handful = min(_HANDFUL, max(1, self.true_count // 20))
        target = np.where(area > 0, np.maximum(np.round(target), handful), 0).astype(int)
        have = np.bincount(self.body, minlength=area.size + 1)[1:]
        short = np.maximum(target - have, 0)
        found = np.bincount(body, minlength=area.size + 1)[1:]
        if np.any(short > found):
            pixels, points, body, _ = self._on_objects(world, t, 4 * int(short.max()))
        # The first ``short[k - 1]`` samples that landed on each object k.
        rank = np.zeros(body.size, int)
        order = np.argsort(body, kind='stable')
        starts = np.searchsorted(body[order], body[order])
        rank[order] = np.arange(body.size) - starts
        take = rank < np.concatenate([[0], short])[body]
        return self._add(t, uv, pixels[take], points[take], body[take]) if take.any() else uv

    def _on_objects(self, world: _World, t: int, samples: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Random pixels, points and bodies on the objects' visible surfaces, from ``samples``
        pixels in each object's bounding box, and the objects' visible areas (K,) in px^2."""
        scene = self.scene
        corners = _corners(scene.object_rotation[t], scene.object_position[t],
                           scene.object_half_extents)
        uv, depth = scene.project(t, corners.reshape(-1, 3))
        uv, depth = uv.reshape(-1, 8, 2), depth.reshape(-1, 8)
        size = [WIDTH_PX - 1, HEIGHT_PX - 1]
        low, high = np.clip(uv.min(axis=1), 0, size), np.clip(uv.max(axis=1), 0, size)
        # Objects with a corner behind the camera are leaving the view: none are born on them.
        box = np.all(depth > _MIN_DEPTH, axis=1) & np.all(high > low, axis=1)
        where = np.repeat(np.flatnonzero(box), samples)
        pixels = low[where] + self.rng.random((where.size, 2)) * (high - low)[where]
        points, hit, body = world.cast(pixels)
        on = (body == where + 1) & np.isfinite(hit)
        area = np.zeros(box.size)
        area[box] = on.reshape(-1, samples).mean(axis=1) * np.prod((high - low)[box], axis=1)
        return pixels[on], points[on], body[on], area

    def _add(self, t: int, uv: np.ndarray, pixels: np.ndarray, points: np.ndarray,
             body: np.ndarray) -> np.ndarray:
        """Start features at ``pixels`` on ``points`` (world) of ``body``; the pixels of all."""
        rotation = np.concatenate([np.eye(3)[None], self.scene.object_rotation[t]])[body]
        centre = np.concatenate([np.zeros((1, 3)), self.scene.object_position[t]])[body]
        local = np.einsum('nji,nj->ni', rotation, points - centre)
        self.ids = np.concatenate([self.ids, self._take(body.size, t)])
        self.body = np.concatenate([self.body, body])
        self.local = np.concatenate([self.local, local])
        return np.concatenate([uv, pixels])

    def _pixels(self, count: int) -> np.ndarray:
        """Uniform random pixels (count, 2) in the image."""
        return self.rng.uniform(0.0, [WIDTH_PX - 1, HEIGHT_PX - 1], (count, 2))

    def _retire(self, ids: np.ndarray, t: int) -> None:
        """Ids of tracks lost in frame t: reusable from frame t + 3."""
        if ids.size == 0:
            return
        self.pool = np.concatenate([self.pool, ids])
        self.died = np.concatenate([self.died, np.full(ids.size, t, np.int64)])

    def _take(self, count: int, t: int) -> np.ndarray:
        """``count`` ids for new tracks: fresh ones, and sometimes one dead for >= 3 frames."""
        if count == 0:
            return np.empty(0, np.int64)
        ready = np.flatnonzero(self.died <= t - 3)
        reuse = self.rng.choice(ready, min(int(self.rng.binomial(count, _REUSE)), ready.size),
                                replace=False)
        taken = self.pool[reuse]
        if reuse.size:
            keep = np.ones(self.pool.size, bool)
            keep[reuse] = False
            self.pool, self.died = self.pool[keep], self.died[keep]
        fresh = np.arange(self.next_id, self.next_id + count - reuse.size, dtype=np.int64)
        self.next_id += fresh.size
        return self.rng.permutation(np.concatenate([taken, fresh]))


def robot_stream(
    num_features: int = 300,
    frames: int = 300,
    seed: int = 0,
    noise: float = 0.5,
    outlier_share: float = 0.1,
    objects: Sequence[str] = ('car', 'person', 'car'),
    death_rate: float = 0.02,
    outlier_step: float = 3.0,
    object_density: float = 4.0,
    start_ns: int = 1_000_000_000,
) -> Iterator[StreamFrame]:
    """Frames of a robot-like stream (see the module docstring); the scene is
    :func:`robot_scene` ``(frames, seed, objects)``. Arguments are checked at the call.

    Parameters
    ----------
    num_features : int, features per frame (outlier tracks included); an object that comes
        into view may add a few for a frame
    frames : int, frames, 30 Hz apart
    seed : int, seed of the one random generator behind the scene, the features and the noise
    noise : float, px, standard deviation of the Gaussian tracking noise per axis
    outlier_share : float in [0, 1), share of each frame's features that are outlier tracks
        (random walks, truth -1)
    objects : 'car' or 'person' per moving object; object k (truth k) is ``objects[k - 1]``
    death_rate : float in [0, 1), probability per frame that a feature is lost at random
    outlier_step : float, px, standard deviation per axis of an outlier walk's step per frame
    object_density : float, features per px^2 on an object in view, relative to
        ``num_features`` spread over the whole image (objects carry more texture than roads and
        walls); an object in view gets at least a handful
    start_ns : int, ns, stamp of the first frame

    Returns
    -------
    iterator of StreamFrame, truth 0 for the static world, k for object k, -1 for an outlier
    track

    Raises
    ------
    InputError
        On an argument out of its bounds or an unknown object kind.
    """
    if num_features < 1:
        raise InputError(f'num_features must be >= 1, got {num_features}')
    if not 0.0 <= outlier_share < 1.0:
        raise InputError(f'outlier_share must be in [0, 1), got {outlier_share!r}')
    if not 0.0 <= death_rate < 1.0:
        raise InputError(f'death_rate must be in [0, 1), got {death_rate!r}')
    if min(noise, outlier_step, object_density) < 0:
        raise InputError(f'noise, outlier_step and object_density must be >= 0, got {noise!r}, '
                         f'{outlier_step!r}, {object_density!r}')
    _check_scene(frames, objects)
    rng = np.random.default_rng(seed)
    scene = _build_scene(rng, frames, tuple(objects))
    outliers = int(round(outlier_share * num_features))
    tracker = _Tracker(rng, scene, num_features - outliers, outliers, death_rate, outlier_step,
                       object_density)
    return _frames(tracker, frames, noise, start_ns)


def _frames(tracker: _Tracker, frames: int, noise: float, start_ns: int
            ) -> Iterator[StreamFrame]:
    """The stream's frames, generated one at a time."""
    for t in range(frames):
        ids, uv, truth = tracker.frame(t, noise)
        yield StreamFrame(start_ns + t * FRAME_NS, ids, uv, truth)

"""Synthetic feature streams with known motions: births, deaths, reused ids, shuffled order.

A tracker's view of rigid bodies under an affine (orthographic, zooming) camera. Body 0 is the
background; every other body is an object with a rigid motion of its own, which may start
moving mid-stream or stop (before it starts and after it stops it moves with the background, and
its ground truth says so). Objects are opaque boxes in front of the background: a background
feature that an object's silhouette covers is lost, and none is born there. Features die at
random and new ones are born on random bodies (where those bodies are now), new features
sometimes take ids that died a few frames before (as trackers reuse ids), and every frame
lists its features in a new order.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

FRAME_NS = 33_333_333  # 30 Hz


@dataclass(frozen=True)
class StreamFrame:
    """One frame as a tracker publishes it, with ground truth.

    Attributes
    ----------
    stamp_ns : int
    ids : (N,) int64, tracker ids, unique in the frame
    uv : (N, 2) float64, pixels
    truth : (N,) int64, motion of each feature in this frame (0 = background)
    """

    stamp_ns: int
    ids: np.ndarray
    uv: np.ndarray
    truth: np.ndarray


@dataclass(frozen=True)
class BodySpec:
    """An object: share of the features, and the frames between which it moves on its own."""

    share: float
    start: int = 0
    stop: int | None = None


def _rotation(rng: np.random.Generator, angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def synthetic_stream(
    num_features: int = 300,
    frames: int = 60,
    objects: Sequence[BodySpec] = (BodySpec(0.2), BodySpec(0.15)),
    death_rate: float = 0.02,
    noise: float = 0.5,
    seed: int = 0,
    start_ns: int = 1_000_000_000,
) -> Iterator[StreamFrame]:
    """Frames of a synthetic stream; the feature count stays ``num_features``.

    Parameters
    ----------
    num_features : int, features per frame
    frames : int
    objects : BodySpec per moving object; the background takes the remaining share
    death_rate : float, probability that a feature is lost in a frame (then replaced)
    noise : float, px, Gaussian tracking noise
    seed : int
    start_ns : int, stamp of the first frame; frames are 30 Hz apart
    """
    rng = np.random.default_rng(seed)
    shares = np.array([1.0 - sum(o.share for o in objects)] + [o.share for o in objects])
    if shares[0] <= 0:
        raise ValueError('objects must leave a positive share of features to the background')
    bodies = len(shares)
    # Each body's points live around its own centre (the background spans the image); the
    # centres sit apart so that objects are image regions, as a tracker sees them.
    centres = np.array([[320.0, 240.0, 0.0]] + [
        [120.0 + 400.0 * (k % 2), 120.0 + 240.0 * ((k // 2) % 2), 0.0] for k in range(bodies - 1)])
    extents = np.array([[300.0, 220.0, 100.0]] + [[60.0, 60.0, 60.0]] * (bodies - 1))
    turns = [_rotation(rng, 0.01)] + [_rotation(rng, 0.08) for _ in range(bodies - 1)]
    shifts = [rng.normal(0, 1.0, 3)] + [rng.normal(0, 6.0, 3) for _ in range(bodies - 1)]
    # Pose (R_k, t_k) of body k: a point at X0 in the body's first pose is at R_k X0 + t_k.
    rots = [np.eye(3) for _ in range(bodies)]
    trans = [np.zeros(3) for _ in range(bodies)]

    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)

    def occluded(body: np.ndarray, world: np.ndarray) -> np.ndarray:
        """Background features inside an object's silhouette (the hull of its box's corners)."""
        hidden = np.zeros(body.size, dtype=bool)
        behind = body == 0
        for k in range(1, bodies):
            box = (corners * extents[k]) @ rots[k].T + centres[k] + trans[k]
            hidden[behind] |= Delaunay(box[:, :2]).find_simplex(world[behind, :2]) >= 0
        return hidden

    def new_points(count: int) -> tuple[np.ndarray, np.ndarray]:
        """Bodies and first-pose coordinates of ``count`` features born now on the bodies as
        they are now, where they show."""
        body = rng.choice(bodies, size=count, p=shares / shares.sum())
        origin = centres[body] + rng.uniform(-1.0, 1.0, (count, 3)) * extents[body]
        for _ in range(100):
            hidden = occluded(body, positions(body, origin))
            if not hidden.any():
                break
            redraw = rng.uniform(-1.0, 1.0, (int(hidden.sum()), 3))
            origin[hidden] = centres[0] + redraw * extents[0]
        return body, origin

    def positions(body: np.ndarray, origin: np.ndarray) -> np.ndarray:
        world = np.empty_like(origin)
        for k in range(bodies):
            on = body == k
            world[on] = (origin[on] - centres[k]) @ rots[k].T + centres[k] + trans[k]
        return world

    def step(k: int, source: int) -> None:
        """Move body k by body ``source``'s step: a turn about ``source``'s current centre,
        then a shift, so that a body moving with the background moves exactly as it does."""
        centre = centres[source] + trans[source]
        turn, shift = turns[source], shifts[source]
        rots[k] = turn @ rots[k]
        trans[k] = turn @ (trans[k] + centres[k] - centre) + centre + shift - centres[k]

    body, origin = new_points(num_features)
    ids = np.arange(num_features, dtype=np.int64)
    next_id = num_features
    dead: list[tuple[int, int]] = []  # (frame it died, id)
    for t in range(frames):
        moving = np.array([True] + [o.start <= t and (o.stop is None or t < o.stop)
                                    for o in objects])
        if t:
            # Every body's move is computed from the current poses before any is changed.
            for k in reversed(range(bodies)):
                step(k, k if moving[k] else 0)
            lost = (rng.random(ids.size) < death_rate) | occluded(body, positions(body, origin))
            dead += [(t, int(i)) for i in ids[lost]]
            reusable = [i for died, i in dead if t - died >= 3]
            fresh_ids = []
            for _ in range(int(lost.sum())):
                if reusable and rng.random() < 0.5:
                    reuse = reusable.pop(int(rng.integers(len(reusable))))
                    dead = [(d, i) for d, i in dead if i != reuse]
                    fresh_ids.append(reuse)
                else:
                    fresh_ids.append(next_id)
                    next_id += 1
            new_body, new_origin = new_points(int(lost.sum()))
            ids[lost], body[lost], origin[lost] = fresh_ids, new_body, new_origin
        world = positions(body, origin)
        uv = world[:, :2] + rng.normal(0, noise, (ids.size, 2))
        truth = np.where(moving[body], body, 0)
        order = rng.permutation(ids.size)
        yield StreamFrame(start_ns + t * FRAME_NS, ids[order].copy(), uv[order],
                          truth[order].astype(np.int64))

"""Synthetic feature streams with known motions: births, deaths, reused ids, shuffled order.

A tracker's view of rigid bodies under an affine (orthographic, zooming) camera. Body 0 is the
background; every other body is an object with a rigid motion of its own, which may start
moving mid-stream, stop, or pause (before it starts, after it stops and while it pauses it
moves with the background, and its ground truth says so). Objects are opaque boxes in front of
the background: a background feature that an object's silhouette covers is lost, and none is
born there. Features die at
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
    """An object: share of the features, the frames between which it moves on its own, and
    frames ``[pause[0], pause[1])`` in between when it moves with the background."""

    share: float
    start: int = 0
    stop: int | None = None
    pause: tuple[int, int] | None = None

    def moving(self, t: int) -> bool:
        """Whether the object moves on its own in frame ``t``."""
        paused = self.pause is not None and self.pause[0] <= t < self.pause[1]
        return self.start <= t and (self.stop is None or t < self.stop) and not paused


def _rotation(rng: np.random.Generator, angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


# The 8 corners of a unit box, scaled by a body's extents for its silhouette.
_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


class _Scene:
    """The bodies, their steps and their current poses; where points are and what hides them.

    Body 0 is the background and spans the image; objects live around centres set apart, so
    that they are image regions, as a tracker sees them. The pose ``(R_k, t_k)`` of body k puts
    a point at ``X0`` in the body's first pose at ``R_k X0 + t_k``.
    """

    def __init__(self, rng: np.random.Generator, shares: np.ndarray) -> None:
        self.rng = rng
        self.shares = shares
        self.bodies = bodies = len(shares)
        self.centres = np.array([[320.0, 240.0, 0.0]] + [
            [120.0 + 400.0 * (k % 2), 120.0 + 240.0 * ((k // 2) % 2), 0.0]
            for k in range(bodies - 1)])
        self.extents = np.array([[300.0, 220.0, 100.0]] + [[60.0, 60.0, 60.0]] * (bodies - 1))
        self.turns = [_rotation(rng, 0.01)] + [_rotation(rng, 0.08) for _ in range(bodies - 1)]
        self.shifts = [rng.normal(0, 1.0, 3)] + [rng.normal(0, 6.0, 3) for _ in range(bodies - 1)]
        self.rots = [np.eye(3) for _ in range(bodies)]
        self.trans = [np.zeros(3) for _ in range(bodies)]

    def positions(self, body: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Where points at first-pose coordinates ``origin`` (N, 3) of bodies ``body`` are now."""
        world = np.empty_like(origin)
        for k in range(self.bodies):
            on = body == k
            world[on] = ((origin[on] - self.centres[k]) @ self.rots[k].T + self.centres[k]
                         + self.trans[k])
        return world

    def occluded(self, body: np.ndarray, world: np.ndarray) -> np.ndarray:
        """Background features inside an object's silhouette (the hull of its box's corners)."""
        hidden = np.zeros(body.size, dtype=bool)
        behind = body == 0
        for k in range(1, self.bodies):
            box = (_CORNERS * self.extents[k]) @ self.rots[k].T + self.centres[k] + self.trans[k]
            hidden[behind] |= Delaunay(box[:, :2]).find_simplex(world[behind, :2]) >= 0
        return hidden

    def new_points(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Bodies and first-pose coordinates of ``count`` features born now on the bodies as
        they are now, where they show."""
        body = self.rng.choice(self.bodies, size=count, p=self.shares / self.shares.sum())
        origin = self.centres[body] + self.rng.uniform(-1.0, 1.0, (count, 3)) * self.extents[body]
        for _ in range(100):
            hidden = self.occluded(body, self.positions(body, origin))
            if not hidden.any():
                break
            redraw = self.rng.uniform(-1.0, 1.0, (int(hidden.sum()), 3))
            origin[hidden] = self.centres[0] + redraw * self.extents[0]
        return body, origin

    def move(self, moving: np.ndarray) -> None:
        """One frame's step: each body by its own step if ``moving``, else by the background's.

        Every body's move is computed from the current poses before any is changed.
        """
        for k in reversed(range(self.bodies)):
            self._step(k, k if moving[k] else 0)

    def _step(self, k: int, source: int) -> None:
        """Move body k by body ``source``'s step: a turn about ``source``'s current centre,
        then a shift, so that a body moving with the background moves exactly as it does."""
        centre = self.centres[source] + self.trans[source]
        turn, shift = self.turns[source], self.shifts[source]
        self.rots[k] = turn @ self.rots[k]
        self.trans[k] = (turn @ (self.trans[k] + self.centres[k] - centre) + centre + shift
                         - self.centres[k])


class _Features:
    """The tracked features: ids, the body each is on, and its first-pose coordinates."""

    def __init__(self, scene: _Scene, count: int) -> None:
        self.scene = scene
        self.body, self.origin = scene.new_points(count)
        self.ids = np.arange(count, dtype=np.int64)
        self.next_id = count
        self.dead: list[tuple[int, int]] = []  # (frame it died, id)

    def replace_lost(self, t: int, death_rate: float) -> None:
        """Features lost in frame ``t`` (at random, or hidden by an object) are replaced by new
        ones, born where bodies show; half of the new ones (when there are) take an id that
        died at least 3 frames before."""
        scene, rng = self.scene, self.scene.rng
        lost = (rng.random(self.ids.size) < death_rate) | scene.occluded(
            self.body, scene.positions(self.body, self.origin))
        self.dead += [(t, int(i)) for i in self.ids[lost]]
        fresh_ids = self._new_ids(t, int(lost.sum()))
        new_body, new_origin = scene.new_points(int(lost.sum()))
        self.ids[lost], self.body[lost], self.origin[lost] = fresh_ids, new_body, new_origin

    def _new_ids(self, t: int, count: int) -> list[int]:
        rng = self.scene.rng
        reusable = [i for died, i in self.dead if t - died >= 3]
        fresh_ids = []
        for _ in range(count):
            if reusable and rng.random() < 0.5:
                reuse = reusable.pop(int(rng.integers(len(reusable))))
                self.dead = [(d, i) for d, i in self.dead if i != reuse]
                fresh_ids.append(reuse)
            else:
                fresh_ids.append(self.next_id)
                self.next_id += 1
        return fresh_ids

    def observe(self, stamp_ns: int, moving: np.ndarray, noise: float) -> StreamFrame:
        """The frame a tracker publishes now: noisy pixels, in a new order, with the truth."""
        rng = self.scene.rng
        world = self.scene.positions(self.body, self.origin)
        uv = world[:, :2] + rng.normal(0, noise, (self.ids.size, 2))
        truth = np.where(moving[self.body], self.body, 0)
        order = rng.permutation(self.ids.size)
        return StreamFrame(stamp_ns, self.ids[order].copy(), uv[order],
                           truth[order].astype(np.int64))


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
    scene = _Scene(rng, shares)
    features = _Features(scene, num_features)
    for t in range(frames):
        moving = np.array([True] + [o.moving(t) for o in objects])
        if t:
            scene.move(moving)
            features.replace_lost(t, death_rate)
        yield features.observe(start_ns + t * FRAME_NS, moving, noise)

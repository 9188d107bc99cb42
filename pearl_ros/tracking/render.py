"""Synthetic image sequences of known motion, with the ground truth a tracker test needs.

A scene is a textured background seen by a camera that pans, rolls and zooms (one affine map of
the background's texture per frame), and textured rectangular objects in front of it, each moved
by its own affine map per frame; objects enter and leave the view. Every surface ``s`` (0 = the
background, 1.. = the objects, later ones in front) has, for every frame ``t``, the 3 x 3 map
``transforms[t, s]`` from its texture coordinates to image pixels. So a pixel of frame ``t0`` that
lies on surface ``s`` (``labels[t0]``) is, in frame ``t``, at ``transforms[t, s] @
inv(transforms[t0, s]) @ [u, v, 1]``, and it is seen there if ``labels[t]`` says ``s`` at that
place: :meth:`Scene.follow`.

Textures are random blocks of several sizes (strong corners for Shi-Tomasi), lightly blurred so
that Lucas-Kanade can locate them to a fraction of a pixel. Pixel centres are at integer
coordinates, as in OpenCV. Everything is drawn from one seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pearl_ros.core.errors import InputError


@dataclass(frozen=True, eq=False)
class Scene:
    """A rendered sequence and its ground truth.

    Attributes
    ----------
    frames : (T, H, W) uint8
        The grey images.
    labels : (T, H, W) int8
        The surface seen at each pixel: 0 background, ``i`` the ``i``-th object.
    transforms : (T, S, 3, 3) float64
        Texture coordinates of surface ``s`` -> pixels of frame ``t``.
    """

    frames: np.ndarray
    labels: np.ndarray
    transforms: np.ndarray

    def surface_at(self, frame: int, uv: np.ndarray) -> np.ndarray:
        """The surface ``(N,)`` int seen at pixels ``uv`` ``(N, 2)`` of ``frame`` (nearest pixel;
        -1 outside the image)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        height, width = self.labels.shape[1:]
        cols, rows = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
        out = np.full(len(uv), -1, dtype=np.int64)
        out[inside] = self.labels[frame, rows[inside], cols[inside]]
        return out

    def follow(self, frame: int, uv: np.ndarray, surface: np.ndarray,
               to_frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Where points of ``frame`` on ``surface`` are in ``to_frame``, and whether seen there.

        Parameters
        ----------
        frame, to_frame : int
            Frame indices.
        uv : (N, 2) float64
            Pixels of ``frame``.
        surface : (N,) int
            The surface each point lies on (for example from :meth:`surface_at`).

        Returns
        -------
        positions : (N, 2) float64
            Pixels in ``to_frame``.
        visible : (N,) bool
            Inside the image and not hidden by a surface in front.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        surface = np.asarray(surface, dtype=np.int64)
        moves = self.transforms[to_frame, surface] @ np.linalg.inv(self.transforms[frame, surface])
        points = np.einsum('nij,nj->ni', moves, np.column_stack([uv, np.ones(len(uv))]))
        positions = points[:, :2] / points[:, 2:]
        visible = self.surface_at(to_frame, positions) == surface
        return positions, visible


def texture(rng: np.random.Generator, height: int, width: int,
            blocks: tuple[int, ...] = (4, 8, 16), blur: float = 0.8) -> np.ndarray:
    """A random texture ``(height, width)`` float32 in [0, 255]: sums of random blocks."""
    out: np.ndarray = np.zeros((height, width), np.float32)
    for side in blocks:
        small = rng.uniform(-1.0, 1.0, (height // side + 1, width // side + 1))
        out += np.repeat(np.repeat(small, side, 0), side, 1)[:height, :width].astype(np.float32)
    out = cv2.GaussianBlur(out, (0, 0), blur) if blur > 0 else out
    out -= out.min()
    return np.asarray(out * (255.0 / max(float(out.max()), 1e-9)), dtype=np.float32)


def _affine(scale: float, angle: float, shift: tuple[float, float],
            centre: tuple[float, float]) -> np.ndarray:
    """3 x 3: rotate by ``angle`` (rad) and scale about texture point ``centre``, then put that
    point at pixel ``shift``."""
    c, s = np.cos(angle) * scale, np.sin(angle) * scale
    to_origin = np.array([[1.0, 0, -centre[0]], [0, 1, -centre[1]], [0, 0, 1]])
    return np.array([[c, -s, shift[0]], [s, c, shift[1]], [0, 0, 1]]) @ to_origin


def _background_path(rng: np.random.Generator, count: int, size: tuple[int, int],
                     margin: int, pan: float, zoom: float) -> np.ndarray:
    """(T, 3, 3): the camera pans up to ``pan`` px per frame, zooms by ``zoom`` per frame and
    rolls slightly; texture centre at the image centre at frame 0."""
    height, width = size
    velocity = rng.uniform(-pan, pan, 2)
    rate = rng.uniform(-zoom, zoom)
    roll = rng.uniform(-0.003, 0.003)
    centre = (width / 2 + margin, height / 2 + margin)
    return np.stack([_affine(1.0 + rate * t, roll * t,
                             (width / 2 + velocity[0] * t, height / 2 + velocity[1] * t), centre)
                     for t in range(count)])


def _object_path(rng: np.random.Generator, count: int, size: tuple[int, int],
                 extent: tuple[int, int], crossing: bool) -> np.ndarray:
    """(T, 3, 3) of one object: a crossing object enters at one side and leaves at the other over
    the clip; another starts in view and drifts with its own rotation and scaling."""
    height, width = size
    h, w = extent
    centre = (w / 2, h / 2)
    if crossing:
        # Out of view at both ends, whatever its rotation (growth 1 + 0.004 t < 1.2 to t = 50).
        reach = width / 2 + 0.6 * np.hypot(w, h) + 2
        side = rng.choice([-1.0, 1.0])
        start = np.array([width / 2 - side * reach, rng.uniform(0.3, 0.7) * height])
        end = np.array([width / 2 + side * reach, rng.uniform(0.3, 0.7) * height])
        velocity = (end - start) / max(count - 1, 1)
    else:
        start = np.array([rng.uniform(0.25, 0.75) * width, rng.uniform(0.3, 0.7) * height])
        velocity = rng.uniform(-4.0, 4.0, 2)
    spin = rng.uniform(-0.01, 0.01)
    grow = rng.uniform(-0.004, 0.004)
    return np.stack([_affine(1.0 + grow * t, spin * t, tuple(start + velocity * t), centre)
                     for t in range(count)])


def render_scene(seed: int | np.random.Generator | None = 0, *, frames: int = 40,
                 size: tuple[int, int] = (480, 640), objects: int = 2, crossing: int = 1,
                 pan: float = 4.0, zoom: float = 0.004, noise: float = 1.0) -> Scene:
    """Render a clip of a moving camera and moving objects.

    Parameters
    ----------
    seed : int, Generator or None
        The one source of randomness.
    frames : int
        Number of frames T (>= 2).
    size : (int, int)
        Image height and width, px.
    objects : int
        Number of objects (>= 0); the last ``crossing`` of them enter at one side and leave at
        the other during the clip, the others start in view and move on their own.
    pan : float
        Most camera pan speed along each axis, px per frame.
    zoom : float
        Most zoom rate, relative scale change per frame.
    noise : float
        Standard deviation of the grey-level noise added to each frame.

    Returns
    -------
    Scene
    """
    if frames < 2 or objects < 0 or not 0 <= crossing <= objects:
        raise InputError(f'need frames >= 2 and 0 <= crossing <= objects, got frames={frames}, '
                         f'objects={objects}, crossing={crossing}')
    rng = np.random.default_rng(seed)
    height, width = size
    margin = int(np.ceil(pan * frames + zoom * frames * max(size))) + 8
    backdrop = texture(rng, height + 2 * margin, width + 2 * margin)
    paths = [_background_path(rng, frames, size, margin, pan, zoom)]
    surfaces = [backdrop]
    for index in range(objects):
        extent = (int(rng.integers(100, 160)), int(rng.integers(120, 200)))
        surfaces.append(texture(rng, *extent, blocks=(3, 6, 12)))
        paths.append(_object_path(rng, frames, size, extent, index >= objects - crossing))
    transforms = np.stack(paths, axis=1)
    images = np.empty((frames, height, width), np.uint8)
    labels = np.zeros((frames, height, width), np.int8)
    for t in range(frames):
        image: np.ndarray = np.zeros((height, width), np.float32)
        for s, surface in enumerate(surfaces):
            matrix = transforms[t, s, :2]
            drawn = cv2.warpAffine(surface, matrix, (width, height), flags=cv2.INTER_LINEAR)
            cover = cv2.warpAffine(np.ones_like(surface), matrix, (width, height),
                                   flags=cv2.INTER_LINEAR)
            image = image * (1.0 - cover) + drawn
            labels[t][cover > 0.5] = s
        image += rng.normal(0.0, noise, image.shape).astype(np.float32)
        images[t] = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return Scene(images, labels, transforms)

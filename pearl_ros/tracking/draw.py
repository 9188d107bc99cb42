"""Labels drawn on images, ROS-free (OpenCV): what ``image_labels``, ``pearl_video --annotated``
and ``pearl_render`` show.

:class:`Overlay` draws one frame's features as dots in their motion's colour, with a short trail
of their recent positions and the number of motions in the top-left corner. It keeps state
between frames: the colour given to each motion number, and each feature id's recent positions.
:func:`to_bgr` turns an image of any encoding :mod:`.image` reads into the bgr8 array it draws on.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

from pearl_ros.core.errors import InputError
from pearl_ros.tracking.image import ENCODINGS, to_mono8

# Motion colours, bgr: saturated and far from grey and from each other (Tableau 10 and two more).
PALETTE: tuple[tuple[int, int, int], ...] = (
    (180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
    (75, 86, 140), (194, 119, 227), (34, 189, 188), (207, 190, 23), (0, 255, 255),
    (255, 0, 255), (0, 255, 0),
)
GREY: tuple[int, int, int] = (128, 128, 128)  # outliers and undecided features (label < 0)
TEXT_COLOUR: tuple[int, int, int] = (255, 255, 255)
TEXT_BACKGROUND: tuple[int, int, int] = (0, 0, 0)

_TO_BGR = {'mono8': cv2.COLOR_GRAY2BGR, 'rgb8': cv2.COLOR_RGB2BGR,
           'bgra8': cv2.COLOR_BGRA2BGR, 'rgba8': cv2.COLOR_RGBA2BGR}
_FAR = 1e6  # px; positions are clipped to this before becoming OpenCV's int coordinates


def to_bgr(array: np.ndarray, encoding: str) -> np.ndarray:
    """A new ``(H, W, 3)`` uint8 bgr image from an array of :func:`.image.image_to_array`.

    mono16 is scaled as :func:`.image.to_mono8` does by default (the top 8 bits); alpha is
    dropped. Raises :class:`InputError` for an unknown encoding or an array of the wrong shape.
    """
    if encoding not in ENCODINGS:
        raise InputError(f'unsupported image encoding {encoding!r} '
                         f'(supported: {", ".join(ENCODINGS)})')
    channels, _ = ENCODINGS[encoding]
    array = np.asarray(array)
    if channels == 1 and array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim != (2 if channels == 1 else 3) or (channels > 1 and array.shape[2] != channels):
        shape = '(H, W)' if channels == 1 else f'(H, W, {channels})'
        raise InputError(f'a {encoding} image must be of shape {shape}, got {array.shape}')
    if encoding == 'bgr8':
        return np.array(array, dtype=np.uint8, copy=True)
    if encoding == 'mono16':
        return np.asarray(cv2.cvtColor(to_mono8(array, encoding), cv2.COLOR_GRAY2BGR))
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(array, dtype=np.uint8),
                                   _TO_BGR[encoding]))


def motions_text(count: int) -> str:
    """``'1 motion'``, ``'3 motions'``."""
    return f'{count} motion' if count == 1 else f'{count} motions'


class Overlay:
    """Draws features coloured by motion on a stream of frames (module docstring).

    A motion keeps its colour for as long as it keeps its number. A new motion number takes a
    palette colour no other number holds; when all are held, the colour of the number seen
    longest ago (and not in this frame) passes to it. Motions in one frame have distinct
    colours up to ``len(PALETTE)`` of them.

    Parameters
    ----------
    trail : int
        Frames of a feature's trail: its positions in up to this many recent frames (the
        current one included) in which its id was seen without a gap, joined by a polyline.
        1 draws no trail.
    radius : int
        Dot radius, pixels.

    Attributes
    ----------
    legend_box : tuple of int or None
        ``(x0, y0, x1, y1)`` pixels (inclusive) the motion count covered in the last frame.
    """

    def __init__(self, trail: int = 10, radius: int = 3) -> None:
        if not 1 <= int(trail) <= 1000:
            raise InputError(f'trail must be within 1..1000 frames, got {trail!r}')
        if not 1 <= int(radius) <= 100:
            raise InputError(f'radius must be within 1..100 pixels, got {radius!r}')
        self.trail, self.radius = int(trail), int(radius)
        self._slot_of: dict[int, int] = {}  # motion number -> palette index
        self._last_seen: dict[int, int] = {}  # motion number -> frame count when last seen
        self._trails: dict[int, deque[tuple[float, float]]] = {}  # id -> recent positions
        self._frames = 0
        self.legend_box: tuple[int, int, int, int] | None = None

    def colour(self, label: int) -> tuple[int, int, int]:
        """The bgr colour of motion ``label`` now (:data:`GREY` for a negative or unseen one)."""
        slot = self._slot_of.get(int(label)) if label >= 0 else None
        return GREY if slot is None else PALETTE[slot]

    def reset(self) -> None:
        """Forget colours and trails (a new clip)."""
        self._slot_of, self._last_seen, self._trails = {}, {}, {}
        self._frames = 0
        self.legend_box = None

    def draw(self, image_bgr: np.ndarray, ids: np.ndarray, uv: np.ndarray,
             labels: np.ndarray) -> np.ndarray:
        """One frame with its features drawn; ``image_bgr`` is not modified.

        Parameters
        ----------
        image_bgr : (H, W, 3) uint8
            The frame, bgr.
        ids : (N,) int
            Feature ids (a trail follows an id from frame to frame).
        uv : (N, 2) float
            Pixels; a feature with a non-finite coordinate is not drawn.
        labels : (N,) int
            Motion numbers; -1 (or any negative) for outliers and undecided features.

        Returns
        -------
        (H, W, 3) uint8
            A copy of the frame with trails, then grey dots, then motion dots (on top), then
            the motion count.
        """
        image = _checked_image(image_bgr)
        ids, uv, labels = _checked_features(ids, uv, labels)
        self._frames += 1
        present = np.unique(labels[labels >= 0])
        self._assign_colours([int(m) for m in present])
        finite = np.isfinite(uv).all(axis=1)
        self._update_trails(ids[finite], uv[finite])
        out = image.copy()
        shown = np.flatnonzero(finite)
        colours = {int(m): self.colour(int(m)) for m in np.unique(labels[shown])}
        self._draw_trails(out, ids[shown], labels[shown], colours)
        centres = np.round(np.clip(uv[shown], -_FAR, _FAR)).astype(np.int64).tolist()
        grey_first = np.argsort(labels[shown] >= 0, kind='stable')  # motions drawn on top
        for k, label in zip(grey_first.tolist(), labels[shown][grey_first].tolist(),
                            strict=True):
            cv2.circle(out, tuple(centres[k]), self.radius, colours[label], -1, cv2.LINE_8)
        self._draw_count(out, present.size)
        return out

    def _draw_trails(self, out: np.ndarray, ids: np.ndarray, labels: np.ndarray,
                     colours: dict[int, tuple[int, int, int]]) -> None:
        """Each feature's trail as a polyline in its motion's colour, one call per colour."""
        trails = [self._trails[key] for key in ids.tolist()]
        lengths = np.array([len(trail) for trail in trails], dtype=np.int64)
        long = lengths > 1
        if not long.any():
            return
        points = np.array([p for trail, keep in zip(trails, long, strict=True) if keep
                           for p in trail], dtype=np.float64)
        points = np.round(np.clip(points, -_FAR, _FAR)).astype(np.int32)
        pieces = np.split(points, np.cumsum(lengths[long])[:-1])
        for label in np.unique(labels[long]).tolist():
            lines = [piece.reshape(-1, 1, 2) for piece, mine
                     in zip(pieces, labels[long] == label, strict=True) if mine]
            cv2.polylines(out, lines, False, colours[label], 1, cv2.LINE_8)

    def _assign_colours(self, present: list[int]) -> None:
        """Give each motion number of this frame a palette slot (class docstring)."""
        for motion in present:
            self._last_seen[motion] = self._frames
        for motion in present:
            if motion in self._slot_of:
                continue
            held = set(self._slot_of.values())
            free = [slot for slot in range(len(PALETTE)) if slot not in held]
            if free:
                self._slot_of[motion] = free[0]
                continue
            absent = [m for m in self._slot_of if self._last_seen[m] < self._frames]
            if absent:  # the colour of the number seen longest ago passes on
                oldest = min(absent, key=lambda m: self._last_seen[m])
                self._slot_of[motion] = self._slot_of.pop(oldest)
                del self._last_seen[oldest]
            else:  # more motions than colours in one frame: some share
                self._slot_of[motion] = motion % len(PALETTE)

    def _update_trails(self, ids: np.ndarray, uv: np.ndarray) -> None:
        """Keep the trails of this frame's ids only, each with its new position appended."""
        trails: dict[int, deque[tuple[float, float]]] = {}
        for key, (u, v) in zip(ids.tolist(), uv.tolist(), strict=True):
            trail = self._trails.get(key, deque(maxlen=self.trail))
            trail.append((u, v))
            trails[key] = trail
        self._trails = trails

    def _draw_count(self, out: np.ndarray, count: int) -> None:
        """The motion count on a dark box in the top-left corner, scaled to the image."""
        text = motions_text(count)
        scale = max(0.4, out.shape[0] / 800)
        thickness = max(1, round(scale * 1.5))
        (width, height), baseline = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale,
                                                    thickness)
        pad = max(2, round(4 * scale))
        x1, y1 = 2 * pad + width - 1, 2 * pad + height + baseline - 1
        cv2.rectangle(out, (0, 0), (x1, y1), TEXT_BACKGROUND, -1)
        cv2.putText(out, text, (pad, pad + height), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    TEXT_COLOUR, thickness, cv2.LINE_AA)
        self.legend_box = (0, 0, min(x1, out.shape[1] - 1), min(y1, out.shape[0] - 1))


def _checked_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f'image must be (H, W, 3) uint8 bgr, got {image.shape} {image.dtype}')
    return image


def _checked_features(ids: np.ndarray, uv: np.ndarray, labels: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ids = np.asarray(ids).reshape(-1).astype(np.int64)
    labels = np.asarray(labels).reshape(-1).astype(np.int64)
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f'uv must be (N, 2), got {uv.shape}')
    if not ids.size == labels.size == len(uv):
        raise InputError(f'ids ({ids.size}), uv ({len(uv)}) and labels ({labels.size}) must '
                         'have one entry per feature')
    return ids, uv, labels

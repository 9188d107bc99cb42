"""The per-message pipeline that ``pearl_node``, ``pearl_replay`` and ``pearl_play`` share.

One feature message in, its two outputs (or the one-line reason there are none) out:

1. decode the ``sensor_msgs/msg/PointCloud`` or ``PointCloud2`` (:mod:`pearl_ros.bagio.decode`,
   with the checks :func:`pearl_ros.bagio.reader.read_features` adds); normalised coordinates
   (a message without pixels) become the pixels of the intrinsics, or of a nominal camera;
2. above ``max_features``, keep the subsample chosen by a hash of the ids
   (:func:`pearl_ros.bagio.encode.subsample_mask`), the rest labelled -1;
3. segment with :class:`~pearl_ros.online.segmenter.OnlineSegmenter`;
4. pick the background motion (``background_motion``, or the largest) for ``static_features``;
5. encode ``motion_labels`` and ``static_features`` with the message classes given.

ROS-free: the message classes come in a :class:`~pearl_ros.bagio.encode.MessageTypes`, rclpy's
for the node, a rosbags typestore's for the replay; decoding reads only what both share.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from pearl_ros.bagio import cdr, decode, encode
from pearl_ros.bagio.reader import TYPESTORE, read_features
from pearl_ros.core.errors import InputError, one_line
from pearl_ros.online.segmenter import FrameResult, OnlineSegmenter
from pearl_ros.pipeline import poses
from pearl_ros.pipeline.poses import PoseBuffer
from pearl_ros.pipeline.settings import Settings

if TYPE_CHECKING:
    from pearl_ros.tracking.tracker import CameraModel

# The focal length (px) of the camera whose pixels normalised coordinates become when no
# intrinsics are known. The segmenter's scales are in pixels (min_noise 0.05 px, set on images
# 640 and 1242 px wide: Hopkins155, KITTI); taken as they are, normalised coordinates put the
# floor at about 25 px of such a camera (a Hopkins155 sample: 4.8% -> 36% misclassified).
NOMINAL_FOCAL = 500.0
# The largest normalised coordinate: 20 is a ray 87 degrees off the optical axis. A message
# whose coordinates named normalised reach beyond it carries pixels (a PointCloud2 whose x, y
# a tracker filled with pixels), and they are taken as such.
NORMALISED_LIMIT = 20.0

# Kinds of skipped message, each with words of the reasons that belong to it (first match).
# A front end warns once per kind and counts the rest.
_KINDS = (
    ('deserialise', (cdr.UNREADABLE,)),
    ('empty', ('empty cloud',)),
    ('stamp', ('stamp',)),
    ('duplicate_ids', ('repeats feature id', 'duplicate ids')),
    ('non_finite', ('non-finite',)),
    ('ids', ('ids above', 'must be integers', 'must be numbers', 'feature ids must be in')),
    ('layout', ('channel', 'field', 'layout', 'row_step', 'data has', 'datatype')),
)


def skip_kind(reason: str) -> str:
    """The kind of a skip ``reason`` (``'layout'``, ``'non_finite'``...; ``'other'``)."""
    lowered = reason.lower()
    for kind, words in _KINDS:
        if any(word in lowered for word in words):
            return kind
    return 'other'


@dataclass(frozen=True)
class Skipped:
    """A message that got no output, and why.

    Attributes
    ----------
    kind : str
        :func:`skip_kind` of the reason.
    reason : str
        One line, the same in every front end.
    malformed : bool
        The message could not be read (else it was read but had nothing to segment: an empty
        cloud, a repeated stamp).
    """

    kind: str
    reason: str
    malformed: bool

    @classmethod
    def because(cls, reason: str | BaseException, malformed: bool = True) -> Skipped:
        """The skip for ``reason`` (an error or its text), its kind told by its words."""
        text = one_line(reason, None)
        return cls(skip_kind(text), text, malformed)

    @property
    def line(self) -> str:
        """``'skipped (kind): reason'``: what every front end says, after its own context."""
        return f'skipped ({self.kind}): {self.reason}'


class SkipWarnings:
    """What a front end says about skipped messages: the first of each kind in full, then how
    many there were of each kind.

    Parameters
    ----------
    topic : str
        The feature topic, named in each warning.
    """

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.kinds: Counter[str] = Counter()

    def warn(self, index: int, skip: Skipped) -> str | None:
        """Count ``skip``; its warning line, or None when one of its kind was already given.

        ``index`` is the message's position on the topic (-1: not a feature message).
        """
        self.kinds[skip.kind] += 1
        if self.kinds[skip.kind] > 1:
            return None
        where = f'message {index} on {self.topic} ' if index >= 0 else ''
        return f'warning: {where}{skip.line}'

    def summary(self) -> str | None:
        """The counts by kind, when some skips were not warned about one by one."""
        total = sum(self.kinds.values())
        if total <= len(self.kinds):
            return None
        kinds = ', '.join(f'{kind} {count}' for kind, count in sorted(self.kinds.items()))
        return f'warning: {total} messages skipped in all ({kinds})'


@dataclass(frozen=True)
class Labelled:
    """One message's labels and the two output messages.

    Attributes
    ----------
    stamp_ns, ids, uv
        The message's stamp and features, as in :class:`~pearl_ros.bagio.reader.FeatureFrame`.
    image_uv : (N, 2) float64 or None
        Where the features lie in the image, and the ``u``, ``v`` of ``labels_msg``: ``uv``,
        or normalised coordinates projected with the intrinsics (a pinhole camera's: the lens's
        distortion is not put back); None for normalised coordinates while no intrinsics are
        known (``labels_msg`` then carries them as they came).
    labels : (N,) int64
        Motion number per input feature in input order, -1 = outlier or undecided.
    segmented : (N,) bool
        Fed to the segmenter (all of them unless more than ``max_features``).
    static : (N,) bool
        On ``static_features``: the background motion's features.
    result : FrameResult
        The segmenter's answer for the segmented features.
    labels_msg, static_msg
        ``motion_labels`` (PointCloud2) and ``static_features`` (the input's type).
    """

    stamp_ns: int
    ids: np.ndarray
    uv: np.ndarray
    labels: np.ndarray
    segmented: np.ndarray
    static: np.ndarray
    result: FrameResult
    labels_msg: Any
    static_msg: Any
    image_uv: np.ndarray | None = None

    @property
    def capped(self) -> bool:
        """More than ``max_features``: only a subsample was segmented."""
        return not bool(self.segmented.all())


def _same_lens(a: CameraModel | None, b: CameraModel | None) -> bool:
    if a is None or b is None:
        return a is b
    return (a.model == b.model and np.array_equal(a.K, b.K)
            and np.array_equal(a.distortion, b.distortion))


class MessagePipeline:
    """Feature messages in recording order -> :class:`Labelled` or :class:`Skipped`.

    Parameters
    ----------
    settings : Settings, optional
        Default: every parameter at its default.
    types : MessageTypes, optional
        Classes of the output messages; default: those of rosbags'
        :data:`~pearl_ros.bagio.reader.TYPESTORE`. The node and the replay pass
        :data:`pearl_ros.bagio.cdr.TYPES` and serialise the outputs with
        :func:`pearl_ros.bagio.cdr.serialize`.
    """

    def __init__(self, settings: Settings | None = None,
                 types: encode.MessageTypes | None = None) -> None:
        self._settings = settings or Settings()
        self._types = types or encode.MessageTypes.from_typestore(TYPESTORE)
        self._segmenter = OnlineSegmenter(*self._settings.configs)
        # Poses as world-to-optical-frame matrices [R^T | -R^T c] (3, 4): the intrinsics are
        # applied when a frame takes its camera, so that poses may come before camera_info.
        self._poses = PoseBuffer(self._pose_tolerance_ns())
        self._camera_info: np.ndarray | None = None  # the latest valid camera_info's k
        self._lens: CameraModel | None = None  # and its lens, where it distorts
        # The camera matrix that the window's normalised coordinates became pixels of.
        self._normalised_k: np.ndarray | None = None
        # Feature frames that got a camera pose, when segmented or later (a pose that came
        # after its frame): what tells a user that poses and frames meet (their clocks agree).
        self.frames_with_camera = 0

    @property
    def settings(self) -> Settings:
        return self._settings

    @property
    def frames_in_window(self) -> int:
        return self._segmenter.frames_in_window

    def delivered(self, at: float | None = None) -> None:
        """The outputs of the last message :meth:`process` labelled went out at ``at``
        (:func:`time.perf_counter`, default now): the time they took after the segmenter's
        answer (encoding, publishing) comes out of the next frames' budget
        (:meth:`OnlineSegmenter.delivered`)."""
        self._segmenter.delivered(at)

    def reconfigure(self, settings: Settings) -> None:
        """New settings from the next message on; the window is kept."""
        self._segmenter.reconfigure(*settings.configs)
        self._settings = settings
        self._poses.tolerance_ns = self._pose_tolerance_ns()

    def _pose_tolerance_ns(self) -> int:
        return int(round(self._settings.node.pose_tolerance_ms * 1e6))

    @property
    def intrinsics(self) -> np.ndarray | None:
        """The camera matrix (3, 3) that poses are projected with: the latest valid
        camera_info's where ``camera_info_topic`` is set (None before the first), else the
        parameters' (None when they are not set)."""
        node = self._settings.node
        if node.camera_info_topic:
            return self._camera_info
        if not (node.camera_fx > 0 and node.camera_fy > 0):
            return None
        return poses.intrinsics_matrix(node.camera_fx, node.camera_fy, node.camera_cx,
                                       node.camera_cy)

    def add_camera_info(self, msg: Any) -> Skipped | None:
        """Take the intrinsics of a ``sensor_msgs/msg/CameraInfo`` (rclpy's or rosbags'), for
        ``camera_info_topic``: with ``pose_topic`` the frames from here on use them, and the
        first valid one also gives the frames of the window that came without a camera
        theirs, from the poses already taken. Where its lens distorts (``d``), the features'
        pixels are undistorted before they are segmented (the published messages keep them as
        they came), and a lens other than the last one's empties the window: its tracks were
        in the other pixels.
        The :class:`Skipped` of one that cannot be used (an uncalibrated camera's zero ``k``, a
        non-finite one, an unknown distortion model), else None."""
        try:
            k = poses.read_intrinsics(msg)
            lens = poses.read_lens(msg, k)
        except InputError as err:
            return Skipped('camera_info', f'camera_info: {one_line(err, None)}', True)
        node = self._settings.node
        first = self._camera_info is None
        if not _same_lens(lens, self._lens):
            self._lens = lens
            if node.camera_info_topic and self._segmenter.frames_in_window:
                self._segmenter.reset()
        self._camera_info = k
        if first and node.camera_info_topic and node.pose_topic:
            for stamp, pose in self._poses.items():
                self.frames_with_camera += self._segmenter.set_camera(
                    stamp, k @ pose, self._poses.tolerance_ns)
        return None

    def add_pose(self, msg: Any) -> Skipped | None:
        """Take a camera pose (``pose_type``; rclpy's or rosbags' message): the feature frame
        of the nearest stamp gets its camera, whether it came before the pose or comes after.
        The :class:`Skipped` of a pose that cannot be read (a zero quaternion, a non-finite
        position), else None."""
        node = self._settings.node
        try:
            position, orientation = poses.read_pose(msg, node.pose_type)
            mount = np.array([node.mount_x, node.mount_y, node.mount_z])
            turn = np.array([node.mount_qx, node.mount_qy, node.mount_qz, node.mount_qw])
            if mount.any() or turn[:3].any():  # else the poses are the camera's own
                position, orientation = poses.mounted(position, orientation, mount, turn)
            pose = poses.camera_matrix(position, orientation, np.eye(3))
            stamp = decode.stamp_ns(msg.header)
        except (InputError, AttributeError, TypeError, ValueError) as err:
            return Skipped('pose', f'pose: {one_line(err, None)}', True)
        self._poses.add(stamp, pose)
        intrinsics = self.intrinsics
        if intrinsics is not None:
            self.frames_with_camera += self._segmenter.set_camera(
                stamp, intrinsics @ pose, self._poses.tolerance_ns)
        return None

    def _camera(self, stamp_ns: int) -> np.ndarray | None:
        """The projection matrix of the frame of ``stamp_ns``: its pose's, with the intrinsics;
        None without either."""
        pose, intrinsics = self._poses.find(stamp_ns), self.intrinsics
        return None if pose is None or intrinsics is None else intrinsics @ pose

    def reset(self) -> None:
        """Empty the window: the next message starts afresh."""
        self._segmenter.reset()

    @staticmethod
    def deserialize(raw: bytes, msgtype: str) -> Any:
        """A serialised (CDR) feature message of type ``msgtype`` as a
        :mod:`~pearl_ros.bagio.cdr` message, or the :class:`Skipped` of a record that cannot be
        read (malformed: ``'cannot deserialise ...'``, as the replay says of a bag's record)."""
        try:
            return cdr.read(raw, msgtype)
        except InputError as err:
            return Skipped.because(cdr.unreadable(msgtype, err))

    def read(self, msg: Any) -> tuple[np.ndarray, np.ndarray] | Skipped:
        """Step 1 alone: the ids ``(N,)`` int64 and pixels ``(N, 2)`` of a feature message, or
        the :class:`Skipped` that :meth:`process` gives it when it cannot be read or is empty.

        Leaves the window untouched: ``pearl_play`` checks a bag with it before playing, so
        that it holds back, with the node's own words, what the node would skip.
        """
        node = self._settings.node
        try:
            ids, uv = read_features(msg, None, node.layout, node.camera_id)
        except InputError as err:
            return Skipped.because(err)
        if ids.size == 0:
            return Skipped.because('empty cloud: no features', malformed=False)
        return ids, uv

    def process(self, msg: Any, header: Any = None,
                arrived: float | None = None) -> Labelled | Skipped:
        """Segment one feature message.

        Parameters
        ----------
        msg : sensor_msgs/msg/PointCloud or PointCloud2
            An rclpy or rosbags message.
        header : std_msgs/msg/Header, optional
            Header of both outputs; default ``msg.header``.
        arrived : float, optional
            When the message arrived (:func:`time.perf_counter`): the segmenter's time budget
            counts from then (:meth:`OnlineSegmenter.process`); default: now.

        Returns
        -------
        Labelled, or Skipped when the message cannot be read (malformed: channel lengths,
        missing channels or fields, NaN or inf coordinates, duplicate or non-integer ids,
        PointCloud ids beyond 2**24) or has nothing to segment (an empty cloud, a stamp equal
        to the last). A stamp earlier than the last empties the window first
        (``result.reset``), and the message is segmented.
        """
        features = self.read(msg)
        if isinstance(features, Skipped):
            return features
        ids, uv = features
        node = self._settings.node
        segmented = encode.subsample_mask(ids, node.max_features)
        stamp = decode.stamp_ns(msg.header)
        pixels = uv[segmented]
        image_uv: np.ndarray | None = uv
        if not decode.carries_pixels(msg, node.layout) and _normalised(uv):
            known = self.intrinsics
            projected = _project(self._normalised_camera(known), uv)
            pixels = projected[segmented]
            image_uv = None if known is None else projected
        elif self._lens is not None and node.camera_info_topic:
            pixels = self._lens.undistort(pixels)
        try:
            camera = self._camera(stamp) if node.pose_topic else None
            result = self._segmenter.process(stamp, ids[segmented], pixels, camera, arrived)
            self.frames_with_camera += camera is not None
        except InputError as err:  # a stamp equal to the last: the window is unchanged
            return Skipped.because(err, malformed=False)
        labels = np.full(ids.size, encode.UNLABELLED, dtype=np.int64)
        labels[segmented] = result.labels
        # The static world when the cameras told which motion it is, else the largest motion.
        background = (node.background_motion if node.background_motion >= 0
                      else result.static_motion)
        static = encode.static_mask(labels, background)
        header = msg.header if header is None else header
        labels_msg = encode.motion_labels(header, ids, uv if image_uv is None else image_uv,
                                          labels, self._types)
        static_msg = encode.static_features(msg, static, self._types, node.layout,
                                            node.camera_id)
        static_msg.header = header
        return Labelled(stamp, ids, uv, labels, segmented, static, result, labels_msg,
                        static_msg, image_uv)

    def _normalised_camera(self, intrinsics: np.ndarray | None) -> np.ndarray:
        """The camera matrix (3, 3) whose pixels a frame's normalised coordinates become: the
        ``intrinsics`` (:attr:`intrinsics`), or a nominal camera's (:data:`NOMINAL_FOCAL`)
        where none are known. One other than the last one's empties the window: its tracks
        were in the other pixels."""
        k = intrinsics
        if k is None:
            k = poses.intrinsics_matrix(NOMINAL_FOCAL, NOMINAL_FOCAL, 0.0, 0.0)
        if (self._normalised_k is not None and not np.array_equal(k, self._normalised_k)
                and self._segmenter.frames_in_window):
            self._segmenter.reset()
        self._normalised_k = k
        return k


def _project(k: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels ``(N, 2)`` of normalised coordinates ``points`` ``(N, 2)`` by camera matrix ``k``."""
    return points @ k[:2, :2].T + k[:2, 2]


def _normalised(points: np.ndarray) -> bool:
    """Whether coordinates ``(N, 2)`` that a message names normalised are: none beyond
    :data:`NORMALISED_LIMIT`."""
    return bool(np.all(np.abs(points) <= NORMALISED_LIMIT))

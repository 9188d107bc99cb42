"""Read tracked features and ground truth from bags with rosbags (no ROS installation needed).

Reads ROS 2 bag folders (mcap or sqlite3), bare ``.mcap`` / ``.db3`` files and ROS 1 ``.bag`` files
(VINS-Mono users often have those). Message decoding lives in :mod:`pearl_ros.bagio.decode`.

Two ways in:

- :func:`read_feature_frames`, :func:`read_ground_truth`, :func:`read_ground_truth_frames`:
  strict, a malformed message raises :class:`~pearl_ros.core.errors.BagError`;
- :func:`open_feature_stream`: what a replay needs, every message in recording order,
  deserialised *or* with the one-line reason it cannot be, so that one bad message is counted
  and skipped instead of ending the run (decoding it is the pipeline's job,
  :mod:`pearl_ros.pipeline.messages`); other topics come along as ROS 2 CDR bytes.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_typestore

from pearl_ros.bagio import cdr, decode, encode
from pearl_ros.core.errors import BagError, InputError, one_line

TYPESTORE = get_typestore(Stores.ROS2_KILTED)

POINTCLOUD = 'sensor_msgs/msg/PointCloud'
POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'
FEATURE_TYPES = (POINTCLOUD, POINTCLOUD2)
TRUTH_TYPES = (POINTCLOUD2,)

# What rosbags (and the storage libraries under it) raise on unreadable input.
_ROSBAGS_ERRORS: tuple[type[BaseException], ...] = (
    AnyReaderError,
    Ros1ReaderError,
    Ros2ReaderError,
    SerdeError,
    TypesysError,
    OSError,
    ValueError,
    RuntimeError,
    KeyError,
    IndexError,
    EOFError,
    struct.error,
)
try:  # the sqlite3 storage reads through apsw
    import apsw

    _ROSBAGS_ERRORS += (apsw.Error,)
except ImportError:  # pragma: no cover - apsw is a dependency of rosbags
    pass
# What a feature record that cannot be deserialised raises (rosbags for ROS 1, cdr for ROS 2).
_UNREADABLE: tuple[type[BaseException], ...] = (*_ROSBAGS_ERRORS, InputError)


@dataclass(frozen=True)
class FeatureFrame:
    """The tracked features of one image.

    Attributes
    ----------
    stamp_ns : int
        Header stamp, int nanoseconds.
    ids : (N,) int64
        Feature ids, unique within the frame.
    uv : (N, 2) float64
        Pixel coordinates (normalised coordinates if the message carried no pixels).
    """

    stamp_ns: int
    ids: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        if isinstance(self.stamp_ns, bool) or not isinstance(self.stamp_ns, (int, np.integer)):
            raise InputError(f'stamp_ns must be an int (nanoseconds), got {self.stamp_ns!r}')
        ids = np.asarray(self.ids)
        uv = np.asarray(self.uv, dtype=np.float64)
        if ids.ndim != 1:
            raise InputError(f'ids must have shape (N,), got {ids.shape}')
        if uv.shape != (ids.size, 2):
            raise InputError(f'uv must have shape ({ids.size}, 2) to match ids, got {uv.shape}')
        ids = decode.integer_ids(ids, 'ids')
        decode.check_features(ids, uv, 'FeatureFrame')
        object.__setattr__(self, 'stamp_ns', int(self.stamp_ns))
        object.__setattr__(self, 'ids', ids)
        object.__setattr__(self, 'uv', uv)


@dataclass(frozen=True)
class FeatureMessage:
    """One message of the feature topic, as :func:`open_feature_stream` yields it.

    Attributes
    ----------
    index : int
        Position on the feature topic, from 0, in recording order.
    log_time_ns : int
        Time the bag recorded the message, int nanoseconds.
    msgtype : str
        ``'sensor_msgs/msg/PointCloud'`` or ``'sensor_msgs/msg/PointCloud2'``.
    msg : object or None
        The deserialised message: a :mod:`~pearl_ros.bagio.cdr` message (arrays) from a ROS 2
        bag, a rosbags dataclass from a ROS 1 bag; None if it could not be deserialised.
    error : str or None
        One-line reason why ``msg`` is None.
    """

    index: int
    log_time_ns: int
    msgtype: str
    msg: Any
    error: str | None = None


@dataclass(frozen=True)
class CopiedMessage:
    """A message of another topic, passed through as ROS 2 CDR.

    Attributes
    ----------
    topic, msgtype : str
    log_time_ns : int
    cdr : bytes or None
        ROS 2 CDR serialisation (re-serialised from ROS 1 if the bag is a ROS 1 bag); None if the
        message could not be read, and then ``error`` says why.
    error : str or None
    """

    topic: str
    msgtype: str
    log_time_ns: int
    cdr: bytes | None
    error: str | None = None


class FeatureStream:
    """An open bag's feature topic (and topics to copy), iterated in recording order.

    Made by :func:`open_feature_stream`; iterating yields :class:`FeatureMessage` for the feature
    topic and :class:`CopiedMessage` for the copied topics, merged by log time.

    Attributes
    ----------
    path : Path
    topic : str
        The feature topic.
    msgtypes : tuple of str
        Message type(s) recorded on it.
    count : int
        Messages on the feature topic.
    copied : dict of str -> str
        Topics to copy that the bag has, with their message type.
    ros1 : bool
        The bag is a ROS 1 bag.
    """

    def __init__(self, reader: AnyReader, path: Path, topic: str,
                 copy_topics: tuple[str, ...]) -> None:
        self._reader = reader
        self.path = path
        self.topic = topic
        self._connections = _connections(reader, path, topic, FEATURE_TYPES)
        self.msgtypes = tuple(sorted({c.msgtype for c in self._connections}))
        self.count = sum(int(c.msgcount) for c in self._connections)
        wanted = set(copy_topics) - {topic}
        self._copies = [c for c in reader.connections if c.topic in wanted]
        self.copied = {name: kind for name, kind in _topic_types(reader).items() if name in wanted}
        self.ros1 = not reader.is2

    def __iter__(self) -> Iterator[FeatureMessage | CopiedMessage]:
        reader = self._reader
        features = {id(c) for c in self._connections}
        iterator = reader.messages(connections=self._connections + self._copies)
        index = 0
        while True:
            try:
                item = next(iterator, None)
            except _ROSBAGS_ERRORS as err:  # storage damage: the rest of the bag is unreadable
                raise BagError(f'cannot read bag {self.path}: {one_line(err)}') from err
            if item is None:
                return
            connection, log_time, raw = item
            if id(connection) in features:
                yield self._feature(index, int(log_time), connection.msgtype, raw)
                index += 1
            else:
                yield self._copy(connection, int(log_time), raw)

    def _feature(self, index: int, log_time: int, msgtype: str, raw: Any) -> FeatureMessage:
        try:
            if self.ros1:
                msg = self._reader.deserialize(raw, msgtype)
            else:  # arrays straight from the CDR bytes: no Python object per point
                msg = cdr.read(raw, msgtype)
        except _UNREADABLE as err:
            return FeatureMessage(index, log_time, msgtype, None, cdr.unreadable(msgtype, err))
        return FeatureMessage(index, log_time, msgtype, msg)

    def _copy(self, connection: Any, log_time: int, raw: Any) -> CopiedMessage:
        topic, msgtype = connection.topic, connection.msgtype
        if not self.ros1:
            return CopiedMessage(topic, msgtype, log_time, bytes(raw))
        try:
            # The serialiser reads fields by name: a ROS 1 Header's seq is simply left behind.
            msg = self._reader.deserialize(raw, msgtype)
            cdr = bytes(TYPESTORE.serialize_cdr(msg, msgtype))
        except _ROSBAGS_ERRORS as err:
            return CopiedMessage(topic, msgtype, log_time, None,
                                 f'cannot convert {msgtype} to ROS 2: {one_line(err)}')
        return CopiedMessage(topic, msgtype, log_time, cdr)


@contextmanager
def open_feature_stream(
    path: str | Path,
    topic: str = '/feature_tracker/feature',
    copy_topics: tuple[str, ...] = (),
) -> Iterator[FeatureStream]:
    """Open a bag for a replay: its feature topic, plus other topics to pass through.

    Parameters
    ----------
    path : str or Path
        ROS 2 bag folder, ``.mcap`` / ``.db3`` file, or ROS 1 ``.bag`` file.
    topic : str
        The feature topic (PointCloud or PointCloud2, detected per connection).
    copy_topics : tuple of str
        Topics to yield as :class:`CopiedMessage`; those the bag lacks are ignored
        (:attr:`FeatureStream.copied` lists the ones found).

    Raises
    ------
    BagError
        Missing or corrupt bag, unknown feature topic, wrong message type: on opening. Storage
        damage met while iterating raises too; a message that cannot be deserialised does not,
        it comes out as a :class:`FeatureMessage` with ``error`` set.
    """
    with open_bag(path) as reader:
        yield FeatureStream(reader, Path(path), topic, tuple(copy_topics))


def read_features(msg: Any, msgtype: str | None = None, layout: str = 'auto',
                  camera_id: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Feature ids (N,) int64 and pixels (N, 2) float64 of one feature message.

    Beyond :mod:`~pearl_ros.bagio.decode`'s checks: PointCloud ids above ``2**24`` (float32
    channels hold integers exactly only up to there, so two tracks may already share one id) and
    ids the ``motion_labels`` uint32 field cannot hold. An empty cloud gives N = 0.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud or PointCloud2
        An rclpy or rosbags message.
    msgtype : str, optional
        ``'sensor_msgs/msg/PointCloud'`` or ``'sensor_msgs/msg/PointCloud2'``; default: told by
        the message's attributes (a PointCloud has ``channels``).
    layout, camera_id
        As :func:`~pearl_ros.bagio.decode.decode_pointcloud` (PointCloud only).

    Raises
    ------
    InputError
        With a one-line reason.
    """
    if msgtype is None:
        msgtype = POINTCLOUD if hasattr(msg, 'channels') else POINTCLOUD2
    ids, uv = _decode(msg, msgtype, layout, camera_id)
    if msgtype == POINTCLOUD:
        encode.check_float32_ids(ids)
    encode.check_label_ids(ids)
    return ids, uv


def _decode(msg: Any, msgtype: str, layout: str, camera_id: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Ids and pixels of a PointCloud or PointCloud2 message, by ``msgtype``."""
    if msgtype == POINTCLOUD2:
        return decode.decode_pointcloud2(msg)
    if msgtype == POINTCLOUD:
        return decode.decode_pointcloud(msg, layout, camera_id)
    raise InputError(f'{msgtype} is not a feature message type {FEATURE_TYPES}')


def decode_feature_message(
    msg: Any, msgtype: str, layout: str = 'auto', camera_id: int = 0
) -> FeatureFrame:
    """The :class:`FeatureFrame` of one feature message, refusing what the node refuses.

    :func:`read_features`, and an empty cloud (nothing to label) is refused too.

    Raises
    ------
    InputError
        With a one-line reason.
    """
    ids, uv = read_features(msg, msgtype, layout, camera_id)
    if ids.size == 0:
        raise InputError('empty cloud: no features')
    return FeatureFrame(decode.stamp_ns(msg.header), ids, uv)


def topics(path: str | Path) -> dict[str, str]:
    """Topic -> message type (``'sensor_msgs/msg/PointCloud'``...) of the bag at ``path``.

    A topic recorded with several types maps to their names joined by ``'|'``.
    """
    with open_bag(path) as reader:
        return _topic_types(reader)


def topic_counts(path: str | Path) -> dict[str, tuple[str, int]]:
    """Topic -> (message type as :func:`topics` gives it, message count) of the bag at ``path``."""
    with open_bag(path) as reader:
        counts: dict[str, int] = {}
        for connection in reader.connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + int(connection.msgcount)
        return {topic: (kind, counts[topic]) for topic, kind in _topic_types(reader).items()}


def read_feature_frames(
    path: str | Path,
    topic: str = '/feature_tracker/feature',
    layout: str = 'auto',
    camera_id: int = 0,
) -> Iterator[FeatureFrame]:
    """Tracked features, one :class:`FeatureFrame` per message, in recording order.

    Parameters
    ----------
    path : str or Path
        ROS 2 bag folder, ``.mcap`` / ``.db3`` file, or ROS 1 ``.bag`` file.
    topic : str
        A ``sensor_msgs/msg/PointCloud`` or ``sensor_msgs/msg/PointCloud2`` topic.
    layout : {'auto', 'vins_mono', 'vins_fusion'}
        PointCloud channel layout, see :mod:`pearl_ros.bagio.decode`.
    camera_id : int
        Camera to keep from a VINS-Fusion cloud.

    Raises
    ------
    BagError
        Missing or corrupt bag, unknown topic (the message lists the bag's topics), wrong message
        type, malformed message. Checked when called, except damage met while iterating.
    InputError
        Bad ``layout`` or ``camera_id``.
    """
    layout = decode.check_layout(layout)
    camera_id = decode.check_camera_id(camera_id)
    with open_bag(path) as reader:  # fail now, not at the first next()
        _connections(reader, path, topic, FEATURE_TYPES)
    return _iter_frames(path, topic, layout, camera_id)


def read_ground_truth(path: str | Path, topic: str = '/ground_truth/labels') -> dict[int, int]:
    """Feature id -> ground-truth label, merged over every message of ``topic``.

    Each message is a ``sensor_msgs/msg/PointCloud2`` with fields ``id`` (uint32) and ``label``
    (int32), usually one per frame with that frame's features. Where the truth changes over time
    (an object starts moving, a tracker reuses an id), read it per frame with
    :func:`read_ground_truth_frames`.

    Raises
    ------
    BagError
        As :func:`read_feature_frames`, and when one id is given two different labels.
    """
    truth: dict[int, int] = {}
    for _, ids, labels in read_ground_truth_frames(path, topic):
        for feature, label in zip(ids.tolist(), labels.tolist(), strict=True):
            if truth.setdefault(feature, label) != label:
                raise BagError(
                    f'{path}: feature {feature} has labels {truth[feature]} and {label} on {topic}'
                )
    return truth


def read_ground_truth_frames(
    path: str | Path, topic: str = '/ground_truth/labels'
) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Ground truth frame by frame: ``(stamp_ns, ids, labels)`` per message, in recording order.

    Returns
    -------
    list of (int, (M,) int64, (M,) int64)
        Header stamp (int nanoseconds; a frame's truth carries its feature message's stamp), and
        that frame's feature ids and labels.

    Raises
    ------
    BagError
        As :func:`read_feature_frames`.
    """
    out = []
    with open_bag(path) as reader:
        connections = _connections(reader, path, topic, TRUTH_TYPES)
        for index, (_, msg) in enumerate(bag_messages(reader, path, connections)):
            try:
                ids, labels = decode.decode_labels(msg)
            except InputError as err:
                raise BagError(f'{path}: message {index} on {topic}: {err}') from err
            out.append((decode.stamp_ns(msg.header), ids, labels))
    return out


def _iter_frames(
    path: str | Path, topic: str, layout: str, camera_id: int
) -> Iterator[FeatureFrame]:
    with open_bag(path) as reader:
        connections = _connections(reader, path, topic, FEATURE_TYPES)
        for index, (msgtype, msg) in enumerate(bag_messages(reader, path, connections)):
            try:
                ids, uv = _decode(msg, msgtype, layout, camera_id)
                frame = FeatureFrame(decode.stamp_ns(msg.header), ids, uv)
            except InputError as err:
                raise BagError(f'{path}: message {index} on {topic}: {err}') from err
            yield frame


@contextmanager
def open_bag(path: str | Path) -> Iterator[AnyReader]:
    """An open AnyReader on ``path``; every rosbags failure becomes a one-line BagError."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'bag not found: {path}')
    if path.is_dir() and path.suffix == '.bag':
        # rosbags takes every *.bag path for a ROS 1 file.
        raise BagError(
            f'{path} is a folder named *.bag: rosbags reads *.bag as a ROS 1 bag file; '
            'rename the ROS 2 bag folder without the .bag suffix'
        )
    if path.is_dir() and not (path / 'metadata.yaml').exists():
        raise BagError(f'{path} is not a ROS 2 bag folder: it has no metadata.yaml')
    try:
        reader = AnyReader([path], default_typestore=TYPESTORE)
        reader.open()
    except _ROSBAGS_ERRORS as err:
        raise BagError(f'cannot open bag {path}: {one_line(err)}') from err
    try:
        yield reader
    finally:
        reader.close()


def _topic_types(reader: AnyReader) -> dict[str, str]:
    types: dict[str, set[str]] = {}
    for connection in reader.connections:
        types.setdefault(connection.topic, set()).add(connection.msgtype)
    return {topic: '|'.join(sorted(names)) for topic, names in sorted(types.items())}


def _connections(
    reader: AnyReader, path: str | Path, topic: str, allowed: tuple[str, ...]
) -> list[Any]:
    """The connections of ``topic``, checked to exist and to carry one of the ``allowed`` types."""
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        listing = ', '.join(f'{name} ({kind})' for name, kind in _topic_types(reader).items())
        raise BagError(f'{path}: no topic {topic!r}; topics: {listing or "none"}')
    wrong = sorted({c.msgtype for c in connections} - set(allowed))
    if wrong:
        raise BagError(
            f'{path}: topic {topic} has type {"|".join(wrong)}, expected {" or ".join(allowed)}'
        )
    return connections


def bag_messages(reader: AnyReader, path: str | Path, connections: list[Any]) -> Iterator[Any]:
    """(msgtype, decoded message) pairs; storage and deserialisation failures become BagError."""
    iterator = reader.messages(connections=connections)
    while True:
        try:
            item = next(iterator, None)
            if item is None:
                return
            connection, _, raw = item
            msg = reader.deserialize(raw, connection.msgtype)
        except _ROSBAGS_ERRORS as err:
            raise BagError(f'cannot read bag {path}: {one_line(err)}') from err
        yield connection.msgtype, msg

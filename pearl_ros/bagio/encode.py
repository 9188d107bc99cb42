"""numpy -> the node's output messages, for rosbags and rclpy message classes alike.

The counterpart of :mod:`pearl_ros.bagio.decode`: nothing here imports ROS or rosbags. The
message classes come in a :class:`MessageTypes` (any object with the same attributes will do),
so the live node builds ``sensor_msgs.msg`` messages and the replay tool builds rosbags typestore
messages with the same code, and both write the same bytes on the wire.

Outputs (issue 4):

``motion_labels`` (:func:`motion_labels`)
    ``sensor_msgs/msg/PointCloud2``, one point per input feature in input order, little-endian,
    ``height = 1``, ``is_dense = True``, fields ``id`` uint32 @0, ``u`` float32 @4,
    ``v`` float32 @8, ``label`` int32 @12 (-1 = outlier or undecided), ``point_step = 16``.
``static_features`` (:func:`static_features`)
    The input message, same type and layout, holding only the kept features (the background
    motion, :func:`static_mask`).

The two containers differ in what they accept for array fields: rosbags wants numpy arrays
(``uint8`` for ``data``, ``float32`` for channel ``values``), rclpy wants ``array.array``
(``'B'``, ``'f'``; a numpy array fails its setter's type check, a list or bytes pass it but are
checked element by element in Python). :class:`MessageTypes` carries the two conversions.
"""

from __future__ import annotations

import array
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pearl_ros.bagio import decode
from pearl_ros.core.errors import InputError

UNLABELLED = -1

# sensor_msgs/msg/PointField datatype constants (the same numbers in every ROS distribution).
_UINT32, _INT32, _FLOAT32 = 6, 5, 7

# The motion_labels point: (name, numpy type, PointField datatype), packed, little-endian.
LABEL_FIELDS = (
    ('id', '<u4', _UINT32),
    ('u', '<f4', _FLOAT32),
    ('v', '<f4', _FLOAT32),
    ('label', '<i4', _INT32),
)
LABEL_DTYPE = np.dtype([(name, code) for name, code, _ in LABEL_FIELDS])  # itemsize 16

_VINS_MONO_ID = 'id_of_point'


def _numpy_uint8(values: np.ndarray) -> Any:
    return np.ascontiguousarray(values, dtype=np.uint8).reshape(-1)


def _numpy_float32(values: np.ndarray) -> Any:
    return np.ascontiguousarray(values, dtype=np.float32).reshape(-1)


def _point_objects(points: Any, index: np.ndarray) -> list[Any]:
    return [points[i] for i in index.tolist()]  # the input's own Point32 objects


def array_uint8(values: np.ndarray) -> array.array:
    """``values`` as ``array.array('B')``, what rclpy's ``uint8[]`` setters take unlooped."""
    return array.array('B', np.ascontiguousarray(values, dtype=np.uint8).tobytes())


def array_float32(values: np.ndarray) -> array.array:
    """``values`` as ``array.array('f')`` (rclpy's ``float32[]``), native byte order."""
    return array.array('f', np.ascontiguousarray(values, dtype=np.float32).tobytes())


@dataclass(frozen=True)
class MessageTypes:
    """The message classes (and array conversions) the encoders build messages with.

    Attributes
    ----------
    PointCloud2, PointField, PointCloud, ChannelFloat32 : type
        ``sensor_msgs/msg/...`` classes of one library.
    uint8s : callable
        (M,) uint8 ndarray -> what the library stores in ``PointCloud2.data``.
    float32s : callable
        (M,) float32 ndarray -> what it stores in ``ChannelFloat32.values``.
    select_points : callable
        (a PointCloud's ``points``, (K,) int index) -> the points at ``index``, what the
        library stores in ``PointCloud.points`` (a list of the input's own ``Point32``
        objects; :mod:`~pearl_ros.bagio.cdr` holds an array).
    """

    PointCloud2: Any
    PointField: Any
    PointCloud: Any
    ChannelFloat32: Any
    uint8s: Callable[[np.ndarray], Any] = _numpy_uint8
    float32s: Callable[[np.ndarray], Any] = _numpy_float32
    select_points: Callable[[Any, np.ndarray], Any] = _point_objects

    @classmethod
    def from_typestore(cls, typestore: Any) -> MessageTypes:
        """The classes of a rosbags typestore (``get_typestore(Stores.ROS2_KILTED)``)."""
        types = typestore.types
        return cls(
            PointCloud2=types['sensor_msgs/msg/PointCloud2'],
            PointField=types['sensor_msgs/msg/PointField'],
            PointCloud=types['sensor_msgs/msg/PointCloud'],
            ChannelFloat32=types['sensor_msgs/msg/ChannelFloat32'],
        )

    @classmethod
    def from_module(cls, sensor_msgs: Any) -> MessageTypes:
        """The classes of the rclpy module ``sensor_msgs.msg``."""
        return cls(
            PointCloud2=sensor_msgs.PointCloud2,
            PointField=sensor_msgs.PointField,
            PointCloud=sensor_msgs.PointCloud,
            ChannelFloat32=sensor_msgs.ChannelFloat32,
            uint8s=array_uint8,
            float32s=array_float32,
        )


def motion_labels(
    header: Any, ids: np.ndarray, uv: np.ndarray, labels: np.ndarray, types: MessageTypes
) -> Any:
    """The ``motion_labels`` PointCloud2 of one frame (module docstring for the layout).

    Parameters
    ----------
    header : std_msgs/msg/Header
        Copied by reference into the message (the input message's header).
    ids : (N,) int, feature ids in ``[0, 2**32)``
    uv : (N, 2) float, pixels (written as float32)
    labels : (N,) int, motion numbers in int32 range, -1 = outlier or undecided
    types : MessageTypes

    Raises
    ------
    InputError
        Mismatched shapes, ids outside uint32, labels outside int32.
    """
    ids = np.asarray(ids)
    uv = np.asarray(uv, dtype=np.float64)
    labels = np.asarray(labels)
    size = ids.size
    if ids.ndim != 1 or uv.shape != (size, 2) or labels.shape != (size,):
        raise InputError(
            f'motion_labels needs ids (N,), uv (N, 2), labels (N,); got {ids.shape}, '
            f'{uv.shape}, {labels.shape}'
        )
    ids = decode.integer_ids(ids, 'motion_labels ids')
    labels = decode.integer_ids(labels, 'motion_labels labels')
    check_range(ids, 0, 2**32, 'motion_labels ids (uint32)')
    check_range(labels, -(2**31), 2**31, 'motion_labels labels (int32)')
    columns = {'id': ids, 'u': uv[:, 0], 'v': uv[:, 1], 'label': labels}
    return packed_cloud2(header, columns, LABEL_FIELDS, types)


def packed_cloud2(header: Any, columns: dict[str, np.ndarray],
                  layout: tuple[tuple[str, str, int], ...], types: MessageTypes) -> Any:
    """An unorganised, packed, little-endian PointCloud2 of ``columns`` (N,) each.

    ``layout`` lists the fields in order as ``(name, numpy type code, PointField datatype)``,
    such as :data:`LABEL_FIELDS`; offsets follow from the packed numpy dtype.
    """
    dtype = np.dtype([(name, code) for name, code, _ in layout])
    size = int(next(iter(columns.values())).size)
    points = np.empty(size, dtype=dtype)
    for name, _, _ in layout:
        points[name] = columns[name]
    offsets: dict[str, Any] = dict(dtype.fields or {})  # name -> (dtype, offset)
    fields = [
        types.PointField(name=name, offset=int(offsets[name][1]), datatype=datatype, count=1)
        for name, _, datatype in layout
    ]
    return types.PointCloud2(
        header=header,
        height=1,
        width=size,
        fields=fields,
        is_bigendian=False,
        point_step=dtype.itemsize,
        row_step=dtype.itemsize * size,
        data=types.uint8s(points.view(np.uint8)),
        is_dense=True,
    )


def background_motion(labels: np.ndarray) -> int | None:
    """The motion with the most features (ties: the lowest number); None if all are -1."""
    labels = np.asarray(labels)
    numbers, counts = np.unique(labels[labels != UNLABELLED], return_counts=True)
    if numbers.size == 0:
        return None
    # np.unique sorts, and argmax returns the first maximum: the lowest number wins a tie.
    return int(numbers[np.argmax(counts)])


def static_mask(labels: np.ndarray, background: int | None = None) -> np.ndarray:
    """(N,) bool: the features of ``background`` (default :func:`background_motion`).

    A feature labelled -1 (outlier or undecided) is never static.
    """
    labels = np.asarray(labels)
    if background is None:
        background = background_motion(labels)
    if background is None or background == UNLABELLED:
        return np.zeros(labels.shape, dtype=bool)
    return labels == background


def static_features(
    msg: Any,
    keep: np.ndarray,
    types: MessageTypes,
    layout: str = 'auto',
    camera_id: int = 0,
) -> Any:
    """The feature message ``msg`` cut down to the features ``keep`` marks, same type and layout.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud or sensor_msgs/msg/PointCloud2
        The input message, as :mod:`~pearl_ros.bagio.decode` read it.
    keep : (N,) bool
        One flag per decoded feature, in decode order (N = the number of features decode gave).
    types : MessageTypes
        Classes of ``msg``'s own library (the header and points are shared with ``msg``).
    layout, camera_id
        As given to :func:`~pearl_ros.bagio.decode.decode_pointcloud` (PointCloud only).
        In the VINS-Fusion layout only camera ``camera_id``'s features are filtered: the other
        cameras' points pass untouched.

    Returns
    -------
    A new message of ``msg``'s type with ``msg``'s header: a PointCloud keeps the order of its
    points and every channel (subset consistently); a PointCloud2 keeps fields, ``point_step``,
    byte order and ``is_dense``, and comes out unorganised (``height = 1``).

    Raises
    ------
    InputError
        ``keep`` does not have one flag per decoded feature, or ``msg`` is malformed.
    """
    keep = np.asarray(keep)
    if keep.dtype != bool or keep.ndim != 1:
        raise InputError(f'keep must be a (N,) bool array, got {keep.dtype} {keep.shape}')
    if hasattr(msg, 'channels'):
        return _select_pointcloud(msg, keep, types, layout, camera_id)
    return _select_pointcloud2(msg, keep, types)


def _select_pointcloud(msg: Any, keep: np.ndarray, types: MessageTypes, layout: str,
                       camera_id: int) -> Any:
    layout = decode.check_layout(layout)
    camera_id = decode.check_camera_id(camera_id)
    num_points = len(msg.points)
    names, values = decode.channels(msg, np.float32)
    if layout == 'auto' and num_points:
        layout = 'vins_mono' if _VINS_MONO_ID in names else 'vins_fusion'
    if layout == 'vins_fusion' and num_points:
        if len(values) < 4:
            raise InputError(
                f'VINS-Fusion PointCloud needs >= 4 channels (id, camera, u, v), got {len(names)}'
            )
        # Same test as decode: features of this camera, in point order.
        mine = values[1].astype(np.float64) == camera_id
        _check_keep(keep, int(mine.sum()))
        point_keep = ~mine
        point_keep[mine] = keep
    else:
        _check_keep(keep, num_points)
        point_keep = keep
    index = np.flatnonzero(point_keep)
    return types.PointCloud(
        header=msg.header,
        points=types.select_points(msg.points, index),
        channels=[
            types.ChannelFloat32(name=name, values=types.float32s(column[index]))
            for name, column in zip(names, values, strict=True)
        ],
    )


def _select_pointcloud2(msg: Any, keep: np.ndarray, types: MessageTypes) -> Any:
    point_step = int(msg.point_step)
    _check_keep(keep, int(msg.height) * int(msg.width))
    points = decode.point_rows(msg)[keep]
    size = int(points.shape[0])
    return types.PointCloud2(
        header=msg.header,
        height=1,
        width=size,
        fields=[
            types.PointField(name=str(f.name), offset=int(f.offset), datatype=int(f.datatype),
                             count=int(f.count))
            for f in msg.fields
        ],
        is_bigendian=bool(msg.is_bigendian),
        point_step=point_step,
        row_step=point_step * size,
        data=types.uint8s(points.reshape(-1)),
        is_dense=bool(msg.is_dense),
    )


def _check_keep(keep: np.ndarray, expected: int) -> None:
    if keep.size != expected:
        raise InputError(f'keep has {keep.size} flags for {expected} features in the message')


def check_range(values: np.ndarray, low: int, high: int, what: str) -> None:
    """Raise InputError naming ``what`` unless ``low <= values < high``."""
    bad = (values < low) | (values >= high)
    if bad.any():
        raise InputError(f'{what} out of range: {values[bad][:3].tolist()}')


# -------------------------------------------------------------------------------------------
# Input checks and caps that decode.py does not make, shared by the node and pearl_replay so
# that both answer the same message in the same way.


def check_float32_ids(ids: np.ndarray) -> None:
    """Refuse PointCloud ids beyond ``2**24``: float32 channels cannot hold them exactly.

    Above ``2**24`` neighbouring integers share one float32, so two tracks can arrive with one
    id, or one track can change id: nothing downstream could be trusted.

    Raises
    ------
    InputError
        Naming the first offending ids.
    """
    ids = np.asarray(ids)
    bad = np.abs(ids) > decode.FLOAT32_EXACT_ID
    if bad.any():
        raise InputError(
            f'PointCloud feature ids above 2**24 are not exact in float32: {ids[bad][:3].tolist()}'
        )


def check_label_ids(ids: np.ndarray) -> None:
    """Refuse ids that the ``motion_labels`` uint32 ``id`` field cannot hold."""
    ids = np.asarray(ids)
    bad = (ids < 0) | (ids >= 2**32)
    if bad.any():
        raise InputError(f'feature ids must be in [0, 2**32), got {ids[bad][:3].tolist()}')


# Fibonacci hashing (Knuth, TAOCP vol. 3, 6.4): 2**64 / golden ratio, odd.
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def subsample_mask(ids: np.ndarray, limit: int) -> np.ndarray:
    """(N,) bool: at most ``limit`` features, picked by a hash of their ids.

    The features with the ``limit`` smallest hashes are kept. The hash depends on the id only,
    so a track kept in one frame is kept in the next one as long as the cap bites alike, and a
    track's history in the window stays whole; the input order plays no part. Ties (equal
    hashes need equal ids, which decode refuses) cannot occur.

    Parameters
    ----------
    ids : (N,) int, unique
    limit : int >= 1
    """
    ids = np.asarray(ids)
    if limit < 1:
        raise InputError(f'limit must be >= 1, got {limit}')
    keep = np.ones(ids.size, dtype=bool)
    if ids.size <= limit:
        return keep
    with np.errstate(over='ignore'):  # multiplication modulo 2**64 is the point
        hashes = ids.astype(np.int64).view(np.uint64) * _GOLDEN
    keep[:] = False
    keep[np.argpartition(hashes, limit - 1)[:limit]] = True
    return keep

"""ROS 2 CDR bytes <-> feature messages, read and written with numpy, no object per point.

A 500-point ``sensor_msgs/msg/PointCloud`` deserialised by rclpy or rosbags becomes 500
``Point32`` objects (about 1 ms; 5 ms at 2,000 points), only for :mod:`~pearl_ros.bagio.decode`
to copy them back into arrays. Here the serialised bytes are read straight into arrays, and
the node's outputs are written straight to bytes, so that ``pearl_node`` (a raw subscription,
raw publishing) and ``pearl_replay`` (raw bag records) skip both steps.

The messages made here are small mirrors of the ROS classes (:class:`PointCloud`,
:class:`PointCloud2`, :class:`Header` ...) with the attributes that :mod:`~pearl_ros.bagio.decode`
and :mod:`~pearl_ros.bagio.encode` read, array fields held as numpy arrays (``points`` as an
``(N, 3)`` float32 array). :data:`TYPES` builds them, :func:`serialize` writes them.

Wire format: the 4-byte encapsulation header (``00 01``: little-endian CDR, ``00 00``:
big-endian; both are read, little-endian is written), then the fields in order, each aligned to
its own size counted from the end of the encapsulation header; a string is a uint32 length
(its terminating NUL included) and its bytes; a sequence a uint32 count and its elements.

Every malformed record raises :class:`~pearl_ros.core.errors.InputError` with a one-line reason.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pearl_ros.bagio.decode import point_array
from pearl_ros.bagio.encode import MessageTypes
from pearl_ros.core.errors import InputError, one_line

POINTCLOUD = 'sensor_msgs/msg/PointCloud'
# The words that open the reason a record that cannot be read is skipped for, in the node's and
# the replay's warnings and counts alike (:func:`unreadable`).
UNREADABLE = 'cannot deserialise'
POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'

_LITTLE, _BIG = b'\x00\x01', b'\x00\x00'
_OFFSET = 4  # alignment counts from the end of the encapsulation header


@dataclass
class Time:
    """``builtin_interfaces/msg/Time``."""

    sec: int = 0
    nanosec: int = 0


@dataclass
class Header:
    """``std_msgs/msg/Header``."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ''


@dataclass
class ChannelFloat32:
    """``sensor_msgs/msg/ChannelFloat32``; ``values`` (M,) float32."""

    name: str = ''
    values: np.ndarray = field(default_factory=lambda: np.empty(0, np.float32))


@dataclass
class PointCloud:
    """``sensor_msgs/msg/PointCloud``; ``points`` (N, 3) float32 (x, y, z)."""

    header: Header = field(default_factory=Header)
    points: np.ndarray = field(default_factory=lambda: np.empty((0, 3), np.float32))
    channels: list[ChannelFloat32] = field(default_factory=list)


@dataclass
class PointField:
    """``sensor_msgs/msg/PointField``, with its datatype constants."""

    INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

    name: str = ''
    offset: int = 0
    datatype: int = 0
    count: int = 0


@dataclass
class PointCloud2:
    """``sensor_msgs/msg/PointCloud2``; ``data`` (M,) uint8."""

    header: Header = field(default_factory=Header)
    height: int = 0
    width: int = 0
    fields: list[PointField] = field(default_factory=list)
    is_bigendian: bool = False
    point_step: int = 0
    row_step: int = 0
    data: np.ndarray = field(default_factory=lambda: np.empty(0, np.uint8))
    is_dense: bool = False


# The classes the encoders build messages with: serialise those with :func:`serialize`.
TYPES = MessageTypes(
    PointCloud2=PointCloud2,
    PointField=PointField,
    PointCloud=PointCloud,
    ChannelFloat32=ChannelFloat32,
    select_points=lambda points, index: point_array(points)[index],
)


class _Reader:
    """A cursor over one CDR record; each read checks that the record holds what it asks."""

    def __init__(self, raw: bytes | memoryview | np.ndarray, what: str) -> None:
        self.buf = memoryview(raw).cast('B')  # type: ignore[arg-type]  # ndarray is a buffer
        self.what = what
        if len(self.buf) < _OFFSET:
            raise InputError(f'{what}: {len(self.buf)} bytes, too short for a CDR record')
        kind = bytes(self.buf[:2])
        if kind not in (_LITTLE, _BIG):
            raise InputError(f'{what}: unknown CDR encapsulation {kind.hex()} (expected 0001 '
                             'or 0000, plain CDR)')
        self.order = '<' if kind == _LITTLE else '>'
        self.pos = _OFFSET

    def _take(self, size: int, align: int) -> int:
        start = self.pos + (-(self.pos - _OFFSET) % align)
        if start + size > len(self.buf):
            raise InputError(f'{self.what}: record ends at byte {len(self.buf)}, '
                             f'{start + size - len(self.buf)} byte(s) short (truncated)')
        self.pos = start + size
        return start

    def scalar(self, code: str) -> int:
        dtype = np.dtype(self.order + code)
        start = self._take(dtype.itemsize, dtype.itemsize)
        return int(np.frombuffer(self.buf, dtype, 1, start)[0])

    def array(self, code: str, count: int) -> np.ndarray:
        """``count`` items of numpy type ``code``, native byte order (a copy)."""
        dtype = np.dtype(self.order + code)
        start = self._take(dtype.itemsize * count, dtype.base.itemsize)
        return np.frombuffer(self.buf, dtype, count, start).astype(dtype.newbyteorder('='))

    def count(self, item_size: int) -> int:
        """A sequence's length, refused if the record cannot hold that many items."""
        count = self.scalar('u4')
        if count * item_size > len(self.buf) - self.pos:
            raise InputError(f'{self.what}: a sequence of {count} items does not fit in the '
                             f'{len(self.buf) - self.pos} bytes left (truncated or corrupt)')
        return count

    def string(self) -> str:
        size = self.count(1)
        start = self._take(size, 1)
        if size == 0 or self.buf[start + size - 1] != 0:
            raise InputError(f'{self.what}: a string without its terminating NUL (corrupt)')
        try:
            return bytes(self.buf[start:start + size - 1]).decode()
        except UnicodeDecodeError as err:
            raise InputError(f'{self.what}: a string that is not UTF-8 ({err.reason})') from None

    def header(self) -> Header:
        sec, nanosec = self.scalar('i4'), self.scalar('u4')
        return Header(Time(sec, nanosec), self.string())


def read_pointcloud(raw: bytes | memoryview | np.ndarray) -> PointCloud:
    """A serialised ``sensor_msgs/msg/PointCloud`` as a :class:`PointCloud`.

    Raises
    ------
    InputError
        Not CDR, truncated, a count or string the record cannot hold.
    """
    reader = _Reader(raw, 'PointCloud')
    header = reader.header()
    points = reader.array('f4', 3 * reader.count(12)).reshape(-1, 3)
    channels = []
    for _ in range(reader.count(8)):
        name = reader.string()
        channels.append(ChannelFloat32(name, reader.array('f4', reader.count(4))))
    return PointCloud(header, points, channels)


def read_pointcloud2(raw: bytes | memoryview | np.ndarray) -> PointCloud2:
    """A serialised ``sensor_msgs/msg/PointCloud2`` as a :class:`PointCloud2` (``data`` a
    uint8 array).

    Raises
    ------
    InputError
        Not CDR, truncated, a count or string the record cannot hold.
    """
    reader = _Reader(raw, 'PointCloud2')
    header = reader.header()
    height, width = reader.scalar('u4'), reader.scalar('u4')
    fields = []
    for _ in range(reader.count(13)):
        name = reader.string()
        offset, datatype, count = reader.scalar('u4'), reader.scalar('u1'), reader.scalar('u4')
        fields.append(PointField(name, offset, datatype, count))
    is_bigendian = bool(reader.scalar('u1'))
    point_step, row_step = reader.scalar('u4'), reader.scalar('u4')
    data = reader.array('u1', reader.count(1))
    is_dense = bool(reader.scalar('u1'))
    return PointCloud2(header, height, width, fields, is_bigendian, point_step, row_step, data,
                       is_dense)


READERS: dict[str, Callable[[bytes | memoryview | np.ndarray], PointCloud | PointCloud2]] = {
    POINTCLOUD: read_pointcloud, POINTCLOUD2: read_pointcloud2}


def read(raw: bytes | memoryview | np.ndarray, msgtype: str) -> PointCloud | PointCloud2:
    """A serialised feature message of type ``msgtype`` (PointCloud or PointCloud2).

    Raises
    ------
    InputError
        Another type, or a malformed record.
    """
    if msgtype not in READERS:
        raise InputError(f'{msgtype} is not a feature message type {tuple(READERS)}')
    return READERS[msgtype](raw)


def stamp_ns(raw: bytes | memoryview | np.ndarray) -> int:
    """The header stamp (int nanoseconds) of any serialised message that starts with a
    ``std_msgs/msg/Header``; InputError if the record is too short to hold one."""
    reader = _Reader(raw, 'message')
    return reader.scalar('i4') * 1_000_000_000 + reader.scalar('u4')


class _Writer:
    """Little-endian CDR, fields appended in order with their alignment."""

    def __init__(self) -> None:
        self.parts: list[bytes] = [_LITTLE + b'\x00\x00']
        self.size = 0  # bytes after the encapsulation header

    def _pad(self, align: int) -> None:
        pad = -self.size % align
        if pad:
            self.parts.append(b'\x00' * pad)
            self.size += pad

    def raw(self, data: bytes, align: int) -> None:
        self._pad(align)
        self.parts.append(data)
        self.size += len(data)

    def scalar(self, code: str, value: int) -> None:
        dtype = np.dtype('<' + code)
        self.raw(np.array(value, dtype).tobytes(), dtype.itemsize)

    def array(self, code: str, values: np.ndarray) -> None:
        """A sequence: its count (``len(values)``), then its items, each row of ``values``
        flattened (an (N, 3) array is a sequence of N Point32)."""
        values = np.ascontiguousarray(values, dtype='<' + code)
        self.scalar('u4', len(values))
        self.raw(values.tobytes(), values.dtype.itemsize)

    def string(self, text: str) -> None:
        data = str(text).encode() + b'\x00'
        self.scalar('u4', len(data))
        self.raw(data, 1)

    def header(self, header: Any) -> None:
        self.scalar('i4', int(header.stamp.sec))
        self.scalar('u4', int(header.stamp.nanosec))
        self.string(header.frame_id)

    def bytes(self) -> bytes:
        return b''.join(self.parts)


def serialize(msg: Any) -> bytes:
    """Little-endian ROS 2 CDR of a :class:`PointCloud` or :class:`PointCloud2` (any object
    with their attributes and array fields, such as the ones :data:`TYPES` builds)."""
    out = _Writer()
    out.header(msg.header)
    if hasattr(msg, 'channels'):
        out.array('f4', point_array(msg.points))
        out.scalar('u4', len(msg.channels))
        for channel in msg.channels:
            out.string(channel.name)
            out.array('f4', np.asarray(channel.values))
        return out.bytes()
    out.scalar('u4', int(msg.height))
    out.scalar('u4', int(msg.width))
    out.scalar('u4', len(msg.fields))
    for point_field in msg.fields:
        out.string(point_field.name)
        out.scalar('u4', int(point_field.offset))
        out.scalar('u1', int(point_field.datatype))
        out.scalar('u4', int(point_field.count))
    out.scalar('u1', int(bool(msg.is_bigendian)))
    out.scalar('u4', int(msg.point_step))
    out.scalar('u4', int(msg.row_step))
    out.array('u1', np.frombuffer(memoryview(msg.data).cast('B'), np.uint8))  # type: ignore[arg-type]
    out.scalar('u1', int(bool(msg.is_dense)))
    return out.bytes()


def unreadable(msgtype: str, err: BaseException) -> str:
    """The one-line reason a record of ``msgtype`` that raised ``err`` is skipped for."""
    return f'{UNREADABLE} {msgtype}: {one_line(err)}'

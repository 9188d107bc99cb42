"""Tracked-feature messages -> numpy, for rosbags and rclpy message objects alike.

Nothing here imports ROS or rosbags: the functions only read attributes that the rosbags
dataclasses and the rclpy message classes share (``header.stamp.sec``, ``points[i].x``,
``channels[j].name`` / ``.values``, ``fields``, ``data``, ``point_step`` ...), so the bag reader
and the ROS node decode with the same code.

Layouts of ``sensor_msgs/msg/PointCloud`` that tracking front ends publish:

``'vins_mono'`` (alias ``'by_name'``)
    VINS-Mono ``feature_tracker``: ``points[i]`` = undistorted normalised ``(x, y, 1)``; channels
    found by name: ``id_of_point``, ``u_of_point``, ``v_of_point`` (pixels), optionally
    ``velocity_x_of_point``, ``velocity_y_of_point``.
``'vins_fusion'`` (alias ``'by_index'``)
    VINS-Fusion feature input: channels by index, 0 feature id, 1 camera id, 2 u, 3 v (pixels),
    4 vx, 5 vy.
``'auto'``
    ``'vins_mono'`` if a channel is named ``id_of_point``, else ``'vins_fusion'`` if the cloud has
    at least 4 channels.

Every malformed message raises :class:`~pearl_ros.core.errors.InputError` with a one-line message.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pearl_ros.core.errors import InputError

LAYOUTS = ('auto', 'vins_mono', 'vins_fusion')
_LAYOUT_ALIASES = {'by_name': 'vins_mono', 'by_index': 'vins_fusion'}

# Ids travel as float32 in PointCloud channels: integers are exact up to 2**24 only.
FLOAT32_EXACT_ID = 2**24

# sensor_msgs/msg/PointField datatype constants -> numpy type codes (byte order added per message).
POINTFIELD_DTYPES = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}

_VINS_MONO_ID = 'id_of_point'
_VINS_MONO_U = 'u_of_point'
_VINS_MONO_V = 'v_of_point'


def stamp_ns(header: Any) -> int:
    """Header stamp as int nanoseconds (``sec * 1e9 + nanosec``)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def check_layout(layout: str) -> str:
    """The canonical name of a PointCloud layout, with aliases resolved."""
    canonical = _LAYOUT_ALIASES.get(layout, layout)
    if canonical not in LAYOUTS:
        names = LAYOUTS + tuple(_LAYOUT_ALIASES)
        raise InputError(f'layout must be one of {names}, got {layout!r}')
    return canonical


def check_camera_id(camera_id: int) -> int:
    """A camera id is an integer >= 0."""
    if isinstance(camera_id, bool) or not isinstance(camera_id, (int, np.integer)):
        raise InputError(f'camera_id must be an integer >= 0, got {camera_id!r}')
    if camera_id < 0:
        raise InputError(f'camera_id must be an integer >= 0, got {camera_id!r}')
    return int(camera_id)


def decode_pointcloud(
    msg: Any, layout: str = 'auto', camera_id: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Feature ids and pixel coordinates of a ``sensor_msgs/msg/PointCloud``.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud
        A rosbags or rclpy message object.
    layout : {'auto', 'vins_mono', 'vins_fusion'}
        Channel layout (module docstring); ``'by_name'`` and ``'by_index'`` are aliases.
    camera_id : int
        Camera whose features are kept (VINS-Fusion layout only).

    Returns
    -------
    ids : (N,) int64
        Feature ids, unique within the message.
    uv : (N, 2) float64
        Pixel coordinates; the normalised ``points[i].x, .y`` instead if a VINS-Mono cloud has
        neither ``u_of_point`` nor ``v_of_point``.

    Raises
    ------
    InputError
        Unknown layout, a channel whose length is not the point count, missing channels,
        non-integer or duplicate ids, non-finite coordinates.
    """
    layout = check_layout(layout)
    camera_id = check_camera_id(camera_id)
    num_points = len(msg.points)
    names, values = channels(msg, np.float64)
    if num_points == 0:
        return _empty()

    layout = _resolved_layout(layout, names)
    if layout == 'vins_mono':
        by_name = dict(zip(names, values, strict=True))
        if _VINS_MONO_ID not in by_name:
            raise InputError(f'PointCloud has no {_VINS_MONO_ID!r} channel; channels: {names}')
        ids = by_name[_VINS_MONO_ID]
        has_u, has_v = _VINS_MONO_U in by_name, _VINS_MONO_V in by_name
        if has_u and has_v:
            uv = np.column_stack((by_name[_VINS_MONO_U], by_name[_VINS_MONO_V]))
        elif not has_u and not has_v:
            # Oldest front ends send ids only: fall back to the normalised coordinates.
            uv = point_array(msg.points)[:, :2].astype(np.float64)
        else:
            raise InputError(
                f'PointCloud has only one of {_VINS_MONO_U!r}, {_VINS_MONO_V!r}; channels: {names}'
            )
    else:
        if len(names) < 4:
            raise InputError(
                f'VINS-Fusion PointCloud needs >= 4 channels (id, camera, u, v), got {len(names)}'
            )
        keep = values[1] == camera_id
        ids = values[0][keep]
        uv = np.column_stack((values[2][keep], values[3][keep]))

    ids_int = integer_ids(ids, 'PointCloud feature ids')
    check_features(ids_int, uv, 'PointCloud')
    return ids_int, uv


def _resolved_layout(layout: str, names: list[str]) -> str:
    """``'vins_mono'`` or ``'vins_fusion'``: ``layout`` (canonical), or what ``'auto'`` tells
    from a PointCloud's channel ``names``."""
    if layout != 'auto':
        return layout
    if _VINS_MONO_ID in names:
        return 'vins_mono'
    if len(names) >= 4:
        return 'vins_fusion'
    raise InputError(
        f'cannot tell the PointCloud layout: no {_VINS_MONO_ID!r} channel and '
        f'{len(names)} channel(s) {names} (VINS-Fusion needs >= 4)'
    )


def carries_pixels(msg: Any, layout: str = 'auto') -> bool:
    """Whether the coordinates that :func:`decode_pointcloud` or :func:`decode_pointcloud2`
    give of ``msg`` are pixels: False where they fall back to normalised coordinates (a
    VINS-Mono cloud without ``u_of_point``, ``v_of_point``; a PointCloud2 without ``u``, ``v``).
    Reads the channel or field names alone; a message the decoders refuse gives True."""
    if hasattr(msg, 'channels'):
        names = [str(channel.name) for channel in msg.channels]
        try:
            layout = _resolved_layout(check_layout(layout), names)
        except InputError:
            return True
        return layout == 'vins_fusion' or _VINS_MONO_U in names or _VINS_MONO_V in names
    try:
        return _coordinate_fields([str(field.name) for field in msg.fields]) == ('u', 'v')
    except InputError:
        return True


def _coordinate_fields(names: list[str]) -> tuple[str, str]:
    """The fields of a PointCloud2's coordinates among its field ``names``: ``u``, ``v``
    (pixels), else ``x``, ``y`` (normalised coordinates)."""
    if 'u' in names and 'v' in names:
        return 'u', 'v'
    if 'x' in names and 'y' in names:
        return 'x', 'y'
    raise InputError(f'PointCloud2 has no u, v (or x, y) fields; fields: {names}')


def point_array(points: Any) -> np.ndarray:
    """(N, 3) float32 ``x, y, z`` of a PointCloud's points: ``Point32`` objects (rclpy, rosbags),
    or an (N, 3) array already (:mod:`~pearl_ros.bagio.cdr`)."""
    if isinstance(points, np.ndarray):
        return np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
    return np.array([(p.x, p.y, p.z) for p in points], dtype=np.float32).reshape(-1, 3)


def channels(msg: Any, dtype: Any) -> tuple[list[str], list[np.ndarray]]:
    """Names and values (as ``dtype``) of a PointCloud's channels, each one value per point.

    Raises
    ------
    InputError
        A channel whose length is not the point count.
    """
    num_points = len(msg.points)
    names = [str(channel.name) for channel in msg.channels]
    values = [np.asarray(channel.values, dtype=dtype) for channel in msg.channels]
    for name, column in zip(names, values, strict=True):
        if column.shape != (num_points,):
            raise InputError(
                f'PointCloud channel {name!r} has {column.size} values for {num_points} points'
            )
    return names, values


def decode_pointcloud2(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """Feature ids and coordinates of a ``sensor_msgs/msg/PointCloud2`` (``id``, ``u``, ``v``).

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        A rosbags or rclpy message object with fields ``id`` and ``u``, ``v`` (pixels) or, if those
        are absent, ``x``, ``y`` (normalised coordinates).

    Returns
    -------
    ids : (N,) int64
    uv : (N, 2) float64
        Pixels from ``u``, ``v``; else normalised coordinates from ``x``, ``y``. A cloud with no
        points gives zero features whatever its fields.

    Raises
    ------
    InputError
        Missing fields, a field outside the point, data shorter than the header says, non-integer
        or duplicate ids, non-finite coordinates.
    """
    if int(msg.height) * int(msg.width) == 0:
        return _empty()
    names = [str(field.name) for field in msg.fields]
    u_name, v_name = _coordinate_fields(names)
    if 'id' not in names:
        raise InputError(f'PointCloud2 has no id field; fields: {names}')
    columns = decode_fields(msg, ('id', u_name, v_name))
    ids = integer_ids(columns['id'], 'PointCloud2 field id')
    uv = np.column_stack((columns[u_name], columns[v_name])).astype(np.float64)
    check_features(ids, uv, 'PointCloud2')
    return ids, uv


def decode_labels(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """Feature ids and ground-truth labels of a PointCloud2 with fields ``id`` and ``label``.

    Returns
    -------
    ids : (N,) int64
    labels : (N,) int64
    """
    if int(msg.height) * int(msg.width) == 0:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    names = [str(field.name) for field in msg.fields]
    missing = [name for name in ('id', 'label') if name not in names]
    if missing:
        raise InputError(f'ground-truth PointCloud2 lacks field(s) {missing}; fields: {names}')
    columns = decode_fields(msg, ('id', 'label'))
    ids = integer_ids(columns['id'], 'ground-truth ids')
    labels = integer_ids(columns['label'], 'ground-truth labels')
    _check_unique(ids, 'ground-truth PointCloud2')
    return ids, labels


def decode_fields(msg: Any, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Columns ``names`` of a PointCloud2, read through a numpy structured dtype.

    The dtype is built from the message's own ``fields`` (offset, datatype), ``point_step`` and
    ``is_bigendian``, so padding and unknown fields are skipped. Rows are ``row_step`` bytes apart
    (organised clouds may pad rows).

    Returns
    -------
    dict of str -> (height * width,) array in native byte order
    """
    fields = {str(field.name): field for field in msg.fields}
    height, width = int(msg.height), int(msg.width)
    point_step = int(msg.point_step)
    order = '>' if msg.is_bigendian else '<'
    formats, offsets = [], []
    for name in names:
        if name not in fields:
            raise InputError(f'PointCloud2 has no field {name!r}; fields: {list(fields)}')
        field = fields[name]
        code = POINTFIELD_DTYPES.get(int(field.datatype))
        if code is None:
            raise InputError(f'PointCloud2 field {name!r} has unknown datatype {field.datatype}')
        if int(field.count) != 1:
            raise InputError(f'PointCloud2 field {name!r} has count {field.count}, expected 1')
        dtype = np.dtype(order + code)
        if int(field.offset) + dtype.itemsize > point_step:
            raise InputError(
                f'PointCloud2 field {name!r} (offset {field.offset}, {dtype.itemsize} bytes) '
                f'does not fit in point_step {point_step}'
            )
        formats.append(dtype)
        offsets.append(int(field.offset))
    point = np.dtype(
        {'names': list(names), 'formats': formats, 'offsets': offsets, 'itemsize': point_step}
    )
    if height * width == 0:
        columns = zip(names, formats, strict=True)
        return {name: np.empty(0, dtype=fmt.newbyteorder('=')) for name, fmt in columns}
    points = point_rows(msg).reshape(-1).view(point)
    columns = zip(names, formats, strict=True)
    return {name: points[name].astype(fmt.newbyteorder('=')) for name, fmt in columns}


def point_rows(msg: Any) -> np.ndarray:
    """The points of a PointCloud2 as ``(height * width, point_step)`` uint8 rows, row padding
    (``row_step`` beyond ``width * point_step``) dropped.

    Raises
    ------
    InputError
        ``row_step`` shorter than a row of points, ``data`` shorter than ``height * row_step``.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    data = _bytes(msg.data)
    if height * width and row_step < width * point_step:
        raise InputError(
            f'PointCloud2 row_step {row_step} < width {width} * point_step {point_step}'
        )
    if data.size < height * row_step:
        raise InputError(
            f'PointCloud2 data has {data.size} bytes, expected height {height} '
            f'* row_step {row_step}'
        )
    if height * width == 0:
        return np.empty((0, point_step), dtype=np.uint8)
    rows = data[: height * row_step].reshape(height, row_step)[:, : width * point_step]
    return np.ascontiguousarray(rows).reshape(height * width, point_step)


def integer_ids(values: np.ndarray, what: str) -> np.ndarray:
    """``values`` as int64, refusing non-finite or non-integer entries (ids sent as floats)."""
    values = np.asarray(values)
    if values.dtype.kind in 'iu':
        return values.astype(np.int64)
    if values.dtype.kind != 'f':
        raise InputError(f'{what} must be numbers, got dtype {values.dtype}')
    bad = ~np.isfinite(values) | (values != np.round(values))
    if bad.any():
        raise InputError(f'{what} must be integers, got {values[bad][:3].tolist()}')
    return values.astype(np.int64)


def check_features(ids: np.ndarray, uv: np.ndarray, what: str) -> None:
    """Ids unique, coordinates finite."""
    _check_unique(ids, what)
    if not np.isfinite(uv).all():
        raise InputError(f'{what} has non-finite coordinates')


def _check_unique(ids: np.ndarray, what: str) -> None:
    unique, counts = np.unique(ids, return_counts=True)
    if unique.size != ids.size:
        raise InputError(f'{what} repeats feature id(s) {unique[counts > 1][:5].tolist()}')


def _bytes(data: Any) -> np.ndarray:
    """A uint8 view of ``data``: numpy array (rosbags), array.array or bytes (rclpy), list."""
    try:
        return np.frombuffer(memoryview(data).cast('B'), dtype=np.uint8)
    except TypeError:
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def _empty() -> tuple[np.ndarray, np.ndarray]:
    return np.empty(0, dtype=np.int64), np.empty((0, 2), dtype=np.float64)

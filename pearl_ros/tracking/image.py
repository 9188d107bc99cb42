"""``sensor_msgs/Image`` <-> numpy, without cv_bridge (there is no wheel of it) and without ROS.

:func:`image_to_array` takes any object with the message's fields (``height``, ``width``,
``encoding``, ``is_bigendian``, ``step``, ``data``): an rclpy message, a rosbags one, or a plain
namespace. Rows may be padded (``step`` > ``width * bytes per pixel``); 16-bit data is read in the
message's byte order. :func:`array_to_image_fields` gives those fields back for building a message.
"""

from __future__ import annotations

import sys
from typing import Any, Literal

import cv2
import numpy as np

from pearl_ros.core.errors import InputError

# encoding -> (channels, dtype of one channel)
ENCODINGS: dict[str, tuple[int, np.dtype[Any]]] = {
    'mono8': (1, np.dtype(np.uint8)),
    'mono16': (1, np.dtype(np.uint16)),
    'bgr8': (3, np.dtype(np.uint8)),
    'rgb8': (3, np.dtype(np.uint8)),
    'bgra8': (4, np.dtype(np.uint8)),
    'rgba8': (4, np.dtype(np.uint8)),
}


def _layout(encoding: str) -> tuple[int, np.dtype[Any]]:
    try:
        return ENCODINGS[encoding]
    except KeyError:
        raise InputError(f'unsupported image encoding {encoding!r} '
                         f'(supported: {", ".join(ENCODINGS)})') from None


def image_to_array(msg: Any) -> np.ndarray:
    """The pixels of an image message as an array.

    Parameters
    ----------
    msg : object
        With the fields of ``sensor_msgs/Image``: ``height``, ``width``, ``encoding``,
        ``is_bigendian``, ``step`` (bytes per row, padding included) and ``data`` (bytes,
        array.array or a uint8 array).

    Returns
    -------
    (H, W) or (H, W, C) ndarray
        uint8 (mono8; bgr8, rgb8, bgra8, rgba8 in their channel order) or uint16 in native byte
        order (mono16); a new array, not a view of ``msg.data``.

    Raises
    ------
    InputError
        Unknown encoding, or ``step`` / ``data`` too short for ``height`` x ``width``.
    """
    encoding = str(msg.encoding)
    channels, dtype = _layout(encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise InputError(f'image step {step} is shorter than a row of {width} {encoding} pixels '
                         f'({row_bytes} bytes)')
    data = np.frombuffer(memoryview(msg.data).cast('B'), dtype=np.uint8)
    if data.size < step * height:
        raise InputError(f'image data holds {data.size} bytes, {height} rows of step {step} '
                         f'need {step * height}')
    rows = data[:step * height].reshape(height, step)[:, :row_bytes]
    order: Literal['<', '>'] = '>' if msg.is_bigendian else '<'
    pixels = np.ascontiguousarray(rows).view(dtype.newbyteorder(order))
    pixels = pixels.astype(dtype.newbyteorder('='), copy=True)
    return pixels.reshape((height, width) if channels == 1 else (height, width, channels))


def array_to_image_fields(array: np.ndarray, encoding: str) -> dict[str, Any]:
    """The fields of a ``sensor_msgs/Image`` holding ``array`` (rows not padded).

    Parameters
    ----------
    array : (H, W) or (H, W, C) ndarray
        uint8, or uint16 for ``mono16``; C as the encoding says (1 may be left out).
    encoding : str
        One of :data:`ENCODINGS`.

    Returns
    -------
    dict
        ``height``, ``width``, ``encoding``, ``is_bigendian`` (this machine's byte order, as
        cv_bridge does), ``step`` and ``data`` (bytes).
    """
    channels, dtype = _layout(encoding)
    array = np.asarray(array)
    if array.ndim == 3 and array.shape[2] == 1 and channels == 1:
        array = array[:, :, 0]
    expected = 2 if channels == 1 else 3
    if array.ndim != expected or (channels > 1 and array.shape[2] != channels):
        shape = '(H, W)' if channels == 1 else f'(H, W, {channels})'
        raise InputError(f'a {encoding} image must be of shape {shape}, got {array.shape}')
    if array.dtype != dtype:
        raise InputError(f'a {encoding} image must be of dtype {dtype}, got {array.dtype}')
    height, width = array.shape[:2]
    native = np.ascontiguousarray(array, dtype=dtype.newbyteorder('='))
    return {'height': height, 'width': width, 'encoding': encoding,
            'is_bigendian': int(sys.byteorder == 'big'),
            'step': width * channels * dtype.itemsize, 'data': native.tobytes()}


# encoding -> OpenCV conversion to grey, for those that need one
_TO_GRAY = {'bgr8': cv2.COLOR_BGR2GRAY, 'rgb8': cv2.COLOR_RGB2GRAY,
            'bgra8': cv2.COLOR_BGRA2GRAY, 'rgba8': cv2.COLOR_RGBA2GRAY}


def to_mono8(array: np.ndarray, encoding: str, shift: int = 8) -> np.ndarray:
    """The ``(H, W)`` uint8 grey image a tracker takes, from an array of :func:`image_to_array`.

    Colour is weighted as OpenCV does (0.299 R + 0.587 G + 0.114 B). mono16 is shifted right by
    ``shift`` bits and saturated: 8 maps the full 16-bit range (as cv_bridge), 4 a 12-bit camera's.
    """
    _layout(encoding)
    if not 0 <= shift <= 16:
        raise InputError(f'shift must be within 0..16 bits, got {shift!r}')
    if encoding == 'mono16':
        return np.minimum(np.asarray(array, dtype=np.uint16) >> shift, 255).astype(np.uint8)
    if encoding == 'mono8':
        return np.ascontiguousarray(array, dtype=np.uint8)
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(array, dtype=np.uint8),
                                   _TO_GRAY[encoding]))

"""sensor_msgs/Image <-> numpy: encodings, padded rows, byte order, one-line errors."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.tracking.image import array_to_image_fields, image_to_array, to_mono8


def _padded(array: np.ndarray, encoding: str, pad: int, bigendian: bool) -> SimpleNamespace:
    """A message built by hand (not by the code under test): rows padded with ``pad`` junk
    bytes, 16-bit values in the byte order asked for."""
    order = '>' if bigendian else '<'
    raw = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder(order))
    height = array.shape[0]
    rows = raw.view(np.uint8).reshape(height, -1)
    junk = np.full((height, pad), 0xAB, np.uint8)
    data = np.concatenate([rows, junk], axis=1)
    return SimpleNamespace(height=height, width=array.shape[1], encoding=encoding,
                           is_bigendian=int(bigendian), step=data.shape[1],
                           data=data.tobytes())


@pytest.mark.parametrize('encoding, shape, dtype', [
    ('mono8', (5, 7), np.uint8), ('bgr8', (5, 7, 3), np.uint8), ('rgb8', (4, 3, 3), np.uint8),
    ('bgra8', (3, 6, 4), np.uint8), ('mono16', (6, 5), np.uint16)])
@pytest.mark.parametrize('bigendian', [False, True])
def test_padded_rows_and_byte_order_read_back_the_pixels(encoding, shape, dtype, bigendian):
    rng = np.random.default_rng(3)
    array = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    out = image_to_array(_padded(array, encoding, pad=5, bigendian=bigendian))
    assert out.dtype == np.dtype(dtype) and out.dtype.isnative
    np.testing.assert_array_equal(out, array)


def test_big_endian_mono16_is_read_most_significant_byte_first():
    msg = SimpleNamespace(height=1, width=2, encoding='mono16', is_bigendian=1, step=4,
                          data=bytes([0x12, 0x34, 0x00, 0x01]))
    np.testing.assert_array_equal(image_to_array(msg), [[0x1234, 0x0001]])
    little = SimpleNamespace(**{**vars(msg), 'is_bigendian': 0})
    np.testing.assert_array_equal(image_to_array(little), [[0x3412, 0x0100]])


@pytest.mark.parametrize('encoding, shape, dtype', [
    ('mono8', (4, 9), np.uint8), ('bgr8', (2, 3, 3), np.uint8), ('rgba8', (2, 2, 4), np.uint8),
    ('mono16', (3, 4), np.uint16)])
def test_array_to_fields_to_array_round_trip(encoding, shape, dtype):
    rng = np.random.default_rng(5)
    array = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    fields = array_to_image_fields(array, encoding)
    itemsize = np.dtype(dtype).itemsize
    channels = shape[2] if len(shape) == 3 else 1
    assert fields['step'] == shape[1] * channels * itemsize
    assert len(fields['data']) == fields['step'] * shape[0]
    np.testing.assert_array_equal(image_to_array(SimpleNamespace(**fields)), array)


def test_rosbags_style_uint8_array_data_is_accepted():
    array = np.arange(12, dtype=np.uint8).reshape(3, 4)
    fields = array_to_image_fields(array, 'mono8')
    fields['data'] = np.frombuffer(fields['data'], np.uint8)
    np.testing.assert_array_equal(image_to_array(SimpleNamespace(**fields)), array)


def _one_line_error(call, *args) -> str:
    with pytest.raises(InputError) as info:
        call(*args)
    message = str(info.value)
    assert '\n' not in message
    return message


def test_unknown_encoding_is_a_one_line_error_naming_it():
    msg = SimpleNamespace(height=1, width=1, encoding='yuv422', is_bigendian=0, step=2,
                          data=b'\x00\x00')
    assert 'yuv422' in _one_line_error(image_to_array, msg)
    assert '32FC1' in _one_line_error(array_to_image_fields, np.zeros((2, 2), np.uint8), '32FC1')


def test_wrong_data_length_and_short_step_are_one_line_errors():
    fields = array_to_image_fields(np.zeros((4, 5), np.uint8), 'mono8')
    short = SimpleNamespace(**{**fields, 'data': fields['data'][:-1]})
    assert '19 bytes' in _one_line_error(image_to_array, short)
    narrow = SimpleNamespace(**{**fields, 'step': 4})
    assert 'step 4' in _one_line_error(image_to_array, narrow)


def test_array_of_the_wrong_shape_or_dtype_is_refused():
    assert 'shape' in _one_line_error(array_to_image_fields, np.zeros((2, 2), np.uint8), 'bgr8')
    assert 'dtype' in _one_line_error(array_to_image_fields, np.zeros((2, 2), np.uint8),
                                      'mono16')


def test_to_mono8_weighs_colours_and_shifts_16_bit():
    bgr = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]]], np.uint8)
    expected = np.rint(np.array([[0.114, 0.587, 0.299]]) * 255)
    np.testing.assert_allclose(to_mono8(bgr, 'bgr8'), expected, atol=1)
    np.testing.assert_array_equal(to_mono8(bgr[:, :, ::-1], 'rgb8'), to_mono8(bgr, 'bgr8'))
    rgba = np.concatenate([bgr[:, :, ::-1], np.full((1, 3, 1), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(to_mono8(rgba, 'rgba8'), to_mono8(bgr, 'bgr8'))
    deep = np.array([[0, 255, 4095, 65535]], np.uint16)
    np.testing.assert_array_equal(to_mono8(deep, 'mono16'), [[0, 0, 15, 255]])
    np.testing.assert_array_equal(to_mono8(deep, 'mono16', shift=4), [[0, 15, 255, 255]])
    assert 'shift' in _one_line_error(to_mono8, deep, 'mono16', 17)

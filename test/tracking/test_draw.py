"""The overlay: stable distinct motion colours, grey outliers, trails, count, input untouched."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.tracking.draw import GREY, PALETTE, Overlay, motions_text, to_bgr

HEIGHT, WIDTH = 120, 160


def _canvas(value: int = 40) -> np.ndarray:
    return np.full((HEIGHT, WIDTH, 3), value, np.uint8)


def _pixel(image: np.ndarray, uv) -> tuple[int, int, int]:
    u, v = np.round(uv).astype(int)
    return tuple(int(c) for c in image[v, u])


def test_a_motion_keeps_its_colour_across_frames_and_motions_differ():
    overlay = Overlay()
    ids = np.array([1, 2, 3, 4])
    labels = np.array([0, 0, 5, 5])
    seen = {0: set(), 5: set()}
    for t in range(6):
        uv = np.array([[40.0 + t, 60], [50 + t, 80], [110 - t, 60], [120 - t, 90]])
        out = overlay.draw(_canvas(), ids, uv, labels)
        for k, label in enumerate(labels):
            seen[int(label)].add(_pixel(out, uv[k]))
    assert len(seen[0]) == 1 and len(seen[5]) == 1
    assert seen[0] != seen[5]
    assert seen[0] | seen[5] <= set(PALETTE)


def test_outliers_and_undecided_features_are_grey():
    overlay = Overlay()
    uv = np.array([[30.0, 60], [90, 70], [130, 100]])
    out = overlay.draw(_canvas(), np.array([7, 8, 9]), uv, np.array([-1, 2, -1]))
    assert _pixel(out, uv[0]) == GREY == _pixel(out, uv[2])
    assert _pixel(out, uv[1]) in PALETTE


def test_motions_in_one_frame_all_get_distinct_colours_while_numbers_grow():
    overlay = Overlay()
    count = len(PALETTE)
    for start in (0, 3, 40):  # numbers of the online segmenter only grow
        labels = np.arange(start, start + count)
        uv = np.column_stack([10.0 + 12 * np.arange(count), np.full(count, 70.0)])
        out = overlay.draw(_canvas(), labels + 100, uv, labels)
        colours = {_pixel(out, p) for p in uv}
        assert len(colours) == count and colours <= set(PALETTE)


def test_output_has_the_input_size_and_the_input_is_not_modified():
    image = np.random.default_rng(1).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    before = image.copy()
    out = Overlay().draw(image, np.array([1]), np.array([[80.0, 60]]), np.array([0]))
    assert out.shape == image.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(image, before)
    assert not np.array_equal(out, image)


def test_a_trail_is_drawn_along_the_previous_positions():
    overlay = Overlay(trail=10)
    path = [np.array([[30.0 + 10 * t, 90.0]]) for t in range(5)]  # moving right, 10 px a frame
    for uv in path:
        out = overlay.draw(_canvas(), np.array([3]), uv, np.array([0]))
    colour = overlay.colour(0)
    # midway between earlier positions, away from the dot at the last one (radius 3)
    for u in (35, 45, 55, 65):
        assert _pixel(out, (u, 90)) == colour
    without = Overlay(trail=1).draw(_canvas(), np.array([3]), path[-1], np.array([0]))
    assert _pixel(without, (55, 90)) == (40, 40, 40)


def test_a_trail_is_cut_when_its_id_is_missing_for_a_frame():
    overlay = Overlay()
    overlay.draw(_canvas(), np.array([3]), np.array([[30.0, 90]]), np.array([0]))
    overlay.draw(_canvas(), np.array([4]), np.array([[100.0, 30]]), np.array([0]))
    out = overlay.draw(_canvas(), np.array([3]), np.array([[70.0, 90]]), np.array([0]))
    assert _pixel(out, (50, 90)) == (40, 40, 40)


def test_the_motion_count_is_written_in_a_corner():
    overlay = Overlay()
    uv = np.array([[60.0, 80], [90, 80], [120, 80], [140, 100]])
    out = overlay.draw(_canvas(), np.arange(4), uv, np.array([0, 4, 9, -1]))
    x0, y0, x1, y1 = overlay.legend_box
    assert x0 == 0 and y0 == 0 and x1 < WIDTH // 2 and y1 < HEIGHT // 2
    box = out[y0:y1 + 1, x0:x1 + 1]
    assert (box > 128).all(axis=2).sum() > 20  # light text on its dark box
    assert motions_text(3) == '3 motions' and motions_text(1) == '1 motion'
    # a different count writes different text
    other = Overlay().draw(_canvas(), np.arange(4), uv, np.array([0, 0, 0, -1]))
    assert not np.array_equal(other[y0:y1 + 1, x0:x1 + 1], box)


def test_features_outside_the_image_or_not_finite_are_skipped():
    uv = np.array([[np.nan, 10], [1e12, -1e12], [80, 60]])
    out = Overlay().draw(_canvas(), np.array([1, 2, 3]), uv, np.array([0, 0, 0]))
    assert _pixel(out, uv[2]) in PALETTE


def test_bad_inputs_are_refused_with_one_line():
    overlay = Overlay()
    with pytest.raises(InputError, match='one entry per feature'):
        overlay.draw(_canvas(), np.arange(3), np.zeros((2, 2)), np.zeros(3))
    with pytest.raises(InputError, match='uint8 bgr'):
        overlay.draw(np.zeros((5, 5), np.uint8), [], np.zeros((0, 2)), [])
    with pytest.raises(InputError, match='trail'):
        Overlay(trail=0)


@pytest.mark.parametrize('encoding, shape, dtype, code', [
    ('mono8', (4, 5), np.uint8, cv2.COLOR_GRAY2BGR),
    ('rgb8', (4, 5, 3), np.uint8, cv2.COLOR_RGB2BGR),
    ('rgba8', (4, 5, 4), np.uint8, cv2.COLOR_RGBA2BGR),
    ('bgra8', (4, 5, 4), np.uint8, cv2.COLOR_BGRA2BGR),
])
def test_to_bgr_converts_each_colour_encoding(encoding, shape, dtype, code):
    array = np.random.default_rng(2).integers(0, 256, shape).astype(dtype)
    out = to_bgr(array, encoding)
    assert out.shape == (4, 5, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out, cv2.cvtColor(array, code))
    if encoding == 'rgb8':  # channel order reversed, by hand
        np.testing.assert_array_equal(out, array[:, :, ::-1])


def test_to_bgr_keeps_bgr8_as_a_copy_and_scales_mono16_to_its_top_byte():
    bgr = np.random.default_rng(3).integers(0, 256, (3, 4, 3)).astype(np.uint8)
    out = to_bgr(bgr, 'bgr8')
    np.testing.assert_array_equal(out, bgr)
    assert not np.shares_memory(out, bgr)
    mono16 = np.array([[0, 255, 256, 65535]], np.uint16)
    np.testing.assert_array_equal(to_bgr(mono16, 'mono16')[0, :, 0], [0, 0, 1, 255])


def test_to_bgr_refuses_unknown_encodings_and_wrong_shapes():
    with pytest.raises(InputError, match='unsupported image encoding'):
        to_bgr(np.zeros((2, 2), np.uint8), 'yuv422')
    with pytest.raises(InputError, match=r'\(H, W, 3\)'):
        to_bgr(np.zeros((2, 2), np.uint8), 'rgb8')

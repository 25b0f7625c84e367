"""vision.greyscale: the one greyscale conversion and its convention for every dtype."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tympani.vision.greyscale import as_float_gray, is_float_gray, to_gray


def _frames():
    rng = np.random.default_rng(4)
    bgr = rng.integers(0, 256, (9, 11, 3), dtype=np.uint8)
    return bgr, np.dstack([bgr, rng.integers(0, 256, (9, 11), dtype=np.uint8)]), bgr[..., 1].copy()


def test_uint8_frames_are_opencvs_grey_levels_in_a_new_array():
    bgr, bgra, grey = _frames()
    np.testing.assert_array_equal(to_gray(bgr), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(to_gray(bgra), cv2.cvtColor(bgra, cv2.COLOR_BGRA2GRAY))
    np.testing.assert_array_equal(to_gray(bgr[:, ::-1]), cv2.cvtColor(np.ascontiguousarray(bgr[:, ::-1]), cv2.COLOR_BGR2GRAY))
    for image in (grey, grey[..., None]):
        out = to_gray(image)
        assert out.dtype == np.uint8 and out.flags.c_contiguous and not np.shares_memory(out, image)
        np.testing.assert_array_equal(out, grey)


def test_other_dtypes_follow_the_float_scale_rounded():
    bgr, _, grey = _frames()
    levels = np.arange(256, dtype=np.uint8)
    np.testing.assert_array_equal(to_gray(levels.astype(np.uint16)[None] * 257), levels[None])  # 0–65535 / 257
    np.testing.assert_array_equal(to_gray(np.array([[1, 128, 129, 65535]], np.uint16)), [[0, 0, 1, 255]])
    np.testing.assert_array_equal(to_gray(levels[None] / 255.0), levels[None])  # float 0–1
    np.testing.assert_array_equal(to_gray(levels[None].astype(np.float32)), levels[None])  # float 0–255
    np.testing.assert_array_equal(to_gray(np.array([[True, False]])), [[255, 0]])
    np.testing.assert_array_equal(to_gray(np.array([[-5, 300]], np.int32)), [[0, 255]])
    np.testing.assert_array_equal(to_gray(np.array([[np.nan, 0.5]])), [[0, 128]])
    np.testing.assert_array_equal(to_gray(bgr.astype(np.float64)), np.rint(as_float_gray(bgr)).astype(np.uint8))
    assert np.abs(to_gray(bgr.astype(np.float64)).astype(int) - to_gray(bgr)).max() <= 1
    with pytest.raises(ValueError):
        to_gray(np.zeros((4, 4, 2), np.uint8))


def test_as_float_gray_keeps_sub_grey_level_precision():
    img = np.linspace(0.0, 1.0, 320)[None, :].repeat(4, axis=0)
    out = as_float_gray(img)
    assert out.dtype == np.float32 and is_float_gray(out)
    assert np.allclose(out[0, :3], [0.0, 255.0 / 319, 2 * 255.0 / 319], atol=1e-3)
    again = as_float_gray(out)
    np.testing.assert_array_equal(again, out)
    assert not np.shares_memory(again, out)
    assert not is_float_gray(img) and not is_float_gray(out / 255.0)


def test_measurement_keeps_uint8_and_float_precision():
    from tympani.vision.angles.measure import _grey_levels

    bgr, _, grey = _frames()
    np.testing.assert_array_equal(_grey_levels(bgr), to_gray(bgr))
    assert _grey_levels(grey).dtype == np.uint8
    merged = grey.astype(np.float32) * 0.75 + 0.25
    np.testing.assert_array_equal(_grey_levels(merged), merged)

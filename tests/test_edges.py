"""Tests of vision.edges: greyscale conversion, Canny with automatic thresholds, segments.

Synthetic images with exact truth (a disc, an anti-aliased step), drawn here with OpenCV and
NumPy rather than by the renderer.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tympani.vision.edges import (
    auto_sigma,
    auto_thresholds,
    canny_edges,
    detect_edges,
    edge_segments,
    gradient_magnitude,
    noise_gradient,
    orientation_field,
    remove_short_segments,
    subpixel_edges,
)
from tympani.vision.greyscale import as_float_gray, to_gray

H, W = 240, 320


def _disc(radius: float = 60.0, centre=(160.3, 119.6), inside: float = 200.0, outside: float = 60.0) -> np.ndarray:
    """Float image (0–255) of an anti-aliased disc (4x supersampled)."""
    k = 4
    yy, xx = np.mgrid[0 : H * k, 0 : W * k]
    x = (xx + 0.5) / k - 0.5
    y = (yy + 0.5) / k - 0.5
    big = np.where(np.hypot(x - centre[0], y - centre[1]) <= radius, inside, outside).astype(np.float32)
    return cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA)


def _ring_distance(mask: np.ndarray, radius: float = 60.0, centre=(160.3, 119.6)) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.abs(np.hypot(xs - centre[0], ys - centre[1]) - radius)


# --------------------------------------------------------------------------- greyscale


def test_to_gray_accepts_bgr_grey_float_uint16_bool_and_bgra():
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (H, W), dtype=np.uint8)
    bgr = np.dstack([grey, grey, grey])
    assert to_gray(grey) is not None and to_gray(grey).dtype == np.uint8
    np.testing.assert_array_equal(to_gray(bgr), grey)
    np.testing.assert_array_equal(to_gray(np.dstack([bgr, np.full_like(grey, 255)])), grey)
    np.testing.assert_array_equal(to_gray(grey[..., None]), grey)
    assert np.abs(to_gray(grey / 255.0).astype(int) - grey).max() <= 1  # float in 0–1
    assert np.abs(to_gray(grey.astype(np.float32)).astype(int) - grey).max() <= 1  # float in 0–255
    assert np.abs(to_gray(grey.astype(np.uint16) * 257).astype(int) - grey).max() <= 1
    assert set(np.unique(to_gray(grey > 128))) <= {0, 255}
    with pytest.raises(ValueError):
        to_gray(np.zeros((4, 4, 2)))


def test_as_float_gray_keeps_sub_grey_level_precision():
    img = np.linspace(0.0, 1.0, W, dtype=np.float64)[None, :].repeat(H, axis=0)
    out = as_float_gray(img)
    assert out.dtype == np.float32
    assert np.allclose(out[0, :3], np.array([0.0, 255.0 / (W - 1), 2 * 255.0 / (W - 1)]), atol=1e-3)


# --------------------------------------------------------------------------- Canny


@pytest.mark.parametrize("kind", ["uint8", "float01", "float255", "bgr"])
def test_canny_finds_a_disc_outline_for_integer_and_float_input(kind):
    """Every edge pixel lies within 1 px of the true circle and the outline is complete
    (scikit-image's Canny test, on the dtypes whose handling has broken before)."""
    img = _disc()
    variants = {
        "uint8": np.clip(np.rint(img), 0, 255).astype(np.uint8),
        "float01": img / 255.0,
        "float255": img,
        "bgr": np.dstack([np.clip(np.rint(img), 0, 255).astype(np.uint8)] * 3),
    }
    mask = canny_edges(variants[kind], sigma_px=1.0)
    assert mask.dtype == bool and mask.shape == (H, W)
    d = _ring_distance(mask)
    assert len(d) > 0.9 * 2 * np.pi * 60  # one-pixel-wide closed outline
    assert d.max() <= 1.0


def test_canny_is_the_same_for_uint8_and_float_input():
    img8 = np.clip(np.rint(_disc()), 0, 255).astype(np.uint8)
    a = canny_edges(img8)
    b = canny_edges(img8.astype(np.float32) / 255.0)
    assert (a ^ b).sum() <= 0.02 * a.sum()


def test_canny_thresholds_follow_contrast_and_brightness():
    """The same scene at a third of the contrast and a different brightness gives the same edges."""
    img = _disc()
    dim = 0.3 * img + 100.0
    a, b = canny_edges(img), canny_edges(dim)
    assert (a & b).sum() >= 0.95 * a.sum()


def test_blank_and_smoothly_shaded_frames_have_no_edges():
    assert not canny_edges(np.full((H, W), 128, np.uint8)).any()
    ramp = np.linspace(60, 200, W, dtype=np.float32)[None, :].repeat(H, axis=0)
    yy, xx = np.mgrid[0:H, 0:W]
    vignette = ramp * (1.0 - 0.4 * ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / (W * W / 4))
    assert not canny_edges(vignette).any()


def test_noise_alone_gives_few_long_edges():
    """White noise (sd 10 grey levels) leaves few edges of 10 px or more (measured: 0.22 % of the
    pixels)."""
    rng = np.random.default_rng(1)
    noise = np.clip(rng.normal(128, 10, (H, W)), 0, 255).astype(np.uint8)
    em = detect_edges(noise, sigma_px=auto_sigma(noise), min_length_px=10)
    assert em.mask.mean() < 0.005


def test_explicit_thresholds_are_used():
    img = _disc()
    em = detect_edges(img, low=5.0, high=10.0)
    assert (em.low, em.high) == (5.0, 10.0)
    assert not canny_edges(img, high=1e4).any()
    with pytest.raises(ValueError):
        detect_edges(img, low=20.0, high=10.0)


def test_auto_thresholds_and_noise_gradient():
    rng = np.random.default_rng(2)
    mag = np.hypot(rng.normal(0, 1.0, 100_000), rng.normal(0, 1.0, 100_000))  # Rayleigh, sigma 1
    assert noise_gradient(mag) == pytest.approx(np.sqrt(2 * np.log(2)), rel=0.05)  # its median
    low, high = auto_thresholds(mag)
    assert high == pytest.approx(3.5 * np.sqrt(2 * np.log(2)), rel=0.05) and low < high
    assert auto_thresholds(np.zeros(1000)) == pytest.approx((0.45 * 0.8, 0.8))


def test_auto_sigma_grows_with_noise_but_not_with_dense_structure():
    rng = np.random.default_rng(3)
    clean = np.clip(np.rint(_disc()), 0, 255).astype(np.uint8)
    noisy = np.clip(_disc() + rng.normal(0, 10, (H, W)), 0, 255).astype(np.uint8)
    grid = np.full((H, W), 180, np.uint8)
    for k in range(0, W, 20):  # about half the pixels see a grid line's gradient
        cv2.line(grid, (k, 0), (k, H), 60, 2)
    for k in range(0, H, 20):
        cv2.line(grid, (0, k), (W, k), 60, 2)
    assert auto_sigma(clean) == 1.0
    assert auto_sigma(noisy) > 1.5
    assert auto_sigma(grid) == 1.0


# --------------------------------------------------------------------------- sub-pixel, orientation


@pytest.mark.parametrize("x0", [100.0, 100.3, 100.5, 100.8])
def test_subpixel_edges_locate_a_step_to_a_tenth_of_a_pixel(x0):
    cols = np.arange(W, dtype=np.float32)
    coverage = np.clip(cols + 0.5 - x0, 0.0, 1.0)  # pixel j spans [j - 0.5, j + 0.5]
    img = np.repeat((50.0 + 150.0 * coverage)[None, :], H, axis=0)
    pts, nrm = subpixel_edges(detect_edges(img, sigma_px=1.0))
    inner = (pts[:, 1] > 10) & (pts[:, 1] < H - 10)
    assert inner.sum() > 0.9 * (H - 20)
    assert np.abs(pts[inner, 0] - x0).max() < 0.1
    assert np.allclose(nrm[inner], [1.0, 0.0], atol=1e-3)  # dark to bright, along +x


def test_orientation_field_adds_both_sides_of_a_line():
    """Doubled angles: the two opposite edges of a thin line reinforce; perpendicular ones cancel."""
    pts = np.array([[10.0, 10.0], [10.0, 10.0], [20.0, 20.0], [20.0, 20.0]])
    nrm = np.array([[1.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    fld = orientation_field(pts, nrm, (32, 32))
    assert fld[10, 10, 0] == pytest.approx(2.0) and fld[10, 10, 1] == pytest.approx(0.0)
    assert np.abs(fld[20, 20]).max() < 1e-6


# --------------------------------------------------------------------------- segments


def test_edge_segments_keep_long_curves_and_drop_specks():
    edges = np.zeros((H, W), np.uint8)
    cv2.line(edges, (10, 10), (300, 10), 1, 1)  # 291 px
    cv2.circle(edges, (160, 120), 50, 1, 1)  # ~280 px closed curve
    cv2.line(edges, (20, 200), (60, 200), 1, 1)  # 41 px
    rng = np.random.default_rng(4)
    for x, y in rng.integers(0, [W, H], size=(40, 2)):
        edges[y, x] = 1  # specks
    segs = edge_segments(edges, min_length_px=30)
    assert len(segs) == 3
    lengths = [len(s) for s in segs]
    assert lengths == sorted(lengths, reverse=True)
    assert segs[-1][:, 1].min() == 200 and segs[-1].shape[1] == 2  # (x, y) columns
    kept = remove_short_segments(edges, min_length_px=30)
    assert kept.sum() == sum(lengths)
    assert edge_segments(np.zeros((H, W), np.uint8), min_length_px=5) == []


def test_gradient_magnitude_does_not_depend_on_where_its_output_lies():
    """The same derivatives give the same magnitude bit for bit, however the allocator lays out
    memory before the call (OpenCV's vectorised path treats the output's unaligned ends apart)."""
    rng = np.random.default_rng(5)
    gx, gy = (rng.normal(0.0, 20.0, (480, 640)).astype(np.float32) for _ in range(2))
    first = gradient_magnitude(gx, gy)
    for pad in range(1, 9):  # shift where the next arrays go
        spacer = np.empty(pad * 8 + 3, np.uint8)
        again = gradient_magnitude(gx, gy)
        assert again.ctypes.data % 64 == 0
        assert np.array_equal(again, first)
        del spacer
    np.testing.assert_allclose(first, np.hypot(gx, gy), rtol=1e-6)

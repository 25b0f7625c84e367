"""Frames and edges: merging the frames of a static view (gain-normalised median or mean),
the derivatives Canny runs on, and the edge points and orientation fields the search and the
fits sample."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from tympani.vision.greyscale import as_float_gray
from tympani.vision.edges import (
    EdgeMap,
    doubled_angles,
    gradient_magnitude,
    gradients,
    sigma_from_magnitude,
    splat_vector_sets,
    subpixel_edges,
)
from tympani.vision.registration.config import RegistrationError


def frame_list(frames: list[np.ndarray] | np.ndarray) -> list[np.ndarray]:
    """One frame (grey or colour) or several, as a non-empty list."""
    if isinstance(frames, np.ndarray) and (frames.ndim == 2 or (frames.ndim == 3 and frames.shape[2] in (1, 3, 4))):
        frames = [frames]
    frames = list(frames)
    if not frames:
        raise RegistrationError("no frames given")
    return frames


def combine_frames(frames: list[np.ndarray] | np.ndarray, how: str = "median") -> np.ndarray:
    """Merge frames of a static view into one float32 grey image (0–255 scale).

    Parameters
    ----------
    frames : list of ndarray, or one ndarray
        Frames (grey or BGR, any dtype :func:`tympani.vision.greyscale.as_float_gray` accepts), same size.
    how : {"median", "mean", "first"}
        Per-pixel median (default: keeps the static walls, drops what moves, such as the
        array), mean, or only the first frame. Each frame's global gain is normalised first,
        so lighting flicker does not enter.

    Returns
    -------
    ndarray of float32, shape (h, w)
    """
    frames = frame_list(frames)
    grey8 = [np.asarray(f) for f in frames]
    grey8 = [np.ascontiguousarray(f[:, :, 0] if f.ndim == 3 and f.shape[2] == 1 else f) for f in grey8]
    if how == "median" and len(grey8) % 2 == 1 and len(grey8) > 1 and all(
        f.dtype == np.uint8 and f.ndim == 2 for f in grey8
    ):
        if any(f.shape != grey8[0].shape for f in grey8):
            raise ValueError("frames differ in size")
        # the float frames are needed only for their means: one at a time
        merged = _median_scaled_uint8(grey8, _gains([float(as_float_gray(f).mean()) for f in grey8]))
        return np.clip(merged, 0.0, 255.0, out=merged)
    greys = [as_float_gray(f) for f in frames]
    shape = greys[0].shape
    if any(g.shape != shape for g in greys):
        raise ValueError("frames differ in size")
    if len(greys) == 1 or how == "first":
        return greys[0]
    gains = _gains([float(g.mean()) for g in greys])
    merged = _reduce_scaled(greys, gains, _median_frames if how == "median" else _mean_frames)
    return np.clip(merged, 0.0, 255.0, out=merged)


def _gains(means: list[float]) -> list[float]:
    """Factors (dimensionless) that bring each frame's mean grey level to their median."""
    ref = float(np.median(means))
    return [ref / m if m > 1e-6 else 1.0 for m in means]


def _mean_frames(stack: np.ndarray) -> np.ndarray:
    """Per-pixel mean over the first axis of ``stack`` (grey levels)."""
    return stack.mean(axis=0)


def _reduce_scaled(
    greys: list[np.ndarray],
    gains: list[float],
    reduce: Callable[[np.ndarray], np.ndarray],
    block_rows: int = 32,
) -> np.ndarray:
    """``reduce`` over the frames, each times its gain, per pixel.

    Products and reduction are in float64 and the result is rounded to float32 once. The
    work goes in blocks of ``block_rows`` rows, so the scaled copies stay in the cache
    instead of making one float64 stack of all frames (a few MB).

    Parameters
    ----------
    greys : list of ndarray of float32, shape (h, w)
        Frames (grey levels).
    gains : list of float
        Factor (dimensionless) of each frame.
    reduce : callable
        Maps an ``(n, rows, w)`` float64 stack to its ``(rows, w)`` per-pixel statistic.
    block_rows : int
        Rows per block.

    Returns
    -------
    ndarray of float32, shape (h, w)
    """
    h, w = greys[0].shape
    out = np.empty((h, w), np.float32)
    block = np.empty((len(greys), block_rows, w), np.float64)
    for r0 in range(0, h, block_rows):
        r1 = min(r0 + block_rows, h)
        for i, (g, k) in enumerate(zip(greys, gains)):
            np.multiply(g[r0:r1], k, out=block[i, : r1 - r0], dtype=np.float64)
        out[r0:r1] = reduce(block[:, : r1 - r0])
    return out


def _median_scaled_uint8(frames: list[np.ndarray], gains: list[float], block_rows: int = 32) -> np.ndarray:
    """Per-pixel median of an odd number of 8-bit frames, each times its gain.

    Equal to ``_reduce_scaled(greys, gains, _median_frames)``: each frame's products are
    formed in float64 by a 256-entry table and rounded to float32 at once. Rounding is
    monotonic, so the median (an order statistic) of the rounded products is the rounded
    median of the exact ones. Table look-up and median run in blocks of ``block_rows``
    rows, which stay in the cache (no full-size scaled copies).

    Parameters
    ----------
    frames : list of ndarray of uint8, shape (h, w)
        Grey frames (grey levels); an odd number of them.
    gains : list of float
        Factor (dimensionless) of each frame.
    block_rows : int
        Rows per block.

    Returns
    -------
    ndarray of float32, shape (h, w)
    """
    levels = np.arange(256, dtype=np.float64)
    tables = [(levels * k).astype(np.float32) for k in gains]
    h, w = frames[0].shape
    out = np.empty((h, w), np.float32)
    block = np.empty((len(frames), block_rows, w), np.float32)
    for r0 in range(0, h, block_rows):
        r1 = min(r0 + block_rows, h)
        for f, table, scaled in zip(frames, tables, block):
            cv2.LUT(f[r0:r1], table, dst=scaled[: r1 - r0])
        out[r0:r1] = _median_frames(block[:, : r1 - r0])
    return out


def _median3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Element-wise median of three arrays without NaNs (min/max only, so exact).

    ``cv2.min``/``cv2.max`` (about a fifth faster than NumPy's on blocks of frame rows) take
    equal-shaped 2-D arrays, as the frames are.
    """
    return cv2.max(cv2.min(a, b), cv2.min(cv2.max(a, b), c))


def _median_frames(stack: np.ndarray | list[np.ndarray]) -> np.ndarray:
    """Per-pixel median over the first axis of ``stack`` (grey levels), equal to ``np.median``.

    ``stack`` is an ``(n, h, w)`` array or a list of ``n`` equal-shaped ``(h, w)`` arrays
    (grey frames or blocks of their rows, without NaNs).

    Three and five frames (the registration's default) take a min/max selection network (a
    dozen passes over the image, no sort); other odd counts one ``np.partition`` (the median
    is one of the values); even counts ``np.median``.
    """
    n = len(stack)
    if n not in (3, 5) and not isinstance(stack, np.ndarray):
        stack = np.stack(stack)
    if n == 3:
        return _median3(stack[0], stack[1], stack[2])
    if n == 5:  # the 2nd and 3rd of the first four, then the median of those and the fifth
        a, b, c, d, e = stack
        return _median3(cv2.max(cv2.min(a, b), cv2.min(c, d)), cv2.min(cv2.max(a, b), cv2.max(c, d)), e)
    if n % 2 == 0:
        return np.median(stack, axis=0)
    return np.partition(stack, n // 2, axis=0)[n // 2]


@dataclass(frozen=True)
class Edges:
    """Edge data of the merged frame, with the fields the search and the fits sample."""

    edge_map: EdgeMap
    points: np.ndarray  # (n, 2) sub-pixel edge points (px)
    pyramid: list[np.ndarray]  # smoothed doubled-angle fields, level L at scale 2^-L
    signed: np.ndarray  # (h, w, 2) smoothed field of signed unit gradient directions


def gradients_for_canny(
    gray: np.ndarray, sigma_px: float | None
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray | None]:
    """Derivatives (grey levels per px) of ``gray`` smoothed for Canny, and the smoothing (px).

    ``sigma_px`` None picks the smoothing from the noise (:func:`tympani.vision.edges.auto_sigma`);
    the 1 px derivatives that takes, and their magnitude, are reused when it keeps 1 px
    (clean frames) rather than computed again. The last item is ``gradient_magnitude(gx, gy)``
    when it was computed on the way, else None.
    """
    if sigma_px is None:
        gx, gy = gradients(gray, 1.0)
        magnitude = gradient_magnitude(gx, gy)
        sigma_px = sigma_from_magnitude(magnitude)
        if sigma_px == 1.0:
            return gx, gy, sigma_px, magnitude
    gx, gy = gradients(gray, sigma_px)
    return gx, gy, float(sigma_px), None


def prepare_edges(em: EdgeMap, levels: int) -> Edges:
    """Sub-pixel points and the orientation fields of the Canny edges of one (merged) frame."""
    pts, nrm = subpixel_edges(em)
    # orientation_field(pts, nrm, ...) and splat_vectors(pts, nrm, ...) in one pass
    fld, signed = splat_vector_sets(pts, [doubled_angles(nrm), nrm], em.shape)
    # each level is shrunk from the unsmoothed one above; all are smoothed in place at the
    # end (new full-size images cost more in page faults than the filtering itself)
    pyramid = [fld]
    for _ in range(levels):
        h, w = pyramid[-1].shape[:2]
        if min(h, w) < 16:
            break
        cur = cv2.resize(pyramid[-1], ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA)
        cur *= 2.0
        pyramid.append(cur)
    for image in pyramid + [signed]:
        cv2.GaussianBlur(image, (0, 0), 0.7, dst=image)
    return Edges(em, pts, pyramid, signed)

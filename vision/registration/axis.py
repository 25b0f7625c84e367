"""Which copy of doubled walls is the wall the array runs in: the straight array outside the
entry lies on the insertion axis, so its centre line, measured across the axis, sits on the axis
of the true copy and off the other's by the parallax's component across it."""

from __future__ import annotations

import math

import cv2
import numpy as np

from tympani.vision.geometry import CameraPose, Phantom, entry_frame

# Stretch of the insertion axis (mm back from the entry's outer end) where the array is sought:
# outside the phantom, clear of its walls; at least a few mm of array stay outside at any depth.
_OUTSIDE_MM = (0.5, 6.0)
# Half width (mm) of each profile across the axis.
_ACROSS_MM = 1.5
# The array's width (mm) seen between its two edges: its diameters, with room for blur.
_WIDTH_MM = (0.4, 1.5)
# Fewest stations (share of those in view) with an edge pair, and the largest spread (mm, robust
# SD) of their centres, for the array's centre to be taken as measured.
_MIN_SHARE = 0.4
_MAX_SPREAD_MM = 0.15
# Least move (px and mm) of the axis across itself for the array to tell the copies apart: our
# renderer's arrays lie up to 1.7 px (0.07 mm) off the axis as measured.
_MIN_ACROSS_PX = 3.0
_MIN_ACROSS_MM = 0.15


def array_axis_offset(gray: np.ndarray, pose: CameraPose, phantom: Phantom, step_px: float = 1.0) -> float:
    """Offset (px, along the entry's outward normal in the image) of the straight array's centre
    line from the insertion axis of ``pose``, outside the entry; NaN where it does not show as a
    consistent pair of edges.

    Parameters
    ----------
    gray : ndarray
        A frame (2-D, grey levels).
    pose : CameraPose
        The walls' pose.
    phantom : Phantom
        Geometry (the entry and its axis).
    step_px : float
        Spacing (px) of the stations along the axis.

    Returns
    -------
    float
        The median, over stations in view, of the midpoint between the strongest falling and
        the strongest rising edge across the axis, where they are an array's width apart; NaN
        with too few such stations or too much spread among them.
    """
    origin, x_w, normal = entry_frame(phantom)
    back = origin - phantom.entry_length_mm * x_w
    ppm = float(pose.px_per_mm)
    along = np.arange(_OUTSIDE_MM[0], _OUTSIDE_MM[1], step_px / ppm)
    across = np.arange(-_ACROSS_MM, _ACROSS_MM + 1e-9, 0.5 / ppm)
    pts = back[None, None, :] - along[:, None, None] * x_w + across[None, :, None] * normal
    img = pose.to_image(pts.reshape(-1, 2)).reshape(len(along), len(across), 2).astype(np.float32)
    h, w = gray.shape[:2]
    inside = ((img[..., 0] >= 0) & (img[..., 0] <= w - 1) & (img[..., 1] >= 0) & (img[..., 1] <= h - 1)).all(axis=1)
    if np.count_nonzero(inside) < 5:
        return math.nan
    prof = cv2.remap(np.asarray(gray, dtype=np.float32), img[inside, :, 0], img[inside, :, 1], cv2.INTER_LINEAR)
    grad = np.gradient(cv2.GaussianBlur(prof, (0, 0), sigmaX=1.0, sigmaY=1.0), axis=1)
    down, up = np.argmin(grad, axis=1), np.argmax(grad, axis=1)
    width = np.abs(across[up] - across[down])
    pair = (width >= _WIDTH_MM[0]) & (width <= _WIDTH_MM[1])
    if np.count_nonzero(pair) < max(5, _MIN_SHARE * len(prof)):
        return math.nan
    centre = 0.5 * (across[up] + across[down])[pair]
    mid = float(np.median(centre))
    if 1.4826 * float(np.median(np.abs(centre - mid))) > _MAX_SPREAD_MM:
        return math.nan
    return mid * ppm


def beyond_array_precision(offset_px: float, px_per_mm: float) -> bool:
    """Whether an offset (px) across the insertion axis is larger than the array outside the entry
    tells apart: at least :data:`_MIN_ACROSS_PX` and :data:`_MIN_ACROSS_MM` (at ``px_per_mm``,
    px/mm); False for NaN."""
    return bool(abs(offset_px) >= max(_MIN_ACROSS_PX, _MIN_ACROSS_MM * px_per_mm))


def second_copy_is_the_wall(gray: np.ndarray, pose: CameraPose, shift: tuple[float, float],
                            phantom: Phantom) -> bool:
    """Whether the array outside the entry lies on the second copy's axis rather than the first's.

    Parameters
    ----------
    gray : ndarray
        A frame (2-D, grey levels).
    pose : CameraPose
        The first copy's pose.
    shift : tuple of float
        The second copy's image shift (px, x right, y down).
    phantom : Phantom
        Geometry.

    Returns
    -------
    bool
        True when the shift moves the axis across itself by at least :data:`_MIN_ACROSS_PX` and
        :data:`_MIN_ACROSS_MM` and the array's centre (:func:`array_axis_offset`) lies within a
        quarter of that of the second copy's axis; False otherwise (including an array not
        found or out of view).
    """
    origin, _, normal = entry_frame(phantom)
    ends = pose.to_image(np.array([origin, origin + normal]))
    n_img = (ends[1] - ends[0]) / max(float(np.hypot(*(ends[1] - ends[0]))), 1e-12)
    delta = float(n_img @ np.asarray(shift, dtype=float))
    if not beyond_array_precision(delta, float(pose.px_per_mm)):
        return False
    offset = array_axis_offset(gray, pose, phantom)
    return bool(np.isfinite(offset) and 0.75 <= offset / delta <= 1.25)

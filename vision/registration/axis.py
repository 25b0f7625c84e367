"""Which copy of doubled walls is the wall the array runs in: the straight array outside the
entry lies on the insertion axis, so its centre line, measured across the axis, sits on the axis
of the true copy and off the other's by the parallax's component across it. A fit whose axis
the array lies off is a cue to seek the other copy where the array lies."""

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
# renderer's arrays lie up to 3 px (0.08 mm) off the axis as measured.
_MIN_ACROSS_PX = 3.0
_MIN_ACROSS_MM = 0.15
# Choosing between two copies already found: how far (mm, and _MIN_ACROSS_PX) the array must lie
# off the first copy's axis (our renderer's lie up to 0.08 mm off as measured), and how much
# nearer (px) the second's.
_NEAR_MIN_MM = 0.10
_NEAR_MARGIN_PX = 0.5


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


def _at_least(offset_px: float, px_per_mm: float, min_mm: float) -> bool:
    """Whether ``offset_px`` (px) is at least :data:`_MIN_ACROSS_PX` and ``min_mm`` (mm, at
    ``px_per_mm`` px/mm) in size; False for NaN."""
    return bool(abs(offset_px) >= max(_MIN_ACROSS_PX, min_mm * px_per_mm))


def beyond_array_precision(offset_px: float, px_per_mm: float) -> bool:
    """Whether an offset (px) across the insertion axis is larger than the array outside the entry
    tells apart: at least :data:`_MIN_ACROSS_PX` and :data:`_MIN_ACROSS_MM` (at ``px_per_mm``,
    px/mm); False for NaN."""
    return _at_least(offset_px, px_per_mm, _MIN_ACROSS_MM)


def off_the_axis(offset_px: float, px_per_mm: float) -> bool:
    """Whether the array lies off a copy's axis by enough (px, at ``px_per_mm`` px/mm) to say
    the other copy may be the wall: at least :data:`_MIN_ACROSS_PX` and :data:`_NEAR_MIN_MM`;
    False for NaN."""
    return _at_least(offset_px, px_per_mm, _NEAR_MIN_MM)


def axis_normal(pose: CameraPose, phantom: Phantom) -> np.ndarray:
    """The entry's outward normal in the image of ``pose`` (unit vector, x right, y down): the
    direction :func:`array_axis_offset` measures along."""
    origin, _, normal = entry_frame(phantom)
    ends = pose.to_image(np.array([origin, origin + normal]))
    return (ends[1] - ends[0]) / max(float(np.hypot(*(ends[1] - ends[0]))), 1e-12)


def nearer_second_copy(offset_px: float, delta_px: float, px_per_mm: float) -> bool:
    """Whether the array lies off the first copy's axis and clearly nearer the second's.

    Parameters
    ----------
    offset_px : float
        The array's offset (px) from the first copy's axis (:func:`array_axis_offset`).
    delta_px : float
        The second copy's axis offset (px) from the first's, along the same normal.
    px_per_mm : float
        Scale (px/mm).

    Returns
    -------
    bool
        True when the array is off the first copy's axis (:func:`off_the_axis`) and nearer
        the second's by at least :data:`_NEAR_MARGIN_PX`; False for NaN.
    """
    if not off_the_axis(offset_px, px_per_mm):
        return False
    return bool(abs(offset_px - delta_px) <= abs(offset_px) - _NEAR_MARGIN_PX)


def copy_offsets(gray: np.ndarray, pose: CameraPose, shift: tuple[float, float],
                 phantom: Phantom) -> tuple[float, float]:
    """Where the array outside the entry lies against two copies of the walls.

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
    offset : float
        The array's centre line off the first copy's axis (px, :func:`array_axis_offset`; NaN
        where it does not show).
    delta : float
        The second copy's axis off the first's (px), along the same normal.
    """
    delta = float(axis_normal(pose, phantom) @ np.asarray(shift, dtype=float))
    return array_axis_offset(gray, pose, phantom), delta


def second_copy_is_the_wall(offset_px: float, delta_px: float, px_per_mm: float) -> bool:
    """Whether the array outside the entry lies on the second copy's axis rather than the first's
    (offsets as :func:`copy_offsets` gives them, at ``px_per_mm`` px/mm).

    Returns
    -------
    bool
        True when the copies' axes are at least :data:`_MIN_ACROSS_PX` and :data:`_MIN_ACROSS_MM`
        apart and the array's centre lies within a quarter of that of the second copy's axis;
        False otherwise (including an array not found or out of view).
    """
    if not beyond_array_precision(delta_px, px_per_mm):
        return False
    return bool(np.isfinite(offset_px) and 0.75 <= offset_px / delta_px <= 1.25)

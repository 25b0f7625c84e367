"""Verification: how well the walls of a pose lie on Canny edges of matching orientation
(:class:`WallFit`), on the whole frame or on a crop of a new one (:func:`wall_fit`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from tympani.vision.edges import EdgeMap, detect_edges
from tympani.vision.greyscale import as_float_gray, to_gray
from tympani.vision.geometry import DEFAULT_PHANTOM, CameraPose, Phantom
from tympani.vision.registration.config import Registration, RegistrationConfig
from tympani.vision.registration.model import WallModel, wall_model
from tympani.vision.registration.poses import image_points


# Largest distance (px) looked for between a wall and its edge when measuring residuals.
# Larger reaches let noise edges stand in for faint walls (and a median over them swing).
_REACH_PX = 5.0
# Scale (px/mm) above which :func:`check` works on a shrunk crop, to stay fast.
_CHECK_MAX_PX_PER_MM = 20.0
# An edge pixel belongs to a wall when its gradient is within 30° of the wall normal.
COS_ALIGNED = math.cos(math.radians(30.0))


@dataclass(frozen=True)
class WallFit:
    """How well the model walls of a pose lie on image edges.

    Distances are measured along each wall's normal, from where the wall's edge is expected
    (at ``±half_width`` for the two polarities, see :func:`refine_signed`) to the nearest
    Canny edge pixel whose gradient is within 30° of the normal, looked for up to 5 px away.

    Parameters
    ----------
    residual_px : float
        The largest, over the wall groups mostly in view (:class:`WallModel`), of the
        median distance (px) of the walls whose edge was found within 5 px (5 px if fewer
        than a quarter were). About 0.2–0.6 px for a good fit; faint or occluded walls do
        not raise it, a displaced pose does, and so does a rotation about the spiral centre,
        which the self-similar spiral alone would hide, through the entry and first half-turn.
    inlier_fraction : float
        Fraction of visible wall points within the inlier tolerance.
    visible_fraction : float
        Fraction of wall points inside the frame.
    matched_length_mm : float
        Wall length (mm) of the inliers.
    """

    residual_px: float
    inlier_fraction: float
    visible_fraction: float
    matched_length_mm: float


def edge_layers(em: EdgeMap) -> np.ndarray:
    """(h, w, 2) float32 unit gradient directions on edge pixels, zero elsewhere."""
    idx = np.flatnonzero(em.mask)
    inv = np.float32(1.0) / np.maximum(em.magnitude.ravel()[idx], np.float32(1e-12))
    layers = np.zeros(em.shape + (2,), np.float32)
    flat = layers.reshape(-1, 2)  # a view: edge pixels are written in place
    flat[idx, 0] = em.gx.ravel()[idx] * inv
    flat[idx, 1] = em.gy.ravel()[idx] * inv
    return layers


def _edge_distances(
    layers: np.ndarray,
    pts: np.ndarray,
    nrm: np.ndarray,
    half_width: float | None,
    reach: float,
    second: np.ndarray | None = None,
    half_width2: float | None = None,
    offset: float = 0.0,
    fringe: float = 0.0,
) -> np.ndarray:
    """Distance (px) along each normal from a wall's expected edge to the nearest edge pixel.

    Only edge pixels whose gradient is within 30° of the normal count. With ``half_width``
    given, an edge whose gradient points out of the channel is expected at ``+half_width``
    and one pointing in at ``-half_width``; with ``None``, any aligned edge counts from the
    wall itself. ``second`` (px, one per point), for doubled walls: the offset along the
    normal of the wall's second copy, whose edges are expected as far from it; an edge counts
    from the nearer copy, the second copy's at ``±half_width2`` (px; None: as the first's).
    Lines whose centres lie ``offset`` (px) outside the channel's edge have their edges that much
    further out. Fringed walls (``fringe`` != 0, px): an edge whose gradient points out of the
    channel when ``fringe > 0`` (into it when ``< 0``) is expected at ``±|fringe|``, the nearer of
    the two, and an edge of the other polarity at the wall itself. Walls without an edge within
    ``reach`` get ``reach``.
    """
    hw = abs(fringe) if half_width is None else max(abs(half_width), abs(half_width2 or 0.0)) + abs(fringe)
    lo, hi = -reach - hw + min(offset, 0.0), reach + hw + max(offset, 0.0)
    if second is not None and len(second):
        lo, hi = lo + min(float(second.min()), 0.0), hi + max(float(second.max()), 0.0)
    t = np.arange(lo, hi + 1e-9, 0.5, dtype=np.float32)
    h, w = layers.shape[:2]
    px, py = pts[:, 0:1].astype(np.float32), pts[:, 1:2].astype(np.float32)
    nx, ny = nrm[:, 0:1].astype(np.float32), nrm[:, 1:2].astype(np.float32)
    # the pixels the normal passes through, and their exact offsets along it (the arrays are
    # n x len(t): the arithmetic goes in place where it can)
    ix, iy = nearest_pixels(px, nx, t, w), nearest_pixels(py, ny, t, h)
    along = ix - px  # float64
    along *= nx
    along_y = iy - py
    along_y *= ny
    along += along_y
    prof = np.take(layers.reshape(-1, 2), iy * w + ix, axis=0)  # = layers[iy, ix], faster
    proj = prof[..., 0] * nx  # cos of the angle, 0 off edges
    proj += prof[..., 1] * ny
    expected = np.float32(offset) + (0.0 if half_width is None else np.where(proj > 0, np.float32(half_width),
                                                                            np.float32(-half_width)))
    if fringe:
        # the pair's nearer edge for the fringe's polarity, the wall itself for the other
        side = np.where(along > expected, np.float32(abs(fringe)), np.float32(-abs(fringe)))
        expected = expected + np.where(proj * np.float32(fringe) > 0, side, np.float32(0.0))
    dist = along - expected
    if second is not None:
        dist2 = dist - second[:, None].astype(np.float32)
        if half_width is not None and half_width2 is not None:
            dist2 += expected
            dist2 -= np.where(proj > 0, np.float32(half_width2), np.float32(-half_width2))
            dist2 -= np.float32(offset)
        dist = np.minimum(np.abs(dist), np.abs(dist2))
    np.abs(dist, out=dist)
    stray = along - t  # distance from the sample's own offset
    np.abs(stray, out=stray)
    dist[(np.abs(proj) < COS_ALIGNED) | (stray > 1.0) | (dist > reach)] = np.inf
    return dist.min(axis=1)


def nearest_pixels(start: np.ndarray, step: np.ndarray, t: np.ndarray, size: int) -> np.ndarray:
    """Index (px) of the pixel nearest to ``start + t * step`` along one axis (float32
    ``(n, 1)``, ``(len(t),)`` and ``(n, 1)`` arrays), clipped to ``[0, size - 1]``.

    Samples off the image read the border, which :func:`_edge_distances`'s offset test then
    rejects as too far or misaligned.
    """
    pos = t * step
    pos += start
    np.rint(pos, out=pos)
    index = pos.astype(np.intp)
    return np.clip(index, 0, size - 1, out=index)


def _median(values: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D array without NaNs (same value, less overhead).

    The middle order statistic, or the mean (in the array's dtype) of the two middle ones.
    """
    k = len(values) // 2
    if len(values) % 2:
        return float(np.partition(values, k)[k])
    return float(np.mean(np.partition(values, [k - 1, k])[k - 1 : k + 1]))


def _summarise(
    dist: np.ndarray,
    group: np.ndarray,
    n_total: int,
    group_sizes: np.ndarray,
    tol: float,
    spacing_mm: float,
    reach: float = _REACH_PX,
) -> WallFit:
    """:class:`WallFit` from the distances (px, inf where no edge) of the visible wall points."""
    if len(dist) == 0:
        return WallFit(float("inf"), 0.0, 0.0, 0.0)
    n_vis = np.bincount(group, minlength=len(group_sizes))
    medians = []
    for g in range(len(group_sizes)):
        if n_vis[g] < max(10, 0.4 * group_sizes[g]):
            continue  # mostly out of view
        found = dist[(group == g) & np.isfinite(dist)]
        # walls whose edge is missing (faint, occluded) do not count, unless most are missing
        medians.append(min(_median(found), reach) if len(found) >= 0.25 * n_vis[g] else reach)
    inlier = dist <= tol
    return WallFit(
        residual_px=max(medians) if medians else float(np.median(np.minimum(dist, reach))),
        inlier_fraction=float(inlier.mean()),
        visible_fraction=len(dist) / max(n_total, 1),
        matched_length_mm=float(inlier.sum() * spacing_mm),
    )


def wall_fit_from(
    pose: CameraPose,
    layers: np.ndarray,
    model: WallModel,
    half_width: float | None,
    tol: float,
    parallax_px: np.ndarray | None = None,
    half_width2: float | None = None,
    offset: float = 0.0,
    fringe: float = 0.0,
) -> WallFit:
    """:class:`WallFit` of ``pose`` against a full-frame edge layer image; with
    ``parallax_px`` (px, image x and y), the walls' second copy that far away counts too, its
    lines ``half_width2`` (px; None: ``half_width``) wide; the lines' centres ``offset`` (px)
    outside the channel's edge; ``fringe`` (px) as :func:`_edge_distances` says."""
    pts, nrm = image_points(pose, model)
    h, w = layers.shape[:2]
    vis = (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
    reach = max(_REACH_PX, tol)
    second = None if parallax_px is None else nrm[vis] @ np.asarray(parallax_px, dtype=float)
    dist = _edge_distances(layers, pts[vis], nrm[vis], half_width, reach, second, half_width2, offset, fringe)
    sizes = np.bincount(model.group, minlength=4)
    return _summarise(dist, model.group[vis], len(pts), sizes, tol, model.spacing_mm, reach)


def check_walls(
    pose: CameraPose, model: WallModel, spacing_px: float = 2.0, max_points: int = 600
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Wall points (px), normals, groups and group sizes for :func:`check`.

    ``model`` is :func:`wall_model` (0.02 mm spacing), thinned to about ``spacing_px`` (px)
    between points and at most about ``max_points`` points.
    """
    model = model.subsample(max(spacing_px / pose.px_per_mm, model.length_mm / max_points))
    pts, nrm = image_points(pose, model)
    return pts, nrm, model.group, np.bincount(model.group, minlength=4)


def _crop_fit(
    frame: np.ndarray,
    walls: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    sigma_px: float,
    px_per_mm: float,
    half_width: float,
    tol: float,
    parallax_px: np.ndarray | None = None,
    offset: float = 0.0,
    fringe: float = 0.0,
) -> WallFit:
    """:class:`WallFit` with Canny run only on the bounding box of the visible walls (and of
    their second copy ``parallax_px`` away, px, when the walls are doubled), their lines'
    centres ``offset`` (px) outside the channel's edge, fringed as ``fringe`` (px) says
    (:func:`_edge_distances`).

    The crop is shrunk when the scale is large (distances are reported in full-resolution
    px), which keeps :func:`check` at a few milliseconds.
    """
    pts, nrm, group, sizes = walls
    h, w = frame.shape[:2]
    vis = (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
    if not vis.any():
        return WallFit(float("inf"), 0.0, 0.0, 0.0)
    pts, nrm, group = pts[vis], nrm[vis], group[vis]
    shift = np.zeros(2) if parallax_px is None else np.asarray(parallax_px, dtype=float)
    margin = int(math.ceil(3.0 * sigma_px + _REACH_PX + abs(half_width) + abs(offset) + abs(fringe)
                           + np.abs(shift).max())) + 2
    x0, y0 = np.maximum(np.floor(pts.min(axis=0)).astype(int) - margin, 0)
    x1, y1 = np.minimum(np.ceil(pts.max(axis=0)).astype(int) + margin + 1, [w, h])
    crop = frame[y0:y1, x0:x1]
    crop = to_gray(crop) if crop.dtype == np.uint8 else as_float_gray(crop)
    local = pts - [x0, y0]
    f = 1.0
    if px_per_mm > _CHECK_MAX_PX_PER_MM * 1.05:
        ch, cw = crop.shape
        shrink = _CHECK_MAX_PX_PER_MM / px_per_mm
        size = (max(1, int(round(cw * shrink))), max(1, int(round(ch * shrink))))
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
        f = size[0] / cw
        local = (local + 0.5) * f - 0.5
    em = detect_edges(crop, sigma_px=max(sigma_px * f, 0.7))
    second = None if parallax_px is None else (nrm @ shift) * f
    dist = _edge_distances(edge_layers(em), local, nrm, half_width * f, _REACH_PX * f, second, offset=offset * f,
                           fringe=fringe * f) / f
    n_total = int(sizes.sum())
    return _summarise(dist, group, n_total, sizes, tol, 0.0)


def wall_fit(
    gray: np.ndarray,
    registration: Registration,
    phantom: Phantom = DEFAULT_PHANTOM,
    cfg: RegistrationConfig = RegistrationConfig(),
) -> WallFit:
    """Fit statistics of a registration on a frame (edges detected afresh on its region).

    Parameters
    ----------
    gray : ndarray, shape (h, w) or (h, w, 3)
        Frame (grey or BGR, any dtype :func:`tympani.vision.greyscale.as_float_gray` accepts).
    registration : Registration
        Pose, line half width, edge smoothing and doubled walls to test.
    phantom : Phantom
        Phantom geometry.
    cfg : RegistrationConfig
        Inlier tolerance.

    Returns
    -------
    WallFit
        ``matched_length_mm`` is not computed (0).
    """
    key = (phantom, registration.pose)
    walls = registration._check_cache.get(key)
    if walls is None:
        walls = check_walls(registration.pose, wall_model(phantom, spacing_mm=0.02))
        registration._check_cache.clear()
        registration._check_cache[key] = walls
    hw = registration.line_half_width_px
    return _crop_fit(
        np.asarray(gray),
        walls,
        registration.edge_sigma_px,
        registration.pose.px_per_mm,
        hw if np.isfinite(hw) else 0.0,
        cfg.inlier_tol_px,
        np.asarray(registration.parallax_px, dtype=float) if registration.walls_doubled else None,
        registration.line_offset_px if np.isfinite(registration.line_offset_px) else 0.0,
        registration.fringe_px,
    )

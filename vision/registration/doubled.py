"""Doubled walls: every wall seen twice, the second copy shifted by one image vector (a
thick plate's top and bottom edges seen at an angle). The copies are started from the shift
surface of a single-copy fit or from how the lines' width varies with their direction, fitted
together, and kept only when the second copy's edges are found. Wall lines, doubled or single
(:func:`lines_beside_the_edge`), may also lie beside the channel's edge rather than on it: a
band of the plate catching the light."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import Enum

import cv2
import numpy as np

from tympani.vision.geometry import CameraPose
from tympani.vision.registration.axis import nearer_second_copy, second_copy_is_the_wall
from tympani.vision.registration.config import RegistrationConfig
from tympani.vision.registration.frames import Edges
from tympani.vision.registration.model import WallModel
from tympani.vision.registration.poses import image_points, similarity_jacobian, updated
from tympani.vision.registration.refine import (
    FIELD_BLUR_VAR,
    normal_profiles,
    profiles,
    refine_signed,
    solve_step,
    visible,
)
from tympani.vision.registration.valley import valley_pose, valley_scan
from tympani.vision.registration.verify import COS_ALIGNED, nearest_pixels, wall_fit_from


# Two edges of the same polarity closer than this (px) show as one: a doubled region
# boundary's two steps merge, and the merged edge is taken as the first (stronger) copy's.
_MERGE_PX = 2.5
# Two wall lines further apart than their width plus this gap (px) show their inner edges too.
_LINE_GAP_PX = 1.0
# A second copy's edge closer than this (px) to the first copy's is not counted as support.
_RESOLVED_PX = 1.0
# Doubled walls are reported when the second copy's resolved edges are expected at no fewer
# than this fraction of the visible wall points ...
_MIN_SECOND_SHOWN = 0.10
# ... and at least this fraction of them lies on an edge (single walls give 0.08–0.2 to a
# spurious shift, doubled ones 0.35–0.95).
_MIN_SECOND_MATCHED = 0.30
# Largest parallax (mm) looked for.
_MAX_PARALLAX_MM = 0.55
# Least parallax (mm) reported: a fit with its copies closer is taken for one (thicker) wall
# (render_c's and our renderer's parallax starts at 0.10 mm; single walls with a shadow or a
# soft region step beside their lines give 0.04–0.08 mm).
_MIN_PARALLAX_MM = 0.08
# :func:`_copy_starts` looks for a second copy off the first's edges only when the masked
# shift surface reaches this fraction of the unmasked one's maximum (single walls 0.07–0.46,
# median 0.18; doubled walls whose second copy is found that way 0.21–0.86).
_MIN_MASKED_RATIO = 0.18
# A line's width must vary by at least this much (px) with its direction, the variation
# explaining at least this fraction of the width's variance, for :func:`_copy_starts` to
# try two overlapping copies.
_MIN_WIDENING_PX = 1.5
_MIN_WIDENING_EXPLAINED = 0.4
# Half widths (px) of the wall lines tried by :func:`_surface_grid` (< 0: bright lines).
_SURFACE_HALF_WIDTHS = (-3.0, -1.5, 0.0, 1.5, 3.0)
# Motion blur along the shift smears each wall into two ridges that pass for two copies: the walls
# whose normal lies along the shift then have weaker edges than those across it, at both ridges.
# Below this ratio of their median peak gradients (the larger of the two copies') the copies are
# taken for a blurred single wall (renderer C: blurred 0.32-0.41; doubled walls 0.52-1.55, ours
# 0.80-1.02).
_MAX_BLUR_RATIO = 0.45
# Walls whose normal lies within about 30° of the copies' shift: |cos| above this.
_ALONG_COS = 0.85
# ... unless the lines' copies have the background between them: the level midway between them is
# at most this share of the lines' own (:func:`_filled_between`).
_MAX_FILLED = 0.3
# How far (px) a guided start's move across the insertion axis may differ from the array's.
_GUIDE_TOL_PX = 1.5
# Lines fitted off the channel's edge (_Copies.offset) replace lines on it only when they lie beside
# the edge: their inner edge no further than this (px) across it (bands drawn beside the edge:
# -0.5 to +0.5 px; off-centre lines that straddle it, below) ...
_MAX_STRADDLE_PX = 0.75
# ... and their median wall-to-edge distance is at most this share of the lines on the edge's, with
# no fewer walls on edges (an independent renderer's bright bands beside the edge: 0.17 px against
# 1.03 px). Lines that straddle the edge off centre (inner edge 0.8-1.6 px across it) fit a few
# renderers' walls better too, but move the scale either way by up to 1 %.
_OFFSET_GAIN = 0.7
# How much more of its expected edges (share) a guided second copy must find than the same
# shift turned by 90, 180 and 270 degrees does (their median: what a random shift finds, about a
# tenth on a harsh frame).
_MIN_GUIDED_EXCESS = 0.08


@dataclass(frozen=True)
class _Copies:
    """Doubled walls: the first copy's pose, its wall lines' half width (px, as
    :attr:`Registration.line_half_width_px`), the second copy's image shift (px), the
    second copy's half width (px; None: the first's) and how far (px) both copies' lines lie
    outside the channel's edge (as :attr:`Registration.line_offset_px`). The copies may look
    different: one a region boundary (half width 0), the other a line, or dark lines beside
    bright ones (half widths of opposite sign)."""

    pose: CameraPose
    half_width: float
    shift: tuple[float, float]
    second_half_width: float | None = None
    offset: float = 0.0

    @property
    def half_width2(self) -> float:
        """The second copy's half width (px)."""
        return self.half_width if self.second_half_width is None else self.second_half_width

    def swapped(self) -> "_Copies":
        """The same walls with the copies' roles exchanged."""
        dx, dy = self.shift
        return _Copies(self.pose.moved((dx, dy)), self.half_width2, (-dx, -dy), self.half_width, self.offset)


@dataclass(frozen=True)
class _Support:
    """Edges found where a two-copy fit expects them (counts over wall points and classes).

    ``matched2`` and ``shown2`` count only the second copy's edges at least
    :data:`_RESOLVED_PX` from the first copy's.
    """

    matched1: int
    shown1: int
    matched2: int
    shown2: int
    n_points: int

    @property
    def score(self) -> float:
        """Matched edges less a quarter of those expected (about the share a random shift
        matches), so that a shift onto stray edges does not pay."""
        return self.matched1 + self.matched2 - 0.25 * (self.shown1 + self.shown2)

    @property
    def first_rate(self) -> float:
        """Fraction of the first copy's shown edges found."""
        return self.matched1 / max(self.shown1, 1)

    @property
    def second_rate(self) -> float:
        """Fraction of the second copy's shown edges found."""
        return self.matched2 / max(self.shown2, 1)

    @property
    def second_is_real(self) -> bool:
        """Whether the second copy is expected at enough points and found at enough of them."""
        return self.shown2 >= _MIN_SECOND_SHOWN * self.n_points and self.matched2 >= _MIN_SECOND_MATCHED * self.shown2


def _copy_offsets(
    delta: np.ndarray, half_width: float, sign: float, lines: bool, half_width2: float | None = None,
    offset: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where one polarity class's edge of each copy is expected, and whether it shows.

    Parameters
    ----------
    delta : ndarray, shape (n,)
        Offset (px) of the second copy along each wall normal.
    half_width : float
        Half width (px) of the first copy's wall lines (< 0: bright lines).
    half_width2 : float, optional
        The second copy's (default: ``half_width``).
    sign : float
        The class: +1 for edges whose gradient points out of the channel, -1 into it.
    lines : bool
        Whether the walls are lines (an edge of each class) or region boundaries (one).
    offset : float
        How far (px) the lines' centres lie outside the channel's edge (along the normal).

    Returns
    -------
    e1, e2 : ndarray, shape (n,)
        Expected offsets (px, along the normals) of the first and the second copy's edge.
    shown1, shown2 : ndarray of bool, shape (n,)
        Whether each shows. Two lines that overlap (closer than their half widths plus
        :data:`_LINE_GAP_PX`) form one thicker line, which shows only the outer of the two
        edges of a class; a dark and a bright line that overlap show each their outer edges, and
        between them one edge of the class their near edges share, taken as the first's. A region
        boundary's second step shows only beyond :data:`_MERGE_PX`; nearer, the two merge into
        one edge, nearer the stronger copy.
    """
    h2 = half_width if half_width2 is None else half_width2
    e1 = np.full(delta.shape, offset + sign * half_width)
    e2 = offset + sign * h2 + delta
    if not lines:
        return e1, e2, np.ones(delta.shape, bool), np.abs(delta) > _MERGE_PX
    apart = np.abs(delta) > abs(half_width) + abs(h2) + _LINE_GAP_PX
    if half_width * h2 < 0:
        return e1, e2, np.ones(delta.shape, bool), apart | (sign * h2 * delta > 0)
    # this class's edge lies on the side sign * sign(half_width) of its line
    second_outer = sign * math.copysign(1.0, half_width + h2) * delta > 0
    return e1, e2, apart | ~second_outer, apart | second_outer


def _wall_classes(pose: CameraPose, sfield: np.ndarray, model: WallModel, reach_px: float = 4.0) -> tuple[float, ...]:
    """The edge polarity classes the walls show near ``pose``: ``(1.0, -1.0)`` for lines
    (an edge on each side), ``(1.0,)`` or ``(-1.0,)`` for region boundaries (gradient out of
    or into the channel).

    A class counts when its mean strongest response along the normals (within ``reach_px``,
    px) is at least 35 % of the other class's.
    """
    pts, nrm = image_points(pose, model)
    vis = visible(pts, sfield.shape)
    pts, nrm = pts[vis], nrm[vis]
    proj = normal_profiles(sfield, pts, nrm, np.arange(-reach_px, reach_px + 1e-9, 0.5))
    out_of, into = float(proj.max(axis=1).mean()), float((-proj).max(axis=1).mean())
    if min(out_of, into) >= 0.35 * max(out_of, into):
        return (1.0, -1.0)
    return (1.0,) if out_of > into else (-1.0,)


def _copy_edges(
    delta: np.ndarray, half_width: float, classes: tuple[float, ...], half_width2: float | None = None,
    offset: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every shown edge of doubled walls (:func:`_copy_offsets`), one row each.

    Parameters
    ----------
    delta : ndarray, shape (n,)
        Offset (px) of the second copy along each wall normal.
    half_width, half_width2 : float
        Half widths (px) of the first and the second copy's wall lines (``half_width2``
        None: the first's).
    classes : tuple of float
        Polarity classes shown (:func:`_wall_classes`).
    offset : float
        How far (px) the lines lie outside the channel's edge.

    Returns
    -------
    point : ndarray of int
        The wall point of each edge.
    sign : ndarray
        Its class (+1 or -1).
    second : ndarray of bool
        Whether it is the second copy's.
    expected : ndarray
        Its expected offset (px) along the normal.
    other : ndarray
        The other copy's edge of the class (px along the normal), NaN where that one does
        not show.
    """
    lines = len(classes) == 2
    parts = []
    for sign in classes:
        e1, e2, shown1, shown2 = _copy_offsets(delta, half_width, sign, lines, half_width2, offset)
        for e, other, shown, other_shown, second in ((e1, e2, shown1, shown2, False), (e2, e1, shown2, shown1, True)):
            rows = np.flatnonzero(shown)
            parts.append((rows, np.full(len(rows), sign), np.full(len(rows), second), e[rows],
                          np.where(other_shown[rows], other[rows], np.nan)))
    return tuple(np.concatenate([part[k] for part in parts]) for k in range(5))  # type: ignore[return-value]


def _refine_copies(
    copies: _Copies,
    sfield: np.ndarray,
    model: WallModel,
    classes: tuple[float, ...],
    *,
    sigma: float,
    iterations: int,
    max_half_width: float,
    max_shift_px: float,
    tol_px: float = 0.05,
    free_offset: bool = False,
) -> _Copies:
    """Polarity-aware refinement (as :func:`refine_signed`) of doubled walls: pose, each copy's
    line half width and the second copy's shift.

    Each class's edge of each copy is expected where :func:`_copy_offsets` puts it; a copy's
    edge that shows takes the samples within ``3 sigma`` (px) of it that are nearer to it than
    to the other copy's edge of the class (where that shows), and their Gaussian-weighted
    mean offset is one row of a weighted Gauss–Newton step (the second copy's rows also move
    the shift). The copies share one half width unless ``copies`` gives the second its own
    (:attr:`_Copies.second_half_width`). With ``free_offset``, lines also move together off
    the channel's edge (:attr:`_Copies.offset`: a bright band beside the edge, on the plate);
    region boundaries (one class) keep their half widths and offset.
    """
    gain = 1.0 + FIELD_BLUR_VAR / sigma**2
    u = np.arange(-3.0 * sigma, 3.0 * sigma + 1e-9, 0.5)
    kernel = np.exp(-0.5 * (u / sigma) ** 2)
    lines = len(classes) == 2
    pose, shift = copies.pose, np.asarray(copies.shift, dtype=float)
    half_width, half_width2, offset = copies.half_width, copies.half_width2, copies.offset
    alike = copies.second_half_width is None
    scale0 = pose.px_per_mm
    for _ in range(iterations):
        pts, nrm = image_points(pose, model)
        vis = visible(pts, sfield.shape)
        if np.count_nonzero(vis) < 20:
            break
        pts, nrm = pts[vis], nrm[vis]
        base, rho = similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        point, sign, second, expected, other = _copy_edges(nrm @ shift, half_width, classes, half_width2, offset)
        n = nrm[point]
        prof = profiles(sfield, pts[point] + expected[:, None] * n, n, u)
        a = prof[..., 0] * n[:, 0:1]
        a += prof[..., 1] * n[:, 1:2]
        a *= sign[:, None]
        np.maximum(a, 0.0, out=a)
        a *= kernel
        # samples nearer the other copy's edge of the class (where it shows) are the other's
        with np.errstate(invalid="ignore"):
            a[np.abs(expected[:, None] + u - other[:, None]) < np.abs(u)] = 0.0
        wsum = a.sum(axis=1)
        ok = wsum > 1e-3
        if np.count_nonzero(ok) < 20:
            break
        jac = np.zeros((np.count_nonzero(ok), 9))
        jac[:, :4] = base[point[ok]]
        if lines and alike:
            jac[:, 4] = sign[ok]
        elif lines:
            jac[:, 4] = sign[ok] * ~second[ok]
            jac[:, 5] = sign[ok] * second[ok]
        jac[:, 6:8] = n[ok] * second[ok, None]
        if lines and free_offset:
            jac[:, 8] = 1.0
        step = solve_step(jac, gain * (a @ u)[ok] / wsum[ok], wsum[ok], max_px=(max_half_width + 3.0 * sigma) * gain)
        if step is None:
            break
        pose = updated(pose, step[:4], rho)
        half_width = min(max(half_width + float(step[4]), -max_half_width), max_half_width)
        half_width2 = half_width if alike else min(max(half_width2 + float(step[5]), -max_half_width), max_half_width)
        shift = shift + step[6:8]
        offset = min(max(offset + float(step[8]), -max_half_width), max_half_width)
        length = float(np.hypot(*shift))
        if length > max_shift_px:
            shift *= max_shift_px / length
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break
        if float(np.abs(step).sum()) < tol_px:
            break
    return _Copies(pose, half_width, (float(shift[0]), float(shift[1])), None if alike else half_width2, offset)


def _class_edge_distances(
    layers: np.ndarray, pts: np.ndarray, nrm: np.ndarray, offsets: np.ndarray, sign: float, reach: float = 1.5
) -> np.ndarray:
    """Distance (px) along each normal from ``offsets`` to the nearest Canny edge pixel of
    polarity class ``sign`` (gradient within 30° of ``sign`` times the normal); ``inf``
    beyond ``reach`` (px)."""
    t = np.arange(-reach, reach + 1e-9, 0.5, dtype=np.float32)
    h, w = layers.shape[:2]
    start = pts + offsets[:, None] * nrm
    px, py = start[:, 0:1].astype(np.float32), start[:, 1:2].astype(np.float32)
    nx, ny = nrm[:, 0:1].astype(np.float32), nrm[:, 1:2].astype(np.float32)
    ix, iy = nearest_pixels(px, nx, t, w), nearest_pixels(py, ny, t, h)
    off = (ix - px) * nx + (iy - py) * ny  # from the expected edge
    prof = np.take(layers.reshape(-1, 2), iy * w + ix, axis=0)
    proj = sign * (prof[..., 0] * nx + prof[..., 1] * ny)
    dist = np.abs(off)
    dist[(proj < COS_ALIGNED) | (np.abs(off - t) > 1.0)] = np.inf
    return dist.min(axis=1)


def _copy_support(
    copies: _Copies, layers: np.ndarray, model: WallModel, classes: tuple[float, ...], tol_px: float = 1.0
) -> _Support:
    """:class:`_Support` of ``copies``: their expected edges with a Canny edge of the same
    class within ``tol_px`` (px).

    Where the walls are lines (two classes), the second copy has a look of its own
    (:attr:`_Copies.second_half_width`) and its edges of one class are found at no more than
    half the rate of the other's, the second copy is a region boundary (a single step) and only
    its found class counts for it.
    """
    pts, nrm = image_points(copies.pose, model)
    vis = visible(pts, layers.shape)
    pts, nrm = pts[vis], nrm[vis]
    delta = nrm @ np.asarray(copies.shift, dtype=float)
    resolved = np.abs(delta) >= _RESOLVED_PX
    counts = np.zeros((len(classes), 4), int)
    for k, sign in enumerate(classes):
        e1, e2, shown1, shown2 = _copy_offsets(delta, copies.half_width, sign, len(classes) == 2, copies.half_width2,
                                               copies.offset)
        found1 = _class_edge_distances(layers, pts, nrm, e1, sign) <= tol_px
        found2 = _class_edge_distances(layers, pts, nrm, e2, sign) <= tol_px
        shown2 &= resolved
        counts[k] = [np.count_nonzero(found1 & shown1), np.count_nonzero(shown1),
                     np.count_nonzero(found2 & shown2), np.count_nonzero(shown2)]
    total = counts.sum(axis=0)
    if len(classes) == 2 and copies.second_half_width is not None:
        rates = counts[:, 2] / np.maximum(counts[:, 3], 1)
        best = int(np.argmax(rates))
        if rates[1 - best] <= 0.5 * rates[best]:
            total[2:] = counts[best, 2:]
    return _Support(*(int(c) for c in total), n_points=len(pts))


def _copy_contrast(
    copies: _Copies, magnitude: np.ndarray, model: WallModel, classes: tuple[float, ...], min_edges: int = 10
) -> float:
    """Edge strength of the second copy relative to the first: ``exp`` of the sum over
    classes of the difference between the median log gradient magnitudes (``magnitude``,
    grey levels/px, the largest within ±0.5 px) at the two copies' shown edges, each at
    least :data:`_RESOLVED_PX` from the other copy's. NaN when no class has ``min_edges`` of
    each.

    Lines that overlap compare one copy's outer edge on one side with the other copy's on
    the other side: taken over the whole spiral, each class is seen on both sides.
    """
    pts, nrm = image_points(copies.pose, model)
    vis = visible(pts, magnitude.shape)
    pts, nrm = pts[vis], nrm[vis]
    delta = nrm @ np.asarray(copies.shift, dtype=float)
    resolved = np.abs(delta) >= _RESOLVED_PX
    t = np.array([-0.5, 0.0, 0.5])
    log_ratio, used = 0.0, False
    for sign in classes:
        e1, e2, shown1, shown2 = _copy_offsets(delta, copies.half_width, sign, len(classes) == 2, copies.half_width2,
                                               copies.offset)
        medians = []
        for e, shown in ((e1, shown1 & resolved), (e2, shown2 & resolved)):
            if np.count_nonzero(shown) < min_edges:
                break
            mag = profiles(magnitude, pts[shown] + e[shown, None] * nrm[shown], nrm[shown], t).max(axis=1)
            medians.append(float(np.median(np.log(np.maximum(mag, 1e-3)))))
        if len(medians) == 2:
            log_ratio += medians[1] - medians[0]
            used = True
    return float(math.exp(log_ratio)) if used else float("nan")


def _bin_sums(rows: np.ndarray, bins: np.ndarray, n_bins: int) -> np.ndarray:
    """Sum of the ``rows`` (shape (n, m)) that fall in each of ``n_bins`` bins (``bins``,
    shape (n,)); shape (n_bins, m)."""
    order = np.argsort(bins, kind="stable")
    counts = np.bincount(bins, minlength=n_bins)
    out = np.zeros((n_bins, rows.shape[1]))
    filled = counts > 0
    if filled.any():
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[filled]
        out[filled] = np.add.reduceat(rows[order], starts, axis=0)
    return out


@dataclass(frozen=True)
class _SurfaceGrid:
    """The shifts a shift surface is evaluated at, and where each normal-direction bin's
    evidence is read for them (:func:`_surface_grid`).

    Attributes
    ----------
    grid : ndarray, shape (m,)
        The shifts (px) of the surface's rows (y) and columns (x).
    t : ndarray
        Offsets (px) along the wall normals at which the evidence is sampled.
    half_widths : tuple of float
        Line half widths (px) tried (< 0: bright lines).
    reads : dict
        For each edge offset ``±h`` (px): the flat index into an ``(n_bins, len(t))`` table
        of the sample at or below each bin's edge for each shift, shape ``(n_bins, m * m)``,
        and the linear weight of the next sample.
    """

    grid: np.ndarray
    t: np.ndarray
    half_widths: tuple[float, ...]
    reads: dict[float, tuple[np.ndarray, np.ndarray]]


def _surface_grid(radius_px: float, classes: tuple[float, ...], n_bins: int = 48) -> _SurfaceGrid:
    """The :class:`_SurfaceGrid` of shifts ``v`` (px, ``|v_x|, |v_y| <= radius_px``) in steps
    of 1 px (more above 12 px of radius, so that the grid has at most 25 steps a side), for
    the half widths of :data:`_SURFACE_HALF_WIDTHS` (lines, two ``classes``) or 0 (region
    boundaries), with ``n_bins`` bins of normal direction over 360°.

    A shift ``v`` moves every edge of the bin centred on normal direction ``n`` by ``n·v``;
    the edge at offset ``±h`` is read at ``n·v ± h`` by linear interpolation between samples
    0.5 px apart.
    """
    half_widths = _SURFACE_HALF_WIDTHS if len(classes) == 2 else (0.0,)
    h_max = max(abs(h) for h in half_widths)
    reach = radius_px * math.sqrt(2.0) + h_max + 1.0
    t = np.arange(-reach, reach + 1e-9, 0.5)
    centre = (np.arange(n_bins) + 0.5) * (2.0 * np.pi / n_bins)
    step = max(1.0, radius_px / 12.0)
    grid = np.arange(-math.floor(radius_px / step), math.floor(radius_px / step) + 1) * step
    vx, vy = np.meshgrid(grid, grid)
    along = np.cos(centre)[:, None] * vx.ravel()[None, :] + np.sin(centre)[:, None] * vy.ravel()[None, :]
    row_start = (np.arange(n_bins) * len(t))[:, None]
    reads = {}
    for offset in sorted({h for h in half_widths} | {-h for h in half_widths}):
        idx = np.clip((along + offset + reach) * 2.0, 0.0, len(t) - 1.001)
        i0 = idx.astype(np.intp)
        reads[offset] = (i0 + row_start, idx - i0)
    return _SurfaceGrid(grid, t, half_widths, reads)


def _surface_tables(
    pose: CameraPose, sfield: np.ndarray, model: WallModel, classes: tuple[float, ...], t: np.ndarray, n_bins: int = 48
) -> np.ndarray:
    """The polarity-aware evidence of ``classes`` along the normals of the walls at ``pose``,
    summed over wall points of about the same normal direction.

    Parameters
    ----------
    pose : CameraPose
        The walls' pose.
    sfield : ndarray, shape (h, w, 2)
        Signed gradient field (grey levels/px).
    model : WallModel
        Wall points.
    classes : tuple of float
        Polarity classes shown (:func:`_wall_classes`).
    t : ndarray
        Offsets (px) along the normals.
    n_bins : int
        Bins of normal direction over 360°.

    Returns
    -------
    ndarray, shape (2, n_bins, len(t))
        Evidence (grey levels/px, summed) of edges whose gradient points out of the channel
        (first) and into it (second), zero for a class not shown.
    """
    pts, nrm = image_points(pose, model)
    vis = visible(pts, sfield.shape)
    pts, nrm = pts[vis], nrm[vis]
    proj = normal_profiles(sfield, pts, nrm, t)
    out_of = np.maximum(proj, 0.0) if 1.0 in classes else np.zeros_like(proj)
    into = np.maximum(-proj, 0.0) if -1.0 in classes else np.zeros_like(proj)
    angle = np.arctan2(nrm[:, 1], nrm[:, 0]) % (2.0 * np.pi)
    bins = np.minimum((angle * (n_bins / (2.0 * np.pi))).astype(int), n_bins - 1)
    return np.stack([_bin_sums(out_of, bins, n_bins), _bin_sums(into, bins, n_bins)])


def _masked_tables(tables: np.ndarray, t: np.ndarray, mask_half_width: float) -> np.ndarray:
    """:func:`_surface_tables` without the edges at ``±mask_half_width`` (px, within 1.5 px):
    the first class's evidence at ``+mask_half_width``, the second's at ``-mask_half_width``."""
    out = tables.copy()
    out[0][:, np.abs(t - mask_half_width) <= 1.5] = 0.0
    out[1][:, np.abs(t + mask_half_width) <= 1.5] = 0.0
    return out


def _shift_surface(tables: np.ndarray, sg: _SurfaceGrid) -> tuple[np.ndarray, np.ndarray]:
    """How well the walls of :func:`_surface_tables` moved by each shift of ``sg``
    (:func:`_surface_grid`) lie on edges: the evidence summed over the walls' bins, the first
    class read at ``+h`` and the second at ``-h``, for the best line half width ``h`` of
    ``sg.half_widths``.

    With :func:`_masked_tables`, the surface shows where else the walls have edges, e.g.
    their second copy.

    Returns
    -------
    surface : ndarray, shape (m, m)
        Evidence (arbitrary units), row index along y, column along x.
    half_width : ndarray, shape (m, m)
        The half width (px) that gave it.
    """
    evidence = {}
    for offset, (flat, frac) in sg.reads.items():
        for k in (0, 1):
            table = tables[k].ravel()
            evidence[k, offset] = (table.take(flat) * (1.0 - frac) + table.take(flat + 1) * frac).sum(axis=0)
    m = len(sg.grid)
    best = np.full(m * m, -np.inf)
    best_h = np.zeros(m * m)
    for h in sg.half_widths:
        total = np.zeros(m * m)
        total += evidence[0, h]
        total += evidence[1, -h]
        better = total > best
        best[better], best_h[better] = total[better], h
    return best.reshape(m, m), best_h.reshape(m, m)


def _surface_peaks(
    surface: np.ndarray, half_width: np.ndarray, grid: np.ndarray, n: int, min_shift_px: float = 0.0
) -> list[tuple[np.ndarray, float, float]]:
    """Up to ``n`` local maxima of a :func:`_shift_surface`, best first, at least
    ``min_shift_px`` (px) from zero shift: (shift (px, x and y), value relative to the
    surface's maximum, half width (px))."""
    top = float(surface.max())
    if not top > 0:
        return []
    values = surface.astype(np.float32)  # compared in the dilation's precision
    rows, cols = np.nonzero(values >= cv2.dilate(values, np.ones((3, 3), np.uint8)))
    out = []
    for r, c in sorted(zip(rows.tolist(), cols.tolist()), key=lambda rc: -surface[rc]):
        v = np.array([grid[c], grid[r]])
        if math.hypot(*v) >= min_shift_px:
            out.append((v, float(surface[r, c]) / top, float(half_width[r, c])))
            if len(out) == n:
                break
    return out


def _line_widening(
    pose: CameraPose, half_width: float, sfield: np.ndarray, model: WallModel, n_bins: int = 24, reach_px: float = 6.0
) -> tuple[np.ndarray, float]:
    """Second copy of wall lines too close to show apart, from how the lines' width varies
    with their direction.

    Two copies ``v`` (px) apart that overlap form one line widened by ``|n·v|`` where its
    normal is ``n``, the widening showing on the outer side of each polarity class's edge; a
    single line has the same width in every direction. The signed field is sampled along
    each wall normal, summed over wall points of about the same normal direction
    (``n_bins`` bins over 360°), and in each bin each class's edge is placed at its strongest
    evidence from 3 px inside to ``reach_px`` (px) outside its expected place (``±half_width``).
    The bins' widths ``w`` are fitted by ``w = c + A |cos(theta - phi)|`` (least squares
    weighted by the weaker class's evidence, ``phi`` in 5° steps).

    Returns
    -------
    shift : ndarray, shape (2,)
        ``A (cos phi, sin phi)`` (px): the second copy's shift, up to its sign.
    explained : float
        Fraction of the weighted variance of the widths the ``|cos|`` term explains (0–1).
    """
    pts, nrm = image_points(pose, model)
    vis = visible(pts, sfield.shape)
    pts, nrm = pts[vis], nrm[vis]
    if len(pts) < 4 * n_bins:
        return np.zeros(2), 0.0
    h = half_width
    t = np.arange(-abs(h) - reach_px - 1.0, abs(h) + reach_px + 1.0 + 1e-9, 0.5)
    proj = normal_profiles(sfield, pts, nrm, t)
    angle = np.arctan2(nrm[:, 1], nrm[:, 0]) % (2.0 * np.pi)
    bins = np.minimum((angle * (n_bins / (2.0 * np.pi))).astype(int), n_bins - 1)
    ends = []
    for sign, evidence in ((1.0, np.maximum(proj, 0.0)), (-1.0, np.maximum(-proj, 0.0))):
        sums = _bin_sums(evidence, bins, n_bins)
        # outward along t for this class's edge: the side sign * sign(h) of the line
        out = sign * (1.0 if h >= 0 else -1.0)
        u = out * (t - sign * h)
        window = (u >= -3.0) & (u <= reach_px)
        best = np.argmax(np.where(window[None, :], sums, -np.inf), axis=1)
        ends.append((u[best], sums[np.arange(n_bins), best]))
    widths = ends[0][0] + ends[1][0]
    weights = np.minimum(ends[0][1], ends[1][1])
    theta = (np.arange(n_bins) + 0.5) * (2.0 * np.pi / n_bins)
    wsum = float(weights.sum())
    if not wsum > 0:
        return np.zeros(2), 0.0
    mean = float(weights @ widths) / wsum
    total = float(weights @ (widths - mean) ** 2)
    best_fit = (0.0, 0.0, total)
    for phi in np.radians(np.arange(0.0, 180.0, 5.0)):
        x = np.abs(np.cos(theta - phi))
        xm = float(weights @ x) / wsum
        sxx = float(weights @ (x - xm) ** 2)
        if sxx <= 0:
            continue
        a = float(weights @ ((x - xm) * (widths - mean))) / sxx
        resid = total - a * a * sxx
        if a > 0 and resid < best_fit[2]:
            best_fit = (a, phi, resid)
    a, phi, resid = best_fit
    explained = 1.0 - resid / total if total > 0 else 0.0
    return np.array([a * math.cos(phi), a * math.sin(phi)]), float(explained)


def _own_look(half_width: float, half_width2: float) -> float | None:
    """The second copy's own half width (px) for :class:`_Copies` where it looks unlike the first
    (a region step, 0, or a line of the other polarity: the product not positive), else None
    (the copies share one)."""
    return half_width2 if half_width * half_width2 <= 0 else None


def _copy_starts(
    pose: CameraPose,
    half_width: float,
    sfield: np.ndarray,
    model: WallModel,
    classes: tuple[float, ...],
    cfg: RegistrationConfig,
    guide: tuple[np.ndarray, float] | None = None,
) -> tuple[list[tuple[_Copies, _Copies | None]], tuple[_Copies, _Copies | None] | None]:
    """Starting points for :func:`_refine_copies` from a single-copy fit ``pose`` (px), which
    may lie on either copy or between them, and with ``guide`` the start where the array says
    the other copy lies (:func:`_guided_start`; None without ``guide`` or where it finds none).

    Copies further apart than their edges' width: the strongest peak of
    :func:`_shift_surface` is taken as one copy and refined alone; with its edges masked
    (:func:`_masked_tables`, on the fit's own tables when that copy is the fit), the surface's
    best peak (two best, for region boundaries) proposes the other copy, unless
    the masked surface's maximum is below :data:`_MIN_MASKED_RATIO` of the unmasked one (no
    edges off the first copy's). Lines closer than that (one thicker line): when the line's
    width varies with its direction (:func:`_line_widening`: at least
    :data:`_MIN_WIDENING_PX` and :data:`_MIN_WIDENING_EXPLAINED` of the variance), the two
    copies ``∓ shift / 2`` either side of ``pose``. (Region boundaries that close merge into
    one edge, which shows no second copy to fit.) Each start comes as a pair: the copies alike
    (one half width), and where the surface's peak has the other polarity or a single step, the
    same shift with a look of its own for the second copy (else None).
    """
    lines = len(classes) == 2
    radius = _MAX_PARALLAX_MM * pose.px_per_mm + 2.0
    sparse = model.subsample(2.0 / pose.px_per_mm)  # enough wall to place the walls to a pixel
    sg = _surface_grid(radius, classes)
    tables = _surface_tables(pose, sfield, sparse, classes, sg.t)
    surface, widths = _shift_surface(tables, sg)
    starts = []
    own_masked = None  # the surface with the fit's own edges masked, and its half widths
    peaks = _surface_peaks(surface, widths, sg.grid, 1)
    if peaks:
        v, _, h = peaks[0]
        one, one_hw, one_tables = pose, half_width, tables
        if math.hypot(*v) >= 1.0:
            one, one_hw = refine_signed(
                pose.moved(v), h, sfield, model, cfg.final_sigma_px, 10, max_half_width=cfg.max_line_half_width_px
            )
            one_tables = _surface_tables(one, sfield, sparse, classes, sg.t)
        masked, masked_hw = _shift_surface(_masked_tables(one_tables, sg.t, one_hw), sg)
        if one is pose:
            own_masked = masked, masked_hw
        if float(masked.max()) >= _MIN_MASKED_RATIO * float(surface.max()):
            for shift, _, h2 in _surface_peaks(masked, masked_hw, sg.grid, 1 if lines else 2, min_shift_px=2.0):
                own = _own_look(one_hw, h2)
                starts.append((_Copies(one, one_hw, (float(shift[0]), float(shift[1]))),
                               None if own is None else _Copies(one, one_hw, (float(shift[0]), float(shift[1])), own)))
    if lines:
        shift, explained = _line_widening(pose, half_width, sfield, sparse)
        if math.hypot(*shift) >= _MIN_WIDENING_PX and explained >= _MIN_WIDENING_EXPLAINED:
            starts.append((_Copies(pose.moved(-0.5 * shift), 0.0, (float(shift[0]), float(shift[1]))), None))
    if guide is None:
        return starts, None
    if own_masked is None:
        own_masked = _shift_surface(_masked_tables(tables, sg.t, half_width), sg)
    return starts, _guided_start(pose, half_width, *own_masked, sg, guide)


def _guided_start(
    pose: CameraPose, half_width: float, masked: np.ndarray, masked_hw: np.ndarray, sg: _SurfaceGrid,
    guide: tuple[np.ndarray, float],
) -> tuple[_Copies, _Copies | None] | None:
    """A start for :func:`_refine_copies` where the array outside the entry says the other copy
    lies: ``guide`` is the image normal of the insertion axis and the array's offset (px) along
    it from ``pose``'s axis. The best shift of ``masked`` (the :func:`_shift_surface` of ``sg``
    with the fit's own edges masked; ``masked_hw`` its half widths, px) whose move across the
    axis is the array's (within :data:`_GUIDE_TOL_PX` or a quarter of it), as a pair like
    :func:`_copy_starts`'; None when no such shift shows any edges."""
    normal, offset = guide
    gx, gy = np.meshgrid(sg.grid, sg.grid)  # x = grid[column], y = grid[row]
    band = (np.abs(normal[0] * gx + normal[1] * gy - offset) <= max(_GUIDE_TOL_PX, 0.25 * abs(offset))) & (
        np.hypot(gx, gy) >= 2.0)
    r, c = np.unravel_index(np.argmax(np.where(band, masked, -np.inf)), masked.shape)
    if not (band[r, c] and masked[r, c] > 0):
        return None
    shift = (float(sg.grid[c]), float(sg.grid[r]))
    own = _own_look(half_width, float(masked_hw[r, c]))
    return _Copies(pose, half_width, shift), None if own is None else _Copies(pose, half_width, shift, own)


def _second_shows(copies: _Copies, support: _Support, layers: np.ndarray, model: WallModel,
                  classes: tuple[float, ...]) -> bool:
    """Whether the second copy of ``copies`` (with ``support`` on ``model``) shows at all:
    expected at enough points (:data:`_MIN_SECOND_SHOWN`) and found at
    :data:`_MIN_GUIDED_EXCESS` more of them than the same shift turned by 90°, 180° and 270°
    finds (the median of the three)."""
    if support.shown2 < _MIN_SECOND_SHOWN * support.n_points:
        return False
    dx, dy = copies.shift
    turned = [(-dy, dx), (-dx, -dy), (dy, -dx)]
    rates = [_copy_support(replace(copies, shift=t), layers, model, classes).second_rate
             for t in turned]
    return support.second_rate >= float(np.median(rates)) + _MIN_GUIDED_EXCESS


def _walls_along(pose: CameraPose, model: WallModel, shape: tuple[int, ...], shift: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The walls in view of an image of ``shape`` at ``pose``, points 1 px apart (px), their
    normals, and how nearly each normal lies along ``shift`` (px): ``|cos|`` of their angle."""
    pts, nrm = image_points(pose, model.subsample(1.0 / pose.px_per_mm))
    seen = visible(pts, shape)
    pts, nrm = pts[seen], nrm[seen]
    return pts, nrm, np.abs(nrm @ (shift / max(float(np.hypot(*shift)), 1e-9)))


def _blur_ratio(magnitude: np.ndarray, pose: CameraPose, model: WallModel, shift: np.ndarray,
                reach_px: float = 6.0) -> float:
    """How much weaker the walls' edges are along ``shift`` than across it, at one copy.

    Parameters
    ----------
    magnitude : ndarray
        Gradient magnitude of the frame.
    pose : CameraPose
        The copy's pose.
    model : WallModel
        The walls.
    shift : ndarray, shape (2,)
        The offset (px) between the copies.
    reach_px : float
        Half length (px) of the profile along each wall normal in which the peak is taken.

    Returns
    -------
    float
        Median peak gradient at walls whose normal is within about 30° of the shift, over that at
        walls within about 17° of perpendicular to it (dimensionless); 1 with fewer than 20
        walls of either.
    """
    pts, nrm, along = _walls_along(pose, model, magnitude.shape, shift)
    t = np.arange(-reach_px, reach_px + 1e-9, 0.5)
    peak = profiles(magnitude, pts, nrm, t).max(axis=1)
    hi, lo = peak[along > _ALONG_COS], peak[along < 0.3]
    if len(hi) < 20 or len(lo) < 20:
        return 1.0
    return float(np.median(hi) / max(float(np.median(lo)), 1e-9))


def _filled_between(gray: np.ndarray, copies: _Copies, model: WallModel, reach_px: float = 3.0) -> float:
    """How far the image between two copies of wall lines is as dark (or bright) as the lines.

    Along walls whose normal lies within about 30° of the shift, the grey level midway between
    the copies, less the level beside the first copy on its far side (``reach_px`` beyond its
    line), over the first copy's line less that level: about 1 where a single line is smeared
    along the shift into a plateau whose two ends pass for copies (motion blur), about 0 where two
    lines have the background between them. NaN with fewer than 20 such walls.
    """
    shift = np.asarray(copies.shift, dtype=float)
    pts, nrm, along = _walls_along(copies.pose, model, gray.shape, shift)
    pts, nrm = pts[along > _ALONG_COS], nrm[along > _ALONG_COS]
    if len(pts) < 20:
        return float("nan")
    delta = nrm @ shift
    far = -np.sign(delta) * (abs(copies.half_width) + reach_px)
    t = copies.offset + np.stack([far, np.zeros_like(delta), 0.5 * delta], axis=1)  # beside, on the line, midway
    sx = (pts[:, 0:1] + t * nrm[:, 0:1]).astype(np.float32)
    sy = (pts[:, 1:2] + t * nrm[:, 1:2]).astype(np.float32)
    level = cv2.remap(np.asarray(gray, dtype=np.float32), sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    line, mid = level[:, 1] - level[:, 0], level[:, 2] - level[:, 0]
    return float(np.median(mid) / np.median(line)) if abs(float(np.median(line))) > 1e-6 else float("nan")


def doubled_walls(
    edges: Edges,
    layers: np.ndarray,
    pose: CameraPose,
    half_width: float,
    model: WallModel,
    cfg: RegistrationConfig,
    b_per_rad: float,
    where_array: Callable[[CameraPose, tuple[float, float]], tuple[float, float]] | None = None,
    guide: tuple[np.ndarray, float] | None = None,
    gray: np.ndarray | None = None,
) -> tuple[_Copies, float] | None:
    """Doubled walls near a single-copy fit, or None when the walls are single.

    Every start of :func:`_copy_starts` is refined on walls 4 px apart. Of those whose
    second copy is real (:attr:`_Support.second_is_real`) and whose first copy lies on edges
    nearly as often as the single copy did (:attr:`_Support.first_rate`, at least 85 % of
    it: a shift onto another turn's walls can pass the first test; or, given
    ``where_array(pose, shift)`` (:func:`~tympani.vision.registration.axis.copy_offsets`), where
    the array lies on the second copy's insertion axis
    (:func:`~tympani.vision.registration.axis.second_copy_is_the_wall`: the single fit then sat
    on a copy that is not the wall), the best supported
    (:attr:`_Support.score`) is refined on walls ``cfg.model_spacing_px`` apart, turned along
    the spiral's valley when that fits better (:func:`valley_scan`), and its copies named
    so that the first is the one with the stronger edges; copies closer than
    :data:`_MIN_PARALLAX_MM`, or that are the two ridges of a wall blurred along the shift
    (:func:`_blur_ratio`; not where two lines show the background between them in ``gray``, the
    frame: :func:`_filled_between`), are taken for single walls. With ``guide`` (see
    :func:`_guided_start`) and ``where_array``, the start where the array says the other copy
    lies (:func:`_copy_starts`) is tried too; it needs only a second copy that shows (:func:`_second_shows`)
    and the array nearer its axis than the first's
    (:func:`~tympani.vision.registration.axis.nearer_second_copy`). A start whose copies, alike,
    are not plausible is tried with a second copy of its own look where it has one
    (:func:`_copy_starts`); the best alike copies go on to the last stage first, and unlike ones
    only where the alike ones' second copy fades there. Returns the copies and the second copy's
    relative contrast (:func:`_copy_contrast`).
    """
    coarse = model.subsample(4.0 / pose.px_per_mm)
    classes = _wall_classes(pose, edges.signed, coarse)
    fine = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
    limits = dict(max_half_width=cfg.max_line_half_width_px, max_shift_px=_MAX_PARALLAX_MM * pose.px_per_mm)
    single = _copy_support(_Copies(pose, half_width, (0.0, 0.0)), layers, coarse, classes)
    plain, guided = _copy_starts(pose, half_width, edges.signed, fine, classes, cfg,
                                 guide if where_array is not None else None)
    starts = [(*pair, False) for pair in plain] + ([(*guided, True)] if guided is not None else [])
    best: dict[bool, tuple[float, _Copies, bool]] = {}  # by whether the copies look alike
    for alike, unlike, by_array in starts:
        for start in (alike, unlike):  # a look of its own only where the copies as alike fail
            if start is None:
                continue
            copies = _refine_copies(start, edges.signed, coarse, classes, sigma=cfg.final_sigma_px, iterations=6,
                                    **limits)
            support = _copy_support(copies, layers, coarse, classes)
            if by_array:  # only with where_array
                plausible = (_second_shows(copies, support, layers, coarse, classes)
                             and nearer_second_copy(*where_array(copies.pose, copies.shift), copies.pose.px_per_mm))
            else:
                plausible = support.second_is_real and (support.first_rate >= 0.85 * single.first_rate or (
                    where_array is not None and second_copy_is_the_wall(*where_array(copies.pose, copies.shift),
                                                                        copies.pose.px_per_mm)))
            if plausible:
                kind = copies.second_half_width is None
                if kind not in best or support.score > best[kind][0]:
                    best[kind] = (support.score, copies, by_array)
                break
    # the best alike copies first; unlike ones only where those fade on the fine walls
    for kind in (True, False):
        if kind in best:
            found = _confirmed(best[kind][1], best[kind][2], edges, layers, model, fine, classes, cfg, b_per_rad,
                               limits, gray)
            if found is not _Verdict.FADED:
                return None if found is _Verdict.SINGLE else found
    return None


def _offset_if_better(copies: _Copies, sfield: np.ndarray, layers: np.ndarray, model: WallModel,
                      classes: tuple[float, ...], cfg: RegistrationConfig, limits: dict[str, float]) -> _Copies:
    """``copies`` (wall lines) refined again with the lines free to lie off the channel's edge
    (:attr:`_Copies.offset`), where they then lie beside it (:data:`_MAX_STRADDLE_PX`) and fit
    the walls of ``model`` clearly better (:data:`_OFFSET_GAIN`); else ``copies`` unchanged.
    ``sfield`` is the signed gradient field and ``layers`` the edge layers the fit is measured
    on."""
    moved = _refine_copies(copies, sfield, model, classes, sigma=cfg.final_sigma_px, iterations=20, free_offset=True,
                           **limits)
    if not abs(moved.offset) >= max(abs(moved.half_width), abs(moved.half_width2)) - _MAX_STRADDLE_PX:
        return copies

    def fit(c: _Copies) -> tuple[float, float]:
        f = wall_fit_from(c.pose, layers, model, c.half_width, cfg.inlier_tol_px, np.asarray(c.shift), c.half_width2,
                          c.offset)
        return f.residual_px, f.inlier_fraction

    (res0, inl0), (res1, inl1) = fit(copies), fit(moved)
    return moved if res1 <= _OFFSET_GAIN * res0 and inl1 >= inl0 else copies


def lines_beside_the_edge(edges: Edges, layers: np.ndarray, pose: CameraPose, half_width: float, model: WallModel,
                          cfg: RegistrationConfig) -> tuple[CameraPose, float, float] | None:
    """Single wall lines refit lying beside the channel's edge, where they are lines (an edge of
    each polarity) and that fits clearly better (:func:`_offset_if_better`): the pose, the
    lines' half width (px) and their offset (px, :attr:`Registration.line_offset_px`); None
    where the lines stay on the edge."""
    coarse = model.subsample(4.0 / pose.px_per_mm)
    classes = _wall_classes(pose, edges.signed, coarse)
    if len(classes) != 2:
        return None
    fine = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
    limits = dict(max_half_width=cfg.max_line_half_width_px, max_shift_px=0.0)
    single = _Copies(pose, half_width, (0.0, 0.0))
    moved = _offset_if_better(single, edges.signed, layers, fine, classes, cfg, limits)
    return None if moved is single else (moved.pose, moved.half_width, moved.offset)


class _Verdict(Enum):
    """Why :func:`_confirmed` keeps no copies."""

    FADED = "the second copy no longer shows, or lies too near"
    SINGLE = "one wall blurred into two ridges"


def _confirmed(copies: _Copies, by_array: bool, edges: Edges, layers: np.ndarray, model: WallModel, fine: WallModel,
               classes: tuple[float, ...], cfg: RegistrationConfig, b_per_rad: float,
               limits: dict[str, float], gray: np.ndarray | None = None) -> tuple[_Copies, float] | _Verdict:
    """The last stage of :func:`doubled_walls` for one plausible candidate: refined on the
    ``fine`` walls, turned along the valley where that fits better, and kept when its second
    copy still shows, lies far enough away and is not a blurred wall's second ridge; returns
    the copies named stronger first and the second copy's relative contrast (``gray``, the frame,
    tells two blurred lines from one smeared line), or why not: :attr:`_Verdict.FADED` when
    the second copy no longer shows (or lies too near), :attr:`_Verdict.SINGLE` for a blurred
    single wall."""
    copies = _refine_copies(copies, edges.signed, fine, classes, sigma=cfg.final_sigma_px, iterations=10, **limits)
    delta = valley_scan(copies.pose, edges.pyramid, model, b_per_rad, np.asarray(copies.shift))
    if delta != 0.0:
        turned = replace(copies, pose=valley_pose(copies.pose, delta, b_per_rad))
        turned = _refine_copies(turned, edges.signed, fine, classes, sigma=cfg.final_sigma_px, iterations=10, **limits)
        if _copy_support(turned, layers, fine, classes).score > _copy_support(copies, layers, fine, classes).score:
            copies = turned
    if len(classes) == 2:
        copies = _offset_if_better(copies, edges.signed, layers, fine, classes, cfg, limits)
    support = _copy_support(copies, layers, fine, classes)
    least = max(_RESOLVED_PX, _MIN_PARALLAX_MM * copies.pose.px_per_mm)
    shows = _second_shows(copies, support, layers, fine, classes) if by_array else support.second_is_real
    if not (shows and math.hypot(*copies.shift) >= least):
        return _Verdict.FADED
    shift = np.asarray(copies.shift)
    magnitude = edges.edge_map.magnitude
    if max(_blur_ratio(magnitude, copies.pose, model, shift),
           _blur_ratio(magnitude, copies.pose.moved(shift), model, shift)) < _MAX_BLUR_RATIO:
        # two lines with the background between them are copies even where blur weakens them
        filled = _filled_between(gray, copies, model) if gray is not None and len(classes) == 2 else math.nan
        if not filled < _MAX_FILLED:
            return _Verdict.SINGLE
    contrast = _copy_contrast(copies, edges.edge_map.magnitude, fine, classes)
    if contrast > 1.0:
        copies, contrast = copies.swapped(), 1.0 / contrast
    return copies, contrast

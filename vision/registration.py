"""Registration: where the phantom is in the image (see docs/how-it-works.md).

The camera looks straight down, so phantom and image differ by a similarity: centre,
rotation, scale and possibly a mirror (:class:`vision.geometry.CameraPose`). :func:`register`
finds it from the channel walls alone, with no initial guess, assuming only that the walls
show as intensity edges (thin lines, region boundaries or both):

1. **Edges** (:mod:`vision.edges`): the frames are merged (per-pixel median), Canny runs
   with thresholds and smoothing set from the image's own noise, short specks are dropped,
   and each edge pixel is refined to sub-pixel precision. Two fields are splatted from the
   edge points: the *doubled-angle orientation* ``exp(2i·alpha)``, in which the two Canny
   edges of a thin line agree and randomly oriented noise and clutter cancel when averaged,
   and the signed gradient direction, which keeps the edges' polarity.
2. **Global search** on the doubled-angle field shrunk, for each candidate scale (10 %
   steps), so the phantom would appear at ``coarse_px_per_mm``: the wall template averaged
   over all rotations (a rotation-invariant ring detector, anchored on the spiral centre)
   proposes centres by correlation; at each proposal the templates of every rotation (128)
   and both mirrors are scored by one matrix product. This covers any rotation, both
   mirrors, the whole scale range and centres anywhere, including a channel partly out of
   frame.
3. **Refinement** of the best proposals down an image pyramid. Each wall point samples the
   field along its normal and takes the Gaussian-weighted mean offset of the edges that
   share its orientation (a 1-D mean shift); a weighted Gauss–Newton step moves the
   similarity. The last pass at full resolution is polarity-aware: edges whose gradient
   points out of the channel are fitted at ``+h`` and those pointing in at ``-h``, ``h``
   (the half width of the wall lines) being estimated with the pose. This centres thin
   lines even when only one of their sides shows, handles region boundaries (``h = 0``),
   and keeps the walls of neighbouring turns (0.24 mm apart, edges facing the other way)
   from pulling on each other. Proposals are refined to half resolution until one fits
   nearly all the walls, then the best few to full resolution; when full resolution does not
   confirm any, the remaining proposals are refined too (a deep array's edges can pass the
   half-resolution fit in a wrong pose).
4. **Verification**: along each wall normal, the distance from where the wall's edge is
   expected to the nearest Canny edge of matching orientation. Too few inliers, too little
   of the channel in view or too large a residual mean no phantom: :class:`RegistrationError`
   says which.

Why the entry matters: beyond 100° the backbone is a logarithmic spiral with a width that
grows with the radius, so a rotation about the centre is nearly the same as a 7.5 %/rad
change of scale there. The entry channel and the first half-turn break that symmetry; the
search and the residual (the largest of per-part medians) both rely on them.

:func:`check` recomputes the residual on a new frame in a few ms, so a batch can notice a
bumped camera and register again.

Units: image lengths in px (pixel centres at integer coordinates, x along columns, y along
rows), phantom lengths in mm, angles in rad unless a name says ``_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable

import cv2
import numpy as np

from tympani.vision.edges import (
    EdgeMap,
    as_float_gray,
    detect_edges,
    edges_from_gradients,
    gradients,
    doubled_angles,
    sigma_from_magnitude,
    splat_vector_sets,
    subpixel_edges,
    to_gray,
)
from tympani.vision.geometry import DEFAULT_PHANTOM, CameraPose, Phantom, backbone_frame, entry_frame, entry_walls

__all__ = [
    "RegistrationConfig",
    "Registration",
    "RegistrationError",
    "WallModel",
    "wall_model",
    "combine_frames",
    "register",
    "check",
    "wall_fit",
    "WallFit",
]


# --------------------------------------------------------------------------- config, results


@dataclass(frozen=True)
class RegistrationConfig:
    """Search ranges and tolerances of :func:`register`.

    Parameters
    ----------
    px_per_mm_range : tuple of float, or None
        Smallest and largest scale (px/mm) searched. None (default): from 10 px/mm to 80 px/mm
        per 640 px of the frame's larger side (80 at 640×480 and below, 240 at 1920×1080),
        the scales at which enough of the walls can be in view (:func:`search_range`).
    coarse_px_per_mm : float
        Working resolution (px/mm of the phantom) of the global search.
    coarse_scale_step : float
        Relative step between the scales of the global search (0.1 = 10 %).
    coarse_rotations : int
        Number of rotations of the global search (per mirror), evenly spaced over 2π.
    coarse_peaks_per_scale : int
        Centres proposed by the rotation-invariant detector at each scale.
    n_candidates : int
        Proposals of the global search that are refined to half resolution.
    n_fine : int
        Best of those that are refined at full resolution.
    edge_sigma_px : float or None
        Gaussian smoothing (px) before Canny; ``None`` chooses it from the image's noise
        (:func:`vision.edges.auto_sigma`).
    min_segment_px : int
        Edge segments shorter than this (px) are dropped as specks.
    refine_sigma_px : float
        Kernel (px, full resolution) of the first, polarity-blind full-resolution pass.
    final_sigma_px : float
        Kernel (px) of the last, polarity-aware pass; small enough that the walls of
        neighbouring turns (0.24 mm apart) stay out of each other's window.
    max_line_half_width_px : float
        Largest half width (px) of a wall drawn as a line (its two edges lie this far from the
        wall on either side).
    model_spacing_px : float
        Spacing (px) of the wall points used in refinement and verification.
    inlier_tol_px : float
        A wall point is an inlier when an edge of matching orientation and polarity lies
        within this distance (px, along its normal) of where the fit expects it.
    min_inlier_fraction : float
        Least fraction of the visible wall points that must be inliers.
    min_visible_fraction : float
        Least fraction of the model's wall length that must be inside the frame.
    max_residual_px : float
        Largest accepted residual (px, :attr:`WallFit.residual_px`).
    combine : {"median", "mean", "first"}
        How several frames are merged before edge detection.
    """

    px_per_mm_range: tuple[float, float] | None = None
    coarse_px_per_mm: float = 2.0
    coarse_scale_step: float = 0.10
    coarse_rotations: int = 128
    coarse_peaks_per_scale: int = 3
    n_candidates: int = 4
    n_fine: int = 2
    edge_sigma_px: float | None = None
    min_segment_px: int = 8
    refine_sigma_px: float = 2.0
    final_sigma_px: float = 1.0
    max_line_half_width_px: float = 4.0
    model_spacing_px: float = 1.5
    inlier_tol_px: float = 2.5
    min_inlier_fraction: float = 0.7
    min_visible_fraction: float = 0.3
    max_residual_px: float = 3.0
    combine: str = "median"

    def __post_init__(self) -> None:
        if self.px_per_mm_range is not None:
            lo, hi = self.px_per_mm_range
            if not 0 < lo <= hi:
                raise ValueError(f"px_per_mm_range must be 0 < lo <= hi, got {self.px_per_mm_range}")
        if self.combine not in ("median", "mean", "first"):
            raise ValueError(f"combine must be 'median', 'mean' or 'first', not {self.combine!r}")
        if self.edge_sigma_px is not None and self.edge_sigma_px <= 0:
            raise ValueError("edge_sigma_px must be positive or None")


#: The automatic scale range (see :attr:`RegistrationConfig.px_per_mm_range`): px/mm, and the
#: largest scale per 640 px of the frame's larger side.
AUTO_MIN_PX_PER_MM, AUTO_MAX_PX_PER_MM_PER_640 = 10.0, 80.0


def search_range(cfg: RegistrationConfig, width: int, height: int) -> tuple[float, float]:
    """The scales (px/mm) :func:`register` searches in a ``width`` × ``height`` (px) frame:
    ``cfg.px_per_mm_range``, or when it is None, 10 px/mm up to 80 px/mm per 640 px of the
    larger side (never less than 80). How much of the frame the phantom fills depends on its
    scale against the frame's size in px, so the largest scale at which enough of its walls
    are in view grows with the frame."""
    if cfg.px_per_mm_range is not None:
        return cfg.px_per_mm_range
    return AUTO_MIN_PX_PER_MM, AUTO_MAX_PX_PER_MM_PER_640 * max(1.0, max(width, height) / 640.0)


@dataclass(frozen=True)
class Registration:
    """A phantom-to-image similarity and how well the walls fit it.

    Parameters
    ----------
    pose : CameraPose
        Phantom (mm) to image (px) similarity.
    residual_px : float
        Median distance (px) from the visible model walls to their image edges (taking the
        edges' polarity and the line half width into account), the statistic :func:`check`
        recomputes on later frames; a few tenths of a pixel for a good registration.
    inlier_fraction : float
        Fraction of visible wall points with an edge of matching orientation within
        ``inlier_tol_px``.
    visible_fraction : float
        Fraction of the model's wall length inside the frame.
    matched_length_mm : float
        Wall length (mm) supported by inliers.
    line_half_width_px : float
        Estimated half width (px) of the wall lines (> 0 dark lines, < 0 bright lines,
        about 0 for region boundaries).
    edge_sigma_px : float
        Canny smoothing (px) used; :func:`check` uses the same.
    image_size : tuple of int
        ``(width, height)`` (px) of the frames registered.
    walls_doubled : bool
        Whether every wall showed twice, the second copy shifted by one image vector
        (``parallax_px``): the top and bottom edges of a thick plate's walls seen at an angle
        (see docs/how-it-works.md). ``pose`` is then that of the *first copy*, the one
        with the stronger edges (the second copy is a fainter replica), and the residual,
        inlier and check statistics count an edge of either copy. The copies are told apart
        where they are resolved: about 1 px for wall lines (the union of two overlapping
        lines is fitted as such) and 2.5 px for region boundaries, whose two steps merge into
        one edge below that; a doubling too small to resolve is not reported (and moves
        the pose by at most about a third of the parallax).
    parallax_px : tuple of float
        Image displacement ``(dx, dy)`` (px, x right, y down) of the second wall copy from the
        first; ``(0, 0)`` unless ``walls_doubled``. Where the copies overlap (wall lines
        closer than their width) it is measured from the union's outer edges, which can read
        up to about a third short.
    second_copy_contrast : float
        Edge strength of the second copy relative to the first (0–1, the ratio of median
        gradient magnitudes at edges of the two copies); NaN when the walls are single or
        where the copies were never resolved.
    """

    pose: CameraPose
    residual_px: float
    inlier_fraction: float = float("nan")
    visible_fraction: float = float("nan")
    matched_length_mm: float = float("nan")
    line_half_width_px: float = float("nan")
    edge_sigma_px: float = 1.0
    image_size: tuple[int, int] = (0, 0)
    walls_doubled: bool = False
    parallax_px: tuple[float, float] = (0.0, 0.0)
    second_copy_contrast: float = float("nan")
    _check_cache: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    @property
    def parallax_mm(self) -> float:
        """Length (mm, in the phantom's plane) of :attr:`parallax_px`; 0 for single walls."""
        return float(math.hypot(*self.parallax_px)) / float(self.pose.px_per_mm)

    def to_dict(self) -> dict:
        """The registration JSON's keys (docs/file-formats.md) plus the fit statistics and the doubled walls (JSON-ready):
        ``walls_doubled``, ``wall_parallax_mm`` (:attr:`parallax_mm`), ``wall_parallax_x_px``,
        ``wall_parallax_y_px`` and ``second_copy_contrast`` (NaN when unknown)."""
        p = self.pose
        return {
            "centre_x_px": float(p.centre_x_px),
            "centre_y_px": float(p.centre_y_px),
            "rotation_rad": float(p.rotation_rad),
            "px_per_mm": float(p.px_per_mm),
            "mirrored": bool(p.mirrored),
            "residual_px": float(self.residual_px),
            "inlier_fraction": float(self.inlier_fraction),
            "visible_fraction": float(self.visible_fraction),
            "matched_length_mm": float(self.matched_length_mm),
            "line_half_width_px": float(self.line_half_width_px),
            "edge_sigma_px": float(self.edge_sigma_px),
            "image_width_px": int(self.image_size[0]),
            "image_height_px": int(self.image_size[1]),
            "walls_doubled": bool(self.walls_doubled),
            "wall_parallax_mm": float(self.parallax_mm),
            "wall_parallax_x_px": float(self.parallax_px[0]),
            "wall_parallax_y_px": float(self.parallax_px[1]),
            "second_copy_contrast": float(self.second_copy_contrast),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Registration":
        """Inverse of :meth:`to_dict`; only the six pose keys are required."""
        pose = CameraPose(
            float(d["centre_x_px"]),
            float(d["centre_y_px"]),
            float(d["rotation_rad"]),
            float(d["px_per_mm"]),
            bool(d["mirrored"]),
        )
        nan = float("nan")
        return cls(
            pose=pose,
            residual_px=float(d["residual_px"]),
            inlier_fraction=float(d.get("inlier_fraction", nan)),
            visible_fraction=float(d.get("visible_fraction", nan)),
            matched_length_mm=float(d.get("matched_length_mm", nan)),
            line_half_width_px=float(d.get("line_half_width_px", nan)),
            edge_sigma_px=float(d.get("edge_sigma_px", 1.0)),
            image_size=(int(d.get("image_width_px", 0)), int(d.get("image_height_px", 0))),
            walls_doubled=bool(d.get("walls_doubled", False)),
            parallax_px=(float(d.get("wall_parallax_x_px", 0.0)), float(d.get("wall_parallax_y_px", 0.0))),
            second_copy_contrast=float(d.get("second_copy_contrast", nan)),
        )


class RegistrationError(Exception):
    """No phantom was found in the frames; the message says why."""


# --------------------------------------------------------------------------- wall model


@dataclass(frozen=True)
class WallModel:
    """The channel walls sampled evenly, with unit normals pointing out of the channel.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        Wall points (mm, phantom frame).
    normals : ndarray, shape (n, 2)
        Unit normals at the points, pointing away from the channel's interior.
    spacing_mm : float
        Arc-length spacing (mm) of the points.
    group : ndarray of int, shape (n,)
        Part of the channel: 0 the entry walls, 1 the spiral walls up to half a turn, 2 the
        second half-turn, 3 the rest with the closing cap. A rotation about the spiral
        centre hardly moves the log-spiral walls but does move groups 0 and 1.
    """

    points: np.ndarray
    normals: np.ndarray
    spacing_mm: float
    group: np.ndarray

    @property
    def length_mm(self) -> float:
        """Total wall length (mm) represented."""
        return len(self.points) * self.spacing_mm

    def subsample(self, spacing_mm: float) -> "WallModel":
        """Every k-th point, so that the spacing is about ``spacing_mm`` (mm) or more."""
        k = max(1, int(round(spacing_mm / self.spacing_mm)))
        return WallModel(self.points[::k], self.normals[::k], self.spacing_mm * k, self.group[::k])


def _resample(line: np.ndarray, spacing_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``spacing_mm`` (mm) along a polyline, their unit left normals and arc lengths."""
    seg = np.diff(line, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    n = max(2, int(np.floor(s[-1] / spacing_mm)) + 1)
    si = (np.arange(n) + 0.5) * (s[-1] / n)
    pts = np.stack([np.interp(si, s, line[:, 0]), np.interp(si, s, line[:, 1])], axis=1)
    eps = 0.5 * spacing_mm
    ahead = np.stack([np.interp(si + eps, s, line[:, 0]), np.interp(si + eps, s, line[:, 1])], axis=1)
    behind = np.stack([np.interp(si - eps, s, line[:, 0]), np.interp(si - eps, s, line[:, 1])], axis=1)
    tangent = ahead - behind
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    return pts, np.stack([-tangent[:, 1], tangent[:, 0]], axis=1), si


# wall_model's last results, keyed by (phantom, spacing_mm): every registration and every
# check() of the same phantom reuses them (~2.5 ms each). Their arrays are read-only.
_WALL_MODEL_CACHE: dict[tuple[Phantom, float], WallModel] = {}


def wall_model(phantom: Phantom = DEFAULT_PHANTOM, spacing_mm: float = 0.02) -> WallModel:
    """All walls of the channel as evenly spaced points with normals pointing out of it.

    Parameters
    ----------
    phantom : Phantom
        Phantom configuration.
    spacing_mm : float
        Arc-length spacing (mm) of the points.

    Returns
    -------
    WallModel
        Outer and inner spiral walls, the two entry walls and the closing cap at theta_end.
        Every normal points away from the channel's interior, so an edge's polarity (dark to
        bright along the normal or against it) means the same on every wall. The model is
        memoised per phantom and spacing (the last few kept), so its arrays are read-only.
    """
    key = (phantom, float(spacing_mm))
    model = _WALL_MODEL_CACHE.get(key)
    if model is None:
        model = _build_wall_model(phantom, float(spacing_mm))
        for a in (model.points, model.normals, model.group):
            a.flags.writeable = False
        if len(_WALL_MODEL_CACHE) >= 4:
            _WALL_MODEL_CACHE.clear()
        _WALL_MODEL_CACHE[key] = model
    return model


def _build_wall_model(phantom: Phantom, spacing_mm: float) -> WallModel:
    """:func:`wall_model` computed afresh (phantom lengths in mm)."""
    def outward(nrm: np.ndarray, ref: np.ndarray) -> np.ndarray:
        return np.where((np.sum(nrm * ref, axis=1) < 0)[:, None], -nrm, nrm)

    parts = []
    for wall, sign in ((phantom.outer_wall, 1.0), (phantom.inner_wall, -1.0)):
        pts, nrm, si = _resample(wall.points, spacing_mm)
        half_turns = (np.interp(si, wall.s, wall.theta) - phantom.theta_start) // np.pi
        # out of the channel: away from the spiral centre on the outer wall, towards it on the inner
        parts.append((pts, outward(nrm, sign * pts), 1 + np.minimum(half_turns, 2).astype(int)))
    _, _, n_w = entry_frame(phantom)
    for segment, out in zip(entry_walls(phantom), (n_w, -n_w)):
        pts, nrm, _ = _resample(segment, spacing_mm)
        parts.append((pts, outward(nrm, out[None, :]), np.zeros(len(pts), int)))
    cap = np.stack([phantom.inner_wall.points[-1], phantom.outer_wall.points[-1]])
    pts, nrm, _ = _resample(cap, spacing_mm)
    t_end = backbone_frame(phantom.theta_end, phantom)[1]
    parts.append((pts, outward(nrm, t_end), np.full(len(pts), 3)))
    return WallModel(
        np.vstack([p[0] for p in parts]),
        np.vstack([p[1] for p in parts]),
        float(spacing_mm),
        np.concatenate([p[2] for p in parts]),
    )


# --------------------------------------------------------------------------- pose helpers


def _image_points(pose: CameraPose, model: WallModel) -> tuple[np.ndarray, np.ndarray]:
    """Model points (px) and their unit normals in the image for ``pose``."""
    m = pose._matrix()  # the linear part of pose.affine(), without building the 2x3 matrix
    pts = model.points @ m.T + np.array([pose.centre_x_px, pose.centre_y_px])
    nrm = model.normals @ (m.T / max(pose.px_per_mm, 1e-12))  # a similarity: normals stay unit
    return pts, nrm


def _scaled_pose(pose: CameraPose, factor: float) -> CameraPose:
    """The pose on an image resized by ``factor`` (pixel-centre convention)."""
    return CameraPose(
        (pose.centre_x_px + 0.5) * factor - 0.5,
        (pose.centre_y_px + 0.5) * factor - 0.5,
        pose.rotation_rad,
        pose.px_per_mm * factor,
        pose.mirrored,
    )


def _wrap(angle: float) -> float:
    """Angle (rad) wrapped to [-π, π)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def _updated(pose: CameraPose, step: np.ndarray, rho: float) -> CameraPose:
    """Apply a linearised similarity update.

    ``step`` = (dx, dy, dlog_scale·rho, dangle·rho) in px, the last two about the current
    centre with lever arm ``rho`` (px); ``dangle`` is an image-frame rotation (x right, y
    down), which is ``-d rotation_rad``.
    """
    return CameraPose(
        float(pose.centre_x_px + step[0]),
        float(pose.centre_y_px + step[1]),
        _wrap(pose.rotation_rad - step[3] / rho),
        float(pose.px_per_mm * math.exp(step[2] / rho)),
        pose.mirrored,
    )


def _similarity_jacobian(pts: np.ndarray, nrm: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, float]:
    """Rows ``d(n·x)/d step`` for :func:`_updated` and the lever arm ``rho`` (px)."""
    d = pts - centre
    dx, dy, nx, ny = d[:, 0], d[:, 1], nrm[:, 0], nrm[:, 1]
    rho = float(np.sqrt(np.mean(dx * dx + dy * dy))) + 1e-9
    jac = np.empty((len(d), 4))
    jac[:, 0] = nx
    jac[:, 1] = ny
    np.divide(nx * dx + ny * dy, rho, out=jac[:, 2])
    np.divide(ny * dx - nx * dy, rho, out=jac[:, 3])
    return jac, rho


# --------------------------------------------------------------------------- frames, edges


def _frame_list(frames: list[np.ndarray] | np.ndarray) -> list[np.ndarray]:
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
        Frames (grey or BGR, any dtype :func:`vision.edges.as_float_gray` accepts), same size.
    how : {"median", "mean", "first"}
        Per-pixel median (default: keeps the static walls, drops what moves, such as the
        array), mean, or only the first frame. Each frame's global gain is normalised first,
        so lighting flicker does not enter.

    Returns
    -------
    ndarray of float32, shape (h, w)
    """
    frames = _frame_list(frames)
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
class _Edges:
    """Edge data of the merged frame, with the fields the search and the fits sample."""

    edge_map: EdgeMap
    points: np.ndarray  # (n, 2) sub-pixel edge points (px)
    pyramid: list[np.ndarray]  # smoothed doubled-angle fields, level L at scale 2^-L
    signed: np.ndarray  # (h, w, 2) smoothed field of signed unit gradient directions


def _gradients_for_canny(
    gray: np.ndarray, sigma_px: float | None
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray | None]:
    """Derivatives (grey levels per px) of ``gray`` smoothed for Canny, and the smoothing (px).

    ``sigma_px`` None picks the smoothing from the noise (:func:`vision.edges.auto_sigma`);
    the 1 px derivatives that takes, and their magnitude, are reused when it keeps 1 px
    (clean frames) rather than computed again. The last item is ``cv2.magnitude(gx, gy)``
    when it was computed on the way, else None.
    """
    if sigma_px is None:
        gx, gy = gradients(gray, 1.0)
        magnitude = cv2.magnitude(gx, gy)
        sigma_px = sigma_from_magnitude(magnitude)
        if sigma_px == 1.0:
            return gx, gy, sigma_px, magnitude
    gx, gy = gradients(gray, sigma_px)
    return gx, gy, float(sigma_px), None


def _prepare_edges(em: EdgeMap, levels: int) -> _Edges:
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
    return _Edges(em, pts, pyramid, signed)


# --------------------------------------------------------------------------- coarse search


@dataclass(frozen=True)
class _Proposal:
    """A candidate pose and its score (larger is better; units depend on the stage)."""

    score: float
    pose: CameraPose


def _splat_many(
    points: np.ndarray, values: np.ndarray, which: np.ndarray, n_images: int, shape: tuple[int, int]
) -> np.ndarray:
    """Bilinear splat of complex ``values`` at ``points`` (px) into image ``which`` of a stack.

    Points are clipped to the image (callers keep them inside). Returns an
    ``(n_images, h * w)`` complex array.
    """
    h, w = shape
    x = np.clip(points[:, 0], 0.0, w - 1.0001)
    y = np.clip(points[:, 1], 0.0, h - 1.0001)
    x0, y0 = x.astype(np.intp), y.astype(np.intp)
    fx, fy = x - x0, y - y0
    base = which * (h * w) + y0 * w + x0
    idx = np.concatenate([base, base + 1, base + w, base + w + 1])
    wgt = np.concatenate([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    vals = np.tile(values, 4) * wgt
    n = n_images * h * w
    out = np.empty(n, np.complex128)
    out.real = np.bincount(idx, vals.real, minlength=n)
    out.imag = np.bincount(idx, vals.imag, minlength=n)
    return out.reshape(n_images, h * w)


@dataclass(frozen=True)
class _TemplateStack:
    """Coarse templates of the walls for every rotation and both mirrors.

    Each template is a ``size x size`` doubled-angle image of the walls at
    ``coarse_px_per_mm`` with the spiral centre on its middle pixel.
    """

    size: int
    rotations: np.ndarray  # (J,) rotation_rad of each template
    # (K, 2J) float32, mirror-major columns: the rows of [real parts; imaginary parts] (2 size²
    # of them) on which some template is non-zero (K is about 70 % of them; the others would
    # only add zeros to the scores)
    stack_real: np.ndarray
    patch_index: np.ndarray  # (K,) where those rows are in a (size, size, 2) patch, flattened
    mean: np.ndarray  # (2, size, size, 2) float32: rotation-averaged template of each mirror
    # memo of the search's per-image-size work, filled by _coarse_plan (read-only values):
    # field shapes -> (block offsets, DFT size, _pair_spectra of ``mean``'s spectra at that size)
    plans: dict = field(default_factory=dict, compare=False, repr=False)


def _template_stack(model: WallModel, cfg: RegistrationConfig) -> _TemplateStack:
    """Render the two mirrors' templates once and rotate them with ``cv2.warpAffine``.

    Raising ``rotation_rad`` by phi turns the image by ``R(-phi)`` about the centre and
    multiplies the doubled-angle values by ``exp(-2i phi)``.
    """
    w0 = cfg.coarse_px_per_mm
    radius = float(np.max(np.hypot(model.points[:, 0], model.points[:, 1])))
    size = 2 * int(math.ceil(radius * w0 + 2.5)) + 1
    c = float(size // 2)
    coarse = model.subsample(0.25 / w0)
    weight = coarse.spacing_mm * w0  # template density: 1 per coarse px of wall
    rotations = np.arange(cfg.coarse_rotations) * (2 * np.pi / cfg.coarse_rotations)
    bases = []
    for mirrored in (False, True):
        pts, nrm = _image_points(CameraPose(c, c, 0.0, w0, mirrored), coarse)
        val = weight * (nrm[:, 0] + 1j * nrm[:, 1]) ** 2
        flat = _splat_many(pts, val, np.zeros(len(pts), np.intp), 1, (size, size))[0].reshape(size, size)
        bases.append(np.dstack([flat.real, flat.imag]).astype(np.float32))
    images = np.empty((2, len(rotations), size, size, 2), np.float32)
    for m, base in enumerate(bases):
        for j, phi in enumerate(rotations):
            cs, sn = math.cos(phi), math.sin(phi)
            # destination x samples the base at c + R(phi) (x - c)
            rot = np.array([[cs, -sn, c - cs * c + sn * c], [sn, cs, c - sn * c - cs * c]], np.float64)
            images[m, j] = cv2.warpAffine(
                base, rot, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0
            )
    phase_c = np.cos(2 * rotations).astype(np.float32)[None, :, None, None]  # exp(-2i phi)
    phase_s = -np.sin(2 * rotations).astype(np.float32)[None, :, None, None]
    re, im = images[..., 0].copy(), images[..., 1]
    images[..., 0] = re * phase_c - im * phase_s
    images[..., 1] = re * phase_s + im * phase_c
    flat = images.reshape(2 * len(rotations), size * size, 2)
    stack_real = np.hstack([flat[..., 0], flat[..., 1]]).T
    support = np.flatnonzero(np.any(stack_real != 0, axis=1))  # row = channel * size² + pixel
    patch_index = (support % (size * size)) * 2 + support // (size * size)
    mean = np.ascontiguousarray(images.mean(axis=1))
    return _TemplateStack(size, rotations, np.ascontiguousarray(stack_real[support]), patch_index, mean)


_TEMPLATE_CACHE: dict[tuple, _TemplateStack] = {}


def _cached_template_stack(model: WallModel, cfg: RegistrationConfig) -> _TemplateStack:
    """:func:`_template_stack`, kept for the last walls and settings it was built for: every
    registration in a process (each video of a batch, a re-registration) of the same phantom
    reuses it (~35 ms each). The key holds the walls' bytes, so equal walls hit."""
    key = (model.points.tobytes(), model.normals.tobytes(), model.spacing_mm, cfg.coarse_px_per_mm,
           cfg.coarse_rotations)
    tpl = _TEMPLATE_CACHE.get(key)
    if tpl is None:
        tpl = _template_stack(model, cfg)
        for a in (tpl.rotations, tpl.stack_real, tpl.patch_index, tpl.mean):
            a.flags.writeable = False
        _TEMPLATE_CACHE.clear()
        _TEMPLATE_CACHE[key] = tpl
    return tpl


def _peaks(score: np.ndarray, n: int, radius: int) -> list[tuple[int, int]]:
    """Up to ``n`` local maxima (row, col) of ``score``, at least ``radius`` apart."""
    k = 2 * radius + 1
    score = np.asarray(score, dtype=np.float32)  # a view with padded rows is fine
    dil = cv2.dilate(score, np.ones((k, k), np.uint8))
    flat = np.flatnonzero(score >= dil)  # row-major order, as np.argwhere
    values = dil.reshape(-1)[flat]  # = the score there (a local maximum is its own dilation)
    flat, values = flat[values > 0], values[values > 0]  # the positive ones (few: no full-size test)
    if len(flat) == 0:
        return []
    width = score.shape[1]
    out: list[tuple[int, int]] = []
    for i in np.argsort(-values).tolist():
        r, c = divmod(int(flat[i]), width)
        if all(max(abs(r - r2), abs(c - c2)) > radius for r2, c2 in out):
            out.append((r, c))
            if len(out) == n:
                break
    return out


def _shrunk_field(pyramid: list[np.ndarray], factor: float) -> tuple[np.ndarray, float, float]:
    """The doubled-angle field shrunk by ``factor`` (> 1), as edge length per shrunk pixel.

    Starts from the pyramid level that leaves at least a factor 2 to shrink. Returns the
    2-channel float32 image and the actual x and y shrink factors (full-resolution px per
    shrunk px).
    """
    level = min(max(math.floor(math.log2(max(factor, 1.0) / 2.0)), 0), len(pyramid) - 1)
    src = pyramid[level]
    h0, w0 = pyramid[0].shape[:2]
    h, w = src.shape[:2]
    wk = max(1, int(round(w0 / factor)))
    hk = max(1, int(round(h0 / factor)))
    zk = cv2.resize(src, (wk, hk), interpolation=cv2.INTER_AREA).reshape(hk, wk, 2)
    zk *= math.sqrt((w / wk) * (h / hk))
    zk = cv2.GaussianBlur(zk, (0, 0), 0.8).reshape(hk, wk, 2)
    return zk, w0 / wk, h0 / hk


def _shelf_layout(shapes: list[tuple[int, int]], gap: int, width: int) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """Blocks of ``shapes`` ((rows, cols), px) packed in order on shelves ``width`` px wide.

    A block starts a new shelf when it would end beyond ``width`` (a block wider than that
    gets a shelf of its own). Every block has ``gap`` px of empty space before it in both
    directions (to the previous block, the previous shelf or the mosaic's start). Returns
    the (row, col) of each block's first pixel and the (rows, cols) of the packed area (up
    to the last block's end, no trailing gap).
    """
    offsets = []
    x, y, shelf, right = gap, gap, 0, 0
    for h, w in shapes:
        if x > gap and x + w > width:
            x, y, shelf = gap, y + shelf + gap, 0
        offsets.append((y, x))
        right = max(right, x + w)
        shelf = max(shelf, h)
        x += w + gap
    return offsets, (y + shelf, right)


def _mosaic_layout(shapes: list[tuple[int, int]], gap: int) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """Shelf layout of ``shapes`` (see :func:`_shelf_layout`) whose DFT is cheapest.

    Tries shelf widths in 32 px steps from the widest block (plus ``gap``) to about twice
    the square root of the packed area and keeps the one with the smallest DFT
    (``cv2.getOptimalDFTSize`` of each side).
    Returns the blocks' (row, col) offsets and the DFT size (rows, cols), which covers the
    packed area.
    """
    widest = max(w for _, w in shapes) + gap
    area = sum((h + gap) * (w + gap) for h, w in shapes)
    best: tuple[int, list[tuple[int, int]], tuple[int, int]] | None = None
    for width in range(widest, max(widest, int(2.0 * math.sqrt(area))) + 1, 32):
        offsets, (rows, cols) = _shelf_layout(shapes, gap, width)
        size = (cv2.getOptimalDFTSize(rows), cv2.getOptimalDFTSize(cols))
        if best is None or size[0] * size[1] < best[0]:
            best = (size[0] * size[1], offsets, size)
    assert best is not None
    return best[1], best[2]


def _template_spectra(templates: np.ndarray, rows: int, cols: int) -> list[np.ndarray]:
    """DFTs of ``templates`` zero-padded to ``rows x cols`` (px).

    Parameters
    ----------
    templates : ndarray of float32, shape (n, s, s, 2)
        Complex templates (real, imaginary), at most ``rows x cols``.
    rows, cols : int
        DFT size (px).

    Returns
    -------
    list of ndarray of complex64, shape (rows, cols)
        One spectrum per template.
    """
    padded = np.zeros((rows, cols, 2), np.float32)
    spectra = []
    for t in templates:
        padded[: t.shape[0], : t.shape[1]] = t
        spectra.append(cv2.dft(padded, flags=cv2.DFT_COMPLEX_OUTPUT).view(np.complex64)[..., 0])
    return spectra


def _reversed_conj(spectrum: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out[k] = conj(spectrum[-k])`` for a 2-D spectrum (indices modulo its size, both axes)."""
    np.conjugate(spectrum[0, 0], out=out[0, 0:1])
    np.conjugate(spectrum[0, :0:-1], out=out[0, 1:])
    np.conjugate(spectrum[:0:-1, 0], out=out[1:, 0])
    np.conjugate(spectrum[:0:-1, :0:-1], out=out[1:, 1:])
    return out


def _pair_spectra(t0: np.ndarray, t1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The factors ``A``, ``B`` with which :func:`_circular_ccorr_pair` correlates an image
    with two templates of spectra ``t0``, ``t1`` (complex64, (H, W)) by one inverse DFT.

    With ``Z`` the image's spectrum, template m's circular cross-correlation is
    ``IDFT(Z conj(T_m))`` and its real part the IDFT of the Hermitian part
    ``(P(k) + conj(P(-k))) / 2`` of ``P = Z conj(T_m)``. The two real parts are therefore the
    real and imaginary parts of the IDFT of ``Z(k) A(k) + conj(Z(-k)) B(k)``, with
    ``A = (conj(T_0) + i conj(T_1)) / 2`` and ``B(k) = (T_0(-k) + i T_1(-k)) / 2``.
    """
    t0, t1 = t0.astype(np.complex128), t1.astype(np.complex128)
    a = 0.5 * (np.conj(t0) + 1j * np.conj(t1))
    # conj(C(-k)) with C = conj(T_0 + i T_1) / 2 is (T_0(-k) + i T_1(-k)) / 2
    b = _reversed_conj(0.5 * np.conj(t0 + 1j * t1), np.empty_like(a))
    return a.astype(np.complex64), b.astype(np.complex64)


def _circular_ccorr_pair(image: np.ndarray, factors: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Larger of two templates' circular cross-correlations with ``image`` (by DFT).

    ``out[u, v] = max_m sum Re(image[(u + i) mod H, (v + j) mod W] · conj(t_m[i, j]))``, the
    sum running over the template's pixels and the two channels being the real and imaginary
    parts; where a template placed at ``(u, v)`` does not wrap, this is ``cv2.matchTemplate``
    with ``TM_CCORR`` (up to float rounding). Both templates take one forward and one
    inverse DFT of the image's size (:func:`_pair_spectra`).

    Parameters
    ----------
    image : ndarray of float32, shape (H, W, 2)
        Complex image (real, imaginary), C-contiguous; overwritten (its memory holds the
        spectrum: every new array of this size costs more in page faults than its arithmetic).
    factors : tuple of ndarray of complex64, shape (H, W)
        :func:`_pair_spectra` of the templates' spectra at the image's size.

    Returns
    -------
    ndarray of float32, shape (H, W)
    """
    a, b = factors
    cv2.dft(image, dst=image, flags=cv2.DFT_COMPLEX_OUTPUT)
    z = image.view(np.complex64)[..., 0]
    mirrored = _reversed_conj(z, np.empty_like(z))
    mirrored *= b
    z *= a
    z += mirrored
    cv2.dft(image, dst=image, flags=cv2.DFT_INVERSE | cv2.DFT_SCALE)
    return np.maximum(image[..., 0], image[..., 1])


def _coarse_plan(
    tpl: _TemplateStack, shapes: list[tuple[int, int]]
) -> tuple[list[tuple[int, int]], tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Mosaic layout (:func:`_mosaic_layout`, gap a template size) of fields of ``shapes``
    ((rows, cols), px) and the spectra of the two mirrors' rotation-averaged templates at its
    DFT size, as :func:`_pair_spectra`.

    Both depend only on the image size and the settings, so they are memoised on ``tpl``
    (every video of a batch has the same size); the spectra are read-only.
    """
    key = tuple(shapes)
    plan = tpl.plans.get(key)
    if plan is None:
        offsets, (rows, cols) = _mosaic_layout(list(shapes), gap=tpl.size)
        spectra = _pair_spectra(*_template_spectra(tpl.mean, rows, cols))
        for a in spectra:
            a.flags.writeable = False
        if len(tpl.plans) >= 4:
            tpl.plans.clear()
        plan = tpl.plans[key] = (offsets, (rows, cols), spectra)
    return plan


def _copy_window(out: np.ndarray, image: np.ndarray, top: int, left: int) -> None:
    """Copy ``image[top : top + rows, left : left + cols]`` (px; ``(rows, cols)`` the shape of
    ``out``) into ``out`` where the window overlaps ``image``; the rest of ``out`` is left
    as it is (zeros, for a window of ``image`` padded with zeros on every side)."""
    rows, cols = out.shape[:2]
    h, w = image.shape[:2]
    r0, r1 = max(top, 0), min(top + rows, h)
    c0, c1 = max(left, 0), min(left + cols, w)
    if r0 < r1 and c0 < c1:
        out[r0 - top : r1 - top, c0 - left : c1 - left] = image[r0:r1, c0:c1]


def _coarse_search(edges: _Edges, model: WallModel, cfg: RegistrationConfig,
                   scale_range: tuple[float, float]) -> list[_Proposal]:
    """Global search over scale (``scale_range``, px/mm), rotation, mirror and centre (see
    module docstring).

    For each scale the orientation field is shrunk so the phantom would appear at
    ``coarse_px_per_mm``; the rotation-averaged template (a ring detector) is correlated with
    it (summing ``Re(z · conj(t))`` over the template, centres up to a template size outside
    the frame) and its best peaks are kept; all rotations and both mirrors are then scored at
    those peaks by one matrix product of image patches with the template stack.

    The shrunk fields of all scales are laid out in one mosaic, a template size of zeros
    around each, so that one DFT of the mosaic, a product with the two mirrors' template
    spectra and one inverse DFT (:func:`_circular_ccorr_pair`) give every scale's detector:
    the values are those of a separate ``cv2.matchTemplate`` on each field zero-padded by a
    template size (up to float rounding), at a fraction of the cost.
    """
    tpl = _cached_template_stack(model, cfg)
    size, c, n_rot = tpl.size, tpl.size // 2, len(tpl.rotations)
    lo, hi = scale_range
    n_scales = max(1, int(math.ceil(math.log(hi / lo) / math.log1p(cfg.coarse_scale_step))) + 1)
    scales = np.geomspace(lo, hi, n_scales)
    fields = [_shrunk_field(edges.pyramid, s / cfg.coarse_px_per_mm) for s in scales]
    offsets, (rows, cols), spectra = _coarse_plan(tpl, [z.shape[:2] for z, _, _ in fields])
    # the DFT wraps around: the zeros before the first shelf and column stand in for those
    # after the last
    mosaic = np.zeros((rows, cols, 2), np.float32)
    for (z, _, _), (oy, ox) in zip(fields, offsets):
        mosaic[oy : oy + z.shape[0], ox : ox + z.shape[1]] = z
    detector = _circular_ccorr_pair(mosaic, spectra)
    spots = []  # (scale, shrink x, shrink y, centre x, centre y) per patch
    windows = []  # (field, top row, left column) per patch
    for s, (z, fx, fy), (oy, ox) in zip(scales, fields, offsets):
        hk, wk = z.shape[:2]
        # this scale's field zero-padded by a template on each side (the spiral centre may
        # lie outside the frame) is the mosaic's [y0 : oy + hk + size, x0 : ox + wk + size]
        y0, x0 = oy - size, ox - size
        # its detector[u, v]: template's top-left at padded (u, v), i.e. at field (v - size,
        # u - size), its centre at image (v + c - size, u + c - size)
        for u, v in _peaks(detector[y0 : oy + hk + 1, x0 : ox + wk + 1], cfg.coarse_peaks_per_scale, radius=2):
            windows.append((z, u - size, v - size))
            spots.append((float(s), fx, fy, v + c - size, u + c - size))
    if not windows:
        return []
    patches = np.zeros((len(windows), size, size, 2), np.float32)
    for patch, (z, top, left) in zip(patches, windows):
        _copy_window(patch, z, top, left)
    # each patch as one row: its values on the rows of the template stack
    rows = patches.reshape(len(windows), 2 * size * size)[:, tpl.patch_index]
    scores = rows @ tpl.stack_real  # (n_spots, 2J)
    best = np.argmax(scores, axis=1)
    best_scores = scores[np.arange(len(scores)), best].tolist()
    proposals: list[_Proposal] = []
    for (s, fx, fy, ax, ay), j, score in zip(spots, best.tolist(), best_scores):
        mirrored, rot = bool(j // n_rot), float(tpl.rotations[j % n_rot])
        cx, cy = (ax + 0.5) * fx - 0.5, (ay + 0.5) * fy - 0.5
        proposals.append(_Proposal(score, CameraPose(cx, cy, _wrap(rot), s, mirrored)))
    proposals.sort(key=lambda p: -p.score)
    return _distinct(proposals, cfg.n_candidates)


def _distinct(proposals: list[_Proposal], n: int) -> list[_Proposal]:
    """The best ``n`` proposals, skipping near-duplicates of better ones."""
    out: list[_Proposal] = []
    for p in proposals:
        dup = False
        for q in out:
            a, b = p.pose, q.pose
            if (
                a.mirrored == b.mirrored
                and abs(math.log(a.px_per_mm / b.px_per_mm)) < 0.12
                and abs(_wrap(a.rotation_rad - b.rotation_rad)) < 0.15
                and math.hypot(a.centre_x_px - b.centre_x_px, a.centre_y_px - b.centre_y_px) < 0.5 * a.px_per_mm
            ):
                dup = True
                break
        if not dup:
            out.append(p)
            if len(out) == n:
                break
    return out


# --------------------------------------------------------------------------- refinement

# Variance (px²) by which an edge is spread in the sampled fields: Gaussian 0.7 px plus the
# bilinear splat and the bilinear sampling (1/6 px² each). A Gaussian-weighted mean offset
# with kernel sigma sees an edge at sigma² / (sigma² + this) of its true offset.
_FIELD_BLUR_VAR = 0.7**2 + 2.0 / 6.0


def _profiles(fld: np.ndarray, pts: np.ndarray, nrm: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Bilinear samples of a 2-channel field along each point's normal at offsets ``t`` (px).

    Returns an ``(n, len(t), 2)`` float32 array (zero outside the image).
    """
    shape = (len(pts), len(t))
    # pts + t * nrm summed in float64 and rounded once to float32 (the maps remap takes)
    sx = np.add(np.multiply.outer(nrm[:, 0], t), pts[:, 0:1], out=np.empty(shape, np.float32))
    sy = np.add(np.multiply.outer(nrm[:, 1], t), pts[:, 1:2], out=np.empty(shape, np.float32))
    return cv2.remap(fld, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _solve_step(jac: np.ndarray, r: np.ndarray, wt: np.ndarray, max_px: float) -> np.ndarray | None:
    """Weighted least-squares step, or None when it is not trustworthy.

    Weights are capped at 3x their mean (no single cluttered spot dominates). The step moves
    no model point by more than ``max_px`` (px): the offsets it fits are at most that large,
    so a bigger step means an ill-conditioned system (e.g. only one straight edge matched).
    """
    wt = np.minimum(wt, 3.0 * float(wt.mean()))
    ata = jac.T @ (jac * wt[:, None])
    atb = jac.T @ (wt * r)
    try:
        step = np.linalg.solve(ata + 1e-9 * np.trace(ata) * np.eye(len(atb)), atb)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(step)):
        return None
    largest = float(np.abs(jac @ step).max()) if len(jac) else 0.0
    return step * (max_px / largest) if largest > max_px else step


def _visible(pts: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    h, w = shape[:2]
    return (pts[:, 0] > -1) & (pts[:, 0] < w) & (pts[:, 1] > -1) & (pts[:, 1] < h)


def _refine_level(
    pose: CameraPose,
    fld: np.ndarray,
    model: WallModel,
    sigma: float,
    iterations: int,
    tol_px: float = 0.02,
) -> CameraPose:
    """Refine ``pose`` on one level of the doubled-angle pyramid (px of that level).

    Every wall point samples the field along its normal; the sample's agreement with the
    wall's orientation, times a Gaussian of the offset (``sigma``, px), weights a mean offset
    (a 1-D mean shift). A weighted Gauss–Newton step of the similarity then moves the walls
    by those offsets; iterate until the step is below ``tol_px``.
    """
    gain = 1.0 + _FIELD_BLUR_VAR / sigma**2  # undoes the shrinkage of the weighted mean
    scale0 = pose.px_per_mm
    t = np.arange(-3.0 * sigma, 3.0 * sigma + 1e-9, 0.5)
    kernel = np.exp(-0.5 * (t / sigma) ** 2)
    for _ in range(iterations):
        pts, nrm = _image_points(pose, model)
        vis = _visible(pts, fld.shape)
        n_vis = int(np.count_nonzero(vis))
        if n_vis < 20:
            break
        if n_vis < len(vis):
            pts, nrm = pts[vis], nrm[vis]
        prof = _profiles(fld, pts, nrm, t)
        c2 = (nrm[:, 0] ** 2 - nrm[:, 1] ** 2)[:, None]  # exp(2i beta) of the wall normal
        s2 = (2.0 * nrm[:, 0] * nrm[:, 1])[:, None]
        # a = max(agreement, 0) * kernel, in place (the samples are many: n x len(t))
        a = prof[..., 0] * c2
        a += prof[..., 1] * s2
        np.maximum(a, 0.0, out=a)
        a *= kernel
        wsum = a.sum(axis=1)
        ok = wsum > 1e-6
        n_ok = int(np.count_nonzero(ok))
        if n_ok < 20:
            break
        moment = a @ t  # of every row: cheaper than copying the rows kept
        if n_ok < len(ok):
            pts, nrm, moment, wsum = pts[ok], nrm[ok], moment[ok], wsum[ok]
        jac, rho = _similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        step = _solve_step(jac, gain * moment / wsum, wsum, max_px=3.0 * sigma * gain)
        if step is None:
            break
        pose = _updated(pose, step, rho)
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break  # diverging: the caller's fit statistics will reject the result
        if float(np.abs(step).sum()) < tol_px:
            break
    return pose


def _refine_signed(
    pose: CameraPose,
    half_width: float,
    sfield: np.ndarray,
    model: WallModel,
    sigma: float,
    iterations: int,
    *,
    max_half_width: float,
    tol_px: float = 0.01,
) -> tuple[CameraPose, float]:
    """Polarity-aware refinement at full resolution.

    Edges whose gradient (dark to bright) points out of the channel (class +) and into it
    (class -) are fitted separately: class + at ``+half_width`` and class - at
    ``-half_width`` (px, along the outward wall normal), ``half_width`` being estimated with
    the pose. A dark line gives both classes at ``±h``, a bright line ``h < 0``, a region
    boundary one class at 0. So a line seen on one side only is not biased by half its width,
    and the walls of neighbouring turns (whose edges face the other way) do not pull on each
    other.

    Returns the pose and the half width (px).
    """
    gain = 1.0 + _FIELD_BLUR_VAR / sigma**2
    scale0 = pose.px_per_mm
    reach = max_half_width + 3.0 * sigma
    t = np.arange(-reach, reach + 1e-9, 0.5)
    for _ in range(iterations):
        pts, nrm = _image_points(pose, model)
        vis = _visible(pts, sfield.shape)
        n_vis = int(np.count_nonzero(vis))
        if n_vis < 20:
            break
        if n_vis < len(vis):
            pts, nrm = pts[vis], nrm[vis]
        prof = _profiles(sfield, pts, nrm, t)
        proj = prof[..., 0] * nrm[:, 0:1]  # in place from here on (n x len(t) samples)
        proj += prof[..., 1] * nrm[:, 1:2]
        base, rho = _similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        classes = []  # (sign, rows kept, their offsets, their weights) of each polarity
        for sign in (1.0, -1.0):
            expected = sign * half_width
            a = sign * proj
            np.maximum(a, 0.0, out=a)
            a *= np.exp(-0.5 * ((t - expected) / sigma) ** 2)
            wsum = a.sum(axis=1)
            ok = wsum > 1e-3
            if np.count_nonzero(ok) < 10:
                continue
            classes.append((sign, ok, gain * (a @ (t - expected))[ok] / wsum[ok], wsum[ok]))
        if not classes:
            break
        # the rows of both classes: the similarity's columns and the half width's (+-1)
        jac = np.empty((sum(len(r) for _, _, r, _ in classes), 5))
        start = 0
        for sign, ok, r, _ in classes:
            np.compress(ok, base, axis=0, out=jac[start : start + len(r), :4])
            jac[start : start + len(r), 4] = sign
            start += len(r)
        rhs = np.concatenate([r for _, _, r, _ in classes])
        step = _solve_step(jac, rhs, np.concatenate([w for *_, w in classes]), max_px=reach * gain)
        if step is None:
            break
        pose = _updated(pose, step[:4], rho)
        half_width = min(max(half_width + float(step[4]), -max_half_width), max_half_width)
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break
        if float(np.abs(step).sum()) < tol_px:
            break
    return pose, half_width


def _start_level(pose: CameraPose, n_levels: int) -> int:
    """Pyramid level at which the phantom appears at 3–6 px/mm."""
    return int(np.clip(math.floor(math.log2(max(pose.px_per_mm, 1e-6) / 3.0)), 0, n_levels - 1))


def _refine_coarse(pose: CameraPose, edges: _Edges, model: WallModel, cfg: RegistrationConfig) -> CameraPose:
    """Refine a proposal down the pyramid to half resolution (doubled-angle field)."""
    for level in range(_start_level(pose, len(edges.pyramid)), 0, -1):
        f = 0.5**level
        lp = _scaled_pose(pose, f)
        sub = model.subsample(cfg.model_spacing_px / lp.px_per_mm)
        lp = _refine_level(lp, edges.pyramid[level], sub, 1.0, iterations=10, tol_px=0.05)
        pose = _scaled_pose(lp, 1.0 / f)
    return pose


def _refine_fine(
    pose: CameraPose, edges: _Edges, model: WallModel, cfg: RegistrationConfig
) -> tuple[CameraPose, float]:
    """Full-resolution refinement: doubled-angle field, then the polarity-aware fit.

    Returns the pose and the wall lines' half width (px).
    """
    sub = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
    pose = _refine_level(pose, edges.pyramid[0], sub, cfg.refine_sigma_px, iterations=10, tol_px=0.05)
    return _refine_signed(
        pose, 0.0, edges.signed, sub, cfg.final_sigma_px, iterations=20, max_half_width=cfg.max_line_half_width_px
    )


# --------------------------------------------------------------------------- verification

# Largest distance (px) looked for between a wall and its edge when measuring residuals.
# Larger reaches let noise edges stand in for faint walls (and a median over them swing).
_REACH_PX = 5.0
# Scale (px/mm) above which :func:`check` works on a shrunk crop, to stay fast.
_CHECK_MAX_PX_PER_MM = 20.0
# An edge pixel belongs to a wall when its gradient is within 30° of the wall normal.
_COS_ALIGNED = math.cos(math.radians(30.0))


@dataclass(frozen=True)
class WallFit:
    """How well the model walls of a pose lie on image edges.

    Distances are measured along each wall's normal, from where the wall's edge is expected
    (at ``±half_width`` for the two polarities, see :func:`_refine_signed`) to the nearest
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


def _edge_layers(em: EdgeMap) -> np.ndarray:
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
) -> np.ndarray:
    """Distance (px) along each normal from a wall's expected edge to the nearest edge pixel.

    Only edge pixels whose gradient is within 30° of the normal count. With ``half_width``
    given, an edge whose gradient points out of the channel is expected at ``+half_width``
    and one pointing in at ``-half_width``; with ``None``, any aligned edge counts from the
    wall itself. ``second`` (px, one per point), for doubled walls: the offset along the
    normal of the wall's second copy, whose edges are expected as far from it; an edge counts
    from the nearer copy. Walls without an edge within ``reach`` get ``reach``.
    """
    hw = 0.0 if half_width is None else abs(half_width)
    lo, hi = -reach - hw, reach + hw
    if second is not None and len(second):
        lo, hi = lo + min(float(second.min()), 0.0), hi + max(float(second.max()), 0.0)
    t = np.arange(lo, hi + 1e-9, 0.5, dtype=np.float32)
    h, w = layers.shape[:2]
    px, py = pts[:, 0:1].astype(np.float32), pts[:, 1:2].astype(np.float32)
    nx, ny = nrm[:, 0:1].astype(np.float32), nrm[:, 1:2].astype(np.float32)
    # the pixels the normal passes through, and their exact offsets along it (the arrays are
    # n x len(t): the arithmetic goes in place where it can)
    ix, iy = _nearest_pixels(px, nx, t, w), _nearest_pixels(py, ny, t, h)
    offset = ix - px  # float64
    offset *= nx
    along_y = iy - py
    along_y *= ny
    offset += along_y
    prof = np.take(layers.reshape(-1, 2), iy * w + ix, axis=0)  # = layers[iy, ix], faster
    proj = prof[..., 0] * nx  # cos of the angle, 0 off edges
    proj += prof[..., 1] * ny
    expected = 0.0 if half_width is None else np.where(proj > 0, np.float32(half_width), np.float32(-half_width))
    dist = offset - expected
    if second is not None:
        dist = np.minimum(np.abs(dist), np.abs(dist - second[:, None].astype(np.float32)))
    np.abs(dist, out=dist)
    stray = offset - t  # distance from the sample's own offset
    np.abs(stray, out=stray)
    dist[(np.abs(proj) < _COS_ALIGNED) | (stray > 1.0) | (dist > reach)] = np.inf
    return dist.min(axis=1)


def _nearest_pixels(start: np.ndarray, step: np.ndarray, t: np.ndarray, size: int) -> np.ndarray:
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


def _wall_fit_from(
    pose: CameraPose,
    layers: np.ndarray,
    model: WallModel,
    half_width: float | None,
    tol: float,
    parallax_px: np.ndarray | None = None,
) -> WallFit:
    """:class:`WallFit` of ``pose`` against a full-frame edge layer image; with
    ``parallax_px`` (px, image x and y), the walls' second copy that far away counts too."""
    pts, nrm = _image_points(pose, model)
    h, w = layers.shape[:2]
    vis = (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
    reach = max(_REACH_PX, tol)
    second = None if parallax_px is None else nrm[vis] @ np.asarray(parallax_px, dtype=float)
    dist = _edge_distances(layers, pts[vis], nrm[vis], half_width, reach, second)
    sizes = np.bincount(model.group, minlength=4)
    return _summarise(dist, model.group[vis], len(pts), sizes, tol, model.spacing_mm, reach)


def _check_walls(
    pose: CameraPose, model: WallModel, spacing_px: float = 2.0, max_points: int = 600
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Wall points (px), normals, groups and group sizes for :func:`check`.

    ``model`` is :func:`wall_model` (0.02 mm spacing), thinned to about ``spacing_px`` (px)
    between points and at most about ``max_points`` points.
    """
    model = model.subsample(max(spacing_px / pose.px_per_mm, model.length_mm / max_points))
    pts, nrm = _image_points(pose, model)
    return pts, nrm, model.group, np.bincount(model.group, minlength=4)


def _crop_fit(
    frame: np.ndarray,
    walls: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    sigma_px: float,
    px_per_mm: float,
    half_width: float,
    tol: float,
    parallax_px: np.ndarray | None = None,
) -> WallFit:
    """:class:`WallFit` with Canny run only on the bounding box of the visible walls (and of
    their second copy ``parallax_px`` away, px, when the walls are doubled).

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
    margin = int(math.ceil(3.0 * sigma_px + _REACH_PX + abs(half_width) + np.abs(shift).max())) + 2
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
    dist = _edge_distances(_edge_layers(em), local, nrm, half_width * f, _REACH_PX * f, second) / f
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
        Frame (grey or BGR, any dtype :func:`vision.edges.as_float_gray` accepts).
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
        walls = _check_walls(registration.pose, wall_model(phantom, spacing_mm=0.02))
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
    )


# --------------------------------------------------------------------------- spiral valley

# Largest turn (rad) about the spiral centre that :func:`_valley_scan` tries either way.
_VALLEY_MAX_RAD = math.radians(30.0)
# Least relative gain of the valley score for which :func:`_valley_scan` proposes a turn (a
# wrong turn of the entry loses a quarter or more of it; noise changes it by about 1 %).
_VALLEY_MIN_GAIN = 0.03


def _valley_pose(pose: CameraPose, delta: float, b_per_rad: float) -> CameraPose:
    """``pose`` turned by ``delta`` (rad, added to ``rotation_rad``) about the spiral centre
    and rescaled so that the exponential part of the spiral (``r = a exp(-b phi)``, ``b`` in
    1/rad, with a width proportional to ``r``) falls on itself: the scale is multiplied by
    ``exp(-b delta)``, or ``exp(+b delta)`` for a mirrored pose.
    """
    sign = 1.0 if pose.mirrored else -1.0
    return CameraPose(
        pose.centre_x_px,
        pose.centre_y_px,
        _wrap(pose.rotation_rad + delta),
        pose.px_per_mm * math.exp(sign * b_per_rad * delta),
        pose.mirrored,
    )


def _valley_scan(
    pose: CameraPose,
    pyramid: list[np.ndarray],
    model: WallModel,
    b_per_rad: float,
    parallax_px: np.ndarray | None = None,
) -> float:
    """The turn (rad) along the spiral's self-similarity valley that best fits the walls that
    break it, 0 when none fits better than ``pose`` itself.

    Beyond the 100° corner the backbone is ``a exp(-b phi)`` with a width proportional to the
    radius, so :func:`_valley_pose` moves those walls onto themselves: only the entry and the
    first half-turn (groups 0 and 1 of :class:`WallModel`) tell the turns along this valley
    apart, and a fit dominated by the rest of the spiral can settle anywhere on it (the
    entry's walls then lie on the array or on nothing). Those walls are scored by their
    orientation agreement with the doubled-angle field on the pyramid level where the phantom
    appears at 8–16 px/mm (points 1.5 px apart), for turns up to ±30° in steps that move the
    farthest of them by a pixel of that level; a turn is proposed when it scores at least
    :data:`_VALLEY_MIN_GAIN` more than ``pose``. With ``parallax_px`` (px, doubled walls) the
    walls' second copy, shifted by it, is scored too.
    """
    level = int(np.clip(math.floor(math.log2(max(pose.px_per_mm, 1e-6) / 8.0)), 0, len(pyramid) - 1))
    fld = pyramid[level]
    f = 0.5**level
    lp = _scaled_pose(pose, f)
    keep = model.group <= 1
    part = WallModel(model.points[keep], model.normals[keep], model.spacing_mm, model.group[keep])
    part = part.subsample(1.5 / lp.px_per_mm)
    r_max = float(np.max(np.hypot(part.points[:, 0], part.points[:, 1]))) * lp.px_per_mm
    n_side = int(math.ceil(_VALLEY_MAX_RAD * r_max))
    deltas = np.linspace(-_VALLEY_MAX_RAD, _VALLEY_MAX_RAD, 2 * n_side + 1)
    sign = 1.0 if lp.mirrored else -1.0
    # the walls at every turn, (len(deltas), n): raising rotation_rad by delta turns the
    # image about the centre by delta counter-clockwise on screen (x right, y down), mirrored
    # or not, and scales it by g
    pts, nrm = _image_points(lp, part)
    centre = np.array([lp.centre_x_px, lp.centre_y_px])
    rel = pts - centre
    cs, sn = np.cos(deltas)[:, None], np.sin(deltas)[:, None]
    g = np.exp(sign * b_per_rad * deltas)[:, None]
    sx = (centre[0] + g * (cs * rel[:, 0] + sn * rel[:, 1])).astype(np.float32)
    sy = (centre[1] + g * (-sn * rel[:, 0] + cs * rel[:, 1])).astype(np.float32)
    nx = cs * nrm[:, 0] + sn * nrm[:, 1]
    ny = -sn * nrm[:, 0] + cs * nrm[:, 1]
    c2, s2 = nx * nx - ny * ny, 2.0 * nx * ny  # the walls' doubled angles
    shifts = [(0.0, 0.0)] if parallax_px is None else [(0.0, 0.0), tuple(np.asarray(parallax_px) * f)]
    score = np.zeros(len(deltas))
    for dx, dy in shifts:
        prof = cv2.remap(fld, sx + np.float32(dx), sy + np.float32(dy), cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        agree = prof[..., 0] * c2 + prof[..., 1] * s2
        score += np.maximum(agree, 0.0).sum(axis=1)
    best = int(np.argmax(score))
    return float(deltas[best]) if score[best] > (1.0 + _VALLEY_MIN_GAIN) * score[n_side] else 0.0


# --------------------------------------------------------------------------- doubled walls

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
# Half widths (px) of the wall lines tried by :func:`_shift_surface` (< 0: bright lines).
_SURFACE_HALF_WIDTHS = (-3.0, -1.5, 0.0, 1.5, 3.0)


@dataclass(frozen=True)
class _Copies:
    """Doubled walls: the first copy's pose, the wall lines' half width (px, as
    :attr:`Registration.line_half_width_px`) and the second copy's image shift (px)."""

    pose: CameraPose
    half_width: float
    shift: tuple[float, float]

    def swapped(self) -> "_Copies":
        """The same walls with the copies' roles exchanged."""
        dx, dy = self.shift
        return _Copies(_translated(self.pose, (dx, dy)), self.half_width, (-dx, -dy))


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
    def second_is_real(self) -> bool:
        """Whether the second copy is expected at enough points and found at enough of them."""
        return self.shown2 >= _MIN_SECOND_SHOWN * self.n_points and self.matched2 >= _MIN_SECOND_MATCHED * self.shown2


def _translated(pose: CameraPose, shift: tuple[float, float] | np.ndarray) -> CameraPose:
    """``pose`` moved by ``shift`` (px, image x and y)."""
    return CameraPose(
        float(pose.centre_x_px + shift[0]), float(pose.centre_y_px + shift[1]), pose.rotation_rad, pose.px_per_mm,
        pose.mirrored,
    )


def _copy_offsets(
    delta: np.ndarray, half_width: float, sign: float, lines: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where one polarity class's edge of each copy is expected, and whether it shows.

    Parameters
    ----------
    delta : ndarray, shape (n,)
        Offset (px) of the second copy along each wall normal.
    half_width : float
        Half width (px) of the wall lines (< 0: bright lines).
    sign : float
        The class: +1 for edges whose gradient points out of the channel, -1 into it.
    lines : bool
        Whether the walls are lines (an edge of each class) or region boundaries (one).

    Returns
    -------
    e1, e2 : ndarray, shape (n,)
        Expected offsets (px, along the normals) of the first and the second copy's edge.
    shown1, shown2 : ndarray of bool, shape (n,)
        Whether each shows. Two lines that overlap (closer than their width plus
        :data:`_LINE_GAP_PX`) form one thicker line, which shows only the outer of the two
        edges of a class. A region boundary's second step shows only beyond
        :data:`_MERGE_PX`; nearer, the two merge into one edge, nearer the stronger copy.
    """
    e1 = np.full(delta.shape, sign * half_width)
    e2 = e1 + delta
    if not lines:
        return e1, e2, np.ones(delta.shape, bool), np.abs(delta) > _MERGE_PX
    apart = np.abs(delta) > 2.0 * abs(half_width) + _LINE_GAP_PX
    # this class's edge lies on the side sign * sign(half_width) of its line
    second_outer = sign * math.copysign(1.0, half_width) * delta > 0
    return e1, e2, apart | ~second_outer, apart | second_outer


def _wall_classes(pose: CameraPose, sfield: np.ndarray, model: WallModel, reach_px: float = 4.0) -> tuple[float, ...]:
    """The edge polarity classes the walls show near ``pose``: ``(1.0, -1.0)`` for lines
    (an edge on each side), ``(1.0,)`` or ``(-1.0,)`` for region boundaries (gradient out of
    or into the channel).

    A class counts when its mean strongest response along the normals (within ``reach_px``,
    px) is at least 35 % of the other class's.
    """
    pts, nrm = _image_points(pose, model)
    vis = _visible(pts, sfield.shape)
    pts, nrm = pts[vis], nrm[vis]
    prof = _profiles(sfield, pts, nrm, np.arange(-reach_px, reach_px + 1e-9, 0.5))
    proj = prof[..., 0] * nrm[:, 0:1] + prof[..., 1] * nrm[:, 1:2]
    out_of, into = float(proj.max(axis=1).mean()), float((-proj).max(axis=1).mean())
    if min(out_of, into) >= 0.35 * max(out_of, into):
        return (1.0, -1.0)
    return (1.0,) if out_of > into else (-1.0,)


def _copy_edges(
    delta: np.ndarray, half_width: float, classes: tuple[float, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every shown edge of doubled walls (:func:`_copy_offsets`), one row each.

    Parameters
    ----------
    delta : ndarray, shape (n,)
        Offset (px) of the second copy along each wall normal.
    half_width : float
        Half width (px) of the wall lines.
    classes : tuple of float
        Polarity classes shown (:func:`_wall_classes`).

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
        e1, e2, shown1, shown2 = _copy_offsets(delta, half_width, sign, lines)
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
) -> _Copies:
    """Polarity-aware refinement (as :func:`_refine_signed`) of doubled walls: pose, line half
    width and the second copy's shift.

    Each class's edge of each copy is expected where :func:`_copy_offsets` puts it; a copy's
    edge that shows takes the samples within ``3 sigma`` (px) of it that are nearer to it than
    to the other copy's edge of the class (where that shows), and their Gaussian-weighted
    mean offset is one row of a weighted Gauss–Newton step (the second copy's rows also move
    the shift). Region boundaries (one class) keep their half width.
    """
    gain = 1.0 + _FIELD_BLUR_VAR / sigma**2
    u = np.arange(-3.0 * sigma, 3.0 * sigma + 1e-9, 0.5)
    kernel = np.exp(-0.5 * (u / sigma) ** 2)
    lines = len(classes) == 2
    pose, half_width, shift = copies.pose, copies.half_width, np.asarray(copies.shift, dtype=float)
    scale0 = pose.px_per_mm
    for _ in range(iterations):
        pts, nrm = _image_points(pose, model)
        vis = _visible(pts, sfield.shape)
        if np.count_nonzero(vis) < 20:
            break
        pts, nrm = pts[vis], nrm[vis]
        base, rho = _similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        point, sign, second, expected, other = _copy_edges(nrm @ shift, half_width, classes)
        n = nrm[point]
        prof = _profiles(sfield, pts[point] + expected[:, None] * n, n, u)
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
        jac = np.zeros((np.count_nonzero(ok), 7))
        jac[:, :4] = base[point[ok]]
        jac[:, 4] = sign[ok] if lines else 0.0
        jac[:, 5:7] = n[ok] * second[ok, None]
        step = _solve_step(jac, gain * (a @ u)[ok] / wsum[ok], wsum[ok], max_px=(max_half_width + 3.0 * sigma) * gain)
        if step is None:
            break
        pose = _updated(pose, step[:4], rho)
        half_width = min(max(half_width + float(step[4]), -max_half_width), max_half_width)
        shift = shift + step[5:7]
        length = float(np.hypot(*shift))
        if length > max_shift_px:
            shift *= max_shift_px / length
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break
        if float(np.abs(step).sum()) < tol_px:
            break
    return _Copies(pose, half_width, (float(shift[0]), float(shift[1])))


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
    ix, iy = _nearest_pixels(px, nx, t, w), _nearest_pixels(py, ny, t, h)
    off = (ix - px) * nx + (iy - py) * ny  # from the expected edge
    prof = np.take(layers.reshape(-1, 2), iy * w + ix, axis=0)
    proj = sign * (prof[..., 0] * nx + prof[..., 1] * ny)
    dist = np.abs(off)
    dist[(proj < _COS_ALIGNED) | (np.abs(off - t) > 1.0)] = np.inf
    return dist.min(axis=1)


def _copy_support(
    copies: _Copies, layers: np.ndarray, model: WallModel, classes: tuple[float, ...], tol_px: float = 1.0
) -> _Support:
    """:class:`_Support` of ``copies``: their expected edges with a Canny edge of the same
    class within ``tol_px`` (px)."""
    pts, nrm = _image_points(copies.pose, model)
    vis = _visible(pts, layers.shape)
    pts, nrm = pts[vis], nrm[vis]
    delta = nrm @ np.asarray(copies.shift, dtype=float)
    resolved = np.abs(delta) >= _RESOLVED_PX
    counts = np.zeros(4, int)
    for sign in classes:
        e1, e2, shown1, shown2 = _copy_offsets(delta, copies.half_width, sign, len(classes) == 2)
        found1 = _class_edge_distances(layers, pts, nrm, e1, sign) <= tol_px
        found2 = _class_edge_distances(layers, pts, nrm, e2, sign) <= tol_px
        shown2 &= resolved
        counts += [np.count_nonzero(found1 & shown1), np.count_nonzero(shown1),
                   np.count_nonzero(found2 & shown2), np.count_nonzero(shown2)]
    return _Support(*(int(c) for c in counts), n_points=len(pts))


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
    pts, nrm = _image_points(copies.pose, model)
    vis = _visible(pts, magnitude.shape)
    pts, nrm = pts[vis], nrm[vis]
    delta = nrm @ np.asarray(copies.shift, dtype=float)
    resolved = np.abs(delta) >= _RESOLVED_PX
    t = np.array([-0.5, 0.0, 0.5])
    log_ratio, used = 0.0, False
    for sign in classes:
        e1, e2, shown1, shown2 = _copy_offsets(delta, copies.half_width, sign, len(classes) == 2)
        medians = []
        for e, shown in ((e1, shown1 & resolved), (e2, shown2 & resolved)):
            if np.count_nonzero(shown) < min_edges:
                break
            mag = _profiles(magnitude, pts[shown] + e[shown, None] * nrm[shown], nrm[shown], t).max(axis=1)
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


def _shift_surface(
    pose: CameraPose,
    sfield: np.ndarray,
    model: WallModel,
    radius_px: float,
    classes: tuple[float, ...],
    mask_half_width: float | None = None,
    n_bins: int = 48,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How well the walls at ``pose`` moved by each shift ``v`` (px, ``|v_x|, |v_y| <=
    radius_px``) lie on edges: the polarity-aware evidence of ``classes`` (at ``±h``)
    summed over the walls, for the best line half width ``h`` of
    :data:`_SURFACE_HALF_WIDTHS` (lines) or ``h = 0`` (region boundaries, one class).

    The signed field is sampled once along each wall normal and the samples summed over
    wall points of about the same normal direction (``n_bins`` bins): a shift ``v`` then
    moves every edge of a bin by the same ``n·v``, one lookup per bin. With
    ``mask_half_width`` (px), the edges at ``±mask_half_width`` (within 1.5 px) are left
    out: the surface then shows where else the walls have edges, e.g. their second copy.

    Returns
    -------
    surface : ndarray, shape (m, m)
        Evidence (arbitrary units), row index along y, column along x.
    half_width : ndarray, shape (m, m)
        The half width (px) that gave it.
    grid : ndarray, shape (m,)
        The shifts (px) of the rows and columns, in steps of 1 px (more above 12 px of
        radius, so that the grid has at most 25 steps a side).
    """
    pts, nrm = _image_points(pose, model)
    vis = _visible(pts, sfield.shape)
    pts, nrm = pts[vis], nrm[vis]
    half_widths = _SURFACE_HALF_WIDTHS if len(classes) == 2 else (0.0,)
    h_max = max(abs(h) for h in half_widths)
    reach = radius_px * math.sqrt(2.0) + h_max + 1.0
    t = np.arange(-reach, reach + 1e-9, 0.5)
    prof = _profiles(sfield, pts, nrm, t)
    proj = prof[..., 0] * nrm[:, 0:1] + prof[..., 1] * nrm[:, 1:2]
    out_of = np.maximum(proj, 0.0) if 1.0 in classes else np.zeros_like(proj)
    into = np.maximum(-proj, 0.0) if -1.0 in classes else np.zeros_like(proj)
    if mask_half_width is not None:
        out_of[:, np.abs(t - mask_half_width) <= 1.5] = 0.0
        into[:, np.abs(t + mask_half_width) <= 1.5] = 0.0
    angle = np.arctan2(nrm[:, 1], nrm[:, 0]) % (2.0 * np.pi)
    bins = np.minimum((angle * (n_bins / (2.0 * np.pi))).astype(int), n_bins - 1)
    sums = np.stack([_bin_sums(out_of, bins, n_bins), _bin_sums(into, bins, n_bins)])
    centre = (np.arange(n_bins) + 0.5) * (2.0 * np.pi / n_bins)
    step = max(1.0, radius_px / 12.0)
    grid = np.arange(-math.floor(radius_px / step), math.floor(radius_px / step) + 1) * step
    vx, vy = np.meshgrid(grid, grid)
    along = np.cos(centre)[:, None] * vx.ravel()[None, :] + np.sin(centre)[:, None] * vy.ravel()[None, :]
    best = np.full(vx.size, -np.inf)
    best_h = np.zeros(vx.size)
    rows = np.arange(n_bins)[:, None]
    for h in half_widths:
        total = np.zeros(vx.size)
        for table, offset in ((sums[0], h), (sums[1], -h)):
            idx = np.clip((along + offset + reach) * 2.0, 0.0, len(t) - 1.001)
            i0 = idx.astype(np.intp)
            frac = idx - i0
            total += (table[rows, i0] * (1.0 - frac) + table[rows, i0 + 1] * frac).sum(axis=0)
        better = total > best
        best[better], best_h[better] = total[better], h
    return best.reshape(vx.shape), best_h.reshape(vx.shape), grid


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
    pts, nrm = _image_points(pose, model)
    vis = _visible(pts, sfield.shape)
    pts, nrm = pts[vis], nrm[vis]
    if len(pts) < 4 * n_bins:
        return np.zeros(2), 0.0
    h = half_width
    t = np.arange(-abs(h) - reach_px - 1.0, abs(h) + reach_px + 1.0 + 1e-9, 0.5)
    prof = _profiles(sfield, pts, nrm, t)
    proj = prof[..., 0] * nrm[:, 0:1] + prof[..., 1] * nrm[:, 1:2]
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


def _copy_starts(
    pose: CameraPose,
    half_width: float,
    sfield: np.ndarray,
    model: WallModel,
    classes: tuple[float, ...],
    cfg: RegistrationConfig,
) -> list[_Copies]:
    """Starting points for :func:`_refine_copies` from a single-copy fit ``pose`` (px), which
    may lie on either copy or between them.

    Copies further apart than their edges' width: the strongest peak of
    :func:`_shift_surface` is taken as one copy and refined alone; with its edges masked,
    the surface's best peak (two best, for region boundaries) proposes the other copy, unless
    the masked surface's maximum is below :data:`_MIN_MASKED_RATIO` of the unmasked one (no
    edges off the first copy's). Lines closer than that (one thicker line): when the line's
    width varies with its direction (:func:`_line_widening`: at least
    :data:`_MIN_WIDENING_PX` and :data:`_MIN_WIDENING_EXPLAINED` of the variance), the two
    copies ``∓ shift / 2`` either side of ``pose``. (Region boundaries that close merge into
    one edge, which shows no second copy to fit.)
    """
    lines = len(classes) == 2
    radius = _MAX_PARALLAX_MM * pose.px_per_mm + 2.0
    sparse = model.subsample(2.0 / pose.px_per_mm)  # enough wall to place the walls to a pixel
    surface, widths, grid = _shift_surface(pose, sfield, sparse, radius, classes)
    starts = []
    peaks = _surface_peaks(surface, widths, grid, 1)
    if peaks:
        v, _, h = peaks[0]
        one, one_hw = pose, half_width
        if math.hypot(*v) >= 1.0:
            one, one_hw = _refine_signed(
                _translated(pose, v), h, sfield, model, cfg.final_sigma_px, 10, max_half_width=cfg.max_line_half_width_px
            )
        masked, masked_hw, _ = _shift_surface(one, sfield, sparse, radius, classes, mask_half_width=one_hw)
        if float(masked.max()) >= _MIN_MASKED_RATIO * float(surface.max()):
            for shift, _, _ in _surface_peaks(masked, masked_hw, grid, 1 if lines else 2, min_shift_px=2.0):
                starts.append(_Copies(one, one_hw, (float(shift[0]), float(shift[1]))))
    if lines:
        shift, explained = _line_widening(pose, half_width, sfield, sparse)
        if math.hypot(*shift) >= _MIN_WIDENING_PX and explained >= _MIN_WIDENING_EXPLAINED:
            starts.append(_Copies(_translated(pose, -0.5 * shift), 0.0, (float(shift[0]), float(shift[1]))))
    return starts


def _doubled_walls(
    edges: _Edges,
    layers: np.ndarray,
    pose: CameraPose,
    half_width: float,
    model: WallModel,
    cfg: RegistrationConfig,
    b_per_rad: float,
) -> tuple[_Copies, float] | None:
    """Doubled walls near a single-copy fit, or None when the walls are single.

    Every start of :func:`_copy_starts` is refined on walls 4 px apart. Of those whose
    second copy is real (:attr:`_Support.second_is_real`) and whose first copy lies on edges
    nearly as often as the single copy did (:attr:`_Support.first_rate`, at least 85 % of
    it: a shift onto another turn's walls can pass the first test), the best supported
    (:attr:`_Support.score`) is refined on walls ``cfg.model_spacing_px`` apart, turned along
    the spiral's valley when that fits better (:func:`_valley_scan`), and its copies named
    so that the first is the one with the stronger edges; copies closer than
    :data:`_MIN_PARALLAX_MM` are taken for single walls. Returns the copies and the second
    copy's relative contrast (:func:`_copy_contrast`).
    """
    coarse = model.subsample(4.0 / pose.px_per_mm)
    classes = _wall_classes(pose, edges.signed, coarse)
    fine = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
    limits = dict(max_half_width=cfg.max_line_half_width_px, max_shift_px=_MAX_PARALLAX_MM * pose.px_per_mm)
    single = _copy_support(_Copies(pose, half_width, (0.0, 0.0)), layers, coarse, classes)
    best: tuple[float, _Copies] | None = None
    for start in _copy_starts(pose, half_width, edges.signed, fine, classes, cfg):
        copies = _refine_copies(start, edges.signed, coarse, classes, sigma=cfg.final_sigma_px, iterations=6, **limits)
        support = _copy_support(copies, layers, coarse, classes)
        plausible = support.second_is_real and support.first_rate >= 0.85 * single.first_rate
        if plausible and (best is None or support.score > best[0]):
            best = (support.score, copies)
    if best is None:
        return None
    copies = _refine_copies(best[1], edges.signed, fine, classes, sigma=cfg.final_sigma_px, iterations=10, **limits)
    delta = _valley_scan(copies.pose, edges.pyramid, model, b_per_rad, np.asarray(copies.shift))
    if delta != 0.0:
        turned = _Copies(_valley_pose(copies.pose, delta, b_per_rad), copies.half_width, copies.shift)
        turned = _refine_copies(turned, edges.signed, fine, classes, sigma=cfg.final_sigma_px, iterations=10, **limits)
        if _copy_support(turned, layers, fine, classes).score > _copy_support(copies, layers, fine, classes).score:
            copies = turned
    support = _copy_support(copies, layers, fine, classes)
    least = max(_RESOLVED_PX, _MIN_PARALLAX_MM * copies.pose.px_per_mm)
    if not (support.second_is_real and math.hypot(*copies.shift) >= least):
        return None
    contrast = _copy_contrast(copies, edges.edge_map.magnitude, fine, classes)
    if contrast > 1.0:
        copies, contrast = copies.swapped(), 1.0 / contrast
    return copies, contrast


# --------------------------------------------------------------------------- public entry points


# A candidate whose inliers cover this fraction of the whole wall model is taken without
# refining the others (nothing else could explain clearly more of the walls).
_EXCELLENT = 0.85


def _best_pose(
    edges: _Edges,
    layers: np.ndarray,
    model: WallModel,
    cfg: RegistrationConfig,
    scale_range: tuple[float, float],
    b_per_rad: float,
) -> tuple[CameraPose, float, WallFit] | None:
    """Global search over ``scale_range`` (px/mm), refinement of the best proposals, and the
    best-supported result.

    Each proposal refined at full resolution is also refined from the best turn along the
    spiral's self-similarity valley (:func:`_valley_scan`), and the better supported of the
    two kept.

    ``layers`` is :func:`_edge_layers` of the edges and ``b_per_rad`` the exponential
    branch's ``b`` (1/rad). Returns the pose, the wall lines' half width (px) and the fit, or
    None.
    """
    proposals = _coarse_search(edges, model, cfg, scale_range)
    lo, hi = scale_range

    def fit(pose: CameraPose, spacing_px: float, half_width: float | None) -> WallFit:
        sub = model.subsample(spacing_px / pose.px_per_mm)
        tol = cfg.inlier_tol_px + (cfg.max_line_half_width_px if half_width is None else 0.0)
        return _wall_fit_from(pose, layers, sub, half_width, tol)

    excellent = _EXCELLENT * model.length_mm
    remaining = list(proposals)
    coarse: list[_Proposal] = []
    refined: list[_Proposal] = []  # those of ``coarse`` already refined at full resolution
    best = None
    while True:
        # proposals to half resolution (until one explains nearly all the walls) ...
        while remaining:
            pose = _refine_coarse(remaining.pop(0).pose, edges, model, cfg)
            if 0.8 * lo <= pose.px_per_mm <= 1.25 * hi:
                matched = fit(pose, 3.0, None).matched_length_mm
                coarse.append(_Proposal(matched, pose))
                if matched >= excellent:
                    break
        # ... and the best supported few not yet refined to full resolution
        ranked = _distinct(sorted(coarse, key=lambda p: -p.score), len(coarse))
        for prop in [p for p in ranked if not any(p is q for q in refined)][: cfg.n_fine]:
            refined.append(prop)
            pose, half_width = _refine_fine(prop.pose, edges, model, cfg)
            result = fit(pose, cfg.model_spacing_px, half_width)
            delta = _valley_scan(pose, edges.pyramid, model, b_per_rad)
            if delta != 0.0:
                turned, turned_hw = _refine_fine(_valley_pose(pose, delta, b_per_rad), edges, model, cfg)
                turned_fit = fit(turned, cfg.model_spacing_px, turned_hw)
                if turned_fit.matched_length_mm > result.matched_length_mm:
                    pose, half_width, result = turned, turned_hw, turned_fit
            if best is None or result.matched_length_mm > best[2].matched_length_mm:
                best = (pose, half_width, result)
            if result.matched_length_mm >= excellent:
                return best
        # Not confirmed at full resolution (the half-resolution fit is lenient: an array deep
        # in the channel, its edges taken for walls, can pass it in a wrong pose): go on
        # with the proposals left, if any.
        if not remaining:
            return best


def register(
    gray_frames: list[np.ndarray] | np.ndarray,
    phantom: Phantom = DEFAULT_PHANTOM,
    cfg: RegistrationConfig = RegistrationConfig(),
) -> Registration:
    """Find the phantom in frames of a static view, with no initial guess.

    Parameters
    ----------
    gray_frames : list of ndarray, or one ndarray
        Frames (grey or BGR; uint8, uint16 or float) of one camera view, e.g. the first
        frames of a video; merged per :attr:`RegistrationConfig.combine`.
    phantom : Phantom
        Phantom geometry.
    cfg : RegistrationConfig
        Search ranges and tolerances.

    Returns
    -------
    Registration

    Raises
    ------
    RegistrationError
        When no pose explains the edges well enough: no phantom, too little of it in view,
        or too few edges. The message says which test failed.
    """
    frames = _frame_list(gray_frames)
    gray = combine_frames(frames, cfg.combine)
    h, w = gray.shape
    scale_range = search_range(cfg, w, h)
    scales = f"{scale_range[0]:g}-{scale_range[1]:g} px/mm"  # named when nothing is found
    gx, gy, sigma, magnitude = _gradients_for_canny(gray, cfg.edge_sigma_px)
    levels = max(0, int(math.floor(math.log2(max(scale_range[1], 1.0) / 3.0))))
    em = edges_from_gradients(gx, gy, sigma_px=sigma, min_length_px=cfg.min_segment_px, magnitude=magnitude)
    edges = _prepare_edges(em, levels)
    if len(edges.points) < 50:
        raise RegistrationError(
            f"no phantom found: only {len(edges.points)} edge pixels in the {w}x{h} frame (blank or featureless)"
        )
    model = wall_model(phantom, spacing_mm=0.02)
    layers = _edge_layers(edges.edge_map)
    b_per_rad = math.degrees(phantom.b_per_deg)  # b of the exponential branch, 1/rad
    best = _best_pose(edges, layers, model, cfg, scale_range, b_per_rad)
    if best is None:
        raise RegistrationError(f"no phantom found at {scales}: no candidate of the global search converged to a "
                                "plausible scale")
    pose, half_width, fit = best
    doubled = _doubled_walls(edges, layers, pose, half_width, model, cfg, b_per_rad)
    shift, contrast = (0.0, 0.0), float("nan")
    if doubled is not None:
        copies, contrast = doubled
        pose, half_width, shift = copies.pose, copies.half_width, copies.shift
        sub = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
        fit = _wall_fit_from(pose, layers, sub, half_width, cfg.inlier_tol_px, np.asarray(shift))
    reasons = []
    if fit.visible_fraction < cfg.min_visible_fraction:
        reasons.append(f"only {fit.visible_fraction:.0%} of its walls would be in view")
    if fit.inlier_fraction < cfg.min_inlier_fraction:
        reasons.append(
            f"only {fit.inlier_fraction:.0%} of its visible walls lie on edges of matching orientation "
            f"(need {cfg.min_inlier_fraction:.0%})"
        )
    if fit.residual_px > cfg.max_residual_px:
        reasons.append(f"median wall-to-edge distance {fit.residual_px:.1f} px (max {cfg.max_residual_px:.1f})")
    if reasons:
        raise RegistrationError(f"no phantom found at {scales}: the best candidate fails: " + "; ".join(reasons))
    registration = Registration(
        pose=pose,
        residual_px=fit.residual_px,
        inlier_fraction=fit.inlier_fraction,
        visible_fraction=fit.visible_fraction,
        matched_length_mm=fit.matched_length_mm,
        line_half_width_px=half_width,
        edge_sigma_px=sigma,
        image_size=(w, h),
        walls_doubled=doubled is not None,
        parallax_px=shift,
        second_copy_contrast=contrast,
    )
    # check()'s wall points, from the model at hand (what wall_fit would build on first use)
    key, walls = (phantom, pose), _check_walls(pose, model)
    registration._check_cache[key] = walls
    # the residual as check() will measure it on later frames: on one frame as given
    result = replace(registration, residual_px=wall_fit(frames[0], registration, phantom, cfg).residual_px)
    result._check_cache[key] = walls  # replace() starts with an empty cache
    return result


def check(gray: np.ndarray, registration: Registration, phantom: Phantom = DEFAULT_PHANTOM) -> float:
    """Residual (px) of an existing registration on a new frame, in a few milliseconds.

    Canny (with the registration's smoothing) runs only on the phantom's bounding box; the
    result is :attr:`WallFit.residual_px`, the statistic stored as
    :attr:`Registration.residual_px`. A bumped camera shows as a residual well above the
    registration's own, since the walls no longer lie on their edges.

    Parameters
    ----------
    gray : ndarray, shape (h, w) or (h, w, 3)
        The new frame (grey or BGR; any dtype :func:`vision.edges.as_float_gray` accepts).
    registration : Registration
        The registration to test. The wall points are cached on it on first use.
    phantom : Phantom
        Phantom geometry.

    Returns
    -------
    float
        Residual (px); ``inf`` when no wall is in view.
    """
    return wall_fit(gray, registration, phantom).residual_px

"""The public entry points: :func:`register` (search, refinement, doubled walls and
verification of a merged frame) and :func:`check` (the residual of a registration on a new
frame)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tympani.vision.edges import edges_from_gradients
from tympani.vision.geometry import DEFAULT_PHANTOM, CameraPose, Phantom
from tympani.vision.registration.axis import (
    array_axis_offset,
    axis_normal,
    copy_offsets,
    nearer_second_copy,
    off_the_axis,
)
from tympani.vision.registration.coarse import Proposal, coarse_search, distinct
from tympani.vision.registration.config import (
    Registration,
    RegistrationConfig,
    RegistrationError,
    search_range,
)
from tympani.vision.registration.doubled import doubled_walls, lines_beside_the_edge
from tympani.vision.registration.frames import (
    Edges,
    combine_frames,
    frame_list,
    gradients_for_canny,
    prepare_edges,
)
from tympani.vision.registration.model import WallModel, wall_model
from tympani.vision.registration.refine import refine_coarse, refine_fine, refine_fringe
from tympani.vision.registration.valley import valley_pose, valley_scan
from tympani.vision.registration.verify import WallFit, check_walls, edge_layers, wall_fit, wall_fit_from


# A candidate whose inliers cover this fraction of the whole wall model is taken without
# refining the others (nothing else could explain clearly more of the walls).
_EXCELLENT = 0.85
# A best fit that does not explain that much is refined again from these multiples of its scale
# (and turned along the spiral's valley where that explains more), and replaced by a fit at least
# _RESTART_STEP away in scale that explains at least _RESTART_GAIN times as much of the walls
# with no larger residual: where a wall's copies are regions (a channel seen twice through a
# thick plate), a fit between them settles a few percent off in scale (an independent renderer:
# 5.8 % and 4.6 px off, 57 mm of walls explained, residual 0.99 px; at the true scale 65 mm,
# 0.41 px). A fit at the same scale
# that explains more is the other copy, which the array decides between (see doubled_walls);
# one that explains more with a larger residual is not better.
_RESTART_SCALES = (0.92, 0.94, 0.96, 1.04, 1.06, 1.08)
_RESTART_GAIN = 1.02
_RESTART_STEP = 0.01


@dataclass(frozen=True)
class Fitted:
    """A pose refined at full resolution: the pose, the wall lines' half width (px), its fit
    and the walls' fringe (px, :attr:`Registration.fringe_px`; 0 for walls without)."""

    pose: CameraPose
    half_width: float
    fit: WallFit
    fringe: float = 0.0


def _fringed_fit(start: CameraPose, edges: Edges, layers: np.ndarray, model: WallModel,
                 cfg: RegistrationConfig) -> Fitted | None:
    """The fit of fringed walls near ``start`` (:func:`refine_fringe`) where one is found and
    passes the fit's tests, else None."""
    found = refine_fringe(start, edges, model, cfg)
    if found is None:
        return None
    pose, fringe = found
    result = wall_fit_from(pose, layers, model.subsample(cfg.model_spacing_px / pose.px_per_mm), 0.0,
                           cfg.inlier_tol_px, fringe=fringe)
    return None if _fit_failures(result, cfg) else Fitted(pose, 0.0, result, fringe)


def _best_pose(
    edges: Edges,
    layers: np.ndarray,
    model: WallModel,
    cfg: RegistrationConfig,
    scale_range: tuple[float, float],
    b_per_rad: float,
) -> tuple[Fitted | None, Fitted | None]:
    """Global search over ``scale_range`` (px/mm), refinement of the best proposals, and the
    best-supported result, with the best-supported fit of fringed walls.

    Each proposal refined at full resolution is also refined from the best turn along the
    spiral's self-similarity valley (:func:`valley_scan`), and the better supported of the
    two kept. A best result that does not explain nearly all the walls is refined again from a
    few percent smaller and larger scales (``_RESTART_SCALES``).

    ``layers`` is :func:`edge_layers` of the edges and ``b_per_rad`` the exponential
    branch's ``b`` (1/rad). Every refinement at full resolution is also fitted as fringed walls
    (:func:`refine_fringe`). Returns the best :class:`Fitted` (or None) and the best fringed
    one that passes the fit's tests (or None).
    """
    proposals = coarse_search(edges, model, cfg, scale_range)
    lo, hi = scale_range

    def fit(pose: CameraPose, spacing_px: float, half_width: float | None, fringe: float = 0.0) -> WallFit:
        sub = model.subsample(spacing_px / pose.px_per_mm)
        tol = cfg.inlier_tol_px + (cfg.max_line_half_width_px if half_width is None else 0.0)
        return wall_fit_from(pose, layers, sub, half_width, tol, fringe=fringe)

    fringed: list[Fitted] = []
    excellent = _EXCELLENT * model.length_mm

    def fine(start: CameraPose) -> Fitted:
        """``start`` refined at full resolution; unless its walls lie within
        ``cfg.fringe_try_residual_px`` of their edges and it explains nearly all of them, its
        fit as fringed walls, where that passes, is kept in ``fringed``."""
        pose, half_width = refine_fine(start, edges, model, cfg)
        result = Fitted(pose, half_width, fit(pose, cfg.model_spacing_px, half_width))
        if result.fit.residual_px > cfg.fringe_try_residual_px or result.fit.matched_length_mm < excellent:
            alternative = _fringed_fit(start, edges, layers, model, cfg)
            if alternative is not None:
                fringed.append(alternative)
        return result

    def refined(start: CameraPose) -> Fitted:
        """``start`` refined at full resolution, or its turn along the valley where that
        explains more of the walls."""
        result = fine(start)
        delta = valley_scan(result.pose, edges.pyramid, model, b_per_rad)
        if delta != 0.0:
            turned = fine(valley_pose(result.pose, delta, b_per_rad))
            if turned.fit.matched_length_mm > result.fit.matched_length_mm:
                return turned
        return result

    def rescaled(best: Fitted) -> Fitted:
        pose0 = best.pose
        for k in _RESTART_SCALES:
            result = refined(CameraPose(pose0.centre_x_px, pose0.centre_y_px, pose0.rotation_rad,
                                        k * pose0.px_per_mm, pose0.mirrored))
            if not 0.8 * lo <= result.pose.px_per_mm <= 1.25 * hi:
                continue
            if (abs(result.pose.px_per_mm / pose0.px_per_mm - 1.0) >= _RESTART_STEP
                    and result.fit.matched_length_mm >= _RESTART_GAIN * best.fit.matched_length_mm
                    and result.fit.residual_px <= best.fit.residual_px):
                best = result
        return best

    def best_fringed() -> Fitted | None:
        return max(fringed, key=lambda f: f.fit.matched_length_mm, default=None)

    remaining = list(proposals)
    coarse: list[Proposal] = []
    done: list[Proposal] = []  # those of ``coarse`` already refined at full resolution
    best = None
    while True:
        # proposals to half resolution (until one explains nearly all the walls) ...
        while remaining:
            pose = refine_coarse(remaining.pop(0).pose, edges, model, cfg)
            if 0.8 * lo <= pose.px_per_mm <= 1.25 * hi:
                matched = fit(pose, 3.0, None).matched_length_mm
                coarse.append(Proposal(matched, pose))
                if matched >= excellent:
                    break
        # ... and the best supported few not yet refined to full resolution
        ranked = distinct(sorted(coarse, key=lambda p: -p.score), len(coarse))
        for prop in [p for p in ranked if not any(p is q for q in done)][: cfg.n_fine]:
            done.append(prop)
            result = refined(prop.pose)
            if best is None or result.fit.matched_length_mm > best.fit.matched_length_mm:
                best = result
            if result.fit.matched_length_mm >= excellent:
                return best, best_fringed()
        # Not confirmed at full resolution (the half-resolution fit is lenient: an array deep
        # in the channel, its edges taken for walls, can pass it in a wrong pose): go on
        # with the proposals left, if any.
        if not remaining:
            return (None if best is None else rescaled(best)), best_fringed()


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
    frames = frame_list(gray_frames)
    gray = combine_frames(frames, cfg.combine)
    h, w = gray.shape
    scale_range = search_range(cfg, w, h)
    scales = f"{scale_range[0]:g}-{scale_range[1]:g} px/mm"  # named when nothing is found
    gx, gy, sigma, magnitude = gradients_for_canny(gray, cfg.edge_sigma_px)
    levels = max(0, int(math.floor(math.log2(max(scale_range[1], 1.0) / 3.0))))
    em = edges_from_gradients(gx, gy, sigma_px=sigma, min_length_px=cfg.min_segment_px, magnitude=magnitude)
    edges = prepare_edges(em, levels)
    if len(edges.points) < 50:
        raise RegistrationError(
            f"no phantom found: only {len(edges.points)} edge pixels in the {w}x{h} frame (blank or featureless)"
        )
    model = wall_model(phantom, spacing_mm=0.02)
    layers = edge_layers(edges.edge_map)
    b_per_rad = math.degrees(phantom.b_per_deg)  # b of the exponential branch, 1/rad
    best, fringed = _best_pose(edges, layers, model, cfg, scale_range, b_per_rad)
    if best is None:
        raise RegistrationError(f"no phantom found at {scales}: no candidate of the global search converged to a "
                                "plausible scale")
    pose, half_width, fit = best.pose, best.half_width, best.fit

    def where_array(first: CameraPose, shift: tuple[float, float]) -> tuple[float, float]:
        return copy_offsets(gray, first, shift, phantom)

    def checked(pose: CameraPose, half_width: float, line_offset: float, shift: np.ndarray | None = None,
                half_width2: float | None = None) -> tuple[WallFit, list[str]]:
        """A candidate's fit on the walls ``cfg.model_spacing_px`` apart, and why it fails."""
        sub = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
        result = wall_fit_from(pose, layers, sub, half_width, cfg.inlier_tol_px, shift, half_width2, line_offset)
        return result, _fit_failures(result, cfg)

    # the array outside the entry off this fit's axis: the other copy of doubled walls is sought
    # where the array lies
    offset = array_axis_offset(gray, pose, phantom)
    guide = (axis_normal(pose, phantom), offset) if off_the_axis(offset, pose.px_per_mm) else None
    doubled = doubled_walls(edges, layers, pose, half_width, model, cfg, b_per_rad, where_array, guide, gray)
    shift, contrast, line_offset = (0.0, 0.0), float("nan"), 0.0
    reasons = _fit_failures(fit, cfg)
    if doubled is not None:
        copies, contrast = doubled
        copy_offset, delta = where_array(copies.pose, copies.shift)
        swapped = nearer_second_copy(copy_offset, delta, copies.pose.px_per_mm)
        if swapped:
            copies, contrast = copies.swapped(), 1.0 / contrast
        copies_fit, copies_reasons = checked(copies.pose, copies.half_width, copies.offset,
                                             np.asarray(copies.shift), copies.half_width2)
        if copies_reasons and not reasons:  # the single fit stands where the copies' fails
            doubled, contrast = None, float("nan")
        else:
            pose, half_width, shift, fit, reasons = (copies.pose, copies.half_width, copies.shift, copies_fit,
                                                     copies_reasons)
            line_offset = copies.offset
            offset = array_axis_offset(gray, pose, phantom) if swapped else copy_offset
    if doubled is None:
        beside = lines_beside_the_edge(edges, layers, pose, half_width, model, cfg)
        if beside is not None:
            moved_pose, moved_hw, moved_offset = beside
            moved_fit, moved_reasons = checked(moved_pose, moved_hw, moved_offset)
            if not moved_reasons or reasons:  # as the copies: not where it fails and the fit before passed
                pose, half_width, line_offset = moved_pose, moved_hw, moved_offset
                fit, reasons = moved_fit, moved_reasons
                offset = array_axis_offset(gray, pose, phantom)
    # fringed walls: where a pair of like edges either side of each wall fits them closely, at
    # least as well and clearly closer than the walls found above (a fringe's three edges give any fit
    # more edges to lie near), the walls lie between the pairs; the single fit takes one edge
    # of each pair, and the pairs of neighbouring walls can pull it off scale or pass for doubled walls
    fringe = 0.0
    if fringed is None and doubled is not None:
        # none found from the proposals (nor tried where the single fit lay within
        # cfg.fringe_try_residual_px): from the single fit, whose pairs passed for copies
        fringed = _fringed_fit(best.pose, edges, layers, model, cfg)
    if fringed is not None and fringed.fit.residual_px <= cfg.fringe_max_residual_px and (reasons or (
            fringed.fit.matched_length_mm >= fit.matched_length_mm
            and fringed.fit.residual_px <= cfg.fringe_residual_share * fit.residual_px)):
        pose, half_width, fit, fringe, reasons = fringed.pose, 0.0, fringed.fit, fringed.fringe, []
        doubled, shift, contrast, line_offset = None, (0.0, 0.0), float("nan"), 0.0
        offset = array_axis_offset(gray, pose, phantom)
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
        array_axis_offset_px=offset,
        line_offset_px=line_offset,
        fringe_px=fringe,
    )
    # check()'s wall points, from the model at hand (what wall_fit would build on first use)
    key, walls = (phantom, pose), check_walls(pose, model)
    registration._check_cache[key] = walls
    # the residual as check() will measure it on later frames: on one frame as given
    result = replace(registration, residual_px=wall_fit(frames[0], registration, phantom, cfg).residual_px)
    result._check_cache[key] = walls  # replace() starts with an empty cache
    return result


def _fit_failures(fit: WallFit, cfg: RegistrationConfig) -> list[str]:
    """Why a registration's :class:`WallFit` is not accepted (empty when it is)."""
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
    return reasons


def check(gray: np.ndarray, registration: Registration, phantom: Phantom = DEFAULT_PHANTOM) -> float:
    """Residual (px) of an existing registration on a new frame, in a few milliseconds.

    Canny (with the registration's smoothing) runs only on the phantom's bounding box; the
    result is :attr:`WallFit.residual_px`, the statistic stored as
    :attr:`Registration.residual_px`. A bumped camera shows as a residual well above the
    registration's own, since the walls no longer lie on their edges.

    Parameters
    ----------
    gray : ndarray, shape (h, w) or (h, w, 3)
        The new frame (grey or BGR; any dtype :func:`tympani.vision.greyscale.as_float_gray` accepts).
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

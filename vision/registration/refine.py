"""Refinement of a proposal: a 1-D mean shift along the wall normals and weighted
Gauss–Newton steps of the similarity, down the pyramid of the doubled-angle field, then the
polarity-aware fit at full resolution that also estimates the wall lines' half width."""

from __future__ import annotations

import math

import cv2
import numpy as np

from tympani.vision.geometry import CameraPose
from tympani.vision.registration.config import RegistrationConfig
from tympani.vision.registration.frames import Edges
from tympani.vision.registration.model import WallModel
from tympani.vision.registration.poses import image_points, scaled_pose, similarity_jacobian, updated


# Variance (px²) by which an edge is spread in the sampled fields: Gaussian 0.7 px plus the
# bilinear splat and the bilinear sampling (1/6 px² each). A Gaussian-weighted mean offset
# with kernel sigma sees an edge at sigma² / (sigma² + this) of its true offset.
FIELD_BLUR_VAR = 0.7**2 + 2.0 / 6.0


def profiles(fld: np.ndarray, pts: np.ndarray, nrm: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Bilinear samples of a field along each point's normal at offsets ``t`` (px).

    Returns an ``(n, len(t))`` float32 array for a one-channel field, ``(n, len(t), 2)`` for a
    two-channel one (zero outside the image).
    """
    shape = (len(pts), len(t))
    # pts + t * nrm summed in float64 and rounded once to float32 (the maps remap takes)
    sx = np.add(np.multiply.outer(nrm[:, 0], t), pts[:, 0:1], out=np.empty(shape, np.float32))
    sy = np.add(np.multiply.outer(nrm[:, 1], t), pts[:, 1:2], out=np.empty(shape, np.float32))
    return cv2.remap(fld, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def normal_profiles(sfield: np.ndarray, pts: np.ndarray, nrm: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The signed field along each point's normal at offsets ``t`` (px), projected on the normal:
    ``(n, len(t))``, + where the edges' gradient (dark to bright) points along the normal."""
    prof = profiles(sfield, pts, nrm, t)
    proj = prof[..., 0] * nrm[:, 0:1]  # in place from here on (n x len(t) samples)
    proj += prof[..., 1] * nrm[:, 1:2]
    return proj


def window_moments(proj: np.ndarray, t: np.ndarray, sign: float, expected: float,
                   sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Per point, the weight of the edges of polarity ``sign`` in a Gaussian window (``sigma``,
    px) about ``expected`` (px along the normal) of :func:`normal_profiles` ``proj`` sampled at
    ``t``, and their first moment about ``expected``: the moment over the weight is their mean
    offset, to be scaled by the field's blur gain (``FIELD_BLUR_VAR``)."""
    a = sign * proj
    np.maximum(a, 0.0, out=a)
    a *= np.exp(-0.5 * ((t - expected) / sigma) ** 2)
    return a.sum(axis=1), a @ (t - expected)


def solve_step(jac: np.ndarray, r: np.ndarray, wt: np.ndarray, max_px: float) -> np.ndarray | None:
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


def visible(pts: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Whether each point (px, x and y) lies less than a pixel beyond the outermost pixel
    centres of an image of ``shape`` (rows and columns first): ``-1 < x < w``, ``-1 < y < h``."""
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
    gain = 1.0 + FIELD_BLUR_VAR / sigma**2  # undoes the shrinkage of the weighted mean
    scale0 = pose.px_per_mm
    t = np.arange(-3.0 * sigma, 3.0 * sigma + 1e-9, 0.5)
    kernel = np.exp(-0.5 * (t / sigma) ** 2)
    for _ in range(iterations):
        pts, nrm = image_points(pose, model)
        vis = visible(pts, fld.shape)
        n_vis = int(np.count_nonzero(vis))
        if n_vis < 20:
            break
        if n_vis < len(vis):
            pts, nrm = pts[vis], nrm[vis]
        prof = profiles(fld, pts, nrm, t)
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
        jac, rho = similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        step = solve_step(jac, gain * moment / wsum, wsum, max_px=3.0 * sigma * gain)
        if step is None:
            break
        pose = updated(pose, step, rho)
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break  # diverging: the caller's fit statistics will reject the result
        if float(np.abs(step).sum()) < tol_px:
            break
    return pose


def refine_signed(
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
    gain = 1.0 + FIELD_BLUR_VAR / sigma**2
    scale0 = pose.px_per_mm
    reach = max_half_width + 3.0 * sigma
    t = np.arange(-reach, reach + 1e-9, 0.5)
    for _ in range(iterations):
        pts, nrm = image_points(pose, model)
        vis = visible(pts, sfield.shape)
        n_vis = int(np.count_nonzero(vis))
        if n_vis < 20:
            break
        if n_vis < len(vis):
            pts, nrm = pts[vis], nrm[vis]
        proj = normal_profiles(sfield, pts, nrm, t)
        base, rho = similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        classes = []  # (sign, rows kept, their offsets, their weights) of each polarity
        for sign in (1.0, -1.0):
            wsum, moment = window_moments(proj, t, sign, sign * half_width, sigma)
            ok = wsum > 1e-3
            if np.count_nonzero(ok) < 10:
                continue
            classes.append((sign, ok, gain * moment[ok] / wsum[ok], wsum[ok]))
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
        step = solve_step(jac, rhs, np.concatenate([w for *_, w in classes]), max_px=reach * gain)
        if step is None:
            break
        pose = updated(pose, step[:4], rho)
        half_width = min(max(half_width + float(step[4]), -max_half_width), max_half_width)
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break
        if float(np.abs(step).sum()) < tol_px:
            break
    return pose, half_width


def refine_fringed(
    pose: CameraPose,
    fringe: float,
    sfield: np.ndarray,
    model: WallModel,
    sigma: float,
    iterations: int,
    *,
    max_fringe: float,
    tol_px: float = 0.01,
) -> tuple[CameraPose, float, tuple[float, float, float, float]]:
    """Polarity-aware refinement of fringed walls at full resolution.

    Light refracted at a wall can show as a bright band on one side and a dark band on the
    other, against the step between fluid and plate: each wall then shows two edges of the
    step's polarity ``±f`` (px, along the outward normal) either side of it and one of the other
    polarity on it. Edges of class ``sign(fringe)`` (as :func:`refine_signed`'s classes) are
    fitted at ``-f`` and ``+f``, the other class at 0, ``f`` estimated with the pose from
    ``|fringe|``; ``f`` is kept within ``[0.5, max_fringe]``. The pair's outer edge is fitted
    only on walls with room beyond them (``model.room_mm``): across a septum between turns a
    neighbouring wall's fringe overlaps it.

    Returns the pose, the signed ``f`` (px), and the mean edge weight per wall point with room
    beyond of the pair's inner (``-f``) and outer (``+f``) edge (a wall fringed on both sides
    supports both about equally), per visible wall point of the middle one, and the pair's
    evenness on the walls with room: its weight on the walls facing each of four directions
    (normals binned by angle modulo π), the weakest direction's over the strongest's.
    """
    sign = 1.0 if fringe > 0 else -1.0
    spread = abs(fringe)
    gain = 1.0 + FIELD_BLUR_VAR / sigma**2
    scale0 = pose.px_per_mm
    reach = max_fringe + 3.0 * sigma
    t = np.arange(-reach, reach + 1e-9, 0.5)
    support = (0.0, 0.0, 0.0, 0.0)
    for _ in range(iterations):
        pts, nrm = image_points(pose, model)
        vis = visible(pts, sfield.shape)
        if int(np.count_nonzero(vis)) < 20:
            break
        pts, nrm = pts[vis], nrm[vis]
        # the pair's outer edge only where the next wall beyond (across a septum) is far enough
        # for its own fringe to stay clear of it
        clear = model.room_mm[vis] * pose.px_per_mm >= 2.0 * spread + 3.0 * sigma
        proj = normal_profiles(sfield, pts, nrm, t)
        base, rho = similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
        rows = []  # (d offset / d f, rows kept, their offsets, their weights) of each expected edge
        for cls, side in ((sign, -1.0), (sign, 1.0), (-sign, 0.0)):
            wsum, moment = window_moments(proj, t, cls, side * spread, sigma)
            ok = (wsum > 1e-3) & (clear if side > 0 else True)
            rows.append((side, ok, gain * moment[ok] / wsum[ok], wsum[ok]))
        # on the walls clear beyond: how often each edge of the pair shows, and how evenly
        # around the spiral (a fringe lies along every wall, the two copies of doubled walls
        # show apart only where the walls face along their parallax)
        pair = np.zeros((2, len(pts)))
        for k, (_, ok, _, w) in enumerate(rows[:2]):
            pair[k, ok] = w
        pair = pair[:, clear]
        n_clear = max(int(np.count_nonzero(clear)), 1)
        facing = np.minimum((np.arctan2(nrm[clear, 1], nrm[clear, 0]) % np.pi) * (4.0 / np.pi), 3.999).astype(np.intp)
        counts = np.bincount(facing, minlength=4)
        per_bin = np.bincount(facing, weights=pair.sum(axis=0), minlength=4) / np.maximum(counts, 1)
        evenness = float(per_bin[counts > 0].min() / max(per_bin.max(), 1e-12)) if counts.any() else 0.0
        support = (float(pair[0].sum()) / n_clear, float(pair[1].sum()) / n_clear,
                   float(rows[2][3].sum()) / len(pts), evenness)
        if sum(len(r) for _, _, r, _ in rows) < 20:
            break
        jac = np.concatenate([np.column_stack([base[ok], np.full(int(ok.sum()), side)]) for side, ok, _, _ in rows])
        rhs = np.concatenate([r for _, _, r, _ in rows])
        step = solve_step(jac, rhs, np.concatenate([w for *_, w in rows]), max_px=reach * gain)
        if step is None:
            break
        pose = updated(pose, step[:4], rho)
        spread = min(max(spread + float(step[4]), 0.5), max_fringe)
        if not 0.5 * scale0 < pose.px_per_mm < 2.0 * scale0:
            break
        if float(np.abs(step).sum()) < tol_px:
            break
    return pose, sign * spread, support


def _start_level(pose: CameraPose, n_levels: int) -> int:
    """Pyramid level at which the phantom appears at 3–6 px/mm."""
    return int(np.clip(math.floor(math.log2(max(pose.px_per_mm, 1e-6) / 3.0)), 0, n_levels - 1))


def refine_coarse(pose: CameraPose, edges: Edges, model: WallModel, cfg: RegistrationConfig) -> CameraPose:
    """Refine a proposal down the pyramid to half resolution (doubled-angle field)."""
    for level in range(_start_level(pose, len(edges.pyramid)), 0, -1):
        f = 0.5**level
        lp = scaled_pose(pose, f)
        sub = model.subsample(cfg.model_spacing_px / lp.px_per_mm)
        lp = _refine_level(lp, edges.pyramid[level], sub, 1.0, iterations=10, tol_px=0.05)
        pose = scaled_pose(lp, 1.0 / f)
    return pose


def refine_fine(
    pose: CameraPose, edges: Edges, model: WallModel, cfg: RegistrationConfig
) -> tuple[CameraPose, float]:
    """Full-resolution refinement: doubled-angle field, then the polarity-aware fit.

    Returns the pose and the wall lines' half width (px).
    """
    sub = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
    pose = _refine_level(pose, edges.pyramid[0], sub, cfg.refine_sigma_px, iterations=10, tol_px=0.05)
    return refine_signed(
        pose, 0.0, edges.signed, sub, cfg.final_sigma_px, iterations=20, max_half_width=cfg.max_line_half_width_px
    )


def refine_fringe(pose: CameraPose, edges: Edges, model: WallModel, cfg: RegistrationConfig) -> tuple[CameraPose, float] | None:
    """The pose and signed fringe (px, :attr:`Registration.fringe_px`) of fringed walls near
    ``pose``, or None where the walls do not look fringed.

    From ``pose`` refined once more polarity-blind (and, where no result from there counts and
    that refinement moved the walls by ``cfg.fringe_min_px`` or more in the median, from
    ``pose`` itself: a blind refinement can settle on one edge of each pair, moving the walls
    by about the fringe across those facing one way), :func:`refine_fringed` runs for both
    polarities from each of ``cfg.fringe_starts_px``; a result counts where its pair of like
    edges lies at least ``cfg.fringe_min_px`` either side of the wall (a single edge or a line
    pulls ``f`` to the smallest or largest value allowed instead), both edges of the pair are
    found about equally often (the weaker at least ``cfg.fringe_balance`` of the stronger) and
    evenly around the spiral (``cfg.fringe_evenness``). Of those, the best supported is returned.
    """
    sub = model.subsample(cfg.model_spacing_px / pose.px_per_mm)
    blind = _refine_level(pose, edges.pyramid[0], sub, cfg.refine_sigma_px, iterations=10, tol_px=0.05)
    best = _fringed_from(blind, edges, sub, cfg)
    if best is None:
        moved = np.linalg.norm(image_points(blind, sub)[0] - image_points(pose, sub)[0], axis=1)
        if float(np.median(moved)) >= cfg.fringe_min_px:
            best = _fringed_from(pose, edges, sub, cfg)
    return best


def _fringed_from(origin: CameraPose, edges: Edges, sub: WallModel,
                  cfg: RegistrationConfig) -> tuple[CameraPose, float] | None:
    """The best supported fringed fit (pose, signed fringe in px) of :func:`refine_fringe`
    from ``origin`` that counts, or None."""
    best, best_support = None, 0.0
    for sign in (1.0, -1.0):
        for start in cfg.fringe_starts_px:
            fitted, fringe, _ = refine_fringed(origin, sign * start, edges.signed, sub, 1.5 * cfg.final_sigma_px, 10,
                                               max_fringe=cfg.fringe_max_px)
            fitted, fringe, (inner, outer, middle, evenness) = refine_fringed(fitted, fringe, edges.signed, sub,
                                                                    cfg.final_sigma_px, 20, max_fringe=cfg.fringe_max_px)
            if not cfg.fringe_min_px <= abs(fringe) <= cfg.fringe_max_px - 0.25:
                continue
            if min(inner, outer) < cfg.fringe_balance * max(inner, outer) or evenness < cfg.fringe_evenness:
                continue
            if inner + outer + middle > best_support:
                best, best_support = (fitted, fringe), inner + outer + middle
    return best

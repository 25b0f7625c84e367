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
        prof = profiles(sfield, pts, nrm, t)
        proj = prof[..., 0] * nrm[:, 0:1]  # in place from here on (n x len(t) samples)
        proj += prof[..., 1] * nrm[:, 1:2]
        base, rho = similarity_jacobian(pts, nrm, np.array([pose.centre_x_px, pose.centre_y_px]))
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

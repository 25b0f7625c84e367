"""Pose helpers shared by the search and the fits: wall points in the image, a pose on a
resized image, and the linearised similarity update with its Jacobian (px, rad)."""

from __future__ import annotations

import math

import numpy as np

from tympani.vision.geometry import CameraPose
from tympani.vision.registration.model import WallModel


def image_points(pose: CameraPose, model: WallModel) -> tuple[np.ndarray, np.ndarray]:
    """Model points (px) and their unit normals in the image for ``pose``."""
    m = pose._matrix()  # the linear part of pose.affine(), without building the 2x3 matrix
    pts = model.points @ m.T + np.array([pose.centre_x_px, pose.centre_y_px])
    nrm = model.normals @ (m.T / max(pose.px_per_mm, 1e-12))  # a similarity: normals stay unit
    return pts, nrm


def scaled_pose(pose: CameraPose, factor: float) -> CameraPose:
    """The pose on an image resized by ``factor`` (pixel-centre convention)."""
    return CameraPose(
        (pose.centre_x_px + 0.5) * factor - 0.5,
        (pose.centre_y_px + 0.5) * factor - 0.5,
        pose.rotation_rad,
        pose.px_per_mm * factor,
        pose.mirrored,
    )


def wrap(angle: float) -> float:
    """Angle (rad) wrapped to [-π, π)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def updated(pose: CameraPose, step: np.ndarray, rho: float) -> CameraPose:
    """Apply a linearised similarity update.

    ``step`` = (dx, dy, dlog_scale·rho, dangle·rho) in px, the last two about the current
    centre with lever arm ``rho`` (px); ``dangle`` is an image-frame rotation (x right, y
    down), which is ``-d rotation_rad``.
    """
    return CameraPose(
        float(pose.centre_x_px + step[0]),
        float(pose.centre_y_px + step[1]),
        wrap(pose.rotation_rad - step[3] / rho),
        float(pose.px_per_mm * math.exp(step[2] / rho)),
        pose.mirrored,
    )


def similarity_jacobian(pts: np.ndarray, nrm: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, float]:
    """Rows ``d(n·x)/d step`` for :func:`updated` and the lever arm ``rho`` (px)."""
    d = pts - centre
    dx, dy, nx, ny = d[:, 0], d[:, 1], nrm[:, 0], nrm[:, 1]
    rho = float(np.sqrt(np.mean(dx * dx + dy * dy))) + 1e-9
    jac = np.empty((len(d), 4))
    jac[:, 0] = nx
    jac[:, 1] = ny
    np.divide(nx * dx + ny * dy, rho, out=jac[:, 2])
    np.divide(ny * dx - nx * dy, rho, out=jac[:, 3])
    return jac, rho

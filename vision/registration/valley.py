"""The spiral's self-similarity valley: a turn about the spiral centre with the matching
change of scale moves the exponential part of the spiral onto itself, so only the entry and
the first half-turn tell such turns apart; :func:`valley_scan` picks the best of them."""

from __future__ import annotations

import math

import cv2
import numpy as np

from tympani.vision.geometry import CameraPose
from tympani.vision.registration.model import WallModel
from tympani.vision.registration.poses import image_points, scaled_pose, wrap


# Largest turn (rad) about the spiral centre that :func:`valley_scan` tries either way: fits 68°
# along the valley (9.4 % in scale) were seen where the entry is faint or hidden.
_VALLEY_MAX_RAD = math.radians(90.0)
# Least relative gain of the valley score for which :func:`valley_scan` proposes a turn (a
# wrong turn of the entry loses a quarter or more of it; noise changes it by about 1 %).
_VALLEY_MIN_GAIN = 0.03


def valley_pose(pose: CameraPose, delta: float, b_per_rad: float) -> CameraPose:
    """``pose`` turned by ``delta`` (rad, added to ``rotation_rad``) about the spiral centre
    and rescaled so that the exponential part of the spiral (``r = a exp(-b phi)``, ``b`` in
    1/rad, with a width proportional to ``r``) falls on itself: the scale is multiplied by
    ``exp(-b delta)``, or ``exp(+b delta)`` for a mirrored pose.
    """
    sign = 1.0 if pose.mirrored else -1.0
    return CameraPose(
        pose.centre_x_px,
        pose.centre_y_px,
        wrap(pose.rotation_rad + delta),
        pose.px_per_mm * math.exp(sign * b_per_rad * delta),
        pose.mirrored,
    )


def valley_scan(
    pose: CameraPose,
    pyramid: list[np.ndarray],
    model: WallModel,
    b_per_rad: float,
    parallax_px: np.ndarray | None = None,
) -> float:
    """The turn (rad) along the spiral's self-similarity valley that best fits the walls that
    break it, 0 when none fits better than ``pose`` itself.

    Beyond the 100° corner the backbone is ``a exp(-b phi)`` with a width proportional to the
    radius, so :func:`valley_pose` moves those walls onto themselves: only the entry and the
    first half-turn (groups 0 and 1 of :class:`WallModel`) tell the turns along this valley
    apart, and a fit dominated by the rest of the spiral can settle anywhere on it (the
    entry's walls then lie on the array or on nothing). Those walls are scored by their
    orientation agreement with the doubled-angle field on the pyramid level where the phantom
    appears at 8–16 px/mm (points 1.5 px apart), for turns up to ±90° in steps that move the
    farthest of them by a pixel of that level; a turn is proposed when it scores at least
    :data:`_VALLEY_MIN_GAIN` more than ``pose``. With ``parallax_px`` (px, doubled walls) the
    walls' second copy, shifted by it, is scored too.
    """
    level = int(np.clip(math.floor(math.log2(max(pose.px_per_mm, 1e-6) / 8.0)), 0, len(pyramid) - 1))
    fld = pyramid[level]
    f = 0.5**level
    lp = scaled_pose(pose, f)
    keep = model.group <= 1
    part = WallModel(model.points[keep], model.normals[keep], model.spacing_mm, model.group[keep], model.room_mm[keep])
    part = part.subsample(1.5 / lp.px_per_mm)
    r_max = float(np.max(np.hypot(part.points[:, 0], part.points[:, 1]))) * lp.px_per_mm
    n_side = int(math.ceil(_VALLEY_MAX_RAD * r_max))
    deltas = np.linspace(-_VALLEY_MAX_RAD, _VALLEY_MAX_RAD, 2 * n_side + 1)
    sign = 1.0 if lp.mirrored else -1.0
    # the walls at every turn, (len(deltas), n): raising rotation_rad by delta turns the
    # image about the centre by delta counter-clockwise on screen (x right, y down), mirrored
    # or not, and scales it by g
    pts, nrm = image_points(lp, part)
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

"""True angles against insertion depth: a vectorised twin of the renderer's pose (family A)."""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np

from tympani.vision.geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    ElectrodeArray,
    Phantom,
    backbone_frame,
    channel_width,
    entry_frame,
)
from tympani.vision.rendering import ContactPolicy

__all__ = ["kinematics_batch", "kinematics_table", "interp_angles", "angles_at_depth"]


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@lru_cache(maxsize=8)
def _entry(phantom: Phantom) -> tuple[np.ndarray, np.ndarray]:
    origin, x_w, _ = entry_frame(phantom)
    return origin, x_w


def kinematics_batch(
    policies: Sequence[ContactPolicy],
    depth_max_mm: float,
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    n_tip: int = 32,
    n_pts: int = 80,
    contact_tol_mm: float = 0.05,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`kinematics_table` of several policies at once: arrays of shape (policies, n_tip + 7)."""
    ts = phantom.theta_start
    wall = phantom.outer_wall
    t_hi = min(float(np.interp(depth_max_mm * 1.25 + 1.0, wall.s, wall.theta)), phantom.theta_end - 1e-3)
    first = np.array([p.theta_first for p in policies], dtype=float)
    lag = np.array([p.lag for p in policies], dtype=float)
    approach = np.array([p.approach_rad for p in policies], dtype=float)
    departure = np.array([p.shape.departure_rad for p in policies], dtype=float)
    far = np.array([p.shape.far_offset for p in policies], dtype=float)
    blend = np.array([p.shape.start_blend_rad for p in policies], dtype=float)
    touch = np.array([p.shape.contact_level for p in policies], dtype=float)
    grid = np.linspace(ts + 1e-4, t_hi, n_tip)
    # extra tip angles where theta_bot bends: the approach to first contact and just after it
    extra = first[:, None] + approach[:, None] * np.array([-0.8, -0.6, -0.45, -0.3, -0.15, 0.0, 0.1])
    tips = np.sort(np.concatenate([np.broadcast_to(grid, (len(policies), n_tip)),
                                   np.clip(extra, ts + 1e-4, t_hi)], axis=1), axis=1)  # (P, N)
    u = np.linspace(0.0, 1.0, n_pts)
    th = tips[..., None] - (tips - ts)[..., None] * u  # (P, N, M), tip first, down to theta_start
    pts, _, nrm = backbone_frame(th.ravel(), phantom)
    pts = pts.reshape(*th.shape, 2)
    nrm = nrm.reshape(*th.shape, 2)
    half = 0.5 * channel_width(th, phantom)
    after = tips >= first[:, None]
    bot_nominal = np.where(after, first[:, None] + lag[:, None] * (tips - first[:, None]), tips)
    level = np.where(after, touch[:, None], _smoothstep(1.0 - (first[:, None] - tips) / approach[:, None]))
    start_blend = _smoothstep((th - ts) / blend[:, None, None])
    depart = _smoothstep((bot_nominal[..., None] - th) / departure[:, None, None])
    radius = np.full(th.shape, float(array.radius(0.0)))
    for _ in range(3):  # the radius depends on arc length, which depends on the offset
        play = np.maximum(half - radius, 0.0)
        e_far = far[:, None, None] * 0.85 * play * start_blend
        e_touch = e_far + level[..., None] * (play - e_far)
        e = e_touch + (e_far - e_touch) * depart
        c = pts + e[..., None] * nrm
        step = np.diff(c, axis=2)
        seg = np.hypot(step[..., 0], step[..., 1])
        s = np.concatenate([np.zeros(th.shape[:2] + (1,)), np.cumsum(seg, axis=2)], axis=2)
        radius = array.radius(s)
    depth = s[..., -1]
    phi = np.arctan2(c[..., 1], c[..., 0])
    theta_pt = th + (np.mod(phi - th + np.pi, 2 * np.pi) - np.pi)
    gap = half - e - radius
    touching = gap <= contact_tol_mm
    out = ~touching
    first_out = np.where(out.any(axis=2), out.argmax(axis=2), n_pts - 1)
    i_last = np.maximum(first_out - 1, 0)
    take = lambda a, i: np.take_along_axis(a, i[..., None], axis=2)[..., 0]  # noqa: E731
    g0, g1 = take(gap, i_last), take(gap, first_out)
    frac = np.clip((contact_tol_mm - g0) / np.where(g1 != g0, g1 - g0, 1.0), 0.0, 1.0)
    th0, th1 = take(theta_pt, i_last), take(theta_pt, first_out)
    tip = theta_pt[..., 0]
    bot = np.where(touching[..., 0], np.minimum(th0 + frac * (th1 - th0), tip), tip)
    order = np.argsort(depth, axis=1)
    return (np.take_along_axis(depth, order, 1), np.take_along_axis(tip, order, 1),
            np.take_along_axis(bot, order, 1))


@lru_cache(maxsize=512)
def kinematics_table(
    policy: ContactPolicy,
    depth_max_mm: float,
    *,
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    n_tip: int = 32,
    n_pts: int = 80,
    contact_tol_mm: float = 0.05,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True angles (docs/file-formats.md) against insertion depth for one contact policy (memoised).

    A vectorised twin of :func:`tympani.vision.rendering.pose_at_depth`: for a grid of tip angles the
    array's centreline is the renderer's normal offset of the backbone (contact run on the outer
    wall, smooth departure, settling at ``far_offset``, blend into the insertion axis), its
    length from the tip to ``theta_start`` is the depth, and the contact start is where the gap
    between the array's outer edge and the outer wall first exceeds ``contact_tol_mm``. Agrees
    with ``pose_at_depth(...).truth`` within about 0.015 rad (the renderer's own grid).

    Parameters
    ----------
    policy : ContactPolicy
        How the contact run grows.
    depth_max_mm : float
        Deepest depth (mm) the table must cover.
    phantom, array : Phantom, ElectrodeArray
        Geometry.
    n_tip : int
        Tip angles evenly spread in the table (plus 7 around first contact, where theta_bot bends).
    n_pts : int
        Centreline samples per tip angle.
    contact_tol_mm : float
        Contact tolerance (mm): largest gap to the outer wall that counts as contact.

    Returns
    -------
    depth_mm, theta_tip, theta_bot : ndarray, shape (n_tip + 7,)
        Depth (mm, increasing, > 0) and the true angles (rad) there; interpolate in depth.
        :func:`angles_at_depth` also handles depths in the entry channel.
    """
    d, tip, bot = kinematics_batch([policy], float(depth_max_mm), phantom, array, n_tip, n_pts, contact_tol_mm)
    return d[0], tip[0], bot[0]


def _entry_angle(depth_mm: np.ndarray, phantom: Phantom) -> np.ndarray:
    """Angle (rad) of the tip on the insertion axis at depth <= 0 (k = 0: the polar angle)."""
    origin, x_w = _entry(phantom)
    xy = origin[None, :] + np.asarray(depth_mm, dtype=float)[:, None] * x_w[None, :]
    return np.arctan2(xy[:, 1], xy[:, 0])


def interp_angles(depth_mm: np.ndarray, table: tuple[np.ndarray, np.ndarray, np.ndarray],
                  phantom: Phantom) -> tuple[np.ndarray, np.ndarray]:
    """True ``(theta_tip, theta_bot)`` (rad) at depths (mm), interpolated in a kinematics table.

    Parameters
    ----------
    depth_mm : array_like
        Insertion depths (mm); at or below the table's first depth the tip is on the insertion axis.
    table : tuple of ndarray
        ``(depth_mm, theta_tip, theta_bot)`` of :func:`kinematics_table` (mm, rad, rad).
    phantom : Phantom
        Geometry.
    """
    d_tab, tip_tab, bot_tab = table
    depth_mm = np.asarray(depth_mm, dtype=float)
    tip = np.interp(depth_mm, d_tab, tip_tab)
    bot = np.interp(depth_mm, d_tab, bot_tab)
    outside = depth_mm <= d_tab[0]
    if outside.any():
        tip[outside] = bot[outside] = _entry_angle(depth_mm[outside], phantom)
    return tip, bot


def angles_at_depth(depth_mm: np.ndarray, policy: ContactPolicy, depth_max_mm: float,
                    phantom: Phantom = DEFAULT_PHANTOM) -> tuple[np.ndarray, np.ndarray]:
    """True ``(theta_tip, theta_bot)`` (rad) at depths (mm) for a contact policy.

    Parameters
    ----------
    depth_mm : array_like
        Insertion depths (mm); at or below 0 the tip is on the insertion axis (no contact).
    policy : ContactPolicy
        How the contact run grows.
    depth_max_mm : float
        Deepest depth (mm) of the table (:func:`kinematics_table`); deeper depths are clipped.
    phantom : Phantom
        Geometry.
    """
    return interp_angles(depth_mm, kinematics_table(policy, float(depth_max_mm), phantom=phantom), phantom)

"""Air bubbles in the channel fluid: the channel's middle line they move along, where a bubble
ahead of the tip sits, how a bubble looks and how it is pasted into a frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tympani.vision.geometry import (
    DEFAULT_PHANTOM,
    Phantom,
    arc_length,
    backbone_frame,
    backbone_radius,
    channel_width,
    entry_frame,
    point_angle,
)
from tympani.vision.rendering.centreline import ArrayState, smoothstep

__all__ = [
    "ChannelPath",
    "channel_path",
    "bubble_ahead_of_tip",
    "BubbleLook",
    "random_bubble_look",
    "bubble_patch",
    "paste",
    "FreeBubble",
]


@dataclass(frozen=True)
class ChannelPath:
    """The channel's middle line from the entry's basal end to its closed end, with its frame.

    Parameters
    ----------
    points_mm : ndarray, shape (n, 2)
        Points (mm, phantom frame): the entry's axis, then the backbone.
    tangent, normal : ndarray, shape (n, 2)
        Unit tangent (apical) and unit normal (towards the outer wall).
    half_width_mm : ndarray, shape (n,)
        Half the channel's width (mm).
    u_mm : ndarray, shape (n,)
        Arc length (mm) from the entry's basal end.
    theta : ndarray, shape (n,)
        Backbone angle (rad); ``theta_start`` along the entry.
    """

    points_mm: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray
    half_width_mm: np.ndarray
    u_mm: np.ndarray
    theta: np.ndarray

    def at(self, u_mm: np.ndarray, lateral_mm: np.ndarray) -> np.ndarray:
        """Points (mm) at arc length ``u_mm`` (mm) and normal offset ``lateral_mm`` (mm)."""
        u = np.atleast_1d(np.asarray(u_mm, dtype=float))
        lat = np.broadcast_to(np.asarray(lateral_mm, dtype=float), u.shape)
        p = np.stack([np.interp(u, self.u_mm, self.points_mm[:, k]) for k in range(2)], axis=1)
        n = np.stack([np.interp(u, self.u_mm, self.normal[:, k]) for k in range(2)], axis=1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return p + lat[:, None] * n

    def half_width(self, u_mm: np.ndarray | float) -> np.ndarray:
        """Half the channel's width (mm) at arc length ``u_mm`` (mm)."""
        return np.interp(u_mm, self.u_mm, self.half_width_mm)

    def locate(self, xy_mm: np.ndarray, phantom: Phantom = DEFAULT_PHANTOM) -> tuple[float, float]:
        """Arc length (mm) and normal offset (mm) of a point in or near the channel.

        The point is matched with the path within about half a turn of its (unwrapped) angle, so a
        point is never matched with a neighbouring turn; behind the entry the arc length is
        negative.
        """
        xy = np.asarray(xy_mm, dtype=float).reshape(2)
        theta = float(point_angle(xy[None, :], phantom)[0])
        cand = np.flatnonzero(np.abs(self.theta - theta) < 0.6)
        if cand.size == 0:
            cand = np.arange(len(self.u_mm))
        j = cand[np.argmin(np.hypot(*(self.points_mm[cand] - xy).T))]
        rel = xy - self.points_mm[j]
        return float(self.u_mm[j] + rel @ self.tangent[j]), float(rel @ self.normal[j])


def channel_path(phantom: Phantom = DEFAULT_PHANTOM, step_mm: float = 0.05) -> ChannelPath:
    """The channel's middle line (entry axis, then backbone) sampled about ``step_mm`` (mm) apart."""
    origin, x_w, n_w = entry_frame(phantom)
    n_e = max(2, int(np.ceil(phantom.entry_length_mm / step_mm)) + 1)
    back = np.linspace(phantom.entry_length_mm, 0.0, n_e)[:-1]  # the origin comes with the spiral
    entry_pts = origin[None, :] - back[:, None] * x_w[None, :]
    r_max = float(backbone_radius(phantom.theta_start, phantom))
    n_s = int(np.ceil((phantom.theta_end - phantom.theta_start) * r_max / step_mm)) + 1
    theta = np.linspace(phantom.theta_start, phantom.theta_end, n_s)
    pts, tangent, normal = backbone_frame(theta, phantom)
    points = np.vstack([entry_pts, pts])
    half = 0.5 * np.concatenate([np.full(len(back), float(channel_width(phantom.theta_start, phantom))),
                                 channel_width(theta, phantom)])
    return ChannelPath(
        points_mm=points,
        tangent=np.vstack([np.tile(x_w, (len(back), 1)), tangent]),
        normal=np.vstack([np.tile(n_w, (len(back), 1)), normal]),
        half_width_mm=half,
        u_mm=arc_length(points),
        theta=np.concatenate([np.full(len(back), phantom.theta_start), theta]),
    )


def _bubble_fit(path: ChannelPath, u_mm: np.ndarray, radius_mm: float, lateral_mm: np.ndarray,
                wall_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Radius (mm) and normal offset (mm) of a bubble at ``u_mm`` cut to fit the channel.

    The radius is cut to the half width less ``wall_mm`` (mm, half a wall line); the offset
    is clamped so that the disc stays clear of both wall lines.
    """
    room = np.maximum(path.half_width(u_mm) - wall_mm, 0.05)
    radius = np.minimum(radius_mm, room)
    return radius, np.clip(lateral_mm, -(room - radius), room - radius)


def bubble_ahead_of_tip(
    state: ArrayState,
    radius_mm: float,
    gap_mm: float,
    path: ChannelPath,
    *,
    phantom: Phantom = DEFAULT_PHANTOM,
    wall_mm: float = 0.05,
) -> tuple[np.ndarray, float] | None:
    """Where a bubble just apical of the array's tip sits.

    The bubble keeps the tip's offset from the channel's middle line (clamped so that it fits
    the channel) and lies apical of the tip, its edge ``gap_mm`` from the tip apex (the first
    centreline point; 0 = touching it).

    Parameters
    ----------
    state : ArrayState
        The array.
    radius_mm : float
        Wanted radius (mm); cut to fit the channel there.
    gap_mm : float
        Distance (mm) from the tip apex to the bubble's edge.
    path : ChannelPath
        The channel (:func:`channel_path`).
    phantom : Phantom
        Geometry.
    wall_mm : float
        Half a wall line's width (mm): the bubble stays clear of it.

    Returns
    -------
    (centre_mm, radius_mm) or None
        Centre (mm, phantom frame) and radius (mm); None when the tip is not in the channel
        yet or the bubble would not fit before the channel's closed end.
    """
    apex = state.centreline_mm[0]
    u_tip, e_tip = path.locate(apex, phantom)
    if u_tip < 0.0 or u_tip > path.u_mm[-1]:
        return None
    reach = radius_mm + gap_mm
    u = u_tip + np.linspace(0.0, 2.0 * reach + 1.0, 400)
    radius, lateral = _bubble_fit(path, u, radius_mm, np.full(len(u), e_tip), wall_mm)
    # distance from the apex to the nearest point of the disc centred at each candidate
    edge_gap = np.hypot(*(path.at(u, lateral) - apex).T) - radius
    if edge_gap[0] >= gap_mm:
        return None
    k = int(np.argmax(edge_gap >= gap_mm))
    if k == 0:
        return None
    w = (gap_mm - edge_gap[k - 1]) / max(edge_gap[k] - edge_gap[k - 1], 1e-12)
    u_b = u[k - 1] + w * (u[k] - u[k - 1])
    r_b, lat_b = _bubble_fit(path, np.array([u_b]), radius_mm, np.array([e_tip]), wall_mm)
    if u_b + r_b[0] > path.u_mm[-1]:
        return None
    return path.at(np.array([u_b]), lat_b)[0], float(r_b[0])


@dataclass(frozen=True)
class BubbleLook:
    """How one air bubble looks (grey levels 0–255).

    Parameters
    ----------
    core : float
        Grey level of the bright inside.
    rim : float
        Grey level of the dark rim.
    rim_frac : float
        Rim thickness as a fraction (0–1) of the radius (never under about 1 px).
    highlight : float
        Extra brightness (grey levels) of a small specular dot.
    light_rad : float
        Image direction (rad) of that dot from the centre.
    """

    core: float
    rim: float
    rim_frac: float
    highlight: float
    light_rad: float


def random_bubble_look(rng: np.random.Generator, fluid: float, light_rad: float) -> BubbleLook:
    """A bubble look around a fluid grey level ``fluid`` (0–255), lit from ``light_rad`` (rad)."""
    return BubbleLook(
        core=float(min(252.0, fluid + rng.uniform(15.0, 55.0))),
        rim=float(fluid * rng.uniform(0.15, 0.6)),
        rim_frac=float(rng.uniform(0.1, 0.4)),
        highlight=float(rng.uniform(0.0, 90.0)),
        light_rad=float(light_rad + rng.normal(0.0, 0.2)),
    )


def bubble_patch(
    centre_px: np.ndarray, radius_px: float, look: BubbleLook
) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
    """Coverage and grey level of a bubble over the pixels it touches.

    Parameters
    ----------
    centre_px : ndarray, shape (2,)
        Centre (px).
    radius_px : float
        Radius (px).
    look : BubbleLook

    Returns
    -------
    bbox : (x0, y0, x1, y1)
        Pixel box (unclipped) of the patch.
    alpha, level : ndarray
        Anti-aliased coverage (0–1) and grey level of each pixel of the box.
    """
    cx, cy = (float(v) for v in centre_px)
    x0, y0 = int(np.floor(cx - radius_px)) - 2, int(np.floor(cy - radius_px)) - 2
    x1, y1 = int(np.ceil(cx + radius_px)) + 3, int(np.ceil(cy + radius_px)) + 3
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    d = np.hypot(xs - cx, ys - cy)
    alpha = np.clip(radius_px - d + 0.5, 0.0, 1.0)
    rim = max(look.rim_frac, 1.2 / max(radius_px, 1e-6))
    # the rim darkens over its inner half and stays dark out to the edge
    ramp = smoothstep((d / radius_px - (1.0 - rim)) / (0.5 * rim))
    level = look.core + (look.rim - look.core) * ramp
    hx = cx + 0.45 * radius_px * np.cos(look.light_rad)
    hy = cy + 0.45 * radius_px * np.sin(look.light_rad)
    sigma = max(0.12 * radius_px, 0.7)
    level = level + look.highlight * np.exp(-((xs - hx) ** 2 + (ys - hy) ** 2) / (2 * sigma**2)) * (1 - ramp)
    return (x0, y0, x1, y1), alpha.astype(np.float32), level.astype(np.float32)


def paste(img: np.ndarray, bbox: tuple[int, int, int, int], alpha: np.ndarray, level: np.ndarray) -> None:
    """Blend ``level`` over ``img`` in place with coverage ``alpha`` on an unclipped pixel box."""
    x0, y0, x1, y1 = bbox
    h, w = img.shape[:2]
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx1 <= cx0 or cy1 <= cy0:
        return
    a = alpha[cy0 - y0 : cy1 - y0, cx0 - x0 : cx1 - x0]
    v = level[cy0 - y0 : cy1 - y0, cx0 - x0 : cx1 - x0]
    img[cy0:cy1, cx0:cx1] = img[cy0:cy1, cx0:cx1] * (1 - a) + v * a


@dataclass(frozen=True)
class FreeBubble:
    """An air bubble drifting along the channel, bouncing at its ends.

    Parameters
    ----------
    u0_mm : float
        Arc length (mm) along the channel's middle line at time 0, before bouncing.
    lateral : float
        Normal offset as a fraction (-1..1) of the free room across the channel.
    radius_mm : float
        Wanted radius (mm); cut to fit the channel where it is.
    speed_mm_s : float
        Drift speed (mm/s) along the channel, signed (positive = apical).
    look : BubbleLook
        How it looks.
    """

    u0_mm: float
    lateral: float
    radius_mm: float
    speed_mm_s: float
    look: BubbleLook


    def at(self, time_s: float, path: ChannelPath, wall_mm: float) -> tuple[np.ndarray, float]:
        """Centre (mm) and radius (mm) at ``time_s`` (s): drifting, bouncing at the channel's ends."""
        lo, hi = self.radius_mm, max(path.u_mm[-1] - self.radius_mm, self.radius_mm + 1e-3)
        span = hi - lo
        x = (self.u0_mm + self.speed_mm_s * time_s - lo) % (2 * span)
        u = np.array([lo + (x if x < span else 2 * span - x)])
        radius, _ = _bubble_fit(path, u, self.radius_mm, np.zeros(1), wall_mm)
        room = np.maximum(path.half_width(u) - wall_mm - radius, 0.0)
        return path.at(u, self.lateral * room)[0], float(radius[0])

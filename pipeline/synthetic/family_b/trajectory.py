"""The array tip's path through the phantom (family B): out of the entry, guided by the walls."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from tympani.pipeline.synthetic.family_b.constants import ARRAY_D_BASE_MM, ARRAY_D_TIP_MM, ARRAY_LENGTH_MM
from tympani.pipeline.synthetic.family_b.phantom import (
    R_TIP_MM,
    Curve,
    PhantomGeometry,
    offset_into_channel,
    point_theta,
    resampled_curve,
)

__all__ = ["TipPath", "tip_path", "wall_clearance"]


@dataclass(frozen=True)
class TipPath:
    """Path of the array tip (centre of its end) as a function of insertion depth.

    Attributes
    ----------
    depth : numpy.ndarray
        Depth grid [mm] (length of array past the entry's end).
    theta : numpy.ndarray
        Angle of the tip [rad] at each depth.
    d_hit : float
        Depth [mm] at which the tip first touches the outer wall.
    theta_hit : float
        Tip angle [rad] at first contact.
    xy : numpy.ndarray
        Tip centre [mm] at each depth, shape (n, 2).
    inner_touch : list of (float, float)
        ``(depth_on, depth_off)`` [mm] of each stretch where the tip slides along the inner
        wall before it reaches the outer wall (empty if it never touches it).
    """

    depth: np.ndarray
    theta: np.ndarray
    d_hit: float
    theta_hit: float
    xy: np.ndarray
    inner_touch: tuple[tuple[float, float], ...] = ()


def _free_arc(q: np.ndarray, psi: float, kappa0: float, d: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``d`` along a circular arc (curvature ``kappa0``) from ``q``."""
    if abs(kappa0) < 1e-9:
        return q + d[:, None] * np.array([math.cos(psi), math.sin(psi)])
    ang = psi + kappa0 * d
    return q + np.stack([np.sin(ang) - math.sin(psi), -np.cos(ang) + math.cos(psi)],
                        axis=1) / kappa0


def _project(curve: Curve, x: np.ndarray) -> float:
    """Arc length [mm] of the point of ``curve`` nearest to ``x``."""
    _, j = curve.tree.query(x)
    return float(curve.S[j] + (x - curve.xy[j]) @ curve.t[j])


@functools.lru_cache(maxsize=8)
def _riders(geom: PhantomGeometry, r_tip: float) -> tuple[Curve, Curve]:
    """Outer and inner rider curves for tip radius ``r_tip`` [mm] (cached)."""
    if r_tip == R_TIP_MM:
        return geom.rider_out, geom.rider_in
    ds = float(geom.S[1] - geom.S[0])
    return (resampled_curve(offset_into_channel(geom.outer, r_tip), ds, "right", geom.phantom),
            resampled_curve(offset_into_channel(geom.inner, r_tip), ds, "left", geom.phantom))


def tip_path(geom: PhantomGeometry, e_lat: float, tilt: float, kappa0: float = 0.0,
             r_tip: float = R_TIP_MM, d_min: float = -2.0, d_max: float = 26.0,
             dd: float = 0.01) -> TipPath:
    """Tip path: out of the entry, guided by the walls, then riding the outer wall.

    In the entry (depth <= 0) the tip centre lies on the entry axis offset laterally by
    ``e_lat`` (``p0 + e_lat n0 + depth x_w``).  It leaves the entry's end heading along
    ``x_w`` rotated by ``tilt`` and moves freely on a circular arc of curvature ``kappa0``
    (the array's residual curvature; 0 = straight).  The walls guide it:

    * **inner wall.**  Just past the entry the backbone first turns right (up to about
      25 deg), then left, so a straight array drifts towards the inner wall near
      0.5-1 rad.  If the tip reaches it (its centre reaches the inner *rider* curve,
      the inner wall offset by the tip radius) it slides along it, taking the wall's
      direction, for as long as the wall turns right more sharply than the free array
      would (wall curvature < ``kappa0``), and then leaves it on the wall's tangent.
    * **outer wall.**  When the tip's centre reaches the outer rider curve (the outer
      wall offset inwards by the tip radius), that is first contact (``d_hit``,
      ``theta_hit``); from there it rides the outer wall.

    Depth is arc length along this path.  Crossings are found with signed distances to
    the rider curves, so the tip never crosses either wall.

    Parameters
    ----------
    geom : PhantomGeometry
        Phantom geometry.
    e_lat : float
        Lateral offset of the array's axis in the entry channel [mm], positive towards the
        outer wall.  The tip fits for ``|e_lat| <= w_max/2 - R_TIP_MM``.
    tilt : float
        Angle of the free array's heading relative to ``x_w`` as it leaves the entry [rad],
        positive counter-clockwise.
    kappa0 : float
        Residual curvature of the free array [1/mm], negative = bending clockwise
        (towards the outer wall).
    r_tip : float
        Tip radius [mm] (default: half the default tip diameter).
    d_min, d_max, dd : float
        Depth grid [mm].

    Returns
    -------
    TipPath

    Raises
    ------
    ValueError
        If the tip does not fit in the entry, never reaches the outer wall, or its angle
        leaves the first turn before contact.
    """
    half_entry = 0.5 * geom.phantom.w_max_mm
    if abs(e_lat) > half_entry - r_tip + 1e-12:
        raise ValueError(f"tip does not fit in the entry channel (e_lat={e_lat})")
    depth = np.arange(d_min, d_max + dd / 2, dd)
    xy = np.empty((depth.size, 2))
    q0 = geom.p0 + e_lat * geom.n0
    ent = depth <= 0.0
    xy[ent] = q0 + depth[ent, None] * geom.x_w
    q, psi, d_cur = q0, math.atan2(geom.x_w[1], geom.x_w[0]) + tilt, 0.0
    r_out, r_in = _riders(geom, float(r_tip))
    inner_touch: list[tuple[float, float]] = []
    d_hit = math.nan
    for _ in range(64):
        sel = depth > d_cur
        dloc = depth[sel] - d_cur
        xf = _free_arc(q, psi, kappa0, dloc)
        xy[sel] = xf
        # signed distances to both rider curves, 2 mm at a time until one is crossed
        sd_o = np.full(dloc.size, -np.inf)
        sd_i = np.full(dloc.size, -np.inf)
        jo = ji = dloc.size
        for c0 in range(0, dloc.size, 200):
            c1 = min(c0 + 200, dloc.size)
            sd_o[c0:c1] = r_out.signed_distance(xf[c0:c1])[0]
            sd_i[c0:c1] = r_in.signed_distance(xf[c0:c1])[0]
            io = np.flatnonzero(sd_o[c0:c1] > 1e-6)
            ii = np.flatnonzero(sd_i[c0:c1] > 1e-6)
            jo = c0 + int(io[0]) if io.size else dloc.size
            ji = c0 + int(ii[0]) if ii.size else dloc.size
            if min(jo, ji) < dloc.size:
                break
        if min(jo, ji) >= dloc.size:
            raise ValueError(f"tip path never reaches the outer wall (e_lat={e_lat}, "
                             f"tilt={tilt}, kappa0={kappa0})")
        use_out = jo <= ji
        j = jo if use_out else ji
        sd = sd_o if use_out else sd_i
        if j == 0:
            d_x = 0.0
        else:
            a = sd[j - 1] / (sd[j - 1] - sd[j])
            d_x = float(dloc[j - 1] + a * (dloc[j] - dloc[j - 1]))
        x_hit = _free_arc(q, psi, kappa0, np.array([d_x]))[0]
        d_glob = d_cur + d_x
        if use_out:
            s_hit = _project(r_out, x_hit)
            post = depth > d_glob
            xy[post] = r_out.at(s_hit + depth[post] - d_glob)
            d_hit = d_glob
            break
        s_hit = _project(r_in, x_hit)
        k0 = int(np.searchsorted(r_in.S, s_hit))
        leave = np.flatnonzero(r_in.kappa[k0:] > kappa0)
        k = k0 + (int(leave[0]) if leave.size else r_in.S.size - 1 - k0)
        s_dep = max(float(r_in.S[k]), s_hit)
        d_dep = d_glob + (s_dep - s_hit)
        ride = (depth > d_glob) & (depth <= d_dep)
        xy[ride] = r_in.at(s_hit + depth[ride] - d_glob)
        inner_touch.append((d_glob, d_dep))
        q = r_in.at(np.array([s_dep]))[0]
        tk = r_in.t[min(k, r_in.S.size - 1)]
        psi = math.atan2(tk[1], tk[0])
        d_cur = d_dep + 1e-9
    else:  # pragma: no cover - the walls guide the tip to the outer wall in 1-2 steps
        raise ValueError("tip path did not settle on the outer wall")
    th = point_theta(xy[:, 0], xy[:, 1], geom.phantom)
    th = np.maximum.accumulate(th)
    th_hit = float(np.interp(d_hit, depth, th))
    if th_hit > math.pi or np.diff(th).max() > 0.1:
        raise ValueError(f"tip path leaves the first turn (e_lat={e_lat}, tilt={tilt})")
    return TipPath(depth=depth, theta=th, d_hit=d_hit, theta_hit=th_hit, xy=xy,
                   inner_touch=tuple(inner_touch))


def wall_clearance(geom: PhantomGeometry, path: TipPath, d_end: float,
                   final_depth: float | None = None,
                   r_tip: float = R_TIP_MM) -> dict[str, float]:
    """Smallest clearance [mm] between the array and each wall along a tip path.

    * ``tip_outer``, ``tip_inner``: gap between the tip (radius ``r_tip``, centre on
      the path) and the outer / inner wall, over depths 0 ... ``d_end``.  Zero means
      touching; negative would mean the tip crosses the wall.
    * ``body_entry``: gap between the array's body and the entry's walls at the deepest
      insertion ``final_depth`` (default ``d_end``): the array's axis lies ``e_lat`` off the
      entry's centre line and its radius grows from the tip to
      ``ARRAY_D_BASE_MM / 2``, so the thickest part inside the entry sits at its start,
      ``final_depth + entry_mm`` from the tip.
    """
    final_depth = d_end if final_depth is None else final_depth
    sel = (path.depth >= 0.0) & (path.depth <= d_end)
    pts = path.xy[sel]
    # signed distance to the wall itself: negative inside the channel
    sd_o, _ = geom.outer.signed_distance(pts)
    sd_i, _ = geom.inner.signed_distance(pts)
    x_back = min(final_depth + geom.phantom.entry_mm, ARRAY_LENGTH_MM)
    a_back = 0.5 * (ARRAY_D_TIP_MM + (ARRAY_D_BASE_MM - ARRAY_D_TIP_MM) * x_back
                    / ARRAY_LENGTH_MM)
    e_lat = float((path.xy[path.depth <= 0.0][-1] - geom.p0) @ geom.n0)
    return {
        "tip_outer": float(-sd_o.max() - r_tip),
        "tip_inner": float(-sd_i.max() - r_tip),
        "body_entry": float(0.5 * geom.phantom.w_max_mm - abs(e_lat) - a_back),
    }

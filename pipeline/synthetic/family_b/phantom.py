"""The planar scala-tympani phantom of family B: backbone, walls and rider curves."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from tympani.pipeline.synthetic.family_b.constants import ARRAY_D_TIP_MM

__all__ = [
    "Phantom",
    "point_theta",
    "R_TIP_MM",
    "THETA_LOOKUP_MAX",
    "Curve",
    "resampled_curve",
    "PhantomGeometry",
    "offset_into_channel",
    "geometry",
]


@dataclass(frozen=True)
class Phantom:
    """Constants of the planar phantom (the default phantom).

    Attributes
    ----------
    a, b, c, d, phi0_deg
        Cohen et al. (1996) backbone constants: ``a`` [mm], ``b`` [1/deg], ``c`` [mm],
        ``d`` [-], ``phi0_deg`` [deg].
    theta_start_deg, theta_end_deg
        Channel start and end angles [deg].
    corner_deg
        Angle where the two branches of Eq. (1) meet [deg].
    w_max_mm, w_ratio
        Channel-width law ``w = min(w_max_mm, w_ratio * r)`` [mm, -].  ``w`` is the *full*
        width of the channel; each wall lies ``w / 2`` from the backbone (half the
        channel width each side, as in :mod:`tympani.vision.geometry`).
    entry_mm
        Length of the straight entry channel [mm].
    """

    a: float = 3.762
    b: float = 0.001317
    c: float = 7.967
    d: float = 0.1287
    phi0_deg: float = 5.0
    theta_start_deg: float = 10.3
    theta_end_deg: float = 720.0
    corner_deg: float = 100.0
    w_max_mm: float = 1.5
    w_ratio: float = 0.38
    entry_mm: float = 5.0

    def r(self, theta: np.ndarray | float) -> np.ndarray:
        """Backbone radius r(theta) [mm] of Eq. (1); theta in rad (unwrapped)."""
        phi = np.degrees(np.asarray(theta, dtype=float))
        r1 = self.c * (1.0 - self.d * np.log(np.maximum(phi - self.phi0_deg, 1e-9)))
        r2 = self.a * np.exp(-self.b * phi)
        return np.where(phi < self.corner_deg, r1, r2)

    def drdtheta(self, theta: np.ndarray | float) -> np.ndarray:
        """Derivative dr/dtheta [mm/rad] of the backbone radius."""
        phi = np.degrees(np.asarray(theta, dtype=float))
        k = 180.0 / math.pi
        d1 = -self.c * self.d / np.maximum(phi - self.phi0_deg, 1e-9) * k
        d2 = -self.b * k * self.a * np.exp(-self.b * phi)
        return np.where(phi < self.corner_deg, d1, d2)

    def width(self, theta: np.ndarray | float) -> np.ndarray:
        """Full channel width ``w(theta) = min(w_max, w_ratio r(theta))`` [mm]."""
        return np.minimum(self.w_max_mm, self.w_ratio * self.r(theta))

    def half_width(self, theta: np.ndarray | float) -> np.ndarray:
        """Channel half-width ``w(theta) / 2`` [mm]: distance from the backbone to each wall."""
        return 0.5 * self.width(theta)

    @property
    def theta_start(self) -> float:
        """Channel start angle [rad]."""
        return math.radians(self.theta_start_deg)

    @property
    def theta_end(self) -> float:
        """Channel end angle [rad]."""
        return math.radians(self.theta_end_deg)


def point_theta(x: np.ndarray, y: np.ndarray, ph: Phantom | None = None) -> np.ndarray:
    """Unwrapped angle of phantom-frame points (tympani's angle of a point, docs/file-formats.md).

    ``theta = phi + 2 pi k`` with ``phi`` in (-pi, pi] the polar angle and ``k >= 0`` the
    integer for which the backbone radius ``r(phi + 2 pi k)`` is closest to the point's
    radius.  Angles below ``theta_start`` (k = 0 near the entry) use ``r(theta_start)``.

    Parameters
    ----------
    x, y : array_like
        Point coordinates [mm] in the phantom frame.
    ph : Phantom, optional
        Phantom constants (default ``Phantom()``).

    Returns
    -------
    numpy.ndarray
        Unwrapped angle [rad], same shape as ``x``.
    """
    ph = ph or Phantom()
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    rho = np.hypot(x, y)
    phi = np.arctan2(y, x)
    best = np.full(rho.shape, np.inf)
    out = phi.copy()
    for k in range(3):
        th = phi + 2.0 * math.pi * k
        ok = th <= ph.theta_end + 0.5
        rk = ph.r(np.clip(th, ph.theta_start, ph.theta_end))
        dist = np.where(ok, np.abs(rk - rho), np.inf)
        better = dist < best
        out = np.where(better, th, out)
        best = np.where(better, dist, best)
    return out


#: Radius of the array's tip [mm] (half the tip diameter).
R_TIP_MM: float = 0.5 * ARRAY_D_TIP_MM
#: Rider curves and wall look-ups only use wall points up to this angle [rad]: every
#: tip position the generator needs lies in the first turn (theta < 2 pi), so a
#: nearest-point query can never pick a point on another turn of the spiral.
THETA_LOOKUP_MAX: float = 5.5


@dataclass(frozen=True, eq=False)
class Curve:
    """A dense, uniformly resampled polyline with its frame (a wall or a rider curve).

    Attributes
    ----------
    S : numpy.ndarray
        Arc length from the curve's start (theta_start end) [mm], uniform steps.
    xy : numpy.ndarray
        Points [mm], shape (n, 2).
    t : numpy.ndarray
        Unit tangent, pointing towards the apex, shape (n, 2).
    n_wall : numpy.ndarray
        Unit normal pointing out of the channel, into the wall this curve belongs to.
    kappa : numpy.ndarray
        Signed curvature [1/mm] (positive: turning counter-clockwise), smoothed over 0.1 mm.
    theta : numpy.ndarray
        Angle of each point [rad] (tympani's unwrapped angle), strictly increasing.
    tree : scipy.spatial.cKDTree
        Nearest-point index over the points with ``theta <= THETA_LOOKUP_MAX``.
    """

    S: np.ndarray
    xy: np.ndarray
    t: np.ndarray
    n_wall: np.ndarray
    kappa: np.ndarray
    theta: np.ndarray
    tree: Any

    def at(self, s: np.ndarray) -> np.ndarray:
        """Points at arc lengths ``s`` [mm] (linear interpolation, clipped to the ends)."""
        return np.stack([np.interp(s, self.S, self.xy[:, 0]),
                         np.interp(s, self.S, self.xy[:, 1])], axis=1)

    def signed_distance(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``pts`` from the curve [mm] (> 0: beyond it, into the wall).

        Returns the distance and the index of the nearest curve point.  Valid for points
        of the first turn near the curve (see ``THETA_LOOKUP_MAX``).
        """
        _, j = self.tree.query(pts)
        n = self.xy.shape[0]
        best = np.full(pts.shape[0], np.inf)
        sd = np.zeros(pts.shape[0])
        for a in (np.maximum(j - 1, 0), np.minimum(j, n - 2)):  # the two segments at j
            p0, p1 = self.xy[a], self.xy[a + 1]
            seg = p1 - p0
            L2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-30)
            u = np.clip(np.einsum("ij,ij->i", pts - p0, seg) / L2, 0.0, 1.0)
            foot = p0 + u[:, None] * seg
            d = np.hypot(*(pts - foot).T)
            side = np.einsum("ij,ij->i", pts - foot, self.n_wall[a] + self.n_wall[a + 1])
            s = np.where(side > 0, d, -d)
            better = d < best
            sd = np.where(better, s, sd)
            best = np.where(better, d, best)
        return sd, j


def resampled_curve(poly: np.ndarray, ds: float, wall_side: str, ph: Phantom) -> Curve:
    """Resample ``poly`` to arc-length steps ``ds`` and compute its frame.

    ``wall_side`` is ``"right"`` when the wall lies on the right of the apex-ward tangent
    (outer wall) and ``"left"`` for the inner wall.
    """
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    poly = poly[np.concatenate([[True], seg > 1e-12])]
    s_raw = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    S = np.arange(0.0, s_raw[-1], ds)
    xy = np.stack([np.interp(S, s_raw, poly[:, 0]), np.interp(S, s_raw, poly[:, 1])], axis=1)
    tan = np.gradient(xy, ds, axis=0)
    tan /= np.linalg.norm(tan, axis=1)[:, None]
    right = np.stack([tan[:, 1], -tan[:, 0]], axis=1)
    n_wall = right if wall_side == "right" else -right
    psi = np.unwrap(np.arctan2(tan[:, 1], tan[:, 0]))
    kappa = np.gradient(psi, ds)
    win = max(1, int(round(0.1 / ds)))
    kappa = np.convolve(kappa, np.ones(win) / win, mode="same")
    # Polar angle unwrapped along the curve from its start (k = 0 there).  This is
    # tympani's angle for points of the channel; it is used instead of the closest-radius rule
    # because the inner wall lies almost exactly half-way between two turns (w = 0.38 r),
    # where that rule is ambiguous.
    theta = np.unwrap(np.arctan2(xy[:, 1], xy[:, 0]))
    theta = np.maximum.accumulate(theta)
    theta = theta + np.arange(theta.size) * 1e-12  # strictly increasing for interpolation

    sel = theta <= THETA_LOOKUP_MAX
    tree = cKDTree(xy[sel])  # indices of the selected points are 0..k-1 = their own indices
    return Curve(S=S, xy=xy, t=tan, n_wall=n_wall, kappa=kappa, theta=theta, tree=tree)


@dataclass(frozen=True, eq=False)
class PhantomGeometry:
    """Walls of the phantom as dense polylines, plus the insertion frame.

    The outer-wall arrays (``S`` ... ``width``) are kept as plain attributes because the
    force model works on the outer wall; the inner wall and the two *rider* curves (the
    walls offset into the channel by the tip radius, i.e. where the tip's centre is when
    the tip touches that wall) are :class:`Curve` objects.

    Attributes
    ----------
    S : numpy.ndarray
        Arc length along the outer wall from its start at theta_start [mm], uniform steps.
    xy : numpy.ndarray
        Outer-wall points [mm], shape (n, 2).
    t : numpy.ndarray
        Unit tangent, pointing towards the apex, shape (n, 2).
    n_out : numpy.ndarray
        Unit outward normal (away from the spiral centre), shape (n, 2).
    theta : numpy.ndarray
        Angle of each wall point [rad] (tympani's unwrapped angle), non-decreasing.
    ndotx : numpy.ndarray
        ``n_out . x_w`` [-].
    kappa : numpy.ndarray
        Signed wall curvature [1/mm] (positive: turning counter-clockwise, towards the
        centre), lightly smoothed.
    width : numpy.ndarray
        Full channel width w(theta) at each outer-wall point [mm] (each wall is w/2 from
        the backbone).
    x_w : numpy.ndarray
        Insertion axis (unit vector).
    p0 : numpy.ndarray
        Backbone point at theta_start = end of the entry channel [mm].
    n0 : numpy.ndarray
        Outward backbone normal at theta_start.
    phantom : Phantom
        The constants used.
    outer, inner : Curve
        Outer and inner wall.
    rider_out, rider_in : Curve
        Outer and inner wall offset into the channel by ``R_TIP_MM``.
    """

    S: np.ndarray
    xy: np.ndarray
    t: np.ndarray
    n_out: np.ndarray
    theta: np.ndarray
    ndotx: np.ndarray
    kappa: np.ndarray
    width: np.ndarray
    x_w: np.ndarray
    p0: np.ndarray
    n0: np.ndarray
    phantom: Phantom
    outer: Curve
    inner: Curve
    rider_out: Curve
    rider_in: Curve

    def s_of_theta(self, theta: np.ndarray) -> np.ndarray:
        """Wall arc length [mm] at angle ``theta`` [rad] (linear interpolation)."""
        return np.interp(theta, self.theta, self.S)


def _backbone(ph: Phantom, th: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backbone points, unit tangents and outward unit normals at angles ``th`` [rad]."""
    r = ph.r(th)
    dr = ph.drdtheta(th)
    er = np.stack([np.cos(th), np.sin(th)], axis=1)
    et = np.stack([-np.sin(th), np.cos(th)], axis=1)
    p = r[:, None] * er
    tan = dr[:, None] * er + r[:, None] * et
    tan /= np.linalg.norm(tan, axis=1)[:, None]
    nrm = np.stack([tan[:, 1], -tan[:, 0]], axis=1)  # right-hand normal = outward (CCW spiral)
    return p, tan, nrm


def _seg_intersect(A: np.ndarray, B: np.ndarray) -> tuple[int, int, np.ndarray] | None:
    """First crossing of polyline ``A``'s segments with polyline ``B``'s segments."""
    a0, a1 = A[:-1], A[1:]
    b0, b1 = B[:-1], B[1:]
    da = a1 - a0
    db = b1 - b0
    rel = b0[None, :, :] - a0[:, None, :]
    den = da[:, None, 0] * db[None, :, 1] - da[:, None, 1] * db[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (rel[..., 0] * db[None, :, 1] - rel[..., 1] * db[None, :, 0]) / den
        tb = (rel[..., 0] * da[:, None, 1] - rel[..., 1] * da[:, None, 0]) / den
    hit = (ta >= 0) & (ta <= 1) & (tb >= 0) & (tb <= 1) & np.isfinite(ta)
    if not hit.any():
        return None
    i, j = np.argwhere(hit)[0]
    return int(i), int(j), a0[i] + ta[i, j] * da[i]


def _wall_polylines(ph: Phantom) -> tuple[np.ndarray, np.ndarray]:
    """Raw outer and inner wall polylines, before resampling.

    Each wall is the backbone offset by half the channel width, ``w(theta) / 2``, along
    the backbone's unit normal (outer: away from o_c; inner: towards it).  At the 100 deg
    corner the backbone turns 6.3 deg to the right: the outer wall is on the inside of
    that corner and its two pieces are cut where they cross; the inner wall is on the
    outside and is closed with a circular arc about the backbone's corner point.
    """
    th1 = np.linspace(ph.theta_start, math.radians(ph.corner_deg), 3000)
    th2 = np.linspace(math.radians(ph.corner_deg), ph.theta_end, 12000)
    outer, inner, frames = [], [], []
    for th in (th1, th2):
        p, _, nrm = _backbone(ph, th)
        h = ph.half_width(th)[:, None]
        outer.append(p + h * nrm)
        inner.append(p - h * nrm)
        frames.append((p, nrm, h))
    A, B = outer
    m = 300
    hit = _seg_intersect(A[-m:], B[:m])
    if hit is None:  # pragma: no cover - geometry always crosses for the default constants
        wall_out = np.vstack([A, B[1:]])
    else:
        i, j, X = hit
        wall_out = np.vstack([A[: len(A) - m + i + 1], X[None, :], B[j + 1:]])
    pc = frames[0][0][-1]
    hc = float(frames[0][2][-1, 0])
    a1 = math.atan2(-frames[0][1][-1, 1], -frames[0][1][-1, 0])
    a2 = math.atan2(-frames[1][1][0, 1], -frames[1][1][0, 0])
    a2 = a1 + (a2 - a1 + math.pi) % (2 * math.pi) - math.pi
    ang = np.linspace(a1, a2, 60)[1:-1]
    arc = pc + hc * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    wall_in = np.vstack([inner[0], arc, inner[1]])
    return wall_out, wall_in


def offset_into_channel(wall: Curve, dist: float) -> np.ndarray:
    """Points at distance ``dist`` from ``wall`` on the channel side (raw polyline).

    Each wall point is moved ``dist`` along its inward normal; where the normal turns
    by more than 0.2 deg between neighbouring points (the cut 100 deg corner of the outer
    wall, which juts into the channel) the gap is filled with an arc of radius ``dist``
    about the wall point, so the offset curve keeps its distance from the corner too.
    """
    n_in = -wall.n_wall
    ang = np.arctan2(n_in[:, 1], n_in[:, 0])
    turn = (np.diff(ang) + math.pi) % (2 * math.pi) - math.pi
    pts = wall.xy + dist * n_in
    corners = np.flatnonzero(np.abs(turn) > math.radians(0.2))
    pieces, last = [], 0
    for i in corners:
        pieces.append(pts[last:i + 1])
        a = ang[i] + turn[i] * np.linspace(0.0, 1.0, 40)[1:-1]
        pieces.append(wall.xy[i] + dist * np.stack([np.cos(a), np.sin(a)], axis=1))
        last = i + 1
    pieces.append(pts[last:])
    return np.vstack(pieces)


@functools.lru_cache(maxsize=4)
def geometry(ph: Phantom = Phantom(), ds: float = 0.005) -> PhantomGeometry:
    """Build the walls of the phantom and the tip's rider curves (cached).

    The walls are the backbone offset by ``w(theta) / 2`` along its unit normal, on each
    side (``w`` is the full channel width).  The polylines are resampled
    to uniform arc-length steps ``ds`` [mm].

    Parameters
    ----------
    ph : Phantom
        Phantom constants.
    ds : float
        Arc-length step of the resampled walls [mm].

    Returns
    -------
    PhantomGeometry
    """
    wall_out, wall_in = _wall_polylines(ph)
    outer = resampled_curve(wall_out, ds, "right", ph)
    # angle of the outer wall by the closest-radius rule of point_theta (it agrees with the
    # unwrapped polar angle to rounding; kept in that form for the contact arc)
    th_spec = np.maximum.accumulate(point_theta(outer.xy[:, 0], outer.xy[:, 1], ph))
    th_spec = th_spec + np.arange(th_spec.size) * 1e-12
    inner = resampled_curve(wall_in, ds, "left", ph)
    rider_out = resampled_curve(offset_into_channel(outer, R_TIP_MM), ds, "right", ph)
    rider_in = resampled_curve(offset_into_channel(inner, R_TIP_MM), ds, "left", ph)
    p0, t0, n0 = _backbone(ph, np.array([ph.theta_start]))
    x_w = t0[0]
    return PhantomGeometry(
        S=outer.S, xy=outer.xy, t=outer.t, n_out=outer.n_wall, theta=th_spec,
        ndotx=outer.n_wall @ x_w, kappa=outer.kappa, width=ph.width(th_spec),
        x_w=x_w, p0=p0[0], n0=n0[0], phantom=ph,
        outer=outer, inner=inner, rider_out=rider_out, rider_in=rider_in,
    )

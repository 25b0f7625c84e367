"""Family-B synthetic force/angle data for blind validation of tympani's gap diagnosis.

This module is an *independent* generator ("family B"): it was written from a physics brief
and the project's contract on geometry, angles, the force model and the effect names only,
without reading the project's own generator (:mod:`pipeline.synthetic.family_a`, "family A") or its
diagnosis, so the gap diagnosis can be checked on data whose functional forms it was not built
around. The diagnosis' thresholds were set on family A; family B is where they are reported
(``tympani evaluate-diagnosis --family B``).

One call of :func:`generate` produces one synthetic experiment: robotic insertions of a
26 mm tapered electrode array into the planar scala-tympani phantom at several nominal
speeds, several trials per speed, as one long table with one row per force sample.  The
force is the paper's friction model (linear contact pressure on the outer-wall arc from
``theta_bot`` to ``theta_tip``, Stribeck friction transmitted along the insertion axis)
plus, optionally, one hidden *unmodelled effect* (named as the diagnosis names them), passed through a
sensor model (calibration gain, tare offset, white + AR(1) noise, 13-bit quantisation).
The angles are those a video tracker would report: sampled at the video frame rate,
noisy, interpolated onto the force clock.

Units follow the contract: mm, s, rad, mm/s, grams-force (1 g = 9.80665e-3 N), MPa.

Physics of every effect, with equations and parameter ranges, is in the docstrings of the
``_effect_*`` functions and in ``docs/diagnosis.md``.

Example
-------
>>> df, truth = generate("hydrodynamic_lift", seed=3)
>>> truth["snr"] > 3
True
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import pandas as pd
from scipy import signal
from scipy.spatial import cKDTree

__all__ = [
    "EFFECTS",
    "G_N",
    "Phantom",
    "PhantomGeometry",
    "Curve",
    "R_TIP_MM",
    "wall_clearance",
    "geometry",
    "point_theta",
    "tip_path",
    "contact_arc",
    "linear_pressure",
    "arc_force_g",
    "stribeck_mu",
    "generate",
    "peak_drop",
]

#: Names of the hidden effects (the diagnosis' names, docs/diagnosis.md).
EFFECTS: tuple[str, ...] = (
    "hydrodynamic_lift",
    "viscous_drag",
    "capstan",
    "sensor_lag",
    "sensor_drift",
    "pressure_profile",
)

#: Newtons per gram-force.
G_N: float = 9.80665e-3

#: Number of elements the contact arc is split into.
N_ARC: int = 64
#: Number of elements the wetted array is split into (viscous drag).
N_WET: int = 48
#: Array geometry (the default array): length and tip/base diameters, mm.
ARRAY_LENGTH_MM: float = 26.0
ARRAY_D_TIP_MM: float = 0.6
ARRAY_D_BASE_MM: float = 1.2


# --------------------------------------------------------------------------------------
# Geometry (the planar phantom of vision/geometry.py)
# --------------------------------------------------------------------------------------
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
        channel width each side, as in :mod:`vision.geometry`).
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


def _curve(poly: np.ndarray, ds: float, wall_side: str, ph: Phantom) -> Curve:
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


def _offset_into_channel(wall: Curve, dist: float) -> np.ndarray:
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
    outer = _curve(wall_out, ds, "right", ph)
    # angle of the outer wall by the closest-radius rule of point_theta (it agrees with the
    # unwrapped polar angle to rounding; kept in that form for the contact arc)
    th_spec = np.maximum.accumulate(point_theta(outer.xy[:, 0], outer.xy[:, 1], ph))
    th_spec = th_spec + np.arange(th_spec.size) * 1e-12
    inner = _curve(wall_in, ds, "left", ph)
    rider_out = _curve(_offset_into_channel(outer, R_TIP_MM), ds, "right", ph)
    rider_in = _curve(_offset_into_channel(inner, R_TIP_MM), ds, "left", ph)
    p0, t0, n0 = _backbone(ph, np.array([ph.theta_start]))
    x_w = t0[0]
    return PhantomGeometry(
        S=outer.S, xy=outer.xy, t=outer.t, n_out=outer.n_wall, theta=th_spec,
        ndotx=outer.n_wall @ x_w, kappa=outer.kappa, width=ph.width(th_spec),
        x_w=x_w, p0=p0[0], n0=n0[0], phantom=ph,
        outer=outer, inner=inner, rider_out=rider_out, rider_in=rider_in,
    )


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
    return (_curve(_offset_into_channel(geom.outer, r_tip), ds, "right", geom.phantom),
            _curve(_offset_into_channel(geom.inner, r_tip), ds, "left", geom.phantom))


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


# --------------------------------------------------------------------------------------
# Friction, pressures and the contact arc (the paper's friction model)
# --------------------------------------------------------------------------------------
def stribeck_mu(v: np.ndarray | float, mu_k: float, mu_s: float, v_s: float,
                delta_s: float) -> np.ndarray:
    """Stribeck friction coefficient ``mu_k + (mu_s - mu_k) exp(-|v/v_s|^delta_s)``.

    Parameters
    ----------
    v : array_like
        Sliding speed [mm/s].
    mu_k, mu_s : float
        Kinetic and static coefficients [-].
    v_s : float
        Stribeck speed [mm/s].
    delta_s : float
        Stribeck exponent [-].

    Returns
    -------
    numpy.ndarray
        Friction coefficient [-].
    """
    v = np.abs(np.asarray(v, dtype=float))
    return mu_k + (mu_s - mu_k) * np.exp(-((v / v_s) ** delta_s))


@dataclass
class Arc:
    """Contact-arc elements for a batch of samples.

    Every array has shape (m, N_ARC); element j of sample i lies at distance
    ``s[i, j] = u_j l[i]`` from the tip, ``u_j = (j + 1/2) / N_ARC``.

    Attributes
    ----------
    l : numpy.ndarray
        Contact arc length l_con [mm], shape (m,).
    ds : numpy.ndarray
        Element length [mm], shape (m,).
    u : numpy.ndarray
        Normalised position from the tip, shape (N_ARC,).
    s : numpy.ndarray
        Distance from the tip [mm].
    ndotx : numpy.ndarray
        ``n_out . x_w`` of each element [-].
    kappa : numpy.ndarray
        Wall curvature [1/mm].
    width : numpy.ndarray
        Full channel width w(theta) at the element [mm] (the walls are w/2 from the
        backbone).
    """

    l: np.ndarray
    ds: np.ndarray
    u: np.ndarray
    s: np.ndarray
    ndotx: np.ndarray
    kappa: np.ndarray
    width: np.ndarray


def contact_arc(geom: PhantomGeometry, theta_bot: np.ndarray, theta_tip: np.ndarray,
                n: int = N_ARC) -> Arc:
    """Discretise the outer wall between ``theta_bot`` and ``theta_tip`` [rad].

    Samples with ``theta_tip <= theta_bot`` get ``l = 0`` (no contact, zero force).
    """
    theta_bot = np.asarray(theta_bot, dtype=float)
    theta_tip = np.asarray(theta_tip, dtype=float)
    s_tip = geom.s_of_theta(theta_tip)
    s_bot = geom.s_of_theta(np.minimum(theta_bot, theta_tip))
    l = np.maximum(s_tip - s_bot, 0.0)
    u = (np.arange(n) + 0.5) / n
    s = u[None, :] * l[:, None]
    S = s_tip[:, None] - s
    return Arc(
        l=l, ds=l / n, u=u, s=s,
        ndotx=np.interp(S, geom.S, geom.ndotx),
        kappa=np.interp(S, geom.S, geom.kappa),
        width=np.interp(S, geom.S, geom.width),
    )


def linear_pressure(arc: Arc, p_tip: np.ndarray, p_bot: np.ndarray) -> np.ndarray:
    """The paper's Eq. (6): ``p(s) = p_tip + (s / l_con)(p_bot - p_tip)`` [MPa], shape (m, N_ARC)."""
    return p_tip[:, None] + arc.u[None, :] * (p_bot - p_tip)[:, None]


def arc_force_g(arc: Arc, p: np.ndarray, mu: np.ndarray, b_c: float) -> np.ndarray:
    """Sensed axial force [g] of a pressure field on the arc ("axial" projection).

    ``F = b_c [ sum p_i ds (n_out_i . x_w) + mu sum p_i ds ] / G_N``.

    Parameters
    ----------
    arc : Arc
        Contact-arc elements.
    p : numpy.ndarray
        Pressure per element [MPa], shape (m, N_ARC).
    mu : numpy.ndarray
        Friction coefficient per sample [-], shape (m,).
    b_c : float
        Effective contact width [mm].
    """
    w = p * arc.ds[:, None]
    return b_c * ((w * arc.ndotx).sum(axis=1) + mu * w.sum(axis=1)) / G_N


# --------------------------------------------------------------------------------------
# Random draws
# --------------------------------------------------------------------------------------
def _rng(seed: int, *keys: int) -> np.random.Generator:
    """Independent generator for one purpose, derived from the user seed and keys."""
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *keys]))


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (recursively) into plain Python objects."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


#: Largest lateral offset of the array's axis in the entry [mm]: the array is 1.1 mm
#: thick at the back of the entry at the deepest insertion (16.8 mm + 5 mm from its
#: tip), so its axis must stay within 0.75 - 0.552 = 0.198 mm of the entry's centre line.
E_LAT_MAX_MM: float = 0.19


def _draw_dataset(seed: int) -> dict[str, Any]:
    """Data-set-level constants of kinematics, base model, sensor and video."""
    rng = _rng(seed, 1)
    mu_k = _u(rng, 0.10, 0.14)
    ds = {
        "force_rate_hz": float(rng.integers(40, 101)),
        "fps": float(rng.choice([25.0, 29.97, 30.0, 50.0, 60.0])),
        "angle_sd_tip": _u(rng, 0.003, 0.01),
        "angle_sd_bot": _u(rng, 0.01, 0.04),
        "p_missing_frame": _u(rng, 0.0, 0.02),
        "noise_rms_g": _u(rng, 0.03, 0.06),
        "noise_ar_share": _u(rng, 0.3, 0.7),
        "noise_tau_s": _u(rng, 0.1, 0.5),
        "full_scale_g": _u(rng, 25.0, 50.0),
        "adc_bits": 13,
        "gain_spread": 0.03,
        "tare_sd_g": _u(rng, 0.01, 0.05),
        "mu_k": mu_k,
        "mu_s": mu_k + _u(rng, 0.0, 0.06),
        "v_s": _logu(rng, 0.1, 1.0),
        "delta_s": _u(rng, 0.35, 2.0),
        "b_c": _u(rng, 0.03, 0.04),
        "final_depth_mm": _u(rng, 14.5, 16.5),
        "e_lat_mean_mm": _u(rng, -0.1, 0.1),
        "kappa0_mean_per_mm": _u(rng, -0.05, 0.0),
        "alpha_mean": _u(rng, -0.55, 0.1),
        "beta_mean": _u(rng, 0.05, 0.4),
        "lambda_mean": _u(rng, 0.3, 1.0),
        "theta_bot_floor": _u(rng, 0.6, 0.8),
        # raw pressure-law shape; rescaled below to hit a target end force
        "pt0": _u(rng, 0.02, 0.05), "pt3": _u(rng, 0.06, 0.12),
        "pb0": _u(rng, 0.03, 0.07), "pb3": _u(rng, 0.10, 0.22),
        "target_end_force_g": _u(rng, 3.5, 7.0),
    }
    return ds


def _draw_trial(seed: int, iv: int, it: int, speed: float, ds: dict[str, Any]) -> dict[str, Any]:
    """Per-trial kinematics, pressure scale and sensor calibration."""
    rng = _rng(seed, 2, iv, it)
    tr = {
        "speed_actual_mm_s": speed * (1.0 + _u(rng, -0.02, 0.02)),
        "pre_roll_s": _u(rng, 0.3, 2.0),
        "dwell_s": _u(rng, 1.0, 4.0),
        "accel_s": _u(rng, 0.05, 0.15),
        "d0_mm": _u(rng, -0.5, 0.5),
        "final_depth_mm": float(np.clip(ds["final_depth_mm"] + _u(rng, -0.3, 0.3), 12.0, 18.0)),
        "e_lat_mm": float(np.clip(ds["e_lat_mean_mm"] + rng.normal(0.0, 0.04), -E_LAT_MAX_MM,
                                  E_LAT_MAX_MM)),
        "tilt_rad": float(np.clip(rng.normal(0.0, math.radians(0.5)), -math.radians(1.2),
                                  math.radians(1.2))),
        "kappa0_per_mm": float(min(ds["kappa0_mean_per_mm"] + rng.normal(0.0, 0.005), 0.0)),
        "alpha": ds["alpha_mean"] + float(rng.normal(0.0, 0.08)),
        "beta": ds["beta_mean"] * _u(rng, 0.8, 1.2),
        "lambda": ds["lambda_mean"] * _u(rng, 0.8, 1.2),
        "wiggle_amp": _u(rng, 0.01, 0.04),
        "wiggle_k": [_u(rng, 3.0, 8.0), _u(rng, 1.5, 4.0)],
        "wiggle_phase": [_u(rng, 0, 2 * math.pi), _u(rng, 0, 2 * math.pi)],
        "p_tip_scale": _u(rng, 0.9, 1.1),
        "p_bot_scale": _u(rng, 0.9, 1.1),
        "gain": 1.0 + _u(rng, -ds["gain_spread"], ds["gain_spread"]),
        "tare_g": float(rng.normal(0.0, ds["tare_sd_g"])),
        "video_start_s": _u(rng, 0.0, 0.3),
        "video_end_early_s": _u(rng, 0.0, 0.3),
    }
    return tr


# --------------------------------------------------------------------------------------
# Kinematics
# --------------------------------------------------------------------------------------
def _motion(t: np.ndarray, tr: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Depth [mm] and speed [mm/s] of the robot at times ``t`` [s].

    Hold for the pre-roll, raised-cosine acceleration over ``accel_s``, constant speed,
    symmetric deceleration, hold.  The distance covered equals final - initial depth.
    """
    v = tr["speed_actual_mm_s"]
    ta = tr["accel_s"]
    dist = tr["final_depth_mm"] - tr["d0_mm"]
    tm = dist / v + ta  # motion duration
    tau = np.clip(t - tr["pre_roll_s"], 0.0, tm)

    def ramp_dist(x: np.ndarray) -> np.ndarray:  # distance after x s of the raised cosine
        return v * (x / 2.0 - ta / (2.0 * math.pi) * np.sin(math.pi * x / ta))

    d_acc = v * ta / 2.0
    pos = np.where(
        tau < ta, ramp_dist(tau),
        np.where(tau <= tm - ta, d_acc + v * (tau - ta), dist - ramp_dist(tm - tau)),
    )
    tau_raw = t - tr["pre_roll_s"]
    vel = np.where(
        (tau_raw <= 0) | (tau_raw >= tm), 0.0,
        np.where(tau_raw < ta, 0.5 * v * (1 - np.cos(math.pi * tau_raw / ta)),
                 np.where(tau_raw <= tm - ta, v,
                          0.5 * v * (1 - np.cos(math.pi * (tm - tau_raw) / ta)))),
    )
    return tr["d0_mm"] + pos, vel


def _motion_times(tr: dict[str, Any]) -> tuple[float, float, float]:
    """(motion start, motion stop, end of log) [s]."""
    v = tr["speed_actual_mm_s"]
    tm = (tr["final_depth_mm"] - tr["d0_mm"]) / v + tr["accel_s"]
    t0 = tr["pre_roll_s"]
    return t0, t0 + tm, t0 + tm + tr["dwell_s"]


def _angles(depth: np.ndarray, path: TipPath, tr: dict[str, Any],
            floor: float) -> tuple[np.ndarray, np.ndarray]:
    """True tip and contact-start angles [rad] for insertion depths ``depth`` [mm].

    ``theta_tip`` follows the tip path.  After first contact (angle ``theta_hit``), with
    ``q = theta_tip - theta_hit``::

        theta_bot = theta_hit + alpha q - beta (1 - exp(-q / lambda)) + wiggle(q)

    softly floored at ``floor``: alpha < 0 makes the contact spread back towards the base
    (as in the paper's video), alpha > 0 makes its start creep forward.
    """
    th_tip = np.interp(depth, path.depth, path.theta)
    q = np.maximum(th_tip - path.theta_hit, 0.0)
    wig = tr["wiggle_amp"] * (1.0 - np.exp(-q / 0.3)) * (
        0.6 * np.sin(tr["wiggle_k"][0] * q + tr["wiggle_phase"][0])
        + 0.4 * np.sin(tr["wiggle_k"][1] * q + tr["wiggle_phase"][1]))
    raw = path.theta_hit + tr["alpha"] * q - tr["beta"] * (1.0 - np.exp(-q / tr["lambda"])) + wig
    eps = 0.08
    bot = floor + eps * np.logaddexp(0.0, (raw - floor) / eps)
    bot = np.minimum(bot, th_tip)
    contact = depth > path.d_hit
    bot = np.where(contact, bot, th_tip)
    return th_tip, bot


# --------------------------------------------------------------------------------------
# Effects acting on the contact mechanics
# --------------------------------------------------------------------------------------
def _softpos(z: np.ndarray, eps: float = 0.03) -> np.ndarray:
    """Smooth max(z, 0) (softplus with width ``eps``)."""
    return eps * np.logaddexp(0.0, z / eps)


def _film_state(t: np.ndarray, t_on: float, t_off: float, v: float,
                prm: dict[str, float]) -> np.ndarray:
    """Film-thickness ratio ``Lam(t) = h / sigma_r`` of the lubricant film (lift effect).

    Steady film (soft-EHL, isoviscous-elastic regime, ``h ~ (eta u)^0.6-0.67``), written
    relative to the composite surface roughness ``sigma_r``:
    ``Lam_ss = (v / v_c)^n_h`` (``v_c``: speed at which the film just covers the
    roughness).  Build-up while sliding: ``dLam/dt = (Lam_ss - Lam) / tau_b`` with
    ``tau_b = tau_0 + L_e / v`` (the surfaces must travel an entrainment length L_e).
    Squeeze-out after the stop, Reynolds squeeze of a compliant film whose drainage
    resistance grows as it thins: ``dLam/dt = -Lam^2 / (Lam_stop tau_s)``, i.e.
    ``Lam = Lam_stop / (1 + (t - t_off) / tau_s)``.  Before the motion ``Lam = 0``.
    """
    lam_ss = (v / prm["v_c_mm_s"]) ** prm["n_h"]
    tau_b = prm["tau_0_s"] + prm["L_e_mm"] / max(v, 1e-6)
    lam = np.zeros_like(t)
    on = (t > t_on) & (t <= t_off)
    lam[on] = lam_ss * (1.0 - np.exp(-(t[on] - t_on) / tau_b))
    lam_stop = lam_ss * (1.0 - math.exp(-(t_off - t_on) / tau_b))
    off = t > t_off
    lam[off] = lam_stop / (1.0 + (t[off] - t_off) / prm["tau_s_s"])
    return lam


def _lift_separation(lam: np.ndarray, prm: dict[str, float]) -> np.ndarray:
    """Separation gained from the film, normalised to its steady value at ``v_ref``.

    Only the part of the film above the roughness lifts the array (mixed -> full film
    transition): ``sep = eps ln(1 + exp((Lam - 1) / eps))`` (smooth ``(Lam - 1)_+``).
    """
    eps = prm["eps_transition"]

    def sep(x: np.ndarray | float) -> np.ndarray:
        return eps * np.logaddexp(0.0, (np.asarray(x, dtype=float) - 1.0) / eps)

    ref = sep((prm["v_ref_mm_s"] / prm["v_c_mm_s"]) ** prm["n_h"])
    return sep(lam) / ref


def _lift_pressure(p: np.ndarray, H: np.ndarray, K: float, p_ref: float,
                   m_load: float) -> np.ndarray:
    """Contact pressure relieved by a lubricant film (elastic-interference relief).

    The array presses on the wall through an elastic interference ``delta = p / k``
    (Winkler foundation of stiffness k).  A film that separates the surfaces by
    ``h_loc`` moves the array off the wall and relieves the interference::

        p' = k (delta - h_loc)_+ = p (1 - k h_loc / p)_+

    with the soft-EHL load dependence ``h_loc = h (p / p_ref)^(-m_load)``.  In
    dimensionless form, with ``H = h / h_ref`` and ``K = k h_ref / p_ref``,
    ``k h_loc / p = K H (p / p_ref)^(-1 - m_load)``.  Friction acts on ``p'`` too.
    """
    x = K * H[:, None] * (np.maximum(p, 1e-9) / p_ref) ** (-1.0 - m_load)
    return p * _softpos(1.0 - x)


def _profile_pressure(arc: Arc, p_lin: np.ndarray, p_tip: np.ndarray, p_bot: np.ndarray,
                      sigma: float, beta: float) -> np.ndarray:
    """End-loaded contact pressure of an elastic beam on an elastic foundation.

    A beam pressed into the wall at both ends of the contact (the advancing tip and the
    point where the array leaves the wall) carries, on a Winkler foundation, the pressure
    of two Hetenyi end-load solutions::

        g(x) = exp(-x) (cos x + sin x),   x = beta s  (from the tip) or beta (l - s)
        p_end(s) = N [p_tip g(beta s) + p_bot g(beta (l - s))]_+ / int[...]_+ ds

    normalised to the same total load ``N = int p_lin ds`` as the linear profile.  Short
    arcs (beta l << 1) are loaded almost uniformly; long arcs become U-shaped with an
    unloaded middle.  The applied pressure is ``(1 - sigma) p_lin + sigma p_end``.
    """
    s = arc.s
    lcol = arc.l[:, None]
    g_t = np.exp(-beta * s) * (np.cos(beta * s) + np.sin(beta * s))
    g_b = np.exp(-beta * (lcol - s)) * (np.cos(beta * (lcol - s)) + np.sin(beta * (lcol - s)))
    shape = _softpos(p_tip[:, None] * g_t + p_bot[:, None] * g_b, eps=0.002)
    tot_lin = p_lin.mean(axis=1)
    tot_shape = np.maximum(shape.mean(axis=1), 1e-12)
    p_end = shape * (tot_lin / tot_shape)[:, None]
    return (1.0 - sigma) * p_lin + sigma * p_end


def _capstan_force_g(arc: Arc, p: np.ndarray, mu: np.ndarray, b_c: float, chi: float,
                     m_rub: float) -> np.ndarray:
    """Axial load at the contact start from a belt equation with distributed load.

    March from the tip (``T = 0``) to the contact start.  Each element adds its base-model
    axial load ``q (n.x_w + mu) ds`` (``q = p b_c`` line load [N/mm]); the axial
    compression ``T`` already built up presses the array on the curved wall with an extra
    line load ``chi kappa T`` (``chi``: share not carried by the array's bending stiffness),
    whose friction follows the elastomer law ``f ~ P^(1 - m_rub)`` (real contact area grows
    sub-linearly with load), normalised to Coulomb friction at the elastic pre-load::

        dT/ds = q (n.x_w + mu) + mu q^m [(q + chi kappa T_+)^(1-m) - q^(1-m)]

    Returns ``T(l_con)`` [g]; with ``chi = 0`` this equals the base-model force.
    """
    q = p * b_c
    contrib = q * (arc.ndotx + mu[:, None]) * arc.ds[:, None]
    kap = np.maximum(arc.kappa, 0.0)
    T = np.zeros(p.shape[0])
    one_m = 1.0 - m_rub
    for j in range(p.shape[1]):
        qj = np.maximum(q[:, j], 1e-12)
        base_j = qj ** one_m

        def extra(Tm: np.ndarray) -> np.ndarray:
            P = qj + chi * kap[:, j] * np.maximum(Tm, 0.0)
            return mu * qj ** m_rub * (P ** one_m - base_j)

        Tm = T + 0.5 * contrib[:, j]
        for _ in range(2):  # midpoint (predictor-corrector) step
            Tm = T + 0.5 * (contrib[:, j] + extra(Tm) * arc.ds)
        T = T + contrib[:, j] + extra(Tm) * arc.ds
    return T / G_N


def _drag_force_g(depth: np.ndarray, vel: np.ndarray, arc: Arc, q: np.ndarray,
                  path: TipPath, geom: PhantomGeometry, prm: dict[str, float],
                  strength: float) -> np.ndarray:
    """Viscous shear drag on the wetted array [g].

    Two parts, each element's drag transmitted along x_w:

    * **free wetted array** (in the fluid-filled entry and in the spiral behind the
      contact): axial Couette flow round a rod of radius ``a(x)`` (tapered) moving at
      ``v`` inside a channel of equivalent radius ``R``; drag per unit length
      ``2 pi eta v / ln(R / a)`` (concentric annulus).  ``R`` is the local half-width
      ``w(theta) / 2`` in the spiral (``w`` = full channel width) and
      ``r_entry w_max / 2`` in the entry, so the drag per mm depends on the local
      clearance and on the taper.  ``R / a`` is at least 1.09 for the default array and
      phantom (entry, deepest insertion, ``r_entry = 0.8``); the floor of 1.05 below is
      only a guard.
    * **contact band** (the arc pressed on the outer wall): shear of the soft-EHL film
      under the flattened band.  Band width grows as ``(q / q_r)^(1/2)`` (Hertz line
      contact), film thickness ``h = h_r (v / v_r)^n_h (q / q_r)^(-0.21)``, so the shear
      force per element is ``eta v b_c (q/q_r)^0.71 ds / h``, i.e. it grows as
      ``v^(1 - n_h)`` and with the load-weighted contact length.

    The wetted array is the inserted part plus the part in the fluid-filled entry.
    """
    eta = prm["eta_mPa_s"] * 1e-3  # Pa s
    L_entry = geom.phantom.entry_mm
    wet = np.clip(depth + L_entry, 0.0, ARRAY_LENGTH_MM)
    u = (np.arange(N_WET) + 0.5) / N_WET
    x = u[None, :] * wet[:, None]  # distance from the tip along the array [mm]
    dx = wet / N_WET
    a = 0.5 * (ARRAY_D_TIP_MM + (ARRAY_D_BASE_MM - ARRAY_D_TIP_MM) * x / ARRAY_LENGTH_MM)
    pos = depth[:, None] - x  # depth coordinate of the element
    th = np.interp(pos, path.depth, path.theta)
    R = np.where(pos > 0, geom.phantom.half_width(th),
                 prm["r_entry"] * 0.5 * geom.phantom.w_max_mm)
    free = x >= arc.l[:, None]
    per = np.where(free, 2 * math.pi / np.log(np.maximum(R / a, 1.05)), 0.0)
    F_free = eta * (vel * 1e-3) * (per.sum(axis=1) * dx * 1e-3)  # N
    vpos = np.maximum(vel, 0.0)
    h = prm["h_r_um"] * 1e-6 * np.maximum(vpos / prm["v_ref_mm_s"], 1e-9) ** prm["n_h"]
    qq = np.maximum(q, 0.0) / prm["q_r_N_per_mm"]
    band = (qq ** 0.71).sum(axis=1) * arc.ds * 1e-3  # m
    F_band = np.where(vpos > 0, eta * (vpos * 1e-3) * prm["b_c_mm"] * 1e-3 * band / h, 0.0)
    return strength * (F_free + F_band) / G_N


# --------------------------------------------------------------------------------------
# Sensor chain
# --------------------------------------------------------------------------------------
def _lag_filter(x: np.ndarray, fs: float, prm: dict[str, float]) -> np.ndarray:
    """Multi-stage sensor/amplifier filter: moving average -> 2nd-order -> 1st-order.

    * anti-alias moving average over ``T_ma`` (group delay ``T_ma/2``),
    * underdamped second-order stage ``w^2 / (s^2 + 2 zeta w s + w^2)`` (delay
      ``2 zeta / w``, overshoot for a step when ``zeta < 1``),
    * first-order amplifier stage ``1 / (tau_1 s + 1)`` (delay ``tau_1``).

    Initial state: steady at the first sample, so the filter acts on the whole log
    (pre-roll, insertion, dwell).
    """
    y = x
    n_ma = int(round(prm["T_ma_s"] * fs))
    if n_ma >= 2:
        pad = np.concatenate([np.full(n_ma - 1, y[0]), y])
        y = np.convolve(pad, np.ones(n_ma) / n_ma, mode="valid")
    if prm["tau_2_s"] > 1e-6:
        wn = 2 * prm["zeta"] / prm["tau_2_s"]
        num, den = [wn**2], [1.0, 2 * prm["zeta"] * wn, wn**2]
        bz, az = signal.bilinear(num, den, fs=fs)
        y = signal.lfilter(bz, az, y, zi=signal.lfilter_zi(bz, az) * y[0])[0]
    if prm["tau_1_s"] > 1e-6:
        bz, az = signal.bilinear([1.0], [prm["tau_1_s"], 1.0], fs=fs)
        y = signal.lfilter(bz, az, y, zi=signal.lfilter_zi(bz, az) * y[0])[0]
    return y


def _drift(t: np.ndarray, F_g: np.ndarray, prm: dict[str, float], strength: float) -> np.ndarray:
    """Sensor drift [g]: thermal exponential approach plus load creep.

    ``d(t) = strength [ A (1 - exp(-(t + t_w)/tau_th)) + c_cr int_0^t F dt' ]``

    The bridge warms towards a new equilibrium with time constant ``tau_th`` since it was
    tared ``t_w`` seconds before the log started (so the drift is already non-zero at
    t = 0 and before contact); the strain gauges creep in proportion to the load
    accumulated over the trial.
    """
    therm = prm["A_g"] * (1.0 - np.exp(-(t + prm["t_w_s"]) / prm["tau_th_s"]))
    dt = np.diff(t, prepend=t[0])
    creep = prm["c_cr_per_s"] * np.cumsum(np.maximum(F_g, 0.0) * dt)
    return strength * (therm + creep)


def _noise(n: int, fs: float, ds: dict[str, Any], noise_scale: float,
           rng: np.random.Generator) -> np.ndarray:
    """White + AR(1) noise [g] with total RMS ``noise_rms_g * noise_scale``."""
    sd = ds["noise_rms_g"] * noise_scale
    sd_ar = sd * math.sqrt(ds["noise_ar_share"])
    sd_w = sd * math.sqrt(1.0 - ds["noise_ar_share"])
    phi = math.exp(-1.0 / (fs * ds["noise_tau_s"]))
    innov = rng.normal(0.0, sd_ar * math.sqrt(1 - phi**2), n)
    x0 = rng.normal(0.0, sd_ar)
    ar = signal.lfilter([1.0], [1.0, -phi], innov, zi=[phi * x0])[0]
    return ar + rng.normal(0.0, sd_w, n)


# --------------------------------------------------------------------------------------
# Effect constants
# --------------------------------------------------------------------------------------
def _draw_effect(effect: str | None, seed: int, ds: dict[str, Any], ref: dict[str, Any],
                 geom: PhantomGeometry) -> dict[str, Any]:
    """Data-set-level constants of the hidden effect (drawn at strength 1)."""
    if effect is None:
        return {}
    rng = _rng(seed, 4, EFFECTS.index(effect))
    if effect == "hydrodynamic_lift":
        prm = {
            "n_h": _u(rng, 0.58, 0.67),
            "m_load": _u(rng, 0.15, 0.25),
            "v_c_mm_s": _u(rng, 0.15, 0.7),
            "eps_transition": _u(rng, 0.2, 0.4),
            "v_ref_mm_s": 7.5,
            "tau_0_s": _u(rng, 0.1, 0.4),
            "L_e_mm": _u(rng, 0.3, 1.0),
            "tau_s_s": _u(rng, 1.0, 3.0),
            "target_drop_7p5": _u(rng, 0.25, 0.40),
            "sigma_r_um": _u(rng, 0.2, 1.0),
        }
        prm["K"] = _calibrate_lift(prm, ds, ref)
        # Physical reading of K = k h_ref / p_ref: the film at v_ref separates the surfaces
        # by h_ref = sigma_r eps ln(1 + exp((Lam_ref - 1)/eps)); k follows.
        lam_ref = (prm["v_ref_mm_s"] / prm["v_c_mm_s"]) ** prm["n_h"]
        prm["h_sep_ref_um"] = prm["sigma_r_um"] * prm["eps_transition"] * float(
            np.logaddexp(0.0, (lam_ref - 1.0) / prm["eps_transition"]))
        prm["winkler_k_MPa_per_um"] = prm["K"] * ref["p_ref"] / prm["h_sep_ref_um"]
        return prm
    if effect == "viscous_drag":
        prm = {
            "eta_mPa_s": _logu(rng, 300.0, 1400.0),
            "r_entry": _u(rng, 0.8, 1.0),
            "n_h": _u(rng, 0.58, 0.67),
            "v_ref_mm_s": 7.5,
            "b_c_mm": ds["b_c"],
            "q_r_N_per_mm": ref["p_ref"] * ds["b_c"],
            "target_drag_7p5_g": _u(rng, 1.3, 2.0),
        }
        prm["h_r_um"] = _calibrate_drag(prm, ds, ref, geom)
        return prm
    if effect == "capstan":
        return {"chi": _u(rng, 0.85, 1.0), "m_rub": _u(rng, 0.05, 0.15)}
    if effect == "sensor_lag":
        D = _u(rng, 0.2, 0.5)
        f_ma, f_2 = _u(rng, 0.1, 0.3), _u(rng, 0.3, 0.6)
        return {
            "delay_s": D,
            "T_ma_s": 2 * f_ma * D,
            "tau_2_s": f_2 * D,
            "zeta": _u(rng, 0.45, 0.8),
            "tau_1_s": (1 - f_ma - f_2) * D,
        }
    if effect == "sensor_drift":
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return {
            "tau_th_s": _u(rng, 10.0, 35.0),
            "A_g": sign * _u(rng, 0.5, 1.2),
            "t_w_s": _u(rng, 0.5, 3.0),
            "c_cr_per_s": _u(rng, 2e-4, 8e-4) * (1.0 if rng.random() < 0.5 else -1.0),
        }
    if effect == "pressure_profile":
        return {"sigma": _u(rng, 0.65, 0.95), "beta_per_mm": 1.0 / _u(rng, 0.8, 2.0)}
    raise ValueError(f"unknown effect {effect!r}; expected one of {EFFECTS} or None")


def _vary_effect(effect: str | None, prm: dict[str, Any], seed: int, iv: int,
                 it: int) -> dict[str, Any]:
    """Trial-to-trial variation (a few to ~15 %) of the effect's constants."""
    if effect is None:
        return {}
    rng = _rng(seed, 5, EFFECTS.index(effect), iv, it)
    out = dict(prm)

    def j(name: str, rel: float) -> None:
        out[name] = prm[name] * (1.0 + _u(rng, -rel, rel))

    if effect == "hydrodynamic_lift":
        j("K", 0.10), j("tau_0_s", 0.15), j("L_e_mm", 0.15), j("tau_s_s", 0.15), j("v_c_mm_s", 0.1)
    elif effect == "viscous_drag":
        j("eta_mPa_s", 0.08), j("h_r_um", 0.15), j("r_entry", 0.05)
    elif effect == "capstan":
        out["chi"] = min(1.0, prm["chi"] * (1.0 + _u(rng, -0.1, 0.1)))
        j("m_rub", 0.15)
    elif effect == "sensor_lag":
        j("T_ma_s", 0.05), j("tau_2_s", 0.05), j("tau_1_s", 0.05), j("zeta", 0.05)
    elif effect == "sensor_drift":
        j("A_g", 0.15), j("tau_th_s", 0.15), j("t_w_s", 0.2), j("c_cr_per_s", 0.2)
    elif effect == "pressure_profile":
        j("sigma", 0.06), j("beta_per_mm", 0.12)
        out["sigma"] = min(out["sigma"], 1.0)
    return out


def _reference(ds: dict[str, Any], geom: PhantomGeometry) -> dict[str, Any]:
    """Reference end-of-insertion state (15 mm, mean kinematics) and pressure scaling."""
    path = tip_path(geom, ds["e_lat_mean_mm"], 0.0, ds["kappa0_mean_per_mm"])
    tr = {"alpha": ds["alpha_mean"], "beta": ds["beta_mean"], "lambda": ds["lambda_mean"],
          "wiggle_amp": 0.0, "wiggle_k": [1.0, 1.0], "wiggle_phase": [0.0, 0.0]}
    th_tip, th_bot = _angles(np.array([15.0]), path, tr, ds["theta_bot_floor"])
    con = th_tip - th_bot
    arc = contact_arc(geom, th_bot, th_tip)
    pt = ds["pt0"] + (ds["pt3"] - ds["pt0"]) / 3.0 * con
    pb = ds["pb0"] + (ds["pb3"] - ds["pb0"]) / 3.0 * con
    mu = stribeck_mu(np.array([3.0]), ds["mu_k"], ds["mu_s"], ds["v_s"], ds["delta_s"])
    F_raw = float(arc_force_g(arc, linear_pressure(arc, pt, pb), mu, ds["b_c"])[0])
    scale = ds["target_end_force_g"] / F_raw
    return {
        "path": path, "theta_tip": float(th_tip[0]), "theta_bot": float(th_bot[0]),
        "arc": arc, "pressure_scale": scale,
        "p_tip": pt * scale, "p_bot": pb * scale,
        "p_ref": float(linear_pressure(arc, pt * scale, pb * scale).mean()),
    }


def _calibrate_lift(prm: dict[str, Any], ds: dict[str, Any], ref: dict[str, Any]) -> float:
    """K such that the steady end force at 7.5 mm/s is ``target_drop_7p5`` below 0.5 mm/s."""
    arc = ref["arc"]
    p = linear_pressure(arc, ref["p_tip"], ref["p_bot"])

    def force(v: float, K: float) -> float:
        mu = stribeck_mu(np.array([v]), ds["mu_k"], ds["mu_s"], ds["v_s"], ds["delta_s"])
        H = _lift_separation(np.array([(v / prm["v_c_mm_s"]) ** prm["n_h"]]), prm)
        p_eff = _lift_pressure(p, H, K, ref["p_ref"], prm["m_load"])
        return float(arc_force_g(arc, p_eff, mu, ds["b_c"])[0])

    lo, hi = 0.0, 3.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        drop = 1.0 - force(7.5, mid) / force(0.5, mid)
        lo, hi = (mid, hi) if drop < prm["target_drop_7p5"] else (lo, mid)
    return 0.5 * (lo + hi)


def _calibrate_drag(prm: dict[str, Any], ds: dict[str, Any], ref: dict[str, Any],
                    geom: PhantomGeometry) -> float:
    """Reference film thickness h_r [um] giving ``target_drag_7p5_g`` at the end state."""
    depth = np.array([15.0])
    vel = np.array([7.5])
    arc = ref["arc"]
    q = linear_pressure(arc, ref["p_tip"], ref["p_bot"]) * ds["b_c"]

    def drag(h_um: float) -> float:
        return float(_drag_force_g(depth, vel, arc, q, ref["path"], geom,
                                   {**prm, "h_r_um": h_um}, 1.0)[0])

    lo, hi = math.log(1e-3), math.log(100.0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if drag(math.exp(mid)) < prm["target_drag_7p5_g"] else (mid, hi)
    return float(math.exp(0.5 * (lo + hi)))


# --------------------------------------------------------------------------------------
# Main entry point
# --------------------------------------------------------------------------------------
def _settled_tip_path(geom: PhantomGeometry, tr: dict[str, Any], tries: int = 6) -> TipPath:
    """The trial's tip path; a draw whose tip slides back and forth along the inner wall without
    settling on the outer one (about 2 % of draws) is bent slightly more clockwise (0.002 /mm a try,
    recorded in ``tr``) until it settles."""
    for k in range(tries):
        try:
            return tip_path(geom, tr["e_lat_mm"], tr["tilt_rad"], tr["kappa0_per_mm"])
        except ValueError as exc:
            if "did not settle" not in str(exc) or k == tries - 1:
                raise
            tr["kappa0_per_mm"] = float(tr["kappa0_per_mm"] - 0.002)
    raise AssertionError("unreachable")  # pragma: no cover


def _trial_frame(effect: str | None, strength: float, seed: int, iv: int, it: int,
                 speed: float, ds: dict[str, Any], eff: dict[str, Any], ref: dict[str, Any],
                 geom: PhantomGeometry,
                 noise_scale: float) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Generate one trial: columns as arrays, plus its per-trial truth."""
    tr = _draw_trial(seed, iv, it, speed, ds)
    prm = _vary_effect(effect, eff, seed, iv, it)
    fs = ds["force_rate_hz"]
    t_on, t_off, t_end = _motion_times(tr)
    t = np.arange(0.0, t_end, 1.0 / fs)
    depth, vel = _motion(t, tr)
    path = _settled_tip_path(geom, tr)
    th_tip, th_bot = _angles(depth, path, tr, ds["theta_bot_floor"])
    con = th_tip - th_bot
    arc = contact_arc(geom, th_bot, th_tip)

    # base model; friction at the cruise speed, frozen (held) while the robot is still
    v_c = tr["speed_actual_mm_s"]
    mu_c = float(stribeck_mu(v_c, ds["mu_k"], ds["mu_s"], ds["v_s"], ds["delta_s"]))
    mu = np.full(t.size, mu_c)
    sc = ref["pressure_scale"]
    pt_law = (ds["pt0"] + (ds["pt3"] - ds["pt0"]) / 3.0 * con) * sc * tr["p_tip_scale"]
    pb_law = (ds["pb0"] + (ds["pb3"] - ds["pb0"]) / 3.0 * con) * sc * tr["p_bot_scale"]
    p_lin = linear_pressure(arc, pt_law, pb_law)
    F_base = arc_force_g(arc, p_lin, mu, ds["b_c"])

    extra_truth: dict[str, Any] = {}
    F_phys = F_base
    if effect == "hydrodynamic_lift":
        lam = _film_state(t, t_on, t_off, v_c, prm)
        H = strength * _lift_separation(lam, prm)
        p_eff = _lift_pressure(p_lin, H, prm["K"], ref["p_ref"], prm["m_load"])
        F_phys = arc_force_g(arc, p_eff, mu, ds["b_c"])
        extra_truth["film_ratio_at_stop"] = float(lam[np.searchsorted(t, t_off) - 1])
    elif effect == "viscous_drag":
        F_phys = F_base + _drag_force_g(depth, vel, arc, p_lin * ds["b_c"], path, geom, prm,
                                        strength)
    elif effect == "capstan":
        F_phys = _capstan_force_g(arc, p_lin, mu, ds["b_c"], prm["chi"] * strength, prm["m_rub"])
    elif effect == "pressure_profile":
        p_eff = _profile_pressure(arc, p_lin, pt_law, pb_law, min(1.0, prm["sigma"] * strength),
                                  prm["beta_per_mm"])
        F_phys = arc_force_g(arc, p_eff, mu, ds["b_c"])

    # sensor: calibration gain and tare, then drift, then the amplifier filter
    true_base = tr["gain"] * F_base + tr["tare_g"]
    sensed = tr["gain"] * F_phys + tr["tare_g"]
    if effect == "sensor_drift":
        sensed = sensed + _drift(t, tr["gain"] * F_phys, prm, strength)
    if effect == "sensor_lag":
        scaled = {k: (v * strength if k.endswith("_s") else v) for k, v in prm.items()}
        sensed = _lag_filter(sensed, fs, scaled)
    rng_n = _rng(seed, 3, iv, it)
    noisy = sensed + _noise(t.size, fs, ds, noise_scale, rng_n)
    lsb = 2.0 * ds["full_scale_g"] / 2 ** ds["adc_bits"]
    force = np.clip(np.round(noisy / lsb) * lsb, -ds["full_scale_g"], ds["full_scale_g"] - lsb)

    # video: frames at fps, noisy angles, missing frames, interpolated to the force clock
    fps = ds["fps"]
    tv = np.arange(tr["video_start_s"], t_end - tr["video_end_early_s"], 1.0 / fps)
    dv, _ = _motion(tv, tr)
    vt, vb = _angles(dv, path, tr, ds["theta_bot_floor"])
    m_tip = vt + rng_n.normal(0.0, ds["angle_sd_tip"], tv.size)
    contact_v = vt > vb
    bot_noisy = np.minimum(vb + rng_n.normal(0.0, ds["angle_sd_bot"], tv.size), m_tip)
    m_bot = np.where(contact_v, bot_noisy, m_tip)
    miss = rng_n.random(tv.size) < ds["p_missing_frame"]
    m_tip[miss] = np.nan
    m_bot[miss] = np.nan
    i_tip = np.interp(t, tv, m_tip, left=np.nan, right=np.nan)
    i_bot = np.interp(t, tv, m_bot, left=np.nan, right=np.nan)

    cols = {
        "time_s": t, "force_g": force, "theta_tip": i_tip, "theta_bot": i_bot,
        "theta_con": i_tip - i_bot, "depth_mm": depth, "true_force_g": sensed,
        "true_base_g": true_base, "true_theta_tip": th_tip, "true_theta_bot": th_bot,
    }
    trial_truth = {
        **{k: tr[k] for k in ("speed_actual_mm_s", "pre_roll_s", "dwell_s", "accel_s", "d0_mm",
                              "final_depth_mm", "e_lat_mm", "tilt_rad", "kappa0_per_mm", "alpha",
                              "beta", "lambda",
                              "p_tip_scale", "p_bot_scale", "gain", "tare_g", "video_start_s")},
        "t_motion_start_s": t_on, "t_motion_stop_s": t_off, "d_hit_mm": path.d_hit,
        "theta_hit": path.theta_hit, "mu": mu_c,
        "theta_tip_end": float(th_tip[-1]), "theta_bot_end": float(th_bot[-1]),
        "effect_params": {k: v for k, v in prm.items()} if effect else {},
        **extra_truth,
    }
    # Design columns of the base pressure law (for the "unabsorbed gap" figure).
    w = arc.ds[:, None] * (arc.ndotx + mu[:, None]) * ds["b_c"] / G_N * tr["gain"]
    A_t = (w * (1 - arc.u)).sum(axis=1)
    A_b = (w * arc.u).sum(axis=1)
    cols["_design"] = np.stack([A_t, A_t * con, A_b, A_b * con], axis=1)
    return cols, trial_truth


def generate(effect: str | None, seed: int, *, strength: float = 1.0,
             speeds_mm_s: Sequence[float] = (0.5, 1.5, 3.0, 5.0, 7.5), trials: int = 10,
             noise_scale: float = 1.0) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Generate one synthetic insertion experiment with (optionally) one hidden effect.

    Parameters
    ----------
    effect : str or None
        One of :data:`EFFECTS`, or None for the pure base model plus noise.
    seed : int
        Seed; the same seed gives identical output.  Base model, kinematics, sensor noise
        and video draws do not depend on ``effect`` or ``strength``, so data sets with the
        same seed differ only by the effect.
    strength : float, keyword-only
        Size of the effect: 0 = absent, 1 = typical and clearly visible.  It multiplies
        the effect's size (film separation, drag, compression-to-wall coupling, filter time
        constants, drift amplitude, share of the end-loaded profile).
    speeds_mm_s : sequence of float, keyword-only
        Nominal insertion speeds [mm/s].
    trials : int, keyword-only
        Trials per speed.
    noise_scale : float, keyword-only
        Multiplies the force-noise RMS (quantisation is always applied).

    Returns
    -------
    df : pandas.DataFrame
        One row per force sample, all trials stacked.  Columns: ``trial`` (str, e.g.
        ``"v3_t04"``: speed index, trial index), ``speed_mm_s`` (nominal), ``time_s``
        (force clock, 0 at the log's start), ``force_g`` (measured), ``theta_tip``,
        ``theta_bot``, ``theta_con`` [rad] (video: noisy, interpolated; NaN where no
        frame), ``depth_mm`` (robot depth), and the truth columns ``true_force_g`` (sensor
        output without random noise/quantisation, effect included), ``true_base_g``
        (base model with the same trial's parameters, gain and tare), ``true_theta_tip``,
        ``true_theta_bot``.
    truth : dict
        JSON-serialisable: ``effect``, ``strength``, ``family`` ("B"), ``params``
        (data-set draws and the effect's constants), ``base`` (base-model constants and
        per-trial values), ``noise``, ``gap_rms_g``, ``noise_rms_g``, ``snr``,
        ``gap_unabsorbed_rms_g`` (gap RMS after removing its least-squares projection on
        the base model's four pressure-law columns, pooled) and ``snr_unabsorbed``.

    Raises
    ------
    ValueError
        For an unknown effect name, a negative strength or no speeds/trials.
    """
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; expected one of {EFFECTS} or None")
    if strength < 0:
        raise ValueError("strength must be >= 0")
    if trials < 1 or len(speeds_mm_s) < 1:
        raise ValueError("need at least one speed and one trial")
    geom = geometry()
    ds = _draw_dataset(seed)
    ref = _reference(ds, geom)
    eff = _draw_effect(effect, seed, ds, ref, geom)

    parts: list[pd.DataFrame] = []
    designs: list[np.ndarray] = []
    trial_truths: dict[str, Any] = {}
    for iv, v in enumerate(speeds_mm_s):
        for it in range(trials):
            cols, tt = _trial_frame(effect, strength, seed, iv, it, float(v), ds, eff, ref,
                                    geom, noise_scale)
            name = f"v{iv}_t{it:02d}"
            designs.append(cols.pop("_design"))
            n = cols["time_s"].size
            parts.append(pd.DataFrame({"trial": [name] * n, "speed_mm_s": np.full(n, float(v)),
                                       **cols}))
            trial_truths[name] = tt
    df = pd.concat(parts, ignore_index=True)
    df = df[["trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con",
             "depth_mm", "true_force_g", "true_base_g", "true_theta_tip", "true_theta_bot"]]

    gap = (df["true_force_g"] - df["true_base_g"]).to_numpy()
    resid = (df["force_g"] - df["true_force_g"]).to_numpy()
    gap_rms = float(np.sqrt(np.mean(gap**2)))
    noise_rms = float(np.sqrt(np.mean(resid**2)))
    X = np.vstack(designs)
    coef, *_ = np.linalg.lstsq(X, gap, rcond=None)
    gap_un = float(np.sqrt(np.mean((gap - X @ coef) ** 2)))

    sc = ref["pressure_scale"]
    base = {
        "model": "the paper's friction model: linear pressure, axial projection of friction",
        "friction_when_stopped": "held: mu frozen at mu(v_cruise) during the dwell, so the "
                                 "base force stays at its last value",
        "mu_k": ds["mu_k"], "mu_s": ds["mu_s"], "v_s_mm_s": ds["v_s"], "delta_s": ds["delta_s"],
        "b_c_mm": ds["b_c"],
        "p_tip_MPa": {"a": ds["pt0"] * sc, "b_per_rad": (ds["pt3"] - ds["pt0"]) / 3.0 * sc},
        "p_bot_MPa": {"a": ds["pb0"] * sc, "b_per_rad": (ds["pb3"] - ds["pb0"]) / 3.0 * sc},
        "per_trial_pressure_scale": "p_tip_scale, p_bot_scale in trials (U(0.9, 1.1) each)",
        "target_end_force_g": ds["target_end_force_g"],
        "reference_state": {"depth_mm": 15.0, "theta_tip": ref["theta_tip"],
                            "theta_bot": ref["theta_bot"], "p_ref_MPa": ref["p_ref"]},
        "trials": trial_truths,
    }
    noise = {
        "force_rate_hz": ds["force_rate_hz"],
        "rms_g": ds["noise_rms_g"] * noise_scale, "ar1_variance_share": ds["noise_ar_share"],
        "ar1_tau_s": ds["noise_tau_s"], "full_scale_g": ds["full_scale_g"], "adc_bits": 13,
        "lsb_g": 2 * ds["full_scale_g"] / 2**13, "gain_spread": ds["gain_spread"],
        "tare_sd_g": ds["tare_sd_g"], "fps": ds["fps"], "angle_sd_tip": ds["angle_sd_tip"],
        "angle_sd_bot": ds["angle_sd_bot"], "p_missing_frame": ds["p_missing_frame"],
        "noise_scale": noise_scale,
    }
    truth = {
        "effect": effect, "strength": float(strength), "family": "B", "seed": int(seed),
        "speeds_mm_s": [float(v) for v in speeds_mm_s], "trials": int(trials),
        "params": {"dataset": {k: v for k, v in ds.items()}, "effect": eff},
        "base": base, "noise": noise,
        "gap_rms_g": gap_rms, "noise_rms_g": noise_rms,
        "snr": gap_rms / noise_rms if noise_rms > 0 else float("inf"),
        "gap_unabsorbed_rms_g": gap_un,
        "snr_unabsorbed": gap_un / noise_rms if noise_rms > 0 else float("inf"),
    }
    truth = _jsonable(truth)
    json.dumps(truth)  # fail early if anything is not serialisable
    return df, truth


# --------------------------------------------------------------------------------------
# Summary (python synthetic_b.py)
# --------------------------------------------------------------------------------------
def peak_drop(df: pd.DataFrame, truth: dict[str, Any], *, column: str = "true_force_g",
              during_motion: bool = True, base_corrected: bool = False) -> dict[float, float]:
    """Relative drop of the mean per-trial peak force at each speed vs the slowest speed.

    Parameters
    ----------
    df, truth
        Output of :func:`generate`.
    column : str
        Force column to use.
    during_motion : bool
        Peak over the insertion only (up to the robot's stop) instead of the whole log.
    base_corrected : bool
        Use per-trial ratios ``peak(column) / peak(true_base_g)`` instead of raw peaks, so
        the trial-to-trial spread of the base model cancels.

    Returns
    -------
    dict
        ``{speed: 1 - peak(speed) / peak(slowest)}``.
    """
    info = truth["base"]["trials"]
    rows = []
    for name, g in df.groupby("trial", sort=False):
        sel = g["time_s"] <= info[name]["t_motion_stop_s"] if during_motion else slice(None)
        pk = float(g.loc[sel, column].max())
        if base_corrected:
            pk /= float(g.loc[sel, "true_base_g"].max())
        rows.append((float(g["speed_mm_s"].iloc[0]), pk))
    s = pd.DataFrame(rows, columns=["v", "pk"]).groupby("v")["pk"].mean()
    return {float(v): float(1.0 - s[v] / s.iloc[0]) for v in s.index}


def _summary(seeds: Sequence[int] = range(5)) -> None:  # pragma: no cover - CLI helper
    import time

    t0 = time.perf_counter()
    generate(None, 0)
    print(f"generation time, 5 speeds x 10 trials, no effect: {time.perf_counter() - t0:.2f} s")
    print(f"{'effect':20s} {'snr@1':>7s} {'snr@0.3':>8s} {'unabs@1':>8s} {'unabs@0.3':>9s} "
          f"{'time':>6s}")
    for eff in EFFECTS:
        res = {}
        for st in (1.0, 0.3):
            snr, un, tt = [], [], []
            for seed in seeds:
                t0 = time.perf_counter()
                _, tr = generate(eff, seed, strength=st)
                tt.append(time.perf_counter() - t0)
                snr.append(tr["snr"])
                un.append(tr["snr_unabsorbed"])
            res[st] = (float(np.median(snr)), float(np.median(un)), float(np.median(tt)))
        print(f"{eff:20s} {res[1.0][0]:7.2f} {res[0.3][0]:8.2f} {res[1.0][1]:8.2f} "
              f"{res[0.3][1]:9.2f} "
              f"{res[1.0][2]:6.2f}")
    print("hydrodynamic_lift, strength 1: peak-force drop vs 0.5 mm/s (3 / 7.5 mm/s)")
    for seed in seeds:
        df, tr = generate("hydrodynamic_lift", seed)
        a = peak_drop(df, tr)
        b = peak_drop(df, tr, base_corrected=True)
        c = peak_drop(df, tr, during_motion=False, base_corrected=True)
        print(f"  seed {seed}: insertion peak {a[3.0]:.2f} / {a[7.5]:.2f}; base-corrected "
              f"{b[3.0]:.2f} / {b[7.5]:.2f}; whole log incl. dwell {c[3.0]:.2f} / {c[7.5]:.2f}")


if __name__ == "__main__":  # pragma: no cover
    _summary()

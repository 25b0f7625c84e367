"""Geometry of the planar scala-tympani phantom and of the electrode array.

Everything here lives in the *phantom frame*: millimetres, origin at the spiral centre,
polar angle counter-clockwise from +x. The renderer and the measurement both use these
functions, so they always agree on the phantom.

The backbone is Eq. (1) of the seed paper (Cohen et al. 1996)::

    r(phi) = c (1 - d ln(phi - phi0))   for phi < 100 deg
    r(phi) = a exp(-b phi)              for phi >= 100 deg

The channel walls are normal offsets of the backbone by half the channel width
``w(theta) = min(1.5 mm, 0.38 r(theta))`` on each side. The backbone turns 6.3 deg to the
right at 100 deg: the outer wall (inside of that corner) is cut where its pieces cross, the
inner wall is closed with a circular arc about the backbone point.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "Phantom",
    "ElectrodeArray",
    "Polyline",
    "backbone_radius",
    "backbone_radius_slope",
    "backbone_frame",
    "channel_width",
    "wall_polyline",
    "entry_frame",
    "channel_polygon",
    "point_angle",
    "arc_length",
    "DEFAULT_PHANTOM",
    "DEFAULT_ARRAY",
    "CameraPose",
    "entry_walls",
    "in_entry",
]


@dataclass(frozen=True)
class Phantom:
    """The planar phantom: Cohen backbone, channel width law, entry channel.

    Parameters
    ----------
    a_mm, b_per_deg, c_mm, d, phi0_deg : float
        Constants of Eq. (1): ``a`` in mm, ``b`` in 1/deg, ``c`` in mm, ``d`` dimensionless,
        ``phi0`` in degrees.
    branch_deg : float
        Angle (deg) where Eq. (1) switches from the logarithmic to the exponential branch.
    theta_start, theta_end : float
        Angles (rad) where the spiral channel begins and where it is closed.
    width_max_mm : float
        Largest channel width (mm).
    width_ratio : float
        Channel width as a fraction of the backbone radius where that is below ``width_max_mm``.
    entry_length_mm : float
        Length (mm) of the straight entry channel basal of ``theta_start``.
    wall_step_mm : float
        Spacing (mm) of the points that sample the walls as polylines.
    """

    a_mm: float = 3.762
    b_per_deg: float = 0.001317
    c_mm: float = 7.967
    d: float = 0.1287
    phi0_deg: float = 5.0
    branch_deg: float = 100.0
    theta_start: float = float(np.deg2rad(10.3))
    theta_end: float = float(4 * np.pi)
    width_max_mm: float = 1.5
    width_ratio: float = 0.38
    entry_length_mm: float = 5.0
    wall_step_mm: float = 0.01

    @cached_property
    def outer_wall(self) -> "Polyline":
        """The outer wall as a polyline from ``theta_start`` to ``theta_end``."""
        return wall_polyline(self, "outer")

    @cached_property
    def inner_wall(self) -> "Polyline":
        """The inner wall as a polyline from ``theta_start`` to ``theta_end``."""
        return wall_polyline(self, "inner")


@dataclass(frozen=True)
class ElectrodeArray:
    """A straight, linearly tapered electrode array with metal bands near the tip.

    Parameters
    ----------
    length_mm : float
        Total length (mm).
    tip_diameter_mm, base_diameter_mm : float
        Diameters (mm) at the tip and at the base; linear taper in between.
    n_bands : int
        Number of platinum bands, counted from the tip.
    band_length_mm : float
        Length (mm) of one band along the array.
    band_pitch_mm : float
        Distance (mm) between the starts of neighbouring bands.
    first_band_mm : float
        Distance (mm) from the tip to the apical edge of the first band.
    """

    length_mm: float = 26.0
    tip_diameter_mm: float = 0.6
    base_diameter_mm: float = 1.2
    n_bands: int = 11
    band_length_mm: float = 0.4
    band_pitch_mm: float = 1.0
    first_band_mm: float = 0.3

    def radius(self, s_mm: np.ndarray | float) -> np.ndarray:
        """Half the array's diameter (mm) at distance ``s_mm`` (mm) from the tip."""
        s = np.clip(np.asarray(s_mm, dtype=float), 0.0, self.length_mm)
        return 0.5 * (self.tip_diameter_mm + (self.base_diameter_mm - self.tip_diameter_mm) * s / self.length_mm)

    def band_intervals(self) -> np.ndarray:
        """``(n_bands, 2)`` array of (start, end) distances (mm) of the bands from the tip."""
        starts = self.first_band_mm + self.band_pitch_mm * np.arange(self.n_bands)
        return np.stack([starts, starts + self.band_length_mm], axis=1)


DEFAULT_PHANTOM = Phantom()
DEFAULT_ARRAY = ElectrodeArray()


# --------------------------------------------------------------------------- backbone


def backbone_radius(theta: np.ndarray | float, phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
    """Backbone radius ``r`` (mm) of Eq. (1) at angle ``theta`` (rad).

    Angles where the logarithmic branch is undefined (phi <= phi0) give NaN.
    """
    phi = np.degrees(np.asarray(theta, dtype=float))
    with np.errstate(invalid="ignore", divide="ignore"):
        log_branch = phantom.c_mm * (1.0 - phantom.d * np.log(phi - phantom.phi0_deg))
    exp_branch = phantom.a_mm * np.exp(-phantom.b_per_deg * phi)
    return np.where(phi < phantom.branch_deg, log_branch, exp_branch)


def backbone_radius_slope(theta: np.ndarray | float, phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
    """Derivative ``dr/dtheta`` (mm/rad) of the backbone radius at ``theta`` (rad).

    At exactly ``branch_deg`` the exponential branch's slope is returned.
    """
    phi = np.degrees(np.asarray(theta, dtype=float))
    with np.errstate(invalid="ignore", divide="ignore"):
        log_slope = -phantom.c_mm * phantom.d / (phi - phantom.phi0_deg)
    exp_slope = -phantom.a_mm * phantom.b_per_deg * np.exp(-phantom.b_per_deg * phi)
    return np.where(phi < phantom.branch_deg, log_slope, exp_slope) * (180.0 / np.pi)


def backbone_frame(
    theta: np.ndarray | float, phantom: Phantom = DEFAULT_PHANTOM
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backbone points with their unit tangent and outward unit normal.

    Parameters
    ----------
    theta : array_like
        Angles (rad), shape ``(n,)``.
    phantom : Phantom
        Phantom configuration.

    Returns
    -------
    points, tangent, normal : ndarray, shape (n, 2)
        Points (mm); unit tangent in the direction of increasing theta; unit normal pointing
        away from the spiral centre (towards the outer wall).
    """
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    r = backbone_radius(theta, phantom)
    dr = backbone_radius_slope(theta, phantom)
    cos, sin = np.cos(theta), np.sin(theta)
    points = np.stack([r * cos, r * sin], axis=1)
    tangent = np.stack([dr * cos - r * sin, dr * sin + r * cos], axis=1)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)  # tangent turned clockwise
    return points, tangent, normal


def channel_width(theta: np.ndarray | float, phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
    """Channel width ``w`` (mm) at ``theta`` (rad): ``min(width_max_mm, width_ratio * r)``."""
    return np.minimum(phantom.width_max_mm, phantom.width_ratio * backbone_radius(theta, phantom))


# --------------------------------------------------------------------------- polylines


@dataclass(frozen=True)
class Polyline:
    """A densely sampled curve with its parameter and a nearest-point index.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        Vertices (mm).
    theta : ndarray, shape (n,)
        Backbone angle (rad) each vertex belongs to (non-decreasing).
    """

    points: np.ndarray
    theta: np.ndarray

    @cached_property
    def s(self) -> np.ndarray:
        """Cumulative arc length (mm) at each vertex."""
        return arc_length(self.points)

    @cached_property
    def _tree(self) -> cKDTree:
        return cKDTree(self.points)

    @cached_property
    def _turn_trees(self) -> list[tuple[int, cKDTree]]:
        """Overlapping pieces one turn long, starting every half turn: (first index, tree)."""
        lo, hi = float(self.theta[0]), float(self.theta[-1])
        n = max(1, int(np.ceil((hi - lo) / np.pi)) - 1)
        pieces = []
        for j in range(n):
            a, b = np.searchsorted(self.theta, [lo + j * np.pi, lo + j * np.pi + 2 * np.pi], side="right")
            a = max(a - 1, 0)
            pieces.append((int(a), cKDTree(self.points[a : max(b, a + 2)])))
        return pieces

    def _nearest_vertex(self, xy: np.ndarray, theta: np.ndarray | None) -> np.ndarray:
        if theta is None:
            return self._tree.query(xy)[1]
        pieces = self._turn_trees
        j = np.clip(np.round((theta - self.theta[0] - np.pi) / np.pi), 0, len(pieces) - 1).astype(int)
        idx = np.empty(len(xy), dtype=int)
        for k in np.unique(j):
            sel = j == k
            first, tree = pieces[k]
            idx[sel] = first + tree.query(xy[sel])[1]
        return idx

    def project(
        self, xy: np.ndarray, theta: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points on the polyline.

        Parameters
        ----------
        xy : ndarray, shape (m, 2)
            Query points (mm).
        theta : ndarray, shape (m,), optional
            The points' angles (rad, unwrapped as :func:`point_angle` gives them). When given,
            each point is projected onto the part of the polyline within about half a turn of its
            own angle, so a point next to the inner wall is not matched with the outer wall of
            the next turn in.

        Returns
        -------
        distance : ndarray, shape (m,)
            Signed distance (mm), positive on the left of the polyline's direction (for a wall
            running towards increasing theta: towards the spiral centre).
        theta : ndarray, shape (m,)
            Backbone angle (rad) at the closest point, interpolated between vertices.
        s : ndarray, shape (m,)
            Arc length (mm) of the closest point along the polyline.
        """
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        n = len(self.points)
        idx = self._nearest_vertex(xy, None if theta is None else np.asarray(theta, dtype=float))
        best_d = np.full(len(xy), np.inf)
        best = np.zeros((len(xy), 3))
        for lo in (idx - 1, idx):  # the two segments that meet at the nearest vertex
            lo = np.clip(lo, 0, n - 2)
            p0, p1 = self.points[lo], self.points[lo + 1]
            seg = p1 - p0
            seg_len2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-18)
            t = np.clip(np.einsum("ij,ij->i", xy - p0, seg) / seg_len2, 0.0, 1.0)
            foot = p0 + t[:, None] * seg
            diff = xy - foot
            d = np.hypot(diff[:, 0], diff[:, 1])
            side = np.sign(seg[:, 0] * diff[:, 1] - seg[:, 1] * diff[:, 0])
            side[side == 0] = 1.0
            theta = self.theta[lo] + t * (self.theta[lo + 1] - self.theta[lo])
            s = self.s[lo] + t * np.sqrt(seg_len2)
            better = d < best_d
            best_d = np.where(better, d, best_d)
            best[better] = np.stack([side * d, theta, s], axis=1)[better]
        return best[:, 0], best[:, 1], best[:, 2]


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length (mm) along a polyline of ``points`` (mm), starting at 0."""
    points = np.asarray(points, dtype=float)
    steps = np.hypot(*np.diff(points, axis=0).T)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _theta_grid(lo: float, hi: float, phantom: Phantom) -> np.ndarray:
    """Angles (rad) from ``lo`` to ``hi`` spaced about ``wall_step_mm`` apart on the backbone."""
    r_max = float(np.nanmax(backbone_radius(np.array([lo, hi]), phantom)))
    n = max(2, int(np.ceil((hi - lo) * r_max / phantom.wall_step_mm)) + 1)
    return np.linspace(lo, hi, n)


def _offset(theta: np.ndarray, sign: float, phantom: Phantom) -> np.ndarray:
    points, _, normal = backbone_frame(theta, phantom)
    return points + sign * 0.5 * channel_width(theta, phantom)[:, None] * normal


def _segment_crossing(a: np.ndarray, b: np.ndarray) -> tuple[int, int, np.ndarray] | None:
    """First crossing of polylines ``a`` and ``b``: (segment of a, segment of b, point)."""
    pa, qa = a[:-1, None, :], a[1:, None, :]
    pb, qb = b[None, :-1, :], b[None, 1:, :]
    ra, rb = qa - pa, qb - pb
    denom = ra[..., 0] * rb[..., 1] - ra[..., 1] * rb[..., 0]
    diff = pb - pa
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (diff[..., 0] * rb[..., 1] - diff[..., 1] * rb[..., 0]) / denom
        u = (diff[..., 0] * ra[..., 1] - diff[..., 1] * ra[..., 0]) / denom
    hit = (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    if not hit.any():
        return None
    i, j = np.argwhere(hit)[0]
    return int(i), int(j), (pa[i, 0] + t[i, j] * ra[i, 0])


def wall_polyline(phantom: Phantom, side: str) -> Polyline:
    """One channel wall from ``theta_start`` to ``theta_end`` as a dense polyline.

    Parameters
    ----------
    phantom : Phantom
        Phantom configuration.
    side : {"outer", "inner"}
        ``"outer"`` is the wall away from the spiral centre.

    Returns
    -------
    Polyline
        Vertices (mm) and the backbone angle (rad) each belongs to. The corner at
        ``branch_deg`` is handled as the module docstring says.
    """
    if side not in ("outer", "inner"):
        raise ValueError(f"side must be 'outer' or 'inner', not {side!r}")
    sign = 1.0 if side == "outer" else -1.0
    corner = np.deg2rad(phantom.branch_deg)
    before = _theta_grid(phantom.theta_start, corner, phantom)
    after = _theta_grid(corner, phantom.theta_end, phantom)
    # the branch value at the corner itself: evaluate the log branch just before it
    before_pts = _offset(before[:-1], sign, phantom)
    p_corner, t_before, n_before = backbone_frame(np.nextafter(corner, 0.0), phantom)
    half = 0.5 * float(channel_width(corner, phantom))
    before_pts = np.vstack([before_pts, p_corner + sign * half * n_before])
    after_pts = _offset(after, sign, phantom)
    turn = np.arctan2(
        t_before[0, 0] * backbone_frame(corner, phantom)[1][0, 1]
        - t_before[0, 1] * backbone_frame(corner, phantom)[1][0, 0],
        float(t_before[0] @ backbone_frame(corner, phantom)[1][0]),
    )  # > 0: left turn, < 0: right turn
    inside_of_corner = (turn < 0) == (sign > 0)
    if inside_of_corner:
        k = max(10, int(0.2 / phantom.wall_step_mm))  # search the last/first ~0.2 mm
        hit = _segment_crossing(before_pts[-k:], after_pts[:k])
        if hit is None:
            raise RuntimeError("wall pieces at the Eq. (1) corner do not cross")
        i, j, x = hit
        i += len(before_pts) - k
        pts = np.vstack([before_pts[: i + 1], x, after_pts[j + 1 :]])
        th = np.concatenate([before[: i + 1], [corner], after[j + 1 :]])
    else:
        n_after = backbone_frame(corner, phantom)[2][0]
        a0 = np.arctan2(sign * n_before[0, 1], sign * n_before[0, 0])
        a1 = np.arctan2(sign * n_after[1], sign * n_after[0])
        da = (a1 - a0 + np.pi) % (2 * np.pi) - np.pi
        m = max(3, int(np.ceil(abs(da) * half / phantom.wall_step_mm)) + 1)
        ang = a0 + da * np.linspace(0, 1, m)[1:-1]
        arc = p_corner + half * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        pts = np.vstack([before_pts, arc, after_pts])
        th = np.concatenate([before, np.full(len(arc), corner), after])
    return Polyline(points=pts, theta=th)


# --------------------------------------------------------------------------- entry, outline


def entry_frame(phantom: Phantom = DEFAULT_PHANTOM) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the spiral channel begins and the insertion axis.

    Returns
    -------
    origin : ndarray, shape (2,)
        Backbone point (mm) at ``theta_start``: the end of the entry channel.
    x_w : ndarray, shape (2,)
        Unit insertion axis: the backbone tangent at ``theta_start``, pointing into the spiral.
    normal : ndarray, shape (2,)
        Outward unit normal there (towards the outer wall).
    """
    p, t, n = backbone_frame(phantom.theta_start, phantom)
    return p[0], t[0], n[0]


def entry_walls(phantom: Phantom = DEFAULT_PHANTOM) -> tuple[np.ndarray, np.ndarray]:
    """The entry channel's (outer, inner) walls as 2-point segments (mm), basal end first."""
    origin, x_w, normal = entry_frame(phantom)
    half = 0.5 * float(channel_width(phantom.theta_start, phantom))
    back = origin - phantom.entry_length_mm * x_w
    outer = np.stack([back + half * normal, origin + half * normal])
    inner = np.stack([back - half * normal, origin - half * normal])
    return outer, inner


def channel_polygon(phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
    """The closed outline (mm) of the whole channel, entry included, as an ``(n, 2)`` array.

    It runs out along the inner wall to ``theta_end``, across the closing cap, back along the
    outer wall and out of the entry.
    """
    entry_outer, entry_inner = entry_walls(phantom)
    return np.vstack(
        [entry_inner[:1], phantom.inner_wall.points, phantom.outer_wall.points[::-1], entry_outer[:1]]
    )


# --------------------------------------------------------------------------- angles


def point_angle(xy: np.ndarray, phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
    """The unwrapped angle (rad) of points in the phantom frame (docs/file-formats.md).

    ``theta = phi + 2 pi k`` with ``phi`` in (-pi, pi] the polar angle and ``k >= 0`` the
    integer for which the backbone radius at ``theta`` is closest to the point's radius
    (outside ``[theta_start, theta_end]`` the radius at the nearer end is used). Points in
    the entry channel, or on the insertion axis behind it, take ``k = 0``.

    Parameters
    ----------
    xy : ndarray, shape (n, 2)
        Points (mm).
    phantom : Phantom
        Phantom configuration.

    Returns
    -------
    ndarray, shape (n,)
        Angles (rad).
    """
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    phi = np.arctan2(xy[:, 1], xy[:, 0])
    rho = np.hypot(xy[:, 0], xy[:, 1])
    n_turns = int(np.ceil((phantom.theta_end + np.pi) / (2 * np.pi))) + 1
    cand = phi[:, None] + 2 * np.pi * np.arange(n_turns)[None, :]
    clipped = np.clip(cand, phantom.theta_start, phantom.theta_end)
    r = backbone_radius(clipped, phantom)
    # a small penalty (mm/rad) beyond the channel's ends breaks ties in favour of the channel
    k = np.argmin(np.abs(r - rho[:, None]) + 0.1 * np.abs(cand - clipped), axis=1)
    theta = phi + 2 * np.pi * k
    return np.where(in_entry(xy, phantom), phi, theta)


def in_entry(xy: np.ndarray, phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
    """True for points (mm) behind the entry's end at ``theta_start``, within a channel
    width of the insertion axis (the entry channel and the uninserted array outside it)."""
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    origin, x_w, normal = entry_frame(phantom)
    rel = xy - origin
    along = rel @ x_w
    lateral = rel @ normal
    width = float(channel_width(phantom.theta_start, phantom))
    return (along < 0) & (np.abs(lateral) <= width)


# --------------------------------------------------------------------------- camera


@dataclass(frozen=True)
class CameraPose:
    """The similarity between the phantom frame (mm, y up) and the image (px, y down).

    ``x_img = cx + s (cos(rot) X - sin(rot) Y')``, ``y_img = cy - s (sin(rot) X + cos(rot) Y')``
    with ``Y' = Y`` for a normal view and ``Y' = -Y`` for a mirrored one (the other ear): the
    phantom is rotated counter-clockwise on screen by ``rotation_rad``.

    Parameters
    ----------
    centre_x_px, centre_y_px : float
        Image position (px) of the spiral centre.
    rotation_rad : float
        On-screen counter-clockwise rotation (rad).
    px_per_mm : float
        Scale (px/mm).
    mirrored : bool
        Whether the phantom appears mirrored.
    """

    centre_x_px: float
    centre_y_px: float
    rotation_rad: float
    px_per_mm: float
    mirrored: bool = False

    def _matrix(self) -> np.ndarray:
        c, s = np.cos(self.rotation_rad), np.sin(self.rotation_rad)
        flip = -1.0 if self.mirrored else 1.0
        return self.px_per_mm * np.array([[c, -s * flip], [-s, -c * flip]])

    def moved(self, shift_px: tuple[float, float] | np.ndarray) -> "CameraPose":
        """The same pose moved by ``shift_px`` (px, image x and y)."""
        return replace(self, centre_x_px=float(self.centre_x_px + shift_px[0]),
                       centre_y_px=float(self.centre_y_px + shift_px[1]))

    def to_image(self, xy_mm: np.ndarray) -> np.ndarray:
        """Phantom-frame points (mm), shape ``(n, 2)``, to image points (px)."""
        xy = np.atleast_2d(np.asarray(xy_mm, dtype=float))
        return xy @ self._matrix().T + np.array([self.centre_x_px, self.centre_y_px])

    def to_phantom(self, xy_px: np.ndarray) -> np.ndarray:
        """Image points (px), shape ``(n, 2)``, to phantom-frame points (mm)."""
        xy = np.atleast_2d(np.asarray(xy_px, dtype=float))
        return (xy - np.array([self.centre_x_px, self.centre_y_px])) @ np.linalg.inv(self._matrix()).T

    def affine(self) -> np.ndarray:
        """The 2x3 affine matrix (phantom mm -> image px), as OpenCV's warp functions take it."""
        return np.hstack([self._matrix(), [[self.centre_x_px], [self.centre_y_px]]])

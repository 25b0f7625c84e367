"""Property tests of the phantom geometry (vision/geometry.py)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tympani.vision.geometry import (
    DEFAULT_PHANTOM as P,
    CameraPose,
    ElectrodeArray,
    Phantom,
    backbone_frame,
    backbone_radius,
    backbone_radius_slope,
    channel_polygon,
    channel_width,
    entry_frame,
    in_entry,
    point_angle,
)


def test_eq1_branches_meet_at_100_degrees():
    corner = np.deg2rad(100.0)
    log_side = float(backbone_radius(np.nextafter(corner, 0.0)))
    exp_side = float(backbone_radius(corner))
    # the two branches of Eq. (1) meet to about 1e-4 mm: with the default constants the mismatch is
    # 1.15e-4 mm
    assert abs(log_side - exp_side) < 1.5e-4
    assert exp_side == pytest.approx(3.298, abs=1e-3)


def test_backbone_turns_right_by_6_3_degrees_at_the_corner():
    corner = np.deg2rad(100.0)
    _, t_before, _ = backbone_frame(np.nextafter(corner, 0.0))
    _, t_after, _ = backbone_frame(corner)
    cross = t_before[0, 0] * t_after[0, 1] - t_before[0, 1] * t_after[0, 0]
    turn = np.degrees(np.arctan2(cross, t_before[0] @ t_after[0]))
    assert turn == pytest.approx(-6.3, abs=0.05)  # negative: a right turn


def test_radius_slope_matches_finite_differences():
    theta = np.linspace(P.theta_start + 0.01, P.theta_end - 0.01, 400)
    theta = theta[np.abs(theta - np.deg2rad(100)) > 1e-3]
    h = 1e-6
    numeric = (backbone_radius(theta + h) - backbone_radius(theta - h)) / (2 * h)
    np.testing.assert_allclose(backbone_radius_slope(theta), numeric, rtol=1e-6)


def test_channel_width_law():
    theta = np.deg2rad([10.3, 40.0, 55.0, 60.0, 300.0, 720.0])
    w = channel_width(theta)
    assert np.all(w[:2] == 1.5)
    np.testing.assert_allclose(w[3:], 0.38 * backbone_radius(theta[3:]))
    assert abs(np.degrees(theta[2]) - 55) < 1 and w[2] == pytest.approx(1.5, abs=0.01)


def test_point_angle_of_backbone_points_is_their_own_angle():
    theta = np.linspace(P.theta_start, P.theta_end, 5000)
    pts, _, normal = backbone_frame(theta)
    np.testing.assert_allclose(point_angle(pts), theta, atol=1e-12)
    # points across the channel keep (nearly) the backbone's angle: the turn is not confused
    half = 0.45 * channel_width(theta)[:, None]
    for sign in (-1, 1):
        off = point_angle(pts + sign * half * normal)
        assert np.max(np.abs(off - theta)) < 0.3


def test_entry_points_take_k_zero():
    origin, x_w, normal = entry_frame()
    behind = origin - np.outer(np.linspace(0.1, 20, 50), x_w)
    assert np.all(in_entry(behind))
    phi = np.arctan2(behind[:, 1], behind[:, 0])
    np.testing.assert_allclose(point_angle(behind), phi)


def test_walls_never_cross_and_keep_015mm_between_turns():
    outer, inner = P.outer_wall, P.inner_wall
    # the inner wall of one turn against the outer wall of the next turn inside it
    i_sel = inner.theta <= P.theta_end - 2 * np.pi
    o_sel = outer.theta >= P.theta_start + 2 * np.pi - 0.2
    gap, _ = cKDTree(outer.points[o_sel]).query(inner.points[i_sel])
    assert gap.min() >= 0.15
    # no inner-wall point touches any outer wall (own turn or the next one in)
    d, _, _ = outer.project(inner.points)
    assert np.abs(d).min() >= 0.15


def test_outline_is_a_simple_polygon():
    """No two non-neighbouring edges of the channel outline intersect."""
    poly = channel_polygon()[::5]
    a, b = poly[:-1], poly[1:]
    # sweep: only test segment pairs whose bounding boxes overlap (grid hashing)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    crossings = 0
    order = np.argsort(lo[:, 0])
    for idx, i in enumerate(order):
        for j in order[idx + 1 :]:
            if lo[j, 0] > hi[i, 0]:
                break
            if abs(int(i) - int(j)) <= 1 or (lo[j, 1] > hi[i, 1] or hi[j, 1] < lo[i, 1]):
                continue
            d1, d2 = b[i] - a[i], b[j] - a[j]
            den = d1[0] * d2[1] - d1[1] * d2[0]
            if den == 0:
                continue
            w = a[j] - a[i]
            t = (w[0] * d2[1] - w[1] * d2[0]) / den
            u = (w[0] * d1[1] - w[1] * d1[0]) / den
            crossings += bool(0 < t < 1 and 0 < u < 1)
    assert crossings == 0


def test_inner_wall_arc_and_outer_wall_cut_at_the_corner():
    corner = np.deg2rad(100)
    p, _, _ = backbone_frame(corner)
    half = 0.5 * float(channel_width(corner))
    arc = P.inner_wall.points[P.inner_wall.theta == corner]
    assert len(arc) >= 3
    np.testing.assert_allclose(np.hypot(*(arc - p[0]).T), half, atol=2e-4)  # branch mismatch
    # the cut outer wall: no vertex closer to the backbone than half the width (no overlap loop)
    near = np.abs(P.outer_wall.theta - corner) < 0.05
    dist = np.hypot(*(P.outer_wall.points[near] - p[0]).T)
    assert dist.min() >= half * np.cos(np.deg2rad(6.3) / 2) - 1e-6


def test_polyline_projection_distance_and_side():
    theta = np.linspace(0.5, 12.0, 300)
    pts, _, normal = backbone_frame(theta)
    half = 0.5 * channel_width(theta)
    d, th, _ = P.outer_wall.project(pts)
    np.testing.assert_allclose(d, half, rtol=0.02)  # positive inside the channel
    np.testing.assert_allclose(th, theta, atol=0.02)
    d_out, _, _ = P.outer_wall.project(pts + (half + 0.2)[:, None] * normal)
    assert np.all(d_out < 0)


@pytest.mark.parametrize("mirrored", [False, True])
def test_camera_pose_round_trip_and_handedness(mirrored):
    pose = CameraPose(311.5, 207.25, 1.1, 23.0, mirrored)
    xy = np.random.default_rng(0).uniform(-8, 8, size=(100, 2))
    np.testing.assert_allclose(pose.to_phantom(pose.to_image(xy)), xy, atol=1e-9)
    # a counter-clockwise turn in the phantom is counter-clockwise on screen unless mirrored
    a, b = pose.to_image(np.array([[1.0, 0.0], [0.0, 1.0]])) - pose.to_image(np.zeros((1, 2)))
    screen_cross = a[0] * (-b[1]) - (-a[1]) * b[0]  # y flipped back to "up"
    assert (screen_cross > 0) != mirrored
    assert np.hypot(*a) == pytest.approx(23.0)


def test_array_taper():
    arr = ElectrodeArray()
    assert arr.radius(0.0) == pytest.approx(0.3)
    assert arr.radius(arr.length_mm) == pytest.approx(0.6)
    assert arr.band_intervals().shape == (11, 2)


def test_geometry_is_configurable():
    narrow = Phantom(width_max_mm=1.0)
    assert float(channel_width(0.5, narrow)) == 1.0
    assert narrow.outer_wall.s[-1] != P.outer_wall.s[-1]


def test_projection_with_angles_stays_on_the_points_own_turn():
    """Next to the inner wall, the outer wall of the next turn in is nearer than the own one."""
    theta = np.linspace(0.5, P.theta_end - 2 * np.pi, 200)
    pts, _, normal = backbone_frame(theta)
    near_inner = pts - (0.45 * channel_width(theta))[:, None] * normal
    d_any, _, _ = P.outer_wall.project(near_inner)
    d_own, th_own, _ = P.outer_wall.project(near_inner, point_angle(near_inner))
    assert np.any(d_any < 0)  # the trap is real
    np.testing.assert_allclose(d_own, 0.95 * channel_width(theta), rtol=0.03)
    np.testing.assert_allclose(th_own, theta, atol=0.05)

"""The force model: invariants and an explicit reference sum (the paper's scenarios: test_paper.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tympani.pipeline.model.friction import (
    G_N,
    ContactGeometry,
    FrictionParams,
    LinearPressure,
    PiecewisePressure,
    contact_geometry,
    flat_params,
    insertion_force,
    params_from_flat,
    stribeck,
)
from tympani.vision.geometry import DEFAULT_PHANTOM, entry_frame

PARAMS = FrictionParams(
    mu_s=0.18, mu_k=0.12, v_s_mm_s=1.5, delta_s=1.5, mu_v_s_per_mm=0.004, contact_width_mm=0.3,
    p_tip_MPa=LinearPressure(0.012, 0.008), p_bot_MPa=LinearPressure(0.02, 0.015),
)
#: realistic contact arcs (rad): first contact 1.0-1.8, tip up to ~4 at 15 mm depth
ARCS = [(1.4, 1.9), (1.2, 2.6), (1.6, 3.2), (1.9, 3.9), (2.15, 3.9), (1.0, 3.5), (1.7, 1.75)]


def _random_arcs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    bot = rng.uniform(1.0, 2.4, n)
    tip = bot + rng.uniform(0.0, 1.6, n)
    speed = rng.uniform(0.5, 7.5, n)
    return bot, tip, speed


# --------------------------------------------------------------------------- reference


def _explicit_force(theta_bot: float, theta_tip: float, v: float, params: FrictionParams, mode: str,
                    m: int = 4000) -> float:
    """Eqs. (2)-(7) element by element with explicit vectors (slow reference).

    ``mode="vector"`` sums the friction vectors before projecting on x_w; ``"axial"`` transmits
    each element's friction magnitude along x_w.

    The arc is cut into ``m`` elements between wall points interpolated at equal steps of the
    channel angle; each element's normal force points into the channel (away from the outward
    normal, found from the element's side relative to the spiral centre), its friction opposes
    the apical sliding.
    """
    wall = DEFAULT_PHANTOM.outer_wall
    _, x_w, _ = entry_frame(DEFAULT_PHANTOM)
    keep = np.concatenate([[True], np.diff(wall.theta) > 0])
    th_w, pts_w = wall.theta[keep], wall.points[keep]
    # include every wall vertex inside the arc so the polyline (and its corner cut) is followed
    inner = th_w[(th_w > theta_bot) & (th_w < theta_tip)]
    th = np.union1d(np.linspace(theta_bot, theta_tip, m + 1), inner)
    pts = np.stack([np.interp(th, th_w, pts_w[:, 0]), np.interp(th, th_w, pts_w[:, 1])], axis=1)
    seg_len = np.hypot(*np.diff(pts, axis=0).T)
    l_con = seg_len.sum()
    theta_con = theta_tip - theta_bot
    p_tip = max(float(params.p_tip_MPa(theta_con)), 0.0)
    p_bot = max(float(params.p_bot_MPa(theta_con)), 0.0)
    mu = float(stribeck(v, params))
    total = np.zeros(2)
    s_from_tip = l_con
    for i in range(len(seg_len)):
        a, b = pts[i], pts[i + 1]
        ds = seg_len[i]
        if ds == 0:
            continue
        t = (b - a) / ds  # towards the apex
        mid = 0.5 * (a + b)
        s_mid = s_from_tip - 0.5 * ds
        s_from_tip -= ds
        normal = np.array([t[1], -t[0]])
        if normal @ mid < 0:  # the outward normal has a positive radial component on a spiral wall
            normal = -normal
        p = p_tip + (s_mid / l_con) * (p_bot - p_tip)
        n_i = -p * params.contact_width_mm * ds * normal  # on the array, towards the channel
        f_i = -mu * np.linalg.norm(n_i) * t  # on the array, basal (opposes apical sliding)
        total += n_i + (f_i if mode == "vector" else -np.linalg.norm(f_i) * x_w)
    f_ins = -total
    return float(f_ins @ x_w) / G_N


@pytest.mark.parametrize("bot, tip", ARCS)
@pytest.mark.parametrize("v", [0.5, 7.5])
@pytest.mark.parametrize("mode", ["axial", "vector"])
def test_vectorised_matches_explicit_sum(bot, tip, v, mode):
    fast = float(insertion_force(bot, tip, v, PARAMS, friction_mode=mode))
    slow = _explicit_force(bot, tip, v, PARAMS, mode)
    assert fast == pytest.approx(slow, rel=1e-3)


def test_axial_mode_matches_its_definition():
    """friction_mode='axial': normal term plus mu * integral p b_c ds along x_w."""
    bot, tip, v = 1.6, 3.4, 2.0
    no_friction = replace(PARAMS, mu_s=0.0, mu_k=0.0, mu_v_s_per_mm=0.0)
    normal_only = float(insertion_force(bot, tip, v, no_friction))
    # integral of p over the arc from the explicit reference with x_w-free geometry: p_mean * b_c * l
    wall_len = float(np.diff(contact_geometry().wall_s(np.array([bot, tip])))[0])
    con = tip - bot
    mean_p = 0.5 * (PARAMS.p_tip_MPa(con) + PARAMS.p_bot_MPa(con))
    expected = normal_only + float(stribeck(v, PARAMS)) * mean_p * PARAMS.contact_width_mm * wall_len / G_N
    assert float(insertion_force(bot, tip, v, PARAMS, friction_mode="axial")) == pytest.approx(expected, rel=1e-9)


# --------------------------------------------------------------------------- invariants


def test_zero_contact_gives_zero_force():
    theta = np.linspace(1.0, 4.0, 7)
    assert np.all(insertion_force(theta, theta, 3.0, PARAMS) == 0.0)
    # contact start beyond the tip is no contact either
    assert np.all(insertion_force(theta + 0.1, theta, 3.0, PARAMS) == 0.0)


def test_forces_are_positive_on_realistic_arcs():
    """The model's sign conventions give F > 0 (pushing in) on realistic arcs (see pipeline/model/friction.py)."""
    bot, tip = np.meshgrid(np.linspace(1.0, 2.6, 60), np.linspace(1.0, 4.0, 90))
    contact = tip > bot + 1e-9
    laws = [
        PARAMS,
        replace(PARAMS, p_tip_MPa=LinearPressure(0.05), p_bot_MPa=LinearPressure(0.0)),
        replace(PARAMS, p_tip_MPa=LinearPressure(0.0), p_bot_MPa=LinearPressure(0.05)),
        replace(PARAMS, mu_s=0.5, mu_k=0.5, mu_v_s_per_mm=0.0, p_tip_MPa=LinearPressure(0.05), p_bot_MPa=LinearPressure(0.0)),
    ]
    for params in laws:
        for v in (0.5, 7.5):
            force = insertion_force(bot, tip, v, params)
            assert np.all(force[contact] > 0), (params, v)
    # the whole band 1.0 <= theta_bot < theta_tip <= 4.0 rad for mu up to 0.25
    bot, tip = np.meshgrid(np.linspace(1.0, 4.0, 120), np.linspace(1.0, 4.0, 120))
    contact = tip > bot + 1e-9
    for params in laws[:3]:
        params = replace(params, mu_s=0.25, mu_k=0.25)
        assert np.all(insertion_force(bot, tip, 3.0, params)[contact] > 0)


def test_force_grows_with_pressure_and_is_linear_in_width_times_pressure():
    rng = np.random.default_rng(1)
    bot, tip, v = _random_arcs(rng, 500)
    contact = tip - bot > 0.05
    base = insertion_force(bot, tip, v, PARAMS)
    more_tip = insertion_force(bot, tip, v, replace(PARAMS, p_tip_MPa=LinearPressure(0.02, 0.008)))
    more_bot = insertion_force(bot, tip, v, replace(PARAMS, p_bot_MPa=LinearPressure(0.03, 0.015)))
    assert np.all(more_tip[contact] > base[contact]) and np.all(more_bot[contact] > base[contact])
    doubled = replace(PARAMS, p_tip_MPa=LinearPressure(0.024, 0.016), p_bot_MPa=LinearPressure(0.04, 0.03))
    np.testing.assert_allclose(insertion_force(bot, tip, v, doubled), 2 * base, rtol=1e-12)
    # b_c x p is exactly degenerate: half the width and double the pressure is the same force
    swapped = replace(doubled, contact_width_mm=PARAMS.contact_width_mm / 2)
    np.testing.assert_allclose(insertion_force(bot, tip, v, swapped), base, rtol=1e-12)


def test_equal_coefficients_and_no_viscosity_remove_speed_dependence():
    rng = np.random.default_rng(2)
    bot, tip, _ = _random_arcs(rng, 300)
    coulomb = replace(PARAMS, mu_s=0.15, mu_k=0.15, mu_v_s_per_mm=0.0)
    forces = [insertion_force(bot, tip, v, coulomb) for v in (0.0, 0.5, 3.0, 7.5, 50.0)]
    for f in forces[1:]:
        np.testing.assert_array_equal(f, forces[0])
    # while the Stribeck parameters do make it depend on speed
    assert not np.allclose(insertion_force(bot, tip, 0.5, PARAMS), insertion_force(bot, tip, 7.5, PARAMS))


def test_stribeck_law():
    p = FrictionParams(mu_s=0.18, mu_k=0.12, v_s_mm_s=2.0, delta_s=2.0, mu_v_s_per_mm=0.01)
    assert float(stribeck(0.0, p)) == pytest.approx(0.18)
    assert float(stribeck(2.0, p)) == pytest.approx(0.12 + 0.06 * np.exp(-1.0) + 0.02)
    assert float(stribeck(1e3, p)) == pytest.approx(0.12 + 10.0)
    assert float(stribeck(-2.0, p)) == float(stribeck(2.0, p))


def test_retraction_reverses_friction():
    """F(v) + F(-v) = 2 * (normal term): friction flips with the sliding direction."""
    rng = np.random.default_rng(3)
    bot, tip, v = _random_arcs(rng, 50)
    no_friction = replace(PARAMS, mu_s=0.0, mu_k=0.0, mu_v_s_per_mm=0.0)
    normal = insertion_force(bot, tip, v, no_friction)
    np.testing.assert_allclose(insertion_force(bot, tip, v, PARAMS) + insertion_force(bot, tip, -v, PARAMS),
                               2 * normal, rtol=1e-10, atol=1e-12)


def _mirror(points: np.ndarray) -> np.ndarray:
    return points * np.array([1.0, -1.0])


def test_mirrored_phantom_frame_gives_the_same_force():
    """The model lives in the phantom frame: reflecting the wall, the insertion axis and the
    angles (a left cochlea seen as the mirror image of a right one) leaves F unchanged."""
    wall = DEFAULT_PHANTOM.outer_wall
    _, x_w, _ = entry_frame(DEFAULT_PHANTOM)
    mirrored_points = _mirror(wall.points)
    # reflected angles: measured clockwise in the mirrored frame, a point keeps its angle, so the
    # wall keeps its angle labels (the angles are a property of the channel, not of the view)
    clockwise = -np.unwrap(np.arctan2(mirrored_points[:, 1], mirrored_points[:, 0]))
    np.testing.assert_allclose(clockwise, np.unwrap(np.arctan2(wall.points[:, 1], wall.points[:, 0])), atol=1e-12)
    mirrored = ContactGeometry.from_wall(mirrored_points, wall.theta, _mirror(x_w[None, :])[0])
    # also an arbitrary rotation + reflection + translation of the whole frame
    rot = np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    shift = np.array([3.0, -2.0])
    moved = ContactGeometry.from_wall(_mirror(wall.points) @ rot.T + shift, wall.theta,
                                      _mirror(x_w[None, :])[0] @ rot.T, centre=shift)
    rng = np.random.default_rng(4)
    bot, tip, v = _random_arcs(rng, 200)
    ref = insertion_force(bot, tip, v, PARAMS)
    np.testing.assert_allclose(insertion_force(bot, tip, v, PARAMS, mirrored), ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(insertion_force(bot, tip, v, PARAMS, moved), ref, rtol=1e-10, atol=1e-12)


def test_broadcasting_and_nan():
    f = insertion_force(np.array([[1.4], [1.6]]), np.array([2.0, 3.0, 3.5]), np.array([0.5, 3.0, 7.5]), PARAMS)
    assert f.shape == (2, 3)
    assert f[1, 2] == pytest.approx(float(insertion_force(1.6, 3.5, 7.5, PARAMS)), rel=1e-12)
    assert np.isnan(insertion_force(np.nan, 3.0, 2.0, PARAMS))


def test_pressure_laws():
    line = LinearPressure(0.01, 0.02)
    piecewise = PiecewisePressure((0.0, 1.0, 2.0), (0.01, 0.03, 0.05))
    con = np.linspace(0, 2, 9)
    np.testing.assert_allclose(piecewise(con), line(con))
    a = insertion_force(1.5, 3.2, 1.0, replace(PARAMS, p_tip_MPa=line))
    b = insertion_force(1.5, 3.2, 1.0, replace(PARAMS, p_tip_MPa=piecewise))
    assert float(a) == pytest.approx(float(b), rel=1e-12)
    with pytest.raises(ValueError):
        PiecewisePressure((1.0, 0.5), (0.1, 0.2))


def test_flat_parameters_round_trip():
    flat = flat_params(PARAMS)
    assert params_from_flat(flat) == PARAMS
    assert params_from_flat({"mu_k": 0.2}, PARAMS).mu_k == 0.2
    with pytest.raises(KeyError):
        params_from_flat({"nonsense": 1.0})

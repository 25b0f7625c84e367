"""Renderer C (tympani.pipeline.synthetic.renderer_c): truth re-derived with independent geometry code, images, determinism."""
import math

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from tympani.pipeline.synthetic import renderer_c as rc
from tympani.pipeline.synthetic.renderer_c.drawing import Renderer

# ------------------------------------------------------------------------------------------------
# independent re-implementation of the phantom's geometry (written separately from renderer C's Phantom)
# ------------------------------------------------------------------------------------------------
A, B, C, D, PHI0 = 3.762, 0.001317, 7.967, 0.1287, 5.0
TH_S, TH_E = math.radians(10.3), 4 * math.pi
TOL = 0.05


def r_of(th):
    deg = np.degrees(np.asarray(th, float))
    out = np.empty_like(deg)
    lo = deg < 100.0
    out[lo] = C * (1 - D * np.log(deg[lo] - PHI0))
    out[~lo] = A * np.exp(-B * deg[~lo])
    return out


def width_of(th):
    return np.minimum(1.5, 0.38 * r_of(th))


def piece(th0, th1, n=60000):
    """Backbone piece with numerically differentiated outward normals."""
    th = np.linspace(th0, th1, n)
    p = np.stack([r_of(th) * np.cos(th), r_of(th) * np.sin(th)], -1)
    t = np.gradient(p, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    nrm = np.stack([t[:, 1], -t[:, 0]], -1)
    if np.mean(np.sum(nrm * p, axis=1)) < 0:
        nrm = -nrm
    return th, p, t, nrm


def spec_geometry():
    k = math.radians(100.0)
    pa = piece(TH_S, k - 1e-9)
    pb = piece(k, TH_E)
    outer = [pp + (width_of(th) / 2)[:, None] * nn for th, pp, _, nn in (pa, pb)]
    inner = [pp - (width_of(th) / 2)[:, None] * nn for th, pp, _, nn in (pa, pb)]
    p0, t0 = pa[1][0], pa[2][0]
    n0 = np.array([t0[1], -t0[0]])
    q = np.linspace(0, 5, 5001)[:, None]
    outer.append(p0 + 0.75 * n0 - q * t0)
    inner.append(p0 - 0.75 * n0 - q * t0)
    return np.vstack(outer), np.vstack(inner), p0, t0, n0


GEOM = spec_geometry()
OUTER_TREE = cKDTree(GEOM[0])
INNER_TREE = cKDTree(GEOM[1])


def theta_spec(pts):
    """The angle of a point (spiral part; callers pass points in the spiral channel)."""
    pts = np.atleast_2d(pts)
    phi = np.arctan2(pts[:, 1], pts[:, 0])
    rad = np.hypot(pts[:, 0], pts[:, 1])
    best = np.full(len(pts), np.inf)
    th = np.zeros(len(pts))
    for k in range(5):
        cand = phi + 2 * math.pi * k
        ok = np.degrees(cand) > PHI0
        rr = np.full(len(pts), np.nan)
        rr[ok] = r_of(cand[ok])
        d = np.where(ok, np.abs(rr - rad), np.inf)
        better = d < best
        best[better], th[better] = d[better], cand[better]
    return th


def independent_truth(shape):
    s, pts, rho = shape["s"], shape["pts"], shape["rho"]
    rho0 = rho[0]
    outer, inner, p0, t0, _ = GEOM
    inside = (pts - p0) @ t0 > -5.0
    n_in = int(np.argmin(inside))
    P = pts[:n_in]
    gap = OUTER_TREE.query(P)[0] - rho[:n_in]
    # cap: 2-D distance from the hemispherical cap outline to the wall
    k0 = int(round(rho0 / (s[1] - s[0])))
    tt = pts[0] - pts[k0]
    tt /= np.linalg.norm(tt)
    nn = np.array([-tt[1], tt[0]])
    psi = np.linspace(-math.pi / 2, math.pi / 2, 721)
    cap = pts[k0] + rho0 * (np.cos(psi)[:, None] * tt + np.sin(psi)[:, None] * nn)
    cap_gap = OUTER_TREE.query(cap)[0].min()
    gap[:k0] = cap_gap
    th_tip = theta_spec(pts[0])[0]
    if gap[0] > TOL:
        return dict(theta_tip=th_tip, theta_bot=th_tip, in_contact=False, gap=gap, n_in=n_in, k_bot=0)
    k = int(np.nonzero(gap > TOL)[0][0])
    return dict(theta_tip=th_tip, theta_bot=theta_spec(pts[k - 1])[0], in_contact=True, gap=gap,
                n_in=n_in, k_bot=k - 1)


# ------------------------------------------------------------------------------------------------
# fixtures
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clean():
    return rc.render_frames(11, n_frames=6)


@pytest.fixture(scope="module")
def bubbly():
    return rc.render_frames(11, n_frames=6, nuisance={"bubbles": 1.0})


def lum(px):
    px = np.asarray(px, float)
    return 0.114 * px[..., 0] + 0.587 * px[..., 1] + 0.299 * px[..., 2]


def bilinear(img, x, y):
    return cv2.getRectSubPix(img.astype(np.float32), (1, 1), (float(x), float(y)))[0, 0]


# ------------------------------------------------------------------------------------------------
# geometry
# ------------------------------------------------------------------------------------------------
def test_phantom_matches_spec_and_independent_geometry():
    ph = rc.Phantom()
    assert abs(ph.r(math.radians(100.0) - 1e-12) - ph.r(math.radians(100.0))) < 1e-3
    assert abs(float(ph.r(math.radians(100.0))) - 3.298) < 1e-3
    assert abs(ph.width(np.array([TH_S]))[0] - 1.5) < 1e-12
    # every wall vertex of render_c lies on the independently built wall (cut/arc aside)
    d_out = OUTER_TREE.query(ph.outer_wall)[0]
    d_in = INNER_TREE.query(ph.inner_wall)[0]
    assert np.percentile(d_out, 99) < 1e-3 and d_out.max() < 0.02
    assert np.percentile(d_in, 99) < 1e-3
    # neighbouring turns keep a wall of at least 0.15 mm between them
    inner_turn = ph.outer_wall[ph.outer_par > TH_S + 2 * math.pi]
    outer_turn_inner = ph.inner_wall[ph.inner_par < TH_E - 2 * math.pi]
    assert cKDTree(outer_turn_inner).query(inner_turn)[0].min() >= 0.15 - 1e-3
    # the outer wall is cut at 100 deg where its pieces cross; the inner wall closes with an arc
    assert np.linalg.norm(ph.outer_cut_point - ph.point(math.radians(100))) > 0.6


def test_theta_of_point_spec():
    ph = rc.Phantom()
    th = np.linspace(TH_S + 1e-3, TH_E - 1e-3, 500)
    pts = ph.point(th)
    assert np.allclose(ph.theta_of_point(pts), th, atol=1e-9)
    p, _, n = ph.frame(th)
    off = p + (0.45 * ph.width(th))[:, None] * n  # points near the walls, same channel turn
    assert np.allclose(ph.theta_of_point(off), theta_spec(off), atol=1e-12)
    assert np.max(np.abs(ph.theta_of_point(off) - th)) < 0.5
    entry = ph.p0 - 3.0 * ph.T0
    assert ph.theta_of_point(entry) == pytest.approx(math.atan2(entry[1], entry[0]))


# ------------------------------------------------------------------------------------------------
# truth
# ------------------------------------------------------------------------------------------------
def test_truth_table_and_pose(clean):
    frames, truth, info = clean
    for col in ["frame", "time_s", "depth_mm", "theta_tip", "theta_bot", "theta_con", "in_contact"]:
        assert col in truth.columns
    assert truth["frame"].tolist() == list(range(6))
    assert truth["in_contact"].dtype == bool
    assert np.allclose(truth["time_s"], np.arange(6) / 30.0)
    assert np.allclose(truth["depth_mm"], np.linspace(2, 17, 6))
    pose = info["pose"]
    for k in ["centre_x_px", "centre_y_px", "px_per_mm", "rotation_rad", "mirrored"]:
        assert k in pose
    assert 15.0 <= pose["px_per_mm"] <= 40.0
    R = info["_renderer"]
    px = R.pose.to_px(R.ph.extent_points())
    assert px[:, 0].min() >= 0 and px[:, 0].max() <= 639 and px[:, 1].min() >= 0 and px[:, 1].max() <= 479
    # the pose maps o_c to the centre and a mirrored pose has a positive determinant (y flips)
    Am = np.array(pose["A_px_from_mm"])
    assert np.allclose(Am[:, 2], [pose["centre_x_px"], pose["centre_y_px"]])
    assert (np.linalg.det(Am[:, :2]) > 0) == pose["mirrored"]
    assert np.allclose(R.pose.to_mm(R.pose.to_px(np.array([[1.0, 2.0]]))), [[1.0, 2.0]])
    assert all(f.shape == (480, 640, 3) and f.dtype == np.uint8 for f in frames)


def test_pose_randomness():
    mirrors, scales = set(), []
    for seed in range(12):
        R = Renderer(seed, 1, (640, 480), None, 3.0, 30.0, (5.0, 5.0), None)
        mirrors.add(R.pose.mirrored)
        scales.append(R.pose.px_per_mm)
        px = R.pose.to_px(R.ph.extent_points())
        assert px.min() >= 0 and px[:, 0].max() <= 639 and px[:, 1].max() <= 479
    assert mirrors == {True, False}
    assert min(scales) >= 15.0 and max(scales) <= 40.0 and np.std(scales) > 0.5


@pytest.mark.parametrize("seed", [0, 3, 11, 27])
def test_truth_matches_independent_measurement(seed):
    R = Renderer(seed, 7, (640, 480), None, 3.0, 30.0, (2.0, 17.0), None)
    prev = -np.inf
    for sh, tr in zip(R.shapes, R.truths):
        ind = independent_truth(sh)
        assert tr["in_contact"] == ind["in_contact"]
        assert tr["theta_tip"] == pytest.approx(ind["theta_tip"], abs=1e-9)
        assert tr["theta_bot"] == pytest.approx(ind["theta_bot"], abs=0.01)
        assert tr["theta_con"] == pytest.approx(tr["theta_tip"] - tr["theta_bot"], abs=1e-12)
        assert tr["tip_gap_mm"] == pytest.approx(ind["gap"][0], abs=2e-3)
        g = ind["gap"]
        if ind["in_contact"]:
            assert np.all(g[: ind["k_bot"] + 1] <= TOL) and g[ind["k_bot"] + 1] > TOL
            assert tr["theta_con"] > 0
        else:
            assert tr["theta_con"] == 0.0 and tr["theta_bot"] == tr["theta_tip"]
        # the whole inserted array stays in the channel (walls minus its own radius)
        assert g.min() >= -1e-3
        gi = INNER_TREE.query(sh["pts"][: ind["n_in"]])[0] - sh["rho"][: ind["n_in"]]
        assert gi.min() >= -1e-3
        # the tip apex lies in the spiral channel
        th = theta_spec(sh["pts"][0])[0]
        assert TH_S < th < TH_E
        assert th > prev
        prev = th


def test_depth_is_arc_length_past_entry_end():
    R = Renderer(5, 4, (640, 480), None, 3.0, 30.0, (2.0, 17.0), None)
    _, _, p0, t0, _ = GEOM
    for D, sh in zip(R.depths, R.shapes):
        pts = sh["pts"]
        seg = np.hypot(*np.diff(pts, axis=0).T)
        assert seg.sum() == pytest.approx(26.0, abs=2e-3)
        u = (pts - p0) @ t0
        k = int(np.argmax(u < 0))  # first station behind the entry's end (from the apex)
        f = u[k - 1] / (u[k - 1] - u[k])
        depth = seg[: k - 1].sum() + f * seg[k - 1]
        assert depth == pytest.approx(D, abs=2e-3)
        # behind the entry's end the array lies on the insertion axis
        behind = pts[k + 5:]
        v = (behind - p0) @ np.array([-t0[1], t0[0]])
        assert np.abs(v).max() < 1e-3


def test_contact_grows_and_angles_consistent():
    for seed in range(6):
        R = Renderer(seed, 8, (640, 480), None, 3.0, 30.0, (2.0, 17.0), None)
        df = R.truth_frame()
        assert np.all(np.diff(df.theta_tip) > 0)
        assert np.all(df.theta_con >= 0)
        assert np.all(df.theta_bot <= df.theta_tip + 1e-12)
        assert not df.in_contact.iloc[0]  # 2 mm: the tip is still free
        assert df.in_contact.iloc[-1]     # 17 mm: riding the outer wall
        con = df.theta_con[df.in_contact].to_numpy()
        assert np.all(np.diff(con) > -0.05)


# ------------------------------------------------------------------------------------------------
# images
# ------------------------------------------------------------------------------------------------
def test_clean_render_tip_is_array_dark(clean):
    frames, truth, info = clean
    R = info["_renderer"]
    fluid = 255 * R.app["fluid_lum"]
    for i, (f, sh) in enumerate(zip(frames, R.shapes)):
        k = int(round(0.5 * R.model.rho0 / R.model.DS))  # half a tip radius behind the apex
        x, y = R.pose.to_px(sh["pts"][k])
        v = lum(bilinear(f, x, y))
        assert v < fluid - 25, (i, v, fluid)
        # free fluid ahead of the tip on the channel centreline is brighter
        sig = sh["meta"]["sig_a"] + 1.5
        q = R.ph.point(R.ph.theta_of_sigma(sig))
        xa, ya = R.pose.to_px(q)
        assert lum(bilinear(f, xa, ya)) > v + 25
        assert abs(truth.tip_x_px[i] - R.pose.to_px(sh["pts"][0])[0]) < 1e-9


def test_bubbles_drawn_where_reported(clean, bubbly):
    frames0, _, _ = clean
    frames1, truth, info = bubbly
    R = info["_renderer"]
    look = R.bub_look
    n_checked = 0
    for i, ex in enumerate(info["frames"]):
        bubs = ex["bubbles"]
        tips = [b for b in bubs if b["role"] == "tip"]
        assert len(tips) == 1  # strength >= 0.5: one bubble sits at the tip
        g = tips[0]["gap_to_array_mm"]
        assert g == pytest.approx(0.0, abs=0.01) or 0.1 - 0.01 <= g <= 1.0 + 0.01
        sh = R.shapes[i]
        for b in bubbs_in_view(bubs):
            c = np.array([b["x_mm"], b["y_mm"]])
            # inside the channel
            assert OUTER_TREE.query(c)[0] >= b["r_mm"] - 0.03 and INNER_TREE.query(c)[0] >= b["r_mm"] - 0.03
            # not overlapping the array
            assert np.min(np.hypot(*(sh["pts"] - c).T) - sh["rho_outline"]) - b["r_mm"] > -0.01
            if b["r_px"] < 5:
                continue
            inside = lum(bilinear(frames1[i], b["x_px"], b["y_px"])) - lum(bilinear(frames0[i], b["x_px"], b["y_px"]))
            assert inside > 8, (i, b, inside)
            rr = b["r_px"] * (1 - look["rim_frac"] / 2)
            ang = R.app["light_dir"] + math.pi  # away from the highlight
            xr, yr = b["x_px"] + rr * math.cos(ang), b["y_px"] + rr * math.sin(ang)
            rim = lum(bilinear(frames1[i], xr, yr)) - lum(bilinear(frames0[i], xr, yr))
            assert rim < -8, (i, b, rim)
            n_checked += 1
    assert n_checked >= 6


def bubbs_in_view(bubs):
    return [b for b in bubs if 0 <= b["x_px"] < 640 and 0 <= b["y_px"] < 480]


def test_tip_bubble_moves_with_tip(bubbly):
    _, truth, info = bubbly
    d = []
    for i, ex in enumerate(info["frames"]):
        tip = [b for b in ex["bubbles"] if b["role"] == "tip"][0]
        d.append(math.hypot(tip["x_px"] - truth.tip_x_px[i], tip["y_px"] - truth.tip_y_px[i]) / info["pose"]["px_per_mm"])
    assert max(d) < 3.0
    assert np.ptp(d) < 1.5


def test_determinism_and_seed_dependence():
    nz = {k: 0.7 for k in rc.NUISANCE_KEYS}
    f1, t1, i1 = rc.render_frames(42, n_frames=3, nuisance=nz)
    f2, t2, i2 = rc.render_frames(42, n_frames=3, nuisance=nz)
    f3, t3, _ = rc.render_frames(43, n_frames=3, nuisance=nz)
    assert all(np.array_equal(a, b) for a, b in zip(f1, f2))
    assert t1.equals(t2)
    assert i1["pose"] == i2["pose"]
    assert not np.array_equal(f1[1], f3[1])
    # nuisances do not change pose or truth
    _, t0, i0 = rc.render_frames(42, n_frames=3)
    assert t0[["theta_tip", "theta_bot", "theta_con"]].equals(t1[["theta_tip", "theta_bot", "theta_con"]])
    assert i0["pose"] == i1["pose"]


def test_nuisance_validation_and_defaults(clean):
    _, _, info = clean
    assert all(v == 0.0 for v in info["nuisance"].values())
    assert all(ex["bubbles"] == [] for ex in info["frames"])
    with pytest.raises(ValueError):
        rc.render_frames(1, n_frames=1, nuisance={"smoke": 1.0})
    with pytest.raises(ValueError):
        rc.render_frames(1, n_frames=1, nuisance={"noise": 1.5})


@pytest.mark.parametrize("level", [0.5, 1.0])
def test_all_nuisances_render(level, tmp_path):
    nz = {k: level for k in rc.NUISANCE_KEYS}
    out = tmp_path / "v.mp4"
    truth, info = rc.render_video(out, 7, n_frames=3, nuisance=nz)
    cap = cv2.VideoCapture(str(out))
    n = 0
    while True:
        ok, fr = cap.read()
        if not ok:
            break
        assert fr.shape == (480, 640, 3)
        n += 1
    assert n == 3
    assert len(truth) == 3 and info["nuisance"]["gripper"] == level
    assert info["frames"][0]["jpeg_quality"] == int(round(95 - 75 * level))
    assert info["doubled_walls"] is not None and 0.1 <= info["doubled_walls"]["parallax_mm"] <= 0.5
    assert "_renderer" not in info


def test_doubled_walls_draw_offset_copy(clean):
    frames0, _, info0 = clean
    frames1, _, info1 = rc.render_frames(11, n_frames=6, nuisance={"doubled_walls": 1.0})
    R = info1["_renderer"]
    off = np.array(info1["doubled_walls"]["offset_px"])
    diff = np.abs(frames1[0].astype(float) - frames0[0].astype(float)).sum(axis=2)
    assert diff.max() > 20
    # the changed pixels lie on the walls shifted by the parallax offset
    walls = np.vstack([R.pose.to_px(w) for w in R.ph.wall_polylines()])
    tree = cKDTree(walls + off)
    ys, xs = np.nonzero(diff > 20)
    d = tree.query(np.stack([xs, ys], -1))[0]
    assert np.percentile(d, 95) < np.linalg.norm(off) + 3.0

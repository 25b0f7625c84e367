"""The renderer: array poses, truth from geometry, frames and videos."""

import cv2
import numpy as np
import pytest

from vision.angles import outer_wall_gap
from vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM as P, CameraPose, point_angle
from vision.rendering import (
    Appearance,
    ArrayShape,
    ContactPolicy,
    Nuisance,
    Scene,
    VideoSpec,
    array_centreline,
    pose_at_depth,
    random_appearance,
    random_nuisance,
    random_pose,
    render_video,
)


def test_array_riding_the_outer_wall_reaches_spec_angle_at_15mm():
    """SPEC §2: riding the outer wall, theta_tip is about 3.8-4.0 rad at 15 mm depth."""
    state = pose_at_depth(15.0, ContactPolicy(theta_first=0.6, lag=0.0))
    assert state.depth_mm == pytest.approx(15.0, abs=1e-2)
    assert 3.8 <= state.truth.theta_tip <= 4.01


def test_array_has_its_length_and_stays_in_the_channel():
    rng = np.random.default_rng(1)
    for _ in range(10):
        tip = rng.uniform(2.0, 6.0)
        shape = ArrayShape(departure_rad=rng.uniform(0.3, 0.7), far_offset=rng.uniform(-0.8, 0.3))
        st = array_centreline(tip, tip - rng.uniform(0.2, 1.5), shape=shape)
        assert st.s_mm[-1] == pytest.approx(DEFAULT_ARRAY.length_mm, abs=0.1)
        inside = st.s_mm <= st.depth_mm
        gap_outer = outer_wall_gap(st.centreline_mm[inside], st.radius_mm[inside], P)
        assert gap_outer.min() > -0.01  # never through the outer wall
        theta = point_angle(st.centreline_mm[inside])
        d_inner, _, _ = P.inner_wall.project(st.centreline_mm[inside], theta)
        assert np.all(-d_inner - st.radius_mm[inside] > -0.01)  # nor through the inner wall


def test_truth_contact_run_follows_the_nominal_angles():
    for tip, bot in [(2.5, 1.8), (4.0, 2.5), (5.5, 3.0), (3.0, 3.0 - 1e-9)]:
        st = array_centreline(tip, bot)
        tr = st.truth
        assert tr.theta_tip == pytest.approx(tip, abs=0.02)
        # the smooth departure keeps the gap under tolerance a little basal of nominal
        assert bot - 0.3 < tr.theta_bot <= bot + 1e-6
        assert tr.theta_con == pytest.approx(tr.theta_tip - tr.theta_bot)


def test_no_contact_before_first_contact():
    policy = ContactPolicy(theta_first=1.8, approach_rad=0.6)
    st = pose_at_depth(2.0, policy)
    assert st.truth.theta_tip < 1.2
    assert st.truth.theta_con == 0.0 and st.truth.theta_bot == st.truth.theta_tip


def test_angles_grow_with_depth():
    policy = ContactPolicy(theta_first=1.3, lag=0.3)
    states = [pose_at_depth(d, policy) for d in np.linspace(1, 20, 12)]
    tips = [s.truth.theta_tip for s in states]
    cons = [s.truth.theta_con for s in states]
    assert np.all(np.diff(tips) > 0)
    assert cons[-1] > 1.0 and cons[0] == 0.0


def test_before_entry_the_tip_is_on_the_axis():
    st = pose_at_depth(-0.5)
    assert st.depth_mm == -0.5 and st.truth.theta_con == 0.0


def _clean_scene(pose, style="both"):
    return Scene(pose, 640, 480, Appearance(wall_style=style), Nuisance())


def test_frame_shows_the_array_dark_with_bright_bands():
    pose = CameraPose(330.0, 250.0, 0.4, 30.0, False)
    st = array_centreline(4.0, 2.6)
    img = cv2.cvtColor(_clean_scene(pose).render(st), cv2.COLOR_BGR2GRAY).astype(float)
    ap = Appearance()
    # midway between two bands near s = 0.85 mm is body; a band centre is bright
    s_body = DEFAULT_ARRAY.band_intervals()[0, 1] + 0.3
    s_band = DEFAULT_ARRAY.band_intervals()[2].mean()
    for s, level in [(s_body, ap.array_level), (s_band, ap.band_level)]:
        xy = pose.to_image(st.centreline_mm[np.argmin(np.abs(st.s_mm - s))])[0]
        assert img[int(round(xy[1])), int(round(xy[0]))] == pytest.approx(level, abs=3)


@pytest.mark.parametrize("style", ["lines", "region"])
def test_walls_appear_where_the_geometry_says(style):
    pose = CameraPose(320.0, 240.0, -1.0, 25.0, True)
    img = cv2.cvtColor(_clean_scene(pose, style).render(pose_at_depth(-1.0)), cv2.COLOR_BGR2GRAY)
    edges = cv2.Canny(img, 30, 90) > 0
    dist = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 5)
    wall = pose.to_image(P.outer_wall.points[::20])
    inside = (wall[:, 0] > 2) & (wall[:, 0] < 637) & (wall[:, 1] > 2) & (wall[:, 1] < 477)
    d = dist[np.round(wall[inside, 1]).astype(int), np.round(wall[inside, 0]).astype(int)]
    assert np.median(d) <= 1.5


def test_mirrored_pose_renders_the_flipped_image():
    st = array_centreline(3.5, 2.5)
    a = _clean_scene(CameraPose(320.0, 239.5, 0.0, 25.0, False)).render(st)
    b = _clean_scene(CameraPose(320.0, 239.5, 0.0, 25.0, True)).render(st)
    diff = np.abs(a.astype(int) - b[::-1].astype(int))
    assert np.mean(diff) < 1.0


def test_random_pose_keeps_the_channel_in_frame():
    rng = np.random.default_rng(5)
    from vision.geometry import channel_polygon

    for _ in range(30):
        w, h = (640, 480) if rng.random() < 0.5 else (1280, 720)
        pose = random_pose(rng, w, h)
        px = pose.to_image(channel_polygon())
        assert px.min() >= 0 and px[:, 0].max() < w and px[:, 1].max() < h
        assert 10 <= pose.px_per_mm <= 60


def test_nuisances_change_the_frame_but_keep_it_valid():
    rng = np.random.default_rng(2)
    pose = random_pose(rng)
    st = pose_at_depth(10.0)
    clean = Scene(pose, nuisance=Nuisance(), rng=np.random.default_rng(0)).render(st)
    noisy = Scene(pose, appearance=random_appearance(rng), nuisance=random_nuisance(rng, 1.0),
                  rng=np.random.default_rng(0)).render(st)
    assert clean.shape == noisy.shape == (480, 640, 3) and noisy.dtype == np.uint8
    assert np.mean(np.abs(clean.astype(int) - noisy.astype(int))) > 2


@pytest.mark.parametrize("target", ["video.mp4", "frames"])
def test_render_video_writes_frames_and_truth(tmp_path, target):
    pose = CameraPose(320.0, 240.0, 0.2, 22.0, False)
    spec = VideoSpec(pose=pose, fps=10.0, speed_mm_s=5.0, start_depth_mm=0.0, end_depth_mm=10.0)
    truth = render_video(tmp_path / target, spec, seed=3)
    assert len(truth) == 21
    np.testing.assert_allclose(truth.depth_mm, np.minimum(truth.time_s * 5.0, 10.0), atol=2e-3)
    assert truth.theta_tip.is_monotonic_increasing
    out = tmp_path / target
    if out.suffix == ".mp4":
        cap = cv2.VideoCapture(str(out))
        n = 0
        while cap.read()[0]:
            n += 1
        assert n == 21
    else:
        assert len(list(out.glob("*.png"))) == 21
    assert not list(tmp_path.glob(".*partial*"))  # nothing half-written left behind


def test_capped_video_keeps_frame_times_on_the_file_clock(tmp_path):
    pose = CameraPose(320.0, 240.0, 0.2, 22.0, False)
    spec = VideoSpec(pose=pose, fps=30.0, speed_mm_s=1.0, start_depth_mm=0.0, end_depth_mm=9.0, max_frames=10)
    truth = render_video(tmp_path / "v.mp4", spec)
    assert len(truth) == 10
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(1.0, rel=1e-3)
    np.testing.assert_allclose(truth.time_s, np.arange(10) / 1.0)

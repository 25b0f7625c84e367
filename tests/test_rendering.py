"""The renderer: array poses, truth from geometry, frames and videos."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from tympani.vision.angles import outer_wall_gap
from tympani.vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM as P, CameraPose, point_angle
from tympani.vision.rendering import (
    Appearance,
    ArrayShape,
    ContactPolicy,
    Nuisance,
    Scene,
    VideoSpec,
    array_centreline,
    channel_path,
    pose_at_depth,
    random_appearance,
    random_harsh_nuisance,
    random_nuisance,
    random_pose,
    render_video,
)


def test_array_riding_the_outer_wall_reaches_about_4_rad_at_15mm():
    """Riding the outer wall (docs/paper.md, TABLE III), theta_tip is about 3.8-4.0 rad at 15 mm depth."""
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
    pose = CameraPose(330.0, 250.0, 0.4, 30.0, mirrored=False)
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
    pose = CameraPose(320.0, 240.0, -1.0, 25.0, mirrored=True)
    img = cv2.cvtColor(_clean_scene(pose, style).render(pose_at_depth(-1.0)), cv2.COLOR_BGR2GRAY)
    edges = cv2.Canny(img, 30, 90) > 0
    dist = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 5)
    wall = pose.to_image(P.outer_wall.points[::20])
    inside = (wall[:, 0] > 2) & (wall[:, 0] < 637) & (wall[:, 1] > 2) & (wall[:, 1] < 477)
    d = dist[np.round(wall[inside, 1]).astype(int), np.round(wall[inside, 0]).astype(int)]
    assert np.median(d) <= 1.5


def test_mirrored_pose_renders_the_flipped_image():
    """A mirrored pose renders the upside-down image (measured: mean |difference| 0.026 grey
    levels)."""
    st = array_centreline(3.5, 2.5)
    a = _clean_scene(CameraPose(320.0, 239.5, 0.0, 25.0, mirrored=False)).render(st)
    b = _clean_scene(CameraPose(320.0, 239.5, 0.0, 25.0, mirrored=True)).render(st)
    diff = np.abs(a.astype(int) - b[::-1].astype(int))
    assert np.mean(diff) < 0.05


def test_random_pose_keeps_the_channel_in_frame():
    rng = np.random.default_rng(5)
    from tympani.vision.geometry import channel_polygon

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
    pose = CameraPose(320.0, 240.0, 0.2, 22.0, mirrored=False)
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
    pose = CameraPose(320.0, 240.0, 0.2, 22.0, mirrored=False)
    spec = VideoSpec(pose=pose, fps=30.0, speed_mm_s=1.0, start_depth_mm=0.0, end_depth_mm=9.0, max_frames=10)
    truth = render_video(tmp_path / "v.mp4", spec)
    assert len(truth) == 10
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(1.0, rel=1e-3)
    np.testing.assert_allclose(truth.time_s, np.arange(10) / 1.0)


# --------------------------------------------------------------------------- harsh nuisances
# Bubbles, doubled walls, glints, motion blur, shadows, a gripper over the array, heavy JPEG:
# each changes the frame where it should, never the truth, and is off by default.

HARSH_KINDS = dict(bubbles=5, bubble_at_tip=0.0, doubled_wall_mm=0.3, glints=1.0, plate_glints=3,
                   motion_blur_px=6.0, shadows=0.5, gripper_overlap_mm=3.0, distractors=2, jpeg_quality=18)
ZOOM = CameraPose(300.0, 250.0, 0.5, 30.0, mirrored=False)  # the spiral and the entry fill a 640x480 frame
SIDE = CameraPose(100.0, 250.0, 0.334, 14.0, mirrored=False)  # the channel and 30 mm of the axis (the gripper) in view


def _grey(bgr):
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(float)


def _render(nuisance, state, pose=ZOOM, time_s=0.0, appearance=Appearance(), seed=3):
    return _grey(Scene(pose, 640, 480, appearance, nuisance, rng=np.random.default_rng(seed)).render(state, time_s))


def _pixel(img, xy):
    return img[int(round(xy[1])), int(round(xy[0]))]


def test_harsh_nuisances_are_off_by_default_and_random_nuisance_draws_are_pinned():
    off = Nuisance(bubbles=0, bubble_at_tip=None, doubled_wall_mm=0.0, glints=0.0, plate_glints=0,
                   motion_blur_px=0.0, shadows=0.0, gripper_overlap_mm=0.0)
    assert off == Nuisance()
    st = pose_at_depth(9.0)
    scene = Scene(ZOOM, nuisance=Nuisance(distractors=2), rng=np.random.default_rng(0))
    np.testing.assert_array_equal(scene.render(st), scene.render(st, time_s=3.7))  # no time dependence
    # random_nuisance draws only the basic kinds, and exactly these values from a given seed
    rng = np.random.default_rng(0)
    assert random_nuisance(rng, 0.0) == Nuisance()
    assert random_nuisance(rng, 0.5) == Nuisance(noise_sigma=4.092404218303636, blur_sigma_px=0.4761700176614514,
                                                 illumination=0.10409735239361946, flicker=0.025, jpeg_quality=70,
                                                 distractors=2)
    assert random_nuisance(rng, 1.0) == Nuisance(noise_sigma=5.082638177642646, blur_sigma_px=1.3599526794002044,
                                                 illumination=0.3825511154555444, flicker=0.05, jpeg_quality=45,
                                                 distractors=4)
    # a scene without the harsh kinds draws no extra random numbers
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    Scene(ZOOM, nuisance=random_nuisance(np.random.default_rng(1), 0.8), rng=a).render(st)
    Scene(ZOOM, nuisance=random_nuisance(np.random.default_rng(1), 0.8), rng=b).render(st, time_s=1.0)
    assert a.random() == b.random()


def test_harsh_nuisances_never_change_the_truth(tmp_path):
    spec = VideoSpec(pose=ZOOM, fps=4.0, speed_mm_s=4.0, start_depth_mm=-0.5, end_depth_mm=4.0)
    clean = render_video(tmp_path / "clean", spec, seed=1)
    harsh = render_video(tmp_path / "harsh", replace(spec, nuisance=Nuisance(**HARSH_KINDS)), seed=1)
    cols = ["theta_tip", "theta_bot", "theta_con", "depth_mm", "tip_x_px", "tip_y_px", "bot_x_px", "bot_y_px"]
    np.testing.assert_array_equal(clean[cols].to_numpy(), harsh[cols].to_numpy())
    a, b = (_grey(cv2.imread(str(tmp_path / d / "frame_00003.png"))) for d in ("clean", "harsh"))
    assert np.mean(np.abs(a - b)) > 3


@pytest.mark.parametrize("gap_mm", [0.0, 0.5])
@pytest.mark.parametrize("depth_mm", [2.0, 9.0, 16.0])
def test_bubble_at_the_tip_is_drawn_touching_or_just_ahead_of_the_apex(gap_mm, depth_mm):
    st = pose_at_depth(depth_mm)
    ppm = ZOOM.px_per_mm
    nu = Nuisance(bubble_at_tip=gap_mm, bubble_radius_mm=0.5)
    scene = Scene(ZOOM, 640, 480, Appearance(), nu, rng=np.random.default_rng(3))
    with_bubble, without = _grey(scene.render(st)), _render(Nuisance(), st)
    centre, radius = scene.tip_bubble(st)
    apex = st.centreline_mm[0]
    # geometry: the bubble's edge is gap_mm from the apex, apical of it, inside the channel
    assert np.linalg.norm(centre - apex) - radius == pytest.approx(gap_mm, abs=1e-3)
    path = channel_path()
    (u_tip, _), (u_b, lat_b) = path.locate(apex), path.locate(centre)
    assert u_b > u_tip
    assert abs(lat_b) + radius <= path.half_width(u_b) + 1e-6
    # pixels: the changed pixels start at the apex (touching) or gap_mm ahead of it
    changed = np.abs(with_bubble - without) > 8
    ys, xs = np.nonzero(changed)
    apex_px, centre_px = ZOOM.to_image(apex)[0], ZOOM.to_image(centre)[0]
    nearest = np.min(np.hypot(xs - apex_px[0], ys - apex_px[1]))
    assert nearest == pytest.approx(gap_mm * ppm, abs=1.5)
    assert np.all(np.hypot(xs - centre_px[0], ys - centre_px[1]) <= radius * ppm + 1.5)  # only the disc
    # a bright inside and a dark rim facing the apex; the array itself is untouched
    fluid = Appearance().fluid
    assert _pixel(with_bubble, centre_px) > fluid + 10
    towards_apex = (apex_px - centre_px) / np.linalg.norm(apex_px - centre_px)
    assert _pixel(with_bubble, centre_px + (radius * ppm - 1.5) * towards_apex) < fluid - 20
    body, _ = scene.array_layers(st)
    assert np.all(with_bubble[body > 0.99] == without[body > 0.99])


def test_tip_bubble_moves_with_the_tip_and_needs_the_tip_in_the_channel():
    scene = Scene(ZOOM, 640, 480, Appearance(), Nuisance(bubble_at_tip=0.3), rng=np.random.default_rng(5))
    centres = [scene.tip_bubble(pose_at_depth(d))[0] for d in (4.0, 4.5, 5.0)]
    assert np.all(np.linalg.norm(np.diff(centres, axis=0), axis=1) == pytest.approx(0.5, abs=0.1))
    assert scene.tip_bubble(pose_at_depth(-7.0)) is None  # the tip is not in the phantom yet


def test_free_bubbles_drift_inside_the_channel_fluid():
    st = pose_at_depth(-40.0)  # the array far out of view
    nu = Nuisance(bubbles=6, bubble_drift_mm_s=0.3)
    scene = Scene(ZOOM, 640, 480, Appearance(wall_style="both"), nu, rng=np.random.default_rng(8))
    path = channel_path()
    before, after = scene.bubbles_at(st, 0.0), scene.bubbles_at(st, 5.0)
    moved = [np.linalg.norm(a[0] - b[0]) for a, b in zip(before, after)]
    assert len(before) == 6 and min(moved) > 0.3  # about 0.75–2.25 mm in 5 s along the channel
    for centre, radius, _ in before + after:
        u, lat = path.locate(centre)
        assert 0.15 - 1e-9 <= radius and abs(lat) + radius <= path.half_width(u) + 1e-6
    changed = np.abs(_grey(scene.render(st, 0.0)) - _grey(scene.render(st, 5.0))) > 3
    from tympani.vision.geometry import channel_polygon

    inside = np.zeros((480, 640), np.uint8)
    cv2.fillPoly(inside, [np.round(ZOOM.to_image(channel_polygon())).astype(np.int32)], 1)
    assert changed.any() and not (changed & (cv2.dilate(inside, np.ones((3, 3), np.uint8)) == 0)).any()


def test_doubled_walls_draw_a_second_line_at_the_parallax():
    ap = Appearance(wall_style="lines", background=185.0, fluid=185.0, wall_level=60.0)
    st = pose_at_depth(-40.0)
    single = _render(Nuisance(), st, appearance=ap)
    nu = Nuisance(doubled_wall_mm=0.3, doubled_wall_contrast=1.0, doubled_wall_direction_rad=0.0)
    scene = Scene(ZOOM, 640, 480, ap, nu, rng=np.random.default_rng(3))
    double = _grey(scene.render(st))
    shift = scene.wall_parallax_px
    np.testing.assert_allclose(shift, [0.3 * ZOOM.px_per_mm, 0.0])
    wall = ZOOM.to_image(P.outer_wall.points[::25])
    tangent = np.gradient(wall, axis=0)
    upright = np.abs(tangent[:, 0]) < 0.3 * np.linalg.norm(tangent, axis=1)  # the shift is across the wall
    moved = wall[upright] + shift
    clear = np.array([_pixel(single, p) > 180 for p in moved])  # no other wall there
    assert clear.sum() >= 10
    second = np.array([_pixel(double, p) for p in moved[clear]])
    first = np.array([_pixel(double, p) for p in wall[upright][clear]])
    assert np.median(second) < 110 and np.median(first) < 110  # both lines, as dark as a wall
    # a weaker second copy keeps the first as it was
    weak = _render(Nuisance(doubled_wall_mm=0.3, doubled_wall_contrast=0.4, doubled_wall_direction_rad=0.0), st,
                   appearance=ap)
    assert np.median([_pixel(weak, p) for p in moved[clear]]) > np.median(second) + 20


def test_doubled_region_walls_show_a_step_between_the_edges():
    ap = Appearance(wall_style="region", background=150.0, fluid=210.0)
    st = pose_at_depth(-40.0)
    nu = Nuisance(doubled_wall_mm=0.4, doubled_wall_contrast=1.0, doubled_wall_direction_rad=np.pi / 2)
    img = _render(nu, st, appearance=ap)
    levels = np.unique(np.round(img[img.shape[0] // 2 - 200 : img.shape[0] // 2 + 200]))
    assert np.any((levels > 165) & (levels < 195))  # the strip between a wall's two edges


def test_glints_flicker_on_the_bands_and_stay_near_them():
    st = pose_at_depth(10.0)
    scene = Scene(ZOOM, 640, 480, Appearance(band_level=170.0), Nuisance(glints=1.0), rng=np.random.default_rng(2))
    clean = _render(Nuisance(), st, appearance=Appearance(band_level=170.0))
    frames = [_grey(scene.render(st, t)) for t in np.arange(6) / 30.0]
    _, bands = scene.array_layers(st)
    near_bands = cv2.dilate((bands > 0).astype(np.uint8), np.ones((61, 61), np.uint8)) > 0  # the bloom: ~1 mm
    for f in frames:
        diff = f - clean
        assert diff.min() >= 0 and not (diff[~near_bands] > 1).any()  # only brightens, only at the bands
    assert max((f - clean)[bands > 0.99].max() for f in frames) > 60
    assert any(np.abs(frames[i + 1] - frames[i]).max() > 20 for i in range(5))  # flickers frame to frame
    np.testing.assert_array_equal(_grey(scene.render(st, 0.1)), _grey(scene.render(st, 0.1)))


def test_plate_glints_are_static_bright_spots():
    st = pose_at_depth(10.0)
    scene = Scene(ZOOM, 640, 480, Appearance(), Nuisance(plate_glints=3), rng=np.random.default_rng(6))
    clean = _render(Nuisance(), st)
    a, b = _grey(scene.render(st, 0.0)), _grey(scene.render(st, 2.0))
    np.testing.assert_array_equal(a, b)
    assert (a - clean).min() >= 0 and (a - clean).max() > 30


def test_motion_blur_smears_the_array_along_itself_only():
    st = pose_at_depth(10.0)
    length = 8.0
    clean, blurred = _render(Nuisance(), st), _render(Nuisance(motion_blur_px=length), st)
    body, bands = Scene(ZOOM, 640, 480).array_layers(st)
    near = cv2.dilate((body > 0).astype(np.uint8), np.ones((13, 13), np.uint8)) > 0
    assert np.array_equal(clean[~near], blurred[~near])  # the phantom does not move
    assert np.abs(clean - blurred)[near].max() > 40
    # along the centreline the band edges are ramps about ``length`` px long
    s = np.linspace(2.0, 6.0, 400)
    line = ZOOM.to_image(np.stack([np.interp(s, st.s_mm, st.centreline_mm[:, k]) for k in range(2)], axis=1))
    prof_clean = np.array([_pixel(clean, p) for p in line])
    prof_blur = np.array([_pixel(blurred, p) for p in line])
    step_px = np.median(np.hypot(*np.diff(line, axis=0).T))
    assert np.abs(np.diff(prof_blur)).max() / step_px < 0.4 * np.abs(np.diff(prof_clean)).max() / step_px
    assert prof_blur.mean() == pytest.approx(prof_clean.mean(), abs=6)  # smeared, not lost
    # the tip is smeared ahead of the apex by about half the length
    apex = ZOOM.to_image(st.centreline_mm[0])[0]
    ahead = (apex - ZOOM.to_image(st.centreline_mm[5])[0])
    ahead /= np.linalg.norm(ahead)
    assert _pixel(blurred, apex + 2.0 * ahead) < _pixel(clean, apex + 2.0 * ahead) - 10


def test_shadows_only_darken_and_the_gripper_casts_one():
    st = pose_at_depth(8.0)
    pose = SIDE
    clean = _render(Nuisance(distractors=1), st, pose=pose)
    shaded = _render(Nuisance(distractors=1, shadows=0.6), st, pose=pose)
    assert (shaded <= clean + 1e-9).all() and clean.mean() - shaded.mean() > 5
    # the gripper's own shadow: darker pixels right next to the jaw, where nothing else is
    scene = Scene(pose, 640, 480, Appearance(), Nuisance(distractors=1, shadows=0.6), rng=np.random.default_rng(3))
    jaw = scene._gripper(st)[0]
    mask = np.zeros((480, 640), np.uint8)
    cv2.fillPoly(mask, [np.round(jaw + scene._grip_shadow_px).astype(np.int32)], 1)
    cv2.fillPoly(mask, [np.round(jaw).astype(np.int32)], 0)
    no_field = Scene(pose, 640, 480, Appearance(), Nuisance(distractors=1), rng=np.random.default_rng(3))
    ratio = _grey(scene.render(st))[mask > 0] / np.maximum(_grey(no_field.render(st))[mask > 0], 1)
    assert np.median(ratio / (scene.gain[mask > 0])) < 0.8


@pytest.mark.parametrize("direction_rad", [0.0, 2.0])
def test_the_array_casts_its_own_shadow_beside_it(direction_rad):
    """The array's shadow: the fluid one shadow offset beside the array's body (and not under
    it, where the array is drawn) is darkened by up to the shadow's darkness (its edges are
    softened by a third of the offset); off by default."""
    st = pose_at_depth(12.0)
    light = replace(Appearance(), array_level=0.8 * Appearance().fluid)
    nu = Nuisance(array_shadow=0.4, array_shadow_mm=0.5, array_shadow_direction_rad=direction_rad)
    scene = Scene(ZOOM, 640, 480, light, nu, rng=np.random.default_rng(3))
    plain = _render(Nuisance(), st, appearance=light)
    shaded = _grey(scene.render(st))
    body, bands = scene.array_layers(st)
    offset = np.round(scene._array_shadow_px).astype(int)
    np.testing.assert_allclose(scene._array_shadow_px, 0.5 * ZOOM.px_per_mm * np.array(
        [np.cos(direction_rad), np.sin(direction_rad)]))
    # cores of the body moved by the offset that lie in open fluid (no array, no wall line)
    core = cv2.erode((body > 0.99).astype(np.uint8), np.ones((5, 5), np.uint8))
    moved = np.roll(core, (offset[1], offset[0]), axis=(0, 1)) > 0
    far = cv2.dilate((body > 0).astype(np.uint8), np.ones((7, 7), np.uint8)) == 0
    fluid = moved & far & (np.abs(plain - light.fluid) < 2)
    assert fluid.sum() > 200
    ratio = shaded[fluid] / plain[fluid]  # 1 - 0.4 x the softened coverage: 0.63 along the middle
    assert ratio.min() >= 0.59 and 0.6 <= np.median(ratio) <= 0.66, (ratio.min(), np.median(ratio))
    inside = core > 0
    assert np.median(np.abs(shaded[inside] - plain[inside])) < 1.0  # the array is drawn over its shadow
    assert Nuisance().array_shadow == 0.0 and np.array_equal(plain, _render(Nuisance(), st, appearance=light))


@pytest.mark.parametrize("depth_mm", [4.0, 15.0])
def test_gripper_hides_part_of_the_straight_array_outside_the_entry(depth_mm):
    pose = SIDE
    st = pose_at_depth(depth_mm)
    img = _render(Nuisance(distractors=1, gripper_overlap_mm=4.0), st, pose=pose)
    grip_level, array_level = 50.0, Appearance().array_level

    def level_at(s_mm):
        return _pixel(img, pose.to_image(st.centreline_mm[np.argmin(np.abs(st.s_mm - s_mm))])[0])

    length = DEFAULT_ARRAY.length_mm
    assert level_at(length - 3.0) == pytest.approx(grip_level, abs=3)  # under the jaw
    assert level_at(length - 5.0) == pytest.approx(array_level, abs=3)  # in view
    # however far it reaches, the jaw stops short of the entry channel
    far = _render(Nuisance(distractors=1, gripper_overlap_mm=30.0), st, pose=pose)
    entry_back = P.entry_length_mm + st.depth_mm  # arc length (mm) of the entry's basal end
    for s in (st.depth_mm + 1.0, entry_back - 0.1):
        xy = pose.to_image(st.centreline_mm[np.argmin(np.abs(st.s_mm - s))])[0]
        assert _pixel(far, xy) == pytest.approx(array_level, abs=3)
    assert _pixel(far, pose.to_image(st.centreline_mm[np.argmin(np.abs(st.s_mm - (entry_back + 1.0)))])[0]) \
        == pytest.approx(grip_level, abs=3)


def test_heavy_jpeg_compression_down_to_15():
    st = pose_at_depth(10.0)
    clean = _render(Nuisance(), st)
    for q in (20, 15):
        img = _render(Nuisance(jpeg_quality=q), st)
        assert 0.3 < np.mean(np.abs(img - clean)) < 10
    with pytest.raises(ValueError):
        Nuisance(jpeg_quality=0)


def test_harsh_scenes_are_deterministic_by_seed():
    st = pose_at_depth(7.0)

    def frames(seed):
        rng = np.random.default_rng(seed)
        pose = random_pose(rng)
        scene = Scene(pose, 640, 480, random_appearance(rng), random_harsh_nuisance(rng, 1.0), rng=rng)
        return [scene.render(st, t) for t in (0.0, 0.5, 1.0)]

    a, b, c = frames(11), frames(11), frames(12)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, z) for x, z in zip(a, c))


def test_random_harsh_nuisance_meets_every_kind():
    rng = np.random.default_rng(0)
    assert random_harsh_nuisance(rng, 0.0) == Nuisance()
    draws = [random_harsh_nuisance(rng, 1.0) for _ in range(40)]
    assert all(n.distractors >= 1 for n in draws)  # the gripper is always there
    assert any(n.bubbles > 0 for n in draws)
    tips = [n.bubble_at_tip for n in draws]
    assert None in tips and 0.0 in tips and any(t is not None and 0.1 <= t <= 1.0 for t in tips)
    assert any(0.1 <= n.doubled_wall_mm <= 0.5 for n in draws) and any(n.doubled_wall_mm == 0 for n in draws)
    for name in ("glints", "plate_glints", "motion_blur_px", "shadows", "gripper_overlap_mm"):
        assert any(getattr(n, name) > 0 for n in draws), name
    assert any(n.array_shadow > 0 for n in draws) and any(n.array_shadow == 0 for n in draws)
    assert min(n.jpeg_quality for n in draws if n.jpeg_quality) <= 20
    mild = [random_harsh_nuisance(rng, 0.3) for _ in range(20)]
    assert np.mean([n.motion_blur_px for n in mild]) < np.mean([n.motion_blur_px for n in draws])


def test_harsh_frames_at_random_poses_and_scales_are_valid():
    rng = np.random.default_rng(21)
    for k in range(6):
        w, h = (640, 480) if k % 2 else (800, 600)
        pose = random_pose(rng, w, h)
        scene = Scene(pose, w, h, random_appearance(rng), random_harsh_nuisance(rng, float(rng.uniform(0.2, 1.0))),
                      rng=rng)
        for depth in (-3.0, 0.5, float(rng.uniform(2.0, 24.0))):
            frame = scene.render(pose_at_depth(depth), time_s=float(rng.uniform(0, 10)))
            assert frame.shape == (h, w, 3) and frame.dtype == np.uint8

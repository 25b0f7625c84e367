"""Tests of vision.registration against exact synthetic truth.

Frames come from our renderer (random poses incl. mirror, scales 15–60 px/mm, random
appearance incl. all three wall styles, nuisances) and, so as not to overfit it, from
drawings made here with OpenCV in other styles. Figures quoted in the docstrings were
measured with these seeds (CPU time on one core, 640x480 unless stated).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from tympani.vision.greyscale import to_gray
from tympani.vision.geometry import DEFAULT_PHANTOM, CameraPose, backbone_frame, channel_polygon, entry_frame, entry_walls
from tympani.vision.registration import (
    Registration,
    RegistrationConfig,
    RegistrationError,
    check,
    combine_frames,
    register,
    search_range,
    wall_fit,
    wall_model,
)
from tympani.vision.rendering import Appearance, Scene, pose_at_depth, random_appearance, random_nuisance, random_pose

POSE_KEYS = {"centre_x_px", "centre_y_px", "rotation_rad", "px_per_mm", "mirrored", "residual_px"}


def _errors(found: CameraPose, truth: CameraPose) -> tuple[float, float, float]:
    """Centre error (px), relative scale error (%), rotation error (deg)."""
    centre = math.hypot(found.centre_x_px - truth.centre_x_px, found.centre_y_px - truth.centre_y_px)
    scale = 100.0 * abs(found.px_per_mm / truth.px_per_mm - 1.0)
    rot = abs((found.rotation_rad - truth.rotation_rad + math.pi) % (2 * math.pi) - math.pi)
    return centre, scale, math.degrees(rot)


def _render(rng: np.random.Generator, strength: float, width: int = 640, height: int = 480):
    """A random view: (true pose, BGR frame, wall style)."""
    pose = random_pose(rng, width, height)
    appearance = random_appearance(rng)
    nuisance = random_nuisance(rng, strength)
    scene = Scene(pose, width, height, appearance, nuisance, rng=rng)
    frame = scene.render(pose_at_depth(float(rng.uniform(-1.0, 15.0))))
    return pose, frame, appearance.wall_style


def _register_timed(frames) -> tuple[Registration, float]:
    t0 = time.process_time()
    reg = register(frames)
    return reg, time.process_time() - t0


# --------------------------------------------------------------------------- renderer frames


@pytest.fixture(scope="module")
def clean_runs():
    """20 clean random views (seed 101): (truth, registration, CPU seconds, style)."""
    rng = np.random.default_rng(101)
    runs = []
    for _ in range(20):
        pose, frame, style = _render(rng, 0.0)
        reg, dt = _register_timed([to_gray(frame)])
        runs.append((pose, reg, dt, style))
    return runs


def test_clean_frames_centre_within_1px_scale_1pct_rotation_half_degree(clean_runs):
    """20 clean views, all wall styles, both mirrors, 16–47 px/mm (what fits 640x480).

    Measured: centre error median 0.013 px, max 0.03 px; scale error median 0.02 %, max
    0.09 %; rotation error max 0.03°; mirror always right.
    """
    errs = np.array([_errors(reg.pose, truth) for truth, reg, _, _ in clean_runs])
    assert all(reg.pose.mirrored == truth.mirrored for truth, reg, _, _ in clean_runs)
    assert errs[:, 0].max() <= 1.0, errs[:, 0]
    assert errs[:, 1].max() <= 1.0, errs[:, 1]
    assert errs[:, 2].max() <= 0.5, errs[:, 2]
    assert {style for *_, style in clean_runs} == {"lines", "region", "both"}
    assert {truth.mirrored for truth, *_ in clean_runs} == {False, True}
    for _, reg, _, _ in clean_runs:
        assert reg.inlier_fraction > 0.9 and reg.residual_px < 1.0


def test_frames_with_nuisances_centre_within_2px_scale_2pct_mirror_right():
    """10 views with random_nuisance(0.5–1.0): noise, blur, uneven light, flicker, JPEG,
    screws, rulers, gripper.

    A registration must be right or refused: returning a wrong pose is never allowed, and
    at most one in ten may be refused (the renderer can saturate the phantom to white under
    strong illumination, which leaves no walls to see). Measured: all 10 registered; centre
    error median 0.03 px, max 0.06 px; scale error median 0.02 %, max 0.23 %; rotation max
    0.02°. (Over 60 further views at full strength 1.0, all registered: centre error under
    0.25 px, scale error under 0.75 %, rotation under 0.16°. With the brightest fluid under
    strong illumination, parts of the phantom clip to white: 2 of 8 such frames were
    refused in a trial, none answered wrongly.)
    """
    rng = np.random.default_rng(202)
    errs, refused = [], 0
    for _ in range(10):
        pose, frame, _ = _render(rng, float(rng.uniform(0.5, 1.0)))
        try:
            reg = register([to_gray(frame)])
        except RegistrationError:
            refused += 1
            continue
        assert reg.pose.mirrored == pose.mirrored
        errs.append(_errors(reg.pose, pose))
    errs = np.array(errs)
    assert refused <= 1
    assert errs[:, 0].max() <= 2.0, errs[:, 0]
    assert errs[:, 1].max() <= 2.0, errs[:, 1]
    assert errs[:, 2].max() <= 1.0, errs[:, 2]


def test_large_frames_up_to_60_px_per_mm():
    """1280x960 views at 30–60 px/mm with moderate nuisances. Measured: centre error
    max 0.02 px, scale error max 0.10 %, about 0.38 s CPU each."""
    rng = np.random.default_rng(303)
    for _ in range(3):
        pose = random_pose(rng, 1280, 960, px_per_mm=(30.0, 60.0))
        scene = Scene(pose, 1280, 960, random_appearance(rng), random_nuisance(rng, 0.5), rng=rng)
        reg = register([scene.render(pose_at_depth(5.0))])
        centre, scale, rot = _errors(reg.pose, pose)
        assert reg.pose.mirrored == pose.mirrored
        assert centre <= 1.0 and scale <= 1.0 and rot <= 0.5


def test_zoomed_in_hd_frames_beyond_80_px_per_mm():
    """The phantom filling HD frames: the default scale range grows with the frame (80 px/mm
    per 640 px of its larger side), so 1920x1080 at 70 px/mm and 1920x1440 at 98 and 115 px/mm
    register. With the old fixed 10-80 px/mm the last two were refused ("no phantom found").
    Measured: centre error max 0.09 px, scale error max 0.07 %, rotation max 0.01 deg."""
    rng = np.random.default_rng(4)
    for w, h, s in ((1920, 1080, 70.0), (1920, 1440, 100.0), (1920, 1440, 115.0)):
        pose = random_pose(rng, w, h, px_per_mm=(s, s + 0.1))
        scene = Scene(pose, w, h, random_appearance(rng), random_nuisance(rng, 0.3), rng=rng)
        reg = register([scene.render(pose_at_depth(8.0))])
        centre, scale, rot = _errors(reg.pose, pose)
        assert reg.pose.mirrored == pose.mirrored
        assert centre <= 1.0 and scale <= 1.0 and rot <= 0.5


def test_search_range_follows_the_frame_and_is_named_when_nothing_is_found():
    auto = RegistrationConfig()
    assert search_range(auto, 640, 480) == (10.0, 80.0) == search_range(auto, 320, 240)
    assert search_range(auto, 1920, 1080) == (10.0, 240.0)
    assert search_range(RegistrationConfig(px_per_mm_range=(20.0, 50.0)), 1920, 1080) == (20.0, 50.0)
    rng = np.random.default_rng(5)
    pose = random_pose(rng, 640, 480, px_per_mm=(40.0, 40.1))
    frame = Scene(pose, 640, 480, random_appearance(rng), random_nuisance(rng, 0.0), rng=rng).render(pose_at_depth(5.0))
    with pytest.raises(RegistrationError, match="no phantom found at 10-20 px/mm"):
        register([frame], cfg=RegistrationConfig(px_per_mm_range=(10.0, 20.0)))


def test_channel_partly_out_of_frame():
    """The spiral may hang over the frame's edge (here 30–45 % of the walls out of view;
    with two thirds out it still registered in trials, below 30 % in view it is refused)."""
    rng = np.random.default_rng(404)
    cases = [
        CameraPose(50.0, 250.0, 2.6, 24.0, False),
        CameraPose(1180.0, 480.0, 0.4, 70.0, True),
    ]
    for pose, (w, h) in zip(cases, [(640, 480), (1280, 960)]):
        scene = Scene(pose, w, h, random_appearance(rng), random_nuisance(rng, 0.3), rng=rng)
        reg = register([scene.render(pose_at_depth(3.0))])
        assert 0.5 < reg.visible_fraction < 0.9
        centre, scale, rot = _errors(reg.pose, pose)
        assert reg.pose.mirrored == pose.mirrored
        assert centre <= 1.0 and scale <= 1.0 and rot <= 0.5


def test_array_deep_in_the_channel_is_not_taken_for_walls():
    """Single frames with the array 12–20 mm deep (as when a bumped camera is registered
    again mid-insertion). The array's two long edges can pass the lenient half-resolution
    fit in a wrong pose (scale about 14 % off); that pose must not be taken when full
    resolution does not confirm it. Seed 6, 30 views: none wrong, at most one refused."""
    rng = np.random.default_rng(6)
    wrong, refused = [], 0
    for i in range(30):
        pose = random_pose(rng, 640, 480, px_per_mm=(16.0, 40.0))
        appearance, nuisance = random_appearance(rng), random_nuisance(rng, float(rng.uniform(0.0, 0.6)))
        scene = Scene(pose, 640, 480, appearance, nuisance, rng=rng)
        frame = to_gray(scene.render(pose_at_depth(float(rng.uniform(12.0, 20.0)))))
        try:
            reg = register([frame])
        except RegistrationError:
            refused += 1
            continue
        centre, scale, _ = _errors(reg.pose, pose)
        if centre > 2.0 or scale > 2.0 or reg.pose.mirrored != pose.mirrored:
            wrong.append((i, round(centre, 1), round(scale, 1)))
    assert wrong == []
    assert refused <= 1


def test_several_frames_are_combined():
    """First frames of an insertion (array moving, flicker, noise) register together."""
    rng = np.random.default_rng(505)
    pose = random_pose(rng)
    scene = Scene(pose, 640, 480, random_appearance(rng), random_nuisance(rng, 0.6), rng=rng)
    frames = [scene.render(pose_at_depth(d)) for d in (-1.0, 0.5, 2.0, 3.5, 5.0)]
    merged = combine_frames(frames)
    assert merged.shape == (480, 640) and merged.dtype == np.float32
    reg = register(frames)
    centre, scale, rot = _errors(reg.pose, pose)
    assert reg.pose.mirrored == pose.mirrored and centre <= 1.0 and scale <= 1.0 and rot <= 0.5


def test_grey_bgr_and_float_input_give_the_same_pose():
    rng = np.random.default_rng(606)
    pose, frame, _ = _render(rng, 0.2)
    grey = to_gray(frame)
    a = register([grey]).pose
    b = register(frame).pose  # one BGR frame, not in a list
    c = register([grey.astype(np.float32) / 255.0]).pose
    for other in (b, c):
        assert _errors(other, a)[0] < 0.05 and _errors(other, a)[1] < 0.05


# --------------------------------------------------------------------------- our own drawings


def _poly(pose: CameraPose, pts_mm: np.ndarray, shift: int = 4) -> np.ndarray:
    return np.round(pose.to_image(pts_mm) * (1 << shift)).astype(np.int32)


def _walls_mm() -> list[np.ndarray]:
    ph = DEFAULT_PHANTOM
    cap = np.stack([ph.inner_wall.points[-1], ph.outer_wall.points[-1]])
    return [*entry_walls(ph), ph.outer_wall.points[::5], ph.inner_wall.points[::5], cap]


def _array_mm(theta_tip: float = 5.0) -> np.ndarray:
    """A crude array: the backbone from theta_start to theta_tip plus 8 mm straight outside."""
    ph = DEFAULT_PHANTOM
    spiral, _, _ = backbone_frame(np.linspace(ph.theta_start, theta_tip, 200), ph)
    origin, x_w, _ = entry_frame(ph)
    outside = origin[None, :] - np.linspace(0.0, 13.0, 20)[::-1, None] * x_w[None, :]
    return np.vstack([outside, spiral])


def _drawing(style: str, pose: CameraPose, rng: np.random.Generator, w: int = 640, h: int = 480) -> np.ndarray:
    """A frame in a style our renderer does not make (OpenCV polygons and polylines)."""
    channel = [_poly(pose, channel_polygon(DEFAULT_PHANTOM))]
    walls = [_poly(pose, line) for line in _walls_mm()]
    array = [_poly(pose, _array_mm())]
    ppm = pose.px_per_mm
    if style == "bright channel on dark":
        img = np.full((h, w), 30, np.uint8)
        cv2.fillPoly(img, channel, 200, cv2.LINE_AA, 4)
        cv2.polylines(img, array, False, 90, max(1, int(0.9 * ppm)), cv2.LINE_AA, 4)
    elif style == "thick lines":
        img = np.full((h, w), 150, np.uint8)
        cv2.fillPoly(img, channel, 135, cv2.LINE_AA, 4)
        cv2.polylines(img, walls, False, 40, 5, cv2.LINE_AA, 4)
    elif style == "grid behind":
        img = np.full((h, w), 170, np.uint8)
        for k in range(0, w, 23):
            cv2.line(img, (k, 0), (k, h), 120, 1, cv2.LINE_AA)
        for k in range(0, h, 23):
            cv2.line(img, (0, k), (w, k), 120, 1, cv2.LINE_AA)
        cv2.fillPoly(img, channel, 215, cv2.LINE_AA, 4)
        cv2.polylines(img, walls, False, 60, 2, cv2.LINE_AA, 4)
        cv2.polylines(img, array, False, 25, max(1, int(0.9 * ppm)), cv2.LINE_AA, 4)
    elif style == "bright lines, shading, noise":
        img = np.full((h, w), 90, np.uint8)
        cv2.polylines(img, walls, False, 230, 2, cv2.LINE_AA, 4)
        shade = (0.6 + 0.8 * np.arange(w) / w)[None, :]
        noisy = cv2.GaussianBlur(img.astype(np.float32) * shade, (0, 0), 1.0) + rng.normal(0, 6, (h, w))
        img = np.clip(noisy, 0, 255).astype(np.uint8)
    else:
        raise ValueError(style)
    return img


OWN_STYLES = ["bright channel on dark", "thick lines", "grid behind", "bright lines, shading, noise"]


@pytest.mark.parametrize("style", OWN_STYLES)
def test_own_drawings_in_other_styles(style):
    """Not our renderer: filled polygons, 5 px lines, a grid over everything, bright lines
    under a light ramp with noise. Measured: centre error max 0.07 px, scale error max
    0.34 %, rotation max 0.06°."""
    rng = np.random.default_rng(OWN_STYLES.index(style) + 1000)
    for mirrored in (False, True):
        pose = CameraPose(
            float(rng.uniform(260, 380)),
            float(rng.uniform(200, 280)),
            float(rng.uniform(-math.pi, math.pi)),
            float(rng.uniform(16, 28)),
            mirrored,
        )
        reg = register([_drawing(style, pose, rng)])
        centre, scale, rot = _errors(reg.pose, pose)
        assert reg.pose.mirrored == mirrored
        assert centre <= 1.0 and scale <= 1.0 and rot <= 0.5, (centre, scale, rot)


# --------------------------------------------------------------------------- no phantom


def _no_phantom_frames() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(707)
    h, w = 480, 640
    frames = {
        "blank": np.full((h, w), 128, np.uint8),
        "noise": np.clip(rng.normal(128, 30, (h, w)), 0, 255).astype(np.uint8),
    }
    clutter = np.full((h, w), 190, np.uint8)
    for k in range(0, w, 25):
        cv2.line(clutter, (k, 0), (k, h), 150, 1)
    for _ in range(12):
        centre = tuple(int(v) for v in rng.uniform([0, 0], [w, h]))
        cv2.circle(clutter, centre, int(rng.uniform(10, 40)), int(rng.uniform(30, 120)), -1)
    for _ in range(3):
        p = rng.uniform([0, 0], [w, h], (2, 2)).astype(int)
        cv2.line(clutter, tuple(p[0]), tuple(p[1]), 235, 30)
    frames["grid, discs and strips"] = clutter
    rings = np.full((h, w), 200, np.uint8)
    for r in range(20, 230, 18):
        cv2.circle(rings, (320, 240), r, 60, 2)
    frames["concentric rings"] = rings
    off = CameraPose(5000.0, 5000.0, 0.0, 30.0, False)  # the renderer's clutter, phantom far away
    scene = Scene(off, w, h, random_appearance(rng), random_nuisance(rng, 1.0), rng=rng)
    frames["renderer clutter only"] = scene.render(pose_at_depth(5.0))
    return frames


@pytest.mark.parametrize("name", list(_no_phantom_frames()))
def test_frames_without_a_phantom_raise(name):
    frame = _no_phantom_frames()[name]
    with pytest.raises(RegistrationError, match="no phantom found"):
        register([frame])


# --------------------------------------------------------------------------- check, JSON


def test_check_flags_a_bumped_camera():
    """Measured (region walls, 37 px/mm): residual 0.45 px at registration
    and on a later frame of the same view; 3.0 px after a 5 px shift, 3.9 px after an 8 px
    shift, 5 px (the cap) after a 3° turn about the spiral centre (which the self-similar
    spiral alone would hide: the entry and first half-turn give it away). Over 12 whole
    rendered insertions (nuisances 0.5–1.0) good frames stayed at or below 0.69 px, while a
    3 px shift gave at least 1.07 px, a 5 px shift 2.3 px and a 1° turn 1.9 px."""
    rng = np.random.default_rng(808)
    pose = random_pose(rng)
    appearance, nuisance = random_appearance(rng), random_nuisance(rng, 0.5)
    scene = Scene(pose, 640, 480, appearance, nuisance, rng=rng)
    reg = register([scene.render(pose_at_depth(d)) for d in (-1.0, 0.0, 1.0)])
    later = scene.render(pose_at_depth(9.0))
    same = check(later, reg)
    assert same <= max(1.0, 2.0 * reg.residual_px)
    for dx, dy, dr in [(5.0, 0.0, 0.0), (0.0, -8.0, 0.0), (0.0, 0.0, math.radians(3.0))]:
        bumped = CameraPose(
            pose.centre_x_px + dx, pose.centre_y_px + dy, pose.rotation_rad + dr, pose.px_per_mm, pose.mirrored
        )
        frame = Scene(bumped, 640, 480, appearance, nuisance, rng=rng).render(pose_at_depth(9.0))
        moved = check(frame, reg)
        assert moved > max(2.0, 3.0 * same), (dx, dy, dr, moved, same)
    gone = CameraPose(5000.0, 5000.0, 0.0, pose.px_per_mm, False)
    assert check(later, Registration(gone, residual_px=0.0)) == float("inf")


def test_registration_to_dict_has_the_pose_keys_and_round_trips():
    rng = np.random.default_rng(909)
    pose, frame, _ = _render(rng, 0.3)
    reg = register([frame])
    d = reg.to_dict()
    assert POSE_KEYS <= set(d)
    json.dumps(d)  # JSON-ready
    back = Registration.from_dict(json.loads(json.dumps(d)))
    numbers = (float(d[k]) for k in ("centre_x_px", "centre_y_px", "rotation_rad", "px_per_mm"))
    assert back.pose == CameraPose(*numbers, d["mirrored"])
    assert back.residual_px == pytest.approx(reg.residual_px)
    assert back.line_half_width_px == pytest.approx(reg.line_half_width_px)
    moved = Registration.from_dict({**d, "line_offset_px": 1.5})
    assert moved.line_offset_px == 1.5 and moved.to_dict()["line_offset_px"] == 1.5
    fringed = Registration.from_dict({**d, "wall_fringe_px": -3.5})
    assert fringed.fringe_px == -3.5 and fringed.to_dict()["wall_fringe_px"] == -3.5
    minimal = Registration.from_dict({k: d[k] for k in POSE_KEYS})
    assert minimal.pose == back.pose and minimal.line_offset_px == 0.0 and minimal.fringe_px == 0.0
    # as the registration JSON has it: NaN written null
    from tympani.pipeline.io import to_jsonable

    unknown = {**d, "array_axis_offset_px": float("nan"), "second_copy_contrast": float("nan")}
    read = Registration.from_dict(json.loads(json.dumps(to_jsonable(unknown), allow_nan=False)))
    assert math.isnan(read.array_axis_offset_px) and math.isnan(read.second_copy_contrast)
    assert read.pose == back.pose
    # the pose keys alone are enough to check a frame (without the line half width, the walls'
    # edges are expected on the walls themselves, so the residual grows by about it)
    assert check(frame, minimal) < reg.residual_px + abs(reg.line_half_width_px) + 0.5
    assert wall_fit(frame, back).inlier_fraction > 0.8


def test_config_is_validated():
    with pytest.raises(ValueError):
        RegistrationConfig(px_per_mm_range=(50.0, 10.0))
    with pytest.raises(ValueError):
        RegistrationConfig(combine="max")
    with pytest.raises(ValueError):
        RegistrationConfig(edge_sigma_px=0.0)


def test_wall_model_normals_point_out_of_the_channel():
    from matplotlib.path import Path

    model = wall_model(DEFAULT_PHANTOM, spacing_mm=0.05)
    channel = Path(channel_polygon(DEFAULT_PHANTOM))
    assert not channel.contains_points(model.points + 0.01 * model.normals).any()
    assert channel.contains_points(model.points - 0.01 * model.normals).all()
    assert np.allclose(np.linalg.norm(model.normals, axis=1), 1.0)
    lengths = np.bincount(model.group) * model.spacing_mm
    assert lengths[0] == pytest.approx(10.0, abs=0.2)  # the two 5 mm entry walls
    assert model.length_mm == pytest.approx(74.2, abs=0.5)


def test_doubled_walls_register_on_the_stronger_copy_and_say_so():
    """12 views whose walls show twice (second copy 0.15–0.45 mm away in a random direction, at
    30–90 % of the first's contrast; all wall styles, both mirrors, mild nuisances, three frames
    each): the pose is that of the stronger copy, without a scale bias, and the registration says
    the walls looked doubled and how far apart. Measured (seeds 700–711): centre error median
    0.05 px, max 0.32 px; scale error median 0.15 %, max 0.22 %; parallax within 0.02 mm; every
    one flagged. Single walls (the clean views) are never flagged. The array's offset from the
    axis is that of the copy registered (it was the single fit's: 1.08 px where the pose gives
    2.99 px, seed 707)."""
    from tympani.vision.registration.axis import array_axis_offset
    from tympani.vision.registration.frames import combine_frames

    for seed in range(700, 712):
        rng = np.random.default_rng(seed)
        pose = random_pose(rng, 640, 480)
        appearance = random_appearance(rng)
        parallax_mm, contrast = float(rng.uniform(0.15, 0.45)), float(rng.uniform(0.3, 0.9))
        nuisance = replace(random_nuisance(rng, 0.3), doubled_wall_mm=parallax_mm, doubled_wall_contrast=contrast)
        scene = Scene(pose, 640, 480, appearance, nuisance, rng=rng)
        frames = [to_gray(scene.render(pose_at_depth(float(d)))) for d in rng.uniform(-1.0, 15.0, 3)]
        reg = register(frames)
        centre, scale, _ = _errors(reg.pose, pose)
        assert reg.pose.mirrored == pose.mirrored
        assert centre <= 0.65 and scale <= 0.45, (seed, centre, scale)
        assert reg.walls_doubled, seed
        shift = np.asarray(reg.parallax_px) - scene.wall_parallax_px
        assert np.hypot(*shift) / pose.px_per_mm <= 0.03, (seed, reg.parallax_px, scene.wall_parallax_px)
        assert reg.to_dict()["walls_doubled"] is True
        offset = array_axis_offset(combine_frames(frames, RegistrationConfig().combine), reg.pose, DEFAULT_PHANTOM)
        np.testing.assert_allclose(reg.array_axis_offset_px, offset, atol=1e-9, equal_nan=True)


def _bands_beside_the_edge(seed: int, doubled: bool) -> tuple[CameraPose, list[np.ndarray], Appearance]:
    """Three frames of walls drawn as a bright band 2-4 px wide just outside the channel's edge
    (the plate's cut face catching the light) over fluid brighter than the plate, at 18-40 px/mm;
    ``doubled``: shown twice, 0.3-0.5 mm apart at 20-40 % strength."""
    rng = np.random.default_rng(seed)
    pose = random_pose(rng, 640, 480, px_per_mm=(18.0, 40.0))
    background = float(rng.uniform(120, 190))
    fluid = background + float(rng.uniform(15, 40))
    appearance = Appearance(background=background, fluid=fluid, wall_style="both",
                            wall_level=min(255.0, fluid + float(rng.uniform(15, 40))),
                            wall_width_px=float(rng.uniform(2.0, 4.0)), array_level=float(rng.uniform(30, 80)),
                            wall_side="outside")
    parallax_mm, contrast = float(rng.uniform(0.3, 0.5)), float(rng.uniform(0.2, 0.4))
    nuisance = replace(random_nuisance(rng, 0.3), doubled_wall_mm=parallax_mm if doubled else 0.0,
                       doubled_wall_contrast=contrast)
    scene = Scene(pose, 640, 480, appearance, nuisance, rng=rng)
    return pose, [to_gray(scene.render(pose_at_depth(float(d)))) for d in rng.uniform(-1.0, 15.0, 3)], appearance


@pytest.mark.parametrize("doubled", [False, True])
def test_bright_bands_beside_the_channel_edge_register_without_a_scale_bias(doubled: bool):
    """Walls drawn as a bright band just outside the channel's edge, single or doubled, eight
    views each. Lines centred on the edge are 1-2 px off it here, and a fit that keeps them there
    settles up to 2.6 % off in scale (measured before the lines could lie off the edge, seeds 0-7:
    single, three of eight beyond 0.5 %, max 2.61 %; doubled, four, max 2.27 %). Measured now:
    single, centre error max 0.05 px, scale error max 0.14 %; doubled, 0.16 px and 0.29 %. Where
    the lines were fitted off the edge (single 7, doubled 5 of 8), the offset is the band's half
    width within 0.42 px, and later frames are checked against the lines where they lie."""
    for seed in range(8):
        pose, frames, appearance = _bands_beside_the_edge(seed, doubled)
        reg = register(frames)
        centre, scale, _ = _errors(reg.pose, pose)
        assert reg.pose.mirrored == pose.mirrored
        assert centre <= (0.25 if doubled else 0.15) and scale <= (0.4 if doubled else 0.25), (seed, centre, scale)
        if reg.line_offset_px != 0.0:
            assert abs(reg.line_offset_px - 0.5 * appearance.wall_width_px) <= 0.5, (seed, reg.line_offset_px)
            assert check(frames[1], reg) < check(frames[1], replace(reg, line_offset_px=0.0)), seed


def test_single_walls_are_not_taken_for_doubled(clean_runs):
    assert not any(reg.walls_doubled for _, reg, _, _ in clean_runs)


def _doubled_drawing(seed: int, opposite: bool) -> tuple[CameraPose, list[np.ndarray], np.ndarray]:
    """Three noisy frames of 2-px dark wall lines (OpenCV) with a second copy 0.10–0.15 mm
    away in a random direction at 50–90 % of their contrast, dark too or (``opposite``)
    bright; the copies' intensities add. Returns the true pose, the frames and the second
    copy's shift (px)."""
    rng = np.random.default_rng(seed)
    pose = random_pose(rng, 640, 480)
    parallax_mm, direction, contrast = rng.uniform(0.10, 0.15), rng.uniform(-np.pi, np.pi), rng.uniform(0.5, 0.9)
    shift = parallax_mm * pose.px_per_mm * np.array([math.cos(direction), math.sin(direction)])
    walls = [_poly(pose, line) for line in _walls_mm()]
    first, second = np.zeros((480, 640), np.float32), np.zeros((480, 640), np.float32)
    cv2.polylines(first, walls, False, 1.0, 2, cv2.LINE_AA, 4)
    cv2.polylines(second, [w + np.round(shift * 16).astype(np.int32) for w in walls], False, 1.0, 2, cv2.LINE_AA, 4)
    img = cv2.GaussianBlur(150.0 - 100.0 * first + (70.0 if opposite else -100.0) * contrast * second, (0, 0), 0.7)
    frames = [np.clip(img + rng.normal(0.0, 3.0, img.shape), 0, 255).astype(np.uint8) for _ in range(3)]
    return pose, frames, shift


def test_close_and_opposite_polarity_doubled_walls_keep_the_first_copy():
    """Copies 0.10–0.15 mm apart (2.5–6.5 px at 17–45 px/mm, i.e. overlapping or just
    apart), eight views each. Alike (both dark): the pose is that of the stronger copy, and
    those found doubled have the parallax right. Measured (seeds 0–7): centre error max
    1.02 px (the two at 2.5 px, within the lines' width, are taken for one thicker line and
    not flagged: the pose lies between the copies), else at most 0.29 px; scale error max
    0.10 %; 6 of 8 flagged, parallax within 0.03 mm. Opposite polarity (a bright copy beside
    the dark line, which the two-copy model does not describe): the pose stays on the dark
    copy; centre error max 0.54 px, scale error max 0.10 %."""
    flagged = 0
    for seed in range(8):
        pose, frames, shift = _doubled_drawing(seed, opposite=False)
        reg = register(frames)
        centre, scale, _ = _errors(reg.pose, pose)
        assert centre <= 1.2 and scale <= 0.2, (seed, centre, scale)
        if reg.walls_doubled:
            flagged += 1
            found = np.asarray(reg.parallax_px)
            error = min(np.hypot(*(found - shift)), np.hypot(*(found + shift))) / pose.px_per_mm
            assert error <= 0.04, (seed, reg.parallax_px, shift)
    assert flagged >= 6
    for seed in range(8):
        pose, frames, _ = _doubled_drawing(seed, opposite=True)
        centre, scale, _ = _errors(register(frames).pose, pose)
        assert centre <= 0.7 and scale <= 0.2, (seed, centre, scale)


def _unlike_copies_drawing(seed: int) -> tuple[CameraPose, list[np.ndarray], np.ndarray]:
    """Three noisy frames whose walls show twice in two looks: the channel as a brighter region
    (a step at each wall) and, 0.15–0.3 mm away in a random direction, a thin line (dark or
    bright, at 40–70 % of the step's contrast) where the plate's other face shows the wall; or
    dark wall lines with a bright second copy. Returns the true pose (the first copy's), the
    frames and the second copy's shift (px)."""
    rng = np.random.default_rng(seed)
    pose = random_pose(rng, 640, 480, px_per_mm=(18.0, 40.0))
    parallax_mm, direction = rng.uniform(0.15, 0.3), rng.uniform(-np.pi, np.pi)
    shift = parallax_mm * pose.px_per_mm * np.array([math.cos(direction), math.sin(direction)])
    offset = np.round(shift * 16).astype(np.int32)
    walls = [_poly(pose, line) for line in _walls_mm()]
    first, second = np.zeros((480, 640), np.float32), np.zeros((480, 640), np.float32)
    contrast = rng.uniform(0.4, 0.7) * rng.choice([-1.0, 1.0])
    if seed % 2 == 0:
        cv2.fillPoly(first, [_poly(pose, channel_polygon(DEFAULT_PHANTOM))], 1.0, cv2.LINE_AA, 4)
        base = 90.0 + 60.0 * first
    else:
        cv2.polylines(first, walls, False, 1.0, 2, cv2.LINE_AA, 4)
        base, contrast = 150.0 - 70.0 * first, abs(contrast)
    cv2.polylines(second, [w + offset for w in walls], False, 1.0, 2, cv2.LINE_AA, 4)
    img = cv2.GaussianBlur(base + 60.0 * contrast * second, (0, 0), 0.7)
    frames = [np.clip(img + rng.normal(0.0, 3.0, img.shape), 0, 255).astype(np.uint8) for _ in range(3)]
    return pose, frames, shift


def test_doubled_walls_whose_copies_look_unlike_are_found():
    """A region step beside a thin line, or a dark line beside a bright one: the second copy has
    its own look (a single step, or a half width of its own sign). Eight views at 18–40 px/mm,
    copies 0.15–0.3 mm apart. Every one is flagged doubled and the pose lies on one of the
    copies (measured, seeds 0–7: within 0.27 px of the first; scale within 0.42 %). The
    parallax is right beside a region step (within 0.02 mm); beside a dark line, the bright
    copy's parallax is off by 0.01–0.13 mm (a known limit: the two lines' edges pair up
    wrongly). Before copies could differ in look, seeds 1 and 2 were not flagged and seed 2's
    pose sat on the line copy, 8.4 px off."""
    for seed in range(8):
        pose, frames, shift = _unlike_copies_drawing(seed)
        reg = register(frames)
        assert reg.walls_doubled, seed
        found = np.asarray(reg.parallax_px)
        error = min(np.hypot(*(found - shift)), np.hypot(*(found + shift))) / pose.px_per_mm
        assert error <= (0.03 if seed % 2 == 0 else 0.15), (seed, reg.parallax_px, shift)
        on_first = _errors(reg.pose, pose)[0]
        moved = CameraPose(pose.centre_x_px + shift[0], pose.centre_y_px + shift[1], pose.rotation_rad,
                           pose.px_per_mm, pose.mirrored)
        assert min(on_first, _errors(reg.pose, moved)[0]) <= 0.5, (seed, on_first)
        assert _errors(reg.pose, pose)[1] <= 0.5, seed


def test_doubled_walls_blurred_along_their_parallax_are_still_doubled():
    """Walls doubled 0.35-0.5 mm apart (8-12 px) and smeared by a motion blur of 3-5 px along the
    same direction: the walls along the shift are weaker than those across it, as for a single wall
    blurred into two ridges, but the background shows between the two lines (a blurred line is a
    plateau as dark between its ends as at them). Eight views: every one flagged doubled, the
    parallax within 0.05 mm and the pose on a copy within 1 px. Measured (seeds 0-7): parallax
    within 0.04 mm, pose within 0.55 px of the first copy, the level between the copies at most
    0.03 of the lines' (blurred single lines: 0.89-1.07). Before, five of the eight were called
    single walls blurred, four of them with the pose between the copies, 5 px from each. A blur as
    long as the copies are apart fills the gap between them: such walls stay single."""
    for seed in range(8):
        rng = np.random.default_rng(1200 + seed)
        pose = random_pose(rng, 640, 480, px_per_mm=(20.0, 28.0))
        parallax_mm, direction, contrast = rng.uniform(0.35, 0.5), rng.uniform(-np.pi, np.pi), rng.uniform(0.5, 0.9)
        unit = np.array([math.cos(direction), math.sin(direction)])
        shift = parallax_mm * pose.px_per_mm * unit
        walls = [_poly(pose, line) for line in _walls_mm()]
        first, second = np.zeros((480, 640), np.float32), np.zeros((480, 640), np.float32)
        cv2.polylines(first, walls, False, 1.0, 2, cv2.LINE_AA, 4)
        cv2.polylines(second, [w + np.round(shift * 16).astype(np.int32) for w in walls], False, 1.0, 2, cv2.LINE_AA, 4)
        length = float(rng.uniform(3.0, 5.0))
        kernel = np.zeros((17, 17), np.float32)
        cv2.line(kernel, tuple(np.round(8 - 0.5 * length * unit).astype(int)),
                 tuple(np.round(8 + 0.5 * length * unit).astype(int)), 1.0, 1)
        img = cv2.filter2D(150.0 - 100.0 * first - 100.0 * contrast * second, -1, kernel / kernel.sum())
        frames = [np.clip(img + rng.normal(0.0, 3.0, img.shape), 0, 255).astype(np.uint8) for _ in range(3)]
        reg = register(frames)
        assert reg.walls_doubled, seed
        found = np.asarray(reg.parallax_px)
        error = min(np.hypot(*(found - shift)), np.hypot(*(found + shift))) / pose.px_per_mm
        assert error <= 0.05, (seed, reg.parallax_px, shift)
        moved = CameraPose(pose.centre_x_px + shift[0], pose.centre_y_px + shift[1], pose.rotation_rad,
                           pose.px_per_mm, pose.mirrored)
        assert min(_errors(reg.pose, pose)[0], _errors(reg.pose, moved)[0]) <= 1.0, seed


def test_coarse_search_peaks_are_scikit_image_peaks():
    """The search's local maxima (OpenCV dilation, positive ones, at least ``radius`` apart in
    the max norm, strongest first) are those of scikit-image's ``peak_local_max``, the
    reference; the search keeps its own for speed (about 15 times cheaper a call)."""
    from skimage.feature import peak_local_max

    from tympani.vision.registration.coarse import _peaks

    rng = np.random.default_rng(11)
    for _ in range(200):
        h, w = rng.integers(20, 160, 2)
        score = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), rng.uniform(0.5, 4))
        score -= np.float32(rng.uniform(0.3, 0.6))
        n, radius = int(rng.integers(1, 12)), int(rng.integers(1, 6))
        reference = peak_local_max(score, min_distance=radius, threshold_abs=0, exclude_border=False, num_peaks=n,
                                   p_norm=np.inf)
        assert _peaks(score, n, radius) == [tuple(map(int, p)) for p in reference]


def _blurred_drawing(seed: int) -> tuple[CameraPose, list[np.ndarray], float]:
    """Three noisy frames of single 2-px dark wall lines (OpenCV), the whole frame smeared by a
    linear motion blur of 8–12 px in a random direction. Returns the true pose, the frames and
    the blur length (px)."""
    rng = np.random.default_rng(seed)
    pose = random_pose(rng, 640, 480, px_per_mm=(15.0, 20.0))
    length, direction = float(rng.uniform(8.0, 12.0)), float(rng.uniform(-np.pi, np.pi))
    walls = [_poly(pose, line) for line in _walls_mm()]
    lines = np.zeros((480, 640), np.float32)
    cv2.polylines(lines, walls, False, 1.0, 2, cv2.LINE_AA, 4)
    kernel = np.zeros((25, 25), np.float32)
    half = 0.5 * length * np.array([math.cos(direction), math.sin(direction)])
    cv2.line(kernel, tuple(np.round(12 - half).astype(int)), tuple(np.round(12 + half).astype(int)), 1.0, 1)
    img = cv2.filter2D(150.0 - 100.0 * lines, -1, kernel / kernel.sum())
    frames = [np.clip(img + rng.normal(0.0, 3.0, img.shape), 0, 255).astype(np.uint8) for _ in range(3)]
    return pose, frames, length


def test_motion_blur_is_not_taken_for_doubled_walls():
    """Walls smeared along one direction show two ridges, like two copies: they are single walls.
    Measured (seeds 800–811, 15–20 px/mm, blur 8–12 px): none flagged; centre error median
    0.9 px, max 3.2 px (the single fit itself is pulled along a blur this strong). Taken for two
    copies, every one was flagged and off by 2.1–4.8 px (median 3.4)."""
    centres = []
    for seed in range(800, 812):
        pose, frames, length = _blurred_drawing(seed)
        reg = register(frames)
        centre, scale, _ = _errors(reg.pose, pose)
        assert not reg.walls_doubled, (seed, length, reg.parallax_px)
        assert scale <= 0.5, (seed, scale)
        centres.append(centre)
    assert np.median(centres) <= 1.5 and max(centres) <= 4.0, np.round(centres, 2)


def _stronger_copy_drawing(seed: int, with_array: bool, contrast_range: tuple[float, float] = (1.3, 1.8),
                          true_blur_px: float = 0.0, noise: float = 3.0) -> tuple[CameraPose, list[np.ndarray], np.ndarray]:
    """Three noisy frames (``noise`` grey levels) of 2-px dark wall lines (OpenCV), blurred by
    ``true_blur_px`` (px, Gaussian sigma; seen through the plate), whose second copy, 0.2–0.45 mm
    away in a random direction, has ``contrast_range`` times their contrast (a thick plate's far
    edge drawn harder), and (``with_array``) a dark array, 1 mm wide, on the true copy's insertion
    axis from 6 mm outside the entry (in view) to 2 mm into the spiral. Returns the true pose, the
    frames and the shift (px)."""
    rng = np.random.default_rng(seed)
    origin, x_w, _ = entry_frame(DEFAULT_PHANTOM)
    while True:  # a view that shows the array outside the entry
        pose = random_pose(rng, 640, 480, px_per_mm=(15.0, 25.0))
        x, y = pose.to_image((origin - 11.5 * x_w)[None, :])[0]
        if 5 <= x <= 635 and 5 <= y <= 475:
            break
    parallax_mm, direction, contrast = rng.uniform(0.2, 0.45), rng.uniform(-np.pi, np.pi), rng.uniform(*contrast_range)
    shift = parallax_mm * pose.px_per_mm * np.array([math.cos(direction), math.sin(direction)])
    walls = [_poly(pose, line) for line in _walls_mm()]
    first, second, array = (np.zeros((480, 640), np.float32) for _ in range(3))
    cv2.polylines(first, walls, False, 1.0, 2, cv2.LINE_AA, 4)
    cv2.polylines(second, [w + np.round(shift * 16).astype(np.int32) for w in walls], False, 1.0, 2, cv2.LINE_AA, 4)
    if with_array:
        path = _array_mm(DEFAULT_PHANTOM.theta_start + 0.6)
        path = path[np.linalg.norm(path - origin, axis=1) <= 11.0 + 1e-9]  # 6 mm outside the 5 mm entry
        cv2.polylines(array, [_poly(pose, path)], False, 1.0, int(round(pose.px_per_mm)), cv2.LINE_AA, 4)
    if true_blur_px > 0:
        first = cv2.GaussianBlur(first, (0, 0), true_blur_px)
    img = 170.0 - 60.0 * first - 60.0 * contrast * second
    img = cv2.GaussianBlur(img * (1.0 - 0.6 * array), (0, 0), 0.7)
    frames = [np.clip(img + rng.normal(0.0, noise, img.shape), 0, 255).astype(np.uint8) for _ in range(3)]
    return pose, frames, shift


def test_doubled_walls_whose_far_copy_is_stronger_register_on_the_arrays_axis():
    """The copy with the stronger edges is not always the wall the array runs in. The straight
    array outside the entry lies on the true copy's insertion axis: eight views (seeds 0–7) whose
    second copy is 1.3–1.8 times as strong register on the true copy (centre within 0.5 px,
    scale within 0.3 %; measured: max 0.29 px, 0.22 %). Without the array nothing tells them
    apart and the stronger copy is taken (the parallax away)."""
    for seed in range(8):
        pose, frames, shift = _stronger_copy_drawing(seed, with_array=True)
        reg = register(frames)
        centre, scale, _ = _errors(reg.pose, pose)
        assert reg.walls_doubled, seed
        assert centre <= 0.5 and scale <= 0.3, (seed, centre, scale, shift)
        pose, frames, shift = _stronger_copy_drawing(seed, with_array=False)
        reg = register(frames)
        assert reg.walls_doubled, seed
        centre, _, _ = _errors(reg.pose, pose)
        assert abs(centre - np.hypot(*shift)) <= 0.5, (seed, centre, shift)


def test_a_faint_true_copy_is_found_where_the_array_lies():
    """The wall copy the array runs in seen faintly through the plate (blurred, sigma 1.5 px, at a
    third of the far copy's contrast, noise 6 grey levels): its edges alone do not pass for a
    second copy, so the fit sits on the far copy with the array 4-9 px off its axis. Where the
    array says, the other copy is sought and taken when its edges stand out from the same shift
    turned. Eight views register on the true copy (measured: centre median 0.37 px, max 1.97;
    scale max 0.25 %), flagged doubled; before, four sat on the far copy (4.5-5 px off)."""
    centres = []
    for seed in range(8):
        pose, frames, shift = _stronger_copy_drawing(seed, True, contrast_range=(2.5, 3.5), true_blur_px=1.5, noise=6.0)
        reg = register(frames)
        centre, scale, _ = _errors(reg.pose, pose)
        assert reg.walls_doubled, seed
        assert centre <= 2.2 and scale <= 0.3, (seed, centre, scale, shift)
        centres.append(centre)
    assert np.median(centres) <= 0.6, centres


def test_the_array_outside_the_entry_measures_the_pose_across_the_axis():
    """The straight array outside the entry lies on the insertion axis: with the true pose its
    centre reads within 0.3 px of the axis, with the pose moved 2-8 px across the axis it reads
    that far off (within 0.3 px; measured max 0.25), and along the axis it does not move. The
    registration JSON carries it, and the extraction warns beyond 3 px and 0.15 mm."""
    from tympani.pipeline.extract.video import axis_warning
    from tympani.vision.registration.axis import array_axis_offset

    for seed in range(4):
        pose, frames, _ = _stronger_copy_drawing(seed, with_array=True)
        origin, x_w, normal = entry_frame(DEFAULT_PHANTOM)
        ends = pose.to_image(np.array([origin, origin + normal, origin + x_w]))
        n_img = (ends[1] - ends[0]) / np.hypot(*(ends[1] - ends[0]))
        t_img = (ends[2] - ends[0]) / np.hypot(*(ends[2] - ends[0]))
        assert abs(array_axis_offset(frames[0], pose, DEFAULT_PHANTOM)) <= 0.3
        for shift in (2.0, -5.0, 8.0):
            moved = replace(pose, centre_x_px=pose.centre_x_px + shift * n_img[0],
                            centre_y_px=pose.centre_y_px + shift * n_img[1])
            assert array_axis_offset(frames[0], moved, DEFAULT_PHANTOM) == pytest.approx(-shift, abs=0.3)
        along = replace(pose, centre_x_px=pose.centre_x_px + 4 * t_img[0], centre_y_px=pose.centre_y_px + 4 * t_img[1])
        assert abs(array_axis_offset(frames[0], along, DEFAULT_PHANTOM)) <= 0.3
    reg = register(frames)
    assert abs(reg.to_dict()["array_axis_offset_px"]) <= 0.5
    assert axis_warning(replace(reg, array_axis_offset_px=2.0)) == ""
    assert axis_warning(replace(reg, array_axis_offset_px=-6.0)).startswith("the array outside the entry lies 6.0 px")


def _grain_drawing(seed: int) -> tuple[CameraPose, list[np.ndarray]]:
    """Three noisy 800×600 frames: the channel a brighter region on a flat plate 20 mm square
    (24–32 px/mm), and outside the plate a wood-grained table: stripes 7–14 px apart, of
    contrast 12–25 grey levels, in a random direction and wavy."""
    rng = np.random.default_rng(seed)
    w, h = 800, 600
    pose = random_pose(rng, w, h, px_per_mm=(24.0, 32.0))
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    theta, period, amp = rng.uniform(0, np.pi), rng.uniform(7.0, 14.0), rng.uniform(12.0, 25.0)
    u = xx * math.cos(theta) + yy * math.sin(theta)
    u += cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 25) * 60
    grain = 110 + amp * np.sin(2 * np.pi * u / period) + 0.4 * amp * np.sin(2 * np.pi * u / (3.7 * period))
    half = 10.0 * pose.px_per_mm
    plate = (np.abs(xx - pose.centre_x_px) < half) & (np.abs(yy - pose.centre_y_px) < half)
    channel = np.zeros((h, w), np.float32)
    cv2.fillPoly(channel, [_poly(pose, channel_polygon(DEFAULT_PHANTOM))], 1.0, cv2.LINE_AA, 4)
    img = np.where(plate, 90.0, grain) + 40.0 * channel
    frames = [np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8) for _ in range(3)]
    return pose, frames


def test_a_wood_grained_table_is_refused_or_seen_through_never_misread():
    """Dense grain around the plate outscores the walls in the global search's raw sums; the
    proposals best by score over their patch's edge density are refined too. Twelve such
    views (seeds 0–11): 3 are registered, each within 0.1 px and 0.1 % (measured 0.05 px, 0.04 %;
    before: none), and every other one is refused, never a wrong pose."""
    found = 0
    for seed in range(12):
        pose, frames = _grain_drawing(seed)
        try:
            reg = register(frames)
        except RegistrationError:
            continue
        centre, scale, _ = _errors(reg.pose, pose)
        assert centre <= 0.1 and scale <= 0.1, (seed, centre, scale)
        found += 1
    assert found >= 3


def test_the_valley_scan_turns_a_fit_back_along_the_spirals_self_similarity():
    """Beyond its 100° corner the spiral falls on itself when turned about its centre with the
    matching change of scale, so a fit can settle turned along that valley where the entry shows
    faintly: turns of 68° (9.4 % in scale) were seen on independent renders. From the true pose
    turned 40–80° either way along the valley, :func:`valley_scan` turns back to within 1° in
    eight clean views (measured: within 0.3°); trying only 30° either way, as before, it turned
    none of them back."""
    from tympani.vision.edges import edges_from_gradients
    from tympani.vision.registration.frames import gradients_for_canny, prepare_edges
    from tympani.vision.registration.model import wall_model
    from tympani.vision.registration.valley import valley_pose, valley_scan

    b_per_rad = math.degrees(DEFAULT_PHANTOM.b_per_deg)
    model = wall_model(DEFAULT_PHANTOM, spacing_mm=0.02)
    for seed in range(8):
        rng = np.random.default_rng(seed)
        pose, frame, _ = _render(rng, 0.0)
        gray = to_gray(frame).astype(np.float32) / 255.0
        gx, gy, sigma, magnitude = gradients_for_canny(gray, 1.0)
        edges = prepare_edges(edges_from_gradients(gx, gy, sigma_px=sigma, magnitude=magnitude), 4)
        turn = math.radians(rng.uniform(40.0, 80.0)) * rng.choice([-1.0, 1.0])
        back = valley_scan(valley_pose(pose, turn, b_per_rad), edges.pyramid, model, b_per_rad)
        assert abs(math.degrees(back + turn)) <= 1.0, (seed, math.degrees(turn), math.degrees(back))


def test_region_walls_seen_twice_do_not_pull_the_scale() -> None:
    """A harsh frame of an independent renderer, a dark channel whose region shows twice 0.43 mm
    apart without wall lines (tests/data/README.md): the best fit of the global search settled
    between the copies a few percent off in scale and failed its verification; refined again from
    a few percent smaller scales it is found within 1 px and 0.5 % (measured: 0.44 px, +0.22 %),
    with the walls seen twice."""
    import math
    from pathlib import Path

    frame = cv2.imread(str(Path(__file__).parent / "data" / "doubled_region_walls.jpg"), cv2.IMREAD_GRAYSCALE)
    reg = register([frame])
    assert math.hypot(reg.pose.centre_x_px - 230.022, reg.pose.centre_y_px - 166.453) <= 1.0, reg.pose
    assert abs(reg.pose.px_per_mm / 26.91875 - 1.0) <= 0.005, reg.pose
    assert reg.walls_doubled


def _fringed_drawing(seed: int, fluid_darker: bool, with_array: bool = True, strength: tuple[float, float] = (0.55, 0.9),
                     width_px: tuple[float, float] = (1.3, 2.4)) -> tuple[CameraPose, np.ndarray]:
    """A frame whose walls show refraction fringes: across each wall the step between plate
    and fluid plus a bright band on one side and a dark band on the other, against the step
    and ``strength`` times it (at least half), so each wall shows two edges of the step's
    polarity either side of it and a weaker one of the other polarity on it; the bands
    ``width_px`` wide. Returns the pose and the frame."""
    rng = np.random.default_rng(seed)
    w, h = 640, 480
    pose = CameraPose(float(rng.uniform(260, 380)), float(rng.uniform(200, 280)), float(rng.uniform(-math.pi, math.pi)),
                      float(rng.uniform(16, 30)), bool(rng.integers(0, 2)))
    plate = float(rng.uniform(140, 190))
    step = float(rng.uniform(18, 30)) * (-1.0 if fluid_darker else 1.0)
    # the channel's coverage of each pixel (filled 8x finer, averaged) and the signed distance
    # (px, + inside) of each pixel centre to its outline, up to 12 px
    outline = pose.to_image(channel_polygon(DEFAULT_PHANTOM))
    fine = np.zeros((8 * h, 8 * w), np.uint8)
    cv2.fillPoly(fine, [np.round((8 * outline + 3.5) * 16).astype(np.int32)], 255, cv2.LINE_8, 4)
    coverage = cv2.resize(fine.astype(np.float32) / 255.0, (w, h), interpolation=cv2.INTER_AREA)
    closed = np.vstack([outline, outline[:1]])
    steps = np.ceil(np.hypot(*np.diff(closed, axis=0).T) / 0.1).astype(int) + 1
    dense = np.vstack([np.linspace(a, b, k, endpoint=False) for a, b, k in zip(closed[:-1], closed[1:], steps)])
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).reshape(-1, 2).astype(float)
    distance = np.minimum(cKDTree(dense).query(grid, distance_upper_bound=12.0)[0], 12.0).reshape(h, w)
    signed = np.where(coverage > 0.5, distance, -distance)
    z = signed / float(rng.uniform(*width_px))  # the bands' width (px)
    amp = -np.sign(step) * float(rng.uniform(*strength)) * abs(step)  # against the step
    img = plate + step * coverage + amp * z * np.exp(0.5 - 0.5 * z * z)
    if with_array:
        cv2.polylines(img, [_poly(pose, _array_mm(4.0))], False, float(min(plate, plate + step) - 60),
                      max(1, int(0.8 * pose.px_per_mm)), cv2.LINE_AA, 4)
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.8) + rng.normal(0, 3.0, (h, w))
    return pose, np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("fluid_darker, with_array, least", [(True, False, 7), (False, False, 7), (True, True, 5),
                                                           (False, True, 3)])
def test_fringed_walls_register_between_their_like_edges(fluid_darker: bool, with_array: bool, least: int) -> None:
    """Fringed walls at 8 random poses (16-30 px/mm, both mirrors), the fluid darker or lighter
    than the plate, with or without an array 0.8 mm thick filling the first turn and a half:
    at least ``least`` of the 8 are registered within 0.5 px and 0.3 %, and every fringe named
    has the step's polarity and a right pose. Measured: without the array 7
    and 7 of 8 (within 0.05 px and 0.13 %), with it 6 and 3 of 8. Before the fringed fit, 0, 0,
    1 and 0 of 8: the single fit took one edge of each pair, 2-15 % off in scale or 3-11 px off
    centre. The array over the fringes still misleads the global search at some poses (known
    limits)."""
    good = 0
    for k in range(8):
        pose, frame = _fringed_drawing(1300 + 10 * fluid_darker + k, fluid_darker, with_array)
        reg = register([frame])
        centre, scale, _ = _errors(reg.pose, pose)
        good += centre <= 0.5 and scale <= 0.3
        if reg.fringe_px != 0.0:
            assert (reg.fringe_px > 0) == fluid_darker and abs(reg.fringe_px) >= 1.5, (k, reg.fringe_px)
            assert centre <= 0.5 and scale <= 0.3, (k, centre, scale)  # never a fringe with a wrong pose
            assert not reg.walls_doubled and reg.to_dict()["wall_fringe_px"] == reg.fringe_px
            assert check(frame, reg) < check(frame, replace(reg, fringe_px=0.0)), k  # check() knows the fringe
    assert good >= least, good


@pytest.mark.parametrize("fluid_darker, least", [(False, 8), (True, 7)])
def test_strong_fringes_are_not_taken_for_doubled_walls(fluid_darker: bool, least: int) -> None:
    """Fringes as strong as the step or stronger (0.9-1.2 times it, 1.3-2.8 px wide), no array,
    8 random poses: the single fit lies on one edge of each pair so closely (residual under
    0.3 px) that the fringed fit was not tried from it, and the pairs passed for doubled walls
    4.2-5.2 px off on 4 of 8 (fluid lighter) and 4 of 8 (darker). The fringed fit is now tried
    where walls come out doubled: at least ``least`` of 8 within 0.5 px and 0.3 % (measured 8
    and 7, within 0.03 px and 0.07 %; one of each as doubled walls, the lighter one's right),
    and every fringe named has the step's polarity and a right pose."""
    good = 0
    for k in range(8):
        pose, frame = _fringed_drawing(1400 + 10 * fluid_darker + k, fluid_darker, False, (0.9, 1.2), (1.3, 2.8))
        reg = register([frame])
        centre, scale, _ = _errors(reg.pose, pose)
        good += centre <= 0.5 and scale <= 0.3
        if reg.fringe_px != 0.0:
            assert (reg.fringe_px > 0) == fluid_darker and not reg.walls_doubled, k
            assert centre <= 0.5 and scale <= 0.3, (k, centre, scale)
    assert good >= least, good


def test_walls_without_fringes_are_not_taken_for_fringed(clean_runs):
    assert all(reg.fringe_px == 0.0 for _, reg, _, _ in clean_runs)

"""Walls that show twice, registered on the copy the array does not touch.

The two copies of a doubled wall fit the spiral equally well; where their parallax runs along
the insertion axis nothing outside the channel tells them apart. Inside, the array presses on
the real copy of the outer wall: on the other copy the gap reads about the parallax (contact
missed) or the array crosses it. The extraction then measures the video again on the other
copy (``remeasure_on_other_copy``); on the right copy it leaves the registration alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.pipeline.extract.video import extract_video, prefers_other_copy
from tympani.vision.geometry import CameraPose
from tympani.vision.registration import Registration
from tympani.vision.rendering import Appearance, Nuisance, VideoSpec, random_pose, render_video

W, H = 640, 480


def _video(tmp_path: Path, seed: int) -> tuple[Path, CameraPose, tuple[float, float], object]:
    """An insertion from 5 to 16 mm (23 frames), walls doubled 0.25-0.4 mm apart in a random
    image direction at 60-90 % contrast; returns the video, the true pose, the second copy's
    shift (px) and the truth table."""
    rng = np.random.default_rng(seed)
    pose = random_pose(rng, W, H, px_per_mm=(20.0, 30.0))
    parallax_mm, direction = float(rng.uniform(0.25, 0.4)), float(rng.uniform(-math.pi, math.pi))
    nuisance = Nuisance(doubled_wall_mm=parallax_mm, doubled_wall_contrast=float(rng.uniform(0.6, 0.9)),
                        doubled_wall_direction_rad=direction)
    spec = VideoSpec(pose, W, H, fps=2.0, speed_mm_s=1.0, start_depth_mm=5.0, end_depth_mm=16.0,
                     appearance=Appearance(), nuisance=nuisance)
    path = tmp_path / f"v{seed}.avi"
    truth = render_video(path, spec, seed=seed)
    shift = (parallax_mm * pose.px_per_mm * math.cos(direction), parallax_mm * pose.px_per_mm * math.sin(direction))
    return path, pose, shift, truth


def _steps(registration: Registration) -> VisionSteps:
    return VisionSteps(register=lambda frames, phantom, *args: registration)


def _right(pose: CameraPose, shift: tuple[float, float]) -> Registration:
    return Registration(pose=pose, residual_px=0.5, image_size=(W, H), walls_doubled=True, parallax_px=shift,
                        second_copy_contrast=0.8)


@pytest.mark.parametrize("seed", range(11, 21))
def test_the_copy_the_array_touches_is_kept(tmp_path: Path, seed: int) -> None:
    """Given the true copy, the extraction keeps it: the array never says otherwise. The other
    copy's line runs beside the array, a lighter shelf the array's darker core is told from
    (when written, seeds 11-20: no frame with theta_con off by more than 0.5 rad, 9-23 of the
    23 frames measured; with the dark's edges only, ``MeasureConfig(core_closer=-1)``, 18 such
    frames on five of the ten seeds)."""
    path, pose, shift, truth = _video(tmp_path, seed)
    kept, _ = extract_video(path, ExtractConfig(), steps=_steps(_right(pose, shift)))
    assert not any("other copy" in w for w in kept.attrs["warnings"])
    assert kept.attrs["registrations"][0]["centre_x_px"] == pose.centre_x_px
    assert (truth["theta_con"] > 0.05).to_numpy()[kept["ok"].to_numpy()].sum() >= 5
    ok = kept["ok"].to_numpy()
    assert ((kept["theta_con"] - truth["theta_con"]).abs().to_numpy()[ok] <= 0.5).all()


@pytest.mark.parametrize("seed", [11, 13, 17])
def test_a_registration_on_the_copy_the_array_does_not_touch_is_measured_again(tmp_path: Path, seed: int) -> None:
    """Given the registration of the wrong copy (the true pose moved by the parallax), the
    extraction switches to the true one and measures every frame as it does given the true
    copy. (Of seeds 11-20, 11, 13 and 17 switch: on the wrong copy the tip stands off the
    wall, or the array crosses it, past half a turn. In the others too few frames there say
    so: the tip touches both copies' walls, where only the contact run's length differs, which
    is no evidence, or the frame is refused (on 12 every frame past half a turn; on 14 enough
    of them, at the tip's checks, that the video is mostly unread on the wrong copy).)"""
    path, pose, shift, truth = _video(tmp_path, seed)
    right = _right(pose, shift)
    kept, _ = extract_video(path, ExtractConfig(), steps=_steps(right))
    table, _ = extract_video(path, ExtractConfig(), steps=_steps(right.other_copy()))
    assert any("measured again on their other copy" in w for w in table.attrs["warnings"]), table.attrs["warnings"]
    switched = table.attrs["registrations"][0]
    assert math.hypot(switched["centre_x_px"] - pose.centre_x_px, switched["centre_y_px"] - pose.centre_y_px) < 1e-9
    angles = ["theta_tip", "theta_bot", "theta_con"]
    assert (table["ok"] == kept["ok"]).all()
    np.testing.assert_allclose(table[angles].to_numpy(float), kept[angles].to_numpy(float), atol=1e-9)


def test_without_evidence_past_half_a_turn_the_copy_stays(tmp_path: Path) -> None:
    """Seed 12: on the wrong copy every frame past half a turn is refused before its centre
    line is complete, so nothing says which copy the array touches: the registration stays,
    and those frames stay refused (none is reported on the wrong copy)."""
    path, pose, shift, truth = _video(tmp_path, 12)
    wrong = _right(pose, shift).other_copy()
    table, _ = extract_video(path, ExtractConfig(), steps=_steps(wrong))
    assert not any("other copy" in w for w in table.attrs["warnings"])
    assert table.attrs["registrations"][0]["centre_x_px"] == wrong.pose.centre_x_px
    assert not table["ok"][(truth["theta_tip"] >= math.pi).to_numpy()].any()


def test_the_copy_is_switched_only_on_enough_evidence() -> None:
    """3 mm of centre line in all, from at least three frames, three times as many as say the
    registered copy; NaN (a tip short of half a turn) is no evidence."""
    assert prefers_other_copy(np.array([np.nan, np.nan, 1.0, 1.0, 1.0, 0.0]))
    assert not prefers_other_copy(np.array([9.0, 9.0, 0.4, 0.0, 0.0, 0.0]))  # two frames
    assert prefers_other_copy(np.array([0.0, 0.0, 2.0, 2.0, 2.0, -1.0]))  # three to one
    assert not prefers_other_copy(np.array([0.0, 2.0, 2.0, 2.0, -1.0, -1.0]))
    assert prefers_other_copy(np.array([0.0, 0.0, 2.0, 2.0, 2.0, -0.4]))  # -0.4: for neither
    assert not prefers_other_copy(np.array([0.0, 0.0, 0.6, 0.6, 0.6, 0.6]))  # 2.4 mm in all
    assert not prefers_other_copy(np.full(6, np.nan))


def test_annotate_draws_the_copy_that_extraction_switches_to(tmp_path: Path) -> None:
    """Seed 11 registered on the wrong copy: ``annotate`` measures the whole video for the
    evidence, as ``extract`` does, and draws (and tabulates) its frames on the copy extraction
    switches to, with the same angles (on the last three frames extraction measured; drawn with
    the first registration, two of them were refused); it says so among its warnings."""
    from tympani.pipeline.extract.annotate import annotate_video

    path, pose, shift, truth = _video(tmp_path, 11)
    steps = _steps(_right(pose, shift).other_copy())
    table, _ = extract_video(path, ExtractConfig(), steps=steps)
    frames = table.loc[table["ok"], "frame"].to_list()[-3:]
    result = annotate_video(path, tmp_path / "annotated", ExtractConfig(), frames=frames, steps=steps)
    assert any("drawn again on their other copy" in w for w in result.warnings), result.warnings
    drawn = pd.read_csv(result.table).set_index("frame").loc[frames]
    angles = ["theta_tip", "theta_bot", "theta_con"]
    assert drawn["ok"].all()
    np.testing.assert_allclose(drawn[angles].to_numpy(float), table.set_index("frame").loc[frames][angles].to_numpy(float),
                               atol=1e-9)

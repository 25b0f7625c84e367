"""``tympani evaluate-extraction``: videos of renderer C scored against their truth."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tympani.pipeline.extract.evaluation import (
    EvaluationConfig,
    VideoCase,
    copy_counts,
    draw_case,
    evaluate_extraction,
    score_video,
    summarise,
)
from tympani.pipeline.synthetic.renderer_c import render_frames
from tympani.vision.angles import measure_frame, prepare_measurement
from tympani.vision.geometry import CameraPose
from tympani.vision.greyscale import to_gray
from tympani.vision.registration import Registration, register


def test_cases_are_drawn_from_the_seed_alone():
    assert draw_case(7, "harsh") == draw_case(7, "harsh")
    clean, harsh = draw_case(8, "clean"), draw_case(8, "harsh")
    assert set(clean.nuisance.values()) == {0.0} and clean.size == (640, 480)
    assert min(v for k, v in harsh.nuisance.items() if k != "doubled_walls") >= 0.3
    with pytest.raises(ValueError, match="unknown nuisance mode"):
        draw_case(1, "rainy")


def test_a_wrong_frame_marked_ok_counts_as_gross_only_there():
    """Five frames: right, tip 0.4 rad off (gross), theta_con 0.6 rad off (gross, not in contact),
    refused, right in contact."""
    truth = pd.DataFrame({"frame": range(5), "theta_tip": [1.0, 2.0, 3.0, 4.0, 5.0], "theta_bot": [1.0, 2.0, 2.5, 3.5, 4.0],
                          "theta_con": [0.0, 0.0, 0.5, 0.5, 1.0], "in_contact": [False, True, False, True, True]})
    table = truth.drop(columns="in_contact").assign(ok=[True, True, True, False, True], reason="")
    table.loc[1, "theta_tip"] += 0.4
    table.loc[2, "theta_con"] += 0.6
    table.loc[3, ["theta_tip", "theta_bot", "theta_con"]] = np.nan
    table.loc[3, "reason"] = "kinematics: depth 3.10 mm is +0.61 mm off the constant-speed insertion (0.5 mm/s)"
    table.loc[4, "theta_tip"] += 0.01
    pose = {"centre_x_px": 100.0, "centre_y_px": 50.0, "px_per_mm": 20.0, "mirrored": False}
    registered = Registration(CameraPose(centre_x_px=103.0, centre_y_px=54.0, rotation_rad=0.0, px_per_mm=20.2,
                                         mirrored=False), residual_px=0.5)
    case = VideoCase(1, (640, 480), None, {"bubbles": 0.5})
    score, frames = score_video(case, table, truth, pose, registered, EvaluationConfig())
    assert (score.frames, score.measured, score.contact_frames, score.gross, score.gross_contact) == (5, 4, 3, 2, 1)
    assert frames["gross"].tolist() == [False, True, True, False, False]
    assert score.tip_median_rad == pytest.approx(0.005) and score.con_median_rad == pytest.approx(0.0)
    assert score.centre_error_px == pytest.approx(5.0) and score.scale_error_pct == pytest.approx(1.0)
    assert score.mirror_ok and score.bubbles == 0.5
    assert score.refused == "kinematics: 1"


@pytest.mark.parametrize("centre, doubled, expected", [
    ((104.0, 47.0), (-4.0, 3.0), (5.0, 5.0, 0.0)),     # on the other copy: its centre is the truth
    ((102.0, 48.5), (-4.0, 3.0), (2.5, 5.0, 2.5)),     # half way between the copies
    ((100.0, 50.0), (-4.0, 3.0), (0.0, 5.0, 5.0)),     # on the right copy
    ((101.0, 50.0), None, (1.0, 0.0, float("nan"))),   # single walls
])
def test_the_score_says_whether_the_registration_took_the_other_copy(centre, doubled, expected):
    """``other_copy_error_px``: the centre error had the registration taken the other copy of
    walls it found twice (the copy ``parallax_px`` away), so a registration on the wrong copy
    shows as a centre error of about the parallax with this near 0."""
    truth = pd.DataFrame({"frame": [0], "theta_tip": [1.0], "theta_bot": [1.0], "theta_con": [0.0],
                          "in_contact": [False]})
    table = truth.drop(columns="in_contact").assign(ok=True, reason="")
    pose = {"centre_x_px": 100.0, "centre_y_px": 50.0, "px_per_mm": 20.0, "mirrored": False}
    registered = Registration(CameraPose(*centre, rotation_rad=0.0, px_per_mm=20.0), residual_px=0.5,
                              walls_doubled=doubled is not None, parallax_px=doubled or (0.0, 0.0))
    score, _ = score_video(VideoCase(1, (640, 480), None, {}), table, truth, pose, registered, EvaluationConfig())
    assert (score.centre_error_px, score.parallax_px) == pytest.approx(expected[:2])
    assert score.walls_doubled_found == (doubled is not None)
    assert score.other_copy_error_px == pytest.approx(expected[2], nan_ok=True)


def test_the_summary_counts_registrations_off_on_doubled_walls():
    """Of the videos whose walls were found twice: those more than 1 px off, on the other copy
    (within 1 px of it) or elsewhere; single walls and failed videos are not counted."""
    results = pd.DataFrame({
        "walls_doubled_found": [True, True, True, True, False, False],
        "centre_error_px": [0.4, 5.0, 2.5, 3.0, 4.0, float("nan")],
        "other_copy_error_px": [5.1, 0.3, 2.6, 0.9, float("nan"), float("nan")],
        "error": ["", "", "", "", "", "registration failed"],
    })
    assert copy_counts(results[results["error"] == ""]) == {"doubled_found": 4, "doubled_off": 3,
                                                         "doubled_other_copy": 2, "doubled_between": 1}


def test_a_clean_video_end_to_end(tmp_path):
    """Seed 200, no nuisances: measured 30 of 30 frames, tip median 0.0031 rad, centre 0.011 px,
    scale 0.03 %."""
    results = evaluate_extraction([200], tmp_path, EvaluationConfig(nuisance="clean", frames=30))
    summary = summarise(results)
    assert (summary["videos"], summary["failed"], summary["frames"]) == (1, 0, 30)
    assert summary["measured_share"] == 1.0 and summary["gross_contact"] == 0
    assert summary["tip_median_rad"] < 0.006 and summary["con_median_rad"] < 0.04
    assert summary["centre_error_max_px"] < 0.05 and summary["scale_error_max_pct"] < 0.1
    assert {p.name for p in tmp_path.iterdir()} >= {"v200.mp4", "v200_truth.csv", "v200_frames.csv"}


def test_an_output_folder_that_cannot_be_made_is_a_one_line_error(tmp_path, capsys):
    from tympani.pipeline.cli import main

    blocker = tmp_path / "taken"
    blocker.write_text("a file, not a folder", encoding="utf-8")
    assert main(["evaluate-extraction", "--videos", "1", "--out", str(blocker / "eval"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"tympani: {blocker / 'eval'}: cannot create the output folder") and "\n" not in err


def test_shading_across_the_fluid_is_not_taken_for_array() -> None:
    """Renderer C's seed 445 (random nuisances): a very dark array with wide bright bands, and
    darker shading across the fluid beyond the tip. The array's grey level, estimated from the
    whole channel, was pulled up to the shading's, which then read as more array: frames 1-4
    had no edges at the dark run's end and were refused. Every frame of the first nine is now
    measured, tip within 0.03 rad and theta_con within 0.1 rad (measured: 0.023 and 0.092)."""
    case = draw_case(445, "random")
    frames, truth, _ = render_frames(445, n_frames=10, size=case.size, px_per_mm=case.px_per_mm,
                                     nuisance=case.nuisance)
    grays = [to_gray(f) for f in frames]
    plan = prepare_measurement(register(grays[0]), grays[0].shape)
    got = [measure_frame(g, plan) for g in grays[:9]]
    assert all(m.ok for m in got), [m.reason for m in got]
    assert max(abs(m.theta_tip - t) for m, t in zip(got, truth["theta_tip"])) < 0.03
    assert max(abs(m.theta_con - t) for m, t in zip(got, truth["theta_con"])) < 0.1


_OTHER_RENDERER = '''
import json
from tympani.pipeline.synthetic import renderer_c

NUISANCE_KEYS = ("noise", "glints")


def render_video(path, seed, *, n_frames, size, px_per_mm, nuisance):
    with open(str(path) + ".call.json", "w") as f:
        json.dump({"seed": seed, "n_frames": n_frames, "size": list(size), "nuisance": nuisance}, f)
    return renderer_c.render_video(path, seed, n_frames=n_frames, size=size, px_per_mm=px_per_mm, nuisance=nuisance)
'''


def test_another_renderer_given_as_a_file(tmp_path, capsys):
    """--renderer FILE.py: its own nuisance names are drawn from the seed and passed with the size
    and frame count; its videos are scored like renderer C's (this one wraps renderer C, so the
    clean video of seed 200 scores as in the test above)."""
    from tympani.pipeline.cli import main

    renderer = tmp_path / "other.py"
    renderer.write_text(_OTHER_RENDERER, encoding="utf-8")
    out = tmp_path / "eval"
    assert main(["evaluate-extraction", "--videos", "1", "--seed", "200", "--nuisance", "clean", "--frames", "12",
                 "--renderer", str(renderer), "--out", str(out), "-q"]) == 0
    call = json.loads((out / "v200.mp4.call.json").read_text())
    assert call == {"seed": 200, "n_frames": 12, "size": [640, 480], "nuisance": {"noise": 0.0, "glints": 0.0}}
    videos = pd.read_csv(out / "videos.csv")
    assert videos["measured"].tolist() == [12] and videos["gross_contact"].tolist() == [0]
    assert draw_case(7, "harsh", ("noise", "bubbles")).nuisance.keys() == {"noise", "bubbles"}
    capsys.readouterr()


_WRAPPER = """from tympani.pipeline.synthetic import renderer_c
NUISANCE_KEYS = renderer_c.NUISANCE_KEYS

def render_video(path, seed, *, n_frames, size, px_per_mm, nuisance):
    truth, info = renderer_c.render_video(path, seed, n_frames=n_frames, size=size, px_per_mm=px_per_mm,
                                          nuisance=nuisance)
    {change}
"""


@pytest.mark.parametrize("change, problem", [
    ("return truth, {'pose': {k: v for k, v in info['pose'].items() if k != 'mirrored'}}", "a pose without mirrored"),
    ("return truth.drop(columns=['in_contact', 'theta_con']), info", "a truth table without theta_con, in_contact"),
    ("return truth", "something other than a (truth, info) pair"),
    ("return truth, {}", "an info without a 'pose' dict"),
])
def test_a_renderer_that_breaks_its_contract_is_a_one_line_error(tmp_path, capsys, change, problem):
    """What ``render_video`` returns is checked: a missing pose key or truth column names the
    renderer file and what is missing (exit 2), rather than failing later with a bare KeyError."""
    from tympani.pipeline.cli import main

    renderer = tmp_path / "r.py"
    renderer.write_text(_WRAPPER.format(change=change), encoding="utf-8")
    assert main(["evaluate-extraction", "--renderer", str(renderer), "--videos", "1", "--frames", "3",
                 "--out", str(tmp_path / "e"), "-q"]) == 2
    assert capsys.readouterr().err.strip() == f"tympani: {renderer}: render_video returned {problem}"


def test_a_renderer_file_with_dataclasses_loads(tmp_path):
    """A renderer file is loaded as a module that can be looked up by name while it runs, as
    ``dataclasses`` (and pickling) do: one defining a dataclass used to fail to load."""
    from tympani.pipeline.extract.evaluation import load_renderer

    renderer = tmp_path / "with_dataclass.py"
    renderer.write_text("from dataclasses import dataclass\n\n@dataclass(frozen=True)\nclass Look:\n"
                        "    fluid: float = 0.8\n\nNUISANCE_KEYS = ('bubbles',)\n\n"
                        "def render_video(path, seed, **kw):\n    return Look().fluid\n", encoding="utf-8")
    module = load_renderer(str(renderer))
    assert module.NUISANCE_KEYS == ("bubbles",) and module.render_video("x.mp4", 0) == 0.8


@pytest.mark.parametrize("text, problem", [
    (None, "no such renderer file"),
    ("x = 1\n", "the renderer defines no NUISANCE_KEYS and no render_video"),
    ("raise RuntimeError('boom')\n", "the renderer does not load: RuntimeError: boom"),
])
def test_a_renderer_file_that_cannot_be_used_is_a_one_line_error(tmp_path, capsys, text, problem):
    from tympani.pipeline.cli import main

    renderer = tmp_path / "r.py"
    if text is not None:
        renderer.write_text(text, encoding="utf-8")
    assert main(["evaluate-extraction", "--renderer", str(renderer), "--out", str(tmp_path / "e"), "-q"]) == 2
    assert capsys.readouterr().err.strip() == f"tympani: {renderer}: {problem}"
    assert not (tmp_path / "e").exists()

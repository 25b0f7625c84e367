"""The ``tympani`` command line: exit codes, one-line errors, extract/annotate/bench."""

from __future__ import annotations

import json

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

import pipeline_fakes as fakes
from tympani.pipeline.cli import COMMANDS, main


@pytest.fixture
def fake_vision():
    """The fake vision steps, for ``_run(..., steps=fake_vision)``."""
    return fakes.STEPS


def _run(capsys, *argv, steps=None):
    code = main(list(argv), steps=steps)
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


# --------------------------------------------------------------------------- help and usage


def test_help_on_every_command(capsys):
    code, out, _ = _run(capsys, "--help")
    assert code == 0 and all(name in out for name in COMMANDS)
    for name in COMMANDS:
        code, out, _ = _run(capsys, name, "--help")
        assert code == 0 and f"tympani {name}" in out


def test_console_script_help():
    script = Path(sys.executable).parent / "tympani"
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "tympani.pipeline.cli"]
    done = subprocess.run([*cmd, "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "extract" in done.stdout


@pytest.mark.parametrize(
    "argv, fragment",
    [
        ([], "no command given"),
        (["nonsense"], "invalid choice"),
        (["extract", "v.mp4"], "required: --out"),
        (["extract", "--out", "x"], "either VIDEO... or --manifest"),
        (["extract", "v.mp4", "--out", "x", "--workers", "0"], "must be >= 1"),
        (["annotate", "v.mp4", "--out", "x", "--frames", "a,b"], "frame numbers"),
        (["annotate", "v.mp4", "--out", "x", "--frames", "1", "--every", "2"], "not allowed with"),
        (["extract", "v.mp4", "--out", "x", "--array-first-band", "0.3"], "(FROM,LENGTH)"),
        (["extract", "v.mp4", "--out", "x", "--array-first-band", "0.3,0"], "(FROM,LENGTH)"),
    ],
)
def test_bad_usage_is_exit_2_with_one_line(capsys, argv, fragment):
    code, out, err = _run(capsys, *argv)
    assert code == 2 and fragment in _one_line_error(err)


# --------------------------------------------------------------------------- extract


def test_extract_missing_video_is_exit_2(capsys, tmp_path, fake_vision):
    code, _, err = _run(capsys, "extract", str(tmp_path / "nope.mp4"), "--out", str(tmp_path / "out"), "-q",
                        steps=fake_vision)
    assert code == 2
    assert _one_line_error(err) == f"tympani: {tmp_path / 'nope.mp4'}: no such file or folder"


def test_the_arrays_first_band_reaches_the_measurement(capsys, tmp_path, fake_vision):
    good = fakes.write_video(tmp_path / "good.mp4", n=4)
    code, _, _ = _run(capsys, "extract", str(good), "--out", str(tmp_path / "out"), "-q", "--array-first-band",
                      "0.5,0.9", steps=fake_vision)
    assert code == 0
    text = (tmp_path / "out" / "good.provenance.json").read_text()
    array = json.loads(text)["params"]["extract"]["array"]
    assert (array["first_band_mm"], array["band_length_mm"]) == (0.5, 0.9)


def test_extract_good_and_bad_videos(capsys, tmp_path, fake_vision):
    good = fakes.write_video(tmp_path / "good.mp4", n=6)
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"junk" * 100)
    out = tmp_path / "out"
    code, stdout, err = _run(capsys, "extract", str(good), str(bad), "--out", str(out), "--quiet", steps=fake_vision)
    assert code == 2 and "not a video" in _one_line_error(err)
    assert "1 ok, 0 skipped, 1 failed" in stdout
    assert pd.read_csv(out / "good.angles.csv")["ok"].all()
    summary = pd.read_csv(out / "extract_summary.csv")
    assert summary["status"].tolist() == ["ok", "failed"]


def test_extract_all_good_then_resume(capsys, tmp_path, fake_vision):
    videos = [str(fakes.write_video(tmp_path / f"v{i}.mp4", n=5)) for i in range(2)]
    out = str(tmp_path / "out")
    code, stdout, err = _run(capsys, "extract", *videos, "--out", out, "-q", steps=fake_vision)
    assert code == 0 and "2 ok" in stdout and err == ""
    code, stdout, _ = _run(capsys, "extract", *videos, "--out", out, "-q", steps=fake_vision)
    assert code == 0 and "2 skipped" in stdout
    code, stdout, _ = _run(capsys, "extract", *videos, "--out", out, "-q", "--overwrite", "--workers", "1",
                           steps=fake_vision)
    assert code == 0 and "2 ok" in stdout


def test_extract_from_manifest(capsys, tmp_path, fake_vision):
    fakes.write_video(tmp_path / "a.mp4", n=5)
    (tmp_path / "a_force.csv").write_text("time_s,force_g\n0,0\n")
    manifest = tmp_path / "m.csv"
    manifest.write_text("trial,speed_mm_s,video,force\ntrial_a,0.5,a.mp4,a_force.csv\n")
    code, stdout, _ = _run(capsys, "extract", "--manifest", str(manifest), "--out", str(tmp_path / "out"), "-q",
                           steps=fake_vision)
    assert code == 0 and (tmp_path / "out" / "trial_a.angles.csv").exists()
    manifest.write_text("trial,speed_mm_s,video,force\ntrial_a,0.5,a.mp4,a_force.csv\ntrial_a,1,a.mp4,a_force.csv\n")
    code, _, err = _run(capsys, "extract", "--manifest", str(manifest), "--out", str(tmp_path / "out"), "-q",
                        steps=fake_vision)
    assert code == 2 and _one_line_error(err) == f"tympani: {manifest}:3: duplicate trial 'trial_a' (first on line 2)"


def test_interrupt_is_exit_130(capsys, tmp_path, monkeypatch, fake_vision):
    from tympani.pipeline.extract import batch

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "extract_batch", interrupted)
    code, _, err = _run(capsys, "extract", "v.mp4", "--out", str(tmp_path / "out"), steps=fake_vision)
    assert code == 130 and "interrupted" in err


def test_unexpected_error_is_exit_1_one_line_and_debug_shows_traceback(capsys, tmp_path, monkeypatch, fake_vision):
    from tympani.pipeline.extract import batch

    def broken(*args, **kwargs):
        raise ZeroDivisionError("oops\nsecond line")

    monkeypatch.setattr(batch, "extract_batch", broken)
    code, _, err = _run(capsys, "extract", "v.mp4", "--out", str(tmp_path / "out"), steps=fake_vision)
    assert code == 1 and "ZeroDivisionError: oops second line" in _one_line_error(err)
    code, _, err = _run(capsys, "extract", "v.mp4", "--out", str(tmp_path / "out"), "--debug", steps=fake_vision)
    assert code == 1 and "Traceback" in err


def test_bug_inside_a_video_is_exit_1(capsys, tmp_path, fake_vision):
    def broken(*args, **kwargs):
        raise RuntimeError("registration bug")

    video = fakes.write_video(tmp_path / "v.mp4", n=3)
    code, _, err = _run(capsys, "extract", str(video), "--out", str(tmp_path / "out"), "-q",
                        steps=replace(fake_vision, register=broken))
    assert code == 1 and "RuntimeError: registration bug" in _one_line_error(err)


# --------------------------------------------------------------------------- annotate, bench


def test_annotate_with_labels(capsys, tmp_path, fake_vision):
    video = fakes.write_video(tmp_path / "an.mp4", n=10)
    labels = tmp_path / "labels.csv"
    labels.write_text("frame,tip_x_px,tip_y_px,bot_x_px,bot_y_px\n6,40,20,,\n")
    out = tmp_path / "out"
    code, stdout, _ = _run(capsys, "annotate", str(video), "--out", str(out), "--frames", "0,3", "-q",
                           "--label", "2", "tip=40,20", "bot=30,30", "--labels", str(labels), steps=fake_vision)
    assert code == 0 and "2 labelled frame(s)" in stdout and "theta_tip" in stdout
    assert {p.name for p in out.glob("*.png")} == {f"an.frame{i:06d}.png" for i in (0, 2, 3, 6)}
    assert pd.read_csv(out / "an.label_compare.csv")["frame"].tolist() == [2, 6]


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--label", "2", "tip=40"], "tip needs two numbers"),
        (["--labels", "missing.csv"], "no such labels file"),
    ],
)
def test_annotate_bad_labels_exit_2(capsys, tmp_path, fake_vision, extra, fragment):
    video = fakes.write_video(tmp_path / "an.mp4", n=3)
    code, _, err = _run(capsys, "annotate", str(video), "--out", str(tmp_path / "out"), "-q", *extra, steps=fake_vision)
    assert code == 2 and fragment in _one_line_error(err)


def test_bench_on_a_given_video(capsys, tmp_path, fake_vision):
    video = fakes.write_video(tmp_path / "b.mp4", n=10)
    code, stdout, _ = _run(capsys, "bench", "--video", str(video), "--skip", "memory,diagnosis,workers,logs",
                           steps=fake_vision)
    assert code == 0 and "decode only" in stdout and "full extract" in stdout and "ratio" in stdout
    assert "measure" in stdout and "peak memory" in stdout


def test_extract_says_why_frames_were_not_measured(capsys, tmp_path, fake_vision):
    """A video measured on under half its frames gets a warning with the refusals by kind, the same
    text as the summary's ``refused`` column, kept when a rerun skips the video."""
    good = fakes.write_video(tmp_path / "good.mp4", n=6)
    dim = fakes.write_video(tmp_path / "dim.mp4", n=10, dark=range(1, 8))
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"junk" * 100)
    out = tmp_path / "out"
    code, _, err = _run(capsys, "extract", str(good), str(dim), str(bad), "--out", str(out), "-q", steps=fake_vision)
    assert code == 2
    # frames 1-7 show no array; the three left are too few to check one another
    said = "no array in view: 7; video mostly unread: 3"
    lines = [line for line in err.splitlines() if "frames measured" in line]
    assert lines == [f"tympani: warning: {dim}: 0 of 10 frames measured; frames refused: {said}"]
    assert [line for line in err.splitlines() if "tympani: hint:" in line and "tympani annotate" in line] != []
    summary = pd.read_csv(out / "extract_summary.csv", keep_default_na=False).set_index("trial")
    assert summary.loc["dim", "refused"] == said and summary.loc["good", "refused"] == ""
    assert summary.loc["bad", "refused"] == ""
    prov = json.loads((out / "dim.provenance.json").read_text())
    assert prov["refused"] == {"no array in view": 7, "video mostly unread": 3}
    code, stdout, err = _run(capsys, "extract", str(good), str(dim), "--out", str(out), "-q", steps=fake_vision)
    assert code == 0 and "2 skipped" in stdout and "frames measured;" not in err and "hint:" not in err
    summary = pd.read_csv(out / "extract_summary.csv", keep_default_na=False).set_index("trial")
    assert summary.loc["dim", "refused"] == said

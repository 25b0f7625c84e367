"""Video → angles plumbing: atomic files, provenance, extraction, batches, manifest, annotate.

Registration and measurement are the fakes of ``pipeline_fakes`` (passed as ``steps=STEPS``) so
these tests check the plumbing only, and stay valid whatever the real vision code does.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import math
import multiprocessing as mp
import os

import cv2
import numpy as np
import pandas as pd
import pytest

import pipeline_fakes as fakes
from pipeline_fakes import STEPS
from tympani.pipeline.extract import batch
from tympani.pipeline.extract.batch import extract_batch, output_paths, process_video
from tympani.pipeline.extract.config import ExtractConfig
from tympani.pipeline.extract.manifest import VideoItem, read_manifest
from tympani.pipeline.extract.records import refusal_kind, refusals, refusals_text
from tympani.pipeline.extract.video import (ANGLE_COLUMNS, _window_medians, contact_excursions, contact_losses,
                                           extract_video, flag_contact_loss, flag_excursions, flag_few, flag_glitches,
                                           flag_lone, flag_sparse)
from tympani.pipeline.io import atomic_open, atomic_write_csv, atomic_write_json, atomic_write_text, content_hash, provenance
from tympani.vision.errors import InputError
from tympani.vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM, point_angle

REGISTRATION_KEYS = {"centre_x_px", "centre_y_px", "rotation_rad", "px_per_mm", "mirrored", "residual_px"}


@pytest.fixture
def fake_vision():
    """Settings for the fake steps."""
    return fakes.fake_config()


def _leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.endswith(".tmp") or p.name.startswith(".")]


# --------------------------------------------------------------------------- io


def test_atomic_write_text_replaces_and_keeps_mode(tmp_path):
    target = tmp_path / "sub" / "a.txt"
    atomic_write_text(target, "one")
    atomic_write_text(target, "two")
    assert target.read_text() == "two"
    assert oct(target.stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    assert _leftovers(target.parent) == []


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_crash_while_writing_leaves_old_file_and_no_temp(tmp_path):
    target = tmp_path / "a.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_open(target) as fh:
            fh.write("half of the new cont")
            raise RuntimeError("crash")
    assert target.read_text() == "old" and _leftovers(tmp_path) == []
    with pytest.raises(KeyboardInterrupt):
        with atomic_open(tmp_path / "b.csv") as fh:
            fh.write("x")
            raise KeyboardInterrupt
    assert not (tmp_path / "b.csv").exists() and _leftovers(tmp_path) == []


def test_crash_at_rename_leaves_no_partial_file(tmp_path, monkeypatch):
    def broken_replace(src, dst):
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError):
        atomic_write_json(tmp_path / "x.json", {"a": 1})
    assert list(tmp_path.iterdir()) == []


def test_csv_and_json_formats(tmp_path):
    df = pd.DataFrame({"frame": [0, 1], "theta_tip": [1.5, math.nan], "ok": [True, False]})
    atomic_write_csv(tmp_path / "t.csv", df)
    assert (tmp_path / "t.csv").read_text().splitlines() == ["frame,theta_tip,ok", "0,1.5,true", "1,,false"]
    atomic_write_json(tmp_path / "t.json", {"a": np.float64(math.nan), "b": np.int64(3), "c": np.arange(2),
                                            "cfg": ExtractConfig(measure=None, registration=None)})
    d = json.loads((tmp_path / "t.json").read_text())
    assert d["a"] is None and d["b"] == 3 and d["c"] == [0, 1]
    assert d["cfg"]["recheck_every"] == 150 and d["cfg"]["phantom"]["c_mm"] == pytest.approx(7.967)


def test_content_hash_and_provenance(tmp_path):
    small = tmp_path / "small.bin"
    small.write_bytes(b"abc")
    h1 = content_hash(small)
    small.write_bytes(b"abd")
    assert content_hash(small) != h1 and content_hash(small).startswith("sha256-ends:3:")
    big = tmp_path / "big.bin"
    data = bytearray(os.urandom(3 << 20))
    big.write_bytes(bytes(data))
    h_big = content_hash(big)
    data[len(data) // 2] ^= 0xFF  # the middle is not hashed (documented: a fingerprint)
    big.write_bytes(bytes(data))
    assert content_hash(big) == h_big
    data[-1] ^= 0xFF
    big.write_bytes(bytes(data))
    assert content_hash(big) != h_big
    prov = provenance(big, {"x": 1.0, "cfg": ExtractConfig(measure=None, registration=None)}, n_frames=3)
    for key in ("tool", "version", "created_utc", "input", "params", "environment", "n_frames"):
        assert key in prov
    assert prov["input"]["hash"] == content_hash(big) and prov["input"]["path"] == str(big.resolve())
    assert {"python", "numpy", "opencv"} <= set(prov["environment"])
    json.dumps(prov, allow_nan=False)
    assert content_hash(tmp_path).startswith("sha256-folder:2:")


# --------------------------------------------------------------------------- config


def test_extract_config_defaults_and_validation():
    cfg = ExtractConfig(measure=None, registration=None)
    assert cfg.recheck_every == 150 and cfg.register_frames == 5
    assert cfg.recheck_threshold_px(fakes.FakeRegistration(None, residual_px=1.0)) == pytest.approx(2.6)
    with pytest.raises(ValueError):
        ExtractConfig(measure=None, registration=None, register_frames=0)
    with pytest.raises(ValueError):
        ExtractConfig(measure=None, registration=None, recheck_every=-1)


# --------------------------------------------------------------------------- one video


def test_extract_video_rows_columns_and_failed_frames(tmp_path, fake_vision):
    video = fakes.write_video(tmp_path / "t1.mp4", n=12, dark={3, 4})
    table, reg = extract_video(video, fake_vision, steps=STEPS)
    assert list(table.columns[: len(ANGLE_COLUMNS)]) == list(ANGLE_COLUMNS)
    assert "depth_mm" in table.columns and table.columns[-1] == "reg_epoch"
    assert table["frame"].tolist() == list(range(12)) and (table["trial"] == "t1").all()
    assert np.allclose(table["time_s"], np.arange(12) / 25.0)
    assert table["ok"].dtype == bool and table["ok"].sum() == 10
    bad = table[~table["ok"]]
    assert bad["frame"].tolist() == [3, 4] and bad["theta_tip"].isna().all() and (bad["reason"] == "no array in view").all()
    assert (table.loc[table["ok"], "reason"] == "").all()
    assert reg.to_dict().keys() == REGISTRATION_KEYS and reg.n_frames == 5  # registered once, on 5 frames
    assert len(table.attrs["registrations"]) == 1 and table.attrs["timing_s"]["measure"] >= 0


def test_short_video_registers_on_what_it_has(tmp_path, fake_vision):
    table, reg = extract_video(fakes.write_video(tmp_path / "s.mp4", n=3), fake_vision, steps=STEPS)
    assert len(table) == 3 and reg.n_frames == 3


def test_camera_bump_triggers_re_registration(tmp_path):
    cfg = fakes.fake_config(recheck_every=5, register_frames=2)
    table, reg = extract_video(fakes.write_video(tmp_path / "b.mp4", n=24, bumped_from=12), cfg, steps=STEPS)
    regs = table.attrs["registrations"]
    assert [r["frame"] for r in regs] == [0, 15] and regs[1]["trigger"] == "check"
    assert regs[1]["check_residual_px"] == 50.0 and regs[1]["threshold_px"] == pytest.approx(1.6)
    assert [f for f, _ in table.attrs["checks"]] == [5, 10, 15, 20]
    # the check at 15 saw the move; frames 12-14 (after the passing check at 10) are measured again
    assert regs[1]["moved_at_frame"] == 12
    assert table.loc[table["frame"] < 12, "reg_epoch"].eq(0).all() and table.loc[table["frame"] >= 12, "reg_epoch"].eq(1).all()
    assert any("camera moved at frame 12" in w for w in table.attrs["warnings"])
    assert len(table) == 24 and reg.pose.centre_x_px == fakes.W / 2  # the first registration is returned


def _rows(table, frames) -> list[tuple[int, bool, int]]:
    """(frame, ok, reg_epoch) of the given frames."""
    sub = table[table["frame"].isin(list(frames))]
    return [(int(f), bool(ok), int(e)) for f, ok, e in zip(sub["frame"], sub["ok"], sub["reg_epoch"])]


def test_failed_re_registration_leaves_frames_unmeasured_until_a_registration_fits(tmp_path):
    """Bumped at 7 into a view that cannot be registered (7-9), registrable again from 10. The
    check at 9 fails and registering there fails: the registration is lost, frames are not
    measured with the old pose, and the next try (frame 11) registers. Going back, 7-9 fit
    neither registration (not ok) and 10 fits the new one."""
    cfg = fakes.fake_config(recheck_every=3, register_frames=1)
    video = fakes.write_video(tmp_path / "l.mp4", n=18, bumped_from=7, blocked={7, 8, 9})
    table, _ = extract_video(video, cfg, steps=STEPS)
    assert len(table) == 18
    assert _rows(table, range(7)) == [(f, True, 0) for f in range(7)]
    assert _rows(table, range(7, 10)) == [(f, False, 1) for f in range(7, 10)]
    assert table.loc[table["frame"].between(7, 9), "reason"].str.contains("no registration fits this frame").all()
    assert _rows(table, range(10, 18)) == [(f, True, 1) for f in range(10, 18)]
    regs = table.attrs["registrations"]
    assert [(r["frame"], r["trigger"]) for r in regs] == [(0, "start"), (11, "check")] and regs[1]["moved_at_frame"] == 7
    warnings = table.attrs["warnings"]
    assert any(w.startswith("re-registration at frame 9 failed (") and "too little of the phantom in view" in w
               for w in warnings)
    assert any("frames 7-10: 1 measured again with the new registration, 3 marked not ok" in w for w in warnings)


def test_registration_lost_to_the_end_marks_the_rest_not_ok(tmp_path):
    """Bumped at 7 into a view that never registers: every frame from the move on is not ok
    (7-8 found going back; 9 on while lost), and the tries back off (9, 11, 14; gaps 1, 2, 3
    frames after each try, capped at ``recheck_every``)."""
    cfg = fakes.fake_config(recheck_every=3, register_frames=1)
    video = fakes.write_video(tmp_path / "e.mp4", n=18, bumped_from=7, blocked=set(range(7, 18)))
    table, _ = extract_video(video, cfg, steps=STEPS)
    assert _rows(table, range(7)) == [(f, True, 0) for f in range(7)]
    assert _rows(table, range(7, 18)) == [(f, False, 0) for f in range(7, 18)]
    reasons = table.set_index("frame")["reason"]
    assert reasons[6] == "" and "no registration fits this frame" in reasons[8]
    assert reasons[12].startswith("registration lost: the check at frame 9 failed and registering again failed (")
    assert [f for f, _ in table.attrs["checks"]] == [3, 6, 9, 11, 14]
    assert len(table.attrs["registrations"]) == 1


def test_view_blocked_for_a_while_resumes_with_the_old_registration(tmp_path):
    """The view is blocked (8-10) but the camera did not move: the registration is lost at the
    check at 9, and the next try (11) finds the old registration fits again."""
    cfg = fakes.fake_config(recheck_every=3, register_frames=1)
    video = fakes.write_video(tmp_path / "k.mp4", n=18, blocked={8, 9, 10})
    table, _ = extract_video(video, cfg, steps=STEPS)
    assert _rows(table, range(8)) == [(f, True, 0) for f in range(8)]
    assert _rows(table, range(8, 11)) == [(f, False, 0) for f in range(8, 11)]
    assert _rows(table, range(11, 18)) == [(f, True, 0) for f in range(11, 18)]
    assert len(table.attrs["registrations"]) == 1
    assert any("frames 9-10 not measured (registration lost); the old registration fits again from frame 11" in w
               for w in table.attrs["warnings"])


def _angle_rows(tip, bot) -> list[dict]:
    return [dict(frame=i, ok=True, theta_tip=t, theta_bot=b, theta_con=t - b, reason="")
            for i, (t, b) in enumerate(zip(tip, bot))]


def test_flag_glitches_removes_spikes_and_keeps_ramps_and_steps():
    """A ramp (the tip advancing 0.15 rad a frame, faster than 7.5 mm/s at 30 frames/s), a step
    in theta_bot (a contact run forming), a one-frame spike of 3 rad and a two-frame spike: only
    the spikes' frames are marked."""
    n = 20
    tip = [1.0 + 0.15 * i for i in range(n)]
    bot = [1.0] * 10 + [0.4] * 10  # the step at frame 10
    bot[4] = 4.0  # a one-frame glitch
    tip[14] = tip[15] = 0.2  # a two-frame glitch
    rows = _angle_rows(tip, bot)
    rows[7]["ok"] = False  # an unmeasured frame is skipped, not counted as a neighbour
    assert flag_glitches(rows, 0.25) == 3
    flagged = [r["frame"] for r in rows if not r["ok"]]  # 7 was not ok before
    assert flagged == [4, 7, 14, 15]
    assert rows[4]["reason"].startswith("glitch: theta_bot 4.000 rad, 3.00 rad from its neighbours' median")
    assert math.isnan(rows[4]["theta_tip"]) and math.isnan(rows[14]["theta_con"])
    assert all(r["ok"] for r in rows if r["frame"] not in (4, 7, 14, 15))
    # off, and too few frames to judge
    assert flag_glitches(_angle_rows(tip, bot), 0.0) == 0
    assert flag_glitches(_angle_rows([1.0, 5.0, 1.0, 1.0], [1.0] * 4), 0.25) == 0



@pytest.mark.parametrize("spike, flagged", [(0.0, []), (2.0, [20])])
def test_flag_glitches_allows_for_the_frames_between_measured_ones(spike, flagged):
    """The tip advancing 0.15 rad a frame, measured on frames 0-10, 15 and 20: frame 20 lies 0.75
    rad from its neighbours' median (frame 15's), five frames of the ramp, and is no glitch; 2 rad
    more, it is. (Counting measured frames only, it lay five typical steps off and was marked.)"""
    frames = [*range(11), 15, 20]
    rows = [dict(frame=f, ok=True, theta_tip=1.0 + 0.15 * f, theta_bot=1.0, theta_con=0.15 * f, reason="")
            for f in frames]
    rows[-1]["theta_tip"] += spike
    flag_glitches(rows, 0.25)
    assert [r["frame"] for r in rows if not r["ok"]] == flagged


def test_flag_glitches_finds_spikes_in_every_other_frame():
    """theta_bot on a contact run's plateau (from 1.48 rad, drifting 0.012 rad a frame) with the
    run read back to the entry (0.25 rad) in frames 18, 21 and 23, as on an independent renderer:
    six of the ten steps around frame 21 are a spike's, and counted as typical they hid all three;
    the first frames, a ramp (no contact yet, theta_bot the tip's) measured 2-3 frames apart, stay."""
    frames = [4, 7, *range(9, 30)]
    tip = {f: 0.82 + 0.12 * (f - 4) for f in frames}
    bot = {f: (tip[f] if f <= 10 else 1.48 - 0.012 * (f - 11)) for f in frames}  # contact from frame 11
    for f in (18, 21, 23):
        bot[f] = 0.25
    rows = [dict(frame=f, ok=True, theta_tip=tip[f], theta_bot=bot[f], theta_con=tip[f] - bot[f], reason="")
            for f in frames]
    flag_glitches(rows, 0.25)
    assert [r["frame"] for r in rows if not r["ok"]] == [18, 21, 23]


def test_flag_excursions_marks_a_run_whose_contact_start_goes_away_and_back():
    """Frames 15-22 of a 30-frame insertion read theta_bot 1.5 rad further along than the frames
    around them (the contact arc's base read off the wall frame after frame, past what the
    two-frame glitch filter removes): marked, with the steps and the frames either side named;
    an unmeasured frame inside the run is skipped. The contact start creeping along, and
    stepping once as a contact run forms, are not excursions."""
    rng = np.random.default_rng(16)
    n = 30
    tip = 0.5 + 0.16 * np.arange(n)
    bot = np.r_[np.full(8, 0.35), np.linspace(0.40, 1.30, n - 8)] + rng.normal(0.0, 0.02, n)
    bot[15:23] += 1.5
    rows = _angle_rows(tip, bot)
    rows[21]["ok"] = False
    assert flag_excursions(rows, 0.5) == 7
    assert [r["frame"] for r in rows if not r["ok"]] == list(range(15, 23))
    d_away, d_back = bot[15] - bot[14], bot[23] - bot[22]
    assert rows[15]["reason"] == (f"contact start: frames 15-22 {d_away:+.2f} rad from frame 14, "
                                  f"{d_back:+.2f} back by frame 23")
    assert math.isnan(rows[18]["theta_con"]) and all(r["ok"] for r in rows if not 15 <= r["frame"] <= 22)
    # off; a creeping contact start with one step (a contact run forming at frame 12) stays
    assert flag_excursions(_angle_rows(tip, bot), 0.0) == 0
    steady = np.r_[np.full(12, 2.0), np.full(18, 0.8)] + 0.03 * np.arange(n)
    assert flag_excursions(_angle_rows(tip, steady), 0.5) == 0



def _contact_start_away(gray, registration, phantom, array, cfg):
    """The fake measurement, with frames 8-11 (brightness 30 + 10 i) reading theta_bot 1.5 rad
    further along: the tip and the depth advance steadily throughout."""
    i = round((float(gray[8:, :].mean()) - 30.0) / 10.0)
    bot = 0.5 + 0.02 * i + (1.5 if 8 <= i <= 11 else 0.0)
    m = fakes.fake_measure_frame(gray, registration, phantom, array, cfg)
    return dataclasses.replace(m, theta_tip=2.5 + 0.1 * i, theta_bot=bot, theta_con=2.5 + 0.1 * i - bot,
                               extras={"depth_mm": 2.0 + 0.5 * i})


def test_extract_video_marks_a_contact_start_that_goes_away_and_back(tmp_path):
    """Through the extraction: frames 8-11 of 20 are marked with the reason and a warning says
    how many; with the check off (excursion_rad 0) every frame stays measured."""
    path = fakes.write_video(tmp_path / "e.mp4", n=20)
    steps = dataclasses.replace(STEPS, measure_frame=_contact_start_away)
    table, _ = extract_video(path, fakes.fake_config(), steps=steps)
    assert table.loc[~table["ok"], "frame"].tolist() == [8, 9, 10, 11]
    assert table.loc[table["frame"] == 9, "reason"].item() == ("contact start: frames 8-11 +1.52 rad from frame 7, "
                                                               "-1.48 back by frame 12")
    assert any(w.startswith("4 frame(s) marked not ok: their contact start went over 0.5 rad away")
               for w in table.attrs["warnings"])
    table, _ = extract_video(path, fakes.fake_config(excursion_rad=0.0), steps=steps)
    assert table["ok"].all()

@pytest.mark.parametrize(
    "bot, runs",
    [
        ([1.0] * 6 + [2.0] * 3 + [1.1] * 6, [(6, 8)]),  # away and back: the run between
        ([1.0] * 6 + [0.2] * 3 + [1.1] * 6, [(6, 8)]),  # back towards the entry and forward again
        ([1.0] * 6 + [2.0] * 3 + [3.0] * 6, []),  # two steps the same way: a staircase
        ([1.0] * 6 + [2.5] * 3 + [2.0] * 6, []),  # it comes back less than the frames either side differ
        ([1.0] * 4 + [2.0] * 8 + [1.1] * 3, []),  # more frames away than around: which side is right?
        ([1.0] * 6 + [2.0] * 3 + [1.1] * 6 + [2.2] * 2 + [1.2] * 5, [(6, 8), (15, 16)]),  # two, apart
        ([1.0] * 6 + [2.0] * 3 + [1.1] * 3 + [2.2] * 2 + [1.2] * 4, []),  # to and fro: no reference
        ([1.0, 2.0, 1.0], [(1, 1)]),
        ([1.0, 2.0], []),
    ],
)
def test_contact_excursions_cases(bot, runs):
    """Which stretches between steps of over 0.5 rad are excursions."""
    assert contact_excursions(np.array(bot), 0.5) == runs

_TIP = 0.6 + 0.12 * np.arange(12)


@pytest.mark.parametrize(
    "bot, marked",
    [
        (_TIP - np.r_[0, 0, 0.5, 0.7, 0.9, 1.0, 1.2, 1.3, 1.5, 1.6, 1.8, 2.0], []),  # contact spreading
        (_TIP - np.r_[[0.0] * 5, [0.6] * 7], []),  # a contact run forming
        (_TIP - np.r_[[0.0] * 3, [0.4] * 4, [0.0] * 5], []),  # a short one (0.4 rad) breaking
        (_TIP - np.r_[[0.0] * 3, [1.2] * 4, [0.0] * 5], [(7, 6), (8, 6), (9, 6), (10, 6), (11, 6)]),  # lost
        (_TIP - np.r_[[1.2] * 4, [0.1] * 3, [1.3] * 5], [(4, 3), (5, 3), (6, 3)]),  # lost, then read again
        (_TIP - np.r_[[1.2] * 4, [0.8] * 8], []),  # 0.4 rad shorter: within the limit
        (np.r_[[0.5] * 6, 0.5 + 0.12 * np.arange(1, 7)], []),  # the arc's start sliding with the tip
    ],
)
def test_contact_losses_cases(bot, marked):
    """Which measured frames have lost over 0.5 rad of the contact arc of the frames before
    them, and the frame each is compared with (the last one not marked)."""
    against = contact_losses(_TIP, bot, 0.5)
    assert [(k, int(against[k])) for k in np.flatnonzero(against >= 0)] == marked


def test_flag_contact_loss_marks_a_contact_arc_read_off_the_wall_for_good():
    """The measured angles of an independent renderer's video (walls that show twice, not found;
    the registration 4.7 px off): frames 3-16 read the contact along the outer wall, frames
    21-29 lose it all (0 rad against 1.33) while the truth's arc went on growing, and neither
    the glitch filter nor the excursion check (it never comes back) marked them. Marked, each
    naming the frame it contradicts; the frames before stay, as does every frame with the
    check off."""
    frames = [*range(17), *range(21, 30)]
    tip = [0.591, 0.668, 0.758, 0.848, 0.941, 1.034, 1.126, 1.222, 1.315, 1.410, 1.511, 1.617, 1.726, 1.835, 1.953,
           2.069, 2.190, 2.814, 2.948, 3.077, 3.213, 3.361, 3.502, 3.644, 3.792, 3.944]
    bot = [0.591, 0.668, 0.758, 0.777, 0.789, 0.871, 0.855, 0.840, 0.783, 0.788, 0.843, 0.769, 0.827, 0.819, 0.800,
           0.868, 0.856, *tip[17:]]

    def rows():
        return [dict(frame=f, ok=True, theta_tip=t, theta_bot=b, theta_con=t - b, reason="")
                for f, t, b in zip(frames, tip, bot)]

    r = rows()
    assert flag_contact_loss(r, 0.5) == 9
    assert [x["frame"] for x in r if not x["ok"]] == list(range(21, 30))
    assert r[17]["reason"] == ("contact lost: theta_con 0.00 rad against 1.33 rad in frame 16 (a contact arc going "
                               "in does not shorten by over 0.5 rad)")
    assert math.isnan(r[20]["theta_bot"]) and all(x["ok"] for x in r[:17])
    r = rows()
    assert flag_contact_loss(r, 0.0) == 0 and all(x["ok"] for x in r)


def _contact_lost(gray, registration, phantom, array, cfg):
    """The fake measurement, with a contact arc of 1.2 rad read as none from frame 12 on: the
    tip and the depth advance steadily throughout."""
    i = round((float(gray[8:, :].mean()) - 30.0) / 10.0)
    tip = 2.5 + 0.1 * i
    bot = tip - (1.2 if i < 12 else 0.0)
    m = fakes.fake_measure_frame(gray, registration, phantom, array, cfg)
    return dataclasses.replace(m, theta_tip=tip, theta_bot=bot, theta_con=tip - bot, extras={"depth_mm": 2.0 + 0.5 * i})


def test_extract_video_marks_a_contact_arc_that_is_lost(tmp_path):
    """Through the extraction: frames 12-19 of 20 are marked with the reason and a warning says
    how many; with the check off (excursion_rad 0) every frame stays measured."""
    path = fakes.write_video(tmp_path / "c.mp4", n=20)
    steps = dataclasses.replace(STEPS, measure_frame=_contact_lost)
    table, _ = extract_video(path, fakes.fake_config(), steps=steps)
    assert table.loc[~table["ok"], "frame"].tolist() == list(range(12, 20))
    assert table.loc[table["frame"] == 15, "reason"].item().startswith("contact lost: theta_con 0.00 rad against "
                                                                       "1.20 rad in frame 11")
    assert any(w.startswith("8 frame(s) marked not ok: their contact arc is over 0.5 rad shorter")
               for w in table.attrs["warnings"])
    table, _ = extract_video(path, fakes.fake_config(excursion_rad=0.0), steps=steps)
    assert table["ok"].all()


def test_flag_lone_marks_frames_with_no_measured_neighbour_within_reach():
    """Frames 6 and 10 have no other measured frame within 3 frames (1, 6, 10 and 14 lie 4-5
    apart): marked; 0 and 1 check each other, 17 has 14 three frames away; a video of fewer
    than 7 frames, or a reach of 0, is left alone."""
    def rows(measured, n=20):
        return [dict(frame=i, ok=i in measured, theta_tip=1.0, theta_bot=0.5, theta_con=0.5, reason="")
                for i in range(n)]

    r = rows({0, 1, 6, 10, 14, 17})
    assert flag_lone(r, 3) == 2
    assert [x["frame"] for x in r if x["ok"]] == [0, 1, 14, 17]
    assert r[10]["reason"] == "unchecked: no other frame measured within 3 frames" and math.isnan(r[6]["theta_tip"])
    assert flag_lone(rows({10}), 3) == 1  # alone in its video
    for measured, n, reach in (({0, 1, 6, 10}, 20, 0), ({2}, 6, 3), (set(), 20, 3)):
        r = rows(measured, n)
        assert flag_lone(r, reach) == 0 and sum(x["ok"] for x in r) == len(measured)


def test_flag_sparse_marks_videos_measured_on_at_most_the_share():
    """Frames 2-17 span 16 frames: 8 measured (half) marks all of them, 9 none; a span under
    ten frames, or a share of 0, is left alone; frames not ok before do not count."""
    def rows(measured):
        return [dict(frame=i, ok=i in measured, theta_tip=1.0, theta_bot=0.5, theta_con=0.5, reason="")
                for i in range(20)]

    half = {2, 4, 6, 8, 10, 12, 14, 17}
    r = rows(half)
    note = flag_sparse(r, 0.5)
    assert note == ("8 frame(s) marked not ok: video mostly unread: 8 of the 16 frames from frame 2 to 17 "
                    "measured (at most 50%)")
    assert not any(x["ok"] for x in r) and math.isnan(r[2]["theta_con"])
    assert r[4]["reason"].startswith("video mostly unread") and r[3]["reason"] == ""
    for measured, share in ((half | {3}, 0.5), ({2, 4, 6, 8, 10}, 0.5), (half, 0.0), (set(), 0.5)):
        r = rows(measured)
        assert flag_sparse(r, share) == ""
        assert sum(x["ok"] for x in r) == len(measured)
    # frames without a registration do not count: 8 of the 14 frames with one is more than half
    r = rows(half)
    for x in r:
        if x["frame"] in (3, 5):
            x["reason"] = "registration lost: the check at frame 3 failed"
    assert flag_sparse(r, 0.5) == "" and sum(x["ok"] for x in r) == 8
    r = rows(half - {14})  # 7 of the 14 frames with a registration: half
    for x in r:
        if x["frame"] in (3, 5):
            x["reason"] = "registration lost: the check at frame 3 failed"
    assert flag_sparse(r, 0.5).endswith("7 of the 14 frames from frame 2 to 17 with a registration (2 without) "
                                         "measured (at most 50%)")


def test_flag_stripes_marks_a_video_whose_frames_show_stripes_past_the_tip():
    """Three frames refused for regular stripes past their tip mark every measured frame of the
    video (the array's bands go unseen on the others too); two are left alone, and 0 turns
    the check off."""
    from tympani.pipeline.extract.video import flag_stripes
    from tympani.vision.angles.beyond import STRIPES_PAST_TIP

    def rows(striped):
        return [dict(frame=i, ok=i not in striped, theta_tip=1.0, theta_bot=0.5, theta_con=0.5,
                     reason=STRIPES_PAST_TIP if i in striped else "") for i in range(20)]

    r = rows({2, 9, 15})
    assert flag_stripes(r, 3) == ("17 frame(s) marked not ok: video: 3 frames show regular stripes past their "
                                  "tip (the array's bands unseen?)")
    assert not any(x["ok"] for x in r) and math.isnan(r[0]["theta_tip"]) and r[2]["reason"] == STRIPES_PAST_TIP
    for striped, least in (({2, 9}, 3), ({2, 9, 15}, 0)):
        r = rows(striped)
        assert flag_stripes(r, least) == "" and sum(x["ok"] for x in r) == 20 - len(striped)


def test_flag_few_marks_a_handful_of_frames_in_a_long_video():
    """Four frames measured of twenty, close together: too few to check one another, all marked;
    five are left alone, and so are four of seven (half of the frames with a registration is the
    most marked: 4 of 8 is half, marked; without a registration a frame does not count)."""
    def rows(measured, n=20, lost=()):
        return [dict(frame=i, ok=i in measured, theta_tip=1.0, theta_bot=0.5, theta_con=0.5,
                     reason="registration lost: the check failed" if i in lost else "") for i in range(n)]

    r = rows({3, 5, 6, 8})
    assert flag_few(r, 0.5) == ("4 frame(s) marked not ok: video mostly unread: only 4 of its 20 frames "
                                   "measured, too few to check one another")
    assert not any(x["ok"] for x in r)
    for measured, n, lost, marked in (({3, 5, 6, 7, 8}, 20, (), False), ({1, 2, 3, 4}, 8, (), True),
                                      ({1, 2, 3, 4}, 7, (), False), ({1, 2, 3, 4}, 9, (0,), True),
                                      ({1, 2, 3, 4}, 9, (0, 8), False)):
        r = rows(measured, n, lost)
        assert (flag_few(r, 0.5) != "") == marked, (measured, n, lost)
        assert sum(x["ok"] for x in r) == (0 if marked else len(measured))
    r = rows({3, 5}, 20, (0, 1))
    assert flag_few(r, 0.5).endswith("only 2 of its 18 frames with a registration measured, too few to check "
                                        "one another")
    assert flag_few(rows({3, 5}), 0.0) == ""


def test_extract_video_marks_a_mostly_unread_video_and_says_so(tmp_path):
    """Ten of 20 frames black (no array in view) and frame 2 too: 9 of the 19 frames from 0 to 18
    are measured, and all of them are marked; --sparse-share 0 keeps them (but frame 0, alone,
    without --lone-reach 0), and ten black frames alone (10 of 19 measured) keep them too."""
    from tympani.pipeline.cli import main

    odd = tuple(range(1, 20, 2))
    path = fakes.write_video(tmp_path / "s.mp4", n=20, dark=odd + (2,))
    table, _ = extract_video(path, fakes.fake_config(), steps=STEPS)
    assert not table["ok"].any()
    assert table.loc[table["frame"] == 4, "reason"].item().startswith("video mostly unread: 9 of the 19 frames")
    assert any("9 frame(s) marked not ok: video mostly unread" in w for w in table.attrs["warnings"])
    assert main(["extract", str(path), "--out", str(tmp_path / "off"), "-q", "--sparse-share", "0", "--lone-reach", "0"],
                steps=STEPS) == 0
    assert pd.read_csv(tmp_path / "off" / "s.angles.csv")["ok"].sum() == 9
    # with the lone-frame check, frame 0 (4 frames from frame 4, the next measured) goes too
    assert main(["extract", str(path), "--out", str(tmp_path / "lone"), "-q", "--sparse-share", "0"], steps=STEPS) == 0
    assert pd.read_csv(tmp_path / "lone" / "s.angles.csv")["ok"].sum() == 8
    table, _ = extract_video(fakes.write_video(tmp_path / "t.mp4", n=20, dark=odd), fakes.fake_config(), steps=STEPS)
    assert table["ok"].sum() == 10
    assert main(["extract", str(path), "--out", str(tmp_path / "bad"), "--sparse-share", "1"]) == 2


def test_window_medians_equal_the_clipped_windows_one_by_one():
    rng = np.random.default_rng(0)
    for n in (1, 4, 5, 6, 10, 11, 40):
        x = rng.normal(size=n)
        for before, width in ((2, 5), (5, 10)):
            for n_out in (n, n + 1):
                one_by_one = [np.median(x[max(0, j - before): j - before + width]) for j in range(n_out)]
                assert np.array_equal(_window_medians(x, before, width, n_out), one_by_one)


def test_extract_video_marks_a_glitch_and_says_so(tmp_path):
    """A frame measured 1.7 rad off its neighbours (here a fake measurement of an odd frame) is
    marked not ok in the angles table, with a warning; glitch_rad=0 leaves it to the kinematics
    check (its depth is off the insertion too); with that off too, its theta_bot, 0.75 rad from
    both neighbours, is an excursion of one frame; all three off keep it."""
    path = tmp_path / "g.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (fakes.W, fakes.H))
    for i in range(12):
        writer.write(fakes.frame_image(20 if i == 5 else i))  # frame 5 as bright as frame 20 (theta_tip 2.3 vs 0.8)
    writer.release()
    table, _ = extract_video(path, fakes.fake_config(), steps=STEPS)
    assert table.loc[table["frame"] != 5, "ok"].all() and not table.loc[table["frame"] == 5, "ok"].item()
    assert table.loc[table["frame"] == 5, "reason"].item().startswith("glitch: theta_tip")
    assert any("1 frame(s) marked not ok as glitches" in w for w in table.attrs["warnings"])
    table, _ = extract_video(path, fakes.fake_config(glitch_rad=0.0), steps=STEPS)
    assert table.loc[table["frame"] == 5, "reason"].item().startswith("kinematics: depth")
    assert any("1 frame(s) marked not ok off the constant-speed insertion" in w for w in table.attrs["warnings"])
    table, _ = extract_video(path, fakes.fake_config(glitch_rad=0.0, kinematics_tol_mm=0.0), steps=STEPS)
    assert table.loc[table["frame"] == 5, "reason"].item().startswith("contact start: frame 5 +0.")
    table, _ = extract_video(path, fakes.fake_config(glitch_rad=0.0, kinematics_tol_mm=0.0, excursion_rad=0.0),
                             steps=STEPS)
    assert table["ok"].all()
    # the command line: --glitch-rad reaches the extraction; a negative value is a usage error
    from tympani.pipeline.cli import main

    for rad, ok in (("0.25", False), ("0", True)):
        assert main(["extract", str(path), "--out", str(tmp_path / rad), "-q", "--glitch-rad", rad,
                     "--kinematics-tol", rad if rad == "0" else "0.5", "--excursion-rad", rad if rad == "0" else "0.5"],
                    steps=STEPS) == 0
        angles = pd.read_csv(tmp_path / rad / "g.angles.csv")
        assert bool(angles.loc[angles["frame"] == 5, "ok"].item()) is ok
    assert main(["extract", str(path), "--out", str(tmp_path / "bad"), "--glitch-rad", "-1"]) == 2
    assert main(["extract", str(path), "--out", str(tmp_path / "bad"), "--kinematics-tol", "-1"]) == 2
    assert main(["extract", str(path), "--out", str(tmp_path / "bad"), "--excursion-rad", "-1"]) == 2


def test_registration_failure_is_input_error(tmp_path, fake_vision):
    with pytest.raises(InputError, match="registration failed: no phantom found"):
        extract_video(fakes.write_video(tmp_path / "black.mp4", n=6, all_dark=True), fake_vision, steps=STEPS)


def test_measurement_exception_keeps_the_row(tmp_path, fake_vision):
    def flaky(gray, registration, phantom, array, cfg):
        if gray[8:].mean() > 100:
            raise ValueError("boom")
        return fakes.fake_measure_frame(gray, registration, phantom, array, cfg)

    steps = dataclasses.replace(STEPS, measure_frame=flaky)
    table, _ = extract_video(fakes.write_video(tmp_path / "f.mp4", n=12), fake_vision, steps=steps)
    failed = table[~table["ok"]]
    assert len(table) == 12 and len(failed) > 0
    assert failed["reason"].str.contains("measurement raised ValueError: boom").all()
    assert any("measurement raised" in w for w in table.attrs["warnings"])


def test_process_video_writes_resumes_and_overwrites(tmp_path, fake_vision):
    video = fakes.write_video(tmp_path / "t2.mp4", n=8)
    out = tmp_path / "out"
    res = process_video(video, out, fake_vision, steps=STEPS)
    assert res["status"] == "ok" and res["n_frames"] == 8 and res["n_ok"] == 8
    files = output_paths(out, "t2")
    reg = json.loads(files["registration"].read_text())
    assert REGISTRATION_KEYS <= reg.keys() and reg["registrations"][0]["frame"] == 0
    prov = json.loads(files["provenance"].read_text())
    assert prov["params"]["extract"]["register_frames"] == 5 and prov["n_frames"] == 8
    assert prov["input"]["hash"] == content_hash(video)
    text = files["angles"].read_text().splitlines()
    assert text[0].startswith("trial,frame,time_s,theta_tip,theta_bot,theta_con,ok,reason")
    assert ",true," in text[1]
    back = pd.read_csv(files["angles"])
    assert back["ok"].dtype == bool and len(back) == 8
    mtimes = {k: f.stat().st_mtime_ns for k, f in files.items()}
    again = process_video(video, out, fake_vision, steps=STEPS)
    assert again["status"] == "skipped" and again["n_frames"] == 8 and again["n_ok"] == 8
    assert {k: f.stat().st_mtime_ns for k, f in files.items()} == mtimes
    assert process_video(video, out, fake_vision, overwrite=True, steps=STEPS)["status"] == "ok"
    files["provenance"].unlink()  # an unfinished set is redone
    assert process_video(video, out, fake_vision, steps=STEPS)["status"] == "ok"
    assert _leftovers(out) == []


def test_interrupt_while_writing_leaves_no_outputs(tmp_path, monkeypatch, fake_vision):
    real = batch.atomic_write_json
    calls = []

    def interrupted(path, obj, **kw):
        calls.append(path)
        if str(path).endswith("provenance.json"):
            raise KeyboardInterrupt
        return real(path, obj, **kw)

    monkeypatch.setattr(batch, "atomic_write_json", interrupted)
    with pytest.raises(KeyboardInterrupt):
        process_video(fakes.write_video(tmp_path / "k.mp4", n=4), tmp_path / "out", fake_vision, steps=STEPS)
    assert len(calls) == 2 and list((tmp_path / "out").iterdir()) == []


def test_trial_name_and_folder_input(tmp_path, fake_vision):
    folder = fakes.write_folder(tmp_path / "trial_7", n=6)
    res = process_video(folder, tmp_path / "out", fake_vision, fps=30.0, steps=STEPS)
    assert res["trial"] == "trial_7" and res["n_frames"] == 6
    assert (tmp_path / "out" / "trial_7.angles.csv").exists()
    with pytest.raises(InputError, match="trial name"):
        process_video(folder, tmp_path / "out", fake_vision, fps=30.0, trial="../escape", steps=STEPS)


# --------------------------------------------------------------------------- batches


def _videos(tmp_path):
    good1 = fakes.write_video(tmp_path / "good1.mp4", n=6)
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"this is not a video" * 50)
    good2 = fakes.write_video(tmp_path / "good2.mp4", n=7)
    black = fakes.write_video(tmp_path / "black.mp4", n=5, all_dark=True)
    return [good1, bad, good2, black]


def _check_summary(summary, out):
    assert summary["trial"].tolist() == ["good1", "bad", "good2", "black"]
    assert summary["status"].tolist() == ["ok", "failed", "ok", "failed"]
    assert summary["n_frames"].tolist()[0::2] == [6, 7]
    assert summary.loc[1, "error_kind"] == "input" and "not a video" in summary.loc[1, "error"]
    assert "registration failed" in summary.loc[3, "error"] and "\n" not in "".join(summary["error"])
    assert sorted(p.name for p in out.iterdir()) == sorted(
        f"{t}.{k}" for t in ("good1", "good2") for k in ("angles.csv", "registration.json", "provenance.json")
    )


def test_batch_one_bad_video_among_good_ones(tmp_path, fake_vision):
    out = tmp_path / "out"
    summary = extract_batch(_videos(tmp_path), out, fake_vision, progress=False, steps=STEPS)
    _check_summary(summary, out)
    again = extract_batch(_videos(tmp_path)[::2], out, fake_vision, progress=False, steps=STEPS)
    assert again["status"].tolist() == ["skipped", "skipped"]


def test_batch_with_process_pool_executor(tmp_path, fake_vision):
    out = tmp_path / "out"
    with cf.ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("fork")) as pool:
        summary = extract_batch(_videos(tmp_path), out, fake_vision, executor=pool, progress=False, steps=STEPS)
    _check_summary(summary, out)


def test_batch_with_workers_keyword(tmp_path, fake_vision):
    """A pool of extract_batch's own (forkserver): the fake steps travel pickled to its workers."""
    out = tmp_path / "out"
    _check_summary(extract_batch(_videos(tmp_path), out, fake_vision, workers=2, progress=False, steps=STEPS), out)


def test_batch_items_and_duplicate_trials(tmp_path, fake_vision):
    v = fakes.write_video(tmp_path / "v.mp4", n=4)
    folder = fakes.write_folder(tmp_path / "frames", n=4)
    items = [VideoItem(str(v), trial="a"), {"path": folder, "trial": "b", "fps": 10.0}]
    summary = extract_batch(items, tmp_path / "out", fake_vision, progress=False, steps=STEPS)
    assert summary["status"].tolist() == ["ok", "ok"]
    with pytest.raises(InputError, match="also used"):
        extract_batch([v, v], tmp_path / "out2", fake_vision, progress=False, steps=STEPS)


def test_batch_dict_items_take_video_when_path_is_blank(tmp_path, fake_vision):
    v = fakes.write_video(tmp_path / "v.mp4", n=4)
    summary = extract_batch([{"path": None, "video": str(v), "trial": "a"}], tmp_path / "out", fake_vision,
                            progress=False, steps=STEPS)
    assert summary["status"].tolist() == ["ok"] and summary["path"].tolist() == [str(v)]
    for item in ({"trial": "b"}, {"path": "", "video": None}):  # no video named: a clear error, not os.fspath's
        with pytest.raises(ValueError, match="needs a 'path' or 'video'"):
            extract_batch([item], tmp_path / "out2", fake_vision, progress=False, steps=STEPS)


class _SerialExecutor:
    """The smallest executor: ``submit`` runs at once; futures only have ``result()``."""

    class _Done:
        def __init__(self, value):
            self.value = value

        def result(self):
            return self.value

    def submit(self, fn, *args, **kwargs):
        return self._Done(fn(*args, **kwargs))


def test_batch_with_any_submit_executor(tmp_path, fake_vision):
    out = tmp_path / "out"
    _check_summary(extract_batch(_videos(tmp_path), out, fake_vision, executor=_SerialExecutor(), progress=False,
                                  steps=STEPS), out)


# --------------------------------------------------------------------------- manifest


def _manifest(tmp_path, body: str):
    (tmp_path / "data").mkdir(exist_ok=True)
    for name in ("a.mp4", "a_force.csv", "b.mp4", "b_force.csv"):
        (tmp_path / "data" / name).write_text("x")
    path = tmp_path / "manifest.csv"
    path.write_text(body)
    return path


def test_read_manifest_valid(tmp_path):
    path = _manifest(tmp_path, "# an experiment\ntrial,speed_mm_s,video,force,fps,video_t0_s,note\n"
                               "a,0.5,data/a.mp4,data/a_force.csv,30,,first\n\n"
                               "b,7.5,data/b.mp4,data/b_force.csv,,0.25,\n")
    m = read_manifest(path)
    assert m["trial"].tolist() == ["a", "b"] and m["speed_mm_s"].tolist() == [0.5, 7.5]
    assert m.loc[0, "video"] == str((tmp_path / "data" / "a.mp4").resolve())
    assert m.loc[0, "fps"] == 30.0 and math.isnan(m.loc[1, "fps"])
    assert m["video_t0_s"].tolist() == [0.0, 0.25] and m["line"].tolist() == [3, 5]
    assert m["angles"].isna().all() and m.loc[0, "note"] == "first"


@pytest.mark.parametrize(
    "body, where, message",
    [
        ("trial,video,force\na,data/a.mp4,data/a_force.csv\n", ":1", "missing column(s): speed_mm_s"),
        ("trial,speed_mm_s,force\na,1,data/a_force.csv\n", ":1", "'video' or an 'angles' column"),
        ("trial,speed_mm_s,video,force\na,1,data/a.mp4,data/a_force.csv\na,2,data/b.mp4,data/b_force.csv\n",
         ":3", "duplicate trial 'a' (first on line 2)"),
        ("trial,speed_mm_s,video,force\na,1,data/a.mp4,data/a_force.csv\nb,1,data/nope.mp4,data/b_force.csv\n",
         ":3", "video file 'data/nope.mp4' not found"),
        ("trial,speed_mm_s,video,force\na,fast,data/a.mp4,data/a_force.csv\n", ":2", "speed_mm_s 'fast' is not a number"),
        ("trial,speed_mm_s,video,force\na,-1,data/a.mp4,data/a_force.csv\n", ":2", "positive"),
        ("trial,speed_mm_s,video,force\na,1,data/a.mp4\n", ":2", "3 fields, but the header has 4"),
        ("trial,speed_mm_s,video,force\n", "", "no trials"),
    ],
)
def test_read_manifest_errors_name_file_and_line(tmp_path, body, where, message):
    path = _manifest(tmp_path, body)
    with pytest.raises(InputError) as info:
        read_manifest(path)
    assert str(info.value).startswith(f"{path}{where}: ") and message in str(info.value)


def test_read_manifest_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such manifest"):
        read_manifest(tmp_path / "nope.csv")


# --------------------------------------------------------------------------- annotate / drawing


def test_annotate_frame_draws_on_a_copy():
    from tympani.vision.drawing import annotate_frame

    reg = fakes.FakeRegistration(fakes.CameraPose(320, 240, 0.3, 20.0, mirrored=False))
    image = np.full((480, 640), 90, np.uint8)
    m = fakes.fake_measure_frame(np.full((48, 64), 150, np.uint8), reg, None, None, None)
    out = annotate_frame(image, reg, DEFAULT_PHANTOM, m, labels_px={"tip": (300, 200), "bot": None}, title="t")
    assert out.shape == (480, 640, 3) and out.dtype == np.uint8 and (image == 90).all()
    assert (out != 90).any(axis=2).mean() > 0.01  # walls, array, text
    failed = annotate_frame(image, reg, DEFAULT_PHANTOM, fakes.FakeMeasurement(ok=False, reason="x"))
    assert failed.shape == (480, 640, 3)


def test_text_stays_legible_on_small_frames():
    from tympani.vision.drawing import draw_text

    for width, min_rows in ((320, 8), (640, 9), (1280, 16)):  # Hershey simplex: about 8 px tall at 0.36
        image = np.full((width * 3 // 4, width, 3), 100, np.uint8)
        draw_text(image, ["tip 2.650 rad"])  # white text in a box darkened to 35 %
        lit = np.flatnonzero((image[:, :, 0] > 180).any(axis=1))
        assert lit.size and lit[-1] - lit[0] + 1 >= min_rows, width  # rows the text spans


def test_annotate_video_with_labels(tmp_path, fake_vision):
    from tympani.pipeline.extract.annotate import annotate_video, labels_frame, parse_label

    video = fakes.write_video(tmp_path / "an.mp4", n=12)
    labels = labels_frame([parse_label(["4", "tip=40,20", "bot=30,30"]), parse_label(["9", "tip=50,10"]),
                           parse_label(["99", "tip=1,1"])])
    res = annotate_video(video, tmp_path / "out", fake_vision, frames=[0, 4], labels=labels, mp4=True,
                         steps=STEPS)
    assert sorted(p.name for p in res.images) == ["an.frame000000.png", "an.frame000004.png", "an.frame000009.png"]
    assert res.video is not None and res.video.stat().st_size > 0 and any("99" in w for w in res.warnings)
    cmp = res.comparison
    assert cmp["frame"].tolist() == [4, 9] and cmp["ok_auto"].all()
    pose = fakes.fake_register([np.full((48, 64), 100, np.uint8)], None, None).pose
    expected = point_angle(pose.to_phantom(np.array([[40.0, 20.0]])), DEFAULT_PHANTOM)[0]
    assert cmp.loc[0, "theta_tip_label"] == pytest.approx(expected)
    assert cmp.loc[0, "d_theta_tip"] == pytest.approx(cmp.loc[0, "theta_tip_auto"] - expected)
    assert math.isnan(cmp.loc[1, "theta_bot_label"])
    stored = pd.read_csv(tmp_path / "out" / "an.labels.csv")
    assert stored["frame"].tolist() == [4, 9] and {"tip_x_px", "theta_tip"} <= set(stored.columns)
    assert (tmp_path / "out" / "an.label_compare.csv").exists() and (tmp_path / "out" / "an.annotated.csv").exists()
    assert _leftovers(tmp_path / "out") == []


def test_parse_label_errors():
    from tympani.pipeline.extract.annotate import parse_label

    for tokens in (["x", "tip=1,2"], ["3", "tip=1"], ["3", "nose=1,2"], ["3"]):
        with pytest.raises(InputError):
            parse_label(tokens)


def test_labels_file_comments_and_errors(tmp_path):
    """A labels CSV: ``#`` starts a comment only at the start of a line, blanks around values are
    fine, and a bad value is a one-line error naming its file and column."""
    from tympani.pipeline.extract.annotate import read_labels

    good = tmp_path / "labels.csv"
    good.write_text("# clicked by hand\nframe, tip_x_px, tip_y_px, bot_x_px, bot_y_px\n4, 10.5, 20, , \n"
                    "# frame 2 next\n2, 1, 2, 3, 4\n", encoding="utf-8")
    table = read_labels(good)
    assert table["frame"].tolist() == [2, 4]
    assert table.loc[1, ["tip_x_px", "tip_y_px"]].tolist() == [10.5, 20.0] and np.isnan(table.loc[1, "bot_x_px"])
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,tip_x_px,tip_y_px,bot_x_px,bot_y_px\n1,2 # px,3,4,5\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"bad.csv.*non-numeric value in column tip_x_px"):
        read_labels(bad)


def test_measure_batch_validation():
    assert ExtractConfig().measure_batch >= 1
    with pytest.raises(ValueError, match="measure_batch"):
        ExtractConfig(measure_batch=0)
    with pytest.raises(ValueError, match="measure_batch_mb"):
        ExtractConfig(measure_batch_mb=0.0)
    with pytest.raises(ValueError, match="decoder_threads"):
        ExtractConfig(decoder_threads=0)


def test_pool_workers_decode_on_one_thread(monkeypatch, tmp_path):
    """A worker of a pool (one a core) runs the decoder (unless told otherwise) and BLAS on one
    thread; a serial run keeps their defaults."""
    from threadpoolctl import threadpool_info

    seen, blas = [], []

    def fake(path, out, cfg, **kw):
        seen.append(cfg.decoder_threads)
        blas.append(max((p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"), default=1))
        return {}

    monkeypatch.setattr(batch, "process_video", fake)
    item = VideoItem(str(tmp_path / "v.mp4"))
    cfg = ExtractConfig(measure=None, registration=None)
    batch._run_one(item, "v", str(tmp_path), cfg, None, overwrite=False, single_thread=True, progress=False)
    batch._run_one(item, "v", str(tmp_path), dataclasses.replace(cfg, decoder_threads=3), None, overwrite=False,
                   single_thread=True, progress=False)
    batch._run_one(item, "v", str(tmp_path), cfg, None, overwrite=False, single_thread=False, progress=False)
    assert seen == [1, 3, None]
    assert blas[:2] == [1, 1]


def test_batched_measurement_equals_one_at_a_time(tmp_path):
    """Real vision on a rendered video, with checks every 7 frames: measuring 8 frames at a
    time (vision.angles.measure_frames_batch), or as many as fit in 1 MiB (3 frames of
    640x480), gives the table of measuring one at a time."""
    from tympani.pipeline.devtools.bench import render_bench_video

    video = render_bench_video(tmp_path / "r.mp4", n_frames=30, seed=3)
    one, _ = extract_video(video, ExtractConfig(measure_batch=1, recheck_every=7))
    eight, _ = extract_video(video, ExtractConfig(measure_batch=8, recheck_every=7))
    capped, _ = extract_video(video, ExtractConfig(measure_batch=64, measure_batch_mb=1.0, recheck_every=7,
                                                   decoder_threads=1))
    cols = [c for c in one.columns if not c.endswith("_ms")]
    pd.testing.assert_frame_equal(one[cols], eight[cols])
    pd.testing.assert_frame_equal(one[cols], capped[cols])  # the decoder's threads change nothing either
    assert one["ok"].sum() >= 25 and len(eight.attrs["checks"]) == len(one.attrs["checks"]) >= 3
    assert eight.attrs["timing_s"]["measure"] > 0 and "measure.survey" in eight.attrs["timing_s"]


def test_array_too_small_in_the_image_is_refused_and_said_once(tmp_path):
    """A phantom filmed at 12 px/mm (the array's tip 7.2 px wide, under MeasureConfig.min_tip_px):
    registration works (measured: 11.9974 px/mm), every frame is refused with the reason, and
    the log says it once."""
    from tympani.vision.geometry import CameraPose
    from tympani.vision.rendering import VideoSpec, render_video

    pose = CameraPose(330.0, 250.0, 0.4, 12.0, mirrored=False)
    video = tmp_path / "far.mp4"
    render_video(video, VideoSpec(width=640, height=480, max_frames=8, pose=pose), seed=1)
    table, registration = extract_video(video, ExtractConfig())
    assert abs(registration.pose.px_per_mm - 12.0) < 0.006
    assert not table["ok"].any()
    assert table["reason"].str.startswith("array too small in the image").all()
    said = [w for w in table.attrs["warnings"] if "too small" in w]
    assert len(said) == 1 and "film closer" in said[0]


def test_array_width_pools_the_measured_frames():
    from tympani.pipeline.extract.video import array_width

    rows = [{"ok": True, "width_ratio": 1.2}] * 9
    rows += [{"ok": False, "width_ratio": 5.0}, {"ok": True, "width_ratio": float("nan")}, {"ok": True}]  # none counts
    few = array_width(rows, DEFAULT_ARRAY)
    assert few["frames"] == 9 and few["median"] == pytest.approx(1.2) and few["warning"] == ""  # too few to tell
    wide = array_width(rows + [{"ok": True, "width_ratio": 1.18}], DEFAULT_ARRAY)
    assert wide["frames"] == 10 and "looks 20% wider" in wide["warning"] and "0.6 mm at the tip" in wide["warning"]
    narrow = array_width([{"ok": True, "width_ratio": 0.88}] * 10, DEFAULT_ARRAY)
    assert "looks 12% narrower" in narrow["warning"]
    assert array_width([{"ok": True, "width_ratio": 1.09}] * 10, DEFAULT_ARRAY)["warning"] == ""  # within 10 %
    empty = array_width([], DEFAULT_ARRAY)
    assert empty["frames"] == 0 and math.isnan(empty["median"]) and empty["warning"] == ""


def test_a_long_reason_is_broken_into_lines_that_fit_the_frame():
    """A reason wider than the frame is written in full over several lines, none running past
    the frame's right edge (it was cut at 80 characters and at the edge)."""
    from tympani.vision.drawing import angle_lines, draw_text

    reason = "the array's bands show beside the dark run, not on it (its shadow followed?)"
    lines = angle_lines(fakes.FakeMeasurement(ok=False, reason=reason))
    for width in (320, 640, 800):
        image = np.full((width * 3 // 4, width, 3), 100, np.uint8)
        draw_text(image, lines)
        lit = np.flatnonzero((image[:, :, 0] > 180).any(axis=0))
        assert lit[-1] < width - 2, width  # the text ends inside the frame
        box = np.flatnonzero((image[:, 8, 0] < 60))  # the darkened box's rows, at its left margin
        four = draw_text(np.full_like(image, 100), ["tip", "bot", "con", "not ok"])
        if width == 320:  # no room for the reason on one line: more lines, not a cut
            assert box.size > np.count_nonzero(four[:, 8, 0] < 60)


@pytest.mark.parametrize("reason, kind", [
    ("kinematics: depth 3.10 mm is +0.61 mm off the constant-speed insertion (0.5 mm/s)", "kinematics"),
    ("contact start unclear: 1.52 rad further with the gaps 2 px narrower", "contact start unclear"),
    ("centre line across a wall into the next turn (tip read at 3.1 rad)",
     "centre line across a wall into the next turn"),
    ("no array edges within 1 mm of the dark run's end", "no array edges within 1 mm of the dark run's end"),
    ("bright bands go on past the dark run's end (the array out of a shadow?)",
     "bright bands go on past the dark run's end (the array out of a shadow?)"),
    ("array too small in the image: its tip is 3.1 px wide at 16 px/mm (at least 5 px needed; film closer)",
     "array too small in the image"),
    ("measurement raised ValueError: bad shape", "measurement raised ValueError"),
    ("", "not measured"),
])
def test_refusal_kind_leaves_out_what_is_particular_to_the_frame(reason, kind):
    assert refusal_kind(reason) == kind


def test_refusals_count_kinds_most_frames_first():
    reasons = ["glitch: theta_tip 2.1 rad", "array edges not found", "glitch: theta_bot 0.4 rad", "tip out of view",
               "array not in channel", "array not in channel", "glitch: theta_tip 2.3 rad", "unchecked: no other"]
    counts = refusals(reasons)
    assert counts == {"glitch": 3, "array not in channel": 2, "array edges not found": 1, "tip out of view": 1,
                      "unchecked": 1}
    assert refusals_text(counts) == "glitch: 3; array not in channel: 2; array edges not found: 1; 2 other kinds: 2"
    assert refusals_text(counts, top=4) == ("glitch: 3; array not in channel: 2; array edges not found: 1; "
                                            "tip out of view: 1; 1 other kind: 1")
    assert refusals_text(refusals([])) == ""

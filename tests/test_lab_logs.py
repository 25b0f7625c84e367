"""A lab's own logs through a log format file: the synced table, the commands, the bad inputs.

The logs are written by :mod:`lab_logs` in the forms of a real lab's files (ROS CSVs with epoch
stamps, newtons with a sign and a gain, a 250 Hz stage log, a 60 frames/s tracker in degrees whose
zero is the stage's motion start), for trials unlike each other: other speeds, depths, clocks,
units, gains, tracks that stop early.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lab_logs import LabTrial, depth_at, lab_format, tip_of_depth, write_lab_experiment, write_lab_trial
from tympani.pipeline.cli import main
from tympani.pipeline.force.labstreams import Clock


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _err_lines(err: str) -> list[str]:
    assert "Traceback" not in err
    return [line for line in err.splitlines() if line.strip()]


#: Trials unlike each other: speed (mm/s), depth (mm), clock unit, force unit, sign, gain, track end.
TRIALS = {
    "slow_ns": LabTrial(speed_mm_s=0.8, depth_mm=18.0, rest_before_s=3.1, time_unit="ns"),
    "fast_us_mN": LabTrial(speed_mm_s=2.0, depth_mm=24.0, rest_before_s=1.4, time_unit="us", force_unit="mN",
                           sign=1, gain=0.93, epoch_ns=1_600_000_000_123_456_789),
    "ms_g_early": LabTrial(speed_mm_s=1.25, depth_mm=26.5, rest_before_s=5.6, time_unit="ms", force_unit="g",
                           gain=1.12, track_stop_s=15.0),
    "seconds": LabTrial(speed_mm_s=1.5, depth_mm=21.0, rest_before_s=2.2, time_unit="s", stage_lead_s=0.0),
}


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Every trial of TRIALS with its own format file, synced through the command line."""
    folder = tmp_path_factory.mktemp("lab")
    rng = np.random.default_rng(18)
    manifest = write_lab_experiment(folder, TRIALS, rng, formats={k: lab_format(t) for k, t in TRIALS.items()})
    code = main(["sync", "--manifest", str(manifest), "--out", str(folder / "synced.csv"), "-q"])
    assert code == 0
    synced = pd.read_csv(folder / "synced.csv", dtype={"trial": str})
    report = json.loads((folder / "synced.sync.json").read_text())
    return folder, synced, {t["trial"]: t for t in report["trials"]}


def _raw_force_g(path: Path, trial: LabTrial) -> np.ndarray:
    from lab_logs import G_PER_UNIT

    raw = pd.read_csv(path)["field.Fz"].to_numpy(float)
    return raw * G_PER_UNIT[trial.force_unit] * trial.sign * trial.gain


def _stage(path: Path, trial: LabTrial) -> tuple[np.ndarray, np.ndarray]:
    """The stage log's times on the force clock (s) and depths (mm), read independently."""
    from lab_logs import NS_PER

    stage = pd.read_csv(path, dtype={"%time": str})
    force = pd.read_csv(path.with_name(path.name.replace("_stage", "_force")), dtype={"%time": str})
    k = NS_PER[trial.time_unit]

    def ns(text: pd.Series) -> np.ndarray:
        if trial.time_unit == "s":
            return np.array([int(a) * k + int(b.ljust(9, "0")) for a, b in (v.split(".") for v in text)], dtype=np.int64)
        return text.astype(np.int64).to_numpy() * k

    origin = ns(force["%time"])[0]
    return (ns(stage["%time"]) - origin) / 1e9, stage["field0"].to_numpy(float)


@pytest.mark.parametrize("name", list(TRIALS))
def test_synced_force_equals_the_raw_log_after_unit_sign_and_gain(lab, name):
    folder, synced, _ = lab
    rows = synced[synced["trial"] == name]
    raw = _raw_force_g(folder / f"{name}_force.csv", TRIALS[name])
    assert len(rows) == raw.size
    assert rows["force_g"].max() == pytest.approx(raw.max(), rel=0.03)
    np.testing.assert_allclose(rows["force_g"].to_numpy(), raw, rtol=1e-9, atol=1e-9)
    assert rows["force_g"].max() > 10 * abs(rows["force_g"].min())  # pushing reads positive


@pytest.mark.parametrize("name", list(TRIALS))
def test_depth_matches_the_stage_log(lab, name):
    """The synced depth is the stage log's, on the force clock (measured: at most 2e-7 mm from the
    stage log, 0.0011 mm from the true motion)."""
    folder, synced, info = lab
    trial = TRIALS[name]
    rows = synced[synced["trial"] == name]
    t_stage, d_stage = _stage(folder / f"{name}_stage.csv", trial)
    t = rows["time_s"].to_numpy(float)
    have = np.isfinite(rows["depth_mm"].to_numpy(float))
    assert have.mean() > 0.99
    expected = np.interp(t[have], t_stage, d_stage)
    assert np.max(np.abs(rows["depth_mm"].to_numpy(float)[have] - expected)) < 1e-6
    assert np.max(np.abs(rows["depth_mm"].to_numpy(float)[have] - depth_at(t[have], trial))) < 0.0025
    motion = info[name]["depth"]["motion"]
    assert motion["start_s"] == pytest.approx(trial.rest_before_s, abs=0.02)
    assert motion["stopped"] and motion["stop_s"] == pytest.approx(trial.rest_before_s + trial.motion_s, abs=0.02)
    assert motion["speed_mm_s"] == pytest.approx(trial.speed_mm_s, rel=0.01)
    assert info[name]["method"] == "format:motion_start"
    assert info[name]["offset_s"] == pytest.approx(motion["start_s"])


@pytest.mark.parametrize("name", list(TRIALS))
def test_tip_angle_at_a_depth_matches_the_tracker(lab, name):
    """The synced tip angle is the tracker's at the same moment (measured: at most 0.0081 rad from
    the angle of the depth, 0.0035 rad from the tracker's own record)."""
    folder, synced, _ = lab
    trial = TRIALS[name]
    rows = synced[synced["trial"] == name]
    tip = rows["theta_tip"].to_numpy(float)
    depth = rows["depth_mm"].to_numpy(float)
    have = np.isfinite(tip) & np.isfinite(depth) & (depth > 0.5)
    assert have.sum() > 100
    assert np.max(np.abs(tip[have] - tip_of_depth(depth[have]))) < 0.016
    track = pd.read_csv(folder / f"{name}_angles.csv")  # the tracker at the same moment, on its own clock
    t_track = rows["time_s"].to_numpy(float)[have] - trial.rest_before_s
    inside = (t_track >= track["time"].iloc[0]) & (t_track <= track["time"].iloc[-1])
    at_tracker = np.radians(np.interp(t_track[inside], track["time"], track["angle"]))
    assert np.max(np.abs(tip[have][inside] - at_tracker)) < 0.007
    assert np.nanmax(tip) > 2 * np.pi  # a 3-D phantom's tip angles pass 2π and are kept
    assert rows["theta_bot"].isna().all() and rows["theta_con"].isna().all()  # a tip-only track


@pytest.mark.parametrize("name", list(TRIALS))
def test_log_force_rises_with_the_tip_angle(lab, name):
    """The data behind 'bounds --angle theta_tip': ln F against theta_tip has a positive slope."""
    _, synced, _ = lab
    rows = synced[(synced["trial"] == name) & synced["theta_tip"].notna() & (synced["force_g"] > 0)]
    slope, _ = np.polyfit(rows["theta_tip"], np.log(rows["force_g"]), 1)
    assert slope == pytest.approx(0.45, abs=0.1)


def test_a_track_that_stops_early_keeps_its_rows_and_warns(lab):
    folder, synced, info = lab
    trial = TRIALS["ms_g_early"]
    rows = synced[synced["trial"] == "ms_g_early"]
    end = trial.rest_before_s + 15.0
    after = rows["time_s"] > end + 0.05
    assert after.sum() > 100 and rows.loc[after, "theta_tip"].isna().all()
    assert rows.loc[after, "force_g"].notna().all() and rows.loc[after, "depth_mm"].notna().all()
    notes = [w for w in info["ms_g_early"]["warnings"] if "angle track stops" in w]
    assert len(notes) == 1 and notes[0].startswith("trial ms_g_early:") and "stage still moves" in notes[0]


def test_epoch_stamps_stay_exact_until_made_relative():
    """Epoch nanoseconds differ in their last digits; a float64 would round them by 256 ns."""
    e = 1_566_497_791_436_127_452
    stamps = np.array([e, e + 7, e + 20_000_000, e + 20_000_013], dtype=np.int64)
    t = Clock(origin_ns=e).seconds(stamps, "ns")
    np.testing.assert_array_equal(t, [0.0, 7e-9, 0.02, 0.020000013])
    assert (stamps.astype(np.float64) - float(e))[1] != 7.0  # what floats would have made of it
    t_us = Clock(origin_ns=e - e % 1000).seconds(stamps // 1000, "us")
    assert t_us[2] == pytest.approx(0.02, abs=1e-12)


def test_sync_with_the_format_option_and_the_report(tmp_path, capsys):
    """``--format`` applies a log format to every manifest row and the report records it (measured:
    the stage's start found to 0.0012 s)."""
    rng = np.random.default_rng(3)
    trials = {"r1": LabTrial(), "r2": LabTrial(rest_before_s=4.0, depth_mm=23.0)}
    manifest = write_lab_experiment(tmp_path, trials, rng)  # no format column: --format for every row
    code, out, err = _run(capsys, "sync", "--manifest", manifest, "--out", tmp_path / "s.csv", "--format",
                          tmp_path / "lab.toml")
    assert code == 0 and not _err_lines(err)
    assert "r1: video_t0_s " in out and "(format:motion_start)" in out
    assert "depth log: the stage starts at 2.69" in out and "stops at 18.7 s" in out and "20 mm at 1.25 mm/s" in out
    report = json.loads((tmp_path / "s.sync.json").read_text())
    assert [t["offset_s"] for t in report["trials"]] == pytest.approx([2.7, 4.0], abs=0.005)
    assert report["log_format"] == str((tmp_path / "lab.toml").resolve())
    r1 = report["trials"][0]
    assert r1["format_path"] == str(tmp_path / "lab.toml") and r1["clock_origin"] == f"{LabTrial().epoch_ns} ns"
    assert r1["depth"]["motion"]["start_uncertainty_s"] < 0.0025
    # without the format the same manifest is read in tympani's own form: a missing column, named
    code, out, err = _run(capsys, "sync", "--manifest", manifest, "--out", tmp_path / "t.csv")
    lines = _err_lines(err)
    assert code == 2 and len(lines) == 2 and all("missing column(s) time_s, force_g or force_N" in x for x in lines)


def test_zero_log_and_zero_seconds(tmp_path, capsys):
    """A track on the force log's own clock (epoch stamps) and one whose zero is given in seconds
    (measured: theta_tip at most 0.0069 rad from the truth)."""
    rng = np.random.default_rng(5)
    trial = LabTrial(rest_before_s=2.0, depth_mm=15.0)
    paths = write_lab_trial(tmp_path, "z", trial, rng)
    track = pd.read_csv(paths["angles"])
    epoch = [str(trial.epoch_ns + int(round((t + trial.rest_before_s) * 1e9))) for t in track["time"]]
    pd.DataFrame({"stamp": epoch, "tip": track["angle"]}).to_csv(tmp_path / "z_epoch.csv", index=False)
    log_fmt = lab_format(trial).replace('time_column = "time"\ntime_unit = "s"\nzero = "motion_start"\ntheta_tip = "angle"',
                                        'time_column = "stamp"\ntime_unit = "ns"\nzero = "log"\ntheta_tip = "tip"')
    (tmp_path / "log.toml").write_text(log_fmt)
    (tmp_path / "sec.toml").write_text(lab_format(trial, zero="2.0"))
    (tmp_path / "m.csv").write_text("trial,speed_mm_s,force,depth,angles,format\n"
                                    "A,1.25,z_force.csv,z_stage.csv,z_epoch.csv,log.toml\n"
                                    "B,1.25,z_force.csv,,z_angles.csv,sec.toml\n")
    code, out, err = _run(capsys, "sync", "--manifest", tmp_path / "m.csv", "--out", tmp_path / "s.csv")
    assert code == 0, err
    s = pd.read_csv(tmp_path / "s.csv")
    for name in ("A", "B"):
        rows = s[(s["trial"] == name) & s["theta_tip"].notna()]
        truth = tip_of_depth(depth_at(rows["time_s"], trial))
        assert np.max(np.abs(rows["theta_tip"] - truth)) < 0.014, name
    assert s.loc[s["trial"] == "B", "depth_mm"].isna().all()  # no depth log for B


def test_tracker_with_contact_angles(tmp_path, capsys):
    """A tracker that gives theta_bot too: theta_con follows, and fit sees the contact angles."""
    rng = np.random.default_rng(6)
    trial = LabTrial(depth_mm=16.0)
    paths = write_lab_trial(tmp_path, "c", trial, rng)
    track = pd.read_csv(paths["angles"])
    track["bot"] = np.minimum(track["angle"], 80.0)
    track.to_csv(paths["angles"], index=False)
    (tmp_path / "f.toml").write_text(lab_format(trial, extra={"angles": 'theta_bot = "bot"'}))
    (tmp_path / "m.csv").write_text("trial,speed_mm_s,force,depth,angles,format\n"
                                    "c,1.25,c_force.csv,c_stage.csv,c_angles.csv,f.toml\n")
    assert main(["sync", "--manifest", str(tmp_path / "m.csv"), "--out", str(tmp_path / "s.csv"), "-q"]) == 0
    capsys.readouterr()
    s = pd.read_csv(tmp_path / "s.csv").dropna(subset=["theta_tip"])
    np.testing.assert_allclose(s["theta_con"], np.clip(s["theta_tip"] - s["theta_bot"], 0, None), atol=1e-9)
    assert s["theta_con"].max() > 3.0


def test_spec_depth_log_without_a_format(tmp_path, capsys):
    """A depth log in tympani's own columns (time_s, depth_mm) needs no format: depth_mm and its motion."""
    from force_synth import Trial, make_trial, write_trial

    rng = np.random.default_rng(8)
    angles, log = make_trial(rng, Trial(speed_mm_s=3.0, t0_s=0.5))
    a, f = write_trial(tmp_path, "t", angles, log)
    t = np.arange(0.0, 8.0, 0.004)
    pd.DataFrame({"time_s": t, "depth_mm": 3.0 * np.clip(t - 1.5, 0, 5.0)}).to_csv(tmp_path / "t.depth.csv", index=False)
    (tmp_path / "m.csv").write_text(f"trial,speed_mm_s,force,angles,depth,video_t0_s\nt,3,{f.name},{a.name},t.depth.csv,0.5\n")
    code, out, err = _run(capsys, "sync", "--manifest", tmp_path / "m.csv", "--out", tmp_path / "s.csv")
    assert code == 0, err
    report = json.loads((tmp_path / "s.sync.json").read_text())["trials"][0]
    assert report["depth"]["motion"]["start_s"] == pytest.approx(1.5, abs=0.005)
    s = pd.read_csv(tmp_path / "s.csv")
    inside = s["time_s"].between(0.0, 7.99)
    np.testing.assert_allclose(s.loc[inside, "depth_mm"], 3.0 * np.clip(s.loc[inside, "time_s"] - 1.5, 0, 5.0), atol=1e-6)


# --------------------------------------------------------------------------- what the data lack


@pytest.fixture(scope="module")
def one_speed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("onespeed")
    rng = np.random.default_rng(21)
    trials = {"t1": LabTrial(depth_mm=23.8, rest_before_s=2.7), "t2": LabTrial(depth_mm=26.5, rest_before_s=5.6)}
    manifest = write_lab_experiment(folder, trials, rng, format_column=True)
    assert main(["sync", "--manifest", str(manifest), "--out", str(folder / "synced.csv"), "-q"]) == 0
    return folder, manifest


def test_diagnose_and_fit_say_what_single_speed_tip_only_data_lack(one_speed, capsys):
    folder, _ = one_speed
    code, out, err = _run(capsys, "diagnose", folder / "synced.csv", "--out", folder / "diag")
    lines = _err_lines(err)
    assert code == 2 and len(lines) == 1
    assert "synced.csv: the diagnosis cannot run" in lines[0] and "1 insertion speed (1.25 mm/s: 2 trials)" in lines[0]
    assert "at least 3 speeds" in lines[0] and "no theta_bot or theta_con" in lines[0]
    assert not (folder / "diag" / "diagnosis.json").exists()
    code, out, err = _run(capsys, "fit", folder / "synced.csv", "--out", folder / "fit")
    lines = _err_lines(err)
    assert code == 2 and len(lines) == 1
    assert "the friction-model fit cannot run" in lines[0] and "no theta_bot or theta_con" in lines[0]
    assert "bounds --angle theta_tip" in lines[0]


def test_run_finishes_and_its_report_says_what_the_data_lack(one_speed, capsys):
    folder, manifest = one_speed
    code, out, err = _run(capsys, "run", "--manifest", manifest, "--out", folder / "run", "-q")
    assert "Traceback" not in err
    record = json.loads((folder / "run" / "run.json").read_text())
    stages = record["stages"]
    assert stages["sync"]["status"] == "ok" and stages["report"]["status"] == "ok"
    assert stages["fit"]["status"] == "not_run" and "no theta_bot or theta_con" in stages["fit"]["message"]
    assert stages["diagnose"]["status"] == "not_run" and "1.25 mm/s: 2 trials" in stages["diagnose"]["message"]
    html = (folder / "run" / "report.html").read_text()
    assert "1 insertion speed (1.25 mm/s: 2 trials)" in html and "friction-model fit cannot run" in html
    assert not any("fit cannot run" in e or "diagnosis cannot run" in e for e in record["errors"])


# --------------------------------------------------------------------------- bad input


def _two_trials(folder: Path, bad_format: str | None = None, **bad: LabTrial) -> tuple[Path, dict[str, Path]]:
    """A good trial 'good' and a trial 'bad' (its own format file when ``bad_format``)."""
    rng = np.random.default_rng(33)
    trials = {"good": LabTrial(depth_mm=12.0), "bad": bad.get("trial", LabTrial(depth_mm=12.0))}
    formats = {"good": lab_format(trials["good"])}
    if bad_format is not None:
        formats["bad"] = bad_format
    else:
        formats["bad"] = lab_format(trials["bad"])
    manifest = write_lab_experiment(folder, trials, rng, formats=formats)
    return manifest, {"force": folder / "bad_force.csv", "depth": folder / "bad_stage.csv",
                      "angles": folder / "bad_angles.csv", "format": folder / "bad.toml"}


def _only_bad_fails(capsys, folder: Path, manifest: Path, *fragments: str) -> str:
    code, out, err = _run(capsys, "sync", "--manifest", manifest, "--out", folder / "s.csv")
    lines = _err_lines(err)
    assert code == 2 and len(lines) == 1, err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert "1 trial(s) synced, 1 failed" in out
    s = pd.read_csv(folder / "s.csv")
    assert set(s["trial"]) == {"good"} and s["theta_tip"].notna().sum() > 100
    return lines[0]


def test_bad_unknown_key(tmp_path, capsys):
    fmt = lab_format(LabTrial()).replace('column = "field.Fz"', 'colum = "field.Fz"')
    manifest, p = _two_trials(tmp_path, fmt)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['format']}: [force] unknown key 'colum'")


def test_bad_unit_not_listed(tmp_path, capsys):
    fmt = lab_format(LabTrial()).replace('unit = "deg"', 'unit = "grad"')
    manifest, p = _two_trials(tmp_path, fmt)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['format']}: [angles] unit 'grad' is not one of rad, deg")


def test_bad_missing_column(tmp_path, capsys):
    fmt = lab_format(LabTrial()).replace('column = "field0"', 'column = "position"')
    manifest, p = _two_trials(tmp_path, fmt)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['depth']}:1: [depth] column 'position' is not a column of the log")


@pytest.mark.parametrize("stream, key", [("force", "[force] time_column '%time'"), ("depth", "[depth] time_column '%time'"),
                                         ("angles", "[angles] time_column 'time'")])
def test_bad_clock_goes_backwards(tmp_path, capsys, stream, key):
    manifest, p = _two_trials(tmp_path)
    lines = p[stream].read_text().splitlines()
    lines[40], lines[41] = lines[41], lines[40]
    p[stream].write_text("\n".join(lines) + "\n")
    _only_bad_fails(capsys, tmp_path, manifest, f"{p[stream]}:42: {key} goes backwards", "on line 41")


def test_bad_depth_log_never_moves(tmp_path, capsys):
    manifest, p = _two_trials(tmp_path)
    stage = pd.read_csv(p["depth"], dtype={"%time": str})
    stage["field0"] = 1.6e-5
    stage.to_csv(p["depth"], index=False)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['depth']}: [depth] column 'field0' never moves")


def test_bad_streams_do_not_overlap(tmp_path, capsys):
    manifest, p = _two_trials(tmp_path)
    stage = pd.read_csv(p["depth"], dtype={"%time": str})
    stage["%time"] = (stage["%time"].astype(np.int64) + 3_600_000_000_000).astype(str)  # an hour later
    stage.to_csv(p["depth"], index=False)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['depth']}: [depth] time_column '%time'", "do not overlap in time")


def test_bad_angle_track_does_not_overlap(tmp_path, capsys):
    fmt = lab_format(LabTrial(), zero="500.0")
    manifest, p = _two_trials(tmp_path, fmt)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['angles']}: [angles] zero '500'", "do not overlap in time")


def test_bad_motion_start_without_a_depth_log(tmp_path, capsys):
    manifest, p = _two_trials(tmp_path)
    text = manifest.read_text().replace("bad_stage.csv", "")
    manifest.write_text(text)
    _only_bad_fails(capsys, tmp_path, manifest, f"{p['format']}: [angles] zero 'motion_start' needs the trial's depth log")


def test_bad_format_option_stops_the_command(tmp_path, capsys):
    manifest, _ = _two_trials(tmp_path)
    (tmp_path / "x.toml").write_text("[force]\ntime_column = \"%time\"\ncolumn = \"field.Fz\"\nunit = \"N\"\nsign = 2\n")
    for command in ("sync", "run"):
        out_flag = tmp_path / ("s.csv" if command == "sync" else "run")
        code, out, err = _run(capsys, command, "--manifest", manifest, "--out", out_flag, "--format", tmp_path / "x.toml")
        lines = _err_lines(err)
        assert code == 2 and lines == [f"tympani: {tmp_path / 'x.toml'}: [force] sign must be 1 or -1, not 2"], command


def test_a_bag_without_the_optional_rosbags_package_is_one_line(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # as if 'tympani[ros]' were not installed
    (tmp_path / "t.bag").write_bytes(b"#ROSBAG V2.0\n")
    (tmp_path / "f.toml").write_text('[force]\ntopic = "/ati/wrench"\ncolumn = "wrench.force.z"\nunit = "N"\n')
    (tmp_path / "m.csv").write_text("trial,speed_mm_s,force,angles,format\nb,1.25,t.bag,a.csv,f.toml\n")
    (tmp_path / "a.csv").write_text("time_s,theta_tip,theta_bot,theta_con,ok\n0,0,0,0,true\n")
    code, out, err = _run(capsys, "sync", "--manifest", tmp_path / "m.csv", "--out", tmp_path / "s.csv")
    assert code == 2 and _err_lines(err) == [
        f"tympani: {tmp_path / 't.bag'}: [force] topic: reading ROS bags needs the optional package rosbags "
        "(pip install 'tympani[ros]')"]

"""Sync: angles on the force clock, the estimated offset and its uncertainty, the command."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from force_synth import Trial, make_trial, write_experiment, write_trial
from tympani.pipeline.cli import main
from tympani.pipeline.force.sync import (
    SYNC_COLUMNS,
    SYNC_NUMBER_COLUMNS,
    SyncConfig,
    estimate_offset,
    interpolate_angles,
    read_angles_table,
    read_synced,
    report_path,
    sync_manifest,
    sync_trial,
    write_sync,
)
from tympani.vision.errors import InputError


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _err_lines(err: str) -> list[str]:
    assert "Traceback" not in err
    return [line for line in err.splitlines() if line.strip()]


# --------------------------------------------------------------------------- interpolation


def _angles(times, tip, ok=None):
    tip = np.asarray(tip, dtype=float)
    ok = np.ones(tip.size, bool) if ok is None else np.asarray(ok, bool)
    return pd.DataFrame({"time_s": times, "theta_tip": np.where(ok, tip, np.nan),
                         "theta_bot": np.where(ok, tip / 2, np.nan), "theta_con": np.where(ok, tip / 2, np.nan), "ok": ok})


def test_interpolation_is_linear_between_measured_frames():
    a = _angles(np.arange(5) * 0.1, [0.0, 1.0, 2.0, 3.0, 4.0])
    out = interpolate_angles(a, np.array([-0.05, 0.0, 0.15, 0.4, 0.41]), max_gap_s=0.3)
    np.testing.assert_allclose(out["theta_tip"], [np.nan, 0.0, 1.5, 4.0, np.nan])
    np.testing.assert_allclose(out["theta_con"], out["theta_tip"] - out["theta_bot"])


def test_interpolation_bridges_short_gaps_only():
    ok = [True, False, True, False, False, False, True, True]
    a = _angles(np.arange(8) * 0.1, np.arange(8.0), ok)
    out = interpolate_angles(a, np.array([0.05, 0.15, 0.3, 0.45, 0.65]), max_gap_s=0.3)
    assert out["theta_tip"].iloc[0] == pytest.approx(0.5) and out["theta_tip"].iloc[1] == pytest.approx(1.5)
    assert out["theta_tip"].iloc[2:4].isna().all()  # inside the 0.4 s gap of failed frames
    assert out["theta_tip"].iloc[4] == pytest.approx(6.5)


def test_read_angles_table_checks(tmp_path):
    good = tmp_path / "a.angles.csv"
    good.write_text("trial,frame,time_s,theta_tip,theta_bot,theta_con,ok,reason\n"
                    "t,0,0.0,0.2,0.2,0.0,true,\nt,1,0.1,,,,false,blur\nt,2,0.2,,,,true,\n", encoding="utf-8")
    table = read_angles_table(good)
    assert table["ok"].tolist() == [True, False, False]  # ok without angles counts as failed
    assert table.attrs["warnings"]
    bad = tmp_path / "b.angles.csv"
    bad.write_text("frame,time_s,theta_tip,theta_bot,theta_con,ok\n0,0.0,0.2,0.2,0,maybe\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"b\.angles\.csv:2: ok 'maybe' is not true or false"):
        read_angles_table(bad)
    back = tmp_path / "c.angles.csv"
    back.write_text("time_s,theta_tip,theta_bot,theta_con,ok\n0.1,0,0,0,true\n0.1,0,0,0,true\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"c\.angles\.csv:3: time_s does not increase"):
        read_angles_table(back)


# --------------------------------------------------------------------------- offset estimate


@pytest.mark.parametrize(
    "speed, seed",
    [(0.5, 1), (1.5, 2), (3.0, 3), (3.0, 4), (7.5, 5), (7.5, 6)],
)
def test_force_offset_recovered_within_uncertainty(speed, seed):
    rng = np.random.default_rng(seed)
    t0 = float(rng.uniform(-2.0, 4.0))
    angles, log = make_trial(rng, Trial(speed_mm_s=speed, t0_s=t0))
    est = estimate_offset(angles, log)
    period = 1 / 30
    assert est.signal == "force" and est.r2 > 0.99
    assert abs(est.offset_s - t0) <= 2.5 * est.uncertainty_s, (est.offset_s - t0, est)
    assert abs(est.offset_s - t0) <= (3 if speed < 1 else 1) * period  # slow trials: ~1-2.5 frames
    assert est.uncertainty_s <= 2 * period  # honest, not inflated
    assert est.uncertainty_s == pytest.approx(math.sqrt(est.stat_se_s ** 2 + est.angle_noise_s ** 2 + est.timing_se_s ** 2))


def test_uncertainty_is_calibrated_over_many_trials():
    """z = error / uncertainty over 24 trials: most within 2, RMS about 1 (not ≪ 1, not ≫ 1)."""
    rng = np.random.default_rng(11)
    z = []
    for k in range(24):
        t0 = float(rng.uniform(0.0, 3.0))
        trial = Trial(speed_mm_s=(1.5, 3.0, 5.0, 7.5)[k % 4], t0_s=t0, with_depth=bool(k % 2))
        angles, log = make_trial(rng, trial)
        est = estimate_offset(angles, log)
        z.append((est.offset_s - t0) / est.uncertainty_s)
    z = np.abs(np.array(z))
    assert np.mean(z <= 2) >= 0.9
    assert 0.2 <= np.sqrt(np.mean(z ** 2)) <= 1.5


def test_depth_offset_is_sharper_and_measures_sensor_lag():
    rng = np.random.default_rng(7)
    trial = Trial(speed_mm_s=3.0, t0_s=0.777, with_depth=True)
    angles, log = make_trial(rng, trial)
    lag = 0.1
    lagged = log.copy()
    lagged["force_g"] = np.interp(log["time_s"] - lag, log["time_s"], log["force_g"])  # the force arrives late
    est = estimate_offset(angles, lagged)
    assert est.signal == "depth"
    assert abs(est.offset_s - 0.777) <= 2 * est.uncertainty_s and est.uncertainty_s < 0.5 / 30
    assert est.force_lag_s == pytest.approx(lag, abs=0.03)
    forced = estimate_offset(angles, lagged, cfg=SyncConfig(signal="force"))
    assert forced.offset_s == pytest.approx(0.777 + lag, abs=0.03)  # force alignment absorbs the lag


def test_unalignable_data_is_refused():
    rng = np.random.default_rng(8)
    angles, log = make_trial(rng, Trial(speed_mm_s=3.0))
    log["force_g"] = rng.normal(1.0, 0.5, len(log))  # force unrelated to the angles
    with pytest.raises(InputError, match="do not line up"):
        estimate_offset(angles, log, where="m.csv:3")
    flat = angles.assign(theta_con=0.0)
    with pytest.raises(InputError, match="theta_con is constant"):
        estimate_offset(flat, log)


def test_sync_trial_columns_and_failed_frames():
    rng = np.random.default_rng(9)
    trial = Trial(speed_mm_s=3.0, t0_s=1.0)
    angles, log = make_trial(rng, trial, fail_frames=slice(60, 70))
    out = sync_trial(angles, log, trial="x", speed_mm_s=3.0, offset_s=1.0, uncertainty_s=0.01)
    assert list(out.columns[: len(SYNC_COLUMNS)]) == list(SYNC_COLUMNS) and len(out) == len(log)
    vt = out["video_time_s"].to_numpy()
    inside_gap = (vt > 59.5 / 30) & (vt < 69.5 / 30)
    assert out.loc[inside_gap, "theta_con"].isna().all() and inside_gap.sum() > 20
    assert out.loc[(vt < 0) | (vt > angles["time_s"].iloc[-1]), "theta_tip"].isna().all()
    np.testing.assert_allclose(out["time_s"] - out["video_time_s"], 1.0)


# --------------------------------------------------------------------------- manifest


def _experiment(folder: Path, rng, **kw) -> Path:
    trials = {"a": Trial(speed_mm_s=3.0, t0_s=0.5), "b": Trial(speed_mm_s=7.5, t0_s=1.5, with_depth=True),
              "c": Trial(speed_mm_s=7.5, t0_s=2.0)}
    return write_experiment(folder, rng, trials, **kw)


def test_sync_manifest_estimates_blank_offsets(tmp_path):
    manifest = _experiment(tmp_path, np.random.default_rng(10))
    result = sync_manifest(manifest)
    assert not result.failed
    truth = {"a": 0.5, "b": 1.5, "c": 2.0}
    for t in result.trials:
        assert t.method.startswith("estimate:") and abs(t.offset_s - truth[t.trial]) <= 2.5 * t.uncertainty_s
    assert set(result.table["trial"]) == {"a", "b", "c"}
    assert result.table.loc[result.table["trial"] == "b", "depth_mm"].notna().all()


def test_manifest_offsets_are_used_and_checked(tmp_path):
    """The manifest's video_t0_s is used as given and checked against the estimate, which finds
    the true 0.5 s when asked (measured: 0.0074 s off)."""
    manifest = _experiment(tmp_path, np.random.default_rng(12), give_t0=True)
    result = sync_manifest(manifest)
    assert [t.method for t in result.trials] == ["manifest"] * 3
    assert [t.offset_s for t in result.trials] == [0.5, 1.5, 2.0]
    assert all(not t.warnings for t in result.trials)
    text = manifest.read_text().replace(",0.5\n", ",0.9\n")  # trial a: wrong by 0.4 s
    manifest.write_text(text)
    result = sync_manifest(manifest)
    assert any("disagrees" in w for w in result.trials[0].warnings)
    estimated = sync_manifest(manifest, cfg=SyncConfig(t0="estimate"))
    assert abs(estimated.trials[0].offset_s - 0.5) < 0.015


def test_bad_trials_fail_alone(tmp_path):
    manifest = _experiment(tmp_path, np.random.default_rng(13))
    (tmp_path / "b.force.csv").unlink()
    log = (tmp_path / "c.force.csv").read_text().splitlines()
    log[10], log[11] = log[11], log[10]  # time goes backwards on file line 12
    (tmp_path / "c.force.csv").write_text("\n".join(log) + "\n")
    result = sync_manifest(manifest)
    status = {t.trial: t for t in result.trials}
    assert status["a"].status == "ok"
    assert status["b"].status == "failed" and status["b"].error.startswith(f"{manifest}:3: force log")
    assert "not found" in status["b"].error
    assert status["c"].error.startswith(f"{tmp_path / 'c.force.csv'}:12: time_s goes backwards")
    assert set(result.table["trial"]) == {"a"}


def test_angles_dir_for_extract_output(tmp_path):
    rng = np.random.default_rng(14)
    angles, log = make_trial(rng, Trial(speed_mm_s=5.0, t0_s=1.0))
    write_trial(tmp_path / "extract", "run1", angles, log)
    (tmp_path / "extract" / "run1.force.csv").rename(tmp_path / "run1.force.csv")
    manifest = tmp_path / "manifest.csv"
    manifest.write_text("trial,speed_mm_s,video,force,video_t0_s\nrun1,5,videos/run1.mp4,run1.force.csv,1.0\n")
    result = sync_manifest(manifest)
    assert result.trials[0].status == "failed" and "--angles-dir" in result.trials[0].error
    result = sync_manifest(manifest, angles_dir=tmp_path / "extract")
    assert result.trials[0].status == "ok" and result.trials[0].offset_s == 1.0


# --------------------------------------------------------------------------- command line


def test_cli_sync_happy_path(tmp_path, capsys):
    manifest = _experiment(tmp_path, np.random.default_rng(15))
    out = tmp_path / "out" / "synced.csv"
    code, stdout, err = _run(capsys, "sync", "--manifest", manifest, "--out", out, "-q")
    assert code == 0, err
    assert _err_lines(err) == [] and "3 trial(s) synced, 0 failed" in stdout
    table = pd.read_csv(out)
    assert list(table.columns[:7]) == list(SYNC_COLUMNS)
    report = json.loads(report_path(out).read_text())
    assert report["n_ok"] == 3 and report["n_failed"] == 0
    trial = report["trials"][0]
    assert {"offset_s", "uncertainty_s", "method", "estimate", "force_report"} <= set(trial)
    assert trial["estimate"]["frame_period_s"] == pytest.approx(1 / 30)


def test_cli_sync_one_bad_trial_exit_2_one_line(tmp_path, capsys):
    manifest = _experiment(tmp_path, np.random.default_rng(16))
    (tmp_path / "c.force.csv").unlink()
    out = tmp_path / "synced.csv"
    code, stdout, err = _run(capsys, "sync", "--manifest", manifest, "--out", out)
    lines = _err_lines(err)
    assert code == 2 and len(lines) == 1
    assert lines[0].startswith(f"tympani: {manifest}:4: force log") and "not found" in lines[0]
    assert set(pd.read_csv(out)["trial"]) == {"a", "b"}
    assert json.loads(report_path(out).read_text())["n_failed"] == 1


def test_cli_sync_missing_manifest(tmp_path, capsys):
    code, _, err = _run(capsys, "sync", "--manifest", tmp_path / "nope.csv", "--out", tmp_path / "s.csv")
    (line,) = _err_lines(err)
    assert code == 2 and "no such manifest file" in line


def test_depth_ramp_without_standing_frames_falls_back_to_force():
    """Videos that start and end with the robot moving (as tympani's own renders do): depth alone
    cannot pin the offset, so ``auto`` aligns the force, says so, and counts the two alignments'
    disagreement in an uncertainty that stays calibrated over 20 trials."""
    z = []
    for k in range(20):
        rng = np.random.default_rng(100 + k)
        t0 = float(rng.uniform(0.5, 2.0))
        trial = Trial(speed_mm_s=(0.5, 1.5, 3.0, 5.0, 7.5)[k % 5], t0_s=t0, pre_s=0.0, post_s=0.0, with_depth=True)
        angles, log = make_trial(rng, trial)
        est = estimate_offset(angles, log, where="m.csv:2")
        assert est.signal == "force" and any("standing" in w for w in est.warnings)
        z.append((est.offset_s - t0) / est.uncertainty_s)
    z = np.abs(np.array(z))
    assert np.mean(z <= 2) >= 0.9
    assert 0.2 <= np.sqrt(np.mean(z ** 2)) <= 1.5
    with pytest.raises(InputError, match="standing"):
        estimate_offset(angles, log, cfg=SyncConfig(signal="depth"), where="m.csv:2")


# --------------------------------------------------------------------------- reading the synced table


def test_read_synced_reads_what_write_sync_writes(tmp_path):
    manifest = _experiment(tmp_path, np.random.default_rng(17))
    result = sync_manifest(manifest)
    path, _ = write_sync(result, tmp_path / "synced.csv")
    table = read_synced(path)
    written = result.table
    assert list(table.columns) == [*written.columns, "line"]
    assert table["trial"].tolist() == written["trial"].tolist()
    assert table["saturated"].dtype == bool and table["saturated"].tolist() == written["saturated"].tolist()
    for column in SYNC_NUMBER_COLUMNS:
        np.testing.assert_array_equal(table[column].to_numpy(float), written[column].to_numpy(float))
    assert table["line"].tolist() == list(range(2, len(written) + 2))
    # the same numbers, bit for bit, as pandas' parser gives
    pandas = pd.read_csv(path)
    for column in SYNC_NUMBER_COLUMNS:
        assert np.array_equal(table[column].to_numpy(float), pandas[column].to_numpy(float), equal_nan=True)


def test_read_synced_comments_and_hash_in_a_field(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("# synced by hand\ntrial,speed_mm_s,force_g,theta_con,saturated,note\n"
                    "  # a comment line may be indented\n\n"
                    "a#1,0.5,1.5,0.2,yes,see # 3\n"
                    "b,1,2.5,,F,\n")
    table = read_synced(path)
    assert table["trial"].tolist() == ["a#1", "b"] and table["note"].tolist() == ["see # 3", ""]
    assert table["line"].tolist() == [5, 6] and table["saturated"].tolist() == [True, False]
    np.testing.assert_array_equal(table["theta_con"].to_numpy(), [0.2, np.nan])
    path.write_text("trial,speed_mm_s,force_g,theta_con\na,0.5,1.5 # gram,0.2\n")
    with pytest.raises(InputError, match="force_g '1.5 # gram' is not a number") as info:
        read_synced(path)
    assert info.value.path == f"{path}:2"


@pytest.mark.parametrize("content, fragment", [
    (None, "no such synced table"),
    ("", "no header row"),
    ("trial,speed_mm_s\n# only a comment\n", "synced table has no rows"),
    ("trial,speed_mm_s\na,1\nb,1,2\n", "s.csv:3: 3 fields, but the header (line 1) has 2"),
    ("trial,speed_mm_s\na,1\nb,fast\n", "s.csv:3: speed_mm_s 'fast' is not a number"),
    ("trial,speed_mm_s,saturated\na,1,maybe\n", "s.csv:2: saturated 'maybe' is not true or false"),
])
def test_read_synced_bad_input_names_the_line(tmp_path, content, fragment):
    path = tmp_path / "s.csv"
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError) as info:
        read_synced(path)
    assert fragment in str(info.value)


@pytest.mark.parametrize("command", ["fit", "bounds", "diagnose"])
def test_every_analysis_reads_a_hash_in_mid_line_alike(tmp_path, capsys, command):
    from tympani.pipeline.model.friction import FrictionParams
    from tympani.pipeline.model.identify import synthetic_synced

    table = synthetic_synced(FrictionParams(), rng=np.random.default_rng(3), trials=2, samples_per_trial=30)
    text = table.to_csv(index=False).splitlines()
    fields = text[5].split(",")
    fields[text[0].split(",").index("force_g")] += " # note"  # pandas' comment="#" would cut the line here
    text[5] = ",".join(fields)
    path = tmp_path / "synced.csv"
    path.write_text("\n".join(text) + "\n")
    code, _, err = _run(capsys, command, path, "--out", tmp_path / "out")
    lines = _err_lines(err)
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"tympani: {path}:6: ") and "is not a number" in lines[0]

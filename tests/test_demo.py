"""`tympani demo` end to end: render, then `tympani run` (extract with 2 workers in the process that
rendered, sync, fit, bounds, diagnose, report), and the angles against the renderer's truth."""

import json

import pandas as pd

from pipeline.cli import main


def test_demo_runs_everything_and_measures_angles_against_truth(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-q", "--out", str(out), "--seed", "4"]) == 0
    printed = capsys.readouterr().out
    assert "pooled median |error|" in printed and "report.html" in printed
    for path in ["manifest.csv", "synced.csv", "fit/fit.json", "bounds/bounds.json", "bounds/bounds.png",
                 "diagnosis/diagnosis.json", "report.html", "run.json", "trials.csv"]:
        assert (out / path).exists(), path
    synced = pd.read_csv(out / "synced.csv")
    manifest = pd.read_csv(out / "manifest.csv")
    assert set(synced.trial) == set(manifest.trial)
    # the smallest experiment the diagnosis accepts: 3 speeds x 2 repeats, and it does make one
    assert manifest.speed_mm_s.nunique() == 3 and manifest.groupby("speed_mm_s").size().eq(2).all()
    diag = json.loads((out / "diagnosis" / "diagnosis.json").read_text())
    assert diag["verdict"] in ("identified", "ambiguous", "no_gap")
    assert json.loads((out / "truth" / "effect.json").read_text()).get("effect") in (None, "none")
    assert json.loads((out / "fit" / "fit.json").read_text())["rmse_g"] < 0.5
    stages = json.loads((out / "run.json").read_text())["stages"]
    assert all(stages[s]["status"] == "ok" for s in ("extract", "sync", "fit", "bounds", "diagnose"))
    # the angles agree with the renderer's truth on these moderately noisy videos
    from pipeline.demo import angle_errors

    err = angle_errors(out / "angles", out / "truth")
    assert len(err) == 6 and (err.measured > 0.9).all()
    assert err.tip_median.median() <= 0.02 and err.bot_median.median() <= 0.08

"""`tympani demo` end to end: render, extract (2 workers, in the process that rendered), sync, fit, bounds."""

import json

import pandas as pd

from pipeline.cli import main


def test_demo_runs_everything_and_measures_angles_against_truth(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-q", "--out", str(out), "--seed", "4"]) == 0
    printed = capsys.readouterr().out
    assert "pooled median |error|" in printed
    for path in ["manifest.csv", "synced.csv", "fit/fit.json", "bounds/bounds.json", "bounds/bounds.png"]:
        assert (out / path).exists(), path
    synced = pd.read_csv(out / "synced.csv")
    assert set(synced.trial) == set(pd.read_csv(out / "manifest.csv").trial)
    assert json.loads((out / "fit" / "fit.json").read_text())["rmse_g"] < 0.5
    # the angles agree with the renderer's truth on these moderately noisy videos
    from pipeline.demo import angle_errors

    err = angle_errors(out / "angles", out / "truth")
    assert len(err) == 6 and (err.measured > 0.9).all()
    assert err.tip_median.median() <= 0.02 and err.bot_median.median() <= 0.08

"""`tympani demo` end to end: render, then `tympani run` (extract with 2 workers in the process that
rendered, sync, fit, bounds, diagnose, report), the angles against the renderer's truth, and the
seed paper's story: the force falls with speed as in its experiments, through an effect hidden from
the analysis, which the diagnosis finds."""

import json

import pandas as pd

from tympani.pipeline.cli import main


def test_demo_tells_the_papers_story(tmp_path, capsys):
    """Measured: peak force -22.7 % at 3 mm/s and -40.4 % at 7.5 mm/s; lift identified with a
    held-out shrinkage of 67 %; the trials' median |error| (median over the 15 trials) 0.00088 rad
    for theta_tip and 0.0105 rad for theta_bot."""
    out = tmp_path / "demo"
    assert main(["demo", "-q", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "pooled median |error|" in printed and "report.html" in printed
    assert "the paper's experiments -24 %" in printed and "the paper's experiments -43 %" in printed
    for path in ["manifest.csv", "synced.csv", "fit/fit.json", "bounds/bounds.json", "bounds/bounds.png",
                 "diagnosis/diagnosis.json", "report.html", "run.json", "trials.csv"]:
        assert (out / path).exists(), path
    synced = pd.read_csv(out / "synced.csv")
    manifest = pd.read_csv(out / "manifest.csv")
    assert set(synced.trial) == set(manifest.trial)
    assert manifest.speed_mm_s.nunique() == 3 and manifest.groupby("speed_mm_s").size().eq(5).all()
    # the measured drop of the peak force (measured -22.7 % and -40.4 %; the paper's -24 % and -43 %)
    from tympani.pipeline.devtools.demo import angle_errors, force_drops

    drops = force_drops(out / "synced.csv").set_index("speed_mm_s")
    assert -27 < drops.loc[3.0, "change_pct"] < -19 and -47 < drops.loc[7.5, "change_pct"] < -37
    assert -2.5 < drops.loc[7.5, "model_pct"] < -1.0  # the paper's model alone
    truth = json.loads((out / "truth" / "effect.json").read_text())
    assert truth["effect"] == "hydrodynamic_lift"
    diag = json.loads((out / "diagnosis" / "diagnosis.json").read_text())
    assert diag["verdict"] == "identified" and diag["effect"] == "hydrodynamic_lift"
    assert diag["gap"]["shrink_pct"] > 50  # measured 67 %
    bounds = json.loads((out / "bounds" / "bounds.json").read_text())
    assert all(0.92 <= r["heldout_coverage"] <= 0.98 for r in bounds["by_speed"])
    stages = json.loads((out / "run.json").read_text())["stages"]
    assert all(stages[s]["status"] == "ok" for s in ("extract", "sync", "fit", "bounds", "diagnose"))
    # the angles agree with the renderer's truth (measured: tip 0.00088, bot 0.0096 rad)
    err = angle_errors(out / "angles", out / "truth")
    assert len(err) == 15 and (err.measured > 0.95).all()
    assert err.tip_median.median() <= 0.002 and err.bot_median.median() <= 0.02

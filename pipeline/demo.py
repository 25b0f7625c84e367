"""``tympani demo``: render a small synthetic experiment and run tympani on it.

The demo is the quickest way to see the whole tool work without a lab: it renders a few
insertion videos with force logs and exact truth, extracts the angles, checks them against the
truth, synchronises angles and force, identifies the friction model and fits the safety bounds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["angle_errors", "run_demo"]


def angle_errors(angles_dir: str | Path, truth_dir: str | Path) -> pd.DataFrame:
    """Per-trial errors (rad) of extracted angles against the renderer's truth.

    Parameters
    ----------
    angles_dir : path
        Folder with ``<trial>.angles.csv`` from ``tympani extract``.
    truth_dir : path
        Folder with ``<trial>.csv`` truth tables from ``tympani render``.

    Returns
    -------
    pandas.DataFrame
        One row a trial: ``trial, frames, measured`` (fraction of frames with ``ok``),
        ``tip_median, tip_p90, bot_median, bot_p90`` (absolute errors, rad).
    """
    rows = []
    for truth_path in sorted(Path(truth_dir).glob("*.csv")):
        trial = truth_path.stem
        angles_path = Path(angles_dir) / f"{trial}.angles.csv"
        if not angles_path.exists():
            continue
        merged = pd.read_csv(angles_path).merge(pd.read_csv(truth_path), on="frame", suffixes=("", "_true"))
        ok = merged["ok"].astype(str).str.lower().eq("true")
        tip = (merged.theta_tip - merged.theta_tip_true).abs()[ok]
        bot = (merged.theta_bot - merged.theta_bot_true).abs()[ok]
        rows.append(dict(trial=trial, frames=len(merged), measured=float(ok.mean()),
                         tip_median=float(np.median(tip)) if len(tip) else np.nan,
                         tip_p90=float(np.quantile(tip, 0.9)) if len(tip) else np.nan,
                         bot_median=float(np.median(bot)) if len(bot) else np.nan,
                         bot_p90=float(np.quantile(bot, 0.9)) if len(bot) else np.nan))
    return pd.DataFrame(rows)


def run_demo(out_dir: str | Path, *, seed: int = 0, workers: int = 2, quiet: bool = False) -> dict:
    """Render a small experiment into ``out_dir`` and run extract → sync → fit → bounds on it.

    Parameters
    ----------
    out_dir : path
        Output folder; a rerun reuses what is already there.
    seed : int
        Seed of the synthetic experiment.
    workers : int
        Processes for the extraction.
    quiet : bool
        No progress bars.

    Returns
    -------
    dict
        Paths of the outputs and the angle errors against the truth.
    """
    from pipeline.cli import main

    out = Path(out_dir)
    q = ["-q"] if quiet else []
    steps = []
    if not (out / "manifest.csv").exists():
        steps.append(["render", "--out", str(out), "--speeds", "0.5,3,7.5", "--trials", "2",
                      "--max-frames", "60", "--seed", str(seed)])
    steps += [
        ["extract", "--manifest", str(out / "manifest.csv"), "--out", str(out / "angles"), "--workers", str(workers)],
        ["sync", "--manifest", str(out / "manifest.csv"), "--angles-dir", str(out / "angles"),
         "--out", str(out / "synced.csv")],
        ["fit", str(out / "synced.csv"), "--out", str(out / "fit")],
        ["bounds", str(out / "synced.csv"), "--out", str(out / "bounds")],
    ]
    for argv in steps:
        status = main([argv[0], *q, *argv[1:]])
        if status != 0:
            raise RuntimeError(f"tympani {argv[0]} exited with status {status}")
    errors = angle_errors(out / "angles", out / "truth")
    return dict(out=str(out), errors=errors)

"""``tympani demo``: render a small synthetic experiment and run tympani on it.

The demo is the quickest way to see the whole tool work without a lab, and it tells the seed
paper's story: its insertion force falls with speed as the paper's experiments did (−24 % at
3 mm/s and −43 % at 7.5 mm/s against 0.5 mm/s), while the paper's friction model falls by under
2 %. The drop comes from an effect hidden in the force logs, a lubricant film that lifts the array
off the wall as speed rises (the paper's own hypothesis; :data:`tympani.pipeline.synthetic.family_a.PAPER_LIFT`),
which the diagnosis is not told about.

:func:`run_demo` renders a few insertion videos with force logs and exact truth
(:func:`demo_experiment`), runs ``tympani run`` on them (:func:`tympani.pipeline.run.run_pipeline`:
extract, sync, fit, bounds, diagnose, report.html), checks the extracted angles against the truth
(:func:`angle_errors`) and measures the force drop with speed (:func:`force_drops`).

The experiment is the paper's three speeds with five repeats each, 60-frame 640x480 videos and a
2 s dwell after the stop. Five repeats give the held-out checks of the safety bounds something to
work with (a bound fitted to two trials has a very uncertain spread) and the diagnosis a
between-repeat scatter to test against; the repeats share their contact growth across speeds (a
paired design), so the drop is not blurred by placement. It runs in about a minute on 2 cores.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["angle_errors", "force_drops", "run_demo", "DEMO_SPEEDS_MM_S", "DEMO_TRIALS", "DEMO_MAX_FRAMES",
           "DEMO_DWELL_S", "demo_experiment"]

#: Insertion speeds of the demo (mm/s): the paper's slowest, middle and fastest.
DEMO_SPEEDS_MM_S: tuple[float, ...] = (0.5, 3.0, 7.5)
#: Repeats per speed.
DEMO_TRIALS = 5
#: Frames per video (the insertion is filmed at a lower frame rate to fit).
DEMO_MAX_FRAMES = 60
#: Time (s) filmed and logged after the robot stops: what a lagging sensor or a squeezing film
#: does there is what tells them apart.
DEMO_DWELL_S = 2.0


def demo_experiment():
    """The demo's :class:`tympani.pipeline.synthetic.experiment.ExperimentConfig`: the paper's speed drop, hidden."""
    from tympani.pipeline.synthetic.experiment import ExperimentConfig
    from tympani.pipeline.synthetic.family_a import PAPER_LIFT

    return ExperimentConfig(speeds_mm_s=DEMO_SPEEDS_MM_S, trials=DEMO_TRIALS, max_frames=DEMO_MAX_FRAMES,
                            dwell_s=DEMO_DWELL_S, effect="hydrodynamic_lift",
                            effect_params=tuple(PAPER_LIFT.items()), paired=True)


def force_drops(synced_path: str | Path) -> pd.DataFrame:
    """Change (%) of the mean peak force from the slowest speed, measured, beside the paper's.

    Parameters
    ----------
    synced_path : path
        The synced table (``trial``, ``speed_mm_s``, ``time_s``, ``force_g``).

    Returns
    -------
    pandas.DataFrame
        Per speed: ``speed_mm_s``, ``n_trials``, ``peak_force_g`` (mean of the trials' peaks, g),
        ``change_pct`` (measured), ``paper_pct`` (the paper's experiments, NaN where it gives none)
        and ``model_pct`` (the paper's model, scenario S4, from the slowest speed to this one).
    """
    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.model.paper import PAPER_DROPS_PCT, peak_force_change
    from tympani.pipeline.synthetic.family_a import peak_force_drop

    table = peak_force_drop(read_synced(synced_path))
    ref = float(table["speed_mm_s"].iloc[0])
    table["paper_pct"] = [PAPER_DROPS_PCT.get(float(v), np.nan) for v in table["speed_mm_s"]]
    table["model_pct"] = [0.0 if v == ref else peak_force_change("S4", ref, float(v)) for v in table["speed_mm_s"]]
    return table


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


def run_demo(out_dir: str | Path, *, seed: int = 0, workers: int = 2, quiet: bool = False,
             overwrite: bool = False) -> dict:
    """Render a small experiment into ``out_dir`` and run ``tympani run`` on it.

    Parameters
    ----------
    out_dir : path
        Output folder; a rerun reuses what is already there (the rendering when
        ``manifest.csv`` exists, and every stage's up-to-date outputs).
    seed : int
        Seed of the synthetic experiment, the fit's starts and the diagnosis' bootstrap.
    workers : int
        Processes for the extraction.
    quiet : bool
        No progress on stderr.
    overwrite : bool
        Redo every stage of the run (the rendering is kept).

    Returns
    -------
    dict
        ``out`` (str), ``report`` (path of report.html or None), ``run``
        (:class:`tympani.pipeline.run.RunResult`), ``errors`` (:func:`angle_errors`, rad), ``drops``
        (:func:`force_drops`, or None without a synced table).
    """
    import sys
    from dataclasses import replace

    from tympani.pipeline.run import RunConfig, run_pipeline

    out = Path(out_dir)
    if not (out / "manifest.csv").exists():  # render_experiment writes the manifest last
        from tympani.pipeline.synthetic.experiment import render_experiment

        if not quiet:
            print(f"demo: rendering {len(DEMO_SPEEDS_MM_S) * DEMO_TRIALS} videos into {out}", file=sys.stderr)
        render_experiment(out, demo_experiment(), seed=seed)
    base = RunConfig()
    cfg = RunConfig(workers=workers, overwrite=overwrite, progress=not quiet, fit=replace(base.fit, seed=seed),
                    diagnosis=replace(base.diagnosis, seed=seed))
    result = run_pipeline(out / "manifest.csv", out, cfg,
                          command=["tympani", "demo", "--out", str(out), "--seed", str(seed), "--workers", str(workers)])
    errors = angle_errors(out / "angles", out / "truth")
    drops = force_drops(out / "synced.csv") if (out / "synced.csv").exists() else None
    return dict(out=str(out), report=None if result.report is None else str(result.report), run=result, errors=errors,
                drops=drops)

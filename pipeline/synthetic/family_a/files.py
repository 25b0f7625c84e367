"""A family-A dataset written as the files ``tympani sync`` reads, plus its truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from tympani.pipeline.io import atomic_write_csv, atomic_write_json
from tympani.pipeline.synthetic.family_a.truth import DatasetTruth

__all__ = ["write_experiment"]


def write_experiment(out_dir: str | Path, synced: pd.DataFrame, truth: DatasetTruth, *,
                     angles_fps: float | None = None) -> pd.DataFrame:
    """Write a synthetic experiment as the files ``tympani sync`` reads, plus its truth.

    Layout::

        OUT/manifest.csv              trial, speed_mm_s, angles, force, fps, video_t0_s (docs/file-formats.md)
        OUT/angles/<trial>.angles.csv trial, frame, time_s, theta_tip, theta_bot, theta_con, ok, reason
        OUT/force/<trial>.csv         time_s, force_g, depth_mm (force clock)
        OUT/truth/effect.json         the truth's JSON (DatasetTruth.to_json) (never read by the diagnosis)
        OUT/truth/synced.csv          the generator's synced table
        OUT/truth/clean.csv           per row: trial, time_s, force_base_g, force_effect_g (noiseless)

    Parameters
    ----------
    out_dir : path
        Output folder (created).
    synced : pandas.DataFrame
        From :func:`synthetic_dataset`.
    truth : DatasetTruth
        Its truth (``tables.frames`` gives the per-frame angles; with an ``angles_fps`` different
        from the generator's, the synced table's angles are resampled instead).
    angles_fps : float, optional
        Frame rate (1/s) of the angles tables (default: the generator's).

    Returns
    -------
    pandas.DataFrame
        The manifest.
    """
    out = Path(out_dir)
    t0 = float(truth.protocol.video_t0_s)
    gen_fps = float(truth.protocol.angles_fps)
    fps = float(angles_fps) if angles_fps is not None else gen_fps
    frames = truth.tables.frames
    use_frames = abs(fps - gen_fps) < 1e-12
    rows = []
    for trial, part in synced.groupby("trial", sort=False):
        speed = float(part["speed_mm_s"].iloc[0])
        if use_frames:
            ang = frames[frames["trial"] == trial].drop(columns="trial")
        else:
            t_force = part["time_s"].to_numpy(float)
            ok_rows = part[["theta_tip", "theta_bot", "theta_con"]].notna().all(axis=1).to_numpy()
            tv = np.arange(0.0, t_force[ok_rows][-1] - t0 + 1e-9, 1.0 / fps)
            tv = tv[tv + t0 >= t_force[ok_rows][0] - 1e-9]
            ang = pd.DataFrame({"frame": np.arange(tv.size), "time_s": tv})
            for c in ("theta_tip", "theta_bot", "theta_con"):
                ang[c] = np.interp(tv + t0, t_force[ok_rows], part[c].to_numpy(float)[ok_rows])
            ang["ok"] = True
        ang = ang.assign(reason="")
        ang.insert(0, "trial", trial)
        angles_name = Path("angles") / f"{trial}.angles.csv"
        atomic_write_csv(out / angles_name, ang[["trial", "frame", "time_s", "theta_tip", "theta_bot", "theta_con",
                                                  "ok", "reason"]])
        force_name = Path("force") / f"{trial}.csv"
        log = part[["time_s", "force_g"] + (["depth_mm"] if "depth_mm" in part else [])]
        atomic_write_csv(out / force_name, log)
        rows.append(dict(trial=trial, speed_mm_s=speed, angles=str(angles_name), force=str(force_name),
                         fps=fps, video_t0_s=t0))
    manifest = pd.DataFrame(rows)
    atomic_write_csv(out / "manifest.csv", manifest)
    atomic_write_json(out / "truth" / "effect.json", truth.to_json())
    atomic_write_csv(out / "truth" / "synced.csv", synced)
    clean = truth.tables.clean
    if len(clean) == len(synced):
        atomic_write_csv(out / "truth" / "clean.csv",
                         pd.concat([synced[["trial", "time_s"]].reset_index(drop=True), clean.reset_index(drop=True)],
                                   axis=1))
    return manifest

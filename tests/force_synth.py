"""Synthetic insertions with exact truth for the force-side tests (sync, bounds).

One trial: the robot waits ``pre_s``, inserts ``depth_mm`` at ``speed_mm_s``, waits ``post_s``.
The tip angle follows the depth (``theta_tip = 0.18 + 0.22 d + 0.0035 d²`` rad, about 4.3 rad at
15 mm), contact starts at ``theta_tip = 1.4`` rad and ``theta_con = 0.7 (theta_tip − 1.4)``
after it (a hinge, as in the renderer's contact policy). The video samples this at ``fps`` on its
own clock (angle noise ``noise_rad``, theta_con ≥ 0); the force log samples
``exp(c1 theta_con + c2) + noise`` (Eq. 8: c1 the slope, c2 the intercept) at ``rate_hz`` on the force clock, where video time 0 is
force time ``t0_s``, and starts ``log_pre_s`` before the video.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class Trial:
    """Settings of one synthetic trial (units in the names)."""

    speed_mm_s: float = 3.0
    t0_s: float = 1.234
    fps: float = 30.0
    rate_hz: float = 100.0
    noise_rad: float = 0.01
    noise_g: float = 0.05
    c1: float = 1.6
    c2: float = -0.5
    depth_mm: float = 15.0
    pre_s: float = 1.0
    post_s: float = 1.0
    log_pre_s: float = 2.0
    log_post_s: float = 2.0
    with_depth: bool = False


def kinematics(t_video_s: np.ndarray, trial: Trial) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact depth (mm), theta_tip and theta_con (rad) at video times (s)."""
    dur = trial.depth_mm / trial.speed_mm_s
    d = trial.speed_mm_s * np.clip(np.asarray(t_video_s, dtype=float) - trial.pre_s, 0.0, dur)
    tip = 0.18 + 0.22 * d + 0.0035 * d * d
    con = 0.7 * np.maximum(0.0, tip - 1.4)
    return d, tip, con


def make_trial(rng: np.random.Generator, trial: Trial = Trial(), *, name: str = "t1",
               fail_frames: slice | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """An angles table (video clock) and a force log (force clock) of one trial.

    ``fail_frames`` marks a run of frames as not measured (``ok`` false, angles empty).
    """
    span = trial.pre_s + trial.depth_mm / trial.speed_mm_s + trial.post_s
    tv = np.arange(0.0, span, 1.0 / trial.fps)
    _, tip, con = kinematics(tv, trial)
    tip_m = tip + rng.normal(0.0, trial.noise_rad, tv.size)
    con_m = np.maximum(0.0, con + np.where(con > 0, rng.normal(0.0, trial.noise_rad, tv.size), 0.0))
    ok = np.ones(tv.size, dtype=bool)
    if fail_frames is not None:
        ok[fail_frames] = False
    angles = pd.DataFrame({
        "trial": name, "frame": np.arange(tv.size), "time_s": tv,
        "theta_tip": np.where(ok, tip_m, np.nan), "theta_bot": np.where(ok, tip_m - con_m, np.nan),
        "theta_con": np.where(ok, con_m, np.nan), "ok": ok, "reason": np.where(ok, "", "no array"),
    })
    tf = trial.t0_s - trial.log_pre_s + np.arange(0.0, span + trial.log_pre_s + trial.log_post_s, 1.0 / trial.rate_hz)
    d_f, _, con_f = kinematics(tf - trial.t0_s, trial)
    force = np.exp(trial.c1 * con_f + trial.c2) + rng.normal(0.0, trial.noise_g, tf.size)
    log = pd.DataFrame({"time_s": np.round(tf, 6), "force_g": force})
    if trial.with_depth:
        log["depth_mm"] = d_f
    return angles, log


def write_trial(folder: Path, name: str, angles: pd.DataFrame, log: pd.DataFrame) -> tuple[Path, Path]:
    """Write ``<name>.angles.csv`` and ``<name>.force.csv`` (with a comment line) to ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    a = folder / f"{name}.angles.csv"
    f = folder / f"{name}.force.csv"
    out = angles.copy()
    out["ok"] = np.where(out["ok"], "true", "false")
    out.to_csv(a, index=False)
    with open(f, "w", encoding="utf-8") as fh:
        fh.write("# synthetic force log\n")
        log.to_csv(fh, index=False)
    return a, f


def write_experiment(folder: Path, rng: np.random.Generator, trials: dict[str, Trial], *,
                     give_t0: bool = False) -> Path:
    """Write trials and a manifest (``angles`` and ``force`` columns, blank ``video_t0_s`` unless
    ``give_t0``); returns the manifest path."""
    rows = []
    for name, trial in trials.items():
        angles, log = make_trial(rng, trial, name=name)
        a, f = write_trial(folder, name, angles, log)
        rows.append({"trial": name, "speed_mm_s": trial.speed_mm_s, "angles": a.name, "force": f.name,
                     "video_t0_s": trial.t0_s if give_t0 else ""})
    manifest = folder / "manifest.csv"
    pd.DataFrame(rows).to_csv(manifest, index=False)
    return manifest

"""Robotic insertions logged as a lab logs them, with exact truth (for the lab-log tests).

The forms are those of a real lab's files (ROS ``rostopic echo -p`` CSVs and a video tracker's
export), written here from a model so that no lab's data is needed:

- a force log ``%time,field.Fx,field.Fy,field.Fz,field.Tx,field.Ty,field.Tz``: UNIX time in the
  trial's ``time_unit`` (integers, or decimals for seconds), the axial force in ``force_unit``
  with the sensor's sign and divided by the calibration gain, about 50 Hz with jitter;
- a stage log ``%time,field0,...,field5`` on the same clock, about 250 Hz, ``field0`` the depth in
  mm (2 nm noise, written to 1e-6 mm), starting ``stage_lead_s`` before the force log; it stands still ``rest_before_s``, moves ``depth_mm`` at ``speed_mm_s`` and
  stands still again;
- a tracker's tip-angle track ``time,angle,angle_smooth`` in degrees, t = 0 at the stage's motion
  start, 60 frames/s with the tracker's uneven spacing; it can stop early (``track_stop_s``).

Truth: ``depth(t)`` as above (t on the force clock: seconds from the force log's first sample),
``theta_tip = 0.12 + 0.30 d + 0.004 d²`` rad (past 2π beyond about 16 mm), and the force
``exp(-1 + 0.45 theta_tip)`` g while the stage moves (and held after it stops).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

N_PER_G = 9.80665e-3
NS_PER = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
G_PER_UNIT = {"g": 1.0, "mN": 1.0 / (N_PER_G * 1000.0), "N": 1.0 / N_PER_G}


@dataclass(frozen=True)
class LabTrial:
    """Settings of one logged insertion (units in the names)."""

    speed_mm_s: float = 1.25
    depth_mm: float = 20.0
    rest_before_s: float = 2.7
    rest_after_s: float = 6.0
    force_hz: float = 50.0
    stage_hz: float = 250.0
    fps: float = 60.0
    epoch_ns: int = 1_566_497_791_436_127_452
    time_unit: str = "ns"
    force_unit: str = "N"
    sign: int = -1
    gain: float = 1.0679
    stage_lead_s: float = 0.015
    track_stop_s: float | None = None
    noise_g: float = 0.05
    noise_deg: float = 0.15

    @property
    def motion_s(self) -> float:
        """Duration of the motion (s)."""
        return self.depth_mm / self.speed_mm_s


def depth_at(t_s: np.ndarray, trial: LabTrial) -> np.ndarray:
    """True depth (mm) at force-clock times (s)."""
    return trial.speed_mm_s * np.clip(np.asarray(t_s, dtype=float) - trial.rest_before_s, 0.0, trial.motion_s)


def tip_of_depth(d_mm: np.ndarray) -> np.ndarray:
    """True tip angle (rad) at a depth (mm)."""
    d = np.asarray(d_mm, dtype=float)
    return 0.12 + 0.30 * d + 0.004 * d * d


def force_of_tip(theta_tip: np.ndarray) -> np.ndarray:
    """True axial force (g) at a tip angle (rad)."""
    return np.exp(-1.0 + 0.45 * np.asarray(theta_tip, dtype=float))


def _stamps(t_s: np.ndarray, trial: LabTrial) -> list[str]:
    """Force-clock seconds as the log's UNIX stamps, as text (integers but for seconds)."""
    ns = trial.epoch_ns + np.round(np.asarray(t_s) * 1e9).astype(np.int64)
    k = NS_PER[trial.time_unit]
    if trial.time_unit == "s":
        return [f"{v // k}.{v % k:09d}" for v in ns.tolist()]
    return [str(v // k) for v in ns.tolist()]


def _times(rng: np.random.Generator, start: float, end: float, rate_hz: float) -> np.ndarray:
    step = rng.uniform(0.8, 1.2, int((end - start) * rate_hz * 1.3) + 10) / rate_hz
    t = start + np.concatenate([[0.0], np.cumsum(step)])
    return t[t <= end]


def write_lab_trial(folder: Path, name: str, trial: LabTrial, rng: np.random.Generator) -> dict[str, Path]:
    """Write ``<name>_force.csv``, ``<name>_stage.csv`` and ``<name>_angles.csv``; returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    span = trial.rest_before_s + trial.motion_s + trial.rest_after_s
    # force log: its first sample is the force clock's 0
    tf = _times(rng, 0.0, span, trial.force_hz)
    force_g = force_of_tip(tip_of_depth(depth_at(tf, trial))) + rng.normal(0.0, trial.noise_g, tf.size)
    logged = force_g * trial.sign / trial.gain / G_PER_UNIT[trial.force_unit]
    other = rng.normal(0.0, 1e-4, (tf.size, 5))
    paths = {"force": folder / f"{name}_force.csv", "depth": folder / f"{name}_stage.csv",
             "angles": folder / f"{name}_angles.csv"}
    with open(paths["force"], "w", encoding="utf-8") as fh:
        fh.write("%time,field.Fx,field.Fy,field.Fz,field.Tx,field.Ty,field.Tz\n")
        for s, f, o in zip(_stamps(tf, trial), logged.tolist(), other.tolist()):
            fh.write(f"{s},{o[0]:.6g},{o[1]:.6g},{f:.12g},{o[2]:.6g},{o[3]:.6g},{o[4]:.6g}\n")
    # stage log on the same clock, from a little before the force log
    ts = _times(rng, -trial.stage_lead_s, span, trial.stage_hz)
    d = np.round(depth_at(ts, trial) + 1.6e-5 + rng.normal(0.0, 2e-6, ts.size), 6)
    with open(paths["depth"], "w", encoding="utf-8") as fh:
        fh.write("%time,field0,field1,field2,field3,field4,field5\n")
        for s, v in zip(_stamps(ts, trial), d.tolist()):
            fh.write(f"{s},{v:.6f},9e-05,0.0,0.0,0.0,0.0\n")
    # tracker: t = 0 at the motion start, uneven frame spacing, degrees
    stop = trial.motion_s if trial.track_stop_s is None else trial.track_stop_s
    ta = np.round(_times(rng, 0.0, stop, trial.fps), 7)
    angle = np.degrees(tip_of_depth(depth_at(ta + trial.rest_before_s, trial))) + rng.normal(0.0, trial.noise_deg, ta.size)
    with open(paths["angles"], "w", encoding="utf-8") as fh:
        fh.write("time,angle,angle_smooth\n")
        for t, a in zip(ta.tolist(), angle.tolist()):
            fh.write(f"{t:g},{a:.6g},{a:.6g}\n")
    return paths


def lab_format(trial: LabTrial, *, zero: str = '"motion_start"', extra: dict[str, str] | None = None) -> str:
    """The log format file of these logs (TOML), with ``extra`` lines per section appended."""
    extra = extra or {}
    return "\n".join([
        "# a lab's ROS logs and its own tracker",
        "[force]",
        'time_column = "%time"',
        f'time_unit = "{trial.time_unit}"',
        'column = "field.Fz"',
        f'unit = "{trial.force_unit}"',
        f"sign = {trial.sign}",
        f"gain = {trial.gain}",
        extra.get("force", ""),
        "[depth]",
        'time_column = "%time"',
        f'time_unit = "{trial.time_unit}"',
        'column = "field0"',
        'unit = "mm"',
        extra.get("depth", ""),
        "[angles]",
        'time_column = "time"',
        'time_unit = "s"',
        f"zero = {zero}",
        'theta_tip = "angle"',
        'unit = "deg"',
        extra.get("angles", ""),
        "",
    ])


def write_lab_experiment(folder: Path, trials: dict[str, LabTrial], rng: np.random.Generator, *,
                         format_column: bool = False, formats: dict[str, str] | None = None) -> Path:
    """Write the trials, one ``lab.toml`` (or per-trial formats) and ``manifest.csv``; returns the manifest.

    ``formats`` gives a trial its own format file text (written as ``<trial>.toml`` and named in
    the manifest's format column); with ``format_column`` every row names ``lab.toml``.
    """
    formats = formats or {}
    first = next(iter(trials.values()))
    (folder / "lab.toml").parent.mkdir(parents=True, exist_ok=True)
    (folder / "lab.toml").write_text(lab_format(first), encoding="utf-8")
    rows = ["trial,speed_mm_s,force,depth,angles,format"]
    for name, trial in trials.items():
        p = write_lab_trial(folder, name, trial, rng)
        fmt = ""
        if name in formats:
            (folder / f"{name}.toml").write_text(formats[name], encoding="utf-8")
            fmt = f"{name}.toml"
        elif format_column:
            fmt = "lab.toml"
        rows.append(f"{name},{trial.speed_mm_s:g},{p['force'].name},{p['depth'].name},{p['angles'].name},{fmt}")
    manifest = folder / "manifest.csv"
    manifest.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return manifest

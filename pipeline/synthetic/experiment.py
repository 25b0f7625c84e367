"""Synthetic experiments: rendered insertion videos and force logs with a manifest and truth.

``tympani render`` calls :func:`render_experiment`. One experiment is one camera set-up (one
pose, one look) and several trials per insertion speed; trials differ in how the contact run
grows (:class:`tympani.vision.rendering.ContactPolicy`) and in their noise. What is written::

    OUT/manifest.csv           trial, speed_mm_s, video, force, fps, video_t0_s (docs/file-formats.md)
    OUT/videos/<trial>.mp4     (or a PNG folder with --png)
    OUT/force/<trial>.csv      force log: time_s, force_g, depth_mm on the sensor's clock
    OUT/truth/<trial>.csv      per frame: time_s, depth_mm, theta_tip, theta_bot, theta_con, ...
    OUT/truth/pose.json        the camera pose (the registration JSON's keys) and the render settings
    OUT/truth/effect.json      the hidden effect (or null) and its noiseless gap vs the noise

The force is the model of :mod:`tympani.pipeline.model.friction` with the paper's S4 constants as fitted to
its TABLE II (:func:`tympani.pipeline.model.paper.paper_params`) on the true angles, plus sensor noise and 13-bit quantisation; frame 0 of the video is at
``video_t0_s`` on the force log's clock.

With ``ExperimentConfig.effect`` set, a hidden unmodelled effect (docs/diagnosis.md) is applied to the
force logs with the generator forms of :mod:`tympani.pipeline.synthetic.family_a` (not the library forms the
diagnosis fits), and ``OUT/truth/effect.json`` records it: name, strength, parameters, and the
noiseless gap (RMS of the force with minus without the effect) against the noise. The
parameters are drawn from a generator of their own (seeded from ``seed``), so the videos, the
contact growth and the noise are the same with and without an effect.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any
from pathlib import Path

import numpy as np
import pandas as pd

from tympani.vision.rendering import (
    VideoSpec,
    random_appearance,
    random_nuisance,
    random_policy,
    random_pose,
    render_video,
)

from tympani.pipeline.model.friction import FrictionParams, insertion_force
from tympani.pipeline.io import atomic_write_csv, atomic_write_json
from tympani.pipeline.model.paper import paper_params
from tympani.pipeline.synthetic.family_a import (
    EffectTruth,
    TrialState,
    apply_hidden_effect,
    draw_effect_params,
    effect_truth,
    trial_name,
)

__all__ = ["ExperimentConfig", "SensorConfig", "VideoTruth", "clean_forces_from_truth", "force_log_from_truth",
           "render_experiment"]


@dataclass(frozen=True)
class SensorConfig:
    """The force sensor of a synthetic experiment.

    Parameters
    ----------
    rate_hz : float
        Sampling rate (1/s).
    noise_g : float
        Standard deviation of white sensor noise (g).
    range_g : float
        Full scale (g): the A/D covers ``[-range_g, range_g]``.
    bits : int
        A/D resolution.
    lead_s : float
        Time (s) logged before frame 0 of the video (``video_t0_s``).
    """

    rate_hz: float = 100.0
    noise_g: float = 0.05
    range_g: float = 50.0
    bits: int = 13
    lead_s: float = 1.0


@dataclass(frozen=True)
class ExperimentConfig:
    """What a synthetic experiment contains.

    Parameters
    ----------
    speeds_mm_s : tuple of float
        Insertion speeds (mm/s).
    trials : int
        Repeats per speed.
    depth_mm : float
        Final insertion depth (mm).
    fps : float
        Frame rate (1/s).
    max_frames : int or None
        Cap on frames per video (time is subsampled evenly beyond it; fps is then lowered to
        match so that ``frame / fps`` stays the frame time).
    width, height : int
        Frame size (px).
    nuisance : float
        Nuisance strength 0 (clean) to 1 (heavy).
    png : bool
        Write PNG folders instead of mp4 files.
    dwell_s : float
        Time (s) filmed and logged after the robot stops at ``depth_mm``.
    effect : str or None
        Hidden effect (its name, as the diagnosis names it) applied to the force logs, or None.
    strength : float
        Size of the hidden effect (0 absent, 1 typical; see :mod:`tympani.pipeline.synthetic.family_a`).
    effect_params : tuple of (str, float) pairs
        Effect parameters that replace the drawn ones (units in the names), e.g. the lift
        calibrated to the paper's speed drop (:data:`tympani.pipeline.synthetic.family_a.PAPER_LIFT`).
    paired : bool
        Repeat ``k`` at every speed shares its contact growth (a paired design: the change of
        force between speeds is then not blurred by which placements each speed drew).
    """

    speeds_mm_s: tuple[float, ...] = (0.5, 1.5, 3.0, 5.0, 7.5)
    trials: int = 2
    depth_mm: float = 15.0
    fps: float = 30.0
    max_frames: int | None = 120
    width: int = 640
    height: int = 480
    nuisance: float = 0.3
    png: bool = False
    sensor: SensorConfig = SensorConfig()
    dwell_s: float = 0.0
    effect: str | None = None
    strength: float = 1.0
    effect_params: tuple[tuple[str, float], ...] = ()
    paired: bool = False


@dataclass(frozen=True)
class VideoTruth(EffectTruth):
    """The truth of a rendered experiment: its hidden effect, the seed and the sensor.

    Parameters
    ----------
    seed : int
        Seed of everything random (:func:`render_experiment`).
    sensor : SensorConfig
        The force sensor.

    The other parameters are those of :class:`tympani.pipeline.synthetic.family_a.EffectTruth`.
    """

    seed: int
    sensor: SensorConfig

    def to_json(self) -> dict[str, Any]:
        """The JSON object written as ``truth/effect.json``."""
        out = super().to_json()
        out.update(mode="video", seed=self.seed, sensor=asdict(self.sensor))
        return out


def _force_clock(truth: pd.DataFrame, speed_mm_s: float, sensor: SensorConfig):
    """Sample times (s, sensor clock), depth (mm), instantaneous speed (mm/s) and true angles (rad)."""
    t_video_end = float(truth.time_s.iloc[-1])
    t = np.arange(0.0, sensor.lead_s + t_video_end + 1e-9, 1.0 / sensor.rate_hz)
    tv = t - sensor.lead_s
    depth = np.interp(tv, truth.time_s, truth.depth_mm, left=float(truth.depth_mm.iloc[0]))
    bot = np.interp(tv, truth.time_s, truth.theta_bot)
    tip = np.interp(tv, truth.time_s, truth.theta_tip)
    moving = np.gradient(depth) > 0
    return t, depth, np.where(moving, speed_mm_s, 0.0), tip, bot


def clean_forces_from_truth(
    truth: pd.DataFrame,
    speed_mm_s: float,
    params: FrictionParams,
    sensor: SensorConfig = SensorConfig(),
    *,
    effect: str | None = None,
    effect_values: dict | None = None,
    rng: np.random.Generator | None = None,
) -> pd.DataFrame:
    """Noiseless forces of one rendered trial, without and with a hidden effect.

    Parameters
    ----------
    truth : pandas.DataFrame
        The renderer's per-frame truth (``time_s`` on the video clock, ``depth_mm``, angles in rad).
    speed_mm_s : float
        Insertion speed (mm/s).
    params : FrictionParams
        Force-model parameters.
    sensor : SensorConfig
        Sampling (``rate_hz``, ``lead_s``).
    effect : str or None
        Hidden effect (its name) or None.
    effect_values : dict, optional
        Its parameters (:func:`tympani.pipeline.synthetic.family_a.draw_effect_params`).
    rng : numpy.random.Generator, optional
        Randomness of the effect (drift's random walk).

    Returns
    -------
    pandas.DataFrame
        ``time_s`` (s, sensor clock), ``depth_mm``, ``force_base_g`` and ``force_effect_g`` (g),
        the true ``theta_tip``, ``theta_bot`` (rad), the instantaneous ``sliding_mm_s`` (mm/s) and
        ``pressure_scale`` (1).
    """
    t, depth, v, tip, bot = _force_clock(truth, speed_mm_s, sensor)
    base = np.where(tip > bot, insertion_force(bot, tip, v, params), 0.0)
    with_effect = base
    if effect is not None:
        state = TrialState.single(t, depth, v, tip, bot, params)
        with_effect = apply_hidden_effect(effect, base, state, effect_values or {},
                                          rng if rng is not None else np.random.default_rng(0))
    return pd.DataFrame(dict(time_s=t, depth_mm=depth, force_base_g=base, force_effect_g=with_effect,
                             theta_tip=tip, theta_bot=bot, sliding_mm_s=v, pressure_scale=1.0))


def _sense(clean: pd.DataFrame, rng: np.random.Generator, sensor: SensorConfig) -> pd.DataFrame:
    force = clean["force_effect_g"].to_numpy() + rng.normal(0.0, sensor.noise_g, len(clean))
    lsb = 2 * sensor.range_g / 2**sensor.bits
    force = np.clip(np.round(force / lsb) * lsb, -sensor.range_g, sensor.range_g)
    return pd.DataFrame(dict(time_s=np.round(clean["time_s"].to_numpy(), 6), force_g=force,
                             depth_mm=np.round(clean["depth_mm"].to_numpy(), 5)))


def force_log_from_truth(
    truth: pd.DataFrame,
    speed_mm_s: float,
    params: FrictionParams,
    rng: np.random.Generator,
    sensor: SensorConfig = SensorConfig(),
    *,
    effect: str | None = None,
    effect_values: dict | None = None,
    effect_rng: np.random.Generator | None = None,
) -> pd.DataFrame:
    """A force log (docs/file-formats.md) for one rendered trial.

    Parameters
    ----------
    truth : pandas.DataFrame
        The renderer's per-frame truth (``time_s`` on the video clock, ``depth_mm``, angles in rad).
    speed_mm_s : float
        Insertion speed (mm/s).
    params : FrictionParams
        Force-model parameters.
    rng : numpy.random.Generator
        Source of the noise.
    sensor : SensorConfig
        Sampling, noise and quantisation.
    effect : str or None
        Hidden effect (its name) applied before the noise, or None.
    effect_values : dict, optional
        Its parameters (:func:`tympani.pipeline.synthetic.family_a.draw_effect_params`).
    effect_rng : numpy.random.Generator, optional
        Randomness of the effect (default: a fixed generator), kept apart from ``rng``.

    Returns
    -------
    pandas.DataFrame
        ``time_s`` (s, sensor clock; the video's frame 0 is at ``sensor.lead_s``), ``force_g``
        and ``depth_mm``.
    """
    clean = clean_forces_from_truth(truth, speed_mm_s, params, sensor, effect=effect, effect_values=effect_values,
                                    rng=effect_rng)
    return _sense(clean, rng, sensor)


def render_experiment(out_dir: str | Path, cfg: ExperimentConfig = ExperimentConfig(), *, seed: int = 0) -> pd.DataFrame:
    """Render a synthetic experiment to ``out_dir`` and return its manifest.

    Parameters
    ----------
    out_dir : path
        Output folder (created).
    cfg : ExperimentConfig
        What to render.
    seed : int
        Seed of everything random (pose, look, contact growth, noise).

    Returns
    -------
    pandas.DataFrame
        The manifest (also written as ``manifest.csv``).
    """
    out = Path(out_dir)
    rng = np.random.default_rng(seed)
    pose = random_pose(rng, cfg.width, cfg.height, px_per_mm=(20.0, 40.0))
    look = random_appearance(rng)
    params = paper_params()
    effect_rng = np.random.default_rng([seed, 5])  # apart from rng: same videos and noise with or without
    effect = None if cfg.effect is None or str(cfg.effect).lower() == "none" else str(cfg.effect)
    values = {}
    if effect is not None:
        values = draw_effect_params(effect, effect_rng, cfg.strength, dict(cfg.effect_params))
    shared = [random_policy(rng) for _ in range(cfg.trials)] if cfg.paired else None
    rows, cleans, logs = [], [], []
    for speed in cfg.speeds_mm_s:
        for k in range(cfg.trials):
            trial = trial_name(speed, k)
            spec = VideoSpec(
                pose=pose, width=cfg.width, height=cfg.height, fps=cfg.fps, speed_mm_s=speed,
                start_depth_mm=-1.0, end_depth_mm=cfg.depth_mm, dwell_s=cfg.dwell_s,
                policy=shared[k] if shared is not None else random_policy(rng),
                appearance=look, nuisance=random_nuisance(rng, cfg.nuisance), max_frames=cfg.max_frames,
            )
            name = Path("videos") / (trial if cfg.png else f"{trial}.mp4")
            truth = render_video(out / name, spec, seed=int(rng.integers(2**31)))
            truth.insert(0, "trial", trial)
            atomic_write_csv(out / "truth" / f"{trial}.csv", truth)
            clean = clean_forces_from_truth(truth, speed, params, cfg.sensor, effect=effect, effect_values=values,
                                            rng=effect_rng)
            log = _sense(clean, rng, cfg.sensor)
            force_name = Path("force") / f"{trial}.csv"
            atomic_write_csv(out / force_name, log)
            cleans.append(clean.assign(speed_mm_s=float(speed)))
            logs.append(log)
            rows.append(dict(trial=trial, speed_mm_s=speed, video=str(name), force=str(force_name),
                             fps=spec.effective_fps(), video_t0_s=cfg.sensor.lead_s))
    manifest = pd.DataFrame(rows)
    atomic_write_csv(out / "manifest.csv", manifest)
    gap = effect_truth(effect, cfg.strength, values, pd.concat(cleans, ignore_index=True),
                       np.concatenate([lg["force_g"].to_numpy() for lg in logs]), base=params)
    atomic_write_json(out / "truth" / "effect.json",
                      VideoTruth(**gap.effect_fields(), seed=seed, sensor=cfg.sensor).to_json())
    atomic_write_json(
        out / "truth" / "pose.json",
        dict(pose=dict(asdict(pose), residual_px=0.0), appearance=asdict(look), config=asdict(cfg), seed=seed),
    )
    return manifest

"""A family-A force-and-angles dataset: trials, kinematics, forces with the hidden effect, sensor noise."""

from __future__ import annotations

import math
import time as _time
from dataclasses import asdict, replace
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom
from tympani.vision.rendering import ContactPolicy, random_policy

from tympani.pipeline.model.friction import FrictionParams, arc_integrals, force_from_integrals
from tympani.pipeline.model.paper import paper_params
from tympani.pipeline.synthetic.family_a.config import NoiseConfig, Protocol, Variability
from tympani.pipeline.synthetic.family_a.effects import apply_hidden_effect, draw_effect_params, find_effect
from tympani.pipeline.synthetic.family_a.kinematics import interp_angles, kinematics_batch
from tympani.pipeline.synthetic.family_a.state import TrialState
from tympani.pipeline.synthetic.family_a.truth import DatasetTruth, TrialRecord, TruthTables, effect_truth

__all__ = ["SYNCED_COLUMNS", "trial_name", "synthetic_dataset"]

#: Columns of the synced table :func:`synthetic_dataset` returns.
SYNCED_COLUMNS = ("trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con", "depth_mm")


def _sensor_noise(rng: np.random.Generator, n: int, dt_s: float, noise: NoiseConfig, scale: float) -> np.ndarray:
    white = rng.normal(0.0, noise.white_g, n)
    if noise.ar_g > 0 and n > 0:
        rho = math.exp(-dt_s / noise.ar_tau_s) if noise.ar_tau_s > 0 else 0.0
        innov = rng.normal(0.0, noise.ar_g * math.sqrt(1.0 - rho * rho), n)
        start = rng.normal(0.0, noise.ar_g)
        ar = lfilter([1.0], [1.0, -rho], innov, zi=[rho * start])[0]
    else:
        ar = 0.0
    return scale * (white + ar)


def _quantise(force_g: np.ndarray, noise: NoiseConfig) -> np.ndarray:
    lsb = noise.lsb_g()
    out = np.round(force_g / lsb) * lsb if lsb > 0 else np.asarray(force_g, dtype=float)
    return np.clip(out, -noise.range_g, noise.range_g)




def trial_name(speed_mm_s: float, k: int) -> str:
    """Trial name of repeat ``k`` (0-based) at a speed (mm/s), as ``tympani render`` names them."""
    return f"v{speed_mm_s:g}_t{k + 1:02d}".replace(".", "p")


def _random_policy(rng: np.random.Generator, var: Variability) -> ContactPolicy:
    policy = random_policy(rng)
    return replace(policy, theta_first=float(rng.uniform(*var.theta_first_rad)), lag=float(rng.uniform(*var.lag)))


def synthetic_dataset(
    rng: np.random.Generator,
    effect: str | None,
    *,
    strength: float = 1.0,
    speeds_mm_s: Sequence[float] = (0.5, 1.5, 3.0, 5.0, 7.5),
    trials: int = 10,
    noise: NoiseConfig = NoiseConfig(),
    depth_mm: float = 15.0,
    rate_hz: float = 50.0,
    dwell_s: float = 1.0,
    pre_s: float = 0.5,
    start_depth_mm: float = -1.0,
    angles_fps: float = 30.0,
    video_t0_s: float = 0.0,
    variability: Variability = Variability(),
    params: FrictionParams | None = None,
    effect_params: Mapping[str, float] | None = None,
    phantom: Phantom = DEFAULT_PHANTOM,
) -> tuple[pd.DataFrame, DatasetTruth]:
    """A force-and-angles experiment with a hidden effect, as a synced table.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of everything random (the only one used).
    effect : str or None
        Name of the hidden effect, or None / ``"none"``.
    strength : float
        Size of the effect (0 absent, 1 typical; dimensionless).
    speeds_mm_s : sequence of float
        Nominal insertion speeds (mm/s).
    trials : int
        Repeats per speed.
    noise : NoiseConfig
        Force and angle noise, A/D.
    depth_mm : float
        Depth (mm) where the robot stops.
    rate_hz : float
        Force sampling rate (1/s).
    dwell_s : float
        Time (s) logged after the stop.
    pre_s : float
        Time (s) logged before the robot starts.
    start_depth_mm : float
        Tip depth (mm) at the start (negative: in the entry channel).
    angles_fps : float
        Frame rate (1/s) of the angle measurements.
    video_t0_s : float
        Force-clock time (s) of the first frame.
    variability : Variability
        Trial-to-trial variability.
    params : FrictionParams, optional
        Base model (default: the paper's S4 with linear pressure laws, :func:`tympani.pipeline.model.paper.paper_params`).
    effect_params : mapping, optional
        Effect parameters replacing the drawn ones.
    phantom : Phantom
        Geometry.

    Returns
    -------
    synced : pandas.DataFrame
        ``trial, speed_mm_s, time_s, force_g, theta_tip, theta_bot, theta_con, depth_mm``; one row
        per force sample, trials in speed order; ``speed_mm_s`` the nominal speed (mm/s), time (s) on
        the force clock from each log's start, force (g), angles (rad; NaN before the first frame).
    truth : DatasetTruth
        The hidden effect, its parameters and noiseless gap against the noise (``gap_rms_g``: RMS
        over all rows of the noiseless force with minus without the effect, g; ``noise_rms_g``:
        RMS of the measured minus the noiseless force, g; ``detectable``: gap > 2 noise; per
        speed in ``gap_by_speed``), the base model, noise, variability, protocol, the trials
        (actual speed, pressure scale, policy, noise scale, start/stop times), ``elapsed_s`` and
        ``tables`` (``frames``, the measured angles per frame; ``clean``, per row ``force_base_g``
        and ``force_effect_g``).
    """
    t_begin = _time.perf_counter()
    eff = find_effect(effect)
    base = params if params is not None else paper_params()
    values = draw_effect_params(effect, rng, strength, effect_params)
    proto = Protocol(depth_mm=depth_mm, start_depth_mm=start_depth_mm, pre_s=pre_s, dwell_s=dwell_s,
                     rate_hz=rate_hz, angles_fps=angles_fps, video_t0_s=video_t0_s)
    dt = 1.0 / rate_hz
    travel = depth_mm - start_depth_mm
    # 1. the trials: contact growth, actual speed, pressure scale, noise scale, tare
    def placement() -> tuple[ContactPolicy, float]:
        return (_random_policy(rng, variability),
                float(1.0 + variability.pressure_frac * rng.uniform(-1.0, 1.0)))

    shared = [placement() for _ in range(trials)] if variability.paired else []
    info, policies = [], []
    for speed in speeds_mm_s:
        for k in range(trials):
            policy, p_scale = shared[k] if variability.paired else placement()
            v_act = float(speed) * (1.0 + variability.speed_frac * rng.uniform(-1.0, 1.0))
            t_stop = pre_s + travel / v_act
            policies.append(policy)
            info.append(TrialRecord(
                trial=trial_name(speed, k), speed_mm_s=float(speed), actual_speed_mm_s=v_act,
                pressure_scale=p_scale,
                noise_scale=float(np.exp(rng.normal(0.0, noise.trial_scale_sd))),
                tare_g=float(rng.normal(0.0, noise.tare_sd_g)),
                t_start_s=pre_s, t_stop_s=t_stop, n_samples=int(math.floor((t_stop + dwell_s) / dt + 1e-9)) + 1,
                theta_first=policy.theta_first, lag=policy.lag, shape=asdict(policy.shape),
            ))
    n_tr = len(info)
    # 2. kinematics: the force clock (rows) and the video clock (frames)
    tables = kinematics_batch(policies, depth_mm, phantom)
    sizes = np.array([d.n_samples for d in info])
    trial_idx = np.repeat(np.arange(n_tr), sizes)
    offsets = np.r_[0, np.cumsum(sizes)]
    t = (np.arange(offsets[-1]) - offsets[:-1][trial_idx]) * dt
    run = np.array([d.actual_speed_mm_s for d in info])[trial_idx]
    t_stop = np.array([d.t_stop_s for d in info])[trial_idx]
    depth = start_depth_mm + run * np.clip(t - pre_s, 0.0, t_stop - pre_s)
    moving = (t >= pre_s) & (t < t_stop)
    tip = np.empty_like(t)
    bot = np.empty_like(t)
    for i in range(n_tr):
        sl = slice(offsets[i], offsets[i + 1])
        tip[sl], bot[sl] = interp_angles(depth[sl], (tables[0][i], tables[1][i], tables[2][i]), phantom)
    scale = np.array([d.pressure_scale for d in info])[trial_idx]
    state = TrialState(trial_idx, t, depth, np.where(moving, run, 0.0), run, np.full_like(t, pre_s), t_stop,
                       tip, bot, scale, base, phantom)
    # 3. forces: base model (pressures scale the force linearly), hidden effect, sensor
    arcs = arc_integrals(bot, tip, phantom)
    f_base = np.where(tip > bot, scale * force_from_integrals(arcs, state.speed_mm_s, base), 0.0)
    f_eff = apply_hidden_effect(effect, f_base, state, values, rng) if eff is not None else f_base
    measured = np.empty_like(t)
    frames, ang = [], {c: np.full_like(t, np.nan) for c in ("theta_tip", "theta_bot", "theta_con")}
    for i, d in enumerate(info):
        sl = slice(offsets[i], offsets[i + 1])
        n = d.n_samples
        measured[sl] = _quantise(f_eff[sl] + d.tare_g + _sensor_noise(rng, n, dt, noise, d.noise_scale), noise)
        # angles measured per frame (video clock), interpolated onto the force clock as tympani sync does
        tq = t[sl] - video_t0_s
        tv = np.arange(max(int(math.floor(tq[-1] * angles_fps + 1e-9)) + 2, 2)) / angles_fps
        d_frame = start_depth_mm + d.actual_speed_mm_s * np.clip(tv + video_t0_s - pre_s, 0.0, d.t_stop_s - pre_s)
        tip_f, bot_f = interp_angles(d_frame, (tables[0][i], tables[1][i], tables[2][i]), phantom)
        tip_m = tip_f + rng.normal(0.0, noise.angle_sd_rad, tv.size)
        bot_m = np.where(tip_f > bot_f, bot_f + rng.normal(0.0, noise.angle_sd_rad, tv.size), tip_m)
        bot_m = np.minimum(bot_m, tip_m)
        con_m = tip_m - bot_m
        frames.append((d.trial, tv, tip_m, bot_m, con_m))
        inside = (tq >= tv[0]) & (tq <= tv[-1])
        for c, x in (("theta_tip", tip_m), ("theta_bot", bot_m), ("theta_con", con_m)):
            ang[c][sl] = np.where(inside, np.interp(tq, tv, x), np.nan)
    names = np.array([d.trial for d in info], dtype=object)
    synced = pd.DataFrame({
        "trial": names[trial_idx], "speed_mm_s": np.array([d.speed_mm_s for d in info])[trial_idx],
        "time_s": t, "force_g": measured, **ang, "depth_mm": depth,
    })
    frames_df = pd.DataFrame({
        "trial": np.concatenate([np.full(f[1].size, f[0], dtype=object) for f in frames]),
        "frame": np.concatenate([np.arange(f[1].size) for f in frames]),
        "time_s": np.concatenate([f[1] for f in frames]),
        "theta_tip": np.concatenate([f[2] for f in frames]),
        "theta_bot": np.concatenate([f[3] for f in frames]),
        "theta_con": np.concatenate([f[4] for f in frames]),
        "ok": True,
    })
    clean = pd.DataFrame({"force_base_g": f_base, "force_effect_g": f_eff})
    gap = effect_truth(
        effect, strength, values,
        clean.assign(speed_mm_s=synced["speed_mm_s"].to_numpy(), theta_tip=tip, theta_bot=bot,
                     sliding_mm_s=state.speed_mm_s, pressure_scale=scale),
        measured, base=base, arcs=arcs,
    )
    truth = DatasetTruth(**gap.effect_fields(), noise=noise, variability=variability, protocol=proto,
                         trials=tuple(info), elapsed_s=_time.perf_counter() - t_begin,
                         tables=TruthTables(frames=frames_df, clean=clean))
    return synced, truth

"""Random draws of family B: seeded generators, data-set and per-trial constants."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "seeded_rng",
    "draw_uniform",
    "draw_log_uniform",
    "jsonable",
    "E_LAT_MAX_MM",
    "draw_dataset",
    "draw_trial",
]


def seeded_rng(seed: int, *keys: int) -> np.random.Generator:
    """Independent generator for one purpose, derived from the user seed and keys."""
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *keys]))


def draw_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A uniform draw in ``[lo, hi)`` (units of ``lo`` and ``hi``) as a Python float."""
    return float(rng.uniform(lo, hi))


def draw_log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A log-uniform draw in ``[lo, hi)`` (``lo > 0``; units of ``lo`` and ``hi``) as a Python float."""
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (recursively) into plain Python objects."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


#: Largest lateral offset of the array's axis in the entry [mm]: the array is 1.1 mm
#: thick at the back of the entry at the deepest insertion (16.8 mm + 5 mm from its
#: tip), so its axis must stay within 0.75 - 0.552 = 0.198 mm of the entry's centre line.
E_LAT_MAX_MM: float = 0.19


def draw_dataset(seed: int) -> dict[str, Any]:
    """Data-set-level constants of kinematics, base model, sensor and video."""
    rng = seeded_rng(seed, 1)
    mu_k = draw_uniform(rng, 0.10, 0.14)
    ds = {
        "force_rate_hz": float(rng.integers(40, 101)),
        "fps": float(rng.choice([25.0, 29.97, 30.0, 50.0, 60.0])),
        "angle_sd_tip": draw_uniform(rng, 0.003, 0.01),
        "angle_sd_bot": draw_uniform(rng, 0.01, 0.04),
        "p_missing_frame": draw_uniform(rng, 0.0, 0.02),
        "noise_rms_g": draw_uniform(rng, 0.03, 0.06),
        "noise_ar_share": draw_uniform(rng, 0.3, 0.7),
        "noise_tau_s": draw_uniform(rng, 0.1, 0.5),
        "full_scale_g": draw_uniform(rng, 25.0, 50.0),
        "adc_bits": 13,
        "gain_spread": 0.03,
        "tare_sd_g": draw_uniform(rng, 0.01, 0.05),
        "mu_k": mu_k,
        "mu_s": mu_k + draw_uniform(rng, 0.0, 0.06),
        "v_s": draw_log_uniform(rng, 0.1, 1.0),
        "delta_s": draw_uniform(rng, 0.35, 2.0),
        "b_c": draw_uniform(rng, 0.03, 0.04),
        "final_depth_mm": draw_uniform(rng, 14.5, 16.5),
        "e_lat_mean_mm": draw_uniform(rng, -0.1, 0.1),
        "kappa0_mean_per_mm": draw_uniform(rng, -0.05, 0.0),
        "alpha_mean": draw_uniform(rng, -0.55, 0.1),
        "beta_mean": draw_uniform(rng, 0.05, 0.4),
        "lambda_mean": draw_uniform(rng, 0.3, 1.0),
        "theta_bot_floor": draw_uniform(rng, 0.6, 0.8),
        # raw pressure-law shape; rescaled below to hit a target end force
        "pt0": draw_uniform(rng, 0.02, 0.05), "pt3": draw_uniform(rng, 0.06, 0.12),
        "pb0": draw_uniform(rng, 0.03, 0.07), "pb3": draw_uniform(rng, 0.10, 0.22),
        "target_end_force_g": draw_uniform(rng, 3.5, 7.0),
    }
    return ds


def draw_trial(seed: int, iv: int, it: int, speed: float, ds: dict[str, Any]) -> dict[str, Any]:
    """Per-trial kinematics, pressure scale and sensor calibration."""
    rng = seeded_rng(seed, 2, iv, it)
    tr = {
        "speed_actual_mm_s": speed * (1.0 + draw_uniform(rng, -0.02, 0.02)),
        "pre_roll_s": draw_uniform(rng, 0.3, 2.0),
        "dwell_s": draw_uniform(rng, 1.0, 4.0),
        "accel_s": draw_uniform(rng, 0.05, 0.15),
        "d0_mm": draw_uniform(rng, -0.5, 0.5),
        "final_depth_mm": float(np.clip(ds["final_depth_mm"] + draw_uniform(rng, -0.3, 0.3), 12.0, 18.0)),
        "e_lat_mm": float(np.clip(ds["e_lat_mean_mm"] + rng.normal(0.0, 0.04), -E_LAT_MAX_MM,
                                  E_LAT_MAX_MM)),
        "tilt_rad": float(np.clip(rng.normal(0.0, math.radians(0.5)), -math.radians(1.2),
                                  math.radians(1.2))),
        "kappa0_per_mm": float(min(ds["kappa0_mean_per_mm"] + rng.normal(0.0, 0.005), 0.0)),
        "alpha": ds["alpha_mean"] + float(rng.normal(0.0, 0.08)),
        "beta": ds["beta_mean"] * draw_uniform(rng, 0.8, 1.2),
        "lambda": ds["lambda_mean"] * draw_uniform(rng, 0.8, 1.2),
        "wiggle_amp": draw_uniform(rng, 0.01, 0.04),
        "wiggle_k": [draw_uniform(rng, 3.0, 8.0), draw_uniform(rng, 1.5, 4.0)],
        "wiggle_phase": [draw_uniform(rng, 0, 2 * math.pi), draw_uniform(rng, 0, 2 * math.pi)],
        "p_tip_scale": draw_uniform(rng, 0.9, 1.1),
        "p_bot_scale": draw_uniform(rng, 0.9, 1.1),
        "gain": 1.0 + draw_uniform(rng, -ds["gain_spread"], ds["gain_spread"]),
        "tare_g": float(rng.normal(0.0, ds["tare_sd_g"])),
        "video_start_s": draw_uniform(rng, 0.0, 0.3),
        "video_end_early_s": draw_uniform(rng, 0.0, 0.3),
    }
    return tr

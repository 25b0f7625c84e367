"""The seed-paper case of family A: hidden lift calibrated to the paper's peak-force drop."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from tympani.pipeline.model.paper import PAPER_DROPS_PCT
from tympani.pipeline.synthetic.family_a.config import NoiseConfig, Variability
from tympani.pipeline.synthetic.family_a.dataset import synthetic_dataset
from tympani.pipeline.synthetic.family_a.effects import PAPER_LIFT
from tympani.pipeline.synthetic.family_a.truth import DatasetTruth, PaperDrops

__all__ = ["peak_force_drop", "PAPER_VARIABILITY", "paper_case", "calibrate_paper_lift"]


def peak_force_drop(synced: pd.DataFrame, *, smooth_s: float = 0.1, force_column: str = "force_g") -> pd.DataFrame:
    """Mean peak force per speed and its change vs the slowest speed.

    Each trial's peak is the maximum of its force after a centred moving average ``smooth_s``
    wide (limits the upward bias of a noisy maximum); the speed's peak is the mean over its trials.

    Parameters
    ----------
    synced : pandas.DataFrame
        Synced table (``trial``, ``speed_mm_s``, ``time_s``, a force column in g).
    smooth_s : float
        Width (s) of the moving average (0: none).
    force_column : str
        Column holding the force (g).

    Returns
    -------
    pandas.DataFrame
        ``speed_mm_s``, ``n_trials``, ``peak_force_g`` (mean, g), ``peak_sd_g`` (between trials, g),
        ``change_pct`` (per cent vs the slowest speed's mean peak).
    """
    peaks = []
    for (trial, speed), part in synced.groupby(["trial", "speed_mm_s"], sort=False):
        f = part[force_column].to_numpy(float)
        t = part["time_s"].to_numpy(float)
        if smooth_s > 0 and f.size > 2:
            dt = float(np.median(np.diff(t)))
            w = max(1, int(round(smooth_s / dt)))
            f = pd.Series(f).rolling(w, center=True, min_periods=1).mean().to_numpy()
        peaks.append(dict(trial=trial, speed_mm_s=float(speed), peak=float(np.nanmax(f))))
    table = pd.DataFrame(peaks).groupby("speed_mm_s", sort=True)["peak"].agg(["count", "mean", "std"]).reset_index()
    table.columns = ["speed_mm_s", "n_trials", "peak_force_g", "peak_sd_g"]
    ref = float(table["peak_force_g"].iloc[0])
    table["change_pct"] = 100.0 * (table["peak_force_g"] / ref - 1.0)
    return table


#: Trial variability of the paper case: ten placements repeated at every speed (paired), so that
#: the speed comparison is not blurred by which placements each speed drew.
PAPER_VARIABILITY = Variability(pressure_frac=0.10, speed_frac=0.02, paired=True)


def paper_case(rng: np.random.Generator, **kwargs) -> tuple[pd.DataFrame, DatasetTruth]:
    """A dataset calibrated to the seed paper: hidden hydrodynamic lift, its speed drop.

    Five speeds (0.5, 1.5, 3, 5, 7.5 mm/s), ten repeats, 15 mm depth, the S4 base model (which
    alone changes the peak force by under ±2 %), and lift with the constants :data:`PAPER_LIFT`
    calibrated (:func:`calibrate_paper_lift`) to the paper's peak-force changes, −24 % at 3 mm/s
    and −43 % at 7.5 mm/s vs 0.5 mm/s. ``truth.paper`` reports the achieved changes (noisy data,
    and noiseless) and those of the base model alone.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of everything random.
    **kwargs
        Passed to :func:`synthetic_dataset` (e.g. ``noise``).
    """
    opts: dict[str, Any] = dict(speeds_mm_s=(0.5, 1.5, 3.0, 5.0, 7.5), trials=10, depth_mm=15.0,
                                variability=PAPER_VARIABILITY, effect_params=PAPER_LIFT, strength=1.0)
    opts.update(kwargs)
    synced, truth = synthetic_dataset(rng, "hydrodynamic_lift", **opts)
    clean = truth.tables.clean
    noiseless = synced[["trial", "speed_mm_s", "time_s"]].assign(
        effect=clean["force_effect_g"].to_numpy(), base=clean["force_base_g"].to_numpy())
    measured = peak_force_drop(synced)
    paper = PaperDrops(
        target_change_pct={str(k): v for k, v in PAPER_DROPS_PCT.items()},
        achieved=measured,
        achieved_noiseless=peak_force_drop(noiseless, smooth_s=0.0, force_column="effect"),
        base_model=peak_force_drop(noiseless, smooth_s=0.0, force_column="base"),
    )
    return synced, replace(truth, paper=paper)


def calibrate_paper_lift(*, targets_pct: Mapping[float, float] = PAPER_DROPS_PCT,
                         free: Sequence[str] = ("film_ratio", "share_power"), seed: int = 0) -> dict[str, float]:
    """Fit the lift constants so that the noiseless mean peak-force changes hit the paper's.

    Uses noiseless paper-case data (same trial draws for every trial of the fit) and least
    squares on the changes at the target speeds.

    Parameters
    ----------
    targets_pct : mapping
        Speed (mm/s) → target peak-force change (per cent vs 0.5 mm/s).
    free : sequence of str
        Lift parameters to fit (the others stay at :data:`PAPER_LIFT`).
    seed : int
        Seed of the trial draws.

    Returns
    -------
    dict
        The full parameter set (:data:`PAPER_LIFT` keys) with the fitted values.
    """
    quiet = NoiseConfig(white_g=0.0, ar_g=0.0, tare_sd_g=0.0, bits=0, angle_sd_rad=0.0)
    speeds = (0.5, *sorted(targets_pct))

    def changes(x: np.ndarray) -> np.ndarray:
        values = {**PAPER_LIFT, **dict(zip(free, map(float, x)))}
        synced, _ = synthetic_dataset(np.random.default_rng(seed), "hydrodynamic_lift", speeds_mm_s=speeds, trials=10,
                                      noise=quiet, variability=PAPER_VARIABILITY, effect_params=values)
        table = peak_force_drop(synced, smooth_s=0.0).set_index("speed_mm_s")
        return np.array([table.loc[v, "change_pct"] - targets_pct[v] for v in sorted(targets_pct)])

    x0 = np.array([PAPER_LIFT[k] for k in free])
    fit = least_squares(changes, x0, bounds=(np.full(len(free), 0.05), np.full(len(free), 3.0)), diff_step=1e-3)
    return {**PAPER_LIFT, **dict(zip(free, map(float, fit.x)))}

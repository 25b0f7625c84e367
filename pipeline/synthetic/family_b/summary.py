"""Summary of family B (``python -m tympani.pipeline.synthetic.family_b.summary``): SNR and peak drops."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from tympani.pipeline.synthetic.family_b.constants import EFFECTS
from tympani.pipeline.synthetic.family_b.generator import generate
from tympani.pipeline.synthetic.family_b.truth import GeneratedTruth

__all__ = ["peak_drop"]


def peak_drop(df: pd.DataFrame, truth: GeneratedTruth, *, column: str = "true_force_g",
              during_motion: bool = True, base_corrected: bool = False) -> dict[float, float]:
    """Relative drop of the mean per-trial peak force at each speed vs the slowest speed.

    Parameters
    ----------
    df, truth
        Output of :func:`generate`.
    column : str
        Force column to use.
    during_motion : bool
        Peak over the insertion only (up to the robot's stop) instead of the whole log.
    base_corrected : bool
        Use per-trial ratios ``peak(column) / peak(true_base_g)`` instead of raw peaks, so
        the trial-to-trial spread of the base model cancels.

    Returns
    -------
    dict
        ``{speed: 1 - peak(speed) / peak(slowest)}``.
    """
    info = truth.base.trials
    rows = []
    for name, g in df.groupby("trial", sort=False):
        sel = g["time_s"] <= info[name].t_motion_stop_s if during_motion else slice(None)
        pk = float(g.loc[sel, column].max())
        if base_corrected:
            pk /= float(g.loc[sel, "true_base_g"].max())
        rows.append((float(g["speed_mm_s"].iloc[0]), pk))
    s = pd.DataFrame(rows, columns=["v", "pk"]).groupby("v")["pk"].mean()
    return {float(v): float(1.0 - s[v] / s.iloc[0]) for v in s.index}


def _summary(seeds: Sequence[int] = range(5)) -> None:  # pragma: no cover - CLI helper
    import time

    t0 = time.perf_counter()
    generate(None, 0)
    print(f"generation time, 5 speeds x 10 trials, no effect: {time.perf_counter() - t0:.2f} s")
    print(f"{'effect':20s} {'snr@1':>7s} {'snr@0.3':>8s} {'unabs@1':>8s} {'unabs@0.3':>9s} "
          f"{'time':>6s}")
    for eff in EFFECTS:
        res = {}
        for st in (1.0, 0.3):
            snr, un, tt = [], [], []
            for seed in seeds:
                t0 = time.perf_counter()
                _, tr = generate(eff, seed, strength=st)
                tt.append(time.perf_counter() - t0)
                snr.append(tr.snr)
                un.append(tr.snr_unabsorbed)
            res[st] = (float(np.median(snr)), float(np.median(un)), float(np.median(tt)))
        print(f"{eff:20s} {res[1.0][0]:7.2f} {res[0.3][0]:8.2f} {res[1.0][1]:8.2f} "
              f"{res[0.3][1]:9.2f} "
              f"{res[1.0][2]:6.2f}")
    print("hydrodynamic_lift, strength 1: peak-force drop vs 0.5 mm/s (3 / 7.5 mm/s)")
    for seed in seeds:
        df, tr = generate("hydrodynamic_lift", seed)
        a = peak_drop(df, tr)
        b = peak_drop(df, tr, base_corrected=True)
        c = peak_drop(df, tr, during_motion=False, base_corrected=True)
        print(f"  seed {seed}: insertion peak {a[3.0]:.2f} / {a[7.5]:.2f}; base-corrected "
              f"{b[3.0]:.2f} / {b[7.5]:.2f}; whole log incl. dwell {c[3.0]:.2f} / {c[7.5]:.2f}")


if __name__ == "__main__":  # pragma: no cover
    _summary()

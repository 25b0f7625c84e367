"""The files of ``tympani bounds``: ``bounds.json``, ``bounds_bands.csv`` and their provenance.

:func:`bounds_record` is the content of ``bounds.json`` (the fits of :mod:`tympani.pipeline.model.bounds`
per speed, the recommended bound and :func:`quote`, what to quote in plain words);
:func:`write_bounds` writes it with the bands table, atomically.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

from tympani.pipeline.io import atomic_write_csv, atomic_write_json, provenance
from tympani.pipeline.model.bounds import BoundsConfig, LogModel, SpeedFit, bands_table

__all__ = ["bounds_record", "quote", "write_bounds"]


def _model_record(m: LogModel) -> dict:
    return {k: getattr(m, k) for k in ("form", "degree", "variance", "centre", "half_range", "coef", "var_coef",
                                       "df_pred", "se_method", "n_trials")}


def _speed_record(f: SpeedFit) -> dict:
    rec: dict[str, Any] = {k: getattr(f, k) for k in (
        "speed_mm_s", "c1", "c2", "c1_se", "c2_se", "n", "n_excluded", "heldout_coverage", "heldout_coverage_eq9",
        "n_no_contact", "n_saturated", "n_missing", "n_trials", "se_method", "c1_se_ols", "c2_se_ols",
        "sigma_log", "r2", "rho", "n_eff", "theta_min", "theta_max", "level")}
    rec["theta_con_min" if f.angle == "theta_con" else "theta_tip_min"] = f.theta_min
    rec["theta_con_max" if f.angle == "theta_con" else "theta_tip_max"] = f.theta_max
    rec["recommended"] = {**_model_record(f.recommended), "holds": f.recommended_holds}
    rec["coverage_note"] = f.coverage_note
    rec["candidates"] = [{"form": s.form, "heldout_coverage": s.coverage, "mean_width_g": s.mean_width_g,
                          "heldout_above": s.above, "n_tested": s.n_tested, "n_outside_range": s.n_outside, "folds": s.folds}
                         for s in f.scores]
    lof = f.lack_of_fit
    rec["lack_of_fit"] = None if lof is None else {
        "test": "Wald F test of a quadratic term added to Eq. (8), trial-robust covariance",
        "statistic": lof.statistic, "df1": lof.df1, "df2": lof.df2, "p_value": lof.p_value,
        "curvature_per_rad2": lof.curvature, "method": lof.method, "rejects_eq8": lof.rejects, "alpha": lof.alpha,
        "words": lof.words(),
    }
    return rec


def quote(fits: Sequence[SpeedFit]) -> str:
    """What a user should quote, in plain words."""
    if not fits:
        return "No speed could be fitted: there is no bound to quote."
    holds = [f for f in fits if f.recommended_holds]
    text = ("Quote the recommended bound's upper limit (rec_hi_g in bounds_bands.csv) as the force above which a "
            "sample is unusual for that speed and angle")
    if len(holds) == len(fits):
        covs = ", ".join(f"{100 * f.heldout_coverage:.0f} %" for f in fits)  # type: ignore[operator]
        text += f": on trials left out of its fit it covered {covs} of the samples (target 95 %)."
    else:
        bad = ", ".join(f"{f.speed_mm_s:g}" for f in fits if not f.recommended_holds)
        text += (f"; at {bad} mm/s no form held within 95 ± 3 % on left-out trials (see the coverage column), so "
                 "treat those bounds with caution and add trials.")
    bent = [f for f in fits if f.lack_of_fit is not None and f.lack_of_fit.rejects]
    if bent:
        text += (" Eq. (8)'s straight line does not fit ln F at " + ", ".join(f"{f.speed_mm_s:g}" for f in bent)
                 + " mm/s: quote c1 and c2 only as the paper's summary of the trend, not as a bound.")
    else:
        text += " Eq. (8)'s c1 and c2 describe the data at every speed (no lack of fit found)."
    return text


def bounds_record(fits: Sequence[SpeedFit], skipped: Sequence[dict], cfg: BoundsConfig, **extra: Any) -> dict:
    """The content of ``bounds.json``."""
    a = cfg.angle
    return {
        "model": f"Eq. (8): ln F = c1 * {a} + c2 (c1 the slope in 1/rad, c2 the intercept; F in g, {a} in rad; "
                 f"OLS on F > 0 and {a} > 0); Eq. (9): F = exp(c1 * {a} + c2), the median force",
        "angle": a,
        "level": cfg.level,
        "se_default": ("cluster-robust by trial (CR1, t with G-1 df) when a speed has >= "
                       f"{cfg.min_clusters} trials, else OLS scaled by n/n_eff (lag-1 autocorrelation within "
                       "trials)") if cfg.se == "auto" else cfg.se,
        "bands": {
            "file": "bounds_bands.csv",
            "confidence": "ci_lo_g..ci_hi_g: where Eq. (9)'s median curve lies",
            "prediction": "pi_lo_g..pi_hi_g: where one force sample of a new insertion lies by Eq. (9) "
                          "(the paper's safety boundaries)",
            "recommended": "rec_lo_g..rec_hi_g: the recommended bound's prediction band",
        },
        "heldout_coverage": "share of a left-out trial's samples inside the recommended bound's band fitted to the "
                            "other trials at that speed (leave one trial out, pooled; samples outside the fitted "
                            "trials' angle range are not counted); heldout_coverage_eq9: the same for Eq. (9)",
        "recommended": f"among {', '.join(cfg.forms)}: held-out coverage within {cfg.level:g} +- "
                       f"{cfg.coverage_tol:g}, then the narrowest band",
        "quote": quote(fits),
        "n_excluded": f"contact samples ({a} > 0) left out because F <= 0; n_no_contact, n_saturated and "
                      "n_missing count the other samples not fitted",
        "by_speed": [_speed_record(f) for f in fits],
        "skipped": list(skipped),
        **extra,
    }


def write_bounds(
    fits: Sequence[SpeedFit],
    skipped: Sequence[dict],
    out_dir: str | os.PathLike,
    *,
    cfg: BoundsConfig = BoundsConfig(),
    input_path: str | os.PathLike | None = None,
    figures: Sequence[str] = (),
) -> dict[str, Path]:
    """Write ``bounds.json`` and ``bounds_bands.csv`` (and a provenance sidecar) atomically.

    Parameters
    ----------
    fits, skipped
        From :func:`fit_bounds`.
    out_dir : str or PathLike
        Output folder (created).
    cfg : BoundsConfig
        Settings (recorded).
    input_path : str or PathLike, optional
        The synced table (recorded with its hash in ``bounds.provenance.json``).
    figures : sequence of str
        Figure file names to list in ``bounds.json``.

    Returns
    -------
    dict
        ``json``, ``bands`` and (with ``input_path``) ``provenance`` paths.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "bands": atomic_write_csv(out / "bounds_bands.csv", bands_table(fits, cfg)),
        "json": atomic_write_json(out / "bounds.json", bounds_record(
            fits, skipped, cfg, input=str(Path(input_path).resolve()) if input_path else None,
            figures=list(figures))),
    }
    if input_path is not None:
        paths["provenance"] = atomic_write_json(out / "bounds.provenance.json", provenance(input_path, {"config": cfg}))
    return paths

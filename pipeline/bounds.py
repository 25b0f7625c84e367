"""Safety bounds of the insertion force, per speed (seed paper Eqs. 8–9; SPEC §6 ``bounds.json``).

Model
-----
For each insertion speed, Eq. (8) regresses the log force on the contact angle by ordinary
least squares::

    ln F = c1 + c2 · θ_con + ε                                    (F in g, θ_con in rad)

on the synced samples with ``F > 0`` and ``θ_con > 0`` (not saturated, angles present), and
Eq. (9) is its curve ``F̂(θ_con) = exp(c1 + c2 θ_con)``. Because ε is modelled in log space,
``F̂`` is the *median* force at θ_con (the geometric mean of F), not the arithmetic mean; it
sits ``exp(σ²/2)`` below the mean under log-normal errors.

Bands (level 95 % by default), both computed in log space and transformed with ``exp`` (a
monotone map: the bands' coverage carries over exactly):

- **confidence band** ``ci_lo_g .. ci_hi_g``: where the *median curve* itself lies:
  ``ŷ ± t · sqrt(x V xᵀ)``, ``x = (1, θ_con)``, ``V`` the coefficients' covariance.
- **prediction band** ``pi_lo_g .. pi_hi_g``: where a *new sample* — one force reading of a new
  insertion at that speed and θ_con — lies: ``ŷ ± t · sqrt(x V xᵀ + s²)`` with ``s²`` the
  residual variance of ln F. **This is the paper's "safety boundary"**: it bounds the force of
  a new insertion, not just the uncertainty of the fitted curve; forces above ``pi_hi_g`` are
  unusual for that speed and angle.

Standard errors
---------------
Samples of one insertion are a curve, not independent draws: their residuals are strongly
autocorrelated, and the plain OLS standard errors are then far too small. ``se_method``:

- ``"cluster"``: cluster-robust (sandwich) covariance with the trials as clusters, CR1
  small-sample factor ``G/(G−1) · (n−1)/(n−2)``; t quantile with ``G − 1`` degrees of freedom.
- ``"effective_n"``: OLS covariance scaled by ``n / n_eff`` with
  ``n_eff = n (1 − ρ) / (1 + ρ)``, ρ the lag-1 autocorrelation of the residuals within trials
  (pooled; clipped to [0, 0.999]); ``n_eff − 2`` degrees of freedom.
- ``"ols"``: the textbook covariance ``s² (XᵀX)⁻¹``, ``n − 2`` degrees of freedom (only right
  for independent samples).
- ``"auto"`` (**default**): ``"cluster"`` when the speed has at least ``min_clusters`` (5)
  trials, ``"effective_n"`` otherwise (too few clusters make sandwich estimates unreliable).

``c1_se``/``c2_se`` in ``bounds.json`` are the chosen method's (named in ``se_method``); the OLS
ones are kept as ``c1_se_ols``/``c2_se_ols`` for comparison. The confidence band uses the chosen
covariance and degrees of freedom. The prediction band uses the same covariance plus ``s²`` and
``n_eff − 2`` degrees of freedom (the residual variance's own effective degrees of freedom).

The residual variance is taken constant over θ_con (homoscedastic in log space);
``hetero_ratio`` (residual variance in the upper half of the θ_con range over that in the lower
half) tells how well that holds — far from 1, the prediction band is too wide at one end and too
narrow at the other.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Sequence

import numpy as np
import pandas as pd

from vision.errors import InputError

__all__ = [
    "BANDS_COLUMNS",
    "BoundsConfig",
    "SpeedFit",
    "read_synced",
    "fit_eq8",
    "fit_bounds",
    "bands",
    "bands_table",
    "bounds_record",
    "write_bounds",
]

#: Columns of ``bounds_bands.csv``.
BANDS_COLUMNS: tuple[str, ...] = ("speed_mm_s", "theta_con", "f_fit_g", "ci_lo_g", "ci_hi_g", "pi_lo_g", "pi_hi_g")

_SE_METHODS = ("auto", "cluster", "effective_n", "ols")


@dataclass(frozen=True)
class BoundsConfig:
    """Settings of the Eq. (8) fits.

    Parameters
    ----------
    level : float
        Coverage of the bands (0–1).
    se : {"auto", "cluster", "effective_n", "ols"}
        Standard-error method (module docstring); ``"auto"`` is the default.
    min_clusters : int
        With ``se="auto"``, fewest trials at a speed for cluster-robust errors.
    min_samples : int
        Fewest usable samples for a speed to be fitted.
    n_grid : int
        θ_con points of the bands per speed.
    exclude_saturated : bool
        Leave out samples flagged ``saturated`` (clipped force) when the table has that column.
    """

    level: float = 0.95
    se: Literal["auto", "cluster", "effective_n", "ols"] = "auto"
    min_clusters: int = 5
    min_samples: int = 5
    n_grid: int = 101
    exclude_saturated: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.level < 1.0:
            raise ValueError("level must be in (0, 1)")
        if self.se not in _SE_METHODS:
            raise ValueError(f"se must be one of {', '.join(_SE_METHODS)}, not {self.se!r}")
        if self.min_clusters < 2 or self.min_samples < 3 or self.n_grid < 2:
            raise ValueError("min_clusters >= 2, min_samples >= 3 and n_grid >= 2 are required")


@dataclass(frozen=True)
class SpeedFit:
    """The Eq. (8) fit at one speed.

    Parameters
    ----------
    speed_mm_s : float
        Insertion speed (mm/s).
    c1 : float
        Intercept of ln F (ln g).
    c2 : float
        Slope of ln F (1/rad).
    c1_se, c2_se : float
        Their standard errors (``se_method``).
    n : int
        Samples in the fit.
    n_excluded : int
        Contact samples (θ_con > 0, angles present, not saturated) left out because F ≤ 0.
    n_no_contact : int
        Samples with θ_con ≤ 0 (outside Eq. 8's domain).
    n_saturated : int
        Samples left out as clipped.
    n_missing : int
        Samples without angles or force (NaN).
    n_trials : int
        Trials among the fitted samples.
    se_method : str
        ``"cluster"``, ``"effective_n"`` or ``"ols"``.
    df : float
        Degrees of freedom of the confidence band's t quantile.
    df_pred : float
        Degrees of freedom of the prediction band's t quantile.
    cov : tuple of tuple of float
        2×2 covariance of (c1, c2) (``se_method``).
    sigma_log : float
        Residual standard deviation of ln F (dimensionless).
    r2 : float
        Coefficient of determination in log space.
    rho : float
        Lag-1 autocorrelation of the residuals within trials.
    n_eff : float
        Effective sample size ``n (1 − ρ) / (1 + ρ)``.
    c1_se_ols, c2_se_ols : float
        Textbook OLS standard errors, for comparison.
    theta_con_min, theta_con_max : float
        Range of the fitted θ_con (rad).
    hetero_ratio : float
        Residual variance in the upper half of the θ_con range over the lower half.
    level : float
        Band coverage.
    """

    speed_mm_s: float
    c1: float
    c2: float
    c1_se: float
    c2_se: float
    n: int
    n_excluded: int
    n_no_contact: int
    n_saturated: int
    n_missing: int
    n_trials: int
    se_method: str
    df: float
    df_pred: float
    cov: tuple[tuple[float, float], tuple[float, float]]
    sigma_log: float
    r2: float
    rho: float
    n_eff: float
    c1_se_ols: float
    c2_se_ols: float
    theta_con_min: float
    theta_con_max: float
    hetero_ratio: float
    level: float = 0.95

    def curve(self, theta_con: np.ndarray | float) -> np.ndarray:
        """Eq. (9): the median force ``exp(c1 + c2 θ_con)`` (g) at θ_con (rad)."""
        return np.exp(self.c1 + self.c2 * np.asarray(theta_con, dtype=float))


# --------------------------------------------------------------------------- input


def read_synced(path: str | os.PathLike) -> pd.DataFrame:
    """Read a synced table (SPEC §6) for the bounds.

    Parameters
    ----------
    path : str or PathLike
        CSV with at least ``speed_mm_s``, ``force_g`` (g), ``theta_con`` (rad); ``trial`` and
        ``time_s`` (s) are used when present (clusters, autocorrelation), ``saturated`` too.

    Returns
    -------
    DataFrame

    Raises
    ------
    InputError
        Missing or unreadable file, missing columns, non-numeric values (naming the line).
    """
    from pipeline.forcelog import parse_numeric, read_table_lines

    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such synced table" if not p.exists() else "synced table is not a file")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read synced table ({type(exc).__name__}: {exc})") from None
    header, rows, lines, _ = read_table_lines(text, name=str(p))
    missing = [c for c in ("speed_mm_s", "force_g", "theta_con") if c not in header]
    if missing:
        raise InputError(p, f"missing column(s) {', '.join(missing)} of a synced table")
    if not rows:
        raise InputError(p, "synced table has no rows")
    cols = dict(zip(header, zip(*rows)))
    out = pd.DataFrame({"trial": list(cols["trial"]) if "trial" in cols else ["all"] * len(rows)})
    for c in ("speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con"):
        if c in cols:
            out[c] = parse_numeric(cols[c], lines, column=c, name=str(p))
    if out["speed_mm_s"].isna().any():
        i = int(np.argmax(out["speed_mm_s"].isna().to_numpy()))
        raise InputError(f"{p}:{lines[i]}", "speed_mm_s is empty")
    if "saturated" in cols:
        out["saturated"] = [c.strip().lower() in ("true", "1", "yes") for c in cols["saturated"]]
    out["line"] = lines
    return out


# --------------------------------------------------------------------------- fit


def _lag1_within(resid: np.ndarray, groups: np.ndarray) -> float:
    """Pooled lag-1 autocorrelation of residuals within groups (rows in time order)."""
    same = groups[1:] == groups[:-1]
    num = float(np.sum(resid[1:][same] * resid[:-1][same]))
    den = float(np.sum(resid * resid))
    return num / den if den > 0 else 0.0


def fit_eq8(
    theta_con: np.ndarray,
    force_g: np.ndarray,
    *,
    speed_mm_s: float,
    trial: np.ndarray | None = None,
    saturated: np.ndarray | None = None,
    cfg: BoundsConfig = BoundsConfig(),
) -> SpeedFit:
    """Fit Eq. (8) ``ln F = c1 + c2 θ_con`` at one speed.

    Parameters
    ----------
    theta_con : ndarray
        Contact angle of each sample (rad); NaN where not measured.
    force_g : ndarray
        Force of each sample (g).
    speed_mm_s : float
        The speed (mm/s), recorded in the result.
    trial : ndarray, optional
        Trial label of each sample (clusters); samples must be in time order within a trial.
        Default: one trial.
    saturated : ndarray of bool, optional
        Clipped samples (left out when ``cfg.exclude_saturated``).
    cfg : BoundsConfig
        Settings.

    Returns
    -------
    SpeedFit

    Raises
    ------
    InputError
        Fewer than ``cfg.min_samples`` usable samples, or θ_con constant.
    """
    th = np.asarray(theta_con, dtype=float)
    f = np.asarray(force_g, dtype=float)
    groups = np.asarray(trial if trial is not None else np.zeros(th.size), dtype=object).astype(str)
    sat = (np.asarray(saturated, dtype=bool) if saturated is not None and cfg.exclude_saturated
           else np.zeros(th.size, dtype=bool))
    finite = np.isfinite(th) & np.isfinite(f)
    contact = finite & (th > 0)
    use = contact & ~sat & (f > 0)
    n_missing = int((~finite).sum())
    n_no_contact = int((finite & ~(th > 0)).sum())
    n_saturated = int((contact & sat).sum())
    n_excluded = int((contact & ~sat & ~(f > 0)).sum())
    n = int(use.sum())
    where = f"speed {speed_mm_s:g} mm/s"
    if n < cfg.min_samples:
        raise InputError(where, f"only {n} usable sample(s) (F > 0 and theta_con > 0); need {cfg.min_samples}")
    x, y, g = th[use], np.log(f[use]), groups[use]
    if not np.ptp(x) > 0:
        raise InputError(where, "theta_con is constant; Eq. (8) has no slope to fit")
    X = np.column_stack([np.ones(n), x])
    xtx_inv = np.linalg.inv(X.T @ X)
    coef = xtx_inv @ (X.T @ y)
    resid = y - X @ coef
    s2 = float(resid @ resid) / (n - 2)
    v_ols = s2 * xtx_inv
    rho = float(np.clip(_lag1_within(resid, g), 0.0, 0.999))
    n_eff = max(n * (1 - rho) / (1 + rho), 3.0)
    labels, codes = np.unique(g, return_inverse=True)
    n_trials = int(labels.size)
    method = cfg.se
    if method == "auto":
        method = "cluster" if n_trials >= cfg.min_clusters else "effective_n"
    if method == "cluster":
        if n_trials < 2:
            raise InputError(where, "cluster-robust errors need at least two trials")
        scores = np.zeros((n_trials, 2))
        np.add.at(scores, codes, X * resid[:, None])
        meat = scores.T @ scores
        factor = n_trials / (n_trials - 1) * (n - 1) / (n - 2)
        cov = factor * xtx_inv @ meat @ xtx_inv
        df = float(n_trials - 1)
    elif method == "effective_n":
        cov = v_ols * (n / n_eff)
        df = max(n_eff - 2.0, 1.0)
    else:
        cov = v_ols
        df = float(n - 2)
    tss = float(((y - y.mean()) ** 2).sum())
    mid = 0.5 * (x.min() + x.max())
    lo_r, hi_r = resid[x < mid], resid[x >= mid]
    hetero = float(np.var(hi_r) / np.var(lo_r)) if lo_r.size > 2 and hi_r.size > 2 and np.var(lo_r) > 0 else math.nan
    return SpeedFit(
        speed_mm_s=float(speed_mm_s),
        c1=float(coef[0]),
        c2=float(coef[1]),
        c1_se=float(math.sqrt(cov[0, 0])),
        c2_se=float(math.sqrt(cov[1, 1])),
        n=n,
        n_excluded=n_excluded,
        n_no_contact=n_no_contact,
        n_saturated=n_saturated,
        n_missing=n_missing,
        n_trials=n_trials,
        se_method=method,
        df=df,
        df_pred=max(n_eff - 2.0, 1.0),
        cov=((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))),
        sigma_log=math.sqrt(s2),
        r2=1.0 - float(resid @ resid) / tss if tss > 0 else math.nan,
        rho=rho,
        n_eff=float(n_eff),
        c1_se_ols=float(math.sqrt(v_ols[0, 0])),
        c2_se_ols=float(math.sqrt(v_ols[1, 1])),
        theta_con_min=float(x.min()),
        theta_con_max=float(x.max()),
        hetero_ratio=hetero,
        level=cfg.level,
    )


def _order(table: pd.DataFrame) -> pd.DataFrame:
    """Rows grouped by trial, in time order within a trial (for the autocorrelation)."""
    keys = ["trial", "time_s"] if "time_s" in table.columns else ["trial"]
    return table.sort_values(keys, kind="stable") if "trial" in table.columns else table


def fit_bounds(synced: pd.DataFrame, cfg: BoundsConfig = BoundsConfig()) -> tuple[list[SpeedFit], list[dict]]:
    """Eq. (8) at every speed of a synced table.

    Parameters
    ----------
    synced : DataFrame
        ``speed_mm_s`` (mm/s), ``force_g`` (g), ``theta_con`` (rad); optional ``trial``,
        ``time_s`` (s), ``saturated``.
    cfg : BoundsConfig
        Settings.

    Returns
    -------
    fits : list of SpeedFit
        One per speed that could be fitted, by increasing speed.
    skipped : list of dict
        ``{speed_mm_s, reason}`` for speeds that could not.
    """
    fits, skipped = [], []
    for speed, part in synced.groupby(synced["speed_mm_s"].round(9), sort=True):
        part = _order(part)
        try:
            fits.append(fit_eq8(
                part["theta_con"].to_numpy(dtype=float), part["force_g"].to_numpy(dtype=float),
                speed_mm_s=float(speed),
                trial=part["trial"].to_numpy() if "trial" in part.columns else None,
                saturated=part["saturated"].to_numpy(dtype=bool) if "saturated" in part.columns else None,
                cfg=cfg,
            ))
        except InputError as exc:
            skipped.append({"speed_mm_s": float(speed), "reason": exc.problem})
    return fits, skipped


# --------------------------------------------------------------------------- bands


def bands(fit: SpeedFit, theta_con: np.ndarray | Sequence[float]) -> pd.DataFrame:
    """Eq. (9) curve with its confidence and prediction bands at given θ_con.

    Parameters
    ----------
    fit : SpeedFit
        The speed's fit.
    theta_con : array_like
        Contact angles (rad).

    Returns
    -------
    DataFrame
        :data:`BANDS_COLUMNS`: ``f_fit_g`` (median force, g), ``ci_lo_g``/``ci_hi_g`` (the
        median curve's confidence band, g) and ``pi_lo_g``/``pi_hi_g`` (the prediction band for
        a new sample — the safety boundary, g).
    """
    from scipy.stats import t as student_t

    th = np.asarray(theta_con, dtype=float)
    cov = np.asarray(fit.cov)
    X = np.column_stack([np.ones(th.size), th])
    y = fit.c1 + fit.c2 * th
    var_mean = np.einsum("ij,jk,ik->i", X, cov, X)
    q = (1 + fit.level) / 2
    t_ci = float(student_t.ppf(q, fit.df))
    t_pi = float(student_t.ppf(q, fit.df_pred))
    half_ci = t_ci * np.sqrt(var_mean)
    half_pi = t_pi * np.sqrt(var_mean + fit.sigma_log ** 2)
    return pd.DataFrame({
        "speed_mm_s": np.full(th.size, fit.speed_mm_s),
        "theta_con": th,
        "f_fit_g": np.exp(y),
        "ci_lo_g": np.exp(y - half_ci),
        "ci_hi_g": np.exp(y + half_ci),
        "pi_lo_g": np.exp(y - half_pi),
        "pi_hi_g": np.exp(y + half_pi),
    })


def bands_table(fits: Sequence[SpeedFit], cfg: BoundsConfig = BoundsConfig()) -> pd.DataFrame:
    """The bands of every fit on ``cfg.n_grid`` θ_con points spanning its fitted range."""
    parts = [bands(f, np.linspace(f.theta_con_min, f.theta_con_max, cfg.n_grid)) for f in fits]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=list(BANDS_COLUMNS))


# --------------------------------------------------------------------------- output


def bounds_record(fits: Sequence[SpeedFit], skipped: Sequence[dict], cfg: BoundsConfig, **extra: Any) -> dict:
    """The content of ``bounds.json`` (SPEC §6 ``by_speed`` plus documented extras)."""
    by_speed = []
    for f in fits:
        rec = {k: getattr(f, k) for k in ("speed_mm_s", "c1", "c2", "c1_se", "c2_se", "n", "n_excluded")}
        rec.update({k: getattr(f, k) for k in f.__dataclass_fields__ if k not in rec})
        by_speed.append(rec)
    return {
        "model": "Eq. (8): ln F = c1 + c2 * theta_con (F in g, theta_con in rad, OLS on F > 0 and theta_con > 0); "
                 "Eq. (9): F = exp(c1 + c2 * theta_con), the median force",
        "level": cfg.level,
        "se_default": ("cluster-robust by trial (CR1, t with G-1 df) when a speed has >= "
                       f"{cfg.min_clusters} trials, else OLS scaled by n/n_eff (lag-1 autocorrelation within "
                       "trials)") if cfg.se == "auto" else cfg.se,
        "bands": {
            "file": "bounds_bands.csv",
            "confidence": "ci_lo_g..ci_hi_g: where the median curve exp(c1 + c2 theta_con) lies",
            "prediction": "pi_lo_g..pi_hi_g: where one force sample of a new insertion lies "
                          "(the paper's safety boundaries)",
        },
        "n_excluded": "contact samples (theta_con > 0) left out because F <= 0; n_no_contact, n_saturated "
                      "and n_missing count the other samples not fitted",
        "by_speed": by_speed,
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
    from pipeline.io import atomic_write_csv, atomic_write_json, provenance

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

"""The evidence of the gap diagnosis: lack of fit against the scatter between repeats, where the
gap lies, and the bootstrap over trials.

*Is there a gap?*  A model's held-out residuals (each speed predicted from the others) are
averaged per trial in cells of insertion phase (before the start, ``phase_bins`` bins of the
insertion, the dwell); each (speed, phase) cell's mean is t-tested against the scatter *between
repeats* (trials are the independent unit, so autocorrelation within a curve does not inflate the
evidence), Holm-corrected over cells. Two families, Bonferroni-combined
(:func:`two_part_lack_of_fit`): *level* (the speed's common prediction, gain 1, so the trials'
placement scales stay in the repeat scatter; standard errors inflated by sqrt(S/(S-1)) because a
held-out level is calibrated on the other speeds' equally random placements) and *shape* (every
trial's gain fitted freely).

*Where?*  The held-out residuals, binned over speed × theta_con and speed × phase (before, early,
middle, late, dwell), with a t-test over trials and a Benjamini–Hochberg q-value per cell and a
split of the speed × theta_con cell means into speed, angle and interaction shares
(:func:`where_is_the_gap`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import pandas as pd
from scipy import stats

from tympani.pipeline.diagnosis.config import PHASES, DiagnosisConfig
from tympani.pipeline.diagnosis.prepare import Prepared

__all__ = [
    "LackOfFit", "TwoPartLackOfFit", "VarianceSplit", "GapCell", "ThetaCell", "PhaseCell", "GapLocation",
    "lack_of_fit", "two_part_lack_of_fit", "systematic_gap", "where_is_the_gap", "trial_sse", "bootstrap_weights",
    "bootstrap_mse", "peak_drop",
]


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class LackOfFit:
    """A lack-of-fit test of residuals against the scatter between repeats (:func:`lack_of_fit`).

    Attributes
    ----------
    p_value : float
        Holm-adjusted smallest p-value over the cells.
    significant : bool
        ``p_value < alpha``.
    cells : int
        (speed, phase) cells tested.
    significant_cells : int
        Cells significant after Holm's correction.
    alpha : float
        Level of the test.
    systematic_rms_g : float
        Noise-corrected RMS of the cell means (g): the repeatable part of the misfit.
    repeat_scatter_g : float
        RMS standard error of the cell means (g).
    """

    p_value: float
    significant: bool
    cells: int
    significant_cells: int
    alpha: float
    systematic_rms_g: float
    repeat_scatter_g: float


@dataclass(frozen=True)
class TwoPartLackOfFit:
    """Lack of fit of level and of shape, Bonferroni-combined (:func:`two_part_lack_of_fit`).

    Attributes
    ----------
    p_value : float
        ``min(1, 2 min(level.p_value, shape.p_value))``.
    significant : bool
        ``p_value < alpha``.
    alpha : float
        Level of the combined test.
    level : LackOfFit
        The test of the gain-1 residuals (each speed's common prediction).
    shape : LackOfFit
        The test of the residuals with every trial's gain free.
    systematic_rms_g : float
        The level test's systematic misfit (g).
    repeat_scatter_g : float
        The level test's repeat scatter (g).
    """

    p_value: float
    significant: bool
    alpha: float
    level: LackOfFit
    shape: LackOfFit
    systematic_rms_g: float
    repeat_scatter_g: float


@dataclass(frozen=True)
class VarianceSplit:
    """Shares (dimensionless, summing to 1) of the weighted sum of squares of the speed × theta_con
    cell means due to speed, theta_con (added second) and their interaction (the rest)."""

    speed: float
    theta_con: float
    interaction: float


@dataclass(frozen=True)
class GapCell:
    """The residual in one cell of the "where" analysis.

    Attributes
    ----------
    speed_mm_s : float
        Nominal speed (mm/s).
    n_trials : int
        Trials with rows in the cell.
    mean_g, se_g : float
        Mean over trials of the trials' mean residual (g; measured - model) and its standard error.
    t, p : float
        t statistic and two-sided p-value of the mean against 0 (NaN with one trial).
    model_g : float
        Mean absolute model force (g) in the cell.
    rel_pct : float
        ``mean_g`` as a percentage of ``model_g``.
    q : float
        Benjamini–Hochberg q-value.
    significant : bool
        ``q`` below the level.
    """

    speed_mm_s: float
    n_trials: int
    mean_g: float
    se_g: float
    t: float
    p: float
    model_g: float
    rel_pct: float
    q: float
    significant: bool


@dataclass(frozen=True)
class ThetaCell(GapCell):
    """A speed × theta_con cell (:class:`GapCell`) and its theta_con range (rad; 0–0 for the rows
    without contact)."""

    theta_lo_rad: float
    theta_hi_rad: float


@dataclass(frozen=True)
class PhaseCell(GapCell):
    """A speed × insertion-phase cell (:class:`GapCell`); ``phase`` is one of
    :data:`tympani.pipeline.diagnosis.config.PHASES`."""

    phase: str


@dataclass(frozen=True)
class GapLocation:
    """Where the residuals lie (:func:`where_is_the_gap`).

    Attributes
    ----------
    summary : str
        The significant cells in words.
    speeds_mm_s : tuple of float
        Speeds (mm/s) of the significant cells, increasing.
    theta_con_range_rad : tuple of float or None
        theta_con range (rad) of the significant contact cells.
    phases : tuple of str
        Phases of the significant cells, in :data:`tympani.pipeline.diagnosis.config.PHASES` order.
    sign : str or None
        ``above``, ``below`` or ``mixed``: the measured force against the model in the significant
        cells (None without any).
    before_contact : bool
        Whether a cell without contact is significant.
    variance_split : VarianceSplit
        Shares of the speed × theta_con cell means.
    cells_theta : tuple of ThetaCell
    cells_phase : tuple of PhaseCell
    """

    summary: str
    speeds_mm_s: tuple[float, ...]
    theta_con_range_rad: tuple[float, float] | None
    phases: tuple[str, ...]
    sign: str | None
    before_contact: bool
    variance_split: VarianceSplit
    cells_theta: tuple[ThetaCell, ...]
    cells_phase: tuple[PhaseCell, ...]


# --------------------------------------------------------------------------- statistics


def _trial_cells(ds: Prepared, residual: np.ndarray, cell: np.ndarray) -> pd.DataFrame:
    """Per (speed, cell, trial) the mean residual (g) and rows."""
    df = pd.DataFrame({"speed_mm_s": ds.speed, "cell": cell, "trial": ds.trial, "r": residual})
    return df.groupby(["speed_mm_s", "cell", "trial"], sort=True)["r"].agg(mean_g="mean", n="size").reset_index()


def _cell_tests(per_trial: pd.DataFrame, se_factor: float = 1.0) -> pd.DataFrame:
    """One-sample t-test over trials for each (speed, cell): ``mean_g, se_g, t, p, n_trials``
    (``se_factor`` inflates the standard error, e.g. for the calibration error of a held-out
    prediction)."""
    rows = []
    for (speed, cell), grp in per_trial.groupby(["speed_mm_s", "cell"], sort=True):
        m = grp["mean_g"].to_numpy(float)
        k = len(m)
        mean = float(m.mean())
        se = float(se_factor * m.std(ddof=1) / math.sqrt(k)) if k > 1 else float("nan")
        if k > 1 and se > 0:
            t = mean / se
            p = float(2 * stats.t.sf(abs(t), k - 1))
        else:
            t, p = float("nan"), float("nan")
        rows.append(dict(speed_mm_s=float(speed), cell=int(cell), n_trials=k, mean_g=mean, se_g=se, t=t, p=p))
    return pd.DataFrame(rows)


def _holm(p: np.ndarray) -> np.ndarray:
    """Holm-adjusted p-values (NaN kept)."""
    p = np.asarray(p, float)
    out = np.full_like(p, np.nan)
    ok = np.isfinite(p)
    q = p[ok]
    m = len(q)
    if m == 0:
        return out
    order = np.argsort(q)
    adj = np.maximum.accumulate((m - np.arange(m)) * q[order])
    res = np.empty(m)
    res[order] = np.minimum(adj, 1.0)
    out[ok] = res
    return out


def _bh(p: np.ndarray) -> np.ndarray:
    """Benjamini–Hochberg q-values (NaN kept)."""
    p = np.asarray(p, float)
    out = np.full_like(p, np.nan)
    ok = np.isfinite(p)
    q = p[ok]
    m = len(q)
    if m == 0:
        return out
    order = np.argsort(q)
    ranked = np.minimum.accumulate((q[order] * m / (np.arange(m) + 1))[::-1])[::-1]
    res = np.empty(m)
    res[order] = np.minimum(ranked, 1.0)
    out[ok] = res
    return out


def _lof_cell(ds: Prepared, bins: int) -> np.ndarray:
    """Cell per row: 0 before the start, 1..bins over the moving part, bins + 1 in the dwell."""
    moving = 1 + np.minimum((ds.phase * bins).astype(int), bins - 1)
    return np.where(ds.phase_label == 0, 0, np.where(ds.phase_label == 4, bins + 1, moving))


def _systematic_rms(cells: pd.DataFrame) -> float:
    """sqrt(mean(max(mean^2 - se^2, 0))) over cells: the repeatable residual (g), noise-corrected."""
    m2 = cells["mean_g"].to_numpy(float) ** 2 - np.nan_to_num(cells["se_g"].to_numpy(float)) ** 2
    return float(math.sqrt(max(float(np.mean(m2)), 0.0))) if len(m2) else 0.0


def lack_of_fit(ds: Prepared, residual: np.ndarray, *, bins: int = 4, alpha: float = 0.01,
                se_factor: float = 1.0) -> LackOfFit:
    """Lack-of-fit test of a model's residuals against the scatter between repeats.

    Residuals (g) are averaged per trial in phase cells (before the start, ``bins`` bins of the
    moving part, the dwell); each (speed, cell) mean over trials is t-tested against zero with the
    across-trial scatter; Holm's correction over the cells gives the global p-value.

    Parameters
    ----------
    ds : Prepared
    residual : ndarray
        Measured minus model (g) per row.
    bins : int
        Bins of the moving part.
    alpha : float
        Level.
    se_factor : float
        Factor on the standard errors (dimensionless).

    Returns
    -------
    LackOfFit
    """
    cells = _cell_tests(_trial_cells(ds, residual, _lof_cell(ds, bins)), se_factor)
    adj = _holm(cells["p"].to_numpy())
    p_min = float(np.nanmin(adj)) if np.isfinite(adj).any() else 1.0
    return LackOfFit(p_value=p_min, significant=bool(p_min < alpha), cells=int(len(cells)),
                     significant_cells=int(np.sum(adj < alpha)), alpha=alpha, systematic_rms_g=_systematic_rms(cells),
                     repeat_scatter_g=float(np.sqrt(np.nanmean(cells["se_g"] ** 2))))


def two_part_lack_of_fit(ds: Prepared, r_level: np.ndarray, r_shape: np.ndarray,
                         config: DiagnosisConfig) -> TwoPartLackOfFit:
    """Lack of fit of level (gain-1 residuals) and of shape (free-gain residuals), Bonferroni x2.

    A held-out speed's predicted level comes from the other speeds, whose mean pressure scales are
    as random as its own: the level test's standard errors are inflated by sqrt(S / (S - 1)).

    Parameters
    ----------
    ds : Prepared
    r_level : ndarray
        Measured minus model (g) per row, every held-out trial at gain 1.
    r_shape : ndarray
        Measured minus model (g) per row, every held-out trial's gain fitted freely.
    config : DiagnosisConfig
        ``phase_bins`` and ``lof_alpha``.

    Returns
    -------
    TwoPartLackOfFit
    """
    s = len(ds.speeds)
    level = lack_of_fit(ds, r_level, bins=config.phase_bins, alpha=config.lof_alpha / 2,
                        se_factor=math.sqrt(s / max(s - 1, 1)))
    shape = lack_of_fit(ds, r_shape, bins=config.phase_bins, alpha=config.lof_alpha / 2)
    p = min(1.0, 2 * min(level.p_value, shape.p_value))
    return TwoPartLackOfFit(p_value=p, significant=bool(p < config.lof_alpha), alpha=config.lof_alpha, level=level,
                            shape=shape, systematic_rms_g=level.systematic_rms_g,
                            repeat_scatter_g=level.repeat_scatter_g)


def systematic_gap(ds: Prepared, residual: np.ndarray, bins: int = 4) -> float:
    """Noise-corrected RMS (g) of the residual's mean over repeats in (speed, phase) cells."""
    return _systematic_rms(_cell_tests(_trial_cells(ds, residual, _lof_cell(ds, bins))))


def where_is_the_gap(ds: Prepared, residual: np.ndarray, model_g: np.ndarray, *, theta_bins: int = 5,
                     q_level: float = 0.05) -> GapLocation:
    """Where the residuals (measured - model, g) lie: speed × theta_con and speed × phase cells.

    Parameters
    ----------
    ds : Prepared
    residual : ndarray
        Held-out residuals (g) per row.
    model_g : ndarray
        The model force (g) per row (for relative sizes).
    theta_bins : int
        Equal-width theta_con bins over ``(0, theta_hi]``; rows without contact form their own bin.
    q_level : float
        Benjamini–Hochberg level of a significant cell.

    Returns
    -------
    GapLocation
    """
    edges = np.linspace(0.0, ds.theta_hi, theta_bins + 1)
    inner = np.clip(np.searchsorted(edges, ds.theta_con, side="left") - 1, 0, theta_bins - 1)
    th_cell = np.where(ds.theta_con <= 0, -1, inner)
    out = {}
    for key, cell in (("theta", th_cell), ("phase", ds.phase_label)):
        tests = _cell_tests(_trial_cells(ds, residual, cell))
        level = pd.DataFrame({"speed_mm_s": ds.speed, "cell": cell, "m": np.abs(model_g)}).groupby(
            ["speed_mm_s", "cell"])["m"].mean()
        tests["model_g"] = [float(level.loc[(s, c)]) for s, c in zip(tests["speed_mm_s"], tests["cell"])]
        tests["rel_pct"] = 100 * tests["mean_g"] / np.maximum(tests["model_g"], 1e-3)
        tests["q"] = _bh(tests["p"].to_numpy())
        tests["significant"] = tests["q"] < q_level
        out[key] = tests
    th, ph = out["theta"], out["phase"]
    th["theta_lo_rad"] = [0.0 if c < 0 else float(edges[c]) for c in th["cell"]]
    th["theta_hi_rad"] = [0.0 if c < 0 else float(edges[c + 1]) for c in th["cell"]]
    ph["phase"] = [PHASES[int(c)] for c in ph["cell"]]
    split = _variance_split(th)
    sig_t, sig_p = th[th["significant"]], ph[ph["significant"]]
    speeds = sorted(set(sig_t["speed_mm_s"]) | set(sig_p["speed_mm_s"]))
    contact = sig_t[sig_t["cell"] >= 0]
    theta_range = (float(contact["theta_lo_rad"].min()), float(contact["theta_hi_rad"].max())) if len(contact) else None
    phases = [p for p in PHASES if p in set(sig_p["phase"])]
    sig_all = pd.concat([sig_t, sig_p], ignore_index=True)
    before = bool((sig_t["cell"] < 0).any())
    if sig_all.empty:
        sign = None
        summary = "no cell of speed × theta_con or speed × phase differs from the model beyond the scatter between repeats"
    else:
        pos = float((sig_all["mean_g"] > 0).mean())
        sign = "above" if pos > 0.8 else "below" if pos < 0.2 else "mixed"
        worst = sig_all.loc[sig_all["mean_g"].abs().idxmax()]
        words = {"above": "above", "below": "below", "mixed": "above and below"}[sign]
        parts = [f"gap at {', '.join(f'{s:g}' for s in speeds)} mm/s", f"measured force {words} the model"]
        if theta_range:
            parts.append(f"theta_con {theta_range[0]:.2f}-{theta_range[1]:.2f} rad")
        if before:
            parts.append("also without contact")
        if phases:
            parts.append(f"phases: {', '.join(phases)}")
        parts.append(f"largest {float(worst['mean_g']):+.3g} g ({float(worst['rel_pct']):+.0f} %) at "
                     f"{float(worst['speed_mm_s']):g} mm/s")
        parts.append("variance of the speed x theta_con cell means: "
                     + ", ".join(f"{f.name} {100 * getattr(split, f.name):.0f} %" for f in fields(split)))
        summary = "; ".join(parts)
    return GapLocation(summary=summary, speeds_mm_s=tuple(speeds), theta_con_range_rad=theta_range,
                       phases=tuple(phases), sign=sign, before_contact=before, variance_split=split,
                       cells_theta=tuple(ThetaCell(**r) for r in th.drop(columns=["cell"]).to_dict("records")),
                       cells_phase=tuple(PhaseCell(**r) for r in ph.drop(columns=["cell"]).to_dict("records")))


def _variance_split(cells: pd.DataFrame) -> VarianceSplit:
    """Shares of the weighted sum of squares of cell means (about 0) due to speed, theta_con and
    their interaction (speed first, then theta_con added, then the rest)."""
    m = cells["mean_g"].to_numpy(float)
    w = cells["n_trials"].to_numpy(float)
    total = float(np.sum(w * m**2))
    if total <= 0 or len(m) == 0:
        return VarianceSplit(speed=0.0, theta_con=0.0, interaction=0.0)
    s_codes = pd.factorize(cells["speed_mm_s"])[0]
    c_codes = pd.factorize(cells["cell"])[0]

    def ss_fit(design: np.ndarray) -> float:
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(design * sw[:, None], m * sw, rcond=None)
        return float(np.sum(w * (design @ coef) ** 2))

    d_s = np.eye(s_codes.max() + 1)[s_codes]
    d_c = np.eye(c_codes.max() + 1)[c_codes][:, 1:]
    ss_s = ss_fit(d_s)
    ss_sc = ss_fit(np.column_stack([d_s, d_c]))
    return VarianceSplit(speed=ss_s / total, theta_con=max(ss_sc - ss_s, 0.0) / total,
                         interaction=max(total - ss_sc, 0.0) / total)


def trial_sse(ds: Prepared, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum of squared residuals and rows of every trial.

    Parameters
    ----------
    ds : Prepared
        The data (its ``trial`` codes).
    residual : ndarray, shape (n,)
        Residual (g) per row.

    Returns
    -------
    sse : ndarray, shape (T,)
        Sum of squared residuals per trial (g²).
    n : ndarray, shape (T,)
        Rows per trial (float).
    """
    sse = np.bincount(ds.trial, weights=residual**2, minlength=ds.n_trials)
    n = np.bincount(ds.trial, minlength=ds.n_trials).astype(float)
    return sse, n


def bootstrap_weights(ds: Prepared, draws: int, rng: np.random.Generator) -> np.ndarray:
    """Trial multiplicities, shape (draws, T), of a bootstrap over trials stratified by speed."""
    w = np.zeros((draws, ds.n_trials))
    rows = np.arange(draws)[:, None]
    for s in ds.speeds:
        idx = np.flatnonzero(ds.trial_speed == s)
        pick = idx[rng.integers(0, len(idx), size=(draws, len(idx)))]
        np.add.at(w, (np.broadcast_to(rows, pick.shape), pick), 1.0)
    return w


def bootstrap_mse(sse: np.ndarray, n: np.ndarray, weights: np.ndarray, trials: np.ndarray | None = None) -> np.ndarray:
    """Mean squared errors (g^2) under each bootstrap draw.

    Parameters
    ----------
    sse : ndarray, shape (T, C)
        Held-out sum of squared residuals per trial and candidate (g^2).
    n : ndarray, shape (T,)
        Rows per trial.
    weights : ndarray, shape (B, T)
        Trial multiplicities per draw.
    trials : ndarray of bool, optional
        Restrict to these trials (e.g. one speed).

    Returns
    -------
    ndarray, shape (B, C)
    """
    if trials is not None:
        sse, n, weights = sse[trials], n[trials], weights[:, trials]
    return (weights @ sse) / np.maximum(weights @ n, 1.0)[:, None]




def peak_drop(ds: Prepared, force_g: np.ndarray, window: int = 3) -> dict[float, float]:
    """Paper-style relative drop of the peak force per speed, vs the slowest speed.

    Each trial's peak is the maximum of the force smoothed by a centred running mean of ``window``
    rows; peaks are averaged over the trials of a speed; the drop at speed ``v`` is
    ``1 - peak(v) / peak(v_min)`` (dimensionless; positive when faster is lower).

    Parameters
    ----------
    ds : Prepared
    force_g : ndarray
        Force (g) per row (measured or modelled).
    window : int
        Running-mean length (rows).

    Returns
    -------
    dict
        Speed (mm/s) -> drop.
    """
    smooth = pd.Series(force_g).groupby(ds.trial).transform(
        lambda x: x.rolling(window, center=True, min_periods=1).mean())
    peaks = smooth.groupby(ds.trial).max().to_numpy()
    by_speed = pd.Series(peaks).groupby(ds.trial_speed).mean()
    ref = float(by_speed.iloc[0])
    return {float(v): float(1.0 - p / ref) if ref != 0 else float("nan") for v, p in by_speed.items()}


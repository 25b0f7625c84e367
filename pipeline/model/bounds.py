"""Safety bounds of the insertion force, per speed (seed paper Eqs. 8–9; ``bounds.json``).

Eq. (8), as the paper writes it
-------------------------------
For each insertion speed, ordinary least squares of the log force on the angle::

    ln F = c1 · θ + c2 + ε                    (F in g, θ in rad: c1 the slope in 1/rad, c2 the intercept)

on the synced samples with ``F > 0`` and ``θ > 0`` (not saturated, angles present). θ is the
contact angle ``theta_con`` unless the data have only the tip angle (``angle="theta_tip"``).
Eq. (9) is the curve ``F(θ) = exp(c1 θ + c2)``: the *median* force at θ (the geometric mean).

Bands (level 95 % by default), computed in log space and mapped back with ``exp``:

- **confidence band** ``ci_lo_g .. ci_hi_g``: where the median curve lies;
- **prediction band** ``pi_lo_g .. pi_hi_g``: where one force sample of a *new insertion* at that
  speed and angle lies. This is the paper's safety boundary: forces above ``pi_hi_g`` are unusual.

Does the bound hold?
--------------------
A straight line in log space is a strong assumption. Over θ_con the log force is usually concave
(it rises fast after first contact and then more slowly; the paper's own TABLE II is too), so the
line overshoots at both ends of the range and undershoots in the middle, and its band, widened
to hold the misfit, reaches far above the data at the largest angles. Two checks say how much
this matters, per speed:

- **held-out coverage** (``heldout_coverage_eq9``): each trial is left out in turn, the band is
  fitted to the other trials of that speed, and the share of the left-out trial's samples inside
  it is counted (pooled over trials; samples outside the angle range of the fitted trials are
  not counted). A 95 % band that holds covers about 95 %.
- **lack of fit**: a quadratic term is added to Eq. (8) and tested (Wald F test with the same
  trial-robust covariance as the fit). A small p-value says ln F is not linear in θ; the sign of
  the term says whether it is concave or convex.

The recommended bound
---------------------
Beside Eq. (9), tympani fits a small family of well-founded forms in log space: ln F a
polynomial of degree 1, 2 or 3 in θ, each with a constant spread of ln F (Eq. 9's assumption)
or with a scatter of F about the curve μ of ``a μ² + b``: a relative noise plus the sensor's
additive floor, fitted to the squared residuals by iteratively reweighted least squares. Near
the first contact the force is within the sensor's noise, where a constant spread in log space
fails both ways; the second model's band is built in force units and stays finite there. Each
band adds the curve's own uncertainty (the covariance below) to the scatter.
The recommended form is the one whose held-out coverage lies within ``level ± coverage_tol``
(95 ± 3 %) with the narrowest band (mean width in g over the held-out samples); when none does,
the one whose coverage is closest to the level. Its coverage is ``heldout_coverage``. With one
trial at a speed no coverage can be measured: the speed's bounds are written, its coverages are
null with the reason, and the command says so and exits with status 2.

Standard errors
---------------
Samples of one insertion are a curve, not independent draws. ``se_method``:

- ``"cluster"``: cluster-robust (sandwich) covariance with the trials as clusters, CR1 factor
  ``G/(G−1) · (n−1)/(n−p)``; t quantile with ``G − 1`` degrees of freedom.
- ``"effective_n"``: OLS covariance scaled by ``n / n_eff``, ``n_eff = n (1 − ρ) / (1 + ρ)`` with
  ρ the pooled lag-1 autocorrelation of the residuals within trials; ``n_eff − p`` degrees of
  freedom.
- ``"ols"``: ``s² (XᵀX)⁻¹``, ``n − p`` degrees of freedom (right only for independent samples).
- ``"auto"`` (default): ``"cluster"`` with at least ``min_clusters`` (5) trials, else
  ``"effective_n"``.

The prediction bands use the chosen covariance plus the residual variance, with ``n_eff − p``
degrees of freedom (the residual variance's own).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np
import pandas as pd
from scipy import stats
from scipy.optimize import nnls

from tympani.vision.errors import InputError

from tympani.pipeline.model.stats import MAX_RHO, cluster_covariance, effective_sample_size, lag1_autocorrelation

__all__ = [
    "ANGLES",
    "FORMS",
    "BoundsConfig",
    "LogModel",
    "FormScore",
    "LackOfFit",
    "SpeedFit",
    "check_synced",
    "fit_log_model",
    "heldout_score",
    "lack_of_fit",
    "fit_eq8",
    "fit_bounds",
    "bands",
    "bands_table",
    "bands_columns",
    "single_trial_speeds",
    "form_label",
]

#: Angles Eq. (8) may be fitted against.
ANGLES = ("theta_con", "theta_tip")

#: Candidate forms of the recommended bound: name -> (polynomial degree in θ, variance model).
FORMS: dict[str, tuple[int, str]] = {
    "eq9": (1, "constant"),
    "linear, varying spread": (1, "loglinear"),
    "quadratic": (2, "constant"),
    "quadratic, varying spread": (2, "loglinear"),
    "cubic": (3, "constant"),
    "cubic, varying spread": (3, "loglinear"),
}

_SE_METHODS = ("auto", "cluster", "effective_n", "ols")


def form_label(form: str) -> str:
    """A form's name for people: ``"Eq. (9)"`` for the paper's, else the key of :data:`FORMS`."""
    return "Eq. (9)" if form == "eq9" else form


@dataclass(frozen=True)
class BoundsConfig:
    """Settings of the Eq. (8)–(9) fits and of the recommended bound.

    Parameters
    ----------
    level : float
        Coverage of the bands (0–1).
    se : {"auto", "cluster", "effective_n", "ols"}
        Standard-error method (module docstring).
    min_clusters : int
        With ``se="auto"``, fewest trials at a speed for cluster-robust errors.
    min_samples : int
        Fewest usable samples for a speed to be fitted.
    n_grid : int
        Angle points of the bands per speed.
    exclude_saturated : bool
        Leave out samples flagged ``saturated`` (clipped force).
    angle : {"theta_con", "theta_tip"}
        The angle θ of Eq. (8).
    forms : tuple of str
        Candidate forms of the recommended bound (keys of :data:`FORMS`).
    coverage_tol : float
        A form holds when its held-out coverage is within ``level ± coverage_tol``.
    lof_alpha : float
        Level of the lack-of-fit test.
    """

    level: float = 0.95
    se: Literal["auto", "cluster", "effective_n", "ols"] = "auto"
    min_clusters: int = 5
    min_samples: int = 5
    n_grid: int = 101
    exclude_saturated: bool = True
    angle: Literal["theta_con", "theta_tip"] = "theta_con"
    forms: tuple[str, ...] = tuple(FORMS)
    coverage_tol: float = 0.03
    lof_alpha: float = 0.05

    def __post_init__(self) -> None:
        if not 0.0 < self.level < 1.0:
            raise ValueError("level must be in (0, 1)")
        if self.se not in _SE_METHODS:
            raise ValueError(f"se must be one of {', '.join(_SE_METHODS)}, not {self.se!r}")
        if self.min_clusters < 2 or self.min_samples < 5 or self.n_grid < 2:
            raise ValueError("min_clusters >= 2, min_samples >= 5 and n_grid >= 2 are required")
        if self.angle not in ANGLES:
            raise ValueError(f"angle must be one of {', '.join(ANGLES)}, not {self.angle!r}")
        unknown = [f for f in self.forms if f not in FORMS]
        if unknown or "eq9" not in self.forms:
            raise ValueError(f"forms must include 'eq9' and come from {', '.join(FORMS)}")


# --------------------------------------------------------------------------- input


def check_synced(table: pd.DataFrame, source: str | os.PathLike = "synced table") -> pd.DataFrame:
    """The columns of a synced table the bounds use, checked.

    Parameters
    ----------
    table : DataFrame
        A synced table as :func:`tympani.pipeline.force.sync.read_synced` reads it: at least
        ``speed_mm_s`` (mm/s), ``force_g`` (g) and an angle (``theta_con`` or ``theta_tip``,
        rad); ``trial`` and ``time_s`` (s) are used when present (clusters,
        autocorrelation), ``saturated`` too.
    source : str or PathLike
        The file, named in errors.

    Returns
    -------
    DataFrame
        ``trial`` (``"all"`` when the table has none), the number columns the bounds use that
        are present, ``saturated`` when present, ``line`` (the file's line of each row, when
        the table gives it).

    Raises
    ------
    InputError
        Missing columns, no rows, an empty ``speed_mm_s`` (naming the line).
    """
    missing = [c for c in ("speed_mm_s", "force_g") if c not in table.columns]
    if not any(a in table.columns for a in ANGLES):
        missing.append("theta_con")
    if missing:
        raise InputError(source, f"missing column(s) {', '.join(missing)} of a synced table")
    if table.empty:
        raise InputError(source, "synced table has no rows")
    lines = table["line"].to_numpy() if "line" in table.columns else np.arange(len(table)) + 2
    out = pd.DataFrame({"trial": table["trial"].to_numpy() if "trial" in table.columns else ["all"] * len(table)})
    for c in ("speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con", "depth_mm"):
        if c in table.columns:
            out[c] = table[c].to_numpy(dtype=float)
    if out["speed_mm_s"].isna().any():
        i = int(np.argmax(out["speed_mm_s"].isna().to_numpy()))
        raise InputError(f"{source}:{lines[i]}", "speed_mm_s is empty")
    if "saturated" in table.columns:
        out["saturated"] = table["saturated"].to_numpy(dtype=bool)
    out["line"] = lines
    return out


# --------------------------------------------------------------------------- one model in log space


@dataclass(frozen=True)
class LogModel:
    """A fitted model of ln F (F in g) against an angle θ (rad), with its prediction band.

    The median curve is ``exp`` of a polynomial in the scaled angle ``z = (θ − centre) /
    half_range``. With a constant variance the band is built in log space (Eq. 9's way); with
    the varying one the scatter of F about the curve ``μ`` is ``a μ² + b`` (a relative noise and
    the sensor's additive floor, in g²) and the band is built in force units, where that floor
    keeps it finite at small forces.

    Attributes
    ----------
    form : str
        Key of :data:`FORMS`.
    degree : int
        Polynomial degree of the mean.
    variance : {"constant", "loglinear"}
        Variance model.
    centre, half_range : float
        Scaling of θ (rad).
    coef : tuple of float
        Polynomial coefficients in ``z`` (ln g), lowest power first.
    cov : tuple of tuple of float
        Covariance of ``coef`` (``se_method``).
    var_coef : tuple of float
        ``(ln s²,)`` (s the residual sd of ln F) for a constant variance, or ``(a, b)`` of
        ``var(F) = a μ² + b`` (dimensionless, g²) for the varying one.
    df_pred : float
        Degrees of freedom of the prediction band's t quantile.
    df : float
        Degrees of freedom of the confidence band's t quantile.
    se_method : str
        Covariance method.
    n : int
        Samples fitted.
    n_trials : int
        Trials among them.
    rho : float
        Pooled lag-1 autocorrelation of the residuals within trials.
    n_eff : float
        Effective sample size.
    theta_min, theta_max : float
        Angle range fitted (rad).
    """

    form: str
    degree: int
    variance: str
    centre: float
    half_range: float
    coef: tuple[float, ...]
    cov: tuple[tuple[float, ...], ...]
    var_coef: tuple[float, ...]
    df_pred: float
    df: float
    se_method: str
    n: int
    n_trials: int
    rho: float
    n_eff: float
    theta_min: float
    theta_max: float

    def design(self, theta: np.ndarray) -> np.ndarray:
        """Polynomial design matrix (n, degree + 1) at angles ``theta`` (rad)."""
        z = (np.asarray(theta, dtype=float) - self.centre) / self.half_range
        return np.vander(z, self.degree + 1, increasing=True)

    def predict(self, theta: np.ndarray, level: float) -> dict[str, np.ndarray]:
        """Median curve and bands (g) at ``theta`` (rad).

        Returns ``fit``, ``ci_lo``, ``ci_hi`` (where the median curve lies), ``pi_lo``, ``pi_hi``
        (where one new sample lies), all in g.
        """
        X = self.design(theta)
        y = X @ np.asarray(self.coef)
        var_mean = np.einsum("ij,jk,ik->i", X, np.asarray(self.cov), X)
        q = (1.0 + level) / 2.0
        t_ci = float(stats.t.ppf(q, self.df))
        t_pi = float(stats.t.ppf(q, self.df_pred))
        mu = np.exp(y)
        ci_lo, ci_hi = np.exp(y - t_ci * np.sqrt(var_mean)), np.exp(y + t_ci * np.sqrt(var_mean))
        if self.variance == "constant":
            half = t_pi * np.sqrt(var_mean + math.exp(self.var_coef[0]))
            return {"fit": mu, "ci_lo": ci_lo, "ci_hi": ci_hi, "pi_lo": np.exp(y - half), "pi_hi": np.exp(y + half)}
        a, b = self.var_coef
        half = t_pi * np.sqrt(mu * mu * (a + var_mean) + b)  # var(F) plus the curve's own (delta method)
        return {"fit": mu, "ci_lo": ci_lo, "ci_hi": ci_hi, "pi_lo": np.maximum(mu - half, 0.0), "pi_hi": mu + half}


def _variance_function(r2: np.ndarray, mu2: np.ndarray, iterations: int = 4) -> tuple[float, float]:
    """``(a, b) >= 0`` of ``var(F) = a μ² + b`` fitted to squared force residuals ``r2`` (g²).

    ``a`` is a relative noise (dimensionless), ``b`` the sensor's additive noise (g²). Squared
    residuals scatter in proportion to their variance, so the fit is weighted least squares with
    weights ``1 / var²`` from the previous iteration (a Gaussian likelihood's scoring steps).
    """
    Z = np.column_stack([mu2, np.ones(r2.size)])
    w = np.ones(r2.size)
    v = np.array([0.0, max(float(r2.mean()), 1e-12)])
    for _ in range(iterations):
        sw = np.sqrt(w)
        v, _ = nnls(Z * sw[:, None], r2 * sw)
        var = np.maximum(Z @ v, 1e-12)
        w = 1.0 / var**2
    return float(v[0]), max(float(v[1]), 1e-12)


def _fit_quasi(
    X: np.ndarray, force: np.ndarray, start: np.ndarray, groups: np.ndarray, codes: np.ndarray, n_groups: int,
    method: str, iterations: int = 8,
) -> tuple[np.ndarray, tuple[float, float], np.ndarray, float, float, float]:
    """Quasi-likelihood fit of ``E[F] = exp(X β)``, ``var(F) = a μ² + b`` (a log-link GLM).

    Iteratively reweighted least squares: each step refits the variance function to the squared
    residuals and solves the weighted normal equations of the working response
    ``η + (F − μ) / μ`` with weights ``μ² / var``. The covariance of β is the GLM sandwich with the
    trials as clusters (``method="cluster"``), or its model-based bread scaled by ``n / n_eff``
    (Pearson residuals' lag-1 autocorrelation) otherwise.

    Returns
    -------
    tuple
        ``(β, (a, b), covariance, rho, n_eff, df)``.
    """
    n, p = X.shape
    beta = np.asarray(start, dtype=float)
    var_coef = (0.0, 1e-12)
    for _ in range(iterations):
        eta = np.clip(X @ beta, -50.0, 50.0)
        mu = np.exp(eta)
        r = force - mu
        var_coef = _variance_function(r * r * (n / max(n - p, 1)), mu * mu)
        var = np.maximum(var_coef[0] * mu * mu + var_coef[1], 1e-12)
        w = mu * mu / var
        z = eta + r / mu
        sw = np.sqrt(w)
        beta, *_ = np.linalg.lstsq(X * sw[:, None], z * sw, rcond=None)
    mu = np.exp(np.clip(X @ beta, -50.0, 50.0))
    var = np.maximum(var_coef[0] * mu * mu + var_coef[1], 1e-12)
    pearson = (force - mu) / np.sqrt(var)
    rho = float(np.clip(lag1_autocorrelation(pearson, groups, centre=False), 0.0, MAX_RHO))
    n_eff = max(effective_sample_size(n, rho), p + 1.0)
    bread = np.linalg.pinv(X.T @ (X * (mu * mu / var)[:, None]))
    if method == "cluster":
        cov = cluster_covariance(bread, X * ((force - mu) * mu / var)[:, None], codes, n_groups)
        return beta, var_coef, cov, rho, n_eff, float(n_groups - 1)
    dispersion = float(np.mean(pearson * pearson))
    scale = n / n_eff if method == "effective_n" else 1.0
    return beta, var_coef, dispersion * scale * bread, rho, n_eff, max((n_eff if scale != 1.0 else n) - p, 1.0)


def _satterthwaite_df(resid: np.ndarray, codes: np.ndarray, n_groups: int, df_within: float) -> float:
    """Degrees of freedom of a residual variance made of a between-trial and a within-trial part.

    The between-trial part (the variance of the trials' mean residuals) is known from
    ``n_groups - 1`` degrees of freedom, the within-trial part from ``df_within``; Satterthwaite's
    approximation weighs them by their shares. One trial: ``df_within``.
    """
    if n_groups < 2:
        return df_within
    counts = np.bincount(codes, minlength=n_groups).astype(float)
    means = np.bincount(codes, weights=resid, minlength=n_groups) / np.maximum(counts, 1.0)
    between = float(np.var(means, ddof=1))
    within = float(np.mean((resid - means[codes]) ** 2))
    total = between + within
    if total <= 0:
        return df_within
    return float(total**2 / (between**2 / (n_groups - 1) + within**2 / df_within))


def _covariance(X: np.ndarray, resid: np.ndarray, codes: np.ndarray, n_groups: int, method: str,
                n_eff: float) -> tuple[np.ndarray, float]:
    """Coefficient covariance and its t degrees of freedom by ``method``."""
    n, p = X.shape
    xtx_inv = np.linalg.pinv(X.T @ X)
    s2 = float(resid @ resid) / max(n - p, 1)
    if method == "cluster":
        return cluster_covariance(xtx_inv, X * resid[:, None], codes, n_groups), float(n_groups - 1)
    if method == "effective_n":
        return s2 * xtx_inv * (n / n_eff), max(n_eff - p, 1.0)
    return s2 * xtx_inv, float(max(n - p, 1))


def fit_log_model(
    theta: np.ndarray,
    ln_force: np.ndarray,
    groups: np.ndarray,
    form: str = "eq9",
    cfg: BoundsConfig = BoundsConfig(),
    *,
    where: str = "bounds",
) -> LogModel:
    """Fit one form of :data:`FORMS` to usable samples.

    Parameters
    ----------
    theta : ndarray
        Angles (rad) of samples with ``F > 0``, in time order within each group.
    ln_force : ndarray
        ``ln F`` (F in g).
    groups : ndarray of str
        Trial of each sample.
    form : str
        Key of :data:`FORMS`.
    cfg : BoundsConfig
        Standard-error method and cluster threshold.
    where : str
        Names the data in errors.

    Returns
    -------
    LogModel

    Raises
    ------
    InputError
        Too few samples for the form, or a constant angle.
    """
    degree, variance = FORMS[form]
    x = np.asarray(theta, dtype=float)
    y = np.asarray(ln_force, dtype=float)
    g = np.asarray(groups).astype(str)
    n = x.size
    p = degree + 1
    if n < max(cfg.min_samples, p + 3):
        raise InputError(where, f"only {n} usable sample(s) (F > 0 and {cfg.angle} > 0); need "
                                f"{max(cfg.min_samples, p + 3)}")
    lo, hi = float(x.min()), float(x.max())
    if not hi > lo:
        raise InputError(where, f"{cfg.angle} is constant; Eq. (8) has no slope to fit")
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    X = np.vander((x - centre) / half, p, increasing=True)
    labels, codes = np.unique(g, return_inverse=True)
    method = cfg.se
    if method == "auto":
        method = "cluster" if labels.size >= cfg.min_clusters else "effective_n"
    if method == "cluster" and labels.size < 2:
        raise InputError(where, "cluster-robust errors need at least two trials")
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    if variance == "constant":
        resid = y - X @ coef
        rho = float(np.clip(lag1_autocorrelation(resid, g, centre=False), 0.0, MAX_RHO))
        n_eff = max(effective_sample_size(n, rho), p + 1.0)
        cov, df = _covariance(X, resid, codes, labels.size, method, n_eff)
        var_coef: tuple[float, ...] = (math.log(max(float(resid @ resid) / max(n - p, 1), 1e-300)),)
        scaled = resid
    else:
        coef, var_coef, cov, rho, n_eff, df = _fit_quasi(X, np.exp(y), coef, g, codes, labels.size, method)
        mu = np.exp(np.clip(X @ coef, -50.0, 50.0))
        scaled = (np.exp(y) - mu) / np.sqrt(np.maximum(var_coef[0] * mu * mu + var_coef[1], 1e-12))
    df_pred = _satterthwaite_df(scaled, codes, labels.size, max(n_eff - p, 1.0))
    return LogModel(
        form=form, degree=degree, variance=variance, centre=centre, half_range=half,
        coef=tuple(float(c) for c in np.ravel(coef)), cov=tuple(tuple(float(c) for c in row) for row in cov),
        var_coef=var_coef, df_pred=df_pred, df=df, se_method=method, n=n, n_trials=int(labels.size),
        rho=rho, n_eff=float(n_eff), theta_min=lo, theta_max=hi,
    )


# --------------------------------------------------------------------------- held-out checks


@dataclass(frozen=True)
class FormScore:
    """Leave-one-trial-out score of one form at one speed.

    Attributes
    ----------
    form : str
        Key of :data:`FORMS`.
    coverage : float or None
        Share of held-out samples inside the band fitted to the other trials (None: not
        measurable).
    mean_width_g : float or None
        Mean width (g) of those bands at the held-out samples.
    above : float or None
        Share of held-out samples above the band's upper limit (half the misses, 2.5 %, when
        the band is centred).
    n_tested : int
        Held-out samples counted (inside the fitted trials' angle range).
    n_outside : int
        Held-out samples outside that range (not counted).
    folds : int
        Trials left out.
    """

    form: str
    coverage: float | None
    mean_width_g: float | None
    above: float | None
    n_tested: int
    n_outside: int
    folds: int


def heldout_score(theta: np.ndarray, ln_force: np.ndarray, groups: np.ndarray, form: str,
                  cfg: BoundsConfig = BoundsConfig()) -> FormScore:
    """Leave-one-trial-out coverage and width of a form's prediction band.

    Parameters
    ----------
    theta, ln_force, groups : ndarray
        Usable samples (rad, ln g, trial), in time order within a trial.
    form : str
        Key of :data:`FORMS`.
    cfg : BoundsConfig
        Level and fit settings.

    Returns
    -------
    FormScore
        ``coverage`` is None with fewer than two trials or when no fold could be fitted.
    """
    g = np.asarray(groups).astype(str)
    labels = np.unique(g)
    inside = above = tested = outside = folds = 0
    width = 0.0
    if labels.size >= 2:
        for label in labels:
            test = g == label
            try:
                model = fit_log_model(theta[~test], ln_force[~test], g[~test], form, cfg)
            except InputError:
                continue
            th = theta[test]
            keep = (th >= model.theta_min) & (th <= model.theta_max)
            outside += int((~keep).sum())
            if not keep.any():
                continue
            band = model.predict(th[keep], cfg.level)
            f = np.exp(ln_force[test][keep])
            inside += int(np.sum((f >= band["pi_lo"]) & (f <= band["pi_hi"])))
            above += int(np.sum(f > band["pi_hi"]))
            width += float(np.sum(band["pi_hi"] - band["pi_lo"]))
            tested += int(keep.sum())
            folds += 1
    if tested == 0:
        return FormScore(form, None, None, None, 0, outside, folds)
    return FormScore(form, inside / tested, width / tested, above / tested, tested, outside, folds)


@dataclass(frozen=True)
class LackOfFit:
    """Test of Eq. (8)'s straight line against a quadratic in θ (log space).

    Attributes
    ----------
    statistic : float
        Wald F statistic of the quadratic term.
    df1, df2 : float
        Its degrees of freedom.
    p_value : float
        Upper tail probability.
    curvature : float
        The quadratic coefficient (ln g per rad², negative: concave).
    method : str
        Covariance method of the test.
    rejects : bool
        Whether the straight line is rejected at ``alpha``.
    alpha : float
        Level of the test.
    """

    statistic: float
    df1: float
    df2: float
    p_value: float
    curvature: float
    method: str
    rejects: bool
    alpha: float

    def words(self) -> str:
        """The result in a sentence."""
        p = "p < 0.0001" if self.p_value < 1e-4 else f"p = {self.p_value:.2g}"
        if not self.rejects:
            return f"ln F is consistent with a straight line in the angle ({p})"
        shape = "concave" if self.curvature < 0 else "convex"
        return f"ln F is {shape} in the angle, not a straight line ({p})"


def lack_of_fit(theta: np.ndarray, ln_force: np.ndarray, groups: np.ndarray,
                cfg: BoundsConfig = BoundsConfig()) -> LackOfFit:
    """Wald test of a quadratic term added to Eq. (8), with the fit's trial-robust covariance.

    Parameters
    ----------
    theta, ln_force, groups : ndarray
        Usable samples (rad, ln g, trial), in time order within a trial.
    cfg : BoundsConfig
        Standard-error method and ``lof_alpha``.

    Returns
    -------
    LackOfFit
    """
    model = fit_log_model(theta, ln_force, groups, "quadratic", cfg)
    b = model.coef[2]
    var = model.cov[2][2]
    stat = b * b / var if var > 0 else math.inf
    df2 = model.df if model.se_method != "cluster" else float(model.n_trials - 1)
    p = float(stats.f.sf(stat, 1.0, df2)) if math.isfinite(stat) else 0.0
    return LackOfFit(statistic=float(stat), df1=1.0, df2=float(df2), p_value=p,
                     curvature=float(b / model.half_range ** 2), method=model.se_method,
                     rejects=p < cfg.lof_alpha, alpha=cfg.lof_alpha)


# --------------------------------------------------------------------------- one speed


@dataclass(frozen=True)
class SpeedFit:
    """Eq. (8)–(9) and the recommended bound at one speed.

    Parameters
    ----------
    speed_mm_s : float
        Insertion speed (mm/s).
    angle : str
        The angle θ (``theta_con`` or ``theta_tip``).
    c1 : float
        Slope of ln F against θ (1/rad).
    c2 : float
        Intercept of ln F (ln g).
    c1_se, c2_se : float
        Their standard errors (``se_method``).
    n : int
        Samples in the fit.
    n_excluded : int
        Contact samples (θ > 0, angles present, not saturated) left out because F ≤ 0.
    n_no_contact, n_saturated, n_missing : int
        Samples with θ ≤ 0, clipped, or without angle or force.
    n_trials : int
        Trials among the fitted samples.
    se_method : str
        ``"cluster"``, ``"effective_n"`` or ``"ols"``.
    c1_se_ols, c2_se_ols : float
        Textbook OLS standard errors, for comparison.
    sigma_log : float
        Residual standard deviation of ln F about Eq. (8).
    r2 : float
        Coefficient of determination in log space.
    rho, n_eff : float
        Lag-1 autocorrelation of the residuals within trials and the effective sample size.
    theta_min, theta_max : float
        Range of the fitted θ (rad).
    eq9 : LogModel
        Eq. (9) with its bands.
    recommended : LogModel
        The recommended bound.
    scores : tuple of FormScore
        Held-out scores of every candidate form.
    heldout_coverage : float or None
        Held-out coverage of the recommended bound.
    heldout_coverage_eq9 : float or None
        Held-out coverage of Eq. (9)'s prediction band.
    recommended_holds : bool
        The recommended bound's coverage is within ``level ± coverage_tol``.
    coverage_note : str
        Why coverage is missing or no form holds ('' otherwise).
    lack_of_fit : LackOfFit or None
        Test of Eq. (8)'s straight line (None when it could not be run).
    level : float
        Band coverage.
    """

    speed_mm_s: float
    angle: str
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
    c1_se_ols: float
    c2_se_ols: float
    sigma_log: float
    r2: float
    rho: float
    n_eff: float
    theta_min: float
    theta_max: float
    eq9: LogModel
    recommended: LogModel
    scores: tuple[FormScore, ...] = field(default=())
    heldout_coverage: float | None = None
    heldout_coverage_eq9: float | None = None
    recommended_holds: bool = False
    coverage_note: str = ""
    lack_of_fit: LackOfFit | None = None
    level: float = 0.95

    def curve(self, theta: np.ndarray | float) -> np.ndarray:
        """Eq. (9): the median force ``exp(c1 θ + c2)`` (g) at θ (rad)."""
        return np.exp(self.c1 * np.asarray(theta, dtype=float) + self.c2)


def _usable(theta: np.ndarray, force: np.ndarray, saturated: np.ndarray | None,
            cfg: BoundsConfig) -> tuple[np.ndarray, dict[str, int]]:
    finite = np.isfinite(theta) & np.isfinite(force)
    contact = finite & (theta > 0)
    sat = (np.asarray(saturated, dtype=bool) if saturated is not None and cfg.exclude_saturated
           else np.zeros(theta.size, dtype=bool))
    use = contact & ~sat & (force > 0)
    counts = dict(n_missing=int((~finite).sum()), n_no_contact=int((finite & ~(theta > 0)).sum()),
                  n_saturated=int((contact & sat).sum()), n_excluded=int((contact & ~sat & ~(force > 0)).sum()))
    return use, counts


def _eq8_coefficients(model: LogModel) -> tuple[float, float, float, float, np.ndarray]:
    """(c1, c2, se c1, se c2, covariance) of ``ln F = c1 θ + c2`` from a degree-1 model in z."""
    a0, a1 = model.coef
    # ln F = a0 + a1 z with z = (θ - centre) / half_range, so (c1, c2) = t @ (a0, a1)
    t = np.array([[0.0, 1.0 / model.half_range], [1.0, -model.centre / model.half_range]])
    c1, c2 = t @ np.array([a0, a1])
    cov = t @ np.asarray(model.cov) @ t.T
    return float(c1), float(c2), float(math.sqrt(cov[0, 0])), float(math.sqrt(cov[1, 1])), cov


def _choose(scores: Sequence[FormScore], cfg: BoundsConfig) -> tuple[FormScore | None, bool]:
    measured = [s for s in scores if s.coverage is not None]
    if not measured:
        return None, False
    upper = (1.0 - cfg.level) / 2.0 + cfg.coverage_tol / 3.0
    holding = [s for s in measured if abs(s.coverage - cfg.level) <= cfg.coverage_tol  # type: ignore[operator]
               and s.above <= upper]  # type: ignore[operator]
    if holding:
        return min(holding, key=lambda s: (s.mean_width_g, s.form)), True
    return min(measured, key=lambda s: (abs(s.coverage - cfg.level), s.mean_width_g, s.form)), False  # type: ignore[operator]


def fit_eq8(
    theta: np.ndarray,
    force_g: np.ndarray,
    *,
    speed_mm_s: float,
    trial: np.ndarray | None = None,
    saturated: np.ndarray | None = None,
    cfg: BoundsConfig = BoundsConfig(),
) -> SpeedFit:
    """Eq. (8)–(9), the held-out checks and the recommended bound at one speed.

    Parameters
    ----------
    theta : ndarray
        The angle of each sample (rad, ``cfg.angle``); NaN where not measured.
    force_g : ndarray
        Force of each sample (g).
    speed_mm_s : float
        The speed (mm/s), recorded in the result.
    trial : ndarray, optional
        Trial label of each sample (clusters, held-out folds); samples in time order within a
        trial. Default: one trial.
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
        Fewer than ``cfg.min_samples`` usable samples, or the angle constant.
    """
    th = np.asarray(theta, dtype=float)
    f = np.asarray(force_g, dtype=float)
    groups = np.asarray(trial if trial is not None else np.zeros(th.size), dtype=object).astype(str)
    use, counts = _usable(th, f, saturated, cfg)
    where = f"speed {speed_mm_s:g} mm/s"
    x, y, g = th[use], np.log(f[use]), groups[use]
    eq9 = fit_log_model(x, y, g, "eq9", cfg, where=where)
    c1, c2, c1_se, c2_se, _ = _eq8_coefficients(eq9)
    ols = fit_log_model(x, y, g, "eq9", BoundsConfig(se="ols", angle=cfg.angle), where=where)
    _, _, c1_se_ols, c2_se_ols, _ = _eq8_coefficients(ols)
    resid = y - eq9.design(x) @ np.asarray(eq9.coef)
    tss = float(((y - y.mean()) ** 2).sum())
    scores = tuple(heldout_score(x, y, g, form, cfg) for form in cfg.forms)
    chosen, holds = _choose(scores, cfg)
    note = ""
    if eq9.n_trials < 2:
        note = f"one trial at {speed_mm_s:g} mm/s: held-out coverage needs at least two"
    elif chosen is None:
        note = "no held-out fold could be fitted"
    elif not holds:
        note = (f"no form's held-out coverage is within {100 * cfg.level:g} ± {100 * cfg.coverage_tol:g} %; "
                f"the closest is recommended ({100 * chosen.coverage:.1f} %)")  # type: ignore[operator]
    recommended = eq9 if chosen is None else fit_log_model(x, y, g, chosen.form, cfg, where=where)
    try:
        lof = lack_of_fit(x, y, g, cfg)
    except InputError:
        lof = None
    eq9_score = next(s for s in scores if s.form == "eq9")
    return SpeedFit(
        speed_mm_s=float(speed_mm_s), angle=cfg.angle, c1=c1, c2=c2, c1_se=c1_se, c2_se=c2_se, n=eq9.n,
        **counts, n_trials=eq9.n_trials, se_method=eq9.se_method, c1_se_ols=c1_se_ols, c2_se_ols=c2_se_ols,
        sigma_log=math.sqrt(math.exp(eq9.var_coef[0])), r2=1.0 - float(resid @ resid) / tss if tss > 0 else math.nan,
        rho=eq9.rho, n_eff=eq9.n_eff, theta_min=eq9.theta_min, theta_max=eq9.theta_max, eq9=eq9,
        recommended=recommended, scores=scores,
        heldout_coverage=None if chosen is None else chosen.coverage,
        heldout_coverage_eq9=eq9_score.coverage, recommended_holds=holds, coverage_note=note,
        lack_of_fit=lof, level=cfg.level,
    )


def _order(table: pd.DataFrame) -> pd.DataFrame:
    """Rows grouped by trial, in time order within a trial (for the autocorrelation)."""
    keys = ["trial", "time_s"] if "time_s" in table.columns else ["trial"]
    return table.sort_values(keys, kind="stable") if "trial" in table.columns else table


def fit_bounds(synced: pd.DataFrame, cfg: BoundsConfig = BoundsConfig()) -> tuple[list[SpeedFit], list[dict]]:
    """Eq. (8)–(9) and the recommended bound at every speed of a synced table.

    Parameters
    ----------
    synced : DataFrame
        ``speed_mm_s`` (mm/s), ``force_g`` (g), the angle ``cfg.angle`` (rad); optional
        ``trial``, ``time_s`` (s), ``saturated``.
    cfg : BoundsConfig
        Settings.

    Returns
    -------
    fits : list of SpeedFit
        One per speed that could be fitted, by increasing speed.
    skipped : list of dict
        ``{speed_mm_s, reason}`` for speeds that could not.

    Raises
    ------
    InputError
        The table has no column ``cfg.angle``.
    """
    if cfg.angle not in synced.columns or not synced[cfg.angle].notna().any():
        raise InputError("synced table", f"no {cfg.angle} values to fit Eq. (8) against"
                         + ("; try --angle theta_tip" if cfg.angle == "theta_con" and "theta_tip" in synced.columns
                            and synced["theta_tip"].notna().any() else ""))
    fits, skipped = [], []
    for speed, part in synced.groupby(synced["speed_mm_s"].round(9), sort=True):
        part = _order(part)
        try:
            fits.append(fit_eq8(
                part[cfg.angle].to_numpy(dtype=float), part["force_g"].to_numpy(dtype=float),
                speed_mm_s=float(speed),
                trial=part["trial"].to_numpy() if "trial" in part.columns else None,
                saturated=part["saturated"].to_numpy(dtype=bool) if "saturated" in part.columns else None,
                cfg=cfg,
            ))
        except InputError as exc:
            skipped.append({"speed_mm_s": float(speed), "reason": exc.problem})
    return fits, skipped


def single_trial_speeds(fits: Sequence[SpeedFit]) -> list[float]:
    """Speeds (mm/s) whose bounds rest on one trial, where held-out coverage is undefined."""
    return [f.speed_mm_s for f in fits if f.n_trials < 2]


# --------------------------------------------------------------------------- bands


def bands_columns(angle: str = "theta_con") -> tuple[str, ...]:
    """Columns of ``bounds_bands.csv`` for an angle."""
    return ("speed_mm_s", angle, "f_fit_g", "ci_lo_g", "ci_hi_g", "pi_lo_g", "pi_hi_g",
            "rec_fit_g", "rec_lo_g", "rec_hi_g")


def bands(fit: SpeedFit, theta: np.ndarray | Sequence[float]) -> pd.DataFrame:
    """Eq. (9) with its bands and the recommended bound at given angles.

    Parameters
    ----------
    fit : SpeedFit
        The speed's fit.
    theta : array_like
        Angles (rad).

    Returns
    -------
    DataFrame
        :func:`bands_columns`: ``f_fit_g`` (Eq. 9's median force, g), ``ci_lo_g``/``ci_hi_g``
        (its confidence band), ``pi_lo_g``/``pi_hi_g`` (its prediction band, the paper's safety
        boundary), ``rec_fit_g`` and ``rec_lo_g``/``rec_hi_g`` (the recommended bound's median
        and 95 % prediction band), all in g.
    """
    th = np.asarray(theta, dtype=float)
    e = fit.eq9.predict(th, fit.level)
    r = fit.recommended.predict(th, fit.level)
    return pd.DataFrame({
        "speed_mm_s": np.full(th.size, fit.speed_mm_s),
        fit.angle: th,
        "f_fit_g": e["fit"],
        "ci_lo_g": e["ci_lo"],
        "ci_hi_g": e["ci_hi"],
        "pi_lo_g": e["pi_lo"],
        "pi_hi_g": e["pi_hi"],
        "rec_fit_g": r["fit"],
        "rec_lo_g": r["pi_lo"],
        "rec_hi_g": r["pi_hi"],
    })


def bands_table(fits: Sequence[SpeedFit], cfg: BoundsConfig = BoundsConfig()) -> pd.DataFrame:
    """The bands of every fit on ``cfg.n_grid`` angles spanning its fitted range."""
    parts = [bands(f, np.linspace(f.theta_min, f.theta_max, cfg.n_grid)) for f in fits]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=list(bands_columns(cfg.angle)))

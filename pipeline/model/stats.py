"""Small statistics shared by the fits: autocorrelation, effective sample size, covariances.

Every fit of the pipeline (:mod:`tympani.pipeline.model.identify`, :mod:`tympani.pipeline.model.bounds`,
:mod:`tympani.pipeline.diagnosis.analysis`) has rows that come in trials (one force curve each), in time order
within a trial. Samples along a curve are autocorrelated, trials are independent; the functions
here turn that into standard errors and model-selection criteria.

- :func:`lag1_autocorrelation`: pooled lag-1 autocorrelation of residuals within groups.
- :func:`effective_sample_size`: the AR(1) effective sample size ``n (1 − ρ) / (1 + ρ)``.
- :func:`cluster_covariance`: the cluster-robust (CR1) sandwich over groups.
- :func:`gram_pseudo_inverse` and :func:`least_squares_covariances`: the covariances of a
  nonlinear least-squares fit from its Jacobian (naive, cluster, effective-n).
- :func:`correlation_from_covariance`: correlations, with NaN for unidentified parameters.
- :func:`gaussian_criteria`: Gaussian log-likelihood, AIC, AICc and BIC of a least-squares fit.
- :func:`mad_sd`: a robust standard deviation (1.4826 × the median absolute deviation).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = [
    "MAX_RHO",
    "lag1_autocorrelation",
    "effective_sample_size",
    "cluster_covariance",
    "gram_pseudo_inverse",
    "least_squares_covariances",
    "correlation_from_covariance",
    "Criteria",
    "gaussian_criteria",
    "mad_sd",
]

#: Largest lag-1 autocorrelation used for an effective sample size (dimensionless): at 0.999 a
#: curve counts as 1/2000 of its rows, never as none.
MAX_RHO = 0.999


def lag1_autocorrelation(residual: np.ndarray, groups: np.ndarray, *, centre: bool = True) -> float:
    """Pooled lag-1 autocorrelation of residuals within groups.

    ``Σ r_i r_(i-1) / Σ r_i²``, the sum above over neighbouring rows of the same group, the sum
    below over all rows.

    Parameters
    ----------
    residual : ndarray, shape (n,)
        Residuals (any unit), rows sorted by group and by time within a group.
    groups : ndarray, shape (n,)
        Group (trial) label of each row (any comparable type).
    centre : bool
        Subtract the mean residual first (the residuals of a least-squares fit of the force,
        :mod:`tympani.pipeline.model.identify`); False uses them as they are (the log-model and Pearson
        residuals of :mod:`tympani.pipeline.model.bounds`).

    Returns
    -------
    float
        ρ (dimensionless, in [-1, 1]); 0 when no two neighbouring rows share a group or every
        residual is 0.
    """
    same = groups[1:] == groups[:-1]
    if not same.any():
        return 0.0
    r = residual - np.mean(residual) if centre else residual
    num = float(np.sum(r[1:][same] * r[:-1][same]))
    den = float(np.sum(r * r))
    return num / den if den > 0 else 0.0


def effective_sample_size(n: float, rho: float) -> float:
    """AR(1) effective sample size ``n (1 − ρ) / (1 + ρ)``, with ρ clipped to ``[0, MAX_RHO]``.

    Parameters
    ----------
    n : float
        Rows (count).
    rho : float
        Lag-1 autocorrelation of the residuals (:func:`lag1_autocorrelation`); a negative one
        counts as 0 (no more information than ``n`` independent rows).

    Returns
    -------
    float
        ``n_eff`` (count, not rounded; callers floor it where they need a minimum).
    """
    rho_c = min(max(rho, 0.0), MAX_RHO)
    return n * (1 - rho_c) / (1 + rho_c)


def cluster_covariance(bread: np.ndarray, row_scores: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """Cluster-robust (CR1) sandwich covariance ``c B (Σ_g s_g s_gᵀ) B``.

    ``s_g`` is the sum of the row scores of group ``g`` and ``c = G/(G−1) · (n−1)/(n−p)`` the
    small-sample factor over ``G`` groups. Valid for any correlation within a group, provided
    groups are independent and ``G`` is not small.

    Parameters
    ----------
    bread : ndarray, shape (p, p)
        The model-based inverse information, e.g. ``(XᵀX)⁻¹`` or ``(JᵀJ)⁺`` (parameter units²
        per score unit²).
    row_scores : ndarray, shape (n, p)
        Score contribution of every row, e.g. ``X_i r_i`` (design row times residual).
    groups : ndarray of int, shape (n,)
        Group code of every row, ``0 .. n_groups − 1``.
    n_groups : int
        Number of groups ``G`` (at least 2).

    Returns
    -------
    ndarray, shape (p, p)
        Covariance of the parameters (their units squared).
    """
    n, p = row_scores.shape
    scores = np.zeros((n_groups, p))
    np.add.at(scores, groups, row_scores)
    factor = n_groups / (n_groups - 1) * (n - 1) / max(n - p, 1)
    return factor * bread @ (scores.T @ scores) @ bread


def gram_pseudo_inverse(jac: np.ndarray, rtol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """``(JᵀJ)⁺`` on column-scaled coordinates, and which parameters lie in its null space.

    A parameter is *unidentified* when its Jacobian column is zero or it loads (> 0.1) on an
    eigenvector of the scaled ``JᵀJ`` whose eigenvalue is below ``rtol`` times the largest.

    Parameters
    ----------
    jac : ndarray, shape (n, p)
        Jacobian of the residuals (residual unit per parameter unit).
    rtol : float
        Relative eigenvalue below which a direction counts as null (dimensionless).

    Returns
    -------
    inverse : ndarray, shape (p, p)
        The pseudo-inverse (parameter units² per residual unit²).
    unidentified : ndarray of bool, shape (p,)
    """
    norms = np.linalg.norm(jac, axis=0)
    dead = ~(norms > 0)
    scale = np.where(dead, 1.0, norms)
    a = (jac / scale).T @ (jac / scale)
    w, v = np.linalg.eigh(a)
    keep = w > rtol * max(float(w.max()), 1e-300)
    inv = (v[:, keep] / w[keep]) @ v[:, keep].T
    null = np.abs(v[:, ~keep]).max(axis=1) > 0.1 if (~keep).any() else np.zeros(len(w), bool)
    return inv / np.outer(scale, scale), dead | null


def least_squares_covariances(jac: np.ndarray, r: np.ndarray, trial: np.ndarray,
                              rho: float) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Covariances of a least-squares fit by method, and its unidentified parameters.

    - ``naive``: ``s² (JᵀJ)⁺`` with ``s² = RSS / (n − p)``; right for independent errors.
    - ``cluster``: :func:`cluster_covariance` over the trials with row scores ``J_i r_i``
      (all NaN with fewer than two trials).
    - ``neff``: ``naive · n / max(n_eff, 1)`` with ``n_eff`` = :func:`effective_sample_size`.

    Unidentified parameters (:func:`gram_pseudo_inverse`) get an infinite variance and NaN
    covariances in every method.

    Parameters
    ----------
    jac : ndarray, shape (n, p)
        Jacobian of the residuals at the optimum (residual unit per parameter unit).
    r : ndarray, shape (n,)
        Residuals (e.g. g).
    trial : ndarray, shape (n,)
        Trial label of every row.
    rho : float
        Lag-1 autocorrelation of the residuals within trials (:func:`lag1_autocorrelation`).

    Returns
    -------
    covariances : dict of str to ndarray, shape (p, p)
        ``naive``, ``cluster`` and ``neff`` (parameter units squared).
    unidentified : ndarray of bool, shape (p,)
    """
    n, p = jac.shape
    bread, unidentified = gram_pseudo_inverse(jac)
    s2 = float(r @ r) / max(n - p, 1)
    naive = s2 * bread
    out = {"naive": naive}
    codes, groups = np.unique(trial, return_inverse=True)
    g = len(codes)
    if g >= 2:
        out["cluster"] = cluster_covariance(bread, jac * r[:, None], groups, g)
    else:
        out["cluster"] = np.full((p, p), np.nan)
    out["neff"] = naive * n / max(effective_sample_size(n, rho), 1.0)
    if unidentified.any():
        for cov in out.values():
            cov[unidentified, :] = np.nan
            cov[:, unidentified] = np.nan
            cov[unidentified, unidentified] = np.inf
    return out, unidentified


def correlation_from_covariance(cov: np.ndarray) -> np.ndarray:
    """Correlation matrix of a covariance matrix.

    Parameters
    ----------
    cov : ndarray, shape (p, p)
        Covariance (any units); an infinite variance marks an unidentified parameter.

    Returns
    -------
    ndarray, shape (p, p)
        Correlations (dimensionless) clipped to [-1, 1], 1 on the diagonal, NaN in the rows and
        columns of parameters with an infinite variance.
    """
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.clip(cov / np.outer(sd, sd), -1.0, 1.0)
    corr[~np.isfinite(sd), :] = np.nan
    corr[:, ~np.isfinite(sd)] = np.nan
    np.fill_diagonal(corr, 1.0)
    return corr


class Criteria(NamedTuple):
    """Gaussian log-likelihood and information criteria of a least-squares fit (dimensionless)."""

    loglik: float
    aic: float
    aicc: float
    bic: float


def gaussian_criteria(rss: float, n: int, k: int) -> Criteria:
    """Log-likelihood, AIC, AICc and BIC with the maximum-likelihood variance ``σ² = RSS / n``.

    ::

        ln L = -n/2 (ln(2 π σ²) + 1)
        AIC  = 2 k - 2 ln L,   AICc = AIC + 2 k (k + 1) / (n - k - 1),   BIC = k ln(n) - 2 ln L

    ``σ²`` is floored at 1e-300; AICc is infinite when ``n - k - 1 <= 0``. Rows along a curve are
    autocorrelated, so with ``n`` counting rows the criteria overstate the evidence: compare
    models on the same table only.

    Parameters
    ----------
    rss : float
        Residual sum of squares (residual unit squared, e.g. g²).
    n : int
        Rows.
    k : int
        Estimated parameters, the variance ``σ²`` included.

    Returns
    -------
    Criteria
    """
    sigma2 = max(rss / n, 1e-300)
    loglik = -0.5 * n * (math.log(2 * math.pi * sigma2) + 1.0)
    aic = 2 * k - 2 * loglik
    aicc = aic + (2 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else float("inf"))
    bic = k * math.log(n) - 2 * loglik
    return Criteria(loglik, aic, aicc, bic)


def mad_sd(x: np.ndarray, *, centre: bool = True) -> float:
    """Robust standard deviation: 1.4826 × the median absolute deviation.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Values (any unit), n >= 1.
    centre : bool
        Deviations from the median of ``x``; False takes them from 0 (``x`` are residuals).

    Returns
    -------
    float
        σ in the unit of ``x`` (exact for normal data in the limit).
    """
    dev = x - np.median(x) if centre else x
    return 1.4826 * float(np.median(np.abs(dev)))

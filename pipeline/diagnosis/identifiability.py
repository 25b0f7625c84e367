"""How well the diagnosis determines each effect's parameters: standard errors (cluster sandwich
over trials, :func:`tympani.pipeline.model.stats.least_squares_covariances`, conditional on the trial
gains), their largest correlation and their spread over the leave-one-speed-out folds."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tympani.pipeline.diagnosis.candidates import CandidateFit, Design, build_design
from tympani.pipeline.diagnosis.config import CONTACT_WIDTH_MM
from tympani.pipeline.diagnosis.prepare import Prepared
from tympani.pipeline.model.friction import G_N
from tympani.pipeline.model.stats import correlation_from_covariance, lag1_autocorrelation, least_squares_covariances

__all__ = ["ParameterIdentifiability", "identifiability"]


@dataclass(frozen=True)
class ParameterIdentifiability:
    """How well one effect parameter is determined by the fit to all speeds.

    Attributes
    ----------
    value : float
        The fitted value (unit in the parameter's name).
    stderr : float
        Cluster-robust standard error over trials, given the trial gains (inf when undetermined).
    z_vs_null : float
        ``(value - null) / stderr`` (NaN without a finite standard error).
    null : float
        The parameter's no-effect value.
    at_bound : bool
        Whether the value lies on a bound of the search.
    max_abs_corr : float
        Largest absolute correlation with another fitted parameter.
    most_correlated_with : str or None
        That parameter.
    fold_min, fold_max : float
        Range of the value over the leave-one-speed-out folds.
    assessment : str
        In words.
    """

    value: float
    stderr: float
    z_vs_null: float
    null: float
    at_bound: bool
    max_abs_corr: float
    most_correlated_with: str | None
    fold_min: float
    fold_max: float
    assessment: str



def identifiability(ds: Prepared, fit: CandidateFit, folds: list[CandidateFit]) -> dict[str, ParameterIdentifiability]:
    """Standard errors (cluster over trials, given the trial gains), correlations and fold spread of
    an effect's parameters.

    Parameters
    ----------
    ds : Prepared
        The data.
    fit : CandidateFit
        A fit of base + one effect to all speeds.
    folds : list of CandidateFit
        Its leave-one-speed-out fits.

    Returns
    -------
    dict
        Parameter name (the kernel's ``params``) -> :class:`ParameterIdentifiability`.
    """
    cand = fit.candidate
    kern = cand.kernel
    assert kern is not None  # called for the effects only
    g = np.where(np.isfinite(fit.gain), fit.gain, 1.0)[ds.trial]

    def model(x: np.ndarray) -> tuple[np.ndarray, Design]:
        d = build_design(ds, cand, x, fit.nominal)
        kg = d.gained.shape[1]
        f = (d.gained @ fit.coef[:kg]) * g + d.fixed @ fit.coef[kg:] + (d.offset if d.offset is not None else 0.0)
        return f, d

    base, d0 = model(fit.x)
    r = ds.y - base
    cols, names = [], []
    for j, nm in enumerate(cand.nonlinear_names):
        h = 1e-5 * max(1.0, abs(fit.x[j]))
        x2 = fit.x.copy()
        x2[j] += h
        cols.append((model(x2)[0] - base) / h)
        names.append(nm)
    for j, nm in enumerate(("p_tip(0)", "p_tip(hi)", "p_bot(0)", "p_bot(hi)")):
        cols.append(d0.gained[:, j] * g)
        names.append(nm)
    lin_cols = np.column_stack([d0.gained[:, 4:] * g[:, None], d0.fixed])
    scale = CONTACT_WIDTH_MM / G_N if cand.effect == "pressure_profile" else 1.0  # columns per reported unit
    for j, nm in enumerate(kern.linear):
        cols.append(lin_cols[:, j] / scale)  # the + column of a signed pair
        names.append(nm)
    jac = np.column_stack(cols)
    covs, unid = least_squares_covariances(jac, r, ds.trial, lag1_autocorrelation(r, ds.trial))
    cov = covs["cluster"]
    corr = correlation_from_covariance(cov)
    values = fit.effect_params()
    out = {}
    for pname in kern.params:
        j = names.index(pname)
        null = float(kern.null.get(pname, 0.0))
        lo_b, hi_b = kern.bounds.get(pname, (-np.inf, np.inf))
        var = cov[j, j]
        se = float(math.sqrt(var)) if np.isfinite(var) and var >= 0 else float("inf")
        others = [(float(abs(corr[j, o])), names[o]) for o in range(len(names)) if o != j and np.isfinite(corr[j, o])]
        worst = max(others) if others else (float("nan"), None)
        fold_vals = [f.effect_params()[pname] for f in folds]
        value = values[pname]
        z = (value - null) / se if 0 < se < float("inf") else float("nan")
        at_bound = bool(np.isclose(value, lo_b, atol=1e-9) or np.isclose(value, hi_b, atol=1e-9)
                        or (pname in kern.linear and not kern.signed[kern.linear.index(pname)] and value <= 1e-12))
        if not np.isfinite(se) or unid[j]:
            words = "not identified (the fit does not change along it)"
        elif worst[0] > 0.95:
            words = f"hard to separate from {worst[1]} (corr {worst[0]:.2f})"
        elif abs(z) >= 3:
            words = "well determined"
        elif abs(z) >= 2:
            words = "weakly determined"
        else:
            words = "not distinguishable from its null value"
        if at_bound:
            words += f"; at its bound {value:g}"
        out[pname] = ParameterIdentifiability(
            value=value, stderr=se, z_vs_null=z, null=null, at_bound=at_bound, max_abs_corr=worst[0],
            most_correlated_with=worst[1], fold_min=float(min(fold_vals)), fold_max=float(max(fold_vals)),
            assessment=words)
    return out

"""Identify friction and pressure parameters of the paper's friction model from a synced table.

``tympani fit SYNCED --out DIR`` calls :func:`tympani.pipeline.force.sync.read_synced`, :func:`fit_synced` and
:func:`write_fit`.

Method
------
Bounded nonlinear least squares (:func:`scipy.optimize.least_squares`, trust-region reflective)
of the measured force (g) against :func:`tympani.pipeline.model.friction.insertion_force` over every row of
every trial and speed, from several seeded starts. The first start is the base parameters; the
others draw the friction constants at random (seeded) within plausible ranges and set the
pressure coefficients, for those friction constants, by *linear* least squares (the force is
linear in the four pressure coefficients), so every start begins near a sensible pressure
scale. The geometry integrals of every row are computed once
(:func:`tympani.pipeline.model.friction.arc_integrals`), so one model evaluation over 10^4 rows costs well
under a millisecond.

What is identified, and what is not
-----------------------------------
- **Contact width × pressure is exactly degenerate**: the force depends on ``b_c · p`` only.
  By default ``contact_width_mm`` is held (0.03453 mm, the width fitted to the paper's TABLE II)
  and the fitted pressures are *effective* pressures for that width; only the products ``b_c · p`` are physical. ``contact_width_mm``
  can be freed only when every pressure coefficient is held.
- The friction law is seen only through ``mu(v)`` at the distinct speeds of the data, so at
  most that many speed-law constants (``mu_s, mu_k, v_s_mm_s, delta_s, mu_v_s_per_mm``) can
  be free; extra ones are held with a warning (``delta_s`` first, then ``mu_v_s_per_mm``,
  ``v_s_mm_s``, ``mu_s``). By default ``delta_s`` (0.348, TABLE II's) and ``mu_v = 0`` are held.
- The friction term is a small share of the force on realistic arcs (see
  :mod:`tympani.pipeline.model.friction`), so ``mu`` values carry much larger relative uncertainties than
  pressures. Pairs with ``|corr| > 0.95``, parameters at a bound, a nearly singular Jacobian
  and starts that end in different minima are reported as warnings.

Uncertainties
-------------
``J`` is the Jacobian of the residuals at the optimum (central differences), ``r`` the
residuals, ``n`` rows, ``p`` fitted model parameters.

- ``naive``: ``s^2 (J^T J)^-1`` with ``s^2 = RSS / (n - p)``; right for independent errors.
- ``cluster`` (trial-level sandwich, CR1): ``c B (sum_g J_g^T r_g r_g^T J_g) B`` with
  ``B = (J^T J)^-1`` and ``c = G/(G-1) (n-1)/(n-p)`` over the ``G`` trials. Samples within a
  force curve are strongly autocorrelated (slow drift, vibration, model error that persists
  along the insertion), which makes ``naive`` errors too small; the cluster form is valid for
  any correlation within a trial, provided trials are independent and ``G`` is not small.
- ``neff``: ``naive * n / n_eff`` with ``n_eff = n (1 - rho) / (1 + rho)`` and ``rho`` the
  pooled lag-1 autocorrelation of the residuals within trials (AR(1) effective sample size).
- ``v_s_mm_s`` is fitted as ``ln v_s`` (its errors are far from symmetric on the linear scale);
  its ``stderr`` is the delta-method ``v_s * se(ln v_s)``, its ``ci95`` is exp(ln v_s ± 1.96 se).
- Every ``ci95`` is cut to the parameter's bounds (``PARAM_BOUNDS``), which the fit cannot leave.
- ``auto`` (default): ``cluster`` when there are at least ``max(20, 3 p)`` trials, else
  ``neff``. All three are written to fit.json.

Goodness of fit
---------------
Gaussian likelihood with the maximum-likelihood variance ``sigma^2 = RSS / n``::

    ln L = -n/2 (ln(2 pi sigma^2) + 1)
    AIC  = 2 k - 2 ln L,    BIC = k ln(n) - 2 ln L,    AICc = AIC + 2 k (k + 1) / (n - k - 1)

with ``k = p + 1`` (the fitted model parameters and sigma). ``n`` counts rows, so with
autocorrelated samples AIC/BIC overstate the evidence; compare models on the same table only.
Per speed: RMSE, mean residual (bias) and R^2.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from tympani.pipeline.model.data_needs import require
from tympani.vision.errors import InputError
from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom

from tympani.pipeline.model.friction import (
    FLAT_NAMES,
    G_N,
    ArcIntegrals,
    DEFAULT_FRICTION_MODE,
    ContactGeometry,
    FrictionMode,
    FrictionParams,
    LinearPressure,
    arc_integrals,
    flat_params,
    force_from_integrals,
    insertion_force,
    params_from_flat,
    stribeck,
)
from tympani.pipeline.io import atomic_write_csv, atomic_write_json, provenance, to_jsonable
from tympani.pipeline.model.stats import (
    correlation_from_covariance,
    effective_sample_size,
    gaussian_criteria,
    lag1_autocorrelation,
    least_squares_covariances,
)

__all__ = [
    "SYNCED_COLUMNS",
    "PARAM_BOUNDS",
    "DEFAULT_FREE",
    "PRESSURE_NAMES",
    "LOG_PARAMS",
    "FitOptions",
    "ParamEstimate",
    "FitResult",
    "validate_synced",
    "not_moving",
    "fit_synced",
    "fit_to_json",
    "write_fit",
    "synthetic_synced",
]

#: Columns a synced table must have (docs/file-formats.md).
SYNCED_COLUMNS = ("trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con")

#: Bounds of every parameter (units as in :class:`tympani.pipeline.model.friction.FrictionParams`).
PARAM_BOUNDS: dict[str, tuple[float, float]] = {
    "mu_s": (0.0, 1.5),
    "mu_k": (0.0, 1.5),
    "v_s_mm_s": (0.01, 100.0),
    "delta_s": (0.2, 6.0),
    "mu_v_s_per_mm": (0.0, 0.5),
    "contact_width_mm": (1e-3, 5.0),
    "p_tip0_MPa": (0.0, 10.0),
    "p_tip1_MPa_per_rad": (-10.0, 10.0),
    "p_bot0_MPa": (0.0, 10.0),
    "p_bot1_MPa_per_rad": (-10.0, 10.0),
}

#: Ranges the random starts are drawn from (log-uniform for ``v_s_mm_s``).
_START_BOX: dict[str, tuple[float, float]] = {
    "mu_s": (0.05, 0.5),
    "mu_k": (0.05, 0.5),
    "v_s_mm_s": (0.1, 10.0),
    "delta_s": (0.7, 3.0),
    "mu_v_s_per_mm": (0.0, 0.02),
    "contact_width_mm": (0.05, 1.0),
}

PRESSURE_NAMES = ("p_tip0_MPa", "p_tip1_MPa_per_rad", "p_bot0_MPa", "p_bot1_MPa_per_rad")
#: Speed-law constants, in the order they are held when the data have too few speeds.
_SPEED_LAW_DROP_ORDER = ("delta_s", "mu_v_s_per_mm", "v_s_mm_s", "mu_s", "mu_k")

#: Parameters fitted as their logarithm (positive, scale-like; better-behaved errors).
LOG_PARAMS = frozenset({"v_s_mm_s"})

#: Parameters fitted by default (contact width, delta_s and mu_v held: see the module doc).
DEFAULT_FREE = PRESSURE_NAMES + ("mu_s", "mu_k", "v_s_mm_s")

SeMethod = Literal["auto", "cluster", "neff", "naive"]


@dataclass(frozen=True)
class FitOptions:
    """What :func:`fit_synced` fits and how.

    Parameters
    ----------
    free : tuple of str
        Parameters to fit (names of :data:`tympani.pipeline.model.friction.FLAT_NAMES`).
    base : FrictionParams
        Values of the held parameters and the first start (linear pressure laws).
    fixed : mapping of str to float
        Overrides of ``base`` for held parameters (units as in FrictionParams).
    starts : int
        Number of starts (>= 1).
    seed : int
        Seed of the random starts.
    se : {"auto", "cluster", "neff", "naive"}
        Which standard errors are reported as ``stderr`` (see the module docstring).
    min_rows : int
        Fewest usable rows accepted.
    friction_mode : {"vector", "axial"}
        Model variant (:func:`tympani.pipeline.model.friction.force_from_integrals`); "axial" (default) reproduces the
        paper's TABLE II.
    moving_only : bool
        Fit only rows where the robot moves, when the table has ``depth_mm`` (see
        :func:`validate_synced`).
    start_rows : int
        The starts run on at most this many rows, evenly spaced; the best is then polished on
        all rows (a long log costs the starts no more than a short one).
    """

    free: tuple[str, ...] = DEFAULT_FREE
    base: FrictionParams = field(default_factory=FrictionParams)
    fixed: Mapping[str, float] = field(default_factory=dict)
    starts: int = 8
    seed: int = 0
    se: SeMethod = "auto"
    min_rows: int = 20
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE
    moving_only: bool = True
    start_rows: int = 3000


@dataclass(frozen=True)
class ParamEstimate:
    """One fitted parameter.

    Attributes
    ----------
    value : float
        Estimate (unit of the parameter's name).
    stderr : float
        Standard error by the result's ``se_method``.
    stderr_naive, stderr_cluster, stderr_neff : float
        The three estimates (NaN when not computable, e.g. one trial).
    at_bound : bool
        Whether the estimate sits on a bound (its standard error is then not meaningful).
    ci95 : tuple of float
        Approximate 95 % interval (±1.96 stderr; on the log scale for log-scale parameters),
        cut to the parameter's :data:`PARAM_BOUNDS`.
    log_scale : bool
        Whether the parameter is fitted as its logarithm (``v_s_mm_s``): its correlations are
        those of the logarithm and ``stderr`` is the delta-method value ``value * se(log)``.
    """

    value: float
    stderr: float
    stderr_naive: float
    stderr_cluster: float
    stderr_neff: float
    at_bound: bool = False
    ci95: tuple[float, float] = (float("nan"), float("nan"))
    log_scale: bool = False


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_synced`: estimates with their statistics.

    Attributes
    ----------
    params : dict of str to ParamEstimate
        Fitted parameters.
    fixed : dict of str to float
        Held parameters and their values.
    model : FrictionParams
        All parameters at the optimum.
    correlation : pandas.DataFrame
        Correlation of the fitted coordinates (from the ``se_method`` covariance; of the
        logarithm for log-scale parameters such as ``v_s_mm_s``).
    covariance : pandas.DataFrame
        Covariance of the fitted coordinates (same convention).
    n : int
        Rows fitted.
    k : int
        Parameters counted by AIC/BIC (fitted model parameters + sigma).
    rss : float
        Residual sum of squares (g^2).
    rmse_g, sigma_g : float
        Root-mean-square residual (g) (= the ML sigma).
    loglik, aic, aicc, bic : float
        Gaussian log-likelihood and criteria (module docstring).
    by_speed : pandas.DataFrame
        ``speed_mm_s, n, n_trials, rmse_g, bias_g, r2``.
    se_method : str
        ``"cluster"``, ``"neff"`` or ``"naive"``.
    n_trials : int
        Trials (clusters).
    rho_lag1 : float
        Pooled lag-1 autocorrelation of residuals within trials.
    n_eff : float
        Effective number of independent samples.
    warnings : tuple of str
        Identifiability, bound, conditioning and multi-start warnings.
    starts : pandas.DataFrame
        One row per start: ``start, cost, rmse_g, status, nfev, best`` and the end values.
    residuals : pandas.DataFrame
        ``trial, speed_mm_s, time_s, force_g, model_g, residual_g`` per row.
    friction_mode : str
        Model variant fitted.
    """

    params: dict
    fixed: dict
    model: FrictionParams
    correlation: pd.DataFrame
    covariance: pd.DataFrame
    n: int
    k: int
    rss: float
    rmse_g: float
    sigma_g: float
    loglik: float
    aic: float
    aicc: float
    bic: float
    by_speed: pd.DataFrame
    se_method: str
    n_trials: int
    rho_lag1: float
    n_eff: float
    warnings: tuple[str, ...]
    starts: pd.DataFrame
    residuals: pd.DataFrame
    friction_mode: str = DEFAULT_FRICTION_MODE

    def predict(self, table: pd.DataFrame, phantom: Phantom = DEFAULT_PHANTOM) -> np.ndarray:
        """Model force (g) for the rows of a synced-like table (``theta_bot, theta_tip`` in
        rad, ``speed_mm_s`` in mm/s)."""
        return insertion_force(table["theta_bot"].to_numpy(float), table["theta_tip"].to_numpy(float),
                               table["speed_mm_s"].to_numpy(float), self.model, phantom,
                               friction_mode=self.friction_mode)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- input


def not_moving(table: pd.DataFrame, fraction: float = 0.5) -> np.ndarray:
    """Rows where the robot stands: the local depth rate is below ``fraction`` of the trial's speed.

    Parameters
    ----------
    table : pandas.DataFrame
        Synced rows (``trial``, ``time_s`` s, ``speed_mm_s`` mm/s; ``depth_mm`` mm when logged).
    fraction : float
        Share of the nominal speed (dimensionless) below which a row counts as standing.

    Returns
    -------
    ndarray of bool, shape (len(table),)
        True where the depth rate (``np.gradient`` of ``depth_mm`` over ``time_s`` within a trial)
        is below ``fraction × |speed_mm_s|``; False where depth is unknown, a trial has fewer than
        three depth samples or its times do not increase.
    """
    still = np.zeros(len(table), dtype=bool)
    if "depth_mm" not in table.columns:
        return still
    depth = pd.to_numeric(table["depth_mm"], errors="coerce").to_numpy(float)
    time_s = table["time_s"].to_numpy(float)
    speed = table["speed_mm_s"].to_numpy(float)
    trials = table["trial"].astype(str).to_numpy()
    for key in np.unique(trials):
        idx = np.flatnonzero(trials == key)
        idx = idx[np.argsort(time_s[idx], kind="stable")]
        ok = np.isfinite(depth[idx])
        if ok.sum() < 3:
            continue
        sel = idx[ok]
        t = time_s[sel]
        if np.any(np.diff(t) <= 0):
            continue
        rate = np.gradient(depth[sel], t)
        still[sel] = np.abs(rate) < fraction * np.abs(speed[sel])
    return still


def validate_synced(
    table: pd.DataFrame, source: str | os.PathLike = "<synced table>", *, min_rows: int = 20, moving_only: bool = True,
) -> tuple[pd.DataFrame, list[str]]:
    """Check a synced table and return its usable rows.

    Parameters
    ----------
    table : pandas.DataFrame
        Synced table: ``trial``, ``speed_mm_s`` (mm/s), ``time_s`` (s), ``force_g``
        (g), ``theta_tip``, ``theta_bot``, ``theta_con`` (rad).
    source : str or PathLike
        Named in errors.
    min_rows : int
        Fewest usable rows accepted.
    moving_only : bool
        Leave out rows where an optional ``depth_mm`` column (mm) shows the robot standing
        (depth rate below half the trial's speed): the dwell before the start and after the stop.

    Returns
    -------
    table : pandas.DataFrame
        Rows with finite values (and not flagged ``saturated``), sorted by trial and time;
        numeric columns as float.
    notes : list of str
        What was dropped or looks odd (for the fit's warnings).

    Raises
    ------
    vision.errors.InputError
        Missing columns, non-numeric values, non-positive speeds, too few usable rows, no
        row in contact.
    """
    missing = [c for c in SYNCED_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(source, f"missing column(s) {', '.join(missing)} (a synced table needs {', '.join(SYNCED_COLUMNS)})")
    out = table.copy()
    notes: list[str] = []
    for col in SYNCED_COLUMNS[1:]:
        values = pd.to_numeric(out[col], errors="coerce")
        bad = values.isna() & out[col].notna()
        if bad.any():  # only the cells that did not parse are formatted (formatting every float is slow)
            bad &= out[col].astype(str).str.strip() != ""
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{source}:{row + 2}", f"column {col} has a non-numeric value {str(out[col].iloc[row])!r}")
        out[col] = values.astype(float)
    finite = np.isfinite(out[list(SYNCED_COLUMNS[1:])].to_numpy(float)).all(axis=1)
    if (~finite).any():
        notes.append(f"{int((~finite).sum())} of {len(out)} rows with missing or non-finite values were left out")
    out = out[finite]
    if "saturated" in out.columns:
        saturated = out["saturated"].astype(str).str.strip().str.lower().isin(("true", "1", "yes", "t", "y"))
        if saturated.any():
            notes.append(f"{int(saturated.sum())} rows flagged saturated (force sensor at its limit) were left out")
            out = out[~saturated.to_numpy()]
    if moving_only:
        still = not_moving(out)
        if still.any():
            notes.append(f"{int(still.sum())} rows where depth_mm shows the robot standing (before the start or "
                         f"after the stop) were left out: the model describes sliding at the trial's speed")
            out = out[~still]
    if (out["speed_mm_s"] <= 0).any():
        raise InputError(source, "speed_mm_s must be positive (insertions only)")
    if len(out) < min_rows:
        raise InputError(source, f"only {len(out)} usable rows; at least {min_rows} are needed to fit")
    if not (out["theta_tip"] - out["theta_bot"] > 0).any():
        raise InputError(source, "no row has contact (theta_tip > theta_bot): nothing to fit")
    mismatch = np.abs(out["theta_con"] - (out["theta_tip"] - out["theta_bot"]).clip(lower=0.0))
    if (mismatch > 1e-3).any():
        notes.append(f"theta_con differs from theta_tip - theta_bot by up to {float(mismatch.max()):.3g} rad in "
                     f"{int((mismatch > 1e-3).sum())} rows; the model uses theta_tip - theta_bot")
    out["trial"] = out["trial"].astype(str)
    out = out.sort_values(["trial", "time_s"], kind="stable").reset_index(drop=True)
    return out, notes


# --------------------------------------------------------------------------- fit internals


def _effective_free(free: Sequence[str], n_speeds: int) -> tuple[tuple[str, ...], list[str]]:
    """Fitted names after the identifiability rules, and the warnings they caused."""
    unknown = [n for n in free if n not in FLAT_NAMES]
    if unknown:
        raise ValueError(f"unknown parameter(s) to fit: {', '.join(unknown)}; choose from {', '.join(FLAT_NAMES)}")
    names = list(dict.fromkeys(free))
    notes: list[str] = []
    if "contact_width_mm" in names and any(n in names for n in PRESSURE_NAMES):
        names.remove("contact_width_mm")
        notes.append("contact_width_mm and the pressures are exactly degenerate (only b_c*p enters the force): "
                     "contact_width_mm is held and the pressures are effective values for it")
    speed_law = [n for n in names if n in _SPEED_LAW_DROP_ORDER]
    for name in _SPEED_LAW_DROP_ORDER:
        if len(speed_law) <= max(n_speeds, 1):
            break
        if name in speed_law:
            speed_law.remove(name)
            names.remove(name)
            notes.append(f"{name} held: {n_speeds} distinct speed(s) cannot identify "
                         f"{len(speed_law) + 1} speed-law constants")
    return tuple(names), notes


def _build(x: np.ndarray, names: Sequence[str], base_flat: Mapping[str, float], tie_mu: bool) -> FrictionParams:
    values = dict(base_flat)
    values.update(zip(names, map(float, x)))
    if tie_mu:
        values["mu_s"] = values["mu_k"]
    return params_from_flat(values)


def _linear_pressure_start(
    flat: dict[str, float], names: Sequence[str], arcs: ArcIntegrals, speed: np.ndarray, y: np.ndarray,
    mode: FrictionMode,
) -> dict[str, float]:
    """Pressure coefficients that minimise the residuals for the given friction constants."""
    free_p = [n for n in PRESSURE_NAMES if n in names]
    if not free_p:
        return flat
    p = params_from_flat(flat)
    mu = stribeck(speed, p)
    col = 1 if mode == "vector" else 2
    a0 = arcs.g0[:, 0] + mu * arcs.g0[:, col]
    a1 = arcs.g1[:, 0] + mu * arcs.g1[:, col]
    th = arcs.theta_con
    scale = p.contact_width_mm / G_N
    basis = {
        "p_tip0_MPa": scale * (a0 - a1),
        "p_tip1_MPa_per_rad": scale * (a0 - a1) * th,
        "p_bot0_MPa": scale * a1,
        "p_bot1_MPa_per_rad": scale * a1 * th,
    }
    held = sum(flat[n] * basis[n] for n in PRESSURE_NAMES if n not in free_p)
    design = np.stack([basis[n] for n in free_p], axis=1)
    coef, *_ = np.linalg.lstsq(design, y - held, rcond=None)
    out = dict(flat)
    for n, c in zip(free_p, coef):
        lo, hi = PARAM_BOUNDS[n]
        out[n] = float(np.clip(c, lo, hi))
    return out


def _model_jacobian(
    params: FrictionParams, names: Sequence[str], arcs: ArcIntegrals, speed: np.ndarray, mode: FrictionMode,
    tie_mu: bool,
) -> np.ndarray:
    """Analytic derivatives (g per unit of each parameter) of the force at ``params``.

    ``F = K [P_n + d mu(v) P_t]`` with ``K = b_c / G_N``, ``P = p_tip (g0 - g1) + p_bot g1``
    (pressures clipped at 0, so a clipped pressure has zero derivative) and Eq. (7)'s ``mu``.
    """
    tip_law, bot_law = params.p_tip_MPa, params.p_bot_MPa
    assert isinstance(tip_law, LinearPressure) and isinstance(bot_law, LinearPressure)
    th = arcs.theta_con
    p_tip_raw = tip_law(th)
    p_bot_raw = bot_law(th)
    p_tip, p_bot = np.maximum(p_tip_raw, 0.0), np.maximum(p_bot_raw, 0.0)
    col = 1 if mode == "vector" else 2
    g0n, g1n = arcs.g0[:, 0], arcs.g1[:, 0]
    g0t, g1t = arcs.g0[:, col], arcs.g1[:, col]
    direction = np.where(speed < 0, -1.0, 1.0)
    mu = stribeck(speed, params)
    k = params.contact_width_mm / G_N
    p_n = p_tip * (g0n - g1n) + p_bot * g1n
    p_t = p_tip * (g0t - g1t) + p_bot * g1t
    d_tip = k * (p_tip_raw > 0) * ((g0n - g1n) + direction * mu * (g0t - g1t))
    d_bot = k * (p_bot_raw > 0) * (g1n + direction * mu * g1t)
    u = np.abs(speed) / params.v_s_mm_s
    u_d = np.power(u, params.delta_s)
    e = np.exp(-u_d)
    dmu = params.mu_s - params.mu_k
    with np.errstate(divide="ignore", invalid="ignore"):
        log_u = np.where(u > 0, np.log(np.where(u > 0, u, 1.0)), 0.0)
    mu_derivs = {
        "mu_s": e,
        "mu_k": np.ones_like(e) if tie_mu else 1.0 - e,
        "v_s_mm_s": dmu * e * params.delta_s * u_d / params.v_s_mm_s,
        "delta_s": -dmu * e * u_d * log_u,
        "mu_v_s_per_mm": np.abs(speed),
    }
    cols = []
    for name in names:
        if name == "p_tip0_MPa":
            cols.append(d_tip)
        elif name == "p_tip1_MPa_per_rad":
            cols.append(d_tip * th)
        elif name == "p_bot0_MPa":
            cols.append(d_bot)
        elif name == "p_bot1_MPa_per_rad":
            cols.append(d_bot * th)
        elif name == "contact_width_mm":
            cols.append((p_n + direction * mu * p_t) / G_N)
        else:
            cols.append(k * direction * p_t * mu_derivs[name])
    return np.stack(cols, axis=1)


def _by_speed(res: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for speed, grp in res.groupby("speed_mm_s", sort=True):
        r = grp["residual_g"].to_numpy()
        y = grp["force_g"].to_numpy()
        sst = float(np.sum((y - y.mean()) ** 2))
        rows.append(dict(speed_mm_s=float(speed), rmse_g=float(np.sqrt(np.mean(r**2))), n=int(len(grp)),
                         n_trials=int(grp["trial"].nunique()), bias_g=float(np.mean(r)),
                         r2=float(1 - np.sum(r**2) / sst) if sst > 0 else float("nan")))
    return pd.DataFrame(rows, columns=["speed_mm_s", "rmse_g", "n", "n_trials", "bias_g", "r2"])


def _encode(x: np.ndarray, is_log: np.ndarray) -> np.ndarray:
    return np.where(is_log, np.log(np.where(is_log, x, 1.0)), x)


def _decode(u: np.ndarray, is_log: np.ndarray) -> np.ndarray:
    return np.where(is_log, np.exp(np.where(is_log, u, 0.0)), u)


def _random_start(base_flat: Mapping[str, float], names: Sequence[str], rng: np.random.Generator) -> dict[str, float]:
    """Friction constants drawn from :data:`_START_BOX` (log-uniform for log-scale ones)."""
    flat = dict(base_flat)
    for name in names:
        if name in _START_BOX:
            a, b = _START_BOX[name]
            flat[name] = float(np.exp(rng.uniform(np.log(a), np.log(b)))) if name in LOG_PARAMS else float(rng.uniform(a, b))
    return flat


def _multistart(residual, jacobian, starts: Sequence[np.ndarray], lo: np.ndarray, hi: np.ndarray,
                rows: np.ndarray | None = None):
    """Run bounded least squares from every start, polish the best; returns (runs, index of best).

    The starts use the LSMR trust-region solver (cheap per step on tall problems) on ``rows``
    (an evenly spaced subset of the rows, or all); the best is then polished on all rows with the
    exact (SVD) solver, which stops more precisely. Every run's ``cost`` is on all rows.
    """
    p = len(lo)
    if rows is None:
        sub_res, sub_jac = residual, jacobian
    else:
        def sub_res(u):
            return residual(u)[rows]

        def sub_jac(u):
            return jacobian(u)[rows]
    runs = [least_squares(sub_res, u0, jac=sub_jac, bounds=(lo, hi), x_scale="jac", method="trf",
                          tr_solver="lsmr", max_nfev=100 * (p + 1)) for u0 in starts]
    for fit in runs:
        fit.start_cost = float(fit.cost)  # on the rows the starts ran on: comparable between starts
        if rows is not None:
            r = residual(fit.x)
            fit.cost = 0.5 * float(r @ r)
    best_i = int(np.argmin([fit.cost for fit in runs]))
    polished = least_squares(residual, runs[best_i].x, jac=jacobian, bounds=(lo, hi), x_scale="jac", method="trf",
                             max_nfev=20 * (p + 1))
    if polished.cost <= runs[best_i].cost:
        polished.nfev += runs[best_i].nfev
        polished.start_cost = runs[best_i].start_cost
        runs[best_i] = polished
    return runs, best_i


def _identifiability_notes(
    names: Sequence[str], corr: np.ndarray, jac: np.ndarray, u: np.ndarray, is_log: np.ndarray, params: dict,
    *, check_condition: bool = True,
) -> list[str]:
    """Warnings for correlated pairs, a nearly singular Jacobian and poorly determined values."""
    notes = []
    p = len(names)
    for i in range(p):
        for j in range(i + 1, p):
            if abs(corr[i, j]) > 0.95:
                notes.append(f"{names[i]} and {names[j]} are hard to separate with these data (corr {corr[i, j]:+.3f})")
    scale = np.where(is_log, 1.0, np.where(np.abs(u) > 0, np.abs(u), 1.0))
    sv = np.linalg.svd(jac * scale[None, :], compute_uv=False)
    if check_condition and sv[-1] <= 1e-8 * sv[0]:
        notes.append(f"the Jacobian is nearly singular (condition {sv[0] / max(sv[-1], 1e-300):.2g}): some "
                     f"combination of parameters is not identified")
    for name in names:
        est = params[name]
        if est.value != 0 and not est.at_bound:
            rel = est.stderr / abs(est.value)
            if np.isfinite(rel) and rel > 1.0:
                notes.append(f"{name} is poorly determined (stderr {100 * rel:.0f} % of its value)")
    return notes


# --------------------------------------------------------------------------- the fit


def _ci95(value: float, se_u: float, log_scale: bool,
          bounds: tuple[float, float] = (-math.inf, math.inf)) -> tuple[float, float]:
    """The 95 % interval of a parameter fitted as ``u`` (the value, or its log when
    ``log_scale``) with standard error ``se_u`` (in ``u``'s unit), cut to the parameter's
    ``bounds`` (its unit), which the fit cannot leave: a friction coefficient the data barely
    constrain gets (0, its upper bound), not a negative lower end.

    A log-scale parameter the data barely constrain can have a finite standard error beyond
    ``exp``'s range (a flat direction the identifiability test did not flag); its interval is
    then (0, inf), before the cut, instead of an OverflowError.
    """
    half = 1.96 * se_u
    if not log_scale:
        lo, hi = value - half, value + half
    else:
        lo, hi = value * math.exp(-half), value * math.exp(half) if half < 709.0 else math.inf
    return max(lo, bounds[0]), min(hi, bounds[1])


def fit_synced(
    table: pd.DataFrame,
    options: FitOptions = FitOptions(),
    *,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
    source: str | os.PathLike = "<synced table>",
) -> FitResult:
    """Fit the paper's friction model to a synced table over all speeds.

    Parameters
    ----------
    table : pandas.DataFrame
        Synced table (``trial``, ``speed_mm_s`` mm/s, ``time_s`` s, ``force_g`` g,
        ``theta_tip``, ``theta_bot``, ``theta_con`` rad); checked with :func:`validate_synced`.
    options : FitOptions
        Free and held parameters, starts, seed, standard-error method.
    phantom : Phantom or ContactGeometry
        Geometry of the phantom (mm, rad).
    source : str or PathLike
        Named in input errors.

    Returns
    -------
    FitResult

    Raises
    ------
    vision.errors.InputError
        Bad table (see :func:`validate_synced`).
    ValueError
        Unknown parameter names or a non-linear pressure law in ``options.base``.
    """
    if options.starts < 1:
        raise ValueError("starts must be >= 1")
    base_flat = flat_params(options.base)
    unknown = set(options.fixed) - set(FLAT_NAMES)
    if unknown:
        raise ValueError(f"unknown parameter(s) to hold: {', '.join(sorted(unknown))}")
    base_flat.update({k: float(v) for k, v in options.fixed.items()})
    free_requested = [n for n in options.free if n not in options.fixed]
    if all(c in table.columns for c in SYNCED_COLUMNS):  # a tip-only angle track: say so in one line
        require(table, source, "the friction-model fit")
    data, notes = validate_synced(table, source, min_rows=max(options.min_rows, len(free_requested) + 2),
                                  moving_only=options.moving_only)
    speeds = data["speed_mm_s"].to_numpy(float)
    n_speeds = int(np.unique(speeds).size)
    names, id_notes = _effective_free(free_requested, n_speeds)
    notes += id_notes
    tie_mu = n_speeds < 2 and "mu_k" in names and "mu_s" not in names
    if tie_mu:
        notes.append("one speed only: Coulomb friction fitted (mu_s tied to mu_k)")
    if not names:
        raise ValueError("no parameter left to fit")
    y = data["force_g"].to_numpy(float)
    trial = data["trial"].to_numpy()
    arcs = arc_integrals(data["theta_bot"].to_numpy(float), data["theta_tip"].to_numpy(float), phantom)
    mode = options.friction_mode
    # internal coordinates u: log for LOG_PARAMS (v_s_mm_s), the value itself otherwise
    is_log = np.array([nm in LOG_PARAMS for nm in names])
    lo = _encode(np.array([PARAM_BOUNDS[nm][0] for nm in names]), is_log)
    hi = _encode(np.array([PARAM_BOUNDS[nm][1] for nm in names]), is_log)

    def build(u: np.ndarray) -> FrictionParams:
        return _build(_decode(u, is_log), names, base_flat, tie_mu)

    def residual(u: np.ndarray) -> np.ndarray:
        return force_from_integrals(arcs, speeds, build(u), friction_mode=mode) - y

    def jacobian(u: np.ndarray) -> np.ndarray:
        chain = np.where(is_log, _decode(u, is_log), 1.0)  # dx/du
        return _model_jacobian(build(u), names, arcs, speeds, mode, tie_mu) * chain[None, :]

    rng = np.random.default_rng(options.seed)
    start_flats = [dict(base_flat)] + [
        _linear_pressure_start(_random_start(base_flat, names, rng), names, arcs, speeds, y, mode)
        for _ in range(options.starts - 1)
    ]
    u_starts = [np.clip(_encode(np.array([f[nm] for nm in names]), is_log), lo, hi) for f in start_flats]
    rows = (np.unique(np.linspace(0, len(y) - 1, options.start_rows).astype(int))
            if len(y) > options.start_rows else None)
    runs, best_i = _multistart(residual, jacobian, u_starts, lo, hi, rows)
    u = runs[best_i].x
    x = _decode(u, is_log)
    r = residual(u)
    n, p = len(y), len(names)
    rss = float(r @ r)
    starts_df = pd.DataFrame([
        dict(start=i, cost=float(fit.cost), rmse_g=float(np.sqrt(2 * fit.cost / n)), status=int(fit.status),
             nfev=int(fit.nfev), best=i == best_i, **dict(zip(names, map(float, _decode(fit.x, is_log)))))
        for i, fit in enumerate(runs)
    ])
    start_costs = np.array([fit.start_cost for fit in runs])
    at_best = np.isclose(start_costs, start_costs.min(), rtol=1e-4, atol=1e-12)
    if at_best.sum() < max(1, len(runs) // 2):
        notes.append(f"only {int(at_best.sum())} of {len(runs)} starts reached the best cost: the fit surface has "
                     f"several minima or flat directions")

    jac = jacobian(u)
    rho = lag1_autocorrelation(r, trial)
    covs, unidentified = least_squares_covariances(jac, r, trial, rho)
    for name in np.asarray(names)[unidentified]:
        notes.append(f"{name} is not identified by these data (the fit does not change along a direction that "
                     f"moves it): its standard error is reported as infinite")
    n_trials = int(np.unique(trial).size)
    method = options.se
    if method == "auto":
        method = "cluster" if n_trials >= max(20, 3 * p) else "neff"
    cov = covs[method]
    with np.errstate(invalid="ignore"):
        se_u = {m: np.sqrt(np.clip(np.diag(c), 0.0, None)) for m, c in covs.items()}
    corr = correlation_from_covariance(cov)
    dx_du = np.where(is_log, x, 1.0)
    at_bound = np.isclose(u, lo, rtol=1e-6, atol=1e-10) | np.isclose(u, hi, rtol=1e-6, atol=1e-10)
    params = {}
    for j, name in enumerate(names):
        if at_bound[j]:
            notes.append(f"{name} = {x[j]:.4g} is at its bound: its standard error is not meaningful")
        ci = _ci95(float(x[j]), float(se_u[method][j]), bool(is_log[j]), PARAM_BOUNDS[name])
        se, se_naive, se_cluster, se_neff = (float(dx_du[j] * se_u[m][j]) for m in (method, "naive", "cluster", "neff"))
        params[name] = ParamEstimate(
            float(x[j]), se, se_naive, se_cluster, se_neff,
            at_bound=bool(at_bound[j]), ci95=(float(ci[0]), float(ci[1])), log_scale=bool(is_log[j]),
        )
    notes += _identifiability_notes(names, corr, jac, u, is_log, params, check_condition=not unidentified.any())

    sigma2 = rss / n
    k = p + 1
    loglik, aic, aicc, bic = gaussian_criteria(rss, n, k)
    model_params = _build(x, names, base_flat, tie_mu)
    final_flat = flat_params(model_params)
    fixed = {nm: final_flat[nm] for nm in FLAT_NAMES if nm not in names}
    residuals = data[["trial", "speed_mm_s", "time_s", "force_g"]].copy()
    residuals["model_g"] = y + r
    residuals["residual_g"] = -r  # measured - model
    return FitResult(
        params=params, fixed=fixed, model=model_params,
        correlation=pd.DataFrame(corr, index=names, columns=names),
        covariance=pd.DataFrame(cov, index=names, columns=names),
        n=n, k=k, rss=rss, rmse_g=float(np.sqrt(sigma2)), sigma_g=float(np.sqrt(sigma2)),
        loglik=float(loglik), aic=float(aic), aicc=float(aicc), bic=float(bic),
        by_speed=_by_speed(residuals), se_method=method, n_trials=n_trials, rho_lag1=float(rho),
        n_eff=float(effective_sample_size(n, rho)),
        warnings=tuple(notes), starts=starts_df, residuals=residuals, friction_mode=mode,
    )


# --------------------------------------------------------------------------- output


def fit_to_json(result: FitResult) -> dict:
    """The fit.json content (docs/file-formats.md): the main keys first, then the details.

    Parameters
    ----------
    result : FitResult

    Returns
    -------
    dict
        ``params`` ({name: {value, stderr, ...}}), ``correlation`` ({name: {name: r}}),
        ``aic``, ``bic``, ``n``, ``rmse_g``, ``by_speed`` (list of {speed_mm_s, rmse_g, n, ...}),
        and ``k``, ``aicc``, ``loglik``, ``sigma_g``, ``se_method``, ``n_trials``, ``rho_lag1``,
        ``n_eff``, ``fixed``, ``model``, ``warnings``, ``starts``, ``formulas``. JSON-safe:
        non-finite numbers (an unidentified parameter's infinite stderr) become None.
    """
    names = list(result.params)
    return to_jsonable({
        "params": {nm: {"value": e.value, "stderr": e.stderr, "stderr_naive": e.stderr_naive,
                        "stderr_cluster": e.stderr_cluster, "stderr_neff": e.stderr_neff,
                        "ci95": list(e.ci95), "log_scale": e.log_scale, "at_bound": e.at_bound}
                   for nm, e in result.params.items()},
        "correlation": {a: {b: float(result.correlation.loc[a, b]) for b in names} for a in names},
        "aic": result.aic,
        "bic": result.bic,
        "n": result.n,
        "rmse_g": result.rmse_g,
        "by_speed": result.by_speed.to_dict("records"),
        "k": result.k,
        "aicc": result.aicc,
        "loglik": result.loglik,
        "sigma_g": result.sigma_g,
        "se_method": result.se_method,
        "n_trials": result.n_trials,
        "rho_lag1": result.rho_lag1,
        "n_eff": result.n_eff,
        "fixed": result.fixed,
        "model": flat_params(result.model),
        "friction_mode": result.friction_mode,
        "warnings": list(result.warnings),
        "starts": result.starts.to_dict("records"),
        "formulas": {
            "loglik": "-n/2 (ln(2 pi sigma^2) + 1), sigma^2 = RSS/n",
            "aic": "2k - 2 lnL", "bic": "k ln(n) - 2 lnL", "aicc": "AIC + 2k(k+1)/(n-k-1)",
            "k": "fitted model parameters + 1 (sigma)",
            "stderr": f"{result.se_method} (naive: s^2 (J^T J)^-1, s^2 = RSS/(n-p); cluster: CR1 sandwich over "
                      "trials; neff: naive * n/n_eff, n_eff = n (1-rho)/(1+rho))",
        },
    })


def write_fit(result: FitResult, out_dir: str | os.PathLike, *, source: str | os.PathLike | None = None) -> Path:
    """Write ``fit.json``, ``fit_residuals.csv`` and ``fit.provenance.json`` to ``out_dir``.

    Parameters
    ----------
    result : FitResult
    out_dir : str or PathLike
        Output folder (created).
    source : str or PathLike, optional
        The synced table fitted (recorded in the provenance sidecar).

    Returns
    -------
    Path
        The fit.json path.
    """
    out = Path(out_dir)
    path = atomic_write_json(out / "fit.json", fit_to_json(result))
    atomic_write_csv(out / "fit_residuals.csv", result.residuals)
    if source is not None:
        atomic_write_json(out / "fit.provenance.json",
                          provenance(source, {"free": list(result.params), "fixed": result.fixed,
                                              "se_method": result.se_method, "friction_mode": result.friction_mode}))
    return path


# --------------------------------------------------------------------------- synthetic data


def synthetic_synced(
    params: FrictionParams,
    *,
    rng: np.random.Generator,
    speeds_mm_s: Sequence[float] = (0.5, 1.5, 3.0, 5.0, 7.5),
    trials: int = 3,
    depth_mm: float = 15.0,
    samples_per_trial: int = 120,
    noise_rel: float = 0.03,
    noise_floor_g: float = 0.02,
    ar_rho: float = 0.0,
    angle_noise_rad: float = 0.0,
    phantom: Phantom = DEFAULT_PHANTOM,
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE,
) -> pd.DataFrame:
    """A synced table generated from known parameters (for tests and demos).

    Each trial inserts from −1 mm to ``depth_mm`` at constant speed; the tip rides the outer
    wall (``theta_tip`` at wall arc length = depth); the contact start follows
    ``theta_bot = theta_first + lag (theta_tip - theta_first)`` after first contact at
    ``theta_first`` ~ U(1.0, 1.8) rad with ``lag`` ~ U(0.15, 0.45) (as the renderer's random
    policies). Noise per sample: Gaussian with sd ``noise_rel * peak + noise_floor_g``, white
    (``ar_rho = 0``) or AR(1) within a trial.

    Parameters
    ----------
    params : FrictionParams
        True parameters.
    rng : numpy.random.Generator
        Source of all randomness.
    speeds_mm_s : sequence of float
        Insertion speeds (mm/s).
    trials : int
        Trials per speed.
    depth_mm : float
        Final depth (mm).
    samples_per_trial : int
        Rows per trial (evenly spaced in time).
    noise_rel : float
        Noise sd as a fraction of the trial's peak force.
    noise_floor_g : float
        Noise sd added in grams-force.
    ar_rho : float
        Lag-1 correlation of the noise within a trial (0 <= rho < 1).
    angle_noise_rad : float
        Gaussian noise (rad) added to the reported angles after computing the force.
    phantom : Phantom
        Geometry.
    friction_mode : {"vector", "axial"}
        Model variant.

    Returns
    -------
    pandas.DataFrame
        ``trial, speed_mm_s, time_s, force_g, theta_tip, theta_bot, theta_con`` (+ ``depth_mm``,
        ``force_true_g``).
    """
    wall = phantom.outer_wall
    frames = []
    for speed in speeds_mm_s:
        for k in range(trials):
            theta_first = rng.uniform(1.0, 1.8)
            lag = rng.uniform(0.15, 0.45)
            depth = np.linspace(-1.0, depth_mm, samples_per_trial)
            time_s = (depth + 1.0) / speed
            tip = np.where(depth > 0, np.interp(np.clip(depth, 0, None), wall.s, wall.theta), phantom.theta_start)
            bot = np.where(tip > theta_first, theta_first + lag * (tip - theta_first), tip)
            truth = insertion_force(bot, tip, speed, params, phantom, friction_mode=friction_mode)
            sd = noise_rel * float(np.max(np.abs(truth))) + noise_floor_g
            e = rng.normal(0.0, 1.0, samples_per_trial)
            if ar_rho > 0:
                for i in range(1, samples_per_trial):
                    e[i] = ar_rho * e[i - 1] + math.sqrt(1 - ar_rho**2) * e[i]
            tip_obs = tip + rng.normal(0.0, angle_noise_rad, samples_per_trial) if angle_noise_rad > 0 else tip
            bot_obs = bot + rng.normal(0.0, angle_noise_rad, samples_per_trial) if angle_noise_rad > 0 else bot
            bot_obs = np.minimum(bot_obs, tip_obs)
            frames.append(pd.DataFrame({
                "trial": f"v{speed:g}_t{k + 1:02d}".replace(".", "p"), "speed_mm_s": float(speed),
                "time_s": time_s, "force_g": truth + sd * e, "theta_tip": tip_obs, "theta_bot": bot_obs,
                "theta_con": tip_obs - bot_obs, "depth_mm": depth, "force_true_g": truth,
            }))
    return pd.concat(frames, ignore_index=True)

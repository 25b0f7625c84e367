"""The candidate models of the gap diagnosis, how each is fitted and how it predicts.

Candidates
----------
- ``base``: the paper's friction model with the *nominal* friction law
  (:attr:`tympani.pipeline.diagnosis.config.DiagnosisConfig.friction`, by default the paper's mu_s = 0.18, mu_k = 0.12 with the v_s and delta_s fitted to TABLE II: the
  simulation's) and the four pressure coefficients identified (Eq. 6, each linear in theta_con).
- ``control``: the same with the Stribeck law re-identified (``mu_s``, ``mu_k``, ``v_s``). An
  effect must beat it, so that no effect is credited with what a better-fitted Stribeck curve
  already explains. The viscous term of the friction law (a coefficient growing in proportion to
  speed: shear of the lubricant film in the contact) is not part of it: that is viscous drag in
  the contact, and the ``viscous_drag`` candidate carries it.
- one per effect of :data:`tympani.pipeline.model.effects.EFFECTS`: ``base`` + the effect's term, with the
  friction law held nominal. Holding it matters: friction is a small share of the force on these
  arcs (:mod:`tympani.pipeline.model.friction`), so a free Stribeck curve is identified mainly by whatever else
  depends on speed, and combined with an effect (e.g. capstan's ``exp(k mu(v) theta_con)``) it
  turns into a flexible speed × angle interaction that mimics other effects and extrapolates
  badly to held-out speeds.

Every candidate also has a **per-trial gain** on the contact force (a trial's pressure scale:
placements differ by about ±10 %). The gains of a speed average to within ``±2 sd / sqrt(n)`` of 1
(``sd`` the between-trial scatter of the gains, ``n`` the speed's trials): a speed's mean placement
scale is itself a random draw of that size, which no model should be credited for fitting, while
any larger level change (lift's, drag's) is left for the model to explain. On a held-out speed the
gains of its trials are estimated from those trials the same way, with the training fit's scatter.
Sensor-side and additive terms (drift, drag) are not scaled by the gain.

Fitting (variable projection)
-----------------------------
With ``mu(v)`` fixed, the model's force is linear in the pressures. They are parametrised by their
values at ``theta_con = 0`` and at the largest theta_con of the data, both >= 0 (so the clipped and
the linear law agree on the data), and found by non-negative least squares (alternating with the
trial gains) inside every evaluation of the non-linear parameters (the control's friction
constants, an effect's non-linear parameters), which :func:`scipy.optimize.least_squares` fits.
Additive effects (drag, drift, profile) are further linear columns (:mod:`tympani.pipeline.diagnosis.kernels`),
so base, drag, drift and profile need no non-linear search at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares, nnls

from tympani.pipeline.diagnosis.config import CONTACT_WIDTH_MM, DiagnosisConfig
from tympani.pipeline.diagnosis.kernels import VARIANTS, Kernel, kernel
from tympani.pipeline.diagnosis.prepare import Prepared
from tympani.pipeline.model.effects import EFFECTS
from tympani.pipeline.model.friction import G_N, FrictionParams
from tympani.pipeline.model.identify import PARAM_BOUNDS

__all__ = ["Candidate", "CandidateFit", "Design", "candidates", "build_design", "fit_candidate", "predict",
           "heldout_predictions"]

#: The control's friction constants: the Stribeck law of a dry-ish contact. Its viscous term (a friction
#: coefficient growing in proportion to speed: shear of the lubricant in the contact) is left to the
#: viscous_drag candidate, which carries it as its contact term.
_FRICTION_CONTROL = ("mu_k", "mu_sk", "log_v_s")
#: Bounds of the control's constants: mu_sk = mu_s - mu_k >= 0 (static friction is not below kinetic, so the
#: law falls with speed, as Stribeck's does; a friction that rises with speed is viscous shear).
_CONTROL_BOUNDS = {"mu_k": (0.0, 1.5), "mu_sk": (0.0, 1.5), "mu_v_s_per_mm": (0.0, 0.5)}


@dataclass(frozen=True)
class Candidate:
    """A model fitted by the diagnosis.

    Parameters
    ----------
    name : str
        ``"base"``, ``"control"`` or an effect name.
    effect : str or None
        The effect added to the base (None for base and control).
    friction : tuple of str
        Friction constants fitted (the control's ``mu_k``, ``mu_sk`` = mu_s - mu_k >= 0, ``log_v_s`` =
        ln(v_s / 1 mm/s), ``mu_v_s_per_mm``); empty: the nominal friction law is held.
    variant : str
        A richer variant of the effect's kernel (``""``: the plain one).
    """

    name: str
    effect: str | None
    friction: tuple[str, ...] = ()
    variant: str = ""

    @property
    def kernel(self) -> Kernel | None:
        """The effect's kernel (None without an effect)."""
        return None if self.effect is None else kernel(self.effect, self.variant)

    @property
    def nonlinear_names(self) -> tuple[str, ...]:
        """Names of the non-linear parameters, in order."""
        kern = self.kernel
        return self.friction + (kern.nonlinear if kern is not None else ())

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the non-linear parameters."""
        lo, hi = [], []
        for nm in self.friction:
            a, b = ((math.log(PARAM_BOUNDS["v_s_mm_s"][0]), math.log(PARAM_BOUNDS["v_s_mm_s"][1]))
                    if nm == "log_v_s" else _CONTROL_BOUNDS[nm])
            lo.append(a)
            hi.append(b)
        if self.effect is not None:
            kern = self.kernel
            assert kern is not None  # the kernel is None only without an effect
            for nm in kern.nonlinear:
                lo.append(kern.bounds[nm][0])
                hi.append(kern.bounds[nm][1])
        return np.asarray(lo, float), np.asarray(hi, float)

    def n_linear(self) -> int:
        """Linear parameters: 4 pressures + the effect's linear ones."""
        kern = self.kernel
        return 4 + (len(kern.linear) if kern is not None else 0)


def candidates(effects: Sequence[str] = tuple(EFFECTS)) -> list[Candidate]:
    """``base``, ``control`` and base + each effect.

    Parameters
    ----------
    effects : sequence of str
        Effect names of :data:`tympani.pipeline.model.effects.EFFECTS`.
    """
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)}; choose from {', '.join(EFFECTS)}")
    return ([Candidate("base", None), Candidate("control", None, _FRICTION_CONTROL)]
            + [Candidate(e, e) for e in effects]
            + [Candidate(f"{e}:{v}", e, variant=v) for (e, v) in VARIANTS if e in effects])


def _friction_law(cand: Candidate, x: np.ndarray, nominal: FrictionParams) -> FrictionParams:
    if not cand.friction:
        return nominal
    values = dict(zip(cand.friction, map(float, x[: len(cand.friction)])))
    return replace(nominal, mu_s=values["mu_k"] + values["mu_sk"], mu_k=values["mu_k"],
                   v_s_mm_s=math.exp(values["log_v_s"]), mu_v_s_per_mm=values.get("mu_v_s_per_mm", nominal.mu_v_s_per_mm))


@dataclass(frozen=True)
class Design:
    """The linear problem of a candidate at given non-linear parameters.

    Attributes
    ----------
    gained : ndarray, shape (n, kg)
        Columns scaled by the trial gain: the four pressure columns (g/MPa), then any gained effect
        columns.
    fixed : ndarray, shape (n, kf)
        Additive effect columns not scaled by the trial gain (g per unit of their coefficient).
    offset : ndarray, shape (n,), or None
        A fixed term (g) of the model.
    mu : ndarray, shape (n,)
        Friction coefficient per row (dimensionless).
    """

    gained: np.ndarray
    fixed: np.ndarray
    offset: np.ndarray | None
    mu: np.ndarray


def build_design(ds: Prepared, cand: Candidate, x: np.ndarray, nominal: FrictionParams) -> Design:
    """The linear problem of a candidate at non-linear values ``x``.

    Parameters
    ----------
    ds : Prepared
        The data.
    cand : Candidate
        The candidate.
    x : ndarray
        Its non-linear parameters (``Candidate.nonlinear_names``; units in the names).
    nominal : FrictionParams
        The nominal friction law (held unless the candidate fits it).

    Returns
    -------
    Design
    """
    mu = ds.friction_coefficient(_friction_law(cand, x, nominal))
    a = ds.a_n + mu[:, None] * ds.a_t
    kern = cand.kernel
    fixed = np.empty((ds.n, 0))
    offset = None
    if kern is not None:
        nl = np.asarray(x[len(cand.friction):], float)
        if kern.transform is not None:
            a = kern.transform(a, ds, mu, nl)
        if kern.columns is not None:
            cols = kern.columns(ds, mu, nl)
            extra = [cols[:, j] for j in range(cols.shape[1])] + [-cols[:, j] for j, s in enumerate(kern.signed) if s]
            block = np.column_stack(extra)
            if kern.gained:
                a = np.column_stack([a, block])
            else:
                fixed = block
        if kern.offset is not None:
            offset = kern.offset(ds, mu, nl)
    return Design(a, fixed, offset, mu)


def _nnls(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Non-negative least squares ``min |a c - b|, c >= 0`` with column scaling."""
    norms = np.sqrt(np.einsum("ij,ij->j", a, a))
    norms[norms <= 0] = 1.0
    try:
        c, _ = nnls(a / norms, b, maxiter=50 * a.shape[1])
    except RuntimeError:  # pragma: no cover - iteration limit on a degenerate design
        c = np.clip(np.linalg.lstsq(a / norms, b, rcond=None)[0], 0.0, None)
    return c / norms


def _trial_gains(p: np.ndarray, target: np.ndarray, trial: np.ndarray, ds: Prepared, bounds: tuple[float, float],
                 present: np.ndarray, normalise: bool = True, scatter: float | None = None,
                 level_sd: float = 2.0) -> np.ndarray:
    """Least-squares gain per trial of ``p`` towards ``target``, clipped to ``bounds``; 1 for trials
    without contact force.

    With ``normalise``, each speed's mean gain over the trials ``present`` is kept within
    ``±level_sd scatter / sqrt(n)`` of 1: a speed's mean placement scale is as random as that
    (``scatter`` is the between-trial SD of the gains, by default the pooled within-speed SD of
    these), and any larger level change is left for the model to explain.
    """
    num = np.bincount(trial, weights=p * target, minlength=ds.n_trials)
    den = np.bincount(trial, weights=p * p, minlength=ds.n_trials)
    ok = den > 1e-9 * max(float(den.max()), 1e-300)
    g = np.where(ok, num / np.where(ok, den, 1.0), 1.0)
    g = np.clip(g, *bounds)
    if not normalise:
        return g
    sd = _gain_scatter(np.where(present, g, np.nan), ds) if scatter is None else scatter
    return _bounded_levels(g, present, ds, level_sd * sd)


def _bounded_levels(g: np.ndarray, present: np.ndarray, ds: Prepared, scatter: float) -> np.ndarray:
    """Gains whose mean per speed (over ``present`` trials) is moved to within ``±scatter / sqrt(n)``
    of 1, keeping their ratios."""
    k = ds.trial_speed_idx
    m = len(ds.speeds)
    count = np.bincount(k[present], minlength=m).astype(float)
    level = np.bincount(k[present], weights=g[present], minlength=m) / np.maximum(count, 1.0)
    allowed = scatter / np.sqrt(np.maximum(count, 1.0))
    factor = np.where(count > 0, (1.0 + np.clip(level - 1.0, -allowed, allowed)) / np.where(level > 0, level, 1.0), 1.0)
    return np.where(present, g * factor[k], g)


def _solve(design: Design, ds: Prepared, rows: np.ndarray | None, use_gain: bool,
           bounds: tuple[float, float], iterations: int = 3,
           level_sd: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coefficients, trial gains and residuals (model - measured, g) on ``rows`` (None: all).

    Alternates non-negative least squares for the coefficients with per-trial gains.
    """
    y = ds.y if design.offset is None else ds.y - design.offset
    ag, af, tr = design.gained, design.fixed, ds.trial
    if rows is not None:
        ag, af, y, tr = ag[rows], af[rows], y[rows], tr[rows]
    kg = ag.shape[1]
    present = np.zeros(ds.n_trials, dtype=bool)
    present[tr] = True
    g = np.ones(ds.n_trials)
    for it in range(iterations + 1 if use_gain else 1):
        coef = _nnls(np.column_stack([ag * g[tr][:, None], af]), y)
        if not use_gain or it == iterations:
            break
        p = ag @ coef[:kg]
        g = _trial_gains(p, y - af @ coef[kg:], tr, ds, bounds, present, level_sd=level_sd)
    r = (ag @ coef[:kg]) * g[tr] + af @ coef[kg:] - y
    g = np.where(present, g, np.nan)
    return coef, g, r


@dataclass(frozen=True)
class CandidateFit:
    """One candidate fitted to some trials.

    Attributes
    ----------
    candidate : Candidate
    x : ndarray
        Non-linear parameters (``Candidate.nonlinear_names``; ``log_v_s`` is ln(v_s / 1 mm/s)).
    coef : ndarray
        Linear coefficients: the four pressure coordinates (MPa), then the effect's linear
        parameters (signed ones as a +/- pair).
    gain : ndarray
        Trial gain per trial (dimensionless; NaN for trials not fitted).
    rss : float
        Residual sum of squares on the training rows (g^2).
    n : int
        Training rows.
    nfev : int
        Model evaluations of the non-linear search (0 for purely linear candidates).
    nominal : FrictionParams
        The nominal friction law (held unless the candidate fits it).
    """

    candidate: Candidate
    x: np.ndarray
    coef: np.ndarray
    gain: np.ndarray
    rss: float
    n: int
    nfev: int
    nominal: FrictionParams

    @property
    def friction(self) -> FrictionParams:
        """The friction law of this fit."""
        return _friction_law(self.candidate, self.x, self.nominal)

    def params(self, theta_hi: float) -> dict[str, float]:
        """Named parameter values: the friction law (``mu_s``, ``mu_k``, ``v_s_mm_s`` mm/s,
        ``delta_s``, ``mu_v_s_per_mm`` s/mm), pressures for ``contact_width_mm`` = 0.03453 mm (MPa,
        MPa/rad) and the effect's parameters in :data:`tympani.pipeline.model.effects.EFFECTS` units."""
        law = self.friction
        out = dict(mu_s=law.mu_s, mu_k=law.mu_k, v_s_mm_s=law.v_s_mm_s, delta_s=law.delta_s,
                   mu_v_s_per_mm=law.mu_v_s_per_mm)
        u = self.coef[:4]
        out.update(p_tip0_MPa=float(u[0]), p_tip1_MPa_per_rad=float((u[1] - u[0]) / theta_hi),
                   p_bot0_MPa=float(u[2]), p_bot1_MPa_per_rad=float((u[3] - u[2]) / theta_hi))
        out.update(self.effect_params())
        return {k: float(v) for k, v in out.items()}

    def effect_params(self) -> dict[str, float]:
        """The effect's parameters by name (the library's first; empty for base and control).
        Units are in the names; the profile's amplitudes are in g/mm as the library's bump."""
        cand = self.candidate
        if cand.effect is None:
            return {}
        kern = cand.kernel
        assert kern is not None  # the kernel is None only without an effect
        values = dict(zip(kern.nonlinear, map(float, self.x[len(cand.friction):])))
        lin = self.coef[4:]
        n_lin = len(kern.linear)
        neg = iter(lin[n_lin:])
        scale = CONTACT_WIDTH_MM / G_N if cand.effect == "pressure_profile" else 1.0  # MPa -> g/mm
        for j, nm in enumerate(kern.linear):
            values[nm] = scale * float(lin[j] - (next(neg) if kern.signed[j] else 0.0))
        return {nm: values[nm] for nm in kern.params}


def _x_scale(cand: Candidate) -> np.ndarray:
    lo, hi = cand.bounds()
    nf = len(cand.friction)
    scale = [{"mu_sk": 0.05, "mu_k": 0.05, "log_v_s": 1.0, "mu_v_s_per_mm": 0.01}[nm] for nm in cand.friction]
    return np.asarray(scale + list((hi - lo)[nf:] / 20.0), float)


def _start_points(ds: Prepared, cand: Candidate, rows: np.ndarray | None, config: DiagnosisConfig,
                  rng: np.random.Generator) -> list[np.ndarray]:
    """Starting non-linear vectors: the nominal friction law (+ random ones for the control); an
    effect's non-linear parameters start at its best grid point."""
    lo, hi = cand.bounds()
    nominal = config.friction
    if cand.friction:
        first = {"mu_sk": max(nominal.mu_s - nominal.mu_k, 0.0), "mu_k": nominal.mu_k,
                 "log_v_s": math.log(nominal.v_s_mm_s), "mu_v_s_per_mm": nominal.mu_v_s_per_mm}
        out = [np.array([first[nm] for nm in cand.friction])]
        for _ in range(max(0, config.starts - 1)):
            draw = {"mu_sk": rng.uniform(0.0, 0.3), "mu_k": rng.uniform(0.05, 0.5),
                    "log_v_s": rng.uniform(math.log(0.1), math.log(10.0)), "mu_v_s_per_mm": rng.uniform(0.0, 0.02)}
            out.append(np.array([draw[nm] for nm in cand.friction]))
        return [np.clip(x, lo, hi) for x in out]
    kern = cand.kernel
    assert kern is not None  # no friction constants and fit_candidate has bounds: an effect
    grid = kern.grid or (tuple(0.5 * (a + b) for a, b in (kern.bounds[nm] for nm in kern.nonlinear)),)
    costs = [float(np.sum(_residual(np.clip(np.asarray(g, float), lo, hi), ds, cand, rows, config) ** 2)) for g in grid]
    order = np.argsort(costs)
    return [np.clip(np.asarray(grid[i], float), lo, hi) for i in order[: max(1, config.starts)]]


def _residual(x: np.ndarray, ds: Prepared, cand: Candidate, rows: np.ndarray | None,
              config: DiagnosisConfig) -> np.ndarray:
    """Variable-projection residual (model - measured, g) on ``rows`` (None: all)."""
    return _solve(build_design(ds, cand, x, config.friction), ds, rows, config.trial_gain, config.gain_bounds,
                  level_sd=config.level_sd)[2]


def fit_candidate(
    ds: Prepared,
    cand: Candidate,
    train: np.ndarray | None = None,
    *,
    config: DiagnosisConfig = DiagnosisConfig(),
    start: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> CandidateFit:
    """Fit one candidate to the training rows by variable projection.

    Parameters
    ----------
    ds : Prepared
        The data.
    cand : Candidate
        What to fit.
    train : ndarray of bool, optional
        Training rows (default: all).
    config : DiagnosisConfig
        Nominal friction law, trial gains, number of starts.
    start : ndarray, optional
        Non-linear start (e.g. the fit to all speeds); then only that start is used.
    rng : numpy.random.Generator, optional
        Source of the control's random starts (default: seeded 0).

    Returns
    -------
    CandidateFit
    """
    rows = None if train is None or np.all(train) else np.flatnonzero(train)
    lo, hi = cand.bounds()
    nfev = 0
    if len(lo) == 0:
        x = np.zeros(0)
    else:
        rng = rng if rng is not None else np.random.default_rng(0)
        x0s = [np.clip(start, lo, hi)] if start is not None else _start_points(ds, cand, rows, config, rng)
        best = None
        for x0 in x0s:
            res = least_squares(_residual, x0, args=(ds, cand, rows, config), bounds=(lo, hi), method="trf",
                                x_scale=_x_scale(cand), diff_step=1e-4, ftol=1e-6, xtol=1e-6,
                                max_nfev=40 * (len(x0) + 1))
            nfev += int(res.nfev)
            if best is None or res.cost < best.cost:
                best = res
        assert best is not None  # x0s is never empty
        x = np.asarray(best.x, float)
    coef, gain, r = _solve(build_design(ds, cand, x, config.friction), ds, rows, config.trial_gain, config.gain_bounds,
                           level_sd=config.level_sd)
    return CandidateFit(cand, x, coef, gain, float(r @ r), len(r), nfev, config.friction)


def predict(ds: Prepared, fit: CandidateFit, *, trials: np.ndarray | None = None,
            config: DiagnosisConfig = DiagnosisConfig(), gains: bool | str = True) -> np.ndarray:
    """Model force (g) of a fitted candidate on every row of ``ds``.

    Trials the fit has a gain for use it; the gains of the others (e.g. a held-out speed) are
    estimated from their own rows (``config.trial_gain``; else 1): their relative sizes freely, their
    mean per speed within ``±2 sd / sqrt(n)`` of 1, where ``sd`` is the scatter of the fit's trial
    gains (a speed's mean placement scale is as random as that; any larger level change is left for
    the model to predict). The fit itself bounds its gains the same way.

    Parameters
    ----------
    ds : Prepared
    fit : CandidateFit
    trials : ndarray of bool, optional
        Trials whose gains are re-estimated (default: those without a gain in ``fit``).
    config : DiagnosisConfig
    gains : bool or "free"
        Apply the trial gains; False gives the model every trial of a speed shares (gain 1), whose
        residuals keep the scatter between repeats (for tests against it); ``"free"`` fits every
        trial's gain to its own rows without the mean-1 constraint (residuals then show only
        errors of shape).
    """
    design = build_design(ds, fit.candidate, fit.x, fit.nominal)
    kg = design.gained.shape[1]
    p = design.gained @ fit.coef[:kg]
    add = design.fixed @ fit.coef[kg:] + (design.offset if design.offset is not None else 0.0)
    if gains is False:
        return p + add
    if gains == "free":
        every = np.ones(ds.n_trials, dtype=bool)
        g = _trial_gains(p, ds.y - add, ds.trial, ds, config.gain_bounds, every, normalise=False)
        return p * g[ds.trial] + add
    g = np.where(np.isfinite(fit.gain), fit.gain, 1.0)
    redo = ~np.isfinite(fit.gain) if trials is None else np.asarray(trials, bool)
    if config.trial_gain and redo.any():
        rows = redo[ds.trial]
        # relative gains from the trials' own rows; the speed's level within the random range of
        # the fit's placement scatter
        new = _trial_gains(p[rows], (ds.y - add)[rows], ds.trial[rows], ds, config.gain_bounds, redo,
                           scatter=_gain_scatter(fit.gain, ds), level_sd=config.level_sd)
        g = np.where(redo, new, g)
    return p * g[ds.trial] + add


def _gain_scatter(gain: np.ndarray, ds: Prepared) -> float:
    """Pooled within-speed standard deviation (dimensionless) of fitted trial gains (0 if unknown)."""
    ok = np.isfinite(gain)
    if ok.sum() < 3:
        return 0.0
    g = gain[ok]
    k = ds.trial_speed_idx[ok]
    m = len(ds.speeds)
    count = np.bincount(k, minlength=m)
    mean = np.bincount(k, weights=g, minlength=m) / np.maximum(count, 1)
    dev = g - mean[k]
    dof = max(int(ok.sum()) - int(np.count_nonzero(count)), 1)
    return float(math.sqrt(np.sum(dev**2) / dof))


def heldout_predictions(
    ds: Prepared, cand: Candidate, full: CandidateFit, config: DiagnosisConfig = DiagnosisConfig()
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[CandidateFit]]:
    """Leave-one-speed-out predictions (g) for every row, and the fold fits.

    Parameters
    ----------
    ds : Prepared
    cand : Candidate
    full : CandidateFit
        The candidate's fit to all speeds (the start of every fold).
    config : DiagnosisConfig

    Returns
    -------
    pred : ndarray
        For each row, the prediction (g) of the fit that did not see its speed (the held-out trials'
        gains estimated from their own rows, mean 1).
    pred_shared : ndarray
        The same with gain 1 for every held-out trial (the speed's common prediction, g).
    pred_free : ndarray
        The same with each held-out trial's gain fitted freely to its rows (g).
    folds : list of CandidateFit
        One per speed, in ``ds.speeds`` order.
    """
    pred, shared, free = np.empty(ds.n), np.empty(ds.n), np.empty(ds.n)
    folds = []
    for k in range(len(ds.speeds)):
        held = ds.speed_idx == k
        fit = fit_candidate(ds, cand, ~held, config=config, start=full.x if len(full.x) else None)
        pred[held] = predict(ds, fit, config=config)[held]
        shared[held] = predict(ds, fit, config=config, gains=False)[held]
        free[held] = predict(ds, fit, config=config, gains="free")[held]
        folds.append(fit)
    return pred, shared, free, folds


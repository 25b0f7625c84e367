"""Sim-to-real gap diagnosis (docs/diagnosis.md; ``diagnosis.json`` in docs/file-formats.md).

``tympani diagnose SYNCED --out DIR`` calls :func:`tympani.pipeline.force.sync.read_synced`,
:func:`diagnose` and :func:`tympani.pipeline.diagnosis.report.write_diagnosis`. The steps are modules of
:mod:`tympani.pipeline.diagnosis`: :mod:`~tympani.pipeline.diagnosis.prepare` (the data),
:mod:`~tympani.pipeline.diagnosis.kernels` and :mod:`~tympani.pipeline.diagnosis.candidates` (the models and their
fits), :mod:`~tympani.pipeline.diagnosis.evidence` (lack of fit, where, bootstrap) and
:mod:`~tympani.pipeline.diagnosis.decision` (the verdict); this module runs them and writes the result.

Questions and how they are answered
-----------------------------------
*Is there a gap?*  The base model's held-out residuals (each speed predicted from the others) are
averaged per trial in cells of insertion phase (before the start, ``phase_bins`` bins of the
insertion, the dwell); each (speed, phase) cell's mean is t-tested against the scatter *between
repeats* (trials are the independent unit, so autocorrelation within a curve does not inflate the
evidence), Holm-corrected over cells. Two families, Bonferroni-combined: *level* (the speed's common
prediction, gain 1, so the trials' placement scales stay in the repeat scatter; standard errors
inflated by sqrt(S/(S-1)) because a held-out level is calibrated on the other speeds' equally random
placements) and *shape* (every trial's gain fitted freely). The control's test is reported too.

*Where?*  The base's held-out residuals, binned over speed × theta_con and speed × phase (before,
early, middle, late, dwell), with a t-test over trials and a Benjamini–Hochberg q-value per cell
and a split of the speed × theta_con cell means into speed, angle and interaction shares; the
summary in words names the speeds, theta_con range and phases of the significant cells.

*Which?*  Every candidate is fitted on all speeds but one and predicts the one held out
(leave-one-speed-out; the fold holding out the fastest speed is the extrapolation test).
Held-out mean squared errors are compared with a bootstrap over trials stratified by speed
(:func:`tympani.pipeline.diagnosis.decision.decide`). AICc and BIC of the fits to all speeds are secondary. Each effect's parameters
get standard errors (cluster sandwich over trials, :func:`tympani.pipeline.model.stats.least_squares_covariances`,
conditional on the trial gains), their largest correlation and their spread over the folds.

*How much?*  Held-out RMSE of base and base + the leading effect, pooled and per speed, with
bootstrap intervals; the *systematic* gap (cell means over repeats, noise-corrected) before and

Criteria
--------
Gaussian likelihood with ``sigma^2 = RSS / n`` over the ``n`` subsampled rows: ``AIC = 2k - 2 lnL``,
``AICc = AIC + 2k(k+1)/(n-k-1)``, ``BIC = k ln n - 2 lnL``, ``k`` = fitted parameters (including
the free trial gains) + 1. Rows within a curve are autocorrelated, so these overstate the
evidence; the verdict uses held-out errors only.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np
import pandas as pd

from tympani.pipeline.diagnosis.candidates import CandidateFit, candidates, fit_candidate, heldout_predictions, predict
from tympani.pipeline.diagnosis.config import DiagnosisConfig
from tympani.pipeline.diagnosis.decision import Decision, VariantChoice, decide
from tympani.pipeline.diagnosis.evidence import (
    GapLocation,
    LackOfFit,
    TwoPartLackOfFit,
    bootstrap_mse,
    bootstrap_weights,
    lack_of_fit,
    peak_drop,
    systematic_gap,
    trial_sse,
    two_part_lack_of_fit,
    where_is_the_gap,
)
from tympani.pipeline.diagnosis.experiments import Experiment, splitting_experiments
from tympani.pipeline.diagnosis.identifiability import ParameterIdentifiability, identifiability
from tympani.pipeline.diagnosis.prepare import Prepared, prepare
from tympani.pipeline.io import to_jsonable
from tympani.pipeline.model.stats import gaussian_criteria
from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom

__all__ = [
    "CandidateScore", "SpeedGap", "GapSize", "SpeedPeakDrop", "PeakDropSummary",
    "LackOfFitTests", "Diagnosis", "diagnose", "diagnosis_to_json",
]

#: How the peak-force drops of :class:`PeakDropSummary` are defined.
PEAK_DROP_DEFINITION = (
    "drop = 1 - mean peak(v) / mean peak(slowest); a trial's peak is the maximum of a 3-row "
    "running mean; models: fits with each speed's placement level pinned, gain 1; explained = (drop with "
    "effect - drop of base) / (measured - base), not given when measured and base drops differ "
    "by less than 2 points")


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class CandidateScore:
    """How well one candidate predicts and fits (a row of :attr:`Diagnosis.ranking`).

    Attributes
    ----------
    candidate : str
        ``base``, ``control`` or an effect.
    effect : str or None
        The effect added to the base (None for base and control).
    heldout_rmse_g : float
        Held-out RMSE (g) over every speed (leave-one-speed-out).
    heldout_rmse_lo_g, heldout_rmse_hi_g : float
        Its 95 % bootstrap interval (g).
    extrap_rmse_g : float
        Held-out RMSE (g) of the fold holding out the fastest speed.
    fit_rmse_g : float
        RMSE (g) of the fit to all speeds.
    k : int
        Fitted parameters (non-linear, linear, free trial gains).
    aic, aicc, bic : float
        Information criteria of the fit to all speeds (``k + 1`` parameters with sigma).
    delta_bic, delta_aicc : float
        BIC and AICc above the smallest over the candidates.
    """

    candidate: str
    effect: str | None
    heldout_rmse_g: float
    heldout_rmse_lo_g: float
    heldout_rmse_hi_g: float
    extrap_rmse_g: float
    fit_rmse_g: float
    k: int
    aic: float
    aicc: float
    bic: float
    delta_bic: float
    delta_aicc: float


@dataclass(frozen=True)
class SpeedGap:
    """The gap at one held-out speed (:class:`GapSize`).

    Attributes
    ----------
    speed_mm_s : float
        Nominal speed (mm/s).
    n_trials : int
        Trials at the speed.
    rmse_base_g, rmse_control_g, rmse_with_effect_g : float
        Held-out RMSE (g) of base, control and base + the effect.
    shrink_pct : float
        ``100 (1 - rmse_with_effect / rmse_base)``.
    shrink_ci95_pct : tuple of float
        Its 95 % bootstrap interval (%).
    bias_base_g, bias_with_effect_g : float
        Mean held-out residual (g; measured - model) of base and base + the effect.
    """

    speed_mm_s: float
    n_trials: int
    rmse_base_g: float
    rmse_control_g: float
    rmse_with_effect_g: float
    shrink_pct: float
    shrink_ci95_pct: tuple[float, float]
    bias_base_g: float
    bias_with_effect_g: float


@dataclass(frozen=True)
class GapSize:
    """How large the gap is on held-out speeds, before (base) and after (base + the effect).

    Attributes
    ----------
    effect : str
        The identified effect, else the leader.
    rmse_base_g, rmse_with_effect_g : float
        Held-out RMSE (g) over every speed.
    shrink_pct : float
        ``100 (1 - rmse_with_effect / rmse_base)``.
    shrink_ci95_pct, rmse_base_ci95_g, rmse_with_effect_ci95_g : tuple of float
        95 % bootstrap intervals (%, g, g).
    rmse_control_g : float
        Held-out RMSE (g) of the control.
    systematic_base_g, systematic_with_effect_g : float
        Systematic misfit (g; :func:`tympani.pipeline.diagnosis.evidence.systematic_gap`) of the gain-1 held-out
        residuals.
    systematic_shrink_pct : float
        ``100 (1 - systematic_with_effect / systematic_base)``.
    by_speed : tuple of SpeedGap
        The same per speed, increasing.
    """

    effect: str
    rmse_base_g: float
    rmse_with_effect_g: float
    shrink_pct: float
    shrink_ci95_pct: tuple[float, float]
    rmse_base_ci95_g: tuple[float, float]
    rmse_with_effect_ci95_g: tuple[float, float]
    rmse_control_g: float
    systematic_base_g: float
    systematic_with_effect_g: float
    systematic_shrink_pct: float
    by_speed: tuple[SpeedGap, ...]


@dataclass(frozen=True)
class SpeedPeakDrop:
    """Peak-force drops (% of the slowest speed's peak; positive when lower) at one speed.

    Attributes
    ----------
    speed_mm_s : float
    measured_pct, base_pct, with_effect_pct, with_effect_heldout_pct : float
        Measured, base model, base + the effect, and base + the effect held out.
    explained_frac, explained_heldout_frac : float
        Share of the drop the base model misses that the effect explains (NaN when the measured
        and the base drops differ by less than 2 points).
    """

    speed_mm_s: float
    measured_pct: float
    base_pct: float
    with_effect_pct: float
    with_effect_heldout_pct: float
    explained_frac: float
    explained_heldout_frac: float


@dataclass(frozen=True)
class PeakDropSummary:
    """Measured and modelled paper-style peak-force drops.

    Attributes
    ----------
    effect : str
        The effect modelled (the identified one, else the leader).
    reference_speed_mm_s : float
        The slowest speed (mm/s).
    by_speed : tuple of SpeedPeakDrop
        Every faster speed, increasing.
    explained_frac_fastest, explained_heldout_frac_fastest : float
        The fastest speed's shares explained (NaN without one).
    definition : str
        The definitions, in words.
    """

    effect: str
    reference_speed_mm_s: float
    by_speed: tuple[SpeedPeakDrop, ...]
    explained_frac_fastest: float
    explained_heldout_frac_fastest: float
    definition: str = PEAK_DROP_DEFINITION


@dataclass(frozen=True)
class LackOfFitTests:
    """Lack-of-fit tests of base and control: of their held-out predictions (``base`` is the
    verdict's gate) and of their fits to all speeds (``*_in_sample``)."""

    base: TwoPartLackOfFit
    control: TwoPartLackOfFit
    base_in_sample: LackOfFit
    control_in_sample: LackOfFit


@dataclass(frozen=True)
class Diagnosis:
    """Everything :func:`diagnose` found (:func:`diagnosis_to_json` writes the file).

    Attributes
    ----------
    decision : Decision
        :func:`tympani.pipeline.diagnosis.decision.decide`'s output, with the variants chosen; its
        ``verdict`` and ``effect`` are the diagnosis's (:attr:`verdict`, :attr:`effect`).
    ranking : tuple of CandidateScore
        One per candidate, best held-out RMSE first.
    fits : dict
        Candidate name -> CandidateFit (all speeds).
    folds : dict
        Candidate name -> fold fits (one per speed).
    heldout : dict
        Candidate name -> held-out predictions (g) per row.
    fitted : dict
        Candidate name -> in-sample predictions (g) per row.
    data : Prepared
    lof : LackOfFitTests
        Lack of fit of the held-out predictions of ``base`` (the verdict's gate) and ``control``,
        and of their fits to all speeds.
    where : GapLocation
        :func:`tympani.pipeline.diagnosis.evidence.where_is_the_gap` of the base's held-out residuals.
    gap : GapSize
        RMSEs before and after, per speed, systematic gap, bootstrap intervals.
    identifiability : dict
        Effect -> parameter -> :class:`tympani.pipeline.diagnosis.identifiability.ParameterIdentifiability`.
    peak_drop : PeakDropSummary
        Measured and modelled peak-force drops and the share explained.
    experiments : tuple of Experiment
        Experiments that would split the tied (or the two leading) effects, with predictions.
    timing_s : float
        Wall time (s).
    config : DiagnosisConfig
    """

    decision: Decision
    ranking: tuple[CandidateScore, ...]
    fits: dict
    folds: dict
    heldout: dict
    fitted: dict
    data: Prepared
    lof: LackOfFitTests
    where: GapLocation
    gap: GapSize
    identifiability: dict[str, dict[str, ParameterIdentifiability]]
    peak_drop: PeakDropSummary
    experiments: tuple[Experiment, ...]
    timing_s: float
    config: DiagnosisConfig = field(default_factory=DiagnosisConfig)

    @property
    def verdict(self) -> str:
        """``identified``, ``ambiguous`` or ``no_gap``."""
        return self.decision.verdict

    @property
    def effect(self) -> str | None:
        """The identified effect (None unless ``identified``)."""
        return self.decision.effect


# --------------------------------------------------------------------------- the diagnosis


def _n_params(ds: Prepared, fit: CandidateFit, config: DiagnosisConfig) -> int:
    """Fitted parameters: non-linear + linear + free trial gains (trials minus speeds)."""
    k = len(fit.x) + fit.candidate.n_linear()
    if config.trial_gain:
        present = np.isfinite(fit.gain)
        k += int(present.sum()) - len(np.unique(ds.trial_speed_idx[present]))
    return k


def diagnose(
    table: pd.DataFrame,
    config: DiagnosisConfig = DiagnosisConfig(),
    *,
    source: str | os.PathLike = "<synced table>",
    phantom: Phantom = DEFAULT_PHANTOM,
) -> Diagnosis:
    """Diagnose the sim-to-real gap of a synced table (see the module docstring).

    Parameters
    ----------
    table : pandas.DataFrame
        Synced table (docs/file-formats.md; units in the column names, angles in rad).
    config : DiagnosisConfig
        Thresholds, subsampling, bootstrap size, seed.
    source : str or PathLike
        Named in input errors.
    phantom : Phantom
        Geometry (mm, rad).

    Returns
    -------
    Diagnosis

    Raises
    ------
    vision.errors.InputError
        Bad or insufficient data (one line saying what the diagnosis needs).
    """
    t0 = time.perf_counter()
    ds = prepare(table, config, source=source, phantom=phantom)
    rng = np.random.default_rng(config.seed)
    cands = candidates(config.effects)
    fits, folds, held, held_shared, held_free, fitted, fitted_shared = {}, {}, {}, {}, {}, {}, {}
    for cand in cands:
        fit = fit_candidate(ds, cand, config=config, rng=rng)
        fits[cand.name] = fit
        fitted[cand.name] = predict(ds, fit, config=config)
        fitted_shared[cand.name] = predict(ds, fit, config=config, gains=False)
        held[cand.name], held_shared[cand.name], held_free[cand.name], folds[cand.name] = heldout_predictions(
            ds, cand, fit, config)
    names = [c.name for c in cands]
    sse = np.column_stack([trial_sse(ds, ds.y - held[nm])[0] for nm in names])
    n_tr = trial_sse(ds, ds.y)[1]
    weights = bootstrap_weights(ds, config.bootstrap, rng)
    draws_all = bootstrap_mse(sse, n_tr, weights)
    draws = {nm: draws_all[:, i] for i, nm in enumerate(names)}
    mse = {nm: float(sse[:, i].sum() / n_tr.sum()) for i, nm in enumerate(names)}
    # a richer variant of an effect replaces its plain kernel only when it predicts the held-out
    # speeds significantly better: its extra parameters must be ones the data separate
    variants = {}
    for cand in [c for c in cands if c.variant]:
        plain = str(cand.effect)
        used = bool(np.quantile(draws[plain] - draws[cand.name], config.alpha) > 0)
        variants[plain] = VariantChoice(variant=cand.variant, used=used, heldout_rmse_plain_g=math.sqrt(mse[plain]),
                                        heldout_rmse_variant_g=math.sqrt(mse[cand.name]))
        for table_ in (fits, folds, held, held_shared, held_free, fitted, fitted_shared, mse, draws):
            if used:
                table_[plain] = table_[cand.name]
            del table_[cand.name]
        if used:
            fits[plain] = replace(fits[plain], candidate=replace(cand, name=plain))
    cands = [fits[c.name].candidate for c in cands if not c.variant]
    keep = [names.index(f"{c.name}:{variants[c.name].variant}" if c.name in variants and variants[c.name].used
                        else c.name) for c in cands]
    names = [c.name for c in cands]
    effects = [c.name for c in cands if c.effect is not None]
    sse = sse[:, keep]

    # Tests against the scatter between repeats use held-out predictions (a flexible friction law
    # cannot hide in-sample a gap it cannot predict), twice: with each speed's common prediction
    # (gain 1: the trials' pressure scales stay in the repeat scatter) for errors of level, and with
    # every trial's gain free for errors of shape; Bonferroni over the two.
    held_out = {nm: two_part_lack_of_fit(ds, ds.y - held_shared[nm], ds.y - held_free[nm], config)
                for nm in ("base", "control")}
    in_sample = {nm: lack_of_fit(ds, ds.y - fitted_shared[nm], bins=config.phase_bins, alpha=config.lof_alpha)
                 for nm in ("base", "control")}
    lof = LackOfFitTests(base=held_out["base"], control=held_out["control"], base_in_sample=in_sample["base"],
                         control_in_sample=in_sample["control"])
    # a gap needs the paper's model as simulated (base) to miss the repeat scatter on held-out speeds;
    # the control nearly always misses it out of sample (its free friction law extrapolates badly),
    # so it takes part through the gain test instead
    systematic = {nm: systematic_gap(ds, ds.y - held_shared[nm], config.phase_bins) for nm in names}
    decision = decide(mse, draws, effects, lof.base.significant, config, systematic,
                      lof_p=(lof.base.p_value, lof.control.p_value))
    decision = replace(decision, variants=variants)
    leader = decision.effect or decision.leader

    fastest = ds.trial_speed == ds.speeds[-1]
    extrap = bootstrap_mse(sse, n_tr, np.ones((1, ds.n_trials)), fastest)[0]
    rows = []
    for i, cand in enumerate(cands):
        fit = fits[cand.name]
        k = _n_params(ds, fit, config)
        _, aic, aicc, bic = gaussian_criteria(fit.rss, fit.n, k + 1)  # k model parameters and sigma
        lo, hi = np.quantile(np.sqrt(draws[cand.name]), [0.025, 0.975])
        rows.append(dict(candidate=cand.name, effect=cand.effect, heldout_rmse_g=math.sqrt(mse[cand.name]),
                         heldout_rmse_lo_g=float(lo), heldout_rmse_hi_g=float(hi),
                         extrap_rmse_g=float(math.sqrt(extrap[i])), fit_rmse_g=math.sqrt(fit.rss / fit.n),
                         k=k, aic=aic, aicc=aicc, bic=bic))
    best_bic = float(np.nanmin([r["bic"] for r in rows]))
    best_aicc = float(np.nanmin([r["aicc"] for r in rows]))
    scores = [CandidateScore(**r, delta_bic=r["bic"] - best_bic, delta_aicc=r["aicc"] - best_aicc) for r in rows]
    ranking = tuple(sorted(scores, key=lambda s: (math.isnan(s.heldout_rmse_g), s.heldout_rmse_g)))

    gap = _gap(ds, held, held_shared, draws, mse, weights, sse, n_tr, names, leader, config)
    where = where_is_the_gap(ds, ds.y - held_shared["base"], held_shared["base"], theta_bins=config.theta_bins)
    ident = {e: identifiability(ds, fits[e], folds[e]) for e in effects}
    pinned = replace(config, level_sd=0.0)  # each speed's level pinned: the models' own drop
    pinned_fits = {nm: fit_candidate(ds, next(c for c in cands if c.name == nm), config=pinned,
                                     start=fits[nm].x if len(fits[nm].x) else None)
                   for nm in dict.fromkeys(("base", leader))}
    drops = _peak_drop_summary(ds, {nm: predict(ds, f, config=pinned, gains=False) for nm, f in pinned_fits.items()},
                               held_shared, leader)
    if decision.verdict == "ambiguous":
        focus = list(decision.tied)
    else:
        focus = [leader] + [s.candidate for s in ranking if s.candidate in effects and s.candidate != leader][:1]
    experiments = splitting_experiments(ds, fits, focus, fitted) if decision.verdict != "no_gap" else ()
    return Diagnosis(
        decision=decision, ranking=ranking, fits=fits,
        folds=folds, heldout=held, fitted=fitted, data=ds, lof=lof, where=where, gap=gap, identifiability=ident,
        peak_drop=drops, experiments=experiments, timing_s=time.perf_counter() - t0, config=config,
    )


def _gap(ds, held, held_shared, draws, mse, weights, sse, n_tr, names, leader, config) -> GapSize:
    """RMSE before (base) and after (base + leader) on held-out speeds, pooled and per speed."""
    i_b, i_e, i_c = names.index("base"), names.index(leader), names.index("control")
    rb, re_ = math.sqrt(mse["base"]), math.sqrt(mse[leader])
    shrink_d = 100 * (1 - np.sqrt(draws[leader] / np.maximum(draws["base"], 1e-300)))
    by_speed = []
    for k, s in enumerate(ds.speeds):
        sel = ds.trial_speed == s
        d = bootstrap_mse(sse, n_tr, weights, sel)
        point = sse[sel].sum(axis=0) / n_tr[sel].sum()
        rows_k = ds.speed_idx == k
        by_speed.append(SpeedGap(
            speed_mm_s=float(s), n_trials=int(sel.sum()), rmse_base_g=float(math.sqrt(point[i_b])),
            rmse_control_g=float(math.sqrt(point[i_c])), rmse_with_effect_g=float(math.sqrt(point[i_e])),
            shrink_pct=float(100 * (1 - math.sqrt(point[i_e] / point[i_b]))) if point[i_b] > 0 else float("nan"),
            shrink_ci95_pct=_interval(100 * (1 - np.sqrt(d[:, i_e] / np.maximum(d[:, i_b], 1e-300)))),
            bias_base_g=float(np.mean((ds.y - held["base"])[rows_k])),
            bias_with_effect_g=float(np.mean((ds.y - held[leader])[rows_k])),
        ))
    sys_b = systematic_gap(ds, ds.y - held_shared["base"], config.phase_bins)
    sys_e = systematic_gap(ds, ds.y - held_shared[leader], config.phase_bins)
    return GapSize(
        effect=leader, rmse_base_g=rb, rmse_with_effect_g=re_, shrink_pct=100 * (1 - re_ / rb) if rb > 0 else float("nan"),
        shrink_ci95_pct=_interval(shrink_d), rmse_base_ci95_g=_interval(np.sqrt(draws["base"])),
        rmse_with_effect_ci95_g=_interval(np.sqrt(draws[leader])), rmse_control_g=math.sqrt(mse["control"]),
        systematic_base_g=sys_b, systematic_with_effect_g=sys_e,
        systematic_shrink_pct=100 * (1 - sys_e / sys_b) if sys_b > 0 else float("nan"),
        by_speed=tuple(by_speed),
    )


def _interval(draws: np.ndarray) -> tuple[float, float]:
    """The central 95 % interval of bootstrap draws (their unit)."""
    lo, hi = np.quantile(draws, [0.025, 0.975])
    return float(lo), float(hi)


def _peak_drop_summary(ds: Prepared, fitted: dict, held: dict, leader: str) -> PeakDropSummary:
    """Measured and modelled peak-force drops. The models are fits with each speed's placement level
    pinned at 1 (``level_sd = 0``), predicted with gain 1: the drop is the model's own, not a speed's
    random placement level; the held-out column uses the diagnosis' held-out predictions (gain 1)."""
    data = peak_drop(ds, ds.y)
    base = peak_drop(ds, fitted["base"])
    eff = peak_drop(ds, fitted[leader])
    eff_h = peak_drop(ds, held[leader])
    rows = []
    for v in ds.speeds[1:]:
        v = float(v)
        need = data[v] - base[v]
        meaningful = abs(need) > 0.02  # a share of less than 2 points of drop is a ratio of noise
        rows.append(SpeedPeakDrop(
            speed_mm_s=v, measured_pct=100 * data[v], base_pct=100 * base[v], with_effect_pct=100 * eff[v],
            with_effect_heldout_pct=100 * eff_h[v],
            explained_frac=float((eff[v] - base[v]) / need) if meaningful else float("nan"),
            explained_heldout_frac=float((eff_h[v] - base[v]) / need) if meaningful else float("nan")))
    return PeakDropSummary(
        effect=leader, reference_speed_mm_s=float(ds.speeds[0]), by_speed=tuple(rows),
        explained_frac_fastest=rows[-1].explained_frac if rows else float("nan"),
        explained_heldout_frac_fastest=rows[-1].explained_heldout_frac if rows else float("nan"))


# --------------------------------------------------------------------------- JSON


def diagnosis_to_json(diag: Diagnosis, source: str | os.PathLike | None = None) -> dict:
    """The ``diagnosis.json`` content (docs/file-formats.md), JSON-safe: the main keys first, then
    the details.

    Parameters
    ----------
    diag : Diagnosis
    source : str or PathLike, optional
        The synced table diagnosed (recorded under ``data``).

    Returns
    -------
    dict
        ``verdict``, ``effect``, ``ranking`` (list of {effect, delta_bic, heldout_rmse_g, params, ...}),
        ``gap`` ({rmse_base_g, rmse_with_effect_g, shrink_pct, by_speed, where, ...}), ``by_speed`` and
        ``where`` (the same, also at the top level), ``heldout``
        (scheme, folds, extrapolation, bootstrap), then ``reason``, ``tied``, ``leader``,
        ``explains``, ``control``, ``lack_of_fit``, ``forms`` (each candidate's functional form),
        ``identifiability``, ``peak_drop``,
        ``experiments``, ``criteria``, ``data``, ``config``, ``timing_s``.
    """
    ds = diag.data
    dec = diag.decision
    ranking = []
    for row in diag.ranking:
        name = row.candidate
        ranking.append(dict(
            effect=name, candidate=name,  # the candidate's name in both, base and control included
            delta_bic=row.delta_bic, heldout_rmse_g=row.heldout_rmse_g, params=diag.fits[name].params(ds.theta_hi),
            heldout_rmse_ci95_g=[row.heldout_rmse_lo_g, row.heldout_rmse_hi_g],
            extrapolation_rmse_g=row.extrap_rmse_g, fit_rmse_g=row.fit_rmse_g, delta_aicc=row.delta_aicc,
            aicc=row.aicc, bic=row.bic, k=int(row.k),
            gain_vs_control=dec.gain.get(name), gain_vs_control_lo=dec.gain_lo.get(name),
        ))
    gap = {f.name: getattr(diag.gap, f.name) for f in fields(diag.gap)}
    gap["where"] = diag.where
    folds = [dict(held_out_speed_mm_s=float(s), n_trials=int(np.sum(ds.trial_speed == s)),
                  n_rows=int(np.sum(ds.speed_idx == k)), trained_on_mm_s=[float(v) for v in ds.speeds if v != s])
             for k, s in enumerate(ds.speeds)]
    cfg = asdict(diag.config)
    cfg["friction"] = {k: v for k, v in cfg["friction"].items() if not k.startswith("p_")}
    out = {
        "verdict": diag.verdict,
        "effect": diag.effect,
        "ranking": ranking,
        "gap": gap,
        # by_speed and where also at the top level, beside gap's RMSEs: a reader finds them either way
        "by_speed": diag.gap.by_speed,
        "where": diag.where,
        "heldout": dict(
            scheme="leave-one-speed-out: each speed's trials are predicted by fits to the other speeds (their trial "
                   "gains, mean 1, from their own rows); the fold holding out the fastest speed is the extrapolation",
            folds=folds,
            extrapolation=dict(speed_mm_s=float(ds.speeds[-1]),
                               rmse_g={r.candidate: r.extrap_rmse_g for r in diag.ranking}),
            bootstrap=dict(draws=diag.config.bootstrap, unit="trial", stratified_by="speed_mm_s", seed=diag.config.seed),
        ),
        "reason": dec.reason,
        "tied": dec.tied,
        "leader": dec.leader,
        "explains": dec.explains,
        "control": dict(description="the model with its Stribeck law re-identified (mu_s, mu_k, v_s); "
                                    "an effect must beat it on held-out speeds",
                        heldout_rmse_g=diag.gap.rmse_control_g, params=diag.fits["control"].params(ds.theta_hi)),
        "lack_of_fit": diag.lof,
        "forms": {"base": "the paper's friction model (Eqs. 2-7) with the nominal friction law; pressures linear in theta_con (Eq. 6); "
                          "a per-trial gain on the contact force, mean per speed within ±2 sd/sqrt(n) of 1",
                  "control": "base with mu_s, mu_k, v_s re-identified",
                  **{e: diag.fits[e].candidate.kernel.form for e in diag.identifiability}},  # type: ignore[union-attr]
        "variants": dec.variants,
        "systematic_misfit_g": dec.systematic_g,
        "identifiability": diag.identifiability,
        "peak_drop": diag.peak_drop,
        "experiments": diag.experiments,
        "criteria": {"loglik": "-n/2 (ln(2 pi sigma^2) + 1), sigma^2 = RSS/n over the subsampled rows",
                     "aicc": "2k - 2 lnL + 2k(k+1)/(n-k-1)", "bic": "k ln(n) - 2 lnL",
                     "k": "fitted parameters (incl. free trial gains) + 1 (sigma)",
                     "note": "rows within a curve are autocorrelated, so AICc/BIC overstate the evidence; the verdict "
                             "uses held-out errors"},
        "data": dict(source=None if source is None else os.fspath(source), speeds_mm_s=[float(s) for s in ds.speeds],
                     trials=int(ds.n_trials), rows_used=int(ds.n), rows_usable=int(ds.n_rows_in),
                     standing_rows_used=int(np.sum(ds.v_inst == 0)), notes=list(ds.notes)),
        "config": cfg,
        "timing_s": diag.timing_s,
    }
    return to_jsonable(out)

"""Blind evaluation of the gap diagnosis on generated data (``tympani evaluate-diagnosis``).

Each case draws a hidden effect (or none), its strength and a noise level, generates an
experiment with :func:`tympani.pipeline.synthetic.family_a.synthetic_dataset` (hidden forms unlike the library's,
see that module), runs :func:`tympani.pipeline.diagnosis.analysis.diagnose` on the synced table alone and scores
the verdict against the truth. Cases are balanced over the effects (case ``i`` gets effect
``i mod (1 + number of effects)``, ``None`` first); everything else is drawn from
``numpy.random.SeedSequence(seed)`` spawned per case, so a case is reproducible on its own and the
result does not depend on the number of workers.

Scores
------
- *correct*: ``identified`` with the hidden effect, or ``no_gap`` when there is none.
- *confident-wrong*: ``identified`` with another effect (or any effect when there is none).
- *false identified on effect-free data*: the share of effect-free cases with ``identified``.
- *held-out shrinkage* when the right effect is identified: ``shrink_pct`` of diagnosis.json
  (held-out RMSE against the measured force, base -> effect; includes the noise floor) and
  ``true_shrink_pct``, the same against the noiseless force of the generator (the gap itself).
- *detectable*: the generator's noiseless gap RMS exceeds twice its noise RMS
  (``truth.detectable``); *residually detectable*: the part of the gap the paper's model cannot absorb
  (:func:`residual_gap`) exceeds twice the noise RMS.

A row-number column (``row_id``, not truth) is added to the table so that the held-out
predictions can be compared with the generator's noiseless force afterwards.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping

import numpy as np
import pandas as pd

from tympani.pipeline.diagnosis.analysis import diagnose
from tympani.pipeline.diagnosis.candidates import candidates, fit_candidate
from tympani.pipeline.diagnosis.config import DiagnosisConfig
from tympani.pipeline.diagnosis.evidence import trial_sse
from tympani.pipeline.synthetic.family_a import NoiseConfig, synthetic_dataset
from tympani.pipeline.synthetic.family_b import generate

__all__ = ["EvalConfig", "CaseSpec", "GeneratedCase", "FAMILIES", "family_a", "family_b", "case_specs", "run_case",
           "evaluate", "summarise", "format_evaluation", "NOISE_LEVELS", "VERDICT_COLUMNS"]

#: Noise levels: factor on the generator's default sensor noise (white, AR(1), tare).
NOISE_LEVELS: dict[str, float] = {"low": 0.5, "nominal": 1.0, "high": 3.0}


@dataclass(frozen=True)
class EvalConfig:
    """What the blind evaluation generates.

    Parameters
    ----------
    effects : tuple of str or None
        Hidden effects cycled over the cases (None: no effect).
    strength_range : tuple of float
        Range of the effect strength (dimensionless, 1 = typical), drawn log-uniformly.
    noise_levels : mapping of str to float
        Named factors on :class:`tympani.pipeline.synthetic.family_a.NoiseConfig`'s white, AR and tare noise.
    speeds_mm_s : tuple of float
        Insertion speeds (mm/s).
    trials : int
        Repeats per speed.
    diagnosis : DiagnosisConfig
        The diagnosis' settings (frozen thresholds by default).
    keep_errors : bool
        Keep each case's per-trial held-out errors (columns starting with ``_``; for studying decision
        rules, not written to files).
    family : str
        Generator family of the data (:data:`FAMILIES`): ``"A"`` (:mod:`tympani.pipeline.synthetic.family_a`) or ``"B"``
        (:mod:`tympani.pipeline.synthetic.family_b`, written independently from a physics brief).
    """

    effects: tuple[str | None, ...] = (None, "hydrodynamic_lift", "viscous_drag", "capstan", "sensor_lag",
                                      "sensor_drift", "pressure_profile")
    strength_range: tuple[float, float] = (0.3, 2.0)
    noise_levels: Mapping[str, float] = field(default_factory=lambda: dict(NOISE_LEVELS))
    speeds_mm_s: tuple[float, ...] = (0.5, 1.5, 3.0, 5.0, 7.5)
    trials: int = 10
    diagnosis: DiagnosisConfig = field(default_factory=lambda: DiagnosisConfig(bootstrap=500))
    keep_errors: bool = False
    family: str = "A"


@dataclass(frozen=True)
class CaseSpec:
    """One blind case.

    Parameters
    ----------
    index : int
        Case number.
    effect : str or None
        Hidden effect.
    strength : float
        Its strength (dimensionless).
    noise_level : str
        Name of the noise level.
    entropy : tuple of int
        Seed material of the case's generator (from ``SeedSequence.spawn``).
    """

    index: int
    effect: str | None
    strength: float
    noise_level: str
    entropy: tuple[int, ...]


def case_specs(cases: int, seed: int, config: EvalConfig = EvalConfig()) -> list[CaseSpec]:
    """The cases of an evaluation (balanced over effects, seeded).

    Parameters
    ----------
    cases : int
        Number of cases.
    seed : int
        Seed of the whole evaluation.
    config : EvalConfig
    """
    root = np.random.SeedSequence(seed)
    children = root.spawn(cases)
    levels = list(config.noise_levels)
    out = []
    lo, hi = config.strength_range
    for i, child in enumerate(children):
        rng = np.random.default_rng(child.spawn(1)[0])
        effect = config.effects[i % len(config.effects)]
        strength = float(math.exp(rng.uniform(math.log(lo), math.log(hi)))) if effect is not None else 0.0
        out.append(CaseSpec(i, effect, strength, levels[int(rng.integers(len(levels)))],
                            tuple(int(v) for v in child.generate_state(4))))
    return out


def run_case(spec: CaseSpec, config: EvalConfig = EvalConfig()) -> dict:
    """Generate one case, diagnose it blind, score it.

    Parameters
    ----------
    spec : CaseSpec
    config : EvalConfig

    Returns
    -------
    dict
        The spec, the truth (``gap_to_noise``, ``detectable``, ``gap_rms_g``, ``noise_rms_g``), the
        verdict (``verdict``, ``effect_found``, ``tied``, ``leader``), scores (``correct``,
        ``confident_wrong``), shrinkages (``shrink_pct``, ``true_shrink_pct``), the share of the
        peak drop explained and timings (s); ``error`` if the diagnosis failed.
    """
    t0 = time.perf_counter()
    try:
        case = FAMILIES[config.family](spec, config)
    except Exception as exc:  # a generator that fails on one draw costs that case only
        return dict(family=config.family, case=spec.index, effect=spec.effect or "none", strength=spec.strength,
                    noise_level=spec.noise_level, gap_to_noise=0.0, detectable=False, gap_rms_g=float("nan"),
                    noise_rms_g=float("nan"), generate_s=time.perf_counter() - t0, verdict="error",
                    effect_found=None, error=f"generator: {type(exc).__name__}: {exc}", correct=False,
                    confident_wrong=False, tied="", leader=None, shrink_pct=float("nan"), true_shrink_pct=float("nan"),
                    peak_explained=float("nan"), diagnose_s=float("nan"))
    synced, clean_all, base_all = case.synced, case.clean_g, case.base_g
    t_gen = time.perf_counter() - t0
    table = synced.assign(row_id=np.arange(len(synced)))
    out: dict[str, Any] = dict(
        family=config.family, case=spec.index, effect=spec.effect or "none", strength=spec.strength,
        noise_level=spec.noise_level, gap_to_noise=case.gap_rms_g / case.noise_rms_g if spec.effect else 0.0,
        detectable=bool(spec.effect and case.gap_rms_g > 2 * case.noise_rms_g),
        gap_rms_g=case.gap_rms_g, noise_rms_g=case.noise_rms_g, generate_s=t_gen)
    try:
        d = diagnose(table, config.diagnosis)
    except Exception as exc:  # a failed case is reported, not fatal to the evaluation
        out.update(verdict="error", effect_found=None, error=f"{type(exc).__name__}: {exc}", correct=False,
                   confident_wrong=False, tied="", leader=None, shrink_pct=float("nan"),
                   true_shrink_pct=float("nan"), peak_explained=float("nan"), diagnose_s=float("nan"))
        return out
    idx = d.data.rows["row_id"].to_numpy(int)
    truth_rows = clean_all[idx]
    base_rows = base_all[idx]
    resid_gap = residual_gap(d.data, truth_rows, base_rows, config.diagnosis) if spec.effect else 0.0
    dec = d.decision
    leader = dec.effect or dec.leader

    def true_rmse(name: str) -> float:
        return float(np.sqrt(np.mean((d.heldout[name] - truth_rows) ** 2)))

    rb, re_ = true_rmse("base"), true_rmse(leader)
    truth_effect = spec.effect
    found = d.effect
    out.update(
        verdict=d.verdict, effect_found=found, tied=",".join(dec.tied), leader=dec.leader, reference=dec.reference,
        correct=bool((truth_effect is None and d.verdict == "no_gap") or (truth_effect is not None and found == truth_effect)),
        confident_wrong=bool(d.verdict == "identified" and found != truth_effect),
        ambiguous_includes_truth=bool(d.verdict == "ambiguous" and truth_effect in dec.tied),
        ambiguous_top2_truth=bool(d.verdict == "ambiguous" and truth_effect in dec.tied[:2]),
        residual_gap_g=resid_gap, residual_gap_to_noise=resid_gap / out["noise_rms_g"] if out["noise_rms_g"] > 0 else 0.0,
        shrink_pct=float(d.gap.shrink_pct), true_shrink_pct=float(100 * (1 - re_ / rb)) if rb > 0 else float("nan"),
        true_rmse_base_g=rb, true_rmse_effect_g=re_, gain_lo=float(dec.gain_lo[dec.leader]),
        lof_p=float(max(d.lof.base.p_value, d.lof.control.p_value)),
        peak_explained=float(d.peak_drop.explained_frac_fastest), diagnose_s=float(d.timing_s), error="",
    )
    if config.keep_errors:  # per-trial held-out errors, to study decision rules afterwards
        names = list(d.fits)
        out["_names"] = names
        out["_sse"] = np.column_stack([trial_sse(d.data, d.data.y - d.heldout[nm])[0] for nm in names])
        out["_n"] = trial_sse(d.data, d.data.y)[1]
        out["_trial_speed"] = d.data.trial_speed
        tests = {f.name: getattr(d.lof, f.name) for f in fields(d.lof)}
        out["_lof"] = {k: (v.p_value, getattr(v, "level", v).p_value, getattr(v, "shape", v).p_value)
                       for k, v in tests.items()}
        out["_systematic"] = dict(dec.systematic_g)
        out["_mse"] = {nm: float(np.sum(out["_sse"][:, i]) / np.sum(out["_n"])) for i, nm in enumerate(names)}
    return out


@dataclass(frozen=True)
class GeneratedCase:
    """One generated experiment as the evaluation needs it.

    Attributes
    ----------
    synced : pandas.DataFrame
        The synced table the diagnosis sees (no truth columns).
    clean_g, base_g : ndarray
        Per row, the noiseless force with and without the hidden effect (g).
    gap_rms_g : float
        RMS over the rows of ``clean_g - base_g`` (g).
    noise_rms_g : float
        RMS of the measured minus the noiseless force (g).
    """

    synced: pd.DataFrame
    clean_g: np.ndarray
    base_g: np.ndarray
    gap_rms_g: float
    noise_rms_g: float


def family_a(spec: "CaseSpec", config: "EvalConfig") -> GeneratedCase:
    """A case of :mod:`tympani.pipeline.synthetic.family_a` (noise level: a factor on its white, AR(1) and tare noise)."""
    factor = config.noise_levels[spec.noise_level]
    base_noise = NoiseConfig()
    noise = replace(base_noise, white_g=base_noise.white_g * factor, ar_g=base_noise.ar_g * factor,
                    tare_sd_g=base_noise.tare_sd_g * factor)
    rng = np.random.default_rng(np.random.SeedSequence(list(spec.entropy)))
    synced, truth = synthetic_dataset(rng, spec.effect, strength=spec.strength if spec.effect else 1.0,
                                      speeds_mm_s=config.speeds_mm_s, trials=config.trials, noise=noise)
    clean = truth.tables.clean
    return GeneratedCase(synced, clean["force_effect_g"].to_numpy(float), clean["force_base_g"].to_numpy(float),
                         float(truth.gap_rms_g), float(truth.noise_rms_g))


def family_b(spec: "CaseSpec", config: "EvalConfig") -> GeneratedCase:
    """A case of :mod:`tympani.pipeline.synthetic.family_b` (noise level: its ``noise_scale``)."""
    seed = int(np.random.SeedSequence(list(spec.entropy)).generate_state(1)[0])
    table, truth = generate(spec.effect, seed, strength=spec.strength if spec.effect else 1.0,
                            speeds_mm_s=config.speeds_mm_s, trials=config.trials,
                            noise_scale=config.noise_levels[spec.noise_level])
    truth_columns = [c for c in table.columns if c.startswith("true_")]
    return GeneratedCase(table.drop(columns=truth_columns).reset_index(drop=True),
                         table["true_force_g"].to_numpy(float), table["true_base_g"].to_numpy(float),
                         float(truth.gap_rms_g), float(truth.noise_rms_g))


#: Generator families: name -> function (case spec, config) -> :class:`GeneratedCase`.
FAMILIES = {"A": family_a, "B": family_b}


def residual_gap(ds, clean_g: np.ndarray, base_g: np.ndarray, config: DiagnosisConfig) -> float:
    """The part (RMS, g) of a hidden effect that the paper's model cannot absorb.

    The control (friction law re-identified, trial gains) is fitted to the noiseless force with the
    effect and to the noiseless force without it (same trials); the result is
    ``sqrt(max(MSE_with - MSE_without, 0))``: what is left by the effect beyond what the model leaves
    anyway (angle noise, the random mean placement scale of each speed).

    Parameters
    ----------
    ds : pipeline.diagnosis.prepare.Prepared
        The rows diagnosed.
    clean_g, base_g : ndarray
        The generator's noiseless force with and without the effect (g) on those rows.
    config : DiagnosisConfig
    """
    control = next(c for c in candidates(()) if c.name == "control")
    mse = []
    for y in (clean_g, base_g):
        fit = fit_candidate(replace(ds, y=np.asarray(y, dtype=float)), control, config=config,
                            rng=np.random.default_rng(0))
        mse.append(fit.rss / fit.n)
    return float(math.sqrt(max(mse[0] - mse[1], 0.0)))


def _run(args: tuple[CaseSpec, EvalConfig]) -> dict:
    return run_case(*args)


def evaluate(cases: int, seed: int, *, workers: int = 1, config: EvalConfig = EvalConfig(),
             progress: bool = False) -> pd.DataFrame:
    """Run a blind evaluation.

    Parameters
    ----------
    cases : int
        Number of cases (spread evenly over ``config.effects``).
    seed : int
        Seed of the evaluation.
    workers : int
        Worker processes (1: in this process).
    config : EvalConfig
    progress : bool
        Print one line per finished case to stderr.

    Returns
    -------
    pandas.DataFrame
        One row per case (:func:`run_case`), in case order.
    """
    specs = case_specs(cases, seed, config)
    rows = []
    if workers <= 1:
        it = (run_case(s, config) for s in specs)
        for r in it:
            rows.append(r)
            if progress:
                print(f"case {r['case']}: {r['effect']} -> {r['verdict']} {r['effect_found'] or ''}", file=sys.stderr)
    else:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")  # one BLAS thread per worker: the workers are the parallelism
        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            for r in pool.map(_run, [(s, config) for s in specs], chunksize=1):
                rows.append(r)
                if progress:
                    print(f"case {r['case']}: {r['effect']} -> {r['verdict']} {r['effect_found'] or ''}", file=sys.stderr)
    return pd.DataFrame(rows).sort_values("case").reset_index(drop=True)


VERDICT_COLUMNS = ("hydrodynamic_lift", "viscous_drag", "capstan", "sensor_lag", "sensor_drift", "pressure_profile",
                   "ambiguous", "no_gap")


def summarise(results: pd.DataFrame) -> dict:
    """Confusion matrix and rates of an evaluation.

    Parameters
    ----------
    results : pandas.DataFrame
        From :func:`evaluate`.

    Returns
    -------
    dict
        ``confusion`` (DataFrame: true effect x predicted, with ``ambiguous`` and ``no_gap``
        columns), ``by_effect`` and ``by_noise`` (DataFrames: cases, accuracy, accuracy on
        detectable cases, confident-wrong rate, ambiguous rate), ``accuracy``,
        ``accuracy_detectable``, ``accuracy_residual_detectable`` (effects whose unabsorbable gap,
        :func:`residual_gap`, exceeds twice the noise), ``confident_wrong_rate`` (over all cases),
        ``false_identified_rate`` (effect-free cases), ``median_shrink_pct`` (against the measured
        force), ``median_true_shrink_pct`` (against the noiseless force) and
        ``median_gap_shrink_pct`` (the same above the effect-free floor ``floor_g`` per noise level:
        ``1 - sqrt(E_eff^2 - F^2) / sqrt(E_base^2 - F^2)``), all when the right effect is identified,
        ``median_shrink_residual_detectable_pct`` and ``median_true_shrink_residual_detectable_pct``
        (the first two on the residually detectable cases only),
        ``shrink_by_effect``, ``median_diagnose_s``, ``errors``.
    """
    r = results.copy()
    r["predicted"] = np.where(r["verdict"] == "identified", r["effect_found"].fillna(""), r["verdict"])
    rows = [e for e in ["none", *VERDICT_COLUMNS[:6]] if e in set(r["effect"])]
    cols = [c for c in VERDICT_COLUMNS] + (["error"] if (r["verdict"] == "error").any() else [])
    confusion = pd.crosstab(r["effect"], r["predicted"]).reindex(index=rows, columns=cols, fill_value=0)

    def block(g: pd.DataFrame) -> dict:
        det = g[g["detectable"] | (g["effect"] == "none")]
        return dict(cases=len(g), accuracy=float(g["correct"].mean()) if len(g) else float("nan"),
                    detectable_cases=len(det),
                    accuracy_detectable=float(det["correct"].mean()) if len(det) else float("nan"),
                    confident_wrong=float(g["confident_wrong"].mean()) if len(g) else float("nan"),
                    ambiguous=float((g["verdict"] == "ambiguous").mean()) if len(g) else float("nan"),
                    no_gap=float((g["verdict"] == "no_gap").mean()) if len(g) else float("nan"))

    by_effect = pd.DataFrame({e: block(g) for e, g in r.groupby("effect")}).T.reindex(rows)
    by_noise = pd.DataFrame({n: block(g) for n, g in r.groupby("noise_level")}).T
    none = r[r["effect"] == "none"]
    right = r[(r["effect"] != "none") & r["correct"]].copy()
    # floor: the held-out error against the noiseless force that the base model has without any effect
    # (angle noise, each speed's random mean placement scale), per noise level, from this evaluation
    floor = none.groupby("noise_level")["true_rmse_base_g"].median() if "true_rmse_base_g" in r else pd.Series(dtype=float)
    if len(right) and len(floor):
        f = right["noise_level"].map(floor).fillna(float(floor.median())).to_numpy(float)
        eb = np.sqrt(np.maximum(right["true_rmse_base_g"].to_numpy(float) ** 2 - f**2, 1e-12))
        ee = np.sqrt(np.maximum(right["true_rmse_effect_g"].to_numpy(float) ** 2 - f**2, 0.0))
        right["gap_shrink_pct"] = 100 * (1 - ee / eb)
    else:
        right["gap_shrink_pct"] = np.nan
    r["useful"] = r["correct"] | r.get("ambiguous_top2_truth", False)
    identified = r[r["verdict"] == "identified"]
    ambiguous = r[r["verdict"] == "ambiguous"]
    visible = r[(r["effect"] != "none") & r["detectable"]]
    visible_res = r[(r["effect"] != "none") & (r.get("residual_gap_to_noise", 0) > 2)]
    rdet = r[(r["effect"] != "none") & (r.get("residual_gap_to_noise", 0) > 2)]
    rright = right[right.get("residual_gap_to_noise", 0) > 2]
    det = r[r["detectable"] | (r["effect"] == "none")]
    return dict(
        confusion=confusion, by_effect=by_effect, by_noise=by_noise, cases=len(r),
        accuracy=float(r["correct"].mean()), accuracy_detectable=float(det["correct"].mean()) if len(det) else float("nan"),
        accuracy_detectable_effects=float(det[det["effect"] != "none"]["correct"].mean())
        if (det["effect"] != "none").any() else float("nan"),
        confident_wrong_rate=float(r["confident_wrong"].mean()),
        false_identified_rate=float((none["verdict"] == "identified").mean()) if len(none) else float("nan"),
        median_shrink_pct=float(right["shrink_pct"].median()) if len(right) else float("nan"),
        median_true_shrink_pct=float(right["true_shrink_pct"].median()) if len(right) else float("nan"),
        median_gap_shrink_pct=float(right["gap_shrink_pct"].median()) if len(right) else float("nan"),
        shrink_by_effect=right.groupby("effect")[["shrink_pct", "true_shrink_pct", "gap_shrink_pct"]].median(),
        floor_g=floor.to_dict(),
        accuracy_residual_detectable=float(rdet["correct"].mean()) if len(rdet) else float("nan"),
        residual_detectable_cases=int(len(rdet)),
        median_shrink_residual_detectable_pct=float(rright["shrink_pct"].median()) if len(rright) else float("nan"),
        median_true_shrink_residual_detectable_pct=(float(rright["true_shrink_pct"].median()) if len(rright)
                                                    else float("nan")),
        median_diagnose_s=float(r["diagnose_s"].median()), errors=int((r["verdict"] == "error").sum()),
        precision_identified=float(identified["correct"].mean()) if len(identified) else float("nan"),
        identified_cases=int(len(identified)),
        ambiguous_cases=int(len(ambiguous)),
        ambiguous_truth_in_set=float(ambiguous["ambiguous_includes_truth"].mean()) if len(ambiguous) else float("nan"),
        ambiguous_truth_in_top2=float(ambiguous["ambiguous_top2_truth"].mean()) if len(ambiguous) else float("nan"),
        useful_visible=float(visible["useful"].mean()) if len(visible) else float("nan"),
        visible_cases=int(len(visible)),
        useful_visible_unabsorbed=float(visible_res["useful"].mean()) if len(visible_res) else float("nan"),
        median_true_shrink_right_pct=float(right["true_shrink_pct"].median()) if len(right) else float("nan"),
    )


def format_evaluation(summary: dict) -> str:
    """The evaluation as text (confusion matrix, accuracies, rates)."""
    short = {"hydrodynamic_lift": "lift", "viscous_drag": "drag", "capstan": "capstan", "sensor_lag": "lag",
             "sensor_drift": "drift", "pressure_profile": "profile", "ambiguous": "ambig", "no_gap": "no_gap",
             "none": "none", "error": "error"}
    conf = summary["confusion"].rename(index=short, columns=short)
    lines = [f"blind evaluation: {summary['cases']} cases", "", "confusion matrix (rows: hidden effect; columns: verdict)",
             conf.to_string(), ""]
    fmt = lambda v: "  -  " if v != v else f"{v:5.2f}"  # noqa: E731
    lines.append(f"{'effect':<10}{'cases':>6}{'acc':>7}{'det':>5}{'acc_det':>8}{'wrong':>7}{'ambig':>7}{'no_gap':>7}")
    for name, row in summary["by_effect"].iterrows():
        lines.append(f"{short.get(name, name):<10}{int(row['cases']):>6}{fmt(row['accuracy']):>7}{int(row['detectable_cases']):>5}"
                     f"{fmt(row['accuracy_detectable']):>8}{fmt(row['confident_wrong']):>7}{fmt(row['ambiguous']):>7}"
                     f"{fmt(row['no_gap']):>7}")
    lines.append("")
    if len(summary.get("shrink_by_effect", [])):
        lines.append("median shrinkage (%) when identified: measured / noiseless / gap above floor")
        for name, row in summary["shrink_by_effect"].iterrows():
            lines.append(f"  {short.get(name, name):<10}{row['shrink_pct']:6.1f}{row['true_shrink_pct']:8.1f}"
                         f"{row['gap_shrink_pct']:8.1f}")
        lines.append("")
    lines.append(f"{'noise':<10}{'cases':>6}{'acc':>7}{'det':>5}{'acc_det':>8}{'wrong':>7}{'ambig':>7}{'no_gap':>7}")
    for name, row in summary["by_noise"].iterrows():
        lines.append(f"{name:<10}{int(row['cases']):>6}{fmt(row['accuracy']):>7}{int(row['detectable_cases']):>5}"
                     f"{fmt(row['accuracy_detectable']):>8}{fmt(row['confident_wrong']):>7}{fmt(row['ambiguous']):>7}"
                     f"{fmt(row['no_gap']):>7}")
    lines += [
        "",
        f"precision of 'identified' {summary['precision_identified']:.3f} ({summary['identified_cases']} cases); "
        f"ambiguous answers {summary['ambiguous_cases']}: the truth among the tied effects in "
        f"{summary['ambiguous_truth_in_set']:.3f}, among the first two in {summary['ambiguous_truth_in_top2']:.3f}",
        f"useful answers (right, or ambiguous with the truth among the first two) where the effect is visible above "
        f"the noise: {summary['useful_visible']:.3f} of {summary['visible_cases']} (noiseless gap > 2 x noise); "
        f"{summary['useful_visible_unabsorbed']:.3f} where the gap the model cannot absorb exceeds 2 x noise",
        f"accuracy {summary['accuracy']:.3f}; on detectable cases (gap > 2 x noise, and effect-free) "
        f"{summary['accuracy_detectable']:.3f} (effects only {summary['accuracy_detectable_effects']:.3f})",
        f"confident-wrong rate {summary['confident_wrong_rate']:.3f}; false 'identified' on effect-free data "
        f"{summary['false_identified_rate']:.3f}",
        f"accuracy on effects whose unabsorbable gap exceeds 2 x noise: {summary['accuracy_residual_detectable']:.3f} "
        f"({summary['residual_detectable_cases']} cases); median held-out shrinkage there when identified: "
        f"{summary['median_shrink_residual_detectable_pct']:.1f} % (measured force), "
        f"{summary['median_true_shrink_residual_detectable_pct']:.1f} % (noiseless force)",
        f"median held-out shrinkage when the right effect is identified: {summary['median_shrink_pct']:.1f} % of the RMSE "
        f"against the measured force, {summary['median_true_shrink_pct']:.1f} % against the noiseless force, "
        f"{summary['median_gap_shrink_pct']:.1f} % of the gap above the effect-free floor "
        f"({', '.join(f'{k} {v:.3f} g' for k, v in summary['floor_g'].items())})",
        f"median time per diagnosis {summary['median_diagnose_s']:.2f} s" + (f"; {summary['errors']} case(s) failed"
                                                                             if summary["errors"] else ""),
    ]
    return "\n".join(lines)

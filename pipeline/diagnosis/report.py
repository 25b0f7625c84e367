"""Files of a diagnosis: ``diagnosis.json``, a Markdown report with figures, the rows used.

:func:`write_diagnosis` writes, in the output folder::

    diagnosis.json              verdict, effect, ranking, gap, ... (pipeline.diagnosis.analysis.diagnosis_to_json)
    diagnosis.md                the report in words, tables and figures
    diagnosis_rows.csv          the subsampled rows with the base, control and leading effect's
                                held-out and in-sample predictions (g)
    fig_gap_heatmap.png         held-out residual of the base, speed x theta_con (% of the model)
    fig_force_vs_theta.png      force vs theta_con per speed: data, base, base + effect (held out)
    fig_ranking.png             held-out RMSE of every candidate with 95 % bootstrap intervals
    fig_phase.png               held-out residual of base and base + effect per insertion phase
    diagnosis.provenance.json   tool, version, input hash, configuration

Figures use matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from tympani.pipeline.diagnosis.analysis import Diagnosis, diagnosis_to_json
from tympani.pipeline.diagnosis.config import PHASES
from tympani.pipeline.diagnosis.kernels import kernel

__all__ = ["write_diagnosis", "report_markdown", "summary_line"]


def summary_line(diag: Diagnosis) -> str:
    """One line for the terminal: verdict, effect or tied effects, held-out RMSE before/after."""
    g = diag.gap
    if diag.verdict == "identified":
        head = f"identified {diag.effect}"
    elif diag.verdict == "ambiguous":
        head = f"ambiguous between {', '.join(diag.decision.tied)}"
    else:
        head = "no_gap"
    return (f"diagnose: {head}; held-out RMSE base {g.rmse_base_g:.3g} g -> with {g.effect} "
            f"{g.rmse_with_effect_g:.3g} g ({g.shrink_pct:+.0f} %); {diag.timing_s:.1f} s")


def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def report_markdown(diag: Diagnosis, figures: dict[str, str], source: str | None = None) -> str:
    """The Markdown report.

    Parameters
    ----------
    diag : Diagnosis
    figures : dict
        Figure key -> file name (relative to the report).
    source : str, optional
        The synced table's path.
    """
    ds = diag.data
    dec = diag.decision
    g = diag.gap
    lines = ["# Sim-to-real gap diagnosis", ""]
    if source:
        lines += [f"Input: `{source}` — {len(ds.speeds)} speeds ({', '.join(f'{s:g}' for s in ds.speeds)} mm/s), "
                  f"{ds.n_trials} trials, {ds.n} rows fitted of {ds.n_rows_in} usable.", ""]
    verdict = {"identified": f"**identified: `{diag.effect}`**",
               "ambiguous": f"**ambiguous** between {', '.join(f'`{e}`' for e in dec.tied)}",
               "no_gap": "**no gap**"}[diag.verdict]
    lines += [f"Verdict: {verdict}: {dec.reason}.", ""]

    lines += ["## Is there a gap?", ""]
    ref = dec.reference
    for name, lof in (("base", diag.lof.base), ("control", diag.lof.control)):
        lines.append(f"- Lack of fit of the {name} model's held-out predictions against the scatter between repeats: "
                     f"p = {_fmt(lof.p_value)} (level {lof.level.p_value:.3g}, shape {lof.shape.p_value:.3g}; "
                     f"Holm over cells, Bonferroni over the two; significant below {lof.alpha:g}); systematic misfit "
                     f"{lof.systematic_rms_g:.3g} g RMS against a repeat scatter of {lof.repeat_scatter_g:.3g} g "
                     f"per cell mean.")
    fails = diag.lof.base.significant
    lines += ["", "A gap needs the base model to fail: " + ("it does." if fails else "it fits within the scatter."), ""]

    lines += ["## Where is it?", "", diag.where.summary + ".", ""]
    if "heatmap" in figures:
        lines += [f"![held-out residual of the base model]({figures['heatmap']})", ""]
    if "phase" in figures:
        lines += [f"![residual per phase]({figures['phase']})", ""]

    lines += ["## Which effect?", "",
              "Held-out RMSE: each speed predicted by fits to the other speeds (leave-one-speed-out); "
              f"extrapolation = the fold holding out {ds.speeds[-1]:g} mm/s. Gain = share of the {ref}'s held-out "
              "MSE removed (lower bound: one-sided 2.5 % bootstrap over trials).", "",
              "| candidate | held-out RMSE (g) | 95 % CI | extrapolation (g) | gain | gain lower bound | ΔBIC | ΔAICc |",
              "|---|---|---|---|---|---|---|---|"]
    for row in diag.ranking:
        nm = row.candidate
        lines.append(f"| {nm} | {row.heldout_rmse_g:.4g} | {row.heldout_rmse_lo_g:.3g}–{row.heldout_rmse_hi_g:.3g} | "
                     f"{row.extrap_rmse_g:.4g} | {_fmt(dec.gain.get(nm), 2)} | {_fmt(dec.gain_lo.get(nm), 2)} | "
                     f"{row.delta_bic:.1f} | {row.delta_aicc:.1f} |")
    lines.append("")
    if "ranking" in figures:
        lines += [f"![ranking]({figures['ranking']})", ""]
    lines += ["Identifiability of each effect's parameters (fit to all speeds; cluster-robust standard errors over "
              "trials; range over the leave-one-speed-out folds):", "",
              "| effect | parameter | value | stderr | z vs null | folds | most correlated with | assessment |",
              "|---|---|---|---|---|---|---|---|"]
    for eff, params in diag.identifiability.items():
        for pname, info in params.items():
            lines.append(f"| {eff} | {pname} | {_fmt(info.value, 4)} | {_fmt(info.stderr, 2)} | "
                         f"{_fmt(info.z_vs_null, 2)} | {_fmt(info.fold_min, 3)}…{_fmt(info.fold_max, 3)} | "
                         f"{info.most_correlated_with or '–'} ({_fmt(info.max_abs_corr, 2)}) | {info.assessment} |")
    lines.append("")

    lines += ["## How much?", "",
              f"Held-out RMSE base {g.rmse_base_g:.4g} g (95 % CI {g.rmse_base_ci95_g[0]:.3g}–{g.rmse_base_ci95_g[1]:.3g}) "
              f"-> base + {g.effect} {g.rmse_with_effect_g:.4g} g "
              f"({g.rmse_with_effect_ci95_g[0]:.3g}–{g.rmse_with_effect_ci95_g[1]:.3g}): shrinks by {g.shrink_pct:.1f} % "
              f"(95 % CI {g.shrink_ci95_pct[0]:.1f}–{g.shrink_ci95_pct[1]:.1f} %); control {g.rmse_control_g:.4g} g. "
              f"Systematic part (cell means over repeats, noise-corrected): {g.systematic_base_g:.3g} g -> "
              f"{g.systematic_with_effect_g:.3g} g.", "",
              "| speed (mm/s) | trials | base (g) | control (g) | with effect (g) | shrink % | 95 % CI | bias base (g) | bias with effect (g) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in g.by_speed:
        lines.append(f"| {r.speed_mm_s:g} | {r.n_trials} | {r.rmse_base_g:.4g} | {r.rmse_control_g:.4g} | "
                     f"{r.rmse_with_effect_g:.4g} | {r.shrink_pct:.1f} | {r.shrink_ci95_pct[0]:.0f}…{r.shrink_ci95_pct[1]:.0f} | "
                     f"{r.bias_base_g:+.3g} | {r.bias_with_effect_g:+.3g} |")
    lines.append("")
    pdrop = diag.peak_drop
    lines += [f"Paper-style peak-force change vs {pdrop.reference_speed_mm_s:g} mm/s (drop = 1 − peak(v)/peak(slowest)):", "",
              "| speed (mm/s) | measured | base model | base + effect | base + effect (held out) | share explained |",
              "|---|---|---|---|---|---|"]
    for p in pdrop.by_speed:
        lines.append(f"| {p.speed_mm_s:g} | {-p.measured_pct:+.1f} % | {-p.base_pct:+.1f} % | "
                     f"{-p.with_effect_pct:+.1f} % | {-p.with_effect_heldout_pct:+.1f} % | "
                     f"{_fmt(100 * p.explained_frac, 3)} % |")
    lines.append("")
    if "force" in figures:
        lines += [f"![force vs theta_con]({figures['force']})", ""]

    if diag.experiments:
        title = ("## Experiments that would split the tied effects" if diag.verdict == "ambiguous"
                 else "## Experiments that would confirm it against the runner-up")
        lines += [title, ""]
        for exp in diag.experiments:
            star = " (recommended)" if exp.recommended else ""
            lines.append(f"- **{exp.experiment}**{star}: {exp.protocol}. Smallest difference between the "
                         f"predictions: {_fmt(exp.min_difference_g)} g.")
            for eff, pred in exp.predictions.items():
                lines.append(f"  - `{eff}`: {pred.words}.")
        lines.append("")
    if ds.notes:
        lines += ["## Notes on the data", ""] + [f"- {n}" for n in ds.notes] + [""]
    lines += ["## Candidate forms", "", "| candidate | form |", "|---|---|",
              "| base | the paper's force model (Eqs. 2-7) with the nominal friction law, pressures linear in "
              "theta_con, a per-trial gain (mean per speed within ±2 sd/sqrt(n) of 1) |",
              "| control | base with the Stribeck law re-identified (mu_s, mu_k, v_s) |"]
    lines += [f"| {e} | {kernel(e).form} |" for e in diag.identifiability]
    lines.append("")
    lines += ["## Method", "",
              "Candidates: base (the paper's force model with the nominal friction law, pressures identified), "
              "control (friction law re-identified), base + each unmodelled effect in the forms above (the "
              "library's, generalised where noted); each with a per-trial gain on the "
              "contact force (mean per speed within ±2 sd/sqrt(n) of 1). Fitted by variable projection on "
              f"{diag.config.rows_per_trial} rows per trial. Decision thresholds: effect must remove more than "
              f"{100 * diag.config.min_gain:.0f} % of the held-out MSE of base and control, the runner-up must miss more "
              f"than {100 * diag.config.min_separation:.0f} % of the leader's gain (both at one-sided level "
              f"{diag.config.alpha:g} of a {diag.config.bootstrap}-draw bootstrap over trials), and the base model must "
              f"fail the lack-of-fit test at {diag.config.lof_alpha:g}. See `pipeline/diagnosis/decision.py`.", ""]
    return "\n".join(lines)


def _figures(diag: Diagnosis, out: Path) -> dict[str, str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ds = diag.data
    leader = diag.gap.effect
    figs: dict[str, str] = {}

    # heat map: base held-out residual, speed x theta_con (% of the model), significant cells marked
    cells = pd.DataFrame([asdict(c) for c in diag.where.cells_theta])
    if not cells.empty:
        cells["label"] = [("no contact" if hi <= 0 else f"{lo:.2f}–{hi:.2f}") for lo, hi in
                          zip(cells["theta_lo_rad"], cells["theta_hi_rad"])]
        order = cells.drop_duplicates("label").sort_values("theta_hi_rad")["label"].tolist()
        pivot = cells.pivot_table(index="speed_mm_s", columns="label", values="mean_g").reindex(columns=order)
        rel = cells.pivot_table(index="speed_mm_s", columns="label", values="rel_pct").reindex(columns=order)
        sig = cells.pivot_table(index="speed_mm_s", columns="label", values="significant", aggfunc="max").reindex(
            columns=order)
        fig, ax = plt.subplots(figsize=(7.5, 3.8))
        lim = float(np.nanmax(np.abs(pivot.to_numpy()))) if np.isfinite(pivot.to_numpy()).any() else 1.0
        im = ax.imshow(pivot.to_numpy(), cmap="RdBu", vmin=-lim, vmax=lim, aspect="auto", origin="lower")
        ax.set_xticks(range(len(order)), order, rotation=30, ha="right", fontsize=8)
        ax.set_yticks(range(len(pivot.index)), [f"{v:g}" for v in pivot.index])
        for i in range(pivot.shape[0]):
            for j in range(pivot.shape[1]):
                v = pivot.iat[i, j]
                if np.isfinite(v):
                    pct = "" if order[j] == "no contact" or not np.isfinite(rel.iat[i, j]) else f"\n{rel.iat[i, j]:+.0f} %"
                    ax.text(j, i, f"{v:+.2g}{'*' if bool(sig.iat[i, j]) else ''}{pct}", ha="center", va="center",
                            fontsize=7, color="white" if abs(v) > 0.6 * lim else "black")  # legible on dark cells
        ax.set_xlabel("theta_con (rad)")
        ax.set_ylabel("speed (mm/s)")
        ax.set_title("held-out residual of the base model, g and % of the model (* q < 0.05)", fontsize=9)
        fig.colorbar(im, ax=ax, label="measured − model (g)")
        fig.tight_layout()
        fig.savefig(out / "fig_gap_heatmap.png", dpi=110)
        plt.close(fig)
        figs["heatmap"] = "fig_gap_heatmap.png"

    # force vs theta_con per speed: binned data, base and base + effect (held out, gain 1)
    n_s = len(ds.speeds)
    fig, axes = plt.subplots(1, n_s, figsize=(3.0 * n_s, 3.2), sharey=True, squeeze=False)
    bins = np.linspace(0.0, ds.theta_hi, 13)
    for k, (ax, s) in enumerate(zip(axes[0], ds.speeds)):
        sel = (ds.speed_idx == k) & (ds.phase_label >= 1) & (ds.phase_label <= 3)
        ax.plot(ds.theta_con[sel], ds.y[sel], ".", ms=1.5, color="0.7", label="measured")
        for name, colour, label in (("base", "tab:blue", "base"), (leader, "tab:red", f"base + {leader}")):
            pred = diag.heldout[name]
            idx = np.digitize(ds.theta_con[sel], bins)
            xs, ys = [], []
            for b in np.unique(idx):
                m = idx == b
                if m.sum() >= 3:
                    xs.append(float(np.mean(ds.theta_con[sel][m])))
                    ys.append(float(np.mean(pred[sel][m])))
            ax.plot(xs, ys, "-", color=colour, lw=1.6, label=label)
        ax.set_title(f"{s:g} mm/s (held out)", fontsize=9)
        ax.set_xlabel("theta_con (rad)")
    axes[0][0].set_ylabel("force (g)")
    axes[0][0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "fig_force_vs_theta.png", dpi=110)
    plt.close(fig)
    figs["force"] = "fig_force_vs_theta.png"

    # ranking
    rk = pd.DataFrame([asdict(r) for r in diag.ranking])
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    y = np.arange(len(rk))[::-1]
    colours = ["tab:red" if c == diag.effect else "tab:orange" if c in diag.decision.tied else
               "0.5" if c in ("base", "control") else "tab:blue" for c in rk["candidate"]]
    ax.barh(y, rk["heldout_rmse_g"], color=colours,
            xerr=[rk["heldout_rmse_g"] - rk["heldout_rmse_lo_g"], rk["heldout_rmse_hi_g"] - rk["heldout_rmse_g"]],
            capsize=3)
    ax.set_yticks(y, rk["candidate"], fontsize=8)
    ax.set_xlabel("held-out RMSE (g), 95 % bootstrap interval")
    ax.set_title(f"effect ranking — verdict: {diag.verdict}", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "fig_ranking.png", dpi=110)
    plt.close(fig)
    figs["ranking"] = "fig_ranking.png"

    # residual per phase and speed
    fig, ax = plt.subplots(figsize=(7.0, 3.2))
    width = 0.8 / n_s
    for k, s in enumerate(ds.speeds):
        for name, alpha in (("base", 0.45), (leader, 1.0)):
            r = (ds.y - diag.heldout[name])
            vals = [float(np.mean(r[(ds.speed_idx == k) & (ds.phase_label == p)])) if np.any(
                (ds.speed_idx == k) & (ds.phase_label == p)) else np.nan for p in range(len(PHASES))]
            ax.bar(np.arange(len(PHASES)) + (k - n_s / 2 + 0.5) * width, vals, width * 0.9, alpha=alpha,
                   color=f"C{k}", label=f"{s:g} mm/s" if name == "base" else None)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xticks(range(len(PHASES)), PHASES)
    ax.set_ylabel("mean held-out residual (g)")
    ax.set_title(f"pale: base; solid: base + {leader}", fontsize=9)
    ax.legend(fontsize=7, ncol=n_s)
    fig.tight_layout()
    fig.savefig(out / "fig_phase.png", dpi=110)
    plt.close(fig)
    figs["phase"] = "fig_phase.png"
    return figs


def write_diagnosis(diag: Diagnosis, out_dir: str | os.PathLike, *, source: str | os.PathLike | None = None,
                    figures: bool = True) -> Path:
    """Write a diagnosis' files (see the module docstring) and return the ``diagnosis.json`` path.

    Parameters
    ----------
    diag : Diagnosis
    out_dir : str or PathLike
        Output folder (created).
    source : str or PathLike, optional
        The synced table diagnosed (recorded in the JSON, the report and the provenance).
    figures : bool
        Draw the figures.
    """
    from tympani.pipeline.io import atomic_write_csv, atomic_write_json, atomic_write_text, provenance

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = atomic_write_json(out / "diagnosis.json", diagnosis_to_json(diag, source))
    ds = diag.data
    leader = diag.gap.effect
    rows = ds.rows[["trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con",
                    "v_inst_mm_s", "phase"]].copy()
    rows["phase"] = [PHASES[int(k)] for k in ds.phase_label]
    for name in dict.fromkeys(("base", "control", leader)):
        rows[f"{name}_heldout_g"] = diag.heldout[name]
        rows[f"{name}_fit_g"] = diag.fitted[name]
    atomic_write_csv(out / "diagnosis_rows.csv", rows)
    figs = _figures(diag, out) if figures else {}
    atomic_write_text(out / "diagnosis.md", report_markdown(diag, figs, None if source is None else os.fspath(source)))
    if source is not None and Path(source).exists():
        cfg = asdict(diag.config)
        cfg["friction"] = {k: v for k, v in cfg["friction"].items() if not k.startswith("p_")}
        atomic_write_json(out / "diagnosis.provenance.json", provenance(source, cfg))
    return path

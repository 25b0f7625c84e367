"""The report of ``tympani run``: one self-contained HTML page.

:func:`write_report` reads the files :func:`tympani.pipeline.run.run_pipeline` wrote in an output folder
(``run.json``, ``trials.csv``, ``synced.csv``, ``fit/fit.json``, ``bounds/bounds.json``,
``diagnosis/diagnosis.json`` and the PNG figures the stages drew) and writes ``report.html``
beside them. Figures are embedded as base64 PNG, tables are inline HTML, the style sheet is
inline: the page loads nothing from anywhere (links to the machine-readable files beside it are
plain relative links). The report draws no figure of its own: it embeds the stages' figures
(:mod:`tympani.pipeline.report.figures`, :mod:`tympani.pipeline.diagnosis.report`).

:func:`load_report_data` (files → dict) and :func:`render_html` (dict → text) are separate, so
the page can be tested without files and the data without HTML.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

__all__ = ["load_report_data", "render_html", "write_report", "REPORT_NAME", "FIGURES"]

REPORT_NAME = "report.html"

#: Embedded figures: key -> (file relative to the output folder, caption).
FIGURES: dict[str, tuple[str, str]] = {
    "force_vs_theta_con": ("bounds/force_vs_theta_con.png",
                           "Measured force against the contact angle per speed, with the force model's simulation "
                           "of the paper's scenario overlaid (the paper's Figs. 9–11)."),
    "log_force": ("bounds/log_force.png", "ln F against the angle with the Eq. (8) line ln F = c1·θ + c2 of each "
                                          "speed (Fig. 12)."),
    "bounds": ("bounds/bounds.png", "Per speed, Eq. (9)'s 95 % prediction band (orange, the paper's safety "
                                    "boundary) and the recommended bound (blue), each with its coverage of trials "
                                    "left out of its fit (Figs. 13–15)."),
    "gap_heatmap": ("diagnosis/fig_gap_heatmap.png", "Held-out residual of the base model over speed × theta_con "
                                                     "(* significant cells)."),
    "diag_force": ("diagnosis/fig_force_vs_theta.png", "Force against theta_con per held-out speed: data, base model "
                                                       "and base + the leading effect, each predicted from the other "
                                                       "speeds."),
    "ranking": ("diagnosis/fig_ranking.png", "Held-out RMSE of every candidate with 95 % bootstrap intervals."),
    "phase": ("diagnosis/fig_phase.png", "Held-out residual per insertion phase and speed."),
}

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:1100px;padding:1.2em 2em;
color:#1d2330;background:#fff;line-height:1.45}
h1{font-size:1.7em;margin-bottom:.2em}h2{border-bottom:2px solid #d8dde6;padding-bottom:.2em;margin-top:1.8em}
h3{margin-top:1.3em}
table.data{border-collapse:collapse;margin:.6em 0 1em;font-size:.88em}
table.data th,table.data td{border:1px solid #cfd5df;padding:.25em .6em;text-align:right;vertical-align:top}
table.data th{background:#eef1f6}table.data td.t,table.data th.t{text-align:left;overflow-wrap:anywhere}
table.data{max-width:100%}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #e2e6ec}figcaption{font-size:.88em;color:#4a5468}
.summary{display:flex;flex-wrap:wrap;gap:.8em}.card{background:#f3f6fa;border:1px solid #d8dde6;border-radius:6px;
padding:.6em 1em;min-width:9em}.card b{display:block;font-size:1.5em}
.verdict{font-size:1.15em;padding:.7em 1em;border-radius:6px;background:#eef5ee;border:1px solid #9cc79c}
.note{padding:.6em 1em;border-radius:6px;background:#fff7e0;border:1px solid #e5c56b}
.error{padding:.6em 1em;border-radius:6px;background:#fdecec;border:1px solid #e39a9a}
code{background:#f1f3f7;padding:0 .25em;border-radius:3px}
"""


# --------------------------------------------------------------------------- loading


def _json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _csv(path: Path, **kwargs: Any) -> pd.DataFrame | None:
    try:
        return pd.read_csv(path, **kwargs)
    except (OSError, ValueError, pd.errors.ParserError):
        return None


def _synced(path: Path) -> pd.DataFrame | None:
    """The synced table's ``trial``, ``speed_mm_s`` and ``theta_con``; None when it cannot be read."""
    from tympani.pipeline.force.sync import read_synced
    from tympani.vision.errors import InputError

    try:
        table = read_synced(path)
    except InputError:
        return None
    wanted = ["trial", "speed_mm_s", "theta_con"]
    return table[wanted] if all(c in table.columns for c in wanted) else None


def load_report_data(out_dir: str | os.PathLike) -> dict:
    """Everything the report shows, read from an output folder of ``tympani run``.

    Parameters
    ----------
    out_dir : str or PathLike

    Returns
    -------
    dict
        ``run`` (run.json), ``trials`` (DataFrame or None), ``synced`` (summary dict or None:
        ``rows``, ``rows_with_angles``, ``speeds_mm_s``, ``trials``), ``sync`` (synced.sync.json),
        ``fit``, ``bounds``, ``diagnosis`` (their JSON or None), ``figures`` (key -> PNG bytes of
        :data:`FIGURES` that exist), ``files`` (machine-readable outputs present, relative
        paths).
    """
    out = Path(out_dir)
    run = _json(out / "run.json") or {}
    stages = run.get("stages", {})
    synced = None
    table = _synced(out / "synced.csv")
    if table is not None and stages.get("sync", {}).get("status") in ("ok", "partial", "skipped"):
        synced = dict(rows=len(table), rows_with_angles=int(table["theta_con"].notna().sum()),
                      speeds_mm_s=sorted(float(v) for v in table["speed_mm_s"].unique()),
                      trials=int(table["trial"].nunique()),
                      trials_per_speed={float(k): int(v) for k, v in
                                        table.groupby("speed_mm_s")["trial"].nunique().items()})

    def usable(stage: str, rel: str) -> dict | None:
        return _json(out / rel) if stages.get(stage, {}).get("status") in ("ok", "skipped", "partial") else None

    figures = {}
    for key, (rel, _) in FIGURES.items():
        stage = "diagnose" if rel.startswith("diagnosis/") else "bounds"
        if stages.get(stage, {}).get("status") in ("ok", "skipped") and (out / rel).is_file():
            figures[key] = (out / rel).read_bytes()
    listed = ["run.json", "trials.csv", "angles/extract_summary.csv", "synced.csv", "synced.sync.json",
              "fit/fit.json", "fit/fit_residuals.csv", "bounds/bounds.json", "bounds/bounds_bands.csv",
              "diagnosis/diagnosis.json", "diagnosis/diagnosis.md", "diagnosis/diagnosis_rows.csv"]
    files = [f for f in listed if (out / f).is_file()]
    angles = sorted(p.name for p in (out / "angles").glob("*.angles.csv")) if (out / "angles").is_dir() else []
    return dict(run=run, trials=_csv(out / "trials.csv", keep_default_na=True), synced=synced,
                sync=usable("sync", "synced.sync.json"), fit=usable("fit", "fit/fit.json"),
                bounds=usable("bounds", "bounds/bounds.json"), diagnosis=usable("diagnose", "diagnosis/diagnosis.json"),
                figures=figures, files=files, angles_tables=angles)


# --------------------------------------------------------------------------- HTML pieces


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _num(value: Any, digits: int = 4) -> str:
    """A number for a table cell: ``digits`` significant digits, an en dash for missing."""
    if value is None:
        return "–"
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    try:
        v = float(value)
    except (TypeError, ValueError):
        return _e(value)
    if not math.isfinite(v):
        return "–"
    if v == round(v) and abs(v) < 1e6 and abs(v) >= 10 ** (digits - 1):
        return str(int(round(v)))
    return f"{v:.{digits}g}"


def _pct(value: Any) -> str:
    """A percentage to 0.1 % (``0.0``, not ``-5.048e-07``), an en dash for missing."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "–"
    return f"{round(v, 1) + 0.0:.1f}" if math.isfinite(v) else "–"  # + 0.0: no "-0.0"


def table_html(rows: Sequence[Sequence[Any]], header: Sequence[str], *, table_id: str,
               text_columns: Iterable[int] = (0,)) -> str:
    """An HTML table (cells escaped; numbers formatted by :func:`_num` unless already str).

    Parameters
    ----------
    rows : sequence of sequences
        Cell values; str cells are escaped as text, others formatted as numbers.
    header : sequence of str
    table_id : str
        The table's ``id``.
    text_columns : iterable of int
        Columns aligned left.
    """
    left = set(text_columns)

    def cell(j: int, v: Any, tag: str) -> str:
        cls = ' class="t"' if j in left else ""
        text = _e(v) if isinstance(v, str) else _num(v)
        return f"<{tag}{cls}>{text}</{tag}>"

    head = "".join(cell(j, h, "th") for j, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell(j, v, "td") for j, v in enumerate(r)) + "</tr>" for r in rows)
    return f'<table class="data" id="{_e(table_id)}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def figure_html(key: str, png: bytes | None, caption: str) -> str:
    """A ``<figure>`` with the PNG embedded as a base64 data URI (empty text when no PNG)."""
    if not png:
        return ""
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure id="fig-{_e(key)}"><img alt="{_e(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")


def _status_note(stage: dict | None, what: str) -> str:
    stage = stage or {}
    msg = stage.get("message") or "the stage did not run"
    cls = "error" if stage.get("status") == "failed" else "note"
    return f'<p class="{cls}">No {_e(what)}: {_e(msg)}.</p>'


def _pm(value: Any, se: Any, digits: int = 4) -> str:
    return f"{_num(value, digits)} ± {_num(se, 2)}"


# --------------------------------------------------------------------------- sections


def _summary(data: dict) -> str:
    trials = data["trials"]
    synced = data["synced"]
    n_trials = len(trials) if trials is not None else 0
    n_synced = int((trials["sync"] == "ok").sum()) if trials is not None else 0
    speeds = synced["speeds_mm_s"] if synced else (sorted(trials["speed_mm_s"].unique()) if trials is not None else [])
    frames = float(trials["frames"].fillna(0).sum()) if trials is not None else 0.0
    frames_ok = float(trials["frames_ok"].fillna(0).sum()) if trials is not None else 0.0
    cards = [("trials", f"{n_synced} / {n_trials}", "synced / in the manifest"),
             ("speeds", ", ".join(f"{v:g}" for v in speeds) or "–", "mm/s"),
             ("frames measured", f"{int(frames_ok)} / {int(frames)}",
              f"{100 * frames_ok / frames:.1f} %" if frames else "no frames"),
             ("force samples", f"{synced['rows']}" if synced else "–",
              f"{synced['rows_with_angles']} with angles" if synced else "no synced table")]
    diag = data["diagnosis"]
    verdict = diag["verdict"] + (f": {diag['effect']}" if diag.get("effect") else "") if diag else "not made"
    cards.append(("diagnosis", verdict, "unmodelled effect"))
    body = "".join(f'<div class="card"><span>{_e(t)}</span><b>{_e(v)}</b><small>{_e(s)}</small></div>'
                   for t, v, s in cards)
    errors = data["run"].get("errors") or []
    err = ""
    if errors:
        items = "".join(f"<li><code>{_e(x)}</code></li>" for x in errors)
        err = (f'<div class="error" id="errors"><b>{len(errors)} input(s) could not be used</b> (the other trials '
               f"were analysed):<ul>{items}</ul></div>")
    return f'<section id="summary"><h2>Summary</h2><div class="summary">{body}</div>{err}</section>'


def _trials(data: dict) -> str:
    t = data["trials"]
    if t is None or t.empty:
        return ""
    rows = []
    for r in t.to_dict("records"):
        rows.append([str(r["trial"]), r["speed_mm_s"], str(r["source"]),
                     None if pd.isna(r["frames"]) else int(r["frames"]),
                     None if pd.isna(r["frames_ok"]) else int(r["frames_ok"]),
                     str(r["sync"]), str(r["sync_method"]) if isinstance(r["sync_method"], str) else "–",
                     r["video_t0_s"], None if pd.isna(r["force_samples"]) else int(r["force_samples"]),
                     int(r["warnings"]), str(r["error"]) if isinstance(r["error"], str) else ""])
    header = ["trial", "speed (mm/s)", "source", "frames", "measured", "sync", "offset from", "video_t0_s (s)",
              "force samples", "sync warnings", "error"]
    warnings = [(t["trial"], w) for t in (data.get("sync") or {}).get("trials", []) for w in t.get("warnings") or []]
    notes = ""
    if warnings:
        items = "".join(f"<li><code>{_e(trial)}</code>: {_e(w)}</li>" for trial, w in warnings)
        notes = (f'<details class="note" id="sync-warnings"><summary>{len(warnings)} sync warning(s) '
                 f"(synced.sync.json)</summary><ul>{items}</ul></details>")
    refused = [(r["trial"], r["refused"]) for r in t.to_dict("records")
               if isinstance(r.get("refused"), str) and r["refused"]]
    if refused:
        items = "".join(f"<li><code>{_e(trial)}</code>: {_e(why)}</li>" for trial, why in refused)
        notes += (f'<details class="note" id="refused"><summary>Why frames were not measured, in {len(refused)} '
                  f"trial(s) (each frame's reason is in its angles table)</summary><ul>{items}</ul></details>")
    return ('<section id="trials"><h2>Trials</h2>'
            + table_html(rows, header, table_id="trials-table", text_columns=(0, 2, 5, 6, 10)) + notes + "</section>")


def _paper_figures(data: dict) -> str:
    stage = data["run"].get("stages", {}).get("bounds")
    parts = ['<section id="figures"><h2>Force against contact angle (the paper\'s figures)</h2>']
    keys = ("force_vs_theta_con", "log_force", "bounds")
    if not any(k in data["figures"] for k in keys):
        parts.append(_status_note(stage, "figures"))
    for key in keys:
        parts.append(figure_html(key, data["figures"].get(key), FIGURES[key][1]))
    parts.append("</section>")
    return "".join(parts)


def _fit(data: dict) -> str:
    fit = data["fit"]
    head = '<section id="fit"><h2>Friction model fit (Eqs. 2–7 of the seed paper)</h2>'
    if not fit:
        return head + _status_note(data["run"].get("stages", {}).get("fit"), "fit") + "</section>"
    rows = []
    for name, p in fit["params"].items():
        ci = p.get("ci95") or [None, None]
        rows.append([name, p.get("value"), p.get("stderr"), ci[0], ci[1], bool(p.get("at_bound"))])
    params = table_html(rows, ["parameter", "value", "s.e.", "95 % CI low", "95 % CI high", "at bound"],
                        table_id="fit-table", text_columns=(0,))
    held = ", ".join(f"{k} = {_num(v)}" for k, v in (fit.get("fixed") or {}).items())
    stats = (f"<p>n = {_e(fit['n'])} rows, RMSE {_num(fit['rmse_g'])} g, AIC {_num(fit['aic'], 6)}, "
             f"BIC {_num(fit['bic'], 6)}; standard errors: {_e(fit.get('se_method', '?'))}"
             + (f"; held: {_e(held)}" if held else "") + ".</p>")
    by_speed = table_html([[r["speed_mm_s"], r["rmse_g"], r["n"]] for r in fit.get("by_speed", [])],
                          ["speed (mm/s)", "RMSE (g)", "n"], table_id="fit-by-speed", text_columns=())
    warnings = fit.get("warnings") or []
    warn = ('<div class="note"><b>Notes of the fit</b><ul>' + "".join(f"<li>{_e(w)}</li>" for w in warnings)
            + "</ul></div>") if warnings else ""
    return head + stats + params + "<h3>Residual by speed</h3>" + by_speed + warn + "</section>"


def _share(value: Any) -> str:
    """A share (0–1) as a percentage, an en dash for missing."""
    return "–" if value is None else f"{100 * float(value):.1f} %"


def _p_value(p: float) -> str:
    return "< 0.0001" if p < 1e-4 else f"{p:.2g}"


def _bounds(data: dict) -> str:
    b = data["bounds"]
    head = '<section id="bounds-section"><h2>Safety bounds, Eq. (8)–(9)</h2>'
    if not b:
        return head + _status_note(data["run"].get("stages", {}).get("bounds"), "bounds") + "</section>"
    angle = b.get("angle", "theta_con")
    rows = []
    for r in b["by_speed"]:
        lof = r.get("lack_of_fit") or {}
        rec = r.get("recommended") or {}
        rows.append([r["speed_mm_s"], _pm(r["c1"], r["c1_se"]), _pm(r["c2"], r["c2_se"]), r["n"], r.get("n_trials"),
                     _share(r.get("heldout_coverage_eq9")),
                     "Eq. (9)" if rec.get("form") == "eq9" else str(rec.get("form", "")), _share(r.get("heldout_coverage")),
                     "–" if not lof else _p_value(lof["p_value"]) + (" (concave)" if lof.get("rejects_eq8") and
                                                                     lof["curvature_per_rad2"] < 0 else
                                                                     " (convex)" if lof.get("rejects_eq8") else "")])
    table = table_html(rows, ["speed (mm/s)", "c1 ± s.e. (1/rad)", "c2 ± s.e.", "n", "trials",
                              "Eq. (9) held-out coverage", "recommended bound", "its held-out coverage",
                              "lack of fit p"], table_id="bounds-table", text_columns=(1, 2, 5, 6, 7, 8))
    notes = "".join(f'<p class="note">{_num(r["speed_mm_s"])} mm/s: {_e(r["coverage_note"])}</p>'
                    for r in b["by_speed"] if r.get("coverage_note"))
    skipped = "".join(f'<p class="note">{_num(s["speed_mm_s"])} mm/s skipped: {_e(s["reason"])}</p>'
                      for s in b.get("skipped") or [])
    explain = (f"<p>Eq. (8) as the paper writes it: <code>ln F = c1 · {_e(angle)} + c2</code>, c1 the slope (1/rad), "
               "c2 the intercept, per speed. A bound <em>holds</em> when about 95 % of the samples of a trial left out "
               "of its fit fall inside its 95 % band (leave one trial out, pooled). The lack-of-fit test adds a "
               "quadratic term to Eq. (8): a small p-value means ln F is not a straight line in the angle, and "
               "Eq. (9)'s band then over- and undershoots. The recommended bound is chosen among low-order forms of "
               "ln F by that held-out coverage (within 95 ± 3 %), then by the narrowest band. Bands in "
               "<code>bounds/bounds_bands.csv</code> (<code>pi_*</code>: Eq. (9); <code>rec_*</code>: recommended)."
               "</p>")
    quote = f'<p class="verdict" id="bounds-quote"><b>What to quote.</b> {_e(b.get("quote", ""))}</p>'
    return head + quote + explain + table + notes + skipped + "</section>"


def _diagnosis(data: dict) -> str:
    d = data["diagnosis"]
    head = '<section id="diagnosis"><h2>Sim-to-real diagnosis: unmodelled effects</h2>'
    if not d:
        return head + _status_note(data["run"].get("stages", {}).get("diagnose"), "diagnosis") + "</section>"
    parts = [head]
    if d["verdict"] == "identified":
        words = f"identified: <code>{_e(d['effect'])}</code>"
    elif d["verdict"] == "ambiguous":
        words = "ambiguous between " + ", ".join(f"<code>{_e(e)}</code>" for e in d.get("tied") or [])
    else:
        words = "no gap: the model fits within the scatter between repeats"
    parts.append(f'<p class="verdict" id="verdict">Verdict — {words}.<br><small>{_e(d.get("reason", ""))}</small></p>')
    synced = data["synced"] or {}
    per_speed = synced.get("trials_per_speed") or {}
    if per_speed and min(per_speed.values()) < 3:
        parts.append('<p class="note">With fewer than 3 repeats at some speed the test against the scatter between '
                     "repeats has little power: a real gap can go undetected. More repeats per speed make the "
                     "verdict firmer.</p>")
    g = d["gap"]
    parts.append(f"<p>Where: {_e(g['where']['summary'])}.</p>")
    parts.append(f"<p>How much (held out): RMSE base {_num(g['rmse_base_g'])} g → base + "
                 f"<code>{_e(g['effect'])}</code> {_num(g['rmse_with_effect_g'])} g "
                 f"({_pct(g['shrink_pct'])} %); control (friction law re-identified) "
                 f"{_num(g.get('rmse_control_g'))} g. {_e(d['heldout']['scheme'])}.</p>")
    rows = [[r["candidate"], r["heldout_rmse_g"], (r.get("heldout_rmse_ci95_g") or [None])[0],
             (r.get("heldout_rmse_ci95_g") or [None, None])[1], r.get("extrapolation_rmse_g"), r["delta_bic"]]
            for r in d["ranking"]]
    parts.append("<h3>Candidates</h3>" + table_html(
        rows, ["candidate", "held-out RMSE (g)", "95 % CI low", "95 % CI high", "extrapolation RMSE (g)", "ΔBIC"],
        table_id="diagnosis-ranking"))
    rows = [[r["speed_mm_s"], r["n_trials"], r["rmse_base_g"], r["rmse_control_g"], r["rmse_with_effect_g"],
             _pct(r["shrink_pct"])] for r in g.get("by_speed", [])]
    parts.append("<h3>By held-out speed</h3>" + table_html(
        rows, ["speed (mm/s)", "trials", "base (g)", "control (g)", "with effect (g)", "shrink %"],
        table_id="diagnosis-by-speed", text_columns=()))
    for key in ("ranking", "gap_heatmap", "diag_force", "phase"):
        parts.append(figure_html(key, data["figures"].get(key), FIGURES[key][1]))
    for exp in d.get("experiments") or []:
        parts.append(f'<p class="note">Experiment that would decide: <b>{_e(exp["experiment"])}</b> — '
                     f"{_e(exp['protocol'])}.</p>")
    parts.append("<p>Full account (tests, identifiability, peak-force drop): <a href=\"diagnosis/diagnosis.md\">"
                 "diagnosis/diagnosis.md</a>.</p></section>")
    return "".join(parts)


def _provenance(data: dict) -> str:
    run = data["run"]
    inp = run.get("input", {})
    env = run.get("environment", {})
    cmd = run.get("command")
    items = [("tool", f"{run.get('tool', 'tympani')} {run.get('version', '?')}"),
             ("created (UTC)", run.get("created_utc", "?")),
             ("command", " ".join(cmd) if cmd else "(Python API)"),
             ("manifest", inp.get("path", run.get("manifest", "?"))),
             ("manifest hash", inp.get("hash", "?")),
             ("environment", ", ".join(f"{k} {v}" for k, v in env.items())),
             ("run time", f"{run.get('seconds', float('nan')):.1f} s" if run.get("seconds") is not None else "?")]
    meta = table_html([[k, str(v)] for k, v in items], ["", ""], table_id="provenance-table", text_columns=(0, 1))
    stages = [[name, s.get("status", ""), s.get("seconds"), s.get("message", "")]
              for name, s in run.get("stages", {}).items() if name != "report"]
    stage_table = table_html(stages, ["stage", "status", "seconds", "message"], table_id="stages-table",
                             text_columns=(0, 1, 3))
    links = "".join(f'<li><a href="{_e(f)}">{_e(f)}</a></li>' for f in data["files"])
    n_angles = len(data.get("angles_tables") or [])
    angles = f"<li><code>angles/</code>: {n_angles} angles table(s) with registration and provenance JSON</li>"
    return ('<section id="provenance"><h2>Provenance and files</h2>' + meta + "<h3>Stages</h3>" + stage_table
            + f"<h3>Machine-readable outputs (beside this page)</h3><ul>{links}{angles}</ul></section>")


def render_html(data: dict) -> str:
    """The report page from :func:`load_report_data`'s dict (no file access).

    Parameters
    ----------
    data : dict

    Returns
    -------
    str
        A complete HTML5 document with inline style and embedded figures.
    """
    run = data["run"]
    title = f"tympani report — {Path(str(run.get('manifest', 'experiment'))).parent.name or 'experiment'}"
    body = "".join([
        f"<h1>{_e(title)}</h1>",
        f"<p>Video and force analysis of electrode-array insertions: <code>{_e(run.get('manifest', ''))}</code>.</p>",
        _summary(data), _trials(data), _paper_figures(data), _fit(data), _bounds(data), _diagnosis(data),
        _provenance(data),
    ])
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{_e(title)}</title>'
            f'<meta name="viewport" content="width=device-width,initial-scale=1"><style>{_CSS}</style></head>'
            f"<body>{body}</body></html>\n")


def write_report(out_dir: str | os.PathLike) -> Path:
    """Write ``report.html`` into a ``tympani run`` output folder, atomically.

    Parameters
    ----------
    out_dir : str or PathLike

    Returns
    -------
    Path
    """
    from tympani.pipeline.io import atomic_write_text

    return atomic_write_text(Path(out_dir) / REPORT_NAME, render_html(load_report_data(out_dir)))

"""The ``tympani simulate``, ``tympani paper`` and ``tympani fit`` commands (registered in :mod:`tympani.pipeline.cli`).

Kept apart from ``pipeline/cli/__init__.py`` so that file only lists them. Importing this module is cheap
(argparse only); the model and the fit are imported when a command runs.
"""

from __future__ import annotations

import argparse
import sys

from tympani.pipeline.cli.argtypes import UsageError, positive_int, speed_list

__all__ = [
    "configure_simulate",
    "run_simulate",
    "configure_paper",
    "run_paper",
    "PAPER_HELP",
    "PAPER_DESCRIPTION",
    "configure_fit",
    "run_fit",
    "SIMULATE_HELP",
    "SIMULATE_DESCRIPTION",
    "FIT_HELP",
    "FIT_DESCRIPTION",
]

SIMULATE_HELP = "the force model on a scenario of the paper's TABLE I"
SIMULATE_DESCRIPTION = (
    "Evaluate the insertion-force model (linear contact pressure along the arc, Stribeck friction) along "
    "scenario S1..S4 of the seed paper's TABLE I at the given insertion speeds (mm/s): S3 and S4 are its six "
    "steps, S1 and S2 hold theta_bot = 1.40 rad at TABLE II's six contact angles. The constants the paper "
    "does not print are the ones fitted to its TABLE II (see 'tympani paper'). Without --out the force (g) "
    "is printed per step and speed; with --out the simulation table (scenario, speed_mm_s, theta_bot, "
    "theta_tip, theta_con, force_g, step) is written as CSV. --grid N evaluates N points along the "
    "scenario instead of its six steps."
)
PAPER_HELP = "the paper's TABLE II beside the model, and the constants fitted to it"
PAPER_DESCRIPTION = (
    "Fit the constants the seed paper does not print (effective contact width, Stribeck velocity and "
    "exponent, which of 0.12/0.18 is static, the garbled fourth p_bot of S3 (and S4), the friction projection) to its "
    "TABLE II, and print the table beside the model cell by cell with the residuals, the speed effect step "
    "by step against the paper's, friction's share of the force, the chosen constants and every "
    "combination tried. With --out DIR also writes table_ii.csv, table_ii_speed.csv and table_ii_fit.json."
)
FIT_HELP = "identified friction-model parameters with uncertainties"
FIT_DESCRIPTION = (
    "Fit the insertion-force model (Stribeck friction, pressures linear in theta_con) to a synced table over "
    "all speeds by bounded least squares from several seeded starts. Writes fit.json (parameters with "
    "standard errors, correlation, AIC/BIC, per-speed RMSE, warnings), fit_residuals.csv and "
    "fit.provenance.json to --out. The contact width is held by default: it is exactly degenerate with the "
    "pressures."
)

_SPEED_DEFAULT = (0.5, 3.0, 7.5)


def _name_list(text: str) -> list[str]:
    from tympani.pipeline.model.friction import FLAT_NAMES

    names = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [n for n in names if n not in FLAT_NAMES]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown parameter name(s) {', '.join(unknown) or repr(text)}; choose from {', '.join(FLAT_NAMES)}")
    return names


def _assignments(text: str) -> dict[str, float]:
    from tympani.pipeline.model.friction import FLAT_NAMES

    out: dict[str, float] = {}
    for item in (v.strip() for v in text.split(",") if v.strip()):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in FLAT_NAMES:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE with NAME one of {', '.join(FLAT_NAMES)}, got {item!r}")
        try:
            out[name] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r}: {value!r} is not a number") from None
    return out


# --------------------------------------------------------------------------- simulate


def configure_simulate(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani simulate``."""
    p.add_argument("--scenario", required=True, type=str.upper, choices=["S1", "S2", "S3", "S4"],
                   help="scenario of TABLE I")
    p.add_argument("--speeds", type=speed_list, default=list(_SPEED_DEFAULT), metavar="V,..",
                   help="insertion speeds in mm/s, each > 0 (default 0.5,3,7.5)")
    p.add_argument("--grid", type=positive_int, default=None, metavar="N",
                   help="N points along the scenario (N >= 2) instead of its six steps")
    p.add_argument("--out", metavar="FILE", help="write the simulation table to this CSV file")
    p.add_argument("--friction-mode", choices=["axial", "vector"], default="axial",
                   help="friction transmitted along the insertion axis (default; reproduces TABLE II) or the "
                        "friction vectors summed before projecting")


def _compact(table) -> str:
    """Force (g) per step (rows) and speed (columns) as text."""
    wide = table.pivot_table(index=["step", "theta_bot", "theta_tip", "theta_con"], columns="speed_mm_s",
                             values="force_g").reset_index()
    wide.columns = [c if isinstance(c, str) else f"F@{c:g}mm/s_g" for c in wide.columns]
    return wide.drop(columns="step").to_string(index=False, float_format=lambda v: f"{v:.3f}")


def run_simulate(args: argparse.Namespace) -> int:
    """Run ``tympani simulate``; returns the exit status."""
    from tympani.pipeline.model.paper import SCENARIOS, SIM_COLUMNS, simulate

    if args.grid is not None and args.grid < 2:
        raise UsageError("tympani simulate: --grid must be at least 2")
    table = simulate(args.scenario, args.speeds, grid=args.grid, friction_mode=args.friction_mode)
    table = table[list(SIM_COLUMNS) + ["step"]]
    sc = SCENARIOS[args.scenario]
    if args.out:
        from tympani.pipeline.io import atomic_write_csv

        atomic_write_csv(args.out, table)
        peaks = table.groupby("speed_mm_s")["force_g"].max()
        summary = ", ".join(f"{v:g} mm/s {f:.3f} g" for v, f in peaks.items())
        print(f"simulate: {sc.name}, {len(table)} rows, peak force {summary} -> {args.out}")
    else:
        print(f"# {sc.name} (TABLE I): {sc.description}; friction {args.friction_mode}, constants fitted to "
              "TABLE II ('tympani paper')")
        print(_compact(table))
    return 0


# --------------------------------------------------------------------------- paper


def configure_paper(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani paper``."""
    p.add_argument("--out", metavar="DIR", help="also write the comparison as CSV and JSON files to DIR")


def run_paper(args: argparse.Namespace) -> int:
    """Run ``tympani paper``; returns the exit status."""
    from tympani.pipeline.model.paper import fit_table_ii, format_table_ii_fit

    fit = fit_table_ii()
    print(format_table_ii_fit(fit))
    if args.out:
        from pathlib import Path

        from tympani.pipeline.io import atomic_write_csv, atomic_write_json

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_csv(out / "table_ii.csv", fit.cells)
        atomic_write_csv(out / "table_ii_speed.csv", fit.drops)
        record = {
            "chosen": _option_record(fit.chosen),
            "options": [_option_record(o) for o in fit.options],
            "delta_profile": fit.delta_profile.to_dict(orient="records"),
        }
        atomic_write_json(out / "table_ii_fit.json", record)
        print(f"paper: -> {out}")
    return 0


def _option_record(option) -> dict:
    keys = ("mu_s", "mu_k", "p_bot4_MPa", "friction_mode", "v_s_mm_s", "v_s_se", "delta_s", "delta_s_se",
            "contact_width_mm", "chi2_speed", "rms_shape_pct", "max_cell_pct")
    return {k: getattr(option, k) for k in keys}


# --------------------------------------------------------------------------- fit


def configure_fit(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani fit``."""
    p.add_argument("synced", metavar="SYNCED", help="synced table (CSV, from 'tympani sync'; docs/file-formats.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (fit.json and companions)")
    p.add_argument("--free", type=_name_list, default=None, metavar="NAME,..",
                   help="parameters to fit (default p_tip0_MPa,p_tip1_MPa_per_rad,p_bot0_MPa,p_bot1_MPa_per_rad,"
                        "mu_s,mu_k,v_s_mm_s)")
    p.add_argument("--fix", type=_assignments, default={}, metavar="NAME=VALUE,..",
                   help="values of held parameters (default: the constants fitted to the paper's TABLE II, "
                        "contact_width_mm=0.03453,delta_s=0.3482,mu_v_s_per_mm=0)")
    p.add_argument("--starts", type=positive_int, default=8, metavar="N", help="number of starts (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts (default 0)")
    p.add_argument("--se", choices=["auto", "cluster", "neff", "naive"], default="auto",
                   help="standard errors reported as stderr (default auto: trial clusters when there are "
                        "enough trials, else effective sample size)")
    p.add_argument("--friction-mode", choices=["axial", "vector"], default="axial",
                   help="friction transmitted along the insertion axis (default; reproduces the paper's TABLE II) "
                        "or the friction vectors summed before projecting")


def run_fit(args: argparse.Namespace) -> int:
    """Run ``tympani fit``; returns the exit status."""
    import os

    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.model.identify import DEFAULT_FREE, FitOptions, fit_synced, write_fit

    table = read_synced(args.synced)
    free = tuple(args.free) if args.free else DEFAULT_FREE
    options = FitOptions(free=free, fixed=dict(args.fix), starts=args.starts, seed=args.seed,
                         se=args.se, friction_mode=args.friction_mode)
    result = fit_synced(table, options, source=args.synced)
    path = write_fit(result, args.out, source=args.synced)
    for warning in result.warnings:
        print(f"tympani: warning: {warning}", file=sys.stderr)
    width = max(len(n) for n in result.params)
    for name, est in result.params.items():
        flag = "  (at bound)" if est.at_bound else ""
        print(f"  {name:<{width}} = {est.value:.5g} ± {est.stderr:.2g}{flag}")
    speeds = ", ".join(f"{r.speed_mm_s:g}: {r.rmse_g:.3g}" for r in result.by_speed.itertuples())
    print(f"fit: n={result.n}, rmse {result.rmse_g:.4g} g (by speed {speeds}), AIC {result.aic:.1f}, "
          f"BIC {result.bic:.1f}, stderr {result.se_method} -> {os.fspath(path)}")
    return 0

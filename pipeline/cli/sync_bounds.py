"""The ``tympani sync`` and ``tympani bounds`` commands (registered in :mod:`tympani.pipeline.cli`).

Importing this module is cheap (argparse only); the work is imported when a command runs.
Results go to files, a short summary to stdout, one line per failed trial to stderr (warnings go
to the JSON reports, counted in the summary).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tympani.pipeline.cli.argtypes import fraction, positive_float

__all__ = [
    "SYNC_HELP",
    "SYNC_DESCRIPTION",
    "BOUNDS_HELP",
    "BOUNDS_DESCRIPTION",
    "configure_sync",
    "run_sync",
    "configure_bounds",
    "run_bounds",
]

SYNC_HELP = "the synced table"
SYNC_DESCRIPTION = (
    "Put every manifest trial's angles table and force log on one clock and write the synced table "
    "(trial, speed_mm_s, time_s, force_g, theta_tip, theta_bot, theta_con, plus depth_mm, video_time_s, "
    "saturated, sync_offset_s, sync_uncertainty_s) to --out, and a report (offset, uncertainty, method, "
    "force-log cleaning, warnings per trial) to <stem>.sync.json beside it. The offset is the manifest's "
    "video_t0_s when the trial's cell is filled in, otherwise estimated from the data (depth_mm against "
    "theta_tip when the log has depth, else force_g against theta_con). Angles tables come from the manifest's "
    "angles column or <angles-dir>/<trial>.angles.csv. A lab's own logs (epoch stamps, newtons, a sign and a gain, "
    "a separate depth log of the robot's stage, another tracker's angles) are read through a log format file: "
    "--format FILE or the manifest's format column; a depth log (manifest column depth) adds depth_mm and its "
    "motion start, which can be the angle track's zero. A bad trial is reported on stderr and the others are "
    "still written; exit 2 if any trial failed."
)
BOUNDS_HELP = "Eq. (8)-(9) fits with 95%% bounds per speed"  # argparse %-formats help
BOUNDS_DESCRIPTION = (
    "Per speed, fit Eq. (8) of the seed paper, ln F = c1 theta + c2 (c1 the slope in 1/rad, c2 the intercept), "
    "by OLS on samples with F > 0 and theta > 0; theta is theta_con, or theta_tip with --angle theta_tip (for "
    "trackers that give the tip angle only). Standard errors are cluster-robust (by trial) when a speed has >= 5 "
    "trials, else autocorrelation-corrected (--se). Beside Eq. (9)'s band, a recommended bound is chosen among "
    "low-order forms of ln F by its coverage of left-out trials (leave one trial out; within 95 +- 3 %, then the "
    "narrowest), and a lack-of-fit test says whether ln F is a straight line in theta. Writes bounds.json "
    "(by_speed: c1, c2, their errors, heldout_coverage, heldout_coverage_eq9, the recommended form, the "
    "lack-of-fit test, ...), bounds_bands.csv and the figures force_vs_theta_con.png (with the simulated force), "
    "log_force.png and bounds.png to --out. A speed with a single trial is fitted but its coverage cannot be "
    "measured: the outputs are written and the command exits 2, naming the speed."
)


# --------------------------------------------------------------------------- sync


def configure_sync(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani sync``."""
    p.add_argument("--manifest", required=True, metavar="M", help="manifest CSV (docs/file-formats.md)")
    p.add_argument("--out", required=True, metavar="FILE", help="synced table to write (CSV)")
    p.add_argument("--angles-dir", metavar="DIR",
                   help="folder of <trial>.angles.csv for trials without an angles column (default: the manifest's folder)")
    p.add_argument("--t0", choices=("auto", "manifest", "estimate"), default="auto",
                   help="offset source: manifest when given else estimate (auto, default), always the manifest "
                        "(blank = 0), or always estimate")
    p.add_argument("--signal", choices=("auto", "depth", "force"), default="auto",
                   help="what the estimate aligns: depth_mm vs theta_tip, force_g vs theta_con, or auto (depth if logged)")
    p.add_argument("--max-gap-frames", type=positive_float, default=3.0, metavar="F",
                   help="do not interpolate angles across more than F frame periods between measured frames (default 3)")
    p.add_argument("--format", metavar="FILE", dest="log_format",
                   help="log format file (TOML) saying how the lab's own force, depth and angle logs are read, for "
                        "the manifest rows whose 'format' cell is blank (default: logs in tympani's own form)")


def run_sync(args: argparse.Namespace) -> int:
    """Run ``tympani sync``; 0 all trials synced, 2 some failed on bad input, 1 on a bug."""
    from tympani.pipeline.force.sync import SyncConfig, sync_manifest, write_sync
    from tympani.vision.errors import InputError

    if args.max_gap_frames < 1:
        raise InputError("--max-gap-frames", "must be >= 1")
    cfg = SyncConfig(t0=args.t0, signal=args.signal, max_gap_frames=args.max_gap_frames)
    result = sync_manifest(args.manifest, cfg=cfg, angles_dir=args.angles_dir, log_format=args.log_format)
    table_path, report = write_sync(result, args.out, cfg=cfg)
    for t in result.failed:
        print(f"tympani: {t.error}", file=sys.stderr)
    ok = [t for t in result.trials if t.status == "ok"]
    n_warn = sum(len(t.warnings) for t in ok)
    print(f"sync: {len(ok)} trial(s) synced, {len(result.failed)} failed; {len(result.table)} rows"
          + (f" -> {table_path}" if table_path else " (no table written)") + f"; report {report}"
          + (f"; {n_warn} warning(s) in the report" if n_warn else ""))
    if not args.quiet:
        for t in ok:
            unc = f" ± {t.uncertainty_s:.2g} s" if t.uncertainty_s else ""
            print(f"  {t.trial}: video_t0_s {t.offset_s:.4g} s{unc} ({t.method}); "
                  f"{t.n_with_angles}/{t.n_samples} samples with angles")
            if t.depth is not None:
                m = t.depth["motion"]
                stop = (f"stops at {m.stop_s:.4g} s ± {m.stop_uncertainty_s:.2g} s" if m.stopped
                        else f"still moves when its log ends at {m.stop_s:.4g} s")
                print(f"    depth log: the stage starts at {m.start_s:.4g} s ± {m.start_uncertainty_s:.2g} s and {stop}; "
                      f"{m.travel_mm:.4g} mm at {m.speed_mm_s:.3g} mm/s")
            for warning in t.warnings:
                print(f"    warning: {warning}")
    if any(t.error_kind == "error" for t in result.failed):
        return 1
    return 2 if result.failed else 0


# --------------------------------------------------------------------------- bounds


def configure_bounds(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani bounds``."""
    p.add_argument("synced", metavar="SYNCED", help="synced table (CSV, from 'tympani sync')")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--level", type=fraction, default=0.95, help="band coverage (default 0.95)")
    p.add_argument("--angle", choices=("theta_con", "theta_tip"), default="theta_con",
                   help="the angle of Eq. (8) (default theta_con; theta_tip for tip-only angle tracks)")
    p.add_argument("--se", choices=("auto", "cluster", "effective_n", "ols"), default="auto",
                   help="standard errors: cluster-robust by trial, autocorrelation-corrected (effective_n), plain "
                        "OLS, or auto (cluster with >= 5 trials per speed, else effective_n; default)")
    sim = p.add_mutually_exclusive_group()
    sim.add_argument("--simulated", metavar="CSV", help="simulation table to overlay (from 'tympani simulate --out')")
    sim.add_argument("--scenario", default="S4", metavar="S",
                     help="scenario simulated with the force model for the overlay (S1..S4, default S4; 'none': no overlay)")
    p.add_argument("--no-figures", action="store_true", help="write no PNG figures")


def _simulated(args: argparse.Namespace):
    """The overlay: a simulation table, a callable over speeds, or None."""
    if args.simulated:
        import pandas as pd

        from tympani.pipeline.force.forcelog import read_csv_columns
        from tympani.pipeline.force.sync import SYNC_NUMBER_COLUMNS
        from tympani.vision.errors import InputError

        path = Path(args.simulated)
        if not path.is_file():
            raise InputError(path, "no such simulation table")
        read = read_csv_columns(path, lambda header: {c: "number" if c in SYNC_NUMBER_COLUMNS else "text"
                                                      for c in header.columns})
        table = pd.DataFrame(read.values)
        missing = [c for c in ("speed_mm_s", "theta_con", "force_g") if c not in table.columns]
        if missing:
            raise InputError(path, f"missing column(s) {', '.join(missing)} of a simulation table")
        return table
    if str(args.scenario).lower() == "none":
        return None
    try:
        from tympani.pipeline.model.paper import SCENARIOS, simulate
    except ImportError:  # pragma: no cover - the model is part of the package
        return None
    name = str(args.scenario).upper()
    if name not in SCENARIOS:
        from tympani.vision.errors import InputError

        raise InputError("--scenario", f"unknown scenario {args.scenario!r}; choose from {', '.join(SCENARIOS)} or none")
    return lambda speeds: simulate(name, speeds)


def run_bounds(args: argparse.Namespace) -> int:
    """Run ``tympani bounds``; 0 on success, 2 on bad input (no speed could be fitted)."""
    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.model.bounds import BoundsConfig, check_synced, fit_bounds, form_label, single_trial_speeds
    from tympani.pipeline.model.bounds_output import write_bounds
    from tympani.vision.errors import InputError

    cfg = BoundsConfig(level=args.level, se=args.se, angle=args.angle)
    synced = check_synced(read_synced(args.synced), args.synced)
    try:
        fits, skipped = fit_bounds(synced, cfg)
    except InputError as exc:
        raise InputError(args.synced, exc.problem) from None
    if not fits:
        reasons = "; ".join(f"{s['speed_mm_s']:g} mm/s: {s['reason']}" for s in skipped)
        raise InputError(args.synced, f"no speed could be fitted ({reasons})")
    simulated = None if args.no_figures or args.angle != "theta_con" else _simulated(args)
    figures = []
    if not args.no_figures:
        from tympani.pipeline.report.figures import write_figures

        figures = [p.name for p in write_figures(synced, fits, args.out, simulated=simulated)]
    paths = write_bounds(fits, skipped, args.out, cfg=cfg, input_path=args.synced, figures=figures)
    print(f"bounds: {len(fits)} speed(s) fitted" + (f", {len(skipped)} skipped" if skipped else "")
          + f" -> {paths['json']}, {paths['bands'].name}" + (f", {', '.join(figures)}" if figures else ""))
    if not args.quiet:
        for f in fits:
            cov = ("coverage undefined" if f.heldout_coverage is None else
                   f"held-out coverage {100 * f.heldout_coverage:.1f} % ({form_label(f.recommended.form)}), "
                   f"Eq. (9) {100 * f.heldout_coverage_eq9:.1f} %" if f.heldout_coverage_eq9 is not None else "")
            lof = "" if f.lack_of_fit is None else f"; {f.lack_of_fit.words()}"
            sign = "+" if f.c2 >= 0 else "-"
            print(f"  {f.speed_mm_s:g} mm/s: ln F = {f.c1:.3f} (±{f.c1_se:.2g}) {args.angle} {sign} {abs(f.c2):.3f} "
                  f"(±{f.c2_se:.2g}); n={f.n}, {f.n_trials} trial(s); {cov}{lof}")
        for s in skipped:
            print(f"  {s['speed_mm_s']:g} mm/s skipped: {s['reason']}")
    single = single_trial_speeds(fits)
    if single:
        raise InputError(args.synced, "held-out coverage is undefined at " + ", ".join(f"{v:g}" for v in single)
                         + " mm/s (one trial each; bounds written without it)")
    return 0

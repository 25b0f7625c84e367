"""The ``tympani diagnose`` and ``tympani evaluate-diagnosis`` commands (registered in
:mod:`tympani.pipeline.cli`).

Importing this module is cheap (argparse only); the diagnosis loads when a command runs.
"""

from __future__ import annotations

import argparse

from tympani.pipeline.cli.argtypes import UsageError, positive_int

__all__ = [
    "configure_diagnose",
    "run_diagnose",
    "configure_evaluate",
    "run_evaluate",
    "DIAGNOSE_HELP",
    "DIAGNOSE_DESCRIPTION",
    "EVALUATE_HELP",
    "EVALUATE_DESCRIPTION",
]

DIAGNOSE_HELP = "the sim-to-real diagnosis"
DIAGNOSE_DESCRIPTION = (
    "Diagnose the gap between a synced table and the seed paper's insertion-force model: is there a gap (lack of "
    "fit against the scatter between repeats), where (speed x theta_con x insertion phase), which unmodelled effect "
    "(hydrodynamic_lift, viscous_drag, capstan, sensor_lag, sensor_drift, pressure_profile) explains it (base, a "
    "control that re-identifies the friction law, and base + each effect, fitted on all speeds but one and scored "
    "on the one held out, with a bootstrap over trials), and how much (held-out RMSE before/after, share of the "
    "peak-force drop). Writes diagnosis.json, diagnosis.md with figures and diagnosis_rows.csv to --out. Needs at "
    "least 3 speeds with at least 2 trials each. Verdicts: identified, ambiguous (with the experiment that would "
    "split the tied effects), no_gap. docs/diagnosis.md says how it decides."
)
EVALUATE_HELP = "blind trials of the diagnosis on generated data with hidden effects"
EVALUATE_DESCRIPTION = (
    "Generate --cases experiments with random hidden effects (and none), strengths and noise levels, diagnose each "
    "without the label, and print per generator family the confusion matrix (with ambiguous and no_gap columns), "
    "the precision of 'identified', how often the truth is among an ambiguous answer's effects, the share of useful "
    "answers where the effect is visible above the noise, the confident-wrong and false-positive rates and the "
    "held-out shrinkage. Family A is the project's first generator; family B was written independently from a "
    "physics brief, with other functional forms. The diagnosis' thresholds were set on family A only: family B is "
    "the honest check. Cases are balanced over the effects and reproducible from --seed whatever --workers is."
)


def configure_diagnose(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani diagnose``."""
    p.add_argument("synced", metavar="SYNCED", help="synced table (CSV, from 'tympani sync'; docs/file-formats.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap and the random starts (default 0)")
    p.add_argument("--bootstrap", type=positive_int, default=1000, metavar="B",
                   help="bootstrap resamples of trials (default 1000)")
    p.add_argument("--rows-per-trial", type=positive_int, default=56, metavar="N",
                   help="rows per trial used for fitting, evenly in time (default 56)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures of the report")


def run_diagnose(args: argparse.Namespace) -> int:
    """Run ``tympani diagnose``."""
    from tympani.pipeline.diagnosis.analysis import diagnose
    from tympani.pipeline.diagnosis.config import DiagnosisConfig
    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.diagnosis.report import summary_line, write_diagnosis

    table = read_synced(args.synced)
    config = DiagnosisConfig(seed=args.seed, bootstrap=args.bootstrap, rows_per_trial=args.rows_per_trial)
    diag = diagnose(table, config, source=args.synced)
    write_diagnosis(diag, args.out, source=args.synced, figures=not args.no_figures)
    print(summary_line(diag))
    print(f"where: {diag.where.summary}")
    if diag.verdict == "ambiguous" and diag.experiments:
        best = diag.experiments[0]
        print(f"to split {', '.join(diag.decision.tied)}: {best.experiment} ({best.protocol})")
    print(f"-> {args.out}/diagnosis.json, diagnosis.md")
    return 0


def configure_evaluate(p: argparse.ArgumentParser) -> None:
    """Arguments of ``tympani evaluate-diagnosis``."""
    p.add_argument("--cases", type=positive_int, default=70, metavar="N",
                   help="number of generated cases per family (default 70)")
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation (default 0)")
    p.add_argument("--workers", type=positive_int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--out", metavar="DIR", help="also write each family's cases.csv, summary.json and summary.txt to "
                                                "DIR/family_A/, DIR/family_B/")
    p.add_argument("--trials", type=positive_int, default=10, metavar="N", help="repeats per speed (default 10)")
    p.add_argument("--family", default="A,B", metavar="F,..",
                   help="generator families of the data, comma-separated: A (the project's first generator) and B "
                        "(written independently from a physics brief); default A,B, each reported on its own")


def run_evaluate(args: argparse.Namespace) -> int:
    """Run ``tympani evaluate-diagnosis``."""
    import time

    from tympani.pipeline.diagnosis.evaluation import EvalConfig, evaluate, format_evaluation, summarise

    from tympani.pipeline.diagnosis.evaluation import FAMILIES

    families = [f.strip().upper() for f in str(args.family).split(",") if f.strip()]
    unknown = [f for f in families if f not in FAMILIES]
    if not families or unknown:
        raise UsageError(f"tympani evaluate-diagnosis: unknown --family {', '.join(unknown) or repr(args.family)}; "
                         f"choose from {', '.join(FAMILIES)}")
    errors = 0
    for family in families:
        t0 = time.perf_counter()
        config = EvalConfig(trials=args.trials, family=family)
        results = evaluate(args.cases, args.seed, workers=args.workers, config=config, progress=not args.quiet)
        summary = summarise(results)
        text = f"family {family}\n" + format_evaluation(summary)
        print(text)
        print(f"wall time {time.perf_counter() - t0:.0f} s with {args.workers} worker(s)\n")
        errors += summary["errors"]
        if args.out:
            from pathlib import Path

            from tympani.pipeline.io import atomic_write_csv, atomic_write_json, atomic_write_text

            out = Path(args.out) / f"family_{family}"
            atomic_write_csv(out / "cases.csv", results[[c for c in results.columns if not c.startswith("_")]])
            atomic_write_text(out / "summary.txt", text + "\n")
            atomic_write_json(out / "summary.json", {k: (v.reset_index().to_dict("records") if hasattr(v, "to_dict")
                                                         else v) for k, v in summary.items()})
    return 0 if errors == 0 else 1

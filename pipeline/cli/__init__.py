"""The ``tympani`` command line (every command is described in ``docs/commands.md``).

Each subcommand is a :class:`Command` in :data:`COMMANDS`: a help line, a function that adds
its arguments to an ``argparse`` parser, and a function that runs it and returns the exit
status. To add a command, write ``_configure_x(parser)`` and ``_run_x(args) -> int`` (import
heavy modules inside ``_run_x``) and add ``"x": Command(...)`` to :data:`COMMANDS`.

Exit status: 0 success; 2 bad usage or bad input (``tympani: <one line>`` on stderr, no
traceback); 130 interrupted (outputs are written atomically, so nothing is left half written);
1 anything else (one line; ``--debug`` shows the traceback). A batch that finished with some
bad inputs exits 2 with the good ones written.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from tympani.pipeline.cli.argtypes import (UsageError, band_pair, diameter_pair, int_list, nonneg_float, nonneg_int, positive_float, positive_int, share,
                               speed_list)
from tympani.vision.errors import InputError, is_input_error

__all__ = ["Command", "COMMANDS", "build_parser", "main", "UsageError"]


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line and do not exit the interpreter."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


@dataclass(frozen=True)
class Command:
    """One subcommand.

    Parameters
    ----------
    help : str
        One line for ``tympani --help``.
    configure : callable
        ``configure(parser)`` adds the command's arguments.
    run : callable
        ``run(args) -> int`` does the work and returns the exit status.
    description : str
        Longer text for ``tympani CMD --help`` (default: ``help``).
    """

    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str = ""


# --------------------------------------------------------------------------- helpers


def _add_extract_options(parser: argparse.ArgumentParser, video_checks: bool = True) -> None:
    """The registration and measurement options; with ``video_checks`` also those of the checks
    run over a whole video's angles (glitches, kinematics, a video mostly unread)."""
    group = parser.add_argument_group("registration")
    group.add_argument("--recheck-every", type=nonneg_int, default=150, metavar="N",
                       help="check the registration every N frames, re-register if the camera moved (0: never; default 150)")
    group.add_argument("--register-frames", type=positive_int, default=5, metavar="N",
                       help="frames used for registration (default 5)")
    if video_checks:
        _add_video_check_options(group)
    group.add_argument("--array-diameters", type=diameter_pair, default=None, metavar="TIP,BASE",
                       help="the electrode array's diameters in mm at its tip and its base (default 0.6,1.2)")
    group.add_argument("--array-first-band", type=band_pair, default=None, metavar="FROM,LENGTH",
                       help="the array's first metal band: its distance from the tip and its length in mm (default "
                            "0.3,0.4); the tip may lie up to its far end and 0.3 mm past the array's last measured "
                            "edges")
    group.add_argument("--calibration", metavar="JSON",
                       help="the camera's lens calibration (camera_matrix, dist_coeffs, image_size: OpenCV's model); "
                            "the lens is taken out of registration, checks and measurement")


def _add_video_check_options(group: Any) -> None:
    group.add_argument("--glitch-rad", type=nonneg_float, default=0.25, metavar="RAD",
                       help="mark a frame not ok when an angle lies this far (rad) from the running median of its "
                            "measured neighbours (0: never; default 0.25)")
    group.add_argument("--kinematics-tol", type=nonneg_float, default=0.5, metavar="MM",
                       help="mark frames not ok, in runs as well as alone, whose insertion depth lies this far (mm) "
                            "from the video's constant-speed insertion (0: never; default 0.5)")
    group.add_argument("--excursion-rad", type=nonneg_float, default=0.5, metavar="RAD",
                       help="mark a run of frames not ok whose theta_bot steps this far (rad) away from the frames "
                            "around it and back, and the frames whose contact arc is this much shorter than the "
                            "frames' before them (0: never; default 0.5)")
    group.add_argument("--lone-reach", type=nonneg_int, default=3, metavar="N",
                       help="mark a measured frame not ok when no other frame within N frames either side is "
                            "measured: nothing checks it (0: never; default 3)")
    group.add_argument("--sparse-share", type=share, default=0.5, metavar="S",
                       help="mark all frames of a video not ok when no more than this share of the frames between "
                            "its first and last measured one is measured, or when no more than 4 frames and this "
                            "share of all its frames are (0: never; default 0.5)")


def _extract_config(args: argparse.Namespace):
    from tympani.pipeline.extract.config import ExtractConfig
    from tympani.vision.frames import LensCalibration
    from tympani.vision.geometry import DEFAULT_ARRAY

    calibration = LensCalibration.from_json(args.calibration) if args.calibration else None
    array = DEFAULT_ARRAY if args.array_diameters is None else replace(
        DEFAULT_ARRAY, tip_diameter_mm=args.array_diameters[0], base_diameter_mm=args.array_diameters[1])
    if args.array_first_band is not None:
        start, length = args.array_first_band
        array = replace(array, first_band_mm=start, band_length_mm=length)
    checks = dict(glitch_rad=args.glitch_rad, kinematics_tol_mm=args.kinematics_tol,
                  excursion_rad=args.excursion_rad, lone_reach=args.lone_reach,
                  sparse_share=args.sparse_share) if hasattr(args, "glitch_rad") else {}
    return ExtractConfig(recheck_every=args.recheck_every, register_frames=args.register_frames,
                         calibration=calibration, array=array, **checks)


def _vision_steps(args: argparse.Namespace):
    """The vision functions :func:`main` was given (``args.steps``), else the real ones."""
    from tympani.pipeline.extract.config import VisionSteps

    steps = getattr(args, "steps", None)
    return steps if steps is not None else VisionSteps()


# --------------------------------------------------------------------------- extract


def _configure_extract(p: argparse.ArgumentParser) -> None:
    p.add_argument("videos", nargs="*", metavar="VIDEO", help="video files or folders of frames")
    p.add_argument("--manifest", metavar="M",
                   help="manifest CSV (docs/file-formats.md); its rows with a video are extracted")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--workers", type=positive_int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask distributed cluster instead (e.g. tcp://host:8786); its workers need tympani "
                        "and the same paths to the videos and --out (pip install 'tympani[distributed]')")
    p.add_argument("--fps", type=positive_float, metavar="F",
                   help="frame rate (frames/s): needed for folders of frames; overrides a video's own clock")
    p.add_argument("--overwrite", action="store_true", help="redo videos whose outputs exist (default: skip them)")
    _add_extract_options(p)


def _dask_client(address: str, command: str = "extract"):
    """A ``dask.distributed.Client`` connected to ``address``.

    Raises
    ------
    UsageError
        Dask's distributed scheduler is not installed (exit 2).
    InputError
        The scheduler cannot be reached within Dask's connect timeout
        (``distributed.comm.timeouts.connect``), or the address is malformed (exit 2).
    """
    try:
        from distributed import Client
    except ImportError:
        raise UsageError(f"tympani {command}: --scheduler needs Dask's distributed scheduler, which is not installed "
                         "(pip install 'tympani[distributed]')") from None
    try:
        return Client(address, set_as_default=False)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(address, f"cannot connect to the Dask scheduler ({reason})") from exc


@contextmanager
def _scheduler(args: argparse.Namespace, command: str):
    """The Dask client of ``--scheduler`` (closed afterwards), or None to run on ``--workers``.

    Raises
    ------
    UsageError
        Both ``--workers`` and ``--scheduler`` given, or Dask not installed.
    """
    if not args.scheduler:
        yield None
        return
    if args.workers != 1:
        raise UsageError(f"tympani {command}: give --workers or --scheduler, not both "
                         f"(see 'tympani {command} --help')")
    client = _dask_client(args.scheduler, command)
    try:
        yield client
    finally:
        client.close()


def _run_extract(args: argparse.Namespace) -> int:
    from tympani.pipeline.extract.batch import extract_batch
    from tympani.pipeline.extract.manifest import read_manifest
    from tympani.pipeline.io import atomic_write_csv

    if bool(args.videos) == bool(args.manifest):
        raise UsageError("tympani extract: give either VIDEO... or --manifest M (see 'tympani extract --help')")
    if args.manifest:
        # missing files are reported per trial by the extraction (the others still run), and a
        # missing force log does not concern extract
        table = read_manifest(args.manifest, check_files=False)
        items = table[table["video"].notna()]
        if items.empty:
            raise InputError(args.manifest, "no trial has a video to extract")
    else:
        items = list(args.videos)
    cfg = _extract_config(args)
    with _scheduler(args, "extract") as client:
        summary = extract_batch(items, args.out, cfg, workers=args.workers, executor=client,
                                overwrite=args.overwrite, progress=not args.quiet, fps=args.fps,
                                steps=_vision_steps(args))
    for _, row in summary[summary["status"] == "failed"].iterrows():
        print(f"tympani: {row['error']}", file=sys.stderr)
    for _, row in summary[(summary["status"] == "ok") & (summary["warnings"].fillna("") != "")].iterrows():
        print(f"tympani: warning: {row['path']}: {' '.join(str(row['warnings']).split())}", file=sys.stderr)
    sparse = summary[(summary["status"] == "ok") & (2 * summary["n_ok"] < summary["n_frames"])]
    for _, row in sparse.iterrows():
        print(f"tympani: warning: {row['path']}: {int(row['n_ok'])} of {int(row['n_frames'])} frames measured; "
              f"frames refused: {row['refused']}", file=sys.stderr)
    if len(sparse):
        print("tympani: hint: 'tympani annotate VIDEO --out DIR' draws what was measured on a video's frames; "
              "the angles table's reason column says why each frame was refused", file=sys.stderr)
    atomic_write_csv(os.path.join(args.out, "extract_summary.csv"), summary)  # after the lines above: it may fail too
    counts = summary["status"].value_counts()
    print(
        f"extract: {counts.get('ok', 0)} ok, {counts.get('skipped', 0)} skipped, {counts.get('failed', 0)} failed;"
        f" {int(summary['n_ok'].fillna(0).sum())} of {int(summary['n_frames'].fillna(0).sum())} frames measured -> {args.out}"
    )
    if (summary["error_kind"] == "error").any():
        return 1
    return 2 if (summary["status"] == "failed").any() else 0


# --------------------------------------------------------------------------- annotate


def _configure_annotate(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", metavar="VIDEO", help="video file or folder of frames")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--frames", type=int_list, metavar="0,10,20", help="frames to draw")
    which.add_argument("--every", type=positive_int, metavar="N", help="draw every N-th frame (default: ~10 frames)")
    p.add_argument("--mp4", action="store_true", help="also write an annotated mp4 of every frame")
    p.add_argument("--label", action="append", nargs="+", metavar="FRAME tip=X,Y bot=X,Y", default=[],
                   help="manual label of a frame in pixels (repeatable); compared with the measurement")
    p.add_argument("--labels", metavar="CSV", help="labels CSV: frame,tip_x_px,tip_y_px,bot_x_px,bot_y_px")
    p.add_argument("--fps", type=positive_float, metavar="F", help="frame rate (frames/s) for folders of frames")
    p.add_argument("--trial", metavar="NAME", help="trial name for the output files (default: file stem)")
    _add_extract_options(p, video_checks=False)  # each frame's own measurement: no checks over the video


def _run_annotate(args: argparse.Namespace) -> int:
    import pandas as pd

    from tympani.pipeline.extract.annotate import annotate_video, labels_frame, parse_label, read_labels, summarize_comparison

    tables = []
    if args.labels:
        tables.append(read_labels(args.labels))
    if args.label:
        tables.append(labels_frame(parse_label(tokens) for tokens in args.label))
    labels = labels_frame(pd.concat(tables).to_dict("records")) if tables else None
    result = annotate_video(args.video, args.out, _extract_config(args), frames=args.frames, every=args.every,
                            mp4=args.mp4, labels=labels, fps=args.fps, trial=args.trial, progress=not args.quiet,
                            steps=_vision_steps(args))
    for warning in result.warnings:
        print(f"tympani: warning: {warning}", file=sys.stderr)
    print(f"annotate: {len(result.images)} frame(s) drawn" + (f", video {result.video}" if result.video else "")
          + f" -> {args.out}")
    if result.comparison is not None:
        print(summarize_comparison(result.comparison))
    return 0


# --------------------------------------------------------------------------- bench


def _configure_bench(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frames", type=positive_int, default=None, metavar="N",
                   help="frames of the rendered video (default 200; 30 with --quick)")
    p.add_argument("--size", type=_size, default=None, metavar="WxH",
                   help="size (px) of the rendered video, e.g. 1280x720 (default 640x480): the same phantom "
                        "in a larger frame")
    p.add_argument("--seed", type=int, default=0, help="render and dataset seed (default 0)")
    p.add_argument("--noise", type=nonneg_float, default=None, metavar="SIGMA",
                   help="sensor noise (grey levels) of the rendered video (default 2, a camera's; 0: noise-free, "
                        "which decodes unusually fast)")
    p.add_argument("--video", metavar="VIDEO", help="time this video instead of rendering one")
    p.add_argument("--fps", type=positive_float, metavar="F", help="frame rate (frames/s) for a folder of frames")
    p.add_argument("--quick", action="store_true",
                   help="small sizes for a smoke test: 30 frames, 2 trials a speed, 1 and 2 workers on 2 videos")
    p.add_argument("--long-factor", type=positive_int, default=10, metavar="K",
                   help="the memory figure's long video has K times the frames (default 10)")
    p.add_argument("--trials", type=positive_int, default=None, metavar="N",
                   help="trials per speed of the diagnosis dataset (5 speeds; default 10, 2 with --quick)")
    p.add_argument("--workers", default=None, metavar="N,..",
                   help="worker counts of the batch figure (default 1,2,4; 1,2 with --quick)")
    p.add_argument("--batch-videos", type=positive_int, default=None, metavar="N",
                   help="videos per batch of the workers figure (default 8; 2 with --quick)")
    p.add_argument("--skip", default="", metavar="SECTION,..",
                   help="sections to leave out: memory, diagnosis, workers, logs")
    p.add_argument("--repeats", type=positive_int, default=None, metavar="N",
                   help="times decoding and extraction are each timed, alternately; the fastest of each "
                        "is compared, and each round's own ratio listed with the warm rounds' median (default 5; 2 with --quick)")


def _configure_evaluate_extraction(p: argparse.ArgumentParser) -> None:
    p.add_argument("--videos", type=positive_int, default=12, metavar="N", help="number of videos (default 12)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first video; the others follow (default 0)")
    p.add_argument("--nuisance", choices=("clean", "random", "harsh"), default="random",
                   help="clean: none; random: each nuisance off with probability 0.3, else of random strength "
                        "(default); harsh: every nuisance at strength 0.3-1, bubbles always, doubled walls often")
    p.add_argument("--frames", type=positive_int, default=30, metavar="N", help="frames per video (default 30)")
    p.add_argument("--workers", type=positive_int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--renderer", default="", metavar="FILE.py",
                   help="another renderer, a Python file defining NUISANCE_KEYS and render_video(path, seed, *, "
                        "n_frames, size, px_per_mm, nuisance) -> (truth table, info with 'pose'); see "
                        "docs/renderer-c.md (default: renderer C)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for the videos, their truth, per-frame scores, videos.csv and summary.json")


def _run_evaluate_extraction(args: argparse.Namespace) -> int:
    from tympani.pipeline.extract.evaluation import (
        EvaluationConfig,
        evaluate_extraction,
        format_summary,
        load_renderer,
        summarise,
    )
    from tympani.pipeline.io import atomic_write_csv, atomic_write_json

    load_renderer(args.renderer)  # a renderer that does not load is refused before any work
    cfg = EvaluationConfig(nuisance=args.nuisance, frames=args.frames, renderer=args.renderer)
    results = evaluate_extraction(range(args.seed, args.seed + args.videos), args.out, cfg, workers=args.workers)
    summary = summarise(results)
    atomic_write_csv(Path(args.out) / "videos.csv", results)
    atomic_write_json(Path(args.out) / "summary.json", {"config": cfg, **summary})
    print(format_summary(summary))
    return 0


def _run_bench(args: argparse.Namespace) -> int:
    from tympani.pipeline.devtools.bench import SECTIONS, BenchConfig, format_bench, run_bench

    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    if skip - set(SECTIONS):
        raise UsageError(f"tympani bench: unknown --skip section(s) {', '.join(sorted(skip - set(SECTIONS)))}; "
                         f"choose from {', '.join(SECTIONS)}")
    try:
        workers = None if args.workers is None else tuple(int(w) for w in args.workers.split(","))
    except ValueError:
        raise UsageError(f"tympani bench: --workers must be integers separated by commas, not {args.workers!r}") from None
    if workers is not None and (not workers or min(workers) < 1):
        raise UsageError("tympani bench: --workers counts must be >= 1")
    config = BenchConfig.quick() if args.quick else BenchConfig()
    changes = {"n_frames": args.frames, "size": args.size, "noise_sigma": args.noise, "trials": args.trials,
               "workers": workers, "batch_videos": args.batch_videos, "repeats": args.repeats}
    try:
        config = replace(config, seed=args.seed, long_factor=args.long_factor,
                         sections=tuple(s for s in SECTIONS if s not in skip),
                         **{k: v for k, v in changes.items() if v is not None})
    except ValueError as exc:
        raise UsageError(f"tympani bench: {exc}") from None
    result = run_bench(video=args.video, fps=args.fps, config=config, steps=_vision_steps(args),
                       log=lambda line: print(f"bench: {line}", file=sys.stderr, flush=True))
    print(format_bench(result))
    return 0


# --------------------------------------------------------------------------- simulate, fit (pipeline/cli/force.py)

def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT") from None
    if w < 320 or h < 240:
        raise argparse.ArgumentTypeError(f"{text!r}: frames must be at least 320x240")
    return w, h


def _configure_render(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--speeds", type=speed_list, default=(0.5, 1.5, 3.0, 5.0, 7.5),
                   help="insertion speeds, mm/s (default 0.5,1.5,3,5,7.5)")
    p.add_argument("--trials", type=positive_int, default=2, help="repeats per speed (default 2)")
    p.add_argument("--seed", type=int, default=0, help="seed of everything random (default 0)")
    p.add_argument("--depth", type=positive_float, default=15.0, help="final insertion depth, mm (default 15)")
    p.add_argument("--fps", type=positive_float, default=30.0, help="frame rate, 1/s (default 30)")
    p.add_argument("--max-frames", type=positive_int, default=120,
                   help="cap on frames per video (a longer insertion is filmed at a lower frame rate; default 120)")
    p.add_argument("--size", type=_size, default=(640, 480), help="frame size WIDTHxHEIGHT, px (default 640x480)")
    p.add_argument("--nuisance", type=float, default=0.3,
                   help="nuisance strength, 0 (clean) to 1 (heavy); default 0.3")
    p.add_argument("--png", action="store_true", help="write PNG folders instead of mp4 videos")
    hidden = p.add_argument_group("hidden effect (docs/diagnosis.md; written to truth/effect.json only)")
    hidden.add_argument("--effect", default="none", metavar="NAME",
                        help="none (default), hydrodynamic_lift, viscous_drag, capstan, sensor_lag, sensor_drift "
                             "or pressure_profile")
    hidden.add_argument("--strength", type=float, default=1.0, metavar="S",
                        help="size of the effect: 0 absent, 1 typical (default 1)")
    hidden.add_argument("--dwell", type=float, default=None, metavar="S",
                        help="time logged (and filmed) after the robot stops, s (default 1 with --no-video or "
                             "--effect, else 0)")
    hidden.add_argument("--no-video", action="store_true",
                        help="force logs and angles tables only (no videos; much faster); --fps is then the "
                             "angles tables' frame rate")
    hidden.add_argument("--rate", type=positive_float, default=None, metavar="HZ",
                        help="force sampling rate, 1/s (default 50 with --no-video, 100 with videos)")


def _run_render(args: argparse.Namespace) -> int:
    from tympani.pipeline.synthetic.experiment import ExperimentConfig, render_experiment
    from tympani.pipeline.synthetic.family_a import hidden_effect_names

    if not 0.0 <= args.nuisance <= 1.0:
        raise UsageError(f"tympani render: --nuisance must be between 0 and 1, not {args.nuisance}")
    names = hidden_effect_names()
    effect = None if args.effect.lower() in ("none", "null") else args.effect
    if effect is not None and effect not in names:
        raise UsageError(f"tympani render: unknown --effect {args.effect!r}; choose from none, {', '.join(names)}")
    dwell = args.dwell if args.dwell is not None else (1.0 if args.no_video or effect is not None else 0.0)
    if not (0.0 <= args.strength < float("inf")) or not (0.0 <= dwell < float("inf")):
        raise UsageError("tympani render: --strength and --dwell must be non-negative numbers")
    if args.no_video:
        import numpy as np

        from tympani.pipeline.synthetic.family_a import synthetic_dataset, write_experiment

        synced, truth = synthetic_dataset(np.random.default_rng(args.seed), effect, strength=args.strength,
                                          speeds_mm_s=args.speeds, trials=args.trials, depth_mm=args.depth,
                                          rate_hz=args.rate or 50.0, dwell_s=dwell, angles_fps=args.fps)
        manifest = write_experiment(args.out, synced, truth)
        print(f"wrote {len(manifest)} trials to {args.out} (manifest.csv, angles/, force/, truth/); hidden effect "
              f"{truth.effect or 'none'}, noiseless gap {truth.gap_rms_g:.3g} g RMS vs noise {truth.noise_rms_g:.3g} g")
        return 0
    cfg = ExperimentConfig(speeds_mm_s=args.speeds, trials=args.trials, depth_mm=args.depth, fps=args.fps,
                           max_frames=args.max_frames, width=args.size[0], height=args.size[1],
                           nuisance=args.nuisance, png=args.png, dwell_s=dwell, effect=effect,
                           strength=args.strength)
    if args.rate:
        cfg = replace(cfg, sensor=replace(cfg.sensor, rate_hz=args.rate))
    manifest = render_experiment(args.out, cfg, seed=args.seed)
    print(f"rendered {len(manifest)} trials to {args.out} (manifest.csv, videos/, force/, truth/)")
    return 0


def _configure_run(p: argparse.ArgumentParser) -> None:
    p.add_argument("--manifest", required=True, metavar="M", help="manifest CSV (docs/file-formats.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (report.html and every table)")
    p.add_argument("--workers", type=positive_int, default=1, metavar="N", help="processes for the extraction (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="extract on a Dask distributed cluster instead (as 'tympani extract --scheduler')")
    p.add_argument("--fps", type=positive_float, metavar="F",
                   help="frame rate (frames/s) for videos whose manifest row gives none (folders of frames)")
    p.add_argument("--scenario", default="S4", metavar="S",
                   help="scenario simulated for the force-vs-theta_con overlay (S1..S4, default S4; 'none': no overlay)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the fit's random starts and the diagnosis' bootstrap (default 0)")
    p.add_argument("--bootstrap", type=positive_int, default=1000, metavar="B",
                   help="bootstrap resamples of trials in the diagnosis (default 1000)")
    p.add_argument("--overwrite", action="store_true", help="redo every stage (default: reuse up-to-date outputs)")
    p.add_argument("--format", metavar="FILE", dest="log_format",
                   help="log format file (TOML) for the lab's own force, depth and angle logs, for the manifest rows "
                        "whose 'format' cell is blank (as 'tympani sync --format')")
    _add_extract_options(p)


def _run_config(args: argparse.Namespace, *, workers: int | None = None):
    from tympani.pipeline.run import RunConfig

    if str(args.scenario).lower() != "none" and str(args.scenario).upper() not in ("S1", "S2", "S3", "S4"):
        raise UsageError(f"tympani {args.command}: unknown --scenario {args.scenario!r}; choose from S1..S4 or none")
    base = RunConfig()
    return RunConfig(
        workers=workers if workers is not None else args.workers, overwrite=args.overwrite, progress=not args.quiet,
        extract=_extract_config(args), fit=replace(base.fit, seed=args.seed),
        diagnosis=replace(base.diagnosis, seed=args.seed, bootstrap=args.bootstrap),
        scenario=None if str(args.scenario).lower() == "none" else str(args.scenario).upper(),
        fps=getattr(args, "fps", None), log_format=getattr(args, "log_format", None),
    )


def _print_run(result) -> None:
    for line in result.errors:
        print(f"tympani: {line}", file=sys.stderr)
    for name, rec in result.stages.items():
        print(f"  {name:<9} {rec.status:<8} {rec.seconds:6.1f} s  {rec.message}")
    report = f"report {result.report}" if result.report else "no report"
    print(f"run: {int((result.trials['sync'] == 'ok').sum())} of {len(result.trials)} trial(s) analysed -> "
          f"{result.out}/ ({report})")


def _run_run(args: argparse.Namespace) -> int:
    from tympani.pipeline.run import run_pipeline

    command = ["tympani", "run", "--manifest", args.manifest, "--out", args.out, "--workers", str(args.workers),
               "--scenario", str(args.scenario), "--seed", str(args.seed), "--bootstrap", str(args.bootstrap),
               "--recheck-every", str(args.recheck_every), "--register-frames", str(args.register_frames),
               "--glitch-rad", str(args.glitch_rad), "--kinematics-tol", str(args.kinematics_tol),
               "--excursion-rad", str(args.excursion_rad), "--lone-reach", str(args.lone_reach),
               "--sparse-share", str(args.sparse_share)]
    command += ["--fps", str(args.fps)] if args.fps else []
    command += ["--format", args.log_format] if args.log_format else []
    command += ["--calibration", args.calibration] if args.calibration else []
    command += ["--array-diameters", ",".join(f"{d:g}" for d in args.array_diameters)] if args.array_diameters else []
    command += ["--array-first-band", ",".join(f"{d:g}" for d in args.array_first_band)] if args.array_first_band else []
    command += ["--overwrite"] if args.overwrite else []
    command += ["--scheduler", args.scheduler] if args.scheduler else []
    with _scheduler(args, "run") as client:
        result = run_pipeline(args.manifest, args.out, _run_config(args), command=command, executor=client)
    _print_run(result)
    return result.exit_status


def _configure_demo(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the synthetic experiment, the fit and the diagnosis (default 0)")
    p.add_argument("--workers", type=positive_int, default=2, help="processes for the extraction (default 2)")
    p.add_argument("--overwrite", action="store_true", help="redo every stage of the run (the rendering is kept)")


def _run_demo(args: argparse.Namespace) -> int:
    import time

    from tympani.pipeline.devtools.demo import run_demo

    t0 = time.perf_counter()
    result = run_demo(args.out, seed=args.seed, workers=args.workers, quiet=args.quiet, overwrite=args.overwrite)
    _print_run(result["run"])
    err = result["errors"]
    print("\nangles against the renderer's truth (|error|, rad):")
    print(err.to_string(index=False, float_format=lambda v: f"{v:.4f}"))
    print(f"\npooled median |error|: theta_tip {err.tip_median.median():.4f} rad, "
          f"theta_bot {err.bot_median.median():.4f} rad")
    drops = result["drops"]
    if drops is not None:
        print("\npeak force against the slowest speed (mean of the trials' peaks):")
        for r in drops.itertuples():
            paper = "" if r.paper_pct != r.paper_pct else f"; the paper's experiments {r.paper_pct:+.0f} %"
            print(f"  {r.speed_mm_s:g} mm/s: {r.peak_force_g:.3f} g, {r.change_pct:+.1f} %{paper}; "
                  f"the paper's model (S4) {r.model_pct:+.1f} %")
    print(f"outputs in {result['out']}/; report {result['report']}")
    print(f"demo: {time.perf_counter() - t0:.0f} s")
    return result["run"].exit_status


from tympani.pipeline.cli import force as _force_cli  # noqa: E402  (cheap: argparse only; the model loads on run)
from tympani.pipeline.cli import sync_bounds as _sync_bounds_cli  # noqa: E402  (cheap: argparse only)
from tympani.pipeline.cli import diagnosis as _diagnosis_cli  # noqa: E402  (cheap: argparse only)


# --------------------------------------------------------------------------- registry

#: The subcommands, by name.
COMMANDS: dict[str, Command] = {
    "run": Command(
        "all of it, and a report",
        _configure_run,
        _run_run,
        "Extract the angles of every video of the manifest, sync them with the force logs, fit the friction model, "
        "fit the safety bounds (Eq. 8-9), diagnose the sim-to-real gap, and write report.html (self-contained: "
        "figures embedded, tables inline) with the machine-readable outputs beside it in --out (angles/, "
        "synced.csv, fit/fit.json, bounds/bounds.json, diagnosis/diagnosis.json, trials.csv, run.json). A rerun "
        "reuses up-to-date outputs. A bad video or force log fails only its trial (one line on stderr; exit 2, "
        "the rest written); a diagnosis the data cannot support is explained in the report.",
    ),
    "demo": Command(
        "renders a small experiment and runs everything on it",
        _configure_demo,
        _run_demo,
        "Render 3 speeds x 5 trials of short (60-frame, 640x480) synthetic insertion videos with force logs and "
        "exact truth, run 'tympani run' on them (extract, sync, fit, bounds, diagnose, report.html) and compare the "
        "angles with the truth. The force falls with speed as in the seed paper's experiments (-24 % at 3 mm/s, "
        "-43 % at 7.5 mm/s) through an effect hidden from the analysis; the demo prints the measured drops beside "
        "the paper's. A rerun reuses what is already there.",
    ),
    "render": Command(
        "a synthetic experiment: videos, force logs, manifest, ground truth",
        _configure_render,
        _run_render,
        "Render synthetic insertion videos (one camera set-up, --trials repeats per speed) with force logs from "
        "the seed paper's insertion-force model (docs/paper.md), a manifest and the exact per-frame truth "
        "(truth/<trial>.csv, truth/pose.json). --effect hides an unmodelled effect (one of those the diagnosis "
        "looks for, docs/diagnosis.md, generated with forms unlike the diagnosis library's) in the "
        "force logs and records it in truth/effect.json; --no-video writes angles tables instead of videos.",
    ),
    "extract": Command(
        "angles tables (and registration JSON) per video",
        _configure_extract,
        _run_extract,
        "Extract per-frame contact angles from videos into <trial>.angles.csv, <trial>.registration.json and "
        "<trial>.provenance.json in --out. Videos whose outputs exist are skipped unless --overwrite. "
        "Exit 0 if every video succeeded, 2 if some inputs were bad (the others are still written), 1 on errors.",
    ),
    "annotate": Command(
        "frames with the registration, walls, array, tip, contact start and angles drawn on them",
        _configure_annotate,
        _run_annotate,
        "Draw the registered phantom and the measurement on chosen frames (PNG, optionally mp4), and compare "
        "manual labels (--label / --labels, pixels) with the automatic angles. Each frame shows its own "
        "measurement: the checks 'extract' runs over a whole video (glitches, kinematics) are not applied; where "
        "the walls show twice, the whole video is read first and the frames are drawn on the copy extract "
        "measures them on.",
    ),
    "bench": Command(
        "throughput, per-stage time and memory figures",
        _configure_bench,
        _run_bench,
        "Render a 640x480 video; time decoding against full extraction on one core (ratio, per-stage ms/frame); "
        "peak memory of a short and a 10x longer video in fresh processes; diagnosis time on a 5-speed synthetic "
        "dataset; batch throughput with 1, 2 and 4 workers; time and peak memory of reading a 1,000,000-row ROS "
        "force CSV. --quick for a smoke test.",
    ),
    "evaluate-extraction": Command(
        "scores the extraction on videos of an independently written renderer",
        _configure_evaluate_extraction,
        _run_evaluate_extraction,
        "Render --videos insertion videos with renderer C (written independently of tympani's vision; "
        "docs/renderer-c.md) or another renderer (--renderer), extract each as 'tympani extract' does and score every frame against the exact "
        "truth: the share of frames measured, the frames marked ok that are grossly wrong (theta_tip off by more "
        "than 0.3 rad or theta_con by more than 0.5 rad) among the contact frames, the median errors, and the "
        "registration's centre and scale errors. Writes videos.csv, summary.json and per-video files to --out.",
    ),
    "simulate": Command(_force_cli.SIMULATE_HELP, _force_cli.configure_simulate, _force_cli.run_simulate,
                        _force_cli.SIMULATE_DESCRIPTION),
    "paper": Command(_force_cli.PAPER_HELP, _force_cli.configure_paper, _force_cli.run_paper,
                     _force_cli.PAPER_DESCRIPTION),
    "fit": Command(_force_cli.FIT_HELP, _force_cli.configure_fit, _force_cli.run_fit, _force_cli.FIT_DESCRIPTION),
    "sync": Command(_sync_bounds_cli.SYNC_HELP, _sync_bounds_cli.configure_sync, _sync_bounds_cli.run_sync,
                    _sync_bounds_cli.SYNC_DESCRIPTION),
    "bounds": Command(_sync_bounds_cli.BOUNDS_HELP, _sync_bounds_cli.configure_bounds, _sync_bounds_cli.run_bounds,
                      _sync_bounds_cli.BOUNDS_DESCRIPTION),
    "diagnose": Command(_diagnosis_cli.DIAGNOSE_HELP, _diagnosis_cli.configure_diagnose, _diagnosis_cli.run_diagnose,
                        _diagnosis_cli.DIAGNOSE_DESCRIPTION),
    "evaluate-diagnosis": Command(_diagnosis_cli.EVALUATE_HELP, _diagnosis_cli.configure_evaluate,
                                  _diagnosis_cli.run_evaluate, _diagnosis_cli.EVALUATE_DESCRIPTION),
}


def build_parser() -> argparse.ArgumentParser:
    """The ``tympani`` argument parser with every command in :data:`COMMANDS`."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        tool_version = version("tympani")
    except PackageNotFoundError:
        tool_version = "0+unknown"
    parser = _Parser(prog="tympani", description="Contact angles and forces of cochlear-implant insertions "
                                                 "into planar phantoms. Every command has its own --help; "
                                                 "docs/commands.md in the source tree describes them all.")
    parser.add_argument("--version", action="version", version=f"tympani {tool_version}")
    parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks on errors")
    common.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, cmd in COMMANDS.items():
        p = sub.add_parser(name, help=cmd.help, description=cmd.description or cmd.help,
                           parents=[common])  # type: ignore[list-item]  # typeshed wants parents of the subparser class
        cmd.configure(p)
        p.set_defaults(_run=cmd.run)
    return parser


def main(argv: Sequence[str] | None = None, *, steps: Any = None) -> int:
    """Run ``tympani`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status.

    ``steps`` (a :class:`~tympani.pipeline.extract.config.VisionSteps`) are the vision functions that
    ``extract``, ``annotate`` and ``bench`` call; None: the real ones. The commands find them
    as ``args.steps``.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    if not debug:
        # keep FFmpeg's and OpenCV's chatter about damaged files off stderr (one-line errors)
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
        os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        args.steps = steps
        if getattr(args, "_run", None) is None:
            raise UsageError("tympani: no command given (see 'tympani --help')")
        return int(args._run(args))
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except UsageError as exc:
        print(" ".join(str(exc).split()), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tympani: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if debug:
            traceback.print_exc()
        if is_input_error(exc):
            print(f"tympani: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        text = " ".join(str(exc).split())
        hint = "" if debug else " (run with --debug for the traceback)"
        print(f"tympani: error: {type(exc).__name__}: {text}{hint}", file=sys.stderr)
        return 1


"""``tympani run``: extract → sync → fit → bounds → diagnose → one report.

:func:`run_pipeline` chains the stage functions of the other modules on one manifest and writes,
in the output folder (columns and keys: ``docs/file-formats.md``)::

    angles/<trial>.angles.csv    angles tables, registration and provenance JSON
    angles/extract_summary.csv   one row a video: status, frames, measured frames, error
    synced.csv                   the synced table; synced.sync.json: offsets, warnings
    fit/fit.json                 friction-model parameters ± s.e., residuals, provenance
    bounds/bounds.json           Eq. (8) per speed, bounds_bands.csv, the paper's figures
    diagnosis/diagnosis.json     the sim-to-real diagnosis, diagnosis.md, its figures
    trials.csv                   one row a manifest trial: what each stage made of it
    run.json                     stages (status, seconds, message), errors, provenance
    report.html                  the self-contained report (pipeline.report.page)

Resuming: extraction skips videos whose outputs exist (:func:`tympani.pipeline.extract.batch.extract_batch`);
every later stage is skipped when its outputs are newer than its inputs and it last ran with the
same settings (recorded in ``run.json``). ``overwrite=True`` redoes everything.

Failures: one bad video or force log fails only its trial (one line naming the file in
:attr:`RunResult.errors`); the others go on, and the run's exit status is 2. A diagnosis the data
cannot support (too few speeds or repeats) is not an error: the report says why.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import pandas as pd

from tympani.pipeline.model.data_needs import NotEnoughData, has_contact_angles
from tympani.vision.errors import InputError, is_input_error, one_line

__all__ = ["RunConfig", "RunResult", "StageRecord", "run_pipeline", "is_fresh", "RUN_JSON", "TRIALS_CSV"]

RUN_JSON = "run.json"
TRIALS_CSV = "trials.csv"

#: Stage names, in order.
STAGES = ("extract", "sync", "fit", "bounds", "diagnose", "report")


def _default_extract() -> Any:
    from tympani.pipeline.extract.config import ExtractConfig

    return ExtractConfig()


def _default_sync() -> Any:
    from tympani.pipeline.force.sync import SyncConfig

    return SyncConfig()


def _default_fit() -> Any:
    from tympani.pipeline.model.identify import FitOptions

    return FitOptions()


def _default_bounds() -> Any:
    from tympani.pipeline.model.bounds import BoundsConfig

    return BoundsConfig()


def _default_diagnosis() -> Any:
    from tympani.pipeline.diagnosis.config import DiagnosisConfig

    return DiagnosisConfig()


@dataclass(frozen=True)
class RunConfig:
    """Settings of :func:`run_pipeline`.

    Parameters
    ----------
    workers : int
        Processes for the extraction (1: in this process).
    overwrite : bool
        Redo every stage, even when its outputs are up to date.
    progress : bool
        Progress bars on stderr.
    extract : pipeline.extract.config.ExtractConfig
    sync : pipeline.force.sync.SyncConfig
    fit : pipeline.model.identify.FitOptions
    bounds : pipeline.model.bounds.BoundsConfig
    diagnosis : pipeline.diagnosis.config.DiagnosisConfig
    scenario : str or None
        Scenario of TABLE I simulated for the force-vs-theta_con overlay (``"S1"``..``"S4"``),
        or None for no overlay.
    fps : float or None
        Frame rate (frames/s) for videos whose manifest row gives none (folders of frames).
    log_format : str or None
        Log format file (:mod:`tympani.pipeline.force.logformat`) for the manifest rows whose ``format`` cell is blank.
    """

    workers: int = 1
    overwrite: bool = False
    progress: bool = True
    extract: Any = field(default_factory=_default_extract)
    sync: Any = field(default_factory=_default_sync)
    fit: Any = field(default_factory=_default_fit)
    bounds: Any = field(default_factory=_default_bounds)
    diagnosis: Any = field(default_factory=_default_diagnosis)
    scenario: str | None = "S4"
    fps: float | None = None
    log_format: str | None = None


@dataclass
class StageRecord:
    """What one stage did (mutable while the run builds it; written to ``run.json``).

    Parameters
    ----------
    status : {"ok", "partial", "skipped", "failed", "not_run"}
        ``skipped``: outputs were up to date; ``partial``: some trials failed; ``not_run``: the
        stage could not run (its input is missing, or the data cannot support it).
    seconds : float
        Wall time (s).
    message : str
        One line for the report.
    settings : str
        The settings it ran with (compared on resume).
    outputs : list of str
        Its files, relative to the output folder.
    """

    status: str = "not_run"
    seconds: float = 0.0
    message: str = ""
    settings: str = ""
    outputs: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class RunResult:
    """Outcome of :func:`run_pipeline`.

    Parameters
    ----------
    out : Path
        Output folder.
    report : Path or None
        ``report.html``.
    stages : dict of str to StageRecord
    trials : DataFrame
        One row a manifest trial (``trials.csv``).
    errors : tuple of str
        One line per bad input (file named), in stage order.
    bug : bool
        Some stage raised something other than bad input.
    """

    out: Path
    report: Path | None
    stages: dict[str, StageRecord]
    trials: pd.DataFrame
    errors: tuple[str, ...]
    bug: bool = False

    @property
    def exit_status(self) -> int:
        """0 all good; 2 some input was bad (the rest written); 1 a bug in some stage."""
        return 1 if self.bug else (2 if self.errors else 0)


# --------------------------------------------------------------------------- helpers


def is_fresh(outputs: Sequence[Path], inputs: Sequence[Path]) -> bool:
    """Whether every output exists and none is older than any existing input (by mtime).

    Parameters
    ----------
    outputs, inputs : sequence of Path

    Returns
    -------
    bool
    """
    if not outputs or not all(Path(p).is_file() for p in outputs):
        return False
    newest_in = max((Path(p).stat().st_mtime_ns for p in inputs if Path(p).exists()), default=0)
    return min(Path(p).stat().st_mtime_ns for p in outputs) >= newest_in


def _settings(*parts: Any) -> str:
    """A stable text of a stage's settings (dataclasses expanded), compared on resume."""
    from tympani.pipeline.io import to_jsonable

    return repr([to_jsonable(dataclasses.asdict(p) if dataclasses.is_dataclass(p) and not isinstance(p, type) else p)
                  for p in parts])


def _previous(out: Path) -> dict[str, dict]:
    """Stage records of the previous run in ``out`` (empty when none or unreadable)."""
    import json

    try:
        return json.loads((out / RUN_JSON).read_text(encoding="utf-8")).get("stages", {})
    except (OSError, ValueError, AttributeError):
        return {}


def _up_to_date(name: str, outputs: Sequence[Path], inputs: Sequence[Path], settings: str,
                previous: dict[str, dict], cfg: RunConfig) -> bool:
    prev = previous.get(name, {})
    return (not cfg.overwrite and prev.get("settings") == settings and prev.get("status") in ("ok", "skipped", "partial")
            and is_fresh(outputs, inputs))


def _kept(previous: dict[str, dict], name: str) -> str:
    """The message of a stage whose outputs were up to date: the previous run's, marked as kept."""
    msg = previous.get(name, {}).get("message", "")
    msg = msg.removesuffix(" (up to date, kept)")
    return f"{msg} (up to date, kept)" if msg else "up to date, kept"


def _remove(paths: Sequence[Path]) -> None:
    """Remove stale outputs of a stage that could not run this time (so nothing misleads)."""
    for p in paths:
        try:
            Path(p).unlink()
        except FileNotFoundError:
            pass


def _timed(record: StageRecord, fn: Callable[[], Any]) -> Any:
    t0 = time.perf_counter()
    try:
        return fn()
    finally:
        record.seconds = round(record.seconds + time.perf_counter() - t0, 3)


def _log(cfg: RunConfig, text: str) -> None:
    if cfg.progress:
        import sys

        print(text, file=sys.stderr)


# --------------------------------------------------------------------------- stages


def _extract(manifest: pd.DataFrame, out: Path, cfg: RunConfig, rec: StageRecord, executor: Any = None) -> pd.DataFrame:
    """Angles tables of the manifest's videos (rows that give an angles table are not extracted)."""
    from tympani.pipeline.extract.batch import SUMMARY_COLUMNS, extract_batch
    from tympani.pipeline.io import atomic_write_csv

    rows = manifest[manifest["video"].notna() & manifest["angles"].isna()]
    rec.settings = _settings(cfg.extract, cfg.fps)
    if rows.empty:
        rec.status, rec.message = "not_run", "no video to extract (the manifest gives angles tables)"
        return pd.DataFrame(columns=list(SUMMARY_COLUMNS))
    angles_dir = out / "angles"
    summary = _timed(rec, lambda: extract_batch(rows, angles_dir, cfg.extract, workers=cfg.workers, executor=executor,
                                                overwrite=cfg.overwrite, progress=cfg.progress, fps=cfg.fps))
    atomic_write_csv(angles_dir / "extract_summary.csv", summary)
    counts = summary["status"].value_counts()
    n_failed = int(counts.get("failed", 0))
    rec.status = "partial" if n_failed and n_failed < len(summary) else ("failed" if n_failed else
                                                                          ("skipped" if counts.get("skipped", 0) == len(summary) else "ok"))
    rec.message = (f"{counts.get('ok', 0)} video(s) extracted, {counts.get('skipped', 0)} already done, {n_failed} failed; "
                   f"{int(summary['n_ok'].fillna(0).sum())} of {int(summary['n_frames'].fillna(0).sum())} frames measured")
    rec.outputs = ["angles/extract_summary.csv"] + [f"angles/{t}.angles.csv" for t in summary.loc[summary.status != "failed", "trial"]]
    return summary


def _sync(manifest_path: Path, manifest: pd.DataFrame, out: Path, cfg: RunConfig, rec: StageRecord,
          previous: dict) -> dict:
    """The synced table; returns the sync report (``synced.sync.json`` content)."""
    import json

    from tympani.pipeline.force.sync import report_path, sync_manifest, write_sync

    table, report = out / "synced.csv", report_path(out / "synced.csv")
    angles_dir = out / "angles"
    logs = [Path(p) for col in ("force", "angles", "depth", "format") if col in manifest.columns
            for p in manifest[col].dropna() if p]
    inputs = [manifest_path, *logs, *([Path(cfg.log_format)] if cfg.log_format else []),
              *[angles_dir / f"{t}.angles.csv" for t in manifest.loc[manifest["angles"].isna(), "trial"]]]
    rec.settings = _settings(cfg.sync, cfg.log_format)
    if _up_to_date("sync", [table, report], inputs, rec.settings, previous, cfg):
        rec.status = "skipped"
        info = json.loads(report.read_text(encoding="utf-8"))
    else:
        def work() -> dict:
            result = sync_manifest(manifest_path, cfg=cfg.sync, angles_dir=angles_dir, log_format=cfg.log_format)
            if not any(t.status == "ok" for t in result.trials):
                _remove([table])
            _, rpath = write_sync(result, table, cfg=cfg.sync)
            return json.loads(rpath.read_text(encoding="utf-8"))

        info = _timed(rec, work)
        rec.status = "ok"
    n_ok, n_failed = int(info.get("n_ok", 0)), int(info.get("n_failed", 0))
    if n_ok == 0:
        rec.status, rec.message = "failed", f"no trial could be synced ({n_failed} failed)"
        return info
    if n_failed:
        rec.status = "partial"
    n_warn = sum(len(t.get("warnings") or []) for t in info.get("trials", []) if t.get("status") == "ok")
    rec.message = (f"{n_ok} trial(s) synced, {n_failed} failed" + (f"; {n_warn} warning(s) in synced.sync.json" if n_warn else ""))
    rec.outputs = ["synced.csv", "synced.sync.json"]
    return info


def _fit(synced_path: Path, out: Path, cfg: RunConfig, rec: StageRecord, previous: dict) -> None:
    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.model.identify import fit_synced, write_fit

    fit_dir = out / "fit"
    rec.settings = _settings(cfg.fit)
    rec.outputs = ["fit/fit.json", "fit/fit_residuals.csv"]
    if _up_to_date("fit", [fit_dir / "fit.json"], [synced_path], rec.settings, previous, cfg):
        rec.status, rec.message = "skipped", _kept(previous, "fit")
        return

    def work() -> None:
        try:
            result = fit_synced(read_synced(synced_path), cfg.fit, source=synced_path)
        except NotEnoughData as exc:  # e.g. a tip-only angle track: say what the data lack, do not fail the run
            _remove([fit_dir / "fit.json", fit_dir / "fit_residuals.csv"])
            rec.status, rec.message = "not_run", exc.problem
            return
        write_fit(result, fit_dir, source=synced_path)
        rec.status, rec.message = "ok", f"n={result.n}, RMSE {result.rmse_g:.3g} g, stderr {result.se_method}"

    _timed(rec, work)


def _simulated(scenario: str | None) -> Callable | None:
    if scenario is None or str(scenario).lower() == "none":
        return None
    from tympani.pipeline.model.paper import SCENARIOS, simulate

    name = str(scenario).upper()
    if name not in SCENARIOS:
        raise InputError("--scenario", f"unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)} or none")
    return lambda speeds: simulate(name, speeds)


def _bounds(synced_path: Path, out: Path, cfg: RunConfig, rec: StageRecord, previous: dict) -> None:
    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.model.bounds import check_synced, fit_bounds, single_trial_speeds
    from tympani.pipeline.model.bounds_output import write_bounds
    from tympani.pipeline.report.figures import write_figures

    bdir = out / "bounds"
    figures = ["force_vs_theta_con.png", "log_force.png", "bounds.png"]
    rec.settings = _settings(cfg.bounds, cfg.scenario)
    rec.outputs = ["bounds/bounds.json", "bounds/bounds_bands.csv", *[f"bounds/{f}" for f in figures]]
    if _up_to_date("bounds", [bdir / "bounds.json", *[bdir / f for f in figures]], [synced_path], rec.settings,
                   previous, cfg):
        rec.status, rec.message = "skipped", _kept(previous, "bounds")
        return

    def work() -> None:
        synced = check_synced(read_synced(synced_path), synced_path)
        bcfg = cfg.bounds
        if bcfg.angle == "theta_con" and not has_contact_angles(synced):
            bcfg = replace(bcfg, angle="theta_tip")  # tip-only angle tracks: the bounds on the tip angle
        fits, skipped = fit_bounds(synced, bcfg)
        if not fits:
            reasons = "; ".join(f"{s['speed_mm_s']:g} mm/s: {s['reason']}" for s in skipped)
            raise InputError(synced_path, f"no speed could be fitted for the bounds ({reasons})")
        names = [p.name for p in write_figures(synced, fits, bdir, simulated=_simulated(cfg.scenario))]
        write_bounds(fits, skipped, bdir, cfg=bcfg, input_path=synced_path, figures=names)
        rec.message = (f"{len(fits)} speed(s) fitted" + (f", {len(skipped)} skipped" if skipped else "")
                       + ("; against theta_tip (the data have no contact angles)" if bcfg.angle == "theta_tip" else ""))
        single = single_trial_speeds(fits)
        if single:
            rec.message += ("; held-out coverage undefined at " + ", ".join(f"{v:g}" for v in single)
                            + " mm/s (one trial each)")

    _timed(rec, work)
    rec.status = "ok"


def _diagnose(synced_path: Path, out: Path, cfg: RunConfig, rec: StageRecord, previous: dict) -> None:
    from tympani.pipeline.diagnosis.analysis import diagnose
    from tympani.pipeline.force.sync import read_synced
    from tympani.pipeline.diagnosis.report import summary_line, write_diagnosis

    ddir = out / "diagnosis"
    rec.settings = _settings(cfg.diagnosis)
    rec.outputs = ["diagnosis/diagnosis.json", "diagnosis/diagnosis.md", "diagnosis/diagnosis_rows.csv"]
    if _up_to_date("diagnose", [ddir / "diagnosis.json", ddir / "diagnosis.md"], [synced_path], rec.settings,
                   previous, cfg):
        rec.status, rec.message = "skipped", _kept(previous, "diagnose")
        return

    def work() -> None:
        table = read_synced(synced_path)
        try:
            diag = diagnose(table, cfg.diagnosis, source=synced_path)
        except InputError as exc:  # the data cannot support a diagnosis: say so, do not fail the run
            _remove([ddir / "diagnosis.json", ddir / "diagnosis.md"])
            rec.status = "not_run"
            rec.message = exc.problem if isinstance(exc, NotEnoughData) else f"the data cannot support a diagnosis: {exc.problem}"
            return
        write_diagnosis(diag, ddir, source=synced_path)
        rec.status, rec.message = "ok", summary_line(diag).removeprefix("diagnose: ")

    _timed(rec, work)


def _run_stage(name: str, rec: StageRecord, fn: Callable[[], Any], errors: list[str], stale: Sequence[Path]) -> bool:
    """Run a stage body; bad input becomes one error line, a bug is recorded. Returns False on a bug."""
    try:
        fn()
        return True
    except Exception as exc:  # one stage failing never loses the others' results
        _remove(stale)
        rec.status = "failed"
        rec.message = one_line(exc)
        if is_input_error(exc):
            errors.append(one_line(exc))
            return True
        errors.append(f"{name}: {rec.message}")
        return False


# --------------------------------------------------------------------------- trials table


def trials_table(manifest: pd.DataFrame, out: Path, extract: pd.DataFrame, sync_info: dict | None) -> pd.DataFrame:
    """One row a manifest trial: inputs, frames measured, sync outcome, the first error.

    Parameters
    ----------
    manifest : DataFrame
        From :func:`tympani.pipeline.extract.manifest.read_manifest`.
    out : Path
        Output folder (``angles/`` inside).
    extract : DataFrame
        The extraction summary (may be empty).
    sync_info : dict or None
        The sync report (``synced.sync.json`` content).

    Returns
    -------
    DataFrame
        ``trial, speed_mm_s, source`` ("video" or "angles"), ``frames, frames_ok, extract``
        (status), ``sync`` (status), ``sync_method, video_t0_s`` (s), ``force_samples,
        samples_with_angles, warnings`` (count), ``error`` (one line or empty), ``refused`` (the
        commonest reasons frames were not measured, from the extraction summary; empty for a
        trial whose angles were given or whose frames were all measured).
    """
    from tympani.pipeline.extract.video import measured_counts

    ex = {r["trial"]: r for r in extract.to_dict("records")} if len(extract) else {}
    sy = {t["trial"]: t for t in (sync_info or {}).get("trials", [])}
    rows = []
    for r in manifest.to_dict("records"):
        trial = str(r["trial"])
        angles = r.get("angles")
        from_video = not isinstance(angles, str) or not angles
        e, s = ex.get(trial, {}), sy.get(trial, {})
        apath = Path(angles) if not from_video else out / "angles" / f"{trial}.angles.csv"
        frames, ok = map(float, (measured_counts(apath) if apath.is_file() else None) or (float("nan"), float("nan")))
        error = e.get("error") if e.get("status") == "failed" else s.get("error")
        rows.append(dict(
            trial=trial, speed_mm_s=float(r["speed_mm_s"]), source="video" if from_video else "angles",
            frames=frames, frames_ok=ok, extract=e.get("status", "" if not from_video else "not_run"),
            sync=s.get("status", "not_run"), sync_method=s.get("method"), video_t0_s=s.get("offset_s"),
            force_samples=s.get("n_samples"), samples_with_angles=s.get("n_with_angles"),
            warnings=len(s.get("warnings") or []), error=error or "", refused=e.get("refused") or "",
        ))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- the run


def run_pipeline(manifest: str | os.PathLike, out_dir: str | os.PathLike, cfg: RunConfig = RunConfig(),
                 *, command: Sequence[str] | None = None, executor: Any = None) -> RunResult:
    """Run every stage on a manifest and write the report (see the module docstring).

    Parameters
    ----------
    manifest : str or PathLike
        Manifest CSV (:func:`tympani.pipeline.extract.manifest.read_manifest`).
    out_dir : str or PathLike
        Output folder (created).
    cfg : RunConfig
        Settings.
    command : sequence of str, optional
        The command line, recorded in ``run.json`` and the report.
    executor : object, optional
        Runs the extraction instead of ``cfg.workers`` local processes (e.g. a
        ``dask.distributed.Client``; see :func:`tympani.pipeline.extract.batch.extract_batch`).

    Returns
    -------
    RunResult

    Raises
    ------
    vision.errors.InputError
        The manifest itself is unusable (missing, bad header or value, a missing file).
    """
    from tympani.pipeline.extract.manifest import read_manifest
    from tympani.pipeline.io import atomic_write_csv, atomic_write_json, provenance

    t_start = time.perf_counter()
    mpath = Path(manifest)
    table = read_manifest(mpath)
    if cfg.log_format is not None:
        from tympani.pipeline.force.logformat import read_log_format

        read_log_format(cfg.log_format)  # a bad --format is one error before anything runs
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    previous = _previous(out)
    stages = {name: StageRecord() for name in STAGES}
    errors: list[str] = []
    ok = True

    _log(cfg, f"run: {len(table)} trial(s) from {mpath} -> {out}")
    extract = pd.DataFrame()

    def do_extract() -> None:
        nonlocal extract
        extract = _extract(table, out, cfg, stages["extract"], executor)
        errors.extend(str(e) for e in extract.loc[extract["status"] == "failed", "error"])
        if (extract["error_kind"] == "error").any():
            raise RuntimeError("; ".join(extract.loc[extract["error_kind"] == "error", "error"]))

    ok &= _run_stage("extract", stages["extract"], do_extract, errors, [])
    failed_videos = set(extract.loc[extract["status"] == "failed", "trial"]) if len(extract) else set()

    sync_info: dict | None = None

    def do_sync() -> None:
        nonlocal sync_info
        sync_info = _sync(mpath, table, out, cfg, stages["sync"], previous)
        for t in sync_info.get("trials", []):
            if t.get("status") != "ok" and t.get("trial") not in failed_videos:  # no second line for a bad video
                errors.append(str(t.get("error")))
                if t.get("error_kind") == "error":
                    raise RuntimeError(str(t.get("error")))

    _log(cfg, "run: sync")
    ok &= _run_stage("sync", stages["sync"], do_sync, errors, [])
    synced = out / "synced.csv"
    have_synced = stages["sync"].status in ("ok", "partial", "skipped") and synced.is_file()
    for name, fn, stale in (("fit", _fit, [out / "fit" / "fit.json"]),
                            ("bounds", _bounds, [out / "bounds" / "bounds.json"]),
                            ("diagnose", _diagnose, [out / "diagnosis" / "diagnosis.json"])):
        if not have_synced:
            stages[name].message = "no synced table"
            _remove(stale)
            continue
        _log(cfg, f"run: {name}")
        # mypy cannot infer the type of a lambda with default arguments (python/mypy#15459)
        ok &= _run_stage(name, stages[name],
                         lambda fn=fn, name=name: fn(synced, out, cfg, stages[name], previous),  # type: ignore[misc]
                         errors, stale)

    trials = trials_table(table, out, extract, sync_info)
    atomic_write_csv(out / TRIALS_CSV, trials)
    record = provenance(mpath, {"workers": cfg.workers, "overwrite": cfg.overwrite, "scenario": cfg.scenario,
                                "fps": cfg.fps, "log_format": cfg.log_format},
                        command=list(command) if command is not None else None,
                        manifest=str(mpath.resolve()), out=str(out.resolve()),
                        stages={k: dataclasses.asdict(v) for k, v in stages.items()},
                        errors=list(errors), seconds=round(time.perf_counter() - t_start, 3))
    atomic_write_json(out / RUN_JSON, record)

    from tympani.pipeline.report.page import write_report

    rec = stages["report"]
    _log(cfg, "run: report")
    report: Path | None = None

    def do_report() -> None:
        nonlocal report
        report = _timed(rec, lambda: write_report(out))
        rec.status, rec.message, rec.outputs = "ok", f"{report.stat().st_size / 1e6:.2f} MB", ["report.html"]

    ok &= _run_stage("report", rec, do_report, errors, [])
    record["stages"]["report"] = dataclasses.asdict(rec)
    record["seconds"] = round(time.perf_counter() - t_start, 3)
    atomic_write_json(out / RUN_JSON, record)
    return RunResult(out=out, report=report, stages=stages, trials=trials, errors=tuple(errors), bug=not ok)

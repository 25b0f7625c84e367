"""Put angles and forces on one clock: the synced table (docs/file-formats.md).

For each trial of a manifest, :func:`sync_manifest` reads the angles table (video clock) and the
force log (force clock), finds the offset ``video_t0_s`` (the force-clock time of the video's
``time_s = 0``), interpolates the angles of the measured frames onto the force samples and
stacks the trials into one table::

    trial, speed_mm_s, time_s, force_g, theta_tip, theta_bot, theta_con,     (what analyses read)
    depth_mm, video_time_s, saturated, sync_offset_s, sync_uncertainty_s     (extras)

``time_s`` is the force clock; ``video_time_s = time_s - sync_offset_s``.

A lab's own logs (epoch stamps, newtons with a sign and a gain, a depth log of the robot's stage,
another tracker's angle track) are read through a log format file (:mod:`tympani.pipeline.force.logformat`,
:mod:`tympani.pipeline.force.labstreams`): the manifest's ``format`` column or ``log_format`` for the rows
without one. A depth log (manifest column ``depth``) fills ``depth_mm``; another tracker's track
brings its own offset (its ``zero``: the force log's clock, the depth log's motion start, or a
number of seconds) instead of the estimate. ``docs/lab-logs.md`` works through an example.

The offset is taken from the manifest's ``video_t0_s`` or estimated from the data
(:mod:`tympani.pipeline.force.offset`, which also holds the settings, :class:`SyncConfig`).

The synced table is read back by :func:`read_synced`, for every analysis.

Angles on the force clock
-------------------------
Only frames with ``ok`` true are used. Between two consecutive measured frames further apart
than ``max_gap_frames`` frame periods (a run of failed frames), and outside the first and last
measured frame, the angles are NaN (no extrapolation, no bridging of long gaps).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from tympani.pipeline.force.forcelog import ColumnKind, CsvHeader, parse_numeric, read_csv_columns, read_table_lines
from tympani.pipeline.io import atomic_write_csv, atomic_write_json, csv_records, data_lines, tool_version
from tympani.pipeline.force.labstreams import read_lab_logs, track_coverage
from tympani.pipeline.force.logformat import LogFormat, read_log_format
from tympani.pipeline.force.motion import Motion
from tympani.pipeline.force.offset import OffsetEstimate, SyncConfig, estimate_offset, frame_period
from tympani.vision.errors import InputError, is_input_error, one_line

__all__ = [
    "SYNC_COLUMNS",
    "SYNC_EXTRA_COLUMNS",
    "SYNC_NUMBER_COLUMNS",
    "SyncConfig",
    "OffsetEstimate",
    "TrialSync",
    "SyncResult",
    "read_synced",
    "read_angles_table",
    "frame_period",
    "interpolate_angles",
    "estimate_offset",
    "sync_trial",
    "sync_manifest",
    "write_sync",
    "report_path",
]

#: The synced table's fixed columns, in order (docs/file-formats.md).
SYNC_COLUMNS: tuple[str, ...] = ("trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con")
#: Extra columns written after :data:`SYNC_COLUMNS`.
SYNC_EXTRA_COLUMNS: tuple[str, ...] = (
    "depth_mm", "video_time_s", "saturated", "sync_offset_s", "sync_uncertainty_s",
)

#: Columns of a synced table read as numbers (float, NaN for an empty cell); ``trial`` and any
#: other column not named here are text, ``saturated`` is a flag.
SYNC_NUMBER_COLUMNS: tuple[str, ...] = (
    "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con",
    "depth_mm", "video_time_s", "sync_offset_s", "sync_uncertainty_s",
)

_ANGLES = ("theta_tip", "theta_bot", "theta_con")
_TRUE = frozenset({"true", "1", "yes", "t", "y"})
_FALSE = frozenset({"false", "0", "no", "f", "n", ""})


@dataclass(frozen=True)
class TrialSync:
    """What happened to one trial in :func:`sync_manifest`.

    Parameters
    ----------
    trial : str
        Trial name.
    line : int
        Its line in the manifest.
    status : {"ok", "failed"}
        Outcome.
    error : str or None
        One-line error of a failed trial (``"<file>:<line>: <problem>"``).
    error_kind : {"input", "error"} or None
        ``"input"`` for bad input, ``"error"`` for a bug.
    method : str or None
        ``"manifest"`` or ``"estimate:<signal>"``.
    offset_s, uncertainty_s : float or None
        The offset used and its standard uncertainty (s; 0 for a manifest offset).
    estimate : OffsetEstimate or None
        The estimate (also made as a check of a manifest offset).
    n_samples : int
        Force samples (rows written).
    n_with_angles : int
        Rows with interpolated angles.
    angles_path, force_path : str or None
        Inputs.
    force_report : dict or None
        The force log's :class:`~tympani.pipeline.force.forcelog.ForceLogReport` as a dict.
    warnings : tuple of str
        One-line warnings.
    format_path : str or None
        The log format file the trial was read through, if any.
    depth_path : str or None
        Its depth log, if any.
    depth : dict or None
        The depth log's summary (:meth:`tympani.pipeline.force.labstreams.DepthLog.summary`): samples, span and
        the motion start and stop found (s on the force clock, with their uncertainties).
    clock_origin : str or None
        With a ``[force]`` format: the force log's first stamp as written (``time_s`` counts
        from it).
    """

    trial: str
    line: int
    status: str
    error: str | None = None
    error_kind: str | None = None
    method: str | None = None
    offset_s: float | None = None
    uncertainty_s: float | None = None
    estimate: OffsetEstimate | None = None
    n_samples: int = 0
    n_with_angles: int = 0
    angles_path: str | None = None
    force_path: str | None = None
    force_report: dict | None = None
    warnings: tuple[str, ...] = ()
    format_path: str | None = None
    depth_path: str | None = None
    depth: dict | None = None
    clock_origin: str | None = None


@dataclass(frozen=True, eq=False)
class SyncResult:
    """The synced table of a manifest and one :class:`TrialSync` per trial."""

    table: pd.DataFrame
    trials: tuple[TrialSync, ...]
    manifest: str = ""
    log_format: str | None = None

    @property
    def failed(self) -> tuple[TrialSync, ...]:
        """The trials that could not be synced."""
        return tuple(t for t in self.trials if t.status != "ok")


# --------------------------------------------------------------------------- flags


def _parse_flag(cells: Sequence[str], lines: np.ndarray, name: str, column: str = "ok") -> np.ndarray:
    """A column of true/false cells as bools; an error naming the line of any other text."""
    low = [c.strip().lower() for c in cells]
    out = np.empty(len(low), dtype=bool)
    for i, c in enumerate(low):
        if c in _TRUE:
            out[i] = True
        elif c in _FALSE:
            out[i] = False
        else:
            raise InputError(f"{name}:{lines[i]}", f"{column} {cells[i]!r} is not true or false")
    return out


# --------------------------------------------------------------------------- the synced table


def _synced_kinds(header: CsvHeader) -> dict[str, ColumnKind]:
    """Every column of a synced table's header: a number column or text."""
    return {c: "number" if c in SYNC_NUMBER_COLUMNS else "text" for c in header.columns}


def read_synced(path: str | os.PathLike) -> pd.DataFrame:
    """Read a synced table (docs/file-formats.md), as :func:`write_sync` writes it or by hand.

    A line whose first non-blank character is ``#`` is a comment and blank lines are skipped;
    a ``#`` anywhere else is part of a field (as in :func:`~tympani.pipeline.io.csv_records`), so a
    number cell such as ``0.5 # note`` is an error naming its line, never a cut line. No
    column is required here: each analysis checks the columns it needs.

    Parameters
    ----------
    path : str or PathLike
        The CSV file.

    Returns
    -------
    DataFrame
        The columns in file order: those of :data:`SYNC_NUMBER_COLUMNS` as float (s, g, mm,
        rad, mm/s; NaN for an empty or NaN cell), ``saturated`` as bool (``true/1/yes/t/y``
        or ``false/0/no/f/n``/empty, any case), every other column (``trial`` among them)
        as stripped text (``str``); then ``line``, the 1-based line of each row in the file.

    Raises
    ------
    InputError
        Missing file, not UTF-8 text, no header, duplicate column names, a row with another
        number of fields than the header, text or an infinity in a number column, a
        ``saturated`` cell that is not true or false (one line naming the file and the
        line), or no data rows.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such synced table" if not p.exists() else "synced table is not a file")
    name = str(p)
    table = read_csv_columns(p, _synced_kinds, name=name)
    if not table.n_rows:
        raise InputError(name, "synced table has no rows")
    out = pd.DataFrame(index=pd.RangeIndex(table.n_rows))
    for column, values in table.values.items():
        if column == "saturated":
            out[column] = _parse_flag(values, table.lines, name, column)
        elif values.dtype == object:
            out[column] = pd.Series(values, dtype=str)
        else:
            out[column] = values
    out["line"] = table.lines
    return out


# --------------------------------------------------------------------------- angles table


def read_angles_table(path: str | os.PathLike) -> pd.DataFrame:
    """Read and check an angles table (docs/file-formats.md).

    Parameters
    ----------
    path : str or PathLike
        ``<trial>.angles.csv`` (``#`` lines are comments).

    Returns
    -------
    DataFrame
        ``time_s`` (s, video clock, strictly increasing), ``theta_tip``, ``theta_bot``,
        ``theta_con`` (rad, NaN where not measured), ``ok`` (bool), ``frame`` (int, the row
        index when the table has no frame column), ``line``. A row marked ok whose angles are
        empty is set to not ok (``attrs["warnings"]`` says how many).

    Raises
    ------
    InputError
        Missing file, missing column, non-numeric cell, bad ``ok`` value, NaN or
        non-increasing ``time_s`` (one line naming the file and line).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such angles table" if not p.exists() else "angles table is not a file")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read angles table ({type(exc).__name__}: {exc})") from None
    name = str(p)
    header, rows, lines, _ = read_table_lines(text, name=name)
    missing = [c for c in ("time_s", *_ANGLES, "ok") if c not in header]
    if missing:
        raise InputError(f"{name}:{_first_line(text)}", f"missing column(s) {', '.join(missing)} of an angles table")
    if not rows:
        raise InputError(name, "angles table has no frames")
    cols = dict(zip(header, zip(*rows)))
    out = pd.DataFrame({"time_s": parse_numeric(cols["time_s"], lines, column="time_s", name=name, allow_nan=False)})
    for c in _ANGLES:
        out[c] = parse_numeric(cols[c], lines, column=c, name=name)
    out["ok"] = _parse_flag(list(cols["ok"]), lines, name)
    out["frame"] = (parse_numeric(cols["frame"], lines, column="frame", name=name, allow_nan=False).astype(int)
                    if "frame" in cols else np.arange(len(rows)))
    out["line"] = lines
    t = out["time_s"].to_numpy()
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(f"{name}:{lines[i]}", f"time_s does not increase ({t[i]:.6g} s after {t[i - 1]:.6g} s)")
    missing_angles = out["ok"].to_numpy() & out[list(_ANGLES)].isna().any(axis=1).to_numpy()
    warnings = []
    if missing_angles.any():
        out.loc[missing_angles, "ok"] = False
        warnings.append(f"{int(missing_angles.sum())} frame(s) marked ok without angles were treated as failed "
                        f"(first on line {int(lines[np.argmax(missing_angles)])})")
    out.attrs["warnings"] = warnings
    return out


def _first_line(text: str) -> int:
    """Number of the first line that is neither blank nor a comment (1 when there is none)."""
    return next((lineno for lineno, _ in data_lines(text.splitlines())), 1)


# --------------------------------------------------------------------------- interpolation


def interpolate_angles(angles: pd.DataFrame, video_time_s: np.ndarray, *, max_gap_s: float) -> pd.DataFrame:
    """Angles of the measured frames, linearly interpolated at video times.

    Parameters
    ----------
    angles : DataFrame
        Angles table: ``time_s`` (s), ``theta_tip``, ``theta_bot``, ``theta_con`` (rad), ``ok``.
    video_time_s : ndarray
        Query times on the video clock (s).
    max_gap_s : float
        Longest interval (s) between two consecutive measured frames that is bridged.

    Returns
    -------
    DataFrame
        ``theta_tip``, ``theta_bot``, ``theta_con`` (rad) at each query time; NaN before the
        first or after the last measured frame and inside longer gaps.
    """
    good = angles[angles["ok"].to_numpy(dtype=bool)]
    t_ok = good["time_s"].to_numpy(dtype=float)
    tq = np.asarray(video_time_s, dtype=float)
    out = {c: np.full(tq.shape, np.nan) for c in _ANGLES}
    if t_ok.size == 0:
        return pd.DataFrame(out)
    if t_ok.size == 1:
        hit = tq == t_ok[0]
        for c in _ANGLES:
            out[c][hit] = float(good[c].iloc[0])
        return pd.DataFrame(out)
    idx = np.clip(np.searchsorted(t_ok, tq, side="right") - 1, 0, t_ok.size - 2)
    gap = t_ok[idx + 1] - t_ok[idx]
    valid = (tq >= t_ok[0]) & (tq <= t_ok[-1]) & (gap <= max_gap_s * (1 + 1e-9))
    for c in _ANGLES:
        values = np.interp(tq, t_ok, good[c].to_numpy(dtype=float))
        out[c] = np.where(valid, values, np.nan)
    return pd.DataFrame(out)


# --------------------------------------------------------------------------- one trial


def sync_trial(
    angles: pd.DataFrame,
    force: pd.DataFrame,
    *,
    trial: str,
    speed_mm_s: float,
    offset_s: float,
    uncertainty_s: float = 0.0,
    max_gap_frames: float = 3.0,
) -> pd.DataFrame:
    """The synced rows of one trial: angles interpolated onto the force samples.

    Parameters
    ----------
    angles : DataFrame
        Angles table on the video clock (``time_s`` s, angles rad, ``ok``).
    force : DataFrame
        Force log (``time_s`` s, ``force_g`` g, optional ``depth_mm`` mm, ``saturated``).
    trial : str
        Trial name.
    speed_mm_s : float
        Insertion speed (mm/s).
    offset_s : float
        ``video_t0_s``: force-clock time of video time 0 (s).
    uncertainty_s : float
        Its standard uncertainty (s), copied into ``sync_uncertainty_s``.
    max_gap_frames : float
        Longest interval between measured frames bridged by interpolation (frame periods).

    Returns
    -------
    DataFrame
        :data:`SYNC_COLUMNS` + :data:`SYNC_EXTRA_COLUMNS`, one row per force sample.
    """
    t = force["time_s"].to_numpy(dtype=float)
    video_t = t - offset_s
    period = frame_period(angles)
    theta = interpolate_angles(angles, video_t, max_gap_s=max_gap_frames * period)
    n = t.size
    depth = force["depth_mm"].to_numpy(dtype=float) if "depth_mm" in force.columns else np.full(n, np.nan)
    saturated = force["saturated"].to_numpy(dtype=bool) if "saturated" in force.columns else np.zeros(n, bool)
    return pd.DataFrame({
        "trial": np.full(n, trial, dtype=object),
        "speed_mm_s": np.full(n, float(speed_mm_s)),
        "time_s": t,
        "force_g": force["force_g"].to_numpy(dtype=float),
        "theta_tip": theta["theta_tip"].to_numpy(),
        "theta_bot": theta["theta_bot"].to_numpy(),
        "theta_con": theta["theta_con"].to_numpy(),
        "depth_mm": depth,
        "video_time_s": video_t,
        "saturated": saturated,
        "sync_offset_s": np.full(n, float(offset_s)),
        "sync_uncertainty_s": np.full(n, float(uncertainty_s)),
    })


# --------------------------------------------------------------------------- manifest


def _manifest_t0_cells(path: Path) -> dict[int, str]:
    """The raw ``video_t0_s`` cell of every manifest line (read_manifest turns blanks into 0)."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        line_numbers, rows = csv_records(fh)
    if not line_numbers:
        return {}
    header = [h.strip() for h in rows[0]]
    if "video_t0_s" not in header:
        return {}
    j = header.index("video_t0_s")
    return {ln: vals[j].strip() for ln, vals in zip(line_numbers[1:], rows[1:]) if len(vals) > j}


def _angles_path(row: pd.Series, angles_dir: Path, where: str) -> Path:
    if row.get("angles"):
        p = Path(row["angles"])
        if not p.is_file():
            raise InputError(where, f"angles table {str(p)!r} not found")
        return p
    p = angles_dir / f"{row['trial']}.angles.csv"
    if not p.is_file():
        raise InputError(where, f"no angles table: the manifest gives none and {str(p)!r} does not exist "
                                "(run 'tympani extract --manifest M --out DIR' and pass --angles-dir DIR)")
    return p


def _row_format(row: pd.Series, default: LogFormat | None) -> LogFormat | None:
    """The log format of a manifest row: its ``format`` cell, else the command's ``--format``."""
    cell = row.get("format")
    if isinstance(cell, str) and cell:
        return read_log_format(cell)
    return default


def _speed_note(motion: Motion, speed_mm_s: float) -> list[str]:
    """A warning when the depth log's speed is not the manifest's (more than 5 % apart)."""
    if not (math.isfinite(motion.speed_mm_s) and speed_mm_s > 0):
        return []
    ratio = abs(motion.speed_mm_s) / speed_mm_s
    if abs(ratio - 1.0) <= 0.05:
        return []
    return [f"the depth log moves at {abs(motion.speed_mm_s):.3g} mm/s, the manifest says {speed_mm_s:g} mm/s"]


def _one_trial(row: pd.Series, t0_given: bool, angles_dir: Path, mpath: Path, cfg: SyncConfig,
               default_format: LogFormat | None = None) -> tuple[pd.DataFrame, TrialSync]:
    where = f"{mpath}:{int(row['line'])}"
    trial = str(row["trial"])
    force_file = row.get("force")
    if not force_file or not Path(force_file).exists():
        raise InputError(where, f"force log {str(force_file)!r} not found")
    fmt = _row_format(row, default_format)
    depth_file = row.get("depth") if isinstance(row.get("depth"), str) and row.get("depth") else None
    tracker = fmt is not None and fmt.angles is not None and bool(row.get("angles"))
    logs = read_lab_logs(force_file, fmt=fmt, depth_path=depth_file, angles_path=row["angles"] if tracker else None,
                         cfg=cfg.force_log)
    force, report = logs.force, logs.force_report
    warnings = [*report.warnings, *logs.warnings]
    estimate: OffsetEstimate | None = None
    if logs.track is not None:
        angles_file = Path(row["angles"])
        angles = logs.track.angles
        warnings = [*angles.attrs.get("warnings", []), *warnings]
        offset, unc, method = logs.track.offset_s, logs.track.uncertainty_s, f"format:{logs.track.zero}"
        warnings.extend(track_coverage(logs.track, force["time_s"].to_numpy(float), trial=trial, depth=logs.depth))
        if t0_given:
            warnings.append("video_t0_s was not used: the log format's [angles] zero gives the offset")
    else:
        angles_file = _angles_path(row, angles_dir, where)
        angles = read_angles_table(angles_file)
        warnings = [*angles.attrs.get("warnings", []), *warnings]
        if not angles["ok"].any():
            raise InputError(angles_file, "no frame was measured (every ok is false)")
        use_manifest = cfg.t0 == "manifest" or (cfg.t0 == "auto" and t0_given)
        if use_manifest:
            offset, unc, method = float(row["video_t0_s"]), 0.0, "manifest"
            if cfg.check_manifest_t0:
                try:
                    estimate = estimate_offset(angles, force, cfg=cfg, where=where)
                except InputError as exc:
                    warnings.append(f"could not check video_t0_s against the data: {exc.problem}")
                if estimate is not None:
                    tol = 3 * estimate.uncertainty_s + estimate.frame_period_s
                    if abs(estimate.offset_s - offset) > tol:
                        warnings.append(f"video_t0_s {offset:.4g} s disagrees with the data's estimate "
                                        f"{estimate.offset_s:.4g} ± {estimate.uncertainty_s:.2g} s")
        else:
            estimate = estimate_offset(angles, force, cfg=cfg, where=where)
            offset, unc, method = estimate.offset_s, estimate.uncertainty_s, f"estimate:{estimate.signal}"
            warnings.extend(estimate.warnings)
    if logs.depth is not None:
        warnings.extend(_speed_note(logs.depth.motion, float(row["speed_mm_s"])))
    table = sync_trial(angles, force, trial=trial, speed_mm_s=float(row["speed_mm_s"]), offset_s=offset,
                       uncertainty_s=unc, max_gap_frames=cfg.max_gap_frames)
    n_with = int(table["theta_tip"].notna().sum())
    if n_with == 0:
        raise InputError(where, f"no force sample falls within the measured frames (offset {offset:.4g} s); "
                                "check video_t0_s")
    info = TrialSync(
        trial=trial, line=int(row["line"]), status="ok", method=method, offset_s=offset, uncertainty_s=unc,
        estimate=estimate, n_samples=len(table), n_with_angles=n_with, angles_path=str(angles_file),
        force_path=str(force_file), force_report=report.to_dict(), warnings=tuple(warnings),
        format_path=fmt.path if fmt is not None else None, depth_path=depth_file,
        depth=logs.depth.summary() if logs.depth is not None else None,
        clock_origin=logs.clock.origin or None,
    )
    return table, info


def sync_manifest(
    manifest: str | os.PathLike,
    *,
    cfg: SyncConfig = SyncConfig(),
    angles_dir: str | os.PathLike | None = None,
    log_format: str | os.PathLike | None = None,
) -> SyncResult:
    """Sync every trial of a manifest; a bad trial is recorded and the others go on.

    Parameters
    ----------
    manifest : str or PathLike
        Manifest CSV (docs/file-formats.md).
    cfg : SyncConfig
        Settings.
    angles_dir : str or PathLike, optional
        Folder of ``<trial>.angles.csv`` for trials whose manifest row names no ``angles``
        table (the ``--out`` of ``tympani extract``); default: the manifest's folder.
    log_format : str or PathLike, optional
        A log format file (:mod:`tympani.pipeline.force.logformat`, docs/lab-logs.md) for the rows whose
        ``format`` cell is blank; without either, the logs are read in tympani's own form.

    Returns
    -------
    SyncResult
        The stacked table of the trials that worked (manifest order) and one
        :class:`TrialSync` per trial.

    Raises
    ------
    InputError
        The manifest itself or ``log_format`` is unusable (missing, bad header, bad value); a
        bad trial (its logs, or its own format file) only marks that trial failed.
    """
    from tympani.pipeline.extract.manifest import read_manifest

    mpath = Path(manifest)
    default_format = read_log_format(log_format) if log_format is not None else None
    table = read_manifest(mpath, check_files=False)
    t0_cells = _manifest_t0_cells(mpath)
    adir = Path(angles_dir) if angles_dir is not None else mpath.resolve().parent
    parts, infos = [], []
    for _, row in table.iterrows():
        line = int(row["line"])
        try:
            part, info = _one_trial(row, bool(t0_cells.get(line)), adir, mpath, cfg, default_format)
        except Exception as exc:  # one bad trial never stops the others
            kind = "input" if is_input_error(exc) else "error"
            text = one_line(exc) if kind == "input" else f"{mpath}:{line}: {one_line(exc)}"
            infos.append(TrialSync(trial=str(row["trial"]), line=line, status="failed", error=text, error_kind=kind))
            continue
        parts.append(part)
        infos.append(info)
    columns = [*SYNC_COLUMNS, *SYNC_EXTRA_COLUMNS]
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=columns)
    return SyncResult(table=out[columns], trials=tuple(infos), manifest=str(mpath),
                      log_format=str(log_format) if log_format is not None else None)


def report_path(out: str | os.PathLike) -> Path:
    """The sync report beside a synced table: ``synced.csv`` → ``synced.sync.json``."""
    p = Path(out)
    return p.with_name(f"{p.stem}.sync.json")


def write_sync(result: SyncResult, out: str | os.PathLike, *, cfg: SyncConfig = SyncConfig()) -> tuple[Path | None, Path]:
    """Write the synced table (if any trial worked) and its JSON report, atomically.

    Parameters
    ----------
    result : SyncResult
        From :func:`sync_manifest`.
    out : str or PathLike
        The synced table's path (CSV).
    cfg : SyncConfig
        Recorded in the report.

    Returns
    -------
    table_path : Path or None
        The CSV, None when no trial worked (nothing written).
    report : Path
        ``<stem>.sync.json``: ``manifest``, ``table``, ``config``, ``n_ok``, ``n_failed`` and
        ``trials`` (per trial: offset, uncertainty, method, estimate, warnings, cleaning,
        error).
    """
    table_path = None
    if any(t.status == "ok" for t in result.trials):
        table_path = atomic_write_csv(out, result.table)
    report = {
        "tool": "tympani",
        "version": tool_version(),
        "manifest": str(Path(result.manifest).resolve()) if result.manifest else None,
        "table": str(Path(out).resolve()) if table_path else None,
        "config": cfg,
        "log_format": str(Path(result.log_format).resolve()) if result.log_format else None,
        "n_ok": sum(t.status == "ok" for t in result.trials),
        "n_failed": len(result.failed),
        "trials": list(result.trials),
    }
    return table_path, atomic_write_json(report_path(out), report)


"""The experiment manifest (:func:`read_manifest`) and the videos of a batch (:class:`VideoItem`,
:func:`video_items`)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from tympani.pipeline.io import csv_records
from tympani.vision.errors import InputError, one_line

__all__ = ["MANIFEST_REQUIRED", "VideoItem", "read_manifest", "video_items"]


@dataclass(frozen=True)
class VideoItem:
    """One video of a batch.

    Parameters
    ----------
    path : str
        Video file or folder of frames.
    trial : str, optional
        Trial name (default: file stem).
    fps : float, optional
        Frame rate (frames/s) for this video (default: the batch's ``fps``).
    """

    path: str
    trial: str | None = None
    fps: float | None = None


def _blank(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value)) or (isinstance(value, str) and not value.strip())


def video_items(items: Any) -> list[VideoItem]:
    """Normalise paths, dicts, :class:`VideoItem` s or a manifest DataFrame to items.

    Parameters
    ----------
    items : str, PathLike, iterable or DataFrame
        One path; or paths, :class:`VideoItem` s and dicts with ``path`` (or ``video``),
        ``trial`` and ``fps`` (frames/s); or a DataFrame with a ``video`` (or ``path``) column,
        e.g. a manifest (:func:`read_manifest`), whose rows without a video are left out.

    Returns
    -------
    list of VideoItem

    Raises
    ------
    ValueError
        An item names no video.
    """
    if isinstance(items, (str, os.PathLike)):
        items = [items]
    if isinstance(items, pd.DataFrame):
        col = "video" if "video" in items.columns else "path"
        if col not in items.columns:
            raise ValueError("a DataFrame of videos needs a 'video' or 'path' column")
        records = [r for r in items.to_dict("records") if not _blank(r.get(col))]
        items = [{"path": r[col], "trial": r.get("trial"), "fps": r.get("fps")} for r in records]
    out = []
    for item in items:
        if isinstance(item, VideoItem):
            out.append(item)
        elif isinstance(item, dict):
            p = next((item[key] for key in ("path", "video") if not _blank(item.get(key))), None)
            if p is None:
                raise ValueError(f"a video item needs a 'path' or 'video': {item!r}")
            trial = None if _blank(item.get("trial")) else str(item["trial"])
            fps = None if _blank(item.get("fps")) else float(item["fps"])
            out.append(VideoItem(os.fspath(p), trial, fps))
        else:
            out.append(VideoItem(os.fspath(item)))
    return out


#: Columns every manifest must have (plus ``video`` and/or ``angles``).
MANIFEST_REQUIRED: tuple[str, ...] = ("trial", "speed_mm_s", "force")
_MANIFEST_PATHS = ("video", "angles", "force", "depth", "format")


def _number(where: str, column: str, text: str, *, positive: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(where, f"{column} {text!r} is not a number") from None
    if not math.isfinite(value) or (positive and value <= 0):
        raise InputError(where, f"{column} must be {'a positive' if positive else 'a finite'} number, not {text!r}")
    return value


def read_manifest(path: str | os.PathLike, *, check_files: bool = True) -> pd.DataFrame:
    """Read and validate an experiment manifest (docs/file-formats.md).

    The manifest is a CSV with a header row and one row a trial: ``trial``, ``speed_mm_s``,
    ``force`` and ``video`` and/or ``angles`` (file paths relative to the manifest's folder),
    optionally ``fps``, ``video_t0_s``, ``depth`` (a depth log) and ``format`` (a log format
    file, :mod:`tympani.pipeline.force.logformat`). Blank lines and lines starting with ``#`` are skipped.
    Further columns are kept.

    Parameters
    ----------
    path : str or PathLike
        The manifest CSV.
    check_files : bool
        Check that every referenced file or folder exists.

    Returns
    -------
    DataFrame
        One row a trial, in file order: ``trial`` (str), ``speed_mm_s`` (float, mm/s),
        ``video``, ``angles``, ``force`` (absolute path strings, None when blank; ``depth`` and
        ``format`` too, when the manifest has those columns), ``fps``
        (float frames/s, NaN when blank), ``video_t0_s`` (float s, 0 when blank), ``line``
        (line number in the manifest) and any extra columns (strings).

    Raises
    ------
    InputError
        Missing or unreadable file, missing columns, no rows, a bad value, a duplicate trial
        name, or a missing referenced file; the message names the manifest and the line.
    """
    mpath = Path(path)
    if not mpath.is_file():
        raise InputError(mpath, "no such manifest file" if not mpath.exists() else "manifest is not a file")
    base = mpath.resolve().parent
    try:
        with open(mpath, newline="", encoding="utf-8-sig") as fh:
            line_numbers, rows = csv_records(fh)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(mpath, f"cannot read manifest ({one_line(exc)})") from None
    if not line_numbers:
        raise InputError(mpath, "empty manifest (no header row)")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        raise InputError(f"{mpath}:{line_numbers[0]}", "duplicate column names in the header")
    missing = [c for c in MANIFEST_REQUIRED if c not in header]
    if missing:
        raise InputError(f"{mpath}:{line_numbers[0]}", f"missing column(s): {', '.join(missing)}")
    if "video" not in header and "angles" not in header:
        raise InputError(f"{mpath}:{line_numbers[0]}", "needs a 'video' or an 'angles' column")
    if len(rows) == 1:
        raise InputError(mpath, "manifest has no trials")
    records: list[dict[str, Any]] = []
    seen: dict[str, int] = {}
    for lineno, values in zip(line_numbers[1:], rows[1:]):
        where = f"{mpath}:{lineno}"
        if len(values) != len(header):
            raise InputError(where, f"{len(values)} fields, but the header has {len(header)}")
        raw = {h: v.strip() for h, v in zip(header, values)}
        trial = raw["trial"]
        if not trial:
            raise InputError(where, "empty trial name")
        if trial in seen:
            raise InputError(where, f"duplicate trial {trial!r} (first on line {seen[trial]})")
        seen[trial] = lineno
        rec: dict[str, Any] = dict(raw)
        rec["speed_mm_s"] = _number(where, "speed_mm_s", raw["speed_mm_s"], positive=True)
        rec["fps"] = _number(where, "fps", raw["fps"], positive=True) if raw.get("fps") else math.nan
        rec["video_t0_s"] = _number(where, "video_t0_s", raw["video_t0_s"], positive=False) if raw.get("video_t0_s") else 0.0
        for col in _MANIFEST_PATHS:
            text = raw.get(col, "")
            if not text:
                rec[col] = None
                continue
            resolved = (base / text).resolve()
            if check_files and not resolved.exists():
                raise InputError(where, f"{col} file {text!r} not found (looked for {resolved})")
            rec[col] = str(resolved)
        if rec["force"] is None:
            raise InputError(where, "no force log given")
        if rec.get("video") is None and rec.get("angles") is None:
            raise InputError(where, "needs a video or an angles table")
        rec["line"] = lineno
        records.append(rec)
    first = ["trial", "speed_mm_s", "video", "angles", "force", "fps", "video_t0_s", "line"]
    table = pd.DataFrame(records)
    for col in first:
        if col not in table.columns:
            table[col] = None
    return table[first + [c for c in table.columns if c not in first]]

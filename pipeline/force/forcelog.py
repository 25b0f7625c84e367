"""Force logs (docs/file-formats.md): read, validate, clean.

A force log is a CSV whose lines starting with ``#`` are comments: a header naming ``time_s``
and ``force_g`` or ``force_N`` (optionally ``depth_mm``), then one row a sample. What is wrong
with a log either stops it with a one-line :class:`~tympani.vision.errors.InputError` naming the file
and the line, or is repaired by a documented cleaning step that is recorded in the
:class:`ForceLogReport`:

=============================================  ================================================
problem                                        what happens (default :class:`ForceLogConfig`)
=============================================  ================================================
no header / missing or unknown columns         error (names the header line)
``force_g`` and ``force_N`` both present       error
a row with the wrong number of fields          error (names the line)
non-numeric text or ±inf in a cell             error (names the line and the column)
empty / NaN ``time_s``                         error
empty / NaN force                              row dropped (``drop_nan``); error when more than
                                               ``max_nan_fraction`` of the rows, or with
                                               ``nan_policy="error"``
empty / NaN ``depth_mm``                       kept as NaN (depth is optional)
time going backwards                           error (names the line and the previous one)
duplicate timestamps                           averaged into one sample (``average_duplicates``)
                                               or error with ``duplicate_policy="error"``
gaps > ``gap_factor`` median periods           warning (listed in ``report.gaps``)
flat run at the largest \\|force\\| (clipping)    samples flagged in column ``saturated`` and a
                                               warning (``flag_saturation``); or dropped /
                                               error (``saturation_policy``)
values that look like the other unit           warning (e.g. ``force_g`` peaking at 0.12)
fewer than ``min_samples`` samples             error
=============================================  ================================================

``force_N`` is converted to grams-force with 1 g = 9.80665e-3 N.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Callable, Iterator, Literal, Mapping, Sequence

import numpy as np
import pandas as pd

from tympani.pipeline.io import csv_records, data_lines, to_jsonable
from tympani.vision.errors import InputError, one_line

__all__ = [
    "G_PER_N",
    "N_PER_G",
    "FORCE_LOG_COLUMNS",
    "ForceLogConfig",
    "CleaningStep",
    "ForceLogReport",
    "read_table_lines",
    "CSV_CHUNK_ROWS",
    "CsvHeader",
    "CsvColumns",
    "read_csv_columns",
    "parse_numeric",
    "ForceSamples",
    "clean_force_samples",
    "parse_force_log",
    "read_force_log",
    "find_saturation",
]

#: Newtons per gram-force (1 g = 9.80665e-3 N).
N_PER_G: float = 9.80665e-3
#: Grams-force per newton.
G_PER_N: float = 1.0 / N_PER_G

#: Columns of the DataFrame returned by :func:`read_force_log`, in order.
FORCE_LOG_COLUMNS: tuple[str, ...] = ("time_s", "force_g", "depth_mm", "saturated", "line")

_KNOWN = ("time_s", "force_g", "force_N", "depth_mm")
_NAN_TEXT = frozenset({"", "nan", "na", "n/a", "null", "none"})
_MAX_LINES_LISTED = 10


@dataclass(frozen=True)
class ForceLogConfig:
    """How strictly :func:`read_force_log` treats a log.

    Parameters
    ----------
    nan_policy : {"drop", "error"}
        Rows whose force is empty or NaN: drop them (recorded as cleaning) or refuse the log.
    max_nan_fraction : float
        With ``nan_policy="drop"``, refuse the log when more than this fraction (0–1) of its
        rows have no force.
    duplicate_policy : {"average", "error"}
        Rows sharing a timestamp: average their force (and depth) into one sample, or refuse.
    gap_factor : float
        An interval between samples longer than ``gap_factor`` times the median interval is a
        gap (dimensionless); gaps are warned about, not repaired.
    saturation_policy : {"flag", "drop", "error"}
        Samples found clipped at the sensor's range: flag them (column ``saturated``), drop
        them, or refuse the log.
    saturation_min_run : int
        A run of at least this many consecutive samples exactly at the largest |force| counts
        as clipping (when the signal's noise would otherwise make such a run unlikely).
    sensor_range_g : float or None
        The sensor's full-scale |force| (g), if known; samples at or beyond
        ``(1 - 1e-6) * sensor_range_g`` are then clipped, whatever the run length.
    plausible_peak_g : tuple of float
        Peak |force| (g) expected of an insertion; a log outside this range whose values would
        be inside it in the other unit gets a wrong-units warning. Reported insertion forces stay
        well under 1.5 N (150 g): in-vivo peaks of 45–102 mN, phantom insertions of 0.1–0.2 N.
    min_samples : int
        Fewest samples a usable log has (after cleaning).
    """

    nan_policy: Literal["drop", "error"] = "drop"
    max_nan_fraction: float = 0.2
    duplicate_policy: Literal["average", "error"] = "average"
    gap_factor: float = 5.0
    saturation_policy: Literal["flag", "drop", "error"] = "flag"
    saturation_min_run: int = 5
    sensor_range_g: float | None = None
    plausible_peak_g: tuple[float, float] = (0.5, 150.0)
    min_samples: int = 3

    def __post_init__(self) -> None:
        if self.nan_policy not in ("drop", "error"):
            raise ValueError(f"nan_policy must be 'drop' or 'error', not {self.nan_policy!r}")
        if self.duplicate_policy not in ("average", "error"):
            raise ValueError(f"duplicate_policy must be 'average' or 'error', not {self.duplicate_policy!r}")
        if self.saturation_policy not in ("flag", "drop", "error"):
            raise ValueError(f"saturation_policy must be 'flag', 'drop' or 'error', not {self.saturation_policy!r}")
        if not 0.0 <= self.max_nan_fraction <= 1.0:
            raise ValueError("max_nan_fraction must be in [0, 1]")
        if self.gap_factor <= 1.0:
            raise ValueError("gap_factor must be > 1")
        if self.saturation_min_run < 2 or self.min_samples < 2:
            raise ValueError("saturation_min_run and min_samples must be >= 2")


@dataclass(frozen=True)
class CleaningStep:
    """One repair applied to a log.

    Parameters
    ----------
    action : str
        ``"drop_nan"``, ``"average_duplicates"``, ``"flag_saturation"`` or
        ``"drop_saturation"``.
    count : int
        Rows affected (for duplicates: rows merged away).
    lines : tuple of int
        Line numbers of the first affected rows (at most 10).
    detail : str
        One line of explanation.
    """

    action: str
    count: int
    lines: tuple[int, ...]
    detail: str


@dataclass(frozen=True)
class ForceLogReport:
    """What :func:`read_force_log` found and did.

    Parameters
    ----------
    path : str
        The log.
    unit : {"g", "N"}
        The unit of the force column as written (the returned data are always in g).
    columns : tuple of str
        The header's columns.
    comments : tuple of str
        The comment lines, without their ``#``.
    n_rows : int
        Data rows read.
    n_samples : int
        Samples returned (after cleaning).
    sample_period_s : float
        Median interval between samples (s).
    duration_s : float
        Last minus first time (s).
    peak_abs_g : float
        Largest |force| (g).
    n_saturated : int
        Samples found clipped (flagged or dropped).
    gaps : tuple of tuple
        ``(t_before_s, t_after_s, line)`` for each gap (line: the row after the gap).
    cleaning : tuple of CleaningStep
        Repairs applied, in order.
    warnings : tuple of str
        One-line warnings (gaps, clipping, suspicious units).
    """

    path: str
    unit: str
    columns: tuple[str, ...]
    comments: tuple[str, ...]
    n_rows: int
    n_samples: int
    sample_period_s: float
    duration_s: float
    peak_abs_g: float
    n_saturated: int = 0
    gaps: tuple[tuple[float, float, int], ...] = ()
    cleaning: tuple[CleaningStep, ...] = ()
    warnings: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """A JSON-compatible dict of the report (non-finite floats become None)."""
        return to_jsonable(self)


# --------------------------------------------------------------------------- generic CSV with comments


def read_table_lines(
    text: str, *, name: str
) -> tuple[list[str], list[list[str]], np.ndarray, list[str]]:
    """Split a CSV with ``#`` comment lines into header, rows and line numbers.

    For small tables (angles, synced) read whole; logs are read in chunks by
    :func:`read_csv_columns`, which follows the same rules.

    Parameters
    ----------
    text : str
        The file's content.
    name : str
        The file's name, for error messages.

    Returns
    -------
    header : list of str
        Column names (stripped).
    rows : list of list of str
        Data rows (cells stripped), in file order.
    lines : ndarray of int
        1-based line number of each data row.
    comments : list of str
        Comment lines without the leading ``#`` (stripped).

    Raises
    ------
    InputError
        No header, or a data row with a different number of fields than the header.
    """
    comments: list[str] = []
    line_numbers, parsed = csv_records(text.splitlines(), comments)
    if not line_numbers:
        raise InputError(name, "no header row (the file is empty or has only comments)")
    header = [h.strip() for h in parsed[0]]
    if len(set(header)) != len(header):
        raise InputError(f"{name}:{line_numbers[0]}", "duplicate column names in the header")
    rows = []
    for lineno, values in zip(line_numbers[1:], parsed[1:]):
        if len(values) != len(header):
            raise InputError(f"{name}:{lineno}", f"{len(values)} fields, but the header (line {line_numbers[0]}) has {len(header)}")
        rows.append([v.strip() for v in values])
    return header, rows, np.array(line_numbers[1:], dtype=int), comments


#: Data rows parsed at a time by :func:`read_csv_columns` (a chunk's text and arrays are the
#: reader's working memory: about 10 MB for a ROS log's lines).
CSV_CHUNK_ROWS = 20_000

#: Kinds of column :func:`read_csv_columns` parses: ``"stamp"`` keeps integer text exact
#: (int64), ``"number"`` is float, ``"text"`` keeps each cell as a stripped ``str`` (an empty
#: cell is ``""``; no text means a missing value).
ColumnKind = Literal["stamp", "number", "text"]

_NA_VALUES = sorted({v for t in _NAN_TEXT for v in (t, t.upper(), t.capitalize())})


@dataclass(frozen=True)
class CsvHeader:
    """The header of a CSV log.

    Parameters
    ----------
    name : str
        The file's name (for messages).
    columns : tuple of str
        Column names (stripped).
    line : int
        Its 1-based line number.
    """

    name: str
    columns: tuple[str, ...]
    line: int


@dataclass(frozen=True, eq=False)
class CsvColumns:
    """Columns of a CSV log read by :func:`read_csv_columns`.

    Parameters
    ----------
    header : CsvHeader
    values : dict of str to ndarray
        Each requested column: int64 for a ``"stamp"`` column whose every cell is an integer,
        object (``str``) for a ``"text"`` column, else float64 (NaN for empty and NaN cells).
    lines : ndarray of int64
        1-based line number of each data row.
    comments : tuple of str
        Comment lines without their ``#`` (stripped).
    """

    header: CsvHeader
    values: dict[str, np.ndarray]
    lines: np.ndarray
    comments: tuple[str, ...]

    @property
    def n_rows(self) -> int:
        """Data rows read."""
        return int(self.lines.size)


@contextlib.contextmanager
def _text_lines(source: str | os.PathLike | IO[str]) -> Iterator[IO[str]]:
    """An open text stream of ``source`` (a path, or a text stream used as it is)."""
    if hasattr(source, "read"):
        yield source  # type: ignore[misc]
        return
    try:
        fh = open(source, encoding="utf-8-sig", newline="")  # type: ignore[arg-type]
    except OSError as exc:
        raise InputError(os.fspath(source), f"cannot read ({type(exc).__name__}: {exc})") from None  # type: ignore[arg-type]
    with fh:
        yield fh


def _split_fields(line: str) -> list[str]:
    return next(csv.reader([line]), [])


def _chunk_values(
    text: str, index: Sequence[int], kinds: Sequence[ColumnKind], names: Sequence[str], lines: np.ndarray, name: str
) -> list[np.ndarray]:
    """Parse the requested columns of one chunk of data lines.

    The C parser reads numbers; a column it could not read as numbers (or with an infinity, or
    a stamp column that is not all integers) is re-read as text and converted by
    :func:`parse_numeric`, which names the first bad cell's line. Text columns are read as
    text, with no missing-value markers.
    """
    import io

    data = text.encode("utf-8")  # the parser reads bytes; a text buffer would hold 4 bytes a character

    def parse(as_text: Sequence[int], usecols: Sequence[int], *, markers: bool = True) -> pd.DataFrame:
        try:
            return pd.read_csv(io.BytesIO(data), header=None, usecols=list(usecols), dtype={i: object for i in as_text},
                               keep_default_na=False, na_values=_NA_VALUES if markers else None,
                               na_filter=markers, skipinitialspace=True, engine="c")
        except (pd.errors.ParserError, ValueError) as exc:
            raise InputError(f"{name}:{int(lines[0])}", f"cannot read the rows from here on as CSV ({one_line(exc)})") from None

    text_index = [i for i, kind in zip(index, kinds) if kind == "text"]
    number_index = [i for i, kind in zip(index, kinds) if kind != "text"]
    frame = parse((), number_index) if number_index else None
    texts_frame = parse(text_index, text_index, markers=False) if text_index else None
    out = []
    for i, kind, column in zip(index, kinds, names):
        if kind == "text":
            out.append(np.array([str(c).strip() for c in texts_frame[i]], dtype=object))
            continue
        col = frame[i]
        if kind == "stamp" and col.dtype.kind == "i":
            out.append(col.to_numpy(np.int64))
            continue
        if kind == "stamp" and col.dtype.kind == "f":
            values = col.to_numpy(np.float64)
            finite = values[np.isfinite(values)]
            # below 2**53 a float holds an integer stamp exactly; larger ones are re-read as text
            if not np.isinf(values).any() and (finite.size == 0 or float(np.max(np.abs(finite))) < 2.0**53):
                out.append(values)
                continue
        if kind == "number" and col.dtype.kind in "fi":
            values = col.to_numpy(np.float64)
            if not np.isinf(values).any():
                out.append(values)
                continue
        cells = parse((i,), number_index)[i].to_numpy(object)
        if kind == "stamp":
            try:
                out.append(cells.astype(np.int64))  # int() of each cell: exact, whitespace allowed
                continue
            except (ValueError, TypeError, OverflowError):
                pass
        texts = ["" if isinstance(c, float) else str(c).strip() for c in cells]
        out.append(parse_numeric(texts, lines, column=column, name=name))
    return out


def read_csv_columns(
    source: str | os.PathLike | IO[str],
    columns: Mapping[str, ColumnKind] | Callable[[CsvHeader], Mapping[str, ColumnKind]],
    *,
    name: str | None = None,
    chunk_rows: int = CSV_CHUNK_ROWS,
) -> CsvColumns:
    """Read some columns of a CSV log in chunks (``#`` lines are comments, blank lines skipped).

    The file is read line by line and parsed ``chunk_rows`` data rows at a time, so memory
    holds one chunk's text and the columns asked for, never the whole file: a 1 GB log of
    seven columns, of which two are read, needs about a fifth of its size.

    Parameters
    ----------
    source : str, PathLike or text stream
        The file, or an open text stream (e.g. ``io.StringIO``).
    columns : mapping or callable
        Column name -> ``"stamp"``, ``"number"`` or ``"text"`` (:data:`ColumnKind`); or a function of the :class:`CsvHeader`
        returning that mapping (it may raise a better-worded error for a header it refuses).
    name : str, optional
        The file's name in messages (default: the path).
    chunk_rows : int
        Data rows per chunk.

    Returns
    -------
    CsvColumns

    Raises
    ------
    InputError
        No header, duplicate column names, a requested column missing, a row with another
        number of fields than the header, text or an infinity in a number column (one line
        naming the file and the line).
    """
    label = name if name is not None else os.fspath(source) if not hasattr(source, "read") else "<csv>"  # type: ignore[arg-type]
    comments: list[str] = []
    header: CsvHeader | None = None
    wanted: dict[str, ColumnKind] = {}
    index: list[int] = []
    parts: list[list[np.ndarray]] = []
    line_parts: list[np.ndarray] = []
    n_fields = 0
    n_commas = 0
    kept: list[str] = []
    kept_lines: list[int] = []

    def flush() -> None:
        if not kept:
            return
        lines = np.asarray(kept_lines, dtype=np.int64)
        parts.append(_chunk_values("".join(kept), index, list(wanted.values()), list(wanted), lines, label))
        line_parts.append(lines)
        kept.clear()
        kept_lines.clear()

    with _text_lines(source) as fh:
        try:
            for lineno, line in data_lines(fh, comments):
                if header is None:
                    names = tuple(h.strip() for h in _split_fields(line))
                    if len(set(names)) != len(names):
                        raise InputError(f"{label}:{lineno}", "duplicate column names in the header")
                    header = CsvHeader(label, names, lineno)
                    wanted = dict(columns(header) if callable(columns) else columns)
                    missing = [c for c in wanted if c not in names]
                    if missing:
                        raise InputError(f"{label}:{lineno}", f"missing column(s) {', '.join(missing)}; found {', '.join(names)}")
                    index = [names.index(c) for c in wanted]
                    n_fields, n_commas = len(names), line.count(",")
                    continue
                if line.count(",") != n_commas:  # quoted commas are rare: let the csv module decide
                    fields = len(_split_fields(line))
                    if fields != n_fields:
                        raise InputError(f"{label}:{lineno}", f"{fields} fields, but the header (line {header.line}) has {n_fields}")
                kept.append(line if line.endswith("\n") else line + "\n")
                kept_lines.append(lineno)
                if len(kept) >= chunk_rows:
                    flush()
        except UnicodeDecodeError as exc:
            raise InputError(label, f"cannot read as text ({exc})") from None
        flush()
    if header is None:
        raise InputError(label, "no header row (the file is empty or has only comments)")
    values: dict[str, np.ndarray] = {}
    for j, column in enumerate(wanted):
        pieces = [p[j] for p in parts]
        if not pieces:
            values[column] = np.empty(0, dtype={"stamp": np.int64, "text": object}.get(wanted[column], np.float64))
        elif wanted[column] == "text" or all(p.dtype.kind == "i" for p in pieces):
            values[column] = np.concatenate(pieces)
        else:
            values[column] = np.concatenate([p.astype(np.float64) for p in pieces])
    lines = np.concatenate(line_parts) if line_parts else np.empty(0, dtype=np.int64)
    return CsvColumns(header=header, values=values, lines=lines, comments=tuple(comments))


def parse_numeric(
    cells: Sequence[str], lines: np.ndarray, *, column: str, name: str, allow_nan: bool = True
) -> np.ndarray:
    """Convert a column of CSV cells to floats, refusing text and infinities.

    Parameters
    ----------
    cells : sequence of str
        The column's cells.
    lines : ndarray of int
        Their line numbers (for messages).
    column : str
        Column name (for messages).
    name : str
        File name (for messages).
    allow_nan : bool
        Whether empty cells and ``nan``/``NA``/``null`` become NaN (else an error).

    Returns
    -------
    ndarray of float
        The values, NaN where a cell was empty or NaN.

    Raises
    ------
    InputError
        ``"<name>:<line>: <column> 'abc' is not a number"`` for the first bad cell.
    """
    text = pd.Series(list(cells), dtype=object)
    values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
    is_nan_text = text.str.lower().isin(_NAN_TEXT).to_numpy()
    bad = np.isnan(values) & ~is_nan_text
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{name}:{lines[i]}", f"{column} {cells[i]!r} is not a number")
    inf = np.isinf(values)
    if inf.any():
        i = int(np.argmax(inf))
        raise InputError(f"{name}:{lines[i]}", f"{column} {cells[i]!r} is not finite")
    if not allow_nan and np.isnan(values).any():
        i = int(np.argmax(np.isnan(values)))
        raise InputError(f"{name}:{lines[i]}", f"{column} is empty or NaN")
    return values


# --------------------------------------------------------------------------- checks


def _columns(header: list[str], name: str, header_line: int) -> tuple[str, str]:
    """The time and force column names, or an error naming what is wrong with the header."""
    where = f"{name}:{header_line}"
    found = ", ".join(header) or "none"
    if "force_g" in header and "force_N" in header:
        raise InputError(where, "both force_g and force_N columns; keep one")
    force_col = "force_g" if "force_g" in header else "force_N" if "force_N" in header else None
    missing = [c for c, ok in (("time_s", "time_s" in header), ("force_g or force_N", force_col is not None)) if not ok]
    if missing:
        hints = [h for h in header if h not in _KNOWN and (h.lower().startswith(("time", "force")) or h.lower() == "t")]
        hint = f" (not names tympani reads: {', '.join(hints)}; use time_s, force_g or force_N, depth_mm)" if hints else ""
        raise InputError(where, f"missing column(s) {', '.join(missing)}; found {found}{hint}")
    return "time_s", force_col  # type: ignore[return-value]


def _check_time(time_s: np.ndarray, lines: np.ndarray, name: str, label: str = "time_s") -> None:
    """Refuse NaN times and times that go backwards (equal times are handled as duplicates).

    ``label`` names the time column in messages (``"time_s"``, ``"[force] time_column '%time'"``).
    """
    if np.isnan(time_s).any():
        i = int(np.argmax(np.isnan(time_s)))
        raise InputError(f"{name}:{lines[i]}", f"{label} is empty or NaN")
    back = np.diff(time_s) < 0
    if back.any():
        i = int(np.argmax(back)) + 1
        raise InputError(
            f"{name}:{lines[i]}",
            f"{label} goes backwards ({time_s[i]:.6g} s after {time_s[i - 1]:.6g} s on line {lines[i - 1]})",
        )


def _listed(lines: np.ndarray) -> tuple[int, ...]:
    return tuple(int(v) for v in lines[:_MAX_LINES_LISTED])


def _average_duplicates(
    time_s: np.ndarray, force: np.ndarray, depth: np.ndarray, lines: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Merge rows with equal (non-decreasing) timestamps by averaging.

    Returns the merged arrays and the line numbers of the rows merged away.
    """
    start = np.r_[True, np.diff(time_s) > 0]
    group = np.cumsum(start) - 1
    counts = np.bincount(group)
    f = np.bincount(group, weights=force) / counts
    finite_d = np.isfinite(depth)
    d_count = np.bincount(group, weights=finite_d.astype(float))
    d_sum = np.bincount(group, weights=np.where(finite_d, depth, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(d_count > 0, d_sum / np.maximum(d_count, 1), np.nan)
    return time_s[start], f, d, lines[start], lines[~start]


def find_saturation(force_g: np.ndarray, *, min_run: int, sensor_range_g: float | None = None) -> np.ndarray:
    """Samples that look clipped at the sensor's range.

    A sample is clipped when ``|force| >= (1 - 1e-6) * sensor_range_g`` (range known), or when
    it equals the signal's largest (or, for a negative peak, smallest) value and that value is
    a rail: it is held for a run of at least ``min_run`` consecutive samples somewhere, *and*
    the signal is noisy enough that such a run is unlikely by chance: the median absolute sample-to-sample change exceeds
    twice the smallest non-zero change (the quantisation step). A quantised, almost noiseless
    signal that rests at its maximum (the robot stopped) is therefore not flagged.

    Parameters
    ----------
    force_g : ndarray
        Force samples (g), NaN-free.
    min_run : int
        Shortest flat run that counts (samples).
    sensor_range_g : float, optional
        Full-scale |force| of the sensor (g).

    Returns
    -------
    ndarray of bool
        True for clipped samples.
    """
    f = np.asarray(force_g, dtype=float)
    out = np.zeros(f.shape, dtype=bool)
    if f.size == 0:
        return out
    if sensor_range_g is not None:
        out |= np.abs(f) >= (1.0 - 1e-6) * float(sensor_range_g)
    if f.size < min_run:
        return out
    steps = np.abs(np.diff(f))
    nonzero = steps[steps > 0]
    if nonzero.size == 0:
        return out
    if np.median(steps) <= 2.0 * nonzero.min():
        return out
    peak = np.max(np.abs(f))
    for extreme in {float(f.max()), float(f.min())}:
        if abs(extreme) != peak:
            continue
        at = f == extreme
        edges = np.diff(np.r_[0, at.astype(np.int8), 0])
        runs = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
        if runs.size and runs.max() >= min_run:
            out |= at  # the value is a rail: every sample on it is clipped, short runs too
    return out


def _unit_warning(column: str, peak_abs: float, cfg: ForceLogConfig) -> str | None:
    """A warning when the force values look like they are in the other unit."""
    lo, hi = cfg.plausible_peak_g
    if column == "force_g":
        peak_g, other_g = peak_abs, peak_abs * G_PER_N
        if peak_g < lo and lo <= other_g <= hi:
            return (f"force_g peaks at {peak_g:.4g}, which is tiny for an insertion; if the values are newtons "
                    f"({peak_abs:.4g} N = {other_g:.4g} g), name the column force_N")
    else:
        peak_g, other_g = peak_abs * G_PER_N, peak_abs
        if peak_g > hi and lo <= other_g <= hi:
            return (f"force_N peaks at {peak_abs:.4g} N = {peak_g:.4g} g, which is large for an insertion; if the "
                    f"values are grams-force, name the column force_g (if millinewtons, divide by 1000)")
    return None


# --------------------------------------------------------------------------- reader


@dataclass(frozen=True)
class ForceSamples:
    """A force log's samples before cleaning, in tympani's units (s, g, mm), and how messages
    name things.

    Parameters
    ----------
    time_s : ndarray
        Sample times (s; NaN allowed, refused by the cleaning).
    force_g : ndarray
        Force (g; NaN where the cell was empty).
    depth_mm : ndarray
        Insertion depth (mm; NaN when not logged).
    lines : ndarray of int
        1-based line number of each row in the file.
    name : str
        The file, for messages and the report.
    unit : str
        The force column's unit as written (``"g"``, ``"N"``, ``"mN"``).
    columns : tuple of str
        The header's columns.
    comments : tuple of str
        Comment lines without their ``#``.
    time_label, force_label : str
        How messages name the time and force columns (``"time_s"``, ``"force_g"``, or a log
        format's ``"[force] column 'field.Fz'"``).
    check_units : bool
        Warn when the values look like they are in the other unit (tympani's own columns only:
        a log format states its unit).
    """

    time_s: np.ndarray
    force_g: np.ndarray
    depth_mm: np.ndarray
    lines: np.ndarray
    name: str
    unit: str
    columns: tuple[str, ...] = ()
    comments: tuple[str, ...] = ()
    time_label: str = "time_s"
    force_label: str = "force_g"
    check_units: bool = True


def clean_force_samples(samples: ForceSamples, cfg: ForceLogConfig = ForceLogConfig()) -> tuple[pd.DataFrame, ForceLogReport]:
    """Validate and clean a force log's samples (the module table), whatever form it was read from.

    Parameters
    ----------
    samples : ForceSamples
        Times (s), forces (g), depths (mm) and line numbers, as read.
    cfg : ForceLogConfig
        Policies.

    Returns
    -------
    data : DataFrame
        :data:`FORCE_LOG_COLUMNS`: ``time_s`` (s, strictly increasing), ``force_g`` (g),
        ``depth_mm`` (mm, NaN when absent), ``saturated`` (bool), ``line`` (the row's line in
        the file; for averaged duplicates the first one).
    report : ForceLogReport
        What was found and done.

    Raises
    ------
    InputError
        ``"<name>:<line>: <problem>"``, one line, for every refused log.
    """
    name, force_col = samples.name, samples.force_label
    time_s, force, depth, lines = samples.time_s, samples.force_g, samples.depth_mm, samples.lines
    if time_s.size == 0:
        raise InputError(name, "no samples (only a header)")
    _check_time(time_s, lines, name, samples.time_label)
    n_rows = int(time_s.size)
    cleaning: list[CleaningStep] = []
    warnings: list[str] = []

    nan_force = np.isnan(force)
    if nan_force.any():
        first = f"{name}:{lines[int(np.argmax(nan_force))]}"
        if cfg.nan_policy == "error":
            raise InputError(first, f"{force_col} is empty or NaN")
        frac = nan_force.mean()
        if frac > cfg.max_nan_fraction:
            raise InputError(first, f"{force_col} is empty or NaN in {nan_force.sum()} of {n_rows} rows "
                                    f"({100 * frac:.0f}% > {100 * cfg.max_nan_fraction:.0f}%)")
        cleaning.append(CleaningStep("drop_nan", int(nan_force.sum()), _listed(lines[nan_force]),
                                     f"dropped {int(nan_force.sum())} row(s) with an empty or NaN {force_col}"))
        keep = ~nan_force
        time_s, force, depth, lines = time_s[keep], force[keep], depth[keep], lines[keep]

    dup = np.r_[False, np.diff(time_s) == 0]
    if dup.any():
        if cfg.duplicate_policy == "error":
            i = int(np.argmax(dup))
            raise InputError(f"{name}:{lines[i]}", f"duplicate {samples.time_label} {time_s[i]:.6g} s (also on line {lines[i - 1]})")
        time_s, force, depth, lines, merged = _average_duplicates(time_s, force, depth, lines)
        cleaning.append(CleaningStep("average_duplicates", int(merged.size), _listed(merged),
                                     f"averaged {int(merged.size)} row(s) sharing a timestamp with the row before"))

    if time_s.size < cfg.min_samples:
        raise InputError(name, f"only {time_s.size} usable sample(s); need at least {cfg.min_samples}")

    dt = np.diff(time_s)
    period = float(np.median(dt))
    gap_idx = np.flatnonzero(dt > cfg.gap_factor * period)
    gaps = tuple((float(time_s[i]), float(time_s[i + 1]), int(lines[i + 1])) for i in gap_idx)
    if gaps:
        longest = max(b - a for a, b, _ in gaps)
        warnings.append(f"{len(gaps)} gap(s) longer than {cfg.gap_factor:g} median sample periods "
                        f"({period:.4g} s), the first before line {gaps[0][2]}, the longest {longest:.4g} s")

    peak = float(np.max(np.abs(force)))
    if samples.check_units:
        unit_note = _unit_warning(force_col, peak / (G_PER_N if force_col == "force_N" else 1.0), cfg)
        if unit_note:
            warnings.append(unit_note)

    saturated = find_saturation(force, min_run=cfg.saturation_min_run, sensor_range_g=cfg.sensor_range_g)
    n_sat = int(saturated.sum())
    if n_sat:
        first_line = int(lines[int(np.argmax(saturated))])
        what = (f"{n_sat} sample(s) look clipped at the sensor's range "
                f"(|force| = {np.max(np.abs(force[saturated])):.4g} g), first on line {first_line}")
        if cfg.saturation_policy == "error":
            raise InputError(f"{name}:{first_line}", what)
        if cfg.saturation_policy == "drop":
            cleaning.append(CleaningStep("drop_saturation", n_sat, _listed(lines[saturated]), f"dropped {what}"))
            keep = ~saturated
            time_s, force, depth, lines, saturated = time_s[keep], force[keep], depth[keep], lines[keep], saturated[keep]
            if time_s.size < cfg.min_samples:
                raise InputError(name, f"only {time_s.size} sample(s) left after dropping clipped ones")
        else:
            cleaning.append(CleaningStep("flag_saturation", n_sat, _listed(lines[saturated]),
                                         f"flagged {what} in column 'saturated'"))
        warnings.append(what)

    data = pd.DataFrame({"time_s": time_s, "force_g": force, "depth_mm": depth, "saturated": saturated,
                         "line": lines.astype(int, copy=False)}, copy=False)
    report = ForceLogReport(
        path=name,
        unit=samples.unit,
        columns=samples.columns,
        comments=samples.comments,
        n_rows=n_rows,
        n_samples=len(data),
        sample_period_s=period,
        duration_s=float(time_s[-1] - time_s[0]),
        peak_abs_g=float(np.max(np.abs(force))) if force.size else math.nan,
        n_saturated=n_sat,
        gaps=gaps,
        cleaning=tuple(cleaning),
        warnings=tuple(warnings),
    )
    return data, report


def _spec_columns(header: CsvHeader) -> dict[str, ColumnKind]:
    """The columns tympani reads from a force log's header (time_s, the force column, depth_mm if any)."""
    time_col, force_col = _columns(list(header.columns), header.name, header.line)
    wanted: dict[str, ColumnKind] = {time_col: "number", force_col: "number"}
    if "depth_mm" in header.columns:
        wanted["depth_mm"] = "number"
    return wanted


def _read_spec_force_log(source: str | os.PathLike | IO[str], name: str, cfg: ForceLogConfig) -> tuple[pd.DataFrame, ForceLogReport]:
    table = read_csv_columns(source, _spec_columns, name=name)
    force_col = "force_N" if "force_N" in table.values else "force_g"
    force = table.values[force_col]
    samples = ForceSamples(
        time_s=table.values["time_s"].astype(float),
        force_g=force * G_PER_N if force_col == "force_N" else force,
        depth_mm=table.values.get("depth_mm", np.full(table.n_rows, np.nan)),
        lines=table.lines,
        name=name,
        unit="N" if force_col == "force_N" else "g",
        columns=table.header.columns,
        comments=table.comments,
        force_label=force_col,
    )
    return clean_force_samples(samples, cfg)


def parse_force_log(text: str, *, name: str = "<force log>", cfg: ForceLogConfig = ForceLogConfig()) -> tuple[pd.DataFrame, ForceLogReport]:
    """Parse, validate and clean the text of a force log.

    Parameters
    ----------
    text : str
        The CSV content, in tympani's own form (docs/file-formats.md).
    name : str
        The log's name or path, used in messages and the report.
    cfg : ForceLogConfig
        Policies (see the module table).

    Returns
    -------
    data : DataFrame
        :data:`FORCE_LOG_COLUMNS`: ``time_s`` (s, strictly increasing), ``force_g`` (g),
        ``depth_mm`` (mm, NaN when absent), ``saturated`` (bool), ``line`` (the row's line in
        the file; for averaged duplicates the first one).
    report : ForceLogReport
        What was found and done.

    Raises
    ------
    InputError
        ``"<name>:<line>: <problem>"``, one line, for every refused log (module table).
    """
    import io

    return _read_spec_force_log(io.StringIO(text), name, cfg)


def read_force_log(path: str | os.PathLike, cfg: ForceLogConfig = ForceLogConfig()) -> tuple[pd.DataFrame, ForceLogReport]:
    """Read, validate and clean a force log file (docs/file-formats.md), in chunks (:func:`read_csv_columns`).

    Parameters
    ----------
    path : str or PathLike
        The CSV file.
    cfg : ForceLogConfig
        Policies (see the module docstring).

    Returns
    -------
    data : DataFrame
        ``time_s`` (s), ``force_g`` (g), ``depth_mm`` (mm or NaN), ``saturated`` (bool),
        ``line`` (int); see :func:`parse_force_log`.
    report : ForceLogReport
        Cleaning steps and warnings.

    Raises
    ------
    InputError
        Missing or unreadable file, or a log refused by the checks (one line naming the file
        and, where it applies, the line).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such force log" if not p.exists() else "force log is not a file")
    return _read_spec_force_log(p, str(p), cfg)

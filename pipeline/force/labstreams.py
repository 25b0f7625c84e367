"""A lab's force, depth and angle logs as they are, read through its log format (docs/lab-logs.md).

:func:`read_lab_logs` reads one trial's logs (CSV in chunks, or ROS bags) and puts them on the
*force clock*:

- **Force** (``[force]``): the time column in its unit, the force column times unit, sign and
  gain, in g; then the same checks and cleaning as a force log in tympani's own form
  (:func:`tympani.pipeline.force.forcelog.clean_force_samples`). Integer stamps (epoch nanoseconds overflow a
  float's exact integers) stay int64 until the force log's first stamp is subtracted, so the
  synced table's ``time_s`` counts seconds from the force log's first sample, exactly. Without
  ``[force]`` the force log is in tympani's own form and ``time_s`` is its own.
- **Depth** (``[depth]``, the manifest's ``depth`` column): the stage's position log on the same
  clock. Its motion start and stop are found (:func:`tympani.pipeline.force.motion.find_motion`) and its
  position is interpolated linearly onto the force samples as ``depth_mm`` (empty outside the
  depth log: no extrapolation). Without ``[depth]`` a depth log has tympani's columns ``time_s`` and
  ``depth_mm``.
- **Angles** (``[angles]``, the manifest's ``angles`` column): another tracker's track, in rad,
  with ``theta_tip`` and whichever of ``theta_bot``/``theta_con`` it has (the third follows from
  the other two; a tip-only track leaves both empty). Its zero gives the clock offset
  (``video_t0_s``, the force-clock time of the track's ``t = 0``): ``"log"`` 0 (the track's
  stamps are put on the force clock like the depth's), ``"motion_start"`` the depth log's motion
  start (with its uncertainty), a number that many seconds.

Every refusal is an :class:`~tympani.vision.errors.InputError` naming the file (for a bag
``file#topic``) and the log format's key: a column the log lacks, a clock that goes backwards,
a depth log that never moves, streams that do not overlap in time.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from tympani.pipeline.force.forcelog import (
    ColumnKind,
    CsvHeader,
    ForceLogConfig,
    ForceLogReport,
    ForceSamples,
    clean_force_samples,
    read_csv_columns,
    read_force_log,
)
from tympani.pipeline.force.logformat import TIME_UNITS, AnglesFormat, DepthFormat, ForceFormat, LogFormat, StreamFormat
from tympani.pipeline.force.motion import Motion, NoMotion, find_motion
from tympani.vision.errors import InputError

__all__ = [
    "Clock",
    "RawStream",
    "DepthLog",
    "AngleTrack",
    "LabLogs",
    "read_stream",
    "read_force_stream",
    "read_depth_log",
    "read_angle_track",
    "depth_on_force_clock",
    "track_coverage",
    "read_lab_logs",
]

_ANGLES = ("theta_tip", "theta_bot", "theta_con")


@dataclass(frozen=True)
class Clock:
    """The force clock: ``time_s = (stamp - origin)`` in seconds.

    Parameters
    ----------
    origin_ns : int or None
        The force log's first stamp in ns, exact; None: stamps are taken as they are (the
        ``time_s`` of a force log in tympani's own form).
    origin : str
        That stamp as written, with its unit (``"1566497791436127452 ns"``), for the report.
    """

    origin_ns: int | None = None
    origin: str = ""

    def seconds(self, stamps: np.ndarray, unit: str) -> np.ndarray:
        """Stamps in ``unit`` as seconds on this clock.

        Integer stamps are scaled to ns and the origin subtracted in int64 (exact), then
        converted; float stamps lose what a float cannot hold, the origin is subtracted in
        their own unit first.
        """
        k = TIME_UNITS[unit]
        if stamps.dtype.kind in "iu":
            big = int(np.max(np.abs(stamps))) if stamps.size else 0
            if big <= (2**62) // k and (self.origin_ns is None or abs(self.origin_ns) < 2**62):
                ns = stamps.astype(np.int64)  # a copy, worked in place (big logs: one temporary array)
                ns *= k
                ns -= self.origin_ns or 0
                out = ns.astype(np.float64)
                del ns
                out /= 1e9
                return out
        origin_units = 0.0 if self.origin_ns is None else self.origin_ns / k
        out = stamps.astype(np.float64)
        out -= origin_units
        out *= k / 1e9
        return out


@dataclass(frozen=True, eq=False)
class RawStream:
    """One stream as logged: stamps in the format's unit, values in the log's units.

    Parameters
    ----------
    name : str
        For messages: the path, or ``path#topic`` for a bag.
    stamps : ndarray
        int64 when every stamp is an integer, else float64.
    values : dict of str to ndarray
        The fields asked for, by key (float64, NaN for empty cells).
    lines : ndarray of int64
        CSV line (or bag message number) of each sample.
    columns : tuple of str
        The CSV header (a bag: the fields read).
    comments : tuple of str
        CSV comment lines.
    time_unit : str
        Unit of ``stamps``: the format's ``time_unit``, or ``"ns"`` for a bag's record time or
        a ROS time field.
    """

    name: str
    stamps: np.ndarray
    values: dict[str, np.ndarray]
    lines: np.ndarray
    columns: tuple[str, ...] = ()
    comments: tuple[str, ...] = ()
    time_unit: str = "s"


@dataclass(frozen=True, eq=False)
class DepthLog:
    """A depth log on the force clock.

    Parameters
    ----------
    path : str
        The file.
    time_s : ndarray
        Sample times (s, force clock, strictly increasing).
    depth_mm : ndarray
        Positions (mm).
    motion : Motion
        Its motion start and stop (s, force clock).
    n_rows : int
        Rows read (before dropping empty depths and merging equal stamps).
    warnings : tuple of str
    """

    path: str
    time_s: np.ndarray
    depth_mm: np.ndarray
    motion: Motion
    n_rows: int
    warnings: tuple[str, ...] = ()

    def summary(self) -> dict:
        """A JSON-ready summary for the sync report (times in s on the force clock)."""
        return {"path": self.path, "n_samples": int(self.time_s.size), "n_rows": self.n_rows,
                "span_s": [float(self.time_s[0]), float(self.time_s[-1])], "motion": self.motion}


@dataclass(frozen=True, eq=False)
class AngleTrack:
    """Another tracker's angle track, as an angles table on its own clock, and its offset.

    Parameters
    ----------
    path : str
        The file.
    angles : DataFrame
        ``time_s`` (s, the track's clock), ``theta_tip``, ``theta_bot``, ``theta_con`` (rad, NaN
        when the tracker does not give them), ``ok`` (theta_tip measured), ``frame`` (row
        number), ``line``; ``attrs["warnings"]`` as :func:`tympani.pipeline.force.sync.read_angles_table`.
    offset_s : float
        ``video_t0_s``: force-clock time of the track's ``t = 0`` (s).
    uncertainty_s : float
        Its standard uncertainty (s): that of the motion start for ``zero = "motion_start"``,
        else 0.
    zero : str
        ``"log"``, ``"motion_start"`` or the number's text.
    """

    path: str
    angles: pd.DataFrame
    offset_s: float
    uncertainty_s: float
    zero: str


@dataclass(frozen=True, eq=False)
class LabLogs:
    """One trial's logs on the force clock.

    Parameters
    ----------
    force : DataFrame
        :data:`tympani.pipeline.force.forcelog.FORCE_LOG_COLUMNS`; ``depth_mm`` from the depth log when the
        trial has one.
    force_report : ForceLogReport
    clock : Clock
    depth : DepthLog or None
    track : AngleTrack or None
        Another tracker's angles (the format's ``[angles]``), or None (tympani's own angles
        table, or a video).
    warnings : tuple of str
    """

    force: pd.DataFrame
    force_report: ForceLogReport
    clock: Clock
    depth: DepthLog | None = None
    track: AngleTrack | None = None
    warnings: tuple[str, ...] = ()


# --------------------------------------------------------------------------- one stream


def _is_bag(path: Path) -> bool:
    from tympani.pipeline.force.rosbag import is_bag

    return is_bag(path)


def read_stream(path: str | os.PathLike, fmt: StreamFormat, fields: Mapping[str, tuple[str, str]]) -> RawStream:
    """Read a stream's time and value fields from a CSV log (in chunks) or a ROS bag.

    Parameters
    ----------
    path : str or PathLike
        The log.
    fmt : StreamFormat
        Its section of the log format (clock, topic).
    fields : mapping
        Key -> (the format's key naming it, the column or field path), e.g.
        ``{"force": ("column", "field.Fz")}``.

    Returns
    -------
    RawStream

    Raises
    ------
    InputError
        Missing file; a bag without ``topic`` or a CSV with one; a column or field the log
        lacks; unreadable cells (one line naming the file and the key).
    """
    p = Path(path)
    name = str(p)
    if not p.exists():
        raise InputError(p, f"no such {fmt.section} log")
    if _is_bag(p):
        if fmt.topic is None:
            raise InputError(p, f"[{fmt.section}] topic: this is a ROS bag; the log format must name its topic")
        from tympani.pipeline.force.rosbag import read_bag_fields

        bag = read_bag_fields(p, fmt.topic, {k: col for k, (_, col) in fields.items()}, time_field=fmt.time_column,
                              section=fmt.section, key_of={k: key for k, (key, _) in fields.items()})
        return RawStream(name=f"{name}#{fmt.topic}", stamps=bag.stamps, values=bag.values, lines=bag.index,
                         columns=tuple(col for _, col in fields.values()),
                         time_unit="ns" if bag.stamps_ns else fmt.time_unit)
    if fmt.topic is not None:
        raise InputError(p, f"[{fmt.section}] topic {fmt.topic!r} is for ROS bags (.bag, .mcap), and this log is "
                            "not one")
    if not p.is_file():
        raise InputError(p, f"{fmt.section} log is not a file")
    time_col = fmt.time_column
    assert time_col is not None  # a CSV section always names its time column (logformat checks)

    def wanted(header: CsvHeader) -> dict[str, ColumnKind]:
        named = [("time_column", time_col), *fields.values()]
        for key, col in named:
            if col not in header.columns:
                raise InputError(f"{name}:{header.line}", f"[{fmt.section}] {key} {col!r} is not a column of the log "
                                                         f"(found: {', '.join(header.columns)})")
        out: dict[str, ColumnKind] = {time_col: "stamp"}
        out.update({col: "number" for _, col in fields.values()})
        return out

    table = read_csv_columns(p, wanted, name=name)
    return RawStream(name=name, stamps=table.values[time_col], values={k: table.values[col] for k, (_, col) in fields.items()},
                     lines=table.lines, columns=table.header.columns, comments=table.comments, time_unit=fmt.time_unit)


def _first_stamp(raw: RawStream, fmt: StreamFormat) -> int | float:
    stamps = raw.stamps
    if stamps.size == 0:
        raise InputError(raw.name, f"[{fmt.section}] no samples (only a header)")
    if stamps.dtype.kind in "iu":
        return int(stamps[0])
    finite = np.flatnonzero(np.isfinite(stamps))
    if finite.size == 0:
        raise InputError(f"{raw.name}:{int(raw.lines[0])}", f"[{fmt.section}] time_column {fmt.time_column!r} is empty or NaN")
    return float(stamps[finite[0]])


def _time_label(fmt: StreamFormat) -> str:
    return f"[{fmt.section}] time_column {fmt.time_column!r}" if fmt.time_column else f"[{fmt.section}] the bag's record time"


def _check_increasing(t: np.ndarray, lines: np.ndarray, name: str, label: str) -> None:
    """Refuse NaN or backward times (equal ones are merged by the caller)."""
    if np.isnan(t).any():
        i = int(np.argmax(np.isnan(t)))
        raise InputError(f"{name}:{lines[i]}", f"{label} is empty or NaN")
    back = np.diff(t) < 0
    if back.any():
        i = int(np.argmax(back)) + 1
        raise InputError(f"{name}:{lines[i]}", f"{label} goes backwards ({t[i]:.6g} s after {t[i - 1]:.6g} s on line "
                                               f"{lines[i - 1]})")


def _merge_equal(t: np.ndarray, columns: dict[str, np.ndarray], lines: np.ndarray
                 ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, int]:
    """Average the rows that share a time (non-decreasing ``t``); returns the merged arrays and
    how many rows were merged away."""
    start = np.r_[True, np.diff(t) > 0]
    if start.all():
        return t, columns, lines, 0
    group = np.cumsum(start) - 1
    out = {}
    for key, v in columns.items():
        finite = np.isfinite(v)
        count = np.bincount(group, weights=finite.astype(float))
        total = np.bincount(group, weights=np.where(finite, v, 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            out[key] = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return t[start], out, lines[start], int((~start).sum())


# --------------------------------------------------------------------------- force


def read_force_stream(path: str | os.PathLike, fmt: ForceFormat, cfg: ForceLogConfig = ForceLogConfig()
                      ) -> tuple[pd.DataFrame, ForceLogReport, Clock]:
    """Read a force log through its ``[force]`` section.

    Returns
    -------
    data : DataFrame
        :data:`tympani.pipeline.force.forcelog.FORCE_LOG_COLUMNS`: ``time_s`` (s from the first sample),
        ``force_g`` (g: value × unit × sign × gain), ``depth_mm`` (NaN), ``saturated``, ``line``.
    report : ForceLogReport
    clock : Clock
        The force clock (origin: the first stamp).
    """
    raw = read_stream(path, fmt, {"force": ("column", fmt.column)})
    first = _first_stamp(raw, fmt)
    k = TIME_UNITS[raw.time_unit]
    origin_ns = first * k if isinstance(first, int) else int(round(first * k))
    clock = Clock(origin_ns=origin_ns, origin=f"{first} {raw.time_unit}")
    force = raw.values["force"]
    force *= fmt.to_g  # in place: a big log's arrays are not copied more than needed
    samples = ForceSamples(
        time_s=clock.seconds(raw.stamps, raw.time_unit),
        force_g=force,
        depth_mm=np.full(raw.stamps.size, np.nan),
        lines=raw.lines,
        name=raw.name,
        unit=fmt.unit,
        columns=raw.columns,
        comments=raw.comments,
        time_label=_time_label(fmt),
        force_label=f"[force] column {fmt.column!r}",
        check_units=False,
    )
    del raw, force
    data, report = clean_force_samples(samples, cfg)
    return data, report, clock


# --------------------------------------------------------------------------- depth


def read_depth_log(path: str | os.PathLike, fmt: DepthFormat | None, clock: Clock) -> DepthLog:
    """Read a depth log, put it on the force clock and find its motion.

    Parameters
    ----------
    path : str or PathLike
        The log (CSV or bag).
    fmt : DepthFormat or None
        Its ``[depth]`` section; None: tympani's columns ``time_s`` (s) and ``depth_mm`` (mm).
    clock : Clock
        The force clock (the depth log shares it).

    Returns
    -------
    DepthLog

    Raises
    ------
    InputError
        Missing columns, a clock that goes backwards, fewer than 3 positions, a log that never
        moves or starts while moving (one line naming the file and the key).
    """
    section = fmt if fmt is not None else DepthFormat(section="depth", time_column="time_s", time_unit="s",
                                                      column="depth_mm", unit="mm")
    raw = read_stream(path, section, {"depth": ("column", section.column)})
    if raw.stamps.size == 0:
        raise InputError(raw.name, "[depth] no samples (only a header)")
    t = clock.seconds(raw.stamps, raw.time_unit)
    depth = raw.values["depth"] * section.to_mm
    lines = raw.lines
    _check_increasing(t, lines, raw.name, _time_label(section))
    warnings = []
    keep = np.isfinite(depth)
    if not keep.all():
        warnings.append(f"{int((~keep).sum())} row(s) of the depth log without a position were left out")
        t, depth, lines = t[keep], depth[keep], lines[keep]
    t, merged, lines, n_merged = _merge_equal(t, {"depth": depth}, lines)
    depth = merged["depth"]
    if n_merged:
        warnings.append(f"{n_merged} row(s) of the depth log sharing a time with the row before were averaged")
    if t.size < 3:
        raise InputError(raw.name, f"[depth] column {section.column!r}: only {t.size} position(s)")
    try:
        motion = find_motion(t, depth)
    except NoMotion as exc:
        raise InputError(raw.name, f"[depth] column {section.column!r} {exc}") from None
    return DepthLog(path=raw.name, time_s=t, depth_mm=depth, motion=motion, n_rows=int(raw.stamps.size),
                    warnings=tuple(warnings))


def depth_on_force_clock(depth: DepthLog, force_time_s: np.ndarray) -> np.ndarray:
    """The depth log's position (mm) at force times (s), linearly interpolated; NaN outside the
    depth log."""
    t = np.asarray(force_time_s, dtype=float)
    inside = (t >= depth.time_s[0]) & (t <= depth.time_s[-1])
    return np.where(inside, np.interp(t, depth.time_s, depth.depth_mm), np.nan)


def _span(t: np.ndarray) -> str:
    return f"{t[0]:.4g} to {t[-1]:.4g} s"


# --------------------------------------------------------------------------- angles


def read_angle_track(path: str | os.PathLike, fmt: AnglesFormat, clock: Clock, depth: DepthLog | None,
                     *, format_path: str = "") -> AngleTrack:
    """Read another tracker's angle track and find its clock offset from ``zero``.

    Parameters
    ----------
    path : str or PathLike
        The track (CSV or bag).
    fmt : AnglesFormat
        The ``[angles]`` section.
    clock : Clock
        The force clock (for ``zero = "log"``).
    depth : DepthLog or None
        The trial's depth log (for ``zero = "motion_start"``).
    format_path : str
        The log format file, named when ``zero`` cannot be used.

    Returns
    -------
    AngleTrack

    Raises
    ------
    InputError
        ``zero = "motion_start"`` without a depth log; missing columns; a clock that goes
        backwards; no finite ``theta_tip`` (one line naming the file and the key).
    """
    if fmt.zero == "motion_start" and depth is None:
        raise InputError(format_path or path, "[angles] zero 'motion_start' needs the trial's depth log "
                                              "(the manifest's depth column)")
    fields = {spec: (spec, col) for spec, col in fmt.columns.items()}
    raw = read_stream(path, fmt, fields)
    if raw.stamps.size == 0:
        raise InputError(raw.name, "[angles] no samples (only a header)")
    own = Clock()  # the track's own clock: its stamps as they are
    t = (clock if fmt.zero == "log" else own).seconds(raw.stamps, raw.time_unit)
    lines = raw.lines
    _check_increasing(t, lines, raw.name, _time_label(fmt))
    values = {k: raw.values[k] * fmt.to_rad for k in fmt.columns}
    t, values, lines, n_merged = _merge_equal(t, values, lines)
    tip = values["theta_tip"]
    bot = values.get("theta_bot")
    con = values.get("theta_con")
    if bot is not None and con is None:
        con = np.clip(tip - bot, 0.0, None)
    elif con is not None and bot is None:
        bot = tip - con
    nan = np.full(t.size, np.nan)
    ok = np.isfinite(tip)
    if not ok.any():
        raise InputError(raw.name, f"[angles] theta_tip {fmt.theta_tip!r} has no value in any row")
    angles = pd.DataFrame({"time_s": t, "theta_tip": tip, "theta_bot": nan if bot is None else bot,
                           "theta_con": nan if con is None else con, "ok": ok, "frame": np.arange(t.size),
                           "line": lines})
    angles.attrs["warnings"] = ([f"{n_merged} row(s) of the angle track sharing a time with the row before were "
                                 "averaged"] if n_merged else [])
    if fmt.zero == "log":
        offset, unc, zero = 0.0, 0.0, "log"
    elif fmt.zero == "motion_start":
        assert depth is not None
        offset, unc, zero = depth.motion.start_s, depth.motion.start_uncertainty_s, "motion_start"
    else:
        offset, unc, zero = float(fmt.zero), 0.0, f"{float(fmt.zero):g}"
    return AngleTrack(path=raw.name, angles=angles, offset_s=float(offset), uncertainty_s=float(unc), zero=zero)


def track_coverage(track: AngleTrack, force_time_s: np.ndarray, *, trial: str, depth: DepthLog | None = None,
                   frame_period_s: float | None = None) -> list[str]:
    """Check that the angle track overlaps the force log and say where it stops early.

    The rows of the synced table beyond the track's last measured frame keep their force (and
    depth) and have empty angles: nothing is extrapolated.

    Parameters
    ----------
    track : AngleTrack
    force_time_s : ndarray
        The force samples' times (s, force clock).
    trial : str
        Named in the warnings.
    depth : DepthLog, optional
        To say whether the stage was still moving when the track stopped.
    frame_period_s : float, optional
        The track's frame period (s); default its median interval.

    Returns
    -------
    list of str
        Warnings naming the trial (empty when the track covers the force log).

    Raises
    ------
    InputError
        The track and the force log do not overlap in time (naming the track and ``[angles] zero``).
    """
    good = track.angles["ok"].to_numpy(bool)
    t = track.angles["time_s"].to_numpy(float)[good] + track.offset_s
    f = np.asarray(force_time_s, dtype=float)
    if f.size == 0 or t[-1] < f[0] or t[0] > f[-1]:
        raise InputError(track.path, f"[angles] zero {track.zero!r}: the angle track ({_span(t)} on the force clock) and "
                                     f"the force log ({_span(f)}) do not overlap in time")
    period = frame_period_s if frame_period_s is not None else (float(np.median(np.diff(t))) if t.size > 1 else 0.0)
    notes = []
    after = int(np.count_nonzero(f > t[-1]))
    if after and f[-1] - t[-1] > 2 * period:
        note = (f"trial {trial}: the angle track stops at {t[-1]:.4g} s on the force clock, {f[-1] - t[-1]:.3g} s before "
                f"the force log ends; the {after} force sample(s) after it are kept with empty angles")
        if depth is not None and depth.motion.stop_s - t[-1] > 2 * period:
            stop = depth.motion.stop_s
            note += (f", and the stage still moves until {stop:.4g} s" if depth.motion.stopped
                     else ", and the stage is still moving when its log ends")
        notes.append(note)
    before = int(np.count_nonzero(f < t[0]))
    if depth is not None and t[0] - depth.motion.start_s > 2 * period and t[0] > f[0]:
        notes.append(f"trial {trial}: the angle track starts at {t[0]:.4g} s on the force clock, "
                     f"{t[0] - depth.motion.start_s:.3g} s after the stage starts moving; the {before} force "
                     "sample(s) before it have empty angles")
    return notes


# --------------------------------------------------------------------------- one trial


def read_lab_logs(
    force_path: str | os.PathLike,
    *,
    fmt: LogFormat | None,
    depth_path: str | os.PathLike | None = None,
    angles_path: str | os.PathLike | None = None,
    cfg: ForceLogConfig = ForceLogConfig(),
) -> LabLogs:
    """Read one trial's force log, and its depth log and angle track when it has them.

    Parameters
    ----------
    force_path : str or PathLike
        The force log (CSV or bag).
    fmt : LogFormat or None
        The lab's log format; None: every log is in tympani's own form.
    depth_path : str or PathLike, optional
        The depth log.
    angles_path : str or PathLike, optional
        Another tracker's angle track, read through ``fmt.angles`` (which must then be set).
    cfg : ForceLogConfig
        Force-log policies.

    Returns
    -------
    LabLogs

    Raises
    ------
    InputError
        As the readers, and for a depth log that does not overlap the force log in time.
    """
    fmt = fmt if fmt is not None else LogFormat(path="")
    if fmt.force is not None:
        force, report, clock = read_force_stream(force_path, fmt.force, cfg)
    else:
        force, report = read_force_log(force_path, cfg)
        clock = Clock()
    warnings: list[str] = []
    depth = None
    if depth_path is not None:
        depth = read_depth_log(depth_path, fmt.depth, clock)
        warnings.extend(depth.warnings)
        t = force["time_s"].to_numpy(float)
        on_force = depth_on_force_clock(depth, t)
        inside = np.isfinite(on_force)
        time_key = _time_label(fmt.depth) if fmt.depth is not None else "time_s"
        if not inside.any():
            raise InputError(depth.path, f"{time_key}: the depth log ({_span(depth.time_s)} on the force clock) and the "
                                         f"force log ({_span(t)}) do not overlap in time")
        if not inside.all():
            warnings.append(f"the depth log covers {_span(depth.time_s)} of the force log's {_span(t)}: depth_mm is "
                            f"empty for the {int((~inside).sum())} force sample(s) outside it")
        if np.isfinite(force["depth_mm"].to_numpy(float)).any():
            warnings.append("the force log's own depth_mm column was replaced by the depth log's positions")
        force = force.assign(depth_mm=on_force)
    track = None
    if angles_path is not None:
        if fmt.angles is None:
            raise ValueError("an angle track needs a log format with an [angles] section")
        track = read_angle_track(angles_path, fmt.angles, clock, depth, format_path=fmt.path)
    return LabLogs(force=force, force_report=report, clock=clock, depth=depth, track=track, warnings=tuple(warnings))


"""One video → its angles table: :func:`extract_video`.

:func:`~tympani.pipeline.extract.stream.measure_frames` streams the video through registration and
measurement; :func:`extract_video` collects that stream into the angles table
(docs/file-formats.md), then goes back over the frames seen after a camera move but before a
check noticed it (:func:`remeasure_after_moves`), marks glitches (:func:`flag_glitches`) and
frames off the constant-speed insertion (:func:`tympani.pipeline.extract.kinematics.flag_kinematics`),
measures again on the other copy of walls that show twice where the array touches that one
(:func:`remeasure_on_other_copy`), marks runs of frames whose contact start goes away and comes
back (:func:`flag_excursions`) and the frames that lost the contact arc of the frames before
them (:func:`flag_contact_loss`), marks the frames of a video mostly unread (:func:`flag_sparse`),
the measured frames with no other measured frame near (:func:`flag_lone`) and those of a video
measured on only a handful of frames (:func:`flag_few`), and pools how wide the array looks
(:func:`array_width`).
"""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import sliding_window_view

from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.pipeline.extract.kinematics import KinematicsConfig, flag_kinematics
from tympani.pipeline.extract.records import mark_not_ok
from tympani.pipeline.extract.stream import (Check, Epoch, ExtractLog, frame_row, lens_undistorter, measure_frames,
                                             measured_row, prepare_plan)
from tympani.pipeline.force.forcelog import read_csv_columns
from tympani.vision.angles.beyond import STRIPES_PAST_TIP
from tympani.vision.errors import InputError
from tympani.vision.frames import Frame, FrameSource, open_frames
from tympani.vision.greyscale import to_gray
from tympani.vision.registration.axis import beyond_array_precision
from tympani.vision.geometry import ElectrodeArray

__all__ = [
    "ANGLE_COLUMNS",
    "Move",
    "ViewChange",
    "trial_name",
    "extract_video",
    "moves_to_go_over",
    "remeasure_after_moves",
    "prefers_other_copy",
    "copies_to_switch",
    "flagged_by_motion",
    "remeasure_on_other_copy",
    "flag_glitches",
    "contact_excursions",
    "flag_excursions",
    "flag_contact_loss",
    "contact_losses",
    "flag_sparse",
    "flag_few",
    "flag_lone",
    "array_width",
]

#: The angles table's fixed columns, in order (docs/file-formats.md); extra columns follow them.
ANGLE_COLUMNS: tuple[str, ...] = ("trial", "frame", "time_s", "theta_tip", "theta_bot", "theta_con", "ok", "reason")


def trial_name(path: str | os.PathLike, trial: str | None = None) -> str:
    """The trial name of a video: ``trial`` if given, else the file stem (folder name).

    Raises
    ------
    InputError
        The name is empty or would escape the output folder (contains a path separator).
    """
    p = Path(path)
    name = trial if trial is not None else (p.name if p.is_dir() else p.stem)
    name = str(name).strip()
    if not name or name in (".", "..") or any(c in name for c in "/\\\0"):
        raise InputError(p, f"unusable trial name {name!r} (empty or contains a path separator)")
    return name


def extract_video(
    path: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    fps: float | None = None,
    trial: str | None = None,
    progress: bool = False,
    steps: VisionSteps = VisionSteps(),
) -> tuple[pd.DataFrame, Any]:
    """Angles of every frame of one video.

    Parameters
    ----------
    path : str or PathLike
        Video file or folder of frames.
    cfg : ExtractConfig
        Settings.
    fps : float, optional
        Frame rate (frames/s); needed for a folder, overrides the file's clock for a video.
    trial : str, optional
        Trial name for the ``trial`` column (default: the file stem).
    progress : bool
        Per-frame progress bar on stderr.
    steps : VisionSteps
        The vision functions (default: :mod:`tympani.vision.registration`'s and :mod:`tympani.vision.angles`'s).

    Returns
    -------
    table : DataFrame
        One row per decoded frame: :data:`ANGLE_COLUMNS`, then the measurement's extra scalar
        columns, then ``reg_epoch``. Failed frames have ``ok`` False, NaN angles and a
        ``reason``. ``table.attrs`` holds ``registrations`` (:meth:`Epoch.record` of each,
        with ``moved_at_frame`` when :func:`remeasure_after_moves` went back over the frames
        before it), ``lost`` (:meth:`LostSpan.record` of the spans in which the registration
        was lost, likewise), ``checks`` (``(frame, residual_px)``), ``warnings`` (decoder,
        measurement, the camera moves whose frames :func:`remeasure_after_moves` went back
        over, and the glitches :func:`flag_glitches` marked), ``timing_s`` (see
        :class:`ExtractLog`), ``source`` and ``array_width`` (see :func:`array_width`).
    registration : Registration
        The first registration (the one frame 0 was measured with).

    Raises
    ------
    InputError
        Unreadable input, or no phantom found in the first frames.
    """
    name = trial_name(path, trial)
    source = open_frames(path, fps=fps, decoder_threads=cfg.decoder_threads)
    log = ExtractLog()
    rows = [m.row for m in measure_frames(source, cfg, trial=name, log=log, progress=progress, keep_colour=False,
                                          steps=steps)]
    t0 = time.perf_counter()
    changes = remeasure_after_moves(source, rows, log, cfg, name, steps=steps)
    log.add_time("remeasure", time.perf_counter() - t0)
    notes = [c.note() for c in changes if c.first is not None]
    checked, flagged = flagged_by_motion(rows, cfg)
    t0 = time.perf_counter()
    switched = remeasure_on_other_copy(source, rows, log, cfg, name, steps=steps, flagged=flagged)
    log.add_time("remeasure", time.perf_counter() - t0)
    if switched:  # the frames measured again are checked again
        checked = motion_checks(rows, cfg)
    notes += switched + checked
    excursions = flag_excursions(rows, cfg.excursion_rad)
    if excursions:
        notes.append(f"{excursions} frame(s) marked not ok: their contact start went over {cfg.excursion_rad:g} rad "
                     "away from the frames around them and came back")
    lost = flag_contact_loss(rows, cfg.excursion_rad)
    if lost:
        notes.append(f"{lost} frame(s) marked not ok: their contact arc is over {cfg.excursion_rad:g} rad shorter "
                     "than the frames' before them")
    note = flag_stripes(rows, cfg.stripe_frames)
    if note:
        notes.append(note)
    note = flag_sparse(rows, cfg.sparse_share)
    if note:
        notes.append(note)
    lone = flag_lone(rows, cfg.lone_reach)
    if lone:
        notes.append(f"{lone} frame(s) marked not ok as unchecked (no other frame measured within {cfg.lone_reach} "
                     "frames)")
    note = flag_few(rows, cfg.sparse_share)
    if note:
        notes.append(note)
    width = array_width(rows, cfg.array)
    if width["warning"]:
        notes.append(width["warning"])
    notes.extend(filter(None, (axis_warning(e.registration) for e in log.epochs)))
    table = pd.DataFrame(rows)
    extras = [c for c in table.columns if c not in ANGLE_COLUMNS and c != "reg_epoch"]
    table = table.reindex(columns=[*ANGLE_COLUMNS, *extras, "reg_epoch"])
    table["ok"] = table["ok"].astype(bool)
    epoch_moved = {c.move.after.index: c.moved_at_frame for c in changes if c.move.after is not None}
    span_moved = {c.move.seen_at: c.moved_at_frame for c in changes if c.move.after is None}
    table.attrs.update(
        registrations=[_with_move(e.record(), epoch_moved.get(e.index)) for e in log.epochs],
        lost=[_with_move(s.record(), span_moved.get(s.frame) if s.ended != "registered" else None) for s in log.lost],
        checks=[(c.frame, c.residual_px) for c in log.checks],
        warnings=[*source.warnings, *log.warnings, *notes],
        timing_s=log.timing_s,
        source=source.info(),
        array_width={k: v for k, v in width.items() if k != "warning"},
    )
    return table, log.first_registration


def motion_checks(rows: list[dict], cfg: ExtractConfig) -> list[str]:
    """Mark the frames the insertion's motion contradicts not ok (rows changed in place):
    glitches (:func:`flag_glitches`) and frames off the constant-speed insertion
    (:func:`~tympani.pipeline.extract.kinematics.flag_kinematics`). Returns their notes."""
    notes = []
    glitches = flag_glitches(rows, cfg.glitch_rad)
    if glitches:
        notes.append(f"{glitches} frame(s) marked not ok as glitches (an angle over {cfg.glitch_rad:g} rad from the "
                     "median of its measured neighbours)")
    if cfg.kinematics_tol_mm > 0:
        _, note = flag_kinematics(rows, KinematicsConfig(tol_mm=cfg.kinematics_tol_mm))
        if note:
            notes.append(note)
    return notes


def flagged_by_motion(rows: list[dict], cfg: ExtractConfig) -> tuple[list[str], frozenset[int]]:
    """:func:`motion_checks` of ``rows`` (changed in place): its notes, and the frames it marked
    not ok (measured before, a tip misread)."""
    measured = [r["ok"] for r in rows]
    notes = motion_checks(rows, cfg)
    return notes, frozenset(r["frame"] for r, ok in zip(rows, measured) if ok and not r["ok"])


def flag_lone(rows: list[dict], reach: int) -> int:
    """Mark measured frames with no other frame measured within ``reach`` frames either side not
    ok, in place: the glitch filter and the kinematics check compare a frame with its measured
    neighbours, and a lone frame among refused ones has none near (on independent renders a
    quarter of such frames were grossly wrong, against about 1 % of all). Videos of fewer than
    ``2 * reach + 1`` frames are left as they are.

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``ok``, angles in rad, ``reason``); changed
        in place.
    reach : int
        Frames on each side (0: nothing is marked).

    Returns
    -------
    int
        Frames marked.
    """
    if reach <= 0 or len(rows) < 2 * reach + 1:
        return 0
    frames = np.array([int(r["frame"]) for r in rows])
    measured = np.sort(frames[[bool(r["ok"]) for r in rows]])
    if not len(measured):
        return 0
    gaps = np.diff(measured)
    before = np.concatenate([[reach + 1], gaps])  # to the previous measured frame
    after = np.concatenate([gaps, [reach + 1]])
    lone = set(measured[(before > reach) & (after > reach)].tolist())
    for row in rows:
        if row["ok"] and int(row["frame"]) in lone:
            mark_not_ok(row, f"unchecked: no other frame measured within {reach} frames")
    return len(lone)


def _with_move(record: dict, moved_at_frame: int | None) -> dict:
    return record if moved_at_frame is None else {**record, "moved_at_frame": moved_at_frame}


# --------------------------------------------------------------------------- camera moves


@dataclass(frozen=True)
class Move:
    """A change of view that a failed check saw, possibly some frames after it happened.

    Parameters
    ----------
    before : Epoch
        The registration in force until then.
    seen_at : int
        The failed check's frame.
    after : Epoch or None
        The registration that followed (from ``seen_at`` on); None when none succeeded (a lost
        span that did not end in a registration).
    """

    before: Epoch
    seen_at: int
    after: Epoch | None


@dataclass(frozen=True)
class ViewChange:
    """What going back over a :class:`Move`'s frames found.

    Parameters
    ----------
    move : Move
        The move gone over.
    first : int or None
        The first frame the old registration no longer fits (the move), None when all fit.
    fitted : int
        Frames from ``first`` on measured again with the new registration.
    """

    move: Move
    first: int | None
    fitted: int

    @property
    def moved_at_frame(self) -> int:
        """Where the view changed: ``first``, or the check that saw it when every frame fitted."""
        return self.first if self.first is not None else self.move.seen_at

    def note(self) -> str:
        """One line on the frames gone over (for a change found, ``first`` not None)."""
        first, seen_at = self.first, self.move.seen_at
        span = f"at frame {first} (seen by the check at {seen_at}); frames {first}-{seen_at - 1}"
        if self.move.after is None:
            return f"view changed {span} marked not ok (no registration fits them)"
        if self.fitted == seen_at - first:
            return f"camera moved {span} measured again with the new registration"
        return (f"camera moved {span}: {self.fitted} measured again with the new registration, "
                f"{seen_at - first - self.fitted} marked not ok (they fit neither registration)")


def moves_to_go_over(log: ExtractLog) -> list[Move]:
    """The moves of a video, in the order they were seen: each re-registration after a failed
    check, and each lost span that did not end in a registration."""
    moves = [Move(log.epochs[e.index - 1], e.frame, e) for e in log.epochs if e.trigger is not None]
    moves += [Move(log.epochs[s.epoch], s.frame, None) for s in log.lost if s.ended != "registered"]
    return sorted(moves, key=lambda m: m.seen_at)


def last_good_frame(move: Move, checks: list[Check], cfg: ExtractConfig) -> int:
    """The last frame known to fit ``move.before``: the last it was registered on, or its last
    passing check before the move was seen."""
    threshold = cfg.recheck_threshold_px(move.before.registration)
    good = move.before.frame + move.before.n_frames_used - 1
    return max([good, *(c.frame for c in checks if good < c.frame < move.seen_at and c.residual_px <= threshold)])


def _frames_between(source: FrameSource, good: int, seen_at: int) -> Iterator[Frame]:
    """The frames after ``good`` and before ``seen_at``, decoded again from the start (seeking
    is not frame-exact in every codec)."""
    frames = iter(source)
    try:
        for frame in frames:
            if frame.index <= good:
                continue
            if frame.index >= seen_at:
                break
            yield frame
    finally:
        close = getattr(frames, "close", None)
        if close is not None:
            close()


class _Lens:
    """What checks see of a grey frame: the frame undistorted by ``calibration`` (its
    undistortion made on the first frame), or the frame itself without one."""

    def __init__(self, calibration: Any, source: FrameSource) -> None:
        self.calibration = calibration
        self.source = source
        self.undistort: Callable[[np.ndarray], np.ndarray] | None = None

    def seen(self, gray: np.ndarray) -> np.ndarray:
        if self.calibration is None:
            return gray
        if self.undistort is None:
            self.undistort = lens_undistorter(self.calibration, self.source, gray.shape)
        return self.undistort(gray)


def _go_over(source: FrameSource, rows: list[dict], at: dict[int, int], move: Move, good: int, cfg: ExtractConfig,
             steps: VisionSteps, trial: str, lens: _Lens) -> ViewChange:
    """Check the frames after ``good`` against the old registration; from the first that fails,
    measure each with the new one when it fits, else mark it not ok (rows replaced in place)."""
    old = move.before.registration
    threshold = cfg.recheck_threshold_px(old)
    new = move.after
    new_threshold = math.nan if new is None else cfg.recheck_threshold_px(new.registration)
    epoch = move.before.index if new is None else new.index
    first, fitted = None, 0
    for frame in _frames_between(source, good, move.seen_at):
        gray = to_gray(frame.image)
        seen = lens.seen(gray)  # the ideal image when there is a lens (the plans sample gray)
        if first is None:
            if float(steps.check(seen, old, cfg.phantom)) <= threshold:  # NaN: moved
                continue
            first = frame.index
        if new is not None and float(steps.check(seen, new.registration, cfg.phantom)) <= new_threshold:
            result = measured_row(steps, gray, new.plan, cfg)
            fitted += 1
        else:  # the camera still moving, the view blocked, or no new registration
            result = {"ok": False, "reason": f"the view changed at frame {first} (seen by the check at "
                                             f"{move.seen_at}) and no registration fits this frame"}
        rows[at[frame.index]] = frame_row(trial, frame, result, epoch)
    return ViewChange(move, first, fitted)


#: The evidence the array must give before a registration's frames are measured again on the
#: walls' other copy (:func:`prefers_other_copy`): centre line (mm) fitting the other copy better,
#: summed over the frames, and frames where it does, at least three times as many as those where
#: the registered copy fits better (by more than half a millimetre each).
OTHER_COPY_MM = 3.0
OTHER_COPY_FRAMES = 3


def prefers_other_copy(support_mm: np.ndarray) -> bool:
    """Whether the array says the registration took the doubled walls' wrong copy.

    Parameters
    ----------
    support_mm : ndarray
        The frames' ``other_copy_mm`` (mm of centre line the other copy fits better, see
        :func:`tympani.vision.angles.results.other_copy_support`; NaN, for a frame whose tip is
        short of half a turn, is ignored).
    """
    s = np.asarray(support_mm, dtype=float)
    s = s[np.isfinite(s)]
    for_other, for_this = int(np.sum(s > 0.5)), int(np.sum(s < -0.5))
    return bool(s.sum() >= OTHER_COPY_MM and for_other >= OTHER_COPY_FRAMES and for_other >= 3 * for_this)


def copies_to_switch(rows: list[dict], epochs: Sequence[Epoch], flagged: frozenset[int] = frozenset()
                     ) -> dict[int, np.ndarray]:
    """The registrations on doubled walls whose measured frames (``rows``, but for those in
    ``flagged``) say the array touches the other copy (:func:`prefers_other_copy`): their
    positions in ``epochs``, each with its frames' ``other_copy_mm`` (mm; the evidence)."""
    out = {}
    for k, epoch in enumerate(epochs):
        if not getattr(epoch.registration, "walls_doubled", False) or not epoch.prepared:
            continue
        mine = [r for r in rows if r["reg_epoch"] == epoch.index]
        support = np.array([r.get("other_copy_mm", math.nan) for r in mine if r["frame"] not in flagged], dtype=float)
        if any("time_ms" in r for r in mine) and prefers_other_copy(support):
            out[k] = support
    return out


def remeasure_on_other_copy(source: FrameSource, rows: list[dict], log: ExtractLog, cfg: ExtractConfig, trial: str,
                            *, steps: VisionSteps = VisionSteps(), flagged: frozenset[int] = frozenset()
                            ) -> list[str]:
    """Measure a registration's frames again on the doubled walls' other copy where the array
    touches that copy and not the registered one (:func:`prefers_other_copy`).

    The copies of a wall seen twice fit the spiral equally well, and where their parallax runs
    along the insertion axis the array outside the entry cannot tell them apart. Inside, the
    array presses on the outer wall's real copy: on the other it stands off by about the
    parallax (contact missed) or crosses it. The epoch's registration in ``log.epochs`` is
    replaced by :meth:`~tympani.vision.registration.Registration.other_copy` and its rows (by
    ``reg_epoch``) in place. The evidence comes from every frame whose centre line was measured
    (refused or not at the last step, where an unclear contact start is often the wrong copy's
    doing), but for the frames in ``flagged``: those the motion checks marked (a tip misread).

    Returns
    -------
    list of str
        A note for each registration switched.
    """
    notes = []
    for k, support in copies_to_switch(rows, log.epochs, flagged).items():
        epoch = log.epochs[k]
        # the frames measured with it (frames of a lost span, never measured, stay as they are)
        at = {row["frame"]: i for i, row in enumerate(rows) if row["reg_epoch"] == epoch.index and "time_ms" in row}
        other = epoch.registration.other_copy()
        plan = prepare_plan(steps, other, epoch.plan.image_shape, cfg)
        log.epochs[k] = Epoch(epoch.index, epoch.frame, other, plan, epoch.n_frames_used, epoch.trigger)
        for frame in _frames_between(source, min(at) - 1, max(at) + 1):
            if frame.index in at:
                result = measured_row(steps, to_gray(frame.image), plan, cfg)
                rows[at[frame.index]] = frame_row(trial, frame, result, epoch.index)
        notes.append(f"walls show twice: frames {min(at)}-{max(at)} measured again on their other copy, which the "
                     f"array touches ({np.nansum(support):.1f} mm of centre line fit it better, over "
                     f"{int(np.sum(support > 0.5))} frames)")
    return notes


def remeasure_after_moves(source: FrameSource, rows: list[dict], log: ExtractLog, cfg: ExtractConfig, trial: str,
                          *, steps: VisionSteps = VisionSteps()) -> list[ViewChange]:
    """Go back over the frames seen after the camera moved but before a check noticed it.

    A check every ``cfg.recheck_every`` frames finds a move late, so the frames between the move
    and the check were measured with the old pose. For each failed check that led to a new
    registration, and for each lost span that did not end in one (:func:`moves_to_go_over`),
    the frames after the last known-good one (the old registration's own frames or its last
    passing check) are decoded again, in order, and checked against the old registration. From
    the first that fails on (the move), each frame is measured with the new registration, and
    gets its ``reg_epoch``, when it fits that one; otherwise (the camera still moving, the view
    blocked, or no new registration) it is marked not ok.

    Parameters
    ----------
    source : FrameSource
        The video, decoded again from the start (seeking is not frame-exact in every codec).
    rows : list of dict
        The frame rows of :func:`~tympani.pipeline.extract.stream.measure_frames`, in frame order;
        replaced in place.
    log : ExtractLog
        Its epochs, checks and lost spans.
    cfg : ExtractConfig
        Settings (check threshold, phantom, measurement).
    trial : str
        Trial name of the rows.
    steps : VisionSteps
        The vision functions.

    Returns
    -------
    list of ViewChange
        One per move whose frames were gone over (moves with no frame between the last
        known-good one and the check are left out).
    """
    at = {int(r["frame"]): i for i, r in enumerate(rows)}
    lens = _Lens(cfg.calibration, source)
    changes = []
    for move in moves_to_go_over(log):
        good = last_good_frame(move, log.checks, cfg)
        if good + 1 >= move.seen_at:
            continue
        changes.append(_go_over(source, rows, at, move, good, cfg, steps, trial, lens))
    return changes


# --------------------------------------------------------------------------- glitches, array width


def axis_warning(registration: Any) -> str:
    """A warning when the straight array outside the entry lies clearly off the registered
    insertion axis (its ``array_axis_offset_px``, px; see
    :class:`~tympani.vision.registration.Registration`), else ""."""
    offset, ppm = float(registration.array_axis_offset_px), float(registration.pose.px_per_mm)
    if not beyond_array_precision(offset, ppm):
        return ""
    return (f"the array outside the entry lies {abs(offset):.1f} px ({abs(offset) / ppm:.2f} mm) off the registered "
            "insertion axis: the pose may be off across it (walls that show twice, registered on the wrong copy); "
            "check it with tympani annotate")


def array_width(rows: list[dict], array: ElectrodeArray, *, tolerance: float = 0.1, min_frames: int = 10) -> dict:
    """How wide the array looks against the model the measurement assumes.

    The measurement reads the gap to the wall from the modelled diameters
    (:class:`~tympani.vision.geometry.ElectrodeArray`), so an array wider or narrower than its model
    biases every gap, and with them where contact begins (theta_bot). Each measured frame's
    ``width_ratio`` (seen width between the two edges over the modelled width; about 1.01 for
    rendered arrays of the modelled size, and 0.86 and 1.21 for arrays 15 % narrower and 20 %
    wider) is pooled here.

    Parameters
    ----------
    rows : list of dict
        Frame rows with ``ok`` and ``width_ratio`` (dimensionless; NaN or missing: not measured).
    array : ElectrodeArray
        The modelled array (its diameters, mm, are named in the warning).
    tolerance : float
        Largest ``|median - 1|`` (dimensionless) without a warning.
    min_frames : int
        Fewest frames with a ratio for a verdict.

    Returns
    -------
    dict
        ``median`` (dimensionless, NaN without frames), ``frames`` (how many had a ratio) and
        ``warning`` (a sentence, or "" when the array matches its model or too few frames tell).
    """
    ratios = np.array([float(r["width_ratio"]) for r in rows if r.get("ok") and r.get("width_ratio") is not None],
                      dtype=float)
    ratios = ratios[np.isfinite(ratios)]
    median = float(np.median(ratios)) if len(ratios) else math.nan
    warning = ""
    if len(ratios) >= min_frames and abs(median - 1.0) > tolerance:
        warning = (f"the array looks {abs(median - 1.0):.0%} {'wider' if median > 1.0 else 'narrower'} than the modelled "
                   f"one ({array.tip_diameter_mm:g} mm at the tip, {array.base_diameter_mm:g} mm at the base; median of "
                   f"{len(ratios)} frames): its gaps to the wall, and so theta_bot, are biased; give its diameters "
                   "(--array-diameters TIP,BASE)")
    return {"median": median, "frames": int(len(ratios)), "warning": warning}


def _window_medians(x: np.ndarray, before: int, width: int, n_out: int) -> np.ndarray:
    """``out[j] = median(x[max(0, j - before) : j - before + width])`` for ``j < n_out``: a
    running median whose windows are clipped to ``x`` at its ends (values in ``x``'s unit; NaN
    values are left out, a window of NaN only gives NaN).
    The windows inside ``x`` are taken in one call; only the clipped ones at the ends loop."""
    out = np.full(n_out, np.nan)
    median = np.nanmedian if np.isnan(x).any() else np.median
    first, last = before, min(n_out - 1, len(x) - width + before)  # the j whose window lies inside x
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows
        if last >= first:
            out[first : last + 1] = median(sliding_window_view(x, width)[: last - first + 1], axis=1)
        for j in (*range(min(first, n_out)), *range(max(last + 1, first), n_out)):
            out[j] = median(x[max(0, j - before) : j - before + width])
    return out


def _measured_in_order(rows: list[dict]) -> list[int]:
    """Indices into ``rows`` (angles-table rows) of the measured ones, in frame order."""
    return [i for i in sorted(range(len(rows)), key=lambda i: rows[i]["frame"]) if rows[i]["ok"]]


def flag_glitches(rows: list[dict], max_rad: float, half_window: int = 2) -> int:
    """Mark isolated outliers in time as not ok, in place.

    The angles move smoothly from frame to frame, or step (theta_bot when a contact run forms or
    breaks). A frame measured far from its neighbours on both sides is a measurement glitch: a
    few edges misread can move theta_bot by radians through the contact run's definition. Over
    a video's measured frames in order, a frame is marked when its ``theta_tip`` or
    ``theta_bot`` lies from the running median of ``2 * half_window + 1`` measured frames
    centred on it (fewer at the ends) by more than ``max_rad``, and by more than the typical
    change a frame times ``2 * half_window`` plus the frames between it and the median of its
    window's frame numbers. The typical change a frame is the median over the 10 steps between
    the 11 measured frames around it of each step's size over the frames it spans, leaving out
    steps into and out of frames more than ``max_rad`` from their median (spikes, even in every
    other frame, are no steps). On a steep ramp (a fast insertion) a spike pulls its neighbours'
    medians by up to ``half_window`` steps, and where frames between were not measured the ramp
    itself moves the angle away from its neighbours' median by as many steps. A running median
    leaves ramps and steps as they are and removes spikes up to ``half_window`` frames long.
    Marked rows get ``ok`` False, NaN angles and the reason.

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``ok``, ``theta_tip``, ``theta_bot`` rad,
        ``theta_con``, ``reason``); changed in place.
    max_rad : float
        Least distance (rad) from the running median that marks a frame; 0 or less does
        nothing.
    half_window : int
        Measured frames on each side in the median.

    Returns
    -------
    int
        Frames marked.
    """
    ok = _measured_in_order(rows)
    if max_rad <= 0 or len(ok) < 2 * half_window + 1:
        return 0
    marked = np.zeros(len(ok), dtype=bool)
    why = [""] * len(ok)
    frames = np.array([float(rows[i]["frame"]) for i in ok])
    # frames between each one and the middle of its window (0 inside runs of measured frames)
    apart = np.abs(frames - _window_medians(frames, half_window, 2 * half_window + 1, len(frames)))
    spans = np.diff(frames)
    for key in ("theta_tip", "theta_bot"):
        x = np.array([float(rows[i][key]) for i in ok])
        med = _window_medians(x, half_window, 2 * half_window + 1, len(x))
        off = np.abs(x - med)
        # a frame, over the 11 frames around, leaving out the steps into and out of frames far
        # from the median: spikes, even in every other frame, are no steps
        steps = np.abs(np.diff(x)) / spans
        suspect = off > max_rad
        steps[suspect[:-1] | suspect[1:]] = np.nan
        typical = np.nan_to_num(_window_medians(steps, 5, 10, len(x)), nan=0.0)
        far = off > np.maximum(max_rad, (2 * half_window + apart) * typical)
        for j in np.flatnonzero(far & ~marked):
            why[j] = f"glitch: {key} {x[j]:.3f} rad, {off[j]:.2f} rad from its neighbours' median"
        marked |= far
    for j in np.flatnonzero(marked):
        mark_not_ok(rows[ok[j]], why[j])
    return int(marked.sum())


def contact_excursions(theta_bot: np.ndarray, max_rad: float) -> list[tuple[int, int]]:
    """Runs of a video's measured frames whose contact start leaves the others and comes back.

    The series is cut where ``theta_bot`` steps by more than ``max_rad`` from one measured
    frame to the next. A stretch between two such steps is an excursion when the steps go
    opposite ways, the frames either side of it lie nearer each other than either step is
    long, and it holds fewer frames than the stretches before and after it together: the
    contact start went away and came back, and most of the frames around it say where it was.
    A contact start that steps once (a contact run forming or breaking) and stays is no
    excursion, and neither are two neighbouring stretches that would both be one (a series
    swinging to and fro: no side is the reference).

    Parameters
    ----------
    theta_bot : ndarray, shape (n,)
        Contact start angles (rad) of the measured frames, in frame order.
    max_rad : float
        Least step (rad) between neighbouring measured frames that cuts the series.

    Returns
    -------
    list of (int, int)
        First and last index (into ``theta_bot``) of each excursion.
    """
    x = np.asarray(theta_bot, dtype=float)
    step = np.diff(x)
    cuts = np.r_[0, np.flatnonzero(np.abs(step) > max_rad) + 1, len(x)]  # stretch k: cuts[k] to cuts[k+1] - 1
    found = np.zeros(len(cuts) + 1, dtype=bool)  # per stretch k at found[k]; False beyond the ends
    for k in range(1, len(cuts) - 2):  # the stretches with a step on both sides
        a, b = int(cuts[k]), int(cuts[k + 1]) - 1
        away, back = step[a - 1], step[b]
        flanks = (a - cuts[k - 1]) + (cuts[k + 2] - b - 1)
        found[k] = away * back < 0 and abs(x[b + 1] - x[a - 1]) < min(abs(away), abs(back)) and b - a + 1 < flanks
    # in a series that swings to and fro, neighbouring stretches both look like excursions and
    # neither side says where the contact start was: those are left as they are
    alone = found[1:-1] & ~found[:-2] & ~found[2:]
    return [(int(cuts[k]), int(cuts[k + 1]) - 1) for k in np.flatnonzero(alone) + 1]


def flag_excursions(rows: list[dict], max_rad: float) -> int:
    """Mark runs of measured frames whose ``theta_bot`` goes away from the others and comes back
    (:func:`contact_excursions`) not ok, in place.

    The contact start moves with the insertion or steps when a contact run forms or breaks; a
    run of frames that has it radians further along (or back) and then returns to where the
    frames around it say it was is a run misread: a stretch of the contact arc read off the wall
    frame after frame (walls that show twice, a wall line beside the array), which the glitch
    filter (spikes of up to two frames) and the depth's kinematics (the tip is right) let
    through. A contact run that truly lifts off the wall for a few frames is marked as well.

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``ok``, angles in rad, ``reason``); changed
        in place.
    max_rad : float
        Least step (rad) of ``theta_bot`` between neighbouring measured frames that starts or
        ends an excursion; 0 or less does nothing.

    Returns
    -------
    int
        Frames marked.
    """
    ok = _measured_in_order(rows)
    if max_rad <= 0 or len(ok) < 3:
        return 0
    x = np.array([float(rows[i]["theta_bot"]) for i in ok])
    runs = contact_excursions(x, max_rad)
    for a, b in runs:
        first, last = rows[ok[a]]["frame"], rows[ok[b]]["frame"]
        before, after = rows[ok[a - 1]]["frame"], rows[ok[b + 1]]["frame"]
        span = f"frames {first}-{last}" if last > first else f"frame {first}"
        why = (f"contact start: {span} {x[a] - x[a - 1]:+.2f} rad from frame {before}, "
               f"{x[b + 1] - x[b]:+.2f} back by frame {after}")
        for j in range(a, b + 1):
            mark_not_ok(rows[ok[j]], why)
    return sum(b - a + 1 for a, b in runs)


def contact_losses(theta_tip: np.ndarray, theta_bot: np.ndarray, max_rad: float) -> np.ndarray:
    """Which of a video's measured frames have lost more than ``max_rad`` of the contact arc the
    frames before them had.

    Going in, the array's contact with the outer wall spreads both ways, its start going back
    as its tip goes on: the contact angle ``theta_tip - theta_bot`` grows, or holds. Each frame
    is compared with the last frame before it that is not marked: where the contact start has
    moved on by more than the tip has (the tip's advance counted from 0) plus ``max_rad``, the
    frame is marked. A frame without contact (``theta_bot == theta_tip``) marks nothing after
    it, so a contact run forming is never marked, nor one shorter than ``max_rad`` breaking.

    Parameters
    ----------
    theta_tip, theta_bot : ndarray, shape (n,)
        Tip and contact start angles (rad) of the measured frames, in frame order.
    max_rad : float
        Largest loss (rad) of the contact angle.

    Returns
    -------
    ndarray of int, shape (n,)
        For each marked frame the index of the frame it was compared with; -1 for the others.
    """
    tip, bot = np.asarray(theta_tip, dtype=float), np.asarray(theta_bot, dtype=float)
    against = np.full(len(tip), -1, dtype=np.intp)
    ref = 0
    for k in range(1, len(tip)):
        if bot[k] - bot[ref] - max(tip[k] - tip[ref], 0.0) > max_rad:
            against[k] = ref
        else:
            ref = k
    return against


def flag_contact_loss(rows: list[dict], max_rad: float) -> int:
    """Mark the measured frames whose contact arc is more than ``max_rad`` shorter than the
    frames before them had (:func:`contact_losses`) not ok, in place: the array went in, and
    its contact along the outer wall was misread (its outer edge lost against a wall that shows
    twice, a registration a few pixels off), in a run that lasts, which neither the glitch
    filter nor the excursion check (the contact start coming back) marks.

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``ok``, angles in rad, ``reason``); changed
        in place.
    max_rad : float
        Largest loss (rad) of the contact angle; 0 or less does nothing.

    Returns
    -------
    int
        Frames marked.
    """
    ok = _measured_in_order(rows)
    if max_rad <= 0 or len(ok) < 2:
        return 0
    tip = np.array([float(rows[i]["theta_tip"]) for i in ok])
    bot = np.array([float(rows[i]["theta_bot"]) for i in ok])
    against = contact_losses(tip, bot, max_rad)
    marked = np.flatnonzero(against >= 0)
    for k, ref in zip(marked.tolist(), against[marked].tolist()):
        mark_not_ok(rows[ok[k]], f"contact lost: theta_con {tip[k] - bot[k]:.2f} rad against {tip[ref] - bot[ref]:.2f} "
                                 f"rad in frame {rows[ok[ref]]['frame']} (a contact arc going in does not shorten "
                                 f"by over {max_rad:g} rad)")
    return len(marked)


# Least number of frames from a video's first measured frame to its last for :func:`flag_sparse`
# to judge it: a short clip says little about how well its video reads.
SPARSE_MIN_SPAN = 10
# A video measured on no more than this many frames (after every other check), at most the share of
# all its frames with a registration, is judged whatever their span (:func:`flag_few`).
SPARSE_FEW = 4


def flag_stripes(rows: list[dict], least: int) -> str:
    """Mark every measured frame not ok, in place, when at least ``least`` frames of the video were
    refused for regular stripes past their tip (:data:`~tympani.vision.angles.beyond.STRIPES_PAST_TIP`).

    Stripes past the tip are the array's bands going on where they are as dull as the fluid:
    the tip is then read where the plain body ends, radians short, on every frame, and advances
    at the insertion's speed, so neither the glitch filter nor the kinematics check sees it; the
    frames where the stripes show are refused one by one, and where several are, the look
    that hides the array's apical part is the video's.

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``ok``, ``reason``); changed in place.
    least : int
        Fewest frames refused so; 0 does nothing.

    Returns
    -------
    str
        A warning naming the count, or "" when nothing was marked.
    """
    n = sum(1 for r in rows if str(r.get("reason", "")) == STRIPES_PAST_TIP)
    if least <= 0 or n < least:
        return ""
    return _mark_all(rows, f"video: {n} frames show regular stripes past their tip (the array's bands unseen?)")


def flag_sparse(rows: list[dict], max_share: float, min_span: int = SPARSE_MIN_SPAN) -> str:
    """Mark every measured frame not ok, in place, when few frames of the video were measured.

    A video whose frames mostly fail the measurement or its checks is one whose look defeats
    it (bubbles over the array, a faint array, heavy compression), and its few measured
    frames are then often wrong in the same way, frame after frame, where neither the glitch
    filter nor the kinematics check can tell (docs/validation-history.md: on the evaluation renderers,
    a third of the frames measured in videos measured on at most half their frames were grossly
    wrong, under 2 % in the others).

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``ok``, ``reason``, angles in rad); changed in
        place.
    max_share : float
        The video's frames are marked when no more than this share (0-1) of the frames from its
        first measured frame to its last is measured; 0 or less does nothing. Frames without a
        registration (reason ``registration lost: ...``: the camera moved or the view was
        blocked) say nothing about how the video reads and are not counted.
    min_span : int
        Videos whose measured frames span fewer frames are left alone.

    Returns
    -------
    str
        A warning naming the count, or "" when nothing was marked.
    """
    frames = [int(r["frame"]) for r in rows if r["ok"]]
    if max_share <= 0 or not frames:
        return ""
    first, last = min(frames), max(frames)
    lost = sum(1 for r in rows if first <= int(r["frame"]) <= last and _lost(r))
    span = last - first + 1 - lost
    if span < min_span or len(frames) > max_share * span:
        return ""
    why = (f"video mostly unread: {len(frames)} of the {span} frames from frame {first} to {last}"
           f"{f' with a registration ({lost} without)' if lost else ''} measured (at most {max_share:.0%})")
    return _mark_all(rows, why)


def flag_few(rows: list[dict], max_share: float, few: int = SPARSE_FEW) -> str:
    """Mark every measured frame not ok, in place, when the video was measured on only a handful
    of frames, however close together (which :func:`flag_sparse` leaves alone): too few to check
    one another (on the evaluation renderers, 4 of the 15 frames of the five videos measured on
    2-4 of their 30-40 frames were grossly wrong, against 0.5 % of the others' frames).

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``ok``, ``reason``, angles in rad), after every
        other check; changed in place.
    max_share : float
        The measured frames must also be no more than this share (0-1) of all the video's frames
        with a registration (see :func:`flag_sparse`); 0 or less does nothing.
    few : int
        Most measured frames marked.

    Returns
    -------
    str
        A warning naming the count, or "" when nothing was marked.
    """
    n = sum(1 for r in rows if r["ok"])
    registered = sum(1 for r in rows if not _lost(r))
    if max_share <= 0 or not 0 < n <= few or n > max_share * registered:
        return ""
    why = (f"video mostly unread: only {n} of its {registered} frames"
           f"{' with a registration' if registered < len(rows) else ''} measured, too few to check one another")
    return _mark_all(rows, why)


def _lost(row: dict) -> bool:
    """Whether a row had no registration (the camera moved or the view was blocked)."""
    return str(row.get("reason", "")).startswith("registration lost")


def _mark_all(rows: list[dict], why: str) -> str:
    """Mark every measured row not ok with reason ``why``; the warning naming the count."""
    n = 0
    for r in rows:
        if r["ok"]:
            mark_not_ok(r, why)
            n += 1
    return f"{n} frame(s) marked not ok: {why}"


def measured_counts(path: str | os.PathLike) -> tuple[int, int] | None:
    """(frames, frames measured) of an angles table, None when it cannot be read.

    Parameters
    ----------
    path : str or PathLike
        A ``<trial>.angles.csv`` (its ``ok`` column: true/1/yes/t/y, any case, is measured).
    """
    try:
        ok = read_csv_columns(path, {"ok": "text"}).values["ok"]
    except Exception:  # noqa: BLE001 - unreadable or without an ok column: the caller redoes or reports it
        return None
    return len(ok), int(np.isin(np.char.lower(np.char.strip(ok.astype(str))), ["true", "1", "yes", "t", "y"]).sum())


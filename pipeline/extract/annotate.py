"""Annotated frames for checking extraction by eye, and manual labels to compare against.

:func:`annotate_video` registers and measures a video exactly as ``extract`` does (it runs
:func:`tympani.pipeline.extract.stream.measure_frames`) and writes, for the chosen frames,
``<trial>.frame<NNNNNN>.png`` with the walls, centre, array, contact arc, tip, contact start and
angles drawn on them (:func:`tympani.vision.drawing.annotate_frame`), optionally an annotated
``<trial>.annotated.mp4`` of every frame, and ``<trial>.annotated.csv`` with the automatic
angles of the drawn frames.

Manual labels are image points (px) of the array's tip and of the start of its contact run,
per frame: ``frame, tip_x_px, tip_y_px, bot_x_px, bot_y_px`` (either point may be blank). They
are converted to phantom angles (rad, as in the angles table) with the frame's registration
(``point_angle(pose.to_phantom(px))``) and stored in ``<trial>.labels.csv``;
``<trial>.label_compare.csv`` puts them beside the automatic angles with the differences
``d_theta_* = auto - label`` (rad).
"""

from __future__ import annotations

import copy
import math
import os
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import numpy as np
import pandas as pd

from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.pipeline.extract.stream import (ExtractLog, frame_row, measure_frames, prepare_plan, raised_row,
                                             try_measure)
from tympani.pipeline.extract.video import copies_to_switch, flagged_by_motion, trial_name
from tympani.pipeline.force.forcelog import read_csv_columns
from tympani.pipeline.io import atomic_write_bytes, atomic_write_csv
from tympani.vision.drawing import annotate_frame
from tympani.vision.errors import InputError
from tympani.vision.frames import open_frames
from tympani.vision.geometry import Phantom, point_angle

__all__ = [
    "LABEL_COLUMNS",
    "AnnotateResult",
    "parse_label",
    "read_labels",
    "labels_frame",
    "label_angles",
    "compare_labels",
    "summarize_comparison",
    "annotate_video",
]

#: Columns of a labels CSV (pixels, x right, y down).
LABEL_COLUMNS: tuple[str, ...] = ("frame", "tip_x_px", "tip_y_px", "bot_x_px", "bot_y_px")


# --------------------------------------------------------------------------- labels


def parse_label(tokens: Sequence[str]) -> dict:
    """One label from command-line tokens ``FRAME tip=X,Y [bot=X,Y]`` (px).

    Returns
    -------
    dict
        A labels-table row (:data:`LABEL_COLUMNS`); a missing point is NaN.

    Raises
    ------
    InputError
        Malformed tokens.
    """
    where = "--label " + " ".join(tokens)
    if not tokens:
        raise InputError("--label", "expected FRAME tip=X,Y bot=X,Y")
    try:
        frame = int(tokens[0])
    except ValueError:
        raise InputError(where, f"frame {tokens[0]!r} is not an integer") from None
    if frame < 0:
        raise InputError(where, "frame must be >= 0")
    row: dict[str, Any] = {c: math.nan for c in LABEL_COLUMNS}
    row["frame"] = frame
    for token in tokens[1:]:
        key, sep, value = token.partition("=")
        if not sep or key not in ("tip", "bot"):
            raise InputError(where, f"expected tip=X,Y or bot=X,Y, got {token!r}")
        try:
            x, y = (float(v) for v in value.split(","))
        except ValueError:
            raise InputError(where, f"{key} needs two numbers X,Y (px), got {value!r}") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputError(where, f"{key} coordinates must be finite")
        row[f"{key}_x_px"], row[f"{key}_y_px"] = x, y
    if all(math.isnan(row[c]) for c in LABEL_COLUMNS[1:]):
        raise InputError(where, "a label needs tip=X,Y and/or bot=X,Y")
    return row


def labels_frame(rows: Iterable[dict]) -> pd.DataFrame:
    """A labels table from rows, validated (integer ``frame`` >= 0, no duplicate frames)."""
    table = pd.DataFrame(list(rows), columns=list(LABEL_COLUMNS))
    return _validate_labels(table, "labels")


def _validate_labels(table: pd.DataFrame, where: str) -> pd.DataFrame:
    missing = [c for c in LABEL_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(where, f"missing column(s): {', '.join(missing)}")
    table = table[list(LABEL_COLUMNS)].copy()
    frames = pd.to_numeric(table["frame"], errors="coerce")
    bad = frames.isna() | (frames < 0) | (frames != np.floor(frames))
    if bad.any():
        raise InputError(where, f"bad frame number {table['frame'][bad].iloc[0]!r} (integers >= 0 expected)")
    table["frame"] = frames.astype(int)
    for col in LABEL_COLUMNS[1:]:
        values = pd.to_numeric(table[col], errors="coerce")
        if (values.isna() & table[col].notna() & (table[col].astype(str).str.strip() != "")).any():
            raise InputError(where, f"non-numeric value in column {col}")
        table[col] = values.astype(float)
    dup = table["frame"].duplicated()
    if dup.any():
        raise InputError(where, f"frame {int(table['frame'][dup].iloc[0])} is labelled twice")
    return table.sort_values("frame", kind="stable").reset_index(drop=True)


def read_labels(path: str | os.PathLike) -> pd.DataFrame:
    """Read a labels CSV (:data:`LABEL_COLUMNS`, pixels; ``#`` lines are comments).

    Raises
    ------
    InputError
        Missing file, unparsable CSV, missing columns, bad values, duplicate frames.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such labels file")
    table = pd.DataFrame(read_csv_columns(p, lambda header: {c: "text" for c in header.columns}).values)
    return _validate_labels(table.apply(lambda column: column.str.strip()), str(p))


def label_angles(label: pd.Series | dict, registration: Any, phantom: Phantom) -> dict:
    """Phantom angles (rad, as in the angles table) of one label's points, mapped with ``registration.pose``.

    Returns
    -------
    dict
        ``theta_tip``, ``theta_bot`` (NaN for a missing point) and ``theta_con`` (``tip - bot``).
    """
    pose = getattr(registration, "pose", registration)
    out = {}
    for key in ("tip", "bot"):
        x, y = float(label[f"{key}_x_px"]), float(label[f"{key}_y_px"])
        if math.isfinite(x) and math.isfinite(y):
            out[f"theta_{key}"] = float(point_angle(pose.to_phantom(np.array([[x, y]])), phantom)[0])
        else:
            out[f"theta_{key}"] = math.nan
    out["theta_con"] = out["theta_tip"] - out["theta_bot"]
    return out


def compare_labels(labelled: pd.DataFrame, auto: pd.DataFrame) -> pd.DataFrame:
    """Labelled and automatic angles side by side.

    Parameters
    ----------
    labelled : DataFrame
        ``frame`` and ``theta_tip``, ``theta_bot``, ``theta_con`` (rad) of the labels.
    auto : DataFrame
        Angles table rows (``frame``, ``theta_*``, ``ok``, ``reason``).

    Returns
    -------
    DataFrame
        Per labelled frame: ``theta_*_label``, ``theta_*_auto``, ``ok_auto``, ``reason_auto``
        and ``d_theta_* = auto - label`` (rad); frames the video lacks have NaN automatic values.
    """
    left = labelled[["frame", "theta_tip", "theta_bot", "theta_con"]].rename(
        columns={c: f"{c}_label" for c in ("theta_tip", "theta_bot", "theta_con")}
    )
    right = auto[["frame", "theta_tip", "theta_bot", "theta_con", "ok", "reason"]].rename(
        columns={"theta_tip": "theta_tip_auto", "theta_bot": "theta_bot_auto", "theta_con": "theta_con_auto",
                 "ok": "ok_auto", "reason": "reason_auto"}
    )
    table = left.merge(right, on="frame", how="left")
    table["ok_auto"] = table["ok_auto"].astype("boolean").fillna(False).astype(bool)
    for key in ("tip", "bot", "con"):
        table[f"d_theta_{key}"] = table[f"theta_{key}_auto"] - table[f"theta_{key}_label"]
    return table


def summarize_comparison(table: pd.DataFrame) -> str:
    """A few lines: how many labels, and the mean and largest |auto - label| in degrees."""
    lines = [f"{len(table)} labelled frame(s), {int(table['ok_auto'].sum())} measured automatically"]
    for key in ("tip", "bot", "con"):
        d = np.degrees(table[f"d_theta_{key}"].abs().dropna())
        if len(d):
            lines.append(f"theta_{key}: |auto - label| mean {d.mean():.2f} deg, max {d.max():.2f} deg (n={len(d)})")
    return "\n".join(lines)


# --------------------------------------------------------------------------- annotate


@dataclass(frozen=True)
class AnnotateResult:
    """What :func:`annotate_video` wrote.

    Parameters
    ----------
    trial : str
        Trial name.
    images : tuple of Path
        Annotated PNGs.
    video : Path or None
        Annotated mp4.
    table : Path
        Automatic angles of the drawn frames (CSV).
    labels : Path or None
        Labels with their angles (CSV).
    comparison : DataFrame or None
        Labels against automatic angles (also written as ``<trial>.label_compare.csv``).
    warnings : tuple of str
        Problems that did not stop the run.
    """

    trial: str
    images: tuple[Path, ...]
    video: Path | None
    table: Path
    labels: Path | None
    comparison: pd.DataFrame | None
    warnings: tuple[str, ...]


def _frame_selector(n_estimate: int, frames: Sequence[int] | None, every: int | None) -> tuple[set[int], int | None]:
    """Explicit frame set, or a stride (``every``; default about ten frames a video)."""
    if frames is not None:
        if any(int(f) < 0 for f in frames):
            raise InputError("--frames", "frame numbers must be >= 0")
        return {int(f) for f in frames}, None
    if every is not None:
        if every < 1:
            raise InputError("--every", "must be >= 1")
        return set(), int(every)
    return set(), max(1, n_estimate // 10)


def annotate_video(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    frames: Sequence[int] | None = None,
    every: int | None = None,
    mp4: bool = False,
    labels: pd.DataFrame | None = None,
    fps: float | None = None,
    trial: str | None = None,
    progress: bool = False,
    steps: VisionSteps = VisionSteps(),
) -> AnnotateResult:
    """Draw registration and measurement on frames of a video; compare with manual labels.

    Parameters
    ----------
    path : str or PathLike
        Video file or folder of frames.
    out_dir : str or PathLike
        Output folder.
    cfg : ExtractConfig
        Settings (as for extraction).
    frames : sequence of int, optional
        Frames to draw. Default: every ``every``-th frame, or about ten spread over the video.
    every : int, optional
        Draw every this many frames.
    mp4 : bool
        Also write ``<trial>.annotated.mp4`` with every frame annotated (at the source's fps).
    labels : DataFrame, optional
        Manual labels (:data:`LABEL_COLUMNS`); labelled frames are drawn too.
    fps : float, optional
        Frame rate (frames/s); needed for a folder of frames.
    trial : str, optional
        Trial name for the output files (default: file stem).
    progress : bool
        Progress bar on stderr.
    steps : VisionSteps
        The vision functions (as for extraction).

    Returns
    -------
    AnnotateResult

    Raises
    ------
    InputError
        Bad video, failed registration, bad frame selection.
    """
    name = trial_name(path, trial)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    source = open_frames(path, fps=fps)
    wanted, stride = _frame_selector(len(source), frames, every)
    label_table = _validate_labels(labels, "labels") if labels is not None else None
    label_rows = {int(r["frame"]): r for _, r in label_table.iterrows()} if label_table is not None else {}
    last_needed = None if (mp4 or stride is not None) else max(wanted | set(label_rows), default=0)

    def draw_pass(overrides: dict[int, tuple[Any, Any]]) -> _Drawn:
        """Measure and draw the video once; frames of an epoch in ``overrides`` are measured and
        drawn with its (registration, plan) instead."""
        drawn = _Drawn(log=ExtractLog())
        writer, tmp_video = None, None
        doubled = False
        try:
            for mf in measure_frames(source, cfg, trial=name, log=drawn.log, progress=progress, steps=steps):
                idx = mf.frame.index
                registration, measurement, row = mf.registration, mf.measurement, mf.row
                if mf.epoch in overrides and "time_ms" in row:
                    registration, plan = overrides[mf.epoch]
                    m = try_measure(steps, mf.gray, plan, cfg)
                    measurement = None if isinstance(m, Exception) else m
                    row = frame_row(name, mf.frame, raised_row(m) if measurement is None else m.to_row(), mf.epoch)
                doubled = doubled or bool(getattr(registration, "walls_doubled", False))
                drawn.rows.append(row)
                draw = idx in wanted or (stride is not None and idx % stride == 0) or idx in label_rows
                labels_px = None
                if idx in label_rows:
                    lab = label_rows[idx]
                    labels_px = {k: (lab[f"{k}_x_px"], lab[f"{k}_y_px"]) for k in ("tip", "bot")}
                    drawn.labels.append({**{c: lab[c] for c in LABEL_COLUMNS},
                                         **label_angles(lab, registration, cfg.phantom)})
                if draw or mp4:
                    title = f"{name}  frame {idx}  {mf.frame.time_s:.3f} s"
                    image = annotate_frame(mf.frame.image, registration, cfg.phantom, measurement,
                                           labels_px=labels_px, title=title)
                    if draw:
                        ok, buf = cv2.imencode(".png", image)
                        if not ok:  # pragma: no cover
                            raise RuntimeError(f"PNG encoding failed for frame {idx}")
                        drawn.images.append(atomic_write_bytes(out / f"{name}.frame{idx:06d}.png", buf.tobytes()))
                        drawn.drawn_rows.append(row)
                    if mp4:
                        if writer is None:
                            tmp_video = out / f".{name}.annotated.{secrets.token_hex(4)}.mp4"
                            h, w = image.shape[:2]
                            writer = cv2.VideoWriter(str(tmp_video), cv2.VideoWriter_fourcc(*"mp4v"), float(source.fps),
                                                     (w, h))
                            if not writer.isOpened():
                                raise RuntimeError("OpenCV cannot write mp4 files here (no mp4v encoder)")
                        writer.write(image)
                # where the walls show twice, every frame is the evidence of which copy the array touches
                if last_needed is not None and idx >= last_needed and not doubled:
                    break
            if writer is not None:
                writer.release()
                writer = None
                assert tmp_video is not None  # set with the writer
                os.replace(tmp_video, final_video)
                tmp_video = None
        finally:
            if writer is not None:
                writer.release()
            if tmp_video is not None:
                Path(tmp_video).unlink(missing_ok=True)
        return drawn

    final_video = out / f"{name}.annotated.mp4"
    drawn = draw_pass({})
    log = drawn.log
    switch = _copy_switches(drawn.rows, log, cfg)
    notes = []
    if switch:  # as extract does: the frames of those registrations measured (and drawn) again
        overrides = {}
        for k in switch:
            epoch = log.epochs[k]
            other = epoch.registration.other_copy()
            overrides[epoch.index] = (other, prepare_plan(steps, other, epoch.plan.image_shape, cfg))
        drawn = draw_pass(overrides)
        log = drawn.log
        notes.append(f"walls show twice: the frames of {len(switch)} registration(s) measured and drawn again on "
                     "their other copy, which the array touches")
    images, drawn_rows, label_out = drawn.images, drawn.drawn_rows, drawn.labels
    all_rows = drawn.rows if label_rows else []

    warnings = [*source.warnings, *log.warnings, *notes]
    seen = {r["frame"] for r in (all_rows or drawn_rows)}
    missing = sorted((wanted | set(label_rows)) - seen)
    if missing:
        warnings.append(f"frame(s) {', '.join(map(str, missing[:10]))} not in the video")
    table_path = atomic_write_csv(out / f"{name}.annotated.csv", _rows_table(drawn_rows))
    labels_path, comparison = None, None
    if label_table is not None:
        labelled = pd.DataFrame(label_out, columns=[*LABEL_COLUMNS, "theta_tip", "theta_bot", "theta_con"])
        labels_path = atomic_write_csv(out / f"{name}.labels.csv", labelled)
        comparison = compare_labels(labelled, _rows_table(all_rows))
        atomic_write_csv(out / f"{name}.label_compare.csv", comparison)
    return AnnotateResult(name, tuple(images), final_video if mp4 else None, table_path, labels_path, comparison,
                          tuple(warnings))


@dataclass
class _Drawn:
    """One pass of :func:`annotate_video` over a video: every frame's row, the drawn frames'
    rows and images, the labels' angles, and the pass's log."""

    log: ExtractLog
    rows: list[dict] = field(default_factory=list)
    drawn_rows: list[dict] = field(default_factory=list)
    images: list[Path] = field(default_factory=list)
    labels: list[dict] = field(default_factory=list)


def _copy_switches(rows: list[dict], log: ExtractLog, cfg: ExtractConfig) -> list[int]:
    """The registrations (positions in ``log.epochs``) that extraction measures again on the
    doubled walls' other copy (:func:`~tympani.pipeline.extract.video.copies_to_switch`), with
    the frames the motion checks mark left out of the evidence, as there."""
    _, flagged = flagged_by_motion(copy.deepcopy(rows), cfg)
    return list(copies_to_switch(rows, log.epochs, flagged))


def _rows_table(rows: list[dict]) -> pd.DataFrame:
    from tympani.pipeline.extract.video import ANGLE_COLUMNS

    table = pd.DataFrame(rows)
    if table.empty:
        return pd.DataFrame(columns=list(ANGLE_COLUMNS))
    extras = [c for c in table.columns if c not in ANGLE_COLUMNS]
    table = table[[*ANGLE_COLUMNS, *extras]]
    table["ok"] = table["ok"].astype(bool)
    return table

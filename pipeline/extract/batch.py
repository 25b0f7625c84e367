"""Video → angles: one video (:func:`extract_video`, :func:`process_video`) and many
(:func:`extract_batch`), plus the experiment manifest (:func:`read_manifest`).

The layers follow trackpy's ``locate``/``batch``:

- :func:`measure_frames` streams a :class:`~vision.frames.FrameSource` through registration
  and ``vision.angles.measure_frame``, one :class:`MeasuredFrame` at a time;
- :func:`extract_video` collects that stream into the angles table (docs/file-formats.md);
- :func:`process_video` is the unit of work: it takes a *path*, opens it itself (so it runs in
  a worker process or on a Dask worker), writes ``<trial>.angles.csv``,
  ``<trial>.registration.json`` and ``<trial>.provenance.json`` atomically, and skips videos
  whose outputs exist (resume) unless told to overwrite;
- :func:`extract_batch` maps :func:`process_video` over videos with a pluggable executor (this
  process, a forkserver process pool, or a ``dask.distributed.Client`` whose workers share the
  output folder) and returns one summary row per video; a failing video never stops the others.

Registration happens once per video on its first ``register_frames`` frames; when
``vision.angles`` offers ``prepare_measurement``, its per-registration plan is built once and
passed to ``measure_frame`` in place of the registration. Every
``recheck_every`` frames ``vision.registration.check`` measures the registration's residual on
the current frame; above ``residual_px * recheck_factor + recheck_margin_px`` the camera is taken
to have moved and the video is registered again on the next ``register_frames`` frames (the
frames since the last check were measured with the old registration; :func:`extract_video`
goes back over them, see :func:`remeasure_after_moves`). When that registration fails, the
registration is *lost*: frames are not measured (``ok`` false, with the reason) and the check
and registration are tried again after ``register_frames`` frames, then twice, four times ...
as many, at most ``recheck_every``, until the old registration fits again (the view was only
blocked) or a new one succeeds. Each registration is recorded; the angles table's
``reg_epoch`` column says which one a frame used.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import sliding_window_view

from tympani.pipeline.io import atomic_write_csv, atomic_write_json, check_writable_dir, csv_records, provenance, remove_stale_temps
from tympani.pipeline.extract.kinematics import KinematicsConfig, flag_kinematics
from tympani.vision.errors import InputError, is_input_error, one_line
from tympani.vision.frames import Frame, FrameSource, LensCalibration, check_decoder_threads, open_frames, to_gray, undistorter
from tympani.vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM, ElectrodeArray, Phantom

if TYPE_CHECKING:  # pragma: no cover
    from tympani.vision.registration import Registration

__all__ = [
    "ANGLE_COLUMNS",
    "SUMMARY_COLUMNS",
    "ExtractConfig",
    "ExtractLog",
    "MeasuredFrame",
    "VideoItem",
    "measure_frames",
    "extract_video",
    "flag_glitches",
    "process_video",
    "extract_batch",
    "is_dask_client",
    "output_paths",
    "trial_name",
    "read_manifest",
    "MANIFEST_REQUIRED",
]

#: The angles table's fixed columns, in order (docs/file-formats.md); extra columns follow them.
ANGLE_COLUMNS: tuple[str, ...] = ("trial", "frame", "time_s", "theta_tip", "theta_bot", "theta_con", "ok", "reason")

#: Columns of the per-video summary returned by :func:`extract_batch`.
SUMMARY_COLUMNS: tuple[str, ...] = (
    "trial", "path", "status", "n_frames", "n_ok", "error", "error_kind", "warnings", "n_registrations", "seconds",
)


def _default_measure_config() -> Any:
    from tympani.vision.angles import MeasureConfig

    return MeasureConfig()


def _default_registration_config() -> Any:
    import tympani.vision.registration as reg_mod

    factory = getattr(reg_mod, "RegistrationConfig", None)
    return factory() if factory is not None else None


@dataclass(frozen=True)
class ExtractConfig:
    """What :func:`extract_video` needs besides the video.

    Parameters
    ----------
    phantom : Phantom
        Phantom geometry (:mod:`vision.geometry`).
    array : ElectrodeArray
        Electrode array (:mod:`vision.geometry`).
    recheck_every : int
        Check the registration every this many frames (0: never).
    register_frames : int
        How many frames (from the start, or from a failed check) registration may use.
    measure : vision.angles.MeasureConfig
        Measurement settings, passed to ``measure_frame`` (and ``prepare_measurement``).
    registration : vision.registration.RegistrationConfig or None
        Registration settings, passed to ``register``; None calls it with its own defaults.
    recheck_factor : float
        A check fails when the residual (px) exceeds ``recheck_factor * residual_px +
        recheck_margin_px`` of the current registration.
    recheck_margin_px : float
        See ``recheck_factor`` (px).
    measure_batch : int
        Frames measured together by ``vision.angles.measure_frames_batch`` (same results as
        one at a time, less overhead per frame); 1 measures each frame on its own.
    measure_batch_mb : float
        Most grey-frame data (MiB) held for one batch: a batch ends at ``measure_batch``
        frames or at this much, whichever comes first (64 frames of 640x480, 16 of 1920x1080).
    decoder_threads : int or None
        Threads of the video decoder (``vision.frames.VideoFrames``); None leaves FFmpeg's
        default, one per core. :func:`extract_batch` runs its workers' decoders on one thread
        when this is None, as every core then has a worker of its own.
    glitch_rad : float
        A measured frame whose theta_tip or theta_bot lies more than this (rad) from the median
        of it and its two measured neighbours on each side is marked not ok as a glitch
        (:func:`flag_glitches`); 0 keeps every frame.
    kinematics_tol_mm : float
        A measured frame whose insertion depth lies more than this (mm; or five robust standard
        deviations of the video's depths about it, if more) from the video's constant-speed
        insertion is marked not ok (:func:`pipeline.extract.kinematics.flag_kinematics`), in runs as
        well as alone; 0 keeps every frame.
    calibration : vision.frames.LensCalibration or None
        The camera's lens. Frames are undistorted with it (:func:`vision.frames.undistorter`)
        before they are registered, checked or drawn, so the pose is that of the ideal pinhole
        image that the registration's similarity (phantom mm to image px) describes; the
        measurement samples the recorded frames where the lens put its strip's points
        (:meth:`~vision.frames.LensCalibration.distort_points`), which costs nothing a frame.
        None: frames are taken as they are.
    """

    phantom: Phantom = DEFAULT_PHANTOM
    array: ElectrodeArray = DEFAULT_ARRAY
    recheck_every: int = 150
    register_frames: int = 5
    measure: Any = field(default_factory=_default_measure_config)
    registration: Any = field(default_factory=_default_registration_config)
    recheck_factor: float = 2.0
    recheck_margin_px: float = 0.6
    measure_batch: int = 64
    measure_batch_mb: float = 32.0
    decoder_threads: int | None = None
    glitch_rad: float = 0.25
    kinematics_tol_mm: float = 0.5
    calibration: LensCalibration | None = None

    def __post_init__(self) -> None:
        if int(self.recheck_every) != self.recheck_every or self.recheck_every < 0:
            raise ValueError(f"recheck_every must be an integer >= 0, not {self.recheck_every!r}")
        if int(self.register_frames) != self.register_frames or self.register_frames < 1:
            raise ValueError(f"register_frames must be an integer >= 1, not {self.register_frames!r}")
        if int(self.measure_batch) != self.measure_batch or self.measure_batch < 1:
            raise ValueError(f"measure_batch must be an integer >= 1, not {self.measure_batch!r}")
        check_decoder_threads(self.decoder_threads)
        if not self.glitch_rad >= 0:
            raise ValueError(f"glitch_rad must be >= 0 rad, not {self.glitch_rad!r}")
        if not self.kinematics_tol_mm >= 0:
            raise ValueError(f"kinematics_tol_mm must be >= 0 mm, not {self.kinematics_tol_mm!r}")
        if not self.measure_batch_mb > 0:
            raise ValueError(f"measure_batch_mb must be > 0, not {self.measure_batch_mb!r}")
        if not (self.recheck_factor >= 1.0 and self.recheck_margin_px >= 0.0):
            raise ValueError("recheck_factor must be >= 1 and recheck_margin_px >= 0")

    def recheck_threshold_px(self, registration: "Registration") -> float:
        """Residual (px) above which a check re-registers the video."""
        return float(registration.residual_px) * self.recheck_factor + self.recheck_margin_px


@dataclass
class ExtractLog:
    """What happened while a video was measured (filled in by :func:`measure_frames`).

    Attributes
    ----------
    registrations : list of dict
        One entry per registration in force: ``frame`` (first frame it was used for), ``epoch``,
        ``trigger`` ("start" or "check"), ``check_residual_px`` and ``threshold_px`` (for
        "check"), ``n_frames_used`` and the registration's ``to_dict()`` keys.
    checks : list of tuple
        ``(frame, residual_px)`` of every registration check.
    warnings : list of str
        One line each (failed re-registrations, measurement exceptions).
    timing_s : dict of str to float
        Wall time (s) spent per stage: ``decode``, ``gray``, ``register``, ``prepare``,
        ``check``, ``measure``, plus ``measure.<stage>`` when measurements expose ``timings``.
    n_frames, n_ok, n_exceptions : int
        Frames measured, frames with ``ok``, frames whose measurement raised.
    first_registration : Registration or None
        The registration frame 0 was measured with.
    in_force : list of tuple
        ``(registration, plan)`` for each entry of ``registrations`` (the plan is what the
        measurement gets, see :func:`measure_frames`).
    lost : list of dict
        One entry per span in which the registration was lost (a failed check, then a failed
        registration): ``frame`` (the failed check), ``in_force`` (index of the registration
        then in force), ``attempts`` (failed registrations), ``ended`` ("check": the old
        registration fitted again, "registered": a new one succeeded, None: the video ended)
        ``ended_at`` (frame, or None), ``reason`` (the rows' reason) and ``retry_at`` (the next
        frame tried); :func:`remeasure_after_moves` adds ``moved_at_frame``.
    """

    registrations: list[dict] = field(default_factory=list)
    checks: list[tuple[int, float]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    timing_s: dict[str, float] = field(default_factory=dict)
    n_frames: int = 0
    n_ok: int = 0
    n_exceptions: int = 0
    first_registration: Any = None
    in_force: list[tuple[Any, Any]] = field(default_factory=list)
    lost: list[dict] = field(default_factory=list)

    def add_time(self, stage: str, seconds: float) -> None:
        self.timing_s[stage] = self.timing_s.get(stage, 0.0) + float(seconds)


@dataclass(frozen=True)
class MeasuredFrame:
    """One frame after measurement.

    Parameters
    ----------
    frame : Frame
        The decoded frame.
    gray : ndarray
        Its ``uint8`` greyscale version.
    registration : Registration
        The registration it was measured with.
    epoch : int
        Which registration (0 the first, 1 after the first re-registration, ...).
    measurement : vision.angles.FrameMeasurement or None
        The result (None when ``measure_frame`` raised).
    row : dict
        The angles-table row.
    """

    frame: Frame
    gray: np.ndarray
    registration: Any
    epoch: int
    measurement: Any
    row: dict


# --------------------------------------------------------------------------- one video


def _frame_row(trial: str, frame: Frame, result: dict, epoch: int) -> dict:
    """The angles-table row of one frame from ``FrameMeasurement.to_row()`` output."""
    ok = bool(result.get("ok", False))
    row: dict[str, Any] = {"trial": trial, "frame": int(frame.index), "time_s": float(frame.time_s)}
    for key in ("theta_tip", "theta_bot", "theta_con"):
        value = result.get(key)
        row[key] = float(value) if ok and value is not None else math.nan
    row["ok"] = ok
    reason = result.get("reason")
    row["reason"] = "" if reason is None else " ".join(str(reason).split())
    if not ok and not row["reason"]:
        row["reason"] = "not measured"
    for key, value in result.items():
        if key in row or key == "reg_epoch":
            continue
        if value is None or np.isscalar(value):
            row[key] = value.item() if isinstance(value, np.generic) else value
    row["reg_epoch"] = int(epoch)
    return row


def _lens(calibration: LensCalibration, source: FrameSource, shape: tuple[int, ...]) -> Callable[[np.ndarray], np.ndarray]:
    """The undistortion of ``source``'s frames of ``shape`` (px) by ``calibration``.

    Raises
    ------
    InputError
        The frames are not of the size the calibration was made at.
    """
    try:
        return undistorter(calibration, shape)
    except ValueError as exc:
        raise InputError(source.path, str(exc)) from None


def _check_due(cfg: ExtractConfig, index: int, last_registered_at: int) -> bool:
    """Whether frame ``index`` gets a registration check."""
    return bool(cfg.recheck_every) and index % cfg.recheck_every == 0 and index > last_registered_at


def _is_registration_failure(exc: BaseException, reg_module: Any) -> bool:
    failure = getattr(reg_module, "RegistrationError", None)
    return is_input_error(exc) or (isinstance(failure, type) and isinstance(exc, failure))


def _try_measure(angles_mod: Any, gray: np.ndarray, plan: Any, cfg: ExtractConfig) -> Any:
    """``angles_mod.measure_frame`` of one grey frame, or the exception it raised (also from
    ``to_row``): a failed frame keeps its row."""
    try:
        m = angles_mod.measure_frame(gray, plan, cfg.phantom, cfg.array, cfg.measure)
        m.to_row()
        return m
    except Exception as exc:
        return exc


def measure_frames(
    source: FrameSource,
    cfg: ExtractConfig,
    *,
    trial: str,
    log: ExtractLog | None = None,
    progress: bool = False,
    keep_colour: bool = True,
) -> Iterator[MeasuredFrame]:
    """Register and measure the frames of ``source``, streaming.

    Parameters
    ----------
    source : FrameSource
        The frames (see :func:`vision.frames.open_frames`).
    cfg : ExtractConfig
        Phantom, array, registration and measurement settings.
    trial : str
        Trial name written in each row.
    log : ExtractLog, optional
        Filled in with registrations, checks, warnings, timings and counts.
    progress : bool
        Show a per-frame progress bar on stderr.
    keep_colour : bool
        Yield each frame as decoded. False yields it with its grey image in place of the
        decoded one, so that the frames waiting for a batch hold no colour copy (a third of
        the memory, and fresh allocations the decoder would otherwise pay for).

    Yields
    ------
    MeasuredFrame
        In frame order. Frames measured with the same plan are measured ``cfg.measure_batch``
        at a time, fewer when those would exceed ``cfg.measure_batch_mb``
        (``vision.angles.measure_frames_batch``, when the measurement has a plan); at most a
        batch, or ``cfg.register_frames`` frames while a registration is pending, are held
        back. The ``measure`` time of a batch is shared equally among its
        frames.

    Raises
    ------
    InputError
        The first registration failed (no phantom found), or the frames are bad.
    """
    import tympani.vision.angles as angles_mod  # looked up at call time: replaceable in tests
    import tympani.vision.registration as reg_mod

    log = log if log is not None else ExtractLog()
    phantom = cfg.phantom
    registration: Any = None
    epoch = -1
    pending: list[tuple[Frame, np.ndarray]] = []
    trigger: dict[str, Any] = {"trigger": "start"}
    last_registered_at = 0

    plan: Any = None  # what measure_frame gets as its registration (see register_pending)

    queue: list[tuple[Frame, np.ndarray]] = []  # frames waiting to be measured with the current plan
    undistort: Callable[[np.ndarray], np.ndarray] | None = None  # cfg.calibration's, made on the first frame
    lost: dict | None = None  # the open entry of log.lost while the registration is lost

    def ideal(gray: np.ndarray) -> np.ndarray:
        """What registration and checks see of a grey frame: undistorted when there is a lens."""
        if undistort is None:
            return gray
        t0 = time.perf_counter()
        out = undistort(gray)
        log.add_time("undistort", time.perf_counter() - t0)
        return out

    def measured(frame: Frame, gray: np.ndarray, m: Any, seconds: float, result: dict | None = None
                 ) -> MeasuredFrame:
        """The row of one measurement ``m`` (an exception when it raised), ``seconds`` spent;
        ``result`` is ``m.to_row()`` when already computed."""
        if isinstance(m, Exception):  # a failed frame keeps its row
            result = {"ok": False, "reason": f"measurement raised {one_line(m)}"}
            if log.n_exceptions == 0:
                log.warnings.append(f"frame {frame.index}: measurement raised {one_line(m)}")
            log.n_exceptions += 1
            m = None
        elif result is None:
            result = m.to_row()
        log.add_time("measure", seconds)
        for stage, stage_s in (getattr(m, "timings", None) or {}).items():
            log.add_time(f"measure.{stage}", stage_s)
        row = _frame_row(trial, frame, result, epoch)
        log.n_frames += 1
        log.n_ok += bool(row["ok"])
        return MeasuredFrame(frame, gray, registration, epoch, m, row)

    def unmeasured(frame: Frame, gray: np.ndarray, reason: str) -> MeasuredFrame:
        """The row of a frame left unmeasured (``ok`` false) for ``reason``."""
        row = _frame_row(trial, frame, {"ok": False, "reason": reason}, epoch)
        log.n_frames += 1
        return MeasuredFrame(frame, gray, registration, epoch, None, row)

    def measure(frame: Frame, gray: np.ndarray) -> MeasuredFrame:
        t0 = time.perf_counter()
        m = _try_measure(angles_mod, gray, plan, cfg)
        return measured(frame, gray, m, time.perf_counter() - t0)

    def flush() -> list[MeasuredFrame]:
        """Measure the queued frames (together when the measurement has a plan for them)."""
        items = queue[:]
        queue.clear()
        batch_fn = getattr(angles_mod, "measure_frames_batch", None)
        if len(items) < 2 or batch_fn is None or plan is registration:  # no plan: one at a time
            return [measure(f, g) for f, g in items]
        t0 = time.perf_counter()
        try:
            ms = list(batch_fn([g for _, g in items], plan))
            if len(ms) != len(items):
                raise RuntimeError(f"measure_frames_batch gave {len(ms)} results for {len(items)} frames")
            results = [m.to_row() for m in ms]
        except Exception:  # one at a time instead, so that only the frame that raises fails
            return [measure(f, g) for f, g in items]
        share = (time.perf_counter() - t0) / len(items)
        return [measured(f, g, m, share, r) for (f, g), m, r in zip(items, ms, results)]

    def enqueue(frame: Frame, gray: np.ndarray) -> list[MeasuredFrame]:
        queue.append((frame, gray))
        full = len(queue) >= cfg.measure_batch or len(queue) * gray.nbytes >= cfg.measure_batch_mb * 2**20
        return flush() if full else []

    def register_pending() -> None:
        """Register on the pending frames; a failure after the first registration opens (or
        extends) a lost span instead of raising."""
        nonlocal registration, plan, epoch, last_registered_at, lost
        at = pending[0][0].index
        frames_used = [ideal(g) for _, g in pending]
        t0 = time.perf_counter()
        try:
            if cfg.registration is None:
                new = reg_mod.register(frames_used, phantom)
            else:
                new = reg_mod.register(frames_used, phantom, cfg.registration)
        except Exception as exc:
            if registration is None:
                if _is_registration_failure(exc, reg_mod):
                    problem = getattr(exc, "problem", None) or " ".join(str(exc).split())
                    raise InputError(source.path, f"registration failed: {problem}") from exc
                raise
            if lost is None:
                lost = {"frame": at, "in_force": len(log.in_force) - 1, "attempts": 0, "ended": None,
                        "ended_at": None, "reason": f"registration lost: the check at frame {at} failed and "
                                                   f"registering again failed ({one_line(exc)})"}
                log.lost.append(lost)
                log.warnings.append(f"re-registration at frame {at} failed ({one_line(exc)}); frames are not "
                                    "measured until the old registration fits again or a new one succeeds")
            lost["attempts"] += 1
            # try again after register_frames frames, then twice, four times ... as many
            gap = min(cfg.register_frames * 2 ** (lost["attempts"] - 1), max(cfg.recheck_every, cfg.register_frames))
            lost["retry_at"] = pending[-1][0].index + 1 + gap
            return
        else:
            if lost is not None:
                lost.update(ended="registered", ended_at=at)
                lost = None
            epoch += 1
            if log.first_registration is None:
                log.first_registration = new
            log.registrations.append(
                {"frame": pending[0][0].index, "epoch": epoch, **trigger, "n_frames_used": len(pending), **new.to_dict()}
            )
        finally:
            log.add_time("register", time.perf_counter() - t0)
        plan = new
        prepare = getattr(angles_mod, "prepare_measurement", None)
        if prepare is not None:  # per-registration precomputation, passed in its place
            t0 = time.perf_counter()
            lens = {} if cfg.calibration is None else {"lens": cfg.calibration.distort_points}
            plan = prepare(new, pending[0][1].shape, phantom, cfg.array, cfg.measure, **lens)
            log.add_time("prepare", time.perf_counter() - t0)
            refusal = getattr(plan, "refusal", None)
            if refusal:  # every frame of this registration fails the same way: say it once
                log.warnings.append(f"frames from {at} on: {refusal}")
        log.in_force.append((new, plan))
        registration = new
        last_registered_at = at

    def after_registering() -> Iterator[MeasuredFrame]:
        """The pending frames, measured with the new registration or left unmeasured when it
        is lost."""
        for f, g in pending:
            if lost is None:
                yield from enqueue(f, g)
            else:
                yield unmeasured(f, g, lost["reason"])

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(source), unit="frame", desc=trial, leave=False, file=sys.stderr, dynamic_ncols=True)
    frames = iter(source)
    try:
        while True:
            t0 = time.perf_counter()
            frame = next(frames, None)
            t1 = time.perf_counter()
            log.add_time("decode", t1 - t0)
            if frame is None:
                break
            gray = to_gray(frame.image)
            log.add_time("gray", time.perf_counter() - t1)
            if cfg.calibration is not None:
                if undistort is None:  # the frame size checked once
                    undistort = _lens(cfg.calibration, source, gray.shape)
                if keep_colour:  # drawn on: the ideal image, as the pose is
                    t1 = time.perf_counter()
                    frame = Frame(frame.index, frame.time_s, undistort(frame.image))
                    log.add_time("undistort", time.perf_counter() - t1)
            if not keep_colour:
                frame = Frame(frame.index, frame.time_s, gray)
            if bar is not None:
                bar.update(1)
            if registration is not None and not pending:
                if lost is not None and frame.index < lost["retry_at"]:
                    yield unmeasured(frame, gray, lost["reason"])
                    continue
                if lost is None and not _check_due(cfg, frame.index, last_registered_at):
                    yield from enqueue(frame, gray)
                    continue
                seen = ideal(gray)
                t2 = time.perf_counter()
                residual = float(reg_mod.check(seen, registration, phantom))
                log.add_time("check", time.perf_counter() - t2)
                log.checks.append((frame.index, residual))
                threshold = cfg.recheck_threshold_px(registration)
                if residual <= threshold:
                    if lost is not None:  # the old registration fits again: the view was blocked, not moved
                        lost.update(ended="check", ended_at=frame.index)
                        log.warnings.append(f"frames {lost['frame']}-{frame.index - 1} not measured (registration "
                                            f"lost); the old registration fits again from frame {frame.index}")
                        lost = None
                    yield from enqueue(frame, gray)
                    continue
                # NaN or too large: the camera moved; register again from this frame on
                trigger = {"trigger": "check", "check_residual_px": residual, "threshold_px": threshold}
            pending.append((frame, gray))
            if len(pending) >= cfg.register_frames:
                yield from flush()  # the frames before these, with the plan they were measured against
                register_pending()
                yield from after_registering()
                pending = []
        yield from flush()
        if pending:  # video (or its rest) shorter than register_frames
            register_pending()
            yield from after_registering()
            yield from flush()
            pending = []
    finally:
        close = getattr(frames, "close", None)
        if close is not None:  # release the decoder now, also when the consumer stops early
            close()
        if bar is not None:
            bar.close()
    if log.n_exceptions > 1:
        log.warnings.append(f"measurement raised on {log.n_exceptions} frames in all")


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


def output_paths(out_dir: str | os.PathLike, trial: str) -> dict[str, Path]:
    """Files :func:`process_video` writes for ``trial`` in ``out_dir``:
    ``angles`` (CSV), ``registration`` (JSON), ``provenance`` (JSON)."""
    out = Path(out_dir)
    return {
        "angles": out / f"{trial}.angles.csv",
        "registration": out / f"{trial}.registration.json",
        "provenance": out / f"{trial}.provenance.json",
    }


def extract_video(
    path: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    fps: float | None = None,
    trial: str | None = None,
    progress: bool = False,
) -> tuple[pd.DataFrame, "Registration"]:
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

    Returns
    -------
    table : DataFrame
        One row per decoded frame: :data:`ANGLE_COLUMNS`, then the measurement's extra scalar
        columns, then ``reg_epoch``. Failed frames have ``ok`` False, NaN angles and a
        ``reason``. ``table.attrs`` holds ``registrations``, ``lost`` (the spans in which the
        registration was lost, see :class:`ExtractLog`), ``checks``, ``warnings``
        (decoder, measurement, the camera moves whose frames :func:`remeasure_after_moves`
        went back over, and the glitches :func:`flag_glitches` marked), ``timing_s`` and
        ``source`` (see :class:`ExtractLog`).
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
    rows = [m.row for m in measure_frames(source, cfg, trial=name, log=log, progress=progress, keep_colour=False)]
    t0 = time.perf_counter()
    notes = remeasure_after_moves(source, rows, log, cfg, name)
    log.add_time("remeasure", time.perf_counter() - t0)
    glitches = flag_glitches(rows, cfg.glitch_rad)
    if glitches:
        notes.append(f"{glitches} frame(s) marked not ok as glitches (an angle over {cfg.glitch_rad:g} rad from the "
                     "median of its measured neighbours)")
    if cfg.kinematics_tol_mm > 0:
        runs, note = flag_kinematics(rows, KinematicsConfig(tol_mm=cfg.kinematics_tol_mm))
        if note:
            notes.append(note)
    width = array_width(rows, cfg.array)
    if width["warning"]:
        notes.append(width["warning"])
    table = pd.DataFrame(rows)
    extras = [c for c in table.columns if c not in ANGLE_COLUMNS and c != "reg_epoch"]
    table = table.reindex(columns=[*ANGLE_COLUMNS, *extras, "reg_epoch"])
    table["ok"] = table["ok"].astype(bool)
    table.attrs.update(
        registrations=log.registrations,
        lost=[{k: v for k, v in span.items() if k not in ("in_force", "retry_at")} for span in log.lost],
        checks=log.checks,
        warnings=[*source.warnings, *log.warnings, *notes],
        timing_s=log.timing_s,
        source=source.info(),
        array_width={k: v for k, v in width.items() if k != "warning"},
    )
    return table, log.first_registration


def array_width(rows: list[dict], array: ElectrodeArray, *, tolerance: float = 0.1, min_frames: int = 10) -> dict:
    """How wide the array looks against the model the measurement assumes.

    The measurement reads the gap to the wall from the modelled diameters
    (:class:`~vision.geometry.ElectrodeArray`), so an array wider or narrower than its model
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
    running median whose windows are clipped to ``x`` at its ends (values in ``x``'s unit).
    The windows inside ``x`` are taken in one call; only the clipped ones at the ends loop."""
    out = np.empty(n_out)
    first, last = before, min(n_out - 1, len(x) - width + before)  # the j whose window lies inside x
    if last >= first:
        out[first : last + 1] = np.median(sliding_window_view(x, width)[: last - first + 1], axis=1)
    for j in (*range(min(first, n_out)), *range(max(last + 1, first), n_out)):
        out[j] = np.median(x[max(0, j - before) : j - before + width])
    return out


def flag_glitches(rows: list[dict], max_rad: float, half_window: int = 2) -> int:
    """Mark isolated outliers in time as not ok, in place.

    The angles move smoothly from frame to frame, or step (theta_bot when a contact run forms or
    breaks). A frame measured far from its neighbours on both sides is a measurement glitch: a
    few edges misread can move theta_bot by radians through the contact run's definition. Over
    a video's measured frames in order, a frame is marked when its ``theta_tip`` or
    ``theta_bot`` lies from the running median of ``2 * half_window + 1`` measured frames
    centred on it (fewer at the ends) by more than ``max_rad``, and by more than ``2 *
    half_window`` typical frame-to-frame steps (the median absolute step over the 11 frames
    around it): on a steep ramp (a fast insertion) a spike pulls its neighbours' medians by up
    to ``half_window`` steps. A running median leaves ramps and steps as they are and removes
    spikes up to ``half_window`` frames long. Marked rows get ``ok`` False, NaN angles and the
    reason.

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
    ok = [i for i in sorted(range(len(rows)), key=lambda i: rows[i]["frame"]) if rows[i]["ok"]]
    if max_rad <= 0 or len(ok) < 2 * half_window + 1:
        return 0
    marked = np.zeros(len(ok), dtype=bool)
    why = [""] * len(ok)
    for key in ("theta_tip", "theta_bot"):
        x = np.array([float(rows[i][key]) for i in ok])
        med = _window_medians(x, half_window, 2 * half_window + 1, len(x))
        typical = _window_medians(np.abs(np.diff(x)), 5, 10, len(x))  # the 10 steps among the 11 frames around
        off = np.abs(x - med)
        far = off > np.maximum(max_rad, 2 * half_window * typical)
        for j in np.flatnonzero(far & ~marked):
            why[j] = f"glitch: {key} {x[j]:.3f} rad, {off[j]:.2f} rad from its neighbours' median"
        marked |= far
    for j in np.flatnonzero(marked):
        rows[ok[j]].update(ok=False, reason=why[j], theta_tip=math.nan, theta_bot=math.nan, theta_con=math.nan)
    return int(marked.sum())


def remeasure_after_moves(source: FrameSource, rows: list[dict], log: ExtractLog, cfg: ExtractConfig,
                          trial: str) -> list[str]:
    """Go back over the frames seen after the camera moved but before a check noticed it.

    A check every ``cfg.recheck_every`` frames finds a move late, so the frames between the move
    and the check were measured with the old pose. For each failed check that led to a new
    registration, and for each lost span that did not end in one (see :func:`measure_frames`),
    the frames after the last known-good one (the old registration's own frames or its last
    passing check) are decoded again, in order, and checked against the old registration. From
    the first that fails on (the move), each frame is measured with the new registration, and
    gets its ``reg_epoch``, when it fits that one; otherwise (the camera still moving, the view
    blocked, or no new registration) it is marked not ok. That entry of ``log.registrations``
    (or of ``log.lost``) gets ``moved_at_frame``.

    Parameters
    ----------
    source : FrameSource
        The video, decoded again from the start (seeking is not frame-exact in every codec).
    rows : list of dict
        The frame rows of :func:`measure_frames`, in frame order; replaced in place.
    log : ExtractLog
        Its registrations, checks, ``in_force`` and lost spans.
    cfg : ExtractConfig
        Settings (check threshold, phantom, measurement).
    trial : str
        Trial name of the rows.

    Returns
    -------
    list of str
        One line per span gone over in which the camera was found to have moved.
    """
    import tympani.vision.angles as angles_mod  # looked up at call time: replaceable in tests
    import tympani.vision.registration as reg_mod

    notes: list[str] = []
    undistort: Callable[[np.ndarray], np.ndarray] | None = None  # cfg.calibration's, made on the first frame
    regs = log.registrations
    at = {int(r["frame"]): i for i, r in enumerate(rows)}
    # (registration in force before, frame where the move was seen, new registration or None, entry)
    spans: list[tuple[int, int, int | None, dict]] = [
        (j - 1, int(regs[j]["frame"]), j, regs[j]) for j in range(1, min(len(regs), len(log.in_force)))
        if regs[j].get("trigger") == "check"]
    spans += [(int(lost["in_force"]), int(lost["frame"]), None, lost) for lost in log.lost
              if lost.get("ended") != "registered"]
    for i_old, seen_at, i_new, entry in sorted(spans, key=lambda sp: sp[1]):
        old = log.in_force[i_old][0]
        threshold = cfg.recheck_threshold_px(old)
        good = int(regs[i_old]["frame"]) + int(regs[i_old].get("n_frames_used", 1)) - 1
        # the old registration's last passing check before the move was seen
        good = max([good, *(f for f, r in log.checks if good < f < seen_at and r <= threshold)])
        if good + 1 >= seen_at:
            continue
        new = None if i_new is None else log.in_force[i_new]
        new_threshold = math.nan if new is None else cfg.recheck_threshold_px(new[0])
        epoch = int(regs[i_old]["epoch"] if i_new is None else regs[i_new]["epoch"])
        first, fitted = None, 0
        frames = iter(source)
        try:
            for frame in frames:
                if frame.index <= good:
                    continue
                if frame.index >= seen_at:
                    break
                gray = to_gray(frame.image)
                seen = gray  # what the checks see: the ideal image when there is a lens (the plans sample gray)
                if cfg.calibration is not None:
                    undistort = undistort or _lens(cfg.calibration, source, gray.shape)
                    seen = undistort(gray)
                if first is None:
                    if float(reg_mod.check(seen, old, cfg.phantom)) <= threshold:  # NaN: moved
                        continue
                    first = frame.index
                if new is not None and float(reg_mod.check(seen, new[0], cfg.phantom)) <= new_threshold:
                    m = _try_measure(angles_mod, gray, new[1], cfg)
                    result = ({"ok": False, "reason": f"measurement raised {one_line(m)}"}
                              if isinstance(m, Exception) else m.to_row())
                    fitted += 1
                else:  # the camera still moving, the view blocked, or no new registration
                    result = {"ok": False, "reason": f"the view changed at frame {first} (seen by the check at "
                                                     f"{seen_at}) and no registration fits this frame"}
                rows[at[frame.index]] = _frame_row(trial, frame, result, epoch)
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()
        entry["moved_at_frame"] = first if first is not None else seen_at
        if first is None:
            continue
        span = f"at frame {first} (seen by the check at {seen_at}); frames {first}-{seen_at - 1}"
        if new is None:
            notes.append(f"view changed {span} marked not ok (no registration fits them)")
        elif fitted == seen_at - first:
            notes.append(f"camera moved {span} measured again with the new registration")
        else:
            notes.append(f"camera moved {span}: {fitted} measured again with the new registration, "
                         f"{seen_at - first - fitted} marked not ok (they fit neither registration)")
    return notes


def _count_ok(csv_path: Path) -> tuple[int, int] | None:
    """(rows, ok rows) of an existing angles table, None when it cannot be read."""
    try:
        ok = pd.read_csv(csv_path, usecols=["ok"], true_values=["true", "True", "TRUE"],
                         false_values=["false", "False", "FALSE"])["ok"]
    except Exception:
        return None
    return len(ok), int((ok == True).sum())  # noqa: E712 - ok may be object dtype


def _summary(trial: str, path: Path, status: str, **values: Any) -> dict:
    row: dict[str, Any] = {c: None for c in SUMMARY_COLUMNS}
    row.update(trial=trial, path=str(path), status=status, error="", error_kind="", warnings="")
    row.update(values)
    return row


def process_video(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    fps: float | None = None,
    trial: str | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> dict:
    """Extract one video's angles and write them, with registration and provenance, to files.

    Writes ``<trial>.angles.csv``, ``<trial>.registration.json`` (the first registration's
    pose and fit keys, docs/file-formats.md, plus ``registrations``: every registration used,
    with the frame it started at, and ``lost``: the spans in which the registration was lost) and
    ``<trial>.provenance.json`` (written last: its presence marks a finished video) in
    ``out_dir``, each atomically. If interrupted while writing, the files written so far in this
    call are removed again.

    Parameters
    ----------
    path : str or PathLike
        Video file or folder of frames (opened here, so this runs in any worker process).
    out_dir : str or PathLike
        Output folder (created if needed).
    cfg : ExtractConfig
        Settings.
    fps : float, optional
        Frame rate (frames/s); see :func:`extract_video`.
    trial : str, optional
        Trial name (default: file stem); names the output files.
    overwrite : bool
        Redo a video whose three outputs exist (default: skip it, so reruns resume).
    progress : bool
        Per-frame progress bar on stderr.

    Returns
    -------
    dict
        A summary row (:data:`SUMMARY_COLUMNS`) with ``status`` "ok" or "skipped".

    Raises
    ------
    InputError
        Bad input or failed registration. Other exceptions are bugs.
    """
    name = trial_name(path, trial)
    path = Path(path)
    files = output_paths(out_dir, name)
    if not overwrite and all(f.exists() for f in files.values()):
        counts = _count_ok(files["angles"])
        if counts is not None:
            return _summary(name, path, "skipped", n_frames=counts[0], n_ok=counts[1], seconds=0.0)
    t0 = time.perf_counter()
    table, registration = extract_video(path, cfg, fps=fps, trial=name, progress=progress)
    registrations = table.attrs["registrations"]
    warnings = list(table.attrs["warnings"])
    n_ok = int(table["ok"].sum())
    seconds = time.perf_counter() - t0
    reg_record = {**registration.to_dict(), "registrations": registrations, "lost": table.attrs["lost"],
                  "array_width_ratio": table.attrs["array_width"]}
    prov = provenance(
        path,
        {"extract": cfg, "fps": fps, "trial": name},
        command="extract",
        source=table.attrs["source"],
        outputs={k: f.name for k, f in files.items()},
        n_frames=len(table),
        n_ok=n_ok,
        checks=[{"frame": f, "residual_px": r} for f, r in table.attrs["checks"]],
        warnings=warnings,
        timing_s={**table.attrs["timing_s"], "total": seconds},
    )
    for f in files.values():  # left by a run killed outright while writing; never read
        remove_stale_temps(f)
    written: list[Path] = []
    try:
        atomic_write_csv(files["angles"], table)
        written.append(files["angles"])
        atomic_write_json(files["registration"], reg_record)
        written.append(files["registration"])
        atomic_write_json(files["provenance"], prov)
    except BaseException:
        for f in written:
            f.unlink(missing_ok=True)
        raise
    return _summary(
        name, path, "ok",
        n_frames=len(table), n_ok=n_ok, warnings="; ".join(warnings),
        n_registrations=len(registrations), seconds=round(seconds, 3),
    )


# --------------------------------------------------------------------------- many videos


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


def _as_items(items: Any) -> list[VideoItem]:
    """Normalise paths, dicts, :class:`VideoItem` s or a manifest DataFrame to items."""
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


# Set in worker processes of a pool that extract_batch owns (by _init_worker): once the main
# process is interrupted, queued videos are skipped instead of started.
_CANCEL_EVENT: Any = None


def _run_one(item: VideoItem, trial: str, out_dir: str, cfg: ExtractConfig, fps: float | None,
             overwrite: bool, single_thread: bool, progress: bool) -> dict:
    """Worker body: :func:`process_video` with every failure turned into a summary row."""
    if _CANCEL_EVENT is not None and _CANCEL_EVENT.is_set():
        return _summary(trial, Path(item.path), "failed", error="cancelled (interrupted)", error_kind="cancelled")
    blas = contextlib.nullcontext()
    if single_thread:  # one worker a core: OpenCV, BLAS and the decoder (unless told otherwise) on one thread
        import cv2
        from threadpoolctl import threadpool_limits

        cv2.setNumThreads(1)
        blas = threadpool_limits(limits=1)
        if cfg.decoder_threads is None:
            cfg = dataclasses.replace(cfg, decoder_threads=1)
    t0 = time.perf_counter()
    try:
        with blas:
            return process_video(item.path, out_dir, cfg, fps=item.fps if item.fps is not None else fps,
                                 trial=trial, overwrite=overwrite, progress=progress)
    except Exception as exc:
        return _summary(trial, Path(item.path), "failed", error=one_line(exc),
                        error_kind="input" if is_input_error(exc) else "error",
                        seconds=round(time.perf_counter() - t0, 3))


def _init_worker(cancel_event: Any) -> None:
    global _CANCEL_EVENT
    import cv2

    cv2.setNumThreads(1)
    _CANCEL_EVENT = cancel_event


def _pool_context():
    """Start method of the worker processes: forkserver, not fork — a forked child of a process
    whose OpenCV or BLAS threads hold locks (e.g. after rendering in the same process) can hang."""
    import multiprocessing

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["numpy", "cv2", "pandas", "tympani.pipeline.extract.batch"])
    return ctx


def is_dask_client(executor: Any) -> bool:
    """Whether ``executor`` is a ``dask.distributed.Client`` (checked without importing Dask)."""
    return type(executor).__module__.split(".")[0] == "distributed" and hasattr(executor, "scheduler_info")


def _submit(executor: Any, fn: Any, *args: Any) -> Any:
    """``executor.submit(fn, *args)``; a Dask client gets ``pure=False`` (always run, even when
    a task with the same arguments is still held by the cluster, e.g. after ``--overwrite``)."""
    if is_dask_client(executor):
        return executor.submit(fn, *args, pure=False)
    return executor.submit(fn, *args)


def _completed(futures: list) -> Iterator:
    """Futures in completion order for ``concurrent.futures`` and Dask futures, else in order
    (any other future's ``result()`` simply blocks)."""
    if futures and all(isinstance(f, cf.Future) for f in futures):
        yield from cf.as_completed(futures)
    elif futures and type(futures[0]).__module__.split(".")[0] == "distributed":
        from distributed import as_completed

        yield from as_completed(futures, loop=futures[0].client.loop)  # the client need not be the default
    else:
        yield from futures


def _for_worker(item: VideoItem) -> VideoItem:
    """``item`` with an absolute path: a worker may run in another folder (forkserver, Dask)."""
    return VideoItem(os.path.abspath(item.path), item.trial, item.fps)


def extract_batch(
    items: Iterable[str | os.PathLike | VideoItem | dict] | pd.DataFrame,
    out_dir: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    workers: int = 1,
    executor: Any = None,
    overwrite: bool = False,
    progress: bool = True,
    fps: float | None = None,
) -> pd.DataFrame:
    """Extract the angles of many videos; a failing video is recorded and the rest go on.

    Parameters
    ----------
    items : iterable or DataFrame
        Video paths, :class:`VideoItem` s, dicts with ``path`` (or ``video``), ``trial``,
        ``fps``, or a manifest DataFrame (:func:`read_manifest`; rows without a video are
        ignored).
    out_dir : str or PathLike
        Output folder.
    cfg : ExtractConfig
        Settings (pickled to workers).
    workers : int
        Processes to use when no ``executor`` is given; 1 runs in this process.
    executor : object, optional
        Anything with ``submit(fn, *args) -> future`` whose futures have ``result()``:
        ``concurrent.futures`` executors, a ``dask.distributed.Client`` (tasks submitted with
        ``pure=False``), ... It is not shut down here. Its workers get ``cv2.setNumThreads(1)``
        and absolute paths; they must be able to import tympani and to read the videos and
        write ``out_dir`` under the same paths as this process (a shared file system).
    overwrite : bool
        Redo videos whose outputs exist.
    progress : bool
        Progress bar (videos; frames too when running serially) on stderr.
    fps : float, optional
        Frame rate (frames/s) for items that do not give their own.

    Returns
    -------
    DataFrame
        One row per video in input order, columns :data:`SUMMARY_COLUMNS`: ``status`` is
        "ok", "skipped" or "failed"; ``error`` a one-line reason; ``error_kind`` "input" (bad
        input, failed registration) or "error" (a bug or a crashed worker).

    Notes
    -----
    On KeyboardInterrupt with a pool of its own, videos not yet started are skipped, the
    running ones are interrupted (Ctrl-C reaches the whole process group) or, when only this
    process got the signal, finish; then the interrupt is re-raised. With a given executor the
    futures not yet finished are cancelled. Outputs are written atomically, so no video is left
    with half-written files, and a rerun redoes exactly the videos that did not finish.

    Raises
    ------
    InputError
        Two videos would get the same trial name (their outputs would collide).
    OutputError
        ``out_dir`` cannot be created or written (checked before any video is started).
    """
    videos = _as_items(items)
    trials: dict[str, str] = {}
    names = []
    for item in videos:
        name = trial_name(item.path, item.trial)
        if name in trials:
            raise InputError(item.path, f"trial name {name!r} is also used by {trials[name]}; give distinct trial names")
        trials[name] = item.path
        names.append(name)
    out = os.fspath(out_dir)
    check_writable_dir(out)
    results: list[dict | None] = [None] * len(videos)
    from tqdm import tqdm

    with tqdm(total=len(videos), unit="video", desc="extract", file=sys.stderr, disable=not progress,
              dynamic_ncols=True) as bar:
        if executor is None and workers <= 1:
            for i, (item, name) in enumerate(zip(videos, names)):
                results[i] = _run_one(item, name, out, cfg, fps, overwrite, False, progress)
                bar.update(1)
        else:
            own = executor is None
            cancel = None
            if own:
                ctx = _pool_context()
                cancel = ctx.Event()
                pool = cf.ProcessPoolExecutor(max_workers=int(workers), mp_context=ctx, initializer=_init_worker,
                                              initargs=(cancel,))
            else:
                pool = executor
            futures: list = []
            try:
                out_abs = os.path.abspath(out)
                futures = [_submit(pool, _run_one, _for_worker(item), name, out_abs, cfg, fps, overwrite, True, False)
                           for item, name in zip(videos, names)]
                index = {id(f): i for i, f in enumerate(futures)}
                for fut in _completed(futures):
                    i = index[id(fut)]
                    try:
                        results[i] = {**fut.result(), "path": str(Path(videos[i].path))}
                    except Exception as exc:  # the worker itself died (crash, pickling, ...)
                        results[i] = _summary(names[i], Path(videos[i].path), "failed",
                                              error=one_line(exc), error_kind="error")
                    bar.update(1)
            except KeyboardInterrupt:
                if own:  # skip queued videos; running ones stop (Ctrl-C reaches them) or finish whole
                    assert cancel is not None  # made with the pool of our own
                    cancel.set()
                    pool.shutdown(wait=True, cancel_futures=True)
                    own = False
                else:  # a given executor (Dask, ...): drop what has not run yet
                    for fut in futures:
                        fut.cancel()
                raise
            finally:
                if own:
                    pool.shutdown(wait=True)
    return pd.DataFrame(results, columns=list(SUMMARY_COLUMNS))


# --------------------------------------------------------------------------- manifest

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
    file, :mod:`pipeline.force.logformat`). Blank lines and lines starting with ``#`` are skipped.
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

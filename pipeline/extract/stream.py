"""One video's frames → measured frames, streaming: :func:`measure_frames`.

The video is registered on its first ``register_frames`` frames. Every ``recheck_every`` frames
``check`` measures the registration's residual on the current frame; above
``residual_px * recheck_factor + recheck_margin_px`` the camera is taken to have moved and the
video is registered again on the next ``register_frames`` frames (the frames since the last
check were measured with the old registration; :func:`~tympani.pipeline.extract.video.extract_video`
goes back over them). When that registration fails, the registration is *lost*: frames are not
measured (``ok`` false, with the reason) and the check and registration are tried again after
``register_frames`` frames, then twice, four times ... as many, at most ``recheck_every``,
until the old registration fits again (the view was only blocked) or a new one succeeds.

This is a state machine over the decoded frames (:class:`FrameMachine`). Its states:

- :class:`Unregistered`: no frame seen yet;
- :class:`Registering`: frames collected for a registration, at the start or after a failed
  check (``after`` is the state the check failed in);
- :class:`Registered`: frames are measured with an :class:`~tympani.pipeline.extract.records.Epoch`
  (one registration in force), checked every ``recheck_every`` frames;
- :class:`Lost`: a re-registration failed; frames are not measured until a retry (at the
  :class:`~tympani.pipeline.extract.records.LostSpan`'s ``retry_at``) finds the old registration
  fitting again or registers anew.

Each registration is an :class:`~tympani.pipeline.extract.records.Epoch` of the
:class:`~tympani.pipeline.extract.records.ExtractLog`, each check a
:class:`~tympani.pipeline.extract.records.Check`, each lost span a
:class:`~tympani.pipeline.extract.records.LostSpan`; the angles table's ``reg_epoch`` column says which
epoch a frame used.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterator, Union

import numpy as np

from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.pipeline.extract.records import Check, Epoch, ExtractLog, LostSpan, MeasuredFrame
from tympani.vision.errors import InputError, one_line
from tympani.vision.frames import Frame, FrameSource, LensCalibration, undistorter
from tympani.vision.greyscale import to_gray

__all__ = [
    "Decoded",
    "Unregistered",
    "Registering",
    "Registered",
    "Lost",
    "FrameMachine",
    "measure_frames",
    "frame_row",
    "try_measure",
    "lens_undistorter",
]


@dataclass(frozen=True)
class Decoded:
    """One decoded frame on its way through the machine.

    Parameters
    ----------
    frame : Frame
        The frame (its image as decoded, undistorted, or its grey image; see
        :func:`measure_frames`'s ``keep_colour``).
    gray : ndarray
        Its ``uint8`` greyscale version, as recorded (the measurement samples it).
    undistort : callable or None
        The lens's undistortion of grey images, None without a calibration.
    """

    frame: Frame
    gray: np.ndarray
    undistort: Callable[[np.ndarray], np.ndarray] | None = None

    @property
    def index(self) -> int:
        return self.frame.index


# --------------------------------------------------------------------------- states


@dataclass(frozen=True)
class Unregistered:
    """No frame seen yet."""


@dataclass(frozen=True)
class Registered:
    """Frames are measured with ``epoch``."""

    epoch: Epoch


@dataclass(frozen=True)
class Lost:
    """The registration is lost: frames are not measured until ``span.retry_at``; ``epoch`` is
    the registration last in force (checked again on the retry)."""

    epoch: Epoch
    span: LostSpan


@dataclass(frozen=True)
class Registering:
    """Frames collected for a registration.

    Parameters
    ----------
    after : Unregistered, Registered or Lost
        The state the start or the failed check was in.
    trigger : Check or None
        The failed check (None at the start).
    frames : tuple of Decoded
        The frames collected, from the failed check on.
    """

    after: Unregistered | Registered | Lost
    trigger: Check | None
    frames: tuple[Decoded, ...] = ()


State = Union[Unregistered, Registering, Registered, Lost]


# --------------------------------------------------------------------------- small functions


def frame_row(trial: str, frame: Frame, result: dict, epoch: int) -> dict:
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


def lens_undistorter(calibration: LensCalibration, source: FrameSource, shape: tuple[int, ...]
                     ) -> Callable[[np.ndarray], np.ndarray]:
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


def try_measure(steps: VisionSteps, gray: np.ndarray, plan: Any, cfg: ExtractConfig) -> Any:
    """``steps.measure_frame`` of one grey frame, or the exception it raised (also from
    ``to_row``): a failed frame keeps its row."""
    try:
        m = steps.measure_frame(gray, plan, cfg.phantom, cfg.array, cfg.measure)
        m.to_row()
        return m
    except Exception as exc:
        return exc


def raised_row(exc: Exception) -> dict:
    """The result row of a frame whose measurement raised ``exc``."""
    return {"ok": False, "reason": f"measurement raised {one_line(exc)}"}


def measured_row(steps: VisionSteps, gray: np.ndarray, plan: Any, cfg: ExtractConfig) -> dict:
    """``to_row()`` of :func:`try_measure`, or :func:`raised_row` of the exception it raised."""
    m = try_measure(steps, gray, plan, cfg)
    return raised_row(m) if isinstance(m, Exception) else m.to_row()


def prepare_plan(steps: VisionSteps, registration: Any, shape: tuple[int, ...], cfg: ExtractConfig) -> Any:
    """``steps.prepare_measurement`` of ``registration`` for frames of ``shape`` (px), with the
    calibration's lens when there is one."""
    lens = {} if cfg.calibration is None else {"lens": cfg.calibration.distort_points}
    return steps.prepare_measurement(registration, shape, cfg.phantom, cfg.array, cfg.measure, **lens)


def check_due(cfg: ExtractConfig, index: int, epoch: Epoch) -> bool:
    """Whether frame ``index``, measured with ``epoch``, gets a registration check."""
    return bool(cfg.recheck_every) and index % cfg.recheck_every == 0 and index > epoch.frame


def retry_gap(cfg: ExtractConfig, attempts: int) -> int:
    """Frames (after the last one registered on) before the next try of a lost registration:
    ``register_frames``, then twice, four times ... as many, at most ``recheck_every``."""
    return min(cfg.register_frames * 2 ** (attempts - 1), max(cfg.recheck_every, cfg.register_frames))


def ideal(d: Decoded, log: ExtractLog) -> np.ndarray:
    """What registration and checks see of a frame: its grey image, undistorted when there is
    a lens."""
    if d.undistort is None:
        return d.gray
    t0 = time.perf_counter()
    out = d.undistort(d.gray)
    log.add_time("undistort", time.perf_counter() - t0)
    return out


def decoded_frames(frames: Iterator[Frame], source: FrameSource, cfg: ExtractConfig, log: ExtractLog,
                   keep_colour: bool) -> Iterator[Decoded]:
    """The frames of ``frames`` (iterating ``source``) with their grey images and lens."""
    undistort = None
    while True:
        t0 = time.perf_counter()
        frame = next(frames, None)
        t1 = time.perf_counter()
        log.add_time("decode", t1 - t0)
        if frame is None:
            return
        gray = to_gray(frame.image)
        log.add_time("gray", time.perf_counter() - t1)
        if cfg.calibration is not None:
            if undistort is None:  # the frame size checked once
                undistort = lens_undistorter(cfg.calibration, source, gray.shape)
            if keep_colour:  # drawn on: the ideal image, as the pose is
                t1 = time.perf_counter()
                frame = Frame(frame.index, frame.time_s, undistort(frame.image))
                log.add_time("undistort", time.perf_counter() - t1)
        if not keep_colour:
            frame = Frame(frame.index, frame.time_s, gray)
        yield Decoded(frame, gray, undistort)


# --------------------------------------------------------------------------- the machine


class FrameMachine:
    """Registers and measures decoded frames one at a time (see the module docstring).

    :meth:`feed` takes the next frame and :meth:`finish` the end of the video, each returning
    the frames measured by then, in frame order; :meth:`close` ends the stream. Frames of one
    epoch wait in a queue and are measured ``cfg.measure_batch`` at a time (fewer when those
    would exceed ``cfg.measure_batch_mb``); the queue is measured out before each registration.

    Parameters
    ----------
    cfg : ExtractConfig
        Settings.
    steps : VisionSteps
        The vision functions.
    trial : str
        Trial name written in each row.
    log : ExtractLog
        Filled in with epochs, checks, lost spans, warnings, timings and counts.
    path : str
        The video (named by a failed first registration).
    """

    def __init__(self, cfg: ExtractConfig, steps: VisionSteps, trial: str, log: ExtractLog, path: Any) -> None:
        self.cfg = cfg
        self.steps = steps
        self.trial = trial
        self.log = log
        self.path = path
        self.state: State = Unregistered()
        self.queue: list[tuple[Decoded, Epoch]] = []

    # ----------------------------------------------------------------------- transitions

    def feed(self, d: Decoded) -> list[MeasuredFrame]:
        """Take the next frame."""
        state = self.state
        if isinstance(state, Unregistered):
            return self._collect(Registering(after=state, trigger=None), d)
        if isinstance(state, Registering):
            return self._collect(state, d)
        if isinstance(state, Lost):
            if d.index < state.span.retry_at:
                return [self._unmeasured(d, state.epoch, state.span.reason)]
            return self._check(state, d)
        if not check_due(self.cfg, d.index, state.epoch):
            return self._enqueue(d, state.epoch)
        return self._check(state, d)

    def finish(self) -> list[MeasuredFrame]:
        """The video ended: measure what waits, registering on the frames collected (a video,
        or its rest, shorter than ``register_frames``)."""
        out = self._flush()
        if isinstance(self.state, Registering):
            out += self._register(self.state)
            out += self._flush()
        return out

    def close(self) -> None:
        """The stream ended: a lost span still open goes to the log."""
        state = self.state
        if isinstance(state, Registering):
            state = state.after
        if isinstance(state, Lost):
            self.log.lost.append(state.span)

    def _check(self, state: Registered | Lost, d: Decoded) -> list[MeasuredFrame]:
        """Check the registration in force on frame ``d``: measure on when it fits (ending a
        lost span), else collect frames for a new registration."""
        check = self._run_check(d, state.epoch)
        if not check.passed:  # NaN or too large: the camera moved; register again from this frame on
            return self._collect(Registering(after=state, trigger=check), d)
        if isinstance(state, Lost):  # the old registration fits again: the view was blocked, not moved
            self._end_span(state.span, "check", d.index)
            self.log.warnings.append(f"frames {state.span.frame}-{d.index - 1} not measured (registration lost); "
                                     f"the old registration fits again from frame {d.index}")
        self.state = Registered(state.epoch)
        return self._enqueue(d, state.epoch)

    def _collect(self, state: Registering, d: Decoded) -> list[MeasuredFrame]:
        """Add ``d`` to the frames of a registration; register once there are enough."""
        state = replace(state, frames=(*state.frames, d))
        self.state = state
        if len(state.frames) < self.cfg.register_frames:
            return []
        return self._register(state)

    def _register(self, state: Registering) -> list[MeasuredFrame]:
        """Register on the collected frames: the frames waiting before them first, then these,
        measured with the new epoch, or unmeasured when the registration is lost."""
        out = self._flush()  # the frames before these, with the plan they were measured against
        try:
            registration = self._run_register(state.frames)
        except Exception as exc:
            if isinstance(state.after, Unregistered):
                if self.steps.is_registration_failure(exc):
                    problem = getattr(exc, "problem", None) or " ".join(str(exc).split())
                    raise InputError(self.path, f"registration failed: {problem}") from exc
                raise
            return out + self._lose(state, exc)
        epoch = self._start_epoch(state, registration)
        for d in state.frames:
            out += self._enqueue(d, epoch)
        return out

    def _lose(self, state: Registering, exc: Exception) -> list[MeasuredFrame]:
        """A re-registration failed: open the lost span (or extend it) and leave the collected
        frames unmeasured."""
        after = state.after
        assert isinstance(after, (Registered, Lost))  # a failed first registration raises
        at = state.frames[0].index
        if isinstance(after, Lost):
            span = replace(after.span, attempts=after.span.attempts + 1)
        else:
            span = LostSpan(frame=at, epoch=after.epoch.index, attempts=1, retry_at=at,
                            reason=f"registration lost: the check at frame {at} failed and registering again "
                                   f"failed ({one_line(exc)})")
            self.log.warnings.append(f"re-registration at frame {at} failed ({one_line(exc)}); frames are not "
                                     "measured until the old registration fits again or a new one succeeds")
        span = replace(span, retry_at=state.frames[-1].index + 1 + retry_gap(self.cfg, span.attempts))
        self.state = Lost(after.epoch, span)
        return [self._unmeasured(d, after.epoch, span.reason) for d in state.frames]

    def _start_epoch(self, state: Registering, registration: Any) -> Epoch:
        """The epoch of a new registration (ending a lost span), with its plan; logged."""
        at = state.frames[0].index
        after = state.after
        if isinstance(after, Lost):
            self._end_span(after.span, "registered", at)
        index = 0 if isinstance(after, Unregistered) else after.epoch.index + 1
        plan = self._run_prepare(registration, state.frames[0], at)
        epoch = Epoch(index, at, registration, plan, len(state.frames), state.trigger)
        self.log.epochs.append(epoch)
        self.state = Registered(epoch)
        return epoch

    def _end_span(self, span: LostSpan, how: str, at: int) -> None:
        self.log.lost.append(replace(span, ended=how, ended_at=at))

    # ----------------------------------------------------------------------- vision steps

    def _run_check(self, d: Decoded, epoch: Epoch) -> Check:
        seen = ideal(d, self.log)
        t0 = time.perf_counter()
        residual = float(self.steps.check(seen, epoch.registration, self.cfg.phantom))
        self.log.add_time("check", time.perf_counter() - t0)
        check = Check(d.index, residual, self.cfg.recheck_threshold_px(epoch.registration))
        self.log.checks.append(check)
        return check

    def _run_register(self, frames: tuple[Decoded, ...]) -> Any:
        frames_used = [ideal(d, self.log) for d in frames]
        t0 = time.perf_counter()
        try:
            if self.cfg.registration is None:
                return self.steps.register(frames_used, self.cfg.phantom)
            return self.steps.register(frames_used, self.cfg.phantom, self.cfg.registration)
        finally:
            self.log.add_time("register", time.perf_counter() - t0)

    def _run_prepare(self, registration: Any, first: Decoded, at: int) -> Any:
        """The plan ``measure_frame`` gets for ``registration`` (the registration itself when
        the steps prepare none); a plan that refuses every frame is said once."""
        prepare = self.steps.prepare_measurement
        if prepare is None:
            return registration
        cfg = self.cfg
        t0 = time.perf_counter()
        plan = prepare_plan(self.steps, registration, first.gray.shape, cfg)
        self.log.add_time("prepare", time.perf_counter() - t0)
        refusal = getattr(plan, "refusal", None)
        if refusal:  # every frame of this registration fails the same way: say it once
            self.log.warnings.append(f"frames from {at} on: {refusal}")
        return plan

    # ----------------------------------------------------------------------- measuring

    def _enqueue(self, d: Decoded, epoch: Epoch) -> list[MeasuredFrame]:
        self.queue.append((d, epoch))
        n = len(self.queue)
        full = n >= self.cfg.measure_batch or n * d.gray.nbytes >= self.cfg.measure_batch_mb * 2**20
        return self._flush() if full else []

    def _flush(self) -> list[MeasuredFrame]:
        """Measure the queued frames (together when their epoch has a plan)."""
        items, self.queue = self.queue, []
        batch = self.steps.measure_frames_batch
        if len(items) < 2 or batch is None or not items[0][1].prepared:
            return [self._measure(d, epoch) for d, epoch in items]
        epoch = items[0][1]
        t0 = time.perf_counter()
        try:
            ms = list(batch([d.gray for d, _ in items], epoch.plan))
            if len(ms) != len(items):
                raise RuntimeError(f"measure_frames_batch gave {len(ms)} results for {len(items)} frames")
            results = [m.to_row() for m in ms]
        except Exception:  # one at a time instead, so that only the frame that raises fails
            return [self._measure(d, e) for d, e in items]
        share = (time.perf_counter() - t0) / len(items)
        return [self._measured(d, epoch, m, share, r) for (d, _), m, r in zip(items, ms, results)]

    def _measure(self, d: Decoded, epoch: Epoch) -> MeasuredFrame:
        t0 = time.perf_counter()
        m = try_measure(self.steps, d.gray, epoch.plan, self.cfg)
        return self._measured(d, epoch, m, time.perf_counter() - t0)

    def _measured(self, d: Decoded, epoch: Epoch, m: Any, seconds: float, result: dict | None = None
                  ) -> MeasuredFrame:
        """The row of one measurement ``m`` (an exception when it raised), ``seconds`` spent;
        ``result`` is ``m.to_row()`` when already computed."""
        log = self.log
        if isinstance(m, Exception):  # a failed frame keeps its row
            result = raised_row(m)
            if log.n_exceptions == 0:
                log.warnings.append(f"frame {d.index}: {result['reason']}")
            log.n_exceptions += 1
            m = None
        elif result is None:
            result = m.to_row()
        log.add_time("measure", seconds)
        for stage, stage_s in (getattr(m, "timings", None) or {}).items():
            log.add_time(f"measure.{stage}", stage_s)
        row = frame_row(self.trial, d.frame, result, epoch.index)
        log.n_frames += 1
        log.n_ok += bool(row["ok"])
        return MeasuredFrame(d.frame, d.gray, epoch.registration, epoch.index, m, row)

    def _unmeasured(self, d: Decoded, epoch: Epoch, reason: str) -> MeasuredFrame:
        """The row of a frame left unmeasured (``ok`` false) for ``reason``."""
        row = frame_row(self.trial, d.frame, {"ok": False, "reason": reason}, epoch.index)
        self.log.n_frames += 1
        return MeasuredFrame(d.frame, d.gray, epoch.registration, epoch.index, None, row)


def measure_frames(
    source: FrameSource,
    cfg: ExtractConfig,
    *,
    trial: str,
    log: ExtractLog | None = None,
    progress: bool = False,
    keep_colour: bool = True,
    steps: VisionSteps = VisionSteps(),
) -> Iterator[MeasuredFrame]:
    """Register and measure the frames of ``source``, streaming.

    Parameters
    ----------
    source : FrameSource
        The frames (see :func:`tympani.vision.frames.open_frames`).
    cfg : ExtractConfig
        Phantom, array, registration and measurement settings.
    trial : str
        Trial name written in each row.
    log : ExtractLog, optional
        Filled in with epochs, checks, lost spans, warnings, timings and counts.
    progress : bool
        Show a per-frame progress bar on stderr.
    keep_colour : bool
        Yield each frame as decoded. False yields it with its grey image in place of the
        decoded one, so that the frames waiting for a batch hold no colour copy (a third of
        the memory, and fresh allocations the decoder would otherwise pay for).
    steps : VisionSteps
        The vision functions (default: :mod:`tympani.vision.registration`'s and :mod:`tympani.vision.angles`'s).

    Yields
    ------
    MeasuredFrame
        In frame order. Frames measured with the same plan are measured ``cfg.measure_batch``
        at a time, fewer when those would exceed ``cfg.measure_batch_mb``
        (``steps.measure_frames_batch``, when the measurement has a plan); at most a batch, or
        ``cfg.register_frames`` frames while a registration is pending, are held back. The
        ``measure`` time of a batch is shared equally among its frames.

    Raises
    ------
    InputError
        The first registration failed (no phantom found), or the frames are bad.
    """
    log = log if log is not None else ExtractLog()
    machine = FrameMachine(cfg, steps, trial, log, source.path)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(source), unit="frame", desc=trial, leave=False, file=sys.stderr, dynamic_ncols=True)
    frames = iter(source)
    try:
        for d in decoded_frames(frames, source, cfg, log, keep_colour):
            if bar is not None:
                bar.update(1)
            yield from machine.feed(d)
        yield from machine.finish()
    finally:
        machine.close()
        close = getattr(frames, "close", None)
        if close is not None:  # release the decoder now, also when the consumer stops early
            close()
        if bar is not None:
            bar.close()
    if log.n_exceptions > 1:
        log.warnings.append(f"measurement raised on {log.n_exceptions} frames in all")

"""What measuring one video records: its registrations (:class:`Epoch`), checks
(:class:`Check`) and lost spans (:class:`LostSpan`), gathered in an :class:`ExtractLog`, and
each frame's result (:class:`MeasuredFrame`). :mod:`tympani.pipeline.extract.stream` makes them."""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from tympani.vision.frames import Frame

__all__ = ["Check", "Epoch", "LostSpan", "ExtractLog", "MeasuredFrame", "mark_not_ok", "refusal_kind", "refusals",
           "refusals_text"]


def mark_not_ok(row: dict, reason: str) -> None:
    """Mark an angles-table row not ok (in place): ``ok`` False, NaN angles, ``reason``."""
    row.update(ok=False, theta_tip=math.nan, theta_bot=math.nan, theta_con=math.nan, reason=reason)


_PARTICULARS = re.compile(r"\s*\([^)]*\d[^)]*\)")


def refusal_kind(reason: str) -> str:
    """A frame's ``reason`` without what is particular to the frame, so that frames refused alike
    group together: the text before its first colon (``"kinematics: depth 3.10 mm is ..."`` ->
    ``"kinematics"``), less any parenthesis holding a number (``"... next turn (tip read at 3.1
    rad)"``). A reason with neither is its own kind."""
    head = " ".join(str(reason).split(":", 1)[0].split())
    return _PARTICULARS.sub("", head).strip() or "not measured"


def refusals(reasons: Iterable[str]) -> dict[str, int]:
    """How many frames were refused for each :func:`refusal_kind` of ``reasons`` (the refused
    frames' reasons), most frames first (ties in order of first appearance)."""
    return dict(Counter(refusal_kind(r) for r in reasons).most_common())


def refusals_text(counts: dict[str, int], top: int = 3) -> str:
    """Refusals as one line: ``"array edges not found: 12; array not in channel: 3; 2 other
    kinds: 4"``.

    Parameters
    ----------
    counts : dict of str to int
        Frames refused for each kind, most first (:func:`refusals`).
    top : int
        Kinds named (the commonest); the rest are summed as other kinds.
    """
    items = list(counts.items())
    parts = [f"{kind}: {n}" for kind, n in items[:top]]
    rest = items[top:]
    if rest:
        parts.append(f"{len(rest)} other kind{'s' if len(rest) > 1 else ''}: {sum(n for _, n in rest)}")
    return "; ".join(parts)


@dataclass(frozen=True)
class Check:
    """One check of the registration in force.

    Parameters
    ----------
    frame : int
        The frame checked.
    residual_px : float
        The registration's residual on it (px; NaN when it does not fit at all).
    threshold_px : float
        The largest residual (px) that passes (:meth:`~tympani.pipeline.extract.config.ExtractConfig.recheck_threshold_px`).
    """

    frame: int
    residual_px: float
    threshold_px: float

    @property
    def passed(self) -> bool:
        """The registration still fits (a NaN residual does not)."""
        return self.residual_px <= self.threshold_px


@dataclass(frozen=True)
class Epoch:
    """One registration in force.

    Parameters
    ----------
    index : int
        0 for the first registration, 1 after the first re-registration, ...
    frame : int
        The first frame it was used for (the first of the frames it was registered on).
    registration : Registration
        The registration.
    plan : object
        What ``measure_frame`` gets: ``prepare_measurement``'s plan, or the registration.
    n_frames_used : int
        Frames it was registered on.
    trigger : Check or None
        The failed check that led to it; None for the first registration.
    """

    index: int
    frame: int
    registration: Any
    plan: Any
    n_frames_used: int
    trigger: Check | None = None

    @property
    def prepared(self) -> bool:
        """Whether the measurement has a plan of its own (so frames may be measured together)."""
        return self.plan is not self.registration

    def record(self) -> dict:
        """Its entry of the registration record (docs/file-formats.md): ``frame``, ``epoch``,
        ``trigger`` ("start" or "check"; for "check" also ``check_residual_px`` and
        ``threshold_px``), ``n_frames_used``, the registration's ``to_dict()`` keys and, where
        the plan has one, ``gap_resolution_px`` (how finely its frames' gaps to the wall were
        told apart, px)."""
        trigger: dict[str, Any] = {"trigger": "start"}
        if self.trigger is not None:
            trigger = {"trigger": "check", "check_residual_px": self.trigger.residual_px,
                       "threshold_px": self.trigger.threshold_px}
        resolution = getattr(self.plan, "gap_resolution_px", None)
        return {"frame": self.frame, "epoch": self.index, **trigger, "n_frames_used": self.n_frames_used,
                **self.registration.to_dict(), **({} if resolution is None else {"gap_resolution_px": resolution})}


@dataclass(frozen=True)
class LostSpan:
    """Frames left unmeasured after a failed check whose re-registration failed.

    Parameters
    ----------
    frame : int
        The failed check.
    epoch : int
        Index of the :class:`Epoch` in force then (the rows keep it).
    attempts : int
        Failed registrations so far.
    reason : str
        The unmeasured rows' reason.
    retry_at : int
        The next frame the check and registration are tried on.
    ended : str or None
        "check" (the old registration fitted again), "registered" (a new one succeeded) or None
        (not ended: the video ended).
    ended_at : int or None
        The frame it ended at.
    """

    frame: int
    epoch: int
    attempts: int
    reason: str
    retry_at: int
    ended: str | None = None
    ended_at: int | None = None

    def record(self) -> dict:
        """Its entry of the registration record: ``frame``, ``attempts``, ``ended``,
        ``ended_at`` and ``reason``."""
        return {"frame": self.frame, "attempts": self.attempts, "ended": self.ended, "ended_at": self.ended_at,
                "reason": self.reason}


@dataclass
class ExtractLog:
    """What happened while a video was measured (filled in by
    :func:`~tympani.pipeline.extract.stream.measure_frames`).

    Attributes
    ----------
    epochs : list of Epoch
        Every registration in force, in order.
    checks : list of Check
        Every registration check, in order.
    lost : list of LostSpan
        The spans in which the registration was lost, in order (one not ended is added when
        the stream ends).
    warnings : list of str
        One line each (failed re-registrations, measurement exceptions).
    timing_s : dict of str to float
        Wall time (s) spent per stage: ``decode``, ``gray``, ``register``, ``prepare``,
        ``check``, ``measure``, plus ``measure.<stage>`` when measurements expose ``timings``.
    n_frames, n_ok, n_exceptions : int
        Frames measured, frames with ``ok``, frames whose measurement raised.
    """

    epochs: list[Epoch] = field(default_factory=list)
    checks: list[Check] = field(default_factory=list)
    lost: list[LostSpan] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    timing_s: dict[str, float] = field(default_factory=dict)
    n_frames: int = 0
    n_ok: int = 0
    n_exceptions: int = 0

    @property
    def first_registration(self) -> Any:
        """The registration frame 0 was measured with (None before it is made)."""
        return self.epochs[0].registration if self.epochs else None

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
        The registration it was measured with (or, when not measured, the one in force).
    epoch : int
        Which registration (0 the first, 1 after the first re-registration, ...).
    measurement : vision.angles.FrameMeasurement or None
        The result (None when ``measure_frame`` raised or the frame was not measured).
    row : dict
        The angles-table row.
    """

    frame: Frame
    gray: np.ndarray
    registration: Any
    epoch: int
    measurement: Any
    row: dict

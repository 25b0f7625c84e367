"""When the robot moves: motion start and stop from a depth (stage position) log.

A robot's stage stands still for a while, moves the array in, and stops. :func:`find_motion`
finds the two events in the stage's own log, and says how sure it is:

1. **Rest level and noise.** The rest position is the median of the log's first samples that lie
   within a band about the first five; the noise ``σ`` is the robust spread (MAD) of their
   sample-to-sample changes, divided by √2.
2. **Threshold.** ``τ = max(k σ, rel · travel)`` (defaults ``k = 10``, ``rel = 1e-5``): ten noise
   widths, and never below a hundred-thousandth of the travel (``max − min``), so that a
   quantised or noiseless rest does not make the threshold zero and a stage that creeps a few
   hundred nanometres while it settles still counts as stopped.
3. **Start.** The first sample further than ``τ`` from the rest level; the stage left between the
   sample before it (at rest) and it. The start is where the straight line between the two
   crosses the band's edge, and its standard uncertainty is the bracket's width / √12 (the
   event may lie anywhere between the two samples).
4. **Stop.** The same from the end of the log, about the final rest level. When the log's last
   samples are still more than ``τ`` from each other (the log ends while the stage moves), there
   is no stop: ``stopped`` is False and ``stop_s`` is the log's end, a lower bound.

A log whose travel is below ``min_travel_mm`` never moves (:class:`NoMotion`), and one that starts
while the stage moves has no start (:class:`NoMotion` too: nothing marks the start).

Everything here is a pure function of arrays: times in s, depths in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tympani.pipeline.model.stats import mad_sd

__all__ = ["Motion", "NoMotion", "find_motion", "rest_noise"]


class NoMotion(ValueError):
    """The depth log shows no motion to find (it never moves, or starts while moving)."""


@dataclass(frozen=True)
class Motion:
    """The stage's motion found in a depth log.

    Parameters
    ----------
    start_s : float
        When the stage leaves its rest position (s, the log's clock).
    start_bracket_s : tuple of float
        The last sample at rest and the first one moved (s): the start lies between them.
    start_uncertainty_s : float
        Standard uncertainty of ``start_s`` (s): the bracket's width / √12.
    stop_s : float
        When the stage arrives at its final position (s); the log's last time when it ends while
        the stage moves (``stopped`` False).
    stop_bracket_s : tuple of float
        The last sample moving and the first at the final rest (s); both the log's end when not
        ``stopped``.
    stop_uncertainty_s : float
        Standard uncertainty of ``stop_s`` (s); inf when not ``stopped``.
    stopped : bool
        Whether the log shows the stage at rest after its motion.
    rest_mm, final_mm : float
        Rest position before the motion and final position (mm; the last sample when not
        ``stopped``).
    travel_mm : float
        ``final_mm - rest_mm`` (mm).
    speed_mm_s : float
        Speed of the motion (mm/s): slope of a straight line through the samples between 10 %
        and 90 % of the travel.
    noise_mm : float
        Noise of the position at rest (mm, standard deviation).
    threshold_mm : float
        ``τ`` (mm).
    """

    start_s: float
    start_bracket_s: tuple[float, float]
    start_uncertainty_s: float
    stop_s: float
    stop_bracket_s: tuple[float, float]
    stop_uncertainty_s: float
    stopped: bool
    rest_mm: float
    final_mm: float
    travel_mm: float
    speed_mm_s: float
    noise_mm: float
    threshold_mm: float

    @property
    def duration_s(self) -> float:
        """``stop_s - start_s`` (s)."""
        return self.stop_s - self.start_s


def rest_noise(depth_mm: np.ndarray) -> float:
    """Noise (mm, standard deviation) of a stretch of positions at rest.

    Robust: 1.4826 × the median absolute deviation of the sample-to-sample changes, / √2
    (a change is the difference of two independent noisy samples). 0 for fewer than 3 samples or
    a constant stretch.
    """
    d = np.asarray(depth_mm, dtype=float)
    if d.size < 3:
        return 0.0
    step = np.diff(d)
    return mad_sd(step) / math.sqrt(2.0)


def _crossing(t0: float, t1: float, a0: float, a1: float, level: float) -> float:
    """Time (s) at which a straight line from ``(t0, a0)`` to ``(t1, a1)`` reaches ``level``
    (clipped to the bracket)."""
    if a1 == a0:
        return t0
    return float(np.clip(t0 + (level - a0) / (a1 - a0) * (t1 - t0), min(t0, t1), max(t0, t1)))


def _departure(t: np.ndarray, d: np.ndarray, rest: float, tau: float) -> int | None:
    """Index of the first sample further than ``tau`` from ``rest``, None if there is none."""
    away = np.flatnonzero(np.abs(d - rest) > tau)
    return int(away[0]) if away.size else None


def _rest_stretch(d: np.ndarray, band: float) -> np.ndarray:
    """The leading samples within ``band`` of the median of the first five."""
    ref = float(np.median(d[: min(5, d.size)]))
    out = np.flatnonzero(np.abs(d - ref) > band)
    return d[: out[0]] if out.size else d


def find_motion(
    time_s: np.ndarray,
    depth_mm: np.ndarray,
    *,
    k_noise: float = 10.0,
    rel_threshold: float = 1e-5,
    min_travel_mm: float = 0.1,
) -> Motion:
    """Find when the stage starts and stops moving (see the module docstring).

    Parameters
    ----------
    time_s : ndarray
        Sample times (s), strictly increasing.
    depth_mm : ndarray
        Stage position (mm), finite.
    k_noise : float
        Threshold in noise standard deviations.
    rel_threshold : float
        Least threshold as a fraction of the travel.
    min_travel_mm : float
        A log whose positions span less than this (mm) never moves.

    Returns
    -------
    Motion

    Raises
    ------
    NoMotion
        The positions span less than ``min_travel_mm``, or the log begins while the stage moves.
    ValueError
        Fewer than 3 samples, unequal lengths.
    """
    t = np.asarray(time_s, dtype=float)
    d = np.asarray(depth_mm, dtype=float)
    if t.shape != d.shape or t.size < 3:
        raise ValueError("need at least 3 samples of time and depth of the same length")
    span = float(np.ptp(d))
    if span < min_travel_mm:
        raise NoMotion(f"never moves: its positions span {span:.3g} mm over {t[-1] - t[0]:.4g} s "
                       f"(less than {min_travel_mm:g} mm)")
    floor = rel_threshold * span
    moving = NoMotion("starts while the stage moves (its first samples already differ by more than "
                      f"{floor:.3g} mm): no rest before the motion marks its start")
    head = _rest_stretch(d, 100.0 * floor)
    if head.size < 3:
        raise moving
    noise = rest_noise(head)
    tau = max(k_noise * noise, floor)
    still = _rest_stretch(d, tau)
    if still.size < 3:
        raise moving
    rest = float(np.median(still))
    i = _departure(t, d, rest, tau)
    if i is None or i < 2:
        raise moving
    start = _crossing(t[i - 1], t[i], abs(d[i - 1] - rest), abs(d[i] - rest), tau)

    final_tail = _rest_stretch(d[::-1], tau)[::-1]
    stopped = final_tail.size >= 3
    if stopped:
        final = float(np.median(final_tail))
        j = int(d.size - 1 - _departure(t[::-1], d[::-1], final, tau))  # type: ignore[operator]
        stop = _crossing(t[j], t[j + 1], abs(d[j] - final), abs(d[j + 1] - final), tau)
        stop_bracket = (float(t[j]), float(t[j + 1]))
        stop_unc = (stop_bracket[1] - stop_bracket[0]) / math.sqrt(12.0)
    else:
        final = float(d[-1])
        stop = float(t[-1])
        stop_bracket = (stop, stop)
        stop_unc = math.inf
    travel = final - rest
    lo, hi = rest + 0.1 * travel, rest + 0.9 * travel
    mid = (t >= start) & (t <= stop) & (np.minimum(lo, hi) <= d) & (d <= np.maximum(lo, hi))
    speed = float(np.polyfit(t[mid], d[mid], 1)[0]) if np.count_nonzero(mid) >= 3 else math.nan
    return Motion(
        start_s=start,
        start_bracket_s=(float(t[i - 1]), float(t[i])),
        start_uncertainty_s=float(t[i] - t[i - 1]) / math.sqrt(12.0),
        stop_s=stop,
        stop_bracket_s=stop_bracket,
        stop_uncertainty_s=stop_unc,
        stopped=stopped,
        rest_mm=rest,
        final_mm=final,
        travel_mm=travel,
        speed_mm_s=speed,
        noise_mm=noise,
        threshold_mm=tau,
    )

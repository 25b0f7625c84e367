"""The insertion's kinematics as a check on a video's measured frames.

The robot pushes the array in at a constant speed, so the measured insertion depth (the length
of array past the entry, mm) of a video's frames lies on one line in time, flat before the robot
starts and after it stops: ``depth(t) = clip(d0 + v t, lo, hi)``. A frame far from that line
was misread (a bubble ahead of the tip taken for more array, a tip lost in a shadow), and so is a
*run* of such frames, which a spike filter keeps when the misreading lasts. :func:`fit_insertion`
fits the line robustly (a consensus line through pairs of frames, then a Cauchy-loss fit of the
clipped line); :func:`flag_kinematics` marks the frames off it, and all of them where those left
on it wander about it in runs (a misreading that lasts and changes bends the line towards it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.ndimage import median_filter
from scipy.optimize import least_squares
from scipy.stats import theilslopes

from tympani.pipeline.extract.records import mark_not_ok
from tympani.pipeline.model.stats import mad_sd

__all__ = ["KinematicsConfig", "InsertionFit", "fit_insertion", "insertion_depth", "flag_kinematics"]


@dataclass(frozen=True)
class KinematicsConfig:
    """Settings of the kinematics check.

    Parameters
    ----------
    tol_mm : float
        Least distance (mm) from the fitted insertion that marks a frame; the check uses the
        larger of this and ``spread`` robust standard deviations of the frames on the line.
    spread : float
        Robust standard deviations (dimensionless) of the depth about the line a frame may lie
        off it.
    min_frames : int
        Fewest measured frames with a depth for the check to run.
    min_share : float
        Least share (dimensionless) of the measured frames the fitted line must hold within the
        tolerance. A video whose frames agree less has at least half of them misread and no way
        to tell which: all its measured frames are marked.
    pairs : int
        Pairs of frames tried as the consensus line.
    near : float
        Share (dimensionless) of ``tol_mm`` within which a frame supports a consensus line: the
        line is chosen by the frames that lie near it, not by those it merely keeps.
    min_after_stop : int
        Fewest frames with a depth after the insertion stops for their fall to be judged: where
        it falls by more than the tolerance, the measured ones among them are marked.
    wander_mm : float
        Largest range (mm) of the measured frames' running median distance from the line (over
        ``wander_frames`` consecutive measured frames), and at least the tolerance: right frames
        scatter about the line by their noise, a hundredth to a tenth of a millimetre; frames
        misread alike for a while (a chain of bubbles carried ahead of the tip taken for array)
        pull the line towards them and leave the rest off it by turns, each within the
        tolerance. Over it, every measured frame left is marked: which of them are right cannot
        be told.
    wander_frames : int
        Window (measured frames) of that running median, and the fewest measured frames the
        wander is judged on.
    """

    tol_mm: float = 0.5
    spread: float = 5.0
    min_frames: int = 8
    min_share: float = 0.5
    pairs: int = 400
    near: float = 0.5
    min_after_stop: int = 4
    wander_mm: float = 0.6
    wander_frames: int = 5


@dataclass(frozen=True)
class InsertionFit:
    """A video's insertion, ``depth(t) = clip(d0 + speed * t, lo, hi)``.

    Parameters
    ----------
    d0_mm : float
        Depth (mm) the moving phase extrapolates to at t = 0.
    speed_mm_s : float
        Insertion speed (mm/s, at least 0).
    lo_mm, hi_mm : float
        Depth (mm) before the robot starts and after it stops.
    sigma_mm : float
        Robust standard deviation (mm) of the frames on the line about it.
    tol_mm : float
        Distance (mm) from the line beyond which a frame is off it.
    share : float
        Share (dimensionless) of the frames within ``tol_mm``.
    """

    d0_mm: float
    speed_mm_s: float
    lo_mm: float
    hi_mm: float
    sigma_mm: float
    tol_mm: float
    share: float


def insertion_depth(fit: InsertionFit, time_s: np.ndarray) -> np.ndarray:
    """Depth (mm) of the fitted insertion at ``time_s`` (s)."""
    return np.clip(fit.d0_mm + fit.speed_mm_s * np.asarray(time_s, dtype=float), fit.lo_mm, fit.hi_mm)


def _consensus_line(t: np.ndarray, d: np.ndarray, tol: float, pairs: int) -> tuple[float, float]:
    """The line ``d0 + v t`` (v >= 0) through two frames with the most support, once clipped to
    the depths it passes: each frame within ``tol`` (mm) counts ``1 - (r / tol)^2`` for its
    distance ``r``; drawn from a fixed seed so that a video always gives the same line."""
    rng = np.random.default_rng(0)
    n = len(t)
    i, j = rng.integers(0, n, size=(2, pairs))
    keep = t[j] > t[i]
    i, j = i[keep], j[keep]
    v = np.maximum((d[j] - d[i]) / (t[j] - t[i]), 0.0)
    d0 = d[i] - v * t[i]
    lo, hi = np.minimum(d[i], d[j]), np.maximum(d[i], d[j])
    # a candidate is clipped to a plateau at either end where the frames are flat there
    line = d0[:, None] + v[:, None] * t[None, :]
    lo_all = np.minimum(lo, np.quantile(d, 0.05))[:, None]
    hi_all = np.maximum(hi, np.quantile(d, 0.95))[:, None]
    # frames count by how near they lie (1 on the line, 0 at tol and beyond): a line between two
    # parallel groups of frames (a bubble carried ahead of the tip misreads every other frame by a
    # steady millimetre) holds both within tol but neither near it
    r = (np.clip(line, lo_all, hi_all) - d[None, :]) / tol
    support = np.maximum(1.0 - r * r, 0.0).sum(axis=1)
    best = int(np.argmax(support)) if len(support) else -1
    if best < 0:
        return float(np.median(d)), 0.0
    return float(d0[best]), float(v[best])


def fit_insertion(time_s: np.ndarray, depth_mm: np.ndarray, cfg: KinematicsConfig = KinematicsConfig()) -> InsertionFit | None:
    """Fit a constant-speed insertion to measured depths, robust to runs of misread frames.

    Parameters
    ----------
    time_s : ndarray
        Frame times (s).
    depth_mm : ndarray
        Measured insertion depth (mm) of the same frames (finite).
    cfg : KinematicsConfig
        Settings.

    Returns
    -------
    InsertionFit or None
        None with fewer than ``cfg.min_frames`` frames.
    """
    t, d = np.asarray(time_s, dtype=float), np.asarray(depth_mm, dtype=float)
    if len(t) < cfg.min_frames or np.ptp(t) <= 0:
        return None
    # a tight kernel: a bubble carried ahead of the tip for half the video misreads its frames
    # by a scattered 1-2 mm, and a line between them and the true ones holds more frames
    # within tol_mm than the true line does, but fewer near it
    d0, v = _consensus_line(t, d, cfg.near * cfg.tol_mm, cfg.pairs)
    on = np.abs(np.clip(d0 + v * t, d.min(), d.max()) - d) <= cfg.tol_mm
    lo0, hi0 = float(np.min(d[on], initial=d.min())), float(np.max(d[on], initial=d.max()))
    scale = max(cfg.tol_mm / 3.0, 1e-3)

    def residual(p: np.ndarray) -> np.ndarray:
        return np.clip(p[0] + p[1] * t, p[2], p[3]) - d

    def jacobian(p: np.ndarray) -> np.ndarray:
        line = p[0] + p[1] * t
        below, above = line < p[2], line > p[3]
        ramp = ~(below | above)
        return np.column_stack([ramp, ramp * t, below, above]).astype(float)

    p0 = np.array([d0, v, lo0, max(hi0, lo0 + 1e-6)])
    # dogbox suits a few variables with simple bounds: on 200 frames it takes 4 steps where the
    # default trust-region method took 55 (0.75 against 14 ms) to the same fit
    res = least_squares(residual, p0, jac=jacobian, loss="cauchy", f_scale=scale, xtol=1e-6, ftol=1e-6,
                        method="dogbox", bounds=([-np.inf, 0.0, -np.inf, -np.inf], [np.inf, np.inf, np.inf, np.inf]))
    p = res.x if res.success else p0
    lo, hi = float(min(p[2], p[3])), float(max(p[2], p[3]))
    r = np.clip(p[0] + p[1] * t, lo, hi) - d
    near = np.abs(r) <= cfg.tol_mm
    sigma = mad_sd(r[near], centre=False) if near.any() else math.inf
    tol = max(cfg.tol_mm, cfg.spread * sigma)
    share = float(np.mean(np.abs(r) <= tol))
    return InsertionFit(float(p[0]), float(p[1]), lo, hi, sigma, tol, share)


def _runs(index: np.ndarray) -> list[tuple[int, int]]:
    """Runs of consecutive integers in sorted ``index``, as (first, last) pairs."""
    if len(index) == 0:
        return []
    cut = np.flatnonzero(np.diff(index) > 1)
    starts = np.concatenate([[0], cut + 1])
    ends = np.concatenate([cut, [len(index) - 1]])
    return [(int(index[a]), int(index[b])) for a, b in zip(starts, ends)]


def _mark_runs(rows: list[dict], ok: list[int], index: np.ndarray, r: np.ndarray,
               reason: Callable[[int], str]) -> list[dict]:
    """Mark the measured rows ``ok[j]`` for ``j`` in ``index`` (sorted) not ok, in place, each
    with ``reason(j)``; one dict per run of consecutive ``j``: its ``first`` and ``last`` frame,
    ``frames`` and ``off_mm``, the largest of its signed distances ``r`` (mm) from the line."""
    runs = []
    for a, b in _runs(index):
        seg = r[a:b + 1]
        runs.append(dict(first=int(rows[ok[a]]["frame"]), last=int(rows[ok[b]]["frame"]), frames=b - a + 1,
                         off_mm=round(float(seg[np.argmax(np.abs(seg))]), 3)))
        for j in range(a, b + 1):
            mark_not_ok(rows[ok[j]], reason(j))
    return runs


def order_conflicts(time_s: np.ndarray, depth_mm: np.ndarray, tol_mm: float) -> np.ndarray:
    """Index, for each frame, of a frame whose depth contradicts it (-1 for none): one later and
    more than ``tol_mm`` (mm) shallower, or earlier and more than ``tol_mm`` deeper; the
    insertion only goes in. Of two such frames either may be the misread one.

    Parameters
    ----------
    time_s, depth_mm : ndarray
        Frame times (s) and measured depths (mm).
    tol_mm : float
        Tolerance (mm).

    Returns
    -------
    ndarray of int
        The most contradicting frame's index (largest depth difference), or -1.
    """
    t, d = np.asarray(time_s, dtype=float), np.asarray(depth_mm, dtype=float)
    if len(t) == 0:
        return np.zeros(0, np.intp)
    # depth lost going forward in time between frame i (row) and frame j (column)
    fall = np.where(t[None, :] > t[:, None], d[:, None] - d[None, :], d[None, :] - d[:, None])
    fall[t[None, :] == t[:, None]] = -np.inf
    worst = np.argmax(fall, axis=1)
    return np.where(fall[np.arange(len(t)), worst] > tol_mm, worst, -1)


def flag_kinematics(rows: list[dict], cfg: KinematicsConfig = KinematicsConfig()) -> tuple[list[dict], str]:
    """Mark the measured frames whose depth is off the video's constant-speed insertion, in place.

    The insertion is fitted (:func:`fit_insertion`) to every row with a finite ``depth_mm``,
    measured or not (a frame refused for an unclear contact start still has its tip and depth),
    and only measured rows are marked. Where the measured rows left on the line wander about it
    in runs (:attr:`KinematicsConfig.wander_mm`), all of them are marked. With fewer than
    ``cfg.min_frames`` such rows, too few for a line, a measured row is marked when another's
    depth contradicts it (:func:`order_conflicts`).

    Parameters
    ----------
    rows : list of dict
        Angles-table rows of one video (``frame``, ``time_s`` s, ``ok``, ``depth_mm`` mm,
        ``theta_tip``, ``theta_bot``, ``theta_con`` rad, ``reason``); changed in place: marked
        rows get ``ok`` False, NaN angles and the reason.
    cfg : KinematicsConfig
        Settings.

    Returns
    -------
    runs : list of dict
        One per run of consecutive measured frames marked: ``first`` and ``last`` frame,
        ``frames`` (how many), ``off_mm`` (the largest distance, mm, signed: + deeper than the
        insertion).
    note : str
        What the check found, or why it did not run ("" when it ran and marked nothing).
    """
    order = sorted(range(len(rows)), key=lambda i: rows[i]["frame"])
    seen = [i for i in order if np.isfinite(float(rows[i].get("depth_mm", math.nan) or math.nan))]
    ok = [i for i in seen if rows[i]["ok"]]
    if len(seen) < cfg.min_frames:
        return _flag_order(rows, seen, cfg)
    # the insertion is fitted to every frame whose depth was measured, the ones refused for
    # their contact start too (their tip was found), and checked on the measured ones
    t_seen = np.array([float(rows[i]["time_s"]) for i in seen])
    d_seen = np.array([float(rows[i]["depth_mm"]) for i in seen])
    fit = fit_insertion(t_seen, d_seen, cfg)
    if fit is None or not ok:
        return [], ""
    t = np.array([float(rows[i]["time_s"]) for i in ok])
    d = np.array([float(rows[i]["depth_mm"]) for i in ok])
    r = d - insertion_depth(fit, t)
    if fit.share < cfg.min_share:  # no insertion to check against: every frame is in doubt
        off = np.arange(len(ok))
        why = (f"the measured depths follow no constant-speed insertion (at most {100 * fit.share:.0f} % "
               f"of the {len(seen)} frames with a depth lie on one)")
    else:
        off = np.flatnonzero(np.abs(r) > fit.tol_mm)
        why = ""
    runs = _mark_runs(rows, ok, off, r, lambda j: "kinematics: " + why if why else
                      f"kinematics: depth {d[j]:.2f} mm is {r[j]:+.2f} mm off the constant-speed insertion "
                      f"({fit.speed_mm_s:.3g} mm/s)")
    note = ""
    if why:
        note = f"{len(off)} frame(s) marked not ok: {why}"
    elif runs:
        spans = ", ".join(f"{u['first']}–{u['last']}" if u["last"] > u["first"] else f"{u['first']}" for u in runs)
        note = (f"{len(off)} frame(s) marked not ok off the constant-speed insertion ({fit.speed_mm_s:.3g} mm/s, "
                f"tolerance {fit.tol_mm:.2f} mm): frames {spans}")
    if not why:
        fall = _fall_after_stop(fit, t_seen, d_seen, cfg)
        after = [j for j in np.flatnonzero(fit.d0_mm + fit.speed_mm_s * t > fit.hi_mm) if rows[ok[j]]["ok"]]
        if fall > fit.tol_mm and after:
            first, last = int(rows[ok[after[0]]]["frame"]), int(rows[ok[after[-1]]]["frame"])
            for j in after:
                mark_not_ok(rows[ok[j]], f"kinematics: the depth falls by {fall:.2f} mm after the insertion stops "
                                         f"(frames {first}-{last}: the tip lost rather than a stop?)")
            runs.append(dict(first=first, last=last, frames=len(after), off_mm=round(-fall, 3)))
            note = "; ".join(filter(None, [note, f"{len(after)} frame(s) marked not ok after the insertion stops: "
                                                 f"their depth falls by {fall:.2f} mm (frames {first}-{last})"]))
        kept = np.array([j for j in range(len(ok)) if rows[ok[j]]["ok"]], dtype=np.intp)
        wander = _wander(r[kept], max(cfg.wander_mm, fit.tol_mm), cfg.wander_frames)
        if wander is not None:  # the frames left on the line are misread alike by turns: all are in doubt
            runs = sorted(runs + _mark_runs(rows, ok, kept, r, lambda j: "kinematics: " + wander),
                          key=lambda u: u["first"])
            note = "; ".join(filter(None, [note, f"{len(kept)} frame(s) marked not ok: {wander}"]))
    return runs, note


def _wander(r: np.ndarray, limit_mm: float, frames: int) -> str | None:
    """Why the measured frames on the insertion line (``r``, their signed distances from it in
    mm, in frame order) cannot be trusted: the running median of their distances over
    ``frames`` frames ranges over more than ``limit_mm`` (mm); None where it does not, or with
    fewer frames than that."""
    if len(r) < frames:
        return None
    smooth = median_filter(r, size=frames, mode="nearest")
    if np.ptp(smooth) <= limit_mm:
        return None
    return (f"the measured depths wander {np.ptp(smooth):.2f} mm about the constant-speed insertion "
            f"({smooth.min():+.2f} to {smooth.max():+.2f} mm over runs of frames): a misreading that lasts, "
            "and which frames are right cannot be told")


def _fall_after_stop(fit: InsertionFit, time_s: np.ndarray, depth_mm: np.ndarray, cfg: KinematicsConfig) -> float:
    """How far (mm) the depth falls over the frames after the fitted insertion stops (0 with
    fewer than ``cfg.min_after_stop`` of them): the Theil-Sen slope of their depth in time
    across their span. A robot that stops holds the array where it is; a tip read further and
    further back while the depth should hold was lost (a band or bead train taken for fluid)."""
    after = fit.d0_mm + fit.speed_mm_s * time_s > fit.hi_mm
    if int(np.count_nonzero(after)) < cfg.min_after_stop:
        return 0.0
    t, d = time_s[after], depth_mm[after]
    slope = theilslopes(d, t)[0]
    return float(max(-slope * (t.max() - t.min()), 0.0))


def _flag_order(rows: list[dict], seen: list[int], cfg: KinematicsConfig) -> tuple[list[dict], str]:
    """Too few frames with a depth for a line: mark the measured ones of ``seen`` (row indices, in
    frame order) whose depth contradicts another's (:func:`order_conflicts`), in place; returns
    runs and note as :func:`flag_kinematics`."""
    if len(seen) < 2:
        return [], ""
    t = np.array([float(rows[i]["time_s"]) for i in seen])
    d = np.array([float(rows[i]["depth_mm"]) for i in seen])
    other = order_conflicts(t, d, cfg.tol_mm)
    marked = [k for k in range(len(seen)) if other[k] >= 0 and rows[seen[k]]["ok"]]
    runs = []
    for k in marked:
        j = int(other[k])
        row, partner = rows[seen[k]], rows[seen[j]]
        mark_not_ok(row, f"kinematics: depth {d[k]:.2f} mm and {d[j]:.2f} mm in frame {partner['frame']} cannot "
                         "both hold (the insertion only goes in; too few frames to tell which is misread)")
        runs.append(dict(first=int(row["frame"]), last=int(row["frame"]), frames=1, off_mm=round(float(d[k] - d[j]), 3)))
    note = ""
    if marked:
        note = (f"{len(marked)} frame(s) marked not ok: with {len(seen)} frames with a depth, too few for the "
                f"constant-speed check, their depths contradict each other (frames "
                f"{', '.join(str(r['first']) for r in runs)})")
    return runs, note

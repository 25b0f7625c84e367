"""Stage 4, the angles: each frame's theta_tip, theta_bot and theta_con, depth and outline."""

from __future__ import annotations

import math

import numpy as np

from tympani.vision.angles.centreline import CentreLine
from tympani.vision.angles.config import FrameMeasurement, MeasureConfig, failure
from tympani.vision.angles.definitions import spiral_angle
from tympani.vision.angles.edges import Edges
from tympani.vision.angles.plan import MeasurePlan
from tympani.vision.angles.ragged import Ragged


def _up(rad: float) -> str:
    """``rad`` (rad) rounded up to two decimals, so that a span just over a limit does not read
    as the limit itself."""
    return f"{math.ceil(rad * 100.0 - 1e-9) / 100.0:.2f}"


def contact_tolerance(gaps: np.ndarray, cl: Ragged, cfg: MeasureConfig) -> np.ndarray:
    """The contact tolerance (mm) at each centre-line point: ``cfg.contact_tol_mm`` raised by any
    bias of its frame's measured gaps (:attr:`MeasureConfig.contact_bias_mm`): the lower median
    gap of the stretch from the tip before the first gap over ``contact_tol_mm +
    contact_excess_mm``, less half the tolerance.

    Parameters
    ----------
    gaps : ndarray
        Gap (mm) to the outer wall at each point, the frames' points laid end to end (``cl``),
        tip first.
    cl : Ragged
        The frames' points.
    cfg : MeasureConfig
        Settings.
    """
    hard = np.where(gaps > cfg.contact_tol_mm + cfg.contact_excess_mm, cl.local, cl.n[cl.row])
    stretch = cl.local < np.minimum.reduceat(hard, cl.start)[cl.row]
    counts = cl.count(stretch)
    ranked = np.sort(cl.pad(np.where(stretch, gaps, np.inf), np.inf), axis=1)  # each frame's stretch, ascending
    median = ranked[np.arange(len(counts)), np.maximum(counts - 1, 0) // 2]  # the lower median
    bias = np.where(counts > 0, np.clip(median - 0.5 * cfg.contact_tol_mm, 0.0, cfg.contact_bias_mm), 0.0)
    return (cfg.contact_tol_mm + bias)[cl.row]


def contact_run(gaps: np.ndarray, tol: np.ndarray | float, cl: Ragged, cfg: MeasureConfig
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The contact run from the tip of each frame (:func:`contact_angles`' rule, all frames at once).

    The run ends where the gap first exceeds the tolerance, but not at a blip of measurement
    noise: an excursion shorter than ``cfg.contact_persist_mm``, by less than
    ``cfg.contact_excess_mm``, after which contact holds again for as long (a real departure from
    the wall widens steadily).

    Parameters
    ----------
    gaps : ndarray
        Gap (mm) at each point, the frames' points laid end to end (``cl``), tip first.
    tol : ndarray or float
        Tolerance (mm) at each point.
    cl : Ragged
        The frames' points.
    cfg : MeasureConfig
        Settings.

    Returns
    -------
    contact : ndarray of bool
        Whether each frame's tip touches.
    i0, i1 : ndarray of int
        Positions of the run's last point and of the next one.
    frac : ndarray
        Where between them the gap reaches the tolerance (0-1).
    """
    tol = np.broadcast_to(tol, gaps.shape)
    touching = gaps <= tol
    pos = np.arange(len(gaps))
    end = (cl.start + cl.n)[cl.row]
    # the next touching / non-touching point of each point's frame, or the frame's end (a later
    # frame's points all lie at or beyond this frame's end, so the running minimum stays in it)
    next_touch = np.minimum.accumulate(np.where(touching, pos, end)[::-1])[::-1]
    next_away = np.minimum.accumulate(np.where(~touching, pos, end)[::-1])[::-1]
    persist = int(np.ceil(cfg.contact_persist_mm / cfg.angle_step_mm))
    resumes = next_away[np.minimum(next_touch, len(gaps) - 1)] - next_touch >= persist
    blip = (next_touch - pos < persist) & (next_touch < end) & resumes & (gaps <= tol + cfg.contact_excess_mm)
    away = np.where(~touching & ~blip, cl.local, cl.n[cl.row])
    out_at = np.minimum.reduceat(away, cl.start)  # first point out of contact (n: none)
    i_last = np.where(out_at < cl.n, out_at - 1, cl.n - 1)
    i0 = cl.start + np.maximum(i_last, 0)
    i1 = cl.start + np.minimum(i_last + 1, cl.n - 1)
    g0, g1 = gaps[i0], gaps[np.minimum(i0 + 1, len(gaps) - 1)]
    frac = np.where((out_at < cl.n) & (g1 != g0),
                    np.minimum(np.maximum((tol[i0] - g0) / (g1 - g0), 0.0), 1.0), 0.0)
    return touching[cl.start], i0, i1, frac


def shows_array(used: np.ndarray, v_in: np.ndarray, v_out: np.ndarray, radius: np.ndarray,
                tol: float = 0.3) -> np.ndarray:
    """Stations whose edges place the array: those whose edges the centre line used (``used``),
    and those whose two edges were found the array's width apart (within ``tol`` of it,
    dimensionless) but not used (a band's glare or blur beside them).

    Parameters
    ----------
    used : ndarray of bool
        Stations whose edges the centre line used.
    v_in, v_out : ndarray
        Inner and outer edge offsets (mm; NaN where not found).
    radius : ndarray
        The array's radius (mm) at each station.
    tol : float
        Largest relative difference of the edges' distance from the array's diameter.
    """
    return used | (np.abs(v_out - v_in - 2.0 * radius) <= tol * 2.0 * radius)  # NaN compares False


def unseen_span(theta: np.ndarray, measured: np.ndarray, away: np.ndarray, i0: np.ndarray, i1: np.ndarray,
                cl: Ragged) -> np.ndarray:
    """Per frame, the angle (rad) from the last centre-line point with measured edges at or
    before its contact run's end (point ``i0``) to the first one from ``i1`` on that, with the
    next point, has measured edges and a gap showing the array off the wall (``away``): how
    far the contact start may lie from where the smoothed gaps put it. The line's basal end
    bounds a frame with no such point.

    Parameters
    ----------
    theta : ndarray
        Angle (rad) of each centre-line point, the frames' points laid end to end (``cl``), tip
        first.
    measured : ndarray of bool
        Whether each point's edges were measured.
    away : ndarray of bool
        Whether each point's gap exceeds the contact tolerance.
    i0, i1 : ndarray of int
        Per frame, the positions of the contact run's last point and of the next one.
    cl : Ragged
        The frames' points.
    """
    pos = np.arange(len(theta))
    last = np.maximum.accumulate(np.where(measured, pos, -1))  # at or before each point
    off = measured & away
    off[:-1] &= off[1:]  # and the next point too: a lone station's edges may be noise
    nxt = np.minimum.accumulate(np.where(off, pos, len(pos))[::-1])[::-1]  # at or after it
    end = cl.start + cl.n - 1
    a = np.maximum(last[i0], cl.start)
    b = np.minimum(nxt[i1], end)
    return np.abs(theta[a] - theta[b])


# Frames whose tip is short of this angle (rad) say nothing of which copy of doubled walls the
# array touches (:func:`other_copy_support`).
_COPY_TIP_RAD = math.pi


def other_copy_support(gaps: np.ndarray, station: np.ndarray, cl: Ragged, plan: MeasurePlan,
                       tip_theta: np.ndarray) -> np.ndarray:
    """Per frame, how much more of its centre line (mm) the walls' other copy fits than the
    registered one, where walls show twice (NaN for single walls, and for frames whose tip is
    short of half a turn).

    The array presses on the outer wall in a run that ends at its tip, and it cannot cross the
    wall. On the other copy each gap grows by the copies' shift along the point's outward
    normal. Where the tip touches one copy's wall and not the other's (gap within
    ``contact_tol_mm`` plus the plan's ``gap_resolution_px``, :func:`contact_run`), the points of its
    contact run count 1 for that copy (only points where the shift exceeds 1.5 times the
    tolerance: nearer, the copies' walls are not told apart); where the tip touches both, a run
    longer on one copy says little (where the array leaves the wall its gap grows gradually).
    A point where the array would cross a copy's wall (gap below minus the tolerance) counts
    −2 for it. An array riding a wall at a constant gap near the parallax, or across it, says
    the registration took the copy the array does not touch. Only frames whose tip is past half a turn say
    so: there an array that touches the outer wall presses on it along a stretch over which
    the wall's normal turns through a large angle, which a copy shifted by one image vector
    cannot follow. Nearer the entry the channel turns little, and an array floating at about
    the parallax from a wall looks like one touching the other copy (seen on independent
    renders in a third of the videos whose walls show twice).

    Parameters
    ----------
    gaps : ndarray
        Gap (mm) to the registered outer wall at each centre-line point, tip first, frames laid
        end to end (``cl``).
    station : ndarray of int
        The station of each point.
    cl : Ragged
        The frames' points.
    plan : MeasurePlan
        The plan (``copy_shift_mm``, ``normal``, the settings, the scale).
    tip_theta : ndarray
        Each frame's tip angle (rad).
    """
    shift = np.asarray(plan.copy_shift_mm, dtype=float)
    if not shift.any():
        return np.full(len(cl.n), np.nan)
    cfg = plan.cfg
    tol = cfg.contact_tol_mm + plan.gap_resolution_px / float(plan.pose.px_per_mm)
    along = plan.normal[station] @ shift
    told = np.abs(along) >= 1.5 * tol  # the copies' walls apart by more than the gaps' resolution

    def run(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        contact, i0, _, _ = contact_run(g, tol, cl, cfg)
        return contact, cl.count(contact[cl.row] & (cl.local <= (i0 - cl.start)[cl.row]) & told)

    (this, run_this), (other, run_other) = run(gaps), run(gaps + along)
    crossed = cl.count(gaps + along < -tol) - cl.count(gaps < -tol)
    support = (np.where(this != other, run_other - run_this, 0) - 2.0 * crossed) * cfg.angle_step_mm
    return np.where(tip_theta >= _COPY_TIP_RAD, support, np.nan)


# A centre-line point whose angle differs from its station's by more than this (rad) lies across a
# wall: its radius is nearer another turn's (a difference of 2 pi, less a little curvature).
_CROSSED_RAD = 1.0


def results_batch(plan: MeasurePlan, staged: list[tuple[Edges, CentreLine, dict[str, float]]]
                   ) -> list[FrameMeasurement]:
    """Stage 4: each frame's angles, depth and outline from its centre line, all frames at once.

    The centre line is the tip, then every ``angle_step_mm`` of stations from the last one at or
    before the tip, basal-wards; the frames' points are laid end to end (a :class:`Ragged`
    batch), their angles taken in one call (:func:`spiral_angle` works point by point) and
    :func:`contact_angles`' rule applied to all frames at once. The depth is the centre line's
    length from the tip to ``theta_start`` (negative, along the entry, when the tip is still in
    the entry channel)."""
    cfg, step = plan.cfg, plan.step_mm
    k = max(1, int(round(cfg.angle_step_mm / step)))
    los = np.array([e.lo for e, _, _ in staged], dtype=np.intp)
    tip_f = np.array([c.tip_f for _, c, _ in staged])
    tip_mm = np.array([c.tip_mm for _, c, _ in staged])
    n = np.array([e.n for e, _, _ in staged], dtype=np.intp)
    line, gap, radius, seen = (np.concatenate([getattr(c, name) for _, c, _ in staged])
                               for name in ("line", "gap", "radius", "measured"))
    # the kept stations: every k-th from the last one at or before the tip
    top = np.minimum(np.floor(tip_f).astype(np.intp), n - 1)
    kept = Ragged.of(top // k + 1)
    keep = top[kept.row] - k * kept.local  # station in its frame
    at = (np.cumsum(n) - n)[kept.row] + keep  # position in line, gap, radius
    # the centre line: the tip, then the kept stations' points
    cl = Ragged.of(kept.n + 1)
    inner = cl.start[kept.row] + 1 + kept.local  # positions of the kept points in cl
    points = np.empty((len(cl.row), 2))
    points[cl.start], points[inner] = tip_mm, line[at]
    gaps = np.empty(len(cl.row))
    gaps[cl.start], gaps[inner] = gap[at[kept.start]], gap[at]
    theta = spiral_angle(points, plan.angles)
    # each point's angle against the channel's own where it was found: a point whose radius is
    # nearer another turn's lies across a wall (the array cannot be there)
    station = np.empty(len(cl.row), dtype=np.intp)
    station[cl.start], station[inner] = los + top, los[kept.row] + keep
    crossed = cl.count(np.abs(theta - plan.station_theta[station]) > _CROSSED_RAD) > 0
    other_copy = other_copy_support(gaps, station, cl, plan, theta[cl.start])
    # contact_angles' rule, with the tolerance raised by any bias of the measured gaps
    tol = contact_tolerance(gaps, cl, cfg)
    contact, i0, i1, frac = contact_run(gaps, tol, cl, cfg)
    theta_tip = theta[cl.start]

    def start_angle(touching: np.ndarray, a: np.ndarray, b: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Each frame's contact start angle (rad) from :func:`contact_run`'s result; the tip's
        where the tip does not touch."""
        return np.where(touching, theta[a] + f * (theta[b] - theta[a]), theta_tip)

    theta_bot = start_angle(contact, i0, i1, frac)
    # the contact run with the tolerance raised by the gaps' resolution: where it starts much
    # further back, the array runs along the wall at about the tolerance and where (or whether)
    # it touches cannot be told at this resolution
    loose = tol + plan.gap_resolution_px / float(plan.pose.px_per_mm)
    swing = theta_bot - np.minimum(start_angle(*contact_run(gaps, loose, cl, cfg)), theta_bot)
    # and with the array against the outer edge of a dark wider than itself near the tip: the
    # gaps less the dark's excess width; where its contact run starts far from this one, which
    # side of that dark the array takes decides the contact
    excess = np.array([c.dark_excess_mm for _, c, _ in staged])
    flush = np.abs(start_angle(*contact_run(gaps - excess[cl.row], loose, cl, cfg)) - theta_bot)
    # and with the array's last stretch, its rounded end, taken as touching: where the array
    # touches the wall just behind its tip and not at it, whether the tip touches decides the
    # contact, and there the edges are the least sure
    end = (np.hypot(*(points - tip_mm[cl.row]).T) <= cfg.contact_tip_mm) & (cfg.contact_tip_mm > 0)
    behind = np.abs(start_angle(*contact_run(np.where(end, 0.0, gaps), loose, cl, cfg)) - theta_bot)
    # where no edges were seen around the contact start, its gaps are only smoothed across
    v_in, v_out = (np.concatenate([getattr(e, name) for e, _, _ in staged]) for name in ("v_in", "v_out"))
    measured = np.ones(len(cl.row), dtype=bool)  # the tip is located where no edges show too
    measured[inner] = shows_array(seen, v_in, v_out, radius)[at]
    blind = unseen_span(theta, measured, gaps > tol, i0, i1, cl)
    bot = np.where(contact[:, None], points[i0] + frac[:, None] * (points[i1] - points[i0]), points[cl.start])
    seg = np.diff(points, axis=0)
    seg = np.hypot(seg[:, 0], seg[:, 1])
    seg[cl.start[1:] - 1] = 0.0  # between frames
    depth = np.add.reduceat(np.append(seg, 0.0), cl.start)
    basal = los + keep[kept.start + kept.n - 1]  # a line that starts in the entry: less its part there
    depth -= np.maximum(plan.p_mm[plan.i_start] - plan.p_mm[basal], 0.0)
    entry = los + tip_f < plan.i_start  # tip in the entry channel: theta = phi (k = 0), no contact
    theta_bot = np.where(entry, theta_tip, theta_bot)
    bot = np.where(entry[:, None], tip_mm, bot)
    depth = np.where(entry, -(plan.p_mm[plan.i_start] - plan.p_mm[los] - tip_f * step), depth)
    # the outline: the tip, one side tipwards to base, the other back
    side = radius[at][:, None] * plan.normal[los[kept.row] + keep]
    ol = Ragged.of(2 * kept.n + 1)
    outline = np.empty((len(ol.row), 2))
    outline[ol.start] = tip_mm
    outline[ol.start[kept.row] + 1 + kept.local] = line[at] - side
    outline[ol.start[kept.row] + 2 * kept.n[kept.row] - kept.local] = line[at] + side
    results = []
    rows = zip(staged, cl.split(points), cl.split(gaps), ol.split(outline), theta_tip.tolist(), theta_bot.tolist(),
               bot, depth.tolist(), entry.tolist(), np.where(entry, 0.0, swing).tolist(), crossed.tolist(),
               other_copy.tolist(), contact.tolist(), blind.tolist(), np.where(entry, 0.0, flush).tolist(),
               excess.tolist(), np.where(entry, 0.0, behind).tolist())
    for (_, _, extras), cl_b, gaps_b, outline_b, t_tip, t_bot, bot_b, depth_b, in_entry, swing_b, crossed_b, other_b, \
            contact_b, blind_b, flush_b, excess_b, behind_b in rows:
        extras["depth_mm"] = depth_b
        extras["other_copy_mm"] = other_b
        if crossed_b:
            # kept within the 72 characters an annotated frame shows of a reason
            results.append(failure(f"centre line across a wall into the next turn (tip read at {t_tip:.2f} rad)",
                                   **extras))
            continue
        if contact_b and not in_entry and blind_b > cfg.contact_swing_rad:
            results.append(failure(f"contact start unclear: no array edges over the {_up(blind_b)} rad it lies in",
                                   **extras))
            continue
        if swing_b > cfg.contact_swing_rad:
            results.append(failure(f"contact start unclear: {_up(swing_b)} rad further with the gaps {plan.gap_resolution_px:.2g} "
                                   "px narrower", **extras))
            continue
        if flush_b > cfg.contact_swing_rad:
            results.append(failure(f"contact unclear: the dark at the tip is {excess_b:.2f} mm wider than the array",
                                   **extras))
            continue
        if behind_b > cfg.contact_swing_rad:
            results.append(failure(f"contact unclear: touching the wall {cfg.contact_tip_mm:g} mm behind the tip, not at it",
                                   **extras))
            continue
        results.append(FrameMeasurement(True, "", t_tip, t_bot, 0.0 if in_entry else t_tip - t_bot, cl_b[0], bot_b,
                                        cl_b, outline_b, gaps_b, extras))
    return results

"""Stage 3, the centre line: the array's centre offset, its tip and its gap to the outer wall.

From the edges and the array's known shape (:func:`centre_line_batch`): stations where the dark
is wider than the array (something dark joined to it) are not used, and checks refuse a dark run
that is not the array's (no edges near its end, edges not the array's width, a last stretch
without the inner edge or crossing a wall, a tip on dark fainter than the array or with a
band's brightness just past it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tympani.vision.angles.arrays import odd_ceil, take2d
from tympani.vision.angles.config import MeasureConfig
from tympani.vision.angles.edges import Edges
from tympani.vision.angles.plan import MeasurePlan
from tympani.vision.angles.ragged import (
    Ragged,
    distance_from_tip_ragged,
    extrapolate_ragged,
    row_quantiles,
    running_median_ragged,
    smooth_ragged,
    tip_crossing_ragged,
)
from tympani.vision.angles.shadow import bands_beside
from tympani.vision.geometry import ElectrodeArray


# Why a frame whose dark run has the array's bands beside it is not measured (:mod:`.shadow`).
_BESIDE = "the array's bands show beside the dark run, not on it (its shadow followed?)"


# Why a frame whose tip lies on dark fainter than the array is not measured (:func:`tip_darkness`).
_FAINT = "the dark at the tip is fainter than the array (a shadow or a speck past the tip?)"
# Why a frame whose tip lies on dark far darker than the array is not measured (:func:`tip_darkness`).
_DARKER = "the dark at the tip is darker than the array (a dark bubble or speck against it?)"
# Why a frame with something as bright as a band just past its tip is not measured (:func:`bright_past_tip`).
_BAND_PAST = "a metal band's brightness just past the tip (the array's end not seen?)"


@dataclass(frozen=True)
class CentreLine:
    """Stage 3: the tip (fractional station ``tip_f`` from ``lo``, point ``tip_mm``), and per
    station the centre-line point ``line`` (mm), the gap (mm), the radius (mm) and whether
    the edges were used (``measured``); ``dark_excess_mm``, how much wider (mm) than the array
    the dark is over the last ``tip_width_mm`` before the tip (:func:`_dark_excess`)."""

    tip_f: float
    tip_mm: np.ndarray
    line: np.ndarray
    gap: np.ndarray
    radius: np.ndarray
    measured: np.ndarray
    width_ratio: float  # seen width over modelled width, median where both edges show (NaN: < 10 such)
    dark_excess_mm: float


def _half_widths(s: np.ndarray, stretch: np.ndarray, array: ElectrodeArray) -> tuple[np.ndarray, np.ndarray]:
    """The array's half-width across the channel (mm; its radius, narrower on the rounded tip,
    times ``stretch``) and its radius (mm) at distances ``s`` (mm) from the tip."""
    length = array.length_mm  # ElectrodeArray.radius, without its Python-level overhead
    s_in = np.minimum(np.maximum(s, 0.0), length)
    radius = 0.5 * (array.tip_diameter_mm + (array.base_diameter_mm - array.tip_diameter_mm) * s_in / length)
    r_tip = 0.5 * array.tip_diameter_mm
    body_half = np.where(s < r_tip, np.sqrt(np.maximum(r_tip**2 - (r_tip - s) ** 2, 0.0)), radius)
    return body_half * stretch, radius


def _width_ratio(v_in: np.ndarray, v_out: np.ndarray, both: np.ndarray, width: np.ndarray, rg: Ragged) -> np.ndarray:
    """Each frame's median width between the two edges (mm) over the modelled ``width`` (mm),
    over the stations ``both`` where both show; NaN where fewer than ten do."""
    ratio = np.where(both, (v_out - v_in) / np.where(both, width, 1.0), 0.0)
    median = row_quantiles(rg.pad(ratio, 0.0), rg.pad(both, False), 0.5)
    return np.where(rg.count(both) >= 10, median, np.nan)


def _dark_excess(v_in: np.ndarray, v_out: np.ndarray, ok_in: np.ndarray, ok_out: np.ndarray, half: np.ndarray,
                 width: np.ndarray, near_tip: np.ndarray, rg: Ragged, min_count: int, noise_mm: float) -> np.ndarray:
    """Per frame, how much wider (mm) than the array the dark is near its tip: the median over
    the stations ``near_tip`` whose inner edge shows of the dark's width (to the outer edge, or
    to the outer wall where that edge is not found: the dark may reach it) less the array's.

    The centre line puts the array against the dark's inner edge; where the dark is wider (a
    shadow beside the array, darker than the array itself, or a dark line joined to it), the
    array may as well lie against its outer edge, nearer the wall by this much.

    Parameters
    ----------
    v_in, v_out : ndarray
        Inner and outer edge offsets (mm) at the frames' stations (ragged ``rg``).
    ok_in, ok_out : ndarray of bool
        Where each edge was seen on the array's body.
    half : ndarray
        The channel's half-width (mm) at each station.
    width : ndarray
        The array's width across the channel (mm) at each station.
    near_tip : ndarray of bool
        The stations near the tip to use.
    rg : Ragged
        The frames' stations.
    min_count : int
        Fewest such stations with the inner edge: a frame with fewer gets 0.
    noise_mm : float
        Excess (mm) within the edges' noise: a smaller one is 0.
    """
    use = near_tip & ok_in
    excess = row_quantiles(rg.pad(np.where(ok_out, v_out, half) - v_in - width, 0.0), rg.pad(use, False), 0.5)
    return np.where((rg.count(use) >= min_count) & (excess > noise_mm), excess, 0.0)


def _misfit(v_in: np.ndarray, v_out: np.ndarray, ok_in: np.ndarray, ok_out: np.ndarray, visible: np.ndarray,
            slack: np.ndarray, clear_mm: np.ndarray, widen: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Where the dark between the edges (mm; ``ok_in``/``ok_out`` where seen) is narrower than
    the array's ``2 * visible`` (mm) less ``slack`` (mm; cut by a band's border), and where it is
    wider than that times ``widen`` plus ``slack`` (crowded: from the one edge seen, out to the
    other wall's margin ``clear_mm``, mm)."""
    cut = ok_in & ok_out & (v_out - v_in < 2.0 * visible - slack)
    wide = 2.0 * visible * widen + slack
    crowded = (ok_in & ~ok_out & (clear_mm - v_in > wide)) | (ok_out & ~ok_in & (v_out + clear_mm > wide)) | (
        ok_in & ok_out & (v_out - v_in > wide))
    return cut, crowded


def _core_where_wider(v_in: np.ndarray, v_out: np.ndarray, ok_in: np.ndarray, ok_out: np.ndarray,
                      core_in: np.ndarray, core_out: np.ndarray, half: np.ndarray, visible: np.ndarray,
                      slack: np.ndarray, clear_mm: np.ndarray, closer: float) -> tuple[np.ndarray, ...]:
    """The edges, with a darker core's (``core_in``/``core_out``, mm, NaN where it has none on
    that side) taken in where its width is nearer the array's (``2 * visible``, mm; the dark
    out to the wall where one edge is not seen) than ``closer`` times the dark's own is: the
    lighter shelf beside the core is a shadow, not the array. Where the dark has about the
    array's width, a core inside it is the darker part of an array lit from one side and stays
    unused, as does a core whose width the array cannot have (:func:`_misfit`).

    Parameters
    ----------
    v_in, v_out : ndarray, shape (n,)
        The dark's edges (mm).
    ok_in, ok_out : ndarray, shape (n,), bool
        Where they were seen.
    core_in, core_out : ndarray, shape (n,)
        The core's edges (mm), NaN where it has none on that side.
    half : ndarray, shape (n,)
        The channel's half-width (mm).
    visible : ndarray, shape (n,)
        The array's half-width (mm).
    slack : ndarray, shape (n,)
        Width tolerance (mm; :func:`_misfit`).
    clear_mm : ndarray, shape (n,)
        Offset (mm) of the last place clear of each wall.
    closer : float
        Largest ratio (dimensionless) of the core's width error to the dark's.

    Returns
    -------
    v_in, v_out, ok_in, ok_out : ndarray
        The edges (mm) and where they were seen.
    """
    seen = ok_in | ok_out
    has_in, has_out = np.isfinite(core_in), np.isfinite(core_out)
    c_in, c_out = np.where(has_in, core_in, v_in), np.where(has_out, core_out, v_out)
    c_ok_in, c_ok_out = np.where(has_in, seen, ok_in), np.where(has_out, seen, ok_out)
    cut, crowded = _misfit(c_in, c_out, c_ok_in, c_ok_out, visible, slack, clear_mm, 1.0)
    width = 2.0 * visible
    error_dark = np.abs(np.where(ok_out, v_out, half) - np.where(ok_in, v_in, -half) - width)
    error_core = np.abs(np.where(c_ok_out, c_out, half) - np.where(c_ok_in, c_in, -half) - width)
    swap = (has_in | has_out) & ~cut & ~crowded & (error_core <= closer * error_dark)
    return (np.where(swap, c_in, v_in), np.where(swap, c_out, v_out), np.where(swap, c_ok_in, ok_in),
            np.where(swap, c_ok_out, ok_out))


def _centre_offsets(
    v_in: np.ndarray,
    v_out: np.ndarray,
    ok_in: np.ndarray,
    ok_out: np.ndarray,
    s: np.ndarray,
    stretch: np.ndarray,
    array: ElectrodeArray,
    cap_min: float,
    tol_mm: float,
    clear_mm: np.ndarray,
    widen: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The array's centre offset at each station from its edges and its known shape.

    Parameters
    ----------
    v_in, v_out : ndarray, shape (n,)
        Offsets (mm, along the backbone normal) of the inner and the outer edge.
    ok_in, ok_out : ndarray, shape (n,), bool
        Where each edge was seen on the array's body.
    s : ndarray, shape (n,)
        Distance (mm) of each station's centre-line point from the tip.
    stretch : ndarray, shape (n,)
        Width across the channel over the array's width (1 / cosine of its slant).
    array : ElectrodeArray
        The array (radius along its length; the tip is a half disc).
    cap_min : float
        Stations closer to the tip than this fraction of the tip radius are not used.
    tol_mm : float
        How much narrower (mm) than expected the two edges may be before the station is
        taken to be cut by a band's border (at least 30 % of the half-width is allowed), and
        wider before it is taken to be crowded.
    clear_mm : ndarray, shape (n,)
        Offset (mm) of the last place clear of each wall (the half-width less the wall
        margin). Where the dark is wider than the array by as much as ``tol_mm`` allows
        narrower (between the two edges, or from the one edge that shows on to the other
        wall's margin), something dark lies beside the array (a bubble's rim, a shadow, a
        doubled wall line) and which side of that dark the array takes is unknown: the
        station is not used.
    widen : ndarray, shape (n,)
        How much wider (factor, at least 1) than modelled the array is seen in the station's
        frame (:func:`_width_ratio`, at least 1); the dark is compared with that width.

    Returns
    -------
    v_c : ndarray, shape (n,)
        Centre offset (mm): the inner edge plus the visible half-width where the inner edge
        was seen, else the outer edge minus it.
    measured : ndarray, shape (n,), bool
        Stations where ``v_c`` was measured.
    radius : ndarray, shape (n,)
        The array's radius (mm) at each station.
    """
    visible, radius = _half_widths(s, stretch, array)
    cut, crowded = _misfit(v_in, v_out, ok_in, ok_out, visible, np.maximum(tol_mm, 0.3 * visible), clear_mm, widen)
    use_in = ok_in & ~cut & ~crowded
    use_out = ok_out & ~ok_in & ~cut & ~crowded
    v_c = np.where(use_in, v_in + visible, v_out - visible)
    return v_c, (use_in | use_out) & (s >= cap_min * 0.5 * array.tip_diameter_mm), radius


@dataclass(frozen=True)
class TipView:
    """One frame's strip around its tip, for the checks of the tip's last stretch.

    ``fine`` the fine strip (grey levels, offsets × stations from its first); per station
    ``fluid`` and ``contrast`` (fluid minus array, grey levels) and ``half_mm`` (the channel's
    half-width, mm); ``u`` the normalised offsets (−1 inner wall, +1 outer wall); the tip at
    fractional station ``tip_f`` and offset ``tip_v`` (mm, along the backbone normal).
    """

    fine: np.ndarray
    fluid: np.ndarray
    contrast: np.ndarray
    half_mm: np.ndarray
    u: np.ndarray
    tip_f: float
    tip_v: float


def _near_tip(views: list[TipView], kept: np.ndarray, j0: np.ndarray, j1: np.ndarray, r_tip_mm: float,
              margin_mm: float) -> tuple[np.ndarray, np.ndarray, Ragged]:
    """The ``kept`` views' strips (at least one) over their stations ``j0 .. j1`` (inclusive),
    laid end to end: the 3x3 mean of the strip (as ``cv2.blur`` gives it, reflected at the
    strip's edges and, for 8-bit strips, rounded; noise then does not pass for dark or bright)
    and, per offset and station, whether the offset lies clear of the walls (``margin_mm``)
    within ``r_tip_mm`` (mm) of the tip's offset. Returns those and their layout."""
    rg = Ragged.of((j1 - j0 + 1)[kept])
    cols = j0[kept][rg.row] + rg.local
    n = np.array([views[b].fine.shape[1] for b in kept.tolist()])[rg.row]
    left, right = np.abs(cols - 1), cols + 1
    right = np.where(right >= n, 2 * (n - 1) - right, right)
    three = np.concatenate([views[b].fine[:, np.concatenate([left[a], cols[a], right[a]])]
                            for b, a in zip(kept.tolist(), rg.split(np.arange(len(cols))))], axis=1)
    k = rg.n[rg.row]
    pos = 3 * rg.start[rg.row] + rg.local  # each station's own column, then its left and right ones
    across = three[:, pos + k].astype(np.float64) + three[:, pos] + three[:, pos + 2 * k]
    m = across.shape[0]
    padded = across[np.concatenate([[1], np.arange(m), [m - 2]])]
    smooth = (padded[:-2] + padded[1:-1] + padded[2:]) * (1.0 / 9.0)
    if views[0].fine.dtype == np.uint8:  # as cv2.blur gives it: rounded to grey levels
        smooth = np.rint(smooth)
    half = np.concatenate([views[b].half_mm[a : c + 1] for b, a, c in zip(kept.tolist(), j0[kept].tolist(),
                                                                           j1[kept].tolist())])
    tip_v = np.array([views[b].tip_v for b in kept.tolist()])[rg.row]
    off = views[0].u[:, None] * half[None, :]
    near = (np.abs(off) <= (half - margin_mm)[None, :]) & (np.abs(off - tip_v[None, :]) <= r_tip_mm)
    return smooth, near, rg


def _gathered(frames: list[TipView] | list[Edges], name: str, kept: np.ndarray, j0: np.ndarray,
              j1: np.ndarray) -> np.ndarray:
    """A per-station field (``fluid`` or ``contrast``) of the ``kept`` frames over their stations
    ``j0 .. j1`` (inclusive), laid end to end."""
    return np.concatenate([getattr(frames[b], name)[a : c + 1]
                           for b, a, c in zip(kept.tolist(), j0[kept].tolist(), j1[kept].tolist())])


def tip_darkness(views: list[TipView], step_mm: float, r_tip_mm: float, margin_mm: float,
                 stretch_mm: tuple[float, float]) -> np.ndarray:
    """How dark (coverage: 0 fluid, 1 the array's nominal contrast) each view's last stretch of
    array is: the darkest point (3x3 mean) clear of the walls and within the tip radius of the
    tip's offset, over the stations ``stretch_mm`` (mm, nearest and farthest) basal of the tip;
    NaN where that stretch has no such point.

    Parameters
    ----------
    views : list of TipView
        The frames' strips and tips.
    step_mm : float
        Station spacing (mm).
    r_tip_mm : float
        The array's tip radius (mm).
    margin_mm : float
        Offsets this close (mm) to a wall are not used (a wall line may be dark).
    stretch_mm : tuple of float
        Nearest and farthest distance (mm) basal of the tip of the stations used.

    Returns
    -------
    ndarray, shape (len(views),)
    """
    tip_f = np.array([v.tip_f for v in views], dtype=float)
    n = np.array([v.fine.shape[1] for v in views], dtype=np.intp)
    j0 = np.maximum(np.ceil(tip_f - stretch_mm[1] / step_mm).astype(np.intp), 0)
    j1 = np.minimum(np.floor(tip_f - stretch_mm[0] / step_mm).astype(np.intp), n - 1)
    out = np.full(len(views), np.nan)
    kept = np.flatnonzero(j1 >= j0)
    if not len(kept):
        return out
    smooth, near, rg = _near_tip(views, kept, j0, j1, r_tip_mm, margin_mm)
    cover = (_gathered(views, "fluid", kept, j0, j1) - smooth) / _gathered(views, "contrast", kept, j0, j1)
    darkest = np.maximum.reduceat(np.where(near, cover, -np.inf).max(axis=0), rg.start)
    out[kept] = np.where(np.isfinite(darkest), darkest, np.nan)
    return out


def bright_past_tip(views: list[TipView], step_mm: float, r_tip_mm: float, margin_mm: float,
                    stretch_mm: tuple[float, float], band_level: float) -> np.ndarray:
    """Per view, the share of the stations ``stretch_mm`` (mm, nearest and farthest) past the
    tip where something as bright as a metal band lies on the array's track: a point (3x3 mean)
    clear of the walls and within the tip radius of the tip's offset at least ``band_level`` (a
    fraction of the fluid's level) brighter than the fluid. NaN where fewer than two stations
    lie there. Parameters as :func:`tip_darkness` (``margin_mm``: a wall line may be bright).
    """
    tip_f = np.array([v.tip_f for v in views], dtype=float)
    n = np.array([v.fine.shape[1] for v in views], dtype=np.intp)
    j0 = np.ceil(tip_f + stretch_mm[0] / step_mm).astype(np.intp)
    j1 = np.minimum(np.floor(tip_f + stretch_mm[1] / step_mm).astype(np.intp), n - 1)
    out = np.full(len(views), np.nan)
    kept = np.flatnonzero(j1 - j0 >= 1)  # at least two stations
    if not len(kept):
        return out
    smooth, near, rg = _near_tip(views, kept, j0, j1, r_tip_mm, margin_mm)
    fluid = _gathered(views, "fluid", kept, j0, j1)
    lit = ((smooth - fluid >= band_level * fluid) & near).any(axis=0)
    out[kept] = rg.count(lit) / rg.n
    return out


def _unlike_tips(plan: MeasurePlan, edges: list[Edges], tip_f: np.ndarray, tip_v: np.ndarray) -> list[str | None]:
    """Why each frame's tip is not the array's end (its last stretch fainter than the array or far
    darker than it, or, no bubble found, a band's brightness just past it), or None. ``tip_f`` is
    each tip's fractional station from its ``edges.lo`` and ``tip_v`` its offset (mm)."""
    cfg = plan.cfg
    views = [TipView(e.fine, e.fluid, e.contrast, plan.half_mm[e.lo : e.lo + e.fine.shape[1]], plan.u, f, v)
             for e, f, v in zip(edges, tip_f.tolist(), tip_v.tolist())]
    if not views:
        return []
    margin = cfg.wall_margin_px / float(plan.pose.px_per_mm)
    dark = tip_darkness(views, plan.step_mm, plan.r_tip_mm, margin, cfg.tip_dark_mm)
    cover = np.array([e.array_cover for e in edges])
    faint = dark < cfg.tip_dark_min * cover  # NaN compares False
    # the array's darkness: where its inner edge reads lighter than the survey's contrast (a
    # wall line or a shadow along that edge), the survey's
    darker = dark > cfg.tip_dark_max * np.maximum(cover, 1.0)
    out: list[str | None] = [_FAINT if f else _DARKER if d else None for f, d in zip(faint.tolist(), darker.tolist())]
    ask = [b for b, e in enumerate(edges) if out[b] is None and not e.bubble]
    if ask:
        shares = bright_past_tip([views[b] for b in ask], plan.step_mm, plan.r_tip_mm, margin, cfg.band_past_mm,
                                 cfg.band_past_level)
        for b, share in zip(ask, shares.tolist()):
            if share >= cfg.band_past_share:
                out[b] = _BAND_PAST
    return out


def speck_cut(cover: np.ndarray, along: np.ndarray, level: float, start: int, tip: float, track: float,
              offset_mm: np.ndarray, widest_mm: float, bright: float) -> float | None:
    """Where the array ends when the dark past a gap of fluid beyond it is narrower than it can
    be (a speck or a thin shadow beside the channel's wall, not the cap beyond a band): the first
    fall of the coverage along the track below ``level`` from station ``start`` on, where it
    rises again before ``tip`` (the last fall), the gap is plain fluid (nowhere brighter than it
    by ``bright``: a metal band is) and the dark beyond is nowhere wider than ``widest_mm``; None
    otherwise.

    Parameters
    ----------
    cover : ndarray, shape (m, k)
        Coverage (0 fluid, 1 array), offsets × stations of the tail.
    along : ndarray, shape (k,)
        Coverage along the track.
    level : float
        The tip's crossing level.
    start : int
        First station of the tail sought (the last with measured edges).
    tip : float
        The tip's fractional station (the last fall).
    track : float
        The track's fractional offset index.
    offset_mm : ndarray, shape (k,)
        Offset spacing (mm) at each station.
    widest_mm : float
        Widest (mm) the dark past the gap may be.
    bright : float
        Coverage below zero (brighter than the fluid) of a metal band.

    Returns
    -------
    float or None
        Fractional station of the first fall.
    """
    above = along >= level
    end = int(np.floor(tip))
    falls = np.flatnonzero(above[start:end] & ~above[start + 1 : end + 1]) + start
    if not len(falls):
        return None
    fall = int(falls[0])
    rises = np.flatnonzero(above[fall + 1 : end + 1]) + fall + 1
    if not len(rises) or along[fall + 1 : rises[0]].min() < -bright:  # a band's brightness: the array goes on
        return None
    m = cover.shape[0]
    row = min(max(int(round(track)), 0), m - 1)
    widest = 0.0
    for j in range(int(rises[0]), end + 1):  # the dark run across the track at each station beyond
        dark = cover[:, j] >= level
        if not dark[row]:
            continue
        lo = row - int(np.argmin(dark[row::-1])) if not dark[: row + 1].all() else -1
        hi = row + int(np.argmin(dark[row:])) if not dark[row:].all() else m
        widest = max(widest, (hi - lo - 1) * float(offset_mm[j]))
    if not 0.0 < widest <= widest_mm:  # nothing dark on the track beyond: no evidence
        return None
    a, b = along[fall], along[fall + 1]
    return fall + min(max((a - level) / max(a - b, 1e-6), 0.0), 1.0)


def _with_falls(edges: list[Edges], last: np.ndarray, tip_f: np.ndarray, rows: np.ndarray,
                level: np.ndarray, bright: float) -> np.ndarray:
    """The frames (indices) where :func:`speck_cut` may find a speck: room for the array's end, a
    gap and more between the last station with measured edges (``last``) and the tip
    (fractional station ``tip_f``), and there a fall of the coverage along the track (the mean
    over the fractional offset indices ``rows``, shape (B, 3)) below ``level`` that rises again
    before the tip, the gap between nowhere ``bright`` below zero (a metal band's brightness:
    the commonest fall, the band behind the array's cap). All frames' stretches at once,
    computed as :func:`speck_cut`'s caller does."""
    frames = np.flatnonzero(tip_f > last + 3.0)
    if not len(frames):
        return frames
    lo = last.astype(np.intp)
    n = np.array([e.fine.shape[1] for e in edges], dtype=np.intp)
    hi = np.minimum(tip_f.astype(np.intp) + 2, n) - 1  # the stretch speck_cut's caller takes
    s0 = lo[frames]
    rg = Ragged.of(hi[frames] + 1 - s0)
    j = rows[frames].astype(int)
    f = rows[frames] - j
    near = np.concatenate([edges[i].fine[np.concatenate([j[c], j[c] + 1]), a : a + k]
                           for c, (i, a, k) in enumerate(zip(frames.tolist(), s0.tolist(), rg.n.tolist()))], axis=1)
    fluid, contrast = (_gathered(edges, name, frames, lo, hi)[None, :] for name in ("fluid", "contrast"))
    cover = (fluid - near) / contrast
    f = f[rg.row].T
    along = ((1.0 - f) * cover[:3] + f * cover[3:]).mean(axis=0)
    above = along >= level[frames][rg.row]
    end = np.floor(tip_f[frames] - s0).astype(np.intp)[rg.row]  # the last fall, the tip
    after = np.append(above[1:], False)
    fall = np.where(above & ~after & (rg.local < np.minimum(end, rg.n[rg.row] - 1)), rg.local, np.iinfo(np.intp).max)
    first = np.minimum.reduceat(fall, rg.start)[rg.row]
    rise = np.minimum.reduceat(np.where(above & (rg.local > first) & (rg.local <= end), rg.local, rg.n[rg.row]),
                               rg.start)
    gap = (rg.local > first) & (rg.local < rise[rg.row])
    lit = np.minimum.reduceat(np.where(gap, along, np.inf), rg.start) < -bright
    return frames[(rise < rg.n) & ~lit]


def _before_specks(plan: MeasurePlan, edges: list[Edges], last: np.ndarray, tip_f: np.ndarray, tip_u: np.ndarray,
                   level: np.ndarray) -> np.ndarray:
    """Each frame's tip (fractional station from its ``lo``) moved back to the gap of fluid before
    a speck (:func:`speck_cut`), where there is one between its last station with measured edges
    (``last``) and the tip; ``tip_u`` the tip's normalised offset and ``level`` its crossing
    level (coverage), per frame."""
    cfg, u = plan.cfg, plan.u
    du = float(u[1] - u[0])
    widest = cfg.speck_share * 2.0 * plan.r_tip_mm
    track = (tip_u - float(u[0])) / du
    rows = np.clip(track[:, None] + np.array([-1.0, 0.0, 1.0]), 0, len(u) - 1.001)
    out = tip_f.copy()
    for i in _with_falls(edges, last, tip_f, rows, level, cfg.band_level).tolist():
        e, s0 = edges[i], int(last[i])
        a = slice(s0, int(tip_f[i]) + 2)
        cover = (e.fluid[None, a] - e.fine[:, a]) / e.contrast[None, a]
        j, f = rows[i].astype(int), rows[i] - rows[i].astype(int)
        along = ((1.0 - f)[:, None] * cover[j] + f[:, None] * cover[j + 1]).mean(axis=0)
        stations = np.minimum(e.lo + s0 + np.arange(cover.shape[1]), len(plan.half_mm) - 1)
        cut = speck_cut(cover, along, float(level[i]), 0, float(tip_f[i] - s0), float(track[i]),
                        du * plan.half_mm[stations], widest, cfg.band_level)
        if cut is not None:
            out[i] = s0 + cut
    return out


def tip_reach(array: ElectrodeArray, cfg: MeasureConfig) -> float:
    """Farthest (mm) the tip may lie past the last station with measured edges: the array's
    first band's far end from the tip (no band: nothing) plus ``cfg.band_edge_mm``, at most
    ``cfg.tip_reach_mm``.

    Parameters
    ----------
    array : ElectrodeArray
        The array (``first_band_mm``, ``band_length_mm``, ``n_bands``; mm).
    cfg : MeasureConfig
        Settings (``band_edge_mm``, ``tip_reach_mm``; mm).
    """
    band_end = array.first_band_mm + array.band_length_mm if array.n_bands > 0 else 0.0
    return float(min(cfg.tip_reach_mm, band_end + cfg.band_edge_mm))


def centre_line_batch(plan: MeasurePlan, edges: list[Edges]) -> list[CentreLine | str]:
    """Stage 3: each frame's centre line, tip and gap to the outer wall, or why there is none: no
    edges, the edges seen on both sides do not have the array's width, or no edges within
    :func:`tip_reach` of the tip (the dark run goes on where no array shows: a bubble's rim, a
    shadow, a doubled wall line)."""
    cfg, array, step, ppm = plan.cfg, plan.array, plan.step_mm, float(plan.pose.px_per_mm)
    u0, du = float(plan.u[0]), float(plan.u[1] - plan.u[0])
    k_smooth = odd_ceil(cfg.gap_smooth_mm / step)
    tol = cfg.outlier_px / ppm
    span = max(4, int(np.ceil(0.4 / step)))
    out: list[CentreLine | str] = ["array edges not found"] * len(edges)
    rg = Ragged.of([e.n for e in edges])
    lo = np.array([e.lo for e in edges], dtype=np.intp)
    station = lo[rg.row] + rg.local
    v_in, v_out, ok_in, ok_out, core_in, core_out = (np.concatenate([getattr(e, name) for e in edges])
                                                     for name in ("v_in", "v_out", "ok_in", "ok_out", "core_in",
                                                                  "core_out"))
    # pass 1: distance from the tip along the backbone, array parallel to the channel
    s = plan.p_mm[lo + rg.n - 1][rg.row] - plan.p_mm[station]
    clear = plan.half_mm[station] - cfg.wall_margin_px / ppm
    visible = _half_widths(s, np.ones(len(s)), array)[0]
    # a darker core's edges where they give the array's width better than the dark's: a shadow
    v_in, v_out, ok_in, ok_out = _core_where_wider(v_in, v_out, ok_in, ok_out, core_in, core_out,
                                                   plan.half_mm[station], visible, np.maximum(tol, 0.3 * visible),
                                                   clear, cfg.core_closer)
    # an array wider than modelled is not crowded by its own width
    widen = np.fmax(_width_ratio(v_in, v_out, ok_in & ok_out & (s >= plan.r_tip_mm), 2.0 * visible, rg), 1.0)[rg.row]
    v_c, measured, _ = _centre_offsets(v_in, v_out, ok_in, ok_out, s, np.ones(len(s)), array, cfg.cap_min, tol, clear,
                                       widen)
    live = np.flatnonzero(rg.count(measured) >= 3)
    if not len(live):
        return out
    if len(live) < len(edges):  # the others have no centre line
        sub, rg = rg.subset(live)
        lo, station = lo[live], station[sub]
        v_in, v_out, ok_in, ok_out, v_c, measured, clear, widen = (
            a[sub] for a in (v_in, v_out, ok_in, ok_out, v_c, measured, clear, widen))
    n, row, local = rg.n, rg.row, rg.local
    # outliers: off their neighbours' running median by more than 3 robust SDs (and tol)
    at = np.flatnonzero(measured)
    med = np.zeros(len(v_c))
    med[at] = running_median_ragged(v_c[at], Ragged.of(rg.count(measured)), k_smooth)
    dev = np.abs(v_c - med)
    mad = row_quantiles(rg.pad(dev, 0.0), rg.pad(measured, False), 0.5)
    measured &= dev <= np.maximum(tol, 3.0 * 1.4826 * mad)[row]
    (centre,), (slant,) = smooth_ragged(v_c[None, :], measured, rg, odd_ceil(2.5 * cfg.gap_smooth_mm / step))
    stretch = np.sqrt(1.0 + (slant / step) ** 2)
    # the tip: the half-level crossing along the centre line, extrapolated from the body
    last = rg.last(measured)
    half_tip = plan.half_mm[lo + n - 1]
    tip_v = extrapolate_ragged(local.astype(float), v_c, measured & (local >= (last - 1.0 / step)[row]), 1.0 / step, rg)
    reach = tip_reach(array, cfg)
    bare = (n - 1 - last) * step > reach  # no array edges near the tip
    for b in np.flatnonzero(bare):
        out[int(live[b])] = f"no array edges within {reach:.2g} mm of the dark run's end"
    tip_u = np.minimum(np.maximum(tip_v / half_tip, -1.0), 1.0)
    k0 = np.maximum(n - 1 - span, 0)
    tail = Ragged.of([len(edges[b].fluid) - k for b, k in zip(live.tolist(), k0.tolist())])
    fine = np.concatenate([edges[b].fine[:, k:] for b, k in zip(live.tolist(), k0.tolist())], axis=1)
    fluid = np.concatenate([edges[b].fluid[k:] for b, k in zip(live.tolist(), k0.tolist())])
    contrast = np.concatenate([edges[b].contrast[k:] for b, k in zip(live.tolist(), k0.tolist())])
    m = fine.shape[0]
    pos = np.minimum(np.maximum(((tip_u - u0) / du)[:, None] + np.array([-1.0, 0.0, 1.0]), 0), m - 1)  # (B, 3)
    j0 = np.minimum(pos.astype(int), m - 2)
    f, j0 = (pos - j0).T[:, tail.row], j0.T[:, tail.row]
    cols = np.arange(len(tail.row))
    sampled = take2d(fine, j0, cols) * (1 - f) + take2d(fine, j0 + 1, cols) * f  # the mean over 3 offsets around the tip's
    along = (fluid - (sampled[0] + sampled[1] + sampled[2]) / 3.0) / contrast
    level = np.array([edges[b].level for b in live.tolist()])
    tip_f = k0 + tip_crossing_ragged(along, level, (n - 1 - k0).astype(float), tail)
    tip_f = _before_specks(plan, [edges[b] for b in live.tolist()], last, tip_f, tip_u, level)
    tip_mm = plan.to_mm(lo + tip_f, tip_u)
    # pass 2: distance along the measured centre line, slant across the channel -> gaps
    point, normal, half = plan.point_mm[station], plan.normal[station], plan.half_mm[station]
    s = distance_from_tip_ragged(point + centre[:, None] * normal, tip_mm, tip_f, rg)
    v_c, measured2, radius = _centre_offsets(v_in, v_out, ok_in, ok_out, s, stretch, array, cfg.cap_min, tol, clear,
                                             widen)
    before = local <= tip_f[row]
    measured &= measured2 & before
    good = rg.count(measured) >= 3
    # where both edges show, the array must be about as wide as it is (noise is not)
    both = ok_in & ok_out & before & (s >= plan.r_tip_mm)
    width = 2.0 * radius * stretch
    fits = np.abs(v_out - v_in - width) <= np.maximum(2.0 / ppm, 0.3 * width)
    n_both = rg.count(both)
    good &= ~((n_both >= 10) & (rg.count(fits & both) / np.maximum(n_both, 1) < 0.5))
    stretch_tip = before & (s <= cfg.tip_width_mm)
    min_count = int(np.ceil(0.25 * cfg.tip_width_mm / step))
    n_tip = rg.count(stretch_tip)
    odd = (n_tip >= min_count) & (rg.count(ok_in & stretch_tip) < cfg.tip_inner_min * n_tip)
    # a centre line closer to a wall than half the array's radius: the array would cross it
    n_meas = rg.count(measured & stretch_tip)
    in_wall = measured & stretch_tip & ((half - np.abs(v_c)) < 0.5 * radius)
    odd |= (n_meas >= min_count) & (rg.count(in_wall) >= cfg.tip_wall_share * n_meas)
    for b in np.flatnonzero(good & ~bare & odd):
        out[int(live[b])] = f"the dark run's last {cfg.tip_width_mm:g} mm does not look like the array (a line?)"
    keep = np.flatnonzero(good & ~bare & ~odd)
    if not len(keep):
        return out
    width_ratio = _width_ratio(v_in, v_out, both, width, rg)
    excess = _dark_excess(v_in, v_out, ok_in, ok_out, half, width, before & (s >= plan.r_tip_mm) & stretch_tip, rg,
                          min_count, 2.0 / ppm)
    sub, part = rg.subset(keep)
    ok = measured[sub]
    (centre, gap), _ = smooth_ragged(np.vstack([v_c[sub], (half - v_c - radius * stretch)[sub]]), ok, part, k_smooth)
    line = point[sub] + centre[:, None] * normal[sub]
    radius = radius[sub]
    unlike = _unlike_tips(plan, [edges[int(live[b])] for b in keep.tolist()], tip_f[keep], (tip_u * half_tip)[keep])
    for b, s0, m_b, reason in zip(keep.tolist(), part.start.tolist(), part.n.tolist(), unlike):
        e = edges[int(live[b])]
        if reason is None and bands_beside(e, float(tip_f[b]), plan):
            reason = _BESIDE
        if reason is not None:
            out[int(live[b])] = reason
            continue
        a = slice(s0, s0 + m_b)
        out[int(live[b])] = CentreLine(float(tip_f[b]), tip_mm[b], line[a], gap[a], radius[a], ok[a],
                                        float(width_ratio[b]), float(excess[b]))
    return out

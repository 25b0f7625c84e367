"""Stage 2, the edges: the array's inner and outer edge at each station that holds it.

On the fine strip of those stations (:func:`edges_batch`): the dark run cut before a bubble
(:mod:`tympani.vision.angles.bubbles`), the half-level crossings of the array's coverage either
side of its darkest offset, and the inner edge moved to the half level between the fluid and
the array just beside it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tympani.vision.angles.arrays import accumulate_rows, median, odd_ceil, take2d
from tympani.vision.angles.bubbles import TRAIN, bubble_end, with_compact
from tympani.vision.angles.config import MeasureConfig
from tympani.vision.angles.plan import MeasurePlan
from tympani.vision.angles.ragged import (
    Ragged,
    erode_ragged,
    interp_ragged,
    near_ragged,
    row_quantiles,
    smooth_ragged,
)
from tympani.vision.angles.survey import Survey


@dataclass(frozen=True)
class Edges:
    """Stage 2: the fine strip from station ``lo`` on (the array holds ``lo .. lo + n - 1``).

    ``fine`` the strip (grey levels), ``fluid`` and ``contrast`` per station (grey levels),
    ``seed`` darkest offset, ``v_in``/``v_out`` edge offsets (mm) and ``ok_in``/``ok_out``
    where they are the array body's, ``core_in``/``core_out`` the edges (mm) of a darker core
    with a lighter shelf beyond it out to the dark's edge (NaN where none; :func:`_shelf_edges`),
    ``level`` the coverage half way between the fluid and the array beside it, ``array_cover``
    the array's coverage just inside its inner edge (1: the survey's contrast), ``bubble``
    whether an air bubble was found at or ahead of the tip, ``train`` whether bright interiors in
    a row there (metal bands or a chain of bubbles, :data:`~tympani.vision.angles.bubbles.TRAIN`)
    leave it open where the array ends.
    """

    lo: int
    n: int
    fine: np.ndarray
    fluid: np.ndarray
    contrast: np.ndarray
    seed: np.ndarray
    v_in: np.ndarray
    v_out: np.ndarray
    ok_in: np.ndarray
    ok_out: np.ndarray
    core_in: np.ndarray
    core_out: np.ndarray
    level: float
    array_cover: float
    bubble: bool = False
    train: bool = False


def _crossing(cover: np.ndarray, j: np.ndarray, cols: np.ndarray, level: float | np.ndarray) -> np.ndarray:
    """Where the coverage crosses ``level`` between offsets ``j`` and ``j + 1`` (linear).

    Parameters
    ----------
    cover : ndarray, shape (m, n)
        Coverage, offsets × stations.
    j : ndarray, shape (k,), int
        Offset just before each crossing (``cover`` is on either side of ``level`` at ``j``
        and ``j + 1``).
    cols : ndarray, shape (k,), int
        Station of each crossing.
    level : float or ndarray, shape (k,)
        Crossing level (of each crossing).

    Returns
    -------
    ndarray, shape (k,)
        Fractional offset index.
    """
    c1, c2 = take2d(cover, j, cols), take2d(cover, j + 1, cols)
    d = c2 - c1
    t = (level - c1) / np.where(np.abs(d) < 1e-6, 1e-6, d)
    return j + np.minimum(np.maximum(t, 0.0), 1.0)


def _half_crossings(cover: np.ndarray, seed: np.ndarray, level: float | np.ndarray, run: np.ndarray | None = None,
                    wall: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel offsets where coverage falls below ``level`` either side of ``seed``, into the fluid.

    A lit array shows a bright stripe along its middle (a specular highlight on a round body),
    which can fall below the half level without being fluid. An edge is therefore only where the
    coverage then stays below the level for ``run`` offsets, or up to the wall margin: the fluid
    beside the array reaches the wall, a highlight inside it does not.

    Parameters
    ----------
    cover : ndarray, shape (m, n)
        Array coverage (0 fluid, 1 array), offsets × stations.
    seed : ndarray, shape (n,), int
        An offset inside the array at each station.
    level : float or ndarray, shape (n,)
        Crossing level (at each station).
    run : ndarray, shape (n,), optional
        Offsets the fluid must span at each station (default 1: the first crossing).
    wall : ndarray, shape (n,), optional
        First offset clear of the inner wall at each station (a run reaching it, or reaching the
        same margin from the outer wall, counts whatever its length; default 0).

    Returns
    -------
    low, high : ndarray, shape (n,)
        Fractional offset index (see :func:`_crossing`) of the nearest such crossing below and
        above ``seed`` at each station; NaN where there is none.
    """
    m, n = cover.shape
    j = np.arange(m, dtype=np.int16)[:, None]  # small integer types keep these passes fast
    s = seed.astype(np.int16)
    cols = np.arange(n)
    below = cover < level
    if run is not None:
        need = np.maximum(np.ceil(run), 1.0).astype(np.int16)[None, :]
        margin = np.floor(wall if wall is not None else np.zeros(n)).astype(np.int16)[None, :]
        # consecutive offsets below the level ending at j going down, and starting at j going up
        last_above = accumulate_rows(np.maximum, np.where(below, np.int16(-1), j))
        next_above = accumulate_rows(np.minimum, np.where(below, np.int16(m), j)[::-1])[::-1]
        down, up = j - last_above, next_above - j
        fluid_low = below & ((down >= need) | (last_above < margin))
        fluid_high = below & ((up >= need) | (next_above > np.int16(m - 1) - margin))
    else:
        fluid_low = fluid_high = below
    lo_idx = ((fluid_low & (j < s)) * (j + np.int16(1))).max(axis=0).astype(np.intp) - 1  # -1: none
    hi_idx = m - ((fluid_high & (j > s)) * (np.int16(m) - j)).max(axis=0).astype(np.intp)  # m: none
    both = np.full(2 * n, np.nan)  # low, then high
    j_both = np.concatenate([lo_idx, hi_idx - 1])
    ok = np.concatenate([lo_idx >= 0, hi_idx < m])
    levels = np.broadcast_to(np.asarray(level, dtype=float), (n,))
    both[ok] = _crossing(cover, j_both[ok], np.concatenate([cols, cols])[ok], np.concatenate([levels, levels])[ok])
    return both[:n], both[n:]


def _sample(cover: np.ndarray, pos: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Coverage at fractional offset indices ``pos`` (shape (r, n), linear interpolation) of
    stations ``cols`` (shape (n,))."""
    m = cover.shape[0]
    pos = np.minimum(np.maximum(pos, 0.0), m - 1.001)
    j = pos.astype(np.intp)
    f = pos - j
    return take2d(cover, j, cols) * (1 - f) + take2d(cover, j + 1, cols) * f


def _plateaus(
    cover: np.ndarray, edge: np.ndarray, valid: np.ndarray, px: np.ndarray, wall: np.ndarray,
    plateau_px: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Coverage of the fluid and of the array either side of a rising edge at each station.

    Parameters
    ----------
    cover : ndarray, shape (m, k)
        Coverage (0 fluid, 1 array), offsets × stations (``k >= len(edge)``).
    edge : ndarray, shape (n,)
        Fractional offset index of an edge where the coverage rises with the offset.
    valid : ndarray, shape (n,), bool
        Stations whose edge was measured.
    px : ndarray, shape (n,)
        Pixels per offset index at each station.
    wall : ndarray, shape (n,)
        Lowest offset index clear of the wall on the low side at each station.
    plateau_px : tuple of float
        Nearest and farthest distance (px) from the edge of the samples averaged.

    Returns
    -------
    c_fluid, c_array : ndarray, shape (n,)
        Mean coverage of three samples on the fluid side and on the array side.
    fluid_ok, array_ok : ndarray, shape (n,), bool
        Where they were measured (the fluid side clear of the wall; inside the strip).
    """
    m, n = cover.shape[0], len(edge)
    cols = np.arange(n)
    e = np.where(valid, edge, 0.0)
    near, far = plateau_px
    dist = np.array([near, 0.5 * (near + far), far])[:, None] / px[None, :]
    both = _sample(cover, np.concatenate([e - dist, e + dist]), cols)
    c_fluid, c_array = (both[0] + both[1] + both[2]) / 3.0, (both[3] + both[4] + both[5]) / 3.0
    return c_fluid, c_array, valid & (e - dist[2] >= wall), valid & (e + dist[2] <= m - 1)


def _relevel(cover: np.ndarray, edge: np.ndarray, valid: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Move rising edges to where the coverage crosses a per-station level nearby.

    Parameters
    ----------
    cover : ndarray, shape (m, k)
        Coverage, offsets × stations (``k >= len(edge)``).
    edge : ndarray, shape (n,)
        Fractional offset index of an edge where the coverage rises with the offset.
    valid : ndarray, shape (n,), bool
        Stations whose edge was measured.
    level : ndarray, shape (n,)
        Coverage at which each edge is to be located.

    Returns
    -------
    ndarray, shape (n,)
        Each edge at the first rising crossing of ``level`` among the ten samples around it
        (linear interpolation); unchanged where there is none.
    """
    m, n = cover.shape[0], len(edge)
    cols = np.arange(n)
    j0 = np.minimum(np.maximum(np.floor(np.where(valid, edge, 0.0)).astype(np.intp) - 4, 0), max(m - 10, 0))
    window = take2d(cover, j0[None, :] + np.arange(min(10, m))[:, None], cols)
    rising = (window[:-1] < level) & (window[1:] >= level)
    k = rising.argmax(axis=0)
    found = valid & rising.any(axis=0)
    a, b = take2d(window, k, cols), take2d(window, k + 1, cols)
    t = np.minimum(np.maximum((level - a) / np.where(np.abs(b - a) < 1e-6, 1e-6, b - a), 0.0), 1.0)
    return np.where(found, j0 + k + t, edge)


def _shelf_edges(cover: np.ndarray, cumulative: np.ndarray, seed: np.ndarray, low: np.ndarray, high: np.ndarray,
                 clear: np.ndarray, shelf_px: np.ndarray, cfg: MeasureConfig) -> tuple[np.ndarray, np.ndarray]:
    """The edges of a darker core inside the dark where a lighter shelf lies beside it, out to
    the dark's edge: the array's shadow beside it, or the lighter side of an array lit from one
    side (:func:`~tympani.vision.angles.centreline.centre_line_batch` tells the two apart by
    the array's width).

    The core ends where the coverage falls below ``cfg.core_share`` of the seed's. Beyond it,
    out to the dark's edge (``low``, ``high``; where none was found, the wall's margin
    ``clear``), lies the shelf: at least ``shelf_px`` offsets wide, its mean coverage at least
    ``cfg.shelf_min`` and at least ``cfg.shelf_step`` below the seed's. The core's edge is where
    the coverage crosses half way between the two, with no return above that level out to the
    dark's edge (a highlight along the array's middle has the array's other side beyond it).

    Parameters
    ----------
    cover : ndarray, shape (m, n)
        Coverage (0 fluid, 1 array), offsets × stations.
    cumulative : ndarray, shape (m + 1, n)
        Its running sums (:func:`_cumulative`).
    seed : ndarray, shape (n,), int
        The darkest offset at each station.
    low, high : ndarray, shape (n,)
        The dark's edges (fractional offset indices; NaN: none).
    clear : ndarray, shape (2, n)
        The first offset index clear of the inner wall and the last clear of the outer one.
    shelf_px : ndarray, shape (n,)
        Least width (offsets) of a shelf.
    cfg : MeasureConfig
        ``core_share``, ``shelf_min``, ``shelf_step``.

    Returns
    -------
    low, high : ndarray, shape (n,)
        The core's edges (fractional offset indices), NaN where no shelf lies beyond them.
    """
    m, n = cover.shape[0], len(seed)
    j = np.arange(m, dtype=np.float32)[:, None]
    peak = take2d(cover, seed, np.arange(n))
    cores = _half_crossings(cover, seed, cfg.core_share * peak)
    out = []
    for side, (edge, stop, sign) in enumerate(((low, clear[0], -1.0), (high, clear[1], 1.0))):
        core = cores[side]
        outer = np.where(np.isfinite(edge), edge, stop)
        shelf = _fill(cumulative, *((outer, core) if side == 0 else (core, outer)))
        at = np.flatnonzero((shelf >= cfg.shelf_min) & (peak - shelf >= cfg.shelf_step)
                            & (sign * (outer - core) >= shelf_px))
        found = np.full(n, np.nan)
        if len(at):  # the stations with a shelf only (few, as a rule)
            sub, level = cover[:, at], 0.5 * (peak[at] + shelf[at])
            core_edge = _half_crossings(sub, seed[at], level)[side]
            # out to the dark's edge the coverage stays below that level (a highlight does not)
            lo, hi = (outer[at], core_edge - 0.5) if side == 0 else (core_edge + 0.5, outer[at])
            between = (j > np.nan_to_num(lo, nan=np.inf)[None, :]) & (j < np.nan_to_num(hi, nan=-np.inf)[None, :])
            keep = np.isfinite(core_edge) & ~(between & (sub >= level[None, :])).any(axis=0)
            found[at[keep]] = core_edge[keep]
        out.append(found)
    return out[0], out[1]


def _cumulative(cover: np.ndarray, n: int) -> np.ndarray:
    """Running sums of the coverage of the first ``n`` stations along the offsets, shape
    (m + 1, n), a row of zeros first (for :func:`_fill`)."""
    cs = np.zeros((cover.shape[0] + 1, n))
    cs[1:] = accumulate_rows(np.add, cover[:, :n])
    return cs


def _fill(cumulative: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Mean coverage between the edges ``low`` and ``high`` (fractional offset indices) at each
    station (NaN where an edge is missing), from the running sums ``cumulative``
    (:func:`_cumulative`)."""
    m, n = cumulative.shape[0] - 1, len(low)
    ok = np.isfinite(low) & np.isfinite(high)
    a = np.clip(np.where(ok, np.ceil(low), 0), 0, m - 1).astype(np.intp)
    b = np.clip(np.where(ok, np.floor(high), 0), 0, m - 1).astype(np.intp)
    ok &= b >= a
    cols = np.arange(n)
    mean = (take2d(cumulative, b + 1, cols) - take2d(cumulative, a, cols)) / np.maximum(b - a + 1, 1)
    return np.where(ok, mean, np.nan)


def _unfilled(fill: np.ndarray, body: np.ndarray, arr: Ragged, least: float) -> np.ndarray:
    """Per frame of ``arr``, whether the array's body is not mostly dark between its edges: the
    median (:func:`~tympani.vision.angles.arrays.quantile`) of ``fill`` over the ``body``
    stations is below ``least`` (a highlight along the middle of a round array takes a third
    of it at most; the grain of noise or of compression fills half). False for a frame with
    no body station."""
    keep = body & np.isfinite(fill)
    median = row_quantiles(arr.pad(fill, 0.0), arr.pad(keep, False), 0.5)
    return ~(np.isnan(median) | (median >= least))


def _fluid_run(plan: MeasurePlan, px: np.ndarray) -> np.ndarray:
    """Offsets (per station, ``px`` px each) the fluid beside an edge must span: a share
    (:attr:`MeasureConfig.fluid_run`) of the array's tip diameter, at least 2 px."""
    ppm = float(plan.pose.px_per_mm)
    return np.maximum(plan.cfg.fluid_run * 2.0 * plan.r_tip_mm * ppm, 2.0) / px


def edges_batch(imgs: list[np.ndarray], plan: MeasurePlan, surveys: list[Survey]) -> list[Edges]:
    """Stage 2: the array's inner and outer edge at each station that holds it, in each frame
    (with its survey; see :mod:`tympani.vision.angles`)."""
    cfg, step, ppm = plan.cfg, plan.step_mm, float(plan.pose.px_per_mm)
    sa, n_all = max(1, int(cfg.coarse_stride)), len(plan.p_mm)
    span = max(4, int(np.ceil(0.4 / step)))
    u0, du = float(plan.u[0]), float(plan.u[1] - plan.u[0])
    # the fine strips, laid end to end
    tips = np.array([sv.tip_est for sv in surveys], dtype=np.intp)
    body = int(np.ceil(cfg.min_body_mm / step))  # the stations basal of the tip the centre line needs
    lo = np.maximum(np.minimum(tips - body, plan.i_start), 0)
    hi0 = np.minimum(tips + sa + span + 1, n_all)  # where the tip is sought
    hi = np.minimum(hi0 + int(np.ceil((2.0 * cfg.bubble_max_mm + 0.3) / step)), n_all)  # and a bubble beyond
    fines = [cv2.remap(img, plan.map_x[:, a:b], plan.map_y[:, a:b], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
             for img, a, b in zip(imgs, lo.tolist(), hi.tolist())]
    strip = Ragged.of(hi - lo)
    station = lo[strip.row] + strip.local
    fluid_c = np.stack([sv.fluid_c for sv in surveys])
    fluid = interp_ragged(station, strip.row, sa * np.arange(fluid_c.shape[1]), fluid_c)
    contrast = fluid * (1.0 - np.array([sv.rho for sv in surveys])[strip.row])
    blurred = np.concatenate([cv2.blur(f, (3, 1)) for f in fines], axis=1)
    scale, shift = -1.0 / contrast, fluid / contrast  # coverage = blurred * scale + shift
    seed_c = np.stack([sv.seed_c for sv in surveys])
    seed = np.minimum(sa * take2d(seed_c, strip.row, station // sa), len(plan.u) - 1)
    # the coverage of every sample, once for the windows, the bubbles and the edges (float64; the
    # blurred levels are exact in it)
    coverage = blurred * scale
    coverage += shift
    at_seed = take2d(coverage, seed, np.arange(len(station)))
    darkness = np.where(np.take(plan.in_view, station), at_seed, 0.0)
    first_n = np.minimum(tips + sa, hi - 1) - lo + 1  # stations where the array's dark end is sought
    last_dark = strip.last((darkness >= cfg.dark_level) & (strip.local < first_n[strip.row]))
    extent = hi0 - lo
    back = int(np.ceil((2.0 * cfg.bubble_max_mm + cfg.max_gap_mm + cfg.bubble_track_mm) / step))
    inner = np.abs(plan.u)
    # an air bubble at or ahead of the tip: each frame's window from `back` before its dark end,
    # its bright pixels (coverage, blurred * scale + shift, up to cfg.bubble_bright) clear of the walls
    windows = []
    bubble = np.zeros(len(surveys), dtype=bool)
    train = np.zeros(len(surveys), dtype=bool)
    half_median: dict[tuple[int, int], float] = {}  # frames with the same window share its median
    for b in np.flatnonzero(last_dark >= 0).tolist():
        end, a = int(last_dark[b]), max(int(last_dark[b]) - back, 0)
        cols = slice(int(strip.start[b]) + a, int(strip.start[b] + strip.n[b]))
        span_b = (int(lo[b]) + a, int(lo[b] + strip.n[b]))
        if span_b not in half_median:
            half_median[span_b] = median(plan.half_mm[span_b[0] : span_b[1]])
        half_b = half_median[span_b]
        windows.append((b, end, a, cols, half_b, inner <= 1.0 - cfg.wall_margin_px / (half_b * ppm)))
    candidates = with_compact([(coverage[:, cols] <= cfg.bubble_bright) & i[:, None]
                               for *_, cols, _, i in windows], step,
                               np.array([du * w[4] for w in windows]), cfg)
    for (b, end, a, cols, half_b, inside_b), candidate in zip(windows, candidates.tolist()):
        if not candidate:  # no bubble-like component in the window: bubble_end would find none
            continue
        cut, stop = bubble_end(coverage[:, cols], darkness[cols] >= cfg.dark_level,
                               seed[cols], inside_b, end - a, step, du * half_b, 2.0 * plan.r_tip_mm, cfg)
        if stop == TRAIN:
            train[b] = True
        elif stop is not None:
            last_dark[b], extent[b] = max(cut + a, 0), stop + a
            bubble[b] = True
    # the stations that hold the array
    arr = Ragged.of(np.where(last_dark >= 0, last_dark + 1, tips - lo + 1))
    take = strip.start[arr.row] + arr.local
    cover = np.take(coverage, take, axis=1)
    seed_a, dark_a = np.take(seed, take), np.take(darkness, take)
    half = np.take(plan.half_mm, lo[arr.row] + arr.local)
    px = du * half * ppm  # px per offset index at each station
    wall = (-1.0 + cfg.wall_margin_px / (half * ppm) - u0) / du  # first offset clear of the inner wall
    # the edges
    low, high = _half_crossings(cover, seed_a, cfg.edge_level, _fluid_run(plan, px), wall)
    body = erode_ragged(dark_a >= cfg.body_level, arr, cfg.border_px)
    c_fluid, c_array, fluid_ok, array_ok = _plateaus(cover, low, body & np.isfinite(low), px, wall, cfg.plateau_px)
    c_f = np.where(arr.count(fluid_ok) >= 10, row_quantiles(arr.pad(c_fluid, 0.0), arr.pad(fluid_ok, False), 0.5), 0.0)
    c_a = np.where(arr.count(array_ok) >= 10, row_quantiles(arr.pad(c_array, 0.0), arr.pad(array_ok, False), 0.5), 1.0)
    implausible = c_a - c_f < 0.3  # keep the global levels
    c_f, c_a = np.where(implausible, 0.0, c_f), np.where(implausible, 1.0, c_a)
    level = (0.5 * (c_f + c_a))[arr.row]
    window = odd_ceil(2.0 * cfg.gap_smooth_mm / step)
    local = np.flatnonzero(arr.count(fluid_ok) >= 3)
    if len(local):  # where the fluid shows clear of the wall, the local levels
        sub, part = arr.subset(local)
        ok = fluid_ok[sub]
        (lf, la), _ = smooth_ragged(np.vstack([c_fluid[sub], c_array[sub]]), ok, part, window)
        near = np.zeros(len(level), dtype=bool)
        near[sub] = near_ragged(ok, part, window)
        smooth = np.zeros(len(level))
        smooth[sub] = 0.5 * (lf + la)
        level = np.where(near, smooth, level)
    low = _relevel(cover, low, np.isfinite(low), level)
    clear = np.vstack([wall, 2.0 * (-u0 / du) - wall])  # the margins clear of either wall (offsets)
    cumulative = _cumulative(cover, len(low))
    core_low, core_high = _shelf_edges(cover, cumulative, seed_a, low, high, clear,
                                       np.maximum(2.0, cfg.shelf_mm * ppm) / px, cfg)
    cf, ca = c_f[arr.row], c_a[arr.row]
    body = erode_ragged((dark_a - cf) / (ca - cf) >= cfg.body_level, arr, cfg.border_px)
    v_in, v_out = (u0 + du * low) * half, (u0 + du * high) * half
    core_in, core_out = (u0 + du * core_low) * half, (u0 + du * core_high) * half
    fill = _fill(cumulative, low, high)
    body &= ~_unfilled(fill, body, arr, cfg.body_fill)[arr.row]  # not dark between its edges: no array
    ok_in, ok_out = body & (v_in >= -half), body & (v_out <= half)  # NaN compares False
    out = []
    for b, (s0, w, s, m) in enumerate(zip(strip.start.tolist(), extent.tolist(), arr.start.tolist(), arr.n.tolist())):
        a = slice(s, s + m)
        out.append(Edges(int(lo[b]), m, fines[b][:, :w], fluid[s0 : s0 + w], contrast[s0 : s0 + w], seed[s0 : s0 + w],
                          v_in[a], v_out[a], ok_in[a], ok_out[a], core_in[a], core_out[a],
                          0.5 * (float(c_f[b]) + float(c_a[b])), float(c_a[b]), bool(bubble[b]),
                          bool(train[b])))
    return out

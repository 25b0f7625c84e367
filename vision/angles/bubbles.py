"""Air bubbles at or ahead of the array's tip: where they end the array's dark run.

A bubble's rim is as dark as the array, so the survey's dark run goes on past the tip into it;
its interior is a compact bright region enclosed on all sides (:func:`with_compact` finds the
frames that may have one, :func:`bubble_end` where the array ends before it).
"""

from __future__ import annotations

import cv2
import numpy as np

from tympani.vision.angles.config import MeasureConfig


def _dark_runs(dark: np.ndarray) -> np.ndarray:
    """Per row of ``dark`` (rows, n), the length of the run of True ending at each entry (0 where
    False)."""
    at = np.arange(dark.shape[1])[None, :]
    last_false = np.maximum.accumulate(np.where(dark, -1, at), axis=1)
    return np.where(dark, at - last_false, 0)


def _dark_beyond(path: np.ndarray, skip: int) -> int:
    """Length (stations) of the dark stretch of ``path`` (bool, from just beyond a bright
    component on) that starts within its first ``skip`` stations: the rim beyond a bubble's
    interior, or the array's body beyond a band, whose lighter border can outlast the bright
    component itself; 0 when none starts there."""
    if not path[:skip].any():
        return 0
    first = int(np.argmax(path))
    return int(np.argmin(np.append(path[first:], False)))


def _compact(x: np.ndarray, y: np.ndarray, w: np.ndarray, h: np.ndarray, area: np.ndarray, m: int,
             n: np.ndarray | int, step_mm: float, offset_mm: np.ndarray | float, cfg: MeasureConfig) -> np.ndarray:
    """Which bright components could be a bubble's interior: enclosed in their window (``m``
    offsets × ``n`` stations; not touching its border), of a bubble's size, fill and aspect.

    Parameters
    ----------
    x, y, w, h, area : ndarray of int
        Bounding boxes (station, offset) and pixel counts of the components, in their window.
    m : int
        Offsets of the windows.
    n : ndarray of int or int
        Stations of each component's window.
    step_mm : float
        Station spacing (mm).
    offset_mm : ndarray or float
        Offset spacing (mm) of each component's window.
    cfg : MeasureConfig
        ``bubble_*`` settings.

    Returns
    -------
    ndarray of bool
    """
    len_mm, wid_mm = w * step_mm, h * offset_mm
    return ((x > 0) & (x + w < n) & (y > 0) & (y + h < m) & (area * (step_mm * offset_mm) >= cfg.bubble_min_mm2)
            & (np.maximum(len_mm, wid_mm) <= 2.0 * cfg.bubble_max_mm)
            & (area >= cfg.bubble_fill[0] * w * h)
            & ((area <= cfg.bubble_fill[1] * w * h) | (np.minimum(w, h) < cfg.bubble_round_px))
            & (len_mm <= cfg.bubble_aspect * wid_mm) & (wid_mm <= cfg.bubble_aspect * len_mm))


def with_compact(brights: list[np.ndarray], step_mm: float, offset_mm: np.ndarray, cfg: MeasureConfig) -> np.ndarray:
    """Which of the windows ``brights`` (each offsets × stations, bool) hold a :func:`_compact`
    component: all windows labelled in one call, side by side with an empty column between.

    Parameters
    ----------
    brights : list of ndarray of bool
        Each frame's bright pixels (same number of rows).
    step_mm : float
        Station spacing (mm).
    offset_mm : ndarray
        Offset spacing (mm) of each window.
    cfg : MeasureConfig
        ``bubble_*`` settings.

    Returns
    -------
    ndarray of bool, shape (len(brights),)
    """
    out = np.zeros(len(brights), bool)
    if not brights:
        return out
    m = brights[0].shape[0]
    widths = np.array([b.shape[1] for b in brights])
    starts = np.concatenate([[0], np.cumsum(widths + 1)[:-1]])
    canvas = np.zeros((m, int(starts[-1] + widths[-1])), np.uint8)
    for s0, b in zip(starts.tolist(), brights):
        canvas[:, s0: s0 + b.shape[1]] = b
    _, _, stats, _ = cv2.connectedComponentsWithStats(canvas, connectivity=4)
    x, y, w, h, area = (stats[1:, k] for k in range(5))
    f = np.searchsorted(starts, x, side="right") - 1
    compact = _compact(x - starts[f], y, w, h, area, m, widths[f], step_mm, offset_mm[f], cfg)
    out[f[compact]] = True
    return out


def _chain_start(k: int, far: int, x: np.ndarray, w: np.ndarray, y: np.ndarray, h: np.ndarray,
                 compact: np.ndarray, reach: float) -> tuple[int, int]:
    """The first bubble of a chain that ends with bubble ``k``, and the thickness (stations) of
    the rim beyond its interior.

    Bubbles touching one another show two rims between their interiors; a bubble-like
    interior (:func:`_compact`) that ends no more than ``reach`` stations before the next
    bubble's begins, across the same offsets, is one more bubble of the chain, where a band
    would have the array's body, longer than two rims, between it and a bubble ahead of the
    tip. Its own rim is taken as half the dark stretch between the two.

    Parameters
    ----------
    k : int
        A bubble's interior (component).
    far : int
        Thickness (stations) of the rim beyond its interior.
    x, w, y, h : ndarray of int
        Bounding boxes (first station, stations, first offset, offsets) of all components.
    compact : ndarray of bool
        Which components could be a bubble's interior.
    reach : float
        Longest dark stretch (stations) between two interiors of a chain.
    """
    while True:
        gap = x[k] - (x + w)
        prev = np.flatnonzero(compact & (gap >= 0) & (gap <= reach) & (y < y[k] + h[k]) & (y[k] < y + h))
        if not len(prev):
            return k, far
        j = int(prev[np.argmin(gap[prev])])
        k, far = j, int(gap[j]) // 2


def _repeats_bands(k: int, x: np.ndarray, w: np.ndarray, y: np.ndarray, h: np.ndarray, compact: np.ndarray,
                   size_tol: float, pitch_tol: float, reach: float) -> bool:
    """Whether the bright interior ``k`` repeats the two before it on the same track: of their
    size and at their pitch, with more than two rims' dark between them (the array's body), as
    the array's metal bands are (a bubble is not; a chain of bubbles touching one another has
    only their rims between them).

    Parameters
    ----------
    k : int
        A bubble-like interior (component).
    x, w, y, h : ndarray of int
        Bounding boxes (first station, stations, first offset, offsets) of all components.
    compact : ndarray of bool
        Which components could be a bubble's interior (a band enclosed by the array's edges is).
    size_tol, pitch_tol : float
        Largest relative difference (dimensionless) in length and width, and in pitch.
    reach : float
        Longest dark stretch (stations) between two interiors of a chain of bubbles.
    """
    prev = np.flatnonzero(compact & (x + w <= x[k]) & (y < y[k] + h[k]) & (y[k] < y + h))
    if len(prev) < 2:
        return False
    j1, j2 = prev[np.argsort(x[prev])[-2:][::-1]]
    like = all(abs(int(a[j]) - int(a[k])) <= max(2.0, size_tol * a[k]) for j in (j1, j2) for a in (w, h))
    p1, p2 = x[k] - x[j1], x[j1] - x[j2]
    apart = x[k] - (x[j1] + w[j1]) > reach and x[j1] - (x[j2] + w[j2]) > reach
    return bool(like and apart and abs(p1 - p2) <= pitch_tol * max(p1, p2))


def _in_train(k: int, x: np.ndarray, w: np.ndarray, y: np.ndarray, h: np.ndarray, compact: np.ndarray,
              size_tol: float, pitch_tol: float) -> bool:
    """Whether the bright interior ``k`` is one of three in a row on its track (before it, after
    it or both) of one size and at one pitch, whatever lies between them: a train of metal bands
    with little body between, or a chain of equal bubbles; nothing in the window tells which.

    Parameters
    ----------
    k : int
        A bubble-like interior (component).
    x, w, y, h : ndarray of int
        Bounding boxes (first station, stations, first offset, offsets) of all components.
    compact : ndarray of bool
        Which components could be a bubble's interior.
    size_tol, pitch_tol : float
        Largest relative difference (dimensionless) in length and width, and in pitch.
    """
    like = compact & (y < y[k] + h[k]) & (y[k] < y + h)
    for a in (w, h):
        like &= np.abs(a.astype(int) - int(a[k])) <= np.maximum(2.0, size_tol * a[k])
    row = np.flatnonzero(like)
    row = row[np.argsort(x[row])]
    at = int(np.flatnonzero(row == k)[0])
    for first in range(max(at - 2, 0), min(at, len(row) - 3) + 1):
        a, b, c = (int(x[j]) for j in row[first : first + 3])
        p1, p2 = b - a, c - b
        if min(p1, p2) > 0 and abs(p1 - p2) <= pitch_tol * max(p1, p2):
            return True
    return False


# What :func:`bubble_end` gives as ``stop`` where the bubble-like interiors on the array's path
# are three or more in a row, of one size and at one pitch (:func:`_in_train`).
TRAIN = -1


# How far (times the array's diameter) the array's track may pass beside a bubble's interior and
# still push it: an array riding a wall meets a bubble pushed off towards the channel's middle.
_TRACK_MARGIN = 0.125
# Coverage (0 fluid, 1 array) within which a station shows plain fluid: neither the array's
# body nor a metal band (brighter than the fluid: negative coverage).
_FLUID_COVER = 0.25
# Farthest (coverage) the fluid's own level beside the array may lie from the survey's fluid
# level (uneven light, a soft shadow) for plain fluid to be told by it.
_FLUID_SHIFT = 0.5
# How far (mm) before a bubble's near rim fluid is sought: past the rim's blurred border.
_GAP_WINDOW_MM = 0.25
# How alike (relative difference in length and width, and in pitch) a bright interior must be
# to the two before it on the array's track to be one more of its metal bands.
_BAND_SIZE_TOL = 0.25
_BAND_PITCH_TOL = 0.2


def _fluid_before_rim(lane: np.ndarray, dark: np.ndarray, base: np.ndarray, step_mm: float,
                      cfg: MeasureConfig) -> bool:
    """Whether plain fluid lies on the array's path (``lane``, its offsets' coverage up to a
    bubble-like interior, and ``dark``, where it is dark) before a dark stretch no thicker than
    two rims that ends at the interior, over at least ``cfg.bubble_gap_mm``: a bubble's near rim
    with fluid before it. Plain fluid is coverage within ``_FLUID_COVER`` of the fluid's own at
    that station (``base``, the channel's lighter offsets: lit unevenly, the fluid need not be
    at the survey's level). A metal band has the array's body before it, or another band
    (brighter than the fluid) and a short body."""
    if len(dark) == 0:
        return False
    rim = int(np.argmin(dark[::-1])) if not dark.all() else len(dark)  # the dark stretch ending at it
    if rim * step_mm > 2.0 * cfg.bubble_rim_mm:
        return False
    before = lane[:, : len(dark) - rim][:, -int(np.ceil(_GAP_WINDOW_MM / step_mm)):]
    base = base[: len(dark) - rim][-before.shape[1]:]
    fluid = (np.abs(before - base).max(axis=0) < _FLUID_COVER) & (np.abs(base) < _FLUID_SHIFT)
    return bool(fluid.sum() >= max(2, int(np.ceil(cfg.bubble_gap_mm / step_mm))))


def bubble_end(cover: np.ndarray, dark: np.ndarray, seed: np.ndarray, inside: np.ndarray, end: int,
                step_mm: float, offset_mm: float, diameter_mm: float, cfg: MeasureConfig) -> tuple[int, int | None]:
    """Where the array ends when an air bubble sits at or ahead of its tip.

    A bubble shows as a bright interior inside a closed dark rim. Along the channel its rim reads
    as more array (the rim is as dark as the array, and its interior no longer than a band) and
    across the channel the darkest offset jumps to the rim, so the dark run goes on past the tip.
    Its interior, unlike the fluid beyond the tip, is a bright region enclosed on all sides: a
    compact, round component of the bright pixels of the channel's interior. A metal band can be
    enclosed too (by the array's shaded edges) but is a rectangle no wider than the array, with
    the array's body beyond it; a bubble's interior is round and either wider than the array or
    followed, along the array's path, by no more than a thin rim. Bubbles touching in a chain
    show only two rims between their interiors, so a band-like interior that ends that close
    before a bubble's is a bubble too (:func:`_chain_start`). A bubble lies on the array's path
    where its interior reaches to within an eighth of the array's diameter of the array's track
    (the median darkest offset just before it): an array riding a wall pushes a bubble towards
    the channel's middle. An interior of the size of the two before it on the track and at
    their pitch is one more band (:func:`_repeats_bands`), however thin the cap beyond it: the
    array's last band may lie right at its tip. The array ends before the first
    bubble on its path, less the rim's thickness (that of the rim beyond the interior): at the
    last dark station before it.

    Parameters
    ----------
    cover : ndarray, shape (offsets, stations)
        Coverage (0 fluid, 1 array) of one frame's fine strip from some stations basal of the
        dark end on.
    dark : ndarray, shape (stations,), bool
        Stations dark at their darkest offset.
    seed : ndarray, shape (stations,), int
        Each station's darkest offset.
    inside : ndarray, shape (offsets,), bool
        Offsets clear of the walls.
    end : int
        The dark run's last station (index into the window).
    step_mm, offset_mm : float
        Station and offset spacing (mm).
    diameter_mm : float
        The array's diameter (mm) near its tip.
    cfg : MeasureConfig
        ``bubble_*`` settings.

    Returns
    -------
    end : int
        The array's last station (``end`` when no bubble is on its path; -1 when none is left).
    stop : int or None
        The first station of the bubble's rim (the tip lies before it), or None; :data:`TRAIN`
        where the first bubble-like interior on the array's path is one of three or more in a
        row of one size and at one pitch: metal bands with little body between them, or a chain
        of equal bubbles, which the window cannot tell apart.
    """
    bright = ((cover <= cfg.bubble_bright) & inside[:, None]).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(bright, connectivity=4)
    m, n = cover.shape
    x, y, w, h, area = (stats[1:, k] for k in range(5))
    wid_mm = h * offset_mm
    compact = _compact(x, y, w, h, area, m, n, step_mm, offset_mm, cfg)
    margin = _TRACK_MARGIN * diameter_mm / offset_mm  # rows
    chain = cfg.bubble_chain * cfg.bubble_rim_mm / step_mm  # stations: two rims between bubbles of a chain
    # the fluid's coverage at each station, beside the array: darker than the survey's level
    # (a shadow, uneven light), never brighter (brighter than the fluid is a metal band's sign)
    base = np.maximum(np.quantile(cover[inside], 0.25, axis=0), 0.0)
    for k in np.flatnonzero(compact)[np.argsort(x[compact])].tolist():
        before = np.flatnonzero(dark[: x[k]])
        if len(before) == 0 or x[k] > end + 1 + int(np.ceil(cfg.max_gap_mm / step_mm)):
            continue
        track = np.median(seed[before[-int(np.ceil(cfg.bubble_track_mm / step_mm)):]])
        if not (y[k] - margin <= track < y[k] + h[k] + margin):  # beside the array's path, not on it
            continue
        reach = max(int(round(0.25 * diameter_mm / offset_mm)), 0)  # rows within a quarter diameter of it
        rows = slice(max(int(round(track)) - reach, 0), int(round(track)) + reach + 1)
        path = cover[rows].max(axis=0) >= cfg.dark_level  # dark on the array's path
        far = _dark_beyond(path[x[k] + w[k]:], max(2, int(np.ceil(0.5 * cfg.bubble_rim_mm / step_mm))))
        narrow = wid_mm[k] < cfg.bubble_wider * diameter_mm  # no wider than a band
        if (narrow and far * step_mm > cfg.bubble_rim_mm
                and not _fluid_before_rim(cover[rows, : x[k]], path[: x[k]], base[: x[k]], step_mm, cfg)):
            continue  # as narrow as a band, with array before and beyond it
        if narrow and _repeats_bands(k, x, w, y, h, compact, _BAND_SIZE_TOL, _BAND_PITCH_TOL, chain):
            continue  # a band like the two before it, however thin the cap beyond
        if _in_train(k, x, w, y, h, compact, _BAND_SIZE_TOL, _BAND_PITCH_TOL):
            return end, TRAIN  # bands with little body between, or a chain of equal bubbles
        k, far = _chain_start(k, far, x, w, y, h, compact, chain)
        # the rim before it, and any array it touches: the longest dark run that ends where the
        # interior begins, over the interior's rows
        inner = labels[y[k] : y[k] + h[k]] == k + 1
        first = np.argmax(inner, axis=1)
        run = _dark_runs(cover[y[k] : y[k] + h[k]] >= cfg.dark_level)
        near = int(np.max(np.where(first > 0, run[np.arange(h[k]), np.maximum(first - 1, 0)], 0)))
        if near * step_mm <= cfg.bubble_rim_mm and x[k] - near > 0:  # fluid before the rim: the array ends there
            stop = int(x[k]) - near
            last = np.flatnonzero(path[:stop] & dark[:stop])
        else:  # the rim touches the array: take as much off as the rim beyond the interior is
            # thick (no more than a rim: beyond it may lie more dark, a line along a wall)
            stop = max(int(x[k]) - min(far, int(np.ceil(cfg.bubble_rim_mm / step_mm))), 0)
            last = np.flatnonzero(dark[:stop])
        return (min(int(last[-1]), end) if len(last) else -1), stop
    return end, None

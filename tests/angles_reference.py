"""Per-frame versions of the measurement's batch helpers (tympani.vision.angles): the references
tests/test_angles_batch.py checks the batch helpers against, frame by frame.

Each function takes one frame's stations. Batch counterparts: :func:`fluid_level` and
:func:`array_ratio` and :func:`run_resumes` of ``survey._fluid_levels``, ``survey._array_ratios``
and ``survey._run_resumes`` (frames stacked along a leading axis); :func:`smooth_valid`, :func:`near`, :func:`running_median`,
:func:`extrapolate`, :func:`tip_crossing` and :func:`distance_from_tip` of the ``*_ragged``
functions of :mod:`tympani.vision.angles.ragged` (frames' stations laid end to end).
"""

from __future__ import annotations

import cv2
import numpy as np

from tympani.vision.angles.arrays import quantile
from tympani.vision.angles.ragged import running_moments, window_line


def fluid_level(
    brightest: np.ndarray, in_view: np.ndarray, block: int, percentile: float, reach: int, floor: float
) -> np.ndarray:
    """The fluid's grey level along the channel.

    Parameters
    ----------
    brightest : ndarray, shape (n,)
        Brightest interior value (grey levels) at each station.
    in_view : ndarray, shape (n,), bool
        Stations inside the image.
    block : int
        Length (stations) of the blocks whose percentile is taken.
    percentile : float
        Percentile (0–100).
    reach : int
        How many blocks either side a block is compared with.
    floor : float
        A block whose level is below this fraction of the brightest block level within
        ``reach`` is taken to be filled by the array and replaced from its neighbours.

    Returns
    -------
    ndarray, shape (n,)
        A low percentile of ``brightest`` in consecutive blocks (blocks filled by the array
        interpolated from the others), the median of each block and its two neighbours,
        interpolated between block centres. It ignores the array where fluid shows beside it,
        metal bands brighter than the fluid (a minority of any block) and stations out of view.
    """
    n = len(brightest)
    good = np.flatnonzero(in_view)
    if len(good) == 0:
        return np.ones(n)
    values = brightest if len(good) == n else np.interp(np.arange(n), good, brightest[good])
    block = max(1, min(int(block), n))
    n_blocks = n // block
    blocks = values[: n_blocks * block].reshape(n_blocks, block)
    q = int(round(percentile / 100.0 * (block - 1)))
    level = np.partition(blocks, q, axis=1)[:, q]
    centres = block * np.arange(n_blocks) + 0.5 * (block - 1)
    # running maximum (scipy.ndimage.maximum_filter1d(mode="nearest") at a fraction of its cost)
    envelope = cv2.dilate(level[None, :], np.ones((1, 2 * reach + 1), np.uint8), borderType=cv2.BORDER_REPLICATE)[0]
    fluid_like = level >= floor * envelope
    if not fluid_like.all() and fluid_like.any():
        level = np.interp(centres, centres[fluid_like], level[fluid_like])
    if n_blocks >= 3:
        a, b, c = np.concatenate([level[:1], level[:-1]]), level, np.concatenate([level[1:], level[-1:]])
        level = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))  # median of three
    return np.maximum(np.interp(np.arange(n), centres, level), 1.0)


def array_ratio(
    darkest: np.ndarray,
    brightest: np.ndarray,
    steepest: np.ndarray,
    fluid: np.ndarray,
    in_view: np.ndarray,
    min_count: int,
) -> float:
    """The array's grey level as a fraction of the fluid's, or NaN where it is not seen.

    Parameters
    ----------
    darkest, brightest : ndarray, shape (n,)
        Darkest and brightest interior value (grey levels) at each station.
    steepest : ndarray, shape (n,)
        Largest change (grey levels) between neighbouring interior samples across the channel.
    fluid : ndarray, shape (n,)
        Estimated fluid level (grey levels) at each station.
    in_view : ndarray, shape (n,), bool
        Stations inside the image.
    min_count : int
        Fewest stations that must show both.

    Returns
    -------
    float
        A low quantile (0.3) of darkest / brightest over stations where the array shows
        beside the fluid (brightest near the fluid level, darkest below 0.88 of it, an edge
        steeper than 5 % of it between neighbouring samples, and so at the station either side
        and, unless a metal band brighter than the fluid lies there, at the next ones): a ratio
        taken side by side, so uneven lighting cancels; stations only partly covered (band
        borders, the tip) raise it, hence not the median.
        NaN when fewer than ``min_count`` stations show both: a dim channel (vignetting) is
        not taken for an array filling it.
    """
    ratio = darkest / np.maximum(brightest, 1.0)
    beside = in_view & (ratio < 0.88) & (np.abs(brightest / fluid - 1.0) < 0.15) & (steepest > 0.05 * brightest)
    near = beside | (in_view & (brightest > 1.15 * fluid))  # or a metal band
    beside[2:-2] &= beside[1:-3] & beside[3:-1] & near[:-4] & near[4:]  # not at band borders
    if beside.sum() < max(min_count, 3):
        return float("nan")
    return quantile(ratio[beside], 0.3)


def smooth_valid(
    values: np.ndarray, valid: np.ndarray, size: int, slope_size: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Local straight-line smoothing of profiles measured only at some stations.

    Parameters
    ----------
    values : ndarray, shape (k, n)
        ``k`` profiles (any unit) along ``n`` stations; only ``valid`` stations are used.
    valid : ndarray, shape (n,), bool
        Stations where ``values`` were measured (at least one).
    size : int
        Window (stations) of the local fits.
    slope_size : int, optional
        Window (stations) of the fits that give the slopes (default ``size``).

    Returns
    -------
    fit, slope : ndarray, shape (k, n)
        At each station, the value (and, over ``slope_size``, the slope in unit per station)
        of the least-squares line through the valid stations within the window (their mean,
        slope 0, where they are too few or too bunched for a slope: fewer than 3, or spread
        over fewer than about 5 stations); stations without any are interpolated linearly
        between the nearest that have (held constant beyond the ends). Unlike a running mean,
        a line is not biased by a trend at the ends of measured stretches (next to bands and
        the tip).
    """
    k, n = values.shape
    slope_size = size if slope_size is None else slope_size
    big = max(size, slope_size) // 2
    x = np.arange(n, dtype=float)
    csum = running_moments(values, valid, x, big)

    def sums(h: int) -> np.ndarray:  # over stations i-h .. i+h (clipped)
        return csum[:, big + h + 1 : big + h + 1 + n] - csum[:, big - h : big - h + n]

    fit, slope, have = window_line(sums(size // 2), k, x)
    if slope_size != size:
        slope = window_line(sums(slope_size // 2), k, x)[1]
    if not have.all():
        for row in fit:
            row[~have] = np.interp(x[~have], x[have], row[have])
    return fit, slope


def near(mask: np.ndarray, size: int) -> np.ndarray:
    """Where ``mask`` holds somewhere within the window of ``size`` (odd) stations centred on
    each station (clipped at the ends).

    Parameters
    ----------
    mask : ndarray, shape (n,), bool
    size : int
        Window length (stations, odd).

    Returns
    -------
    ndarray, shape (n,), bool
    """
    n, h = len(mask), int(size) // 2
    csum = np.zeros(n + 2 * h + 1, dtype=np.intp)
    np.cumsum(mask, out=csum[h + 1 : n + h + 1])
    csum[n + h + 1 :] = csum[n + h]
    return csum[2 * h + 1 :] > csum[: n]


def running_median(x: np.ndarray, size: int) -> np.ndarray:
    """Median of each window of ``size`` (odd) samples of ``x`` centred on it, the ends
    extended with the end values (``scipy.ndimage.median_filter(x, size, mode="nearest")``
    in a handful of NumPy calls).

    Parameters
    ----------
    x : ndarray, shape (m,)
        Samples (any unit).
    size : int
        Window length (samples, odd).

    Returns
    -------
    ndarray, shape (m,)
    """
    h = int(size) // 2
    idx = np.arange(-h, h + 1)[None, :] + np.arange(len(x))[:, None]
    np.minimum(np.maximum(idx, 0, out=idx), len(x) - 1, out=idx)  # np.clip costs more per call
    return np.partition(x[idx], h, axis=1)[:, h]


def extrapolate(stations: np.ndarray, values: np.ndarray, at: float, span: float) -> float:
    """Value at station ``at`` of a straight line fitted to the last ``span`` stations measured.

    Parameters
    ----------
    stations : ndarray, shape (k,)
        Stations (increasing) where ``values`` were measured.
    values : ndarray, shape (k,)
        Measured values (any unit).
    at : float
        Station (fractional) to evaluate the line at.
    span : float
        Length (stations) of the stretch fitted, ending at the last measured station.

    Returns
    -------
    float
        The line's value; the stretch's median when it holds fewer than 3 stations or spans
        less than a third of ``span``.
    """
    sel = stations >= stations[-1] - span
    r, v = stations[sel].astype(float), values[sel]
    if len(r) < 3 or r[-1] - r[0] < span / 3:
        return quantile(v, 0.5)
    rm, vm = r.sum() / len(r), v.sum() / len(v)  # = .mean(), with less overhead
    return float(vm + np.dot(r - rm, v - vm) / np.dot(r - rm, r - rm) * (at - rm))


def tip_crossing(cover_at: np.ndarray, level: float, fallback: float) -> float:
    """Fractional index where a coverage profile along the array last falls below ``level``.

    Parameters
    ----------
    cover_at : ndarray, shape (k,)
        Coverage (0 fluid, 1 array) along the channel at the array's centre line, basal first.
    level : float
        Crossing level.
    fallback : float
        Returned when the profile never falls below ``level``.

    Returns
    -------
    float
        Linear interpolation between the last station at or above ``level`` and the next.
    """
    above = cover_at >= level
    falls = np.flatnonzero(above[:-1] & ~above[1:])
    if len(falls) == 0:
        return fallback
    k = int(falls[-1])
    a, b = cover_at[k], cover_at[k + 1]
    return k + min(max(float((a - level) / max(a - b, 1e-6)), 0.0), 1.0)


def distance_from_tip(line: np.ndarray, tip_mm: np.ndarray, stations: np.ndarray, tip: float) -> np.ndarray:
    """Arc length (mm) from the tip along a centre line given basal station first.

    Parameters
    ----------
    line : ndarray, shape (n, 2)
        Centre-line point (mm) of each station, basal first.
    tip_mm : ndarray, shape (2,)
        The tip (mm), apical of the last station.
    stations : ndarray, shape (n,)
        Station indices.
    tip : float
        Fractional station of the tip; stations beyond it get 0.

    Returns
    -------
    ndarray, shape (n,)
    """
    d = np.diff(line, axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    s = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]]) + float(np.hypot(*(line[-1] - tip_mm)))
    return np.where(stations > tip, 0.0, s)


def run_resumes(dark: np.ndarray, band: np.ndarray, end: int, max_gap: float, reach: int, length: int) -> bool:
    """Whether a run of dark or band stations (``dark``, ``band``: shape (n,)), bridging gaps up
    to ``max_gap`` stations, starts within ``reach`` stations past ``end`` (−1: no run, False),
    goes on for ``length`` stations or more and holds two or more separate band stretches."""
    if end < 0:
        return False
    carry = dark | band
    starts_b = band.copy()
    starts_b[1:] &= ~band[:-1]
    e = end + 1
    at = np.flatnonzero(carry[e:])  # stations past the end
    if not len(at):
        return False
    breaks = np.flatnonzero(np.diff(at) - 1 > max_gap)
    first, last = at[np.r_[0, breaks + 1]], at[np.r_[breaks, len(at) - 1]]
    count = np.concatenate([[0], np.cumsum(starts_b[e:])])
    bands = count[last + 1] - count[first]
    return bool(np.any((first < reach) & (last - first >= length) & (bands >= 2)))

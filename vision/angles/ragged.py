"""Frames' stations laid end to end (:class:`Ragged`), and the batch helpers that work on them.

Stages 2-4 of B frames run in lock-step (:func:`~tympani.vision.angles.measure_frames_batch`).
The frames' stations are laid end to end on one axis (a :class:`Ragged` batch), so each step is
one NumPy call for all frames: station-wise arithmetic as it is; windows (erosion, nearness,
running medians) clipped at each frame's ends; per-frame statistics (medians, counts, last
stations, the tip) from the frames padded to a common length; the local line fits
(:func:`smooth_ragged`), whose windows must stop at each frame's last station, from running sums
over all frames' stations with each window clipped to its frame, which leaves every frame's
sums of weights and positions, and so which stations get a fit, exactly what they are alone.
A frame's results do not depend on the others in its batch (to rounding: a few sums add in
another order). The row-wise helpers (:func:`fill_rows`, :func:`interp_rows`,
:func:`row_quantiles`) do the same for frames stacked along a leading axis (stage 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np


@dataclass(frozen=True, eq=False)
class Ragged:
    """Frames' stations laid end to end on one axis.

    Frame ``b`` holds positions ``start[b] .. start[b] + n[b] - 1``; ``row`` and ``local`` give
    each position's frame and its station in that frame. Every frame holds at least one.
    """

    n: np.ndarray
    start: np.ndarray
    row: np.ndarray
    local: np.ndarray

    @classmethod
    def of(cls, lengths: np.ndarray | list[int]) -> "Ragged":
        """The layout of frames of ``lengths`` (stations, each at least 1)."""
        n = np.asarray(lengths, dtype=np.intp)
        start = np.zeros(len(n), dtype=np.intp)
        np.cumsum(n[:-1], out=start[1:])
        row = np.repeat(np.arange(len(n)), n)
        return cls(n, start, row, np.arange(int(n.sum())) - start[row])

    @cached_property
    def width(self) -> int:
        """The longest frame (stations)."""
        return int(self.n.max())

    @cached_property
    def flat(self) -> np.ndarray:
        """Each position's index in the frames padded to :attr:`width` and flattened."""
        return self.row * self.width + self.local

    def pad(self, x: np.ndarray, fill: Any) -> np.ndarray:
        """``x`` (shape (..., total)) as (..., B, max n), each frame left-aligned, ``fill`` after."""
        out = np.full(x.shape[:-1] + (len(self.n) * self.width,), fill, dtype=x.dtype)
        out[..., self.flat] = x
        return out.reshape(x.shape[:-1] + (len(self.n), self.width))

    def count(self, mask: np.ndarray) -> np.ndarray:
        """Per frame, how many of its positions ``mask`` holds at."""
        return np.add.reduceat(mask.astype(np.intp), self.start)

    def last(self, mask: np.ndarray) -> np.ndarray:
        """Per frame, the last station where ``mask`` holds (−1 where none)."""
        return np.maximum.reduceat(np.where(mask, self.local, -1), self.start)

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """``x`` (shape (total, ...)) cut into its frames (views)."""
        return [x[s : s + m] for s, m in zip(self.start.tolist(), self.n.tolist())]

    def subset(self, frames: np.ndarray) -> tuple[np.ndarray, "Ragged"]:
        """The positions of ``frames`` (increasing frame indices), as a mask over the
        positions, and those frames' own layout."""
        chosen = np.zeros(len(self.n), dtype=bool)
        chosen[frames] = True
        return chosen[self.row], Ragged.of(self.n[frames])


def erode_ragged(mask: np.ndarray, rg: Ragged, reach: int) -> np.ndarray:
    """:func:`erode` of each frame of a ragged ``mask`` (stations beyond a frame's ends fail)."""
    out = mask.copy()
    for k in range(1, reach + 1):
        out[k:] &= mask[:-k]
        out[:-k] &= mask[k:]
    return out & (rg.local >= reach) & (rg.local < rg.n[rg.row] - reach)


def near_ragged(mask: np.ndarray, rg: Ragged, size: int) -> np.ndarray:
    """Where ``mask`` holds somewhere within the window of ``size`` (odd) stations centred on
    each station, the window clipped at its frame's ends.

    Parameters
    ----------
    mask : ndarray, shape (total,), bool
        At the frames' stations (ragged ``rg``).
    rg : Ragged
        The frames' layout.
    size : int
        Window length (stations, odd).

    Returns
    -------
    ndarray, shape (total,), bool
    """
    h = int(size) // 2
    csum = np.zeros(len(mask) + 1, dtype=np.intp)
    np.cumsum(mask, out=csum[1:])
    i = np.arange(len(mask))
    first = rg.start[rg.row]
    last = first + rg.n[rg.row] - 1
    return csum[np.minimum(i + h, last) + 1] > csum[np.maximum(i - h, first)]


def running_median_ragged(x: np.ndarray, rg: Ragged, size: int) -> np.ndarray:
    """Median of each window of ``size`` (odd) samples centred on each sample of a ragged ``x``,
    each window's indices clamped to its own frame's ends (so a frame's ends are extended
    with its end values, as ``scipy.ndimage.median_filter(x, size, mode="nearest")`` of each
    frame).

    Parameters
    ----------
    x : ndarray, shape (total,)
        Samples (any unit) of the frames (ragged ``rg``).
    rg : Ragged
        The frames' layout.
    size : int
        Window length (samples, odd).

    Returns
    -------
    ndarray, shape (total,)
    """
    h = int(size) // 2
    first = rg.start[rg.row][:, None]
    idx = np.arange(-h, h + 1)[None, :] + np.arange(len(x))[:, None]
    np.minimum(np.maximum(idx, first, out=idx), first + rg.n[rg.row][:, None] - 1, out=idx)
    return np.partition(x[idx], h, axis=1)[:, h]


def running_moments(values: np.ndarray, valid: np.ndarray, x: np.ndarray, pad: int) -> np.ndarray:
    """Running sums along the stations of the moments the local line fits need.

    Parameters
    ----------
    values : ndarray, shape (k, n)
        ``k`` profiles (any unit); only ``valid`` stations count (NaN elsewhere is ignored).
    valid : ndarray, shape (n,), bool
        Stations measured.
    x : ndarray, shape (n,)
        Station positions (stations).
    pad : int
        Columns of zeros before the sums and of the held total after them.

    Returns
    -------
    ndarray, shape (3 + 2k, n + 2 pad + 1)
        Rows w, w x, w x², w y (``k`` rows), w y x (``k`` rows), with w = ``valid``: column
        ``pad + 1 + i`` sums stations 0..i, the ``pad + 1`` columns before it are 0 and the
        ``pad`` after the last hold the total.
    """
    k, n = values.shape
    csum = np.zeros((3 + 2 * k, n + 2 * pad + 1))
    body = csum[:, pad + 1 : n + pad + 1]
    body[0] = valid
    np.multiply(body[0], x, out=body[1])
    np.multiply(body[1], x, out=body[2])
    np.copyto(body[3 : 3 + k], values, where=valid)  # 0 elsewhere (NaN there is ignored)
    np.multiply(body[3 : 3 + k], x, out=body[3 + k :])
    np.cumsum(body, axis=1, out=body)
    csum[:, n + pad + 1 :] = csum[:, n + pad : n + pad + 1]
    return csum


def window_line(sums: np.ndarray, k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares lines from window sums (rows of :func:`running_moments`): fit, slope, has-data.

    The line through the valid stations of each window; their mean, slope 0, where they are
    too few or too bunched for a slope (fewer than 3, or spread over fewer than about 5
    stations); ``have`` is False where the window holds none.
    """
    s0, s1, s2, t0, t1 = sums[0], sums[1], sums[2], sums[3 : 3 + k], sums[3 + k :]
    have = s0 > 0.5
    m0 = np.where(have, s0, 1.0)
    mx, my = s1 / m0, t0 / m0
    var = s2 / m0 - mx * mx
    sloped = have & (s0 >= 3) & (var >= 2.0)
    slope = np.where(sloped, (t1 / m0 - mx * my) / np.where(sloped, var, 1.0), 0.0)
    return my + slope * (x - mx), slope, have


def smooth_ragged(values: np.ndarray, valid: np.ndarray, rg: Ragged, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Local straight-line smoothing of each frame's profiles, measured only at some stations.

    At each station, the value and the slope of the least-squares line through the valid
    stations of its frame within the window (:func:`window_line`); stations without any are
    interpolated linearly between the nearest of their frame that have (held constant beyond
    its ends, :func:`fill_ragged`). Unlike a running mean, a line is not biased by a trend at
    the ends of measured stretches (next to bands and the tip).

    The running sums (:func:`running_moments`) run over all frames' stations end to end, and
    each window's sum is the difference of two of them with the window clipped to its own
    frame (as in :func:`near_ragged`). The weights, stations and their products are integers,
    so their sums, and with them which stations get a fit and a slope, are exactly the
    frame's own; the sums of the values differ from the frame's alone by rounding only.

    Parameters
    ----------
    values : ndarray, shape (k, total)
        ``k`` profiles (any unit) at the frames' stations (ragged ``rg``).
    valid : ndarray, shape (total,), bool
        Stations measured (at least one per frame); the others' values are ignored.
    rg : Ragged
        The frames' layout.
    size : int
        Window (stations) of the local fits.

    Returns
    -------
    fit, slope : ndarray, shape (k, total)
        Fitted value (unit) and slope (unit per station) at each station.

    Raises
    ------
    ValueError
        A frame has no station with a fit (:func:`fill_ragged`).
    """
    k, total = values.shape
    h = size // 2
    x = rg.local.astype(float)
    csum = running_moments(values, valid, x, h)
    sums = csum[:, 2 * h + 1 :] - csum[:, :total]  # over positions i-h .. i+h
    near_end = np.flatnonzero((rg.local < h) | (rg.local >= rg.n[rg.row] - h))  # windows to clip to the frame
    if len(near_end):
        first = rg.start[rg.row[near_end]]
        hi = np.minimum(near_end + h, first + rg.n[rg.row[near_end]] - 1) + h + 1
        sums[:, near_end] = csum[:, hi] - csum[:, np.maximum(near_end - h, first) + h]
    fit, slope, have = window_line(sums, k, x)
    if not have.all():
        fill_ragged(fit, have, rg)
    return fit, slope


def fill_ragged(fit: np.ndarray, known: np.ndarray, rg: Ragged) -> None:
    """Fill ``fit[:, i]`` where not ``known[i]`` by linear interpolation between the known
    stations of its frame (their end values beyond them), in place: the per-frame
    ``np.interp(x[~known], x[known], row[known])`` for all frames and rows, equal to it.

    The frames' stations are laid on one axis a whole number of stations apart, each frame
    flanked by a point of its first and of its last known value, so no query interpolates
    across frames and the differences of positions stay exact.

    Raises
    ------
    ValueError
        A frame has no known station.
    """
    i = np.arange(len(known))
    first = np.minimum.reduceat(np.where(known, i, len(known)), rg.start)
    last = np.maximum.reduceat(np.where(known, i, -1), rg.start)
    if (last < 0).any():
        raise ValueError("a frame has no valid station to interpolate from")
    pos = rg.local + float(rg.width + 3) * rg.row
    # each frame's stations between its two flanks: station i at i + 2 row + 1
    lo_at = rg.start + 2 * np.arange(len(rg.n))
    hi_at = lo_at + rg.n + 1
    at = i + 2 * rg.row + 1
    xp = np.empty(len(known) + 2 * len(rg.n))
    xp[lo_at], xp[hi_at], xp[at] = pos[rg.start] - 1.0, pos[rg.start] + rg.n, pos
    use = np.ones(len(xp), dtype=bool)
    use[at] = known
    xp, unknown = xp[use], np.flatnonzero(~known)
    fp = np.empty(len(use))
    for row in fit:
        fp[lo_at], fp[hi_at], fp[at] = row[first], row[last], row
        row[unknown] = np.interp(pos[unknown], xp, fp[use])


def fill_rows(fit: np.ndarray, known: np.ndarray, unknown: np.ndarray, x: np.ndarray) -> None:
    """Fill ``fit[b, r, j]`` where ``unknown[b, j]`` by linear interpolation over ``x[j]``
    between frame ``b``'s ``known`` stations (the end values beyond them), in place: the
    per-frame ``np.interp(x[unknown[b]], x[known[b]], fit[b, r, known[b]])`` for all frames
    (with any known station) in one call per ``r``.

    The frames' positions ``x`` (increasing, integers or halves) are laid on one axis, each
    frame flanked by a point of its first and of its last known value, so no query
    interpolates across frames; the frames are an integer distance apart, so the differences
    of positions stay exact and each value equals its frame's own.
    """
    n_frames, n = known.shape
    pos = np.empty((n_frames, n + 2))  # each frame's positions between its two flanks
    pos[:, 1:-1] = x
    pos[:, 0], pos[:, -1] = x[0] - 1.0, x[-1] + 1.0
    pos += (float(np.ceil(x[-1] - x[0])) + 5.0) * np.arange(n_frames)[:, None]
    has = known.any(axis=1)
    use = np.zeros((n_frames, n + 2), dtype=bool)
    use[:, 1:-1], use[:, 0], use[:, -1] = known, has, has
    first = np.argmax(known, axis=1)
    last = n - 1 - np.argmax(known[:, ::-1], axis=1)
    xp = pos[use]  # increasing: frame by frame, each in order
    at = np.flatnonzero(unknown.ravel())
    xq = np.take(pos[:, 1:-1].ravel(), at)
    rows = np.arange(n_frames)
    values = np.empty((n_frames, n + 2))
    for r in range(fit.shape[1]):
        values[:, 1:-1] = fit[:, r]
        values[:, 0], values[:, -1] = fit[rows, r, first], fit[rows, r, last]
        filled = fit[:, r].copy()
        filled.ravel()[at] = np.interp(xq, xp, values[use])
        fit[:, r] = filled


def _bracket(x: np.ndarray, xp: np.ndarray) -> np.ndarray:
    """For each query ``x``, the ``j`` with ``xp[j] <= x < xp[j + 1]`` as ``np.interp`` finds it,
    clipped to ``0 .. len(xp) - 2`` (``xp`` strictly increasing, at least 2 samples)."""
    return np.minimum(np.maximum(np.searchsorted(xp, x, side="right") - 1, 0), len(xp) - 2)


def _interp_at(x: np.ndarray, xp: np.ndarray, j: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """``np.interp``'s value at ``x`` from its bracket ``j`` (:func:`_bracket`) and the samples
    there (``lo`` at ``xp[j]``, ``hi`` at ``xp[j + 1]``), with its own arithmetic; ``first``
    and ``last`` (the end samples) beyond the ends."""
    value = (hi - lo) / (xp[j + 1] - xp[j]) * (x - xp[j]) + lo
    return np.where(x < xp[0], first, np.where(x >= xp[-1], last, value))


def interp_ragged(x: np.ndarray, row: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp(x[i], xp, fp[row[i]])`` for each query ``i``, equal to it (finite values).

    Each query's bracket ``xp[j] <= x < xp[j + 1]`` is found once, as ``np.interp`` finds it,
    and the value computed with its arithmetic, ``(fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) *
    (x - xp[j]) + fp[j]``; beyond the ends, the end values.

    Parameters
    ----------
    x : ndarray, shape (q,)
        Query positions.
    row : ndarray, shape (q,), int
        Row of ``fp`` of each query.
    xp : ndarray, shape (m,)
        Strictly increasing sample positions, common to all rows.
    fp : ndarray, shape (B, m)
        Sample values per row.

    Returns
    -------
    ndarray, shape (q,)
    """
    m = len(xp)
    if m == 1:
        return fp[row, 0].astype(float)
    j = _bracket(x, xp)
    flat, at, first = fp.ravel(), row * m + j, row * m
    return _interp_at(x, xp, j, np.take(flat, at), np.take(flat, at + 1), np.take(flat, first),
                      np.take(flat, first + m - 1))


def interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp(x, xp, fp[b])`` for each row ``b`` of ``fp``, equal to it row by row (see
    :func:`interp_ragged`; the brackets are common to all rows).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Query positions, common to all rows.
    xp : ndarray, shape (m,)
        Strictly increasing sample positions, common to all rows.
    fp : ndarray, shape (B, m)
        Sample values per row.

    Returns
    -------
    ndarray, shape (B, n)
    """
    m = len(xp)
    if m == 1:
        return np.repeat(fp[:, :1].astype(float), len(x), axis=1)
    j = _bracket(x, xp)
    return _interp_at(x, xp, j, fp[:, j], fp[:, j + 1], fp[:, :1], fp[:, -1:])


def row_quantiles(x: np.ndarray, keep: np.ndarray, q: float) -> np.ndarray:
    """:func:`~tympani.vision.angles.arrays.quantile` of ``x[b][keep[b]]`` for each row ``b`` (NaN
    where none is kept)."""
    count = keep.sum(axis=1)
    xs = np.sort(np.where(keep, x, np.inf), axis=1)
    idx = np.round(q * (np.maximum(count, 1) - 1)).astype(np.intp)
    return np.where(count > 0, xs[np.arange(len(x)), idx].astype(np.float64), np.nan)


def distance_from_tip_ragged(line: np.ndarray, tip_mm: np.ndarray, tip_f: np.ndarray, rg: Ragged) -> np.ndarray:
    """Arc length (mm) from the tip along each frame's centre line, given basal station first.

    The lines are right-aligned in one array, padded in front with their first point (zero
    segments), so that each row's reversed running sum adds the line's own segments in the
    same order, then zeros.

    Parameters
    ----------
    line : ndarray, shape (total, 2)
        Centre-line points (mm) of the frames' stations (ragged ``rg``), basal first.
    tip_mm : ndarray, shape (B, 2)
        Per frame, the tip (mm).
    tip_f : ndarray, shape (B,)
        Per frame, the tip's fractional station; stations beyond it get 0.
    rg : Ragged
        The frames' layout.

    Returns
    -------
    ndarray, shape (total,)
    """
    n = int(rg.n.max())
    col = n - rg.n[rg.row] + rg.local
    padded = np.repeat(line[rg.start][:, None, :], n, axis=1)
    padded[rg.row, col] = line
    d = np.diff(padded, axis=1)
    seg = np.hypot(d[:, :, 0], d[:, :, 1])
    s = np.zeros((len(rg.n), n))
    s[:, :-1] = np.cumsum(seg[:, ::-1], axis=1)[:, ::-1]
    last = padded[:, -1] - tip_mm
    s += np.hypot(last[:, 0], last[:, 1])[:, None]
    return np.where(rg.local > tip_f[rg.row], 0.0, s[rg.row, col])


def extrapolate_ragged(stations: np.ndarray, values: np.ndarray, sel: np.ndarray, span: float,
                       rg: Ragged) -> np.ndarray:
    """Per frame, the value at its last station of a straight line fitted to the values of the
    stations ``sel``.

    Parameters
    ----------
    stations, values : ndarray, shape (total,)
        Station (float) and value (any unit) at each position of the frames (ragged ``rg``).
    sel : ndarray, shape (total,), bool
        The stations each frame's line is fitted to: measured, and within ``span`` of the
        frame's last measured station (at least one per frame).
    span : float
        Length (stations) of the stretch fitted.
    rg : Ragged
        The frames' layout.

    Returns
    -------
    ndarray, shape (B,)
        Per frame, the line's value at its last station; the stretch's median when it holds
        fewer than 3 stations or spans less than a third of ``span``.
    """
    count = rg.count(sel)
    w = rg.pad(sel, False)
    r, v = rg.pad(np.where(sel, stations, 0.0), 0.0), rg.pad(np.where(sel, values, 0.0), 0.0)
    rm, vm = r.sum(axis=1) / count, v.sum(axis=1) / count
    dr = np.where(w, r - rm[:, None], 0.0)
    num, den = (dr * (v - vm[:, None])).sum(axis=1), (dr * dr).sum(axis=1)
    slope = np.divide(num, den, out=np.zeros_like(num), where=den > 0)  # den 0: one station, taken as short
    line = vm + slope * ((rg.n - 1) - rm)
    spread = np.where(w, r, -np.inf).max(axis=1) - np.where(w, r, np.inf).min(axis=1)
    short = (count < 3) | (spread < span / 3)
    return np.where(short, row_quantiles(v, w, 0.5), line) if short.any() else line


def tip_crossing_ragged(cover_at: np.ndarray, level: np.ndarray, fallback: np.ndarray, rg: Ragged) -> np.ndarray:
    """Per frame, the fractional station where its coverage profile last falls below its level:
    linear interpolation between the last station at or above the level and the next.

    Parameters
    ----------
    cover_at : ndarray, shape (total,)
        Coverage (0 fluid, 1 array) along each frame's centre line (ragged ``rg``), basal first.
    level : ndarray, shape (B,)
        Per frame, the crossing level.
    fallback : ndarray, shape (B,)
        Per frame, the value where the profile never falls below its level.
    rg : Ragged
        The frames' layout.

    Returns
    -------
    ndarray, shape (B,)
    """
    above = cover_at >= level[rg.row]
    falls = above.copy()
    falls[:-1] &= ~above[1:]
    k = rg.last(falls & (rg.local < rg.n[rg.row] - 1))
    at = rg.start + np.maximum(k, 0)
    a, b = cover_at[at], cover_at[np.minimum(at + 1, len(cover_at) - 1)]
    t = np.minimum(np.maximum((a - level) / np.maximum(a - b, 1e-6), 0.0), 1.0)
    return np.where(k >= 0, k + t, fallback)

"""Stage 1, the survey: fluid level, the array's level and its dark run along the whole channel.

The survey of B frames runs at once (:func:`survey_batch`): the coarse strip is the same for
every frame of a plan, so the strips are stacked along a leading axis and each step runs once
per batch (the remap and the blur stay per frame); every step works row by row, so a frame's
survey does not depend on the others in its batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tympani.vision.angles.arrays import erode
from tympani.vision.angles.config import FrameMeasurement, MeasureConfig, failure
from tympani.vision.angles.plan import MeasurePlan
from tympani.vision.angles.ragged import fill_rows, interp_rows, row_quantiles


@dataclass(frozen=True)
class Survey:
    """Stage 1 (coarse strip of the whole channel), at every ``sa``-th station.

    ``fluid_c`` fluid level (grey levels), ``rho`` array / fluid, ``contrast`` fluid − array
    at the entry (grey levels), ``seed_c`` darkest offset (coarse index), ``tip_est`` the
    dark run's last station (fine index), ``resumes`` whether a train of bright stretches
    goes on past it (:func:`_run_resumes`), ``lighter`` whether stretch after stretch of part
    dark does (``MeasureConfig.lighter_stretches``).
    """

    fluid_c: np.ndarray
    rho: float
    contrast: float
    seed_c: np.ndarray
    tip_est: int
    resumes: bool = False
    lighter: bool = False


def _first_fluid_levels(brightest: np.ndarray, in_view: np.ndarray, block: int, reach: int, band_length: int,
                        cfg: MeasureConfig) -> np.ndarray:
    """The survey's first fluid level (:func:`_fluid_levels` at ``cfg.fluid_percentile``), shape
    (B, n), grey levels, taken without the metal bands where they fill most of a block.

    Where long bands with little body between fill most of a block, its percentile lies on
    their blurred shoulders, far above the fluid seen between them (and beside the array there
    no longer reads as fluid). Where the level stands more than ``cfg.band_fill_rise`` above the
    same level of ``brightest`` without bright stretches shorter than ``band_length`` stations
    (:func:`_without_bands`), the latter is taken. Blocks the array fills in part, noise and
    shading leave the two levels close, and the first stands; so does the first level where it
    eases down to the fluid's over the two blocks past the bands' end (a median over three
    blocks, interpolated between their centres), up to ``cfg.band_fill_rise`` above it: taking
    the lower level there as well measured fewer frames on independent renderers.

    Parameters
    ----------
    brightest : ndarray, shape (B, n), float32
        Brightest interior value (grey levels) at each station of each frame.
    in_view : ndarray, shape (B, n), bool
        Stations used, per frame.
    block, reach : int
        As :func:`_fluid_levels` takes them (stations, blocks).
    band_length : int
        Longest bright stretch (stations) removed: ``cfg.band_open_mm`` in stations.
    cfg : MeasureConfig
        ``fluid_percentile``, ``fluid_floor`` and ``band_fill_rise``.
    """
    level = _fluid_levels(brightest, in_view, block, cfg.fluid_percentile, reach, cfg.fluid_floor)
    bare = _fluid_levels(_without_bands(brightest, band_length), in_view, block, cfg.fluid_percentile, reach,
                         cfg.fluid_floor)
    return np.where(level > (1.0 + cfg.band_fill_rise) * bare, bare, level)


def _without_bands(brightest: np.ndarray, length: int) -> np.ndarray:
    """``brightest`` (shape (B, n), float32, grey levels) with its bright stretches shorter than
    ``length`` stations (metal bands, glints) cut down to their surroundings: a grey-level
    opening along the channel, which keeps every dark stretch and every longer bright one
    (the fluid beyond the tip) as they are."""
    kernel = np.ones((1, 2 * (max(1, int(length)) // 2) + 1), np.uint8)
    return cv2.morphologyEx(brightest, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_REPLICATE)


def _band_border_c(cfg: MeasureConfig, step_mm: float) -> int:
    """Coarse stations either side of a band's border kept out of the fluid's second estimate
    (``cfg.band_border_mm``, at least 2), for stations ``step_mm`` (mm) apart."""
    return max(2, int(np.ceil(cfg.band_border_mm / (max(1, int(cfg.coarse_stride)) * step_mm))))


def _fluid_levels(
    brightest: np.ndarray, in_view: np.ndarray, block: int, percentile: float, reach: int, floor: float
) -> np.ndarray:
    """The fluid's grey level along the channel, in each row (frame) of ``brightest``.

    Parameters
    ----------
    brightest : ndarray, shape (B, n), float32
        Brightest interior value (grey levels) at each station of each frame.
    in_view : ndarray, shape (B, n), bool
        Stations used, per frame.
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
    ndarray, shape (B, n)
        Fluid level (grey levels): a low percentile of ``brightest`` in consecutive blocks
        (blocks filled by the array interpolated from the others), the median of each block
        and its two neighbours, interpolated between block centres; 1 in a frame with no
        station used. It ignores the array where fluid shows beside it, metal bands brighter
        than the fluid (a minority of any block) and the stations not used (interpolated from
        the others).

    Notes
    -----
    A frame with every station used compares its blocks with the envelope in ``brightest``'s
    precision (float32), the others in float64 (their values interpolated); the rest is exact
    in float64 either way. Row by row this equals the same computation on each frame alone
    (``tests/test_angles_batch.py``).
    """
    n_rows, n = brightest.shape
    stations = np.arange(n)
    all_in, any_in = in_view.all(axis=1), in_view.any(axis=1)
    values = brightest.astype(np.float64)  # exact
    partial = (any_in & ~all_in)[:, None]
    if partial.any():  # stations out of view interpolated from those in view
        fill_rows(values[:, None, :], in_view & partial, ~in_view & partial, stations.astype(float))
    block = max(1, min(int(block), n))
    n_blocks = n // block
    blocks = values[:, : n_blocks * block].reshape(n_rows, n_blocks, block)
    q = int(round(percentile / 100.0 * (block - 1)))
    level = np.partition(blocks, q, axis=2)[:, :, q]
    centres = block * np.arange(n_blocks) + 0.5 * (block - 1)
    envelope = cv2.dilate(level, np.ones((1, 2 * reach + 1), np.uint8), borderType=cv2.BORDER_REPLICATE)
    single = all_in if brightest.dtype == np.float32 else np.zeros(n_rows, bool)
    thr32 = (envelope.astype(np.float32) * np.float32(floor)).astype(np.float64)
    fluid_like = np.where(single[:, None], level >= thr32, level >= floor * envelope)
    partial = (fluid_like.any(axis=1) & ~fluid_like.all(axis=1))[:, None]
    if partial.any():  # blocks filled by the array interpolated from the others
        fill_rows(level[:, None, :], fluid_like & partial, ~fluid_like & partial, centres)
    if n_blocks >= 3:
        a = np.concatenate([level[:, :1], level[:, :-1]], axis=1)
        c = np.concatenate([level[:, 1:], level[:, -1:]], axis=1)
        level = np.maximum(np.minimum(a, level), np.minimum(np.maximum(a, level), c))
    out = np.ones((n_rows, n))
    rows = np.flatnonzero(any_in)
    if len(rows):
        out[rows] = np.maximum(interp_rows(stations, centres, level[rows]), 1.0)
    return out


def _array_ratios(
    darkest: np.ndarray, brightest: np.ndarray, steepest: np.ndarray, fluid: np.ndarray, in_view: np.ndarray,
    min_count: int,
) -> np.ndarray:
    """The array's grey level as a fraction of the fluid's in each row (frame), NaN where it is
    not seen.

    Parameters
    ----------
    darkest, brightest : ndarray, shape (B, n)
        Darkest and brightest interior value (grey levels) at each station.
    steepest : ndarray, shape (B, n)
        Largest change (grey levels) between neighbouring interior samples across the channel.
    fluid : ndarray, shape (B, n)
        Estimated fluid level (grey levels) at each station.
    in_view : ndarray, shape (n,) or (B, n), bool
        Stations inside the image.
    min_count : int
        Fewest stations that must show both.

    Returns
    -------
    ndarray, shape (B,)
        A low quantile (0.3) of darkest / brightest over stations where the array shows
        beside the fluid (brightest near the fluid level, darkest below 0.88 of it, an edge
        steeper than 5 % of it between neighbouring samples, and so at the station either side
        and, unless a metal band brighter than the fluid lies there, at the next ones: bands
        as long as the body between them leave it only three stations at a time): a ratio
        taken side by side, so uneven lighting cancels; stations only partly covered (band
        borders, the tip) raise it, hence not the median. NaN when fewer than ``min_count``
        stations show both: a dim channel (vignetting) is not taken for an array filling it.
    """
    ratio = darkest / np.maximum(brightest, 1.0)
    beside = in_view & (ratio < 0.88) & (np.abs(brightest / fluid - 1.0) < 0.15) & (steepest > 0.05 * brightest)
    # its neighbours show it too, but for a metal band two stations away
    near = beside | (in_view & (brightest > 1.15 * fluid))
    beside[:, 2:-2] &= beside[:, 1:-3] & beside[:, 3:-1] & near[:, :-4] & near[:, 4:]
    rho = row_quantiles(ratio, beside, 0.3)
    return np.where(beside.sum(axis=1) < max(min_count, 3), np.nan, rho)


def _array_ratio_low(
    darkest: np.ndarray, brightest: np.ndarray, steepest: np.ndarray, fluid: np.ndarray, in_view: np.ndarray,
    entry: np.ndarray, min_count: int,
) -> np.ndarray:
    """The lower of :func:`_array_ratios` over all stations in view and over the entry channel's
    (``entry``, shape (n,), bool), where the array lies once inserted.

    Shadows and shading across the fluid beyond the tip pass the same side-by-side test, and
    where they outnumber the array's stations they raise the whole channel's quantile towards
    their own ratio (then the shading reads as more array); the entry's stations are the
    array's, but where its thick base fills the entry they see too little fluid beside it and
    read high. Too low a ratio only asks more contrast of the array's body, which it has.
    """
    every = _array_ratios(darkest, brightest, steepest, fluid, in_view, min_count)
    return np.fmin(every, _array_ratios(darkest, brightest, steepest, fluid, entry, min_count))


def _attached(band: np.ndarray, dark: np.ndarray, border: int, reach: int) -> np.ndarray:
    """Stations of ``band`` (shape (B, n)) in an unbroken stretch of band stations with a dark
    station at most ``border`` stations on one side of it and at most ``reach`` stations on the
    other: a metal band lies between two stretches of the array's body (its borders blurred
    over a few stations; where bands are long and the body between them short, the thin body
    near the tip reads dark only here and there), a glint or a bubble's halo out in the fluid
    does not."""
    n_rows, n = band.shape
    at = np.arange(n)
    far = n + border + 1
    last_dark = np.maximum.accumulate(np.where(dark, at, -far), axis=1)
    next_dark = np.minimum.accumulate(np.where(dark, at, 2 * far)[:, ::-1], axis=1)[:, ::-1]
    # each station's band stretch: its first station and the first station after it
    start = np.maximum.accumulate(np.where(band, -1, at), axis=1) + 1
    stop = np.minimum.accumulate(np.where(band, n, at)[:, ::-1], axis=1)[:, ::-1]
    before = np.take_along_axis(last_dark, np.maximum(start - 1, 0), axis=1)
    after = np.take_along_axis(next_dark, np.minimum(stop, n - 1), axis=1)
    gap_before, gap_after = start - before - 1, after - stop
    joined = ((gap_before <= border) & (gap_after <= reach)) | ((gap_before <= reach) & (gap_after <= border))
    return band & (start > 0) & (stop < n) & joined


def _array_runs(dark: np.ndarray, probe: np.ndarray, max_gap: float, band: np.ndarray | None = None,
                border: int = 2) -> np.ndarray:
    """Per row (frame) of ``dark``, shape (B, n), the last station of
    the dark run that starts at the first dark probe station, bridging gaps up to ``max_gap``
    stations (−1 where no probe station is dark).

    The run ends at the first dark station from its start whose next dark station is more
    than ``max_gap`` stations away, or that has none. Stations of ``band`` (shape (B, n), a
    metal band brighter than the fluid) carry the run like dark ones where they join a dark
    station (:func:`_attached`: within ``border`` stations on one side, ``max_gap`` on the
    other), but it still ends on a dark station: a band longer than ``max_gap`` does not end
    the array.
    """
    n_rows, n = dark.shape
    at = np.arange(n)
    carry = dark if band is None else dark | _attached(band, dark, border, int(max_gap))
    in_probe = dark[:, probe]
    start = np.where(in_probe.any(axis=1), probe[in_probe.argmax(axis=1)], n)
    nxt = np.full((n_rows, n), n)  # the next carrying station after each station (n: none)
    nxt[:, :-1] = np.minimum.accumulate(np.where(carry, at, n)[:, :0:-1], axis=1)[:, ::-1]
    ends = carry & (at >= start[:, None]) & ((nxt == n) | (nxt - at - 1 > max_gap))
    end = ends.argmax(axis=1)
    if band is not None:  # back to the run's last dark station
        last_dark = np.maximum.accumulate(np.where(dark, at, -1), axis=1)
        end = last_dark[np.arange(n_rows), end]
    return np.where(start < n, end, -1)


def _run_resumes(dark: np.ndarray, band: np.ndarray, end: np.ndarray, max_gap: float, reach: int,
                 length: int, stretches: int = 2, starts: np.ndarray | None = None,
                 window: int | None = None) -> np.ndarray:
    """Per row (frame) of ``dark`` and ``band`` (shape (B, n)), whether another run of dark or
    band stations, bridging gaps up to ``max_gap`` stations, starts within ``reach`` stations
    past ``end`` (the dark run's last station; −1: none), goes on for ``length`` stations or
    more and holds ``stretches`` or more separate band stretches: a train of bright stretches
    longer than a bubble, the array going on where its body is too light to count as dark
    (the run ended at a shadow's edge), or a chain of bubbles ahead of the tip. Shading across
    the fluid makes no bands. ``starts`` (shape (B, n), bool), where given, marks the stations
    that begin a stretch in place of each band stretch's first station; ``window``, where given,
    counts them only over the run's first ``window`` stations."""
    n_rows, n = dark.shape
    at = np.arange(n)
    past = (at > end[:, None]) & (end[:, None] >= 0)
    carry = (dark | band) & past
    # the previous carrying station past the end (−n−max_gap−2: none), to break runs at wide gaps
    none = -n - int(max_gap) - 2
    prev = np.maximum.accumulate(np.where(carry, at, none), axis=1)
    prev = np.concatenate([np.full((n_rows, 1), none), prev[:, :-1]], axis=1)
    first = carry & (at - prev - 1 > max_gap)  # each run's first station
    flat = np.flatnonzero(carry)  # row-major: runs are contiguous
    if not len(flat):
        return np.zeros(n_rows, dtype=bool)
    heads = np.flatnonzero(first.ravel()[flat])
    lo, hi = flat[heads], flat[np.r_[heads[1:], len(flat)] - 1]  # each run's first and last (flat)
    if starts is None:
        starts = band.copy()
        starts[:, 1:] &= ~band[:, :-1]
    count = np.concatenate([[0], np.cumsum(starts.ravel())])
    row = lo // n
    last = hi if window is None else np.minimum(hi, lo + window - 1)
    ok = ((lo % n) - end[row] - 1 < reach) & (hi - lo >= length) & (count[last + 1] - count[lo] >= stretches)
    return np.bincount(row[ok], minlength=n_rows) > 0


def _part_dark_starts(darkness: np.ndarray, level: float, clear: float) -> np.ndarray:
    """Stations (shape (B, n), bool) that begin a part-dark stretch: at least ``level`` dark
    (``darkness``: 0 the fluid, 1 the array's body) with a station under ``clear`` since the
    previous such station, or none before it. Noise about a level in between (shading) does
    not begin new stretches."""
    n_rows, n = darkness.shape
    at = np.arange(n)
    half = darkness >= level
    prev_half = np.maximum.accumulate(np.where(half, at, -1), axis=1)
    prev_half = np.concatenate([np.full((n_rows, 1), -1), prev_half[:, :-1]], axis=1)
    last_clear = np.maximum.accumulate(np.where(darkness < clear, at, -1), axis=1)
    return half & ((last_clear > prev_half) | (prev_half < 0))


def survey_batch(imgs: list[np.ndarray], plan: MeasurePlan) -> list[Survey | FrameMeasurement]:
    """Stage 1 of each frame of ``imgs`` (grey, the plan's shape), computed together.

    Parameters
    ----------
    imgs : list of ndarray
        Grey frames (uint8 or float32) of the plan's image shape.
    plan : MeasurePlan
        The video's plan.

    Returns
    -------
    list of Survey or FrameMeasurement
        Per frame, its survey, or why it cannot be measured (the plan's refusal, the entry or
        the tip out of view, no array in the channel).
    """
    if plan.refusal is not None:
        return [failure(plan.refusal) for _ in imgs]
    cfg, step, sa = plan.cfg, plan.step_mm, max(1, int(plan.cfg.coarse_stride))
    coarse = np.empty((len(imgs),) + plan.coarse_x.shape, np.float32)
    for img, dst in zip(imgs, coarse):  # each frame's blurred coarse strip, written in place
        strip = cv2.remap(img, plan.coarse_x, plan.coarse_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        cv2.blur(strip.astype(np.float32, copy=False), (3, 3), dst=dst)
    n_rows = len(imgs)
    low = coarse + plan.coarse_penalty
    darkest = low.min(axis=1)
    seed_c = (low == darkest[:, None, :]).argmax(axis=1) + plan.coarse_row0  # = argmin (finite values), faster
    high = coarse - plan.coarse_penalty
    brightest = high.max(axis=1)
    pair_penalty = plan.coarse_penalty[1:] + plan.coarse_penalty[:-1]
    steepest = (np.abs(coarse[:, 1:] - coarse[:, :-1]) - pair_penalty).max(axis=1)
    view_c = plan.in_view[::sa]
    probe = np.flatnonzero((plan.p_mm[::sa] <= cfg.probe_mm) & view_c)
    if len(probe) == 0:
        return [failure("entry out of view") for _ in imgs]
    block = int(round(cfg.fluid_window_mm / (sa * step)))
    reach = int(np.ceil(cfg.fluid_reach_mm / cfg.fluid_window_mm))
    min_beside = int(np.ceil(cfg.beside_mm / (sa * step)))
    views = np.broadcast_to(view_c, brightest.shape)
    fluid_c = _first_fluid_levels(brightest, views, block, reach, int(round(cfg.band_open_mm / (sa * step))), cfg)
    entry_c = view_c & (np.arange(len(view_c)) * sa < plan.i_start)
    rho1 = _array_ratio_low(darkest, brightest, steepest, fluid_c, view_c, entry_c, min_beside)
    rho = rho1[:, None]
    contrast_c = fluid_c * (1.0 - rho)
    body = (fluid_c - darkest) / contrast_c >= cfg.body_level
    # the fluid shows beside the array's body, or the channel is plain; a station brighter by a
    # metal band's margin than the first estimate anywhere within reach shows a band or a glint,
    # not the fluid (the first estimate runs low where the array fills the channel)
    trusted = view_c & (erode(body, _band_border_c(cfg, step)) | ((brightest - darkest) / contrast_c < 0.3))
    near = cv2.dilate(fluid_c.astype(np.float32), np.ones((1, 2 * reach * block + 1), np.uint8),
                      borderType=cv2.BORDER_REPLICATE)
    trusted &= brightest < (1.0 + cfg.band_level) * near
    fluid_c = _fluid_levels(brightest, trusted, block, 75.0, reach, cfg.fluid_floor)
    rho2 = _array_ratio_low(darkest, brightest, steepest, fluid_c, view_c, entry_c, min_beside)
    contrast = np.sort(fluid_c[:, probe], axis=1)[:, int(round(0.5 * (len(probe) - 1)))] * (1.0 - rho2)
    dark = ((1.0 - darkest / fluid_c) / (1.0 - rho2[:, None]) >= cfg.dark_level) & view_c
    # a metal band: brighter than the fluid, and no wider than the array (a bubble's bright
    # inside, against the tip, is wider)
    lit = (high >= ((1.0 + cfg.band_level) * fluid_c)[:, None, :]).sum(axis=1)
    across_mm = sa * float(plan.u[1] - plan.u[0]) * plan.half_mm[::sa]  # the coarse offsets' spacing
    band = (lit > 0) & (lit * across_mm <= cfg.band_width_mm) & view_c
    max_gap_c = cfg.max_gap_mm / (sa * step)
    runs = _array_runs(dark, probe, max_gap_c, band, _band_border_c(cfg, step))
    resume_reach, resume_length = (int(np.ceil(x / (sa * step))) for x in (cfg.resume_mm, cfg.resume_length_mm))
    resumes = _run_resumes(dark, band, runs, max_gap_c, resume_reach, resume_length)
    # the array going on past the run's end: with bands and body blurred together, no longer
    # dark nor bright but part dark in stretch after stretch; or with bands as bright as the
    # fluid and longer than the gaps a run may bridge, dark stretch after dark stretch
    darkness = np.where(view_c, (1.0 - darkest / fluid_c) / (1.0 - rho2[:, None]), 0.0)
    half = darkness >= cfg.lighter_level
    lighter = _run_resumes(half, half, runs, max_gap_c, resume_reach, resume_length, cfg.lighter_stretches,
                           _part_dark_starts(darkness, cfg.lighter_level, cfg.lighter_clear * cfg.lighter_level),
                           2 * resume_length)
    lighter |= _run_resumes(dark, dark, runs, 2.0 * max_gap_c, resume_reach, resume_length, cfg.lighter_stretches,
                            _part_dark_starts(darkness, cfg.dark_level, cfg.lighter_clear * cfg.dark_level),
                            2 * resume_length)
    lighter = lighter.tolist()
    resumes = resumes.tolist()
    tips_c = runs.tolist()
    out: list[Survey | FrameMeasurement] = []
    for b in range(n_rows):
        if not rho1[b] == rho1[b] or not rho2[b] == rho2[b]:
            out.append(failure("array not in channel"))
            continue
        c = float(contrast[b])
        if c < cfg.min_contrast:
            out.append(failure("array not in channel", contrast=c))
            continue
        tip_c = tips_c[b]
        if tip_c < 0:
            out.append(failure("array not in channel", contrast=c))
        elif not plan.in_view[min(sa * tip_c + sa + 2, len(plan.p_mm) - 1)]:
            out.append(failure("tip out of view", contrast=c))
        else:
            out.append(Survey(fluid_c[b], float(rho2[b]), c, seed_c[b], sa * tip_c, bool(resumes[b]), bool(lighter[b])))
    return out

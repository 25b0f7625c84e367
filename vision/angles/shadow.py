"""A dark run that is the array's shadow, with the array beside it: its bands show there.

A light, translucent array can cast a shadow darker than itself. Where the shadow lies apart
from the array and is about as wide, the dark run follows the shadow, and the array (its metal
bands, brighter and darker in turn at their pitch) lies beside it, between it and the outer
wall. The shadow shows no bands. :func:`bands_beside` compares the two lanes along the last
millimetres before the tip: a lane beside the run's outer edge that brightens and darkens
periodically, and more strongly than the run itself, is the array, not fluid.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from tympani.vision.angles.config import MeasureConfig
from tympani.vision.angles.edges import Edges
from tympani.vision.angles.plan import MeasurePlan

# Where the lane beside the run starts, past its outer edge (a share of the array's width).
_LANE_FROM = 0.1
# Fewest stations of a lane that say anything about a period.
_LEAST = 20


def periodicity(signal: np.ndarray, step_mm: float, lags_mm: tuple[float, float], detrend_mm: float,
                least: int = _LEAST) -> tuple[float, float]:
    """How periodic a signal along the channel is, and how strongly it varies.

    Parameters
    ----------
    signal : ndarray, shape (n,)
        Values at stations ``step_mm`` (mm) apart; NaN where not seen (left out, the rest laid
        end to end).
    step_mm : float
        Station spacing (mm).
    lags_mm : tuple of float
        Shortest and longest period (mm) sought.
    detrend_mm : float
        Length (mm) of the running median taken off first: changes of the light slower than
        it go, bands and gaps between them shorter than half of it stay.
    least : int
        Fewest stations seen: with fewer, both results are NaN.

    Returns
    -------
    correlation : float
        Largest normalised autocorrelation over the lags of the signal less its running median,
        1 when exactly periodic; NaN when the signal is too short for the lags.
    spread : float
        Standard deviation of the signal less its running median (its units).
    """
    x = np.asarray(signal, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) < least:
        return np.nan, np.nan
    d = x - median_filter(x, size=max(3, int(round(detrend_mm / step_mm)) | 1), mode="nearest")
    spread = float(d.std())
    if spread < 1e-9:
        return 0.0, 0.0
    d = d - d.mean()
    lo, hi = int(lags_mm[0] / step_mm), min(int(lags_mm[1] / step_mm), len(d) - 5)
    if hi <= lo or hi < 1:
        return np.nan, spread
    n = len(d)
    lags = np.arange(max(lo, 1), hi + 1)
    products = np.correlate(d, d, mode="full")[n - 1 + lags]  # sum of d[:-lag] * d[lag:]
    energy = np.concatenate([[0.0], np.cumsum(d * d)])
    head, tail = energy[n - lags], energy[n] - energy[lags]  # sums of squares of d[:-lag], d[lag:]
    return float(np.max(products / (np.sqrt(head * tail) + 1e-12))), spread


def lanes(rel: np.ndarray, offset_mm: np.ndarray, inner_mm: np.ndarray, outer_mm: np.ndarray,
          clear_mm: np.ndarray, width_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The brightest value on the array and in the lane beside its outer edge, at each station.

    Parameters
    ----------
    rel : ndarray, shape (m, n)
        Brightness above the fluid's in units of the array's contrast (offsets × stations).
    offset_mm : ndarray, shape (m, n)
        Offset (mm, towards the outer wall positive) of each sample.
    inner_mm, outer_mm : ndarray, shape (n,)
        The array's edges (mm); NaN where not known.
    clear_mm : ndarray, shape (n,)
        Largest offset (mm) clear of the outer wall.
    width_mm : float
        The array's width (mm): the lane runs from a tenth of it (``_LANE_FROM``) to all of it
        past the outer edge.

    Returns
    -------
    on, beside : ndarray, shape (n,)
        NaN where the array's edges are not known, or the lane holds fewer than two samples.
    """
    on_array = (offset_mm >= inner_mm) & (offset_mm <= outer_mm)
    lane = (offset_mm > outer_mm + _LANE_FROM * width_mm) & (offset_mm <= np.minimum(outer_mm + width_mm, clear_mm))
    on = np.where(on_array.any(axis=0), np.where(on_array, rel, -np.inf).max(axis=0), np.nan)
    beside = np.where(lane.sum(axis=0) >= 2, np.where(lane, rel, -np.inf).max(axis=0), np.nan)
    return on, beside


def _banded(corr: float, spread: float, cfg: MeasureConfig) -> bool:
    """Whether a lane of this periodicity and spread (:func:`periodicity`) could be a train of
    bands (``cfg.shadow_correlation``, ``cfg.shadow_spread``); NaN could not."""
    return bool(corr >= cfg.shadow_correlation and spread >= cfg.shadow_spread)


def band_signals(edges: Edges, tip_f: float, plan: MeasurePlan) -> tuple[float, float, float]:
    """The lane beside the dark run's outer edge and the run itself, over the stretch before the
    tip (``MeasureConfig.shadow_length_mm`` to ``shadow_cap_mm`` from it): the lane's
    periodicity and spread, and the run's spread (contrast units; :func:`periodicity`), NaN
    where too little is seen; the run's only where the lane passes ``shadow_correlation`` and
    ``shadow_spread`` (else it does not matter). The lane is left out within
    ``shadow_band_margin_mm`` of the stations where the run's edges are not found (its own
    bands).

    Parameters
    ----------
    edges : Edges
        The frame's stage 2.
    tip_f : float
        The tip (fractional station from ``edges.lo``).
    plan : MeasurePlan
        The video's plan.
    """
    cfg: MeasureConfig = plan.cfg
    step = plan.step_mm
    j0 = max(0, int(tip_f) - int(cfg.shadow_length_mm / step))
    j1 = min(max(0, int(tip_f) - int(cfg.shadow_cap_mm / step)), edges.n)  # the tip may lie past the edges
    if j1 - j0 < _LEAST:
        return np.nan, np.nan, np.nan
    sl = slice(j0, j1)
    half = plan.half_mm[edges.lo + j0: edges.lo + j1]
    width = plan.array.tip_diameter_mm
    ok_in, ok_out = edges.ok_in[sl], edges.ok_out[sl]
    outer = np.where(ok_out, edges.v_out[sl], np.where(ok_in, edges.v_in[sl] + width, np.nan))
    inner = np.where(ok_in, edges.v_in[sl], outer - width)
    clear = half - cfg.shadow_clear_px / float(plan.pose.px_per_mm)
    # the run's own bands (no edges there), a little wider than its body or blurred along it,
    # show in the lane too: the stations near them are left out
    k = int(np.ceil(cfg.shadow_band_margin_mm / step))
    near_band = np.convolve(~np.isfinite(outer), np.ones(2 * k + 1), mode="same") > 0
    room = clear - (outer + _LANE_FROM * width) >= float(plan.u[1] - plan.u[0]) * half  # room for two offsets
    if np.count_nonzero(room & ~near_band) < _LEAST:  # too little of the lane (the array against the wall)
        return np.nan, np.nan, np.nan
    rel = (edges.fine[:, sl] - edges.fluid[sl].astype(np.float32)) / edges.contrast[sl].astype(np.float32)
    on, beside = lanes(rel, plan.u[:, None] * half[None, :], inner, outer, clear, width)
    beside[near_band] = np.nan
    corr, spread = periodicity(beside, step, cfg.shadow_period_mm, cfg.shadow_detrend_mm)
    if not _banded(corr, spread, cfg):  # not the bands: done
        return corr, spread, np.nan
    return corr, spread, periodicity(on, step, cfg.shadow_period_mm, cfg.shadow_detrend_mm)[1]


def bands_beside(edges: Edges, tip_f: float, plan: MeasurePlan) -> bool:
    """Whether the array's bands show beside the dark run's outer edge rather than on it: the
    lane beside it periodic (``MeasureConfig.shadow_correlation``), varying by
    ``shadow_spread`` contrast units or more and ``shadow_ratio`` times the run's own spread
    (:func:`band_signals`; see the module's notes).

    Parameters
    ----------
    edges : Edges
        The frame's stage 2.
    tip_f : float
        The tip (fractional station from ``edges.lo``).
    plan : MeasurePlan
        The video's plan.
    """
    corr, spread, spread_on = band_signals(edges, tip_f, plan)
    return _banded(corr, spread, plan.cfg) and bool(spread >= plan.cfg.shadow_ratio * spread_on)

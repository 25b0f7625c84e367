"""The channel past a measured tip: a regular pattern of stripes there is more of the array.

Metal bands as dull as the fluid, with little body between them, leave an array's apical part
showing only as faint stripes across the channel; the dark run, and the tip read from it, then
end where the plain body does, radians short, and the tip so read advances at the insertion's
speed frame after frame. Plain fluid past a tip has no such pattern. :func:`stripe_periodicity`
measures it: the autocorrelation of the channel's grey level along its backbone over the
millimetres past the tip, normalised by the whole profile's energy.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from tympani.vision.angles.config import MeasureConfig
from tympani.vision.angles.plan import MeasurePlan

# Why a frame whose channel past the tip shows a regular pattern of stripes is not measured.
STRIPES_PAST_TIP = "regular stripes along the channel past the tip (the array's bands going on, unseen?)"


def profile_periodicity(profiles: np.ndarray, step_mm: float, lags_mm: tuple[float, float],
                        detrend_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """How periodic grey-level profiles along the channel are, and how strongly they vary.

    Parameters
    ----------
    profiles : ndarray, shape (B, n)
        Grey levels at stations ``step_mm`` (mm) apart, one profile a row.
    step_mm : float
        Station spacing (mm).
    lags_mm : tuple of float
        Shortest and longest period (mm) sought.
    detrend_mm : float
        Length (mm) of the running mean taken off first (changes of the light along the channel).

    Returns
    -------
    correlation : ndarray, shape (B,)
        Per row, the largest autocorrelation of the detrended profile, normalised by its whole
        energy, over the lags from the first at which it turns negative (and the shortest
        period) to the longest period; 0 when it does not turn negative there; NaN for all
        rows when the profiles are too short.
    spread : ndarray, shape (B,)
        Per row, the standard deviation (grey levels) of the detrended profile.
    """
    x = np.asarray(profiles, dtype=np.float64)
    n_rows, n = x.shape
    width = max(3, int(round(detrend_mm / step_mm)) | 1)
    hi = min(int(lags_mm[1] / step_mm), n // 2)
    if n < 2 * width or hi < 2:
        return np.full(n_rows, np.nan), np.full(n_rows, np.nan)
    d = x - cv2.blur(x, (width, 1), borderType=cv2.BORDER_REPLICATE)  # less a running mean, edges repeated
    d -= d.mean(axis=1, keepdims=True)
    energy = np.einsum("ij,ij->i", d, d)
    spread = np.sqrt(energy / n)
    spectrum = np.fft.rfft(d, 2 * n, axis=1)
    acf = np.fft.irfft(spectrum * spectrum.conj(), 2 * n, axis=1)[:, 1 : hi + 1] / np.maximum(energy, 1e-300)[:, None]
    lag = np.arange(hi)
    negative = np.where(acf < 0.0, lag, hi)
    first = np.maximum(negative.min(axis=1), int(lags_mm[0] / step_mm) - 1)
    correlation = np.where(lag >= first[:, None], acf, -np.inf).max(axis=1)
    return np.where(np.isfinite(correlation) & (energy > 0), correlation, 0.0), spread


def stripe_periodicity(imgs: list[np.ndarray], plan: MeasurePlan, theta_tips: np.ndarray,
                       cfg: MeasureConfig) -> tuple[np.ndarray, np.ndarray]:
    """:func:`profile_periodicity` of the channel past measured tips, one frame each.

    Parameters
    ----------
    imgs : list of ndarray
        Grey frames (uint8 or float32) of the plan's shape.
    plan : MeasurePlan
        The video's plan.
    theta_tips : ndarray, shape (len(imgs),)
        Each frame's measured tip angle (rad).
    cfg : MeasureConfig
        ``stripe_*`` settings: the stretch sought starts ``stripe_skip_mm`` past the tip (its
        cap) and is ``stripe_length_mm`` long.

    Returns
    -------
    correlation, spread : ndarray, shape (len(imgs),)
        As :func:`profile_periodicity` (spread in grey levels) of the median grey level across
        the channel's interior at each station; NaN where the stretch is not wholly in view.
    """
    step = plan.step_mm
    length = int(round(cfg.stripe_length_mm / step))
    firsts = np.searchsorted(plan.station_theta, np.asarray(theta_tips, dtype=float)) + int(round(cfg.stripe_skip_mm / step))
    correlation, spread = np.full(len(imgs), np.nan), np.full(len(imgs), np.nan)
    seen, strips, interiors = [], [], []
    for b, first in enumerate(firsts.tolist()):
        span = slice(first, first + length)
        if first + length > plan.map_x.shape[1] or not plan.in_view[span].all():
            continue
        interior = plan.fine_penalty[:, span] == 0
        if not interior.any(axis=0).all():
            continue
        seen.append(b)
        strips.append(cv2.remap(imgs[b], plan.map_x[:, span], plan.map_y[:, span], cv2.INTER_LINEAR))
        interiors.append(interior)
    if not seen:
        return correlation, spread
    interior = np.stack(interiors)
    count = interior.sum(axis=1)
    ordered = np.sort(np.where(interior, np.stack(strips).astype(np.float64), np.inf), axis=1)  # interior first
    low = np.take_along_axis(ordered, ((count - 1) // 2)[:, None, :], axis=1)[:, 0]
    high = np.take_along_axis(ordered, (count // 2)[:, None, :], axis=1)[:, 0]
    correlation[seen], spread[seen] = profile_periodicity(0.5 * (low + high), step, cfg.stripe_lags_mm, cfg.stripe_detrend_mm)
    return correlation, spread

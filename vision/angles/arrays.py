"""Small array helpers the measurement's stages share: element picking, odd window lengths, a
quantile by sorting, a median by partition, running reductions down the offsets and the erosion
of masks along the stations."""

from __future__ import annotations

import numpy as np


def take2d(a: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``a[i, j]`` of a 2-D array (indices broadcast together), by one flat ``np.take``: the
    same values, several times cheaper than NumPy's two-array fancy indexing."""
    a = np.ascontiguousarray(a)
    return np.take(a.reshape(-1), i * a.shape[1] + j)


def odd_ceil(n: float) -> int:
    """The smallest odd integer (at least 1) not below ``n``."""
    k = max(1, int(np.ceil(n)))
    return k if k % 2 == 1 else k + 1


def quantile(x: np.ndarray, q: float) -> float:
    """The ``q``-quantile (0–1) of ``x`` by sorting (cheaper than ``np.percentile`` here)."""
    xs = np.sort(x)
    return float(xs[int(round(q * (len(xs) - 1)))])


def median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array without NaN, by partition (the same value, several times
    cheaper on short arrays)."""
    n = len(x)
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, (k - 1, k))
    return float(0.5 * (part[k - 1] + part[k]))


def accumulate_rows(ufunc: np.ufunc, a: np.ndarray) -> np.ndarray:
    """``ufunc.accumulate(a, axis=0)`` of a 2-D array, one whole row at a time: the same values
    (each row combined with the running result in the same order), several times cheaper than
    NumPy's accumulation along the first axis, which runs one column at a time."""
    out = np.empty_like(a)
    if len(a):
        out[0] = a[0]
    for k in range(1, len(a)):
        ufunc(out[k - 1], a[k], out=out[k])
    return out


def erode(mask: np.ndarray, reach: int) -> np.ndarray:
    """``mask`` where it also holds at the ``reach`` stations on either side (along the last
    axis, so rows of frames are eroded independently)."""
    out = mask.copy()
    for k in range(1, reach + 1):
        out[..., k:] &= mask[..., :-k]
        out[..., :-k] &= mask[..., k:]
        out[..., :k] = False
        out[..., -k:] = False
    return out

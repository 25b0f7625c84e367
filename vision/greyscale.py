"""Greyscale conversion of frames: one convention for every stage.

Videos and image folders decode to ``uint8`` grey, BGR or BGRA frames; those are converted with
OpenCV's BT.601 weights in fixed point (``cv2.cvtColor``), so the grey levels are exactly
OpenCV's. Other inputs (frames combined in float, test images) follow one rule, the scale of
:func:`as_float_gray`:

=========================  =====================================================
input                      grey level (0–255 scale)
=========================  =====================================================
``uint8``                  as is
``uint16``                 value / 257 (0–65535 onto 0–255)
``bool``                   0 or 255
other integers             value, clipped to 0–255
float                      0–1 scale when the maximum is at most 1 (times 255), else 0–255;
                           clipped to 0–255, NaN is 0
=========================  =====================================================

Colour images of those dtypes are weighted in float (B 0.114, G 0.587, R 0.299; alpha ignored).
:func:`to_gray` gives ``uint8`` levels (such inputs rounded to the nearest level);
:func:`as_float_gray` keeps float precision (for medians of several frames and sub-level
gradients).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["to_gray", "as_float_gray", "is_float_gray"]

_BGR_WEIGHTS = np.array([0.114, 0.587, 0.299], np.float32)


def _channels_last(image: np.ndarray) -> np.ndarray:
    """``image`` with a single channel axis dropped, its shape checked."""
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        raise ValueError(f"expected a (h, w), (h, w, 1), (h, w, 3) or (h, w, 4) image, got shape {image.shape}")
    return image


def to_gray(image: np.ndarray) -> np.ndarray:
    """An 8-bit greyscale copy of a frame.

    Parameters
    ----------
    image : ndarray
        ``(h, w)`` grey, ``(h, w, 1)``, ``(h, w, 3)`` BGR or ``(h, w, 4)`` BGRA; any dtype of
        the module's table (``uint8`` 0–255, ``uint16`` 0–65535, ``bool``, float 0–1 or 0–255).

    Returns
    -------
    ndarray of uint8, shape (h, w)
        Grey levels 0–255 (a new C-contiguous array; the input is not modified). ``uint8``
        colour is converted by ``cv2.cvtColor``; other dtypes are :func:`as_float_gray`
        rounded to the nearest level.

    Raises
    ------
    ValueError
        Another shape.
    """
    image = _channels_last(image)
    if image.dtype != np.uint8:
        return np.clip(np.rint(as_float_gray(image)), 0, 255).astype(np.uint8)
    if image.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return np.ascontiguousarray(cv2.cvtColor(np.ascontiguousarray(image), code))
    return np.array(image, order="C", copy=True)


def as_float_gray(image: np.ndarray) -> np.ndarray:
    """A greyscale float32 copy of a frame on the 0–255 scale, without rounding to 8 bits.

    Parameters
    ----------
    image : ndarray
        As for :func:`to_gray`. Colour images of any dtype are weighted in float (BT.601).

    Returns
    -------
    ndarray of float32, shape (h, w)
        Grey levels on the 0–255 scale (a new array).

    Raises
    ------
    ValueError
        Another shape.
    """
    image = _channels_last(image)
    if image.dtype == np.uint8:
        out = image.astype(np.float32)
    elif image.dtype == np.uint16:
        out = image.astype(np.float32) / 257.0
    elif image.dtype == np.bool_:
        out = image.astype(np.float32) * 255.0
    elif np.issubdtype(image.dtype, np.integer):
        out = np.clip(image, 0, 255).astype(np.float32)
    else:
        out = np.array(image, dtype=np.float32, order="C")  # our own copy, changed in place
        if out.size:
            cv2.patchNaNs(out.reshape(-1, 1), 0.0)  # NaN -> 0 in place; +-inf go to 255 and 0 in the clip
        largest = float(out.max()) if out.size else 0.0
        if largest <= 1.0:
            out *= 255.0
        np.clip(out, 0.0, 255.0, out=out)
    if out.ndim == 3:
        out = out[:, :, :3] @ _BGR_WEIGHTS
    return np.ascontiguousarray(out, dtype=np.float32)


def is_float_gray(image: np.ndarray) -> bool:
    """Whether :func:`as_float_gray` would return ``image``'s values unchanged (as a copy).

    True for a C-contiguous 2-D float32 image without NaNs whose grey levels lie in
    ``[0, 255]`` with a maximum above 1 (a maximum of at most 1 means the 0–1 scale), such
    as :func:`tympani.vision.registration.combine_frames` returns. Two reductions, no copy.

    Parameters
    ----------
    image : ndarray
        Any image.

    Returns
    -------
    bool
    """
    if not (isinstance(image, np.ndarray) and image.dtype == np.float32 and image.ndim == 2):
        return False
    if not image.flags.c_contiguous or image.size == 0:
        return False
    largest = float(image.max())  # NaN if any NaN: the comparison below is then False
    return 1.0 < largest <= 255.0 and float(image.min()) >= 0.0

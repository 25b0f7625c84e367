"""Lens distortion of a rendered (ideal pinhole) frame."""

from __future__ import annotations

import cv2
import numpy as np

from tympani.vision.frames import LensCalibration

__all__ = ["distort"]


def distort(image: np.ndarray, calibration: LensCalibration) -> np.ndarray:
    """The frame a camera with ``calibration``'s lens records of the ideal pinhole ``image``.

    Each recorded pixel shows the ideal image where ``cv2.undistortPoints`` (with the camera
    matrix as the new one) sends it, sampled bilinearly; ideal content beyond the frame repeats
    its edge. :func:`tympani.vision.frames.undistorter` inverts this up to interpolation blur and the
    parts of the ideal image a barrel lens pushes out of the frame.

    Parameters
    ----------
    image : ndarray
        Ideal frame, ``(h, w)`` or ``(h, w, 3)``, of ``calibration.image_size`` (px).
    calibration : LensCalibration
        The lens.

    Returns
    -------
    ndarray
        The distorted frame, same shape and dtype.
    """
    calibration.check_size(image.shape)
    h, w = image.shape[:2]
    k, d = calibration.opencv()
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1)[:, None, :]
    ideal = cv2.undistortPoints(pts, k, d, P=k).reshape(h, w, 2).astype(np.float32)
    return cv2.remap(image, ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

"""Overlays for checking a registration and a measurement by eye.

Everything is drawn in image pixels on a BGR copy of the frame: the registered channel walls
and entry (green), the spiral centre (magenta cross), the array's outline (yellow) and
centreline (cyan), the contact arc on the outer wall from ``theta_bot`` to ``theta_tip`` (red,
thick), the tip (red dot) and the contact start (orange dot), manual labels (white rings), and
the three angles as text. Geometry comes from :mod:`tympani.vision.geometry` mapped with the
registration's :class:`~tympani.vision.geometry.CameraPose`, so what is drawn is exactly what was
measured against.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Iterable, Mapping, Sequence

import cv2
import numpy as np

from tympani.vision.geometry import CameraPose, Phantom, entry_walls

__all__ = [
    "COLORS",
    "as_bgr",
    "draw_polyline",
    "draw_marker",
    "draw_registration",
    "draw_measurement",
    "draw_labels",
    "draw_text",
    "angle_lines",
    "annotate_frame",
]

#: BGR colours of the overlay elements.
COLORS: dict[str, tuple[int, int, int]] = {
    "wall": (0, 200, 0),
    "entry": (0, 140, 0),
    "centre": (255, 0, 255),
    "outline": (0, 230, 230),
    "centreline": (255, 255, 0),
    "contact": (0, 0, 255),
    "tip": (0, 0, 255),
    "bot": (0, 140, 255),
    "label": (255, 255, 255),
    "text": (255, 255, 255),
    "text_bg": (0, 0, 0),
}

_SHIFT = 4  # sub-pixel bits for OpenCV drawing


def _pose(registration: Any) -> CameraPose:
    """The camera pose of a Registration (``.pose``) or a CameraPose itself."""
    return getattr(registration, "pose", registration)


def as_bgr(image: np.ndarray) -> np.ndarray:
    """A ``uint8`` BGR copy of a grey, BGR or BGRA image (``uint8``, or float in [0, 1])."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = (np.clip(np.nan_to_num(img.astype(float)), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 1):
        return cv2.cvtColor(img.reshape(img.shape[:2]), cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img.copy()


#: Smallest size factor of the text (:func:`draw_text`): 0.45 * 0.8 is Hershey simplex about 8 px
#: tall, legible on a 320 px wide frame, where :func:`_scale` would give 5 px.
_MIN_TEXT_SCALE = 0.8


def _scale(image: np.ndarray) -> float:
    """Size factor for markers and text: 1 at 640 px width."""
    return max(0.5, image.shape[1] / 640.0)


def draw_polyline(
    image: np.ndarray,
    points_px: np.ndarray,
    color: tuple[int, int, int],
    *,
    thickness: int = 1,
    closed: bool = False,
) -> np.ndarray:
    """Draw a polyline in place with sub-pixel precision and anti-aliasing.

    Parameters
    ----------
    image : ndarray
        BGR ``uint8`` image, modified in place.
    points_px : ndarray, shape (n, 2)
        Vertices (px, x right, y down). Non-finite vertices split the line.
    color : tuple of int
        BGR colour.
    thickness : int
        Line width (px).
    closed : bool
        Join the last vertex to the first.

    Returns
    -------
    ndarray
        ``image``.
    """
    pts = np.asarray(points_px, dtype=float).reshape(-1, 2)
    finite = np.isfinite(pts).all(axis=1)
    # keep coordinates well inside int32 after the shift
    pts = np.clip(pts, -1e5, 1e5)
    runs, start = [], None
    for i, good in enumerate(np.append(finite, False)):
        if good and start is None:
            start = i
        elif not good and start is not None:
            if i - start >= 2:
                runs.append(np.round(pts[start:i] * (1 << _SHIFT)).astype(np.int32))
            start = None
    if runs:
        cv2.polylines(image, runs, closed and len(runs) == 1, color, int(thickness), cv2.LINE_AA, _SHIFT)
    return image


def draw_marker(
    image: np.ndarray,
    point_px: Sequence[float],
    color: tuple[int, int, int],
    *,
    kind: str = "dot",
    size_px: float = 4.0,
    thickness: int = 1,
) -> np.ndarray:
    """Draw a marker in place at ``point_px`` (px): ``"dot"`` (filled), ``"ring"`` or
    ``"cross"`` of radius ``size_px`` (px). Non-finite points are skipped."""
    x, y = (float(v) for v in np.asarray(point_px, dtype=float).reshape(-1)[:2])
    if not (math.isfinite(x) and math.isfinite(y)):
        return image
    c = (int(round(x * (1 << _SHIFT))), int(round(y * (1 << _SHIFT))))
    r = max(1, int(round(size_px * (1 << _SHIFT))))
    if kind == "dot":
        cv2.circle(image, c, r, color, -1, cv2.LINE_AA, _SHIFT)
    elif kind == "ring":
        cv2.circle(image, c, r, color, int(thickness), cv2.LINE_AA, _SHIFT)
    elif kind == "cross":
        cv2.line(image, (c[0] - r, c[1]), (c[0] + r, c[1]), color, int(thickness), cv2.LINE_AA, _SHIFT)
        cv2.line(image, (c[0], c[1] - r), (c[0], c[1] + r), color, int(thickness), cv2.LINE_AA, _SHIFT)
    else:
        raise ValueError(f"unknown marker kind {kind!r}")
    return image


def draw_registration(image: np.ndarray, registration: Any, phantom: Phantom, *, thickness: int = 1) -> np.ndarray:
    """Draw the registered phantom: both channel walls, the entry channel and the centre.

    Parameters
    ----------
    image : ndarray
        BGR ``uint8`` image, modified in place.
    registration : Registration or CameraPose
        Maps phantom mm to image px.
    phantom : Phantom
        Phantom geometry.
    thickness : int
        Line width (px).

    Returns
    -------
    ndarray
        ``image``.
    """
    pose = _pose(registration)
    for wall in (phantom.outer_wall, phantom.inner_wall):
        draw_polyline(image, pose.to_image(wall.points), COLORS["wall"], thickness=thickness)
    for seg in entry_walls(phantom):
        draw_polyline(image, pose.to_image(seg), COLORS["entry"], thickness=thickness)
    draw_marker(image, (pose.centre_x_px, pose.centre_y_px), COLORS["centre"], kind="cross",
                size_px=6 * _scale(image), thickness=thickness)
    return image


def _xy(value: Any) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    return arr.reshape(-1, 2) if arr.size >= 2 else None


def draw_measurement(
    image: np.ndarray, measurement: Any, registration: Any, phantom: Phantom, *, thickness: int = 1
) -> np.ndarray:
    """Draw a frame's measurement: array outline and centreline, contact arc, tip, contact start.

    Parameters
    ----------
    image : ndarray
        BGR ``uint8`` image, modified in place.
    measurement : FrameMeasurement
        With ``outline_mm``, ``centreline_mm``, ``tip_mm``, ``bot_mm`` (mm, or None),
        ``theta_tip``, ``theta_bot`` (rad) and ``ok``; missing attributes are skipped.
    registration : Registration or CameraPose
        Maps phantom mm to image px.
    phantom : Phantom
        Phantom geometry (for the contact arc on its outer wall).
    thickness : int
        Base line width (px).

    Returns
    -------
    ndarray
        ``image``.
    """
    pose = _pose(registration)
    s = _scale(image)
    outline = _xy(getattr(measurement, "outline_mm", None))
    if outline is not None:
        draw_polyline(image, pose.to_image(outline), COLORS["outline"], thickness=thickness, closed=True)
    centreline = _xy(getattr(measurement, "centreline_mm", None))
    if centreline is not None:
        draw_polyline(image, pose.to_image(centreline), COLORS["centreline"], thickness=thickness)
    tip_t = _float(getattr(measurement, "theta_tip", None))
    bot_t = _float(getattr(measurement, "theta_bot", None))
    if getattr(measurement, "ok", False) and math.isfinite(tip_t) and math.isfinite(bot_t) and tip_t > bot_t:
        wall = phantom.outer_wall
        run = (wall.theta >= bot_t) & (wall.theta <= tip_t)
        if run.sum() >= 2:
            draw_polyline(image, pose.to_image(wall.points[run]), COLORS["contact"], thickness=max(2, 3 * thickness))
    bot = _xy(getattr(measurement, "bot_mm", None))
    if bot is not None:
        draw_marker(image, pose.to_image(bot)[0], COLORS["bot"], size_px=3.5 * s)
    tip = _xy(getattr(measurement, "tip_mm", None))
    if tip is not None:
        draw_marker(image, pose.to_image(tip)[0], COLORS["tip"], size_px=3.5 * s)
    return image


def draw_labels(image: np.ndarray, labels_px: Mapping[str, Sequence[float] | None], *, thickness: int = 1) -> np.ndarray:
    """Draw manual labels in place: a ring (px radius ~6) and the label's name at each point.

    Parameters
    ----------
    image : ndarray
        BGR ``uint8`` image, modified in place.
    labels_px : mapping
        Name (e.g. ``"tip"``, ``"bot"``) to an image point ``(x, y)`` in px, or None.
    """
    s = _scale(image)
    for name, point in labels_px.items():
        if point is None:
            continue
        x, y = (float(v) for v in point)
        if not (math.isfinite(x) and math.isfinite(y)):
            continue
        draw_marker(image, (x, y), COLORS["label"], kind="ring", size_px=6 * s, thickness=thickness)
        cv2.putText(image, name, (int(x + 8 * s), int(y - 8 * s)), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * s,
                    COLORS["label"], 1, cv2.LINE_AA)
    return image


def _wrap(line: str, fits: Callable[[str], bool]) -> list[str]:
    """``line`` broken at spaces into pieces that ``fits`` (a word too long stays whole)."""
    pieces: list[str] = []
    for word in line.split(" "):
        if pieces and fits(pieces[-1] + " " + word):
            pieces[-1] += " " + word
        else:
            pieces.append(word)
    return pieces or [""]


def draw_text(image: np.ndarray, lines: Iterable[str], *, origin_px: tuple[int, int] = (6, 6)) -> np.ndarray:
    """Write lines of text in place at the top left (``origin_px``, px), on a dark box; a line
    wider than the image is broken at spaces."""
    lines = [str(line) for line in lines]
    if not lines:
        return image
    s = max(_scale(image), _MIN_TEXT_SCALE)  # below this the text is a few px tall: unreadable
    font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.45 * s, 1
    room = image.shape[1] - origin_px[0] - int(8 * s)
    lines = [piece for line in lines
             for piece in _wrap(line, lambda text: cv2.getTextSize(text, font, scale, thick)[0][0] <= room)]
    sizes = [cv2.getTextSize(line, font, scale, thick) for line in lines]
    step = max(h + b for (_, h), b in sizes) + int(4 * s)
    width = max(w for (w, _), _ in sizes)
    x0, y0 = origin_px
    box = image[y0 : y0 + step * len(lines) + int(4 * s), x0 : x0 + width + int(8 * s)]
    box[...] = (box * 0.35).astype(np.uint8)  # darken behind the text, keep the frame visible
    for i, line in enumerate(lines):
        y = y0 + (i + 1) * step
        cv2.putText(image, line, (x0 + int(4 * s), y), font, scale, COLORS["text"], thick, cv2.LINE_AA)
    return image


def _float(value: Any) -> float:
    try:
        return float(value) if value is not None else math.nan
    except (TypeError, ValueError):
        return math.nan


def _angle(value: Any) -> str:
    v = _float(value)
    return "--" if not math.isfinite(v) else f"{v:.3f} rad ({math.degrees(v):.1f} deg)"


def angle_lines(measurement: Any) -> list[str]:
    """Text lines with ``theta_tip``, ``theta_bot``, ``theta_con`` and, for a failed frame, the
    reason."""
    if measurement is None:
        return ["no measurement"]
    lines = [
        f"tip {_angle(getattr(measurement, 'theta_tip', None))}",
        f"bot {_angle(getattr(measurement, 'theta_bot', None))}",
        f"con {_angle(getattr(measurement, 'theta_con', None))}",
    ]
    if not getattr(measurement, "ok", False):
        lines.append(f"not ok: {getattr(measurement, 'reason', '') or 'no reason given'}"[:240])
    return lines


def annotate_frame(
    image: np.ndarray,
    registration: Any,
    phantom: Phantom,
    measurement: Any = None,
    *,
    labels_px: Mapping[str, Sequence[float] | None] | None = None,
    title: str | None = None,
) -> np.ndarray:
    """A BGR copy of ``image`` with the registration, the measurement, labels and angles drawn.

    Parameters
    ----------
    image : ndarray
        Grey or BGR ``uint8`` frame (not modified).
    registration : Registration or CameraPose
        Maps phantom mm to image px.
    phantom : Phantom
        Phantom geometry.
    measurement : FrameMeasurement, optional
        Drawn when given (see :func:`draw_measurement`).
    labels_px : mapping, optional
        Manual labels (name to ``(x, y)`` px).
    title : str, optional
        First text line (e.g. ``"trial 3  frame 120  4.000 s"``).

    Returns
    -------
    ndarray, shape (h, w, 3)
        The annotated ``uint8`` BGR image.
    """
    out = as_bgr(image)
    draw_registration(out, registration, phantom)
    if measurement is not None:
        draw_measurement(out, measurement, registration, phantom)
    if labels_px:
        draw_labels(out, labels_px)
    lines = ([title] if title else []) + angle_lines(measurement)
    return draw_text(out, lines)

"""The straightened channel of one registration (:func:`prepare_measurement`), built once per video.

The plan holds remap tables that straighten the channel into a strip (offsets across ×
stations along the channel), the channel's geometry at each station, which samples lie in the
channel's interior and in the image, and why no frame can be measured at the registration's
scale (:attr:`MeasurePlan.refusal`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from tympani.vision.angles.config import MeasureConfig
from tympani.vision.angles.definitions import AngleTable, angle_table, spiral_angle
from tympani.vision.geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    CameraPose,
    ElectrodeArray,
    Phantom,
    backbone_frame,
    channel_width,
    entry_frame,
)


class HasPose(Protocol):
    """A registration: anything with the phantom-to-image ``pose`` (:class:`CameraPose`), which
    :func:`prepare_measurement` and :func:`~tympani.vision.angles.measure_frame` accept."""

    pose: CameraPose


@dataclass(frozen=True, eq=False)
class MeasurePlan:
    """The straightened channel of one registration, built once and reused for every frame.

    Build it with :func:`prepare_measurement`. It has a ``pose`` so that it can be passed to
    :func:`measure_frame` in place of the registration. Strips are stored offsets × stations
    (across × along the channel).

    Parameters
    ----------
    pose : CameraPose
        Phantom-to-image similarity the strip was built for.
    image_shape : tuple of int
        ``(height, width)`` (px) of the frames.
    phantom, array, cfg : Phantom, ElectrodeArray, MeasureConfig
        Geometry and settings the strip was built for.
    map_x, map_y : ndarray, shape (offsets, stations), float32
        Image coordinates (px) of the strip's samples, for ``cv2.remap``.
    coarse_x, coarse_y : ndarray, shape (offsets_c, stations_c), float32
        The same for every ``cfg.coarse_stride``-th offset and station, from coarse offset
        ``coarse_row0`` on: only the offsets inside the channel somewhere, and one more either
        side for the coarse strip's 3×3 blur.
    coarse_row0 : int
        The first coarse offset kept (coarse offset ``c`` is fine offset ``c * coarse_stride``).
    coarse_penalty : ndarray, shape (offsets_c, stations_c), float32
        0 on samples of the channel's interior, a large number elsewhere.
    fine_penalty : ndarray, shape (offsets, stations), float32
        The same for the full strip.
    u : ndarray, shape (offsets,)
        Normalised lateral offset of each strip offset (−1 inner wall, +1 outer wall).
    p_mm : ndarray, shape (stations,)
        Backbone arc length (mm) of each station from the outer end of the entry channel.
    point_mm, normal : ndarray, shape (stations, 2)
        Backbone point (mm, phantom frame) and outward unit normal of each station.
    half_mm : ndarray, shape (stations,)
        Half the channel's width (mm) at each station.
    i_start : int
        First station of the spiral (at or after ``theta_start``).
    in_view : ndarray, shape (stations,), bool
        Stations whose interior samples all lie inside the image.
    angles : AngleTable
        The phantom's constants for the angles of measured points.
    station_theta : ndarray, shape (stations,)
        The angle (rad, unwrapped) of each station's backbone point.
    r_tip_mm : float
        The array's radius (mm) at its tip.
    refusal : str or None
        Why no frame of this registration can be measured (the array too small in the image,
        see ``MeasureConfig.min_tip_px``), or None.
    copy_shift_mm : tuple of float
        Where walls show twice, the phantom-frame vector (mm) from the registered walls to their
        other copy (the registration's ``parallax_px``); ``(0, 0)`` for single walls.
    gap_resolution_px : float
        How finely (px) the gap to the wall is told apart with this registration
        (:func:`gap_resolution`).
    """

    pose: CameraPose
    image_shape: tuple[int, int]
    phantom: Phantom
    array: ElectrodeArray
    cfg: MeasureConfig
    map_x: np.ndarray
    map_y: np.ndarray
    coarse_x: np.ndarray
    coarse_y: np.ndarray
    coarse_row0: int
    coarse_penalty: np.ndarray
    fine_penalty: np.ndarray
    u: np.ndarray
    p_mm: np.ndarray
    point_mm: np.ndarray
    normal: np.ndarray
    half_mm: np.ndarray
    i_start: int
    in_view: np.ndarray
    angles: AngleTable
    station_theta: np.ndarray
    r_tip_mm: float
    refusal: str | None = None
    copy_shift_mm: tuple[float, float] = (0.0, 0.0)
    gap_resolution_px: float = 2.0

    @property
    def step_mm(self) -> float:
        """Spacing (mm) of the stations along the backbone."""
        return float(self.p_mm[1] - self.p_mm[0])

    def to_mm(self, station: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Phantom-frame points (mm) at fractional stations and normalised lateral offsets.

        Parameters
        ----------
        station : ndarray, shape (n,)
            Fractional station indices.
        u : ndarray, shape (n,)
            Normalised lateral offsets (−1 inner wall, +1 outer wall).

        Returns
        -------
        ndarray, shape (n, 2)
        """
        station = np.minimum(np.maximum(np.atleast_1d(np.asarray(station, dtype=float)), 0), len(self.p_mm) - 1)
        i0 = np.minimum(station.astype(int), len(self.p_mm) - 2)
        f = (station - i0)[:, None]
        point = self.point_mm[i0] * (1 - f) + self.point_mm[i0 + 1] * f
        normal = self.normal[i0] * (1 - f) + self.normal[i0 + 1] * f
        normal /= np.hypot(normal[:, 0], normal[:, 1])[:, None]
        half = self.half_mm[i0] * (1 - f[:, 0]) + self.half_mm[i0 + 1] * f[:, 0]
        return point + (np.atleast_1d(np.asarray(u, dtype=float)) * half)[:, None] * normal


# _backbone_arc_length's last results, keyed by phantom: every video's plan of the same
# phantom reuses the 40001-point table (~7 ms each). Its arrays are read-only.
_ARC_LENGTH_CACHE: dict[Phantom, tuple[np.ndarray, np.ndarray]] = {}


def _backbone_arc_length(phantom: Phantom) -> tuple[np.ndarray, np.ndarray]:
    """Backbone angle (rad) and arc length (mm) from ``theta_start`` on a fine grid (40001 points).

    Memoised per phantom (the last few kept); the returned arrays are read-only.
    """
    table = _ARC_LENGTH_CACHE.get(phantom)
    if table is None:
        theta = np.linspace(phantom.theta_start, phantom.theta_end, 40001)
        pts, _, _ = backbone_frame(theta, phantom)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
        for a in (theta, s):
            a.flags.writeable = False
        if len(_ARC_LENGTH_CACHE) >= 4:
            _ARC_LENGTH_CACHE.clear()
        table = _ARC_LENGTH_CACHE[phantom] = (theta, s)
    return table


def _channel_stations(
    phantom: Phantom, step_mm: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Stations along the channel's backbone, ``step_mm`` (mm) apart, from the entry's outer end.

    Parameters
    ----------
    phantom : Phantom
        Phantom configuration.
    step_mm : float
        Station spacing (mm) along the backbone.

    Returns
    -------
    p_mm, point_mm, normal, half_mm : ndarray
        Arc length (mm), backbone point (mm), outward unit normal and half width (mm) per
        station.
    i_start : int
        First spiral station.
    """
    theta, s = _backbone_arc_length(phantom)
    entry = phantom.entry_length_mm
    p = np.arange(0.0, entry + s[-1] - 0.5 * step_mm, step_mm)
    spiral = p >= entry
    th = np.interp(p[spiral] - entry, s, theta)
    sp_pts, _, sp_nrm = backbone_frame(th, phantom)
    origin, x_w, n_w = entry_frame(phantom)
    back = entry - p[~spiral]
    en_pts = origin[None, :] - back[:, None] * x_w[None, :]
    en_nrm = np.repeat(n_w[None, :], len(back), axis=0)
    half_start = 0.5 * float(channel_width(phantom.theta_start, phantom))
    half = np.concatenate([np.full(len(back), half_start), 0.5 * channel_width(th, phantom)])
    return p, np.vstack([en_pts, sp_pts]), np.vstack([en_nrm, sp_nrm]), half, int(np.argmax(spiral))


def _scale_refusal(px_per_mm: float, array: ElectrodeArray, cfg: MeasureConfig) -> str | None:
    """Why frames at ``px_per_mm`` (px/mm) cannot be measured (``cfg.min_tip_px``), or None."""
    tip_px = 2.0 * float(array.radius(0.0)) * px_per_mm
    if tip_px >= cfg.min_tip_px:
        return None
    return (f"array too small in the image: its tip is {tip_px:.1f} px wide at {px_per_mm:.1f} px/mm "
            f"(at least {cfg.min_tip_px:g} px needed; film closer)")


def prepare_measurement(
    registration: HasPose | CameraPose,
    image_shape: tuple[int, ...],
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    cfg: MeasureConfig = MeasureConfig(),
    lens: Callable[[np.ndarray], np.ndarray] | None = None,
) -> MeasurePlan:
    """Build the straightened-channel strip of one registration (once per video).

    Stations run along the channel's backbone from the outer end of the entry channel through
    ``theta_start`` to ``theta_end``, ``cfg.station_step_px`` apart; offsets run across it at
    normalised lateral positions ``u`` (−1 inner wall, +1 outer wall), at most
    ``cfg.offset_step_px`` apart (both at least ``cfg.min_step_mm``).

    Parameters
    ----------
    registration : object with ``.pose``, or CameraPose
        The video's registration (phantom mm ↔ image px).
    image_shape : tuple of int
        Shape of the frames; the first two entries are (height, width) in px.
    phantom, array : Phantom, ElectrodeArray
        Geometry.
    cfg : MeasureConfig
        Settings.
    lens : callable, optional
        Maps ideal (pinhole) image points, an ``(n, 2)`` array in px, to where the camera's lens
        records them (e.g. :meth:`tympani.vision.frames.LensCalibration.distort_points`): the strip then
        samples the recorded frames themselves, and the pose is that of the undistorted image.

    Returns
    -------
    MeasurePlan
    """
    pose = registration if isinstance(registration, CameraPose) else registration.pose
    ppm = float(pose.px_per_mm)
    height, width = int(image_shape[0]), int(image_shape[1])
    p, pts, nrm, half, i_start = _channel_stations(phantom, max(cfg.station_step_px / ppm, cfg.min_step_mm))
    stride = max(1, int(cfg.coarse_stride))
    offset_step_px = max(cfg.offset_step_px, cfg.min_step_mm * ppm)
    n_u = int(np.ceil(2 * cfg.lateral_extent * half.max() * ppm / offset_step_px / stride)) * stride + 1
    u = np.linspace(-cfg.lateral_extent, cfg.lateral_extent, n_u)
    xy = pts[None, :, :] + (u[:, None, None] * half[None, :, None]) * nrm[None, :, :]
    img = pose.to_image(xy.reshape(-1, 2))
    img = (img if lens is None else lens(img)).reshape(n_u, len(p), 2)
    map_x = np.ascontiguousarray(img[..., 0], dtype=np.float32)
    map_y = np.ascontiguousarray(img[..., 1], dtype=np.float32)
    inside = (map_x >= 0) & (map_x <= width - 1) & (map_y >= 0) & (map_y <= height - 1)
    limit = np.maximum(1.0 - cfg.wall_margin_px / (half * ppm), cfg.min_interior)
    interior = np.abs(u)[:, None] <= limit[None, :]
    penalty = np.where(interior, 0.0, 1e4).astype(np.float32)
    # the coarse strip's offsets that are never inside the channel only feed the blur of their
    # neighbours: keep one either side of those that are (the survey's results do not change)
    table = angle_table(phantom)
    inside_c = np.flatnonzero(interior[::stride, ::stride].any(axis=1))
    rows = slice(max(int(inside_c[0]) - 1, 0), int(inside_c[-1]) + 2)
    return MeasurePlan(
        pose=pose, image_shape=(height, width), phantom=phantom, array=array, cfg=cfg,
        map_x=map_x, map_y=map_y,
        coarse_x=np.ascontiguousarray(map_x[::stride, ::stride][rows]),
        coarse_y=np.ascontiguousarray(map_y[::stride, ::stride][rows]), coarse_row0=rows.start,
        coarse_penalty=np.ascontiguousarray(penalty[::stride, ::stride][rows]), fine_penalty=penalty,
        u=u, p_mm=p, point_mm=pts, normal=nrm, half_mm=half, i_start=i_start,
        in_view=np.all(inside | ~interior, axis=0),
        angles=table, station_theta=spiral_angle(pts, table), r_tip_mm=float(array.radius(0.0)),
        refusal=_scale_refusal(ppm, array, cfg), copy_shift_mm=_copy_shift_mm(registration, pose),
        gap_resolution_px=gap_resolution(getattr(registration, "residual_px", None),
                                         bool(getattr(registration, "walls_doubled", False)), cfg),
    )


def gap_resolution(residual_px: float | None, walls_doubled: bool, cfg: MeasureConfig) -> float:
    """How finely (px) the gap to the wall is told apart with a registration whose walls fit
    with ``residual_px`` (px RMS; None or NaN: unknown): ``cfg.gap_resolution_px``, raised to
    ``cfg.residual_resolution`` times the residual, at most ``cfg.max_gap_resolution_px``; that
    much where the walls show twice (``walls_doubled``)."""
    resolution = float(cfg.gap_resolution_px)
    if residual_px is not None and math.isfinite(float(residual_px)):
        resolution = max(resolution, min(cfg.residual_resolution * float(residual_px), cfg.max_gap_resolution_px))
    if walls_doubled:
        resolution = max(resolution, float(cfg.max_gap_resolution_px))
    return resolution


def _copy_shift_mm(registration: HasPose | CameraPose, pose: CameraPose) -> tuple[float, float]:
    """The registration's ``parallax_px`` (px, image) as a phantom-frame vector (mm); zero for
    single walls or a bare pose."""
    shift = getattr(registration, "parallax_px", (0.0, 0.0)) if getattr(registration, "walls_doubled", False) else (
        0.0, 0.0)
    centre = np.array([pose.centre_x_px, pose.centre_y_px])
    a, b = pose.to_phantom(np.vstack([centre, centre + np.asarray(shift, dtype=float)]))
    return float(b[0] - a[0]), float(b[1] - a[1])

"""Synthetic overhead frames of the phantom with the electrode array, and their exact truth.

The renderer runs the measurement backwards: geometry (:mod:`vision.geometry`) → image.
Ground truth is computed from the very centreline that is drawn, with the angles' definitions
(docs/file-formats.md, :func:`vision.angles.contact_angles`).

Pieces, from geometry to file:

* :func:`array_centreline` — the array's centreline for a tip angle and contact start angle;
* :func:`pose_at_depth` — the same for an insertion depth, following a :class:`ContactPolicy`;
* :class:`Scene` — a static view (pose, appearance, nuisances) that draws frames;
* :class:`Nuisance`, :func:`random_nuisance`, :func:`random_harsh_nuisance` — what degrades a
  frame: noise, blur, uneven light and shadows, clutter and the gripper, bubbles in the fluid,
  doubled walls, glints, motion blur, JPEG;
* :func:`render_video` — a whole insertion to mp4 or a PNG folder, with a truth table;
* :func:`distort` — what a lens with a given :class:`vision.frames.LensCalibration` makes of
  a rendered (ideal pinhole) frame.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import brentq

from tympani.vision.angles import ContactAngles, contact_angles
from tympani.vision.frames import LensCalibration
from tympani.vision.geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    CameraPose,
    ElectrodeArray,
    Phantom,
    arc_length,
    backbone_frame,
    backbone_radius,
    channel_polygon,
    channel_width,
    entry_frame,
    entry_walls,
    point_angle,
)

__all__ = [
    "ArrayShape",
    "ContactPolicy",
    "ArrayState",
    "Appearance",
    "Nuisance",
    "VideoSpec",
    "Scene",
    "array_centreline",
    "array_at_angles",
    "pose_at_depth",
    "random_pose",
    "random_policy",
    "random_appearance",
    "random_nuisance",
    "random_harsh_nuisance",
    "BubbleLook",
    "ChannelPath",
    "channel_path",
    "bubble_ahead_of_tip",
    "render_video",
    "distort",
]


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


# --------------------------------------------------------------------------- array shape


@dataclass(frozen=True)
class ArrayShape:
    """How the array lies in the channel basal of its contact run.

    Parameters
    ----------
    departure_rad : float
        Angular span (rad) over which the array leaves the outer wall basal of theta_bot
        (the gap grows smoothly, quadratically at first).
    far_offset : float
        Where the array settles basally, as a fraction of the free lateral play: -1 on the
        inner wall, 0 on the backbone, +1 on the outer wall.
    start_blend_rad : float
        Angular span (rad) after theta_start over which the array leaves the insertion axis.
    contact_level : float
        1 when the tip rides the outer wall; below 1 the tip is short of it by that fraction
        of the lateral play (before first contact).
    """

    departure_rad: float = 0.5
    far_offset: float = -0.3
    start_blend_rad: float = 0.6
    contact_level: float = 1.0


@dataclass(frozen=True)
class ArrayState:
    """An array posed in the phantom, with its truth.

    Parameters
    ----------
    centreline_mm : ndarray, shape (n, 2)
        Centreline (mm, phantom frame) from the tip to the base.
    s_mm : ndarray, shape (n,)
        Arc length (mm) from the tip.
    radius_mm : ndarray, shape (n,)
        Half-width (mm) of the array body at each point.
    depth_mm : float
        Length (mm) of array past the entry's end at theta_start.
    truth : ContactAngles
        The angles of this centreline (as the measurement defines them).
    """

    centreline_mm: np.ndarray
    s_mm: np.ndarray
    radius_mm: np.ndarray
    depth_mm: float
    truth: ContactAngles


def _spiral_part(
    theta_tip: float, theta_bot: float, shape: ArrayShape, phantom: Phantom, array: ElectrodeArray, step_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Centreline (mm) of the array inside the spiral, tip first, and arc length (mm) from the tip."""
    n = max(50, int((theta_tip - phantom.theta_start) * 8.0 / step_mm))
    theta = np.linspace(theta_tip, phantom.theta_start, n)  # tip first
    pts, _, normal = backbone_frame(theta, phantom)
    half = 0.5 * channel_width(theta, phantom)
    start_blend = _smoothstep((theta - phantom.theta_start) / shape.start_blend_rad)
    depart = _smoothstep((theta_bot - theta) / shape.departure_rad)
    radius = array.radius(np.zeros(n))
    for _ in range(3):  # the radius depends on arc length, which depends on the offset
        play = np.maximum(half - radius, 0.0)
        e_far = shape.far_offset * 0.85 * play * start_blend
        e_touch = e_far + shape.contact_level * (play - e_far)
        e = e_touch + (e_far - e_touch) * depart
        spiral = pts + e[:, None] * normal
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(spiral, axis=0).T))])
        radius = array.radius(s)
    return spiral, s


def array_centreline(
    theta_tip: float,
    theta_bot: float,
    *,
    shape: ArrayShape = ArrayShape(),
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    step_mm: float = 0.02,
    contact_tol_mm: float = 0.05,
) -> ArrayState:
    """Pose the array with its tip at ``theta_tip`` riding the outer wall back to ``theta_bot``.

    In the channel the centreline is a normal offset ``e(theta)`` of the backbone: from the tip to
    ``theta_bot`` the array's outer edge lies on the outer wall; basal of it the array departs
    smoothly towards ``shape.far_offset``; near ``theta_start`` it joins the insertion axis,
    along which the rest of the array runs straight out of the entry.

    Parameters
    ----------
    theta_tip : float
        Tip angle (rad), ``theta_start < theta_tip < theta_end``.
    theta_bot : float
        Nominal contact start angle (rad), ``<= theta_tip``. The true contact start of the
        result (``truth.theta_bot``) lies slightly basal of it, where the smooth departure's
        gap reaches ``contact_tol_mm``.
    shape : ArrayShape
        Departure and settling of the basal part.
    phantom, array : Phantom, ElectrodeArray
        Geometry.
    step_mm : float
        Approximate spacing (mm) of the centreline samples.
    contact_tol_mm : float
        Contact tolerance (mm) for the truth.

    Returns
    -------
    ArrayState
    """
    if not phantom.theta_start < theta_tip < phantom.theta_end:
        raise ValueError(f"theta_tip={theta_tip:.3f} rad is outside the channel")
    if theta_bot > theta_tip:
        raise ValueError("theta_bot must not exceed theta_tip")
    spiral, s = _spiral_part(theta_tip, theta_bot, shape, phantom, array, step_mm)
    depth = float(s[-1])
    origin, x_w, _ = entry_frame(phantom)
    rest = max(array.length_mm - depth, 0.0)
    m = max(2, int(np.ceil(rest / (4 * step_mm))) + 1)
    back = np.linspace(0.0, rest, m)[1:]
    straight = origin[None, :] - back[:, None] * x_w[None, :]
    centreline = np.vstack([spiral, straight])
    s_all = np.concatenate([s, depth + back])
    keep = s_all <= array.length_mm
    centreline, s_all = centreline[keep], s_all[keep]
    radius_all = array.radius(s_all)
    truth = contact_angles(
        centreline[: len(s)], radius_all[: len(s)], phantom, contact_tol_mm=contact_tol_mm
    )
    return ArrayState(centreline, s_all, radius_all, depth, truth)


def array_at_angles(
    theta_tip: float,
    theta_bot: float,
    *,
    shape: ArrayShape = ArrayShape(),
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    tol_rad: float = 1e-4,
    max_iter: int = 20,
) -> ArrayState:
    """Pose the array so that its *measured* tip and contact start angles are the given ones.

    :func:`array_centreline` places the nominal angles; the truth of the result differs
    slightly (the contact start lies where the departing edge's gap reaches the tolerance). This
    corrects the nominal angles until the truth matches, e.g. to render the paper's TABLE III.

    Parameters
    ----------
    theta_tip, theta_bot : float
        Wanted tip and contact start angles (rad), ``theta_bot < theta_tip``.
    shape, phantom, array
        As :func:`array_centreline`.
    tol_rad : float
        Largest difference (rad) accepted between the truth and the wanted angles.
    max_iter : int
        Most corrections tried.

    Returns
    -------
    ArrayState

    Raises
    ------
    ValueError
        When the angles cannot be reached (outside the channel, or not converging).
    """
    tip_nom, bot_nom = float(theta_tip), float(theta_bot)
    for _ in range(max_iter):
        state = array_centreline(tip_nom, min(bot_nom, tip_nom), shape=shape, phantom=phantom, array=array)
        d_tip = theta_tip - state.truth.theta_tip
        d_bot = theta_bot - state.truth.theta_bot
        if abs(d_tip) <= tol_rad and abs(d_bot) <= tol_rad:
            return state
        tip_nom += d_tip
        bot_nom += d_bot
    raise ValueError(f"cannot pose the array at theta_tip={theta_tip:.3f}, theta_bot={theta_bot:.3f} rad "
                     f"(off by {d_tip:+.4f}, {d_bot:+.4f} rad after {max_iter} corrections)")


@dataclass(frozen=True)
class ContactPolicy:
    """How the contact run grows with depth during one insertion.

    Before ``theta_first`` the tip approaches the outer wall over ``approach_rad``; from there
    on it rides the wall and the contact start follows
    ``theta_bot = theta_first + lag * (theta_tip - theta_first)``.

    Parameters
    ----------
    theta_first : float
        Tip angle (rad) at first contact with the outer wall.
    lag : float
        Fraction (0–1) of the tip's advance that the contact start follows.
    approach_rad : float
        Angular span (rad) before first contact over which the tip closes on the wall.
    shape : ArrayShape
        Departure and settling of the basal part.
    """

    theta_first: float = 1.4
    lag: float = 0.3
    approach_rad: float = 0.6
    shape: ArrayShape = ArrayShape()

    def at(self, theta_tip: float) -> tuple[float, ArrayShape]:
        """Nominal contact start (rad) and shape for a tip angle (rad)."""
        if theta_tip >= self.theta_first:
            return self.theta_first + self.lag * (theta_tip - self.theta_first), self.shape
        level = float(_smoothstep(1.0 - (self.theta_first - theta_tip) / self.approach_rad))
        return theta_tip, replace(self.shape, contact_level=level)


def pose_at_depth(
    depth_mm: float,
    policy: ContactPolicy = ContactPolicy(),
    *,
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
) -> ArrayState:
    """The array at insertion depth ``depth_mm`` (mm), its contact run following ``policy``.

    Depths at or below zero put the tip on the insertion axis behind the entry's end.
    """
    if depth_mm <= 0.0:
        return _outside_pose(depth_mm, phantom, array)
    lo, hi = phantom.theta_start + 1e-4, phantom.theta_end - 1e-3

    def excess(theta_tip: float) -> float:
        theta_bot, shape = policy.at(theta_tip)
        return float(_spiral_part(theta_tip, theta_bot, shape, phantom, array, 0.02)[1][-1]) - depth_mm

    if excess(hi) < 0:
        raise ValueError(f"depth {depth_mm} mm is beyond the end of the channel")
    theta_tip = brentq(excess, lo, hi, xtol=1e-7) if excess(lo) < 0 else lo
    theta_bot, shape = policy.at(theta_tip)
    return array_centreline(theta_tip, theta_bot, shape=shape, phantom=phantom, array=array)


def _outside_pose(depth_mm: float, phantom: Phantom, array: ElectrodeArray) -> ArrayState:
    origin, x_w, _ = entry_frame(phantom)
    s = np.linspace(0.0, array.length_mm, 200)
    centreline = origin[None, :] + (depth_mm - s)[:, None] * x_w[None, :]
    radius = array.radius(s)
    truth = contact_angles(centreline[:2], radius[:2], phantom)
    return ArrayState(centreline, s, radius, float(depth_mm), truth)


# --------------------------------------------------------------------------- appearance


@dataclass(frozen=True)
class Appearance:
    """How the phantom and array look (grey levels 0–255 before nuisances).

    Parameters
    ----------
    background : float
        Phantom material outside the channel.
    fluid : float
        Lubricant inside the channel (equal to ``background`` when walls are only lines).
    wall_style : {"lines", "region", "both"}
        Walls as thin lines, as the boundary between fluid and background, or both.
    wall_level : float
        Grey level of wall lines.
    wall_width_px : float
        Width (px) of wall lines.
    array_level : float
        Silicone body of the array (darker than the fluid).
    band_level : float
        Platinum bands.
    tint : tuple of float
        Per-channel (B, G, R) gains of the colour image.
    """

    background: float = 185.0
    fluid: float = 205.0
    wall_style: str = "both"
    wall_level: float = 90.0
    wall_width_px: float = 2.0
    array_level: float = 70.0
    band_level: float = 230.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Nuisance:
    """Image degradations and clutter, each off at zero (the defaults draw a clean frame).

    None of these touches the array's geometry, so none changes the truth.

    Parameters
    ----------
    noise_sigma : float
        Standard deviation of additive sensor noise (grey levels).
    blur_sigma_px : float
        Gaussian blur (px) of the whole frame (focus).
    illumination : float
        Relative amplitude (0–0.5) of a smooth, uneven illumination field.
    flicker : float
        Relative standard deviation of the per-frame global gain.
    jpeg_quality : int or None
        Re-encode every frame as JPEG of this quality (1–100; 15–20 is heavy compression).
    distractors : int
        Number of objects outside the channel (screws, a ruler); a gripper holding the array's
        base is drawn when this is at least 1.
    bubbles : int
        Number of free air bubbles in the channel fluid; each drifts slowly along the channel
        (bouncing at its ends) at about ``bubble_drift_mm_s``.
    bubble_at_tip : float or None
        Gap (mm) between the array's tip apex and the edge of a bubble just apical of it,
        pushed along with the tip (0 = touching the apex; 0.1–1 mm = ahead of it).
        None: no such bubble.
    bubble_radius_mm : float or None
        Radius (mm) of every bubble; None draws each log-uniformly from 0.15 mm to the widest
        half channel (0.75 mm by default). A bubble never spans more than the channel: where
        it is narrower the radius is cut to the local half width (mm) less half a wall line.
    bubble_drift_mm_s : float
        Typical speed (mm/s) of the free bubbles along the channel.
    doubled_wall_mm : float
        Parallax (mm, typically 0.1–0.5) between a wall's top and bottom edge in a thick
        plate: every wall is drawn a second time displaced by this much (0 = single walls).
    doubled_wall_contrast : float
        Contrast (0–1) of the second wall relative to the first.
    doubled_wall_direction_rad : float or None
        Image direction (rad, ``atan2(dy, dx)`` in pixel coordinates, y down) of the
        displacement; None draws it at random.
    glints : float
        Strength (0–1) of specular glints on the metal bands: each band's glint flickers
        with the frame time; at 1 a glint saturates.
    plate_glints : int
        Number of static specular reflections (bright spots) on the plate.
    motion_blur_px : float
        Length (px) of the smear of the moving parts (array, gripper) during one exposure,
        along the array's local direction (centred on the frame's instant).
    shadows : float
        Darkness (0–0.9) of soft shadows across part of the image (on top of
        ``illumination``) and of the gripper's shadow.
    gripper_overlap_mm : float
        Length (mm) of the array's straight part, next to its base, that the gripper's jaw
        hides; the jaw stops 0.5 mm short of the entry channel (outside the entry).
    """

    noise_sigma: float = 0.0
    blur_sigma_px: float = 0.0
    illumination: float = 0.0
    flicker: float = 0.0
    jpeg_quality: int | None = None
    distractors: int = 0
    bubbles: int = 0
    bubble_at_tip: float | None = None
    bubble_radius_mm: float | None = None
    bubble_drift_mm_s: float = 0.1
    doubled_wall_mm: float = 0.0
    doubled_wall_contrast: float = 0.7
    doubled_wall_direction_rad: float | None = None
    glints: float = 0.0
    plate_glints: int = 0
    motion_blur_px: float = 0.0
    shadows: float = 0.0
    gripper_overlap_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be 1–100, not {self.jpeg_quality}")
        if self.bubble_at_tip is not None and self.bubble_at_tip < 0:
            raise ValueError("bubble_at_tip must be a gap >= 0 mm or None")
        if self.bubble_radius_mm is not None and self.bubble_radius_mm <= 0:
            raise ValueError("bubble_radius_mm must be > 0 mm or None")
        if not 0.0 <= self.doubled_wall_contrast <= 1.0:
            raise ValueError("doubled_wall_contrast must be 0–1")
        if not 0.0 <= self.shadows <= 0.9:
            raise ValueError("shadows must be 0–0.9")
        for name in ("bubbles", "plate_glints", "doubled_wall_mm", "glints", "motion_blur_px",
                     "gripper_overlap_mm", "bubble_drift_mm_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative")

    @property
    def has_bubbles(self) -> bool:
        """Whether any bubble is drawn."""
        return self.bubbles > 0 or self.bubble_at_tip is not None


@dataclass(frozen=True)
class VideoSpec:
    """One synthetic insertion video.

    Parameters
    ----------
    pose : CameraPose
        Phantom-to-image similarity.
    width, height : int
        Frame size (px).
    fps : float
        Frame rate (1/s).
    speed_mm_s : float
        Insertion speed (mm/s).
    start_depth_mm, end_depth_mm : float
        Depth (mm) at the first frame and where the robot stops.
    dwell_s : float
        Time (s) recorded after the robot stops.
    policy : ContactPolicy
        How the contact run grows.
    appearance : Appearance
    nuisance : Nuisance
    max_frames : int or None
        Cap on the number of frames: a longer recording is written at a lower frame rate
        (:meth:`effective_fps`), so that ``frame / fps`` stays each frame's time.
    """

    pose: CameraPose
    width: int = 640
    height: int = 480
    fps: float = 30.0
    speed_mm_s: float = 1.0
    start_depth_mm: float = -1.0
    end_depth_mm: float = 15.0
    dwell_s: float = 0.0
    policy: ContactPolicy = ContactPolicy()
    appearance: Appearance = Appearance()
    nuisance: Nuisance = Nuisance()
    max_frames: int | None = None

    def duration_s(self) -> float:
        """Length (s) of the recording: the insertion plus the dwell."""
        return (self.end_depth_mm - self.start_depth_mm) / self.speed_mm_s + self.dwell_s

    def effective_fps(self) -> float:
        """Frame rate (1/s) of the written video: ``fps``, lowered when ``max_frames`` caps it."""
        n = int(np.floor(self.duration_s() * self.fps)) + 1
        if self.max_frames is not None and n > self.max_frames:
            return (self.max_frames - 1) / self.duration_s()
        return self.fps

    def frame_times(self) -> np.ndarray:
        """Times (s) of the frames, ``index / effective_fps()``."""
        fps = self.effective_fps()
        n = int(np.floor(self.duration_s() * fps + 1e-9)) + 1
        return np.arange(n) / fps

    def depth_at(self, time_s: np.ndarray) -> np.ndarray:
        """Insertion depth (mm) at ``time_s`` (s)."""
        return np.minimum(self.start_depth_mm + self.speed_mm_s * np.asarray(time_s), self.end_depth_mm)


# --------------------------------------------------------------------------- nuisance helpers


@dataclass(frozen=True)
class ChannelPath:
    """The channel's middle line from the entry's basal end to its closed end, with its frame.

    Parameters
    ----------
    points_mm : ndarray, shape (n, 2)
        Points (mm, phantom frame): the entry's axis, then the backbone.
    tangent, normal : ndarray, shape (n, 2)
        Unit tangent (apical) and unit normal (towards the outer wall).
    half_width_mm : ndarray, shape (n,)
        Half the channel's width (mm).
    u_mm : ndarray, shape (n,)
        Arc length (mm) from the entry's basal end.
    theta : ndarray, shape (n,)
        Backbone angle (rad); ``theta_start`` along the entry.
    """

    points_mm: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray
    half_width_mm: np.ndarray
    u_mm: np.ndarray
    theta: np.ndarray

    def at(self, u_mm: np.ndarray, lateral_mm: np.ndarray) -> np.ndarray:
        """Points (mm) at arc length ``u_mm`` (mm) and normal offset ``lateral_mm`` (mm)."""
        u = np.atleast_1d(np.asarray(u_mm, dtype=float))
        lat = np.broadcast_to(np.asarray(lateral_mm, dtype=float), u.shape)
        p = np.stack([np.interp(u, self.u_mm, self.points_mm[:, k]) for k in range(2)], axis=1)
        n = np.stack([np.interp(u, self.u_mm, self.normal[:, k]) for k in range(2)], axis=1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return p + lat[:, None] * n

    def half_width(self, u_mm: np.ndarray | float) -> np.ndarray:
        """Half the channel's width (mm) at arc length ``u_mm`` (mm)."""
        return np.interp(u_mm, self.u_mm, self.half_width_mm)

    def locate(self, xy_mm: np.ndarray, phantom: Phantom = DEFAULT_PHANTOM) -> tuple[float, float]:
        """Arc length (mm) and normal offset (mm) of a point in or near the channel.

        The point is matched with the path within about half a turn of its (unwrapped) angle, so a
        point is never matched with a neighbouring turn; behind the entry the arc length is
        negative.
        """
        xy = np.asarray(xy_mm, dtype=float).reshape(2)
        theta = float(point_angle(xy[None, :], phantom)[0])
        cand = np.flatnonzero(np.abs(self.theta - theta) < 0.6)
        if cand.size == 0:
            cand = np.arange(len(self.u_mm))
        j = cand[np.argmin(np.hypot(*(self.points_mm[cand] - xy).T))]
        rel = xy - self.points_mm[j]
        return float(self.u_mm[j] + rel @ self.tangent[j]), float(rel @ self.normal[j])


def channel_path(phantom: Phantom = DEFAULT_PHANTOM, step_mm: float = 0.05) -> ChannelPath:
    """The channel's middle line (entry axis, then backbone) sampled about ``step_mm`` (mm) apart."""
    origin, x_w, n_w = entry_frame(phantom)
    n_e = max(2, int(np.ceil(phantom.entry_length_mm / step_mm)) + 1)
    back = np.linspace(phantom.entry_length_mm, 0.0, n_e)[:-1]  # the origin comes with the spiral
    entry_pts = origin[None, :] - back[:, None] * x_w[None, :]
    r_max = float(backbone_radius(phantom.theta_start, phantom))
    n_s = int(np.ceil((phantom.theta_end - phantom.theta_start) * r_max / step_mm)) + 1
    theta = np.linspace(phantom.theta_start, phantom.theta_end, n_s)
    pts, tangent, normal = backbone_frame(theta, phantom)
    points = np.vstack([entry_pts, pts])
    half = 0.5 * np.concatenate([np.full(len(back), float(channel_width(phantom.theta_start, phantom))),
                                 channel_width(theta, phantom)])
    return ChannelPath(
        points_mm=points,
        tangent=np.vstack([np.tile(x_w, (len(back), 1)), tangent]),
        normal=np.vstack([np.tile(n_w, (len(back), 1)), normal]),
        half_width_mm=half,
        u_mm=arc_length(points),
        theta=np.concatenate([np.full(len(back), phantom.theta_start), theta]),
    )


def _bubble_fit(path: ChannelPath, u_mm: np.ndarray, radius_mm: float, lateral_mm: np.ndarray,
                wall_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Radius (mm) and normal offset (mm) of a bubble at ``u_mm`` cut to fit the channel.

    The radius is cut to the half width less ``wall_mm`` (mm, half a wall line); the offset
    is clamped so that the disc stays clear of both wall lines.
    """
    room = np.maximum(path.half_width(u_mm) - wall_mm, 0.05)
    radius = np.minimum(radius_mm, room)
    return radius, np.clip(lateral_mm, -(room - radius), room - radius)


def bubble_ahead_of_tip(
    state: ArrayState,
    radius_mm: float,
    gap_mm: float,
    path: ChannelPath,
    *,
    phantom: Phantom = DEFAULT_PHANTOM,
    wall_mm: float = 0.05,
) -> tuple[np.ndarray, float] | None:
    """Where a bubble just apical of the array's tip sits.

    The bubble keeps the tip's offset from the channel's middle line (clamped so that it fits
    the channel) and lies apical of the tip, its edge ``gap_mm`` from the tip apex (the first
    centreline point; 0 = touching it).

    Parameters
    ----------
    state : ArrayState
        The array.
    radius_mm : float
        Wanted radius (mm); cut to fit the channel there.
    gap_mm : float
        Distance (mm) from the tip apex to the bubble's edge.
    path : ChannelPath
        The channel (:func:`channel_path`).
    phantom : Phantom
        Geometry.
    wall_mm : float
        Half a wall line's width (mm): the bubble stays clear of it.

    Returns
    -------
    (centre_mm, radius_mm) or None
        Centre (mm, phantom frame) and radius (mm); None when the tip is not in the channel
        yet or the bubble would not fit before the channel's closed end.
    """
    apex = state.centreline_mm[0]
    u_tip, e_tip = path.locate(apex, phantom)
    if u_tip < 0.0 or u_tip > path.u_mm[-1]:
        return None
    reach = radius_mm + gap_mm
    u = u_tip + np.linspace(0.0, 2.0 * reach + 1.0, 400)
    radius, lateral = _bubble_fit(path, u, radius_mm, np.full(len(u), e_tip), wall_mm)
    # distance from the apex to the nearest point of the disc centred at each candidate
    edge_gap = np.hypot(*(path.at(u, lateral) - apex).T) - radius
    if edge_gap[0] >= gap_mm:
        return None
    k = int(np.argmax(edge_gap >= gap_mm))
    if k == 0:
        return None
    w = (gap_mm - edge_gap[k - 1]) / max(edge_gap[k] - edge_gap[k - 1], 1e-12)
    u_b = u[k - 1] + w * (u[k] - u[k - 1])
    r_b, lat_b = _bubble_fit(path, np.array([u_b]), radius_mm, np.array([e_tip]), wall_mm)
    if u_b + r_b[0] > path.u_mm[-1]:
        return None
    return path.at(np.array([u_b]), lat_b)[0], float(r_b[0])


@dataclass(frozen=True)
class BubbleLook:
    """How one air bubble looks (grey levels 0–255).

    Parameters
    ----------
    core : float
        Grey level of the bright inside.
    rim : float
        Grey level of the dark rim.
    rim_frac : float
        Rim thickness as a fraction (0–1) of the radius (never under about 1 px).
    highlight : float
        Extra brightness (grey levels) of a small specular dot.
    light_rad : float
        Image direction (rad) of that dot from the centre.
    """

    core: float
    rim: float
    rim_frac: float
    highlight: float
    light_rad: float


def _random_bubble_look(rng: np.random.Generator, fluid: float, light_rad: float) -> BubbleLook:
    """A bubble look around a fluid grey level ``fluid`` (0–255), lit from ``light_rad`` (rad)."""
    return BubbleLook(
        core=float(min(252.0, fluid + rng.uniform(15.0, 55.0))),
        rim=float(fluid * rng.uniform(0.15, 0.6)),
        rim_frac=float(rng.uniform(0.1, 0.4)),
        highlight=float(rng.uniform(0.0, 90.0)),
        light_rad=float(light_rad + rng.normal(0.0, 0.2)),
    )


def _bubble_patch(
    centre_px: np.ndarray, radius_px: float, look: BubbleLook
) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
    """Coverage and grey level of a bubble over the pixels it touches.

    Parameters
    ----------
    centre_px : ndarray, shape (2,)
        Centre (px).
    radius_px : float
        Radius (px).
    look : BubbleLook

    Returns
    -------
    bbox : (x0, y0, x1, y1)
        Pixel box (unclipped) of the patch.
    alpha, level : ndarray
        Anti-aliased coverage (0–1) and grey level of each pixel of the box.
    """
    cx, cy = (float(v) for v in centre_px)
    x0, y0 = int(np.floor(cx - radius_px)) - 2, int(np.floor(cy - radius_px)) - 2
    x1, y1 = int(np.ceil(cx + radius_px)) + 3, int(np.ceil(cy + radius_px)) + 3
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    d = np.hypot(xs - cx, ys - cy)
    alpha = np.clip(radius_px - d + 0.5, 0.0, 1.0)
    rim = max(look.rim_frac, 1.2 / max(radius_px, 1e-6))
    # the rim darkens over its inner half and stays dark out to the edge
    ramp = _smoothstep((d / radius_px - (1.0 - rim)) / (0.5 * rim))
    level = look.core + (look.rim - look.core) * ramp
    hx = cx + 0.45 * radius_px * np.cos(look.light_rad)
    hy = cy + 0.45 * radius_px * np.sin(look.light_rad)
    sigma = max(0.12 * radius_px, 0.7)
    level = level + look.highlight * np.exp(-((xs - hx) ** 2 + (ys - hy) ** 2) / (2 * sigma**2)) * (1 - ramp)
    return (x0, y0, x1, y1), alpha.astype(np.float32), level.astype(np.float32)


def _paste(img: np.ndarray, bbox: tuple[int, int, int, int], alpha: np.ndarray, level: np.ndarray) -> None:
    """Blend ``level`` over ``img`` in place with coverage ``alpha`` on an unclipped pixel box."""
    x0, y0, x1, y1 = bbox
    h, w = img.shape[:2]
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx1 <= cx0 or cy1 <= cy0:
        return
    a = alpha[cy0 - y0 : cy1 - y0, cx0 - x0 : cx1 - x0]
    v = level[cy0 - y0 : cy1 - y0, cx0 - x0 : cx1 - x0]
    img[cy0:cy1, cx0:cx1] = img[cy0:cy1, cx0:cx1] * (1 - a) + v * a


def _gaussian_spot(shape: tuple[int, int], centre_px: np.ndarray, along: np.ndarray, sigma_along_px: float,
                  sigma_across_px: float, amplitude: float) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """An elongated Gaussian spot (grey levels) on the pixels it reaches (3 sigma).

    Parameters
    ----------
    shape : (height, width)
        Frame size (px): the returned box is clipped to it.
    centre_px : ndarray, shape (2,)
        Centre (px).
    along : ndarray, shape (2,)
        Unit image direction of the long axis.
    sigma_along_px, sigma_across_px : float
        Standard deviations (px) along and across ``along``.
    amplitude : float
        Peak (grey levels).

    Returns
    -------
    bbox, spot
        Clipped pixel box ``(x0, y0, x1, y1)`` and the spot's values over it.
    """
    reach = 3.0 * max(sigma_along_px, sigma_across_px)
    cx, cy = (float(v) for v in centre_px)
    x0, y0 = max(int(np.floor(cx - reach)), 0), max(int(np.floor(cy - reach)), 0)
    x1, y1 = min(int(np.ceil(cx + reach)) + 1, shape[1]), min(int(np.ceil(cy + reach)) + 1, shape[0])
    if x1 <= x0 or y1 <= y0:
        return (0, 0, 0, 0), np.zeros((0, 0), np.float32)
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    dx, dy = xs - cx, ys - cy
    a = dx * along[0] + dy * along[1]
    c = -dx * along[1] + dy * along[0]
    spot = amplitude * np.exp(-0.5 * ((a / sigma_along_px) ** 2 + (c / sigma_across_px) ** 2))
    return (x0, y0, x1, y1), spot.astype(np.float32)


def _line_kernel(direction: np.ndarray, length_px: float) -> np.ndarray:
    """A normalised kernel (sums to 1) that smears along the unit image ``direction`` over
    ``length_px`` (px), centred: a motion blur of constant speed."""
    half = int(np.ceil(0.5 * length_px)) + 1
    k = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    n = max(2, int(np.ceil(length_px)) * 2 + 1)
    t = np.linspace(-0.5 * length_px, 0.5 * length_px, n)
    x, y = half + t * direction[0], half + t * direction[1]
    ix, iy = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - ix, y - iy
    # each sample split bilinearly over its four pixels
    for ox, oy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (iy + oy, ix + ox), wt)
    return k / k.sum()


def _shadow_field(rng: np.random.Generator, width: int, height: int, darkness: float) -> np.ndarray:
    """A multiplicative field (0–1) of 1–3 soft shadows: blobs and straight-edged strips.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the shapes.
    width, height : int
        Frame size (px).
    darkness : float
        Largest darkening (0–1) of a shadow's core.

    Returns
    -------
    ndarray, shape (height, width), float32
    """
    lo_w, lo_h = max(8, width // 8), max(8, height // 8)  # smooth: computed coarse, then resized
    ys, xs = np.mgrid[0:lo_h, 0:lo_w].astype(np.float32)
    xs, ys = xs / lo_w * width, ys / lo_h * height
    diag = float(np.hypot(width, height))
    field = np.ones((lo_h, lo_w), np.float32)
    for _ in range(int(rng.integers(1, 4))):
        depth = darkness * rng.uniform(0.5, 1.0)
        soft = rng.uniform(0.2, 0.7)
        a = rng.uniform(0, 2 * np.pi)
        c, s = np.cos(a), np.sin(a)
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        dx, dy = xs - cx, ys - cy
        if rng.random() < 0.6:  # an elliptical blob
            ax, ay = rng.uniform(0.1, 0.35, size=2) * diag
            rho = np.hypot((c * dx + s * dy) / ax, (-s * dx + c * dy) / ay)
            core = 1.0 - _smoothstep((rho - (1 - soft)) / (2 * soft))
        else:  # a strip (an arm's shadow) with soft edges
            half = rng.uniform(0.04, 0.15) * diag
            dist = np.abs(-s * dx + c * dy)
            core = 1.0 - _smoothstep((dist - half * (1 - soft)) / (2 * soft * half))
        field *= 1.0 - depth * core
    return cv2.resize(field, (width, height), interpolation=cv2.INTER_LINEAR)


def _glint_flicker(time_s: float, freq_hz: np.ndarray, phase_rad: np.ndarray) -> np.ndarray:
    """Glint strength (0–1) at ``time_s`` (s): a clipped, sharpened sine per band."""
    return np.clip(np.sin(2 * np.pi * freq_hz * time_s + phase_rad), 0.0, 1.0) ** 2


@dataclass(frozen=True)
class _FreeBubble:
    u0_mm: float
    lateral: float  # offset as a fraction (-1..1) of the free room
    radius_mm: float
    speed_mm_s: float
    look: BubbleLook

    def at(self, time_s: float, path: ChannelPath, wall_mm: float) -> tuple[np.ndarray, float]:
        """Centre (mm) and radius (mm) at ``time_s`` (s): drifting, bouncing at the channel's ends."""
        lo, hi = self.radius_mm, max(path.u_mm[-1] - self.radius_mm, self.radius_mm + 1e-3)
        span = hi - lo
        x = (self.u0_mm + self.speed_mm_s * time_s - lo) % (2 * span)
        u = np.array([lo + (x if x < span else 2 * span - x)])
        radius, _ = _bubble_fit(path, u, self.radius_mm, np.zeros(1), wall_mm)
        room = np.maximum(path.half_width(u) - wall_mm - radius, 0.0)
        return path.at(u, self.lateral * room)[0], float(radius[0])


# --------------------------------------------------------------------------- scene


class Scene:
    """A fixed view of the phantom (pose, appearance, nuisances) that draws frames.

    The static part (phantom, doubled walls, clutter, illumination and shadows, the looks of
    bubbles and glints) is computed once; each frame adds the bubbles, the array, the gripper
    and the per-frame degradations. Nuisances that are off draw no random numbers, so a scene
    without them renders exactly as before they existed.

    Parameters
    ----------
    pose : CameraPose
    width, height : int
        Frame size (px).
    appearance : Appearance
    nuisance : Nuisance
    phantom, array : Phantom, ElectrodeArray
    rng : numpy.random.Generator
        Source of all randomness (clutter placement, noise).
    """

    SUPERSAMPLE = 4

    def __init__(
        self,
        pose: CameraPose,
        width: int = 640,
        height: int = 480,
        appearance: Appearance = Appearance(),
        nuisance: Nuisance = Nuisance(),
        *,
        phantom: Phantom = DEFAULT_PHANTOM,
        array: ElectrodeArray = DEFAULT_ARRAY,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.pose, self.width, self.height = pose, width, height
        self.appearance, self.nuisance = appearance, nuisance
        self.phantom, self.array = phantom, array
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.wall_parallax_px = self._wall_parallax()
        self.background = self._static_background()
        self.gain = self._illumination_field()
        nu = nuisance
        if nu.shadows > 0:
            self.gain = self.gain * _shadow_field(self.rng, width, height, nu.shadows)
        self._path = channel_path(phantom) if nu.has_bubbles else None
        self._free_bubbles = [self._new_free_bubble() for _ in range(nu.bubbles)]
        self._tip_bubble = self._new_tip_bubble() if nu.bubble_at_tip is not None else None
        self._glint = self._new_band_glints() if nu.glints > 0 else None
        self._plate_glint = self._plate_glints() if nu.plate_glints > 0 else None
        self._grip_shadow_px = self._gripper_shadow_offset() if nu.shadows > 0 and nu.distractors else None

    # -- static part
    def _coverage(self, polygons_px: list[np.ndarray], bbox: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Anti-aliased coverage (0–1) of filled polygons (px), over ``bbox`` = (x0, y0, x1, y1)."""
        x0, y0, x1, y1 = bbox if bbox is not None else (0, 0, self.width, self.height)
        k = self.SUPERSAMPLE
        canvas = np.zeros(((y1 - y0) * k, (x1 - x0) * k), np.uint8)
        shift = 4
        pts = [
            np.round(((p - [x0, y0]) * k + (k - 1) / 2.0) * (1 << shift)).astype(np.int32) for p in polygons_px
        ]
        cv2.fillPoly(canvas, pts, 255, lineType=cv2.LINE_8, shift=shift)
        small = cv2.resize(canvas, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        return small.astype(np.float32) / 255.0

    def _wall_lines_px(self) -> list[np.ndarray]:
        ph = self.phantom
        outer_e, inner_e = entry_walls(ph)
        cap = np.stack([ph.inner_wall.points[-1], ph.outer_wall.points[-1]])
        lines = [outer_e, inner_e, ph.outer_wall.points, ph.inner_wall.points, cap]
        return [self.pose.to_image(line) for line in lines]

    def _line_coverage(self, lines_px: list[np.ndarray], width_px: float) -> np.ndarray:
        """Anti-aliased coverage of polylines drawn ``width_px`` wide."""
        polys = []
        for line in lines_px:
            seg = np.diff(line, axis=0)
            norm = np.linalg.norm(seg, axis=1, keepdims=True)
            good = norm[:, 0] > 1e-9
            seg, p0, p1 = seg[good] / norm[good], line[:-1][good], line[1:][good]
            off = 0.5 * width_px * np.stack([-seg[:, 1], seg[:, 0]], axis=1)
            # each segment as a quad, slightly lengthened so neighbours overlap
            ext = 0.5 * width_px * seg
            quads = np.stack([p0 - ext + off, p1 + ext + off, p1 + ext - off, p0 - ext - off], axis=1)
            polys.extend(list(quads))
        return self._coverage(polys)

    def _wall_parallax(self) -> np.ndarray | None:
        """Image displacement (px) of the walls' second copy, or None without doubled walls."""
        nu = self.nuisance
        if nu.doubled_wall_mm <= 0:
            return None
        a = nu.doubled_wall_direction_rad
        a = float(self.rng.uniform(0, 2 * np.pi)) if a is None else float(a)
        return nu.doubled_wall_mm * self.pose.px_per_mm * np.array([np.cos(a), np.sin(a)])

    def _static_background(self) -> np.ndarray:
        ap, h, w = self.appearance, self.height, self.width
        shift, contrast = self.wall_parallax_px, self.nuisance.doubled_wall_contrast
        img = np.full((h, w), ap.background, np.float32)
        if ap.wall_style in ("region", "both"):
            outline = self.pose.to_image(channel_polygon(self.phantom))
            inside = self._coverage([outline])
            img += (ap.fluid - ap.background) * inside
            if shift is not None:
                # between a wall's two edges (its side face) the level is part way between
                # fluid and background: two steps instead of one
                moved = self._coverage([outline + shift])
                img += 0.5 * contrast * (ap.fluid - ap.background) * (moved - inside)
        if ap.wall_style in ("lines", "both"):
            lines = self._wall_lines_px()
            if shift is not None:
                cov = contrast * self._line_coverage([line + shift for line in lines], ap.wall_width_px)
                img = img * (1 - cov) + ap.wall_level * cov
            cov = self._line_coverage(lines, ap.wall_width_px)
            img = img * (1 - cov) + ap.wall_level * cov
        if self.nuisance.distractors:
            img = self._draw_distractors(img)
        return img

    def _free_spot(self, radius_px: float, tries: int = 200) -> np.ndarray | None:
        """A random image point at least ``radius_px`` clear of the channel and its axis."""
        far = self.pose.to_image(np.array([[0.0, 0.0]]))[0]
        channel_px = self.pose.to_image(channel_polygon(self.phantom))
        origin, x_w, _ = entry_frame(self.phantom)
        axis_px = self.pose.to_image(origin[None, :] - np.linspace(0, 40, 60)[:, None] * x_w[None, :])
        keep_out = np.vstack([channel_px, axis_px, far[None, :]])
        for _ in range(tries):
            p = self.rng.uniform([radius_px, radius_px], [self.width - radius_px, self.height - radius_px])
            if np.min(np.hypot(*(keep_out - p).T)) > radius_px + 4 * self.pose.px_per_mm:
                return p
        return None

    def _draw_distractors(self, img: np.ndarray) -> np.ndarray:
        ppm = self.pose.px_per_mm
        for i in range(self.nuisance.distractors):
            if i % 2 == 0:  # a screw head with a slot
                rad = self.rng.uniform(1.0, 2.0) * ppm
                c = self._free_spot(rad)
                if c is None:
                    continue
                level = self.rng.uniform(40, 120)
                ang = np.linspace(0, 2 * np.pi, 48, endpoint=False)
                disc = c + rad * np.stack([np.cos(ang), np.sin(ang)], axis=1)
                cov = self._coverage([disc])
                img = img * (1 - cov) + level * cov
                a = self.rng.uniform(0, np.pi)
                d = np.array([np.cos(a), np.sin(a)])
                slot = np.stack([c - rad * 0.8 * d, c + rad * 0.8 * d])
                cov = self._line_coverage([slot], max(1.5, 0.15 * rad))
                img = img * (1 - cov) + (level + 80) * cov
            else:  # a ruler: a bright strip with tick marks
                c = self._free_spot(3 * ppm)
                if c is None:
                    continue
                a = self.rng.uniform(0, np.pi)
                d, nrm = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
                length = self.rng.uniform(4, 8) * ppm
                strip = np.stack([c - length * d - ppm * nrm, c + length * d - ppm * nrm,
                                  c + length * d + ppm * nrm, c - length * d + ppm * nrm])
                cov = self._coverage([strip])
                img = img * (1 - cov) + 235.0 * cov
                ticks = [np.stack([c + t * d - ppm * nrm, c + t * d - (0.3 + 0.3 * (k % 5 == 0)) * ppm * nrm])
                         for k, t in enumerate(np.arange(-length, length, ppm))]
                cov = self._line_coverage(ticks, 1.2)
                img = img * (1 - cov) + 40.0 * cov
        return img

    def _illumination_field(self) -> np.ndarray:
        amp = self.nuisance.illumination
        if amp <= 0:
            return np.ones((self.height, self.width), np.float32)
        yy, xx = np.mgrid[0 : self.height, 0 : self.width].astype(np.float32)
        xx, yy = xx / self.width - 0.5, yy / self.height - 0.5
        a = self.rng.uniform(0, 2 * np.pi)
        cx, cy = self.rng.uniform(-0.3, 0.3, size=2)
        ramp = np.cos(a) * xx + np.sin(a) * yy
        vignette = (xx - cx) ** 2 + (yy - cy) ** 2
        field = 1.0 + amp * (1.2 * ramp - 1.5 * vignette + 0.2)
        return np.clip(field, 0.2, 2.0).astype(np.float32)

    # -- per frame
    def array_layers(self, state: ArrayState) -> tuple[np.ndarray, np.ndarray]:
        """Coverage (0–1) of the array body and of its bands in the frame."""
        body, bands, _ = self._array_layers(state)
        return body, bands

    def _array_layers(
        self, state: ArrayState, pad_px: int = 0
    ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int] | None]:
        """Coverage (0–1) of the body and the bands, and the pixel box (x0, y0, x1, y1) they
        were drawn in (the array's box grown by ``pad_px``; None when off the frame)."""
        c, s, rad = state.centreline_mm, state.s_mm, state.radius_mm.copy()
        cap = s < rad[0]  # rounded tip: a half disc whose apex is the tip point
        rad[cap] = np.sqrt(np.maximum(rad[0] ** 2 - (rad[0] - s[cap]) ** 2, 0.0))
        tangent = np.gradient(c, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        nrm = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        left, right = c + rad[:, None] * nrm, c - rad[:, None] * nrm
        body = self.pose.to_image(np.vstack([left, right[::-1]]))
        x0, y0 = np.floor(body.min(axis=0)).astype(int) - 2 - pad_px
        x1, y1 = np.ceil(body.max(axis=0)).astype(int) + 3 + pad_px
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, self.width), min(y1, self.height)
        full_body = np.zeros((self.height, self.width), np.float32)
        full_bands = np.zeros_like(full_body)
        if x1 <= x0 or y1 <= y0:
            return full_body, full_bands, None
        bbox = (x0, y0, x1, y1)
        full_body[y0:y1, x0:x1] = self._coverage([body], bbox)
        bands = []
        for a, b in self.array.band_intervals():
            sel = (s >= a) & (s <= b)
            if sel.sum() >= 2:
                bands.append(self.pose.to_image(np.vstack([left[sel], right[sel][::-1]])))
        if bands:
            full_bands[y0:y1, x0:x1] = self._coverage(bands, bbox)
        return full_body, full_bands, bbox

    def _gripper(self, state: ArrayState) -> list[np.ndarray]:
        """The gripper's jaw (px): it holds the array's base, reaching ``gripper_overlap_mm``
        over the array's straight part but never closer than 0.5 mm to the entry channel."""
        base = state.centreline_mm[-1]
        origin, x_w, nrm = entry_frame(self.phantom)
        front = base
        overlap = self.nuisance.gripper_overlap_mm
        if overlap > 0:
            along = float((base - origin) @ x_w)  # negative: behind the entry's end
            limit = -(self.phantom.entry_length_mm + 0.5)
            front = base + (min(along + overlap, max(limit, along)) - along) * x_w
        jaw = np.stack([front + 1.5 * nrm, base - 4 * x_w + 1.5 * nrm, base - 4 * x_w - 1.5 * nrm, front - 1.5 * nrm])
        return [self.pose.to_image(jaw)]

    def _image_direction(self, v_mm: np.ndarray) -> np.ndarray:
        """Unit image direction of the phantom-frame direction ``v_mm``."""
        d = self.pose.to_image(np.stack([np.zeros(2), v_mm]))
        d = d[1] - d[0]
        return d / np.linalg.norm(d)

    def _bbox(self, poly_px: np.ndarray, pad_px: int) -> tuple[int, int, int, int] | None:
        """Pixel box (x0, y0, x1, y1) of a polygon grown by ``pad_px`` and clipped to the frame."""
        x0, y0 = np.maximum(np.floor(poly_px.min(axis=0)).astype(int) - 2 - pad_px, 0)
        x1, y1 = np.minimum(np.ceil(poly_px.max(axis=0)).astype(int) + 3 + pad_px, [self.width, self.height])
        return (int(x0), int(y0), int(x1), int(y1)) if x1 > x0 and y1 > y0 else None

    def _gripper_shadow_offset(self) -> np.ndarray:
        """Image offset (px) of the gripper's shadow: 0.8–2.5 mm in a random direction."""
        a = self.rng.uniform(0, 2 * np.pi)
        return self.rng.uniform(0.8, 2.5) * self.pose.px_per_mm * np.array([np.cos(a), np.sin(a)])

    def _draw_gripper(self, img: np.ndarray, state: ArrayState) -> np.ndarray:
        """``img`` with the gripper's soft shadow and the gripper (smeared when it moves) on it."""
        nu = self.nuisance
        jaw = self._gripper(state)[0]
        if self._grip_shadow_px is not None:
            sigma = max(0.4 * self.pose.px_per_mm, 1.0)
            shadow = jaw + self._grip_shadow_px
            box = self._bbox(shadow, int(np.ceil(3 * sigma)))
            if box is not None:
                x0, y0, x1, y1 = box
                cov = cv2.GaussianBlur(self._coverage([shadow], box), (0, 0), sigma)
                img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - nu.shadows * cov)
        pad = int(np.ceil(0.5 * nu.motion_blur_px)) + 1 if nu.motion_blur_px > 0 else 0
        box = self._bbox(jaw, pad)
        if box is not None:
            x0, y0, x1, y1 = box
            grip = self._coverage([jaw], box)
            if pad:  # the gripper moves along the insertion axis
                d = self._image_direction(entry_frame(self.phantom)[1])
                grip = cv2.filter2D(grip, -1, _line_kernel(d, nu.motion_blur_px), borderType=cv2.BORDER_CONSTANT)
            img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - grip) + 50.0 * grip
        return img

    # -- bubbles
    def _wall_mm(self) -> float:
        """Half a wall line (mm) and a little more: bubbles keep clear of the wall lines."""
        return 0.5 * self.appearance.wall_width_px / self.pose.px_per_mm + 0.02

    def _bubble_radius(self) -> float:
        """``bubble_radius_mm``, or a radius (mm) drawn log-uniformly from 0.15 mm to the widest
        half channel."""
        if self.nuisance.bubble_radius_mm is not None:
            return float(self.nuisance.bubble_radius_mm)
        return float(np.exp(self.rng.uniform(np.log(0.15), np.log(0.5 * self.phantom.width_max_mm))))

    def _new_free_bubble(self) -> _FreeBubble:
        radius = self._bubble_radius()
        speed = self.nuisance.bubble_drift_mm_s * self.rng.uniform(0.5, 1.5) * self.rng.choice([-1.0, 1.0])
        return _FreeBubble(
            u0_mm=float(self.rng.uniform(0.0, self._path.u_mm[-1])),
            lateral=float(self.rng.uniform(-1.0, 1.0)),
            radius_mm=radius,
            speed_mm_s=float(speed),
            look=_random_bubble_look(self.rng, self.appearance.fluid, float(self.rng.uniform(0, 2 * np.pi))),
        )

    def _new_tip_bubble(self) -> tuple[float, BubbleLook]:
        radius = self._bubble_radius()
        return radius, _random_bubble_look(self.rng, self.appearance.fluid, float(self.rng.uniform(0, 2 * np.pi)))

    def tip_bubble(self, state: ArrayState) -> tuple[np.ndarray, float] | None:
        """Centre (mm, phantom frame) and radius (mm) of the bubble drawn ahead of the array's
        tip in ``state``; None when there is none (off, tip outside the channel, no room)."""
        if self._tip_bubble is None:
            return None
        return bubble_ahead_of_tip(state, self._tip_bubble[0], float(self.nuisance.bubble_at_tip), self._path,
                                   phantom=self.phantom, wall_mm=self._wall_mm())

    def bubbles_at(self, state: ArrayState, time_s: float) -> list[tuple[np.ndarray, float, BubbleLook]]:
        """Every bubble drawn at ``time_s`` (s): centre (mm), radius (mm) and look."""
        wall = self._wall_mm()
        out = [(*b.at(time_s, self._path, wall), b.look) for b in self._free_bubbles]
        tip = self.tip_bubble(state)
        if tip is not None:
            out.append((tip[0], tip[1], self._tip_bubble[1]))
        return out

    def _with_bubbles(self, state: ArrayState, time_s: float) -> np.ndarray:
        """The static background with the bubbles at ``time_s`` (s) on it."""
        img = self.background.copy()
        for centre, radius, look in self.bubbles_at(state, time_s):
            _paste(img, *_bubble_patch(self.pose.to_image(centre)[0], radius * self.pose.px_per_mm, look))
        return img

    # -- glints
    def _new_band_glints(self) -> dict[str, np.ndarray | float]:
        """Per band: flicker frequency (Hz), phase (rad) and peak (0.5–1); the lit side (-0.5..0.5
        of the radius, one lamp for all bands)."""
        n = self.array.n_bands
        return dict(freq=self.rng.uniform(1.5, 7.0, n), phase=self.rng.uniform(0, 2 * np.pi, n),
                    peak=self.rng.uniform(0.5, 1.0, n), side=float(self.rng.uniform(-0.5, 0.5)))

    def _band_glints(
        self, state: ArrayState, bands: np.ndarray, bbox: tuple[int, int, int, int], time_s: float
    ) -> np.ndarray:
        """Additive grey levels of the band glints at ``time_s`` (s): a core kept on the bands'
        coverage and a weaker bloom around it, inside the array's pixel box ``bbox``."""
        g, ppm = self._glint, self.pose.px_per_mm
        out = np.zeros((self.height, self.width), np.float32)
        mids = self.array.band_intervals().mean(axis=1)
        strength = self.nuisance.glints * g["peak"] * _glint_flicker(time_s, g["freq"], g["phase"])
        keep = (mids < state.s_mm[-1] - 0.05) & (strength > 1e-3)
        if not keep.any():
            return out
        mids, strength = mids[keep], strength[keep]
        c, s = state.centreline_mm, state.s_mm

        def at(q: np.ndarray) -> np.ndarray:
            return np.stack([np.interp(q, s, c[:, 0]), np.interp(q, s, c[:, 1])], axis=1)

        tangent = at(mids - 0.05) - at(mids + 0.05)  # apical
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        centre = self.pose.to_image(at(mids) + (g["side"] * self.array.radius(mids))[:, None] * normal)
        along = self.pose.to_image(at(mids) + tangent) - self.pose.to_image(at(mids))
        along /= np.linalg.norm(along, axis=1, keepdims=True)
        peak = max(330.0 - self.appearance.band_level, 100.0)  # at full strength a glint saturates
        sig_along = max(0.3 * self.array.band_length_mm * ppm, 0.8)
        x0, y0, x1, y1 = bbox
        h, w = y1 - y0, x1 - x0
        core, bloom = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
        centre = centre - [x0, y0]
        for k in range(len(mids)):
            sig_across = max(0.15 * float(self.array.radius(mids[k])) * ppm, 0.6)
            amp = float(strength[k] * peak)
            (a0, b0, a1, b1), spot = _gaussian_spot((h, w), centre[k], along[k], sig_along, sig_across, amp)
            core[b0:b1, a0:a1] += spot
            # a saturated glint blooms past the band onto the body and the fluid
            (a0, b0, a1, b1), spot = _gaussian_spot((h, w), centre[k], along[k], 2.5 * sig_along,
                                                   3.0 * sig_across, 0.5 * amp)
            bloom[b0:b1, a0:a1] += spot
        out[y0:y1, x0:x1] = core * bands[y0:y1, x0:x1] + bloom
        return out

    def _plate_glints(self) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
        """Static lamp reflections on the plate (0.15–0.8 mm spots): pixel boxes and the grey
        levels they add."""
        ppm = self.pose.px_per_mm
        out = []
        for _ in range(self.nuisance.plate_glints):
            centre = self.rng.uniform([0, 0], [self.width, self.height])
            a = self.rng.uniform(0, np.pi)
            sig = self.rng.uniform(0.15, 0.8) * ppm
            out.append(_gaussian_spot((self.height, self.width), centre, np.array([np.cos(a), np.sin(a)]), sig,
                                     sig / self.rng.uniform(1.0, 3.0), float(self.rng.uniform(60, 220))))
        return out

    # -- motion blur
    def _motion_field(self, state: ArrayState, bbox: tuple[int, int, int, int]) -> np.ndarray:
        """Unit image direction (an (h, w, 2) image of x, y over ``bbox``) in which the array
        moves (apically along itself), near the array; zero elsewhere."""
        x0, y0, x1, y1 = bbox
        length = self.nuisance.motion_blur_px
        c = self.pose.to_image(state.centreline_mm)
        spacing = float(np.median(np.hypot(*np.diff(c, axis=0).T)))
        step = max(1, int(round(6.0 / max(spacing, 1e-6))))  # vertices about 6 px apart
        p = c[np.unique(np.r_[np.arange(0, len(c), step), len(c) - 1])]
        t = -np.gradient(p, axis=0)  # the centreline runs tip to base: apical is backwards
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
        reach = 0.5 * length + 3.0  # the smear reaches ahead of the tip
        p = np.vstack([p[0] + reach * t[0], p])
        t = np.vstack([t[0], t])
        thick = int(np.ceil(2 * state.radius_mm.max() * self.pose.px_per_mm + length + 6))
        field = np.zeros((y1 - y0, x1 - x0, 2), np.float32)
        q = np.round((p - [x0, y0]) * 16).astype(np.int32)
        for j in range(len(p) - 1):
            a, b = (int(q[j, 0]), int(q[j, 1])), (int(q[j + 1, 0]), int(q[j + 1, 1]))
            cv2.line(field, a, b, (float(t[j, 0]), float(t[j, 1])), thick, cv2.LINE_8, 4)
        return field

    def _motion_blurred(
        self, state: ArrayState, bbox: tuple[int, int, int, int], layers: list[np.ndarray | None]
    ) -> list[np.ndarray | None]:
        """The array's layers averaged over the exposure: each pixel near the array samples the
        layers along the array's local direction, ``motion_blur_px`` long and centred on it.
        The layers are overwritten."""
        x0, y0, x1, y1 = bbox
        length = self.nuisance.motion_blur_px
        field = self._motion_field(state, bbox)
        dx, dy = field[..., 0], field[..., 1]
        ys, xs = np.nonzero(np.any(field != 0, axis=2))
        present = [k for k, layer in enumerate(layers) if layer is not None]
        if len(ys) == 0 or not present:
            return layers
        stack = np.dstack([layers[k][y0:y1, x0:x1] for k in present])
        # only the pixels near the array are resampled, laid out as a block of 256-wide rows
        # (OpenCV's maps must stay under 32767 px a side)
        m = len(ys)
        rows = -(-m // 256)

        def block(v: np.ndarray) -> np.ndarray:
            return np.pad(v.astype(np.float32), (0, rows * 256 - m)).reshape(rows, 256)

        ddx, ddy = block(dx[ys, xs]), block(dy[ys, xs])
        fx, fy = block(xs), block(ys)
        n = int(np.clip(np.ceil(length) + 1, 3, 17))
        acc = np.zeros((rows * 256, len(present)), np.float32)
        for u in np.linspace(-0.5 * length, 0.5 * length, n, dtype=np.float32):
            acc += cv2.remap(stack, fx + u * ddx, fy + u * ddy, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0).reshape(rows * 256, len(present))
        acc = acc[:m] / n
        for i, k in enumerate(present):
            layers[k][y0 + ys, x0 + xs] = acc[:, i]
        return layers

    # -- per frame
    def render(self, state: ArrayState, time_s: float = 0.0) -> np.ndarray:
        """One BGR uint8 frame with the array in ``state`` at ``time_s`` (s).

        The time moves what changes by itself during a video (drifting bubbles, flickering
        glints); with those nuisances off it changes nothing.
        """
        ap, nu = self.appearance, self.nuisance
        pad = int(np.ceil(0.5 * nu.motion_blur_px)) + 4 if nu.motion_blur_px > 0 else 0
        body, bands, bbox = self._array_layers(state, pad)
        glint = self._band_glints(state, bands, bbox, time_s) if self._glint is not None and bbox else None
        if nu.motion_blur_px > 0 and bbox is not None:
            body, bands, glint = self._motion_blurred(state, bbox, [body, bands, glint])
        # bubbles lie under the array: they may sit against it but never hide any of it
        img = self._with_bubbles(state, time_s) if nu.has_bubbles else self.background
        img = img * (1 - body) + ap.array_level * body
        img = img * (1 - bands) + ap.band_level * bands
        if glint is not None:
            x0, y0, x1, y1 = bbox
            img[y0:y1, x0:x1] += glint[y0:y1, x0:x1]
        if nu.distractors:
            img = self._draw_gripper(img, state)
        gain = self.gain
        if nu.flicker > 0:
            gain = gain * float(1.0 + nu.flicker * self.rng.standard_normal())
        img = img * gain
        if self._plate_glint is not None:  # lamp reflections on the plate's top: not shaded
            for (x0, y0, x1, y1), spot in self._plate_glint:
                img[y0:y1, x0:x1] += spot
        if nu.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), nu.blur_sigma_px)
        if nu.noise_sigma > 0:
            img = img + nu.noise_sigma * self.rng.standard_normal(img.shape, dtype=np.float32)
        grey = np.clip(img, 0, 255)
        bgr = np.clip(grey[..., None] * np.asarray(ap.tint, np.float32), 0, 255).round().astype(np.uint8)
        if nu.jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(nu.jpeg_quality)])
            bgr = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        return bgr


# --------------------------------------------------------------------------- randomness


def random_pose(
    rng: np.random.Generator,
    width: int = 640,
    height: int = 480,
    *,
    px_per_mm: tuple[float, float] = (15.0, 60.0),
    phantom: Phantom = DEFAULT_PHANTOM,
    margin_px: float = 10.0,
) -> CameraPose:
    """A random similarity that keeps the whole channel (entry included) inside the frame.

    The scale is drawn from ``px_per_mm`` (px/mm) and reduced if the channel would not fit.
    """
    outline = channel_polygon(phantom)
    mirrored = bool(rng.integers(0, 2))
    rot = float(rng.uniform(-np.pi, np.pi))
    scale = float(rng.uniform(*px_per_mm))
    probe = CameraPose(0.0, 0.0, rot, 1.0, mirrored).to_image(outline)
    span = probe.max(axis=0) - probe.min(axis=0)
    scale = min(scale, (width - 2 * margin_px) / span[0], (height - 2 * margin_px) / span[1])
    lo = -probe.min(axis=0) * scale + margin_px
    hi = np.array([width, height]) - probe.max(axis=0) * scale - margin_px
    cx, cy = rng.uniform(lo, np.maximum(hi, lo))
    return CameraPose(float(cx), float(cy), rot, scale, mirrored)


def random_policy(rng: np.random.Generator) -> ContactPolicy:
    """A plausible, random way for the contact run to grow during one insertion.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of six uniform draws, in a fixed order (the shape's three, then the policy's).

    Returns
    -------
    ContactPolicy
        First contact at a tip angle of 1.0–1.8 rad, a contact start that follows 15–45 % of
        the tip's advance, an approach over 0.4–0.8 rad; basally (:class:`ArrayShape`) the array
        leaves the wall over 0.35–0.7 rad, settles at -0.7 to +0.2 of the lateral play and leaves
        the insertion axis over 0.4–0.8 rad.
    """
    shape = ArrayShape(
        departure_rad=float(rng.uniform(0.35, 0.7)),
        far_offset=float(rng.uniform(-0.7, 0.2)),
        start_blend_rad=float(rng.uniform(0.4, 0.8)),
    )
    return ContactPolicy(
        theta_first=float(rng.uniform(1.0, 1.8)),
        lag=float(rng.uniform(0.15, 0.45)),
        approach_rad=float(rng.uniform(0.4, 0.8)),
        shape=shape,
    )


def random_appearance(rng: np.random.Generator) -> Appearance:
    """An appearance drawn from a wide range of plausible looks."""
    style = str(rng.choice(["lines", "region", "both"]))
    background = float(rng.uniform(120, 220))
    delta = float(rng.uniform(15, 45)) * (1 if rng.random() < 0.6 else -1)
    fluid = background if style == "lines" else float(np.clip(background + delta, 60, 245))
    wall_level = float(rng.uniform(30, 90)) if rng.random() < 0.8 else float(min(255, background + 50))
    array_level = float(rng.uniform(20, min(fluid, background) - 50))
    band_level = float(rng.uniform(max(array_level + 60, 150), 255))
    b, g, r = (float(t) for t in rng.uniform(0.85, 1.15, size=3))
    tint = (b, g, r)
    return Appearance(background, fluid, style, wall_level, float(rng.uniform(1.2, 3.0)), array_level, band_level, tint)


def random_nuisance(rng: np.random.Generator, strength: float) -> Nuisance:
    """Nuisances scaled by ``strength`` (0 = clean, 1 = heavy)."""
    if strength <= 0:
        return Nuisance()
    return Nuisance(
        noise_sigma=float(rng.uniform(0.5, 1.0) * 10 * strength),
        blur_sigma_px=float(rng.uniform(0.5, 1.0) * 1.5 * strength),
        illumination=float(rng.uniform(0.5, 1.0) * 0.4 * strength),
        flicker=float(0.05 * strength),
        jpeg_quality=int(95 - 50 * strength) if strength >= 0.3 else None,
        distractors=int(round(4 * strength)),
    )


def random_harsh_nuisance(rng: np.random.Generator, strength: float) -> Nuisance:
    """Everything real footage of a glycerin-filled acrylic phantom shows, scaled by ``strength``.

    On top of :func:`random_nuisance`'s kinds (drawn from wider ranges, JPEG quality down to
    15 at full strength): free and tip bubbles, doubled walls, band and plate glints, motion
    blur, shadows and a gripper that hides part of the straight array. Each kind is present
    at random, so a set of draws meets every combination.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    strength : float
        0 (clean, ``Nuisance()``) to 1 (harsh).

    Returns
    -------
    Nuisance
    """
    if strength <= 0:
        return Nuisance()
    s = float(min(strength, 1.0))
    u = rng.uniform
    quality = int(np.clip(round(95 - 80 * s * u(0.6, 1.0)), 15, 95))
    tip_kind = int(rng.integers(0, 3))  # none, touching, ahead
    return Nuisance(
        noise_sigma=float(u(0.3, 1.0) * 12 * s),
        blur_sigma_px=float(u(0.2, 1.0) * 1.8 * s),
        illumination=float(u(0.3, 1.0) * 0.45 * s),
        flicker=float(u(0.3, 1.0) * 0.08 * s),
        jpeg_quality=quality if u() < 0.5 + 0.5 * s else None,
        distractors=int(rng.integers(1, 2 + round(4 * s))),
        bubbles=int(rng.integers(0, 1 + round(8 * s))),
        bubble_at_tip=(None, 0.0, float(u(0.1, 1.0)))[tip_kind],
        bubble_radius_mm=None,
        bubble_drift_mm_s=float(u(0.02, 0.4)),
        doubled_wall_mm=float(u(0.1, 0.1 + 0.4 * s)) if u() < 0.4 + 0.5 * s else 0.0,
        doubled_wall_contrast=float(u(0.3, 1.0)),
        doubled_wall_direction_rad=None,
        glints=float(u(0.3, 1.0) * s),
        plate_glints=int(rng.integers(0, 1 + round(4 * s))),
        motion_blur_px=float(u(0.0, 8.0) * s),
        shadows=float(u(0.2, 0.7) * s),
        gripper_overlap_mm=float(u(0.0, 6.0) * s),
    )

# --------------------------------------------------------------------------- video


def _atomic_target(path: Path) -> Path:
    return path.with_name(f".{path.name}.partial{path.suffix}")


def render_video(
    out_path: str | os.PathLike,
    spec: VideoSpec,
    *,
    seed: int = 0,
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
) -> pd.DataFrame:
    """Render one insertion to ``out_path`` and return its per-frame truth.

    Parameters
    ----------
    out_path : path
        A ``.mp4``/``.avi`` file (written through OpenCV, mp4v codec), or a directory that will
        hold ``frame_00000.png``… Written under a temporary name and moved into place at the end.
    spec : VideoSpec
        What to render.
    seed : int
        Seed of the noise and clutter.
    phantom, array : Phantom, ElectrodeArray
        Geometry.

    Returns
    -------
    pandas.DataFrame
        One row a frame: ``frame, time_s, depth_mm, theta_tip, theta_bot, theta_con`` (rad) and
        ``tip_x_px, tip_y_px, bot_x_px, bot_y_px``.
    """
    out_path = Path(out_path)
    rng = np.random.default_rng(seed)
    scene = Scene(spec.pose, spec.width, spec.height, spec.appearance, spec.nuisance,
                  phantom=phantom, array=array, rng=rng)
    times = spec.frame_times()
    is_video = out_path.suffix.lower() in (".mp4", ".avi", ".mov", ".mkv")
    tmp = _atomic_target(out_path) if is_video else out_path.with_name(f".{out_path.name}.partial")
    tmp.parent.mkdir(parents=True, exist_ok=True)
    writer = None
    if is_video:
        fourcc = cv2.VideoWriter_fourcc(*("mp4v" if out_path.suffix.lower() != ".avi" else "MJPG"))
        writer = cv2.VideoWriter(str(tmp), fourcc, float(spec.effective_fps()), (spec.width, spec.height))
        if not writer.isOpened():
            raise OSError(f"{out_path}: OpenCV cannot write this video format")
    else:
        tmp.mkdir(parents=True, exist_ok=True)
    rows = []
    cache: dict[float, ArrayState] = {}
    try:
        for i, t in enumerate(times):
            depth = float(spec.depth_at(t))
            key = round(depth, 6)
            if key not in cache:
                cache.clear()
                cache[key] = pose_at_depth(depth, spec.policy, phantom=phantom, array=array)
            state = cache[key]
            frame = scene.render(state, time_s=float(t))
            if writer is not None:
                writer.write(frame)
            else:
                cv2.imwrite(str(tmp / f"frame_{i:05d}.png"), frame)
            tr = state.truth
            tip_px = spec.pose.to_image(tr.tip_mm)[0]
            bot_px = spec.pose.to_image(tr.bot_mm)[0]
            rows.append(dict(frame=i, time_s=float(t), depth_mm=state.depth_mm, theta_tip=tr.theta_tip,
                             theta_bot=tr.theta_bot, theta_con=tr.theta_con, tip_x_px=tip_px[0],
                             tip_y_px=tip_px[1], bot_x_px=bot_px[0], bot_y_px=bot_px[1]))
    finally:
        if writer is not None:
            writer.release()
    if out_path.exists() and not is_video:
        import shutil

        shutil.rmtree(out_path)
    os.replace(tmp, out_path)
    return pd.DataFrame(rows)


def spec_to_dict(spec: VideoSpec) -> dict:
    """A JSON-ready dict of a :class:`VideoSpec` (pose keys as in the registration JSON)."""
    d = asdict(spec)
    return json.loads(json.dumps(d, default=float))


def distort(image: np.ndarray, calibration: LensCalibration) -> np.ndarray:
    """The frame a camera with ``calibration``'s lens records of the ideal pinhole ``image``.

    Each recorded pixel shows the ideal image where ``cv2.undistortPoints`` (with the camera
    matrix as the new one) sends it, sampled bilinearly; ideal content beyond the frame repeats
    its edge. :func:`vision.frames.undistorter` inverts this up to interpolation blur and the
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

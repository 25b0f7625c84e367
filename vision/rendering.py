"""Synthetic overhead frames of the phantom with the electrode array, and their exact truth.

The renderer runs the measurement backwards: geometry (:mod:`vision.geometry`) → image.
Ground truth is computed from the very centreline that is drawn, with the SPEC definitions
(:func:`vision.angles.contact_angles`).

Pieces, from geometry to file:

* :func:`array_centreline` — the array's centreline for a tip angle and contact start angle;
* :func:`pose_at_depth` — the same for an insertion depth, following a :class:`ContactPolicy`;
* :class:`Scene` — a static view (pose, appearance, nuisances) that draws frames;
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

from .angles import ContactAngles, contact_angles
from .frames import LensCalibration
from .geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    CameraPose,
    ElectrodeArray,
    Phantom,
    backbone_frame,
    channel_polygon,
    channel_width,
    entry_frame,
    entry_walls,
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
    "random_appearance",
    "random_nuisance",
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
        SPEC angles of this centreline.
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
        Nominal contact start angle (rad), ``<= theta_tip``. The SPEC contact start of the
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
    """Pose the array so that its *measured* (SPEC) tip and contact start angles are the given ones.

    :func:`array_centreline` places the nominal angles; the SPEC truth of the result differs
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
    """Image degradations and clutter, each off at zero.

    Parameters
    ----------
    noise_sigma : float
        Standard deviation of additive sensor noise (grey levels).
    blur_sigma_px : float
        Gaussian blur (px).
    illumination : float
        Relative amplitude of a smooth, uneven illumination field (0–0.5).
    flicker : float
        Relative standard deviation of the per-frame global gain.
    jpeg_quality : int or None
        Re-encode every frame as JPEG of this quality (compression artefacts).
    distractors : int
        Number of objects outside the channel (screws, a ruler); a gripper holding the array's
        base is drawn when this is at least 1.
    """

    noise_sigma: float = 0.0
    blur_sigma_px: float = 0.0
    illumination: float = 0.0
    flicker: float = 0.0
    jpeg_quality: int | None = None
    distractors: int = 0


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


# --------------------------------------------------------------------------- scene


class Scene:
    """A fixed view of the phantom (pose, appearance, nuisances) that draws frames.

    The static part (phantom, clutter, illumination field) is computed once; each frame adds
    the array and the per-frame degradations.

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
        self.background = self._static_background()
        self.gain = self._illumination_field()

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

    def _static_background(self) -> np.ndarray:
        ap, h, w = self.appearance, self.height, self.width
        img = np.full((h, w), ap.background, np.float32)
        if ap.wall_style in ("region", "both"):
            inside = self._coverage([self.pose.to_image(channel_polygon(self.phantom))])
            img += (ap.fluid - ap.background) * inside
        if ap.wall_style in ("lines", "both"):
            cov = self._line_coverage(self._wall_lines_px(), ap.wall_width_px)
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
        c, s, rad = state.centreline_mm, state.s_mm, state.radius_mm.copy()
        cap = s < rad[0]  # rounded tip: a half disc whose apex is the tip point
        rad[cap] = np.sqrt(np.maximum(rad[0] ** 2 - (rad[0] - s[cap]) ** 2, 0.0))
        tangent = np.gradient(c, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        nrm = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        left, right = c + rad[:, None] * nrm, c - rad[:, None] * nrm
        body = self.pose.to_image(np.vstack([left, right[::-1]]))
        x0, y0 = np.floor(body.min(axis=0)).astype(int) - 2
        x1, y1 = np.ceil(body.max(axis=0)).astype(int) + 3
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, self.width), min(y1, self.height)
        full_body = np.zeros((self.height, self.width), np.float32)
        full_bands = np.zeros_like(full_body)
        if x1 <= x0 or y1 <= y0:
            return full_body, full_bands
        bbox = (x0, y0, x1, y1)
        full_body[y0:y1, x0:x1] = self._coverage([body], bbox)
        bands = []
        for a, b in self.array.band_intervals():
            sel = (s >= a) & (s <= b)
            if sel.sum() >= 2:
                bands.append(self.pose.to_image(np.vstack([left[sel], right[sel][::-1]])))
        if bands:
            full_bands[y0:y1, x0:x1] = self._coverage(bands, bbox)
        return full_body, full_bands

    def _gripper(self, state: ArrayState) -> list[np.ndarray]:
        base = state.centreline_mm[-1]
        _, x_w, nrm = entry_frame(self.phantom)
        jaw = np.stack([base + 1.5 * nrm, base - 4 * x_w + 1.5 * nrm, base - 4 * x_w - 1.5 * nrm, base - 1.5 * nrm])
        return [self.pose.to_image(jaw)]

    def render(self, state: ArrayState) -> np.ndarray:
        """One BGR uint8 frame with the array in ``state``."""
        ap, nu = self.appearance, self.nuisance
        body, bands = self.array_layers(state)
        img = self.background * (1 - body) + ap.array_level * body
        img = img * (1 - bands) + ap.band_level * bands
        if nu.distractors:
            jaw = self._gripper(state)[0]
            x0, y0 = np.maximum(np.floor(jaw.min(axis=0)).astype(int) - 2, 0)
            x1, y1 = np.minimum(np.ceil(jaw.max(axis=0)).astype(int) + 3, [self.width, self.height])
            if x1 > x0 and y1 > y0:
                grip = self._coverage([jaw], (x0, y0, x1, y1))
                img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - grip) + 50.0 * grip
        gain = self.gain
        if nu.flicker > 0:
            gain = gain * float(1.0 + nu.flicker * self.rng.standard_normal())
        img = img * gain
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
            frame = scene.render(state)
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
    """A JSON-ready dict of a :class:`VideoSpec` (pose keys as SPEC's registration JSON)."""
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

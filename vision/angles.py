"""The array's angles theta_tip, theta_bot and theta_con, and their measurement.

The angles are defined in docs/how-it-works.md. :func:`contact_angles` applies the definitions to
an array centreline given in the phantom frame. The renderer uses it to compute ground truth from
the geometry it draws; the measurement uses it on the centreline it finds in a frame, so both
answer the same question.

Per frame (:func:`measure_frame`): greyscale frame + registration → straightened channel →
the array's dark run, tip, edges and gap to the outer wall → :func:`contact_angles`. Build
the straightened channel once per registration with :func:`prepare_measurement` and pass
that plan in place of the registration::

    plan = prepare_measurement(registration, frame.shape)
    for frame in frames:
        row = measure_frame(frame, plan).to_row()
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable, Protocol

import cv2
import numpy as np

from tympani.vision.geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    CameraPose,
    ElectrodeArray,
    Phantom,
    backbone_frame,
    channel_width,
    entry_frame,
    point_angle,
)

__all__ = [
    "ContactAngles",
    "contact_angles",
    "outer_wall_gap",
    "MeasureConfig",
    "FrameMeasurement",
    "MeasurePlan",
    "prepare_measurement",
    "measure_frame",
    "measure_frames_batch",
]


@dataclass(frozen=True)
class ContactAngles:
    """The three angles (rad) and where they are.

    Parameters
    ----------
    theta_tip, theta_bot, theta_con : float
        Tip angle, contact start angle and contact angle (rad).
    tip_mm, bot_mm : ndarray, shape (2,)
        Centreline points (mm, phantom frame) of the tip and of the contact start.
    """

    theta_tip: float
    theta_bot: float
    theta_con: float
    tip_mm: np.ndarray
    bot_mm: np.ndarray


def outer_wall_gap(
    centreline_mm: np.ndarray, radius_mm: np.ndarray, phantom: Phantom, theta: np.ndarray | None = None
) -> np.ndarray:
    """Gap (mm) between the array's outer edge and the outer wall at each centreline point.

    Parameters
    ----------
    centreline_mm : ndarray, shape (n, 2)
        Centreline points (mm, phantom frame).
    radius_mm : ndarray, shape (n,)
        Half the array's width (mm) at each point.
    phantom : Phantom
        Phantom configuration.
    theta : ndarray, shape (n,), optional
        The points' angles (rad, unwrapped); computed when not given.

    Returns
    -------
    ndarray, shape (n,)
        Distance from the centreline to the outer wall of its own turn, less the radius (mm); negative where the
        outline crosses the wall.
    """
    if theta is None:
        theta = point_angle(centreline_mm, phantom)
    distance, _, _ = phantom.outer_wall.project(centreline_mm, theta)
    return distance - np.asarray(radius_mm, dtype=float)


def contact_angles(
    centreline_mm: np.ndarray,
    radius_mm: np.ndarray,
    phantom: Phantom,
    *,
    contact_tol_mm: float = 0.05,
    gap_mm: np.ndarray | None = None,
    theta: np.ndarray | None = None,
) -> ContactAngles:
    """The angles of an array given by its centreline, tip first.

    Parameters
    ----------
    centreline_mm : ndarray, shape (n, 2)
        Centreline points (mm, phantom frame) ordered from the tip towards the base.
    radius_mm : ndarray, shape (n,)
        Half the array's width (mm) at each point.
    phantom : Phantom
        Phantom configuration.
    contact_tol_mm : float
        Largest gap (mm) between outer edge and outer wall that counts as contact.
    gap_mm : ndarray, shape (n,), optional
        Gaps (mm) if already known (e.g. measured); otherwise :func:`outer_wall_gap`.
    theta : ndarray, shape (n,), optional
        The points' angles (rad, unwrapped) if already known (the measurement computes them with
        precomputed constants, see :func:`_spiral_angle`); otherwise
        :func:`vision.geometry.point_angle`.

    Returns
    -------
    ContactAngles
        ``theta_bot`` is where the unbroken contact run ending at the tip begins, interpolated
        between the last point in contact and the first one out of it; without contact at the
        tip ``theta_bot = theta_tip`` and ``theta_con = 0``.
    """
    centreline_mm = np.atleast_2d(np.asarray(centreline_mm, dtype=float))
    if theta is None:
        theta = point_angle(centreline_mm, phantom)
    if gap_mm is None:
        gap_mm = outer_wall_gap(centreline_mm, radius_mm, phantom, theta)
    tip = centreline_mm[0]
    theta_tip = float(theta[0])
    touching = np.asarray(gap_mm) <= contact_tol_mm
    if not touching[0]:
        return ContactAngles(theta_tip, theta_tip, 0.0, tip, tip)
    out = np.flatnonzero(~touching)
    if len(out) == 0:
        i_last, frac = len(theta) - 1, 0.0
    else:
        i_last = int(out[0]) - 1
        g0, g1 = gap_mm[i_last], gap_mm[i_last + 1]
        frac = min(max(float((contact_tol_mm - g0) / (g1 - g0)), 0.0), 1.0) if g1 != g0 else 0.0
    j = min(i_last + 1, len(theta) - 1)
    bot = centreline_mm[i_last] + frac * (centreline_mm[j] - centreline_mm[i_last])
    theta_bot = float(theta[i_last] + frac * (theta[j] - theta[i_last]))
    return ContactAngles(theta_tip, theta_bot, theta_tip - theta_bot, tip, bot)


# =========================================================================== measurement
#
# How a frame is measured (see also measure_frame):
#
# The channel is registered once per video, so everything that depends only on the pose is
# computed once (prepare_measurement): remap tables that *straighten* the channel into a
# strip. Its *stations* run along the channel's backbone, one px apart, from the outer end of
# the entry channel through theta_start to theta_end; its *offsets* run across the channel
# at normalised lateral positions u (-1 the inner wall, +1 the outer wall), at most one px
# apart. The strip is stored offsets x stations, so that reductions across the channel run
# over its short first axis and OpenCV's filters see a wide image (both several times
# faster than the other way round). Each frame then costs two cv2.remap calls and mostly
# 1-D work along the channel:
#
# 1. survey, on a coarse strip (every 2nd offset and station) of the whole channel, using
#    each station's darkest and brightest value in the channel's interior (clear of wall
#    lines): the fluid level along the channel (a low percentile per 1.5 mm block, blocks
#    where the array fills the channel interpolated; then again over stations whose
#    brightest value is fluid); the array's level as a ratio to the fluid's, taken side by
#    side where the array shows beside the fluid with a sharp edge (so uneven lighting
#    cancels, and a channel merely dimmed by vignetting is not taken for an array); each
#    station's darkness (0 fluid, 1 array); the array is the dark run that starts at the
#    entry's outer end, bridging gaps up to 0.8 mm (metal bands as bright as the fluid);
# 2. edges, on the fine strip of the stations that hold the array: at each station the
#    array's inner and outer edge are the half-level crossings of its coverage either side
#    of its darkest offset (sub-pixel, linear interpolation); the inner edge is then moved to
#    the half level between the fluid and the array just beside it (median over the frame,
#    local where the fluid shows clear of the wall), which removes the biases of the global
#    levels (noise, compression, lighting);
# 3. centre line: the inner edge faces the fluid wherever the array rides the outer wall,
#    whereas the outer edge then merges with the wall (a dark wall line hides gaps narrower
#    than half its width), so the centre line is the inner edge plus the array's known
#    half-width at that distance from the tip (the outer edge minus it where the inner edge
#    is lost), widened by the array's slant across the channel; in the rounded tip the
#    half-width is the half disc's; stations at band borders, cut by a band's slanted border
#    (edges too close together) or off their neighbours' median are dropped; the tip is the
#    half-level crossing along the centre line, whose offset is extrapolated from the body;
#    gap = half the channel width - centre offset - radius, smoothed with local straight-line
#    fits (unbiased next to bands and the tip, where only one side has data) and carried
#    across bands and the last of the tip cap;
# 4. angles: contact_angles() on the measured centre line with the measured gaps, so the
#    angle definitions are applied by the same code that computes the renderer's truth.


class _HasPose(Protocol):
    pose: CameraPose


@dataclass(frozen=True)
class MeasureConfig:
    """Settings of the per-frame measurement (:func:`measure_frame`).

    Parameters
    ----------
    contact_tol_mm : float
        Largest gap (mm) between the array's outer edge and the outer wall that counts as
        contact.
    contact_persist_mm : float
        An excursion of the measured gap above ``contact_tol_mm`` shorter than this (mm, along
        the array), after which contact holds again for as long, is measurement noise and does
        not end the contact run (a real departure from the wall widens steadily).
    contact_excess_mm : float
        Excess gap (mm) over ``contact_tol_mm`` beyond which an excursion always ends the run.
    contact_bias_mm : float
        Largest allowance (mm) for a bias of the measured gap. Blur, compression, doubled
        wall lines, a registration a pixel or two off and an array somewhat wider than modelled
        can make a gap read some hundredths of a millimetre wide all along; where
        the median measured gap of the stretch from the tip to the first gap above
        ``contact_tol_mm + contact_excess_mm`` exceeds ``contact_tol_mm / 2``, the excess (up
        to this much) is taken as bias and added to the tolerance. (With gaps read without
        bias, touching stretches have a median gap well under half the tolerance.)
    station_step_px : float
        Spacing (px) of the strip's stations along the channel's backbone.
    offset_step_px : float
        Largest spacing (px) of the strip's offsets across the channel (where it is widest).
    min_step_mm : float
        Least spacing (mm) of the stations and of the offsets: above ``1 / min_step_mm`` px/mm
        (33 px/mm) the steps grow past ``station_step_px`` and ``offset_step_px``, so that
        a frame's cost stops growing with the magnification (``measure_frame`` 1.2-1.5x faster
        at 35-70 px/mm and 2.3x at 60-110 px/mm; theta_tip max error on the 36 zoomed-in test
        frames 0.0016 -> 0.0027 rad, see ``tests/test_angles.py``).
    coarse_stride : int
        Every how many offsets and stations the coarse strip (used to find the array) keeps.
    lateral_extent : float
        The strip spans normalised lateral offsets ``u`` in ``[-lateral_extent,
        lateral_extent]`` (``u = -1`` the inner wall, ``u = +1`` the outer wall).
    wall_margin_px : float
        Width (px) next to each wall left out of the channel's *interior*, so that wall lines
        and their blur are not taken for the array or for the fluid.
    min_interior : float
        Smallest half-width of the interior, as a fraction of the channel's half-width.
    fluid_window_mm : float
        Length (mm) along the channel of the blocks whose percentile estimates the fluid level
        (a median over three blocks follows).
    fluid_percentile : float
        Percentile (0–100) of the stations' brightest interior values taken as a first fluid
        level (the second is the median over stations whose brightest value is fluid).
    fluid_reach_mm : float
        Distance (mm) along the channel over which a block's fluid level is compared with its
        neighbours' (to find blocks where the array fills the channel). The light must not fall
        by more than ``1 - fluid_floor`` over it, or plain fluid is taken for the array: at
        6 mm (before session 6) the tip ran on by 1-2 rad under strong uneven light.
    fluid_floor : float
        A block darker than this fraction of its brightest neighbour within ``fluid_reach_mm``
        is taken to be filled by the array, and its fluid level interpolated.
    probe_mm : float
        Length (mm) of the outer end of the entry channel where the array must be seen.
    beside_mm : float
        Length (mm) of channel over which the array must be seen beside the fluid for a frame
        to count as having an array in the channel.
    band_border_mm : float
        Length (mm) along the channel either side of a metal band's border that the fluid's
        second estimate leaves out (at least two coarse stations): a border is blurred, and
        oblique where the array crosses the channel, so it spans a length in mm, not in px.
        Two coarse stations alone let band brightness into the fluid level above ~50 px/mm.
    dark_level : float
        Darkness (0 fluid, 1 array) from which a station holds the array.
    body_level : float
        Darkness from which a station is array body whose edges are measured (stations below
        are metal bands, band borders or noise).
    border_px : int
        Stations (px apart) either side of a band's border (or any non-body station) whose
        edges are not used: blur and the smoothing along the channel mix the band into them.
    edge_level : float
        Coverage (0 fluid, 1 array) at which edges and the tip are located.
    body_fill : float
        Least median, over the array's stations, of the mean coverage (0 fluid, 1 array) between
        a station's two edges: below it the frame has no array (a body is mostly dark between its
        edges; the grain of noise or compression is not).
    fluid_run : float
        Share of the array's tip diameter (dimensionless) the fluid beside an edge must span
        across the channel, unless it reaches the wall: a bright highlight along the middle of a
        round, lit array is narrower, and is not taken for the fluid.
    min_body_mm : float
        Least length (mm) of array basal of the tip whose edges are sought, even where part of it
        is still in the entry channel (beyond, the edges are sought from theta_start on).
    bubble_bright : float
        Highest coverage (dimensionless, 0 fluid, 1 array) of a bubble's interior.
    bubble_min_mm2 : float
        Least area (mm²) of a bubble's interior.
    bubble_max_mm : float
        Largest radius (mm) of a bubble's interior.
    bubble_fill : tuple of float
        Least and largest share (dimensionless) of its bounding box a bubble's interior fills (a
        disc: 0.79; a band, a rectangle: about 1).
    bubble_wider : float
        Width (dimensionless, times the array's tip diameter) above which an enclosed bright
        region cannot be a band.
    bubble_rim_mm : float
        Longest dark stretch (mm) along the array's path beyond a narrower one for it to be a
        bubble's rim rather than more array.
    bubble_aspect : float
        Largest ratio (dimensionless) of the longer to the shorter side of that box.
    bubble_track_mm : float
        Length (mm) of the dark stations before a bubble whose median darkest offset is the
        array's path.
    max_gap_mm : float
        Longest stretch (mm) along the array that may look like fluid (a metal band as bright
        as the fluid) without ending it.
    min_contrast : float
        Smallest fluid-minus-array difference (grey levels) of a usable frame.
    gap_smooth_mm : float
        Length (mm) along the channel of the local line fits that smooth centre offsets and
        gaps (the slant is fitted over 2.5 times this).
    outlier_px : float
        Smallest deviation (px) of a station's centre offset from its neighbours' median that
        drops the station.
    plateau_px : tuple of float
        Nearest and farthest distance (px) from the array's inner edge of the samples whose
        coverage gives the local fluid and array levels the edge is relocated between.
    tip_reach_mm : float
        Farthest (mm) the centre line is extrapolated from the last station with measured edges
        to the tip; a frame whose dark run goes on farther is not measured (what continues it
        is not the array's body: a bubble's rim, a shadow, a doubled wall line).
    tip_width_mm : float
        Length (mm) before the tip over which the array must show as the array: its inner edge
        found (``tip_inner_min``) and its centre line clear of the walls (``tip_wall_share``). A
        frame whose dark run ends in something else (a doubled wall line followed into the next
        turn) is not measured.
    tip_inner_min : float
        Least share of the tip stretch's stations where the array's inner edge (the one away
        from the outer wall, which it shows in contact too) is found. On 150 random frames with
        doubled walls, every frame under 0.1 was wrong (a wall line followed past the tip) and
        the correct ones had 0.17 or more.
    tip_wall_share : float
        A frame whose tip stretch has its centre line closer to a wall than half the array's
        radius at this share of its measured stations or more is not measured: the array cannot
        cross a wall, a wall line followed past the tip lies there.
    cap_min : float
        Stations of the rounded tip closer to the tip than this fraction of its radius are not
        used for edges (farther cap stations are, with the half disc's width).
    angle_step_mm : float
        Approximate spacing (mm) of the centre-line points handed to :func:`contact_angles`.
    min_tip_px : float
        Smallest width (px) of the array's tip in the image (14.2 px/mm with the default
        array): at smaller scales every frame is refused ("array too small in the image").
        On 150 random 640x480 frames at 10-20 px/mm, 17-61 % of those below it were measured,
        three of them far off (theta_tip by 0.18 rad, theta_bot by 2.1 and 2.5 rad, at 11-13
        px/mm); from 14 px/mm up none was off by more than 0.03 rad (tip) or 0.25 rad (bot).
    """

    contact_tol_mm: float = 0.05
    contact_persist_mm: float = 0.5
    contact_excess_mm: float = 0.1
    contact_bias_mm: float = 0.1
    station_step_px: float = 1.0
    offset_step_px: float = 1.0
    min_step_mm: float = 0.03
    coarse_stride: int = 2
    lateral_extent: float = 1.1
    wall_margin_px: float = 3.5
    min_interior: float = 0.25
    fluid_window_mm: float = 1.5
    fluid_percentile: float = 25.0
    fluid_reach_mm: float = 3.0
    fluid_floor: float = 0.85
    probe_mm: float = 1.5
    beside_mm: float = 0.3
    band_border_mm: float = 0.1
    dark_level: float = 0.5
    body_level: float = 0.8
    border_px: int = 1
    edge_level: float = 0.5
    fluid_run: float = 0.4
    body_fill: float = 0.6
    min_body_mm: float = 2.0
    bubble_bright: float = 0.3
    bubble_min_mm2: float = 0.02
    bubble_max_mm: float = 0.9
    bubble_fill: tuple[float, float] = (0.5, 0.86)
    bubble_aspect: float = 2.5
    bubble_wider: float = 1.15
    bubble_rim_mm: float = 0.2
    bubble_track_mm: float = 0.6
    max_gap_mm: float = 0.8
    min_contrast: float = 18.0
    gap_smooth_mm: float = 0.4
    outlier_px: float = 1.5
    plateau_px: tuple[float, float] = (2.5, 4.0)
    tip_reach_mm: float = 1.5
    tip_width_mm: float = 2.0
    tip_inner_min: float = 0.1
    tip_wall_share: float = 0.5
    cap_min: float = 0.4
    angle_step_mm: float = 0.1
    min_tip_px: float = 8.5


@dataclass(frozen=True)
class FrameMeasurement:
    """What :func:`measure_frame` found in one frame.

    Parameters
    ----------
    ok : bool
        Whether the angles were measured.
    reason : str
        Why not (``''`` when ``ok``).
    theta_tip, theta_bot, theta_con : float
        The angles (rad); NaN when not ``ok``.
    tip_mm, bot_mm : ndarray, shape (2,), or None
        Tip and contact start on the centre line (mm, phantom frame).
    centreline_mm : ndarray, shape (n, 2), or None
        Measured centre line (mm, phantom frame), tip first, down to ``theta_start`` (down to
        the entry's outer end when the tip is in the entry channel).
    outline_mm : ndarray, shape (m, 2), or None
        Closed outline (mm, phantom frame) of that part of the array.
    gap_mm : ndarray, shape (n,), or None
        Measured gap (mm) between the array's outer edge and the outer wall at each
        centre-line point.
    extras : dict of str to float
        Diagnostics: ``depth_mm`` (length of array past ``theta_start``, mm; negative when the
        tip is in the entry channel), ``contrast`` (fluid minus array, grey levels),
        ``edge_fraction`` (fraction of the array's stations whose edges were used),
        ``width_ratio`` (the array's width between its two edges over the modelled
        :class:`~vision.geometry.ElectrodeArray`'s, median over the stations where both show;
        NaN where fewer than 10 do: about 1.01 when the model is right), ``bare_tip_mm`` (length
        of the array, mm, between its last station with measured edges and the tip: the tip's
        offset is extrapolated over it), ``time_ms`` (ms spent on the frame).
    timings : dict of str to float
        Seconds spent per stage (``survey``, ``edges``, ``centre_line``, ``angles``); not in
        :meth:`to_row`.
    """

    ok: bool
    reason: str = ""
    theta_tip: float = float("nan")
    theta_bot: float = float("nan")
    theta_con: float = float("nan")
    tip_mm: np.ndarray | None = None
    bot_mm: np.ndarray | None = None
    centreline_mm: np.ndarray | None = None
    outline_mm: np.ndarray | None = None
    gap_mm: np.ndarray | None = None
    extras: dict[str, float] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    def to_row(self) -> dict[str, Any]:
        """Scalar columns for an angles table: the angles, ``ok``, ``reason`` and the extras."""
        row: dict[str, Any] = dict(
            theta_tip=self.theta_tip,
            theta_bot=self.theta_bot,
            theta_con=self.theta_con,
            ok=bool(self.ok),
            reason=self.reason,
        )
        row.update({key: float(value) for key, value in self.extras.items()})
        return row


@dataclass(frozen=True, eq=False)
class _AngleTable:
    """The constants :func:`vision.geometry.point_angle` derives from a phantom, computed once
    per plan so that :func:`_spiral_angle` costs a dozen NumPy calls per frame.

    ``turns`` are the candidate offsets 2πk (rad); ``origin``, ``x_w``, ``normal`` (mm, unit)
    the entry frame and ``entry_width_mm`` the entry channel's width (mm); the rest are
    :class:`~vision.geometry.Phantom` fields of Eq. (1) and the channel's ends (rad).
    """

    turns: np.ndarray
    theta_start: float
    theta_end: float
    branch_deg: float
    c_mm: float
    d: float
    phi0_deg: float
    a_mm: float
    b_per_deg: float
    origin: np.ndarray
    x_w: np.ndarray
    normal: np.ndarray
    entry_width_mm: float


def _angle_table(phantom: Phantom) -> _AngleTable:
    """:class:`_AngleTable` of ``phantom``, with the same constants as ``point_angle``."""
    n_turns = int(np.ceil((phantom.theta_end + np.pi) / (2 * np.pi))) + 1
    origin, x_w, normal = entry_frame(phantom)
    return _AngleTable(
        turns=2 * np.pi * np.arange(n_turns), theta_start=float(phantom.theta_start),
        theta_end=float(phantom.theta_end), branch_deg=float(phantom.branch_deg), c_mm=float(phantom.c_mm),
        d=float(phantom.d), phi0_deg=float(phantom.phi0_deg), a_mm=float(phantom.a_mm),
        b_per_deg=float(phantom.b_per_deg), origin=origin, x_w=x_w, normal=normal,
        entry_width_mm=float(channel_width(phantom.theta_start, phantom)),
    )


def _spiral_angle(xy: np.ndarray, t: _AngleTable) -> np.ndarray:
    """Unwrapped angles (rad) of points ``xy`` (mm, shape (n, 2)): the same arithmetic as
    :func:`vision.geometry.point_angle`, with the phantom's constants precomputed in ``t``.

    Candidates clipped to [theta_start, theta_end] (> phi0) keep the logarithm finite, so no
    error-state guard is needed.
    """
    x, y = xy[:, 0], xy[:, 1]
    phi = np.arctan2(y, x)
    rho = np.hypot(x, y)
    cand = phi[:, None] + t.turns[None, :]
    clipped = np.minimum(np.maximum(cand, t.theta_start), t.theta_end)
    deg = np.degrees(clipped)
    r = np.where(deg < t.branch_deg, t.c_mm * (1.0 - t.d * np.log(deg - t.phi0_deg)), t.a_mm * np.exp(-t.b_per_deg * deg))
    k = np.argmin(np.abs(r - rho[:, None]) + 0.1 * np.abs(cand - clipped), axis=1)
    rel = xy - t.origin
    entry = ((rel @ t.x_w) < 0) & (np.abs(rel @ t.normal) <= t.entry_width_mm)
    return np.where(entry, phi, phi + 2 * np.pi * k)


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
    angles : _AngleTable
        The phantom's constants for the angles of measured points.
    r_tip_mm : float
        The array's radius (mm) at its tip.
    refusal : str or None
        Why no frame of this registration can be measured (the array too small in the image,
        see ``MeasureConfig.min_tip_px``), or None.
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
    angles: _AngleTable
    r_tip_mm: float
    refusal: str | None = None

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
    registration: _HasPose | CameraPose,
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
        records them (e.g. :meth:`vision.frames.LensCalibration.distort_points`): the strip then
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
        angles=_angle_table(phantom), r_tip_mm=float(array.radius(0.0)), refusal=_scale_refusal(ppm, array, cfg),
    )


# --------------------------------------------------------------------------- per-frame steps


def _to_gray(frame: np.ndarray) -> np.ndarray:
    """A 2-D uint8 or float32 grey image (grey levels 0–255) from a grey, BGR or BGRA frame."""
    a = np.asarray(frame)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        if a.dtype not in (np.uint8, np.float32):
            a = a.astype(np.float32)
        a = cv2.cvtColor(a, cv2.COLOR_BGRA2GRAY if a.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if a.ndim != 2 or a.size == 0:
        raise ValueError(f"a frame must be 2-D grey or BGR(A) colour, not shape {a.shape}")
    if a.dtype not in (np.uint8, np.float32):
        a = a.astype(np.float32)
    return a


def _odd(n: float) -> int:
    """The smallest odd integer (at least 1) not below ``n``."""
    k = max(1, int(np.ceil(n)))
    return k if k % 2 == 1 else k + 1


def _quantile(x: np.ndarray, q: float) -> float:
    """The ``q``-quantile (0–1) of ``x`` by sorting (cheaper than ``np.percentile`` here)."""
    xs = np.sort(x)
    return float(xs[int(round(q * (len(xs) - 1)))])


def _fluid_level(
    brightest: np.ndarray, in_view: np.ndarray, block: int, percentile: float, reach: int, floor: float
) -> np.ndarray:
    """The fluid's grey level along the channel.

    Parameters
    ----------
    brightest : ndarray, shape (n,)
        Brightest interior value (grey levels) at each station.
    in_view : ndarray, shape (n,), bool
        Stations inside the image.
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
    ndarray, shape (n,)
        A low percentile of ``brightest`` in consecutive blocks (blocks filled by the array
        interpolated from the others), the median of each block and its two neighbours,
        interpolated between block centres. It ignores the array where fluid shows beside it,
        metal bands brighter than the fluid (a minority of any block) and stations out of view.
    """
    n = len(brightest)
    good = np.flatnonzero(in_view)
    if len(good) == 0:
        return np.ones(n)
    values = brightest if len(good) == n else np.interp(np.arange(n), good, brightest[good])
    block = max(1, min(int(block), n))
    n_blocks = n // block
    blocks = values[: n_blocks * block].reshape(n_blocks, block)
    q = int(round(percentile / 100.0 * (block - 1)))
    level = np.partition(blocks, q, axis=1)[:, q]
    centres = block * np.arange(n_blocks) + 0.5 * (block - 1)
    # running maximum (scipy.ndimage.maximum_filter1d(mode="nearest") at a fraction of its cost)
    envelope = cv2.dilate(level[None, :], np.ones((1, 2 * reach + 1), np.uint8), borderType=cv2.BORDER_REPLICATE)[0]
    fluid_like = level >= floor * envelope
    if not fluid_like.all() and fluid_like.any():
        level = np.interp(centres, centres[fluid_like], level[fluid_like])
    if n_blocks >= 3:
        a, b, c = np.concatenate([level[:1], level[:-1]]), level, np.concatenate([level[1:], level[-1:]])
        level = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))  # median of three
    return np.maximum(np.interp(np.arange(n), centres, level), 1.0)


def _array_ratio(
    darkest: np.ndarray,
    brightest: np.ndarray,
    steepest: np.ndarray,
    fluid: np.ndarray,
    in_view: np.ndarray,
    min_count: int,
) -> float:
    """The array's grey level as a fraction of the fluid's, or NaN where it is not seen.

    Parameters
    ----------
    darkest, brightest : ndarray, shape (n,)
        Darkest and brightest interior value (grey levels) at each station.
    steepest : ndarray, shape (n,)
        Largest change (grey levels) between neighbouring interior samples across the channel.
    fluid : ndarray, shape (n,)
        Estimated fluid level (grey levels) at each station.
    in_view : ndarray, shape (n,), bool
        Stations inside the image.
    min_count : int
        Fewest stations that must show both.

    Returns
    -------
    float
        A low quantile (0.3) of darkest / brightest over stations where the array shows
        beside the fluid (brightest near the fluid level, darkest below 0.88 of it, an edge
        steeper than 5 % of it between neighbouring samples, and so at the two stations either
        side): a ratio taken side by side, so uneven lighting cancels;
        stations only partly covered (band borders, the tip) raise it, hence not the median.
        NaN when fewer than ``min_count`` stations show both: a dim channel (vignetting) is
        not taken for an array filling it.
    """
    ratio = darkest / np.maximum(brightest, 1.0)
    beside = in_view & (ratio < 0.88) & (np.abs(brightest / fluid - 1.0) < 0.15) & (steepest > 0.05 * brightest)
    beside[2:-2] &= beside[:-4] & beside[1:-3] & beside[3:-1] & beside[4:]  # not at band borders
    if beside.sum() < max(min_count, 3):
        return float("nan")
    return _quantile(ratio[beside], 0.3)


def _band_border_c(cfg: MeasureConfig, step_mm: float) -> int:
    """Coarse stations either side of a band's border kept out of the fluid's second estimate
    (``cfg.band_border_mm``, at least 2), for stations ``step_mm`` (mm) apart."""
    return max(2, int(np.ceil(cfg.band_border_mm / (max(1, int(cfg.coarse_stride)) * step_mm))))


def _erode(mask: np.ndarray, reach: int) -> np.ndarray:
    """``mask`` where it also holds at the ``reach`` stations on either side (along the last
    axis, so rows of frames are eroded independently)."""
    out = mask.copy()
    for k in range(1, reach + 1):
        out[..., k:] &= mask[..., :-k]
        out[..., :-k] &= mask[..., k:]
        out[..., :k] = False
        out[..., -k:] = False
    return out


def _dark_runs(dark: np.ndarray) -> np.ndarray:
    """Per row of ``dark`` (rows, n), the length of the run of True ending at each entry (0 where
    False)."""
    at = np.arange(dark.shape[1])[None, :]
    last_false = np.maximum.accumulate(np.where(dark, -1, at), axis=1)
    return np.where(dark, at - last_false, 0)


def _compact(x: np.ndarray, y: np.ndarray, w: np.ndarray, h: np.ndarray, area: np.ndarray, m: int,
             n: np.ndarray | int, step_mm: float, offset_mm: np.ndarray | float, cfg: MeasureConfig) -> np.ndarray:
    """Which bright components could be a bubble's interior: enclosed in their window (``m``
    offsets × ``n`` stations; not touching its border), of a bubble's size, fill and aspect.

    Parameters
    ----------
    x, y, w, h, area : ndarray of int
        Bounding boxes (station, offset) and pixel counts of the components, in their window.
    m : int
        Offsets of the windows.
    n : ndarray of int or int
        Stations of each component's window.
    step_mm : float
        Station spacing (mm).
    offset_mm : ndarray or float
        Offset spacing (mm) of each component's window.
    cfg : MeasureConfig
        ``bubble_*`` settings.

    Returns
    -------
    ndarray of bool
    """
    len_mm, wid_mm = w * step_mm, h * offset_mm
    return ((x > 0) & (x + w < n) & (y > 0) & (y + h < m) & (area * (step_mm * offset_mm) >= cfg.bubble_min_mm2)
            & (np.maximum(len_mm, wid_mm) <= 2.0 * cfg.bubble_max_mm)
            & (area >= cfg.bubble_fill[0] * w * h) & (area <= cfg.bubble_fill[1] * w * h)
            & (len_mm <= cfg.bubble_aspect * wid_mm) & (wid_mm <= cfg.bubble_aspect * len_mm))


def _with_compact(brights: list[np.ndarray], step_mm: float, offset_mm: np.ndarray, cfg: MeasureConfig) -> np.ndarray:
    """Which of the windows ``brights`` (each offsets × stations, bool) hold a :func:`_compact`
    component: all windows labelled in one call, side by side with an empty column between.

    Parameters
    ----------
    brights : list of ndarray of bool
        Each frame's bright pixels (same number of rows).
    step_mm : float
        Station spacing (mm).
    offset_mm : ndarray
        Offset spacing (mm) of each window.
    cfg : MeasureConfig
        ``bubble_*`` settings.

    Returns
    -------
    ndarray of bool, shape (len(brights),)
    """
    out = np.zeros(len(brights), bool)
    if not brights:
        return out
    m = brights[0].shape[0]
    widths = np.array([b.shape[1] for b in brights])
    starts = np.concatenate([[0], np.cumsum(widths + 1)[:-1]])
    canvas = np.zeros((m, int(starts[-1] + widths[-1])), np.uint8)
    for s0, b in zip(starts.tolist(), brights):
        canvas[:, s0: s0 + b.shape[1]] = b
    _, _, stats, _ = cv2.connectedComponentsWithStats(canvas, connectivity=4)
    x, y, w, h, area = (stats[1:, k] for k in range(5))
    f = np.searchsorted(starts, x, side="right") - 1
    compact = _compact(x - starts[f], y, w, h, area, m, widths[f], step_mm, offset_mm[f], cfg)
    out[f[compact]] = True
    return out


def _bubble_end(cover: np.ndarray, dark: np.ndarray, seed: np.ndarray, inside: np.ndarray, end: int,
                step_mm: float, offset_mm: float, diameter_mm: float, cfg: MeasureConfig) -> tuple[int, int | None]:
    """Where the array ends when an air bubble sits at or ahead of its tip.

    A bubble shows as a bright interior inside a closed dark rim. Along the channel its rim reads
    as more array (the rim is as dark as the array, and its interior no longer than a band) and
    across the channel the darkest offset jumps to the rim, so the dark run goes on past the tip.
    Its interior, unlike the fluid beyond the tip, is a bright region enclosed on all sides: a
    compact, round component of the bright pixels of the channel's interior. A metal band can be
    enclosed too (by the array's shaded edges) but is a rectangle no wider than the array, with
    the array's body beyond it; a bubble's interior is round and either wider than the array or
    followed, along the array's path, by no more than a thin rim. The array ends before the
    first such component on its path, less the rim's thickness (that of the rim beyond the
    interior): at the last dark station before it.

    Parameters
    ----------
    cover : ndarray, shape (offsets, stations)
        Coverage (0 fluid, 1 array) of one frame's fine strip from some stations basal of the
        dark end on.
    dark : ndarray, shape (stations,), bool
        Stations dark at their darkest offset.
    seed : ndarray, shape (stations,), int
        Each station's darkest offset.
    inside : ndarray, shape (offsets,), bool
        Offsets clear of the walls.
    end : int
        The dark run's last station (index into the window).
    step_mm, offset_mm : float
        Station and offset spacing (mm).
    diameter_mm : float
        The array's diameter (mm) near its tip.
    cfg : MeasureConfig
        ``bubble_*`` settings.

    Returns
    -------
    end : int
        The array's last station (``end`` when no bubble is on its path; -1 when none is left).
    stop : int or None
        The first station of the bubble's rim (the tip lies before it), or None.
    """
    bright = ((cover <= cfg.bubble_bright) & inside[:, None]).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(bright, connectivity=4)
    m, n = cover.shape
    x, y, w, h, area = (stats[1:, k] for k in range(5))
    wid_mm = h * offset_mm
    compact = _compact(x, y, w, h, area, m, n, step_mm, offset_mm, cfg)
    for k in np.flatnonzero(compact)[np.argsort(x[compact])].tolist():
        before = np.flatnonzero(dark[: x[k]])
        if len(before) == 0 or x[k] > end + 1 + int(np.ceil(cfg.max_gap_mm / step_mm)):
            continue
        track = np.median(seed[before[-int(np.ceil(cfg.bubble_track_mm / step_mm)):]])
        if not (y[k] <= track < y[k] + h[k]):  # beside the array's path, not on it
            continue
        reach = max(int(round(0.25 * diameter_mm / offset_mm)), 0)  # rows within a quarter diameter of it
        rows = slice(max(int(round(track)) - reach, 0), int(round(track)) + reach + 1)
        path = cover[rows].max(axis=0) >= cfg.dark_level  # dark on the array's path
        far = int(np.argmin(np.append(path[x[k] + w[k]:], False)))  # the rim beyond the interior
        if wid_mm[k] < cfg.bubble_wider * diameter_mm and far * step_mm > cfg.bubble_rim_mm:
            continue  # as narrow as a band, and array beyond it
        # the rim before it, and any array it touches: the longest dark run that ends where the
        # interior begins, over the interior's rows
        inner = labels[y[k] : y[k] + h[k]] == k + 1
        first = np.argmax(inner, axis=1)
        run = _dark_runs(cover[y[k] : y[k] + h[k]] >= cfg.dark_level)
        near = int(np.max(np.where(first > 0, run[np.arange(h[k]), np.maximum(first - 1, 0)], 0)))
        if near * step_mm <= cfg.bubble_rim_mm and x[k] - near > 0:  # fluid before the rim: the array ends there
            stop = int(x[k]) - near
            last = np.flatnonzero(path[:stop] & dark[:stop])
        else:  # the rim touches the array: take as much off as the rim beyond the interior is thick
            stop = max(int(x[k]) - far, 0)
            last = np.flatnonzero(dark[:stop])
        return (min(int(last[-1]), end) if len(last) else -1), stop
    return end, None


def _array_runs(dark: np.ndarray, probe: np.ndarray, max_gap: float) -> np.ndarray:
    """:func:`_array_run` of each row (frame) of ``dark``, shape (B, n): the last station of
    the dark run that starts at the first dark probe station, bridging gaps up to ``max_gap``
    stations (−1 where no probe station is dark).

    The run ends at the first dark station from its start whose next dark station is more
    than ``max_gap`` stations away, or that has none.
    """
    n_rows, n = dark.shape
    at = np.arange(n)
    in_probe = dark[:, probe]
    start = np.where(in_probe.any(axis=1), probe[in_probe.argmax(axis=1)], n)
    nxt = np.full((n_rows, n), n)  # the next dark station after each station (n: none)
    nxt[:, :-1] = np.minimum.accumulate(np.where(dark, at, n)[:, :0:-1], axis=1)[:, ::-1]
    ends = dark & (at >= start[:, None]) & ((nxt == n) | (nxt - at - 1 > max_gap))
    return np.where(start < n, ends.argmax(axis=1), -1)


def _at(a: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``a[i, j]`` of a 2-D array (indices broadcast together), by one flat ``np.take``: the
    same values, several times cheaper than NumPy's two-array fancy indexing."""
    a = np.ascontiguousarray(a)
    return np.take(a.reshape(-1), i * a.shape[1] + j)


def _crossing(cover: np.ndarray, j: np.ndarray, cols: np.ndarray, level: float) -> np.ndarray:
    """Where the coverage crosses ``level`` between offsets ``j`` and ``j + 1`` (linear).

    Parameters
    ----------
    cover : ndarray, shape (m, n)
        Coverage, offsets × stations.
    j : ndarray, shape (k,), int
        Offset just before each crossing (``cover`` is on either side of ``level`` at ``j``
        and ``j + 1``).
    cols : ndarray, shape (k,), int
        Station of each crossing.
    level : float
        Crossing level.

    Returns
    -------
    ndarray, shape (k,)
        Fractional offset index.
    """
    c1, c2 = _at(cover, j, cols), _at(cover, j + 1, cols)
    d = c2 - c1
    t = (level - c1) / np.where(np.abs(d) < 1e-6, 1e-6, d)
    return j + np.minimum(np.maximum(t, 0.0), 1.0)


def _half_crossings(cover: np.ndarray, seed: np.ndarray, level: float, run: np.ndarray | None = None,
                    wall: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel offsets where coverage falls below ``level`` either side of ``seed``, into the fluid.

    A lit array shows a bright stripe along its middle (a specular highlight on a round body),
    which can fall below the half level without being fluid. An edge is therefore only where the
    coverage then stays below the level for ``run`` offsets, or up to the wall margin: the fluid
    beside the array reaches the wall, a highlight inside it does not.

    Parameters
    ----------
    cover : ndarray, shape (m, n)
        Array coverage (0 fluid, 1 array), offsets × stations.
    seed : ndarray, shape (n,), int
        An offset inside the array at each station.
    level : float
        Crossing level.
    run : ndarray, shape (n,), optional
        Offsets the fluid must span at each station (default 1: the first crossing).
    wall : ndarray, shape (n,), optional
        First offset clear of the inner wall at each station (a run reaching it, or reaching the
        same margin from the outer wall, counts whatever its length; default 0).

    Returns
    -------
    low, high : ndarray, shape (n,)
        Fractional offset index (see :func:`_crossing`) of the nearest such crossing below and
        above ``seed`` at each station; NaN where there is none.
    """
    m, n = cover.shape
    j = np.arange(m, dtype=np.int16)[:, None]  # small integer types keep these passes fast
    s = seed.astype(np.int16)
    cols = np.arange(n)
    below = cover < level
    if run is not None:
        need = np.maximum(np.ceil(run), 1.0).astype(np.int16)[None, :]
        margin = np.floor(wall if wall is not None else np.zeros(n)).astype(np.int16)[None, :]
        # consecutive offsets below the level ending at j going down, and starting at j going up
        last_above = np.maximum.accumulate(np.where(below, np.int16(-1), j), axis=0)
        next_above = np.minimum.accumulate(np.where(below, np.int16(m), j)[::-1], axis=0)[::-1]
        down, up = j - last_above, next_above - j
        fluid_low = below & ((down >= need) | (last_above < margin))
        fluid_high = below & ((up >= need) | (next_above > np.int16(m - 1) - margin))
    else:
        fluid_low = fluid_high = below
    lo_idx = ((fluid_low & (j < s)) * (j + np.int16(1))).max(axis=0).astype(np.intp) - 1  # -1: none
    hi_idx = m - ((fluid_high & (j > s)) * (np.int16(m) - j)).max(axis=0).astype(np.intp)  # m: none
    both = np.full(2 * n, np.nan)  # low, then high
    j_both = np.concatenate([lo_idx, hi_idx - 1])
    ok = np.concatenate([lo_idx >= 0, hi_idx < m])
    both[ok] = _crossing(cover, j_both[ok], np.concatenate([cols, cols])[ok], level)
    return both[:n], both[n:]


def _window_line(sums: np.ndarray, k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares lines from window sums (see :func:`_smooth_valid`): fit, slope, has-data."""
    s0, s1, s2, t0, t1 = sums[0], sums[1], sums[2], sums[3 : 3 + k], sums[3 + k :]
    have = s0 > 0.5
    m0 = np.where(have, s0, 1.0)
    mx, my = s1 / m0, t0 / m0
    var = s2 / m0 - mx * mx
    sloped = have & (s0 >= 3) & (var >= 2.0)
    slope = np.where(sloped, (t1 / m0 - mx * my) / np.where(sloped, var, 1.0), 0.0)
    return my + slope * (x - mx), slope, have


def _sample(cover: np.ndarray, pos: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Coverage at fractional offset indices ``pos`` (shape (r, n), linear interpolation) of
    stations ``cols`` (shape (n,))."""
    m = cover.shape[0]
    pos = np.minimum(np.maximum(pos, 0.0), m - 1.001)
    j = pos.astype(np.intp)
    f = pos - j
    return _at(cover, j, cols) * (1 - f) + _at(cover, j + 1, cols) * f


def _plateaus(
    cover: np.ndarray, edge: np.ndarray, valid: np.ndarray, px: np.ndarray, wall: np.ndarray,
    plateau_px: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Coverage of the fluid and of the array either side of a rising edge at each station.

    Parameters
    ----------
    cover : ndarray, shape (m, k)
        Coverage (0 fluid, 1 array), offsets × stations (``k >= len(edge)``).
    edge : ndarray, shape (n,)
        Fractional offset index of an edge where the coverage rises with the offset.
    valid : ndarray, shape (n,), bool
        Stations whose edge was measured.
    px : ndarray, shape (n,)
        Pixels per offset index at each station.
    wall : ndarray, shape (n,)
        Lowest offset index clear of the wall on the low side at each station.
    plateau_px : tuple of float
        Nearest and farthest distance (px) from the edge of the samples averaged.

    Returns
    -------
    c_fluid, c_array : ndarray, shape (n,)
        Mean coverage of three samples on the fluid side and on the array side.
    fluid_ok, array_ok : ndarray, shape (n,), bool
        Where they were measured (the fluid side clear of the wall; inside the strip).
    """
    m, n = cover.shape[0], len(edge)
    cols = np.arange(n)
    e = np.where(valid, edge, 0.0)
    near, far = plateau_px
    dist = np.array([near, 0.5 * (near + far), far])[:, None] / px[None, :]
    both = _sample(cover, np.concatenate([e - dist, e + dist]), cols)
    c_fluid, c_array = (both[0] + both[1] + both[2]) / 3.0, (both[3] + both[4] + both[5]) / 3.0
    return c_fluid, c_array, valid & (e - dist[2] >= wall), valid & (e + dist[2] <= m - 1)


def _relevel(cover: np.ndarray, edge: np.ndarray, valid: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Move rising edges to where the coverage crosses a per-station level nearby.

    Parameters
    ----------
    cover : ndarray, shape (m, k)
        Coverage, offsets × stations (``k >= len(edge)``).
    edge : ndarray, shape (n,)
        Fractional offset index of an edge where the coverage rises with the offset.
    valid : ndarray, shape (n,), bool
        Stations whose edge was measured.
    level : ndarray, shape (n,)
        Coverage at which each edge is to be located.

    Returns
    -------
    ndarray, shape (n,)
        Each edge at the first rising crossing of ``level`` among the ten samples around it
        (linear interpolation); unchanged where there is none.
    """
    m, n = cover.shape[0], len(edge)
    cols = np.arange(n)
    j0 = np.minimum(np.maximum(np.floor(np.where(valid, edge, 0.0)).astype(np.intp) - 4, 0), max(m - 10, 0))
    window = _at(cover, j0[None, :] + np.arange(min(10, m))[:, None], cols)
    rising = (window[:-1] < level) & (window[1:] >= level)
    k = rising.argmax(axis=0)
    found = valid & rising.any(axis=0)
    a, b = _at(window, k, cols), _at(window, k + 1, cols)
    t = np.minimum(np.maximum((level - a) / np.where(np.abs(b - a) < 1e-6, 1e-6, b - a), 0.0), 1.0)
    return np.where(found, j0 + k + t, edge)


def _running_moments(values: np.ndarray, valid: np.ndarray, x: np.ndarray, pad: int) -> np.ndarray:
    """Running sums along the stations of the moments the local line fits need.

    Parameters
    ----------
    values : ndarray, shape (k, n)
        ``k`` profiles (any unit); only ``valid`` stations count (NaN elsewhere is ignored).
    valid : ndarray, shape (n,), bool
        Stations measured.
    x : ndarray, shape (n,)
        Station positions (stations).
    pad : int
        Columns of zeros before the sums and of the held total after them.

    Returns
    -------
    ndarray, shape (3 + 2k, n + 2 pad + 1)
        Rows w, w x, w x², w y (``k`` rows), w y x (``k`` rows), with w = ``valid``: column
        ``pad + 1 + i`` sums stations 0..i, the ``pad + 1`` columns before it are 0 and the
        ``pad`` after the last hold the total.
    """
    k, n = values.shape
    csum = np.zeros((3 + 2 * k, n + 2 * pad + 1))
    body = csum[:, pad + 1 : n + pad + 1]
    body[0] = valid
    np.multiply(body[0], x, out=body[1])
    np.multiply(body[1], x, out=body[2])
    np.copyto(body[3 : 3 + k], values, where=valid)  # 0 elsewhere (NaN there is ignored)
    np.multiply(body[3 : 3 + k], x, out=body[3 + k :])
    np.cumsum(body, axis=1, out=body)
    csum[:, n + pad + 1 :] = csum[:, n + pad : n + pad + 1]
    return csum


def _smooth_valid(
    values: np.ndarray, valid: np.ndarray, size: int, slope_size: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Local straight-line smoothing of profiles measured only at some stations.

    Parameters
    ----------
    values : ndarray, shape (k, n)
        ``k`` profiles (any unit) along ``n`` stations; only ``valid`` stations are used.
    valid : ndarray, shape (n,), bool
        Stations where ``values`` were measured (at least one).
    size : int
        Window (stations) of the local fits.
    slope_size : int, optional
        Window (stations) of the fits that give the slopes (default ``size``).

    Returns
    -------
    fit, slope : ndarray, shape (k, n)
        At each station, the value (and, over ``slope_size``, the slope in unit per station)
        of the least-squares line through the valid stations within the window (their mean,
        slope 0, where they are too few or too bunched for a slope: fewer than 3, or spread
        over fewer than about 5 stations); stations without any are interpolated linearly
        between the nearest that have (held constant beyond the ends). Unlike a running mean,
        a line is not biased by a trend at the ends of measured stretches (next to bands and
        the tip).
    """
    k, n = values.shape
    slope_size = size if slope_size is None else slope_size
    big = max(size, slope_size) // 2
    x = np.arange(n, dtype=float)
    csum = _running_moments(values, valid, x, big)

    def sums(h: int) -> np.ndarray:  # over stations i-h .. i+h (clipped)
        return csum[:, big + h + 1 : big + h + 1 + n] - csum[:, big - h : big - h + n]

    fit, slope, have = _window_line(sums(size // 2), k, x)
    if slope_size != size:
        slope = _window_line(sums(slope_size // 2), k, x)[1]
    if not have.all():
        for row in fit:
            row[~have] = np.interp(x[~have], x[have], row[have])
    return fit, slope


def _near(mask: np.ndarray, size: int) -> np.ndarray:
    """Where ``mask`` holds somewhere within the window of ``size`` (odd) stations centred on
    each station (clipped at the ends).

    Parameters
    ----------
    mask : ndarray, shape (n,), bool
    size : int
        Window length (stations, odd).

    Returns
    -------
    ndarray, shape (n,), bool
    """
    n, h = len(mask), int(size) // 2
    csum = np.zeros(n + 2 * h + 1, dtype=np.intp)
    np.cumsum(mask, out=csum[h + 1 : n + h + 1])
    csum[n + h + 1 :] = csum[n + h]
    return csum[2 * h + 1 :] > csum[: n]


def _running_median(x: np.ndarray, size: int) -> np.ndarray:
    """Median of each window of ``size`` (odd) samples of ``x`` centred on it, the ends
    extended with the end values (``scipy.ndimage.median_filter(x, size, mode="nearest")``
    in a handful of NumPy calls).

    Parameters
    ----------
    x : ndarray, shape (m,)
        Samples (any unit).
    size : int
        Window length (samples, odd).

    Returns
    -------
    ndarray, shape (m,)
    """
    h = int(size) // 2
    idx = np.arange(-h, h + 1)[None, :] + np.arange(len(x))[:, None]
    np.minimum(np.maximum(idx, 0, out=idx), len(x) - 1, out=idx)  # np.clip costs more per call
    return np.partition(x[idx], h, axis=1)[:, h]


def _extrapolate(stations: np.ndarray, values: np.ndarray, at: float, span: float) -> float:
    """Value at station ``at`` of a straight line fitted to the last ``span`` stations measured.

    Parameters
    ----------
    stations : ndarray, shape (k,)
        Stations (increasing) where ``values`` were measured.
    values : ndarray, shape (k,)
        Measured values (any unit).
    at : float
        Station (fractional) to evaluate the line at.
    span : float
        Length (stations) of the stretch fitted, ending at the last measured station.

    Returns
    -------
    float
        The line's value; the stretch's median when it holds fewer than 3 stations or spans
        less than a third of ``span``.
    """
    sel = stations >= stations[-1] - span
    r, v = stations[sel].astype(float), values[sel]
    if len(r) < 3 or r[-1] - r[0] < span / 3:
        return _quantile(v, 0.5)
    rm, vm = r.sum() / len(r), v.sum() / len(v)  # = .mean(), with less overhead
    return float(vm + np.dot(r - rm, v - vm) / np.dot(r - rm, r - rm) * (at - rm))


def _tip_crossing(cover_at: np.ndarray, level: float, fallback: float) -> float:
    """Fractional index where a coverage profile along the array last falls below ``level``.

    Parameters
    ----------
    cover_at : ndarray, shape (k,)
        Coverage (0 fluid, 1 array) along the channel at the array's centre line, basal first.
    level : float
        Crossing level.
    fallback : float
        Returned when the profile never falls below ``level``.

    Returns
    -------
    float
        Linear interpolation between the last station at or above ``level`` and the next.
    """
    above = cover_at >= level
    falls = np.flatnonzero(above[:-1] & ~above[1:])
    if len(falls) == 0:
        return fallback
    k = int(falls[-1])
    a, b = cover_at[k], cover_at[k + 1]
    return k + min(max(float((a - level) / max(a - b, 1e-6)), 0.0), 1.0)


def _sample_offsets(block: np.ndarray, j: float, around: np.ndarray) -> np.ndarray:
    """Mean over offsets ``j + around`` (fractional, interpolated) of each station of ``block``.

    Parameters
    ----------
    block : ndarray, shape (m, k)
        Strip (any unit), offsets × stations.
    j : float
        Fractional offset index.
    around : ndarray
        Offsets (in offset indices) averaged around ``j``.

    Returns
    -------
    ndarray, shape (k,)
    """
    m = block.shape[0]
    pos = np.minimum(np.maximum(j + around, 0), m - 1)
    j0 = np.minimum(pos.astype(int), m - 2)
    f = (pos - j0)[:, None]
    return (block[j0] * (1 - f) + block[j0 + 1] * f).mean(axis=0)


def _centre_offsets(
    v_in: np.ndarray,
    v_out: np.ndarray,
    ok_in: np.ndarray,
    ok_out: np.ndarray,
    s: np.ndarray,
    stretch: np.ndarray,
    array: ElectrodeArray,
    cap_min: float,
    tol_mm: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The array's centre offset at each station from its edges and its known shape.

    Parameters
    ----------
    v_in, v_out : ndarray, shape (n,)
        Offsets (mm, along the backbone normal) of the inner and the outer edge.
    ok_in, ok_out : ndarray, shape (n,), bool
        Where each edge was seen on the array's body.
    s : ndarray, shape (n,)
        Distance (mm) of each station's centre-line point from the tip.
    stretch : ndarray, shape (n,)
        Width across the channel over the array's width (1 / cosine of its slant).
    array : ElectrodeArray
        The array (radius along its length; the tip is a half disc).
    cap_min : float
        Stations closer to the tip than this fraction of the tip radius are not used.
    tol_mm : float
        How much narrower (mm) than expected the two edges may be before the station is
        taken to be cut by a band's border (at least 30 % of the half-width is allowed).

    Returns
    -------
    v_c : ndarray, shape (n,)
        Centre offset (mm): the inner edge plus the visible half-width where the inner edge
        was seen, else the outer edge minus it.
    measured : ndarray, shape (n,), bool
        Stations where ``v_c`` was measured.
    radius : ndarray, shape (n,)
        The array's radius (mm) at each station.
    """
    length = array.length_mm  # ElectrodeArray.radius, without its Python-level overhead
    s_in = np.minimum(np.maximum(s, 0.0), length)
    radius = 0.5 * (array.tip_diameter_mm + (array.base_diameter_mm - array.tip_diameter_mm) * s_in / length)
    r_tip = 0.5 * array.tip_diameter_mm
    body_half = np.where(s < r_tip, np.sqrt(np.maximum(r_tip**2 - (r_tip - s) ** 2, 0.0)), radius)
    visible = body_half * stretch
    cut = ok_in & ok_out & (v_out - v_in < 2.0 * visible - np.maximum(tol_mm, 0.3 * visible))
    use_in = ok_in & ~cut
    use_out = ok_out & ~ok_in & ~cut
    v_c = np.where(use_in, v_in + visible, v_out - visible)
    return v_c, (use_in | use_out) & (s >= cap_min * r_tip), radius


def _distance_from_tip(line: np.ndarray, tip_mm: np.ndarray, stations: np.ndarray, tip: float) -> np.ndarray:
    """Arc length (mm) from the tip along a centre line given basal station first.

    Parameters
    ----------
    line : ndarray, shape (n, 2)
        Centre-line point (mm) of each station, basal first.
    tip_mm : ndarray, shape (2,)
        The tip (mm), apical of the last station.
    stations : ndarray, shape (n,)
        Station indices.
    tip : float
        Fractional station of the tip; stations beyond it get 0.

    Returns
    -------
    ndarray, shape (n,)
    """
    d = np.diff(line, axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    s = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]]) + float(np.hypot(*(line[-1] - tip_mm)))
    return np.where(stations > tip, 0.0, s)


def _fail(reason: str, **extras: float) -> FrameMeasurement:
    """A not-ok measurement with a reason."""
    return FrameMeasurement(False, reason, extras={k: float(v) for k, v in extras.items()})


@dataclass(frozen=True)
class _Survey:
    """Stage 1 (coarse strip of the whole channel), at every ``sa``-th station.

    ``fluid_c`` fluid level (grey levels), ``rho`` array / fluid, ``contrast`` fluid − array
    at the entry (grey levels), ``seed_c`` darkest offset (coarse index), ``tip_est`` the
    dark run's last station (fine index).
    """

    fluid_c: np.ndarray
    rho: float
    contrast: float
    seed_c: np.ndarray
    tip_est: int


# --------------------------------------------------------------------------- stage 1 on a batch
#
# The survey of B frames at once (measure_frames_batch): the coarse strip is the same for
# every frame of a plan, so the strips are stacked along a leading axis and each step runs
# once per batch (the remap and the blur stay per frame); every step works row by row, so a
# frame's survey does not depend on the others in its batch.


def _fluid_levels(
    brightest: np.ndarray, in_view: np.ndarray, block: int, percentile: float, reach: int, floor: float
) -> np.ndarray:
    """:func:`_fluid_level` of each row (frame) of ``brightest``, equal to it row by row.

    Parameters
    ----------
    brightest : ndarray, shape (B, n), float32
        Brightest interior value (grey levels) at each station of each frame.
    in_view : ndarray, shape (B, n), bool
        Stations used, per frame.
    block, percentile, reach, floor
        As :func:`_fluid_level`.

    Returns
    -------
    ndarray, shape (B, n)
        Fluid level (grey levels).

    Notes
    -----
    A frame with every station in view keeps ``brightest``'s float32 in :func:`_fluid_level`
    (the others are interpolated to float64); only the comparison with the envelope depends
    on it, so it is made in that frame's precision.
    """
    n_rows, n = brightest.shape
    stations = np.arange(n)
    all_in, any_in = in_view.all(axis=1), in_view.any(axis=1)
    values = brightest.astype(np.float64)  # exact
    partial = (any_in & ~all_in)[:, None]
    if partial.any():  # stations out of view interpolated from those in view
        _fill_rows(values[:, None, :], in_view & partial, ~in_view & partial, stations.astype(float))
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
        _fill_rows(level[:, None, :], fluid_like & partial, ~fluid_like & partial, centres)
    if n_blocks >= 3:
        a = np.concatenate([level[:, :1], level[:, :-1]], axis=1)
        c = np.concatenate([level[:, 1:], level[:, -1:]], axis=1)
        level = np.maximum(np.minimum(a, level), np.minimum(np.maximum(a, level), c))
    out = np.ones((n_rows, n))
    rows = np.flatnonzero(any_in)
    if len(rows):
        out[rows] = np.maximum(_interp_rows(stations, centres, level[rows]), 1.0)
    return out


def _bracket(x: np.ndarray, xp: np.ndarray) -> np.ndarray:
    """For each query ``x``, the ``j`` with ``xp[j] <= x < xp[j + 1]`` as ``np.interp`` finds it,
    clipped to ``0 .. len(xp) - 2`` (``xp`` strictly increasing, at least 2 samples)."""
    return np.minimum(np.maximum(np.searchsorted(xp, x, side="right") - 1, 0), len(xp) - 2)


def _interp_at(x: np.ndarray, xp: np.ndarray, j: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """``np.interp``'s value at ``x`` from its bracket ``j`` (:func:`_bracket`) and the samples
    there (``lo`` at ``xp[j]``, ``hi`` at ``xp[j + 1]``), with its own arithmetic; ``first``
    and ``last`` (the end samples) beyond the ends."""
    value = (hi - lo) / (xp[j + 1] - xp[j]) * (x - xp[j]) + lo
    return np.where(x < xp[0], first, np.where(x >= xp[-1], last, value))


def _interp_ragged(x: np.ndarray, row: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp(x[i], xp, fp[row[i]])`` for each query ``i``, equal to it (finite values).

    Each query's bracket ``xp[j] <= x < xp[j + 1]`` is found once, as ``np.interp`` finds it,
    and the value computed with its arithmetic, ``(fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) *
    (x - xp[j]) + fp[j]``; beyond the ends, the end values.

    Parameters
    ----------
    x : ndarray, shape (q,)
        Query positions.
    row : ndarray, shape (q,), int
        Row of ``fp`` of each query.
    xp : ndarray, shape (m,)
        Strictly increasing sample positions, common to all rows.
    fp : ndarray, shape (B, m)
        Sample values per row.

    Returns
    -------
    ndarray, shape (q,)
    """
    m = len(xp)
    if m == 1:
        return fp[row, 0].astype(float)
    j = _bracket(x, xp)
    flat, at, first = fp.ravel(), row * m + j, row * m
    return _interp_at(x, xp, j, np.take(flat, at), np.take(flat, at + 1), np.take(flat, first),
                      np.take(flat, first + m - 1))


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp(x, xp, fp[b])`` for each row ``b`` of ``fp``, equal to it row by row (see
    :func:`_interp_ragged`; the brackets are common to all rows).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Query positions, common to all rows.
    xp : ndarray, shape (m,)
        Strictly increasing sample positions, common to all rows.
    fp : ndarray, shape (B, m)
        Sample values per row.

    Returns
    -------
    ndarray, shape (B, n)
    """
    m = len(xp)
    if m == 1:
        return np.repeat(fp[:, :1].astype(float), len(x), axis=1)
    j = _bracket(x, xp)
    return _interp_at(x, xp, j, fp[:, j], fp[:, j + 1], fp[:, :1], fp[:, -1:])


def _row_quantiles(x: np.ndarray, keep: np.ndarray, q: float) -> np.ndarray:
    """:func:`_quantile` of ``x[b][keep[b]]`` for each row ``b`` (NaN where none is kept)."""
    count = keep.sum(axis=1)
    xs = np.sort(np.where(keep, x, np.inf), axis=1)
    idx = np.round(q * (np.maximum(count, 1) - 1)).astype(np.intp)
    return np.where(count > 0, xs[np.arange(len(x)), idx].astype(np.float64), np.nan)


def _array_ratios(
    darkest: np.ndarray, brightest: np.ndarray, steepest: np.ndarray, fluid: np.ndarray, in_view: np.ndarray,
    min_count: int,
) -> np.ndarray:
    """:func:`_array_ratio` of each row (frame), shape (B,) (NaN where not seen)."""
    ratio = darkest / np.maximum(brightest, 1.0)
    beside = in_view & (ratio < 0.88) & (np.abs(brightest / fluid - 1.0) < 0.15) & (steepest > 0.05 * brightest)
    beside[:, 2:-2] &= beside[:, :-4] & beside[:, 1:-3] & beside[:, 3:-1] & beside[:, 4:]
    rho = _row_quantiles(ratio, beside, 0.3)
    return np.where(beside.sum(axis=1) < max(min_count, 3), np.nan, rho)


def _survey_batch(imgs: list[np.ndarray], plan: MeasurePlan) -> list[_Survey | FrameMeasurement]:
    """:func:`_survey` of each frame of ``imgs`` (grey, the plan's shape), computed together.

    Parameters
    ----------
    imgs : list of ndarray
        Grey frames (uint8 or float32) of the plan's image shape.
    plan : MeasurePlan
        The video's plan.

    Returns
    -------
    list of _Survey or FrameMeasurement
        Per frame, what :func:`_survey` returns for it.
    """
    if plan.refusal is not None:
        return [_fail(plan.refusal) for _ in imgs]
    cfg, step, sa = plan.cfg, plan.step_mm, max(1, int(plan.cfg.coarse_stride))
    coarse = np.empty((len(imgs),) + plan.coarse_x.shape, np.float32)
    for img, dst in zip(imgs, coarse):  # each frame's blurred coarse strip, written in place
        strip = cv2.remap(img, plan.coarse_x, plan.coarse_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        cv2.blur(strip.astype(np.float32, copy=False), (3, 3), dst=dst)
    n_rows = len(imgs)
    low = coarse + plan.coarse_penalty
    darkest = low.min(axis=1)
    seed_c = (low == darkest[:, None, :]).argmax(axis=1) + plan.coarse_row0  # = argmin (finite values), faster
    brightest = (coarse - plan.coarse_penalty).max(axis=1)
    pair_penalty = plan.coarse_penalty[1:] + plan.coarse_penalty[:-1]
    steepest = (np.abs(coarse[:, 1:] - coarse[:, :-1]) - pair_penalty).max(axis=1)
    view_c = plan.in_view[::sa]
    probe = np.flatnonzero((plan.p_mm[::sa] <= cfg.probe_mm) & view_c)
    if len(probe) == 0:
        return [_fail("entry out of view") for _ in imgs]
    block = int(round(cfg.fluid_window_mm / (sa * step)))
    reach = int(np.ceil(cfg.fluid_reach_mm / cfg.fluid_window_mm))
    min_beside = int(np.ceil(cfg.beside_mm / (sa * step)))
    views = np.broadcast_to(view_c, brightest.shape)
    fluid_c = _fluid_levels(brightest, views, block, cfg.fluid_percentile, reach, cfg.fluid_floor)
    rho1 = _array_ratios(darkest, brightest, steepest, fluid_c, view_c, min_beside)
    rho = rho1[:, None]
    contrast_c = fluid_c * (1.0 - rho)
    body = (fluid_c - darkest) / contrast_c >= cfg.body_level
    trusted = view_c & (_erode(body, _band_border_c(cfg, step)) | ((brightest - darkest) / contrast_c < 0.3))
    fluid_c = _fluid_levels(brightest, trusted, block, 75.0, reach, cfg.fluid_floor)
    rho2 = _array_ratios(darkest, brightest, steepest, fluid_c, view_c, min_beside)
    contrast = np.sort(fluid_c[:, probe], axis=1)[:, int(round(0.5 * (len(probe) - 1)))] * (1.0 - rho2)
    dark = ((1.0 - darkest / fluid_c) / (1.0 - rho2[:, None]) >= cfg.dark_level) & view_c
    tips_c = _array_runs(dark, probe, cfg.max_gap_mm / (sa * step)).tolist()
    out: list[_Survey | FrameMeasurement] = []
    for b in range(n_rows):
        if not rho1[b] == rho1[b] or not rho2[b] == rho2[b]:
            out.append(_fail("array not in channel"))
            continue
        c = float(contrast[b])
        if c < cfg.min_contrast:
            out.append(_fail("array not in channel", contrast=c))
            continue
        tip_c = tips_c[b]
        if tip_c < 0:
            out.append(_fail("array not in channel", contrast=c))
        elif not plan.in_view[min(sa * tip_c + sa + 2, len(plan.p_mm) - 1)]:
            out.append(_fail("tip out of view", contrast=c))
        else:
            out.append(_Survey(fluid_c[b], float(rho2[b]), c, seed_c[b], sa * tip_c))
    return out


@dataclass(frozen=True)
class _Edges:
    """Stage 2: the fine strip from station ``lo`` on (the array holds ``lo .. lo + n - 1``).

    ``fine`` the strip (grey levels), ``fluid`` and ``contrast`` per station (grey levels),
    ``seed`` darkest offset, ``v_in``/``v_out`` edge offsets (mm) and ``ok_in``/``ok_out``
    where they are the array body's, ``level`` the coverage half way between the fluid and
    the array beside it.
    """

    lo: int
    n: int
    fine: np.ndarray
    fluid: np.ndarray
    contrast: np.ndarray
    seed: np.ndarray
    v_in: np.ndarray
    v_out: np.ndarray
    ok_in: np.ndarray
    ok_out: np.ndarray
    level: float


def _fill(cover: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Mean coverage between the edges ``low`` and ``high`` (fractional offset indices) at each
    station (NaN where an edge is missing)."""
    m, n = cover.shape[0], len(low)
    ok = np.isfinite(low) & np.isfinite(high)
    a = np.clip(np.where(ok, np.ceil(low), 0), 0, m - 1).astype(np.intp)
    b = np.clip(np.where(ok, np.floor(high), 0), 0, m - 1).astype(np.intp)
    ok &= b >= a
    cs = np.vstack([np.zeros((1, n)), np.cumsum(cover[:, :n], axis=0)])
    cols = np.arange(n)
    mean = (_at(cs, b + 1, cols) - _at(cs, a, cols)) / np.maximum(b - a + 1, 1)
    return np.where(ok, mean, np.nan)


def _filled(fill: np.ndarray, body: np.ndarray, least: float) -> bool:
    """Whether the array's body is mostly dark between its edges: the median of ``fill`` over the
    ``body`` stations is at least ``least`` (a highlight along the middle of a round array takes a
    third of it at most; the grain of noise or of compression fills half)."""
    values = fill[body & np.isfinite(fill)]
    return len(values) == 0 or _quantile(values, 0.5) >= least


def _fluid_run(plan: MeasurePlan, px: np.ndarray) -> np.ndarray:
    """Offsets (per station, ``px`` px each) the fluid beside an edge must span: a share
    (:attr:`MeasureConfig.fluid_run`) of the array's tip diameter, at least 2 px."""
    ppm = float(plan.pose.px_per_mm)
    return np.maximum(plan.cfg.fluid_run * 2.0 * plan.r_tip_mm * ppm, 2.0) / px


@dataclass(frozen=True)
class _CentreLine:
    """Stage 3: the tip (fractional station ``tip_f`` from ``lo``, point ``tip_mm``), and per
    station the centre-line point ``line`` (mm), the gap (mm), the radius (mm) and whether
    the edges were used (``measured``)."""

    tip_f: float
    tip_mm: np.ndarray
    line: np.ndarray
    gap: np.ndarray
    radius: np.ndarray
    measured: np.ndarray
    width_ratio: float  # seen width over modelled width, median where both edges show (NaN: < 10 such)


# --------------------------------------------------------------------------- stages 2–3 on a batch
#
# Stages 2 and 3 of B frames in lock-step (measure_frames_batch). The frames' stations are laid
# end to end on one axis (a _Ragged batch), so each step is one NumPy call for all frames:
# station-wise arithmetic as it is; windows (erosion, _near, running medians) clipped at each
# frame's ends; per-frame statistics (medians, counts, last stations, the tip) from the frames
# padded to a common length; _smooth_valid, whose windows must stop at each frame's last
# station, on frames padded with invalid (zero-weight) stations, which leaves every frame's
# cumulative sums, and so its fits, exactly what they are alone. The only Python loops left are
# the per-frame remaps and the results' assembly. A frame's results do not depend on the others
# in its batch (to rounding: a few sums add in another order).


@dataclass(frozen=True, eq=False)
class _Ragged:
    """Frames' stations laid end to end on one axis.

    Frame ``b`` holds positions ``start[b] .. start[b] + n[b] - 1``; ``row`` and ``local`` give
    each position's frame and its station in that frame. Every frame holds at least one.
    """

    n: np.ndarray
    start: np.ndarray
    row: np.ndarray
    local: np.ndarray

    @classmethod
    def of(cls, lengths: np.ndarray | list[int]) -> "_Ragged":
        """The layout of frames of ``lengths`` (stations, each at least 1)."""
        n = np.asarray(lengths, dtype=np.intp)
        start = np.zeros(len(n), dtype=np.intp)
        np.cumsum(n[:-1], out=start[1:])
        row = np.repeat(np.arange(len(n)), n)
        return cls(n, start, row, np.arange(int(n.sum())) - start[row])

    @cached_property
    def width(self) -> int:
        """The longest frame (stations)."""
        return int(self.n.max())

    @cached_property
    def flat(self) -> np.ndarray:
        """Each position's index in the frames padded to :attr:`width` and flattened."""
        return self.row * self.width + self.local

    def pad(self, x: np.ndarray, fill: Any) -> np.ndarray:
        """``x`` (shape (..., total)) as (..., B, max n), each frame left-aligned, ``fill`` after."""
        out = np.full(x.shape[:-1] + (len(self.n) * self.width,), fill, dtype=x.dtype)
        out[..., self.flat] = x
        return out.reshape(x.shape[:-1] + (len(self.n), self.width))

    def count(self, mask: np.ndarray) -> np.ndarray:
        """Per frame, how many of its positions ``mask`` holds at."""
        return np.add.reduceat(mask.astype(np.intp), self.start)

    def last(self, mask: np.ndarray) -> np.ndarray:
        """Per frame, the last station where ``mask`` holds (−1 where none)."""
        return np.maximum.reduceat(np.where(mask, self.local, -1), self.start)

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """``x`` (shape (total, ...)) cut into its frames (views)."""
        return [x[s : s + m] for s, m in zip(self.start.tolist(), self.n.tolist())]

    def subset(self, frames: np.ndarray) -> tuple[np.ndarray, "_Ragged"]:
        """The positions of ``frames`` (increasing frame indices), as a mask over the
        positions, and those frames' own layout."""
        chosen = np.zeros(len(self.n), dtype=bool)
        chosen[frames] = True
        return chosen[self.row], _Ragged.of(self.n[frames])


def _erode_ragged(mask: np.ndarray, rg: _Ragged, reach: int) -> np.ndarray:
    """:func:`_erode` of each frame of a ragged ``mask`` (stations beyond a frame's ends fail)."""
    out = mask.copy()
    for k in range(1, reach + 1):
        out[k:] &= mask[:-k]
        out[:-k] &= mask[k:]
    return out & (rg.local >= reach) & (rg.local < rg.n[rg.row] - reach)


def _near_ragged(mask: np.ndarray, rg: _Ragged, size: int) -> np.ndarray:
    """:func:`_near` of each frame of a ragged ``mask`` (windows clipped at the frame's ends)."""
    h = int(size) // 2
    csum = np.zeros(len(mask) + 1, dtype=np.intp)
    np.cumsum(mask, out=csum[1:])
    i = np.arange(len(mask))
    first = rg.start[rg.row]
    last = first + rg.n[rg.row] - 1
    return csum[np.minimum(i + h, last) + 1] > csum[np.maximum(i - h, first)]


def _smooth_ragged(values: np.ndarray, valid: np.ndarray, rg: _Ragged, size: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_smooth_valid` of each frame of a ragged batch, equal to it frame by frame.

    The running sums of :func:`_smooth_valid` run over all frames' stations end to end, and
    each window's sum is the difference of two of them with the window clipped to its own
    frame (as in :func:`_near_ragged`). The weights, stations and their products are integers,
    so their sums, and with them which stations get a fit and a slope, are exactly the
    frame's own; the sums of the values differ from the frame's by rounding only.

    Parameters
    ----------
    values : ndarray, shape (k, total)
        ``k`` profiles (any unit) at the frames' stations (ragged ``rg``).
    valid : ndarray, shape (total,), bool
        Stations measured (at least one per frame); the others' values are ignored.
    rg : _Ragged
        The frames' layout.
    size : int
        Window (stations) of the local fits.

    Returns
    -------
    fit, slope : ndarray, shape (k, total)
        As :func:`_smooth_valid` (unit, unit per station).

    Raises
    ------
    ValueError
        A frame has no station with a fit (as ``np.interp`` in :func:`_smooth_valid`).
    """
    k, total = values.shape
    h = size // 2
    x = rg.local.astype(float)
    csum = _running_moments(values, valid, x, h)
    sums = csum[:, 2 * h + 1 :] - csum[:, :total]  # over positions i-h .. i+h
    near_end = np.flatnonzero((rg.local < h) | (rg.local >= rg.n[rg.row] - h))  # windows to clip to the frame
    if len(near_end):
        first = rg.start[rg.row[near_end]]
        hi = np.minimum(near_end + h, first + rg.n[rg.row[near_end]] - 1) + h + 1
        sums[:, near_end] = csum[:, hi] - csum[:, np.maximum(near_end - h, first) + h]
    fit, slope, have = _window_line(sums, k, x)
    if not have.all():
        _fill_ragged(fit, have, rg)
    return fit, slope


def _fill_ragged(fit: np.ndarray, known: np.ndarray, rg: _Ragged) -> None:
    """Fill ``fit[:, i]`` where not ``known[i]`` by linear interpolation between the known
    stations of its frame (their end values beyond them), in place: the per-frame
    ``np.interp(x[~known], x[known], row[known])`` of :func:`_smooth_valid` for all frames
    and rows, equal to it.

    The frames' stations are laid on one axis a whole number of stations apart, each frame
    flanked by a point of its first and of its last known value, so no query interpolates
    across frames and the differences of positions stay exact.

    Raises
    ------
    ValueError
        A frame has no known station.
    """
    i = np.arange(len(known))
    first = np.minimum.reduceat(np.where(known, i, len(known)), rg.start)
    last = np.maximum.reduceat(np.where(known, i, -1), rg.start)
    if (last < 0).any():
        raise ValueError("a frame has no valid station to interpolate from")
    pos = rg.local + float(rg.width + 3) * rg.row
    # each frame's stations between its two flanks: station i at i + 2 row + 1
    lo_at = rg.start + 2 * np.arange(len(rg.n))
    hi_at = lo_at + rg.n + 1
    at = i + 2 * rg.row + 1
    xp = np.empty(len(known) + 2 * len(rg.n))
    xp[lo_at], xp[hi_at], xp[at] = pos[rg.start] - 1.0, pos[rg.start] + rg.n, pos
    use = np.ones(len(xp), dtype=bool)
    use[at] = known
    xp, unknown = xp[use], np.flatnonzero(~known)
    fp = np.empty(len(use))
    for row in fit:
        fp[lo_at], fp[hi_at], fp[at] = row[first], row[last], row
        row[unknown] = np.interp(pos[unknown], xp, fp[use])


def _fill_rows(fit: np.ndarray, known: np.ndarray, unknown: np.ndarray, x: np.ndarray) -> None:
    """Fill ``fit[b, r, j]`` where ``unknown[b, j]`` by linear interpolation over ``x[j]``
    between frame ``b``'s ``known`` stations (the end values beyond them), in place: the
    per-frame ``np.interp(x[unknown[b]], x[known[b]], fit[b, r, known[b]])`` for all frames
    (with any known station) in one call per ``r``.

    The frames' positions ``x`` (increasing, integers or halves) are laid on one axis, each
    frame flanked by a point of its first and of its last known value, so no query
    interpolates across frames; the frames are an integer distance apart, so the differences
    of positions stay exact and each value equals its frame's own.
    """
    n_frames, n = known.shape
    pos = np.empty((n_frames, n + 2))  # each frame's positions between its two flanks
    pos[:, 1:-1] = x
    pos[:, 0], pos[:, -1] = x[0] - 1.0, x[-1] + 1.0
    pos += (float(np.ceil(x[-1] - x[0])) + 5.0) * np.arange(n_frames)[:, None]
    has = known.any(axis=1)
    use = np.zeros((n_frames, n + 2), dtype=bool)
    use[:, 1:-1], use[:, 0], use[:, -1] = known, has, has
    first = np.argmax(known, axis=1)
    last = n - 1 - np.argmax(known[:, ::-1], axis=1)
    xp = pos[use]  # increasing: frame by frame, each in order
    at = np.flatnonzero(unknown.ravel())
    xq = np.take(pos[:, 1:-1].ravel(), at)
    rows = np.arange(n_frames)
    values = np.empty((n_frames, n + 2))
    for r in range(fit.shape[1]):
        values[:, 1:-1] = fit[:, r]
        values[:, 0], values[:, -1] = fit[rows, r, first], fit[rows, r, last]
        filled = fit[:, r].copy()
        filled.ravel()[at] = np.interp(xq, xp, values[use])
        fit[:, r] = filled


def _edges_batch(imgs: list[np.ndarray], plan: MeasurePlan, surveys: list[_Survey]) -> list[_Edges]:
    """Stage 2: the array's inner and outer edge at each station that holds it, in each frame
    (with its survey; see the notes above :class:`MeasureConfig`)."""
    cfg, step, ppm = plan.cfg, plan.step_mm, float(plan.pose.px_per_mm)
    sa, n_all = max(1, int(cfg.coarse_stride)), len(plan.p_mm)
    span = max(4, int(np.ceil(0.4 / step)))
    u0, du = float(plan.u[0]), float(plan.u[1] - plan.u[0])
    # the fine strips (_fine_strip), laid end to end
    tips = np.array([sv.tip_est for sv in surveys], dtype=np.intp)
    body = int(np.ceil(cfg.min_body_mm / step))  # the stations basal of the tip the centre line needs
    lo = np.maximum(np.minimum(tips - body, plan.i_start), 0)
    hi0 = np.minimum(tips + sa + span + 1, n_all)  # where the tip is sought
    hi = np.minimum(hi0 + int(np.ceil((2.0 * cfg.bubble_max_mm + 0.3) / step)), n_all)  # and a bubble beyond
    fines = [cv2.remap(img, plan.map_x[:, a:b], plan.map_y[:, a:b], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
             for img, a, b in zip(imgs, lo.tolist(), hi.tolist())]
    strip = _Ragged.of(hi - lo)
    station = lo[strip.row] + strip.local
    fluid_c = np.stack([sv.fluid_c for sv in surveys])
    fluid = _interp_ragged(station, strip.row, sa * np.arange(fluid_c.shape[1]), fluid_c)
    contrast = fluid * (1.0 - np.array([sv.rho for sv in surveys])[strip.row])
    blurred = np.concatenate([cv2.blur(f, (3, 1)) for f in fines], axis=1)
    scale, shift = -1.0 / contrast, fluid / contrast  # coverage = blurred * scale + shift
    seed_c = np.stack([sv.seed_c for sv in surveys])
    seed = np.minimum(sa * _at(seed_c, strip.row, station // sa), len(plan.u) - 1)
    at_seed = _at(blurred, seed, np.arange(len(station))).astype(np.float32) * scale + shift
    darkness = np.where(np.take(plan.in_view, station), at_seed, 0.0)
    first_n = np.minimum(tips + sa, hi - 1) - lo + 1  # stations where the array's dark end is sought
    last_dark = strip.last((darkness >= cfg.dark_level) & (strip.local < first_n[strip.row]))
    extent = hi0 - lo
    back = int(np.ceil((2.0 * cfg.bubble_max_mm + cfg.max_gap_mm + cfg.bubble_track_mm) / step))
    inner = np.abs(plan.u)
    windows = []  # an air bubble at or ahead of the tip: each frame's window from `back` before its dark end
    for b in np.flatnonzero(last_dark >= 0).tolist():
        end, a = int(last_dark[b]), max(int(last_dark[b]) - back, 0)
        cols = slice(int(strip.start[b]) + a, int(strip.start[b] + strip.n[b]))
        half_b = float(np.median(plan.half_mm[lo[b] + a : lo[b] + strip.n[b]]))
        windows.append((b, end, a, cols, half_b, blurred[:, cols] * scale[cols] + shift[cols],
                        inner <= 1.0 - cfg.wall_margin_px / (half_b * ppm)))
    candidates = _with_compact([(c <= cfg.bubble_bright) & i[:, None] for *_, c, i in windows], step,
                               np.array([du * w[4] for w in windows]), cfg)
    for (b, end, a, cols, half_b, cover_b, inside_b), candidate in zip(windows, candidates.tolist()):
        if not candidate:  # no bubble-like component in the window: _bubble_end would find none
            continue
        cut, stop = _bubble_end(cover_b, darkness[cols] >= cfg.dark_level, seed[cols], inside_b, end - a, step,
                                du * half_b, 2.0 * plan.r_tip_mm, cfg)
        if stop is not None:
            last_dark[b], extent[b] = max(cut + a, 0), stop + a
    # the stations that hold the array
    arr = _Ragged.of(np.where(last_dark >= 0, last_dark + 1, tips - lo + 1))
    take = strip.start[arr.row] + arr.local
    cover = np.take(blurred, take, axis=1).astype(np.float64)  # = the float32 levels, exactly
    cover *= np.take(scale, take)  # float64 throughout: a float32 operand costs a cast pass
    cover += np.take(shift, take)
    seed_a, dark_a = np.take(seed, take), np.take(darkness, take)
    half = np.take(plan.half_mm, lo[arr.row] + arr.local)
    px = du * half * ppm  # px per offset index at each station
    wall = (-1.0 + cfg.wall_margin_px / (half * ppm) - u0) / du  # first offset clear of the inner wall
    # the edges (_edges)
    low, high = _half_crossings(cover, seed_a, cfg.edge_level, _fluid_run(plan, px), wall)
    body = _erode_ragged(dark_a >= cfg.body_level, arr, cfg.border_px)
    c_fluid, c_array, fluid_ok, array_ok = _plateaus(cover, low, body & np.isfinite(low), px, wall, cfg.plateau_px)
    c_f = np.where(arr.count(fluid_ok) >= 10, _row_quantiles(arr.pad(c_fluid, 0.0), arr.pad(fluid_ok, False), 0.5), 0.0)
    c_a = np.where(arr.count(array_ok) >= 10, _row_quantiles(arr.pad(c_array, 0.0), arr.pad(array_ok, False), 0.5), 1.0)
    implausible = c_a - c_f < 0.3  # keep the global levels (_edge_levels)
    c_f, c_a = np.where(implausible, 0.0, c_f), np.where(implausible, 1.0, c_a)
    level = (0.5 * (c_f + c_a))[arr.row]
    window = _odd(2.0 * cfg.gap_smooth_mm / step)
    local = np.flatnonzero(arr.count(fluid_ok) >= 3)
    if len(local):  # where the fluid shows clear of the wall, the local levels
        sub, part = arr.subset(local)
        ok = fluid_ok[sub]
        (lf, la), _ = _smooth_ragged(np.vstack([c_fluid[sub], c_array[sub]]), ok, part, window)
        near = np.zeros(len(level), dtype=bool)
        near[sub] = _near_ragged(ok, part, window)
        smooth = np.zeros(len(level))
        smooth[sub] = 0.5 * (lf + la)
        level = np.where(near, smooth, level)
    low = _relevel(cover, low, np.isfinite(low), level)
    cf, ca = c_f[arr.row], c_a[arr.row]
    body = _erode_ragged((dark_a - cf) / (ca - cf) >= cfg.body_level, arr, cfg.border_px)
    v_in, v_out = (u0 + du * low) * half, (u0 + du * high) * half
    fill = _fill(cover, low, high)
    for b in range(arr.n.size):  # a frame whose "body" is not dark between its edges has no array
        sl = slice(int(arr.start[b]), int(arr.start[b] + arr.n[b]))
        if not _filled(fill[sl], body[sl], cfg.body_fill):
            body[sl] = False
    ok_in, ok_out = body & (v_in >= -half), body & (v_out <= half)  # NaN compares False
    out = []
    for b, (s0, w, s, m) in enumerate(zip(strip.start.tolist(), extent.tolist(), arr.start.tolist(), arr.n.tolist())):
        a = slice(s, s + m)
        out.append(_Edges(int(lo[b]), m, fines[b][:, :w], fluid[s0 : s0 + w], contrast[s0 : s0 + w], seed[s0 : s0 + w],
                          v_in[a], v_out[a], ok_in[a], ok_out[a], 0.5 * (float(c_f[b]) + float(c_a[b]))))
    return out


def _distance_from_tip_ragged(line: np.ndarray, tip_mm: np.ndarray, tip_f: np.ndarray, rg: _Ragged) -> np.ndarray:
    """:func:`_distance_from_tip` of each frame's centre line, equal to it frame by frame.

    The lines are right-aligned in one array, padded in front with their first point (zero
    segments), so that each row's reversed running sum adds the line's own segments in the
    same order, then zeros.

    Parameters
    ----------
    line : ndarray, shape (total, 2)
        Centre-line points (mm) of the frames' stations (ragged ``rg``), basal first.
    tip_mm : ndarray, shape (B, 2)
        Per frame, the tip (mm).
    tip_f : ndarray, shape (B,)
        Per frame, the tip's fractional station; stations beyond it get 0.
    rg : _Ragged
        The frames' layout.

    Returns
    -------
    ndarray, shape (total,)
    """
    n = int(rg.n.max())
    col = n - rg.n[rg.row] + rg.local
    padded = np.repeat(line[rg.start][:, None, :], n, axis=1)
    padded[rg.row, col] = line
    d = np.diff(padded, axis=1)
    seg = np.hypot(d[:, :, 0], d[:, :, 1])
    s = np.zeros((len(rg.n), n))
    s[:, :-1] = np.cumsum(seg[:, ::-1], axis=1)[:, ::-1]
    last = padded[:, -1] - tip_mm
    s += np.hypot(last[:, 0], last[:, 1])[:, None]
    return np.where(rg.local > tip_f[rg.row], 0.0, s[rg.row, col])


def _running_median_ragged(x: np.ndarray, rg: _Ragged, size: int) -> np.ndarray:
    """:func:`_running_median` of each frame of a ragged ``x``, each window's indices clamped
    to its own frame's ends."""
    h = int(size) // 2
    first = rg.start[rg.row][:, None]
    idx = np.arange(-h, h + 1)[None, :] + np.arange(len(x))[:, None]
    np.minimum(np.maximum(idx, first, out=idx), first + rg.n[rg.row][:, None] - 1, out=idx)
    return np.partition(x[idx], h, axis=1)[:, h]


def _centre_line_batch(plan: MeasurePlan, edges: list[_Edges]) -> list[_CentreLine | str]:
    """Stage 3: each frame's centre line, tip and gap to the outer wall, or why there is none: no
    edges, the edges seen on both sides do not have the array's width, or no edges within
    ``tip_reach_mm`` of the tip (the dark run goes on where no array shows: a bubble's rim, a
    shadow, a doubled wall line)."""
    cfg, array, step, ppm = plan.cfg, plan.array, plan.step_mm, float(plan.pose.px_per_mm)
    u0, du = float(plan.u[0]), float(plan.u[1] - plan.u[0])
    k_smooth = _odd(cfg.gap_smooth_mm / step)
    tol = cfg.outlier_px / ppm
    span = max(4, int(np.ceil(0.4 / step)))
    out: list[_CentreLine | str] = ["array edges not found"] * len(edges)
    rg = _Ragged.of([e.n for e in edges])
    lo = np.array([e.lo for e in edges], dtype=np.intp)
    station = lo[rg.row] + rg.local
    v_in, v_out, ok_in, ok_out = (np.concatenate([getattr(e, name) for e in edges])
                                  for name in ("v_in", "v_out", "ok_in", "ok_out"))
    # pass 1: distance from the tip along the backbone, array parallel to the channel
    s = plan.p_mm[lo + rg.n - 1][rg.row] - plan.p_mm[station]
    v_c, measured, _ = _centre_offsets(v_in, v_out, ok_in, ok_out, s, np.ones(len(s)), array, cfg.cap_min, tol)
    live = np.flatnonzero(rg.count(measured) >= 3)
    if not len(live):
        return out
    if len(live) < len(edges):  # the others have no centre line
        sub, rg = rg.subset(live)
        lo, station = lo[live], station[sub]
        v_in, v_out, ok_in, ok_out, v_c, measured = (a[sub] for a in (v_in, v_out, ok_in, ok_out, v_c, measured))
    n, row, local = rg.n, rg.row, rg.local
    # outliers: off their neighbours' running median by more than 3 robust SDs (and tol)
    at = np.flatnonzero(measured)
    med = np.zeros(len(v_c))
    med[at] = _running_median_ragged(v_c[at], _Ragged.of(rg.count(measured)), k_smooth)
    dev = np.abs(v_c - med)
    mad = _row_quantiles(rg.pad(dev, 0.0), rg.pad(measured, False), 0.5)
    measured &= dev <= np.maximum(tol, 3.0 * 1.4826 * mad)[row]
    (centre,), (slant,) = _smooth_ragged(v_c[None, :], measured, rg, _odd(2.5 * cfg.gap_smooth_mm / step))
    stretch = np.sqrt(1.0 + (slant / step) ** 2)
    # the tip: the half-level crossing along the centre line, extrapolated from the body
    last = rg.last(measured)
    half_tip = plan.half_mm[lo + n - 1]
    tip_v = _extrapolate_ragged(local.astype(float), v_c, measured & (local >= (last - 1.0 / step)[row]), 1.0 / step, rg)
    bare = (n - 1 - last) * step > cfg.tip_reach_mm  # no array edges near the tip
    for b in np.flatnonzero(bare):
        out[int(live[b])] = f"no array edges within {cfg.tip_reach_mm:g} mm of the dark run's end"
    tip_u = np.minimum(np.maximum(tip_v / half_tip, -1.0), 1.0)
    k0 = np.maximum(n - 1 - span, 0)
    tail = _Ragged.of([len(edges[b].fluid) - k for b, k in zip(live.tolist(), k0.tolist())])
    fine = np.concatenate([edges[b].fine[:, k:] for b, k in zip(live.tolist(), k0.tolist())], axis=1)
    fluid = np.concatenate([edges[b].fluid[k:] for b, k in zip(live.tolist(), k0.tolist())])
    contrast = np.concatenate([edges[b].contrast[k:] for b, k in zip(live.tolist(), k0.tolist())])
    m = fine.shape[0]
    pos = np.minimum(np.maximum(((tip_u - u0) / du)[:, None] + np.array([-1.0, 0.0, 1.0]), 0), m - 1)  # (B, 3)
    j0 = np.minimum(pos.astype(int), m - 2)
    f, j0 = (pos - j0).T[:, tail.row], j0.T[:, tail.row]
    cols = np.arange(len(tail.row))
    sampled = _at(fine, j0, cols) * (1 - f) + _at(fine, j0 + 1, cols) * f  # _sample_offsets
    along = (fluid - (sampled[0] + sampled[1] + sampled[2]) / 3.0) / contrast
    level = np.array([edges[b].level for b in live.tolist()])
    tip_f = k0 + _tip_crossing_ragged(along, level, (n - 1 - k0).astype(float), tail)
    tip_mm = plan.to_mm(lo + tip_f, tip_u)
    # pass 2: distance along the measured centre line, slant across the channel -> gaps
    point, normal, half = plan.point_mm[station], plan.normal[station], plan.half_mm[station]
    s = _distance_from_tip_ragged(point + centre[:, None] * normal, tip_mm, tip_f, rg)
    v_c, measured2, radius = _centre_offsets(v_in, v_out, ok_in, ok_out, s, stretch, array, cfg.cap_min, tol)
    before = local <= tip_f[row]
    measured &= measured2 & before
    good = rg.count(measured) >= 3
    # where both edges show, the array must be about as wide as it is (noise is not)
    both = ok_in & ok_out & before & (s >= plan.r_tip_mm)
    width = 2.0 * radius * stretch
    fits = np.abs(v_out - v_in - width) <= np.maximum(2.0 / ppm, 0.3 * width)
    n_both = rg.count(both)
    good &= ~((n_both >= 10) & (rg.count(fits & both) / np.maximum(n_both, 1) < 0.5))
    stretch_tip = before & (s <= cfg.tip_width_mm)
    min_count = int(np.ceil(0.25 * cfg.tip_width_mm / step))
    n_tip = rg.count(stretch_tip)
    odd = (n_tip >= min_count) & (rg.count(ok_in & stretch_tip) < cfg.tip_inner_min * n_tip)
    # a centre line closer to a wall than half the array's radius: the array would cross it
    n_meas = rg.count(measured & stretch_tip)
    in_wall = measured & stretch_tip & ((half - np.abs(v_c)) < 0.5 * radius)
    odd |= (n_meas >= min_count) & (rg.count(in_wall) >= cfg.tip_wall_share * n_meas)
    for b in np.flatnonzero(good & ~bare & odd):
        out[int(live[b])] = f"the dark run's last {cfg.tip_width_mm:g} mm does not look like the array (a line?)"
    keep = np.flatnonzero(good & ~bare & ~odd)
    if not len(keep):
        return out
    seen = np.where(both, (v_out - v_in) / np.where(both, width, 1.0), 0.0)
    width_ratio = np.where(n_both >= 10, _row_quantiles(rg.pad(seen, 0.0), rg.pad(both, False), 0.5), np.nan)
    sub, part = rg.subset(keep)
    ok = measured[sub]
    (centre, gap), _ = _smooth_ragged(np.vstack([v_c[sub], (half - v_c - radius * stretch)[sub]]), ok, part, k_smooth)
    line = point[sub] + centre[:, None] * normal[sub]
    radius = radius[sub]
    for b, s0, m_b in zip(keep.tolist(), part.start.tolist(), part.n.tolist()):
        a = slice(s0, s0 + m_b)
        out[int(live[b])] = _CentreLine(float(tip_f[b]), tip_mm[b], line[a], gap[a], radius[a], ok[a],
                                        float(width_ratio[b]))
    return out


def _extrapolate_ragged(stations: np.ndarray, values: np.ndarray, sel: np.ndarray, span: float,
                       rg: _Ragged) -> np.ndarray:
    """:func:`_extrapolate` of each frame to its last station.

    Parameters
    ----------
    stations, values : ndarray, shape (total,)
        Station (float) and value (any unit) at each position of the frames (ragged ``rg``).
    sel : ndarray, shape (total,), bool
        The stations each frame's line is fitted to: measured, and within ``span`` of the
        frame's last measured station (at least one per frame).
    span : float
        Length (stations) of the stretch fitted.
    rg : _Ragged
        The frames' layout.

    Returns
    -------
    ndarray, shape (B,)
        Per frame, the line's value at its last station; the stretch's median when it holds
        fewer than 3 stations or spans less than a third of ``span``.
    """
    count = rg.count(sel)
    w = rg.pad(sel, False)
    r, v = rg.pad(np.where(sel, stations, 0.0), 0.0), rg.pad(np.where(sel, values, 0.0), 0.0)
    rm, vm = r.sum(axis=1) / count, v.sum(axis=1) / count
    dr = np.where(w, r - rm[:, None], 0.0)
    line = vm + (dr * (v - vm[:, None])).sum(axis=1) / (dr * dr).sum(axis=1) * ((rg.n - 1) - rm)
    spread = np.where(w, r, -np.inf).max(axis=1) - np.where(w, r, np.inf).min(axis=1)
    short = (count < 3) | (spread < span / 3)
    return np.where(short, _row_quantiles(v, w, 0.5), line) if short.any() else line


def _tip_crossing_ragged(cover_at: np.ndarray, level: np.ndarray, fallback: np.ndarray, rg: _Ragged) -> np.ndarray:
    """:func:`_tip_crossing` of each frame's coverage profile.

    Parameters
    ----------
    cover_at : ndarray, shape (total,)
        Coverage (0 fluid, 1 array) along each frame's centre line (ragged ``rg``), basal first.
    level : ndarray, shape (B,)
        Per frame, the crossing level.
    fallback : ndarray, shape (B,)
        Per frame, the value where the profile never falls below its level.
    rg : _Ragged
        The frames' layout.

    Returns
    -------
    ndarray, shape (B,)
    """
    above = cover_at >= level[rg.row]
    falls = above.copy()
    falls[:-1] &= ~above[1:]
    k = rg.last(falls & (rg.local < rg.n[rg.row] - 1))
    at = rg.start + np.maximum(k, 0)
    a, b = cover_at[at], cover_at[np.minimum(at + 1, len(cover_at) - 1)]
    t = np.minimum(np.maximum((a - level) / np.maximum(a - b, 1e-6), 0.0), 1.0)
    return np.where(k >= 0, k + t, fallback)


def _results_batch(plan: MeasurePlan, staged: list[tuple[_Edges, _CentreLine, dict[str, float]]]
                   ) -> list[FrameMeasurement]:
    """Stage 4: each frame's angles, depth and outline from its centre line, all frames at once.

    The centre line is the tip, then every ``angle_step_mm`` of stations from the last one at or
    before the tip, basal-wards; the frames' points are laid end to end (a :class:`_Ragged`
    batch), their angles taken in one call (:func:`_spiral_angle` works point by point) and
    :func:`contact_angles`' rule applied to all frames at once. The depth is the centre line's
    length from the tip to ``theta_start`` (negative, along the entry, when the tip is still in
    the entry channel)."""
    cfg, step = plan.cfg, plan.step_mm
    k = max(1, int(round(cfg.angle_step_mm / step)))
    los = np.array([e.lo for e, _, _ in staged], dtype=np.intp)
    tip_f = np.array([c.tip_f for _, c, _ in staged])
    tip_mm = np.array([c.tip_mm for _, c, _ in staged])
    n = np.array([e.n for e, _, _ in staged], dtype=np.intp)
    line, gap, radius = (np.concatenate([getattr(c, name) for _, c, _ in staged]) for name in ("line", "gap", "radius"))
    # the kept stations: every k-th from the last one at or before the tip
    top = np.minimum(np.floor(tip_f).astype(np.intp), n - 1)
    kept = _Ragged.of(top // k + 1)
    keep = top[kept.row] - k * kept.local  # station in its frame
    at = (np.cumsum(n) - n)[kept.row] + keep  # position in line, gap, radius
    # the centre line: the tip, then the kept stations' points
    cl = _Ragged.of(kept.n + 1)
    inner = cl.start[kept.row] + 1 + kept.local  # positions of the kept points in cl
    points = np.empty((len(cl.row), 2))
    points[cl.start], points[inner] = tip_mm, line[at]
    gaps = np.empty(len(cl.row))
    gaps[cl.start], gaps[inner] = gap[at[kept.start]], gap[at]
    theta = _spiral_angle(points, plan.angles)
    # contact_angles' rule: the contact run from the tip ends where the gap first exceeds the
    # tolerance, but not at a blip of measurement noise: an excursion shorter than
    # contact_persist_mm, by less than contact_excess_mm, after which contact holds again for
    # contact_persist_mm (a real departure from the wall widens steadily)
    # the tolerance, raised by any bias of the measured gaps (MeasureConfig.contact_bias_mm): the
    # median gap of each frame's stretch before its first gap over tol + excess
    hard = np.where(gaps > cfg.contact_tol_mm + cfg.contact_excess_mm, cl.local, cl.n[cl.row])
    stretch = cl.local < np.minimum.reduceat(hard, cl.start)[cl.row]
    counts = cl.count(stretch)
    ranked = np.sort(cl.pad(np.where(stretch, gaps, np.inf), np.inf), axis=1)  # each frame's stretch, ascending
    median = ranked[np.arange(len(counts)), np.maximum(counts - 1, 0) // 2]  # the lower median
    bias = np.where(counts > 0, np.clip(median - 0.5 * cfg.contact_tol_mm, 0.0, cfg.contact_bias_mm), 0.0)
    tol = (cfg.contact_tol_mm + bias)[cl.row]
    touching = gaps <= tol
    pos = np.arange(len(gaps))
    end = (cl.start + cl.n)[cl.row]
    # the next touching / non-touching point of each point's frame, or the frame's end (a later
    # frame's points all lie at or beyond this frame's end, so the running minimum stays in it)
    next_touch = np.minimum.accumulate(np.where(touching, pos, end)[::-1])[::-1]
    next_away = np.minimum.accumulate(np.where(~touching, pos, end)[::-1])[::-1]
    persist = int(np.ceil(cfg.contact_persist_mm / cfg.angle_step_mm))
    resumes = next_away[np.minimum(next_touch, len(gaps) - 1)] - next_touch >= persist
    blip = (next_touch - pos < persist) & (next_touch < end) & resumes & (gaps <= tol + cfg.contact_excess_mm)
    away = np.where(~touching & ~blip, cl.local, cl.n[cl.row])
    out_at = np.minimum.reduceat(away, cl.start)  # first point out of contact (n: none)
    i_last = np.where(out_at < cl.n, out_at - 1, cl.n - 1)
    i0 = cl.start + np.maximum(i_last, 0)
    i1 = cl.start + np.minimum(i_last + 1, cl.n - 1)
    g0, g1 = gaps[i0], gaps[np.minimum(i0 + 1, len(gaps) - 1)]
    frac = np.where((out_at < cl.n) & (g1 != g0),
                    np.minimum(np.maximum((tol[i0] - g0) / (g1 - g0), 0.0), 1.0), 0.0)
    contact = touching[cl.start]
    theta_tip = theta[cl.start]
    theta_bot = np.where(contact, theta[i0] + frac * (theta[i1] - theta[i0]), theta_tip)
    bot = np.where(contact[:, None], points[i0] + frac[:, None] * (points[i1] - points[i0]), points[cl.start])
    seg = np.diff(points, axis=0)
    seg = np.hypot(seg[:, 0], seg[:, 1])
    seg[cl.start[1:] - 1] = 0.0  # between frames
    depth = np.add.reduceat(np.append(seg, 0.0), cl.start)
    basal = los + keep[kept.start + kept.n - 1]  # a line that starts in the entry: less its part there
    depth -= np.maximum(plan.p_mm[plan.i_start] - plan.p_mm[basal], 0.0)
    entry = los + tip_f < plan.i_start  # tip in the entry channel: theta = phi (k = 0), no contact
    theta_bot = np.where(entry, theta_tip, theta_bot)
    bot = np.where(entry[:, None], tip_mm, bot)
    depth = np.where(entry, -(plan.p_mm[plan.i_start] - plan.p_mm[los] - tip_f * step), depth)
    # the outline: the tip, one side tipwards to base, the other back
    side = radius[at][:, None] * plan.normal[los[kept.row] + keep]
    ol = _Ragged.of(2 * kept.n + 1)
    outline = np.empty((len(ol.row), 2))
    outline[ol.start] = tip_mm
    outline[ol.start[kept.row] + 1 + kept.local] = line[at] - side
    outline[ol.start[kept.row] + 2 * kept.n[kept.row] - kept.local] = line[at] + side
    results = []
    rows = zip(staged, cl.split(points), cl.split(gaps), ol.split(outline), theta_tip.tolist(), theta_bot.tolist(),
               bot, depth.tolist(), entry.tolist())
    for (_, _, extras), cl_b, gaps_b, outline_b, t_tip, t_bot, bot_b, depth_b, in_entry in rows:
        extras["depth_mm"] = depth_b
        results.append(FrameMeasurement(True, "", t_tip, t_bot, 0.0 if in_entry else t_tip - t_bot, cl_b[0], bot_b,
                                        cl_b, outline_b, gaps_b, extras))
    return results


def _extras(contrast: float, c: _CentreLine, step_mm: float) -> dict[str, float]:
    """The diagnostics of a frame with a centre line (see :class:`FrameMeasurement`'s ``extras``):
    its ``contrast`` (grey levels), edge fraction, width ratio and bare tip length."""
    seen = np.flatnonzero(c.measured)
    bare = (c.tip_f - seen[-1]) * step_mm if len(seen) else math.nan
    return dict(contrast=contrast, edge_fraction=float(len(seen)) / len(c.measured), width_ratio=c.width_ratio,
                bare_tip_mm=float(bare))


def measure_frame(
    gray: np.ndarray,
    registration: _HasPose | MeasurePlan,
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    cfg: MeasureConfig = MeasureConfig(),
) -> FrameMeasurement:
    """Measure theta_tip, theta_bot and theta_con in one frame (defined in docs/how-it-works.md).

    Parameters
    ----------
    gray : ndarray
        The frame: 2-D grey (uint8, or float in grey levels 0–255) or BGR/BGRA colour.
    registration : object with ``.pose`` (CameraPose), or MeasurePlan
        The video's registration. Pass the :class:`MeasurePlan` of :func:`prepare_measurement`
        to reuse the straightened channel across frames (the fast path); given a registration,
        the strip is built for this frame alone (10–100 ms).
    phantom, array : Phantom, ElectrodeArray
        Geometry (a plan's own are used when a plan is passed).
    cfg : MeasureConfig
        Settings (a plan's own are used when a plan is passed).

    Returns
    -------
    FrameMeasurement
        Never raises on a bad frame: one that cannot be measured gives ``ok=False`` with a
        ``reason``: ``"array not in channel"`` (no array at the entry's outer end: not
        inserted yet, absent, hidden, or too faint), ``"tip out of view"``, ``"entry out of
        view"``, ``"array edges not found"``, ``"bad frame: ..."`` or ``"measurement failed:
        ..."``. ``extras['time_ms']`` is the time spent on the frame (ms), without the strip's
        preparation when a plan is passed; ``timings`` splits it by stage (s).

    Raises
    ------
    AttributeError
        ``registration`` is neither a plan nor has a ``pose`` (a programming error, not a bad
        frame).

    Notes
    -----
    A tip in the entry channel (behind ``theta_start``) gives ``ok=True``: the angle definitions give such
    points ``theta = phi`` (k = 0), so theta_tip is defined there (and below
    ``theta_start``); contact counts against the spiral's outer wall only, so then
    ``theta_bot = theta_tip`` and ``theta_con = 0``.
    """
    t0 = time.perf_counter()
    try:
        img = _to_gray(gray)
    except (ValueError, TypeError, cv2.error) as exc:
        return _fail(f"bad frame: {exc}")
    if not isinstance(registration, MeasurePlan):
        plan = prepare_measurement(registration, img.shape, phantom, array, cfg)
        t0 = time.perf_counter()
    elif registration.image_shape != img.shape[:2]:
        plan = prepare_measurement(registration.pose, img.shape, registration.phantom, registration.array,
                                   registration.cfg)
        t0 = time.perf_counter()
    else:
        plan = registration
    result = _measure_batch([img], plan)[0]
    result.extras["time_ms"] = 1e3 * (time.perf_counter() - t0)
    return result


def measure_frames_batch(
    grays: list[np.ndarray] | np.ndarray,
    plan: MeasurePlan,
) -> list[FrameMeasurement]:
    """:func:`measure_frame` of several frames of one plan, all four stages run on all at once.

    The survey (stage 1) of the frames is computed stacked along a leading axis, a few dozen
    NumPy calls for the whole batch instead of per frame; the edges, the centre line and the
    angles (stages 2–4) run on all frames' stations laid end to end (see the notes above
    :class:`_Ragged`), so that only the remaps and the assembly of the results are per frame.
    :func:`measure_frame` is a batch of one: a frame's result does not depend on the others
    in its batch (``tests/test_angles_batch.py``).

    Parameters
    ----------
    grays : list of ndarray, or ndarray of shape (B, H, W)
        The frames, each as :func:`measure_frame` accepts it (2-D grey or BGR/BGRA colour).
        32–64 frames amortise the per-call overhead; more only hold more frames in memory.
    plan : MeasurePlan
        The video's plan (:func:`prepare_measurement`).

    Returns
    -------
    list of FrameMeasurement
        One per frame, in order. ``timings['survey']``, ``timings['edges']``,
        ``timings['centre_line']``, ``timings['angles']`` and ``extras['time_ms']`` of each
        frame hold an equal share of the batch's stages (stage 4's among the frames measured).

    Notes
    -----
    Frames that are not valid images, or not of the plan's shape, are measured one by one with
    :func:`measure_frame`; a batch whose joint stages raise is measured again frame by frame.
    """
    results: list[FrameMeasurement | None] = [None] * len(grays)
    imgs: list[np.ndarray] = []
    where: list[int] = []
    for i, gray in enumerate(grays):
        try:
            img = _to_gray(gray)
        except (ValueError, TypeError, cv2.error):
            img = None
        if img is None or img.shape[:2] != plan.image_shape:
            results[i] = measure_frame(gray, plan)
        else:
            imgs.append(img)
            where.append(i)
    for i, result in zip(where, _measure_batch(imgs, plan)):
        results[i] = result
    return [r for r in results if r is not None]


_ERRORS = (ValueError, IndexError, FloatingPointError, cv2.error)


def _measure_batch(imgs: list[np.ndarray], plan: MeasurePlan) -> list[FrameMeasurement]:
    """The four stages on grey frames of the plan's shape, all frames at once.

    A batch whose joint stages raise is measured again frame by frame; a single frame that
    raises gives ``ok=False`` with the error as the reason.
    """
    if not imgs:
        return []
    t0 = time.perf_counter()
    try:
        with np.errstate(divide="ignore", invalid="ignore"):
            surveys = list(_survey_batch(imgs, plan))
            t1 = time.perf_counter()
            found = [k for k, sv in enumerate(surveys) if isinstance(sv, _Survey)]  # the frames stage 1 passed
            edges = _edges_batch([imgs[k] for k in found], plan, [surveys[k] for k in found]) if found else []
            t2 = time.perf_counter()
            lines = _centre_line_batch(plan, edges) if found else []
            t3 = time.perf_counter()
            measured = [j for j, c in enumerate(lines) if isinstance(c, _CentreLine)]
            finals = _results_batch(plan, [(edges[j], lines[j], _extras(surveys[found[j]].contrast, lines[j], plan.step_mm))
                                           for j in measured]) if measured else []
            t4 = time.perf_counter()
    except _ERRORS as exc:
        if len(imgs) > 1:
            return [r for img in imgs for r in _measure_batch([img], plan)]
        return [_fail(f"measurement failed: {type(exc).__name__}: {exc}")]
    share = [(t1 - t0) / len(imgs), (t2 - t1) / max(len(found), 1), (t3 - t2) / max(len(found), 1),
             (t4 - t3) / max(len(measured), 1)]
    out: list[FrameMeasurement] = []
    by_frame = {found[j]: j for j in range(len(found))}
    final_of = dict(zip(measured, finals))
    for k, sv in enumerate(surveys):
        if not isinstance(sv, _Survey):
            result = sv
            result.timings.update(survey=share[0])
        elif final_of.get(by_frame[k]) is None:
            result = _fail(str(lines[by_frame[k]]), contrast=sv.contrast)
            result.timings.update(survey=share[0], edges=share[1], centre_line=share[2])
        else:
            result = final_of[by_frame[k]]
            result.timings.update(survey=share[0], edges=share[1], centre_line=share[2], angles=share[3])
        result.extras["time_ms"] = 1e3 * sum(result.timings.values())
        out.append(result)
    return out

"""Settings of the measurement and the record of one frame's result.

:class:`MeasureConfig` holds every setting of :func:`~tympani.vision.angles.measure_frame`;
:class:`FrameMeasurement` is what it finds in a frame, and :func:`failure` the record of a frame
that could not be measured.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


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
    gap_resolution_px : float
        How finely (px) the gap to the wall is told apart. The contact run is found again with
        the tolerance raised by this much; a frame whose contact run then starts more than
        ``contact_swing_rad`` (rad) further back is not measured ("contact start unclear"): the
        array runs along the wall at about the tolerance, and whether (or from where) it touches
        cannot be told at this resolution. A frame read as not touching whose tip would touch
        is one of these.
    contact_swing_rad : float
        See ``gap_resolution_px``. Also the largest move (rad) of the contact start allowed
        were the array against the outer edge of a dark wider than itself near the tip (a
        shadow beside it), rather than against its inner edge; beyond it the frame is refused
        ("contact unclear: the dark at the tip is ... wider than the array"), and were the
        array touching the wall over its last ``contact_tip_mm`` (see there).
    contact_tip_mm : float
        Length (mm) of the array's last stretch, from the tip, whose gaps are the least sure:
        its rounded end, where blur, a highlight or a bubble move the edges most. Where the
        contact run would start more than ``contact_swing_rad`` further back were that stretch
        touching the wall (the array touches it just behind the tip, and not at the tip), the
        frame is refused ("contact unclear: touching the wall ... behind the tip, not at it");
        0 does not look.
    residual_resolution, max_gap_resolution_px : float
        The gaps are told apart no more finely than the registration fits the walls: the
        resolution is raised to ``residual_resolution`` times the registration's residual (px),
        at most ``max_gap_resolution_px`` (px; larger residuals, on independent renders, came
        with good poses as often as with bad ones). Where the walls show twice it is
        ``max_gap_resolution_px``: which copy the array touches, or where between two copies
        that merge the wall lies, is uncertain by up to their parallax.
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
        6 mm the tip runs on by 1-2 rad under strong uneven light.
    fluid_floor : float
        A block darker than this fraction of its brightest neighbour within ``fluid_reach_mm``
        is taken to be filled by the array, and its fluid level interpolated.
    band_open_mm : float
        Length (mm) along the channel below which bright stretches (metal bands, glints) are
        removed from the stations' brightest values for the fluid's band-free level.
    band_fill_rise : float
        A block whose first fluid level stands more than this fraction above its band-free
        level is one that metal bands fill for the most part (long bands, little body between
        them: its percentile falls on their blurred shoulders), and takes the band-free level.
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
        disc: 0.79; a band, a rectangle: about 1). The largest applies only to interiors at
        least ``bubble_round_px`` across both ways.
    bubble_round_px : int
        Least extent (px, along and across the channel) of an interior whose fill tells a disc
        from a rectangle: a smaller disc, blurred and thresholded, fills nearly all of its
        bounding box (8 × 9 px: 0.93).
    bubble_wider : float
        Width (dimensionless, times the array's tip diameter) above which an enclosed bright
        region cannot be a band.
    bubble_rim_mm : float
        Longest dark stretch (mm) along the array's path beyond a narrower one for it to be a
        bubble's rim rather than more array.
    bubble_gap_mm : float
        Least plain fluid (mm) on the array's path just before a bubble-like interior's near rim
        (no thicker than two rims) for it to be a bubble, however narrow: a metal band has the
        array's body before it. A bubble as wide as the array pushed a little ahead of the tip
        reads otherwise as its last band and tip (an independent renderer: the tip 0.43 rad too
        far, the contact missed, frame after frame).
    bubble_chain : float
        Bubbles touching in a chain show two rims between their interiors: a dark stretch up to
        this many times ``bubble_rim_mm`` that ends at another bubble-like interior is taken for
        two rims (an array's body between its bands is longer).
    bubble_aspect : float
        Largest ratio (dimensionless) of the longer to the shorter side of that box.
    bubble_track_mm : float
        Length (mm) of the dark stations before a bubble whose median darkest offset is the
        array's path.
    max_gap_mm : float
        Longest stretch (mm) along the array that may look like fluid (a metal band as bright
        as the fluid) without ending it.
    band_level : float
        Brightness above the fluid, as a share (dimensionless) of the fluid's level, from which
        a station is a metal band brighter than the fluid: such stations, joined to the array's
        body, carry its run whatever their length.
    band_width_mm : float
        Widest (mm) such a bright stretch across the channel may be to be a band: the array's
        base with a margin for blur; a bubble's bright inside is wider.
    resume_mm, resume_length_mm : float
        A frame where another run of dark or band stations (gaps up to ``max_gap_mm``)
        starts within ``resume_mm`` (mm) past the dark run's end and goes on for
        ``resume_length_mm`` (mm) or more, longer than a bubble, with two or more bright
        stretches in it, and where no bubble was found at or ahead of the tip, is not
        measured: the array may go on there with its body too light to count as dark
        throughout (the run ended at a shadow's edge), and where its tip lies is unknown.
    lighter_level : float
        Darkness (0 the fluid, 1 the array's body) from which a station past the dark run's
        end is part dark.
    lighter_clear : float
        Share of a darkness level below which a station is clear of it: a stretch at that
        level counts towards :attr:`lighter_stretches` where a clear station separates it from
        the one before (noise about a level does not begin new stretches).
    lighter_stretches : int
        A frame where, as for ``resume_mm``, a run of part-dark stations follows the dark
        run's end with this many separate stretches or more in its first twice
        ``resume_length_mm`` is not measured either, bubble or
        not: long metal bands blurred together with the short body between them leave the
        array only part dark, stretch after stretch (shading across the fluid is part dark
        throughout, in one stretch). Nor is one followed by as many dark stretches
        (``dark_level``) with gaps of up to twice ``max_gap_mm`` between them: bands as bright
        as the fluid, longer than a run may bridge.
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
    core_share, shelf_min, shelf_step, shelf_mm : float
        A shadow beside the array: where, out from the darkest offset, the coverage falls below
        ``core_share`` (dimensionless) of the darkest's and then stays on a lighter shelf out
        to the dark's edge, at least ``shelf_mm`` (mm, and 2 px) wide, at least ``shelf_min``
        dark and at least ``shelf_step`` lighter than the darkest (coverage, 0 fluid, 1
        array), the darker core's edge lies half way between the two.
    core_closer : float
        The core's edges are used in place of the dark's where the core's width is nearer the
        array's than this fraction (dimensionless) of the dark's distance from it: a shadow
        widens the dark by its own width, the lighter side of an array lit from one side makes
        the core narrower than the array while the dark has the array's width.
    speck_share : float
        Past a gap of plain fluid beyond the array's end (no brighter than the fluid by
        ``band_level``), dark nowhere wider than this share (dimensionless) of the tip's diameter
        is not more array (a speck, a thin shadow): the array ends at the gap.
    tip_reach_mm : float
        Farthest (mm) the centre line is extrapolated from the last station with measured edges
        to the tip; a frame whose dark run goes on farther is not measured (what continues it
        is not the array's body: a bubble's rim, a shadow, a doubled wall line).
    band_edge_mm : float
        Length (mm) of the array's body beside a metal band whose edges may be lost to the
        band's glare and blur. The tip may lie at most this much further than the array's
        first band's far end (``first_band_mm + band_length_mm`` from the tip) past the last
        station with measured edges, and at most ``tip_reach_mm``: 1 mm for the default array.
        A dark run that goes on further past the edges is seldom the array (on independent
        renders three frames in four with 1-1.5 mm were misread: a bubble's rims and bright
        inside, a dark patch ahead of the tip).
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
    tip_dark_mm : tuple of float
        Nearest and farthest distance (mm) basal of the tip of the stretch whose darkness
        ``tip_dark_min`` checks (the rounded tip, at the tip radius, is the array's full width).
    tip_dark_min : float
        A frame whose darkest point near the tip over ``tip_dark_mm`` (clear of the walls) is
        lighter than this share of the array's darkness just inside its inner edge is not
        measured: its dark run ends on something fainter than the array (the array's shadow
        falling past its tip, a speck beyond a band). On held-out videos (fresh seeds of two
        independent renderers it was chosen on, and a third renderer; about 1400 frames
        measured before), 28 of the 35 frames it refused had their tip off by more than 0.1 rad
        and 7 were within 0.05 rad.
    tip_dark_max : float
        A frame whose darkest point near the tip (as for ``tip_dark_min``) is darker than this
        multiple of the array's darkness (just inside its inner edge, and at least the survey's
        contrast) is not measured: the array's end is no darker than the rest of it, a dark
        bubble or speck against it (taken for the array's last millimetre) is (inf: off). Over
        the videos of seven independent renderers it refuses 30 of the 38 grossly wrong frames
        marked ok there (the other 8: a contact missed, a tip on fainter dark) and 19 of 4659
        frames measured within 0.05 rad.
    band_past_mm : tuple of float
        Nearest and farthest distance (mm) past the tip of the stretch ``band_past_share``
        looks at (the nearest leaves out the tip's own blurred end).
    band_past_share : float
        A frame where, at this share or more of the stations within ``band_past_mm`` past its
        tip, something on the array's track is as bright as a metal band (``band_level``) is
        not measured, unless an air bubble was found there: the array's last band lies there
        and its short cap beyond is lost in glare or blur (the tip then reads 0.1-0.2 rad
        short), or what was taken for the tip lies inside the array. A bubble touching the tip
        that is not found as one is refused too (its bright inside looks the same). On the
        held-out videos above, 27 of the 35 frames it refused had their tip off by more than
        0.1 rad and 8 within 0.05 rad.
    band_past_level : float
        Brightness above the fluid, as a share (dimensionless) of the fluid's level, from which
        a point past the tip counts as a band's for ``band_past_share``: lower than
        ``band_level`` (which lets bright stretches carry the array's run), since bands only
        a tenth brighter than the fluid, too dim to carry the run, still show that the array
        goes on past a dark body ending at its first band.
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
    shadow_length_mm, shadow_cap_mm : float
        The stretch (mm from the tip: from ``shadow_length_mm`` to ``shadow_cap_mm``) over which
        the lane beside the dark run's outer edge is compared with the run itself, for the
        array's metal bands beside the run (the run then the array's shadow; see
        :mod:`tympani.vision.angles.shadow`).
    shadow_clear_px : float
        How far (px) from the outer wall that lane stops.
    shadow_band_margin_mm : float
        The lane is not used within this distance (mm) along the channel of a station where the
        run's edges are not found (the run's own bands, which can be a little wider than its
        body or blurred along it, show in the lane there).
    shadow_period_mm : tuple of float
        Shortest and longest band pitch (mm) sought.
    shadow_detrend_mm : float
        Length (mm) of the running median taken off the lanes (slower changes of the light go;
        bands and gaps both longer than half of it go too).
    shadow_correlation, shadow_spread, shadow_ratio : float
        A frame is refused ("the array's bands show beside the dark run") when the lane's
        autocorrelation over those pitches reaches ``shadow_correlation``, it varies by
        ``shadow_spread`` contrast units or more (standard deviation) and by ``shadow_ratio``
        times the run's own variation. On 3670 right and 154 grossly wrong frames measured one by
        one on eight study renderers (each frame alone, before the whole-video checks), these
        refuse 5 right frames (0.14 %) and 27 wrong ones (21 of the 24 of the two videos that
        follow the shadow).
    stripe_skip_mm, stripe_length_mm : float
        Where past a measured tip (mm, its cap skipped) and over what length (mm) the channel
        is sought for a regular pattern of stripes (the array's bands going on, unseen).
    stripe_lags_mm : tuple of float
        Shortest and longest period (mm) of the stripes sought.
    stripe_detrend_mm : float
        Length (mm) of the running mean taken off the channel's profile first.
    stripe_correlation, stripe_spread : float
        A frame is refused (``beyond.STRIPES_PAST_TIP``) when the profile's autocorrelation
        (:func:`~tympani.vision.angles.beyond.profile_periodicity`) reaches
        ``stripe_correlation`` and it varies by ``stripe_spread`` contrast units or more
        (standard deviation). Over 4910 right frames of 21 rendered sets the autocorrelation
        was at most 0.66; over the 18 frames of a held-out video whose dull bands went unseen,
        0.21-0.83.
    """

    contact_tol_mm: float = 0.05
    contact_persist_mm: float = 0.5
    contact_excess_mm: float = 0.1
    contact_bias_mm: float = 0.1
    gap_resolution_px: float = 2.0
    contact_swing_rad: float = 0.6
    contact_tip_mm: float = 0.5
    residual_resolution: float = 2.0
    max_gap_resolution_px: float = 3.0
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
    band_open_mm: float = 1.0
    band_fill_rise: float = 0.3
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
    bubble_fill: tuple[float, float] = (0.5, 0.9)
    bubble_round_px: int = 10
    bubble_aspect: float = 2.5
    bubble_wider: float = 1.15
    bubble_rim_mm: float = 0.2
    bubble_gap_mm: float = 0.1
    bubble_chain: float = 1.5
    bubble_track_mm: float = 0.6
    max_gap_mm: float = 0.8
    band_level: float = 0.15
    band_width_mm: float = 1.5
    resume_mm: float = 2.0
    resume_length_mm: float = 2.0
    lighter_level: float = 0.3
    lighter_clear: float = 0.5
    lighter_stretches: int = 3
    min_contrast: float = 12.0
    gap_smooth_mm: float = 0.4
    outlier_px: float = 1.5
    plateau_px: tuple[float, float] = (2.5, 4.0)
    core_share: float = 0.9
    shelf_min: float = 0.25
    shelf_mm: float = 0.05
    shelf_step: float = 0.15
    core_closer: float = 0.5
    speck_share: float = 0.6
    tip_reach_mm: float = 1.5
    band_edge_mm: float = 0.3
    tip_width_mm: float = 2.0
    tip_inner_min: float = 0.1
    tip_wall_share: float = 0.5
    tip_dark_mm: tuple[float, float] = (0.1, 0.35)
    tip_dark_min: float = 0.5
    tip_dark_max: float = 1.4
    band_past_mm: tuple[float, float] = (0.05, 0.25)
    band_past_share: float = 0.6
    band_past_level: float = 0.10
    cap_min: float = 0.4
    angle_step_mm: float = 0.1
    min_tip_px: float = 8.5
    shadow_length_mm: float = 4.0
    shadow_cap_mm: float = 0.3
    shadow_clear_px: float = 1.5
    shadow_band_margin_mm: float = 0.1
    shadow_period_mm: tuple[float, float] = (0.5, 1.8)
    shadow_detrend_mm: float = 1.1
    shadow_correlation: float = 0.4
    shadow_spread: float = 0.1
    shadow_ratio: float = 2.0
    stripe_skip_mm: float = 0.14
    stripe_length_mm: float = 3.0
    stripe_lags_mm: tuple[float, float] = (0.1, 1.5)
    stripe_detrend_mm: float = 1.0
    stripe_correlation: float = 0.7
    stripe_spread: float = 0.03


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
        :class:`~tympani.vision.geometry.ElectrodeArray`'s, median over the stations where both show;
        NaN where fewer than 10 do: about 1.01 when the model is right), ``bare_tip_mm`` (length
        of the array, mm, between its last station with measured edges and the tip: the tip's
        offset is extrapolated over it), ``other_copy_mm`` (where walls show twice, how much more
        of the centre line the walls' other copy fits, see
        :func:`~tympani.vision.angles.results.other_copy_support`; NaN for single walls or a tip
        short of half a turn), ``time_ms`` (ms spent on the frame).
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


def failure(reason: str, **extras: float) -> FrameMeasurement:
    """A not-ok measurement with a reason.

    Parameters
    ----------
    reason : str
        Why the frame was not measured.
    **extras : float
        Diagnostics known so far (see :class:`FrameMeasurement`), e.g. ``contrast`` (grey levels).

    Returns
    -------
    FrameMeasurement
    """
    return FrameMeasurement(False, reason, extras={k: float(v) for k, v in extras.items()})

"""The array's angles theta_tip, theta_bot and theta_con, and their measurement in a frame.

The angles are defined in docs/how-it-works.md and applied by :func:`contact_angles`
(:mod:`.definitions`), which the renderer uses for its ground truth. Per frame
(:func:`measure_frame`): greyscale frame + registration → straightened channel → the array's
dark run, tip, edges and gap to the outer wall → the three angles. Build the straightened
channel once per registration with :func:`prepare_measurement` and pass that plan in place of
the registration::

    plan = prepare_measurement(registration, frame.shape)
    for frame in frames:
        row = measure_frame(frame, plan).to_row()

How a frame is measured
-----------------------
The channel is registered once per video, so everything that depends only on the pose is
computed once (:mod:`.plan`): remap tables that *straighten* the channel into a strip. Its
*stations* run along the channel's backbone, one px apart, from the outer end of the entry
channel through theta_start to theta_end; its *offsets* run across the channel at normalised
lateral positions u (-1 the inner wall, +1 the outer wall), at most one px apart. The strip is
stored offsets x stations, so that reductions across the channel run over its short first axis
and OpenCV's filters see a wide image (both several times faster than the other way round).
Each frame then costs two cv2.remap calls and mostly 1-D work along the channel:

1. survey (:mod:`.survey`), on a coarse strip (every 2nd offset and station) of the whole
   channel, using each station's darkest and brightest value in the channel's interior (clear
   of wall lines): the fluid level along the channel (a low percentile per 1.5 mm block, blocks
   where the array fills the channel interpolated; then again over stations whose brightest
   value is fluid); the array's level as a ratio to the fluid's, taken side by side where the
   array shows beside the fluid with a sharp edge (so uneven lighting cancels, and a channel
   merely dimmed by vignetting is not taken for an array); each station's darkness (0 fluid,
   1 array); the array is the dark run that starts at the entry's outer end, bridging gaps up
   to 0.8 mm (metal bands as bright as the fluid);
2. edges (:mod:`.edges`), on the fine strip of the stations that hold the array: a bubble at
   or ahead of the tip ends the dark run (:mod:`.bubbles`); at each station the array's inner
   and outer edge are the half-level crossings of its coverage either side of its darkest
   offset (sub-pixel, linear interpolation); the inner edge is then moved to the half level
   between the fluid and the array just beside it (median over the frame, local where the
   fluid shows clear of the wall), which removes the biases of the global levels (noise,
   compression, lighting);
3. centre line (:mod:`.centreline`): the inner edge faces the fluid wherever the array rides
   the outer wall, whereas the outer edge then merges with the wall (a dark wall line hides
   gaps narrower than half its width), so the centre line is the inner edge plus the array's
   known half-width at that distance from the tip (the outer edge minus it where the inner
   edge is lost), widened by the array's slant across the channel; in the rounded tip the
   half-width is the half disc's; stations at band borders, cut by a band's slanted border
   (edges too close together) or off their neighbours' median are dropped; the tip is the
   half-level crossing along the centre line, whose offset is extrapolated from the body;
   gap = half the channel width - centre offset - radius, smoothed with local straight-line
   fits (unbiased next to bands and the tip, where only one side has data) and carried across
   bands and the last of the tip cap; a run with the array's bands beside it rather than on
   it is the array's shadow, and is refused (:mod:`.shadow`);
4. angles (:mod:`.results`): the points' angles by :func:`~.definitions.spiral_angle` (the
   arithmetic of :func:`~tympani.vision.geometry.point_angle`) and :func:`contact_angles`' rule
   on the measured centre line with the measured gaps, allowing for noise blips and a bias of
   the measured gap (``MeasureConfig.contact_*``).

All frames of a batch run through the four stages together (:func:`measure_frames_batch`;
:func:`measure_frame` is a batch of one): stage 1 on the frames' coarse strips stacked along a
leading axis, stages 2-4 on the frames' stations laid end to end (:mod:`.ragged`). A frame's
result does not depend on the others in its batch.

Modules, in the order of the data flow: :mod:`.definitions`, :mod:`.config`, :mod:`.plan`,
:mod:`.survey`, :mod:`.bubbles`, :mod:`.edges`, :mod:`.shadow`, :mod:`.centreline`, :mod:`.results`,
:mod:`.measure` (the entry points); :mod:`.arrays` and :mod:`.ragged` hold the array helpers
the stages share.
"""

from __future__ import annotations

from tympani.vision.angles.config import FrameMeasurement, MeasureConfig
from tympani.vision.angles.definitions import ContactAngles, contact_angles, outer_wall_gap
from tympani.vision.angles.measure import measure_frame, measure_frames_batch
from tympani.vision.angles.plan import MeasurePlan, prepare_measurement

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

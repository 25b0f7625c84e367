"""Registration: where the phantom is in the image (see docs/how-it-works.md).

The camera looks straight down, so phantom and image differ by a similarity: centre,
rotation, scale and possibly a mirror (:class:`tympani.vision.geometry.CameraPose`). :func:`register`
finds it from the channel walls alone, with no initial guess, assuming only that the walls
show as intensity edges (thin lines, region boundaries or both):

1. **Edges** (:mod:`tympani.vision.edges`): the frames are merged (per-pixel median), Canny runs
   with thresholds and smoothing set from the image's own noise, short specks are dropped,
   and each edge pixel is refined to sub-pixel precision. Two fields are splatted from the
   edge points: the *doubled-angle orientation* ``exp(2i·alpha)``, in which the two Canny
   edges of a thin line agree and randomly oriented noise and clutter cancel when averaged,
   and the signed gradient direction, which keeps the edges' polarity.
2. **Global search** on the doubled-angle field shrunk, for each candidate scale (10 %
   steps), so the phantom would appear at ``coarse_px_per_mm``: the wall template averaged
   over all rotations (a rotation-invariant ring detector, anchored on the spiral centre)
   proposes centres by correlation; at each proposal the templates of every rotation (128)
   and both mirrors are scored by one matrix product. This covers any rotation, both
   mirrors, the whole scale range and centres anywhere, including a channel partly out of
   frame.
3. **Refinement** of the best proposals down an image pyramid. Each wall point samples the
   field along its normal and takes the Gaussian-weighted mean offset of the edges that
   share its orientation (a 1-D mean shift); a weighted Gauss–Newton step moves the
   similarity. The last pass at full resolution is polarity-aware: edges whose gradient
   points out of the channel are fitted at ``+h`` and those pointing in at ``-h``, ``h``
   (the half width of the wall lines) being estimated with the pose. This centres thin
   lines even when only one of their sides shows, handles region boundaries (``h = 0``),
   and keeps the walls of neighbouring turns (0.24 mm apart, edges facing the other way)
   from pulling on each other. Proposals are refined to half resolution until one fits
   nearly all the walls, then the best few to full resolution; when full resolution does not
   confirm any, the remaining proposals are refined too (a deep array's edges can pass the
   half-resolution fit in a wrong pose). Each is also fitted as *fringed* walls
   (:func:`~tympani.vision.registration.refine.refine_fringe`): light refracted at a wall can
   show a bright band on one side and a dark band on the other, against the step, so each wall
   shows a pair of edges of the step's polarity either side of it; the wall lies between them.
   Such a fit replaces the walls found otherwise where it is clearly closer; it is also tried
   from the single fit wherever the walls come out doubled (a fit on one edge of each pair can
   lie so close that the pairs pass for two copies).
4. **Verification**: along each wall normal, the distance from where the wall's edge is
   expected to the nearest Canny edge of matching orientation. Too few inliers, too little
   of the channel in view or too large a residual mean no phantom: :class:`RegistrationError`
   says which.

Why the entry matters: beyond 100° the backbone is a logarithmic spiral with a width that
grows with the radius, so a rotation about the centre is nearly the same as a 7.5 %/rad
change of scale there. The entry channel and the first half-turn break that symmetry; the
search and the residual (the largest of per-part medians) both rely on them.

:func:`check` recomputes the residual on a new frame in a few ms, so a batch can notice a
bumped camera and register again.

Units: image lengths in px (pixel centres at integer coordinates, x along columns, y along
rows), phantom lengths in mm, angles in rad unless a name says ``_deg``.

Modules, one per step: :mod:`.config` (settings and results), :mod:`.model` (the wall
model), :mod:`.poses` (pose helpers), :mod:`.frames` (merged frames and their edges),
:mod:`.coarse` (the global search), :mod:`.refine` (refinement), :mod:`.verify` (the fit
statistics), :mod:`.valley` (the spiral's self-similarity valley), :mod:`.doubled` (doubled
walls) and :mod:`.core` (:func:`register` and :func:`check`).
"""

from __future__ import annotations

from tympani.vision.registration.config import (
    AUTO_MAX_PX_PER_MM_PER_640,
    AUTO_MIN_PX_PER_MM,
    Registration,
    RegistrationConfig,
    RegistrationError,
    search_range,
)
from tympani.vision.registration.core import check, register
from tympani.vision.registration.frames import combine_frames
from tympani.vision.registration.model import WallModel, wall_model
from tympani.vision.registration.verify import WallFit, wall_fit

__all__ = [
    "RegistrationConfig",
    "Registration",
    "RegistrationError",
    "search_range",
    "AUTO_MIN_PX_PER_MM",
    "AUTO_MAX_PX_PER_MM_PER_640",
    "WallModel",
    "wall_model",
    "combine_frames",
    "register",
    "check",
    "wall_fit",
    "WallFit",
]

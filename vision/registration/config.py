"""Settings and results of registration: :class:`RegistrationConfig`, the automatic scale
range (:func:`search_range`), :class:`Registration` and :class:`RegistrationError`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from tympani.vision.geometry import CameraPose


@dataclass(frozen=True)
class RegistrationConfig:
    """Search ranges and tolerances of :func:`register`.

    Parameters
    ----------
    px_per_mm_range : tuple of float, or None
        Smallest and largest scale (px/mm) searched. None (default): from 10 px/mm to 80 px/mm
        per 640 px of the frame's larger side (80 at 640×480 and below, 240 at 1920×1080),
        the scales at which enough of the walls can be in view (:func:`search_range`).
    coarse_px_per_mm : float
        Working resolution (px/mm of the phantom) of the global search.
    coarse_scale_step : float
        Relative step between the scales of the global search (0.1 = 10 %).
    coarse_rotations : int
        Number of rotations of the global search (per mirror), evenly spaced over 2π.
    coarse_peaks_per_scale : int
        Centres proposed by the rotation-invariant detector at each scale.
    n_candidates : int
        Proposals of the global search that are refined to half resolution.
    n_fine : int
        Best of those that are refined at full resolution.
    edge_sigma_px : float or None
        Gaussian smoothing (px) before Canny; ``None`` chooses it from the image's noise
        (:func:`tympani.vision.edges.auto_sigma`).
    min_segment_px : int
        Edge segments shorter than this (px) are dropped as specks.
    refine_sigma_px : float
        Kernel (px, full resolution) of the first, polarity-blind full-resolution pass.
    final_sigma_px : float
        Kernel (px) of the last, polarity-aware pass; small enough that the walls of
        neighbouring turns (0.24 mm apart) stay out of each other's window.
    max_line_half_width_px : float
        Largest half width (px) of a wall drawn as a line (its two edges lie this far from the
        wall on either side).
    model_spacing_px : float
        Spacing (px) of the wall points used in refinement and verification.
    inlier_tol_px : float
        A wall point is an inlier when an edge of matching orientation and polarity lies
        within this distance (px, along its normal) of where the fit expects it.
    min_inlier_fraction : float
        Least fraction of the visible wall points that must be inliers.
    min_visible_fraction : float
        Least fraction of the model's wall length that must be inside the frame.
    max_residual_px : float
        Largest accepted residual (px, :attr:`WallFit.residual_px`).
    combine : {"median", "mean", "first"}
        How several frames are merged before edge detection.
    fringe_try_residual_px : float
        Fringed walls are not fitted from refinements that explain nearly all the walls within
        this (px, their residual): a fringed fit could not be clearly closer. Where such a fit
        comes out as doubled walls, they are (a fit on one edge of each pair lies that close
        and the pairs pass for two copies).
    fringe_starts_px : tuple of float
        Half spacings (px) of a fringed wall's like edges from which the fringe fit starts
        (:func:`tympani.vision.registration.refine.refine_fringe`).
    fringe_min_px, fringe_max_px : float
        Least and largest half spacing (px) of a fringe's like edges.
    fringe_balance : float
        Least ratio of the weaker to the stronger edge of a fringe's pair (how often each is
        found along the walls).
    fringe_evenness : float
        Least evenness of a fringe's pair of like edges around the spiral (the weakest of four
        facing directions against the strongest): the two copies of doubled walls show apart
        only where the walls face along their parallax.
    fringe_residual_share : float
        A fringed fit replaces the walls found otherwise (single, doubled or beside the edge)
        only where its residual is at most this share of theirs, or where they fail ...
    fringe_max_residual_px : float
        ... and its residual is at most this (px): fringes that the model of a symmetric pair
        describes fit within a few tenths of a pixel.
    """

    px_per_mm_range: tuple[float, float] | None = None
    coarse_px_per_mm: float = 2.0
    coarse_scale_step: float = 0.10
    coarse_rotations: int = 128
    coarse_peaks_per_scale: int = 3
    n_candidates: int = 4
    n_fine: int = 2
    edge_sigma_px: float | None = None
    min_segment_px: int = 8
    refine_sigma_px: float = 2.0
    final_sigma_px: float = 1.0
    max_line_half_width_px: float = 4.0
    model_spacing_px: float = 1.5
    inlier_tol_px: float = 2.5
    min_inlier_fraction: float = 0.7
    min_visible_fraction: float = 0.3
    max_residual_px: float = 3.0
    combine: str = "median"
    fringe_try_residual_px: float = 0.3
    fringe_starts_px: tuple[float, ...] = (3.0, 4.5)
    fringe_min_px: float = 1.5
    fringe_max_px: float = 6.0
    fringe_balance: float = 0.6
    fringe_residual_share: float = 0.65
    fringe_max_residual_px: float = 0.5
    fringe_evenness: float = 0.75

    def __post_init__(self) -> None:
        if self.px_per_mm_range is not None:
            lo, hi = self.px_per_mm_range
            if not 0 < lo <= hi:
                raise ValueError(f"px_per_mm_range must be 0 < lo <= hi, got {self.px_per_mm_range}")
        if self.combine not in ("median", "mean", "first"):
            raise ValueError(f"combine must be 'median', 'mean' or 'first', not {self.combine!r}")
        if self.edge_sigma_px is not None and self.edge_sigma_px <= 0:
            raise ValueError("edge_sigma_px must be positive or None")


#: The automatic scale range (see :attr:`RegistrationConfig.px_per_mm_range`): px/mm, and the
#: largest scale per 640 px of the frame's larger side.
AUTO_MIN_PX_PER_MM, AUTO_MAX_PX_PER_MM_PER_640 = 10.0, 80.0


def search_range(cfg: RegistrationConfig, width: int, height: int) -> tuple[float, float]:
    """The scales (px/mm) :func:`register` searches in a ``width`` × ``height`` (px) frame:
    ``cfg.px_per_mm_range``, or when it is None, 10 px/mm up to 80 px/mm per 640 px of the
    larger side (never less than 80). How much of the frame the phantom fills depends on its
    scale against the frame's size in px, so the largest scale at which enough of its walls
    are in view grows with the frame."""
    if cfg.px_per_mm_range is not None:
        return cfg.px_per_mm_range
    return AUTO_MIN_PX_PER_MM, AUTO_MAX_PX_PER_MM_PER_640 * max(1.0, max(width, height) / 640.0)


@dataclass(frozen=True)
class Registration:
    """A phantom-to-image similarity and how well the walls fit it.

    Parameters
    ----------
    pose : CameraPose
        Phantom (mm) to image (px) similarity.
    residual_px : float
        Median distance (px) from the visible model walls to their image edges (taking the
        edges' polarity and the line half width into account), the statistic :func:`check`
        recomputes on later frames; a few tenths of a pixel for a good registration.
    inlier_fraction : float
        Fraction of visible wall points with an edge of matching orientation within
        ``inlier_tol_px``.
    visible_fraction : float
        Fraction of the model's wall length inside the frame.
    matched_length_mm : float
        Wall length (mm) supported by inliers.
    line_half_width_px : float
        Estimated half width (px) of the wall lines (> 0 dark lines, < 0 bright lines,
        about 0 for region boundaries).
    line_offset_px : float
        How far (px) the wall lines' centres lie outside the channel's edge (along the normal
        pointing out of the channel): a band of the plate beside the edge (its cut face catching
        the light) rather than a line on it; 0 unless lines beside the edge fit the walls clearly
        better.
    edge_sigma_px : float
        Canny smoothing (px) used; :func:`check` uses the same.
    image_size : tuple of int
        ``(width, height)`` (px) of the frames registered.
    walls_doubled : bool
        Whether every wall showed twice, the second copy shifted by one image vector
        (``parallax_px``): the top and bottom edges of a thick plate's walls seen at an angle
        (see docs/how-it-works.md). ``pose`` is then that of the *first copy*: the one whose
        insertion axis the straight array outside the entry lies on, where the array shows and
        the copies' axes are far enough apart to tell, else the one with the stronger edges;
        the residual,
        inlier and check statistics count an edge of either copy. The copies are told apart
        where they are resolved: about 1 px for wall lines (the union of two overlapping
        lines is fitted as such) and 2.5 px for region boundaries, whose two steps merge into
        one edge below that; a doubling too small to resolve is not reported, and moves
        the pose a third to a half of the parallax towards the fainter copy (an independent
        renderer's walls doubled 1.9-3.1 px apart: 0.63-1.23 px).
    parallax_px : tuple of float
        Image displacement ``(dx, dy)`` (px, x right, y down) of the second wall copy from the
        first; ``(0, 0)`` unless ``walls_doubled``. Where the copies overlap (wall lines
        closer than their width) it is measured from the union's outer edges, which can read
        up to about a third short.
    second_copy_contrast : float
        Edge strength of the second copy relative to the first (the ratio of median gradient
        magnitudes at edges of the two copies; below 1 unless the array chose the fainter copy
        as the wall); NaN when the walls are single or
        where the copies were never resolved.
    array_axis_offset_px : float
        How far (px, across the insertion axis) the straight array outside the entry lies from the
        registered axis; NaN where it does not show as a pair of edges an array's width apart. The
        array lies on the axis, so a few pixels here mean the pose is off across it (walls that
        show twice, registered on the wrong copy) or something else lies there.
    fringe_px : float
        Half the spacing (px) of a fringed wall's pair of like edges: light refracted at the
        wall shows a bright band on one side and a dark band on the other, against the step
        between fluid and plate, so each wall shows two edges of the step's polarity
        ``|fringe_px|`` either side of it and one of the other polarity on it. Positive when
        the pair's gradients point out of the channel (dark to bright outwards), negative when
        into it; 0 for walls without fringes (or where a single edge or line fits as well).
    """

    pose: CameraPose
    residual_px: float
    inlier_fraction: float = float("nan")
    visible_fraction: float = float("nan")
    matched_length_mm: float = float("nan")
    line_half_width_px: float = float("nan")
    edge_sigma_px: float = 1.0
    image_size: tuple[int, int] = (0, 0)
    walls_doubled: bool = False
    parallax_px: tuple[float, float] = (0.0, 0.0)
    second_copy_contrast: float = float("nan")
    array_axis_offset_px: float = float("nan")
    line_offset_px: float = 0.0
    fringe_px: float = 0.0
    _check_cache: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    def other_copy(self) -> "Registration":
        """The same registration with the doubled walls' other copy as the first: the pose
        moved by :attr:`parallax_px`, the parallax reversed and the contrast inverted; the
        array's axis offset, measured against the first copy's axis, becomes NaN. Single walls:
        the registration itself."""
        if not self.walls_doubled:
            return self
        dx, dy = self.parallax_px
        return replace(self, pose=self.pose.moved((dx, dy)), parallax_px=(-float(dx), -float(dy)),
                       second_copy_contrast=1.0 / self.second_copy_contrast, array_axis_offset_px=float("nan"))

    @property
    def parallax_mm(self) -> float:
        """Length (mm, in the phantom's plane) of :attr:`parallax_px`; 0 for single walls."""
        return float(math.hypot(*self.parallax_px)) / float(self.pose.px_per_mm)

    def to_dict(self) -> dict:
        """The registration JSON's keys (docs/file-formats.md) plus the fit statistics and the doubled walls (JSON-ready):
        ``walls_doubled``, ``wall_parallax_mm`` (:attr:`parallax_mm`), ``wall_parallax_x_px``,
        ``wall_parallax_y_px``, ``second_copy_contrast``, ``array_axis_offset_px`` (NaN when
        unknown), ``line_offset_px`` and ``wall_fringe_px`` (:attr:`fringe_px`)."""
        p = self.pose
        return {
            "centre_x_px": float(p.centre_x_px),
            "centre_y_px": float(p.centre_y_px),
            "rotation_rad": float(p.rotation_rad),
            "px_per_mm": float(p.px_per_mm),
            "mirrored": bool(p.mirrored),
            "residual_px": float(self.residual_px),
            "inlier_fraction": float(self.inlier_fraction),
            "visible_fraction": float(self.visible_fraction),
            "matched_length_mm": float(self.matched_length_mm),
            "line_half_width_px": float(self.line_half_width_px),
            "edge_sigma_px": float(self.edge_sigma_px),
            "image_width_px": int(self.image_size[0]),
            "image_height_px": int(self.image_size[1]),
            "walls_doubled": bool(self.walls_doubled),
            "wall_parallax_mm": float(self.parallax_mm),
            "wall_parallax_x_px": float(self.parallax_px[0]),
            "wall_parallax_y_px": float(self.parallax_px[1]),
            "second_copy_contrast": float(self.second_copy_contrast),
            "array_axis_offset_px": float(self.array_axis_offset_px),
            "line_offset_px": float(self.line_offset_px),
            "wall_fringe_px": float(self.fringe_px),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Registration":
        """Inverse of :meth:`to_dict`, also of the registration JSON (where NaN is written
        ``null``); only the six pose keys are required."""
        nan = float("nan")

        def num(key: str, default: float = nan) -> float:
            value = d.get(key, default)
            return nan if value is None else float(value)

        pose = CameraPose(
            float(d["centre_x_px"]),
            float(d["centre_y_px"]),
            float(d["rotation_rad"]),
            float(d["px_per_mm"]),
            bool(d["mirrored"]),
        )
        return cls(
            pose=pose,
            residual_px=num("residual_px"),
            inlier_fraction=num("inlier_fraction"),
            visible_fraction=num("visible_fraction"),
            matched_length_mm=num("matched_length_mm"),
            line_half_width_px=num("line_half_width_px"),
            edge_sigma_px=num("edge_sigma_px", 1.0),
            image_size=(int(d.get("image_width_px", 0)), int(d.get("image_height_px", 0))),
            walls_doubled=bool(d.get("walls_doubled", False)),
            parallax_px=(num("wall_parallax_x_px", 0.0), num("wall_parallax_y_px", 0.0)),
            second_copy_contrast=num("second_copy_contrast"),
            array_axis_offset_px=num("array_axis_offset_px"),
            line_offset_px=num("line_offset_px", 0.0),
            fringe_px=num("wall_fringe_px", 0.0),
        )


class RegistrationError(Exception):
    """No phantom was found in the frames; the message says why."""

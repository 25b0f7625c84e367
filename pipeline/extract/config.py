"""What the extraction of a video's angles is set with: its settings (:class:`ExtractConfig`)
and the vision functions it calls (:class:`VisionSteps`).

The settings are recorded in every video's provenance; the steps are code, passed next to the
settings to :func:`~tympani.pipeline.extract.video.extract_video`,
:func:`~tympani.pipeline.extract.batch.process_video` and :func:`~tympani.pipeline.extract.batch.extract_batch`.
The default steps are :mod:`tympani.vision.registration`'s and :mod:`tympani.vision.angles`'s; other steps
(simpler stand-ins, another measurement) are module-level functions, so that a
:class:`VisionSteps` pickles to worker processes and Dask workers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from tympani.vision.angles import MeasureConfig, measure_frame, measure_frames_batch, prepare_measurement
from tympani.vision.errors import is_input_error
from tympani.vision.frames import LensCalibration, check_decoder_threads
from tympani.vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM, ElectrodeArray, Phantom
from tympani.vision.registration import Registration, RegistrationConfig, RegistrationError, check, register

__all__ = ["ExtractConfig", "VisionSteps"]


@dataclass(frozen=True)
class VisionSteps:
    """The vision functions one video's extraction calls.

    Parameters
    ----------
    register : callable
        ``register(gray_frames, phantom[, registration_config]) -> Registration``: the
        phantom's pose from a few greyscale frames of one view (the registration has
        ``pose``, ``residual_px`` and ``array_axis_offset_px``, px, and ``to_dict()``).
    check : callable
        ``check(gray, registration, phantom) -> float``: the residual (px) of a registration
        on one greyscale frame (NaN or large: the view changed).
    measure_frame : callable
        ``measure_frame(gray, plan, phantom, array, measure_config)``: one frame's measurement
        (with ``to_row()``); ``plan`` is what ``prepare_measurement`` made of the registration,
        or the registration itself when there is no ``prepare_measurement``.
    prepare_measurement : callable or None
        ``prepare_measurement(registration, shape, phantom, array, measure_config[, lens=])``:
        the per-registration plan, built once per registration (``shape`` in px, ``lens`` the
        calibration's ``distort_points``). None: ``measure_frame`` gets the registration, and
        frames are measured one at a time.
    measure_frames_batch : callable or None
        ``measure_frames_batch(grays, plan) -> list``: ``measure_frame`` of several frames of
        one plan at once. None: one at a time.
    registration_error : type
        The exception ``register`` raises when it finds no phantom: the first registration of a
        video failing with it (or with an input error) makes the video a bad input.
    """

    register: Callable[..., Any] = register
    check: Callable[..., float] = check
    measure_frame: Callable[..., Any] = measure_frame
    prepare_measurement: Callable[..., Any] | None = prepare_measurement
    measure_frames_batch: Callable[..., list] | None = measure_frames_batch
    registration_error: type[BaseException] = RegistrationError

    def is_registration_failure(self, exc: BaseException) -> bool:
        """Whether ``exc``, raised by ``register``, says the frames hold no usable phantom (bad
        input) rather than a bug."""
        return is_input_error(exc) or isinstance(exc, self.registration_error)


@dataclass(frozen=True)
class ExtractConfig:
    """What :func:`~tympani.pipeline.extract.video.extract_video` needs besides the video.

    Parameters
    ----------
    phantom : Phantom
        Phantom geometry (:mod:`tympani.vision.geometry`).
    array : ElectrodeArray
        Electrode array (:mod:`tympani.vision.geometry`).
    recheck_every : int
        Check the registration every this many frames (0: never).
    register_frames : int
        How many frames (from the start, or from a failed check) registration may use.
    measure : vision.angles.MeasureConfig
        Measurement settings, passed to ``measure_frame`` (and ``prepare_measurement``).
    registration : vision.registration.RegistrationConfig or None
        Registration settings, passed to ``register``; None calls it with its own defaults.
    recheck_factor : float
        A check fails when the residual (px) exceeds ``recheck_factor * residual_px +
        recheck_margin_px`` of the current registration.
    recheck_margin_px : float
        See ``recheck_factor`` (px).
    measure_batch : int
        Frames measured together by ``vision.angles.measure_frames_batch`` (same results as
        one at a time, less overhead per frame); 1 measures each frame on its own.
    measure_batch_mb : float
        Most grey-frame data (MiB) held for one batch: a batch ends at ``measure_batch``
        frames or at this much, whichever comes first (64 frames of 640x480, 16 of 1920x1080).
    decoder_threads : int or None
        Threads of the video decoder (``vision.frames.VideoFrames``); None leaves FFmpeg's
        default, one per core. :func:`~tympani.pipeline.extract.batch.extract_batch` runs its workers'
        decoders on one thread when this is None, as every core then has a worker of its own.
    glitch_rad : float
        A measured frame whose theta_tip or theta_bot lies more than this (rad) from the median
        of it and its two measured neighbours on each side is marked not ok as a glitch
        (:func:`~tympani.pipeline.extract.video.flag_glitches`); 0 keeps every frame.
    kinematics_tol_mm : float
        A measured frame whose insertion depth lies more than this (mm; or five robust standard
        deviations of the video's depths about it, if more) from the video's constant-speed
        insertion is marked not ok (:func:`tympani.pipeline.extract.kinematics.flag_kinematics`), in runs as
        well as alone; 0 keeps every frame.
    excursion_rad : float
        A run of measured frames whose theta_bot steps this far (rad) or more away from the
        frames around it and back, fewer frames than those around it, is marked not ok
        (:func:`~tympani.pipeline.extract.video.flag_excursions`), and so is a measured frame whose
        contact angle is more than this shorter than that of the frames before it
        (:func:`~tympani.pipeline.extract.video.flag_contact_loss`); 0 keeps every frame.
    lone_reach : int
        A measured frame with no other frame measured within this many frames either side is
        marked not ok: nothing checks it (:func:`~tympani.pipeline.extract.video.flag_lone`; not
        in videos of fewer than ``2 * lone_reach + 1`` frames); 0 keeps every frame.
    sparse_share : float
        When no more than this share (0-1) of the frames from a video's first measured frame to its
        last is measured (after the glitch and kinematics checks; spans of at least
        :data:`~tympani.pipeline.extract.video.SPARSE_MIN_SPAN` frames), all of them are marked not ok
        (:func:`~tympani.pipeline.extract.video.flag_sparse`); so are they where they are at most
        :data:`~tympani.pipeline.extract.video.SPARSE_FEW` frames and this share of all the video's
        frames (:func:`~tympani.pipeline.extract.video.flag_few`, after the lone-frame check); 0
        keeps every frame.
    stripe_frames : int
        When at least this many frames of a video were refused for regular stripes past their tip
        (the array's bands going on, unseen), its measured frames are marked not ok too: the
        array's look hides its apical part, and the tips read short advance at the insertion's
        speed (:func:`~tympani.pipeline.extract.video.flag_stripes`); 0 keeps every frame.
    calibration : vision.frames.LensCalibration or None
        The camera's lens. Frames are undistorted with it (:func:`tympani.vision.frames.undistorter`)
        before they are registered, checked or drawn, so the pose is that of the ideal pinhole
        image that the registration's similarity (phantom mm to image px) describes; the
        measurement samples the recorded frames where the lens put its strip's points
        (:meth:`~tympani.vision.frames.LensCalibration.distort_points`), which costs nothing a frame.
        None: frames are taken as they are.
    """

    phantom: Phantom = DEFAULT_PHANTOM
    array: ElectrodeArray = DEFAULT_ARRAY
    recheck_every: int = 150
    register_frames: int = 5
    measure: Any = field(default_factory=MeasureConfig)
    registration: Any = field(default_factory=RegistrationConfig)
    recheck_factor: float = 2.0
    recheck_margin_px: float = 0.6
    measure_batch: int = 64
    measure_batch_mb: float = 32.0
    decoder_threads: int | None = None
    glitch_rad: float = 0.25
    kinematics_tol_mm: float = 0.5
    excursion_rad: float = 0.5
    lone_reach: int = 3
    sparse_share: float = 0.5
    stripe_frames: int = 3
    calibration: LensCalibration | None = None

    def __post_init__(self) -> None:
        if int(self.recheck_every) != self.recheck_every or self.recheck_every < 0:
            raise ValueError(f"recheck_every must be an integer >= 0, not {self.recheck_every!r}")
        if int(self.register_frames) != self.register_frames or self.register_frames < 1:
            raise ValueError(f"register_frames must be an integer >= 1, not {self.register_frames!r}")
        if int(self.measure_batch) != self.measure_batch or self.measure_batch < 1:
            raise ValueError(f"measure_batch must be an integer >= 1, not {self.measure_batch!r}")
        check_decoder_threads(self.decoder_threads)
        if not self.glitch_rad >= 0:
            raise ValueError(f"glitch_rad must be >= 0 rad, not {self.glitch_rad!r}")
        if not self.excursion_rad >= 0:
            raise ValueError(f"excursion_rad must be >= 0 rad, not {self.excursion_rad!r}")
        if int(self.lone_reach) != self.lone_reach or self.lone_reach < 0:
            raise ValueError(f"lone_reach must be an integer >= 0, not {self.lone_reach!r}")
        if not self.kinematics_tol_mm >= 0:
            raise ValueError(f"kinematics_tol_mm must be >= 0 mm, not {self.kinematics_tol_mm!r}")
        if int(self.stripe_frames) != self.stripe_frames or self.stripe_frames < 0:
            raise ValueError(f"stripe_frames must be an integer >= 0, not {self.stripe_frames!r}")
        if not 0.0 <= self.sparse_share < 1.0:
            raise ValueError(f"sparse_share must be in [0, 1), not {self.sparse_share!r}")
        if not self.measure_batch_mb > 0:
            raise ValueError(f"measure_batch_mb must be > 0, not {self.measure_batch_mb!r}")
        if not (self.recheck_factor >= 1.0 and self.recheck_margin_px >= 0.0):
            raise ValueError("recheck_factor must be >= 1 and recheck_margin_px >= 0")

    def recheck_threshold_px(self, registration: Registration) -> float:
        """Residual (px) above which a check re-registers the video."""
        return float(registration.residual_px) * self.recheck_factor + self.recheck_margin_px

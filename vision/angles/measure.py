"""The entry points: :func:`measure_frame` and :func:`measure_frames_batch`.

Both run the four stages (survey, edges, centre line, angles) on all their frames at once;
:func:`measure_frame` is a batch of one.
"""

from __future__ import annotations

import math
import time

import cv2
import numpy as np

from tympani.vision.angles.beyond import STRIPES_PAST_TIP, stripe_periodicity
from tympani.vision.angles.centreline import CentreLine, centre_line_batch
from tympani.vision.angles.config import FrameMeasurement, MeasureConfig, failure
from tympani.vision.angles.edges import edges_batch
from tympani.vision.angles.plan import HasPose, MeasurePlan, prepare_measurement
from tympani.vision.angles.results import results_batch
from tympani.vision.angles.survey import Survey, survey_batch
from tympani.vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM, ElectrodeArray, Phantom
from tympani.vision.greyscale import as_float_gray, to_gray


def _grey_levels(frame: np.ndarray) -> np.ndarray:
    """A 2-D grey image (0–255 scale) of a frame: ``uint8`` for a ``uint8`` frame, else float32
    with the float precision kept (:mod:`tympani.vision.greyscale`)."""
    a = np.asarray(frame)
    if a.size == 0:
        raise ValueError(f"a frame must be 2-D grey or BGR(A) colour, not shape {a.shape}")
    if a.dtype == np.uint8 and a.ndim == 2:
        return a  # already grey levels; the measurement only reads it
    return to_gray(a) if a.dtype == np.uint8 else as_float_gray(a)


def _extras(contrast: float, c: CentreLine, step_mm: float) -> dict[str, float]:
    """The diagnostics of a frame with a centre line (see :class:`FrameMeasurement`'s ``extras``):
    its ``contrast`` (grey levels), edge fraction, width ratio and bare tip length."""
    seen = np.flatnonzero(c.measured)
    bare = (c.tip_f - seen[-1]) * step_mm if len(seen) else math.nan
    return dict(contrast=contrast, edge_fraction=float(len(seen)) / len(c.measured), width_ratio=c.width_ratio,
                bare_tip_mm=float(bare))


def measure_frame(
    gray: np.ndarray,
    registration: HasPose | MeasurePlan,
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
        view"``, ``"array edges not found"``, bright bands going on past the dark run's end
        (the array lighter past a shadow's edge, see ``MeasureConfig.resume_mm``), part-dark
        stretches going on past it (bands blurred into the body, see
        ``MeasureConfig.lighter_stretches``), the array's
        bands beside the dark run rather than on it (the run its shadow, see
        :mod:`tympani.vision.angles.shadow`), ``"bad frame: ..."`` or ``"measurement failed:
        ..."``. ``extras['time_ms']`` is the time
        spent on the frame (ms), without the strip's preparation when a plan is passed;
        ``timings`` splits it by stage (s).

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
        img = _grey_levels(gray)
    except (ValueError, TypeError, cv2.error) as exc:
        return failure(f"bad frame: {exc}")
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
    angles (stages 2–4) run on all frames' stations laid end to end (see
    :mod:`tympani.vision.angles.ragged`), so that only the remaps and the assembly of the results are per frame.
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
            img = _grey_levels(gray)
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

# Why a frame whose dark run is followed by a train of bright stretches (metal bands, with the
# array's body too light to count as dark) is not measured (:attr:`Survey.resumes`).
_RESUMES = "bright bands go on past the dark run's end (the array out of a shadow?)"
# ... and one whose tip meets bright interiors in a row, as alike as metal bands or a chain of
# equal bubbles (:data:`~tympani.vision.angles.bubbles.TRAIN`).
_TRAIN = "bright interiors in a row at the tip: metal bands with little body between, or a chain of bubbles?"
# ... and one followed by stretch after stretch of part dark (:attr:`Survey.lighter`), bubbles or not.
_LIGHTER = "part-dark stretches go on past the dark run's end (bands blurred into the array's body?)"


def _stripes_past_tip(imgs: list[np.ndarray], plan: MeasurePlan, results: list[FrameMeasurement],
                      contrasts: list[float]) -> np.ndarray:
    """Which of ``results`` (one per frame of ``imgs``; a bool array in their order) are measured ok and
    show a regular pattern of stripes past their tip
    (:func:`~tympani.vision.angles.beyond.stripe_periodicity`), varying by at least
    ``plan.cfg.stripe_spread`` of the array's contrast (``contrasts``, grey levels)."""
    cfg = plan.cfg
    hit = np.zeros(len(results), dtype=bool)
    ok = [i for i, r in enumerate(results) if r.ok]
    if ok:
        correlation, spread = stripe_periodicity([imgs[i] for i in ok], plan,
                                                 np.array([results[i].theta_tip for i in ok]), cfg)
        hit[ok] = (correlation >= cfg.stripe_correlation) & (spread >= cfg.stripe_spread * np.array(contrasts)[ok])
    return hit


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
            surveys = list(survey_batch(imgs, plan))
            t1 = time.perf_counter()
            found = [k for k, sv in enumerate(surveys) if isinstance(sv, Survey)]  # the frames stage 1 passed
            edges = edges_batch([imgs[k] for k in found], plan, [surveys[k] for k in found]) if found else []
            t2 = time.perf_counter()
            lines = centre_line_batch(plan, edges) if found else []
            for j, k in enumerate(found):  # bright stretches past the tip that no bubble explains
                if edges[j].train:
                    lines[j] = _TRAIN
                elif surveys[k].resumes and not edges[j].bubble:
                    lines[j] = _RESUMES
                elif surveys[k].lighter:
                    lines[j] = _LIGHTER
            t3 = time.perf_counter()
            measured = [j for j, c in enumerate(lines) if isinstance(c, CentreLine)]
            finals = results_batch(plan, [(edges[j], lines[j], _extras(surveys[found[j]].contrast, lines[j], plan.step_mm))
                                           for j in measured]) if measured else []
            striped = _stripes_past_tip([imgs[found[j]] for j in measured], plan, finals,
                                        [surveys[found[j]].contrast for j in measured])
            t4 = time.perf_counter()
    except _ERRORS as exc:
        if len(imgs) > 1:
            return [r for img in imgs for r in _measure_batch([img], plan)]
        return [failure(f"measurement failed: {type(exc).__name__}: {exc}")]
    share = [(t1 - t0) / len(imgs), (t2 - t1) / max(len(found), 1), (t3 - t2) / max(len(found), 1),
             (t4 - t3) / max(len(measured), 1)]
    out: list[FrameMeasurement] = []
    by_frame = {found[j]: j for j in range(len(found))}
    final_of = dict(zip(measured, finals))
    striped_of = dict(zip(measured, striped.tolist()))
    for k, sv in enumerate(surveys):
        if not isinstance(sv, Survey):
            result = sv
            result.timings.update(survey=share[0])
        elif final_of.get(by_frame[k]) is None:
            result = failure(str(lines[by_frame[k]]), contrast=sv.contrast)
            result.timings.update(survey=share[0], edges=share[1], centre_line=share[2])
        else:
            result = final_of[by_frame[k]]
            if striped_of[by_frame[k]]:
                result = failure(STRIPES_PAST_TIP, contrast=sv.contrast)
            result.timings.update(survey=share[0], edges=share[1], centre_line=share[2], angles=share[3])
        result.extras["time_ms"] = 1e3 * sum(result.timings.values())
        out.append(result)
    return out

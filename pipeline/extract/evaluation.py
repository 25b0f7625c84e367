"""Blind evaluation of the extraction on videos of renderer C (``tympani evaluate-extraction``), or
of any renderer given as a Python file.

Renderer C (:mod:`tympani.pipeline.synthetic.renderer_c`) was written independently of tympani's
vision. Each seed draws a video (frame size, scale, the nuisances' strengths), renders it with its
exact truth, extracts it as ``tympani extract`` does and scores every frame against the truth:

- *measured*: the share of frames marked ``ok``;
- *grossly wrong*: a frame marked ``ok`` whose ``theta_tip`` is off by more than 0.3 rad or whose
  ``theta_con`` is off by more than 0.5 rad, counted among the frames where the array touches
  the outer wall (contact frames) — a wrong answer that says it is right;
- the medians of |error| over the measured frames (``theta_con`` over measured contact frames);
- the registration's centre (px) and scale (%) errors against the renderer's pose.
"""

from __future__ import annotations

import importlib.util
import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from types import ModuleType

import numpy as np
import pandas as pd

from tympani.pipeline.extract.config import ExtractConfig
from tympani.pipeline.extract.records import refusals, refusals_text
from tympani.pipeline.extract.video import extract_video
from tympani.pipeline.io import atomic_write_csv, check_writable_dir
from tympani.pipeline.synthetic import renderer_c
from tympani.vision.errors import InputError, one_line
from tympani.vision.registration import Registration

#: How the nuisances of a video are drawn: none; each off with probability 0.3, else of strength
#: U(0.1, 1); every one at U(0.3, 1) with bubbles at U(0.5, 1) and doubled walls in 60 % of videos.
NUISANCE_MODES = ("clean", "random", "harsh")


@dataclass(frozen=True)
class EvaluationConfig:
    """Settings of the extraction evaluation.

    Parameters
    ----------
    nuisance : str
        One of :data:`NUISANCE_MODES`.
    frames : int
        Frames per video (30 fps; the insertion runs from 2 to 17 mm deep over the video).
    gross_tip_rad, gross_con_rad : float
        A measured frame is grossly wrong beyond these |errors| (rad) of ``theta_tip`` or
        ``theta_con``.
    renderer : str
        A Python file defining the renderer (:func:`load_renderer`); empty: renderer C.
    """

    nuisance: str = "random"
    frames: int = 30
    gross_tip_rad: float = 0.3
    gross_con_rad: float = 0.5
    renderer: str = ""


def load_renderer(path: str) -> ModuleType:
    """The renderer of a Python file, or renderer C for an empty ``path``.

    The file defines ``NUISANCE_KEYS`` (the nuisances' names; a seed's draw gives each a strength
    0–1) and ``render_video(path, seed, *, n_frames, size, px_per_mm, nuisance)``, which writes a
    video OpenCV reads (30 fps) and returns ``(truth, info)``: a table with one row a frame
    (``frame``, ``theta_tip``, ``theta_bot``, ``theta_con`` in rad, ``in_contact``) and a dict whose
    ``"pose"`` holds ``centre_x_px``, ``centre_y_px`` (the image of the spiral's centre) and
    ``px_per_mm``, and ``mirrored`` in the renderer's own convention. ``size`` is ``(width,
    height)`` (px) and ``px_per_mm`` None leaves the scale to the renderer.

    Raises
    ------
    InputError
        The file does not exist, does not load, or lacks one of the two names.
    """
    if not path:
        return renderer_c
    if not Path(path).is_file():
        raise InputError(path, "no such renderer file")
    name = f"tympani_renderer_{abs(hash(str(Path(path).resolve())))}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    # registered while it runs, as an import would: dataclasses and pickling look the module up by name
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)  # type: ignore[union-attr]
    except Exception as exc:  # the renderer's own code: any failure to load is the file's
        del sys.modules[name]
        raise InputError(path, f"the renderer does not load: {one_line(exc)}") from exc
    missing = [name for name in ("NUISANCE_KEYS", "render_video") if not hasattr(module, name)]
    if missing:
        raise InputError(path, f"the renderer defines no {' and no '.join(missing)}")
    return module


@dataclass(frozen=True)
class VideoCase:
    """What one seed draws: the frame size (px), the scale (px/mm, None: the renderer's own draw)
    and each nuisance's strength (0–1)."""

    seed: int
    size: tuple[int, int]
    px_per_mm: float | None
    nuisance: dict[str, float]


@dataclass(frozen=True)
class VideoScore:
    """The scores of one video (angles in rad; NaN where no frame qualifies).

    ``refused`` says why the frames not measured were not, every kind of reason with its frames
    (:func:`~tympani.pipeline.extract.records.refusals_text`). ``walls_doubled_found`` says
    whether the registration found the walls twice, ``parallax_px`` how far apart it found the
    copies (px), and ``other_copy_error_px`` the centre error had it taken the other copy (px; NaN
    for single walls): a ``centre_error_px`` near the parallax with ``other_copy_error_px`` near 0
    is a registration on the wrong copy, both well above 0 one between the copies.
    """

    seed: int
    width_px: int
    px_per_mm: float
    doubled_walls: float
    bubbles: float
    frames: int
    measured: int
    contact_frames: int
    gross_contact: int
    gross: int
    tip_median_rad: float
    bot_median_rad: float
    con_median_rad: float
    centre_error_px: float
    scale_error_pct: float
    mirror_ok: bool
    refused: str
    error: str = ""
    walls_doubled_found: bool = False
    parallax_px: float = 0.0
    other_copy_error_px: float = float("nan")


def draw_case(seed: int, mode: str, keys: tuple[str, ...] = renderer_c.NUISANCE_KEYS) -> VideoCase:
    """The video a seed stands for: 640×480 or 800×600 by parity, 15–20 px/mm in 40 % of videos
    (else the renderer's draw), and the nuisances ``keys`` as ``mode`` says (:data:`NUISANCE_MODES`;
    harsh draws treat ``bubbles`` and ``doubled_walls`` as said there where the renderer has them)."""
    if mode not in NUISANCE_MODES:
        raise ValueError(f"unknown nuisance mode {mode!r}; choose from {', '.join(NUISANCE_MODES)}")
    rng = np.random.default_rng(seed)
    size = [(640, 480), (800, 600)][seed % 2]
    px_per_mm = float(rng.uniform(15, 20)) if rng.random() < 0.4 else None
    if mode == "clean":
        nuisance = {k: 0.0 for k in keys}
    elif mode == "random":
        nuisance = {k: (0.0 if rng.random() < 0.3 else float(rng.uniform(0.1, 1.0))) for k in keys}
    else:
        nuisance = {k: float(rng.uniform(0.3, 1.0)) for k in keys}
        bubbles = float(rng.uniform(0.5, 1.0))
        doubled = float(rng.uniform(0.0, 1.0)) if rng.random() < 0.6 else 0.0
        nuisance.update({k: v for k, v in (("bubbles", bubbles), ("doubled_walls", doubled)) if k in keys})
    return VideoCase(seed, size, px_per_mm, nuisance)


def _median(x: pd.Series) -> float:
    return float(x.median()) if len(x) else float("nan")


def _video_fields(case: VideoCase, pose: dict) -> dict:
    """The :class:`VideoScore` fields that describe the video rather than score it."""
    return dict(seed=case.seed, width_px=case.size[0], px_per_mm=round(float(pose["px_per_mm"]), 2),
                doubled_walls=case.nuisance.get("doubled_walls", 0.0), bubbles=case.nuisance.get("bubbles", 0.0))


def score_video(case: VideoCase, table: pd.DataFrame, truth: pd.DataFrame, pose: dict, registration: Registration,
                cfg: EvaluationConfig) -> tuple[VideoScore, pd.DataFrame]:
    """Score an extracted angles table against the renderer's truth.

    Parameters
    ----------
    case : VideoCase
        The video.
    table : DataFrame
        The angles table of :func:`extract_video`.
    truth : DataFrame
        The renderer's truth (``frame``, ``theta_tip``, ``theta_bot``, ``theta_con`` in rad,
        ``in_contact``).
    pose : dict
        The renderer's pose (``centre_x_px``, ``centre_y_px``, ``px_per_mm``, ``mirrored``).
    registration : Registration
        What tympani registered (its pose, and the parallax where it found the walls twice).
    cfg : EvaluationConfig
        Gross-error thresholds.

    Returns
    -------
    score : VideoScore
    frames : DataFrame
        The table joined with the truth (``*_t`` columns) and a ``gross`` column.
    """
    m = table.merge(truth[["frame", "theta_tip", "theta_bot", "theta_con", "in_contact"]], on="frame",
                    suffixes=("", "_t"))
    ok = m["ok"].astype(bool)
    contact = m["in_contact"].astype(bool)
    tip, bot, con = ((m[c] - m[f"{c}_t"]).abs() for c in ("theta_tip", "theta_bot", "theta_con"))
    gross = ok & ((tip > cfg.gross_tip_rad) | (con > cfg.gross_con_rad))
    reg_centre = np.array([registration.pose.centre_x_px, registration.pose.centre_y_px])
    truth_centre = np.array([pose["centre_x_px"], pose["centre_y_px"]])
    parallax = np.asarray(registration.parallax_px, dtype=float)  # (0, 0) for single walls
    refused = refusals(m.loc[~ok, "reason"].astype(str))
    score = VideoScore(
        **_video_fields(case, pose),
        frames=len(m), measured=int(ok.sum()), contact_frames=int(contact.sum()),
        gross_contact=int((gross & contact).sum()), gross=int(gross.sum()),
        tip_median_rad=_median(tip[ok]), bot_median_rad=_median(bot[ok]), con_median_rad=_median(con[ok & contact]),
        centre_error_px=float(np.hypot(*(reg_centre - truth_centre))),
        scale_error_pct=float(100.0 * (registration.pose.px_per_mm / pose["px_per_mm"] - 1.0)),
        mirror_ok=bool(registration.pose.mirrored == pose["mirrored"]),
        refused=refusals_text(refused, top=len(refused)),
        walls_doubled_found=bool(registration.walls_doubled),
        parallax_px=float(np.hypot(*parallax)),
        other_copy_error_px=float(np.hypot(*(reg_centre + parallax - truth_centre))) if registration.walls_doubled
        else float("nan"),
    )
    return score, m.assign(gross=gross)


_TRUTH_COLUMNS = ("frame", "theta_tip", "theta_bot", "theta_con", "in_contact")
_POSE_KEYS = ("centre_x_px", "centre_y_px", "px_per_mm", "mirrored")


def checked_render(result: object, renderer: str) -> tuple[pd.DataFrame, dict]:
    """The truth table and pose of what a renderer's ``render_video`` returned, checked against
    the contract of :func:`load_renderer`.

    Raises
    ------
    InputError
        Naming the renderer file (``renderer``; renderer C when empty) and what is missing.
    """
    name = renderer or "renderer C"

    def refuse(problem: str) -> InputError:
        return InputError(name, f"render_video returned {problem}")

    if not (isinstance(result, tuple) and len(result) == 2):
        raise refuse("something other than a (truth, info) pair")
    truth, info = result
    if not isinstance(truth, pd.DataFrame):
        raise refuse(f"a truth of type {type(truth).__name__}, not a table")
    missing = [c for c in _TRUTH_COLUMNS if c not in truth.columns]
    if missing:
        raise refuse(f"a truth table without {', '.join(missing)}")
    pose = info.get("pose") if isinstance(info, dict) else None
    if not isinstance(pose, dict):
        raise refuse("an info without a 'pose' dict")
    missing = [k for k in _POSE_KEYS if k not in pose]
    if missing:
        raise refuse(f"a pose without {', '.join(missing)}")
    return truth, pose


def evaluate_video(seed: int, out_dir: str | os.PathLike, cfg: EvaluationConfig = EvaluationConfig()) -> VideoScore:
    """Render seed's video into ``out_dir`` (``v<seed>.mp4`` with ``v<seed>_truth.csv``), extract
    it, score it and write its per-frame table (``v<seed>_frames.csv``). A video tympani cannot
    extract at all scores no frame measured, with the error."""
    renderer = load_renderer(cfg.renderer)
    case = draw_case(seed, cfg.nuisance, tuple(renderer.NUISANCE_KEYS))
    out = Path(out_dir)
    path = out / f"v{seed}.mp4"
    truth, pose = checked_render(renderer.render_video(path, seed, n_frames=cfg.frames, size=case.size,
                                                       px_per_mm=case.px_per_mm, nuisance=case.nuisance), cfg.renderer)
    atomic_write_csv(out / f"v{seed}_truth.csv", truth)
    try:
        table, registration = extract_video(path, ExtractConfig(), fps=30.0)
    except InputError as exc:  # a refusal of the whole video (no phantom found) is a result too
        nan = float("nan")
        return VideoScore(**_video_fields(case, pose), frames=len(truth), measured=0,
                          contact_frames=int(truth["in_contact"].astype(bool).sum()), gross_contact=0, gross=0,
                          tip_median_rad=nan, bot_median_rad=nan, con_median_rad=nan, centre_error_px=nan,
                          scale_error_pct=nan, mirror_ok=False, refused="", error=one_line(exc)[:200])
    score, frames = score_video(case, table, truth, pose, registration, cfg)
    atomic_write_csv(out / f"v{seed}_frames.csv", frames)
    return score


def _evaluate_one(args: tuple[int, str, EvaluationConfig]) -> VideoScore:
    return evaluate_video(*args)


def evaluate_extraction(seeds: range | list[int], out_dir: str | os.PathLike,
                        cfg: EvaluationConfig = EvaluationConfig(), *, workers: int = 1) -> pd.DataFrame:
    """:func:`evaluate_video` of every seed (in ``workers`` processes), one row a video."""
    check_writable_dir(out_dir)
    jobs = [(int(s), str(out_dir), cfg) for s in seeds]
    if workers <= 1:
        scores = [_evaluate_one(j) for j in jobs]
    else:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            scores = list(pool.map(_evaluate_one, jobs))
    return pd.DataFrame([asdict(s) for s in scores])


def summarise(results: pd.DataFrame) -> dict[str, float]:
    """The evaluation's figures over all videos: ``gross_contact_share`` (grossly wrong among the
    contact frames), ``measured_share`` (among all frames), the medians over videos of the
    videos' median |errors| (rad), the largest registration errors, and how many videos failed."""
    done = results[results["error"] == ""]
    contact = int(done["contact_frames"].sum())
    return {
        "videos": int(len(results)),
        "failed": int((results["error"] != "").sum()),
        "frames": int(results["frames"].sum()),
        "measured_share": float(results["measured"].sum() / max(int(results["frames"].sum()), 1)),
        "contact_frames": contact,
        "gross_contact": int(done["gross_contact"].sum()),
        "gross_contact_share": float(done["gross_contact"].sum() / max(contact, 1)),
        "tip_median_rad": float(done["tip_median_rad"].median()),
        "bot_median_rad": float(done["bot_median_rad"].median()),
        "con_median_rad": float(done["con_median_rad"].median()),
        "centre_error_max_px": float(done["centre_error_px"].max()),
        "scale_error_max_pct": float(done["scale_error_pct"].abs().max()),
        "mirror_wrong": int((~done["mirror_ok"].astype(bool)).sum()),
        **copy_counts(done),
    }


def copy_counts(done: pd.DataFrame, within_px: float = 1.0) -> dict[str, int]:
    """How the registration fared where it found the walls twice: the videos where it did, and
    of those, how many lie more than ``within_px`` (px) from the renderer's centre, on the other
    copy (within ``within_px`` of it) or elsewhere (between the copies)."""
    found = done[done["walls_doubled_found"].astype(bool)]
    off = found[found["centre_error_px"] > within_px]
    other = int((off["other_copy_error_px"] <= within_px).sum())
    return {"doubled_found": int(len(found)), "doubled_off": int(len(off)), "doubled_other_copy": other,
            "doubled_between": int(len(off)) - other}


def format_summary(summary: dict[str, float]) -> str:
    """The summary in a few lines of text."""
    s = summary
    return "\n".join([
        f"videos {s['videos']} ({s['failed']} not extracted), frames {s['frames']}",
        f"measured {100 * s['measured_share']:.1f} % of frames",
        f"grossly wrong but marked ok: {s['gross_contact']} of {s['contact_frames']} contact frames "
        f"({100 * s['gross_contact_share']:.1f} %)",
        f"median |error| (median of the videos' medians): theta_tip {s['tip_median_rad']:.4f} rad, "
        f"theta_bot {s['bot_median_rad']:.4f} rad, theta_con {s['con_median_rad']:.4f} rad",
        f"registration: centre error max {s['centre_error_max_px']:.2f} px, scale error max "
        f"{s['scale_error_max_pct']:.2f} %, mirror wrong in {s['mirror_wrong']}",
        f"walls found twice in {s['doubled_found']} videos: centre more than 1 px off in {s['doubled_off']} "
        f"({s['doubled_other_copy']} on the other copy, {s['doubled_between']} elsewhere)",
    ])

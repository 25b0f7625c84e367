"""Whole synthetic insertions: what to render (:class:`VideoSpec`) and :func:`render_video`, which
writes the frames to mp4 or a PNG folder and returns the per-frame truth.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from tympani.vision.geometry import DEFAULT_ARRAY, DEFAULT_PHANTOM, CameraPose, ElectrodeArray, Phantom
from tympani.vision.rendering.appearance import Appearance
from tympani.vision.rendering.centreline import ArrayState, ContactPolicy, pose_at_depth
from tympani.vision.rendering.nuisances import Nuisance
from tympani.vision.rendering.scene import Scene

__all__ = ["VideoSpec", "render_video", "spec_to_dict"]


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

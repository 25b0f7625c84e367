"""Small stand-ins for registration and measurement, and tiny test videos.

The batch/CLI tests check plumbing (streaming, re-registration, files, exit codes), not vision,
so they pass :data:`STEPS` (a :class:`~tympani.pipeline.extract.config.VisionSteps` of the fakes
below, with no measurement plan and no batches) in place of the real registration and
measurement. The fakes are driven by simple image statistics:

- registration fails ("no phantom found") on a black first frame;
- a frame whose top-left 8x8 block is white fails the registration check (camera bumped);
- a frame whose bottom-right 8x8 block is black while the frame is not dark is *blocked*: it
  fails every registration check and registering on it fails (too little of the phantom in
  view);
- measurement: frames darker than mean 20 are not ok; otherwise theta_tip = mean/100,
  theta_bot = mean/200 (rad) and an extra column ``depth_mm``.

Tiny videos encode their frame index in their brightness, so frames can be told apart after
compression.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.vision.geometry import CameraPose

W, H = 64, 48


class FakeRegistrationError(Exception):
    """What the fake registration raises when it finds no phantom."""

    def __init__(self, problem: str) -> None:
        super().__init__(problem)
        self.problem = problem


@dataclass(frozen=True)
class FakeRegistration:
    pose: CameraPose
    residual_px: float = 0.5
    n_frames: int = 0
    array_axis_offset_px: float = float("nan")

    def to_dict(self) -> dict:
        p = self.pose
        return dict(centre_x_px=p.centre_x_px, centre_y_px=p.centre_y_px, rotation_rad=p.rotation_rad,
                    px_per_mm=p.px_per_mm, mirrored=p.mirrored, residual_px=self.residual_px)

    @classmethod
    def from_dict(cls, d: dict) -> "FakeRegistration":
        pose = CameraPose(d["centre_x_px"], d["centre_y_px"], d["rotation_rad"], d["px_per_mm"], d["mirrored"])
        return cls(pose, d["residual_px"])


@dataclass(frozen=True)
class FakeMeasurement:
    ok: bool
    reason: str = ""
    theta_tip: float = float("nan")
    theta_bot: float = float("nan")
    theta_con: float = float("nan")
    tip_mm: np.ndarray | None = None
    bot_mm: np.ndarray | None = None
    centreline_mm: np.ndarray | None = None
    outline_mm: np.ndarray | None = None
    extras: dict = field(default_factory=dict)

    def to_row(self) -> dict:
        return dict(theta_tip=self.theta_tip, theta_bot=self.theta_bot, theta_con=self.theta_con,
                    ok=self.ok, reason=self.reason, **self.extras)


def _blocked(g: np.ndarray) -> bool:
    return g[-8:, -8:].mean() < 5 and g[:8, -8:].mean() > 20


def fake_register(gray_frames, phantom, cfg=None):
    assert gray_frames and all(g.ndim == 2 and g.dtype == np.uint8 for g in gray_frames)
    g = gray_frames[0]
    if g.mean() < 5:
        raise FakeRegistrationError("no phantom found")
    if _blocked(g):
        raise FakeRegistrationError("too little of the phantom in view")
    bumped = g[:8, :8].mean() > 200
    pose = CameraPose(g.shape[1] / 2 + (5.0 if bumped else 0.0), g.shape[0] / 2, 0.0, 4.0, mirrored=False)
    return FakeRegistration(pose, 0.5, len(gray_frames))


def fake_check(gray, registration, phantom) -> float:
    if _blocked(gray):
        return 50.0
    bumped = gray[:8, :8].mean() > 200
    registered_bumped = registration.pose.centre_x_px != gray.shape[1] / 2
    return 50.0 if bumped != registered_bumped else 0.4


def fake_measure_frame(gray, registration, phantom, array, cfg):
    assert hasattr(registration, "pose")
    v = float(gray[8:, :].mean())
    if v < 20:
        return FakeMeasurement(ok=False, reason="no array in view")
    tip = np.array([3.0, 0.0])
    return FakeMeasurement(
        ok=True, theta_tip=v / 100, theta_bot=v / 200, theta_con=v / 200, tip_mm=tip, bot_mm=np.array([0.0, 3.0]),
        centreline_mm=np.array([[3.0, 0.0], [2.0, 2.0], [0.0, 3.0]]),
        outline_mm=np.array([[3.2, 0.0], [0.0, 3.2], [0.0, 2.8], [2.8, 0.0]]),
        extras={"depth_mm": v / 10},
    )


@dataclass(frozen=True)
class FakeConfig:
    """Stands in for MeasureConfig / RegistrationConfig (the fakes ignore their settings)."""

    name: str = "fake"


#: The fakes as the extraction's vision steps (module-level functions: they pickle to workers).
STEPS = VisionSteps(register=fake_register, check=fake_check, measure_frame=fake_measure_frame,
                    prepare_measurement=None, measure_frames_batch=None, registration_error=FakeRegistrationError)


def fake_config(**kwargs):
    """An :class:`ExtractConfig` whose measurement and registration settings are placeholders."""
    return ExtractConfig(measure=FakeConfig("measure"), registration=FakeConfig("registration"), **kwargs)


# --------------------------------------------------------------------------- tiny videos


def frame_image(i: int, *, dark: bool = False, bumped: bool = False, blocked: bool = False, w: int = W,
                h: int = H) -> np.ndarray:
    """A BGR frame whose brightness encodes ``i`` (30 + 10 i), or black when ``dark``; the
    bump and block markers as in the module docstring (a bump shows up to ``i`` = 17)."""
    img = np.full((h, w, 3), 0 if dark else min(30 + 10 * i, 250), np.uint8)
    if bumped:
        img[:8, :8] = 255
    if blocked:
        img[-8:, -8:] = 0
    return img


def write_video(path: Path, n: int = 20, *, fps: float = 25.0, fourcc: str = "mp4v", dark=(), bumped_from=None,
                all_dark: bool = False, blocked=()) -> Path:
    """Write a small video with ``cv2.VideoWriter``; frames in ``dark`` are black, those in
    ``blocked`` blocked, those from ``bumped_from`` on bumped."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (W, H))
    assert writer.isOpened()
    for i in range(n):
        bumped = bumped_from is not None and i >= bumped_from
        writer.write(frame_image(i, dark=all_dark or i in dark, bumped=bumped, blocked=i in blocked))
    writer.release()
    return path


def write_folder(path: Path, n: int = 12, *, grey: bool = False, name: str = "frame_{}.png") -> Path:
    path.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        img = frame_image(i)
        cv2.imwrite(str(path / name.format(i)), img[:, :, 0] if grey else img)
    return path

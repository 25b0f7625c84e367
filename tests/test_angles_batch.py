"""measure_frames_batch equals measure_frame, frame by frame.

Rendered frames of four random poses (two mirrored, two not), with depths from not inserted
(no array in the channel) through the entry channel to deep insertions, nuisance strengths 0–1,
and frames where the measurement fails (no array, an array painted over with the fluid); plus
colour, float32 and wrong-size frames, which the batch hands to the per-frame function.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from vision import angles as angles_mod
from vision.angles import FrameMeasurement, measure_frame, measure_frames_batch, prepare_measurement
from vision.rendering import Scene, pose_at_depth, random_appearance, random_nuisance, random_pose

W, H = 640, 480
DEPTHS_MM = (-40.0, -7.0, -2.0, 3.0, 8.0, 12.0, 16.0, 20.0)


def _gray(bgr: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)


def _assert_same(a: FrameMeasurement, b: FrameMeasurement) -> None:
    """Same outcome, angles, lines and extras (to 1e-9; time_ms aside)."""
    assert (a.ok, a.reason) == (b.ok, b.reason)
    for name in ("theta_tip", "theta_bot", "theta_con", "tip_mm", "bot_mm", "centreline_mm", "outline_mm", "gap_mm"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_allclose(np.asarray(y, float), np.asarray(x, float), rtol=0, atol=1e-9, err_msg=name)
    ex = {k: v for k, v in a.extras.items() if k != "time_ms"}
    ey = {k: v for k, v in b.extras.items() if k != "time_ms"}
    assert ex.keys() == ey.keys()
    np.testing.assert_allclose([ey[k] for k in ex], [ex[k] for k in ex], rtol=0, atol=1e-9)
    assert set(a.timings) == set(b.timings) and ("time_ms" in a.extras) == ("time_ms" in b.extras)


@pytest.fixture(scope="module", autouse=True)
def _one_opencv_thread():
    """Single-threaded OpenCV in this module, restored after it: a process whose OpenCV
    threads are busy cannot be forked safely, and test_batch forks a pool after this module."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(threads)


@pytest.fixture(scope="module")
def videos() -> list[tuple[object, list[np.ndarray]]]:
    """Per pose: its plan and a batch of grey frames (some with the array hidden)."""
    rng = np.random.default_rng(7)
    out = []
    for mirrored in (False, True, False, True):
        pose = random_pose(rng, W, H, px_per_mm=(15.0, 45.0))
        while pose.mirrored != mirrored:
            pose = random_pose(rng, W, H, px_per_mm=(15.0, 45.0))
        frames = []
        for i, depth in enumerate(DEPTHS_MM):
            scene = Scene(pose, W, H, random_appearance(rng), random_nuisance(rng, float(rng.uniform(0.0, 1.0))), rng=rng)
            state = pose_at_depth(depth)
            frame = _gray(scene.render(state))
            if i == len(DEPTHS_MM) - 2:  # the array painted over with the fluid: not found
                body, bands = scene.array_layers(state)
                empty = _gray(scene.render(pose_at_depth(-40.0)))
                covered = np.maximum(body, bands) > 0
                frame[covered] = empty[covered]
            frames.append(frame)
        out.append((prepare_measurement(SimpleNamespace(pose=pose), (H, W)), frames))
    return out


def test_batch_equals_per_frame(videos: list[tuple[object, list[np.ndarray]]]) -> None:
    """Every frame of every pose: the batch gives what measure_frame gives; the set covers
    measured frames, the entry channel and failures."""
    reasons = set()
    for plan, frames in videos:
        batch = measure_frames_batch(frames, plan)
        assert len(batch) == len(frames)
        for frame, b in zip(frames, batch):
            a = measure_frame(frame, plan)
            _assert_same(a, b)
            reasons.add(a.reason)
    assert "" in reasons and "array not in channel" in reasons and len(reasons) >= 2


def test_batched_stages_equal_per_frame_stages(videos: list[tuple[object, list[np.ndarray]]]) -> None:
    """Stages 2 and 3 run together (not the per-frame fallback of measure_frames_batch) and
    give _edges' and _centre_line's values frame by frame: padded and end-to-end stations
    change no frame's filters at its borders."""
    lines = 0
    for plan, frames in videos:
        with np.errstate(divide="ignore", invalid="ignore"):
            surveys = angles_mod._survey_batch(frames, plan)
            keep = [k for k, sv in enumerate(surveys) if isinstance(sv, angles_mod._Survey)]
            edges = angles_mod._edges_batch([frames[k] for k in keep], plan, [surveys[k] for k in keep])
            centres = angles_mod._centre_line_batch(plan, edges)
            for k, e_b, c_b in zip(keep, edges, centres):
                e_a = angles_mod._edges(frames[k], plan, surveys[k])
                c_a = angles_mod._centre_line(plan, e_a)
                assert (e_a.lo, e_a.n, e_a.level) == (e_b.lo, e_b.n, e_b.level)
                for name in ("v_in", "v_out", "ok_in", "ok_out"):
                    np.testing.assert_allclose(getattr(e_b, name), getattr(e_a, name), rtol=0, atol=1e-9, err_msg=name)
                assert (c_a is None) == (c_b is None)
                if c_a is not None:
                    lines += 1
                    assert abs(c_a.tip_f - c_b.tip_f) <= 1e-9
                    for name in ("tip_mm", "line", "gap", "radius", "measured"):
                        np.testing.assert_allclose(np.asarray(getattr(c_b, name), float),
                                                   np.asarray(getattr(c_a, name), float), rtol=0, atol=1e-9,
                                                   err_msg=name)
    assert lines >= 10


def test_batch_of_a_stack_and_of_one(videos: list[tuple[object, list[np.ndarray]]]) -> None:
    """A (B, H, W) array and a batch of one frame work the same way."""
    plan, frames = videos[0]
    stacked = measure_frames_batch(np.stack(frames[3:6]), plan)
    single = measure_frames_batch(frames[4:5], plan)
    _assert_same(measure_frame(frames[4], plan), single[0])
    for frame, b in zip(frames[3:6], stacked):
        _assert_same(measure_frame(frame, plan), b)


def test_batch_with_odd_frames(videos: list[tuple[object, list[np.ndarray]]]) -> None:
    """Colour, float32, wrong-size and broken frames mixed into a batch keep their place and
    get measure_frame's result."""
    plan, frames = videos[1]
    colour = cv2.cvtColor(frames[5], cv2.COLOR_GRAY2BGR)
    odd = [frames[4], colour, frames[5].astype(np.float32), frames[6][:200, :300], np.zeros((0,), np.uint8), frames[7]]
    batch = measure_frames_batch(odd, plan)
    assert len(batch) == len(odd)
    for frame, b in zip(odd, batch):
        _assert_same(measure_frame(frame, plan), b)
    assert batch[4].reason.startswith("bad frame")

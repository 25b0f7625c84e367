"""Renderer C: synthetic overhead insertion videos written independently of tympani's vision.

It was written by someone who had not read tympani's measurement or its own renderer
(:mod:`tympani.vision.rendering`), from a description of the phantom, the array, the angle
definitions and what real footage shows (docs/how-it-works.md, docs/renderer-c.md). It renders
what an overhead camera sees of the transparent planar phantom with the tapered electrode array
inserted at constant speed, under a random similarity pose, with optional nuisances, and returns
the ground truth (theta_tip, theta_bot, theta_con) measured on the rendered geometry.
``tympani evaluate-extraction`` scores the extraction on its videos.

Only numpy, scipy, pandas and OpenCV are used.  Everything random comes from
``numpy.random.SeedSequence(seed)`` (one child stream per concern), so identical calls give
identical output and switching a nuisance on or off does not change the pose, the array
shape or the base appearance.

Public API::

    render_video(out_path, seed, *, n_frames=30, size=(640, 480), px_per_mm=None,
                 speed_mm_s=3.0, fps=30.0, depth_range_mm=(2.0, 17.0), nuisance=None)
        -> (truth: pandas.DataFrame, info: dict)

    render_frames(seed, ...)  same keywords, no file: returns (frames, truth, info), frames a
                              list of HxWx3 uint8 BGR images exactly as written to the video.

Also exported for tests and other tools: ``Phantom`` (geometry, the angle of a point,
wall distances), ``ArrayModel`` (shape model) and ``measure_truth``.

Conventions (docs/renderer-c.md):
* phantom frame: mm, origin o_c, x right, y up (counter-clockwise polar angle);
* image: OpenCV pixels, x right, y down, pixel centres at integers;
* pose: [u - cx, -(v - cy)] = s * R(rotation_rad) * M * [X, Y], M = diag(-1, 1) when mirrored,
  i.e. rotation_rad is counter-clockwise *as seen on screen* and a mirrored pose flips the
  phantom's x axis before rotating.  ``info['pose']['A_px_from_mm']`` is the 2x3 affine.
"""
from __future__ import annotations

import os

import cv2

from tympani.pipeline.synthetic.renderer_c.drawing import Renderer
from tympani.pipeline.synthetic.renderer_c.geometry import (
    NUISANCE_KEYS,
    ArrayConfig,
    ArrayModel,
    Phantom,
    PhantomConfig,
    Pose,
    measure_truth,
)

__all__ = [
    "render_video", "render_frames", "Phantom", "PhantomConfig", "ArrayConfig", "ArrayModel",
    "measure_truth", "Pose", "NUISANCE_KEYS",
]


def _make(seed, n_frames, size, px_per_mm, speed_mm_s, fps, depth_range_mm, nuisance):
    return Renderer(seed, n_frames, size, px_per_mm, speed_mm_s, fps, depth_range_mm, nuisance)


def render_frames(seed, *, n_frames=30, size=(640, 480), px_per_mm=None, speed_mm_s=3.0, fps=30.0,
                  depth_range_mm=(2.0, 17.0), nuisance=None):
    """Like render_video but returns (frames, truth, info) and writes nothing."""
    R = _make(seed, n_frames, size, px_per_mm, speed_mm_s, fps, depth_range_mm, nuisance)
    frames, extras = [], []
    for i in range(R.n):
        f, e = R.render_frame(i)
        frames.append(f)
        e["frame"] = i
        e["tip_px"] = R.pose.to_px(R.shapes[i]["pts"][0]).tolist()
        e["tip_mm"] = R.shapes[i]["pts"][0].tolist()
        e["tip_tangent_mm"] = R.shapes[i]["tangent"][0].tolist()
        extras.append(e)
    info = R.info(extras)
    info["_renderer"] = R  # geometry access for tests / tools (not JSON)
    return frames, R.truth_frame(), info


def render_video(out_path, seed, *, n_frames=30, size=(640, 480), px_per_mm=None, speed_mm_s=3.0,
                 fps=30.0, depth_range_mm=(2.0, 17.0), nuisance: dict | None = None):
    """Render an mp4 ('mp4v') at out_path; return (truth DataFrame, info dict)."""
    frames, truth, info = render_frames(seed, n_frames=n_frames, size=size, px_per_mm=px_per_mm,
                                        speed_mm_s=speed_mm_s, fps=fps, depth_range_mm=depth_range_mm,
                                        nuisance=nuisance)
    info.pop("_renderer", None)
    d = os.path.dirname(os.path.abspath(str(out_path)))
    os.makedirs(d, exist_ok=True)
    W, H = int(size[0]), int(size[1])
    wr = cv2.VideoWriter(str(out_path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W, H), True)
    if not wr.isOpened():
        raise RuntimeError(f"cannot open video writer for {out_path}")
    for f in frames:
        wr.write(f)
    wr.release()
    info["video_path"] = str(out_path)
    return truth, info

"""Throughput of the video → angles path on one core (``tympani bench``).

:func:`run_bench` renders a 640×480 synthetic video with :mod:`vision.rendering` (or takes a
given one), then times, with OpenCV limited to one thread,

1. *decode only*: iterate the frames and convert them to grey;
2. *full extraction*: :func:`pipeline.batch.extract_video` (registration, checks, measurement);

and reports frames/s of both, their ratio, the per-stage wall time per frame that the
extraction recorded (``decode``, ``gray``, ``register``, ``check``, ``measure`` and the
measurement's own ``measure.<stage>`` timings when it exposes them) and the peak resident
memory of the process. It is a command, not a test: numbers depend on the machine.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["render_bench_video", "run_bench", "format_bench"]


def render_bench_video(out_path: str | os.PathLike, *, n_frames: int = 200, seed: int = 0) -> Path:
    """Render the benchmark video (640×480 mp4) with :func:`vision.rendering.render_video`.

    Parameters
    ----------
    out_path : str or PathLike
        Target ``.mp4`` file.
    n_frames : int
        Number of frames (the renderer's ``max_frames``/``n_frames``; a default insertion at
        30 frames/s and 1 mm/s has about 480, subsampled evenly to this many).
    seed : int
        Seed of the renderer's random generator.
    """
    import numpy as np

    from vision import rendering

    names = {f.name for f in dataclasses.fields(rendering.VideoSpec)}
    wanted: dict[str, Any] = {"width": 640, "height": 480, "n_frames": int(n_frames), "max_frames": int(n_frames)}
    if "pose" in names and hasattr(rendering, "random_pose"):
        wanted["pose"] = rendering.random_pose(np.random.default_rng(seed), 640, 480)
    spec = rendering.VideoSpec(**{k: v for k, v in wanted.items() if k in names})
    rendering.render_video(Path(out_path), spec, seed=seed)
    return Path(out_path)


def _peak_rss_mib() -> float:
    """Peak resident set size of this process (MiB)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 / (1024.0 if sys.platform == "darwin" else 1.0)  # bytes on macOS, KiB elsewhere


def run_bench(
    *, video: str | os.PathLike | None = None, n_frames: int = 200, seed: int = 0, fps: float | None = None,
    cfg: Any = None,
) -> dict:
    """Time decoding against full extraction on one core.

    Parameters
    ----------
    video : str or PathLike, optional
        Video to time (default: render one, see :func:`render_bench_video`).
    n_frames : int
        Frames of the rendered video.
    seed : int
        Render seed.
    fps : float, optional
        Frame rate (frames/s) for a folder of frames.
    cfg : ExtractConfig, optional
        Extraction settings (default ``ExtractConfig()``).

    Returns
    -------
    dict
        ``video``, ``n_frames``, ``width_px``, ``height_px``, ``decode_fps``, ``extract_fps``
        (frames/s), ``ratio`` (decode_fps / extract_fps), ``stage_ms_per_frame`` (ms),
        ``extract_fps_steady`` (frames/s without registration and its preparation),
        ``stage_s`` (s, whole video), ``n_ok``, ``peak_rss_mib`` (MiB).
    """
    import cv2
    import pandas as pd

    from pipeline.batch import ExtractConfig, extract_video
    from vision.frames import open_frames, to_gray

    cfg = cfg if cfg is not None else ExtractConfig()
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with tempfile.TemporaryDirectory(prefix="tympani-bench-") as tmp:
            path = Path(video) if video is not None else render_bench_video(Path(tmp) / "bench.mp4", n_frames=n_frames, seed=seed)
            source = open_frames(path, fps=fps)
            t0 = time.perf_counter()
            n = 0
            for frame in source:
                to_gray(frame.image)
                n += 1
            decode_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            table, _ = extract_video(path, cfg, fps=fps)
            extract_s = time.perf_counter() - t0
    finally:
        cv2.setNumThreads(threads)
    decode_fps = n / decode_s if decode_s > 0 else float("inf")
    extract_fps = len(table) / extract_s if extract_s > 0 else float("inf")
    timing = dict(table.attrs.get("timing_s", {}))
    stages = {k: 1000.0 * v / max(len(table), 1) for k, v in timing.items()}
    once_s = timing.get("register", 0.0) + timing.get("prepare", 0.0)
    steady_s = extract_s - once_s
    for col in table.columns:  # timings the measurement reports per frame, e.g. time_ms
        if col.endswith("_ms") and pd.api.types.is_numeric_dtype(table[col]) and table[col].notna().any():
            stages[f"measure_frame {col}"] = float(table[col].mean())
    return {
        "video": str(video) if video is not None else f"rendered (seed {seed})",
        "n_frames": n,
        "width_px": source.shape[1],
        "height_px": source.shape[0],
        "decode_fps": decode_fps,
        "extract_fps": extract_fps,
        "ratio": decode_fps / extract_fps if extract_fps > 0 else float("inf"),
        "extract_fps_steady": len(table) / steady_s if steady_s > 0 else float("inf"),
        "stage_s": timing,
        "stage_ms_per_frame": stages,
        "n_ok": int(table["ok"].sum()),
        "peak_rss_mib": _peak_rss_mib(),
    }


def format_bench(result: dict) -> str:
    """The benchmark result as a short human-readable report."""
    lines = [
        f"video          {result['video']}: {result['n_frames']} frames, {result['width_px']}x{result['height_px']} px",
        f"decode only    {result['decode_fps']:8.1f} frames/s (1 core)",
        f"full extract   {result['extract_fps']:8.1f} frames/s (1 core), {result['n_ok']} frames ok",
        f"ratio          {result['ratio']:8.1f} x (decode / extract)",
        f"steady state   {result['extract_fps_steady']:8.1f} frames/s (extraction without the one-off registration)",
        f"{'stage':<24s} {'total s':>9s} {'ms/frame':>9s}",
    ]
    totals = result.get("stage_s", {})
    for stage, ms in sorted(result["stage_ms_per_frame"].items(), key=lambda kv: -kv[1]):
        total = f"{totals[stage]:9.3f}" if stage in totals else f"{'':9s}"
        lines.append(f"  {stage:<22s} {total} {ms:9.3f}")
    lines.append(f"peak memory    {result['peak_rss_mib']:8.1f} MiB (resident, whole process)")
    return "\n".join(lines)

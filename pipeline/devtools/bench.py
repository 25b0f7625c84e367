"""Throughput, per-stage time and memory figures (``tympani bench``).

:func:`run_bench` prints, in one run (each figure with OpenCV limited to one thread):

1. **decode vs extraction** on one video (a rendered 640×480 mp4 with a camera's sensor noise
   by default, see :func:`render_bench_video` and :attr:`BenchConfig.noise_sigma`): frames/s of
   decoding alone (read + grey conversion) and of the full extraction
   (:func:`tympani.pipeline.extract.video.extract_video`: registration, checks, measurement), and their ratio.
   Both are timed ``repeats`` times (5), alternately, and the fastest of each is compared. Each
   round's own ratio (its extraction against the decoding just before it) is listed too, with
   the median of the warm rounds: adjacent timings share the machine's load, so that median
   moves less between runs than the fastest-against-fastest figure does. The first
   extraction in a process also pays one-off start-up costs (imports, first calls), so it is
   reported beside as the cold figure. The process is pinned to one CPU meanwhile
   (:func:`_one_cpu`), since the video decoder runs threads of its own (FFmpeg's, as many as
   there are cores) that OpenCV's thread setting does not reach, and both decode on one thread
   (``decoder_threads=1``), the decoder's faster setting on one core;
2. **per-stage time** (ms/frame) of the warm extraction: decode (+ grey), registration (the
   one-off registration, its measurement plan and the periodic checks) and the measurement's
   stages (survey, edges, centre line, angles);
3. **peak memory** (resident set, MiB) of :func:`tympani.pipeline.extract.batch.process_video` on the video and
   on a ``long_factor`` times longer one (the same frames looped), each in a fresh Python process
   (a peak is per process; see :func:`tympani.pipeline.devtools.memory.peak_rss_mib`), so that streaming shows as two nearly
   equal figures;
4. **diagnosis time** of :func:`tympani.pipeline.diagnosis.analysis.diagnose` on a synthetic 5-speed ×
   ``trials`` dataset (:func:`tympani.pipeline.synthetic.family_a.synthetic_dataset`, no video);
5. **batch throughput** of :func:`tympani.pipeline.extract.batch.extract_batch` on ``batch_videos`` copies of
   the video with 1, 2 and 4 worker processes;
6. **log reading**: seconds and peak memory of reading a ``log_rows``-row ROS force CSV through
   a log format, in a fresh process (:mod:`tympani.pipeline.devtools.logbench`).

A section that fails is reported with its reason; the others still run. It is a command, not a
test: the numbers depend on the machine and its load (the ratio is the most robust figure).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import pickle
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from threadpoolctl import threadpool_limits

from tympani.pipeline.devtools.logbench import bench_log_read, format_log_bench
from tympani.pipeline.devtools.memory import peak_rss_mib
from tympani.vision.errors import one_line

__all__ = ["BenchConfig", "render_bench_video", "loop_video", "run_bench", "format_bench", "SECTIONS"]

#: Optional sections of the bench (the decode/extraction comparison always runs).
SECTIONS: tuple[str, ...] = ("memory", "diagnosis", "workers", "logs")


@dataclass(frozen=True)
class BenchConfig:
    """Sizes of the benchmark.

    Parameters
    ----------
    n_frames : int
        Frames of the rendered video (ignored for a given video).
    size : tuple of int
        ``(width, height)`` (px) of the rendered video. The phantom's scale (px/mm) is drawn
        from ``seed`` and shrunk only if the channel would not fit, so a larger frame shows
        the same phantom, as a camera with a larger sensor would: more pixels to decode, the
        same channel to measure.
    seed : int
        Seed of the renderer and of the synthetic diagnosis dataset.
    noise_sigma : float
        Sensor noise (grey levels, standard deviation) of the rendered video; 2 is the value
        the robustness tests use for a camera's video. Decoding time follows the video's
        bitrate and the measurement's does not, so the ratio depends on it. A noise-free render
        (0) compresses to about 0.6 Mbit/s at 640×480 and 30 frames/s, which no camera gives,
        and decodes unusually fast; 2 gives about 0.8 Mbit/s, 3 about 3 Mbit/s.
    long_factor : int
        The long video of the memory figure has this many times the frames of the short one.
    speeds_mm_s : tuple of float
        Insertion speeds (mm/s) of the diagnosis dataset.
    trials : int
        Trials per speed of the diagnosis dataset (at least 2: the diagnosis measures the scatter
        between repeats).
    workers : tuple of int
        Worker-process counts of the batch throughput figure.
    batch_videos : int
        Videos (copies of the bench video) per batch. A pool's start-up (its processes, their
        imports and first registration) takes 1.5-2 s on 2 cores: with 4 videos of 200 frames
        it outweighed the parallel work in every run, so the default is 8.
    sections : tuple of str
        Which of :data:`SECTIONS` to run.
    log_rows : int
        Rows of the ROS force CSV of the log-reading figure.
    repeats : int
        Times decoding and extraction are each timed, alternately (the fastest of each is
        compared; at least 3 give a median of the warm rounds).
    """

    n_frames: int = 200
    size: tuple[int, int] = (640, 480)
    seed: int = 0
    noise_sigma: float = 2.0
    long_factor: int = 10
    speeds_mm_s: tuple[float, ...] = (0.5, 1.5, 3.0, 5.0, 7.5)
    trials: int = 10
    workers: tuple[int, ...] = (1, 2, 4)
    batch_videos: int = 8
    sections: tuple[str, ...] = SECTIONS
    repeats: int = 5
    log_rows: int = 1_000_000

    def __post_init__(self) -> None:
        if self.n_frames < 1 or self.long_factor < 1 or self.batch_videos < 1 or self.repeats < 1 or self.log_rows < 1:
            raise ValueError("n_frames, long_factor, batch_videos, repeats and log_rows must be >= 1")
        if not self.noise_sigma >= 0:
            raise ValueError(f"noise_sigma must be >= 0 grey levels, not {self.noise_sigma!r}")
        if len(self.size) != 2 or min(self.size) < 64:
            raise ValueError(f"size must be (width, height) with both >= 64 px, not {self.size!r}")
        if self.trials < 2:
            raise ValueError("the diagnosis needs at least 2 trials a speed")
        if not self.workers or min(self.workers) < 1:
            raise ValueError("workers must be a non-empty list of counts >= 1")
        unknown = set(self.sections) - set(SECTIONS)
        if unknown:
            raise ValueError(f"unknown bench section(s) {sorted(unknown)}; choose from {', '.join(SECTIONS)}")

    @classmethod
    def quick(cls, **changes: Any) -> "BenchConfig":
        """Small sizes for a smoke test (about 30 s): 30 frames, 2 trials a speed, 1 and 2
        workers on 2 videos, 2 timings each, a 50,000-row log; ``changes`` override."""
        return dataclasses.replace(cls(n_frames=30, trials=2, workers=(1, 2), batch_videos=2, repeats=2,
                                       log_rows=50_000), **changes)


def render_bench_video(out_path: str | os.PathLike, *, n_frames: int = 200, seed: int = 0,
                       size: tuple[int, int] = (640, 480), noise_sigma: float = 2.0) -> Path:
    """Render the benchmark video (an mp4, 640×480 by default) with :func:`tympani.vision.rendering.render_video`.

    Parameters
    ----------
    out_path : str or PathLike
        Target ``.mp4`` file.
    n_frames : int
        Number of frames (the renderer's ``max_frames``/``n_frames``; a default insertion at
        30 frames/s and 1 mm/s has about 480, subsampled evenly to this many).
    seed : int
        Seed of the renderer's random generator.
    size : tuple of int
        ``(width, height)`` (px); see :attr:`BenchConfig.size`.
    noise_sigma : float
        Sensor noise (grey levels); see :attr:`BenchConfig.noise_sigma`.
    """
    import numpy as np

    from tympani.vision import rendering

    names = {f.name for f in dataclasses.fields(rendering.VideoSpec)}
    width, height = int(size[0]), int(size[1])
    wanted: dict[str, Any] = {"width": width, "height": height, "n_frames": int(n_frames), "max_frames": int(n_frames)}
    if "pose" in names and hasattr(rendering, "random_pose"):
        wanted["pose"] = rendering.random_pose(np.random.default_rng(seed), width, height)
    if noise_sigma and "nuisance" in names:
        wanted["nuisance"] = rendering.Nuisance(noise_sigma=float(noise_sigma))
    spec = rendering.VideoSpec(**{k: v for k, v in wanted.items() if k in names})
    rendering.render_video(Path(out_path), spec, seed=seed)
    return Path(out_path)


def loop_video(src: str | os.PathLike, dst: str | os.PathLike, times: int, *, fps: float | None = None) -> Path:
    """Write ``src``'s frames ``times`` over, one pass after the other, as an mp4 (mp4v).

    Parameters
    ----------
    src : str or PathLike
        Video file or folder of frames.
    dst : str or PathLike
        Target ``.mp4`` file.
    times : int
        Number of passes.
    fps : float, optional
        Frame rate (frames/s) for a folder of frames (default: the source's).

    Returns
    -------
    Path
        ``dst``. Frames are streamed (one pass decoded at a time, none held).
    """
    import cv2

    from tympani.vision.frames import open_frames

    source = open_frames(src, fps=fps)
    height, width = source.shape[:2]
    writer = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"mp4v"), float(source.fps), (width, height))
    if not writer.isOpened():
        raise RuntimeError(f"cannot write {dst}")
    try:
        for _ in range(int(times)):
            for frame in source:
                image = frame.image
                writer.write(image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    finally:
        writer.release()
    return Path(dst)


# --------------------------------------------------------------------------- 1-2: decode vs extraction


@contextlib.contextmanager
def _one_cpu() -> Iterator[int | None]:
    """Pin this process (all its threads) to one CPU for the duration; yields the CPU, or None
    where the platform cannot pin (no ``os.sched_setaffinity``) or refuses to.

    ``cv2.setNumThreads(1)`` and the BLAS limit do not reach the video decoder: OpenCV's FFmpeg
    backend decodes with one thread per core, so on 2 cores decoding alone ran about 1.4x
    faster than on one, and "decode speed on one core" was not on one core. The affinity is
    restored on exit (the worker-count figure must not inherit it).
    """
    getter, setter = getattr(os, "sched_getaffinity", None), getattr(os, "sched_setaffinity", None)
    if getter is None or setter is None:
        yield None
        return
    before = getter(0)
    cpu = min(before)
    try:
        setter(0, {cpu})
    except OSError:
        yield None
        return
    try:
        yield cpu
    finally:
        setter(0, before)


def _decode_s(path: Path, fps: float | None, decoder_threads: int | None = None) -> tuple[int, float, tuple[int, int]]:
    """Frames, wall time (s) and (height, width) of opening ``path`` (as the extraction does,
    which reads its first frame for the size), decoding it (decoder on ``decoder_threads``,
    None: its default) and converting to grey."""
    from tympani.vision.frames import open_frames
    from tympani.vision.greyscale import to_gray

    t0 = time.perf_counter()
    source = open_frames(path, fps=fps, decoder_threads=decoder_threads)
    n = 0
    for frame in source:
        to_gray(frame.image)
        n += 1
    return n, time.perf_counter() - t0, source.shape[:2]


def _extract_s(path: Path, cfg: Any, fps: float | None, steps: Any) -> tuple[Any, float]:
    """The angles table of ``path`` and the wall time (s) of its extraction."""
    from tympani.pipeline.extract.video import extract_video

    t0 = time.perf_counter()
    table, _ = extract_video(path, cfg, fps=fps, steps=steps)
    return table, time.perf_counter() - t0


#: Stage groups of the report: name -> timing keys of :class:`tympani.pipeline.extract.stream.ExtractLog`.
STAGE_GROUPS: dict[str, tuple[str, ...]] = {
    "decode": ("decode", "gray"),
    "registration": ("register", "prepare", "check"),
    "measure": ("measure",),
    "  survey": ("measure.survey",),
    "  edges": ("measure.edges",),
    "  centre_line": ("measure.centre_line",),
    "  angles": ("measure.angles",),
}


def _speed(path: Path, cfg: Any, steps: Any, fps: float | None, repeats: int = 5) -> dict:
    """Section 1-2: decode-only against full extraction, cold and warm, and per-stage times.

    Decoding and extraction are timed ``repeats`` times each, alternately, and the fastest
    run of each is compared (the first extraction, which pays the process's one-off costs, is
    also reported as the cold figure): on shared cores a run's speed follows the machine's
    load, and alternating gives both the same chances of a quiet moment.
    """
    import pandas as pd

    decodes, extracts = [], []
    cfg = dataclasses.replace(cfg, decoder_threads=1)  # the decoder's one-core setting, for both
    with _one_cpu() as cpu:
        for _ in range(max(1, int(repeats))):
            decodes.append(_decode_s(path, fps, cfg.decoder_threads))
            extracts.append(_extract_s(path, cfg, fps, steps))
    # each round's extraction speed as a fraction of the decoding timed just before it; the
    # first round's extraction is the cold one
    rounds = [(len(t) / e) / (k / d) if e > 0 and d > 0 else 0.0 for (k, d, _), (t, e) in zip(decodes, extracts)]
    n, decode_s, shape = min(decodes, key=lambda d: d[1])
    table, cold_s = extracts[0]
    table_b, warm_s = min(extracts, key=lambda e: e[1])  # the best run is the warm figure
    rows = max(len(table_b), 1)
    decode_fps = n / decode_s if decode_s > 0 else float("inf")
    extract_fps = len(table_b) / warm_s if warm_s > 0 else float("inf")
    timing = dict(table_b.attrs.get("timing_s", {}))
    stages = {k: 1000.0 * v / rows for k, v in timing.items()}
    groups = {name: 1000.0 * sum(timing.get(k, 0.0) for k in keys) / rows
              for name, keys in STAGE_GROUPS.items() if any(k in timing for k in keys)}
    accounted = sum(timing.get(k, 0.0) for k in ("decode", "gray", "register", "prepare", "check", "measure"))
    groups["other"] = 1000.0 * max(warm_s - accounted, 0.0) / rows
    once_s = timing.get("register", 0.0) + timing.get("prepare", 0.0)
    for col in table_b.columns:  # timings the measurement reports per frame, e.g. time_ms
        if col.endswith("_ms") and pd.api.types.is_numeric_dtype(table_b[col]) and table_b[col].notna().any():
            stages[f"measure_frame {col}"] = float(table_b[col].mean())
    return {
        "n_frames": n,
        "pinned_cpu": cpu,
        "height_px": shape[0],
        "width_px": shape[1],
        "decode_fps": decode_fps,
        "extract_fps": extract_fps,
        "extract_fps_cold": len(table) / cold_s if cold_s > 0 else float("inf"),
        "ratio": decode_fps / extract_fps if extract_fps > 0 else float("inf"),
        "extract_vs_decode": extract_fps / decode_fps if decode_fps > 0 else 0.0,
        "extract_vs_decode_rounds": rounds,
        # the warm rounds' median (the first round's extraction is cold); None below 2 of them
        "extract_vs_decode_median_warm": statistics.median(rounds[1:]) if len(rounds) >= 3 else None,
        "extract_fps_steady": (steady := len(table_b) / (warm_s - once_s) if warm_s > once_s else float("inf")),
        "ratio_steady": decode_fps / steady if steady > 0 else float("inf"),
        "stage_s": timing,
        "stage_ms_per_frame": stages,
        "stage_groups_ms": groups,
        "n_ok": int(table_b["ok"].sum()),
    }


# --------------------------------------------------------------------------- 3: memory


def _child_rss(argv: list[str]) -> None:
    """Body of the memory subprocess: ``python -m tympani.pipeline.devtools.bench rss VIDEO CFG_PICKLE [FPS]``
    (``CFG_PICKLE``: the pickled ``(ExtractConfig, VisionSteps)``).

    Prints one JSON line: ``import_rss_mib`` (peak after the imports), ``peak_rss_mib`` (after
    :func:`tympani.pipeline.extract.batch.process_video`), ``n_frames`` and ``seconds``.
    """
    import cv2

    from tympani.pipeline.extract.batch import process_video

    cv2.setNumThreads(1)
    video, cfg_path = argv[0], argv[1]
    fps = float(argv[2]) if len(argv) > 2 else None
    with open(cfg_path, "rb") as fh:
        cfg, steps = pickle.load(fh)
    before = peak_rss_mib()
    with tempfile.TemporaryDirectory(prefix="tympani-bench-rss-") as out:
        t0 = time.perf_counter()
        summary = process_video(video, out, cfg, fps=fps, overwrite=True, steps=steps)
        seconds = time.perf_counter() - t0
    print(json.dumps({"import_rss_mib": before, "peak_rss_mib": peak_rss_mib(), "n_frames": int(summary["n_frames"]),
                      "n_ok": int(summary["n_ok"]), "seconds": seconds}))


def _rss_in_subprocess(video: Path, cfg_path: Path, fps: float | None) -> dict:
    """Run :func:`_child_rss` in a fresh interpreter and return its JSON."""
    cmd = [sys.executable, "-m", "tympani.pipeline.devtools.bench", "rss", str(video), str(cfg_path)]
    if fps is not None:
        cmd.append(repr(float(fps)))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise RuntimeError(f"memory subprocess failed: {lines[-1] if lines else 'exit ' + str(done.returncode)}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _memory(path: Path, cfg: Any, steps: Any, fps: float | None, factor: int, tmp: Path) -> dict:
    """Section 3: peak RSS of one extraction of the video and of a ``factor`` times longer one."""
    cfg_path = tmp / "extract_config.pickle"
    with open(cfg_path, "wb") as fh:
        pickle.dump((cfg, steps), fh)
    long_path = loop_video(path, tmp / "bench_long.mp4", factor, fps=fps)
    short = _rss_in_subprocess(path, cfg_path, fps)
    long = _rss_in_subprocess(long_path, cfg_path, fps)
    return {"short": short, "long": long, "factor": factor,
            "growth_mib": long["peak_rss_mib"] - short["peak_rss_mib"]}


# --------------------------------------------------------------------------- 4: diagnosis


def _diagnosis(config: BenchConfig) -> dict:
    """Section 4: time to generate and diagnose a synthetic speeds × trials dataset."""
    import numpy as np

    from tympani.pipeline.diagnosis.analysis import diagnose
    from tympani.pipeline.diagnosis.config import DiagnosisConfig
    from tympani.pipeline.synthetic.family_a import synthetic_dataset

    t0 = time.perf_counter()
    synced, _ = synthetic_dataset(np.random.default_rng(config.seed), "hydrodynamic_lift",
                                  speeds_mm_s=config.speeds_mm_s, trials=config.trials)
    t1 = time.perf_counter()
    result = diagnose(synced, DiagnosisConfig())
    t2 = time.perf_counter()
    return {"speeds": len(config.speeds_mm_s), "trials": config.trials, "rows": len(synced),
            "generate_s": t1 - t0, "diagnose_s": t2 - t1, "verdict": str(getattr(result, "verdict", "")),
            "effect": getattr(result, "effect", None)}


# --------------------------------------------------------------------------- 5: workers


def _workers(path: Path, cfg: Any, steps: Any, fps: float | None, config: BenchConfig, tmp: Path) -> list[dict]:
    """Section 5: :func:`tympani.pipeline.extract.batch.extract_batch` on copies of the video per worker count."""
    from tympani.pipeline.extract.batch import extract_batch
    from tympani.pipeline.extract.manifest import VideoItem

    items = [VideoItem(str(path), trial=f"bench{i:02d}", fps=fps) for i in range(config.batch_videos)]
    out = []
    for workers in config.workers:
        out_dir = tmp / f"batch_w{workers}"
        t0 = time.perf_counter()
        summary = extract_batch(items, out_dir, cfg, workers=workers, overwrite=True, progress=False, fps=fps,
                                steps=steps)
        seconds = time.perf_counter() - t0
        shutil.rmtree(out_dir, ignore_errors=True)
        ok = summary["status"] == "ok"
        frames = int(summary.loc[ok, "n_frames"].sum())
        errors = sorted({str(e) for e in summary.loc[~ok, "error"]})
        out.append({"workers": workers, "videos": len(items), "ok": int(ok.sum()), "frames": frames,
                    "seconds": seconds, "videos_per_s": int(ok.sum()) / seconds, "frames_per_s": frames / seconds,
                    "error": "; ".join(errors)})
    return out


# --------------------------------------------------------------------------- 6: log reading


def _logs(config: BenchConfig, tmp: Path) -> dict:
    """Section 6: read a ``config.log_rows``-row ROS force CSV in a fresh process."""
    return bench_log_read(config.log_rows, seed=config.seed, folder=tmp / "logs")


# --------------------------------------------------------------------------- all


def run_bench(
    *, video: str | os.PathLike | None = None, n_frames: int | None = None, seed: int | None = None,
    fps: float | None = None, cfg: Any = None, config: BenchConfig | None = None,
    log: Callable[[str], None] | None = None, steps: Any = None,
) -> dict:
    """Run the benchmark (see the module docstring) with OpenCV on one thread.

    Parameters
    ----------
    video : str or PathLike, optional
        Video to time (default: render one, see :func:`render_bench_video`).
    n_frames, seed : int, optional
        Override ``config.n_frames`` and ``config.seed``.
    fps : float, optional
        Frame rate (frames/s) for a folder of frames.
    cfg : ExtractConfig, optional
        Extraction settings (default ``ExtractConfig()``).
    config : BenchConfig, optional
        Sizes and sections (default ``BenchConfig()``).
    log : callable, optional
        Called with a short line as each section starts (progress).
    steps : VisionSteps, optional
        The vision functions extraction calls (default ``VisionSteps()``).

    Returns
    -------
    dict
        ``video`` and the decode/extraction figures: ``n_frames``, ``pinned_cpu`` (the CPU they
        ran on, None when the process could not be pinned), ``width_px``, ``height_px``,
        ``decode_fps``, ``extract_fps`` (warm), ``extract_fps_cold`` (frames/s), ``ratio``
        (decode_fps / extract_fps), ``extract_vs_decode`` (extract_fps / decode_fps),
        ``extract_fps_steady`` (frames/s without registration and its preparation),
        ``ratio_steady`` (decode_fps / extract_fps_steady: the ratio of a long video, where the
        one-off registration is negligible),
        ``stage_s`` (s, whole video), ``stage_ms_per_frame`` and ``stage_groups_ms`` (ms/frame),
        ``n_ok``; ``peak_rss_mib`` (MiB, this process); ``memory`` (``short``/``long``: each
        ``import_rss_mib``, ``peak_rss_mib``, ``n_frames``, ``seconds``; ``growth_mib``),
        ``diagnosis`` (``rows``, ``generate_s``, ``diagnose_s``, ``verdict``, ...), ``workers``
        (one dict per count: ``workers``, ``videos``, ``ok``, ``frames``, ``seconds``,
        ``videos_per_s``, ``frames_per_s``, ``error``), ``logs`` (see
        :func:`tympani.pipeline.devtools.logbench.bench_log_read`) for the sections run; ``errors``
        (section -> one-line reason) and ``total_s``.
    """
    import cv2

    from tympani.pipeline.extract.config import ExtractConfig, VisionSteps

    config = config if config is not None else BenchConfig()
    overrides: dict[str, Any] = {k: v for k, v in (("n_frames", n_frames), ("seed", seed)) if v is not None}
    config = dataclasses.replace(config, **overrides)
    cfg = cfg if cfg is not None else ExtractConfig()
    steps = steps if steps is not None else VisionSteps()
    say = log if log is not None else (lambda _line: None)
    t_start = time.perf_counter()
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    # one core also for BLAS: registration's coarse search is one matrix product, which a
    # multi-threaded BLAS on busy shared cores made up to 10x slower (and noisy)
    blas = threadpool_limits(limits=1)
    result: dict[str, Any] = {"errors": {}}
    try:
        with tempfile.TemporaryDirectory(prefix="tympani-bench-") as tmp_name:
            tmp = Path(tmp_name)
            if video is None:
                say(f"rendering a {config.n_frames}-frame {config.size[0]}x{config.size[1]} video")
                path = render_bench_video(tmp / "bench.mp4", n_frames=config.n_frames, seed=config.seed,
                                          size=config.size, noise_sigma=config.noise_sigma)
                result["video"] = f"rendered (seed {config.seed}, sensor noise {config.noise_sigma:g} grey levels)"
            else:
                path = Path(video)
                result["video"] = str(video)
            result["file_bytes"] = path.stat().st_size if path.is_file() else None
            say("decode vs extraction")
            result.update(_speed(path, cfg, steps, fps, config.repeats))
            sections: list[tuple[str, Callable[[], Any]]] = [
                ("memory", lambda: _memory(path, cfg, steps, fps, config.long_factor, tmp)),
                ("diagnosis", lambda: _diagnosis(config)),
                ("workers", lambda: _workers(path, cfg, steps, fps, config, tmp)),
                ("logs", lambda: _logs(config, tmp)),
            ]
            for name, run in sections:
                if name not in config.sections:
                    continue
                say(name)
                try:
                    result[name] = run()
                except Exception as exc:  # a failed section is reported; the others still run
                    result["errors"][name] = one_line(exc)
    finally:
        cv2.setNumThreads(threads)
        blas.restore_original_limits()
    result["peak_rss_mib"] = peak_rss_mib()
    result["total_s"] = time.perf_counter() - t_start
    return result


def format_bench(result: dict) -> str:
    """The benchmark result as a short human-readable report."""
    cpu = result.get("pinned_cpu")
    core = f"1 core: pinned to CPU {cpu}" if cpu is not None else "1 thread each, NOT pinned to a core"
    lines = [
        f"video          {result['video']}: {result['n_frames']} frames, {result['width_px']}x{result['height_px']} px"
        + (f", {result['file_bytes'] / max(result['n_frames'], 1) / 1024:.1f} KiB/frame"
           if result.get("file_bytes") else ""),
        f"decode only    {result['decode_fps']:8.1f} frames/s ({core}; read + grey)",
        f"full extract   {result['extract_fps']:8.1f} frames/s (same core, warm), {result['n_ok']} frames ok; "
        f"{result['extract_fps_cold']:.1f} frames/s cold (first in the process)",
        f"ratio          {result['ratio']:8.2f} x (decode / extract): extraction at "
        f"{100.0 * result['extract_vs_decode']:.0f} % of decode speed",
        *([f"per round      {', '.join(f'{100.0 * r:.0f}' for r in result['extract_vs_decode_rounds'])} % of decode "
           f"speed (each round: decode, then extract; the first extraction is cold)"
           + (f"; median of the warm rounds {100.0 * result['extract_vs_decode_median_warm']:.0f} %"
              if result.get("extract_vs_decode_median_warm") is not None else "")]
          if result.get("extract_vs_decode_rounds") else []),
        f"steady state   {result['extract_fps_steady']:8.1f} frames/s (extraction without the one-off registration)",
        f"ratio steady   {result['ratio_steady']:8.2f} x (decode / steady state): extraction at "
        f"{100.0 / result['ratio_steady']:.0f} % of decode speed after the one-off registration",
        f"{'stage':<24s} {'ms/frame':>9s}",
    ]
    for stage, ms in result.get("stage_groups_ms", {}).items():
        lines.append(f"  {stage:<22s} {ms:9.3f}")
    lines.append(f"{'timed step':<24s} {'total s':>9s} {'ms/frame':>9s}")
    totals = result.get("stage_s", {})
    for stage, ms in sorted(result["stage_ms_per_frame"].items(), key=lambda kv: -kv[1]):
        total = f"{totals[stage]:9.3f}" if stage in totals else f"{'':9s}"
        lines.append(f"  {stage:<22s} {total} {ms:9.3f}")
    lines.append(f"peak memory    {result['peak_rss_mib']:8.1f} MiB (resident, whole bench process)")
    errors = result.get("errors", {})
    if "memory" in result:
        m = result["memory"]
        for key in ("short", "long"):
            r = m[key]
            lines.append(f"  extraction {key:<5s} {r['n_frames']:6d} frames: peak {r['peak_rss_mib']:7.1f} MiB "
                         f"(after imports {r['import_rss_mib']:.1f} MiB), {r['seconds']:.1f} s, fresh process")
        lines.append(f"  long - short   {m['growth_mib']:+7.1f} MiB for {m['factor']}x the frames")
    if "diagnosis" in result:
        d = result["diagnosis"]
        lines.append(f"diagnosis      {d['diagnose_s']:8.2f} s for {d['speeds']} speeds x {d['trials']} trials "
                     f"({d['rows']} rows; generated in {d['generate_s']:.2f} s; verdict {d['verdict']})")
    if "workers" in result:
        lines.append(f"{'batch workers':<14s} {'videos':>6s} {'s':>7s} {'videos/s':>9s} {'frames/s':>9s}")
        for w in result["workers"]:
            note = f"  {w['videos'] - w['ok']} failed: {w['error']}" if w["ok"] < w["videos"] else ""
            lines.append(f"  {w['workers']:<12d} {w['videos']:6d} {w['seconds']:7.2f} {w['videos_per_s']:9.2f} "
                         f"{w['frames_per_s']:9.1f}{note}")
    if "logs" in result:
        lines.append(format_log_bench(result["logs"]))
    for name, reason in errors.items():
        lines.append(f"{name:<14s} FAILED: {reason}")
    lines.append(f"bench total    {result['total_s']:8.1f} s")
    return "\n".join(lines)


if __name__ == "__main__":  # the memory figure's subprocess (see _rss_in_subprocess)
    if len(sys.argv) >= 4 and sys.argv[1] == "rss":
        _child_rss(sys.argv[2:])
    else:
        sys.exit("usage: python -m tympani.pipeline.devtools.bench rss VIDEO CONFIG_PICKLE [FPS]")

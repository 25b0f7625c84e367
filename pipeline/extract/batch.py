"""Many videos → angles tables: :func:`extract_batch`, and its unit of work, :func:`process_video`.

The layers follow trackpy's ``locate``/``batch``:

- :func:`~tympani.pipeline.extract.stream.measure_frames` streams a
  :class:`~tympani.vision.frames.FrameSource` through registration and measurement, one
  :class:`~tympani.pipeline.extract.stream.MeasuredFrame` at a time;
- :func:`~tympani.pipeline.extract.video.extract_video` collects that stream into the angles table
  (docs/file-formats.md);
- :func:`process_video` is the unit of work: it takes a *path*, opens it itself (so it runs in
  a worker process or on a Dask worker), writes ``<trial>.angles.csv``,
  ``<trial>.registration.json`` and ``<trial>.provenance.json`` atomically, and skips videos
  whose outputs exist (resume) unless told to overwrite;
- :func:`extract_batch` maps :func:`process_video` over videos with a pluggable executor (this
  process, a forkserver process pool, or a ``dask.distributed.Client`` whose workers share the
  output folder) and returns one summary row per video; a failing video never stops the others.

The settings (:class:`~tympani.pipeline.extract.config.ExtractConfig`) and the vision functions
(:class:`~tympani.pipeline.extract.config.VisionSteps`) are pickled to the workers.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, Iterable, Iterator

import pandas as pd

from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.pipeline.extract.manifest import VideoItem, video_items
from tympani.pipeline.extract.records import refusals, refusals_text
from tympani.pipeline.extract.video import extract_video, measured_counts, trial_name
from tympani.pipeline.io import atomic_write_csv, atomic_write_json, check_writable_dir, provenance, remove_stale_temps
from tympani.vision.errors import InputError, is_input_error, one_line

__all__ = [
    "SUMMARY_COLUMNS",
    "output_paths",
    "process_video",
    "extract_batch",
    "is_dask_client",
]

#: Columns of the per-video summary returned by :func:`extract_batch`.
SUMMARY_COLUMNS: tuple[str, ...] = (
    "trial", "path", "status", "n_frames", "n_ok", "refused", "error", "error_kind", "warnings", "n_registrations",
    "seconds",
)


def output_paths(out_dir: str | os.PathLike, trial: str) -> dict[str, Path]:
    """Files :func:`process_video` writes for ``trial`` in ``out_dir``:
    ``angles`` (CSV), ``registration`` (JSON), ``provenance`` (JSON)."""
    out = Path(out_dir)
    return {
        "angles": out / f"{trial}.angles.csv",
        "registration": out / f"{trial}.registration.json",
        "provenance": out / f"{trial}.provenance.json",
    }


def _summary(trial: str, path: Path, status: str, **values: Any) -> dict:
    row: dict[str, Any] = {c: None for c in SUMMARY_COLUMNS}
    row.update(trial=trial, path=str(path), status=status, refused="", error="", error_kind="", warnings="")
    row.update(values)
    return row


def _refused_before(provenance_path: Path) -> dict[str, int]:
    """The ``refused`` counts a finished video's provenance holds (empty when it holds none)."""
    try:
        counts = json.loads(provenance_path.read_text()).get("refused", {})
        return {str(k): int(v) for k, v in counts.items()}
    except (OSError, ValueError, TypeError, AttributeError):  # unreadable, or not as written: say nothing
        return {}


def process_video(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    fps: float | None = None,
    trial: str | None = None,
    overwrite: bool = False,
    progress: bool = False,
    steps: VisionSteps = VisionSteps(),
) -> dict:
    """Extract one video's angles and write them, with registration and provenance, to files.

    Writes ``<trial>.angles.csv``, ``<trial>.registration.json`` (the first registration's
    pose and fit keys, docs/file-formats.md, plus ``registrations``: every registration used,
    with the frame it started at, and ``lost``: the spans in which the registration was lost) and
    ``<trial>.provenance.json`` (written last: its presence marks a finished video) in
    ``out_dir``, each atomically. If interrupted while writing, the files written so far in this
    call are removed again.

    Parameters
    ----------
    path : str or PathLike
        Video file or folder of frames (opened here, so this runs in any worker process).
    out_dir : str or PathLike
        Output folder (created if needed).
    cfg : ExtractConfig
        Settings.
    fps : float, optional
        Frame rate (frames/s); see :func:`~tympani.pipeline.extract.video.extract_video`.
    trial : str, optional
        Trial name (default: file stem); names the output files.
    overwrite : bool
        Redo a video whose three outputs exist (default: skip it, so reruns resume).
    progress : bool
        Per-frame progress bar on stderr.
    steps : VisionSteps
        The vision functions (default: :mod:`tympani.vision.registration`'s and :mod:`tympani.vision.angles`'s).

    Returns
    -------
    dict
        A summary row (:data:`SUMMARY_COLUMNS`) with ``status`` "ok" or "skipped".

    Raises
    ------
    InputError
        Bad input or failed registration. Other exceptions are bugs.
    """
    name = trial_name(path, trial)
    path = Path(path)
    files = output_paths(out_dir, name)
    if not overwrite and all(f.exists() for f in files.values()):
        counts = measured_counts(files["angles"])
        if counts is not None:
            return _summary(name, path, "skipped", n_frames=counts[0], n_ok=counts[1],
                            refused=refusals_text(_refused_before(files["provenance"])), seconds=0.0)
    t0 = time.perf_counter()
    table, registration = extract_video(path, cfg, fps=fps, trial=name, progress=progress, steps=steps)
    registrations = table.attrs["registrations"]
    warnings = list(table.attrs["warnings"])
    n_ok = int(table["ok"].sum())
    refused = refusals(table.loc[~table["ok"], "reason"].astype(str))
    seconds = time.perf_counter() - t0
    reg_record = {**registration.to_dict(), "registrations": registrations, "lost": table.attrs["lost"],
                  "array_width_ratio": table.attrs["array_width"]}
    prov = provenance(
        path,
        {"extract": cfg, "fps": fps, "trial": name},
        command="extract",
        source=table.attrs["source"],
        outputs={k: f.name for k, f in files.items()},
        n_frames=len(table),
        n_ok=n_ok,
        refused=refused,
        checks=[{"frame": f, "residual_px": r} for f, r in table.attrs["checks"]],
        warnings=warnings,
        timing_s={**table.attrs["timing_s"], "total": seconds},
    )
    for f in files.values():  # left by a run killed outright while writing; never read
        remove_stale_temps(f)
    written: list[Path] = []
    try:
        atomic_write_csv(files["angles"], table)
        written.append(files["angles"])
        atomic_write_json(files["registration"], reg_record)
        written.append(files["registration"])
        atomic_write_json(files["provenance"], prov)
    except BaseException:
        for f in written:
            f.unlink(missing_ok=True)
        raise
    return _summary(
        name, path, "ok",
        n_frames=len(table), n_ok=n_ok, refused=refusals_text(refused), warnings="; ".join(warnings),
        n_registrations=len(registrations), seconds=round(seconds, 3),
    )


# --------------------------------------------------------------------------- many videos

# Set in worker processes of a pool that extract_batch owns (by _init_worker): once the main
# process is interrupted, queued videos are skipped instead of started.
_CANCEL_EVENT: Any = None


def _run_one(item: VideoItem, trial: str, out_dir: str, cfg: ExtractConfig, fps: float | None,
             overwrite: bool, single_thread: bool, progress: bool, steps: VisionSteps = VisionSteps()) -> dict:
    """Worker body: :func:`process_video` with every failure turned into a summary row."""
    if _CANCEL_EVENT is not None and _CANCEL_EVENT.is_set():
        return _summary(trial, Path(item.path), "failed", error="cancelled (interrupted)", error_kind="cancelled")
    blas = contextlib.nullcontext()
    if single_thread:  # one worker a core: OpenCV, BLAS and the decoder (unless told otherwise) on one thread
        import cv2
        from threadpoolctl import threadpool_limits

        cv2.setNumThreads(1)
        blas = threadpool_limits(limits=1)
        if cfg.decoder_threads is None:
            cfg = dataclasses.replace(cfg, decoder_threads=1)
    t0 = time.perf_counter()
    try:
        with blas:
            return process_video(item.path, out_dir, cfg, fps=item.fps if item.fps is not None else fps,
                                 trial=trial, overwrite=overwrite, progress=progress, steps=steps)
    except Exception as exc:
        return _summary(trial, Path(item.path), "failed", error=one_line(exc),
                        error_kind="input" if is_input_error(exc) else "error",
                        seconds=round(time.perf_counter() - t0, 3))


def _init_worker(cancel_event: Any) -> None:
    global _CANCEL_EVENT
    import cv2

    cv2.setNumThreads(1)
    _CANCEL_EVENT = cancel_event


def _pool_context():
    """Start method of the worker processes: forkserver, not fork — a forked child of a process
    whose OpenCV or BLAS threads hold locks (e.g. after rendering in the same process) can hang."""
    import multiprocessing

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["numpy", "cv2", "pandas", "tympani.pipeline.extract.batch"])
    return ctx


def is_dask_client(executor: Any) -> bool:
    """Whether ``executor`` is a ``dask.distributed.Client`` (checked without importing Dask)."""
    return type(executor).__module__.split(".")[0] == "distributed" and hasattr(executor, "scheduler_info")


def _submit(executor: Any, fn: Any, *args: Any) -> Any:
    """``executor.submit(fn, *args)``; a Dask client gets ``pure=False`` (always run, even when
    a task with the same arguments is still held by the cluster, e.g. after ``--overwrite``)."""
    if is_dask_client(executor):
        return executor.submit(fn, *args, pure=False)
    return executor.submit(fn, *args)


def _completed(futures: list) -> Iterator:
    """Futures in completion order for ``concurrent.futures`` and Dask futures, else in order
    (any other future's ``result()`` simply blocks)."""
    if futures and all(isinstance(f, cf.Future) for f in futures):
        yield from cf.as_completed(futures)
    elif futures and type(futures[0]).__module__.split(".")[0] == "distributed":
        from distributed import as_completed

        yield from as_completed(futures, loop=futures[0].client.loop)  # the client need not be the default
    else:
        yield from futures


def _for_worker(item: VideoItem) -> VideoItem:
    """``item`` with an absolute path: a worker may run in another folder (forkserver, Dask)."""
    return VideoItem(os.path.abspath(item.path), item.trial, item.fps)


def extract_batch(
    items: Iterable[str | os.PathLike | VideoItem | dict] | pd.DataFrame,
    out_dir: str | os.PathLike,
    cfg: ExtractConfig,
    *,
    workers: int = 1,
    executor: Any = None,
    overwrite: bool = False,
    progress: bool = True,
    fps: float | None = None,
    steps: VisionSteps = VisionSteps(),
) -> pd.DataFrame:
    """Extract the angles of many videos; a failing video is recorded and the rest go on.

    Parameters
    ----------
    items : iterable or DataFrame
        Video paths, :class:`~tympani.pipeline.extract.manifest.VideoItem` s, dicts with ``path`` (or ``video``), ``trial``,
        ``fps``, or a manifest DataFrame (:func:`~tympani.pipeline.extract.manifest.read_manifest`;
        rows without a video are ignored); see :func:`~tympani.pipeline.extract.manifest.video_items`.
    out_dir : str or PathLike
        Output folder.
    cfg : ExtractConfig
        Settings (pickled to workers).
    workers : int
        Processes to use when no ``executor`` is given; 1 runs in this process.
    executor : object, optional
        Anything with ``submit(fn, *args) -> future`` whose futures have ``result()``:
        ``concurrent.futures`` executors, a ``dask.distributed.Client`` (tasks submitted with
        ``pure=False``), ... It is not shut down here. Its workers get ``cv2.setNumThreads(1)``
        and absolute paths; they must be able to import tympani and to read the videos and
        write ``out_dir`` under the same paths as this process (a shared file system).
    overwrite : bool
        Redo videos whose outputs exist.
    progress : bool
        Progress bar (videos; frames too when running serially) on stderr.
    fps : float, optional
        Frame rate (frames/s) for items that do not give their own.
    steps : VisionSteps
        The vision functions (default: :mod:`tympani.vision.registration`'s and :mod:`tympani.vision.angles`'s;
        pickled to workers, so module-level functions).

    Returns
    -------
    DataFrame
        One row per video in input order, columns :data:`SUMMARY_COLUMNS`: ``status`` is
        "ok", "skipped" or "failed"; ``error`` a one-line reason; ``error_kind`` "input" (bad
        input, failed registration) or "error" (a bug or a crashed worker).

    Notes
    -----
    On KeyboardInterrupt with a pool of its own, videos not yet started are skipped, the
    running ones are interrupted (Ctrl-C reaches the whole process group) or, when only this
    process got the signal, finish; then the interrupt is re-raised. With a given executor the
    futures not yet finished are cancelled. Outputs are written atomically, so no video is left
    with half-written files, and a rerun redoes exactly the videos that did not finish.

    Raises
    ------
    InputError
        Two videos would get the same trial name (their outputs would collide).
    OutputError
        ``out_dir`` cannot be created or written (checked before any video is started).
    """
    videos = video_items(items)
    trials: dict[str, str] = {}
    names = []
    for item in videos:
        name = trial_name(item.path, item.trial)
        if name in trials:
            raise InputError(item.path, f"trial name {name!r} is also used by {trials[name]}; give distinct trial names")
        trials[name] = item.path
        names.append(name)
    out = os.fspath(out_dir)
    check_writable_dir(out)
    results: list[dict | None] = [None] * len(videos)
    from tqdm import tqdm

    with tqdm(total=len(videos), unit="video", desc="extract", file=sys.stderr, disable=not progress,
              dynamic_ncols=True) as bar:
        if executor is None and workers <= 1:
            for i, (item, name) in enumerate(zip(videos, names)):
                results[i] = _run_one(item, name, out, cfg, fps, overwrite, False, progress, steps)
                bar.update(1)
        else:
            own = executor is None
            cancel = None
            if own:
                ctx = _pool_context()
                cancel = ctx.Event()
                pool = cf.ProcessPoolExecutor(max_workers=int(workers), mp_context=ctx, initializer=_init_worker,
                                              initargs=(cancel,))
            else:
                pool = executor
            futures: list = []
            try:
                out_abs = os.path.abspath(out)
                futures = [_submit(pool, _run_one, _for_worker(item), name, out_abs, cfg, fps, overwrite, True, False,
                                   steps)
                           for item, name in zip(videos, names)]
                index = {id(f): i for i, f in enumerate(futures)}
                for fut in _completed(futures):
                    i = index[id(fut)]
                    try:
                        results[i] = {**fut.result(), "path": str(Path(videos[i].path))}
                    except Exception as exc:  # the worker itself died (crash, pickling, ...)
                        results[i] = _summary(names[i], Path(videos[i].path), "failed",
                                              error=one_line(exc), error_kind="error")
                    bar.update(1)
            except KeyboardInterrupt:
                if own:  # skip queued videos; running ones stop (Ctrl-C reaches them) or finish whole
                    assert cancel is not None  # made with the pool of our own
                    cancel.set()
                    pool.shutdown(wait=True, cancel_futures=True)
                    own = False
                else:  # a given executor (Dask, ...): drop what has not run yet
                    for fut in futures:
                        fut.cancel()
                raise
            finally:
                if own:
                    pool.shutdown(wait=True)
    return pd.DataFrame(results, columns=list(SUMMARY_COLUMNS))

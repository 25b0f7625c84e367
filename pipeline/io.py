"""Output files that are never half written, and the provenance sidecar beside them.

Every writer here puts the content in a temporary file in the target's own folder, flushes and
``fsync``\\ s it, then renames it over the target with :func:`os.replace` (atomic on POSIX and
Windows within one file system) and finally syncs the folder entry. A crash or Ctrl-C at any
point leaves either the old file or the new one, plus at worst a hidden ``.<name>.*.tmp`` file
that is removed when the failure is seen by Python (:func:`remove_stale_temps` clears those left
by a killed process).

A write that the operating system refuses (read-only folder, permission denied, disk full, ...)
raises :class:`OutputError`, an :class:`~tympani.vision.errors.InputError` that names the file the
command could not write: the command line reports it in one line with exit status 2.

The project's CSV inputs (manifests, force logs, synced tables) may carry ``#`` comment lines:
:func:`data_lines` is the one rule that skips them (and blank lines) and keeps every line's number;
:func:`csv_records` parses what it keeps.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime as _dt
import errno
import hashlib
import json
import math
import os
import platform
import secrets
import sys
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

import numpy as np
import pandas as pd

from tympani.vision.errors import InputError

__all__ = [
    "OutputError",
    "output_error",
    "check_writable_dir",
    "remove_stale_temps",
    "atomic_open",
    "atomic_write_bytes",
    "atomic_write_text",
    "atomic_write_json",
    "atomic_write_csv",
    "to_jsonable",
    "content_hash",
    "tool_version",
    "provenance",
    "data_lines",
    "csv_records",
    "HASH_CHUNK_BYTES",
]

#: Bytes hashed at each end of a file by :func:`content_hash` (1 MiB).
HASH_CHUNK_BYTES = 1 << 20


# --------------------------------------------------------------------------- atomic writes


class OutputError(InputError, OSError):
    """An output file or folder that cannot be written (exit status 2, like bad input).

    It is both an :class:`~tympani.vision.errors.InputError` (one line naming the file) and an
    ``OSError`` (so code that catches ``OSError`` around writes still does).

    Parameters
    ----------
    path : str or PathLike
        The file or folder that could not be written.
    problem : str
        One line, e.g. ``"cannot write (No space left on device)"``.
    errno : int, optional
        The operating system's error number (``errno.ENOSPC``, ``errno.EACCES``, ...).
    """

    def __init__(self, path: str | os.PathLike, problem: str, errno: int | None = None) -> None:
        InputError.__init__(self, path, problem)
        self.errno = errno

    def __reduce__(self):  # keep errno across worker processes
        return (type(self), (self.path, self.problem, self.errno))


def output_error(path: str | os.PathLike, exc: OSError, what: str = "cannot write") -> OutputError:
    """An :class:`OutputError` for ``path`` from the ``OSError`` that refused the write.

    Parameters
    ----------
    path : str or PathLike
        The file or folder being written.
    exc : OSError
        What the operating system said.
    what : str
        The action that failed ("cannot write", "cannot create folder", ...).
    """
    reason = exc.strerror or (errno.errorcode.get(exc.errno or 0) if exc.errno else None) or str(exc) or type(exc).__name__
    return OutputError(path, f"{what} ({reason})", exc.errno)


def check_writable_dir(folder: str | os.PathLike) -> Path:
    """Create ``folder`` if needed and check that files can be created in it.

    The check really creates (and removes) a temporary file, so it also catches read-only
    mounts and, for root, what permission bits would not show.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    OutputError
        The folder cannot be created or written.
    """
    out = Path(folder)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(out, exc, "cannot create the output folder") from exc
    if not out.is_dir():
        raise OutputError(out, "output folder is not a folder", errno.ENOTDIR)
    try:
        fd, tmp = _create_temp(out, "write-check")
    except OSError as exc:
        raise output_error(out, exc, "output folder is not writable") from exc
    os.close(fd)
    with contextlib.suppress(OSError):
        tmp.unlink()
    return out


def remove_stale_temps(path: str | os.PathLike) -> list[Path]:
    """Remove the hidden temporary files an interrupted atomic write of ``path`` left behind.

    Only a process killed outright (SIGKILL, power loss) leaves them; they are never read.
    Call this only when no other process is writing ``path``.

    Returns
    -------
    list of Path
        The files removed.
    """
    import glob

    target = Path(path)
    removed = []
    for tmp in target.parent.glob(f".{glob.escape(target.name)}.*.tmp"):
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed.append(tmp)
    return removed


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every platform allows it)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _create_temp(folder: Path, name: str) -> tuple[int, Path]:
    """Create a new hidden temporary file beside ``name`` in ``folder``.

    ``os.open`` with mode 0o666 lets the process umask decide the permissions, so the final
    file gets the same mode as a plainly written one (``mkstemp`` would force 0600).
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = folder / f".{name}.{secrets.token_hex(4)}.tmp"
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"could not create a temporary file in {folder}")


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", *, encoding: str | None = "utf-8", newline: str | None = None) -> Iterator[IO]:
    """Open a temporary file that replaces ``path`` only when the ``with`` block succeeds.

    Parameters
    ----------
    path : str or PathLike
        Final file. Its folder is created if needed.
    mode : {"w", "wb"}
        Text or binary.
    encoding : str, optional
        Text encoding (ignored for ``"wb"``).
    newline : str, optional
        As for :func:`open`.

    Yields
    ------
    file object
        Write to it; on normal exit it is flushed, fsynced and renamed over ``path``. On any
        exception (KeyboardInterrupt included) it is deleted and ``path`` is untouched.

    Raises
    ------
    OutputError
        The folder, the temporary file or the rename was refused, or a write failed (an
        ``OSError`` raised inside the block, e.g. disk full, becomes one too).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', not {mode!r}")
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _create_temp(target.parent, target.name)
    except OSError as exc:
        raise output_error(target, exc) from exc
    try:
        binary = mode == "wb"
        with os.fdopen(fd, mode, encoding=None if binary else encoding, newline=None if binary else newline) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and not isinstance(exc, InputError):
            raise output_error(target, exc) from exc
        raise
    _fsync_dir(target.parent)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_open(path, "w", encoding=encoding, newline="") as fh:
        fh.write(text)
    return Path(path)


def to_jsonable(obj: Any) -> Any:
    """A JSON-compatible copy of ``obj``.

    Dataclasses become dicts of their fields, numpy scalars and arrays become Python numbers and
    lists, paths become strings, non-finite floats become ``None`` (JSON has no NaN), sets and
    tuples become lists; anything else unknown becomes its ``repr``.
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in obj]
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return to_jsonable(obj.to_dict())
    return repr(obj)


def atomic_write_json(path: str | os.PathLike, obj: Any, *, indent: int = 2) -> Path:
    """Write ``obj`` (made JSON-compatible by :func:`to_jsonable`) to ``path`` atomically."""
    text = json.dumps(to_jsonable(obj), indent=indent, allow_nan=False, ensure_ascii=False)
    return atomic_write_text(path, text + "\n")


def atomic_write_csv(path: str | os.PathLike, df: pd.DataFrame, *, index: bool = False, **kwargs: Any) -> Path:
    """Write a DataFrame as CSV atomically.

    Boolean columns are written as ``true``/``false`` (docs/file-formats.md), missing values as empty
    fields. Extra keyword arguments go to :meth:`pandas.DataFrame.to_csv`.
    """
    out = df.copy()
    for col in out.columns:
        if out[col].dtype == bool:
            out[col] = np.where(out[col].to_numpy(), "true", "false")
    kwargs.setdefault("lineterminator", "\n")
    with atomic_open(path, "w", newline="") as fh:
        out.to_csv(fh, index=index, **kwargs)
    return Path(path)


# --------------------------------------------------------------------------- provenance


def content_hash(path: str | os.PathLike, *, chunk_bytes: int = HASH_CHUNK_BYTES) -> str:
    """A fast fingerprint of a file or a folder of frames.

    For a file: ``"sha256-ends:<size>:<hex>"``, the SHA-256 of the size, the first and the last
    ``chunk_bytes`` bytes (the whole file when it is smaller than two chunks). It changes when a
    video is re-encoded, cut or replaced, but not necessarily when bytes in the middle of a large
    file change; it is a fingerprint, not a proof of integrity. For a folder: the SHA-256 of
    the sorted file names with their sizes plus the fingerprints of the first and last file
    (``"sha256-folder:<n files>:<hex>"``).

    Parameters
    ----------
    path : str or PathLike
        File or folder.
    chunk_bytes : int
        Bytes hashed at each end of a file.
    """
    p = Path(path)
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.is_file() and not f.name.startswith("."))
        h = hashlib.sha256()
        for f in files:
            h.update(f"{f.name}\0{f.stat().st_size}\n".encode())
        for f in files[:1] + files[-1:]:
            h.update(content_hash(f, chunk_bytes=chunk_bytes).encode())
        return f"sha256-folder:{len(files)}:{h.hexdigest()}"
    size = p.stat().st_size
    h = hashlib.sha256(str(size).encode() + b"\0")
    with open(p, "rb") as fh:
        if size <= 2 * chunk_bytes:
            h.update(fh.read())
        else:
            h.update(fh.read(chunk_bytes))
            fh.seek(size - chunk_bytes)
            h.update(fh.read(chunk_bytes))
    return f"sha256-ends:{size}:{h.hexdigest()}"


def tool_version() -> str:
    """The installed tympani version, or ``"0+unknown"`` when run from an uninstalled tree."""
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:  # pragma: no cover
        return "0+unknown"
    try:
        return version("tympani")
    except PackageNotFoundError:
        return "0+unknown"


def provenance(input_path: str | os.PathLike, params: dict, **extra: Any) -> dict:
    """The provenance record written beside an output.

    Parameters
    ----------
    input_path : str or PathLike
        The input the output was computed from (file or folder).
    params : dict
        The parameters of the computation (dataclasses and numpy values are converted).
    **extra
        Further JSON-compatible entries (e.g. ``source=``, ``warnings=``).

    Returns
    -------
    dict
        ``tool``, ``version``, ``created_utc`` (ISO 8601), ``input`` (``path`` absolute,
        ``hash`` from :func:`content_hash`, ``size_bytes`` for files), ``params``,
        ``environment`` (python, numpy, pandas, opencv, platform) and ``extra``'s keys.
    """
    import cv2  # local: keep this module cheap to import

    p = Path(input_path)
    info: dict[str, Any] = {"path": str(p.resolve())}
    if p.exists():
        info["hash"] = content_hash(p)
        if p.is_file():
            info["size_bytes"] = p.stat().st_size
    record = {
        "tool": "tympani",
        "version": tool_version(),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "input": info,
        "params": to_jsonable(params),
        "environment": {
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "pandas": pd.__version__,
            "opencv": cv2.__version__,
            "platform": platform.platform(),
        },
    }
    record.update(to_jsonable(extra))
    return record


# --------------------------------------------------------------------------- reading


def data_lines(lines: Iterable[str], comments: list[str] | None = None) -> Iterator[tuple[int, str]]:
    """The lines of a CSV text that are neither blank nor ``#`` comments, with their numbers.

    A line is a comment when its first non-blank character is ``#``; a ``#`` anywhere else is
    data. The lines are read one at a time (a stream of any length keeps one line in memory).

    Parameters
    ----------
    lines : iterable of str
        The text's lines: a file opened with ``newline=""``, or ``str.splitlines()``.
    comments : list of str, optional
        Receives the text of every comment line after its ``#``, stripped, as it is passed.

    Yields
    ------
    tuple of (int, str)
        The 1-based line number and the line as given (line ending included, if any).
    """
    for lineno, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if comments is not None:
                comments.append(stripped[1:].strip())
            continue
        yield lineno, line


def csv_records(lines: Iterable[str], comments: list[str] | None = None) -> tuple[list[int], list[list[str]]]:
    """The records of a CSV text without its blank lines and ``#`` comment lines.

    The lines kept are those of :func:`data_lines`: a ``#`` anywhere but at the start of a line
    (in a field, quoted or not) is data. (pandas' ``read_csv(comment="#")`` would also cut a line
    at an unquoted ``#`` and lose the line numbers, so it is not used.)

    Parameters
    ----------
    lines : iterable of str
        The text's lines: a file opened with ``newline=""``, or ``str.splitlines()``.
    comments : list of str, optional
        Receives the text of every comment line after its ``#``, stripped, in file order.

    Returns
    -------
    line_numbers : list of int
        1-based line number of every kept line, in file order (the header's first).
    records : list of list of str
        The kept lines parsed by :func:`csv.reader` (fields not stripped); one a kept line
        unless a quoted field spans lines.
    """
    kept = list(data_lines(lines, comments))
    return [k for k, _ in kept], list(csv.reader(line for _, line in kept))

"""Lazy frame sources: a video file or a folder of still frames, decoded on demand.

``open_frames(path, fps=...)`` returns a :class:`FrameSource`. Iterating it streams
:class:`Frame` objects (index, time in s, image) one at a time, so a video is never held in
memory whole; ``source[i]`` fetches a single frame; ``len(source)`` is the number of frames
(an estimate for videos until they have been read once, see :meth:`VideoFrames.__len__`).

A source holds no open file handle between calls: each iteration opens its own decoder and
closes it at the end. A source can therefore be pickled and iterated in a worker process, and
iterated twice.

Video time stamps
-----------------
For a video, ``time_s`` is the decoder's presentation time stamp (``CAP_PROP_POS_MSEC``)
relative to frame 0 when it is *sane*: finite, strictly increasing, and within
``0.5 s + 10 %`` of ``index / fps``. Otherwise the frame gets the previous frame's time plus
``1 / fps`` and the source records a warning. Passing ``fps`` for a video overrides the file's
clock altogether (``time_s = index / fps``), for footage stored at another rate than it was
recorded (high-speed cameras). Frames are counted as decoded; the container's frame count is only
used for :func:`len` before a first full pass and to detect truncated files.

Damaged input
-------------
- missing path, a path that is neither a folder nor a video OpenCV can open (including an mp4 cut
  before its index), or a video whose first frame does not decode: :class:`InputError` when
  the source is opened;
- a video that stops decoding early (truncated or corrupt in the middle): iteration yields the
  frames that decode, then stops and appends a message to :attr:`FrameSource.warnings`;
- a folder without PNG/JPEG files, without ``fps``, with an unreadable image or with images of
  different sizes: :class:`InputError` naming the offending file. Frames are *not* resized: a
  size change in a folder means frames from different recordings were mixed.

Lens distortion
---------------
The registration's frame model is a similarity between phantom and image. A lens that bends
straight lines breaks it (see docs/known-limits.md). :class:`LensCalibration` holds OpenCV's
camera model (read from a JSON file): :func:`undistorter` maps a frame back to the ideal pinhole
image, with the same camera matrix so that scale and centre stay those of the recording (what
registration and checks see), and :meth:`LensCalibration.distort_points` sends ideal points to
where the lens records them (how the measurement samples the recorded frames directly).
"""

from __future__ import annotations

import abc
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from tympani.vision.errors import InputError

__all__ = [
    "Frame",
    "FrameSource",
    "VideoFrames",
    "FolderFrames",
    "IMAGE_SUFFIXES",
    "open_frames",
    "check_decoder_threads",
    "LensCalibration",
    "undistorter",
]

#: File name endings (lower case) of the still frames a folder source reads.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg")

_MAX_FPS = 1.0e5  # frames/s; anything above is a broken header, not a camera


def _video_backend() -> int:
    """FFmpeg when this OpenCV build has it, else whatever OpenCV picks.

    Only FFmpeg is asked (not the other backends in turn): OpenCV's own AVI/MJPEG reader prints
    parser messages to stderr on damaged files, which would spoil one-line error reports.
    """
    try:
        from cv2 import videoio_registry

        if videoio_registry.hasBackend(cv2.CAP_FFMPEG):
            return cv2.CAP_FFMPEG
    except Exception:  # pragma: no cover - very old or unusual builds
        pass
    return cv2.CAP_ANY


@dataclass(frozen=True)
class Frame:
    """One decoded frame.

    Parameters
    ----------
    index : int
        Position in the source, counting decoded frames from 0.
    time_s : float
        Time (s) of the frame relative to frame 0.
    image : ndarray
        The image as decoded: ``(h, w, 3)`` BGR or ``(h, w)`` grey, ``uint8``.
    """

    index: int
    time_s: float
    image: np.ndarray


# --------------------------------------------------------------------------- helpers


def _check_fps(path: Path, fps: float | None) -> float | None:
    """Validate a user-supplied frame rate (frames/s); ``None`` passes through."""
    if fps is None:
        return None
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise InputError(path, f"invalid frame rate {fps!r} (frames per second expected)") from None
    if not (math.isfinite(value) and 0.0 < value <= _MAX_FPS):
        raise InputError(path, f"invalid frame rate {fps!r} (must be a positive number of frames per second)")
    return value


def check_decoder_threads(decoder_threads: int | None) -> int | None:
    """``decoder_threads`` (a decoder thread count: an integer >= 1, or None for the decoder's
    default) as an int or None.

    Raises
    ------
    ValueError
        Anything else.
    """
    if decoder_threads is None:
        return None
    if int(decoder_threads) != decoder_threads or decoder_threads < 1:
        raise ValueError(f"decoder_threads must be an integer >= 1 or None, not {decoder_threads!r}")
    return int(decoder_threads)


def _natural_key(name: str) -> list:
    """Sort key that orders ``frame2`` before ``frame10`` (and agrees with plain order on
    zero-padded names)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


# --------------------------------------------------------------------------- sources


class FrameSource(abc.ABC):
    """A sequence of frames decoded lazily.

    Attributes
    ----------
    path : Path
        The video file or the folder of frames.
    fps : float
        Frame rate (frames/s) used for ``index / fps`` times.
    shape : tuple of int
        ``(height, width)`` in px of the frames.
    warnings : list of str
        Problems met while decoding (truncation, unusable time stamps), one line each, in the
        order found; they do not stop a run.
    """

    kind: str = ""

    def __init__(self, path: Path, fps: float, shape: tuple[int, int]) -> None:
        self.path = path
        self.fps = fps
        self.shape = shape
        self.warnings: list[str] = []

    def _warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)

    @abc.abstractmethod
    def __iter__(self) -> Iterator[Frame]:
        """Stream the frames from the first to the last decodable one."""

    @abc.abstractmethod
    def __len__(self) -> int:
        """Number of frames."""

    @abc.abstractmethod
    def __getitem__(self, index: int) -> Frame:
        """One frame by position (decodes only what is needed to reach it)."""

    def info(self) -> dict:
        """What the source is, for provenance records (JSON-compatible)."""
        return {"kind": self.kind, "fps": self.fps, "height_px": self.shape[0], "width_px": self.shape[1]}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, fps={self.fps:g}, shape={self.shape})"


class VideoFrames(FrameSource):
    """Frames of a video file decoded with OpenCV (``cv2.VideoCapture``).

    Parameters
    ----------
    path : Path
        A video file OpenCV can read (mp4, avi, ...).
    fps : float, optional
        Frame rate (frames/s) that overrides the file's clock: frame ``i`` is at ``i / fps`` s.
        Without it the decoder's time stamps are used (see the module notes) and the file's
        declared rate is the fallback.
    decoder_threads : int, optional
        Threads the decoder may use (default: FFmpeg's own choice, one per core). One is the
        better choice where every core already runs a process of its own (a worker pool, one
        pinned core): the threads then only compete, and two such processes of two threads
        each decoded 40 % fewer frames/s than of one thread each.

    Raises
    ------
    InputError
        The file cannot be opened as a video, its first frame does not decode, or it declares
        no usable frame rate and ``fps`` is not given.
    """

    kind = "video"

    def __init__(self, path: Path, *, fps: float | None = None, decoder_threads: int | None = None) -> None:
        path = Path(path)
        user_fps = _check_fps(path, fps)
        decoder_threads = check_decoder_threads(decoder_threads)
        self._backend = _video_backend()
        self._params = [] if decoder_threads is None else [cv2.CAP_PROP_N_THREADS, decoder_threads]
        cap = cv2.VideoCapture(str(path), self._backend, self._params)
        try:
            if not cap.isOpened():
                raise InputError(path, "not a video OpenCV can read (unknown format, or damaged)")
            declared_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            declared_count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            try:
                ok, first = cap.read()
            except cv2.error:
                ok, first = False, None
            if not ok or first is None:
                raise InputError(path, "no decodable frames")
            t0_ms = float(cap.get(cv2.CAP_PROP_POS_MSEC))
        finally:
            cap.release()
        if user_fps is not None:
            rate, self.fps_source = user_fps, "user"
        elif math.isfinite(declared_fps) and 0.0 < declared_fps <= _MAX_FPS:
            rate, self.fps_source = declared_fps, "file"
        else:
            raise InputError(path, "the video declares no valid frame rate; give one (--fps)")
        super().__init__(path, rate, (int(first.shape[0]), int(first.shape[1])))
        self.declared_count = max(declared_count, 0)
        self._t0_ms = t0_ms if math.isfinite(t0_ms) else 0.0
        self._n_decoded: int | None = None

    # -- decoding

    def _open(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.path), self._backend, self._params)
        if not cap.isOpened():
            raise InputError(self.path, "could not be reopened as a video (was it changed or removed?)")
        return cap

    def _decoder_time(self, cap: cv2.VideoCapture, index: int, prev_s: float | None) -> float | None:
        """The decoder's time (s) of the frame just read, or None when it is not sane."""
        if self.fps_source == "user":
            return None
        t = (float(cap.get(cv2.CAP_PROP_POS_MSEC)) - self._t0_ms) / 1000.0
        nominal = index / self.fps
        if not math.isfinite(t) or abs(t - nominal) > 0.5 + 0.1 * nominal:
            return None
        if index == 0:
            return 0.0
        if prev_s is not None and t <= prev_s:
            return None
        return t

    def __iter__(self) -> Iterator[Frame]:
        cap = self._open()
        try:
            index, prev_s, n_fallback = 0, None, 0
            while True:
                try:
                    ok, image = cap.read()
                except cv2.error as exc:  # some builds raise instead of returning False
                    self._warn(f"decoding stopped at frame {index}: {' '.join(str(exc).split())}")
                    break
                if not ok or image is None:
                    break
                t = self._decoder_time(cap, index, prev_s)
                if t is None:
                    t = index / self.fps if prev_s is None else prev_s + 1.0 / self.fps
                    n_fallback += self.fps_source != "user"
                yield Frame(index, t, image)
                prev_s = t
                index += 1
        finally:
            cap.release()
        if index == 0:
            raise InputError(self.path, "no decodable frames")
        self._n_decoded = index
        if n_fallback:
            self._warn(f"{n_fallback} of {index} frames had no usable decoder time stamp; used 1/fps steps")
        if self.declared_count and index < self.declared_count:
            self._warn(
                f"decoded {index} of the {self.declared_count} frames the file declares "
                "(truncated or corrupt file, or a wrong frame count)"
            )

    def count(self) -> int:
        """Exact number of decodable frames (decodes the whole video once if not yet known)."""
        if self._n_decoded is None:
            cap = self._open()
            n = 0
            try:
                while cap.grab():
                    n += 1
            except cv2.error:
                pass
            finally:
                cap.release()
            self._n_decoded = n
        return self._n_decoded

    def __len__(self) -> int:
        """Number of frames: the decoded count after a full pass, before that the count the
        file declares (an estimate: containers are often off by a few frames); when the file
        declares none, the frames are counted by decoding."""
        if self._n_decoded is not None:
            return self._n_decoded
        if self.declared_count > 0:
            return self.declared_count
        return self.count()

    def __getitem__(self, index: int) -> Frame:
        """Frame ``index`` (negative counts from the end of the exact count).

        Seeks with ``CAP_PROP_POS_FRAMES`` and checks where the decoder landed; if the seek is
        refused or inexact, decodes sequentially from the start. Meant for a few frames; to
        visit many, iterate.
        """
        if not isinstance(index, (int, np.integer)):
            raise TypeError(f"frame index must be an int, not {type(index).__name__}")
        index = int(index)
        if index < 0:
            index += self.count()
            if index < 0:
                raise IndexError("frame index out of range")
        cap = self._open()
        try:
            image = None
            if index > 0 and cap.set(cv2.CAP_PROP_POS_FRAMES, index):
                ok, img = cap.read()
                if ok and img is not None and int(round(cap.get(cv2.CAP_PROP_POS_FRAMES))) == index + 1:
                    image = img
            if image is None:  # sequential fallback
                cap.release()
                cap = self._open()
                for _ in range(index):
                    if not cap.grab():
                        raise IndexError(f"frame index {index} out of range")
                ok, image = cap.read()
                if not ok or image is None:
                    raise IndexError(f"frame index {index} out of range")
            t = self._decoder_time(cap, index, None)
            return Frame(index, index / self.fps if t is None else t, image)
        finally:
            cap.release()

    def info(self) -> dict:
        d = super().info()
        d.update(
            fps_source=self.fps_source,
            declared_frames=self.declared_count,
            decoded_frames=self._n_decoded,
        )
        return d


class FolderFrames(FrameSource):
    """Frames stored as PNG/JPEG files in one folder, in natural name order.

    Natural order sorts digit runs by value (``f2.png`` before ``f10.png``) and agrees with
    plain name order for zero-padded names. Hidden files (names starting with ``.``) and other
    file types are ignored.

    Parameters
    ----------
    path : Path
        The folder.
    fps : float
        Frame rate (frames/s); frame ``i`` is at ``i / fps`` s. Required.

    Raises
    ------
    InputError
        No frames in the folder, no ``fps``, or an image that cannot be read or whose size
        differs from the first frame's (names the file). Sizes are checked from the image headers
        when the source is opened (with Pillow when it is installed) and again while decoding.
    """

    kind = "folder"

    def __init__(self, path: Path, *, fps: float | None) -> None:
        path = Path(path)
        files = sorted(
            (p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") and p.is_file()),
            key=lambda p: _natural_key(p.name),
        )
        if not files:
            raise InputError(path, f"folder has no frames ({', '.join(IMAGE_SUFFIXES)} files)")
        rate = _check_fps(path, fps)
        if rate is None:
            raise InputError(path, "a folder of frames needs a frame rate (--fps)")
        first = self._read(files[0])
        super().__init__(path, rate, (int(first.shape[0]), int(first.shape[1])))
        self.files = files
        self._check_sizes()

    @staticmethod
    def _read(file: Path) -> np.ndarray:
        image = cv2.imread(str(file), cv2.IMREAD_ANYCOLOR)
        if image is None:
            raise InputError(file, "cannot be decoded as an image")
        return image

    def _size_problem(self, file: Path, height: int, width: int) -> InputError | None:
        if (height, width) == self.shape:
            return None
        return InputError(
            file,
            f"frame size {width}x{height} px differs from {self.shape[1]}x{self.shape[0]} px "
            f"of the first frame {self.files[0].name} (frames are not resized)",
        )

    def _check_sizes(self) -> None:
        try:
            from PIL import Image
        except ImportError:  # sizes are still checked while decoding
            return
        for file in self.files[1:]:
            try:
                with Image.open(file) as im:
                    width, height = im.size
            except Exception:
                raise InputError(file, "not a readable image") from None
            problem = self._size_problem(file, height, width)
            if problem is not None:
                raise problem

    def _frame(self, index: int) -> Frame:
        file = self.files[index]
        image = self._read(file)
        problem = self._size_problem(file, image.shape[0], image.shape[1])
        if problem is not None:
            raise problem
        return Frame(index, index / self.fps, image)

    def __iter__(self) -> Iterator[Frame]:
        for index in range(len(self.files)):
            yield self._frame(index)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, index: int) -> Frame:
        if not isinstance(index, (int, np.integer)):
            raise TypeError(f"frame index must be an int, not {type(index).__name__}")
        index = int(index)
        n = len(self.files)
        if not -n <= index < n:
            raise IndexError(f"frame index {index} out of range for {n} frames")
        return self._frame(index % n)

    def info(self) -> dict:
        d = super().info()
        d.update(n_files=len(self.files), first_file=self.files[0].name, last_file=self.files[-1].name)
        return d


def open_frames(path: str | os.PathLike, *, fps: float | None = None, decoder_threads: int | None = None) -> FrameSource:
    """Open a video file or a folder of frames for lazy reading.

    Parameters
    ----------
    path : str or PathLike
        A video file OpenCV can read, or a folder of PNG/JPEG frames.
    fps : float, optional
        Frame rate (frames/s). Required for a folder; for a video it overrides the file's clock
        (see the module notes).
    decoder_threads : int, optional
        Threads of a video's decoder (see :class:`VideoFrames`; a folder ignores it).

    Returns
    -------
    FrameSource
        :class:`VideoFrames` or :class:`FolderFrames`.

    Raises
    ------
    InputError
        Missing or unreadable path, a single image, or any of the problems listed for the two
        source types.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such file or folder")
    if not os.access(p, os.R_OK):
        raise InputError(p, "permission denied")
    if p.is_dir():
        return FolderFrames(p, fps=fps)
    if p.suffix.lower() in IMAGE_SUFFIXES:
        raise InputError(p, "is a single image, not a video; pass the folder of frames (with --fps)")
    if p.stat().st_size == 0:
        raise InputError(p, "empty file")
    return VideoFrames(p, fps=fps, decoder_threads=decoder_threads)


# --------------------------------------------------------------------------- lens distortion


@dataclass(frozen=True)
class LensCalibration:
    """A camera's intrinsics and lens distortion, in OpenCV's model (``cv2.calibrateCamera``).

    Parameters
    ----------
    camera_matrix : tuple of tuples of float
        ``((fx, 0, cx), (0, fy, cy), (0, 0, 1))`` (px), 3 x 3.
    dist_coeffs : tuple of float
        ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])`` (dimensionless), 4, 5 or 8 of them.
    image_size : tuple of int
        ``(width, height)`` (px) of the images the calibration was made with; frames of another
        size are refused rather than guessed at.
    """

    camera_matrix: tuple[tuple[float, ...], ...]
    dist_coeffs: tuple[float, ...]
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        k = np.asarray(self.camera_matrix, dtype=float)
        d = np.asarray(self.dist_coeffs, dtype=float)
        if k.shape != (3, 3) or not np.isfinite(k).all():
            raise ValueError(f"camera_matrix must be 3x3 finite numbers, not {self.camera_matrix!r}")
        if not (k[0, 0] > 0 and k[1, 1] > 0 and k[0, 1] == k[1, 0] == k[2, 0] == k[2, 1] == 0 and k[2, 2] == 1):
            raise ValueError("camera_matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        if d.ndim != 1 or len(d) not in (4, 5, 8) or not np.isfinite(d).all():
            raise ValueError(f"dist_coeffs must be 4, 5 or 8 finite numbers, not {self.dist_coeffs!r}")
        w, h = self.image_size
        if int(w) != w or int(h) != h or w < 1 or h < 1:
            raise ValueError(f"image_size must be (width, height) in px, not {self.image_size!r}")

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> "LensCalibration":
        """Read ``{"camera_matrix": [[...], [...], [...]], "dist_coeffs": [...],
        "image_size": [width, height]}`` (px; other keys are ignored).

        Raises
        ------
        InputError
            Unreadable file, not JSON, a key missing or a value of the wrong shape.
        """
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except OSError as exc:
            raise InputError(p, f"cannot read the calibration ({exc.strerror or exc})") from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(p, f"not a JSON calibration ({exc})") from None
        if not isinstance(data, dict):
            raise InputError(p, "a calibration is a JSON object with camera_matrix, dist_coeffs and image_size")
        missing = [key for key in ("camera_matrix", "dist_coeffs", "image_size") if key not in data]
        if missing:
            raise InputError(p, f"calibration lacks {', '.join(missing)}")
        try:
            d = np.asarray(data["dist_coeffs"], dtype=float).ravel()  # OpenCV writes a 1 x n array
            k = np.asarray(data["camera_matrix"], dtype=float)
            size = [float(v) for v in data["image_size"]]
            if len(size) != 2 or not all(v == int(v) for v in size):
                raise ValueError(f"image_size must be [width, height] in whole px, not {data['image_size']!r}")
            return cls(tuple(tuple(float(x) for x in row) for row in np.atleast_2d(k)), tuple(float(x) for x in d),
                       (int(size[0]), int(size[1])))
        except (TypeError, ValueError) as exc:
            raise InputError(p, f"bad calibration: {exc}") from None

    def opencv(self) -> tuple[np.ndarray, np.ndarray]:
        """The camera matrix (3 x 3, px) and distortion coefficients as OpenCV takes them (float64)."""
        return np.asarray(self.camera_matrix, dtype=np.float64), np.asarray(self.dist_coeffs, dtype=np.float64)

    def check_size(self, shape: tuple[int, ...]) -> None:
        """Raise ValueError unless images of ``shape`` ((h, w[, c]), px) are the calibration's size."""
        h, w = int(shape[0]), int(shape[1])
        if (w, h) != tuple(self.image_size):
            cw, ch = self.image_size
            raise ValueError(f"frames are {w}x{h} px but the lens calibration was made at {cw}x{ch} px")

    def distort_points(self, points_px: np.ndarray) -> np.ndarray:
        """Where the camera records ideal (pinhole) image points: ``(n, 2)`` px in, ``(n, 2)`` px
        out (``cv2.projectPoints`` of the points' rays through the lens)."""
        pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
        k, d = self.opencv()
        rays = np.column_stack([(pts[:, 0] - k[0, 2]) / k[0, 0], (pts[:, 1] - k[1, 2]) / k[1, 1], np.ones(len(pts))])
        out, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, d)
        return out.reshape(-1, 2)

    def to_dict(self) -> dict:
        """The JSON form :meth:`from_json` reads."""
        return {"camera_matrix": [list(row) for row in self.camera_matrix], "dist_coeffs": list(self.dist_coeffs),
                "image_size": list(self.image_size)}


def undistorter(calibration: LensCalibration, shape: tuple[int, ...]) -> Callable[[np.ndarray], np.ndarray]:
    """A function mapping frames of ``shape`` ((h, w[, c]), px) to their undistorted image.

    The maps are built once (``cv2.initUndistortRectifyMap`` with the calibration's own camera
    matrix as the new one, fixed-point); each call is one ``cv2.remap`` (bilinear). Pixels whose
    source lies outside the frame repeat the nearest edge pixel rather than turning black, so
    the undistorted frame's border adds no edges.

    Raises
    ------
    ValueError
        ``shape`` differs from the calibration's ``image_size``.
    """
    calibration.check_size(shape)
    k, d = calibration.opencv()
    map1, map2 = cv2.initUndistortRectifyMap(k, d, None, k, tuple(calibration.image_size), cv2.CV_16SC2)

    def undistort(image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    return undistort

"""Frame sources: videos, folders of frames, damaged input (vision.frames)."""

from __future__ import annotations

import pickle

import cv2
import numpy as np
import pytest

from pipeline_fakes import H, W, frame_image, write_folder, write_video
from tympani.vision.errors import InputError, is_input_error
from tympani.vision.frames import Frame, FolderFrames, LensCalibration, VideoFrames, open_frames, undistorter
from tympani.vision.greyscale import as_float_gray, to_gray


def _level(frame: Frame) -> float:
    return float(to_gray(frame.image)[8:].mean())


def _index_from_level(level: float) -> int:
    return int(round((level - 30) / 10))


# --------------------------------------------------------------------------- errors


def test_input_error_is_one_line_and_pickles():
    err = InputError("a/b.mp4", "no decodable\nframes")
    assert str(err) == "a/b.mp4: no decodable frames"
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, InputError) and str(back) == str(err)
    assert is_input_error(err) and not is_input_error(ValueError("x"))


# --------------------------------------------------------------------------- videos


@pytest.fixture(scope="module")
def mp4(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("v") / "clip.mp4", n=20, fps=25.0)


def test_mp4_streams_every_frame_with_decoder_times(mp4):
    src = open_frames(mp4)
    assert isinstance(src, VideoFrames) and src.shape == (H, W) and src.fps == pytest.approx(25.0)
    it = iter(src)
    first = next(it)  # lazy: a generator, not a list
    assert first.index == 0 and first.time_s == 0.0
    frames = [first, *it]
    assert [f.index for f in frames] == list(range(20))
    assert np.allclose([f.time_s for f in frames], np.arange(20) / 25.0, atol=1e-6)
    assert all(f.image.dtype == np.uint8 and f.image.shape == (H, W, 3) for f in frames)
    assert [_index_from_level(_level(f)) for f in frames] == list(range(20))
    assert len(src) == 20 and src.count() == 20 and not src.warnings


def test_decoder_threads_give_the_same_frames(mp4):
    """The decoder's thread count is a speed setting only: one thread decodes the same images."""
    one = open_frames(mp4, decoder_threads=1)
    if one._open().get(cv2.CAP_PROP_N_THREADS) > 0:  # backends that report it
        assert one._open().get(cv2.CAP_PROP_N_THREADS) == 1
    assert all(np.array_equal(a.image, b.image) and a.time_s == b.time_s for a, b in zip(one, open_frames(mp4)))
    for bad in (0, -1, 1.5):
        with pytest.raises(ValueError, match="decoder_threads"):
            open_frames(mp4, decoder_threads=bad)


def test_mp4_random_access_matches_iteration(mp4):
    src = open_frames(mp4)
    for i in (0, 7, 13, 19):
        frame = src[i]
        assert frame.index == i and _index_from_level(_level(frame)) == i
        assert frame.time_s == pytest.approx(i / 25.0)
    assert _index_from_level(_level(src[-1])) == 19
    with pytest.raises(IndexError):
        src[20]


class _NoSeek:
    """A VideoCapture that refuses to seek, to exercise the sequential fallback."""

    def __init__(self, cap):
        self._cap = cap

    def set(self, prop, value):
        return False

    def __getattr__(self, name):
        return getattr(self._cap, name)


def test_random_access_falls_back_to_sequential_decoding(mp4, monkeypatch):
    real_open = VideoFrames._open
    monkeypatch.setattr(VideoFrames, "_open", lambda self: _NoSeek(real_open(self)))
    src = open_frames(mp4)
    assert _index_from_level(_level(src[11])) == 11 and src[11].index == 11


def test_fps_overrides_the_video_clock(mp4):
    src = open_frames(mp4, fps=10.0)
    assert [f.time_s for f in src][:3] == pytest.approx([0.0, 0.1, 0.2])
    assert src.info()["fps_source"] == "user"


def test_source_pickles_and_iterates_twice(mp4):
    src = pickle.loads(pickle.dumps(open_frames(mp4)))
    assert sum(1 for _ in src) == 20 and sum(1 for _ in src) == 20


def test_truncated_avi_yields_decodable_frames_then_warns(tmp_path):
    full = write_video(tmp_path / "full.avi", n=30, fourcc="MJPG")
    data = full.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    src = open_frames(cut)
    frames = list(src)
    assert 0 < len(frames) < 30
    assert [f.index for f in frames] == list(range(len(frames)))
    assert any("decoded" in w and "30" in w for w in src.warnings)
    assert len(src) == len(frames)  # exact count after a full pass


def test_corrupt_middle_of_mp4_stops_without_crashing(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "noisy.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (160, 120))
    for _ in range(30):
        writer.write(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    writer.release()
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 5000] = bytes(5000)
    bad = tmp_path / "corrupt.mp4"
    bad.write_bytes(bytes(data))
    src = open_frames(bad)
    frames = list(src)  # must not raise
    assert len(frames) >= 1
    if len(frames) < 30:
        assert src.warnings


def test_mp4_cut_before_its_index_is_input_error(tmp_path, mp4):
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(mp4.read_bytes()[: mp4.stat().st_size // 2])
    with pytest.raises(InputError, match="not a video"):
        open_frames(cut)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "missing.mp4", "no such file"),
        (lambda d: (d / "empty.mp4").write_bytes(b"") and None or d / "empty.mp4", "empty file"),
        (lambda d: (d / "junk.mp4").write_bytes(b"hello" * 200) and None or d / "junk.mp4", "not a video"),
        (lambda d: cv2.imwrite(str(d / "one.png"), frame_image(0)) and d / "one.png", "single image"),
    ],
)
def test_bad_paths_raise_input_error(tmp_path, make, message):
    path = make(tmp_path)
    with pytest.raises(InputError, match=message) as info:
        open_frames(path)
    assert str(info.value).startswith(str(path))
    assert "\n" not in str(info.value)


def test_all_black_video_still_opens(tmp_path):
    # a black video is a valid video; registration, not the reader, rejects it
    src = open_frames(write_video(tmp_path / "black.mp4", n=3, all_dark=True))
    assert len(list(src)) == 3


# --------------------------------------------------------------------------- folders


def test_folder_in_natural_name_order(tmp_path):
    folder = write_folder(tmp_path / "frames", n=12)  # frame_0 ... frame_11 (not zero-padded)
    (tmp_path / "frames" / "notes.txt").write_text("not a frame")
    src = open_frames(folder, fps=5.0)
    assert isinstance(src, FolderFrames) and len(src) == 12 and src.shape == (H, W)
    frames = list(src)
    assert [f.index for f in frames] == list(range(12))
    assert [_index_from_level(_level(f)) for f in frames] == list(range(12))  # 2 before 10
    assert [f.time_s for f in frames] == pytest.approx(np.arange(12) / 5.0)
    assert _index_from_level(_level(src[10])) == 10 and src[-1].index == 11


def test_grey_png_frames_stay_grey(tmp_path):
    src = open_frames(write_folder(tmp_path / "g", n=3, grey=True), fps=1.0)
    assert src[0].image.ndim == 2 and src[0].image.dtype == np.uint8


def test_folder_needs_fps(tmp_path):
    folder = write_folder(tmp_path / "frames", n=2)
    with pytest.raises(InputError, match="frame rate"):
        open_frames(folder)
    with pytest.raises(InputError, match="invalid frame rate"):
        open_frames(folder, fps=-3)


def test_folder_without_images(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("x")
    with pytest.raises(InputError, match="no frames"):
        open_frames(tmp_path / "empty", fps=10)


def test_folder_with_mixed_sizes_names_the_file(tmp_path):
    folder = write_folder(tmp_path / "frames", n=4, name="f{:03d}.png")
    cv2.imwrite(str(folder / "f002.png"), np.zeros((H + 2, W, 3), np.uint8))
    with pytest.raises(InputError, match="f002.png") as info:
        open_frames(folder, fps=10)
    assert "differs" in str(info.value)


def test_folder_with_undecodable_image_names_it(tmp_path):
    folder = write_folder(tmp_path / "frames", n=3, name="f{:03d}.png")
    (folder / "f001.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="f001.png"):
        list(open_frames(folder, fps=10))


# --------------------------------------------------------------------------- to_gray


def test_to_gray_variants():
    bgr = np.zeros((4, 5, 3), np.uint8)
    bgr[..., 2] = 255  # pure red
    g = to_gray(bgr)
    assert g.shape == (4, 5) and g.dtype == np.uint8 and 70 <= g[0, 0] <= 80
    f = as_float_gray(bgr)
    assert f.dtype == np.float32 and np.abs(f - g).max() <= 0.5
    bgra = np.dstack([bgr, np.full((4, 5), 7, np.uint8)])
    assert np.array_equal(to_gray(bgra), g)
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
    out = to_gray(grey)
    assert np.array_equal(out, grey) and out is not grey
    assert to_gray(np.full((2, 2), 65535, np.uint16))[0, 0] == 255
    assert to_gray(np.full((2, 2, 1), 0.5))[0, 0] in (127, 128)
    with pytest.raises(ValueError):
        to_gray(np.zeros((2, 2, 2), np.uint8))


# --------------------------------------------------------------------------- lens calibration

_BARREL = {"camera_matrix": [[520.0, 0.0, 205.0], [0.0, 520.0, 148.0], [0.0, 0.0, 1.0]],
           "dist_coeffs": [[-0.3, 0.08, 0.0, 0.0, 0.0]], "image_size": [400, 300]}  # OpenCV writes 1 x n


def test_calibration_reads_opencv_json_and_refuses_bad_files(tmp_path):
    import json

    good = tmp_path / "cal.json"
    good.write_text(json.dumps(_BARREL))
    cal = LensCalibration.from_json(good)
    assert cal.dist_coeffs == (-0.3, 0.08, 0.0, 0.0, 0.0) and cal.image_size == (400, 300)
    assert cal.camera_matrix[0] == (520.0, 0.0, 205.0)
    again = tmp_path / "again.json"
    again.write_text(json.dumps(cal.to_dict()))
    assert LensCalibration.from_json(again) == cal  # to_dict writes what from_json reads
    bad = {
        "not a JSON": "{camera",
        "a JSON object": "[1, 2]",
        "lacks dist_coeffs": json.dumps({k: v for k, v in _BARREL.items() if k != "dist_coeffs"}),
        "3x3": json.dumps({**_BARREL, "camera_matrix": [[1.0, 0.0], [0.0, 1.0]]}),
        "fx, fy > 0": json.dumps({**_BARREL, "camera_matrix": [[-5.0, 0, 1], [0, 5.0, 1], [0, 0, 1]]}),
        "4, 5 or 8": json.dumps({**_BARREL, "dist_coeffs": [0.1, 0.2, 0.3]}),
        "whole px": json.dumps({**_BARREL, "image_size": [400.5, 300]}),
        "finite": json.dumps({**_BARREL, "dist_coeffs": [0.1, 0.0, 0.0, "nan"]}),
    }
    for i, (words, text) in enumerate(bad.items()):
        path = tmp_path / f"bad{i}.json"
        path.write_text(text)
        with pytest.raises(InputError, match=words) as info:
            LensCalibration.from_json(path)
        assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)
    with pytest.raises(InputError, match="cannot read"):
        LensCalibration.from_json(tmp_path / "missing.json")


def test_undistortion_inverts_the_lens():
    """A grid of lines bent by a barrel lens (vision.rendering.distort) comes back straight."""
    from tympani.vision.rendering import distort

    cal = LensCalibration(tuple(map(tuple, _BARREL["camera_matrix"])), tuple(_BARREL["dist_coeffs"][0]), (400, 300))
    ideal = np.full((300, 400), 40, np.uint8)
    ideal[:, ::25] = ideal[::25, :] = 220
    ideal = cv2.GaussianBlur(ideal, (0, 0), 1.2)
    bent = distort(ideal, cal)
    straight = undistorter(cal, bent.shape)(bent)
    inner = (slice(10, 290), slice(10, 390))  # the rim: what a barrel lens pushed out of the frame
    before = np.abs(bent[inner].astype(float) - ideal[inner]).mean()  # grey levels
    after = np.abs(straight[inner].astype(float) - ideal[inner]).mean()
    assert before > 8.0 and after < 0.15 * before, (before, after)  # 11.4 -> 1.2: interpolation blur left
    colour = undistorter(cal, (300, 400, 3))(cv2.cvtColor(bent, cv2.COLOR_GRAY2BGR))
    assert colour.shape == (300, 400, 3) and np.array_equal(colour[..., 1], straight)
    with pytest.raises(ValueError, match="400x300"):
        undistorter(cal, (480, 640))


def test_distort_points_is_where_the_lens_records_a_point():
    """A small bright dot drawn at ideal points shows up, through vision.rendering.distort, at
    LensCalibration.distort_points of them (measured: within 0.011 px); the identity lens leaves
    points where they are."""
    from tympani.vision.rendering import distort

    cal = LensCalibration(tuple(map(tuple, _BARREL["camera_matrix"])), tuple(_BARREL["dist_coeffs"][0]), (400, 300))
    ideal_pts = np.array([[60.0, 50.0], [340.0, 70.0], [205.0, 148.0], [90.0, 250.0], [330.0, 260.0]])
    expected = cal.distort_points(ideal_pts)
    for p, q in zip(ideal_pts, expected):
        ideal = np.zeros((300, 400), np.float32)
        ideal[int(p[1]), int(p[0])] = 1.0
        ideal = cv2.GaussianBlur(ideal, (0, 0), 2.0)
        seen = distort(ideal, cal)
        ys, xs = np.mgrid[0:300, 0:400]
        w = np.clip(seen - 0.2 * seen.max(), 0.0, None)
        found = np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()
        assert np.hypot(*(found - q)) < 0.025, (p, q, found)
    assert np.linalg.norm(expected[0] - ideal_pts[0]) > 5.0  # the corner moves: the test has teeth
    plain = LensCalibration(cal.camera_matrix, (0.0,) * 5, (400, 300))
    assert np.allclose(plain.distort_points(ideal_pts), ideal_pts, atol=1e-9)

"""measure_frames_batch equals measure_frame, frame by frame.

Rendered frames of four random poses (two mirrored, two not), with depths from not inserted
(no array in the channel) through the entry channel to deep insertions, nuisance strengths 0–1,
and frames where the measurement fails (no array, an array painted over with the fluid); plus
colour, float32 and wrong-size frames, which the batch hands to the per-frame function. The
batch helpers (stations of several frames laid end to end) are also checked one by one against
their per-frame originals on random inputs.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import angles_reference as ref
from tympani.vision.angles import FrameMeasurement, measure_frame, measure_frames_batch, prepare_measurement, survey
from tympani.vision.angles.arrays import erode
from tympani.vision.angles.ragged import (
    Ragged,
    distance_from_tip_ragged,
    erode_ragged,
    extrapolate_ragged,
    fill_rows,
    interp_ragged,
    interp_rows,
    near_ragged,
    running_median_ragged,
    smooth_ragged,
    tip_crossing_ragged,
)
from tympani.vision.rendering import Scene, pose_at_depth, random_appearance, random_nuisance, random_pose

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
    """Every frame of every pose: a batch gives what each frame alone (measure_frame, a batch of
    one) gives, so frames laid end to end do not see each other; the set covers measured frames,
    the entry channel and failures."""
    reasons = set()
    for plan, frames in videos:
        batch = measure_frames_batch(frames, plan)
        assert len(batch) == len(frames)
        for frame, b in zip(frames, batch):
            a = measure_frame(frame, plan)
            _assert_same(a, b)
            reasons.add(a.reason)
    assert "" in reasons and "array not in channel" in reasons and len(reasons) >= 2


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


# --------------------------------------------------------------------------- the ragged helpers
#
# Each batch helper against its per-frame original on random frames (lengths 1-40, random masks
# and values), so that a frame's ends, empty masks and single stations are all met.


def _random_frames(rng: np.random.Generator, n_frames: int = 7) -> list[int]:
    return [int(rng.integers(1, 41)) for _ in range(n_frames)]


@pytest.mark.parametrize("seed", range(5))
def test_ragged_helpers_equal_per_frame(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lengths = _random_frames(rng)
    rg = Ragged.of(lengths)
    mask = rng.random(rg.row.size) < rng.uniform(0.2, 0.9)
    values = rng.normal(size=rg.row.size)
    for reach in (1, 2):
        eroded = erode_ragged(mask, rg, reach)
        expected = np.concatenate([erode(m, reach) for m in rg.split(mask)])
        np.testing.assert_array_equal(eroded, expected)
    for size in (1, 3, 7):
        near = near_ragged(mask, rg, size)
        np.testing.assert_array_equal(near, np.concatenate([ref.near(m, size) for m in rg.split(mask)]))
        med = running_median_ragged(values, rg, size)
        np.testing.assert_array_equal(med, np.concatenate([ref.running_median(v, size) for v in rg.split(values)]))
    padded = rg.pad(values, np.nan)  # each frame left-aligned in its row, the fill after it
    for b, v in enumerate(rg.split(values)):
        np.testing.assert_array_equal(padded[b, : len(v)], v)
        assert np.isnan(padded[b, len(v) :]).all()
    np.testing.assert_array_equal(rg.count(mask), [m.sum() for m in rg.split(mask)])
    np.testing.assert_array_equal(rg.last(mask), [np.flatnonzero(m)[-1] if m.any() else -1 for m in rg.split(mask)])


@pytest.mark.parametrize("seed", range(5))
def test_ragged_smoothing_equals_per_frame(seed: int) -> None:
    """smooth_ragged (running sums across frames, window clipped to each frame, gaps filled)
    against smooth_valid frame by frame, sparse frames included (their gaps are filled)."""
    rng = np.random.default_rng(seed)
    rg = Ragged.of(_random_frames(rng, 9))
    density = rng.uniform(0.05, 1.0, len(rg.n))[rg.row]  # some frames nearly empty: long gaps
    valid = (rng.random(rg.row.size) < density) | (rg.local == rng.integers(0, rg.n)[rg.row])
    for k in (1, 2):
        values = rng.normal(size=(k, rg.row.size)).cumsum(axis=1) + 100.0  # far from 0, as offsets in mm are not
        values[:, ~valid] = np.nan  # ignored
        for size in (1, 5, 9, 13):
            fit, slope = smooth_ragged(values, valid, rg, size)
            for b, (v, ok) in enumerate(zip(np.split(values, rg.start[1:], axis=1), rg.split(valid))):
                f_b, s_b = ref.smooth_valid(v, ok, size)
                cut = slice(rg.start[b], rg.start[b] + rg.n[b])
                np.testing.assert_allclose(fit[:, cut], f_b, rtol=0, atol=1e-9)
                np.testing.assert_allclose(slope[:, cut], s_b, rtol=0, atol=1e-9)
    with pytest.raises(ValueError):  # a frame with no valid station, as np.interp in smooth_valid
        smooth_ragged(np.zeros((1, rg.row.size)), valid & (rg.row != 0), rg, 3)


@pytest.mark.parametrize("seed", range(5))
def test_ragged_tip_and_extrapolation_equal_per_frame(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rg = Ragged.of(_random_frames(rng))
    cover = np.clip(rng.normal(0.5, 0.4, rg.row.size), 0.0, 1.0)
    level = rng.uniform(0.3, 0.7, len(rg.n))
    fallback = rng.uniform(0.0, 5.0, len(rg.n))
    got = tip_crossing_ragged(cover, level, fallback, rg)
    for b, c in enumerate(rg.split(cover)):
        assert abs(got[b] - ref.tip_crossing(c, float(level[b]), float(fallback[b]))) <= 1e-12
    span = float(rng.uniform(2.0, 15.0))
    stations = rg.local.astype(float)
    values = rng.normal(size=rg.row.size).cumsum()
    measured = (rng.random(rg.row.size) < 0.7) | (rg.local == 0)
    last = rg.last(measured)
    sel = measured & (rg.local >= (last - span)[rg.row])
    with np.errstate(divide="raise", invalid="raise"):  # a frame fitted to one station divides nothing by zero
        got = extrapolate_ragged(stations, values, sel, span, rg)
    for b, (st, v, ms) in enumerate(zip(rg.split(stations), rg.split(values), rg.split(measured))):
        expected = ref.extrapolate(st[ms].astype(int), v[ms], float(rg.n[b] - 1), span)
        assert abs(got[b] - expected) <= 1e-9 * max(1.0, abs(expected))


@pytest.mark.parametrize("seed", range(5))
def test_batch_interpolations_and_runs_equal_per_frame(seed: int) -> None:
    """fill_rows (integer and half positions), interp_rows, _array_runs (with and without
    metal bands) and _run_resumes against np.interp, _array_run and run_resumes row by row."""
    rng = np.random.default_rng(seed)
    n_rows, n = 6, int(rng.integers(2, 30))
    for x in (np.arange(n, dtype=float), 4 * np.arange(n) + 1.5):
        known = rng.random((n_rows, n)) < 0.5
        known[0] = False  # a row with nothing to interpolate from is left alone
        fit = rng.normal(size=(n_rows, 2, n))
        expected = fit.copy()
        for b in range(1, n_rows):
            if known[b].any():
                for r in range(2):
                    expected[b, r, ~known[b]] = np.interp(x[~known[b]], x[known[b]], fit[b, r, known[b]])
        fill_rows(fit, known, ~known & known.any(axis=1)[:, None], x)
        np.testing.assert_array_equal(fit, expected)
    xp = 3 * np.arange(8) + 1.5
    fp = rng.normal(size=(n_rows, 8))
    x = np.concatenate([np.arange(30, dtype=float), xp, rng.uniform(-5.0, 30.0, 20)])  # sample positions too
    np.testing.assert_array_equal(interp_rows(x, xp, fp), [np.interp(x, xp, f) for f in fp])
    row = rng.integers(0, n_rows, len(x))
    np.testing.assert_array_equal(interp_ragged(x, row, xp, fp),
                                  [np.interp(q, xp, fp[r]) for q, r in zip(x, row)])
    dark = rng.random((n_rows, n)) < rng.uniform(0.2, 0.9)
    probe = np.flatnonzero(rng.random(n) < 0.3)
    probe = probe if len(probe) else np.array([0])
    gap = float(rng.uniform(0.0, 4.0))
    np.testing.assert_array_equal(survey._array_runs(dark, probe, gap), [_array_run(d, probe, gap) for d in dark])
    band = ~dark & (rng.random((n_rows, n)) < 0.6)
    border = int(rng.integers(0, 3))
    np.testing.assert_array_equal(survey._array_runs(dark, probe, gap, band, border),
                                  [_array_run(d, probe, gap, b, border) for d, b in zip(dark, band)])
    end = rng.integers(-1, n, n_rows)
    reach, length = int(rng.integers(1, 20)), int(rng.integers(1, 40))
    np.testing.assert_array_equal(survey._run_resumes(dark, band, end, gap, reach, length),
                                  [ref.run_resumes(d, b, int(e), gap, reach, length) for d, b, e in zip(dark, band, end)])



@pytest.mark.parametrize("seed", range(5))
def test_survey_levels_equal_per_frame(seed: int) -> None:
    """_fluid_levels and _array_ratios against fluid_level and array_ratio row by row: frames all
    in view (float32, as the survey gives them), partly in view, with scattered stations out of
    view, and out of view."""
    rng = np.random.default_rng(seed)
    n_rows, n = 6, int(rng.integers(20, 200))
    lit = rng.uniform(80.0, 200.0) * (1.0 + 0.3 * np.sin(np.linspace(0.0, 3.0, n)))
    brightest = (lit * rng.uniform(0.5, 1.05, (n_rows, n))).astype(np.float32)
    in_view = np.ones((n_rows, n), dtype=bool)
    in_view[1, : n // 3] = False
    in_view[2] = rng.random(n) < 0.7
    in_view[3] = False
    block, reach = int(rng.integers(1, 12)), int(rng.integers(0, 4))
    fluid = survey._fluid_levels(brightest, in_view, block, 25.0, reach, 0.85)
    for b in range(n_rows):
        np.testing.assert_array_equal(fluid[b], ref.fluid_level(brightest[b], in_view[b], block, 25.0, reach, 0.85))
    darkest = (brightest * rng.uniform(0.3, 1.0, (n_rows, n))).astype(np.float32)
    steepest = (brightest - darkest) * rng.uniform(0.0, 1.0, (n_rows, n)).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = survey._array_ratios(darkest, brightest, steepest, fluid, in_view, 3)
        expected = [ref.array_ratio(darkest[b], brightest[b], steepest[b], fluid[b], in_view[b], 3) for b in range(n_rows)]
    np.testing.assert_array_equal(rho, expected)


@pytest.mark.parametrize("seed", range(5))
def test_ragged_distance_from_tip_equals_per_frame(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rg = Ragged.of(_random_frames(rng))
    line = rng.normal(size=(rg.row.size, 2)).cumsum(axis=0)
    tip_mm = rng.normal(size=(len(rg.n), 2))
    tip_f = rng.uniform(-1.0, 41.0, len(rg.n))
    got = distance_from_tip_ragged(line, tip_mm, tip_f, rg)
    for b, points in enumerate(rg.split(line)):
        expected = ref.distance_from_tip(points, tip_mm[b], np.arange(len(points)), float(tip_f[b]))
        np.testing.assert_array_equal(rg.split(got)[b], expected)


def _array_run(dark: np.ndarray, probe: np.ndarray, max_gap: float, band: np.ndarray | None = None,
               border: int = 2) -> int:
    """Reference for one row: last station of the dark run that starts in the probe stations,
    bridging gaps of up to ``max_gap`` stations that are neither dark nor in a stretch of
    ``band`` stations with dark ones at most ``border`` stations on one side and ``max_gap``
    on the other; the run
    ends on a dark station (-1 when no probe station is dark)."""
    first = probe[dark[probe]]
    if len(first) == 0:
        return -1
    carry = dark.copy()
    if band is not None:
        n, i = len(band), 0
        while i < n:
            if not band[i]:
                i += 1
                continue
            j = i
            while j < n and band[j]:
                j += 1  # the stretch is i .. j-1
            def near(reach: int) -> tuple[bool, bool]:
                return i > 0 and any(dark[max(i - 1 - reach, 0):i]), j < n and any(dark[j:j + reach + 1])
            (before, after), (before_far, after_far) = near(border), near(int(max_gap))
            if (before and after_far) or (before_far and after):
                carry[i:j] = True
            i = j
    idx = np.flatnonzero(carry[first[0]:]) + first[0]
    breaks = np.flatnonzero(np.diff(idx) - 1 > max_gap)
    end = int(idx[breaks[0]] if len(breaks) else idx[-1])
    return int(np.flatnonzero(dark[: end + 1])[-1])


def _pattern(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Dark and band stations (shape (1, n)) of a pattern: ``D`` dark, ``B`` band, ``#`` both."""
    chars = np.array(list(text))
    return np.isin(chars, ["D", "#"])[None, :], np.isin(chars, ["B", "#"])[None, :]


def test_runs_carry_bands_joined_to_the_body_on_one_side() -> None:
    """Long bands with a short body between them that reads dark only here and there (an
    independent renderer's array at 20 px/mm, coarse stations as the survey saw them): a band
    joined to the body on one side with the body again within ``max_gap`` on the other carries
    the run to the tip's dark cap (it stopped 22 stations short, before ``..BBBBB#``). A bright
    stretch past the tip with no body after it (a bubble's inside) does not carry it."""
    text = "DDDDDDDDDD.BBB.D.BBB.DD.BBB.DBBBB.D.BBB.DD.BB.DD.BBB.DD.BB.DD.BBB..BBBBB#.BBBDDDDDD...BBBBBBB......."
    dark, band = _pattern(text)
    probe = np.arange(5)
    assert survey._array_runs(dark, probe, 8.0, band, 2)[0] == text.rindex("DDDDDD") + 5
    assert _array_run(dark[0], probe, 8.0, band[0], 2) == text.rindex("DDDDDD") + 5
    dark, band = _pattern("DDDDDDDDDD..BBBBBBB" + "." * 20 + "DD")
    assert survey._array_runs(dark, probe, 8.0, band, 2)[0] == 9


def test_part_dark_stretches_past_the_run_end() -> None:
    """Bands blurred into the body: darkness alternating 0.6 / 0.0 past the run's end begins a
    stretch per band and is refused as the array going on; shading at 0.3 +- 0.05 (never clear
    of it) is one stretch, and so is a single bubble's far rim."""
    rng = np.random.default_rng(0)
    end = np.array([19])
    blurred = np.r_[np.ones(20), np.tile([0.6, 0.6, 0.6, 0.0, 0.0, 0.0, 0.0], 6)]
    shaded = np.r_[np.ones(20), 0.3 + rng.uniform(-0.05, 0.05, 42)]
    rim = np.r_[np.ones(20), np.zeros(5), 0.8, 0.8, np.zeros(35)]
    for darkness, expected in ((blurred, True), (shaded, False), (rim, False)):
        darkness = darkness[None, :]
        half = darkness >= 0.3
        starts = survey._part_dark_starts(darkness, 0.3, 0.15)  # the default levels
        assert survey._run_resumes(half, half, end, 8.0, 21, 21, 3, starts)[0] == expected


def test_a_line_fitted_to_one_station_gives_that_stations_value() -> None:
    """A frame whose fitted stretch holds one station gives that station's value (the median
    of a stretch too short for a line), without dividing by zero; the other frame its line's
    value at its last station."""
    rg = Ragged.of([5, 4])
    stations = rg.local.astype(float)
    values = np.array([0.0, 0.0, 7.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0])
    sel = np.array([False, False, True, False, False, True, True, True, True])
    with np.errstate(divide="raise", invalid="raise"):
        got = extrapolate_ragged(stations, values, sel, 6.0, rg)
    np.testing.assert_allclose(got, [7.0, 4.0])

"""The array's bands beside the dark run: the run is its shadow (vision/angles/shadow.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tympani.vision.angles.shadow import lanes, periodicity

STEP = 0.04  # mm between stations


def _bands(n: int, pitch_mm: float, length_mm: float, level: float) -> np.ndarray:
    """``level`` on metal bands ``length_mm`` long every ``pitch_mm`` (mm), 0 between."""
    s = STEP * np.arange(n)
    return np.where((s % pitch_mm) < length_mm, level, 0.0)


@pytest.mark.parametrize("pitch_mm, share", [(0.6, 0.4), (1.0, 0.2), (1.0, 0.4), (1.5, 0.2)])
def test_a_train_of_bands_is_periodic(pitch_mm: float, share: float) -> None:
    """Bands ``share`` of the pitch long, 0.8 contrast units above the body, over 3.7 mm, with
    noise of 0.05: measured, autocorrelation 0.58-0.69 and spread 0.29-0.51 (without noise)."""
    rng = np.random.default_rng(int(pitch_mm * 10))
    signal = _bands(93, pitch_mm, share * pitch_mm, 0.8) + rng.normal(0.0, 0.05, 93)
    corr, spread = periodicity(signal, STEP, (0.5, 1.8), 1.1)
    assert corr >= 0.5, corr
    assert 0.25 <= spread <= 0.55, spread


def test_bands_and_gaps_both_longer_than_half_the_median_are_not_seen() -> None:
    """The running median (1.1 mm) follows a band and a gap both longer than 0.55 mm: such a
    train (0.6 mm bands every 1.5 mm) is taken for slow changes of the light, and nothing is
    left of it (a known limit of the check)."""
    assert periodicity(_bands(93, 1.5, 0.6, 0.8), STEP, (0.5, 1.8), 1.1) == (0.0, 0.0)


def test_noise_and_a_slow_ramp_are_not_periodic() -> None:
    """Fluid: a slow ramp of the light (taken off by the running median) and noise of 0.05
    contrast units: no period, and a spread of the noise's size."""
    rng = np.random.default_rng(1)
    signal = np.linspace(0.0, 0.5, 93) + rng.normal(0.0, 0.05, 93)
    corr, spread = periodicity(signal, STEP, (0.5, 1.8), 1.1)
    assert corr < 0.4, corr
    assert spread < 0.06, spread


def test_periodicity_of_too_little_or_nothing() -> None:
    assert all(np.isnan(periodicity(np.ones(19), STEP, (0.5, 1.8), 1.1)))
    assert periodicity(np.full(40, 0.3), STEP, (0.5, 1.8), 1.1) == (0.0, 0.0)
    signal = np.full(60, np.nan)
    signal[::2] = _bands(60, 1.0, 0.4, 1.0)[::2]
    assert np.isfinite(periodicity(signal, STEP, (0.5, 1.0), 1.1)[0])  # the seen half, end to end


def test_lanes_take_the_brightest_on_the_array_and_beside_its_outer_edge() -> None:
    """Offsets -0.7..0.7 mm every 0.1 mm at 3 stations; the array from -0.3 to 0.3 mm; the lane
    beside it from 0.36 mm to 0.9 mm but not past 0.6 mm (the wall)."""
    offset = np.repeat(np.round(np.arange(-0.7, 0.71, 0.1), 2)[:, None], 3, axis=1)
    rel = np.zeros_like(offset)
    rel[offset == 0.0] = [0.2, 0.3, 0.1]  # on the array
    rel[offset == 0.5] = [0.9, 0.0, 0.4]  # beside it
    rel[offset == 0.7] = 5.0  # past the wall: not used
    inner, outer = np.array([-0.3, -0.3, np.nan]), np.array([0.3, 0.3, np.nan])
    on, beside = lanes(rel, offset, inner, outer, np.full(3, 0.6), 0.6)
    assert on[:2].tolist() == [0.2, 0.3] and np.isnan(on[2])
    assert beside[:2].tolist() == [0.9, 0.0] and np.isnan(beside[2])


def _edges_and_plan(n: int, extent: int, beside: np.ndarray | None):
    """A plan for a 30 px/mm view and a frame's stage 2 from station 400 on: the array's edges
    at -0.3 and 0.3 mm on its ``n`` stations (of ``extent``), in contact with nothing, the fluid
    at 200 and the array 100 grey levels darker; ``beside`` (per station, grey levels) painted
    0.45 mm out from the centre."""
    from types import SimpleNamespace

    from tympani.vision.angles import prepare_measurement
    from tympani.vision.angles.edges import Edges
    from tympani.vision.geometry import CameraPose

    plan = prepare_measurement(SimpleNamespace(pose=CameraPose(320.0, 240.0, 0.3, 30.0)), (480, 640))
    lo = 400
    offset = plan.u[:, None] * plan.half_mm[None, lo: lo + extent]
    fine = np.where(np.abs(offset) <= 0.3, 100.0, 200.0)
    if beside is not None:
        fine = np.where(np.abs(offset - 0.45) <= 0.05, beside[None, :extent], fine)
    v = np.full(n, 0.3)
    edges = Edges(lo, n, fine.astype(np.float32), np.full(extent, 200.0), np.full(extent, 100.0),
                  np.zeros(extent, int), -v, v, np.ones(n, bool), np.ones(n, bool), np.full(n, np.nan),
                  np.full(n, np.nan), 0.5, 1.0)
    return edges, plan


def test_the_lanes_end_with_the_edges_when_the_tip_lies_past_them() -> None:
    """A tip read past the last station with edges (the strip goes on to it) must not widen the
    stretch past the edges: no error, and the bands painted beside the array are found."""
    from tympani.vision.angles.shadow import band_signals, bands_beside

    edges, plan = _edges_and_plan(150, 190, None)
    step = plan.step_mm
    s = step * np.arange(190)
    bands = 200.0 + np.where((s % 1.0) < 0.4, 60.0, 0.0)  # brighter than the fluid every 1 mm
    edges, plan = _edges_and_plan(150, 190, bands)
    corr, spread, spread_on = band_signals(edges, 185.0, plan)
    assert corr >= 0.5 and spread >= 0.1 and spread_on < 0.01, (corr, spread, spread_on)
    assert bands_beside(edges, 185.0, plan)
    assert not bands_beside(_edges_and_plan(150, 190, None)[0], 185.0, plan)

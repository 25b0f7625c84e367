"""Motion start and stop from a stage's position log."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tympani.pipeline.force.motion import NoMotion, find_motion, rest_noise


def _stage(rng, *, start=2.7, travel=23.8, speed=1.25, rate=250.0, after=8.0, noise=2e-6, quantum=1e-6,
           accel_s=0.0, end=None):
    """A stage log: rest, a ramp at ``speed`` (reached after ``accel_s`` of constant acceleration), rest."""
    span = start + travel / speed + accel_s / 2 + after if end is None else end
    t = np.cumsum(rng.uniform(0.8, 1.2, int(span * rate * 1.3)) / rate)
    t = t[t <= span]
    tau = np.clip(t - start, 0.0, None)
    if accel_s > 0:
        a = speed / accel_s
        d = np.where(tau < accel_s, 0.5 * a * tau**2, 0.5 * speed * accel_s + speed * (tau - accel_s))
    else:
        d = speed * tau
    d = np.minimum(d, travel) + 1.6e-5 + rng.normal(0.0, noise, t.size)
    return t, np.round(d / quantum) * quantum


@pytest.mark.parametrize("seed, speed, rate", [(1, 1.25, 250.0), (2, 0.5, 100.0), (3, 3.0, 250.0), (4, 1.25, 50.0)])
def test_start_and_stop_within_their_brackets_and_uncertainty(seed, speed, rate):
    rng = np.random.default_rng(seed)
    t, d = _stage(rng, speed=speed, rate=rate, travel=20.0)
    m = find_motion(t, d)
    stop = 2.7 + 20.0 / speed
    assert m.start_bracket_s[0] <= 2.7 <= m.start_bracket_s[1]
    assert m.stop_bracket_s[0] <= stop <= m.stop_bracket_s[1]
    assert abs(m.start_s - 2.7) <= 1.0 / rate and abs(m.stop_s - stop) <= 1.0 / rate
    assert m.start_uncertainty_s == pytest.approx((m.start_bracket_s[1] - m.start_bracket_s[0]) / math.sqrt(12))
    assert m.start_uncertainty_s < 1.2 / rate
    assert m.stopped and m.travel_mm == pytest.approx(20.0, abs=1e-4)
    assert m.speed_mm_s == pytest.approx(speed, rel=1e-3)
    assert m.noise_mm == pytest.approx(2e-6, rel=0.5) and m.threshold_mm >= 10 * m.noise_mm
    assert m.duration_s == pytest.approx(20.0 / speed, abs=2.0 / rate)


def test_an_accelerating_start_is_found_where_the_stage_leaves():
    rng = np.random.default_rng(5)
    t, d = _stage(rng, accel_s=0.01)
    m = find_motion(t, d)
    assert 2.7 <= m.start_s <= 2.7 + 0.01  # within the acceleration, not at the ramp's extrapolation


def test_a_log_that_ends_while_moving_has_no_stop():
    rng = np.random.default_rng(6)
    t, d = _stage(rng, travel=26.5, end=20.0)  # the ramp would end at 23.9 s
    m = find_motion(t, d)
    assert not m.stopped and m.stop_s == t[-1] and math.isinf(m.stop_uncertainty_s)
    assert m.final_mm == d[-1]


def test_a_creeping_settle_counts_as_stopped():
    rng = np.random.default_rng(7)
    t, d = _stage(rng, travel=10.0)
    stop = 2.7 + 10.0 / 1.25
    d = d + np.where(t > stop, 9e-5 * np.clip((t - stop) / 0.1, 0, 1), 0.0)  # 90 nm over 0.1 s after arriving
    m = find_motion(t, d)
    assert m.stopped and abs(m.stop_s - stop) < 0.01


def test_a_log_that_never_moves():
    rng = np.random.default_rng(8)
    t = np.arange(0, 30, 0.004)
    with pytest.raises(NoMotion, match=r"never moves: its positions span .* mm over 30 s"):
        find_motion(t, 1e-5 + rng.normal(0, 2e-6, t.size))


def test_a_log_that_starts_moving_has_no_start():
    rng = np.random.default_rng(9)
    t, d = _stage(rng, start=-1.0)
    keep = t > 0.5
    with pytest.raises(NoMotion, match="starts while the stage moves"):
        find_motion(t[keep], d[keep])


def test_rest_noise_is_robust():
    rng = np.random.default_rng(10)
    x = rng.normal(0, 3e-6, 2000)
    x[::100] += 1e-3  # glitches
    assert rest_noise(x) == pytest.approx(3e-6, rel=0.1)
    assert rest_noise(np.zeros(10)) == 0.0 and rest_noise(np.zeros(2)) == 0.0

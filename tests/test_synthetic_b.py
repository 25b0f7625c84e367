"""Tests of the family-B synthetic generator (run: ``python -m pytest -q test_synthetic_b.py``).

Data sets are cached per (effect, seed, strength) so the whole file runs in well under a
minute.  Every assertion is one a broken generator could fail.
"""

from __future__ import annotations

import functools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tympani.pipeline.synthetic import family_b as sb
from tympani.pipeline.synthetic.family_b import draws, effects, phantom

SEED = 1
COLUMNS = ["trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con",
           "depth_mm", "true_force_g", "true_base_g", "true_theta_tip", "true_theta_bot"]


@functools.lru_cache(maxsize=None)
def gen(effect: str | None, seed: int = SEED, strength: float = 1.0) -> tuple[pd.DataFrame, sb.GeneratedTruth]:
    return sb.generate(effect, seed, strength=strength)


def phases(df: pd.DataFrame, truth: sb.GeneratedTruth) -> tuple[pd.Series, pd.Series, pd.Series]:
    """Boolean masks: before motion, during motion, after the stop (dwell)."""
    info = truth.base.trials
    on = df["trial"].map({k: v.t_motion_start_s for k, v in info.items()})
    off = df["trial"].map({k: v.t_motion_stop_s for k, v in info.items()})
    return df["time_s"] < on, (df["time_s"] > on) & (df["time_s"] < off), df["time_s"] >= off


def true_con(df: pd.DataFrame) -> pd.Series:
    return df["true_theta_tip"] - df["true_theta_bot"]


# ---------------------------------------------------------------------------------------
# contract geometry
# ---------------------------------------------------------------------------------------
def test_backbone_branches_meet_at_100_deg_and_width_law():
    ph = sb.Phantom()
    phi = 100.0
    r1 = ph.c * (1 - ph.d * math.log(phi - ph.phi0_deg))
    r2 = ph.a * math.exp(-ph.b * phi)
    assert abs(r1 - r2) < 1e-3 and abs(r1 - 3.298) < 2e-3
    th = np.linspace(ph.theta_start, ph.theta_end, 500)
    w = ph.width(th)  # the FULL channel width, as in vision/geometry.py
    np.testing.assert_allclose(w, np.minimum(1.5, 0.38 * ph.r(th)))
    np.testing.assert_allclose(ph.half_width(th), w / 2)
    assert w.max() == 1.5 and w.min() < 0.8


def test_walls_lie_half_the_channel_width_from_the_backbone():
    """The phantom's walls are offset by w/2 each side, w = min(1.5, 0.38 r) the full width."""
    g = sb.geometry()
    ph = g.phantom
    th = np.linspace(ph.theta_start + 0.05, phantom.THETA_LOOKUP_MAX - 0.1, 2000)  # look-up range
    th = th[np.abs(th - math.radians(ph.corner_deg)) > 0.05]  # away from the corner
    p, _, n = phantom._backbone(ph, th)
    for curve, sign in ((g.outer, 1.0), (g.inner, -1.0)):
        sd, _ = curve.signed_distance(p + sign * ph.half_width(th)[:, None] * n)
        assert np.abs(sd).max() < 1e-4
    # channel 1.5 mm wide at the start: outer and inner wall 1.5 mm apart there
    p0, _, n0 = phantom._backbone(ph, np.array([ph.theta_start + 0.05]))
    sd_o, _ = g.outer.signed_distance(p0 - 0.75 * n0)
    assert abs(sd_o[0] + 1.5) < 1e-3
    # neighbouring turns keep a wall of at least 0.15 mm between them (a check on the phantom's
    # constants; with w read as the half width the turns would overlap)
    from scipy.spatial import cKDTree

    inner_1 = g.inner.xy[(g.inner.theta >= ph.theta_start) & (g.inner.theta <= 2 * math.pi)]
    outer_2 = g.outer.xy[g.outer.theta >= 2 * math.pi]
    gap = cKDTree(outer_2).query(inner_1)[0].min()
    assert 0.15 <= gap < 0.25


def test_array_riding_the_outer_wall_reaches_about_4_rad_at_15_mm():
    """An array riding the outer wall reaches theta_tip 3.8-4.0 at 15 mm (docs/paper.md, TABLE III)."""
    g = sb.geometry()
    x = g.rider_out.at(np.array([15.0]))
    th = float(sb.point_theta(x[:, 0], x[:, 1])[0])
    assert 3.8 <= th <= 4.0
    # a generated trial's tip (which crosses the channel before riding) lands close by
    p = sb.tip_path(g, 0.0, 0.0, -0.02)
    assert 3.8 <= float(np.interp(15.0, p.depth, p.theta)) <= 4.1


def test_straight_array_slides_on_the_inner_wall_then_meets_the_outer_wall():
    g = sb.geometry()
    p = sb.tip_path(g, 0.0, 0.0, 0.0)
    assert len(p.inner_touch) >= 1  # the backbone first turns right past the entry
    assert 1.0 <= p.theta_hit <= 1.8 and 5.0 < p.d_hit < 7.5
    c = sb.wall_clearance(g, p, 17.0)
    assert min(c["tip_outer"], c["tip_inner"]) > -1e-3 and c["tip_inner"] < 1e-3
    with pytest.raises(ValueError):
        sb.tip_path(g, 0.5, 0.0)  # the tip does not fit in the entry that far out


def test_no_trial_crosses_either_wall():
    g = sb.geometry()
    worst = {"tip_outer": 1.0, "tip_inner": 1.0, "body_entry": 1.0}
    for seed in range(5):
        ds = draws.draw_dataset(seed)
        for iv in range(5):
            for it in range(10):
                tr = draws.draw_trial(seed, iv, it, 1.0, ds)
                p = sb.tip_path(g, tr["e_lat_mm"], tr["tilt_rad"], tr["kappa0_per_mm"])
                c = sb.wall_clearance(g, p, tr["final_depth_mm"])
                worst = {k: min(v, c[k]) for k, v in worst.items()}
    # the tip touches the walls (0) but never goes through them (1 um numerical tolerance)
    assert worst["tip_outer"] > -1e-3 and worst["tip_inner"] > -1e-3
    assert abs(worst["tip_outer"]) < 1e-3  # every trial rides the outer wall
    assert worst["body_entry"] >= 0.0  # the 1.1 mm thick array fits in the 1.5 mm entry


def test_point_theta_recovers_backbone_angles_on_every_turn():
    ph = sb.Phantom()
    th = np.linspace(0.3, 4 * math.pi - 0.1, 400)
    r = ph.r(th)
    got = sb.point_theta(r * np.cos(th), r * np.sin(th), ph)
    np.testing.assert_allclose(got, th, atol=1e-9)


def test_outer_wall_is_outside_backbone_and_angles_increase():
    g = sb.geometry()
    assert np.all(np.diff(g.theta) > 0)
    rho = np.hypot(g.xy[:, 0], g.xy[:, 1])
    sel = (g.theta > 0.5) & (g.theta < 4.5)
    assert np.all(rho[sel] > g.phantom.r(g.theta[sel]))
    # unit vectors, outward normal has a positive radial component
    np.testing.assert_allclose(np.linalg.norm(g.n_out, axis=1), 1.0, atol=1e-9)
    radial = (g.n_out * g.xy).sum(axis=1) / rho
    assert np.all(radial[sel] > 0.3)
    # x_w is the tangent at theta_start and points into the spiral (towards smaller radius)
    assert g.x_w @ g.p0 < 0


# ---------------------------------------------------------------------------------------
# API, determinism, truth
# ---------------------------------------------------------------------------------------
def test_columns_types_and_truth_keys():
    df, truth = gen(None)
    assert list(df.columns) == COLUMNS
    assert df["trial"].map(type).eq(str).all()
    assert df["trial"].nunique() == 50
    assert (df.groupby("trial")["speed_mm_s"].nunique() == 1).all()
    assert sorted(df["speed_mm_s"].unique()) == [0.5, 1.5, 3.0, 5.0, 7.5]
    for key in ("effect", "strength", "params", "base", "noise", "gap_rms_g", "noise_rms_g",
                "snr", "family"):
        assert key in truth.to_json()
    assert truth.family == "B"
    json.dumps(truth.to_json())  # serialisable


def test_same_seed_identical_and_other_seed_different():
    a, ta = sb.generate("capstan", 7, trials=2)
    b, tb = sb.generate("capstan", 7, trials=2)
    pd.testing.assert_frame_equal(a, b)
    assert json.dumps(ta.to_json(), sort_keys=True) == json.dumps(tb.to_json(), sort_keys=True)
    c, _ = sb.generate("capstan", 8, trials=2)
    assert len(a) != len(c) or not np.allclose(a["force_g"], c["force_g"])


def test_base_is_shared_between_effects_with_the_same_seed():
    df0, _ = gen(None)
    for eff in ("hydrodynamic_lift", "sensor_drift"):
        df1, _ = gen(eff)
        np.testing.assert_array_equal(df0["true_base_g"], df1["true_base_g"])
        np.testing.assert_array_equal(df0["theta_tip"].fillna(-9), df1["theta_tip"].fillna(-9))


def test_no_effect_means_truth_equals_base_and_noise_is_sane():
    df, truth = gen(None)
    np.testing.assert_array_equal(df["true_force_g"], df["true_base_g"])
    assert truth.gap_rms_g == 0.0 and truth.snr == 0.0
    resid = df["force_g"] - df["true_force_g"]
    rms = float(np.sqrt(np.mean(resid**2)))
    assert math.isclose(rms, truth.noise_rms_g, rel_tol=1e-9)
    assert 0.02 < rms < 0.07
    assert abs(resid.mean()) < 0.02
    # 13-bit quantisation: every reading is a multiple of the LSB
    lsb = truth.noise.lsb_g
    k = df["force_g"] / lsb
    assert np.allclose(k, np.round(k), atol=1e-6)


@pytest.mark.parametrize("eff", sb.EFFECTS)
def test_strength_zero_is_no_effect(eff):
    df, truth = sb.generate(eff, 3, strength=0.0, speeds_mm_s=(0.5, 7.5), trials=2)
    np.testing.assert_allclose(df["true_force_g"], df["true_base_g"], atol=1e-9)


def test_noise_scale_scales_the_noise():
    _, t1 = sb.generate(None, 2, trials=2)
    _, t2 = sb.generate(None, 2, trials=2, noise_scale=2.0)
    assert 1.7 < t2.noise_rms_g / t1.noise_rms_g < 2.3


def test_bad_arguments():
    with pytest.raises(ValueError):
        sb.generate("friction_heating", 0)
    with pytest.raises(ValueError):
        sb.generate("capstan", 0, strength=-1.0)


def test_gap_and_snr_are_what_the_truth_says():
    df, truth = gen("viscous_drag")
    gap = df["true_force_g"] - df["true_base_g"]
    assert math.isclose(float(np.sqrt(np.mean(gap**2))), truth.gap_rms_g, rel_tol=1e-9)
    assert math.isclose(truth.snr, truth.gap_rms_g / truth.noise_rms_g, rel_tol=1e-12)


# ---------------------------------------------------------------------------------------
# time, depth and angles
# ---------------------------------------------------------------------------------------
def test_time_depth_and_angles_are_sane():
    df, truth = gen(None)
    for name, g in df.groupby("trial"):
        t = g["time_s"].to_numpy()
        assert t[0] == 0.0 and np.all(np.diff(t) > 0)
        d = g["depth_mm"].to_numpy()
        assert np.all(np.diff(d) >= -1e-12)
        assert 12.0 <= d[-1] <= 18.0 and abs(d[0]) <= 0.5 + 1e-9
        info = truth.base.trials[name]
        assert 0.3 <= info.pre_roll_s <= 2.0 and 1.0 <= info.dwell_s <= 4.0
        v = info.speed_actual_mm_s / g["speed_mm_s"].iloc[0]
        assert 0.98 <= v <= 1.02
        tip = g["true_theta_tip"].to_numpy()
        assert np.all(np.diff(tip) >= -1e-12)
        assert 1.0 <= info.theta_hit <= 1.8  # first contact on the outer wall
        assert 3.0 < tip[-1] < 4.8
    con = true_con(df)
    assert (con >= 0).all() and con.max() > 1.5
    # measured angles: theta_con = tip - bot, within noise of the truth
    m = df.dropna(subset=["theta_tip"])
    np.testing.assert_allclose(m["theta_con"], m["theta_tip"] - m["theta_bot"], atol=1e-12)
    assert (m["theta_bot"] <= m["theta_tip"] + 1e-12).all()
    sd_tip = truth.noise.angle_sd_tip
    sd_bot = truth.noise.angle_sd_bot
    assert np.abs(m["theta_tip"] - m["true_theta_tip"]).quantile(0.99) < 4 * sd_tip + 0.01
    assert np.abs(m["theta_bot"] - m["true_theta_bot"]).quantile(0.99) < 4 * sd_bot + 0.02
    # before contact the tracker reports theta_bot = theta_tip, theta_con = 0
    # (away from the frame interval in which contact begins)
    hit = m["trial"].map({k: v.theta_hit for k, v in truth.base.trials.items()})
    pre = m[m["true_theta_tip"] < hit - 0.15]
    assert len(pre) > 0 and (pre["theta_con"] == 0).all()
    # NaN only where there is no video frame: a small share
    assert 0 < df["theta_tip"].isna().mean() < 0.1


def test_contact_start_moves_differently_between_trials():
    _, truth = gen(None, 2)
    ends = [v.theta_bot_end - v.theta_hit for v in truth.base.trials.values()]
    assert np.std(ends) > 0.03


# ---------------------------------------------------------------------------------------
# signatures
# ---------------------------------------------------------------------------------------
def test_lift_relative_drop_grows_with_speed_at_every_theta_con():
    df, truth = gen("hydrodynamic_lift")
    _, moving, _ = phases(df, truth)
    con = true_con(df)
    sel = moving & (con > 0.5)
    rel = (1.0 - df["true_force_g"] / df["true_base_g"]).where(sel)
    bins = pd.cut(con, [0.5, 1.0, 1.5, 2.0, 2.5])
    tab = rel.groupby([bins, df["speed_mm_s"]], observed=True).mean().unstack()
    for _, row in tab.iterrows():
        vals = row.dropna().to_numpy()
        assert np.all(np.diff(vals) > 0), row
        assert vals[-1] > 0.1  # present at every theta_con at the fastest speed
    drop = sb.peak_drop(df, truth, base_corrected=True)
    assert 0.15 < drop[7.5] < 0.5 and drop[3.0] > 0.03 and drop[7.5] > drop[3.0] > drop[1.5]


def test_lift_film_squeezes_out_after_the_stop():
    df, truth = gen("hydrodynamic_lift")
    g = df[df["trial"] == "v4_t00"]
    info = truth.base.trials["v4_t00"]
    after = g[g["time_s"] > info.t_motion_stop_s + 0.05]
    ratio = (after["true_force_g"] / after["true_base_g"]).to_numpy()
    assert ratio[0] < 0.9 and np.all(np.diff(ratio) > -1e-9) and ratio[-1] > ratio[0] + 0.05


def test_drag_adds_force_growing_with_speed_and_vanishing_at_rest():
    df, truth = gen("viscous_drag")
    before, moving, dwell = phases(df, truth)
    gap = (df["true_force_g"] - df["true_base_g"]) / df["trial"].map(
        {k: v.gain for k, v in truth.base.trials.items()})
    cruise = moving & (true_con(df) > 1.0)
    by_v = gap[cruise].groupby(df["speed_mm_s"][cruise]).mean().to_numpy()
    assert np.all(by_v > 0) and np.all(np.diff(by_v) > 0)
    assert np.abs(gap[dwell | before]).max() < 1e-12
    # not proportional to the wetted length: drag per mm of wetted array grows with contact
    g = df[(df["trial"] == "v4_t01") & moving]
    wet = g["depth_mm"] + 5.0
    per_mm = (gap[g.index] / wet)
    early = per_mm[true_con(g) == 0].median()
    late = per_mm[true_con(g) > 1.5].median()
    assert late > 3 * early


def test_capstan_grows_with_wrap_and_is_speed_independent():
    df, truth = gen("capstan")
    con = true_con(df)
    rel = (df["true_force_g"] / df["true_base_g"] - 1.0).where(con > 0.5)
    assert (df["true_force_g"] - df["true_base_g"])[con > 0.3].min() > -1e-9
    by_con = rel.groupby(pd.cut(con, [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]), observed=True).mean()
    assert np.all(np.diff(by_con.to_numpy()) > 0) and by_con.iloc[-1] > 0.05
    mid = (con > 1.5) & (con < 2.5)
    by_v = rel[mid].groupby(df["speed_mm_s"][mid]).mean()
    assert by_v.max() - by_v.min() < 0.25 * by_v.mean()


def test_capstan_belt_equation_limits():
    g = sb.geometry()
    arc = sb.contact_arc(g, np.array([1.2, 1.2]), np.array([3.4, 3.4]))
    p = sb.linear_pressure(arc, np.array([0.1, 0.1]), np.array([0.2, 0.2]))
    mu = np.array([0.12, 0.12])
    base = sb.arc_force_g(arc, p, mu, 0.035)
    np.testing.assert_allclose(effects.capstan_force_g(arc, p, mu, 0.035, 0.0, 0.1), base, rtol=1e-9)
    f1 = effects.capstan_force_g(arc, p, mu, 0.035, 1.0, 0.1)
    f2 = effects.capstan_force_g(arc, p, mu * 2, 0.035, 1.0, 0.1)
    base2 = sb.arc_force_g(arc, p, mu * 2, 0.035)
    assert f1[0] > base[0] and (f2[0] - base2[0]) > 1.5 * (f1[0] - base[0])
    # the wrap, not theta_con alone: same theta_con further along the spiral turns more wall
    arc_b = sb.contact_arc(g, np.array([1.8]), np.array([4.0]))
    pb = sb.linear_pressure(arc_b, np.array([0.1]), np.array([0.2]))
    turn_a = np.sum(np.maximum(arc.kappa[0], 0) * arc.ds[0])
    turn_b = np.sum(np.maximum(arc_b.kappa[0], 0) * arc_b.ds[0])
    assert turn_b > turn_a
    gain_a = effects.capstan_force_g(arc, p, mu, 0.035, 1.0, 0.1)[0] - base[0]
    gain_b = (effects.capstan_force_g(arc_b, pb, mu[:1], 0.035, 1.0, 0.1)[0]
              - sb.arc_force_g(arc_b, pb, mu[:1], 0.035)[0])
    assert not math.isclose(gain_a, gain_b, rel_tol=0.05)


def test_lag_lags_during_the_ramp_and_relaxes_after_the_stop():
    df, truth = gen("sensor_lag")
    _, moving, dwell = phases(df, truth)
    gap = df["true_force_g"] - df["true_base_g"]
    by_v = gap[moving].groupby(df["speed_mm_s"][moving]).mean().to_numpy()
    assert np.all(by_v < 0) and np.all(np.diff(by_v) < 0)  # grows with v
    delay = truth.effect_params["delay_s"]
    shifts = np.arange(0.0, 1.5, 0.01)
    for name in ("v4_t00", "v3_t02"):
        g = df[df["trial"] == name]
        info = truth.base.trials[name]
        t, b, f = (g[c].to_numpy() for c in ("time_s", "true_base_g", "true_force_g"))
        stop = t >= info.t_motion_stop_s
        # relaxes after the stop: large deficit at the stop, small at the end of the dwell
        assert abs(f[stop][0] - b[stop][0]) > 5 * abs(f[-1] - b[-1])
        assert f[stop][-1] > f[stop][0]
        err = [np.mean((np.interp(t - s, t, b) - f) ** 2) for s in shifts]
        est = shifts[int(np.argmin(err))]
        assert 0.5 * delay < est < 1.6 * delay


def test_drift_largest_in_long_trials_and_present_before_contact():
    df, truth = gen("sensor_drift")
    gap = df["true_force_g"] - df["true_base_g"]
    end = gap.groupby(df["trial"]).last().abs()
    dur = df.groupby("trial")["time_s"].max()
    rho = pd.Series(end).corr(dur, method="spearman")
    assert rho > 0.7
    v = df.groupby("trial")["speed_mm_s"].first()
    assert end[v == 0.5].mean() > 1.5 * end[v == 7.5].mean()
    # not a linear drift: a straight line leaves a clear residual on the longest trial
    g = df[df["trial"] == dur.idxmax()]
    d = (g["true_force_g"] - g["true_base_g"]).to_numpy()
    t = g["time_s"].to_numpy()
    res = d - np.polyval(np.polyfit(t, d, 1), t)
    assert np.sqrt(np.mean(res**2)) > 0.02 * np.ptp(d)
    no_contact = true_con(df) == 0
    assert gap[no_contact].abs().mean() > 0.05
    before, _, _ = phases(df, truth)
    assert gap[before].abs().min() > 0  # already drifting when the log starts


def test_profile_is_speed_independent_and_shape_changes_with_theta_con():
    df, truth = gen("pressure_profile")
    con = true_con(df)
    rel = (df["true_force_g"] / df["true_base_g"] - 1.0).where(con > 0.5)
    bins = pd.cut(con, [0.5, 1.0, 1.5, 2.0, 2.5])
    tab = rel.groupby([bins, df["speed_mm_s"]], observed=True).mean().unstack()
    spread = (tab.max(axis=1) - tab.min(axis=1)).to_numpy()
    level = tab.abs().mean(axis=1).to_numpy()
    assert np.all(spread < 0.02 + 0.15 * level)
    assert level[-1] > 3 * level[0] and level[-1] > 0.05


def test_profile_preserves_the_load_and_concentrates_it_at_the_ends():
    g = sb.geometry()
    arc = sb.contact_arc(g, np.array([1.0]), np.array([3.8]))
    pt, pb = np.array([0.1]), np.array([0.2])
    lin = sb.linear_pressure(arc, pt, pb)
    prof = effects.profile_pressure(arc, lin, pt, pb, 1.0, 1.0)
    assert math.isclose(prof.sum(), lin.sum(), rel_tol=1e-9)
    mid = slice(arc.u.size // 3, 2 * arc.u.size // 3)
    assert prof[0, mid].mean() < 0.5 * lin[0, mid].mean()
    assert prof[0, 0] > lin[0, 0] and prof[0, -1] > lin[0, -1]


# ---------------------------------------------------------------------------------------
# strength and timing
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("eff", sb.EFFECTS)
def test_snr_at_strength_one_is_at_least_three(eff):
    for seed in (0, 1, 2):
        _, truth = gen(eff, seed)
        assert truth.snr >= 3.0, (eff, seed, truth.snr)
    _, weak = gen(eff, 1, 0.3)
    _, strong = gen(eff, 1, 1.0)
    assert weak.gap_rms_g < 0.6 * strong.gap_rms_g


def test_generation_time_is_reported():
    t0 = time.perf_counter()
    df, _ = sb.generate("capstan", 11)
    dt = time.perf_counter() - t0
    print(f"\n5 speeds x 10 trials ({len(df)} rows, capstan): {dt:.2f} s")
    assert len(df) > 5000

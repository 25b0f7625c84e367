"""Synthetic experiments with hidden effects (pipeline.synthetic.family_a): signatures, no inverse crime,
the paper case, files that round-trip through ``tympani sync``."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import least_squares

from tympani.pipeline.cli import main
from tympani.pipeline.model.effects import EFFECTS, EffectContext
from tympani.pipeline.model.friction import stribeck
from tympani.pipeline.model.paper import paper_params
from tympani.pipeline.synthetic.family_a import (
    HIDDEN_EFFECTS,
    PAPER_DROPS_PCT,
    NoiseConfig,
    Variability,
    angles_at_depth,
    paper_case,
    peak_force_drop,
    synthetic_dataset,
    write_experiment,
)
from tympani.vision.rendering import pose_at_depth

QUIET = NoiseConfig(white_g=0.0, ar_g=0.0, tare_sd_g=0.0, bits=0, angle_sd_rad=0.0)
SPEEDS = (0.5, 1.5, 3.0, 5.0, 7.5)
PARAMS = paper_params()

#: Fixed effect parameters (strength ~1) so that the signature tests do not depend on draws.
FIXED = {
    "hydrodynamic_lift": dict(film_ratio=0.29, speed_exponent=0.65, load_exponent=0.21, share_power=1.18,
                              squeeze_time_s=5.0),
    "viscous_drag": dict(viscosity_Pa_s=1.2, film_um=1.5, gap_min_mm=0.1),
    "capstan": dict(capstan_gain=1.0),
    "sensor_lag": dict(pole_time_s=0.12, dead_time_s=0.03),
    "sensor_drift": dict(drift_g_per_s=0.025, curvature=0.3, walk_g_per_sqrt_s=0.004, trial_jitter=0.2),
    "pressure_profile": dict(bump_gain=0.5, bending_length_mm=2.5, bump_shape=2.0),
}


def _clean(effect: str | None, *, seed: int = 3, trials: int = 3) -> pd.DataFrame:
    """Noiseless rows (paired placements) with base and effect forces, phase and the trial's speed law."""
    synced, truth = synthetic_dataset(np.random.default_rng(seed), effect, noise=QUIET, trials=trials,
                                      variability=Variability(paired=True),
                                      effect_params=FIXED.get(effect) if effect else None)
    clean = truth.tables.clean
    stop = {d.trial: d.t_stop_s for d in truth.trials}
    df = synced.assign(base=clean["force_base_g"].to_numpy(), eff=clean["force_effect_g"].to_numpy())
    df["gap"] = df["eff"] - df["base"]
    df["t_stop"] = df["trial"].map(stop)
    df["phase"] = np.where(df["time_s"] < 0.5, "pre", np.where(df["time_s"] < df["t_stop"], "insert", "dwell"))
    return df


def _insert_rel(df: pd.DataFrame) -> pd.DataFrame:
    ins = df[(df["phase"] == "insert") & (df["base"] > 0.5)].copy()
    ins["rel"] = ins["gap"] / ins["base"]
    ins["con_bin"] = pd.cut(ins["theta_con"], [0.0, 0.75, 1.25, 1.75, 3.0])
    return ins


def _dwell_ends(df: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    dwell = df[df["phase"] == "dwell"].groupby("trial")["gap"]
    return dwell.first(), dwell.last()


# --------------------------------------------------------------------------- signatures


def test_generators_cover_the_spec_names():
    from tympani.pipeline.model.effects import effect_names

    assert set(HIDDEN_EFFECTS) == set(effect_names())
    for eff in HIDDEN_EFFECTS.values():
        assert eff.form != eff.library_form and eff.ranges


def test_none_and_strength_zero_change_nothing():
    df = _clean(None, trials=1)
    assert np.array_equal(df["eff"].to_numpy(), df["base"].to_numpy())
    for name in HIDDEN_EFFECTS:
        synced, truth = synthetic_dataset(np.random.default_rng(1), name, strength=0.0, noise=QUIET, trials=1,
                                          speeds_mm_s=(0.5, 7.5))
        clean = truth.tables.clean
        np.testing.assert_allclose(clean["force_effect_g"], clean["force_base_g"], atol=1e-9, err_msg=name)
        assert truth.gap_rms_g < 1e-9 and not truth.detectable


def test_lift_relative_drop_grows_with_speed_at_every_theta_con_and_persists_in_the_dwell():
    df = _clean("hydrodynamic_lift")
    table = _insert_rel(df).pivot_table(index="con_bin", columns="speed_mm_s", values="rel", observed=True)
    assert (table.to_numpy() < -0.05).all()  # present at every theta_con, at every speed
    assert (np.diff(table.to_numpy(), axis=1) < 0).all()  # the drop grows with v in every bin
    assert (table[7.5] < -0.35).all()
    first, last = _dwell_ends(df)
    assert (first < 0).all() and (last / first > 0.7).all()  # the film squeezes out slowly: lift stays


def test_drag_adds_force_growing_with_speed_and_depth_and_vanishes_at_rest():
    df = _clean("viscous_drag")
    moving = df[df["phase"] == "insert"]
    assert (moving["gap"] > 0).all()
    per_speed = moving.groupby("speed_mm_s")["gap"].mean()
    assert (np.diff(per_speed.to_numpy()) > 0).all()
    # roughly proportional to v at matched depth (the wetted geometry is the same)
    deep = moving[moving["depth_mm"].between(12.0, 14.0)].groupby("speed_mm_s")["gap"].mean()
    ratio = deep / deep.index.to_numpy()
    assert ratio.max() / ratio.min() < 1.3
    for _, trial in moving.groupby("trial"):
        assert np.corrcoef(trial["depth_mm"], trial["gap"])[0, 1] > 0.9
    assert np.abs(df.loc[df["phase"] != "insert", "gap"]).max() < 1e-12


def test_capstan_grows_with_theta_con_and_its_log_slope_follows_mu():
    df = _clean("capstan")
    ins = _insert_rel(df)
    ins["rel_per_mu"] = ins["rel"] / stribeck(ins["speed_mm_s"].to_numpy(), PARAMS)
    table = ins.pivot_table(index="con_bin", columns="speed_mm_s", values="rel_per_mu", observed=True)
    by_con = table.mean(axis=1).to_numpy()
    # friction transmitted along the insertion axis (the default projection) is amplified from the
    # first bin on, so the growth is gentler than with the vector sum: 1.57x over the bins, measured
    assert (np.diff(by_con) > 0).all() and by_con[-1] > 1.4 * by_con[0]
    spread = table.max(axis=1) / table.min(axis=1)  # nearly independent of v once divided by mu(v)
    assert (spread < 1.1).all()
    first, last = _dwell_ends(df)
    assert (first > 0).all() and np.allclose(first, last, rtol=1e-3)  # holds at rest


def test_lag_follows_dfdt_grows_with_speed_and_relaxes_in_the_dwell():
    df = _clean("sensor_lag")
    rms = df.groupby("speed_mm_s")["gap"].apply(lambda g: np.sqrt(np.mean(g**2)))
    assert (np.diff(rms.to_numpy()) > 0).all()
    for _, trial in df[df["speed_mm_s"] >= 3.0].groupby("trial"):
        ins = trial[trial["phase"] == "insert"]
        dfdt = np.gradient(ins["base"].to_numpy(), ins["time_s"].to_numpy())
        assert np.corrcoef(-dfdt, ins["gap"])[0, 1] > 0.9  # the shortfall is where dF/dt is
    first, last = _dwell_ends(df)
    fast = first.index.str.startswith("v7p5")
    assert (first[fast] < -0.3).all()
    assert (np.abs(last) < 0.05 * np.abs(first).max()).all()  # relaxes after the stop


def test_drift_grows_with_time_is_largest_in_slow_trials_and_shows_before_contact():
    df = _clean("sensor_drift")
    pre = df[df["phase"] == "pre"]
    assert np.abs(pre["gap"]).max() > 1e-3
    ends = df.groupby(["speed_mm_s", "trial"])["gap"].last().abs().groupby("speed_mm_s").mean()
    assert ends[0.5] > 5 * ends[7.5]
    for _, trial in df[df["speed_mm_s"] == 0.5].groupby("trial"):
        assert np.corrcoef(trial["time_s"], np.abs(trial["gap"]))[0, 1] > 0.9


def test_pressure_profile_is_a_shape_change_independent_of_speed():
    df = _clean("pressure_profile")
    table = _insert_rel(df).pivot_table(index="con_bin", columns="speed_mm_s", values="rel", observed=True)
    assert (table.max(axis=1) - table.min(axis=1) < 0.01).all()  # independent of v
    by_con = table.mean(axis=1)
    assert (by_con > 0.02).all()
    assert by_con.max() - by_con.min() > 0.1 * by_con.mean()  # not a constant factor: a shape error


def test_gap_against_noise_at_strength_one_is_reported_and_detectable():
    for name in HIDDEN_EFFECTS:
        _, truth = synthetic_dataset(np.random.default_rng(11), name, trials=2)
        assert truth.effect == name and truth.gap_to_noise > 3.0, (name, truth.gap_to_noise)
        assert truth.detectable
        assert 0.02 < truth.noise_rms_g < 0.08
        json.dumps(truth.to_json())  # JSON-ready apart from the tables


# --------------------------------------------------------------------------- no inverse crime


@pytest.mark.parametrize("name", list(HIDDEN_EFFECTS))
def test_library_form_does_not_fit_the_generator_exactly(name):
    df = _clean(name, trials=2, seed=5)
    rows = (df["phase"] == "insert").to_numpy()
    table = df[rows].reset_index(drop=True)
    ctx = EffectContext.from_synced(table)
    mu = stribeck(table["speed_mm_s"].to_numpy(), PARAMS)
    base, target = table["base"].to_numpy(), table["eff"].to_numpy()
    effect = EFFECTS[name]

    def residual(x):
        return effect.apply(base, ctx, x, mu) - target

    best = None
    for x0 in (effect.start, effect.null):
        x0 = np.clip(np.asarray(x0, float), np.asarray(effect.lower) + 1e-9, np.asarray(effect.upper) - 1e-9)
        fit = least_squares(residual, x0, bounds=(effect.lower, effect.upper))
        best = fit if best is None or fit.cost < best.cost else best
    gap = np.sqrt(np.mean((target - base) ** 2))
    left = np.sqrt(np.mean(best.fun**2))
    assert left > 0.03 * gap, f"{name}: library form fits the generator to {left / gap:.1%} of the gap"
    assert left < gap  # but it does capture the effect's direction


# --------------------------------------------------------------------------- paper case


def test_paper_case_hits_the_papers_drops():
    synced, truth = paper_case(np.random.default_rng(0))
    drops = peak_force_drop(synced).set_index("speed_mm_s")["change_pct"]
    for speed, target in PAPER_DROPS_PCT.items():
        assert abs(drops[speed] - target) <= 3.0, (speed, drops[speed])
    base = truth.paper.base_model.set_index("speed_mm_s")["change_pct"]
    assert base.abs().max() <= 2.0
    assert sorted(synced["speed_mm_s"].unique()) == list(SPEEDS)
    assert synced.groupby("speed_mm_s")["trial"].nunique().eq(10).all()
    assert synced["depth_mm"].max() == pytest.approx(15.0)


def test_peak_force_drop_table():
    df = pd.DataFrame({"trial": np.repeat(["a", "b", "c", "d"], 5), "speed_mm_s": np.repeat([1.0, 1.0, 2.0, 2.0], 5),
                       "time_s": np.tile(np.arange(5) * 0.1, 4),
                       "force_g": np.r_[[0, 1, 2, 1, 0], [0, 1, 4, 1, 0], [0, 1, 1.5, 1, 0], [0, 1, 1.5, 1, 0]]})
    table = peak_force_drop(df, smooth_s=0.0)
    assert table["peak_force_g"].tolist() == [3.0, 1.5]
    assert table["change_pct"].tolist() == [0.0, -50.0]


# --------------------------------------------------------------------------- geometry, noise, files


def test_kinematics_agree_with_the_renderer():
    from tympani.vision.rendering import random_policy

    policy = random_policy(np.random.default_rng(4))
    depths = np.array([-0.5, 1.0, 4.0, 7.0, 10.0, 13.0, 15.0])
    tip, bot = angles_at_depth(depths, policy, 15.0)
    for d, a, b in zip(depths, tip, bot):
        truth = pose_at_depth(d, policy).truth
        assert abs(a - truth.theta_tip) < 0.025 and abs(b - truth.theta_bot) < 0.025, d


def test_dataset_layout_noise_and_reproducibility():
    a, truth = synthetic_dataset(np.random.default_rng(7), "capstan", speeds_mm_s=(1.5, 7.5), trials=2)
    b, _ = synthetic_dataset(np.random.default_rng(7), "capstan", speeds_mm_s=(1.5, 7.5), trials=2)
    pd.testing.assert_frame_equal(a, b)
    assert list(a.columns) == ["trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con",
                               "depth_mm"]
    lsb = NoiseConfig().lsb_g()
    np.testing.assert_allclose(a["force_g"] / lsb, np.round(a["force_g"] / lsb), atol=1e-6)
    for _, trial in a.groupby("trial"):
        depth = trial["depth_mm"].to_numpy()
        assert depth[0] == -1.0 and depth[-1] == pytest.approx(15.0)
        held = np.sum(depth == depth[-1]) * 0.02
        assert held == pytest.approx(1.0, abs=0.05)  # the dwell
        assert (trial["theta_con"].iloc[:25] == 0).all()  # samples before contact
        assert (trial["theta_con"] >= 0).all()
    resid = a["force_g"].to_numpy() - truth.tables.clean["force_effect_g"].to_numpy()
    r = resid[: truth.trials[0].n_samples]
    assert np.corrcoef(r[:-1], r[1:])[0, 1] > 0.3  # correlated, not only white noise
    speeds = {d.trial: d.actual_speed_mm_s / d.speed_mm_s for d in truth.trials}
    assert all(0.98 <= s <= 1.02 for s in speeds.values())


def test_written_experiment_round_trips_through_sync(tmp_path, capsys):
    """A written experiment syncs back to the same table; resampled at 24 frames/s its contact
    angle agrees within the angle noise (measured: |difference| max 0.026 rad, median 0.0008)."""
    synced, truth = synthetic_dataset(np.random.default_rng(2), "sensor_lag", speeds_mm_s=(1.5, 7.5), trials=2,
                                      video_t0_s=0.3)
    manifest = write_experiment(tmp_path / "exp", synced, truth)
    assert set(manifest.columns) >= {"trial", "speed_mm_s", "angles", "force", "fps", "video_t0_s"}
    out = tmp_path / "synced.csv"
    assert main(["sync", "--manifest", str(tmp_path / "exp" / "manifest.csv"), "--out", str(out), "-q"]) == 0
    back = pd.read_csv(out)
    assert back["trial"].tolist() == synced["trial"].tolist()
    for col in ("speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con", "depth_mm"):
        np.testing.assert_allclose(back[col], synced[col], atol=1e-9, equal_nan=True, err_msg=col)
    assert synced["theta_tip"].isna().sum() > 0  # force samples before frame 0 have no angles, as after sync
    meta = json.loads((tmp_path / "exp" / "truth" / "effect.json").read_text())
    assert meta["effect"] == "sensor_lag" and "tables" not in meta
    # resampled at another frame rate the angles agree within the angle noise
    write_experiment(tmp_path / "exp24", synced, truth, angles_fps=24.0)
    out24 = tmp_path / "synced24.csv"
    assert main(["sync", "--manifest", str(tmp_path / "exp24" / "manifest.csv"), "--out", str(out24), "-q"]) == 0
    back24 = pd.read_csv(out24)
    diff = (back24["theta_con"] - synced["theta_con"]).abs()
    assert diff.max() < 0.05 and np.nanmedian(diff) < 0.002


def test_default_dataset_is_five_speeds_of_ten_trials():
    """The default dataset: 5 speeds x 10 trials. How long it takes is a figure of ``tympani
    bench`` (its diagnosis section), not a test."""
    synced, _ = synthetic_dataset(np.random.default_rng(0), "hydrodynamic_lift")
    assert synced["trial"].nunique() == 50 and synced["speed_mm_s"].nunique() == 5


# --------------------------------------------------------------------------- command line


def test_render_no_video_with_effect(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["render", "--out", str(out), "--no-video", "--effect", "capstan", "--trials", "1",
                 "--speeds", "1.5,7.5", "--seed", "3", "-q"]) == 0
    meta = json.loads((out / "truth" / "effect.json").read_text())
    assert meta["effect"] == "capstan" and meta["gap_rms_g"] > 0
    manifest = pd.read_csv(out / "manifest.csv")
    assert len(manifest) == 2 and (out / manifest["angles"][0]).is_file()
    assert main(["render", "--out", str(tmp_path / "n"), "--no-video", "--effect", "none", "--trials", "1",
                 "--speeds", "3", "-q"]) == 0
    assert json.loads((tmp_path / "n" / "truth" / "effect.json").read_text())["effect"] is None
    assert main(["render", "--out", str(tmp_path / "x"), "--no-video", "--effect", "gremlins"]) == 2
    assert "unknown --effect" in capsys.readouterr().err


def test_render_video_with_effect_changes_only_the_force(tmp_path):
    common = ["--speeds", "7.5", "--trials", "1", "--max-frames", "12", "--size", "320x240", "--seed", "4",
              "--dwell", "0.5", "-q"]
    assert main(["render", "--out", str(tmp_path / "a"), "--effect", "none", *common]) == 0
    assert main(["render", "--out", str(tmp_path / "b"), "--effect", "viscous_drag", "--strength", "2", *common]) == 0
    fa = pd.read_csv(tmp_path / "a" / "force" / "v7p5_t01.csv")
    fb = pd.read_csv(tmp_path / "b" / "force" / "v7p5_t01.csv")
    ta = pd.read_csv(tmp_path / "a" / "truth" / "v7p5_t01.csv")
    tb = pd.read_csv(tmp_path / "b" / "truth" / "v7p5_t01.csv")
    pd.testing.assert_frame_equal(ta, tb)  # same video truth
    diff = fb["force_g"] - fa["force_g"]
    moving = np.gradient(fa["depth_mm"].to_numpy()) > 0
    assert (diff[moving & (fa["depth_mm"] > 2)] > 0).all()  # drag adds force while moving
    assert np.abs(diff[~moving]).max() < 0.01  # and nothing at rest (up to one A/D step)
    meta = json.loads((tmp_path / "b" / "truth" / "effect.json").read_text())
    assert meta["effect"] == "viscous_drag" and meta["strength"] == 2.0 and meta["mode"] == "video"

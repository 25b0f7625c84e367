"""Identification of friction and pressure parameters from synced tables, and the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from tympani.pipeline.cli import main
from tympani.pipeline.force.sync import read_synced
from tympani.pipeline.model.friction import FLAT_NAMES, FrictionParams, LinearPressure, arc_integrals, flat_params, force_from_integrals
from tympani.pipeline.model.identify import (
    DEFAULT_FREE,
    FitOptions,
    _build,
    _ci95,
    _model_jacobian,
    PARAM_BOUNDS,
    fit_synced,
    fit_to_json,
    synthetic_synced,
    validate_synced,
)
from tympani.vision.errors import InputError

TRUTH = FrictionParams(mu_s=0.18, mu_k=0.12, v_s_mm_s=3.0, delta_s=2.0, mu_v_s_per_mm=0.0, contact_width_mm=0.3,
                       p_tip_MPa=LinearPressure(0.01, 0.01), p_bot_MPa=LinearPressure(0.02, 0.02))
#: first start away from the truth
START = FrictionParams(mu_s=0.3, mu_k=0.2, v_s_mm_s=1.0, delta_s=2.0, contact_width_mm=0.3,
                       p_tip_MPa=LinearPressure(0.03), p_bot_MPa=LinearPressure(0.03))


def _z(estimate, true: float) -> float:
    """Error in reported standard errors (on the log scale for log-scale parameters)."""
    if estimate.log_scale:
        return math.log(estimate.value / true) * estimate.value / estimate.stderr
    return (estimate.value - true) / estimate.stderr


@pytest.fixture(scope="module")
def white_fit():
    rng = np.random.default_rng(11)
    table = synthetic_synced(TRUTH, rng=rng, trials=5, noise_rel=0.03)
    return table, fit_synced(table, FitOptions(base=START, starts=6, seed=1))


def test_ci95_linear_log_and_beyond_exp_range():
    assert _ci95(2.0, 0.5, log_scale=False) == pytest.approx((2.0 - 0.98, 2.0 + 0.98))
    lo, hi = _ci95(2.0, 0.5, log_scale=True)
    assert (lo, hi) == pytest.approx((2.0 * math.exp(-0.98), 2.0 * math.exp(0.98)))
    # a barely constrained log-scale parameter (seen on the committed samples: log-se ~724)
    assert _ci95(0.9, 724.0, log_scale=True) == (0.0, math.inf)
    # cut to the bounds the fit cannot leave (the samples' mu_s: 0.16 +- 64)
    assert _ci95(0.16, 33.0, log_scale=False, bounds=(0.0, 1.5)) == (0.0, 1.5)
    assert _ci95(0.9, 724.0, log_scale=True, bounds=(0.01, 100.0)) == (0.01, 100.0)
    assert _ci95(2.0, 0.5, log_scale=False, bounds=(0.0, 10.0)) == pytest.approx((2.0 - 0.98, 2.0 + 0.98))


def test_recovers_parameters_within_three_standard_errors(white_fit):
    table, fit = white_fit
    truth = flat_params(TRUTH)
    assert set(fit.params) == set(DEFAULT_FREE)
    for name, est in fit.params.items():
        assert not est.at_bound
        assert abs(_z(est, truth[name])) < 3.0, (name, est, truth[name])
        lo, hi = est.ci95
        assert lo < est.value < hi
    # residual scatter at the noise level, no bias by speed
    noise = (table["force_g"] - table["force_true_g"]).std()
    assert fit.rmse_g == pytest.approx(noise, rel=0.1)
    assert (fit.by_speed["bias_g"].abs() < 0.05).all() and (fit.by_speed["r2"] > 0.95).all()
    assert fit.se_method == "cluster" and fit.n_trials == 25
    assert abs(fit.rho_lag1) < 0.2  # white noise
    # held parameters are reported
    assert fit.fixed["contact_width_mm"] == 0.3 and fit.fixed["delta_s"] == 2.0
    print({k: (round(v.value, 4), round(v.stderr, 4), round(_z(v, truth[k]), 2)) for k, v in fit.params.items()})


def test_statistics_are_consistent(white_fit):
    _, fit = white_fit
    n, k = fit.n, len(fit.params) + 1
    sigma2 = fit.rss / n
    loglik = -0.5 * n * (math.log(2 * math.pi * sigma2) + 1)
    assert fit.k == k and fit.loglik == pytest.approx(loglik)
    assert fit.aic == pytest.approx(2 * k - 2 * loglik)
    assert fit.bic == pytest.approx(k * math.log(n) - 2 * loglik)
    corr = fit.correlation.to_numpy()
    np.testing.assert_allclose(np.diag(corr), 1.0)
    np.testing.assert_allclose(corr, corr.T, atol=1e-12)
    assert np.all(np.abs(corr) <= 1 + 1e-9)
    # tip/bottom pressure levels trade off along the arc: flagged
    assert any("hard to separate" in w for w in fit.warnings)
    assert fit.by_speed["n"].sum() == n
    assert fit.starts["best"].sum() == 1


def test_fit_json_has_the_main_keys(white_fit):
    _, fit = white_fit
    doc = json.loads(json.dumps(fit_to_json(fit)))
    assert {"params", "correlation", "aic", "bic", "n", "rmse_g", "by_speed"} <= set(doc)
    for entry in doc["params"].values():
        assert {"value", "stderr"} <= set(entry)
    assert set(doc["correlation"]) == set(doc["params"])
    assert all({"speed_mm_s", "rmse_g", "n"} <= set(row) for row in doc["by_speed"])
    assert "contact_width_mm" in doc["fixed"]


def test_autocorrelated_noise_inflates_honest_errors():
    """AR(1) noise within trials: the naive errors are too small, cluster/n_eff errors are not."""
    rng = np.random.default_rng(12)
    table = synthetic_synced(TRUTH, rng=rng, trials=5, noise_rel=0.03, ar_rho=0.9)
    fit = fit_synced(table, FitOptions(base=START, starts=4, seed=2, free=("p_tip0_MPa", "p_tip1_MPa_per_rad",
                                                                             "p_bot0_MPa", "p_bot1_MPa_per_rad")))
    assert fit.rho_lag1 > 0.6 and fit.n_eff < 0.25 * fit.n
    truth = flat_params(TRUTH)
    for name, est in fit.params.items():
        assert est.stderr_cluster > 1.5 * est.stderr_naive
        assert est.stderr_neff > 1.5 * est.stderr_naive
        assert abs(_z(est, truth[name])) < 3.0


@pytest.mark.parametrize("mode", ["axial", "vector"])
def test_analytic_jacobian_matches_finite_differences(mode):
    rng = np.random.default_rng(13)
    table = synthetic_synced(TRUTH, rng=rng, trials=1, samples_per_trial=40)
    arcs = arc_integrals(table["theta_bot"].to_numpy(), table["theta_tip"].to_numpy())
    speed = table["speed_mm_s"].to_numpy()
    base = flat_params(FrictionParams(v_s_mm_s=2.0, delta_s=1.5, mu_v_s_per_mm=0.01))
    names = list(FLAT_NAMES)
    x = np.array([base[n] for n in names])
    jac = _model_jacobian(_build(x, names, base, tie_mu=False), names, arcs, speed, mode, tie_mu=False)
    for i, name in enumerate(names):
        h = 1e-6 * max(abs(x[i]), 1e-4)
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        fd = (force_from_integrals(arcs, speed, _build(up, names, base, tie_mu=False), friction_mode=mode)
              - force_from_integrals(arcs, speed, _build(down, names, base, tie_mu=False), friction_mode=mode)) / (2 * h)
        np.testing.assert_allclose(jac[:, i], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max(), err_msg=name)


# --------------------------------------------------------------------------- identifiability rules


def test_contact_width_is_held_when_pressures_are_free():
    rng = np.random.default_rng(14)
    table = synthetic_synced(TRUTH, rng=rng, trials=1, samples_per_trial=60)
    fit = fit_synced(table, FitOptions(free=DEFAULT_FREE + ("contact_width_mm",), starts=1))
    assert "contact_width_mm" not in fit.params and "contact_width_mm" in fit.fixed
    assert any("exactly degenerate" in w for w in fit.warnings)


def test_one_speed_fits_coulomb_friction():
    rng = np.random.default_rng(15)
    table = synthetic_synced(TRUTH, rng=rng, speeds_mm_s=(3.0,), trials=3, samples_per_trial=60)
    fit = fit_synced(table, FitOptions(starts=2))
    assert set(fit.params) == {"p_tip0_MPa", "p_tip1_MPa_per_rad", "p_bot0_MPa", "p_bot1_MPa_per_rad", "mu_k"}
    assert fit.model.mu_s == fit.model.mu_k
    assert any("held" in w for w in fit.warnings) and any("Coulomb" in w for w in fit.warnings)


def test_unidentified_parameter_gets_infinite_error():
    """With v_s held tiny, mu_s never acts at the data's speeds: flagged, stderr = inf."""
    rng = np.random.default_rng(20)
    table = synthetic_synced(TRUTH, rng=rng, trials=1, samples_per_trial=60)
    free = ("p_tip0_MPa", "p_tip1_MPa_per_rad", "p_bot0_MPa", "p_bot1_MPa_per_rad", "mu_s", "mu_k")
    fit = fit_synced(table, FitOptions(free=free, fixed={"v_s_mm_s": 0.01, "delta_s": 2.0}, starts=2))
    assert math.isinf(fit.params["mu_s"].stderr) and math.isfinite(fit.params["mu_k"].stderr)
    assert any("mu_s is not identified" in w for w in fit.warnings)
    doc = json.loads(json.dumps(fit_to_json(fit)))  # inf/NaN become null: still valid JSON
    assert doc["params"]["mu_s"]["stderr"] is None
    # its interval is all the fit allows, its bounds (not -inf .. inf)
    assert tuple(doc["params"]["mu_s"]["ci95"]) == PARAM_BOUNDS["mu_s"]


def test_unknown_parameter_names_are_rejected():
    rng = np.random.default_rng(16)
    table = synthetic_synced(TRUTH, rng=rng, trials=1, samples_per_trial=40)
    with pytest.raises(ValueError):
        fit_synced(table, FitOptions(free=("mu_x",)))
    with pytest.raises(ValueError):
        fit_synced(table, FitOptions(fixed={"mu_x": 1.0}))


# --------------------------------------------------------------------------- bad input


@pytest.fixture
def small_table():
    return synthetic_synced(TRUTH, rng=np.random.default_rng(17), trials=1, samples_per_trial=30)


def test_bad_tables_raise_input_errors(small_table, tmp_path):
    with pytest.raises(InputError, match="missing column"):
        validate_synced(small_table.drop(columns=["theta_bot"]), "t.csv")
    bad = small_table.astype({"force_g": object})
    bad.loc[3, "force_g"] = "abc"
    with pytest.raises(InputError, match="non-numeric") as info:
        validate_synced(bad, "t.csv")
    assert info.value.path == "t.csv:5"
    with pytest.raises(InputError, match="usable rows"):
        validate_synced(small_table.head(10), "t.csv")
    no_contact = small_table.assign(theta_bot=small_table["theta_tip"], theta_con=0.0)
    with pytest.raises(InputError, match="no row has contact"):
        validate_synced(no_contact, "t.csv")
    with pytest.raises(InputError, match="no such synced table"):
        read_synced(tmp_path / "missing.csv")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(InputError, match="no header row"):
        read_synced(empty)
    # NaN rows (frames that could not be measured) are dropped with a note
    holes = small_table.copy()
    holes.loc[[2, 4], "theta_tip"] = np.nan
    table, notes = validate_synced(holes, "t.csv")
    assert len(table) == len(small_table) - 2 and any("left out" in n for n in notes)


def test_standing_and_saturated_rows_are_left_out(small_table):
    last = small_table.iloc[[-1]]
    dwell = pd.concat([last] * 10, ignore_index=True)
    dwell["time_s"] = last["time_s"].iloc[0] + 0.1 * np.arange(1, 11)
    table = pd.concat([small_table, dwell], ignore_index=True)
    table["saturated"] = "false"
    table.loc[5, "saturated"] = "true"
    kept, notes = validate_synced(table, "t.csv")
    assert len(kept) == len(small_table) - 1  # the 10 dwell rows and the saturated row are out
    same_trial = kept[kept["trial"] == last["trial"].iloc[0]]
    assert not (same_trial["time_s"] > last["time_s"].iloc[0]).any()
    assert any("standing" in n for n in notes) and any("saturated" in n for n in notes)
    kept_all, _ = validate_synced(table, "t.csv", moving_only=False)
    assert len(kept_all) == len(table) - 1


# --------------------------------------------------------------------------- command line


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_cli_simulate_prints_and_writes(capsys, tmp_path):
    code, out, err = _run(capsys, "simulate", "--scenario", "S4", "--speeds", "0.5,3,7.5")
    assert code == 0 and "TABLE I" in out and "F@7.5mm/s_g" in out
    target = tmp_path / "sim.csv"
    code, out, err = _run(capsys, "simulate", "--scenario", "s2", "--speeds", "0.5,7.5", "--out", target)
    assert code == 0 and target.exists()
    table = pd.read_csv(target)
    assert list(table.columns[:6]) == ["scenario", "speed_mm_s", "theta_bot", "theta_tip", "theta_con", "force_g"]
    assert set(table["scenario"]) == {"S2"} and set(table["speed_mm_s"]) == {0.5, 7.5}


@pytest.mark.parametrize("argv, fragment", [
    (["simulate", "--scenario", "S9"], "invalid choice"),
    (["simulate", "--scenario", "S1", "--speeds", "0,-1"], "positive speeds"),
    (["simulate"], "required: --scenario"),
    (["fit", "x.csv"], "required: --out"),
    (["fit", "x.csv", "--out", "o", "--free", "mu_x"], "unknown parameter"),
    (["fit", "x.csv", "--out", "o", "--fix", "mu_k"], "NAME=VALUE"),
])
def test_cli_usage_errors(capsys, argv, fragment):
    code, _, err = _run(capsys, *argv)
    assert code == 2 and fragment in _one_line(err)


def test_cli_fit_happy_path(capsys, tmp_path):
    table = synthetic_synced(TRUTH, rng=np.random.default_rng(18), trials=2, samples_per_trial=60)
    synced = tmp_path / "synced.csv"
    table.to_csv(synced, index=False)
    out = tmp_path / "fit"
    code, stdout, err = _run(capsys, "fit", synced, "--out", out, "--starts", "2", "--fix", "delta_s=2.5")
    assert code == 0, err
    doc = json.loads((out / "fit.json").read_text())
    assert {"params", "correlation", "aic", "bic", "n", "rmse_g", "by_speed"} <= set(doc)
    assert doc["n"] == len(table) and doc["fixed"]["delta_s"] == 2.5
    assert (out / "fit_residuals.csv").exists() and (out / "fit.provenance.json").exists()
    assert "fit: n=" in stdout


def test_cli_fit_bad_input_exits_2(capsys, tmp_path):
    code, _, err = _run(capsys, "fit", tmp_path / "missing.csv", "--out", tmp_path / "o")
    assert code == 2 and "no such synced table" in _one_line(err)
    bad = tmp_path / "bad.csv"
    bad.write_text("trial,speed_mm_s,time_s,force_g\nA,1,0,0\n")
    code, _, err = _run(capsys, "fit", bad, "--out", tmp_path / "o")
    assert code == 2 and "missing column" in _one_line(err)
    text = tmp_path / "text.csv"
    table = synthetic_synced(TRUTH, rng=np.random.default_rng(19), trials=1, samples_per_trial=30)
    table["theta_tip"] = table["theta_tip"].astype(object)
    table.loc[7, "theta_tip"] = "n/a?"
    table.to_csv(text, index=False)
    code, _, err = _run(capsys, "fit", text, "--out", tmp_path / "o")
    assert code == 2 and _one_line(err) == f"tympani: {text}:9: theta_tip 'n/a?' is not a number"

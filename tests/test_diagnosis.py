"""The sim-to-real gap diagnosis (issue 4): verdicts on generated data with hidden effects, the
paper's case, kernels against the library's forms, bad input, the CLI and a small blind evaluation.

Data come from :mod:`tympani.pipeline.synthetic.family_a` (hidden forms unlike the library's); seeds are fixed and
differ from the development seeds used to calibrate the decision thresholds (101, 102).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tympani.pipeline.cli import main
from tympani.pipeline.diagnosis.analysis import diagnose, diagnosis_to_json
from tympani.pipeline.diagnosis.candidates import candidates, fit_candidate, predict
from tympani.pipeline.diagnosis.config import DATA_NEEDED, DiagnosisConfig
from tympani.pipeline.diagnosis.kernels import dead_time, kernel, lag_foh
from tympani.pipeline.diagnosis.prepare import prepare, smooth_angles
from tympani.pipeline.model.effects import EFFECTS, EffectContext, first_order_lag
from tympani.pipeline.model.friction import FrictionParams
from tympani.pipeline.synthetic.family_a import paper_case, synthetic_dataset
from tympani.vision.errors import InputError

FAST = DiagnosisConfig(bootstrap=300)


def _data(effect, seed, **kw):
    return synthetic_dataset(np.random.default_rng(seed), effect, **kw)


@pytest.fixture(scope="module")
def effect_free():
    synced, truth = _data(None, 7)
    return synced, diagnose(synced, FAST)


@pytest.fixture(scope="module")
def strong():
    out = {}
    for effect, seed in (("hydrodynamic_lift", 11), ("sensor_lag", 12), ("viscous_drag", 13), ("sensor_drift", 14)):
        synced, truth = _data(effect, seed, strength=1.5)
        out[effect] = (truth, diagnose(synced, FAST))
    return out


# --------------------------------------------------------------------------- verdicts


def test_no_gap_on_effect_free_data(effect_free):
    _, d = effect_free
    assert d.verdict == "no_gap" and d.effect is None
    # nothing beats the reference by much, and the lack-of-fit test of the reference passes
    assert max(d.decision.gain_lo.values()) < d.config.min_gain
    assert abs(d.gap.shrink_pct) < 10


def test_lag_and_a_squeezing_film_are_told_apart_only_by_another_experiment(strong):
    """A first-order sensor lag and a lubricant film that builds up as the array slides and squeezes
    out after the stop on the lag's time scale predict nearly the same insertion and dwell: the
    verdict is ambiguous, lag first, and the experiment recommended (a retraction) has the two
    predict opposite signs."""
    truth, d = strong["sensor_lag"]
    assert truth.detectable
    assert d.verdict == "ambiguous" and d.decision.tied[:2] == ("sensor_lag", "hydrodynamic_lift")
    assert d.decision.variants["hydrodynamic_lift"].used
    best = d.experiments[0]
    assert best.experiment == "retraction" and best.complete
    pred = best.predictions
    assert pred["sensor_lag"].change_g > 0 > pred["hydrodynamic_lift"].change_g


@pytest.mark.parametrize("effect", ["hydrodynamic_lift", "viscous_drag", "sensor_drift"])
def test_strong_effects_are_identified(strong, effect):
    truth, d = strong[effect]
    assert truth.detectable
    assert d.verdict == "identified" and d.effect == effect, d.decision.reason
    assert d.gap.shrink_pct > 15  # held-out RMSE against the measured force (includes the noise floor)
    assert d.ranking[0].candidate == effect
    # the leader's parameters are determined away from their null values
    ident = d.identifiability[effect]
    first = next(iter(ident.values()))
    assert abs(first.z_vs_null) > 3


def test_where_names_the_speeds_of_a_speed_effect(strong):
    _, d = strong["hydrodynamic_lift"]
    where = d.where
    assert where.sign in ("below", "mixed")
    assert 7.5 in where.speeds_mm_s
    assert where.variance_split.speed > 0.3
    assert "7.5" in where.summary


def test_drift_shows_without_contact(strong):
    _, d = strong["sensor_drift"]
    assert d.where.before_contact or "before" in d.where.phases or "dwell" in d.where.phases


# --------------------------------------------------------------------------- the paper's case


@pytest.fixture(scope="module")
def paper():
    synced, truth = paper_case(np.random.default_rng(0))
    return truth, diagnose(synced, FAST)


def test_paper_case_explains_the_drop(paper):
    truth, d = paper
    assert d.verdict == "identified" and d.effect == "hydrodynamic_lift"
    drops = {r.speed_mm_s: r for r in d.peak_drop.by_speed}
    assert drops[7.5].measured_pct == pytest.approx(43, abs=4)
    assert drops[3.0].measured_pct == pytest.approx(24, abs=4)
    assert abs(drops[7.5].base_pct) < 3  # the paper's model alone barely drops
    assert 0.8 < d.peak_drop.explained_frac_fastest < 1.25


@pytest.mark.parametrize("seed", [0, 1])
def test_the_papers_protocol_tells_lift_from_lag_one_way_only(seed):
    """The paper's protocol (5 speeds x 10 insertions, no dwell). A lift with the paper's drops
    (-24 % and -43 %) is identified: a sensor lag cannot make that pattern. A sensor lag tuned to
    -43 % at 7.5 mm/s drops only about -16 % at 3 mm/s, and a lubricant film can mimic it: the
    answer is ambiguous, lag first, and a retraction is named to split them."""
    from tympani.pipeline.synthetic.family_a import PAPER_VARIABILITY, peak_force_drop

    synced, _ = paper_case(np.random.default_rng(seed), dwell_s=0.0)
    d = diagnose(synced, FAST)
    assert d.verdict == "identified" and d.effect == "hydrodynamic_lift"
    synced, _ = synthetic_dataset(np.random.default_rng(seed), "sensor_lag", strength=0.6,
                                  speeds_mm_s=(0.5, 1.5, 3.0, 5.0, 7.5), trials=10, dwell_s=0.0,
                                  variability=PAPER_VARIABILITY)
    drop = peak_force_drop(synced).set_index("speed_mm_s")["change_pct"]
    assert -48 < drop[7.5] < -38 and -20 < drop[3.0] < -12
    d = diagnose(synced, FAST)
    assert d.verdict == "ambiguous" and d.decision.tied[:2] == ("sensor_lag", "hydrodynamic_lift")
    assert d.experiments[0].experiment == "retraction"


def test_paper_case_says_how_to_split_lift_from_lag(paper):
    _, d = paper
    # lag is the runner-up (or tied); the experiments name what each predicts
    ranked = [r.candidate for r in d.ranking]
    assert ranked.index("sensor_lag") <= 2
    assert d.experiments, "an experiment to confirm lift against the runner-up is proposed"
    best = d.experiments[0]
    assert best.recommended and set(best.predictions) >= {"hydrodynamic_lift", "sensor_lag"}
    for pred in best.predictions.values():
        assert pred.words
    names = {e.experiment for e in d.experiments}
    assert {"dwell", "retraction", "viscosity"} <= names


def test_paper_sized_lag_is_not_called_lift():
    """A paper-sized sensor lag (pole 0.15 s, dead time 0.03 s) without a dwell or a log before
    the motion: nothing in the data separates it from a squeezing film, so the answer is
    ambiguous, the lag first and the lift tied with it, never lift alone (measured: ambiguous,
    tied sensor_lag and hydrodynamic_lift; noiseless gap 2.3 x the noise)."""
    synced, _ = _data("sensor_lag", 5, effect_params=dict(pole_time_s=0.15, dead_time_s=0.03), dwell_s=0.0, pre_s=0.0)
    d = diagnose(synced, FAST)
    assert d.verdict == "ambiguous" and d.effect is None
    assert d.decision.tied[:2] == ("sensor_lag", "hydrodynamic_lift") and d.decision.leader == "sensor_lag"


# --------------------------------------------------------------------------- kernels vs library


@pytest.fixture(scope="module")
def prepared():
    synced, _ = _data(None, 3, trials=3, speeds_mm_s=(0.5, 3.0, 7.5))
    return prepare(synced, DiagnosisConfig())


def test_lag_kernel_matches_the_library_on_dense_data(prepared):
    ds = prepared
    ctx = EffectContext.from_synced(ds.rows)
    x = np.cumsum(np.abs(np.sin(ds.rows["time_s"].to_numpy()))) % 7.0 + ds.y
    x = pd.Series(x).groupby(ds.trial).transform(lambda v: v.rolling(5, min_periods=1).mean()).to_numpy()
    tau = 0.3
    ours = lag_foh(x, ds, tau)
    lib = first_order_lag(x, ctx.time_s, ctx.trial, ctx.order, tau)
    # the library's zero-order hold lags by half a sample more: compare with a tolerance of one step
    step = np.abs(np.diff(x)).max()
    assert np.max(np.abs(ours - lib)) < step
    # exact for a ramp: tau dy/dt = t - y from rest gives y = t - tau (1 - exp(-t/tau))
    t = ds.rows["time_s"].to_numpy() - ds.rows.groupby("trial")["time_s"].transform("min").to_numpy()
    ramp = lag_foh(t.copy(), ds, tau)
    assert np.allclose(ramp, t - tau * (1 - np.exp(-t / tau)), atol=1e-9)
    assert np.allclose(dead_time(t.copy(), ds, 0.0), t)


def test_kernels_reduce_to_the_library_forms(prepared):
    ds = prepared
    rng = np.random.default_rng(0)
    f = rng.uniform(0.5, 3.0, ds.n)
    mu = np.full(ds.n, 0.15)
    a = np.column_stack([f, 2 * f, f, f])
    ctx = ds.ctx
    lift = kernel("hydrodynamic_lift").transform(a, ds, mu, np.array([0.1, 0.65]))
    assert np.allclose(lift[:, 0], EFFECTS["hydrodynamic_lift"].apply(f, ctx, [0.1, 0.65], mu))
    # capstan along the arc: exactly the base at k = 0, grows with k
    cap = kernel("capstan").transform(ds.a_n + mu[:, None] * ds.a_t, ds, mu, np.array([0.0]))
    assert np.array_equal(cap, ds.a_n + mu[:, None] * ds.a_t)
    cap2 = kernel("capstan").transform(ds.a_n + mu[:, None] * ds.a_t, ds, mu, np.array([2.0]))
    contact = ds.theta_con > 0.3
    assert np.all(cap2[contact].sum(axis=1) >= (ds.a_n + mu[:, None] * ds.a_t)[contact].sum(axis=1) - 1e-9)
    # drift: the library's linear drift from the log start; profile: the library's bump is the first mode
    drift = kernel("sensor_drift").columns(ds, mu, np.zeros(0))[:, 0]
    assert np.all(np.diff(drift[ds.trial == 0]) > 0)
    prof = kernel("pressure_profile").columns(ds, mu, np.zeros(0))[:, 0] / (FrictionParams().contact_width_mm / 9.80665e-3)  # per g/mm
    lib = EFFECTS["pressure_profile"].apply(np.zeros(ds.n), ctx, [1.0], mu)
    assert np.corrcoef(prof, lib)[0, 1] > 0.99
    assert np.allclose(prof, lib, rtol=0.05, atol=0.02 * np.abs(lib).max())


def test_fit_recovers_a_library_lag(prepared):
    """Inverse crime on purpose (library form in, library form out): the fitter itself is right."""
    ds = prepared
    cand = next(c for c in candidates(("sensor_lag",)) if c.name == "sensor_lag")
    base = next(c for c in candidates(()) if c.name == "base")
    fit0 = fit_candidate(ds, base)
    clean = predict(ds, fit0, gains=False)
    ctx = EffectContext.from_synced(ds.rows)
    lagged = first_order_lag(clean, ctx.time_s, ctx.trial, ctx.order, 0.4)
    from dataclasses import replace

    fit = fit_candidate(replace(ds, y=lagged), cand)
    assert fit.effect_params()["tau_s"] + fit.effect_params()["dead_time_s"] == pytest.approx(0.4, abs=0.08)


# --------------------------------------------------------------------------- output


def test_diagnosis_json_has_the_documented_keys(strong):
    """The keys of diagnosis.json (docs/file-formats.md), on the strong lag (its verdict: ambiguous
    between the lag and a squeezing film, see :func:`test_lag_and_a_squeezing_film_are_told_apart_only_by_another_experiment`)."""
    _, d = strong["sensor_lag"]
    out = diagnosis_to_json(d, "x.csv")
    json.dumps(out, allow_nan=False)
    assert list(out)[:4] == ["verdict", "effect", "ranking", "gap"] and "heldout" in out
    assert out["where"] == out["gap"]["where"] and out["by_speed"] == out["gap"]["by_speed"]  # top level and gap
    assert out["verdict"] == "ambiguous" and out["effect"] is None
    for row in out["ranking"]:
        assert {"effect", "delta_bic", "heldout_rmse_g", "params"} <= set(row)
    assert {"rmse_base_g", "rmse_with_effect_g", "shrink_pct", "by_speed", "where"} <= set(out["gap"])
    assert {"speeds_mm_s", "theta_con_range_rad", "phases", "summary"} <= set(out["gap"]["where"])
    assert out["heldout"]["folds"] and "extrapolation" in out["heldout"]
    assert out["ranking"][0]["effect"] == "sensor_lag"
    assert {"lack_of_fit", "identifiability", "peak_drop", "experiments", "control"} <= set(out)


# --------------------------------------------------------------------------- bad input


def _small(speeds=(0.5, 3.0, 7.5), trials=2):
    synced, _ = _data(None, 1, speeds_mm_s=speeds, trials=trials)
    return synced


@pytest.mark.parametrize("case", ["two_speeds", "single_trial", "one_trial_per_speed", "constant"])
def test_bad_input_says_what_the_diagnosis_needs(case):
    if case == "two_speeds":
        table = _small(speeds=(0.5, 7.5))
    elif case == "single_trial":
        table = _small(speeds=(3.0,), trials=1)
    elif case == "one_trial_per_speed":
        table = _small(trials=1)
    else:
        table = _small().assign(force_g=1.25)
    with pytest.raises(InputError) as err:
        diagnose(table, FAST, source="t.csv")
    text = str(err.value)
    assert "\n" not in text and text.startswith("t.csv: ")
    assert DATA_NEEDED in text


def test_cli_diagnose_writes_the_report_and_exit_codes(tmp_path, capsys):
    """``tympani diagnose`` on a hidden viscous drag (3 speeds x 4 trials) finds it (measured:
    identified viscous_drag, held-out RMSE 0.422 g -> 0.036 g, +91 %), writes the report and
    figures; bad input exits 2 with one line."""
    synced, _ = _data("viscous_drag", 21, strength=1.5, speeds_mm_s=(0.5, 3.0, 7.5), trials=4)
    path = tmp_path / "synced.csv"
    synced.to_csv(path, index=False)
    out = tmp_path / "diag"
    assert main(["diagnose", str(path), "--out", str(out), "--bootstrap", "200"]) == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["verdict"] == "identified" and doc["effect"] == "viscous_drag"
    assert (out / "diagnosis.md").read_text().startswith("# Sim-to-real gap diagnosis")
    for fig in ("fig_gap_heatmap.png", "fig_force_vs_theta.png", "fig_ranking.png", "fig_phase.png"):
        assert (out / fig).stat().st_size > 1000
    assert "diagnose:" in capsys.readouterr().out

    bad = tmp_path / "bad.csv"
    _small(speeds=(0.5, 7.5)).to_csv(bad, index=False)
    assert main(["diagnose", str(bad), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "at least 3 insertion speeds" in err
    assert main(["diagnose", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "x")]) == 2
    assert main(["diagnose", "--out", str(tmp_path / "x")]) == 2  # usage


# --------------------------------------------------------------------------- blind evaluation


@pytest.mark.parametrize("family", ["A", "B"])
def test_small_blind_evaluation(family):
    """A small seeded version of ``tympani evaluate-diagnosis`` on each generator family (3 data sets
    per label). The thresholds were set on family A; family B was written independently, with
    other functional forms, and is the honest check."""
    from tympani.pipeline.diagnosis.evaluation import EvalConfig, evaluate, format_evaluation, summarise

    config = EvalConfig(family=family, diagnosis=DiagnosisConfig(bootstrap=300))
    results = evaluate(21, 2027, workers=2, config=config)
    summary = summarise(results)
    text = format_evaluation(summary)
    print(text)
    assert "confusion matrix" in text and "ambig" in text and "no_gap" in text
    assert summary["errors"] == 0
    assert summary["false_identified_rate"] == 0.0
    assert summary["confident_wrong_rate"] == 0.0
    assert summary["precision_identified"] == 1.0
    assert summary["useful_visible_unabsorbed"] >= 0.85
    assert summary["median_true_shrink_right_pct"] > 50


def test_smooth_angles_keeps_trends_and_cuts_noise():
    """Quadratic trends pass unchanged; white angle noise shrinks; rows, order and trials are kept."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 6.0, 0.01)
    tip = 0.2 + 0.4 * t + 0.02 * t**2
    bot = np.where(t > 2.0, 0.1 + 0.05 * (t - 2.0) ** 2, tip)
    rows = []
    for k, shift in enumerate((0.0, 0.3)):
        rows.append(pd.DataFrame(dict(trial=f"t{k}", time_s=t + shift, theta_tip=tip, theta_bot=np.minimum(bot, tip))))
    clean = pd.concat(rows, ignore_index=True).sample(frac=1.0, random_state=0)  # rows in any order
    noisy = clean.assign(theta_tip=clean["theta_tip"] + rng.normal(0, 0.01, len(clean)))
    out = smooth_angles(noisy, 0.6)
    assert out.index.equals(noisy.index) and out["trial"].equals(noisy["trial"])
    err_before = (noisy["theta_tip"] - clean["theta_tip"]).std()
    err_after = (out["theta_tip"] - clean["theta_tip"]).std()
    assert err_after < 0.45 * err_before
    same = smooth_angles(clean, 0.6)
    np.testing.assert_allclose(same["theta_tip"], clean["theta_tip"], atol=1e-9)  # a quadratic is kept exactly
    assert (same["theta_con"] >= 0).all()
    assert smooth_angles(noisy, 0.0) is noisy


def test_splitting_experiments_rank_by_the_fixed_predictions(monkeypatch):
    """Differences are taken among the fixed predictions; an experiment with one left open ranks as
    if its difference were half as large."""
    from types import SimpleNamespace

    from tympani.pipeline.diagnosis import experiments as dx

    table = {  # predicted change (g) of each experiment for each effect; None: not fixed
        "a": {"retraction": 1.0, "viscosity": 0.0, "dwell": 0.0, "baseline": 0.0},
        "b": {"retraction": 0.4, "viscosity": 0.9, "dwell": 0.0, "baseline": 0.0},
        "c": {"retraction": 0.0, "viscosity": None, "dwell": None, "baseline": 0.0},
    }
    monkeypatch.setattr(dx, "effect_predictions",
                        lambda ds, fit, model_g: {k: {"change_g": v, "words": "w"} for k, v in table[fit.name].items()})
    fits = {e: SimpleNamespace(name=e, candidate=SimpleNamespace(effect=e)) for e in table}
    model = {e: None for e in table}
    rows = dx.splitting_experiments(None, fits, ["a", "b", "c"], model)
    by = {r.experiment: r for r in rows}
    assert by["retraction"].min_difference_g == pytest.approx(0.4) and by["retraction"].complete
    assert by["viscosity"].min_difference_g == pytest.approx(0.9) and not by["viscosity"].complete
    assert by["baseline"].min_difference_g == 0.0 and by["baseline"].complete
    # viscosity ranks at 0.45 (half of 0.9, incomplete), above retraction's 0.4
    assert [r.experiment for r in rows][:2] == ["viscosity", "retraction"] and rows[0].recommended
    # with "a" and "c" only, the dwell and the viscosity have one fixed prediction: no difference
    by = {r.experiment: r for r in dx.splitting_experiments(None, fits, ["a", "c"], model)}
    assert by["dwell"].min_difference_g is None and not by["dwell"].complete
    assert by["retraction"].min_difference_g == pytest.approx(1.0) and by["retraction"].recommended

"""One family-B experiment: :func:`generate` runs the trials and assembles the truth."""

from __future__ import annotations

import json
from typing import Any, Sequence

import numpy as np
import pandas as pd

from tympani.pipeline.synthetic.family_b.calibration import draw_effect_constants, reference_state, vary_effect_constants
from tympani.pipeline.synthetic.family_b.constants import EFFECTS, G_N
from tympani.pipeline.synthetic.family_b.contact import arc_force_g, contact_arc, linear_pressure, stribeck_mu
from tympani.pipeline.synthetic.family_b.draws import draw_dataset, draw_trial, seeded_rng
from tympani.pipeline.synthetic.family_b.effects import (
    capstan_force_g,
    drag_force_g,
    drift_signal,
    film_state,
    lag_filter,
    lift_pressure,
    lift_separation,
    profile_pressure,
    sensor_noise,
)
from tympani.pipeline.synthetic.family_b.kinematics import motion_times, robot_motion, true_angles
from tympani.pipeline.synthetic.family_b.phantom import PhantomGeometry, geometry
from tympani.pipeline.synthetic.family_b.trajectory import TipPath, tip_path
from tympani.pipeline.synthetic.family_b.truth import (
    BaseModelTruth,
    GeneratedTruth,
    LinearLawTruth,
    NoiseTruth,
    ReferenceTruth,
    TrialTruth,
)

__all__ = ["generate"]


def _settled_tip_path(geom: PhantomGeometry, tr: dict[str, Any], tries: int = 6) -> TipPath:
    """The trial's tip path; a draw whose tip slides back and forth along the inner wall without
    settling on the outer one (about 2 % of draws) is bent slightly more clockwise (0.002 /mm a try,
    recorded in ``tr``) until it settles."""
    for k in range(tries):
        try:
            return tip_path(geom, tr["e_lat_mm"], tr["tilt_rad"], tr["kappa0_per_mm"])
        except ValueError as exc:
            if "did not settle" not in str(exc) or k == tries - 1:
                raise
            tr["kappa0_per_mm"] = float(tr["kappa0_per_mm"] - 0.002)
    raise AssertionError("unreachable")  # pragma: no cover


def _trial_frame(effect: str | None, strength: float, seed: int, iv: int, it: int,
                 speed: float, ds: dict[str, Any], eff: dict[str, Any], ref: dict[str, Any],
                 geom: PhantomGeometry,
                 noise_scale: float) -> tuple[dict[str, np.ndarray], TrialTruth]:
    """Generate one trial: columns as arrays, plus its per-trial truth."""
    tr = draw_trial(seed, iv, it, speed, ds)
    prm = vary_effect_constants(effect, eff, seed, iv, it)
    fs = ds["force_rate_hz"]
    t_on, t_off, t_end = motion_times(tr)
    t = np.arange(0.0, t_end, 1.0 / fs)
    depth, vel = robot_motion(t, tr)
    path = _settled_tip_path(geom, tr)
    th_tip, th_bot = true_angles(depth, path, tr, ds["theta_bot_floor"])
    con = th_tip - th_bot
    arc = contact_arc(geom, th_bot, th_tip)

    # base model; friction at the cruise speed, frozen (held) while the robot is still
    v_c = tr["speed_actual_mm_s"]
    mu_c = float(stribeck_mu(v_c, ds["mu_k"], ds["mu_s"], ds["v_s"], ds["delta_s"]))
    mu = np.full(t.size, mu_c)
    sc = ref["pressure_scale"]
    pt_law = (ds["pt0"] + (ds["pt3"] - ds["pt0"]) / 3.0 * con) * sc * tr["p_tip_scale"]
    pb_law = (ds["pb0"] + (ds["pb3"] - ds["pb0"]) / 3.0 * con) * sc * tr["p_bot_scale"]
    p_lin = linear_pressure(arc, pt_law, pb_law)
    F_base = arc_force_g(arc, p_lin, mu, ds["b_c"])

    film_ratio_at_stop: float | None = None
    F_phys = F_base
    if effect == "hydrodynamic_lift":
        lam = film_state(t, t_on, t_off, v_c, prm)
        H = strength * lift_separation(lam, prm)
        p_eff = lift_pressure(p_lin, H, prm["K"], ref["p_ref"], prm["m_load"])
        F_phys = arc_force_g(arc, p_eff, mu, ds["b_c"])
        film_ratio_at_stop = float(lam[np.searchsorted(t, t_off) - 1])
    elif effect == "viscous_drag":
        F_phys = F_base + drag_force_g(depth, vel, arc, p_lin * ds["b_c"], path, geom, prm,
                                       strength)
    elif effect == "capstan":
        F_phys = capstan_force_g(arc, p_lin, mu, ds["b_c"], prm["chi"] * strength, prm["m_rub"])
    elif effect == "pressure_profile":
        p_eff = profile_pressure(arc, p_lin, pt_law, pb_law, min(1.0, prm["sigma"] * strength),
                                 prm["beta_per_mm"])
        F_phys = arc_force_g(arc, p_eff, mu, ds["b_c"])

    # sensor: calibration gain and tare, then drift, then the amplifier filter
    true_base = tr["gain"] * F_base + tr["tare_g"]
    sensed = tr["gain"] * F_phys + tr["tare_g"]
    if effect == "sensor_drift":
        sensed = sensed + drift_signal(t, tr["gain"] * F_phys, prm, strength)
    if effect == "sensor_lag":
        scaled = {k: (v * strength if k.endswith("_s") else v) for k, v in prm.items()}
        sensed = lag_filter(sensed, fs, scaled)
    rng_n = seeded_rng(seed, 3, iv, it)
    noisy = sensed + sensor_noise(t.size, fs, ds, noise_scale, rng_n)
    lsb = 2.0 * ds["full_scale_g"] / 2 ** ds["adc_bits"]
    force = np.clip(np.round(noisy / lsb) * lsb, -ds["full_scale_g"], ds["full_scale_g"] - lsb)

    # video: frames at fps, noisy angles, missing frames, interpolated to the force clock
    fps = ds["fps"]
    tv = np.arange(tr["video_start_s"], t_end - tr["video_end_early_s"], 1.0 / fps)
    dv, _ = robot_motion(tv, tr)
    vt, vb = true_angles(dv, path, tr, ds["theta_bot_floor"])
    m_tip = vt + rng_n.normal(0.0, ds["angle_sd_tip"], tv.size)
    contact_v = vt > vb
    bot_noisy = np.minimum(vb + rng_n.normal(0.0, ds["angle_sd_bot"], tv.size), m_tip)
    m_bot = np.where(contact_v, bot_noisy, m_tip)
    miss = rng_n.random(tv.size) < ds["p_missing_frame"]
    m_tip[miss] = np.nan
    m_bot[miss] = np.nan
    i_tip = np.interp(t, tv, m_tip, left=np.nan, right=np.nan)
    i_bot = np.interp(t, tv, m_bot, left=np.nan, right=np.nan)

    cols = {
        "time_s": t, "force_g": force, "theta_tip": i_tip, "theta_bot": i_bot,
        "theta_con": i_tip - i_bot, "depth_mm": depth, "true_force_g": sensed,
        "true_base_g": true_base, "true_theta_tip": th_tip, "true_theta_bot": th_bot,
    }
    trial_truth = TrialTruth(
        **{k: tr[k] for k in ("speed_actual_mm_s", "pre_roll_s", "dwell_s", "accel_s", "d0_mm",
                              "final_depth_mm", "e_lat_mm", "tilt_rad", "kappa0_per_mm", "alpha",
                              "beta", "p_tip_scale", "p_bot_scale", "gain", "tare_g", "video_start_s")},
        lambda_=tr["lambda"],
        t_motion_start_s=t_on, t_motion_stop_s=t_off, d_hit_mm=path.d_hit,
        theta_hit=path.theta_hit, mu=mu_c,
        theta_tip_end=float(th_tip[-1]), theta_bot_end=float(th_bot[-1]),
        effect_params={k: v for k, v in prm.items()} if effect else {},
        film_ratio_at_stop=film_ratio_at_stop,
    )
    # Design columns of the base pressure law (for the "unabsorbed gap" figure).
    w = arc.ds[:, None] * (arc.ndotx + mu[:, None]) * ds["b_c"] / G_N * tr["gain"]
    A_t = (w * (1 - arc.u)).sum(axis=1)
    A_b = (w * arc.u).sum(axis=1)
    cols["_design"] = np.stack([A_t, A_t * con, A_b, A_b * con], axis=1)
    return cols, trial_truth


def generate(effect: str | None, seed: int, *, strength: float = 1.0,
             speeds_mm_s: Sequence[float] = (0.5, 1.5, 3.0, 5.0, 7.5), trials: int = 10,
             noise_scale: float = 1.0) -> tuple[pd.DataFrame, GeneratedTruth]:
    """Generate one synthetic insertion experiment with (optionally) one hidden effect.

    Parameters
    ----------
    effect : str or None
        One of :data:`EFFECTS`, or None for the pure base model plus noise.
    seed : int
        Seed; the same seed gives identical output.  Base model, kinematics, sensor noise
        and video draws do not depend on ``effect`` or ``strength``, so data sets with the
        same seed differ only by the effect.
    strength : float, keyword-only
        Size of the effect: 0 = absent, 1 = typical and clearly visible.  It multiplies
        the effect's size (film separation, drag, compression-to-wall coupling, filter time
        constants, drift amplitude, share of the end-loaded profile).
    speeds_mm_s : sequence of float, keyword-only
        Nominal insertion speeds [mm/s].
    trials : int, keyword-only
        Trials per speed.
    noise_scale : float, keyword-only
        Multiplies the force-noise RMS (quantisation is always applied).

    Returns
    -------
    df : pandas.DataFrame
        One row per force sample, all trials stacked.  Columns: ``trial`` (str, e.g.
        ``"v3_t04"``: speed index, trial index), ``speed_mm_s`` (nominal), ``time_s``
        (force clock, 0 at the log's start), ``force_g`` (measured), ``theta_tip``,
        ``theta_bot``, ``theta_con`` [rad] (video: noisy, interpolated; NaN where no
        frame), ``depth_mm`` (robot depth), and the truth columns ``true_force_g`` (sensor
        output without random noise/quantisation, effect included), ``true_base_g``
        (base model with the same trial's parameters, gain and tare), ``true_theta_tip``,
        ``true_theta_bot``.
    truth : GeneratedTruth
        ``effect``, ``strength``, ``family`` ("B"), the data-set draws and the effect's
        constants, ``base`` (base-model constants and per-trial values), ``noise``,
        ``gap_rms_g``, ``noise_rms_g``, ``snr``, ``gap_unabsorbed_rms_g`` (gap RMS after
        removing its least-squares projection on the base model's four pressure-law columns,
        pooled) and ``snr_unabsorbed``; ``to_json()`` gives its JSON object.

    Raises
    ------
    ValueError
        For an unknown effect name, a negative strength or no speeds/trials.
    """
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; expected one of {EFFECTS} or None")
    if strength < 0:
        raise ValueError("strength must be >= 0")
    if trials < 1 or len(speeds_mm_s) < 1:
        raise ValueError("need at least one speed and one trial")
    geom = geometry()
    ds = draw_dataset(seed)
    ref = reference_state(ds, geom)
    eff = draw_effect_constants(effect, seed, ds, ref, geom)

    parts: list[pd.DataFrame] = []
    designs: list[np.ndarray] = []
    trial_truths: dict[str, TrialTruth] = {}
    for iv, v in enumerate(speeds_mm_s):
        for it in range(trials):
            cols, tt = _trial_frame(effect, strength, seed, iv, it, float(v), ds, eff, ref,
                                    geom, noise_scale)
            name = f"v{iv}_t{it:02d}"
            designs.append(cols.pop("_design"))
            n = cols["time_s"].size
            parts.append(pd.DataFrame({"trial": [name] * n, "speed_mm_s": np.full(n, float(v)),
                                       **cols}))
            trial_truths[name] = tt
    df = pd.concat(parts, ignore_index=True)
    df = df[["trial", "speed_mm_s", "time_s", "force_g", "theta_tip", "theta_bot", "theta_con",
             "depth_mm", "true_force_g", "true_base_g", "true_theta_tip", "true_theta_bot"]]

    gap = (df["true_force_g"] - df["true_base_g"]).to_numpy()
    resid = (df["force_g"] - df["true_force_g"]).to_numpy()
    gap_rms = float(np.sqrt(np.mean(gap**2)))
    noise_rms = float(np.sqrt(np.mean(resid**2)))
    X = np.vstack(designs)
    coef, *_ = np.linalg.lstsq(X, gap, rcond=None)
    gap_un = float(np.sqrt(np.mean((gap - X @ coef) ** 2)))

    sc = ref["pressure_scale"]
    base = BaseModelTruth(
        mu_k=ds["mu_k"], mu_s=ds["mu_s"], v_s_mm_s=ds["v_s"], delta_s=ds["delta_s"], b_c_mm=ds["b_c"],
        p_tip_MPa=LinearLawTruth(a=ds["pt0"] * sc, b_per_rad=(ds["pt3"] - ds["pt0"]) / 3.0 * sc),
        p_bot_MPa=LinearLawTruth(a=ds["pb0"] * sc, b_per_rad=(ds["pb3"] - ds["pb0"]) / 3.0 * sc),
        target_end_force_g=ds["target_end_force_g"],
        reference_state=ReferenceTruth(depth_mm=15.0, theta_tip=ref["theta_tip"], theta_bot=ref["theta_bot"],
                                       p_ref_MPa=ref["p_ref"]),
        trials=trial_truths,
    )
    noise = NoiseTruth(
        force_rate_hz=ds["force_rate_hz"],
        rms_g=ds["noise_rms_g"] * noise_scale, ar1_variance_share=ds["noise_ar_share"],
        ar1_tau_s=ds["noise_tau_s"], full_scale_g=ds["full_scale_g"], adc_bits=13,
        lsb_g=2 * ds["full_scale_g"] / 2**13, gain_spread=ds["gain_spread"],
        tare_sd_g=ds["tare_sd_g"], fps=ds["fps"], angle_sd_tip=ds["angle_sd_tip"],
        angle_sd_bot=ds["angle_sd_bot"], p_missing_frame=ds["p_missing_frame"],
        noise_scale=noise_scale,
    )
    truth = GeneratedTruth(
        effect=effect, strength=float(strength), seed=int(seed),
        speeds_mm_s=tuple(float(v) for v in speeds_mm_s), trials=int(trials),
        dataset_params=dict(ds), effect_params=eff,
        base=base, noise=noise,
        gap_rms_g=gap_rms, noise_rms_g=noise_rms,
        snr=gap_rms / noise_rms if noise_rms > 0 else float("inf"),
        gap_unabsorbed_rms_g=gap_un,
        snr_unabsorbed=gap_un / noise_rms if noise_rms > 0 else float("inf"),
    )
    json.dumps(truth.to_json())  # fail early if anything is not serialisable
    return df, truth

"""Constants of the hidden effect in family B: drawn, calibrated on a reference state, varied per trial."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tympani.pipeline.synthetic.family_b.constants import EFFECTS
from tympani.pipeline.synthetic.family_b.contact import arc_force_g, contact_arc, linear_pressure, stribeck_mu
from tympani.pipeline.synthetic.family_b.draws import draw_log_uniform, draw_uniform, seeded_rng
from tympani.pipeline.synthetic.family_b.effects import drag_force_g, lift_pressure, lift_separation
from tympani.pipeline.synthetic.family_b.kinematics import true_angles
from tympani.pipeline.synthetic.family_b.phantom import PhantomGeometry
from tympani.pipeline.synthetic.family_b.trajectory import tip_path

__all__ = ["draw_effect_constants", "vary_effect_constants", "reference_state"]


def draw_effect_constants(effect: str | None, seed: int, ds: dict[str, Any], ref: dict[str, Any],
                          geom: PhantomGeometry) -> dict[str, Any]:
    """Data-set-level constants of the hidden effect (drawn at strength 1)."""
    if effect is None:
        return {}
    rng = seeded_rng(seed, 4, EFFECTS.index(effect))
    if effect == "hydrodynamic_lift":
        prm = {
            "n_h": draw_uniform(rng, 0.58, 0.67),
            "m_load": draw_uniform(rng, 0.15, 0.25),
            "v_c_mm_s": draw_uniform(rng, 0.15, 0.7),
            "eps_transition": draw_uniform(rng, 0.2, 0.4),
            "v_ref_mm_s": 7.5,
            "tau_0_s": draw_uniform(rng, 0.1, 0.4),
            "L_e_mm": draw_uniform(rng, 0.3, 1.0),
            "tau_s_s": draw_uniform(rng, 1.0, 3.0),
            "target_drop_7p5": draw_uniform(rng, 0.25, 0.40),
            "sigma_r_um": draw_uniform(rng, 0.2, 1.0),
        }
        prm["K"] = _calibrate_lift(prm, ds, ref)
        # Physical reading of K = k h_ref / p_ref: the film at v_ref separates the surfaces
        # by h_ref = sigma_r eps ln(1 + exp((Lam_ref - 1)/eps)); k follows.
        lam_ref = (prm["v_ref_mm_s"] / prm["v_c_mm_s"]) ** prm["n_h"]
        prm["h_sep_ref_um"] = prm["sigma_r_um"] * prm["eps_transition"] * float(
            np.logaddexp(0.0, (lam_ref - 1.0) / prm["eps_transition"]))
        prm["winkler_k_MPa_per_um"] = prm["K"] * ref["p_ref"] / prm["h_sep_ref_um"]
        return prm
    if effect == "viscous_drag":
        prm = {
            "eta_mPa_s": draw_log_uniform(rng, 300.0, 1400.0),
            "r_entry": draw_uniform(rng, 0.8, 1.0),
            "n_h": draw_uniform(rng, 0.58, 0.67),
            "v_ref_mm_s": 7.5,
            "b_c_mm": ds["b_c"],
            "q_r_N_per_mm": ref["p_ref"] * ds["b_c"],
            "target_drag_7p5_g": draw_uniform(rng, 1.3, 2.0),
        }
        prm["h_r_um"] = _calibrate_drag(prm, ds, ref, geom)
        return prm
    if effect == "capstan":
        return {"chi": draw_uniform(rng, 0.85, 1.0), "m_rub": draw_uniform(rng, 0.05, 0.15)}
    if effect == "sensor_lag":
        D = draw_uniform(rng, 0.2, 0.5)
        f_ma, f_2 = draw_uniform(rng, 0.1, 0.3), draw_uniform(rng, 0.3, 0.6)
        return {
            "delay_s": D,
            "T_ma_s": 2 * f_ma * D,
            "tau_2_s": f_2 * D,
            "zeta": draw_uniform(rng, 0.45, 0.8),
            "tau_1_s": (1 - f_ma - f_2) * D,
        }
    if effect == "sensor_drift":
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return {
            "tau_th_s": draw_uniform(rng, 10.0, 35.0),
            "A_g": sign * draw_uniform(rng, 0.5, 1.2),
            "t_w_s": draw_uniform(rng, 0.5, 3.0),
            "c_cr_per_s": draw_uniform(rng, 2e-4, 8e-4) * (1.0 if rng.random() < 0.5 else -1.0),
        }
    if effect == "pressure_profile":
        return {"sigma": draw_uniform(rng, 0.65, 0.95), "beta_per_mm": 1.0 / draw_uniform(rng, 0.8, 2.0)}
    raise ValueError(f"unknown effect {effect!r}; expected one of {EFFECTS} or None")


def vary_effect_constants(effect: str | None, prm: dict[str, Any], seed: int, iv: int,
                          it: int) -> dict[str, Any]:
    """Trial-to-trial variation (a few to ~15 %) of the effect's constants."""
    if effect is None:
        return {}
    rng = seeded_rng(seed, 5, EFFECTS.index(effect), iv, it)
    out = dict(prm)

    def j(name: str, rel: float) -> None:
        out[name] = prm[name] * (1.0 + draw_uniform(rng, -rel, rel))

    if effect == "hydrodynamic_lift":
        j("K", 0.10), j("tau_0_s", 0.15), j("L_e_mm", 0.15), j("tau_s_s", 0.15), j("v_c_mm_s", 0.1)
    elif effect == "viscous_drag":
        j("eta_mPa_s", 0.08), j("h_r_um", 0.15), j("r_entry", 0.05)
    elif effect == "capstan":
        out["chi"] = min(1.0, prm["chi"] * (1.0 + draw_uniform(rng, -0.1, 0.1)))
        j("m_rub", 0.15)
    elif effect == "sensor_lag":
        j("T_ma_s", 0.05), j("tau_2_s", 0.05), j("tau_1_s", 0.05), j("zeta", 0.05)
    elif effect == "sensor_drift":
        j("A_g", 0.15), j("tau_th_s", 0.15), j("t_w_s", 0.2), j("c_cr_per_s", 0.2)
    elif effect == "pressure_profile":
        j("sigma", 0.06), j("beta_per_mm", 0.12)
        out["sigma"] = min(out["sigma"], 1.0)
    return out


def reference_state(ds: dict[str, Any], geom: PhantomGeometry) -> dict[str, Any]:
    """Reference end-of-insertion state (15 mm, mean kinematics) and pressure scaling."""
    path = tip_path(geom, ds["e_lat_mean_mm"], 0.0, ds["kappa0_mean_per_mm"])
    tr = {"alpha": ds["alpha_mean"], "beta": ds["beta_mean"], "lambda": ds["lambda_mean"],
          "wiggle_amp": 0.0, "wiggle_k": [1.0, 1.0], "wiggle_phase": [0.0, 0.0]}
    th_tip, th_bot = true_angles(np.array([15.0]), path, tr, ds["theta_bot_floor"])
    con = th_tip - th_bot
    arc = contact_arc(geom, th_bot, th_tip)
    pt = ds["pt0"] + (ds["pt3"] - ds["pt0"]) / 3.0 * con
    pb = ds["pb0"] + (ds["pb3"] - ds["pb0"]) / 3.0 * con
    mu = stribeck_mu(np.array([3.0]), ds["mu_k"], ds["mu_s"], ds["v_s"], ds["delta_s"])
    F_raw = float(arc_force_g(arc, linear_pressure(arc, pt, pb), mu, ds["b_c"])[0])
    scale = ds["target_end_force_g"] / F_raw
    return {
        "path": path, "theta_tip": float(th_tip[0]), "theta_bot": float(th_bot[0]),
        "arc": arc, "pressure_scale": scale,
        "p_tip": pt * scale, "p_bot": pb * scale,
        "p_ref": float(linear_pressure(arc, pt * scale, pb * scale).mean()),
    }


def _calibrate_lift(prm: dict[str, Any], ds: dict[str, Any], ref: dict[str, Any]) -> float:
    """K such that the steady end force at 7.5 mm/s is ``target_drop_7p5`` below 0.5 mm/s."""
    arc = ref["arc"]
    p = linear_pressure(arc, ref["p_tip"], ref["p_bot"])

    def force(v: float, K: float) -> float:
        mu = stribeck_mu(np.array([v]), ds["mu_k"], ds["mu_s"], ds["v_s"], ds["delta_s"])
        H = lift_separation(np.array([(v / prm["v_c_mm_s"]) ** prm["n_h"]]), prm)
        p_eff = lift_pressure(p, H, K, ref["p_ref"], prm["m_load"])
        return float(arc_force_g(arc, p_eff, mu, ds["b_c"])[0])

    lo, hi = 0.0, 3.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        drop = 1.0 - force(7.5, mid) / force(0.5, mid)
        lo, hi = (mid, hi) if drop < prm["target_drop_7p5"] else (lo, mid)
    return 0.5 * (lo + hi)


def _calibrate_drag(prm: dict[str, Any], ds: dict[str, Any], ref: dict[str, Any],
                    geom: PhantomGeometry) -> float:
    """Reference film thickness h_r [um] giving ``target_drag_7p5_g`` at the end state."""
    depth = np.array([15.0])
    vel = np.array([7.5])
    arc = ref["arc"]
    q = linear_pressure(arc, ref["p_tip"], ref["p_bot"]) * ds["b_c"]

    def drag(h_um: float) -> float:
        return float(drag_force_g(depth, vel, arc, q, ref["path"], geom,
                                  {**prm, "h_r_um": h_um}, 1.0)[0])

    lo, hi = math.log(1e-3), math.log(100.0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if drag(math.exp(mid)) < prm["target_drag_7p5_g"] else (mid, hi)
    return float(math.exp(0.5 * (lo + hi)))

"""The hidden effects of family B: on the contact mechanics, and the sensor chain."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import signal

from tympani.pipeline.synthetic.family_b.constants import ARRAY_D_BASE_MM, ARRAY_D_TIP_MM, ARRAY_LENGTH_MM, G_N, N_WET
from tympani.pipeline.synthetic.family_b.contact import Arc
from tympani.pipeline.synthetic.family_b.phantom import PhantomGeometry
from tympani.pipeline.synthetic.family_b.trajectory import TipPath

__all__ = [
    "film_state",
    "lift_separation",
    "lift_pressure",
    "profile_pressure",
    "capstan_force_g",
    "drag_force_g",
    "lag_filter",
    "drift_signal",
    "sensor_noise",
]


def _softpos(z: np.ndarray, eps: float = 0.03) -> np.ndarray:
    """Smooth max(z, 0) (softplus with width ``eps``)."""
    return eps * np.logaddexp(0.0, z / eps)


def film_state(t: np.ndarray, t_on: float, t_off: float, v: float,
               prm: dict[str, float]) -> np.ndarray:
    """Film-thickness ratio ``Lam(t) = h / sigma_r`` of the lubricant film (lift effect).

    Steady film (soft-EHL, isoviscous-elastic regime, ``h ~ (eta u)^0.6-0.67``), written
    relative to the composite surface roughness ``sigma_r``:
    ``Lam_ss = (v / v_c)^n_h`` (``v_c``: speed at which the film just covers the
    roughness).  Build-up while sliding: ``dLam/dt = (Lam_ss - Lam) / tau_b`` with
    ``tau_b = tau_0 + L_e / v`` (the surfaces must travel an entrainment length L_e).
    Squeeze-out after the stop, Reynolds squeeze of a compliant film whose drainage
    resistance grows as it thins: ``dLam/dt = -Lam^2 / (Lam_stop tau_s)``, i.e.
    ``Lam = Lam_stop / (1 + (t - t_off) / tau_s)``.  Before the motion ``Lam = 0``.
    """
    lam_ss = (v / prm["v_c_mm_s"]) ** prm["n_h"]
    tau_b = prm["tau_0_s"] + prm["L_e_mm"] / max(v, 1e-6)
    lam = np.zeros_like(t)
    on = (t > t_on) & (t <= t_off)
    lam[on] = lam_ss * (1.0 - np.exp(-(t[on] - t_on) / tau_b))
    lam_stop = lam_ss * (1.0 - math.exp(-(t_off - t_on) / tau_b))
    off = t > t_off
    lam[off] = lam_stop / (1.0 + (t[off] - t_off) / prm["tau_s_s"])
    return lam


def lift_separation(lam: np.ndarray, prm: dict[str, float]) -> np.ndarray:
    """Separation gained from the film, normalised to its steady value at ``v_ref``.

    Only the part of the film above the roughness lifts the array (mixed -> full film
    transition): ``sep = eps ln(1 + exp((Lam - 1) / eps))`` (smooth ``(Lam - 1)_+``).
    """
    eps = prm["eps_transition"]

    def sep(x: np.ndarray | float) -> np.ndarray:
        return eps * np.logaddexp(0.0, (np.asarray(x, dtype=float) - 1.0) / eps)

    ref = sep((prm["v_ref_mm_s"] / prm["v_c_mm_s"]) ** prm["n_h"])
    return sep(lam) / ref


def lift_pressure(p: np.ndarray, H: np.ndarray, K: float, p_ref: float,
                  m_load: float) -> np.ndarray:
    """Contact pressure relieved by a lubricant film (elastic-interference relief).

    The array presses on the wall through an elastic interference ``delta = p / k``
    (Winkler foundation of stiffness k).  A film that separates the surfaces by
    ``h_loc`` moves the array off the wall and relieves the interference::

        p' = k (delta - h_loc)_+ = p (1 - k h_loc / p)_+

    with the soft-EHL load dependence ``h_loc = h (p / p_ref)^(-m_load)``.  In
    dimensionless form, with ``H = h / h_ref`` and ``K = k h_ref / p_ref``,
    ``k h_loc / p = K H (p / p_ref)^(-1 - m_load)``.  Friction acts on ``p'`` too.
    """
    x = K * H[:, None] * (np.maximum(p, 1e-9) / p_ref) ** (-1.0 - m_load)
    return p * _softpos(1.0 - x)


def profile_pressure(arc: Arc, p_lin: np.ndarray, p_tip: np.ndarray, p_bot: np.ndarray,
                     sigma: float, beta: float) -> np.ndarray:
    """End-loaded contact pressure of an elastic beam on an elastic foundation.

    A beam pressed into the wall at both ends of the contact (the advancing tip and the
    point where the array leaves the wall) carries, on a Winkler foundation, the pressure
    of two Hetenyi end-load solutions::

        g(x) = exp(-x) (cos x + sin x),   x = beta s  (from the tip) or beta (l - s)
        p_end(s) = N [p_tip g(beta s) + p_bot g(beta (l - s))]_+ / int[...]_+ ds

    normalised to the same total load ``N = int p_lin ds`` as the linear profile.  Short
    arcs (beta l << 1) are loaded almost uniformly; long arcs become U-shaped with an
    unloaded middle.  The applied pressure is ``(1 - sigma) p_lin + sigma p_end``.
    """
    s = arc.s
    lcol = arc.l[:, None]
    g_t = np.exp(-beta * s) * (np.cos(beta * s) + np.sin(beta * s))
    g_b = np.exp(-beta * (lcol - s)) * (np.cos(beta * (lcol - s)) + np.sin(beta * (lcol - s)))
    shape = _softpos(p_tip[:, None] * g_t + p_bot[:, None] * g_b, eps=0.002)
    tot_lin = p_lin.mean(axis=1)
    tot_shape = np.maximum(shape.mean(axis=1), 1e-12)
    p_end = shape * (tot_lin / tot_shape)[:, None]
    return (1.0 - sigma) * p_lin + sigma * p_end


def capstan_force_g(arc: Arc, p: np.ndarray, mu: np.ndarray, b_c: float, chi: float,
                    m_rub: float) -> np.ndarray:
    """Axial load at the contact start from a belt equation with distributed load.

    March from the tip (``T = 0``) to the contact start.  Each element adds its base-model
    axial load ``q (n.x_w + mu) ds`` (``q = p b_c`` line load [N/mm]); the axial
    compression ``T`` already built up presses the array on the curved wall with an extra
    line load ``chi kappa T`` (``chi``: share not carried by the array's bending stiffness),
    whose friction follows the elastomer law ``f ~ P^(1 - m_rub)`` (real contact area grows
    sub-linearly with load), normalised to Coulomb friction at the elastic pre-load::

        dT/ds = q (n.x_w + mu) + mu q^m [(q + chi kappa T_+)^(1-m) - q^(1-m)]

    Returns ``T(l_con)`` [g]; with ``chi = 0`` this equals the base-model force.
    """
    q = p * b_c
    contrib = q * (arc.ndotx + mu[:, None]) * arc.ds[:, None]
    kap = np.maximum(arc.kappa, 0.0)
    T = np.zeros(p.shape[0])
    one_m = 1.0 - m_rub
    for j in range(p.shape[1]):
        qj = np.maximum(q[:, j], 1e-12)
        base_j = qj ** one_m

        def extra(Tm: np.ndarray) -> np.ndarray:
            P = qj + chi * kap[:, j] * np.maximum(Tm, 0.0)
            return mu * qj ** m_rub * (P ** one_m - base_j)

        Tm = T + 0.5 * contrib[:, j]
        for _ in range(2):  # midpoint (predictor-corrector) step
            Tm = T + 0.5 * (contrib[:, j] + extra(Tm) * arc.ds)
        T = T + contrib[:, j] + extra(Tm) * arc.ds
    return T / G_N


def drag_force_g(depth: np.ndarray, vel: np.ndarray, arc: Arc, q: np.ndarray,
                 path: TipPath, geom: PhantomGeometry, prm: dict[str, float],
                 strength: float) -> np.ndarray:
    """Viscous shear drag on the wetted array [g].

    Two parts, each element's drag transmitted along x_w:

    * **free wetted array** (in the fluid-filled entry and in the spiral behind the
      contact): axial Couette flow round a rod of radius ``a(x)`` (tapered) moving at
      ``v`` inside a channel of equivalent radius ``R``; drag per unit length
      ``2 pi eta v / ln(R / a)`` (concentric annulus).  ``R`` is the local half-width
      ``w(theta) / 2`` in the spiral (``w`` = full channel width) and
      ``r_entry w_max / 2`` in the entry, so the drag per mm depends on the local
      clearance and on the taper.  ``R / a`` is at least 1.09 for the default array and
      phantom (entry, deepest insertion, ``r_entry = 0.8``); the floor of 1.05 below is
      only a guard.
    * **contact band** (the arc pressed on the outer wall): shear of the soft-EHL film
      under the flattened band.  Band width grows as ``(q / q_r)^(1/2)`` (Hertz line
      contact), film thickness ``h = h_r (v / v_r)^n_h (q / q_r)^(-0.21)``, so the shear
      force per element is ``eta v b_c (q/q_r)^0.71 ds / h``, i.e. it grows as
      ``v^(1 - n_h)`` and with the load-weighted contact length.

    The wetted array is the inserted part plus the part in the fluid-filled entry.
    """
    eta = prm["eta_mPa_s"] * 1e-3  # Pa s
    L_entry = geom.phantom.entry_mm
    wet = np.clip(depth + L_entry, 0.0, ARRAY_LENGTH_MM)
    u = (np.arange(N_WET) + 0.5) / N_WET
    x = u[None, :] * wet[:, None]  # distance from the tip along the array [mm]
    dx = wet / N_WET
    a = 0.5 * (ARRAY_D_TIP_MM + (ARRAY_D_BASE_MM - ARRAY_D_TIP_MM) * x / ARRAY_LENGTH_MM)
    pos = depth[:, None] - x  # depth coordinate of the element
    th = np.interp(pos, path.depth, path.theta)
    R = np.where(pos > 0, geom.phantom.half_width(th),
                 prm["r_entry"] * 0.5 * geom.phantom.w_max_mm)
    free = x >= arc.l[:, None]
    per = np.where(free, 2 * math.pi / np.log(np.maximum(R / a, 1.05)), 0.0)
    F_free = eta * (vel * 1e-3) * (per.sum(axis=1) * dx * 1e-3)  # N
    vpos = np.maximum(vel, 0.0)
    h = prm["h_r_um"] * 1e-6 * np.maximum(vpos / prm["v_ref_mm_s"], 1e-9) ** prm["n_h"]
    qq = np.maximum(q, 0.0) / prm["q_r_N_per_mm"]
    band = (qq ** 0.71).sum(axis=1) * arc.ds * 1e-3  # m
    F_band = np.where(vpos > 0, eta * (vpos * 1e-3) * prm["b_c_mm"] * 1e-3 * band / h, 0.0)
    return strength * (F_free + F_band) / G_N


# --------------------------------------------------------------------------------------
# Sensor chain
# --------------------------------------------------------------------------------------
def lag_filter(x: np.ndarray, fs: float, prm: dict[str, float]) -> np.ndarray:
    """Multi-stage sensor/amplifier filter: moving average -> 2nd-order -> 1st-order.

    * anti-alias moving average over ``T_ma`` (group delay ``T_ma/2``),
    * underdamped second-order stage ``w^2 / (s^2 + 2 zeta w s + w^2)`` (delay
      ``2 zeta / w``, overshoot for a step when ``zeta < 1``),
    * first-order amplifier stage ``1 / (tau_1 s + 1)`` (delay ``tau_1``).

    Initial state: steady at the first sample, so the filter acts on the whole log
    (pre-roll, insertion, dwell).
    """
    y = x
    n_ma = int(round(prm["T_ma_s"] * fs))
    if n_ma >= 2:
        pad = np.concatenate([np.full(n_ma - 1, y[0]), y])
        y = np.convolve(pad, np.ones(n_ma) / n_ma, mode="valid")
    if prm["tau_2_s"] > 1e-6:
        wn = 2 * prm["zeta"] / prm["tau_2_s"]
        num, den = [wn**2], [1.0, 2 * prm["zeta"] * wn, wn**2]
        bz, az = signal.bilinear(num, den, fs=fs)
        y = signal.lfilter(bz, az, y, zi=signal.lfilter_zi(bz, az) * y[0])[0]
    if prm["tau_1_s"] > 1e-6:
        bz, az = signal.bilinear([1.0], [prm["tau_1_s"], 1.0], fs=fs)
        y = signal.lfilter(bz, az, y, zi=signal.lfilter_zi(bz, az) * y[0])[0]
    return y


def drift_signal(t: np.ndarray, F_g: np.ndarray, prm: dict[str, float], strength: float) -> np.ndarray:
    """Sensor drift [g]: thermal exponential approach plus load creep.

    ``d(t) = strength [ A (1 - exp(-(t + t_w)/tau_th)) + c_cr int_0^t F dt' ]``

    The bridge warms towards a new equilibrium with time constant ``tau_th`` since it was
    tared ``t_w`` seconds before the log started (so the drift is already non-zero at
    t = 0 and before contact); the strain gauges creep in proportion to the load
    accumulated over the trial.
    """
    therm = prm["A_g"] * (1.0 - np.exp(-(t + prm["t_w_s"]) / prm["tau_th_s"]))
    dt = np.diff(t, prepend=t[0])
    creep = prm["c_cr_per_s"] * np.cumsum(np.maximum(F_g, 0.0) * dt)
    return strength * (therm + creep)


def sensor_noise(n: int, fs: float, ds: dict[str, Any], noise_scale: float,
                 rng: np.random.Generator) -> np.ndarray:
    """White + AR(1) noise [g] with total RMS ``noise_rms_g * noise_scale``."""
    sd = ds["noise_rms_g"] * noise_scale
    sd_ar = sd * math.sqrt(ds["noise_ar_share"])
    sd_w = sd * math.sqrt(1.0 - ds["noise_ar_share"])
    phi = math.exp(-1.0 / (fs * ds["noise_tau_s"]))
    innov = rng.normal(0.0, sd_ar * math.sqrt(1 - phi**2), n)
    x0 = rng.normal(0.0, sd_ar)
    ar = signal.lfilter([1.0], [1.0, -phi], innov, zi=[phi * x0])[0]
    return ar + rng.normal(0.0, sd_w, n)

"""The paper's friction model in family B: Stribeck friction, linear pressure, the contact arc."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tympani.pipeline.synthetic.family_b.constants import G_N, N_ARC
from tympani.pipeline.synthetic.family_b.phantom import PhantomGeometry

__all__ = ["stribeck_mu", "Arc", "contact_arc", "linear_pressure", "arc_force_g"]


def stribeck_mu(v: np.ndarray | float, mu_k: float, mu_s: float, v_s: float,
                delta_s: float) -> np.ndarray:
    """Stribeck friction coefficient ``mu_k + (mu_s - mu_k) exp(-|v/v_s|^delta_s)``.

    Parameters
    ----------
    v : array_like
        Sliding speed [mm/s].
    mu_k, mu_s : float
        Kinetic and static coefficients [-].
    v_s : float
        Stribeck speed [mm/s].
    delta_s : float
        Stribeck exponent [-].

    Returns
    -------
    numpy.ndarray
        Friction coefficient [-].
    """
    v = np.abs(np.asarray(v, dtype=float))
    return mu_k + (mu_s - mu_k) * np.exp(-((v / v_s) ** delta_s))


@dataclass
class Arc:
    """Contact-arc elements for a batch of samples.

    Every array has shape (m, N_ARC); element j of sample i lies at distance
    ``s[i, j] = u_j l[i]`` from the tip, ``u_j = (j + 1/2) / N_ARC``.

    Attributes
    ----------
    l : numpy.ndarray
        Contact arc length l_con [mm], shape (m,).
    ds : numpy.ndarray
        Element length [mm], shape (m,).
    u : numpy.ndarray
        Normalised position from the tip, shape (N_ARC,).
    s : numpy.ndarray
        Distance from the tip [mm].
    ndotx : numpy.ndarray
        ``n_out . x_w`` of each element [-].
    kappa : numpy.ndarray
        Wall curvature [1/mm].
    width : numpy.ndarray
        Full channel width w(theta) at the element [mm] (the walls are w/2 from the
        backbone).
    """

    l: np.ndarray
    ds: np.ndarray
    u: np.ndarray
    s: np.ndarray
    ndotx: np.ndarray
    kappa: np.ndarray
    width: np.ndarray


def contact_arc(geom: PhantomGeometry, theta_bot: np.ndarray, theta_tip: np.ndarray,
                n: int = N_ARC) -> Arc:
    """Discretise the outer wall between ``theta_bot`` and ``theta_tip`` [rad].

    Samples with ``theta_tip <= theta_bot`` get ``l = 0`` (no contact, zero force).
    """
    theta_bot = np.asarray(theta_bot, dtype=float)
    theta_tip = np.asarray(theta_tip, dtype=float)
    s_tip = geom.s_of_theta(theta_tip)
    s_bot = geom.s_of_theta(np.minimum(theta_bot, theta_tip))
    l = np.maximum(s_tip - s_bot, 0.0)
    u = (np.arange(n) + 0.5) / n
    s = u[None, :] * l[:, None]
    S = s_tip[:, None] - s
    return Arc(
        l=l, ds=l / n, u=u, s=s,
        ndotx=np.interp(S, geom.S, geom.ndotx),
        kappa=np.interp(S, geom.S, geom.kappa),
        width=np.interp(S, geom.S, geom.width),
    )


def linear_pressure(arc: Arc, p_tip: np.ndarray, p_bot: np.ndarray) -> np.ndarray:
    """The paper's Eq. (6): ``p(s) = p_tip + (s / l_con)(p_bot - p_tip)`` [MPa], shape (m, N_ARC)."""
    return p_tip[:, None] + arc.u[None, :] * (p_bot - p_tip)[:, None]


def arc_force_g(arc: Arc, p: np.ndarray, mu: np.ndarray, b_c: float) -> np.ndarray:
    """Sensed axial force [g] of a pressure field on the arc ("axial" projection).

    ``F = b_c [ sum p_i ds (n_out_i . x_w) + mu sum p_i ds ] / G_N``.

    Parameters
    ----------
    arc : Arc
        Contact-arc elements.
    p : numpy.ndarray
        Pressure per element [MPa], shape (m, N_ARC).
    mu : numpy.ndarray
        Friction coefficient per sample [-], shape (m,).
    b_c : float
        Effective contact width [mm].
    """
    w = p * arc.ds[:, None]
    return b_c * ((w * arc.ndotx).sum(axis=1) + mu * w.sum(axis=1)) / G_N

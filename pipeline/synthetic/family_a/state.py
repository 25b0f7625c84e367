"""The rows of trials an effect acts on, and midpoint quadrature on their contact arcs (family A)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom

from tympani.pipeline.model.friction import (
    DEFAULT_FRICTION_MODE,
    G_N,
    ContactGeometry,
    FrictionParams,
    contact_geometry,
    stribeck,
)

__all__ = ["TrialState", "ContactArc", "arc_nodes", "physical_effect"]


@dataclass(frozen=True)
class TrialState:
    """Everything an effect may use about one or more trials (per-row arrays on the force clock).

    Rows of a trial are contiguous and in time order.

    Parameters
    ----------
    trial : ndarray of int
        Trial index of each row.
    time_s : ndarray
        Sample times (s) from the start of each log.
    depth_mm : ndarray
        Insertion depth (mm).
    speed_mm_s : ndarray
        Instantaneous sliding speed (mm/s): the trial's actual speed while the robot moves, 0 else.
    run_speed_mm_s : ndarray
        The trial's actual insertion speed (mm/s), on every row.
    t_start_s, t_stop_s : ndarray
        When the trial's robot starts and stops (s), on every row.
    theta_tip, theta_bot : ndarray
        True angles (rad).
    pressure_scale : ndarray
        The trial's factor (dimensionless) on both pressure laws, on every row.
    params : FrictionParams
        The base force model (unscaled pressures).
    phantom : Phantom
        Geometry.
    """

    trial: np.ndarray
    time_s: np.ndarray
    depth_mm: np.ndarray
    speed_mm_s: np.ndarray
    run_speed_mm_s: np.ndarray
    t_start_s: np.ndarray
    t_stop_s: np.ndarray
    theta_tip: np.ndarray
    theta_bot: np.ndarray
    pressure_scale: np.ndarray
    params: FrictionParams
    phantom: Phantom = DEFAULT_PHANTOM

    @classmethod
    def single(cls, time_s: np.ndarray, depth_mm: np.ndarray, speed_mm_s: np.ndarray, theta_tip: np.ndarray,
               theta_bot: np.ndarray, params: FrictionParams, *, pressure_scale: float = 1.0,
               phantom: Phantom = DEFAULT_PHANTOM) -> "TrialState":
        """The state of one trial from its samples (start and stop found from ``speed_mm_s`` > 0).

        Parameters
        ----------
        time_s, depth_mm, speed_mm_s, theta_tip, theta_bot : ndarray
            Times (s), depths (mm), instantaneous speed (mm/s), true angles (rad).
        params : FrictionParams
            Base model.
        pressure_scale : float
            Factor on the pressures (dimensionless).
        phantom : Phantom
            Geometry.
        """
        t = np.asarray(time_s, dtype=float)
        v = np.asarray(speed_mm_s, dtype=float)
        n = t.size
        moving = np.flatnonzero(v > 0)
        t_start = float(t[moving[0]]) if moving.size else float(t[-1]) + 1.0
        t_stop = float(t[moving[-1]] + (t[1] - t[0] if n > 1 else 0.0)) if moving.size else t_start
        v_run = float(v.max()) if moving.size else 0.0
        return cls(np.zeros(n, dtype=int), t, np.asarray(depth_mm, dtype=float), v, np.full(n, v_run),
                   np.full(n, t_start), np.full(n, t_stop), np.asarray(theta_tip, dtype=float),
                   np.asarray(theta_bot, dtype=float), np.full(n, float(pressure_scale)), params, phantom)

    @property
    def moving(self) -> np.ndarray:
        """True where the robot moves."""
        return self.speed_mm_s > 0

    def segments(self) -> list[tuple[int, int]]:
        """``(start, stop)`` row slices of the trials."""
        cuts = np.flatnonzero(np.diff(self.trial)) + 1
        return list(zip(np.r_[0, cuts].tolist(), np.r_[cuts, len(self.trial)].tolist()))

    def dt_s(self, lo: int, hi: int) -> float:
        """Sample period (s) of the rows ``lo:hi``."""
        return float(np.median(np.diff(self.time_s[lo:hi]))) if hi - lo > 1 else 1.0




@lru_cache(maxsize=8)
def _wall_turn(geom: ContactGeometry) -> np.ndarray:
    """Unwrapped tangent angle (rad) of each wall segment relative to the insertion axis."""
    return np.unwrap(np.arctan2(geom.seg_g[:, 0], geom.seg_g[:, 1]))


@dataclass(frozen=True)
class ContactArc:
    """Midpoint quadrature nodes on the contact arcs of some rows.

    ``u`` (nodes,) from the tip; per row: ``length_mm``, ``p`` (MPa, the paper's Eq. 6 at the nodes),
    ``gn``/``gt`` (n_out . x_w, and the friction direction's component along x_w: 1 for the default
    axial projection), ``psi`` (rad, wall turning from the contact start).
    """

    u: np.ndarray
    length_mm: np.ndarray
    p: np.ndarray
    gn: np.ndarray
    gt: np.ndarray
    psi: np.ndarray

    def force_g(self, p: np.ndarray, mu: np.ndarray, weight: np.ndarray | float = 1.0, b_c: float = 0.3) -> np.ndarray:
        """``b_c * sum p w (g_n + mu g_t) ds`` in grams-force for node pressures ``p`` (MPa)."""
        ds = self.length_mm / len(self.u)
        integrand = p * weight * (self.gn + mu[:, None] * self.gt)
        return b_c * ds * integrand.sum(axis=1) / G_N


def arc_nodes(theta_bot: np.ndarray, theta_tip: np.ndarray, params: FrictionParams, scale: np.ndarray,
              phantom: Phantom, nodes: int = 16) -> ContactArc:
    """Midpoint quadrature nodes on the contact arcs of some rows, with the paper's linear pressure.

    Parameters
    ----------
    theta_bot, theta_tip : ndarray
        True angles (rad) of the rows.
    params : FrictionParams
        Base model (its pressure laws, MPa).
    scale : ndarray
        Each row's factor (dimensionless) on the pressures.
    phantom : Phantom
        Geometry.
    nodes : int
        Quadrature nodes per arc.
    """
    geom = contact_geometry(phantom)
    bot = np.asarray(theta_bot, dtype=float)
    tip = np.asarray(theta_tip, dtype=float)
    s_b, s_t = geom.wall_s(bot), geom.wall_s(tip)
    length = np.maximum(s_t - s_b, 0.0)
    u = (np.arange(nodes) + 0.5) / nodes
    s = s_t[:, None] - u[None, :] * length[:, None]
    k = np.clip(np.searchsorted(geom.s, s, side="right") - 1, 0, len(geom.s) - 2)
    k_b = np.clip(np.searchsorted(geom.s, s_b, side="right") - 1, 0, len(geom.s) - 2)
    turn = _wall_turn(geom)
    theta_con = np.clip(tip - bot, 0.0, None)
    p_tip = scale * np.maximum(np.asarray(params.p_tip_MPa(theta_con), dtype=float), 0.0)
    p_bot = scale * np.maximum(np.asarray(params.p_bot_MPa(theta_con), dtype=float), 0.0)
    p = p_tip[:, None] + u[None, :] * (p_bot - p_tip)[:, None]
    gt = geom.seg_g[k, 1] if DEFAULT_FRICTION_MODE == "vector" else np.ones_like(s)  # friction along x_w
    return ContactArc(u=u, length_mm=length, p=p, gn=geom.seg_g[k, 0], gt=gt,
                psi=np.maximum(turn[k] - turn[k_b][:, None], 0.0))


def physical_effect(state: TrialState, force_g: np.ndarray,
                    modified: Callable[[ContactArc, np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Base force + (quadrature with the effect - quadrature without it), on rows in contact.

    ``modified(arc, rows, mu)`` returns the force (g) with the effect on the contact rows.
    """
    out = np.array(force_g, dtype=float, copy=True)
    contact = (state.theta_tip - state.theta_bot) > 0
    if not contact.any():
        return out
    arc = arc_nodes(state.theta_bot[contact], state.theta_tip[contact], state.params, state.pressure_scale[contact],
                    state.phantom)
    mu = stribeck(state.speed_mm_s[contact], state.params)
    base = arc.force_g(arc.p, mu, 1.0, state.params.contact_width_mm)
    out[contact] += modified(arc, contact, mu) - base
    return out

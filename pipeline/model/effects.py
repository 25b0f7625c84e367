"""Unmodelled effects (docs/diagnosis.md) as composable terms on the base friction model.

Each :class:`Effect` turns the base model's force into an augmented force with one or two
parameters; all of them have a *null* value at which they change nothing, so "no effect" is
always inside the search. The diagnosis (:mod:`tympani.pipeline.diagnosis.analysis`) fits base + effect and asks
which effect explains a sim-to-real gap on held-out speeds.

An effect sees the data through an :class:`EffectContext` (per-row arrays built once per
dataset) and the base model's friction coefficient ``mu`` at each row's speed (it changes while
the base parameters are fitted).

These are the *library's* functional forms. Synthetic experiments with hidden effects are
generated with different forms (:mod:`tympani.pipeline.synthetic.experiment`), so the diagnosis is always tested
on a model-form mismatch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom
from tympani.pipeline.model.friction import DEFAULT_FRICTION_MODE, FrictionMode

__all__ = ["EffectContext", "Effect", "EFFECTS", "effect_names", "bump_integrals", "first_order_lag"]

G_N = 9.80665e-3  # newtons per gram-force


# --------------------------------------------------------------------------- context


def bump_integrals(
    theta_bot: np.ndarray, theta_tip: np.ndarray, phantom: Phantom = DEFAULT_PHANTOM, nodes: int = 16,
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE,
) -> np.ndarray:
    """Integrals of a mid-arc pressure bump over the contact arcs.

    For ``u = s / l_con`` along the arc and the bump ``b(u) = 4 u (1 - u)`` (1 at mid-arc, 0 at
    both ends), returns ``(integral b (n_out . x_w) ds, integral b t_f ds)`` in mm, by midpoint
    quadrature on the outer wall, with ``t_f`` the friction's component along the insertion axis
    (1 for the default axial projection, ``t . x_w`` for the vector sum; :mod:`tympani.pipeline.model.friction`).
    Zero where there is no contact.

    Parameters
    ----------
    theta_bot, theta_tip : ndarray, shape (n,)
        Contact start and tip angles (rad).
    phantom : Phantom
        Geometry.
    nodes : int
        Quadrature nodes per arc.
    friction_mode : {"axial", "vector"}
        Friction projection.

    Returns
    -------
    ndarray, shape (n, 2)
    """
    wall = phantom.outer_wall
    s_wall = wall.s
    tangent = np.gradient(wall.points, s_wall, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    _, x_w, _ = _entry_axis(phantom)
    along = tangent @ x_w if friction_mode == "vector" else np.ones(len(s_wall))
    proj = np.stack([normal @ x_w, along], axis=1)  # (m, 2)
    bot = np.nan_to_num(np.asarray(theta_bot, dtype=float))
    tip = np.nan_to_num(np.asarray(theta_tip, dtype=float))
    s_b = np.interp(bot, wall.theta, s_wall)
    s_t = np.interp(tip, wall.theta, s_wall)
    length = np.maximum(s_t - s_b, 0.0)
    u = (np.arange(nodes) + 0.5) / nodes
    s = s_b[:, None] + u[None, :] * length[:, None]
    weight = 4 * u * (1 - u) / nodes
    out = np.stack([np.interp(s, s_wall, proj[:, k]) @ weight for k in range(2)], axis=1)
    return out * length[:, None]


def _entry_axis(phantom: Phantom):
    from tympani.vision.geometry import entry_frame

    return entry_frame(phantom)


@dataclass(frozen=True)
class EffectContext:
    """Per-row data an effect may use (built once per dataset).

    Parameters
    ----------
    time_s : ndarray
        Sample times (s).
    trial : ndarray of int
        Trial index of each row (rows of one trial need not be contiguous).
    speed_mm_s : ndarray
        Insertion speed (mm/s).
    theta_con : ndarray
        Contact angle (rad).
    wetted_mm : ndarray
        Length of array in the lubricant (mm): the insertion depth.
    bump : ndarray, shape (n, 2)
        :func:`bump_integrals` of each row's contact arc (mm).
    order : ndarray of int
        Row order that sorts by (trial, time).
    """

    time_s: np.ndarray
    trial: np.ndarray
    speed_mm_s: np.ndarray
    theta_con: np.ndarray
    wetted_mm: np.ndarray
    bump: np.ndarray
    order: np.ndarray

    @classmethod
    def from_synced(cls, df: pd.DataFrame, phantom: Phantom = DEFAULT_PHANTOM) -> "EffectContext":
        """Build the context of a synced table (docs/file-formats.md; ``depth_mm`` used when present)."""
        trial = pd.factorize(df["trial"])[0]
        time = df["time_s"].to_numpy(float)
        theta_con = np.clip(df["theta_con"].to_numpy(float), 0.0, None)
        if "depth_mm" in df:
            wetted = np.clip(df["depth_mm"].to_numpy(float), 0.0, None)
        else:  # arc length of the outer wall from the entry to the tip
            wall = phantom.outer_wall
            wetted = np.interp(df["theta_tip"].to_numpy(float), wall.theta, wall.s, left=0.0)
        bump = bump_integrals(df["theta_bot"].to_numpy(float), df["theta_tip"].to_numpy(float), phantom)
        order = np.lexsort((time, trial))
        return cls(time, trial, df["speed_mm_s"].to_numpy(float), theta_con, np.nan_to_num(wetted), bump, order)


# --------------------------------------------------------------------------- terms


def first_order_lag(signal: np.ndarray, time_s: np.ndarray, trial: np.ndarray, order: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order low-pass ``tau dy/dt = x - y`` of ``signal``, restarted at each trial.

    Each trial is filtered with its median sample period (force logs are evenly sampled), the
    filter starting at rest on the trial's first sample. ``tau_s <= 0`` returns the signal.

    Parameters
    ----------
    signal : ndarray
        Values per row.
    time_s : ndarray
        Times (s) per row.
    trial : ndarray of int
        Trial index per row.
    order : ndarray of int
        Row order sorting by (trial, time).
    tau_s : float
        Time constant (s).
    """
    if tau_s <= 0:
        return signal
    x, t, k = signal[order], time_s[order], trial[order]
    y = np.empty_like(x)
    bounds = np.flatnonzero(np.diff(k)) + 1
    for lo, hi in zip(np.r_[0, bounds], np.r_[bounds, len(x)]):
        seg = x[lo:hi]
        dt = float(np.median(np.diff(t[lo:hi]))) if hi - lo > 1 else 1.0
        a = 1.0 - np.exp(-dt / tau_s)
        y[lo:hi] = lfilter([a], [1.0, a - 1.0], seg, zi=[(1.0 - a) * seg[0]])[0]
    out = np.empty_like(y)
    out[order] = y
    return out


def _lift(force, ctx, p, mu):
    share = np.clip(p[0] * np.power(np.abs(ctx.speed_mm_s), p[1]), 0.0, 0.95)
    return force * (1.0 - share)


def _drag(force, ctx, p, mu):
    return force + p[0] * np.abs(ctx.speed_mm_s) * ctx.wetted_mm


def _capstan(force, ctx, p, mu):
    return force * np.exp(p[0] * mu * ctx.theta_con)


def _lag(force, ctx, p, mu):
    return first_order_lag(force, ctx.time_s, ctx.trial, ctx.order, float(p[0]))


def _drift(force, ctx, p, mu):
    start = pd.Series(ctx.time_s).groupby(ctx.trial).transform("min").to_numpy()
    return force + p[0] * (ctx.time_s - start)


def _profile(force, ctx, p, mu):
    return force + p[0] * (ctx.bump[:, 0] + mu * ctx.bump[:, 1])


@dataclass(frozen=True)
class Effect:
    """One unmodelled effect: a named, bounded term on the base force.

    Parameters
    ----------
    name : str
        Effect name, as the diagnosis and ``--effect`` name it.
    params : tuple of str
        Parameter names (with units).
    lower, upper : tuple of float
        Bounds of the parameters.
    null : tuple of float
        Values at which the effect vanishes.
    start : tuple of float
        A starting point for fits.
    term : callable
        ``term(force_g, ctx, values, mu) -> force_g``.
    signature : str
        How the effect shows in data.
    """

    name: str
    params: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    null: tuple[float, ...]
    start: tuple[float, ...]
    term: Callable[..., np.ndarray]
    signature: str

    def apply(self, force_g: np.ndarray, ctx: EffectContext, values, mu: np.ndarray) -> np.ndarray:
        """The augmented force (g) for parameter ``values`` and the base model's ``mu`` per row."""
        return self.term(np.asarray(force_g, dtype=float), ctx, np.asarray(values, dtype=float), mu)


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect(
            "hydrodynamic_lift", ("lift_share", "lift_exponent"), (0.0, 0.2), (0.9, 1.5), (0.0, 0.65),
            (0.1, 0.65), _lift,
            "A lubricant film carries the share a·(v / 1 mm/s)^n of the load (soft-EHL film thickness "
            "grows like (eta v)^0.6-0.67), so the whole contact force falls by that share: relative "
            "drop grows with v, the same at every theta_con.",
        ),
        Effect(
            "viscous_drag", ("drag_g_s_per_mm2",), (0.0,), (2.0,), (0.0,), (0.01,), _drag,
            "Shear of the lubricant along the wetted array adds c·v·L_wet (L_wet = insertion depth): "
            "grows with v and with depth, positive (opposite in sign to lift).",
        ),
        Effect(
            "capstan", ("capstan_gain",), (0.0,), (20.0,), (0.0,), (1.0,), _capstan,
            "Belt friction multiplies the force by exp(k·mu(v)·theta_con): grows exponentially with "
            "theta_con, its log-slope follows mu(v) (nearly independent of v).",
        ),
        Effect(
            "sensor_lag", ("tau_s",), (0.0,), (3.0,), (0.0,), (0.2,), _lag,
            "The sensed force is the true force through a first-order low-pass of time constant tau: "
            "it lags in time, most where dF/dt is largest; the shortfall grows with v.",
        ),
        Effect(
            "sensor_drift", ("drift_g_per_s",), (-1.0,), (1.0,), (0.0,), (0.0,), _drift,
            "The force signal drifts linearly in time from the start of each log: largest in slow, "
            "long trials, visible before contact.",
        ),
        Effect(
            "pressure_profile", ("bump_g_per_mm",), (-50.0,), (50.0,), (0.0,), (0.0,), _profile,
            "Contact pressure has a mid-arc bump 4u(1-u) on top of the linear Eq. (6) profile: a shape "
            "error over theta_con, independent of v.",
        ),
    ]
}


def effect_names() -> list[str]:
    """The effect names, in the library's order."""
    return list(EFFECTS)

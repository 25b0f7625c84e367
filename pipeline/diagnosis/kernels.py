"""How each unmodelled effect enters the diagnosis' design matrix (its :class:`Kernel`).

The effects' functional forms are the library's (:mod:`tympani.pipeline.model.effects`), re-implemented on
the design matrix (equality with ``Effect.apply`` is tested), with two deliberate differences: the
sensor lag is the exact first-order response to a piecewise-linear input (first-order hold; the
library's zero-order hold adds half a sample of delay on subsampled rows), and drag uses the
instantaneous speed (zero while the robot stands). An effect without a kernel here falls back to
``Effect.apply`` on each column (valid for effects affine in the force, as all six are).
Additive effects (drag, drift, profile) are further linear columns of the design.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
from scipy.signal import lfilter

from tympani.pipeline.diagnosis.config import CONTACT_WIDTH_MM
from tympani.pipeline.diagnosis.prepare import Prepared
from tympani.pipeline.model.effects import EFFECTS
from tympani.pipeline.model.friction import G_N

__all__ = ["Kernel", "KERNEL_FORMS", "VARIANTS", "kernel", "lag_foh", "dead_time", "film_factor"]


def lag_foh(x: np.ndarray, ds: Prepared, tau_s: float) -> np.ndarray:
    """First-order sensor lag ``tau dy/dt = x - y`` of ``x``, exact for a piecewise-linear input.

    Restarted at rest (``y = x``) on each trial's first row, with the trial's median sample period.
    For a linear input between samples ``k`` and ``k + 1`` (period ``dt``, ``a = exp(-dt/tau)``,
    ``beta = tau (1 - a) / dt``): ``y[k+1] = a y[k] + (1 - beta) x[k+1] + (beta - a) x[k]``.

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, k)
        Signal per row (any unit), rows as in ``ds``.
    ds : Prepared
        Rows and their trial groups.
    tau_s : float
        Time constant (s); ``<= 0`` returns ``x``.

    Returns
    -------
    ndarray
        Same shape and unit as ``x``.
    """
    if tau_s <= 1e-9:
        return x
    out = np.empty_like(x)
    for index, valid, dt in ds.lag_groups:
        a = math.exp(-dt / tau_s)
        beta = tau_s * (1.0 - a) / dt
        seg = x[index]
        y, _ = lfilter([1.0 - beta, beta - a], [1.0, -a], seg, axis=1, zi=beta * seg[:, :1])
        out[index[valid]] = y[valid]
    return out


def dead_time(x: np.ndarray, ds: Prepared, delay_s: float) -> np.ndarray:
    """``x`` delayed by ``delay_s`` (s) within each trial (linear interpolation; the first sample
    is held before the trial's start).

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, k)
        Signal per row.
    ds : Prepared
    delay_s : float
        Delay (s); ``<= 0`` returns ``x``.
    """
    if delay_s <= 1e-9:
        return x
    out = np.empty_like(x)
    for index, valid, dt in ds.lag_groups:
        seg = x[index]
        m = seg.shape[1]
        pos = np.arange(m) - delay_s / dt
        i0 = np.clip(np.floor(pos).astype(int), 0, m - 1)
        i1 = np.clip(i0 + 1, 0, m - 1)
        f = np.clip(pos - np.floor(pos), 0.0, 1.0)
        f = np.where(pos < 0, 0.0, f)
        shape = (1, m) + (1,) * (seg.ndim - 2)
        y = seg[:, i0] * (1 - f).reshape(shape) + seg[:, i1] * f.reshape(shape)
        out[index[valid]] = y[valid]
    return out


@dataclass(frozen=True)
class Kernel:
    """How an effect enters the design.

    Attributes
    ----------
    params : tuple of str
        All the kernel's parameters (the library's first).
    nonlinear : tuple of str
        The parameters fitted by the outer search, within ``bounds``.
    bounds : mapping
        Parameter name -> (lower, upper), in the parameter's unit (in its name).
    linear : tuple of str
        The coefficients of the added ``columns(ds, mu, nl) -> (n, len(linear))`` (g per unit).
    signed : tuple of bool
        Per linear parameter: whether it may be negative.
    gained : bool
        Whether the added columns are scaled by the trial gain, as contact forces are.
    transform : callable or None
        ``transform(A, ds, mu, nl)`` maps the pressure columns (g/MPa).
    columns : callable or None
        The added columns (see ``linear``).
    offset : callable or None
        ``offset(ds, mu, nl)``: a fixed term (g) added to the model.
    null : mapping
        Every parameter's no-effect value.
    grid : tuple of tuple of float
        Starting points of the non-linear search.
    form : str
        The functional form, in words (for the report).
    """

    params: tuple[str, ...]
    nonlinear: tuple[str, ...] = ()
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    linear: tuple[str, ...] = ()
    signed: tuple[bool, ...] = ()
    gained: bool = False
    transform: Callable | None = None
    columns: Callable | None = None
    offset: Callable | None = None
    null: Mapping[str, float] = field(default_factory=dict)
    grid: tuple[tuple[float, ...], ...] = ()
    form: str = ""


def _lift_transform(a, ds, mu, nl):
    share = np.clip(nl[0] * np.power(np.abs(ds.speed), nl[1]), 0.0, 0.95)
    return a * (1.0 - share)[:, None]


def film_factor(ds: Prepared, build_mm: float, squeeze_s: float) -> np.ndarray:
    """Share (0–1) of its steady state a lubricant film has reached, per row.

    The film is dragged in by the sliding: it builds up over a sliding distance ``build_mm`` (mm)
    once the robot moves, ``1 - exp(-v t / build_mm)`` at the run speed ``v``, and squeezes out with
    a time constant ``squeeze_s`` (s) once it stops (no sliding then): that value times
    ``exp(-t' / squeeze_s)`` a time ``t'`` after the stop; 0 before the start. Building up over a
    distance rather than a time is what tells a film from a sensor's lag, whose time constant is
    the same at every speed.
    """
    t0, t1 = ds.since_start_s, ds.since_stop_s
    v = np.abs(ds.speed)

    def built(t: np.ndarray) -> np.ndarray:
        if build_mm <= 1e-9:
            return np.ones_like(t)
        return -np.expm1(-v * np.maximum(t, 0.0) / build_mm)

    moving = np.where(t0 >= 0, built(t0), 0.0)
    at_stop = built(t0 - np.where(np.isfinite(t1), t1, 0.0))
    after = at_stop * np.exp(-np.maximum(t1, 0.0) / max(squeeze_s, 1e-9))
    return np.where(np.isfinite(t1) & (t1 >= 0), after, moving)


def _lift_film_transform(a, ds, mu, nl):
    share = np.clip(nl[0] * np.power(np.abs(ds.speed), nl[1]) * film_factor(ds, float(nl[2]), float(nl[3])), 0.0, 0.95)
    return a * (1.0 - share)[:, None]


def _drag_columns(ds, mu, nl):
    """Shear on the wetted array: the speed times the wetted lengths in the spiral, the entry and the
    contact (g per g s/mm^2)."""
    return ds.v_inst[:, None] * np.stack([ds.ctx.wetted_mm, ds.entry_wetted_mm, ds.l_con_mm], axis=1)


def _contact_shear_transform(a, ds, mu, nl):
    """Lubricant shear in the contact film: the friction coefficient grows by ``m v^q`` (``v`` the
    instantaneous speed in mm/s; nothing while standing)."""
    m, q = float(nl[0]), float(nl[1])
    return a if m == 0.0 else a + (m * np.power(ds.v_inst, q))[:, None] * ds.a_t


def _capstan_transform(a, ds, mu, nl):
    """Capstan equation along the arc: each element's load (normal + friction) times
    ``exp(k mu dtheta)``, ``dtheta`` its wrap angle from the contact start (rad); the exact base
    columns plus the quadrature of ``weight - 1`` (so k = 0 is exactly the base)."""
    k = float(nl[0])
    if k == 0.0:
        return a
    q = ds.quad
    weight = np.expm1(k * mu[:, None] * q.dtheta)          # (n, m)
    load = (q.gn + mu[:, None] * q.gt) * weight * q.ds[:, None]  # (n, m)
    tip = np.sum(load * (1.0 - q.u), axis=1)
    bot = np.sum(load * q.u, axis=1)
    w1 = q.w1
    extra = (CONTACT_WIDTH_MM / G_N) * np.stack([tip * (1 - w1), tip * w1, bot * (1 - w1), bot * w1], axis=1)
    return a + extra


def _lag_transform(a, ds, mu, nl):
    return dead_time(lag_foh(a, ds, float(nl[0])), ds, float(nl[1]))


def _profile_columns(ds, mu, nl):
    """Pressure modes along the arc (MPa coefficients -> g): the library's symmetric bump
    ``4u(1-u)`` and a skew mode ``4u(1-u)(1-2u)``, each with a constant amplitude and one growing
    linearly with theta_con (as Eq. 6's pressures do)."""
    q = ds.quad
    load = (q.gn + mu[:, None] * q.gt) * q.ds[:, None]
    sym = 4.0 * q.u * (1.0 - q.u)
    skew = sym * (1.0 - 2.0 * q.u)
    k = CONTACT_WIDTH_MM / G_N
    c_sym = k * np.sum(load * sym, axis=1)
    c_skew = k * np.sum(load * skew, axis=1)
    return np.stack([c_sym, c_sym * q.w1, c_skew, c_skew * q.w1], axis=1)


_PROFILE_PARAMS = ("bump_g_per_mm", "bump_slope_g_per_mm", "skew_g_per_mm", "skew_slope_g_per_mm")

_KERNELS: dict[str, Kernel] = {
    "hydrodynamic_lift": Kernel(
        params=("lift_share", "lift_exponent"), nonlinear=("lift_share", "lift_exponent"),
        bounds={"lift_share": (0.0, 0.9), "lift_exponent": (0.2, 1.5)}, transform=_lift_transform,
        null={"lift_share": 0.0, "lift_exponent": 0.65},
        grid=tuple((a, n) for a in (0.03, 0.1, 0.3) for n in (0.3, 0.65, 1.1)),
        form="F (1 - a v^n) on the contact force (library form; the run speed is kept in a dwell)"),
    "viscous_drag": Kernel(
        params=("drag_g_s_per_mm2", "drag_entry_g_s_per_mm2", "drag_contact_g_s_per_mm2"),
        linear=("drag_g_s_per_mm2", "drag_entry_g_s_per_mm2", "drag_contact_g_s_per_mm2"), signed=(False, False, False),
        columns=_drag_columns,
        null={"drag_g_s_per_mm2": 0.0, "drag_entry_g_s_per_mm2": 0.0, "drag_contact_g_s_per_mm2": 0.0},
        form="v (c L_spiral + c_entry L_entry + c_contact l_con), zero while standing (library: c v L_wet)"),
    "capstan": Kernel(
        params=("capstan_gain",), nonlinear=("capstan_gain",), bounds={"capstan_gain": (0.0, 20.0)},
        transform=_capstan_transform, null={"capstan_gain": 0.0}, grid=((0.3,), (1.0,), (3.0,), (8.0,)),
        form="each arc element's load times exp(k mu(v) dtheta), dtheta its wrap from the contact start "
             "(library: one factor exp(k mu theta_con))"),
    "sensor_lag": Kernel(
        params=("tau_s", "dead_time_s"), nonlinear=("tau_s", "dead_time_s"),
        bounds={"tau_s": (0.0, 3.0), "dead_time_s": (0.0, 0.5)}, transform=_lag_transform,
        null={"tau_s": 0.0, "dead_time_s": 0.0},
        grid=tuple((t, d) for t in (0.03, 0.1, 0.3, 0.8, 2.0) for d in (0.0, 0.05)),
        form="first-order lag tau plus a dead time (library: first-order lag)"),
    "sensor_drift": Kernel(
        params=("drift_g_per_s",), linear=("drift_g_per_s",), signed=(True,),
        columns=lambda ds, mu, nl: ds.elapsed_s[:, None],
        null={"drift_g_per_s": 0.0},
        form="r t from the start of each log (library form; a quadratic term was tried and extrapolates badly to "
             "the long slow trials)"),
    "pressure_profile": Kernel(
        params=_PROFILE_PARAMS, linear=_PROFILE_PARAMS, signed=(True,) * len(_PROFILE_PARAMS), gained=True,
        columns=_profile_columns, null={p: 0.0 for p in _PROFILE_PARAMS},
        form="pressure modes 4u(1-u) and 4u(1-u)(1-2u) along the arc, amplitudes linear in theta_con "
             "(library: one symmetric bump of fixed amplitude)"),
}


def _drift_thermal_columns(ds, mu, nl):
    """A thermal drift that settles, ``r tau (1 - exp(-t / tau))`` (slope ``r`` g/s at the log's
    start; a straight line as tau grows), and a creep under load, ``c integral F dt`` (g per g s)."""
    tau = float(nl[0])
    t = ds.elapsed_s
    return np.stack([-tau * np.expm1(-t / tau), ds.load_time_g_s], axis=1)


#: Richer variants of effects: (effect, variant) -> kernel. A variant is used only when it predicts
#: held-out speeds significantly better than the effect's plain kernel
#: (:func:`tympani.pipeline.diagnosis.analysis.diagnose`): its extra parameters must be ones the data can separate.
VARIANTS: dict[tuple[str, str], Kernel] = {
    ("hydrodynamic_lift", "film"): Kernel(
        params=("lift_share", "lift_exponent", "film_build_mm", "film_squeeze_s"),
        nonlinear=("lift_share", "lift_exponent", "film_build_mm", "film_squeeze_s"),
        bounds={"lift_share": (0.0, 0.9), "lift_exponent": (0.2, 1.5), "film_build_mm": (0.0, 10.0),
                "film_squeeze_s": (0.1, 100.0)},
        transform=_lift_film_transform,
        null={"lift_share": 0.0, "lift_exponent": 0.65, "film_build_mm": 0.0, "film_squeeze_s": 100.0},
        grid=tuple((a, n, b, q) for a in (0.03, 0.1, 0.3) for n in (0.3, 0.65, 1.1) for b in (0.0, 2.0)
                   for q in (2.0, 30.0)),
        form="F (1 - a v^n f), the film f built up over a sliding distance once the robot moves and squeezed "
             "out with a time constant after it stops"),
    ("viscous_drag", "contact"): Kernel(
        params=("drag_g_s_per_mm2", "drag_entry_g_s_per_mm2", "drag_contact_g_s_per_mm2", "shear_coefficient",
                "shear_exponent"),
        nonlinear=("shear_coefficient", "shear_exponent"),
        bounds={"shear_coefficient": (0.0, 0.5), "shear_exponent": (0.2, 1.5)},
        transform=_contact_shear_transform,
        linear=("drag_g_s_per_mm2", "drag_entry_g_s_per_mm2", "drag_contact_g_s_per_mm2"), signed=(False, False, False),
        columns=_drag_columns,
        null={"drag_g_s_per_mm2": 0.0, "drag_entry_g_s_per_mm2": 0.0, "drag_contact_g_s_per_mm2": 0.0,
              "shear_coefficient": 0.0, "shear_exponent": 1.0},
        grid=((0.01, 0.5), (0.01, 1.0), (0.05, 0.5), (0.05, 1.0)),
        form="shear on the wetted array, v (c L_spiral + c_entry L_entry + c_contact l_con), plus shear in the "
             "contact film, a friction coefficient growing as m v^q with the contact load"),
    ("sensor_drift", "thermal"): Kernel(
        params=("drift_g_per_s", "drift_settle_s", "creep_per_s"), nonlinear=("drift_settle_s",),
        bounds={"drift_settle_s": (2.0, 500.0)}, linear=("drift_g_per_s", "creep_per_s"), signed=(True, True),
        columns=_drift_thermal_columns, null={"drift_g_per_s": 0.0, "drift_settle_s": 500.0, "creep_per_s": 0.0},
        grid=((5.0,), (20.0,), (100.0,)),
        form="r tau (1 - exp(-t / tau)) + c integral F dt: a thermal drift that settles and a creep under load"),
}


def _generic_kernel(name: str) -> Kernel:
    """Any library effect, assumed affine in the force: ``apply`` on each pressure column."""
    effect = EFFECTS[name]

    def transform(a, ds, mu, nl):
        zero = effect.apply(np.zeros(ds.n), ds.ctx, nl, mu)
        return np.stack([effect.apply(a[:, j], ds.ctx, nl, mu) - zero for j in range(a.shape[1])], axis=1)

    return Kernel(params=effect.params, nonlinear=effect.params,
                   bounds={p: (lo, hi) for p, lo, hi in zip(effect.params, effect.lower, effect.upper)},
                   transform=transform, offset=lambda ds, mu, nl: effect.apply(np.zeros(ds.n), ds.ctx, nl, mu),
                   null=dict(zip(effect.params, effect.null)), grid=(tuple(effect.start),), form="library form")


def kernel(name: str, variant: str = "") -> Kernel:
    """The diagnosis' kernel of a library effect (its own, a richer variant, or the generic one)."""
    if variant:
        return VARIANTS[(name, variant)]
    return _KERNELS.get(name) or _generic_kernel(name)


#: Line-by-line forms of the candidates (for the report).
KERNEL_FORMS: dict[str, str] = {name: k.form for name, k in _KERNELS.items()}


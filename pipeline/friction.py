"""The insertion-force model of SPEC §4 (seed paper, Eqs. 2–7), vectorised.

Model
-----
The array touches the *outer wall* from ``theta_bot`` to ``theta_tip`` (the contact arc). With
``s`` the arc length measured from the tip and ``l_con`` the arc's length, the contact pressure
is linear along the arc (Eq. 6)::

    p(s) = p_tip + (s / l_con) (p_bot - p_tip)                       [MPa = N/mm^2]

Element ``i`` of the arc (length ``ds_i``) carries

    n_i = p(s_i) b_c ds_i (-n_out_i)          normal force on the array, towards the channel
    f_i = mu(v) |n_i| (-t_i) sign(v)          friction on the array, opposing the sliding

where ``n_out`` is the wall's unit normal pointing away from the spiral centre, ``t`` the wall's
unit tangent towards the apex and ``b_c`` the effective contact width (mm). The array slides
along the wall towards the apex during an insertion (``v > 0``), so friction on the array points
basally. ``mu(v)`` is the Stribeck law (Eq. 7)::

    mu(v) = mu_k + (mu_s - mu_k) exp(-|v / v_s|^delta_s) + mu_v |v|

The sensed force is the reaction the robot must supply (Eqs. 2–5)::

    f_ins = -sum_i (n_i + f_i) = b_c [ integral p n_out ds + sign(v) mu(v) integral p t ds ]
    F     = f_ins . x_w / 9.80665e-3                                  [grams-force]

with ``x_w`` the insertion axis (the backbone tangent at ``theta_start``, pointing into the
spiral).

Sign convention (checked, not flipped)
--------------------------------------
With SPEC's conventions the force is **positive** (the robot pushes the array in) for realistic
contact arcs: checked (tests/test_friction.py) for every arc with ``1.0 <= theta_bot <
theta_tip <= 4.0`` rad, non-negative pressures and ``mu <= 0.25``, and for ``theta_bot <= 2.6``
rad with ``mu <= 0.5``. Two features of SPEC's geometry give *negative* F elsewhere, and they
are reported, not flipped:

- arcs lying within ~0.8 rad of ``theta_start``: Eq. (1)'s log branch makes the outer wall
  first turn *away* from the centre (clockwise), so its outward normal points against ``x_w``
  there (``n_out . x_w < 0`` for theta in (0.18, 0.95) rad); the array does not touch the outer
  wall there in practice (first contact at 1.0–1.8 rad);
- short arcs deep in the spiral (both ends beyond ~3.9 rad, or ~4.1 rad for mu = 0.18), where
  ``n_out . x_w`` has fallen below ``mu |t . x_w|``.

The *friction* term is a vector sum projected on ``x_w``: where the wall has turned more than
90 deg away from ``x_w`` (``t . x_w < 0`` beyond theta ~ 2.7 rad on the default phantom) the
tangent points back towards the entry and that element's friction *lowers* F. For early arcs
friction adds to F; for the long arcs at the end of a 15 mm insertion (theta_bot ~ 2,
theta_tip ~ 3.9) its net effect subtracts. Consequently, in the SPEC model a Stribeck law that
lowers ``mu`` with speed *raises* the late-insertion (peak) force slightly, the opposite sign of
the paper's reported simulated −2 %. This is what Eqs. 2–5 give as written;
:func:`insertion_force` offers ``friction_mode="axial"`` (every element's friction magnitude
transmitted along ``x_w``, as for a stiff array in a straight sheath) for comparison, never as
the default.

Magnitude of the speed effect (GUIDE §5)
----------------------------------------
Friction is a small share of the normal term on these arcs, so the speed dependence is small.
With mu_s = 0.18, mu_k = 0.12 and the reconstructed S4 preset, the peak force changes between
0.5 and 7.5 mm/s by (:func:`speed_change_table`; delta_s = 1 / 2):

    v_s (mm/s)        0.1      0.3          1            3            10
    SPEC "vector"   +0.0 %   +0.2/+0.1 %  +0.7/+0.9 %  +0.9/+1.1 %  +0.5/+0.5 %
    "axial"         -0.0 %   -1.1/-0.4 %  -3.5/-4.5 %  -4.4/-5.6 %  -2.7/-2.4 %

i.e. at most ~1 % (and a *rise*) with the SPEC vector sum, a few per cent drop if friction were
transmitted axially; both an order of magnitude short of the paper's experiments (−24 % at
3 mm/s, −43 % at 7.5 mm/s). The exact figures depend on the reconstructed pressures.

Implementation
--------------
For one phantom, :class:`ContactGeometry` holds the cumulative integrals, over outer-wall arc
length ``S`` (from ``theta_start``), of ``g(S)`` and ``S g(S)`` for ``g`` in
``{n_out . x_w, t . x_w, 1}`` (exact for the polyline: the unit vectors are constant on each
segment). A linear pressure needs only the 0th and 1st moments: with ``S_t``, ``S_b`` the wall
positions of the tip and the contact start and ``l = S_t - S_b``::

    integral p g dS = p_tip G0 + (p_bot - p_tip) G1
    G0 = integral_{S_b}^{S_t} g dS,    G1 = (S_t G0 - integral_{S_b}^{S_t} S g dS) / l

so each sample costs two binary searches and a few multiplications (:func:`arc_integrals`), and
a fit that only changes pressures and friction reuses them (:func:`force_from_integrals`). An
angle is placed on the wall at the outer-wall vertex with the same backbone angle (the wall point
beside the centreline point, SPEC §3); angles outside the channel are clipped to it.

The paper's TABLE I (scenario definitions) and TABLE II (simulated forces) are not available:
:data:`SCENARIOS` is a documented *reconstruction*, every number of which is in
:data:`RECONSTRUCTION`; :func:`fit_table` is ready to fit the unstated constants once TABLE II is
supplied.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from functools import lru_cache
from typing import Any, Literal, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from vision.geometry import DEFAULT_PHANTOM, Phantom, entry_frame

__all__ = [
    "G_N",
    "PressureLaw",
    "LinearPressure",
    "PiecewisePressure",
    "FrictionParams",
    "ContactGeometry",
    "ArcIntegrals",
    "contact_geometry",
    "stribeck",
    "arc_integrals",
    "force_from_integrals",
    "insertion_force",
    "Scenario",
    "RECONSTRUCTION",
    "reconstructed_friction",
    "SCENARIOS",
    "SIM_COLUMNS",
    "simulate",
    "peak_force_change",
    "speed_change_table",
    "TableFit",
    "fit_table",
    "flat_params",
    "params_from_flat",
    "FLAT_NAMES",
    "FrictionMode",
]

#: Newtons per gram-force (SPEC §1).
G_N = 9.80665e-3

#: Columns of the simulation table (SPEC §6), in order; ``step`` is appended.
SIM_COLUMNS = ("scenario", "speed_mm_s", "theta_bot", "theta_tip", "theta_con", "force_g")

FrictionMode = Literal["vector", "axial"]


# --------------------------------------------------------------------------- pressure laws


@runtime_checkable
class PressureLaw(Protocol):
    """A contact pressure (MPa) as a function of the contact angle ``theta_con`` (rad)."""

    def __call__(self, theta_con: np.ndarray) -> np.ndarray:  # pragma: no cover - protocol
        ...


@dataclass(frozen=True)
class LinearPressure:
    """``p = p0 + p1 * theta_con`` (the default law, SPEC §4).

    Parameters
    ----------
    p0_MPa : float
        Pressure (MPa) at ``theta_con = 0``.
    p1_MPa_per_rad : float
        Change of pressure (MPa/rad) per radian of contact angle.
    """

    p0_MPa: float
    p1_MPa_per_rad: float = 0.0

    def __call__(self, theta_con: np.ndarray) -> np.ndarray:
        """Pressure (MPa) at contact angles ``theta_con`` (rad)."""
        return self.p0_MPa + self.p1_MPa_per_rad * np.asarray(theta_con, dtype=float)


@dataclass(frozen=True)
class PiecewisePressure:
    """Pressure (MPa) interpolated linearly between knots in ``theta_con`` (rad).

    Meant for tabulated laws such as a TABLE I that lists pressures per insertion phase.
    Constant beyond the first and last knot.

    Parameters
    ----------
    theta_con : tuple of float
        Knots (rad), increasing.
    p_MPa : tuple of float
        Pressure (MPa) at each knot.
    """

    theta_con: tuple[float, ...]
    p_MPa: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.theta_con) != len(self.p_MPa) or len(self.theta_con) < 1:
            raise ValueError("theta_con and p_MPa must be non-empty and of equal length")
        if np.any(np.diff(self.theta_con) <= 0):
            raise ValueError("theta_con knots must increase")

    def __call__(self, theta_con: np.ndarray) -> np.ndarray:
        """Pressure (MPa) at contact angles ``theta_con`` (rad)."""
        return np.interp(np.asarray(theta_con, dtype=float), self.theta_con, self.p_MPa)


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class FrictionParams:
    """Parameters of the SPEC §4 force model.

    The defaults are the reconstruction of :data:`RECONSTRUCTION` (S4-like), not values from
    the paper's tables.

    Parameters
    ----------
    mu_s : float
        Static friction coefficient (dimensionless): ``mu`` at ``v = 0``.
    mu_k : float
        Kinetic friction coefficient (dimensionless): ``mu`` for ``v >> v_s``.
    v_s_mm_s : float
        Stribeck velocity (mm/s).
    delta_s : float
        Stribeck exponent (dimensionless).
    mu_v_s_per_mm : float
        Viscous term (s/mm): ``mu`` grows by ``mu_v |v|``.
    contact_width_mm : float
        Effective contact width ``b_c`` (mm). Exactly degenerate with the pressure scale:
        only ``b_c * p`` enters the force.
    p_tip_MPa : PressureLaw
        Pressure (MPa) at the tip as a function of ``theta_con`` (rad).
    p_bot_MPa : PressureLaw
        Pressure (MPa) at the contact start as a function of ``theta_con`` (rad).
    """

    mu_s: float = 0.18
    mu_k: float = 0.12
    v_s_mm_s: float = 1.0
    delta_s: float = 2.0
    mu_v_s_per_mm: float = 0.0
    contact_width_mm: float = 0.3
    p_tip_MPa: PressureLaw = field(default_factory=lambda: LinearPressure(0.01, 0.01))
    p_bot_MPa: PressureLaw = field(default_factory=lambda: LinearPressure(0.02, 0.02))


#: Flat names of the scalar parameters (for fits and JSON), with linear pressure laws.
FLAT_NAMES = (
    "mu_s", "mu_k", "v_s_mm_s", "delta_s", "mu_v_s_per_mm", "contact_width_mm",
    "p_tip0_MPa", "p_tip1_MPa_per_rad", "p_bot0_MPa", "p_bot1_MPa_per_rad",
)


def flat_params(params: FrictionParams) -> dict[str, float]:
    """The parameters as ``{name: value}`` with the names of :data:`FLAT_NAMES`.

    Parameters
    ----------
    params : FrictionParams
        Must use :class:`LinearPressure` laws.

    Returns
    -------
    dict
        Friction constants (dimensionless, mm/s, s/mm), ``contact_width_mm`` (mm) and the
        pressure laws' ``p*0_MPa`` (MPa) and ``p*1_MPa_per_rad`` (MPa/rad).
    """
    if not (isinstance(params.p_tip_MPa, LinearPressure) and isinstance(params.p_bot_MPa, LinearPressure)):
        raise TypeError("flat_params needs LinearPressure laws")
    out = {f.name: float(getattr(params, f.name)) for f in fields(params) if f.name in FLAT_NAMES}
    out.update(
        p_tip0_MPa=params.p_tip_MPa.p0_MPa, p_tip1_MPa_per_rad=params.p_tip_MPa.p1_MPa_per_rad,
        p_bot0_MPa=params.p_bot_MPa.p0_MPa, p_bot1_MPa_per_rad=params.p_bot_MPa.p1_MPa_per_rad,
    )
    return {name: float(out[name]) for name in FLAT_NAMES}


def params_from_flat(values: Mapping[str, float], base: FrictionParams | None = None) -> FrictionParams:
    """Build :class:`FrictionParams` from flat names (see :func:`flat_params`).

    Parameters
    ----------
    values : mapping
        Any subset of :data:`FLAT_NAMES`; the rest comes from ``base``.
    base : FrictionParams, optional
        Defaults (``FrictionParams()``); its pressure laws must be linear if a pressure name
        is missing from ``values``.
    """
    unknown = set(values) - set(FLAT_NAMES)
    if unknown:
        raise KeyError(f"unknown parameter(s): {', '.join(sorted(unknown))}")
    merged = {**flat_params(base or FrictionParams()), **{k: float(v) for k, v in values.items()}}
    scalars = {k: merged[k] for k in FLAT_NAMES[:6]}
    return FrictionParams(
        **scalars,
        p_tip_MPa=LinearPressure(merged["p_tip0_MPa"], merged["p_tip1_MPa_per_rad"]),
        p_bot_MPa=LinearPressure(merged["p_bot0_MPa"], merged["p_bot1_MPa_per_rad"]),
    )


# --------------------------------------------------------------------------- friction law


def stribeck(v_mm_s: np.ndarray | float, params: FrictionParams) -> np.ndarray:
    """Friction coefficient of Eq. (7) at sliding speed ``v_mm_s``.

    ``mu(v) = mu_k + (mu_s - mu_k) exp(-|v / v_s|^delta_s) + mu_v |v|``. SPEC writes the viscous
    term ``mu_v v``; for the insertion speeds it is about (``v > 0``) the two agree. A negative
    speed (retraction) gives the same ``mu`` as its magnitude; the direction is handled in
    :func:`force_from_integrals`.

    Parameters
    ----------
    v_mm_s : array_like
        Sliding speed (mm/s).
    params : FrictionParams
        Uses ``mu_s``, ``mu_k`` (dimensionless), ``v_s_mm_s`` (mm/s), ``delta_s``
        (dimensionless), ``mu_v_s_per_mm`` (s/mm).

    Returns
    -------
    ndarray
        Friction coefficient (dimensionless).
    """
    v = np.abs(np.asarray(v_mm_s, dtype=float))
    decay = np.exp(-np.power(v / params.v_s_mm_s, params.delta_s))
    return params.mu_k + (params.mu_s - params.mu_k) * decay + params.mu_v_s_per_mm * v


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True, eq=False)
class ContactGeometry:
    """Cumulative wall integrals along the outer wall, for one phantom.

    Build with :meth:`from_wall` or :func:`contact_geometry`. Arrays are per wall vertex
    ``j`` (``*_cum``: integral from the first vertex to vertex ``j``) or per segment ``k``
    (``seg_*``: the constant integrand on segment ``k``).

    Attributes
    ----------
    theta : ndarray, shape (m,)
        Channel angle (rad) of each vertex, strictly increasing.
    s : ndarray, shape (m,)
        Wall arc length (mm) from the first vertex.
    seg_g : ndarray, shape (m - 1, 3)
        Per segment ``(n_out . x_w, t . x_w, 1)`` (dimensionless).
    cum0 : ndarray, shape (m, 3)
        ``integral g dS`` from the first vertex (mm).
    cum1 : ndarray, shape (m, 3)
        ``integral S g dS`` from the first vertex (mm^2).
    x_w : ndarray, shape (2,)
        Insertion axis (unit vector, phantom frame).
    """

    theta: np.ndarray
    s: np.ndarray
    seg_g: np.ndarray
    cum0: np.ndarray
    cum1: np.ndarray
    x_w: np.ndarray

    @classmethod
    def from_wall(
        cls,
        points: np.ndarray,
        theta: np.ndarray,
        x_w: np.ndarray,
        centre: Sequence[float] = (0.0, 0.0),
    ) -> "ContactGeometry":
        """Integrals of a wall polyline.

        Parameters
        ----------
        points : ndarray, shape (m, 2)
            Wall vertices (mm), from base to apex.
        theta : ndarray, shape (m,)
            Channel angle (rad) of each vertex, non-decreasing (repeated angles are merged).
        x_w : ndarray, shape (2,)
            Insertion axis (any length; normalised here).
        centre : sequence of 2 float
            Spiral centre (mm). The outward normal is the segment normal on the side away
            from it, so a mirrored (clockwise) spiral gets the same physical normal.
        """
        points = np.asarray(points, dtype=float)
        theta = np.asarray(theta, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) != len(theta) or len(points) < 2:
            raise ValueError("points must be (m, 2) with m >= 2 and match theta")
        if np.any(np.diff(theta) < 0):
            raise ValueError("theta must be non-decreasing along the wall")
        keep = np.concatenate([[True], np.diff(theta) > 0])
        points, theta = points[keep], theta[keep]
        x_w = np.asarray(x_w, dtype=float)
        x_w = x_w / np.linalg.norm(x_w)
        step = np.diff(points, axis=0)
        length = np.hypot(step[:, 0], step[:, 1])
        tangent = step / np.maximum(length, 1e-300)[:, None]
        normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)  # tangent turned clockwise
        mid = 0.5 * (points[1:] + points[:-1]) - np.asarray(centre, dtype=float)
        # orientation of the spiral about its centre: +1 counter-clockwise, -1 clockwise
        orientation = np.sign(np.sum(mid[:, 0] * tangent[:, 1] - mid[:, 1] * tangent[:, 0]))
        normal *= orientation if orientation != 0 else 1.0
        s = np.concatenate([[0.0], np.cumsum(length)])
        seg_g = np.stack([normal @ x_w, tangent @ x_w, np.ones(len(length))], axis=1)
        cum0 = np.vstack([np.zeros(3), np.cumsum(seg_g * length[:, None], axis=0)])
        dsq = 0.5 * (s[1:] ** 2 - s[:-1] ** 2)
        cum1 = np.vstack([np.zeros(3), np.cumsum(seg_g * dsq[:, None], axis=0)])
        return cls(theta=theta, s=s, seg_g=seg_g, cum0=cum0, cum1=cum1, x_w=x_w)

    def wall_s(self, theta: np.ndarray) -> np.ndarray:
        """Wall arc length (mm) at channel angles ``theta`` (rad), clipped to the wall."""
        return np.interp(np.asarray(theta, dtype=float), self.theta, self.s)

    def locate(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment index and wall arc length (mm) of channel angles ``theta`` (rad).

        Angles outside the wall are clipped to its ends; NaN gives NaN arc length.
        """
        theta = np.asarray(theta, dtype=float)
        k = np.clip(np.searchsorted(self.theta, theta, side="right") - 1, 0, len(self.theta) - 2)
        t0, t1 = self.theta[k], self.theta[k + 1]
        frac = np.clip((theta - t0) / (t1 - t0), 0.0, 1.0)
        return k, self.s[k] + frac * (self.s[k + 1] - self.s[k])

    def cumulative(self, s_mm: np.ndarray, k: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(integral g dS, integral S g dS)`` from the wall's start to ``s_mm`` (mm).

        ``k`` (the segment holding each ``s_mm``, from :meth:`locate`) saves a search. Returns
        arrays of shape ``s_mm.shape + (3,)`` (mm and mm^2), exact for the polyline.
        """
        s = np.asarray(s_mm, dtype=float)
        if k is None:
            k = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2)
        g = self.seg_g[k]
        s0 = self.s[k]
        c0 = self.cum0[k] + g * (s - s0)[..., None]
        c1 = self.cum1[k] + g * (0.5 * (s * s - s0 * s0))[..., None]
        return c0, c1


@lru_cache(maxsize=8)
def contact_geometry(phantom: Phantom = DEFAULT_PHANTOM) -> ContactGeometry:
    """The :class:`ContactGeometry` of ``phantom``'s outer wall and insertion axis (memoised).

    Parameters
    ----------
    phantom : Phantom
        Phantom configuration (mm, rad).
    """
    wall = phantom.outer_wall
    _, x_w, _ = entry_frame(phantom)
    return ContactGeometry.from_wall(wall.points, wall.theta, x_w)


def _geometry(phantom: Phantom | ContactGeometry) -> ContactGeometry:
    return phantom if isinstance(phantom, ContactGeometry) else contact_geometry(phantom)


# --------------------------------------------------------------------------- the force


@dataclass(frozen=True)
class ArcIntegrals:
    """Pressure-independent integrals of contact arcs (see the module docstring).

    Attributes
    ----------
    theta_con : ndarray
        Contact angle (rad), ``theta_tip - theta_bot`` (zero where not positive).
    g0 : ndarray, shape (..., 3)
        ``integral g dS`` over the arc (mm) for ``g = (n_out . x_w, t . x_w, 1)``.
    g1 : ndarray, shape (..., 3)
        ``integral (S_t - S) / l g dS`` (mm): the weight of ``p_bot - p_tip``.
    length_mm : ndarray
        Arc length ``l_con`` (mm) on the wall.
    """

    theta_con: np.ndarray
    g0: np.ndarray
    g1: np.ndarray
    length_mm: np.ndarray


def arc_integrals(
    theta_bot: np.ndarray | float,
    theta_tip: np.ndarray | float,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
) -> ArcIntegrals:
    """Geometry integrals of the contact arcs ``[theta_bot, theta_tip]`` on the outer wall.

    Parameters
    ----------
    theta_bot, theta_tip : array_like
        Contact start and tip angles (rad), broadcast together.
    phantom : Phantom or ContactGeometry
        Phantom (its geometry is memoised) or a prepared geometry.

    Returns
    -------
    ArcIntegrals
        Zero integrals where ``theta_tip <= theta_bot``; NaN where an angle is NaN.
    """
    geom = _geometry(phantom)
    bot, tip = np.broadcast_arrays(np.asarray(theta_bot, dtype=float), np.asarray(theta_tip, dtype=float))
    theta_con = tip - bot
    k_b, s_b = geom.locate(bot)
    k_t, s_t = geom.locate(tip)
    length = s_t - s_b
    c0b, c1b = geom.cumulative(s_b, k_b)
    c0t, c1t = geom.cumulative(s_t, k_t)
    g0 = c0t - c0b
    m1 = c1t - c1b
    contact = length > 0
    safe = np.where(contact, length, 1.0)
    g1 = (s_t[..., None] * g0 - m1) / safe[..., None]
    g0 = np.where(contact[..., None], g0, 0.0)
    g1 = np.where(contact[..., None], g1, 0.0)
    nan = np.isnan(theta_con)
    if nan.any():
        g0 = np.where(nan[..., None], np.nan, g0)
        g1 = np.where(nan[..., None], np.nan, g1)
    return ArcIntegrals(
        theta_con=np.where(theta_con > 0, theta_con, np.where(nan, np.nan, 0.0)),
        g0=g0, g1=g1, length_mm=np.where(contact, length, np.where(nan, np.nan, 0.0)),
    )


def force_from_integrals(
    arcs: ArcIntegrals,
    speed_mm_s: np.ndarray | float,
    params: FrictionParams,
    *,
    friction_mode: FrictionMode = "vector",
) -> np.ndarray:
    """Sensed insertion force (g) from precomputed arc integrals.

    Parameters
    ----------
    arcs : ArcIntegrals
        From :func:`arc_integrals`.
    speed_mm_s : array_like
        Insertion speed (mm/s), broadcast with the arcs; negative means retraction (friction
        reverses), zero means impending insertion (``mu = mu_s``, friction basal).
    params : FrictionParams
        Model parameters (pressures in MPa, ``b_c`` in mm). Pressures are clipped at 0: a
        wall cannot pull the array.
    friction_mode : {"vector", "axial"}
        ``"vector"`` (default, SPEC Eqs. 2–5): friction vectors summed and projected on
        ``x_w``. ``"axial"``: each element's friction magnitude acts along ``x_w`` (for
        comparison only; not SPEC).

    Returns
    -------
    ndarray
        ``F = f_ins . x_w`` in grams-force (positive: the robot pushes the array in).
    """
    theta_con = arcs.theta_con
    p_tip = np.maximum(np.asarray(params.p_tip_MPa(theta_con), dtype=float), 0.0)
    p_bot = np.maximum(np.asarray(params.p_bot_MPa(theta_con), dtype=float), 0.0)
    dp = p_bot - p_tip
    normal = p_tip * arcs.g0[..., 0] + dp * arcs.g1[..., 0]
    if friction_mode not in ("vector", "axial"):
        raise ValueError(f"friction_mode must be 'vector' or 'axial', not {friction_mode!r}")
    col = 1 if friction_mode == "vector" else 2
    along = p_tip * arcs.g0[..., col] + dp * arcs.g1[..., col]
    v = np.asarray(speed_mm_s, dtype=float)
    direction = np.where(v < 0, -1.0, 1.0)
    force_n = params.contact_width_mm * (normal + direction * stribeck(v, params) * along)
    return force_n / G_N


def insertion_force(
    theta_bot: np.ndarray | float,
    theta_tip: np.ndarray | float,
    speed_mm_s: np.ndarray | float,
    params: FrictionParams,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
    *,
    friction_mode: FrictionMode = "vector",
) -> np.ndarray:
    """Sensed insertion force (g) of SPEC §4 for contact arcs and speeds.

    Parameters
    ----------
    theta_bot : array_like
        Contact start angle (rad, SPEC §3).
    theta_tip : array_like
        Tip angle (rad). ``theta_con = theta_tip - theta_bot <= 0`` gives 0 force.
    speed_mm_s : array_like
        Insertion speed (mm/s); all three inputs broadcast together.
    params : FrictionParams
        Friction law, contact width (mm) and pressure laws (MPa vs rad).
    phantom : Phantom or ContactGeometry
        Phantom frame geometry (default: SPEC's phantom).
    friction_mode : {"vector", "axial"}
        See :func:`force_from_integrals`.

    Returns
    -------
    ndarray
        Force along the insertion axis in grams-force (1 g = 9.80665e-3 N), positive when the
        robot pushes the array in. See the module docstring for the sign of the friction term.

    Examples
    --------
    >>> f = insertion_force([1.6, 2.0], [3.0, 3.9], 3.0, FrictionParams())
    >>> bool(np.all(f > 0))
    True
    """
    bot, tip, v = np.broadcast_arrays(
        np.asarray(theta_bot, dtype=float), np.asarray(theta_tip, dtype=float), np.asarray(speed_mm_s, dtype=float)
    )
    return force_from_integrals(arc_integrals(bot, tip, phantom), v, params, friction_mode=friction_mode)


# --------------------------------------------------------------------------- scenarios

#: Every number of the reconstructed TABLE I scenarios, in one place. None of these is from
#: the paper's TABLE I (not available to us): replace them when it is supplied. The two
#: friction coefficients 0.12 and 0.18 are the paper's, but which one is static is not stated
#: (0.18 static is assumed; :func:`fit_table` tests both assignments).
RECONSTRUCTION: dict[str, float | str] = {
    "status": "reconstruction — replace with TABLE I values when available",
    # trajectory of an insertion (rad): tip from first contact to ~15 mm depth; the contact
    # start follows a fraction `lag` of the tip's advance (as the synthetic renderer's default)
    "theta_first": 1.4,
    "theta_tip_end": 3.9,
    "theta_step": 0.1,
    "lag": 0.3,
    # friction
    "mu_static": 0.18,
    "mu_kinetic": 0.12,
    "v_s_mm_s": 1.0,
    "delta_s": 2.0,
    "mu_v_s_per_mm": 0.0,
    "contact_width_mm": 0.3,
    # pressures (MPa; MPa/rad of theta_con), chosen so the peak force is a few grams
    "S1_p_MPa": 0.02,
    "S2_p_tip_MPa": 0.01,
    "S2_p_bot0_MPa": 0.01,
    "S2_p_bot1_MPa_per_rad": 0.02,
    "S3_p_tip0_MPa": 0.01,
    "S3_p_tip1_MPa_per_rad": 0.01,
    "S3_p_bot0_MPa": 0.02,
    "S3_p_bot1_MPa_per_rad": 0.02,
}


def reconstructed_friction(stribeck_law: bool = True) -> FrictionParams:
    """Friction constants of the reconstruction (pressures are the scenario's).

    Parameters
    ----------
    stribeck_law : bool
        True: Stribeck with ``mu_s = 0.18``, ``mu_k = 0.12`` (S4). False: Coulomb friction,
        ``mu = mu_k`` at every speed (S1–S3).
    """
    r = RECONSTRUCTION
    mu_k = float(r["mu_kinetic"])
    return FrictionParams(
        mu_s=float(r["mu_static"]) if stribeck_law else mu_k,
        mu_k=mu_k,
        v_s_mm_s=float(r["v_s_mm_s"]),
        delta_s=float(r["delta_s"]),
        mu_v_s_per_mm=float(r["mu_v_s_per_mm"]) if stribeck_law else 0.0,
        contact_width_mm=float(r["contact_width_mm"]),
    )


@dataclass(frozen=True)
class Scenario:
    """A preset insertion: contact arcs step by step, a pressure law and a friction law.

    Parameters
    ----------
    name : str
        ``"S1"`` … ``"S4"``.
    description : str
        What the scenario assumes.
    theta_bot, theta_tip : tuple of float
        Contact start and tip angles (rad) at each step of the insertion.
    p_tip_MPa, p_bot_MPa : PressureLaw
        Pressure laws (MPa as a function of ``theta_con`` in rad).
    stribeck_law : bool
        Stribeck friction (True) or Coulomb friction ``mu = mu_k`` (False).
    source : str
        Where the numbers come from.
    """

    name: str
    description: str
    theta_bot: tuple[float, ...]
    theta_tip: tuple[float, ...]
    p_tip_MPa: PressureLaw
    p_bot_MPa: PressureLaw
    stribeck_law: bool
    source: str = "reconstruction — replace with TABLE I values when available"

    def params(self, friction: FrictionParams | None = None) -> FrictionParams:
        """The scenario's full parameters.

        Parameters
        ----------
        friction : FrictionParams, optional
            Friction constants and contact width to use (default: the reconstruction's).
            Without Stribeck friction, ``mu_s`` is set to ``mu_k`` and ``mu_v`` to 0.
        """
        base = friction if friction is not None else reconstructed_friction(True)
        if not self.stribeck_law:
            base = replace(base, mu_s=base.mu_k, mu_v_s_per_mm=0.0)
        return replace(base, p_tip_MPa=self.p_tip_MPa, p_bot_MPa=self.p_bot_MPa)


def _reconstructed_path() -> tuple[tuple[float, ...], tuple[float, ...]]:
    r = RECONSTRUCTION
    first, end, step, lag = (float(r[k]) for k in ("theta_first", "theta_tip_end", "theta_step", "lag"))
    tip = np.round(np.arange(first, end + 0.5 * step, step), 6)
    bot = np.round(first + lag * (tip - first), 6)
    return tuple(float(x) for x in bot), tuple(float(x) for x in tip)


def _build_scenarios() -> dict[str, Scenario]:
    r = RECONSTRUCTION
    bot, tip = _reconstructed_path()
    s3_tip = LinearPressure(float(r["S3_p_tip0_MPa"]), float(r["S3_p_tip1_MPa_per_rad"]))
    s3_bot = LinearPressure(float(r["S3_p_bot0_MPa"]), float(r["S3_p_bot1_MPa_per_rad"]))
    return {
        "S1": Scenario("S1", "constant, uniform contact pressure; Coulomb friction", bot, tip,
                       LinearPressure(float(r["S1_p_MPa"])), LinearPressure(float(r["S1_p_MPa"])), False),
        "S2": Scenario("S2", "constant pressure at the tip, pressure at the contact start growing linearly "
                             "with theta_con; Coulomb friction", bot, tip,
                       LinearPressure(float(r["S2_p_tip_MPa"])),
                       LinearPressure(float(r["S2_p_bot0_MPa"]), float(r["S2_p_bot1_MPa_per_rad"])), False),
        "S3": Scenario("S3", "tip and contact-start pressures both growing linearly with theta_con; "
                             "Coulomb friction", bot, tip, s3_tip, s3_bot, False),
        "S4": Scenario("S4", "S3's pressures with Stribeck friction (the full model)", bot, tip,
                       s3_tip, s3_bot, True),
    }


#: The scenarios S1–S4 (a reconstruction of TABLE I; see :data:`RECONSTRUCTION`).
SCENARIOS: dict[str, Scenario] = _build_scenarios()


def _scenario(name: str | Scenario) -> Scenario:
    if isinstance(name, Scenario):
        return name
    try:
        return SCENARIOS[str(name).upper()]
    except KeyError:
        raise KeyError(f"unknown scenario {name!r}; choose from {', '.join(SCENARIOS)}") from None


def simulate(
    scenario_name: str | Scenario,
    speeds_mm_s: Sequence[float],
    *,
    friction: FrictionParams | None = None,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
    friction_mode: FrictionMode = "vector",
) -> pd.DataFrame:
    """The force model along a scenario at several speeds (SPEC §6 simulation table).

    Parameters
    ----------
    scenario_name : str or Scenario
        ``"S1"`` … ``"S4"`` or a :class:`Scenario`.
    speeds_mm_s : sequence of float
        Insertion speeds (mm/s).
    friction : FrictionParams, optional
        Friction constants and contact width (default: the reconstruction's).
    phantom : Phantom or ContactGeometry
        Geometry.
    friction_mode : {"vector", "axial"}
        See :func:`force_from_integrals`.

    Returns
    -------
    pandas.DataFrame
        One row per (step, speed), speed-major: ``scenario, speed_mm_s, theta_bot, theta_tip,
        theta_con`` (rad), ``force_g`` (g), ``step``.
    """
    sc = _scenario(scenario_name)
    params = sc.params(friction)
    speeds = np.asarray(list(speeds_mm_s), dtype=float)
    bot = np.asarray(sc.theta_bot)
    tip = np.asarray(sc.theta_tip)
    arcs = arc_integrals(bot, tip, phantom)
    force = force_from_integrals(
        ArcIntegrals(arcs.theta_con[None, :], arcs.g0[None], arcs.g1[None], arcs.length_mm[None]),
        speeds[:, None], params, friction_mode=friction_mode,
    )
    n, m = len(speeds), len(bot)
    return pd.DataFrame(
        {
            "scenario": sc.name,
            "speed_mm_s": np.repeat(speeds, m),
            "theta_bot": np.tile(bot, n),
            "theta_tip": np.tile(tip, n),
            "theta_con": np.tile(tip - bot, n),
            "force_g": force.ravel(),
            "step": np.tile(np.arange(m), n),
        }
    )


def peak_force_change(
    scenario_name: str | Scenario = "S4",
    v_ref_mm_s: float = 0.5,
    v_mm_s: float = 7.5,
    *,
    friction: FrictionParams | None = None,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
    friction_mode: FrictionMode = "vector",
) -> float:
    """Relative change (%) of the scenario's peak force from ``v_ref_mm_s`` to ``v_mm_s``.

    Negative means the peak force drops with speed (the paper's experiments: −24 % at 3 mm/s,
    −43 % at 7.5 mm/s; its simulation −2 %).

    Parameters
    ----------
    scenario_name : str or Scenario
        Scenario (default S4).
    v_ref_mm_s, v_mm_s : float
        Reference and compared speeds (mm/s).
    friction : FrictionParams, optional
        Friction constants (default: the reconstruction's).
    phantom : Phantom or ContactGeometry
        Geometry.
    friction_mode : {"vector", "axial"}
        See :func:`force_from_integrals`.
    """
    table = simulate(scenario_name, [v_ref_mm_s, v_mm_s], friction=friction, phantom=phantom,
                     friction_mode=friction_mode)
    peaks = table.groupby("speed_mm_s")["force_g"].max()
    return float(100.0 * (peaks[float(v_mm_s)] / peaks[float(v_ref_mm_s)] - 1.0))


def speed_change_table(
    v_s_values: Sequence[float] = (0.1, 0.3, 1.0, 3.0, 10.0),
    delta_values: Sequence[float] = (1.0, 2.0),
    *,
    mu_s: float = 0.18,
    mu_k: float = 0.12,
    scenario_name: str = "S4",
    v_ref_mm_s: float = 0.5,
    v_mm_s: float = 7.5,
) -> pd.DataFrame:
    """Peak-force change (%) between two speeds over a grid of Stribeck constants.

    Parameters
    ----------
    v_s_values : sequence of float
        Stribeck velocities (mm/s).
    delta_values : sequence of float
        Stribeck exponents (dimensionless).
    mu_s, mu_k : float
        Static and kinetic coefficients (dimensionless).
    scenario_name : str
        Scenario whose pressures and path are used.
    v_ref_mm_s, v_mm_s : float
        Speeds compared (mm/s).

    Returns
    -------
    pandas.DataFrame
        ``v_s_mm_s, delta_s, change_pct_vector, change_pct_axial``.
    """
    rows = []
    for v_s in v_s_values:
        for delta in delta_values:
            fr = replace(reconstructed_friction(True), mu_s=mu_s, mu_k=mu_k, v_s_mm_s=float(v_s), delta_s=float(delta))
            rows.append(dict(
                v_s_mm_s=float(v_s), delta_s=float(delta),
                change_pct_vector=peak_force_change(scenario_name, v_ref_mm_s, v_mm_s, friction=fr),
                change_pct_axial=peak_force_change(scenario_name, v_ref_mm_s, v_mm_s, friction=fr,
                                                   friction_mode="axial"),
            ))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- TABLE II fit


@dataclass(frozen=True)
class TableFit:
    """Constants fitted to a TABLE-II-like table.

    Attributes
    ----------
    mu_s, mu_k : float
        The better assignment of the two given coefficients (dimensionless).
    params : dict
        ``{name: (value, stderr)}`` of the fitted constants (units as in FrictionParams).
    friction : FrictionParams
        The fitted friction constants (pressures come from the scenarios).
    residuals : pandas.DataFrame
        Per cell: ``scenario, speed_mm_s, theta_con, force_g, model_g, residual_g, residual_pct``.
    rmse_g : float
        Root-mean-square residual (g).
    rss_by_assignment : dict
        Residual sum of squares (g^2) for ``"mu_s>mu_k"`` and ``"mu_s<mu_k"``.
    warnings : tuple of str
        Identifiability and bound warnings.
    """

    mu_s: float
    mu_k: float
    params: dict
    friction: FrictionParams
    residuals: pd.DataFrame
    rmse_g: float
    rss_by_assignment: dict
    warnings: tuple[str, ...]


_TABLE_BOUNDS = {
    "contact_width_mm": (1e-3, 5.0),
    "v_s_mm_s": (1e-3, 100.0),
    "delta_s": (0.2, 6.0),
    "mu_v_s_per_mm": (0.0, 0.2),
}


def _cell_arcs(table: pd.DataFrame, phantom: Phantom | ContactGeometry) -> tuple[np.ndarray, np.ndarray]:
    """(theta_bot, theta_tip) per table row: given, or read off the scenario path by theta_con."""
    if {"theta_bot", "theta_tip"} <= set(table.columns):
        return table["theta_bot"].to_numpy(float), table["theta_tip"].to_numpy(float)
    bot = np.empty(len(table))
    tip = np.empty(len(table))
    for name, idx in table.groupby("scenario").indices.items():
        sc = _scenario(name)
        con = np.asarray(sc.theta_tip) - np.asarray(sc.theta_bot)
        if np.any(np.diff(con) <= 0):
            raise ValueError(f"scenario {name}: theta_con must increase along the path to look cells up by it")
        want = table["theta_con"].to_numpy(float)[idx]
        bot[idx] = np.interp(want, con, sc.theta_bot)
        tip[idx] = np.interp(want, con, sc.theta_tip)
    return bot, tip


def fit_table(
    table: pd.DataFrame,
    *,
    mu_pair: tuple[float, float] = (0.12, 0.18),
    free: Sequence[str] = ("contact_width_mm", "v_s_mm_s", "delta_s"),
    start: FrictionParams | None = None,
    starts: int = 6,
    seed: int = 0,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
) -> TableFit:
    """Fit the paper's unstated constants to a TABLE-II-like table.

    For each assignment of ``mu_pair`` to (static, kinetic), bounded least squares (absolute
    residuals in g, several seeded starts) fits the ``free`` constants with the scenarios'
    pressure laws held; the assignment with the smaller residual sum of squares is kept.
    Standard errors: ``sqrt(diag(s^2 (J^T J)^-1))`` with ``s^2 = RSS / (n - k)``.

    Parameters
    ----------
    table : pandas.DataFrame
        ``scenario`` (S1–S4), ``speed_mm_s`` (mm/s), ``theta_con`` (rad), ``force_g`` (g);
        optional ``theta_bot``/``theta_tip`` (rad), else the cells are placed on the
        scenario's path by ``theta_con``.
    mu_pair : tuple of float
        The two friction coefficients (dimensionless), in either order.
    free : sequence of str
        Constants to fit, from ``contact_width_mm`` (mm), ``v_s_mm_s`` (mm/s), ``delta_s``,
        ``mu_v_s_per_mm`` (s/mm).
    start : FrictionParams, optional
        Starting values of the constants (default: the reconstruction's).
    starts : int
        Number of starts (the first is ``start``; others are drawn with ``seed``).
    seed : int
        Seed of the random starts.
    phantom : Phantom or ContactGeometry
        Geometry.

    Returns
    -------
    TableFit
    """
    needed = {"scenario", "speed_mm_s", "theta_con", "force_g"}
    missing = needed - set(table.columns)
    if missing:
        raise ValueError(f"table lacks column(s): {', '.join(sorted(missing))}")
    free = tuple(free)
    bad = set(free) - set(_TABLE_BOUNDS)
    if bad:
        raise ValueError(f"cannot fit {', '.join(sorted(bad))} to a table")
    table = table.reset_index(drop=True)
    bot, tip = _cell_arcs(table, phantom)
    arcs = arc_integrals(bot, tip, phantom)
    speed = table["speed_mm_s"].to_numpy(float)
    y = table["force_g"].to_numpy(float)
    groups = table.groupby("scenario").indices
    base0 = start if start is not None else reconstructed_friction(True)
    lo = np.array([_TABLE_BOUNDS[n][0] for n in free])
    hi = np.array([_TABLE_BOUNDS[n][1] for n in free])
    rng = np.random.default_rng(seed)

    def model(x: np.ndarray, base: FrictionParams) -> np.ndarray:
        changes: dict[str, Any] = dict(zip(free, map(float, x)))
        fr = replace(base, **changes)
        out = np.empty(len(y))
        for name, idx in groups.items():
            sub = ArcIntegrals(arcs.theta_con[idx], arcs.g0[idx], arcs.g1[idx], arcs.length_mm[idx])
            out[idx] = force_from_integrals(sub, speed[idx], _scenario(name).params(fr))
        return out

    x_first = np.clip([float(getattr(base0, n)) for n in free], lo, hi)
    # further starts log-uniform within the bounds (lower bounds of 0 raised to 1e-3)
    log_lo, log_hi = np.log(np.maximum(lo, 1e-3)), np.log(hi)
    candidates = [x_first] + [np.exp(rng.uniform(log_lo, log_hi)) for _ in range(max(0, starts - 1))]
    fits = {}
    for label, (mu_s, mu_k) in {"mu_s>mu_k": (max(mu_pair), min(mu_pair)),
                                "mu_s<mu_k": (min(mu_pair), max(mu_pair))}.items():
        base = replace(base0, mu_s=float(mu_s), mu_k=float(mu_k))
        best = None
        for x0 in candidates:
            res = least_squares(lambda x: model(x, base) - y, np.clip(x0, lo, hi), bounds=(lo, hi), x_scale="jac")
            if best is None or res.cost < best.cost:
                best = res
        assert best is not None  # candidates always holds x_first
        fits[label] = (base, best)
    label = min(fits, key=lambda k: fits[k][1].cost)
    base, res = fits[label]
    n, k = len(y), len(free)
    rss = 2.0 * float(res.cost)
    s2 = rss / max(n - k, 1)
    jac = np.asarray(res.jac, dtype=float)
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    warnings = []
    for name, value, low, high in zip(free, res.x, lo, hi):
        if np.isclose(value, low, rtol=1e-6) or np.isclose(value, high, rtol=1e-6):
            warnings.append(f"{name} is at its bound {value:.4g}: its standard error is not meaningful")
    sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    corr = cov / np.outer(sd, sd)
    for i in range(k):
        for j in range(i + 1, k):
            if abs(corr[i, j]) > 0.95:
                warnings.append(f"{free[i]} and {free[j]} are not separable by this table (corr {corr[i, j]:+.3f})")
    rss_all = {lab: 2.0 * float(r.cost) for lab, (_, r) in fits.items()}
    if min(rss_all.values()) > 0 and max(rss_all.values()) / min(rss_all.values()) < 1.05:
        warnings.append("the two mu assignments fit almost equally well (RSS within 5 %): static/kinetic not identified")
    fitted_values: dict[str, Any] = dict(zip(free, map(float, res.x)))
    fitted = replace(base, **fitted_values)
    pred = model(res.x, base)
    residuals = table[["scenario", "speed_mm_s", "theta_con", "force_g"]].copy()
    residuals["model_g"] = pred
    residuals["residual_g"] = y - pred
    with np.errstate(divide="ignore", invalid="ignore"):
        residuals["residual_pct"] = np.where(pred != 0, 100.0 * (y - pred) / pred, np.nan)
    return TableFit(
        mu_s=float(base.mu_s), mu_k=float(base.mu_k),
        params={name: (float(v), float(e)) for name, v, e in zip(free, res.x, se)},
        friction=fitted, residuals=residuals, rmse_g=float(np.sqrt(rss / n)),
        rss_by_assignment=rss_all, warnings=tuple(warnings),
    )

"""The insertion-force model of the seed paper (Eqs. 2–7), vectorised.

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

The sensed force is the reaction the robot must supply, along the insertion axis ``x_w`` (the
backbone tangent at ``theta_start``, pointing into the spiral), in grams-force::

    F = b_c [ integral p (n_out . x_w) ds + sign(v) mu(v) integral p (t_f . x_w) ds ] / 9.80665e-3

Two readings of the friction term (``friction_mode``):

- ``"axial"`` (**default**): every element's friction magnitude is transmitted along the array
  to its base, ``t_f . x_w = 1``. This is the reading that reproduces the paper's TABLE II,
  its speed effect in particular (:mod:`tympani.pipeline.model.paper`, ``tympani paper``): fitted to the
  table it falls by 1.05–1.77 % from 0.5 to 7.5 mm/s at every step, as the table does
  (1.03–1.94 %), with every cell within 6.3 %.
- ``"vector"``: the friction vectors are summed and then projected, ``t_f = t``, as Eqs. (2)–(5)
  read literally. Deep in the spiral the wall has turned more than 90° away from ``x_w``
  (``t . x_w < 0`` beyond about 2.7 rad), so friction there *lowers* F and the net friction
  term nearly cancels on long arcs: fitted to TABLE II it gives every cell within 4.8 % but a
  speed drop of only 0.02–1.2 % (0.02 % at the step where the table falls by 1.0 %), and no
  Stribeck constants can do better: projected that way, friction is a few per cent of the
  sensed force on those arcs, and ``mu_s - mu_k`` is 0.06.

Sign convention (checked, not flipped)
--------------------------------------
With these conventions the force is **positive** (the robot pushes the array in) for realistic
contact arcs (tests/test_friction.py). The normal term is negative for arcs lying within ~0.8
rad of ``theta_start``: Eq. (1)'s log branch makes the outer wall first turn *away* from the
centre there, so its outward normal points against ``x_w`` (``n_out . x_w < 0`` for theta in
(0.18, 0.95) rad); the array does not touch the outer wall there in practice (first contact at
1.0–1.8 rad). Such values are reported, not flipped.

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
beside the centreline point); angles outside the channel are clipped to it.

The paper's scenarios (TABLE I), its simulated forces (TABLE II) and the fit of the constants it
does not print are in :mod:`tympani.pipeline.model.paper`; :class:`FrictionParams`' defaults are that fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from functools import lru_cache
from typing import Literal, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom, entry_frame

__all__ = [
    "G_N",
    "FrictionMode",
    "DEFAULT_FRICTION_MODE",
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
    "flat_params",
    "params_from_flat",
    "FLAT_NAMES",
]

#: Newtons per gram-force (1 g = 9.80665e-3 N).
G_N = 9.80665e-3

FrictionMode = Literal["vector", "axial"]

#: The friction projection that reproduces the paper's TABLE II (see the module docstring).
DEFAULT_FRICTION_MODE: FrictionMode = "axial"


# --------------------------------------------------------------------------- pressure laws


@runtime_checkable
class PressureLaw(Protocol):
    """A contact pressure (MPa) as a function of the contact angle ``theta_con`` (rad)."""

    def __call__(self, theta_con: np.ndarray) -> np.ndarray:  # pragma: no cover - protocol
        ...


@dataclass(frozen=True)
class LinearPressure:
    """``p = p0 + p1 * theta_con`` (the default pressure law of the paper's friction model).

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
    """Parameters of the paper's friction model (Eqs. 2–7, docs/paper.md).

    The defaults are the seed paper's S4 as fitted to its TABLE II (:func:`tympani.pipeline.model.paper.fit_table_ii`,
    ``tympani paper``): the quoted coefficients with 0.18 static, the fitted Stribeck constants
    and contact width, and pressure laws that are the least-squares lines with non-negative
    coefficients through S4's six steps (:func:`tympani.pipeline.model.paper.paper_params`).

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
    v_s_mm_s: float = 0.1200
    delta_s: float = 0.3482
    mu_v_s_per_mm: float = 0.0
    contact_width_mm: float = 0.03453
    p_tip_MPa: PressureLaw = field(default_factory=lambda: LinearPressure(0.0, 0.02386))
    p_bot_MPa: PressureLaw = field(default_factory=lambda: LinearPressure(0.0, 0.03830))


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

    ``mu(v) = mu_k + (mu_s - mu_k) exp(-|v / v_s|^delta_s) + mu_v |v|``. The viscous term
    ``mu_v |v|`` extends the paper's Eq. (7) (held at 0 by default); for the insertion speeds
    (``v > 0``) it equals ``mu_v v``. A negative
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
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE,
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
        ``"axial"`` (default, :data:`DEFAULT_FRICTION_MODE`): each element's friction magnitude
        acts along ``x_w``, the reading that reproduces the paper's TABLE II. ``"vector"``:
        friction vectors summed and projected on ``x_w``, Eqs. (2)–(5) read literally.

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
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE,
) -> np.ndarray:
    """Sensed insertion force (g) of the paper's friction model for contact arcs and speeds.

    Parameters
    ----------
    theta_bot : array_like
        Contact start angle (rad; docs/file-formats.md, the angles).
    theta_tip : array_like
        Tip angle (rad). ``theta_con = theta_tip - theta_bot <= 0`` gives 0 force.
    speed_mm_s : array_like
        Insertion speed (mm/s); all three inputs broadcast together.
    params : FrictionParams
        Friction law, contact width (mm) and pressure laws (MPa vs rad).
    phantom : Phantom or ContactGeometry
        Phantom frame geometry (default: :data:`~tympani.vision.geometry.DEFAULT_PHANTOM`).
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

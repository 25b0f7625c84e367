"""The array's angles theta_tip, theta_bot and theta_con, by their definitions.

The angles are defined in docs/how-it-works.md. :func:`contact_angles` applies the definitions to
an array centreline given in the phantom frame. The renderer uses it to compute ground truth from
the geometry it draws; the measurement applies its rule to the centreline it finds in a frame
(:mod:`tympani.vision.angles.results`), with the points' angles from :func:`spiral_angle`, the
arithmetic of :func:`~tympani.vision.geometry.point_angle` with the phantom's constants computed
once (:class:`AngleTable`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tympani.vision.geometry import Phantom, channel_width, entry_frame, point_angle


@dataclass(frozen=True)
class ContactAngles:
    """The three angles (rad) and where they are.

    Parameters
    ----------
    theta_tip, theta_bot, theta_con : float
        Tip angle, contact start angle and contact angle (rad).
    tip_mm, bot_mm : ndarray, shape (2,)
        Centreline points (mm, phantom frame) of the tip and of the contact start.
    """

    theta_tip: float
    theta_bot: float
    theta_con: float
    tip_mm: np.ndarray
    bot_mm: np.ndarray


def outer_wall_gap(
    centreline_mm: np.ndarray, radius_mm: np.ndarray, phantom: Phantom, theta: np.ndarray | None = None
) -> np.ndarray:
    """Gap (mm) between the array's outer edge and the outer wall at each centreline point.

    Parameters
    ----------
    centreline_mm : ndarray, shape (n, 2)
        Centreline points (mm, phantom frame).
    radius_mm : ndarray, shape (n,)
        Half the array's width (mm) at each point.
    phantom : Phantom
        Phantom configuration.
    theta : ndarray, shape (n,), optional
        The points' angles (rad, unwrapped); computed when not given.

    Returns
    -------
    ndarray, shape (n,)
        Distance from the centreline to the outer wall of its own turn, less the radius (mm); negative where the
        outline crosses the wall.
    """
    if theta is None:
        theta = point_angle(centreline_mm, phantom)
    distance, _, _ = phantom.outer_wall.project(centreline_mm, theta)
    return distance - np.asarray(radius_mm, dtype=float)


def contact_angles(
    centreline_mm: np.ndarray,
    radius_mm: np.ndarray,
    phantom: Phantom,
    *,
    contact_tol_mm: float = 0.05,
    gap_mm: np.ndarray | None = None,
    theta: np.ndarray | None = None,
) -> ContactAngles:
    """The angles of an array given by its centreline, tip first.

    Parameters
    ----------
    centreline_mm : ndarray, shape (n, 2)
        Centreline points (mm, phantom frame) ordered from the tip towards the base.
    radius_mm : ndarray, shape (n,)
        Half the array's width (mm) at each point.
    phantom : Phantom
        Phantom configuration.
    contact_tol_mm : float
        Largest gap (mm) between outer edge and outer wall that counts as contact.
    gap_mm : ndarray, shape (n,), optional
        Gaps (mm) if already known (e.g. measured); otherwise :func:`outer_wall_gap`.
    theta : ndarray, shape (n,), optional
        The points' angles (rad, unwrapped) if already known (the measurement computes them with
        precomputed constants, see :func:`spiral_angle`); otherwise
        :func:`tympani.vision.geometry.point_angle`.

    Returns
    -------
    ContactAngles
        ``theta_bot`` is where the unbroken contact run ending at the tip begins, interpolated
        between the last point in contact and the first one out of it; without contact at the
        tip ``theta_bot = theta_tip`` and ``theta_con = 0``.
    """
    centreline_mm = np.atleast_2d(np.asarray(centreline_mm, dtype=float))
    if theta is None:
        theta = point_angle(centreline_mm, phantom)
    if gap_mm is None:
        gap_mm = outer_wall_gap(centreline_mm, radius_mm, phantom, theta)
    tip = centreline_mm[0]
    theta_tip = float(theta[0])
    touching = np.asarray(gap_mm) <= contact_tol_mm
    if not touching[0]:
        return ContactAngles(theta_tip, theta_tip, 0.0, tip, tip)
    out = np.flatnonzero(~touching)
    if len(out) == 0:
        i_last, frac = len(theta) - 1, 0.0
    else:
        i_last = int(out[0]) - 1
        g0, g1 = gap_mm[i_last], gap_mm[i_last + 1]
        frac = min(max(float((contact_tol_mm - g0) / (g1 - g0)), 0.0), 1.0) if g1 != g0 else 0.0
    j = min(i_last + 1, len(theta) - 1)
    bot = centreline_mm[i_last] + frac * (centreline_mm[j] - centreline_mm[i_last])
    theta_bot = float(theta[i_last] + frac * (theta[j] - theta[i_last]))
    return ContactAngles(theta_tip, theta_bot, theta_tip - theta_bot, tip, bot)


@dataclass(frozen=True, eq=False)
class AngleTable:
    """The constants :func:`tympani.vision.geometry.point_angle` derives from a phantom, computed once
    per plan so that :func:`spiral_angle` costs a dozen NumPy calls per frame.

    ``turns`` are the candidate offsets 2πk (rad); ``origin``, ``x_w``, ``normal`` (mm, unit)
    the entry frame and ``entry_width_mm`` the entry channel's width (mm); the rest are
    :class:`~tympani.vision.geometry.Phantom` fields of Eq. (1) and the channel's ends (rad).
    """

    turns: np.ndarray
    theta_start: float
    theta_end: float
    branch_deg: float
    c_mm: float
    d: float
    phi0_deg: float
    a_mm: float
    b_per_deg: float
    origin: np.ndarray
    x_w: np.ndarray
    normal: np.ndarray
    entry_width_mm: float


def angle_table(phantom: Phantom) -> AngleTable:
    """:class:`AngleTable` of ``phantom``, with the same constants as ``point_angle``."""
    n_turns = int(np.ceil((phantom.theta_end + np.pi) / (2 * np.pi))) + 1
    origin, x_w, normal = entry_frame(phantom)
    return AngleTable(
        turns=2 * np.pi * np.arange(n_turns), theta_start=float(phantom.theta_start),
        theta_end=float(phantom.theta_end), branch_deg=float(phantom.branch_deg), c_mm=float(phantom.c_mm),
        d=float(phantom.d), phi0_deg=float(phantom.phi0_deg), a_mm=float(phantom.a_mm),
        b_per_deg=float(phantom.b_per_deg), origin=origin, x_w=x_w, normal=normal,
        entry_width_mm=float(channel_width(phantom.theta_start, phantom)),
    )


def spiral_angle(xy: np.ndarray, t: AngleTable) -> np.ndarray:
    """Unwrapped angles (rad) of points ``xy`` (mm, shape (n, 2)): the same arithmetic as
    :func:`tympani.vision.geometry.point_angle`, with the phantom's constants precomputed in ``t``.

    Candidates clipped to [theta_start, theta_end] (> phi0) keep the logarithm finite, so no
    error-state guard is needed.
    """
    x, y = xy[:, 0], xy[:, 1]
    phi = np.arctan2(y, x)
    rho = np.hypot(x, y)
    cand = phi[:, None] + t.turns[None, :]
    clipped = np.minimum(np.maximum(cand, t.theta_start), t.theta_end)
    deg = np.degrees(clipped)
    r = np.where(deg < t.branch_deg, t.c_mm * (1.0 - t.d * np.log(deg - t.phi0_deg)), t.a_mm * np.exp(-t.b_per_deg * deg))
    k = np.argmin(np.abs(r - rho[:, None]) + 0.1 * np.abs(cand - clipped), axis=1)
    rel = xy - t.origin
    entry = ((rel @ t.x_w) < 0) & (np.abs(rel @ t.normal) <= t.entry_width_mm)
    return np.where(entry, phi, phi + 2 * np.pi * k)

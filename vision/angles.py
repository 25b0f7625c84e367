"""The array's angles: theta_tip, theta_bot and theta_con (SPEC §3).

:func:`contact_angles` applies the SPEC definitions to an array centreline given in the
phantom frame. The renderer uses it to compute ground truth from the geometry it draws; the
measurement uses it on the centreline it finds in a frame, so both answer the same question.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Phantom, point_angle

__all__ = ["ContactAngles", "contact_angles", "outer_wall_gap"]


@dataclass(frozen=True)
class ContactAngles:
    """The three SPEC §3 angles (rad) and where they are.

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
        The points' SPEC angles (rad); computed when not given.

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
) -> ContactAngles:
    """SPEC §3 angles of an array given by its centreline, tip first.

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

    Returns
    -------
    ContactAngles
        ``theta_bot`` is where the unbroken contact run ending at the tip begins, interpolated
        between the last point in contact and the first one out of it; without contact at the
        tip ``theta_bot = theta_tip`` and ``theta_con = 0``.
    """
    centreline_mm = np.atleast_2d(np.asarray(centreline_mm, dtype=float))
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
        frac = float(np.clip((contact_tol_mm - g0) / (g1 - g0), 0.0, 1.0)) if g1 != g0 else 0.0
    j = min(i_last + 1, len(theta) - 1)
    bot = centreline_mm[i_last] + frac * (centreline_mm[j] - centreline_mm[i_last])
    theta_bot = float(theta[i_last] + frac * (theta[j] - theta[i_last]))
    return ContactAngles(theta_tip, theta_bot, theta_tip - theta_bot, tip, bot)

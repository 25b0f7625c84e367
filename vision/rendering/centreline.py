"""The array's centre line in the phantom for given angles or an insertion depth, with its truth.

:func:`array_centreline` poses the array for a tip angle and a nominal contact start angle;
:func:`array_at_angles` corrects the nominal angles until the measured ones match;
:func:`pose_at_depth` poses it for an insertion depth, its contact run following a
:class:`ContactPolicy`. The truth of every pose comes from the drawn centre line, through the
angles' definitions (:func:`tympani.vision.angles.contact_angles`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq

from tympani.vision.angles import ContactAngles, contact_angles
from tympani.vision.geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    ElectrodeArray,
    Phantom,
    backbone_frame,
    channel_width,
    entry_frame,
)

__all__ = [
    "ArrayShape",
    "ArrayState",
    "ContactPolicy",
    "array_centreline",
    "array_at_angles",
    "pose_at_depth",
    "smoothstep",
]


def smoothstep(x: np.ndarray) -> np.ndarray:
    """Cubic step of ``x`` (dimensionless): 0 at or below 0, 1 at or above 1, flat at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class ArrayShape:
    """How the array lies in the channel basal of its contact run.

    Parameters
    ----------
    departure_rad : float
        Angular span (rad) over which the array leaves the outer wall basal of theta_bot
        (the gap grows smoothly, quadratically at first).
    far_offset : float
        Where the array settles basally, as a fraction of the free lateral play: -1 on the
        inner wall, 0 on the backbone, +1 on the outer wall.
    start_blend_rad : float
        Angular span (rad) after theta_start over which the array leaves the insertion axis.
    contact_level : float
        1 when the tip rides the outer wall; below 1 the tip is short of it by that fraction
        of the lateral play (before first contact).
    """

    departure_rad: float = 0.5
    far_offset: float = -0.3
    start_blend_rad: float = 0.6
    contact_level: float = 1.0


@dataclass(frozen=True)
class ArrayState:
    """An array posed in the phantom, with its truth.

    Parameters
    ----------
    centreline_mm : ndarray, shape (n, 2)
        Centreline (mm, phantom frame) from the tip to the base.
    s_mm : ndarray, shape (n,)
        Arc length (mm) from the tip.
    radius_mm : ndarray, shape (n,)
        Half-width (mm) of the array body at each point.
    depth_mm : float
        Length (mm) of array past the entry's end at theta_start.
    truth : ContactAngles
        The angles of this centreline (as the measurement defines them).
    """

    centreline_mm: np.ndarray
    s_mm: np.ndarray
    radius_mm: np.ndarray
    depth_mm: float
    truth: ContactAngles


def _spiral_part(
    theta_tip: float, theta_bot: float, shape: ArrayShape, phantom: Phantom, array: ElectrodeArray, step_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Centreline (mm) of the array inside the spiral, tip first, and arc length (mm) from the tip."""
    n = max(50, int((theta_tip - phantom.theta_start) * 8.0 / step_mm))
    theta = np.linspace(theta_tip, phantom.theta_start, n)  # tip first
    pts, _, normal = backbone_frame(theta, phantom)
    half = 0.5 * channel_width(theta, phantom)
    start_blend = smoothstep((theta - phantom.theta_start) / shape.start_blend_rad)
    depart = smoothstep((theta_bot - theta) / shape.departure_rad)
    radius = array.radius(np.zeros(n))
    for _ in range(3):  # the radius depends on arc length, which depends on the offset
        play = np.maximum(half - radius, 0.0)
        e_far = shape.far_offset * 0.85 * play * start_blend
        e_touch = e_far + shape.contact_level * (play - e_far)
        e = e_touch + (e_far - e_touch) * depart
        spiral = pts + e[:, None] * normal
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(spiral, axis=0).T))])
        radius = array.radius(s)
    return spiral, s


def array_centreline(
    theta_tip: float,
    theta_bot: float,
    *,
    shape: ArrayShape = ArrayShape(),
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    step_mm: float = 0.02,
    contact_tol_mm: float = 0.05,
) -> ArrayState:
    """Pose the array with its tip at ``theta_tip`` riding the outer wall back to ``theta_bot``.

    In the channel the centreline is a normal offset ``e(theta)`` of the backbone: from the tip to
    ``theta_bot`` the array's outer edge lies on the outer wall; basal of it the array departs
    smoothly towards ``shape.far_offset``; near ``theta_start`` it joins the insertion axis,
    along which the rest of the array runs straight out of the entry.

    Parameters
    ----------
    theta_tip : float
        Tip angle (rad), ``theta_start < theta_tip < theta_end``.
    theta_bot : float
        Nominal contact start angle (rad), ``<= theta_tip``. The true contact start of the
        result (``truth.theta_bot``) lies slightly basal of it, where the smooth departure's
        gap reaches ``contact_tol_mm``.
    shape : ArrayShape
        Departure and settling of the basal part.
    phantom, array : Phantom, ElectrodeArray
        Geometry.
    step_mm : float
        Approximate spacing (mm) of the centreline samples.
    contact_tol_mm : float
        Contact tolerance (mm) for the truth.

    Returns
    -------
    ArrayState
    """
    if not phantom.theta_start < theta_tip < phantom.theta_end:
        raise ValueError(f"theta_tip={theta_tip:.3f} rad is outside the channel")
    if theta_bot > theta_tip:
        raise ValueError("theta_bot must not exceed theta_tip")
    spiral, s = _spiral_part(theta_tip, theta_bot, shape, phantom, array, step_mm)
    depth = float(s[-1])
    origin, x_w, _ = entry_frame(phantom)
    rest = max(array.length_mm - depth, 0.0)
    m = max(2, int(np.ceil(rest / (4 * step_mm))) + 1)
    back = np.linspace(0.0, rest, m)[1:]
    straight = origin[None, :] - back[:, None] * x_w[None, :]
    centreline = np.vstack([spiral, straight])
    s_all = np.concatenate([s, depth + back])
    keep = s_all <= array.length_mm
    centreline, s_all = centreline[keep], s_all[keep]
    radius_all = array.radius(s_all)
    truth = contact_angles(
        centreline[: len(s)], radius_all[: len(s)], phantom, contact_tol_mm=contact_tol_mm
    )
    return ArrayState(centreline, s_all, radius_all, depth, truth)


def array_at_angles(
    theta_tip: float,
    theta_bot: float,
    *,
    shape: ArrayShape = ArrayShape(),
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
    tol_rad: float = 1e-4,
    max_iter: int = 20,
) -> ArrayState:
    """Pose the array so that its *measured* tip and contact start angles are the given ones.

    :func:`array_centreline` places the nominal angles; the truth of the result differs
    slightly (the contact start lies where the departing edge's gap reaches the tolerance). This
    corrects the nominal angles until the truth matches, e.g. to render the paper's TABLE III.

    Parameters
    ----------
    theta_tip, theta_bot : float
        Wanted tip and contact start angles (rad), ``theta_bot < theta_tip``.
    shape, phantom, array
        As :func:`array_centreline`.
    tol_rad : float
        Largest difference (rad) accepted between the truth and the wanted angles.
    max_iter : int
        Most corrections tried.

    Returns
    -------
    ArrayState

    Raises
    ------
    ValueError
        When the angles cannot be reached (outside the channel, or not converging).
    """
    tip_nom, bot_nom = float(theta_tip), float(theta_bot)
    for _ in range(max_iter):
        state = array_centreline(tip_nom, min(bot_nom, tip_nom), shape=shape, phantom=phantom, array=array)
        d_tip = theta_tip - state.truth.theta_tip
        d_bot = theta_bot - state.truth.theta_bot
        if abs(d_tip) <= tol_rad and abs(d_bot) <= tol_rad:
            return state
        tip_nom += d_tip
        bot_nom += d_bot
    raise ValueError(f"cannot pose the array at theta_tip={theta_tip:.3f}, theta_bot={theta_bot:.3f} rad "
                     f"(off by {d_tip:+.4f}, {d_bot:+.4f} rad after {max_iter} corrections)")


@dataclass(frozen=True)
class ContactPolicy:
    """How the contact run grows with depth during one insertion.

    Before ``theta_first`` the tip approaches the outer wall over ``approach_rad``; from there
    on it rides the wall and the contact start follows
    ``theta_bot = theta_first + lag * (theta_tip - theta_first)``.

    Parameters
    ----------
    theta_first : float
        Tip angle (rad) at first contact with the outer wall.
    lag : float
        Fraction (0–1) of the tip's advance that the contact start follows.
    approach_rad : float
        Angular span (rad) before first contact over which the tip closes on the wall.
    shape : ArrayShape
        Departure and settling of the basal part.
    """

    theta_first: float = 1.4
    lag: float = 0.3
    approach_rad: float = 0.6
    shape: ArrayShape = ArrayShape()

    def at(self, theta_tip: float) -> tuple[float, ArrayShape]:
        """Nominal contact start (rad) and shape for a tip angle (rad)."""
        if theta_tip >= self.theta_first:
            return self.theta_first + self.lag * (theta_tip - self.theta_first), self.shape
        level = float(smoothstep(1.0 - (self.theta_first - theta_tip) / self.approach_rad))
        return theta_tip, replace(self.shape, contact_level=level)


def pose_at_depth(
    depth_mm: float,
    policy: ContactPolicy = ContactPolicy(),
    *,
    phantom: Phantom = DEFAULT_PHANTOM,
    array: ElectrodeArray = DEFAULT_ARRAY,
) -> ArrayState:
    """The array at insertion depth ``depth_mm`` (mm), its contact run following ``policy``.

    Depths at or below zero put the tip on the insertion axis behind the entry's end.
    """
    if depth_mm <= 0.0:
        return _outside_pose(depth_mm, phantom, array)
    lo, hi = phantom.theta_start + 1e-4, phantom.theta_end - 1e-3

    def excess(theta_tip: float) -> float:
        theta_bot, shape = policy.at(theta_tip)
        return float(_spiral_part(theta_tip, theta_bot, shape, phantom, array, 0.02)[1][-1]) - depth_mm

    if excess(hi) < 0:
        raise ValueError(f"depth {depth_mm} mm is beyond the end of the channel")
    theta_tip = brentq(excess, lo, hi, xtol=1e-7) if excess(lo) < 0 else lo
    theta_bot, shape = policy.at(theta_tip)
    return array_centreline(theta_tip, theta_bot, shape=shape, phantom=phantom, array=array)


def _outside_pose(depth_mm: float, phantom: Phantom, array: ElectrodeArray) -> ArrayState:
    origin, x_w, _ = entry_frame(phantom)
    s = np.linspace(0.0, array.length_mm, 200)
    centreline = origin[None, :] + (depth_mm - s)[:, None] * x_w[None, :]
    radius = array.radius(s)
    truth = contact_angles(centreline[:2], radius[:2], phantom)
    return ArrayState(centreline, s, radius, float(depth_mm), truth)


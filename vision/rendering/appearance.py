"""How a scene looks and where it is seen from: the grey levels, and random draws of a look,
a camera pose and a contact policy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tympani.vision.geometry import DEFAULT_PHANTOM, CameraPose, Phantom, channel_polygon
from tympani.vision.rendering.centreline import ArrayShape, ContactPolicy

__all__ = ["Appearance", "random_appearance", "random_pose", "random_policy"]


@dataclass(frozen=True)
class Appearance:
    """How the phantom and array look (grey levels 0–255 before nuisances).

    Parameters
    ----------
    background : float
        Phantom material outside the channel.
    fluid : float
        Lubricant inside the channel (equal to ``background`` when walls are only lines).
    wall_style : {"lines", "region", "both"}
        Walls as thin lines, as the boundary between fluid and background, or both.
    wall_level : float
        Grey level of wall lines.
    wall_width_px : float
        Width (px) of wall lines.
    wall_side : {"on", "outside"}
        Wall lines centred on the channel's edge, or as a band that wide just outside it (the
        plate's cut face catching the light).
    array_level : float
        Silicone body of the array (darker than the fluid).
    band_level : float
        Platinum bands.
    tint : tuple of float
        Per-channel (B, G, R) gains of the colour image.
    """

    background: float = 185.0
    fluid: float = 205.0
    wall_style: str = "both"
    wall_level: float = 90.0
    wall_width_px: float = 2.0
    array_level: float = 70.0
    band_level: float = 230.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    wall_side: str = "on"


def random_pose(
    rng: np.random.Generator,
    width: int = 640,
    height: int = 480,
    *,
    px_per_mm: tuple[float, float] = (15.0, 60.0),
    phantom: Phantom = DEFAULT_PHANTOM,
    margin_px: float = 10.0,
) -> CameraPose:
    """A random similarity that keeps the whole channel (entry included) inside the frame.

    The scale is drawn from ``px_per_mm`` (px/mm) and reduced if the channel would not fit.
    """
    outline = channel_polygon(phantom)
    mirrored = bool(rng.integers(0, 2))
    rot = float(rng.uniform(-np.pi, np.pi))
    scale = float(rng.uniform(*px_per_mm))
    probe = CameraPose(0.0, 0.0, rot, 1.0, mirrored).to_image(outline)
    span = probe.max(axis=0) - probe.min(axis=0)
    scale = min(scale, (width - 2 * margin_px) / span[0], (height - 2 * margin_px) / span[1])
    lo = -probe.min(axis=0) * scale + margin_px
    hi = np.array([width, height]) - probe.max(axis=0) * scale - margin_px
    cx, cy = rng.uniform(lo, np.maximum(hi, lo))
    return CameraPose(float(cx), float(cy), rot, scale, mirrored)


def random_policy(rng: np.random.Generator) -> ContactPolicy:
    """A plausible, random way for the contact run to grow during one insertion.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of six uniform draws, in a fixed order (the shape's three, then the policy's).

    Returns
    -------
    ContactPolicy
        First contact at a tip angle of 1.0–1.8 rad, a contact start that follows 15–45 % of
        the tip's advance, an approach over 0.4–0.8 rad; basally (:class:`ArrayShape`) the array
        leaves the wall over 0.35–0.7 rad, settles at -0.7 to +0.2 of the lateral play and leaves
        the insertion axis over 0.4–0.8 rad.
    """
    shape = ArrayShape(
        departure_rad=float(rng.uniform(0.35, 0.7)),
        far_offset=float(rng.uniform(-0.7, 0.2)),
        start_blend_rad=float(rng.uniform(0.4, 0.8)),
    )
    return ContactPolicy(
        theta_first=float(rng.uniform(1.0, 1.8)),
        lag=float(rng.uniform(0.15, 0.45)),
        approach_rad=float(rng.uniform(0.4, 0.8)),
        shape=shape,
    )


def random_appearance(rng: np.random.Generator) -> Appearance:
    """An appearance drawn from a wide range of plausible looks."""
    style = str(rng.choice(["lines", "region", "both"]))
    background = float(rng.uniform(120, 220))
    delta = float(rng.uniform(15, 45)) * (1 if rng.random() < 0.6 else -1)
    fluid = background if style == "lines" else float(np.clip(background + delta, 60, 245))
    wall_level = float(rng.uniform(30, 90)) if rng.random() < 0.8 else float(min(255, background + 50))
    array_level = float(rng.uniform(20, min(fluid, background) - 50))
    band_level = float(rng.uniform(max(array_level + 60, 150), 255))
    b, g, r = (float(t) for t in rng.uniform(0.85, 1.15, size=3))
    tint = (b, g, r)
    return Appearance(background, fluid, style, wall_level, float(rng.uniform(1.2, 3.0)), array_level, band_level, tint)

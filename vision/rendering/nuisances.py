"""What degrades a frame (:class:`Nuisance`), its random draws, and the image pieces the scene
draws them with: Gaussian spots (glints), motion-blur kernels, shadow fields and glint flicker.

Bubbles in the fluid are drawn with :mod:`.bubbles`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tympani.vision.rendering.centreline import smoothstep

__all__ = [
    "Nuisance",
    "random_nuisance",
    "random_harsh_nuisance",
    "gaussian_spot",
    "line_kernel",
    "shadow_field",
    "glint_flicker",
]


@dataclass(frozen=True)
class Nuisance:
    """Image degradations and clutter, each off at zero (the defaults draw a clean frame).

    None of these touches the array's geometry, so none changes the truth.

    Parameters
    ----------
    noise_sigma : float
        Standard deviation of additive sensor noise (grey levels).
    blur_sigma_px : float
        Gaussian blur (px) of the whole frame (focus).
    illumination : float
        Relative amplitude (0–0.5) of a smooth, uneven illumination field.
    flicker : float
        Relative standard deviation of the per-frame global gain.
    jpeg_quality : int or None
        Re-encode every frame as JPEG of this quality (1–100; 15–20 is heavy compression).
    distractors : int
        Number of objects outside the channel (screws, a ruler); a gripper holding the array's
        base is drawn when this is at least 1.
    bubbles : int
        Number of free air bubbles in the channel fluid; each drifts slowly along the channel
        (bouncing at its ends) at about ``bubble_drift_mm_s``.
    bubble_at_tip : float or None
        Gap (mm) between the array's tip apex and the edge of a bubble just apical of it,
        pushed along with the tip (0 = touching the apex; 0.1–1 mm = ahead of it).
        None: no such bubble.
    bubble_radius_mm : float or None
        Radius (mm) of every bubble; None draws each log-uniformly from 0.15 mm to the widest
        half channel (0.75 mm by default). A bubble never spans more than the channel: where
        it is narrower the radius is cut to the local half width (mm) less half a wall line.
    bubble_drift_mm_s : float
        Typical speed (mm/s) of the free bubbles along the channel.
    doubled_wall_mm : float
        Parallax (mm, typically 0.1–0.5) between a wall's top and bottom edge in a thick
        plate: every wall is drawn a second time displaced by this much (0 = single walls).
    doubled_wall_contrast : float
        Contrast (0–1) of the second wall relative to the first.
    doubled_wall_direction_rad : float or None
        Image direction (rad, ``atan2(dy, dx)`` in pixel coordinates, y down) of the
        displacement; None draws it at random.
    glints : float
        Strength (0–1) of specular glints on the metal bands: each band's glint flickers
        with the frame time; at 1 a glint saturates.
    plate_glints : int
        Number of static specular reflections (bright spots) on the plate.
    motion_blur_px : float
        Length (px) of the smear of the moving parts (array, gripper) during one exposure,
        along the array's local direction (centred on the frame's instant).
    shadows : float
        Darkness (0–0.9) of soft shadows across part of the image (on top of
        ``illumination``) and of the gripper's shadow.
    gripper_overlap_mm : float
        Length (mm) of the array's straight part, next to its base, that the gripper's jaw
        hides; the jaw stops 0.5 mm short of the entry channel (outside the entry).
    array_shadow : float
        Darkness (0–0.9) of the array's own shadow on the channel floor under it: the array's
        outline moved by ``array_shadow_mm`` and softened, darkening what lies there (fluid,
        wall lines, bubbles) but drawn under the array. With a light array (little darker
        than the fluid) the shadow beside it is darker than the array itself.
    array_shadow_mm : float
        How far (mm) the shadow lies from the array (a lamp at a slant; 0.2–0.6 mm is typical).
    array_shadow_direction_rad : float or None
        Image direction (rad, ``atan2(dy, dx)`` in pixel coordinates, y down) of the shadow's
        offset; None draws it at random.
    """

    noise_sigma: float = 0.0
    blur_sigma_px: float = 0.0
    illumination: float = 0.0
    flicker: float = 0.0
    jpeg_quality: int | None = None
    distractors: int = 0
    bubbles: int = 0
    bubble_at_tip: float | None = None
    bubble_radius_mm: float | None = None
    bubble_drift_mm_s: float = 0.1
    doubled_wall_mm: float = 0.0
    doubled_wall_contrast: float = 0.7
    doubled_wall_direction_rad: float | None = None
    glints: float = 0.0
    plate_glints: int = 0
    motion_blur_px: float = 0.0
    shadows: float = 0.0
    gripper_overlap_mm: float = 0.0
    array_shadow: float = 0.0
    array_shadow_mm: float = 0.4
    array_shadow_direction_rad: float | None = None

    def __post_init__(self) -> None:
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be 1–100, not {self.jpeg_quality}")
        if self.bubble_at_tip is not None and self.bubble_at_tip < 0:
            raise ValueError("bubble_at_tip must be a gap >= 0 mm or None")
        if self.bubble_radius_mm is not None and self.bubble_radius_mm <= 0:
            raise ValueError("bubble_radius_mm must be > 0 mm or None")
        if not 0.0 <= self.doubled_wall_contrast <= 1.0:
            raise ValueError("doubled_wall_contrast must be 0–1")
        for name in ("shadows", "array_shadow"):
            if not 0.0 <= getattr(self, name) <= 0.9:
                raise ValueError(f"{name} must be 0–0.9")
        for name in ("bubbles", "plate_glints", "doubled_wall_mm", "glints", "motion_blur_px",
                     "gripper_overlap_mm", "bubble_drift_mm_s", "array_shadow_mm"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative")

    @property
    def has_bubbles(self) -> bool:
        """Whether any bubble is drawn."""
        return self.bubbles > 0 or self.bubble_at_tip is not None


def random_nuisance(rng: np.random.Generator, strength: float) -> Nuisance:
    """Nuisances scaled by ``strength`` (0 = clean, 1 = heavy)."""
    if strength <= 0:
        return Nuisance()
    return Nuisance(
        noise_sigma=float(rng.uniform(0.5, 1.0) * 10 * strength),
        blur_sigma_px=float(rng.uniform(0.5, 1.0) * 1.5 * strength),
        illumination=float(rng.uniform(0.5, 1.0) * 0.4 * strength),
        flicker=float(0.05 * strength),
        jpeg_quality=int(95 - 50 * strength) if strength >= 0.3 else None,
        distractors=int(round(4 * strength)),
    )


def random_harsh_nuisance(rng: np.random.Generator, strength: float) -> Nuisance:
    """Everything real footage of a glycerin-filled acrylic phantom shows, scaled by ``strength``.

    On top of :func:`random_nuisance`'s kinds (drawn from wider ranges, JPEG quality down to
    15 at full strength): free and tip bubbles, doubled walls, band and plate glints, motion
    blur, shadows (the array's own in half the draws) and a gripper that hides part of the
    straight array. Each kind is present at random, so a set of draws meets every combination.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    strength : float
        0 (clean, ``Nuisance()``) to 1 (harsh).

    Returns
    -------
    Nuisance
    """
    if strength <= 0:
        return Nuisance()
    s = float(min(strength, 1.0))
    u = rng.uniform
    quality = int(np.clip(round(95 - 80 * s * u(0.6, 1.0)), 15, 95))
    tip_kind = int(rng.integers(0, 3))  # none, touching, ahead
    return Nuisance(
        noise_sigma=float(u(0.3, 1.0) * 12 * s),
        blur_sigma_px=float(u(0.2, 1.0) * 1.8 * s),
        illumination=float(u(0.3, 1.0) * 0.45 * s),
        flicker=float(u(0.3, 1.0) * 0.08 * s),
        jpeg_quality=quality if u() < 0.5 + 0.5 * s else None,
        distractors=int(rng.integers(1, 2 + round(4 * s))),
        bubbles=int(rng.integers(0, 1 + round(8 * s))),
        bubble_at_tip=(None, 0.0, float(u(0.1, 1.0)))[tip_kind],
        bubble_radius_mm=None,
        bubble_drift_mm_s=float(u(0.02, 0.4)),
        doubled_wall_mm=float(u(0.1, 0.1 + 0.4 * s)) if u() < 0.4 + 0.5 * s else 0.0,
        doubled_wall_contrast=float(u(0.3, 1.0)),
        doubled_wall_direction_rad=None,
        glints=float(u(0.3, 1.0) * s),
        plate_glints=int(rng.integers(0, 1 + round(4 * s))),
        motion_blur_px=float(u(0.0, 8.0) * s),
        shadows=float(u(0.2, 0.7) * s),
        gripper_overlap_mm=float(u(0.0, 6.0) * s),
        array_shadow=float(u(0.2, 0.6) * s) if u() < 0.5 else 0.0,
        array_shadow_mm=float(u(0.2, 0.6)),
        array_shadow_direction_rad=None,
    )


def gaussian_spot(shape: tuple[int, int], centre_px: np.ndarray, along: np.ndarray, sigma_along_px: float,
                  sigma_across_px: float, amplitude: float) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """An elongated Gaussian spot (grey levels) on the pixels it reaches (3 sigma).

    Parameters
    ----------
    shape : (height, width)
        Frame size (px): the returned box is clipped to it.
    centre_px : ndarray, shape (2,)
        Centre (px).
    along : ndarray, shape (2,)
        Unit image direction of the long axis.
    sigma_along_px, sigma_across_px : float
        Standard deviations (px) along and across ``along``.
    amplitude : float
        Peak (grey levels).

    Returns
    -------
    bbox, spot
        Clipped pixel box ``(x0, y0, x1, y1)`` and the spot's values over it.
    """
    reach = 3.0 * max(sigma_along_px, sigma_across_px)
    cx, cy = (float(v) for v in centre_px)
    x0, y0 = max(int(np.floor(cx - reach)), 0), max(int(np.floor(cy - reach)), 0)
    x1, y1 = min(int(np.ceil(cx + reach)) + 1, shape[1]), min(int(np.ceil(cy + reach)) + 1, shape[0])
    if x1 <= x0 or y1 <= y0:
        return (0, 0, 0, 0), np.zeros((0, 0), np.float32)
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    dx, dy = xs - cx, ys - cy
    a = dx * along[0] + dy * along[1]
    c = -dx * along[1] + dy * along[0]
    spot = amplitude * np.exp(-0.5 * ((a / sigma_along_px) ** 2 + (c / sigma_across_px) ** 2))
    return (x0, y0, x1, y1), spot.astype(np.float32)


def line_kernel(direction: np.ndarray, length_px: float) -> np.ndarray:
    """A normalised kernel (sums to 1) that smears along the unit image ``direction`` over
    ``length_px`` (px), centred: a motion blur of constant speed."""
    half = int(np.ceil(0.5 * length_px)) + 1
    k = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    n = max(2, int(np.ceil(length_px)) * 2 + 1)
    t = np.linspace(-0.5 * length_px, 0.5 * length_px, n)
    x, y = half + t * direction[0], half + t * direction[1]
    ix, iy = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - ix, y - iy
    # each sample split bilinearly over its four pixels
    for ox, oy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (iy + oy, ix + ox), wt)
    return k / k.sum()


def shadow_field(rng: np.random.Generator, width: int, height: int, darkness: float) -> np.ndarray:
    """A multiplicative field (0–1) of 1–3 soft shadows: blobs and straight-edged strips.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the shapes.
    width, height : int
        Frame size (px).
    darkness : float
        Largest darkening (0–1) of a shadow's core.

    Returns
    -------
    ndarray, shape (height, width), float32
    """
    lo_w, lo_h = max(8, width // 8), max(8, height // 8)  # smooth: computed coarse, then resized
    ys, xs = np.mgrid[0:lo_h, 0:lo_w].astype(np.float32)
    xs, ys = xs / lo_w * width, ys / lo_h * height
    diag = float(np.hypot(width, height))
    field = np.ones((lo_h, lo_w), np.float32)
    for _ in range(int(rng.integers(1, 4))):
        depth = darkness * rng.uniform(0.5, 1.0)
        soft = rng.uniform(0.2, 0.7)
        a = rng.uniform(0, 2 * np.pi)
        c, s = np.cos(a), np.sin(a)
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        dx, dy = xs - cx, ys - cy
        if rng.random() < 0.6:  # an elliptical blob
            ax, ay = rng.uniform(0.1, 0.35, size=2) * diag
            rho = np.hypot((c * dx + s * dy) / ax, (-s * dx + c * dy) / ay)
            core = 1.0 - smoothstep((rho - (1 - soft)) / (2 * soft))
        else:  # a strip (an arm's shadow) with soft edges
            half = rng.uniform(0.04, 0.15) * diag
            dist = np.abs(-s * dx + c * dy)
            core = 1.0 - smoothstep((dist - half * (1 - soft)) / (2 * soft * half))
        field *= 1.0 - depth * core
    return cv2.resize(field, (width, height), interpolation=cv2.INTER_LINEAR)


def glint_flicker(time_s: float, freq_hz: np.ndarray, phase_rad: np.ndarray) -> np.ndarray:
    """Glint strength (0–1) at ``time_s`` (s): a clipped, sharpened sine per band."""
    return np.clip(np.sin(2 * np.pi * freq_hz * time_s + phase_rad), 0.0, 1.0) ** 2

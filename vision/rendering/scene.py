"""A fixed view of the phantom (camera pose, appearance, nuisances) that draws frames of the array."""

from __future__ import annotations

import cv2
import numpy as np

from tympani.vision.geometry import (
    DEFAULT_ARRAY,
    DEFAULT_PHANTOM,
    CameraPose,
    ElectrodeArray,
    Phantom,
    channel_polygon,
    entry_frame,
    entry_walls,
)
from tympani.vision.rendering.appearance import Appearance
from tympani.vision.rendering.bubbles import (
    BubbleLook,
    FreeBubble,
    bubble_ahead_of_tip,
    bubble_patch,
    channel_path,
    paste,
    random_bubble_look,
)
from tympani.vision.rendering.centreline import ArrayState
from tympani.vision.rendering.nuisances import Nuisance, gaussian_spot, glint_flicker, line_kernel, shadow_field

__all__ = ["Scene"]


class Scene:
    """A fixed view of the phantom (pose, appearance, nuisances) that draws frames.

    The static part (phantom, doubled walls, clutter, illumination and shadows, the looks of
    bubbles and glints) is computed once; each frame adds the bubbles, the array, the gripper
    and the per-frame degradations. Nuisances that are off draw no random numbers, so they do
    not shift the random draws of the others.

    Parameters
    ----------
    pose : CameraPose
    width, height : int
        Frame size (px).
    appearance : Appearance
    nuisance : Nuisance
    phantom, array : Phantom, ElectrodeArray
    rng : numpy.random.Generator
        Source of all randomness (clutter placement, noise).
    """

    SUPERSAMPLE = 4

    def __init__(
        self,
        pose: CameraPose,
        width: int = 640,
        height: int = 480,
        appearance: Appearance = Appearance(),
        nuisance: Nuisance = Nuisance(),
        *,
        phantom: Phantom = DEFAULT_PHANTOM,
        array: ElectrodeArray = DEFAULT_ARRAY,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.pose, self.width, self.height = pose, width, height
        self.appearance, self.nuisance = appearance, nuisance
        self.phantom, self.array = phantom, array
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.wall_parallax_px = self._wall_parallax()
        self.background = self._static_background()
        self.gain = self._illumination_field()
        nu = nuisance
        if nu.shadows > 0:
            self.gain = self.gain * shadow_field(self.rng, width, height, nu.shadows)
        self._path = channel_path(phantom) if nu.has_bubbles else None
        self._free_bubbles = [self._new_free_bubble() for _ in range(nu.bubbles)]
        self._tip_bubble = self._new_tip_bubble() if nu.bubble_at_tip is not None else None
        self._glint = self._new_band_glints() if nu.glints > 0 else None
        self._plate_glint = self._plate_glints() if nu.plate_glints > 0 else None
        self._grip_shadow_px = self._gripper_shadow_offset() if nu.shadows > 0 and nu.distractors else None
        self._array_shadow_px = self._array_shadow_offset() if nu.array_shadow > 0 else None

    # -- static part
    def _coverage(self, polygons_px: list[np.ndarray], bbox: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Anti-aliased coverage (0–1) of filled polygons (px), over ``bbox`` = (x0, y0, x1, y1)."""
        x0, y0, x1, y1 = bbox if bbox is not None else (0, 0, self.width, self.height)
        k = self.SUPERSAMPLE
        canvas = np.zeros(((y1 - y0) * k, (x1 - x0) * k), np.uint8)
        shift = 4
        pts = [
            np.round(((p - [x0, y0]) * k + (k - 1) / 2.0) * (1 << shift)).astype(np.int32) for p in polygons_px
        ]
        cv2.fillPoly(canvas, pts, 255, lineType=cv2.LINE_8, shift=shift)
        small = cv2.resize(canvas, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        return small.astype(np.float32) / 255.0

    def _wall_lines_px(self) -> list[np.ndarray]:
        ph = self.phantom
        outer_e, inner_e = entry_walls(ph)
        cap = np.stack([ph.inner_wall.points[-1], ph.outer_wall.points[-1]])
        lines = [outer_e, inner_e, ph.outer_wall.points, ph.inner_wall.points, cap]
        return [self.pose.to_image(line) for line in lines]

    def _line_coverage(self, lines_px: list[np.ndarray], width_px: float) -> np.ndarray:
        """Anti-aliased coverage of polylines drawn ``width_px`` wide."""
        polys = []
        for line in lines_px:
            seg = np.diff(line, axis=0)
            norm = np.linalg.norm(seg, axis=1, keepdims=True)
            good = norm[:, 0] > 1e-9
            seg, p0, p1 = seg[good] / norm[good], line[:-1][good], line[1:][good]
            off = 0.5 * width_px * np.stack([-seg[:, 1], seg[:, 0]], axis=1)
            # each segment as a quad, slightly lengthened so neighbours overlap
            ext = 0.5 * width_px * seg
            quads = np.stack([p0 - ext + off, p1 + ext + off, p1 + ext - off, p0 - ext - off], axis=1)
            polys.extend(list(quads))
        return self._coverage(polys)

    def _wall_coverage(self, shift_px: np.ndarray) -> np.ndarray:
        """Coverage of the wall lines moved by ``shift_px`` (px): centred on the channel's edge,
        or (``Appearance.wall_side`` "outside") a band as wide just outside it."""
        ap = self.appearance
        lines = [line + shift_px for line in self._wall_lines_px()]
        if ap.wall_side == "on":
            return self._line_coverage(lines, ap.wall_width_px)
        inside = self._coverage([self.pose.to_image(channel_polygon(self.phantom)) + shift_px])
        return self._line_coverage(lines, 2.0 * ap.wall_width_px) * (1.0 - inside)

    def _wall_parallax(self) -> np.ndarray | None:
        """Image displacement (px) of the walls' second copy, or None without doubled walls."""
        nu = self.nuisance
        if nu.doubled_wall_mm <= 0:
            return None
        a = nu.doubled_wall_direction_rad
        a = float(self.rng.uniform(0, 2 * np.pi)) if a is None else float(a)
        return nu.doubled_wall_mm * self.pose.px_per_mm * np.array([np.cos(a), np.sin(a)])

    def _static_background(self) -> np.ndarray:
        ap, h, w = self.appearance, self.height, self.width
        shift, contrast = self.wall_parallax_px, self.nuisance.doubled_wall_contrast
        img = np.full((h, w), ap.background, np.float32)
        if ap.wall_style in ("region", "both"):
            outline = self.pose.to_image(channel_polygon(self.phantom))
            inside = self._coverage([outline])
            img += (ap.fluid - ap.background) * inside
            if shift is not None:
                # between a wall's two edges (its side face) the level is part way between
                # fluid and background: two steps instead of one
                moved = self._coverage([outline + shift])
                img += 0.5 * contrast * (ap.fluid - ap.background) * (moved - inside)
        if ap.wall_style in ("lines", "both"):
            for move, strength in ([] if shift is None else [(shift, contrast)]) + [(np.zeros(2), 1.0)]:
                cov = strength * self._wall_coverage(move)
                img = img * (1 - cov) + ap.wall_level * cov
        if self.nuisance.distractors:
            img = self._draw_distractors(img)
        return img

    def _free_spot(self, radius_px: float, tries: int = 200) -> np.ndarray | None:
        """A random image point at least ``radius_px`` clear of the channel and its axis."""
        far = self.pose.to_image(np.array([[0.0, 0.0]]))[0]
        channel_px = self.pose.to_image(channel_polygon(self.phantom))
        origin, x_w, _ = entry_frame(self.phantom)
        axis_px = self.pose.to_image(origin[None, :] - np.linspace(0, 40, 60)[:, None] * x_w[None, :])
        keep_out = np.vstack([channel_px, axis_px, far[None, :]])
        for _ in range(tries):
            p = self.rng.uniform([radius_px, radius_px], [self.width - radius_px, self.height - radius_px])
            if np.min(np.hypot(*(keep_out - p).T)) > radius_px + 4 * self.pose.px_per_mm:
                return p
        return None

    def _draw_distractors(self, img: np.ndarray) -> np.ndarray:
        ppm = self.pose.px_per_mm
        for i in range(self.nuisance.distractors):
            if i % 2 == 0:  # a screw head with a slot
                rad = self.rng.uniform(1.0, 2.0) * ppm
                c = self._free_spot(rad)
                if c is None:
                    continue
                level = self.rng.uniform(40, 120)
                ang = np.linspace(0, 2 * np.pi, 48, endpoint=False)
                disc = c + rad * np.stack([np.cos(ang), np.sin(ang)], axis=1)
                cov = self._coverage([disc])
                img = img * (1 - cov) + level * cov
                a = self.rng.uniform(0, np.pi)
                d = np.array([np.cos(a), np.sin(a)])
                slot = np.stack([c - rad * 0.8 * d, c + rad * 0.8 * d])
                cov = self._line_coverage([slot], max(1.5, 0.15 * rad))
                img = img * (1 - cov) + (level + 80) * cov
            else:  # a ruler: a bright strip with tick marks
                c = self._free_spot(3 * ppm)
                if c is None:
                    continue
                a = self.rng.uniform(0, np.pi)
                d, nrm = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
                length = self.rng.uniform(4, 8) * ppm
                strip = np.stack([c - length * d - ppm * nrm, c + length * d - ppm * nrm,
                                  c + length * d + ppm * nrm, c - length * d + ppm * nrm])
                cov = self._coverage([strip])
                img = img * (1 - cov) + 235.0 * cov
                ticks = [np.stack([c + t * d - ppm * nrm, c + t * d - (0.3 + 0.3 * (k % 5 == 0)) * ppm * nrm])
                         for k, t in enumerate(np.arange(-length, length, ppm))]
                cov = self._line_coverage(ticks, 1.2)
                img = img * (1 - cov) + 40.0 * cov
        return img

    def _illumination_field(self) -> np.ndarray:
        amp = self.nuisance.illumination
        if amp <= 0:
            return np.ones((self.height, self.width), np.float32)
        yy, xx = np.mgrid[0 : self.height, 0 : self.width].astype(np.float32)
        xx, yy = xx / self.width - 0.5, yy / self.height - 0.5
        a = self.rng.uniform(0, 2 * np.pi)
        cx, cy = self.rng.uniform(-0.3, 0.3, size=2)
        ramp = np.cos(a) * xx + np.sin(a) * yy
        vignette = (xx - cx) ** 2 + (yy - cy) ** 2
        field = 1.0 + amp * (1.2 * ramp - 1.5 * vignette + 0.2)
        return np.clip(field, 0.2, 2.0).astype(np.float32)

    # -- per frame
    def array_layers(self, state: ArrayState) -> tuple[np.ndarray, np.ndarray]:
        """Coverage (0–1) of the array body and of its bands in the frame."""
        body, bands, _ = self._array_layers(state)
        return body, bands

    def _array_layers(
        self, state: ArrayState, pad_px: int = 0
    ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int] | None]:
        """Coverage (0–1) of the body and the bands, and the pixel box (x0, y0, x1, y1) they
        were drawn in (the array's box grown by ``pad_px``; None when off the frame)."""
        c, s, rad = state.centreline_mm, state.s_mm, state.radius_mm.copy()
        cap = s < rad[0]  # rounded tip: a half disc whose apex is the tip point
        rad[cap] = np.sqrt(np.maximum(rad[0] ** 2 - (rad[0] - s[cap]) ** 2, 0.0))
        tangent = np.gradient(c, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        nrm = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        left, right = c + rad[:, None] * nrm, c - rad[:, None] * nrm
        body = self.pose.to_image(np.vstack([left, right[::-1]]))
        x0, y0 = np.floor(body.min(axis=0)).astype(int) - 2 - pad_px
        x1, y1 = np.ceil(body.max(axis=0)).astype(int) + 3 + pad_px
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, self.width), min(y1, self.height)
        full_body = np.zeros((self.height, self.width), np.float32)
        full_bands = np.zeros_like(full_body)
        if x1 <= x0 or y1 <= y0:
            return full_body, full_bands, None
        bbox = (x0, y0, x1, y1)
        full_body[y0:y1, x0:x1] = self._coverage([body], bbox)
        bands = []
        for a, b in self.array.band_intervals():
            sel = (s >= a) & (s <= b)
            if sel.sum() >= 2:
                bands.append(self.pose.to_image(np.vstack([left[sel], right[sel][::-1]])))
        if bands:
            full_bands[y0:y1, x0:x1] = self._coverage(bands, bbox)
        return full_body, full_bands, bbox

    def _gripper(self, state: ArrayState) -> list[np.ndarray]:
        """The gripper's jaw (px): it holds the array's base, reaching ``gripper_overlap_mm``
        over the array's straight part but never closer than 0.5 mm to the entry channel."""
        base = state.centreline_mm[-1]
        origin, x_w, nrm = entry_frame(self.phantom)
        front = base
        overlap = self.nuisance.gripper_overlap_mm
        if overlap > 0:
            along = float((base - origin) @ x_w)  # negative: behind the entry's end
            limit = -(self.phantom.entry_length_mm + 0.5)
            front = base + (min(along + overlap, max(limit, along)) - along) * x_w
        jaw = np.stack([front + 1.5 * nrm, base - 4 * x_w + 1.5 * nrm, base - 4 * x_w - 1.5 * nrm, front - 1.5 * nrm])
        return [self.pose.to_image(jaw)]

    def _image_direction(self, v_mm: np.ndarray) -> np.ndarray:
        """Unit image direction of the phantom-frame direction ``v_mm``."""
        d = self.pose.to_image(np.stack([np.zeros(2), v_mm]))
        d = d[1] - d[0]
        return d / np.linalg.norm(d)

    def _bbox(self, poly_px: np.ndarray, pad_px: int) -> tuple[int, int, int, int] | None:
        """Pixel box (x0, y0, x1, y1) of a polygon grown by ``pad_px`` and clipped to the frame."""
        x0, y0 = np.maximum(np.floor(poly_px.min(axis=0)).astype(int) - 2 - pad_px, 0)
        x1, y1 = np.minimum(np.ceil(poly_px.max(axis=0)).astype(int) + 3 + pad_px, [self.width, self.height])
        return (int(x0), int(y0), int(x1), int(y1)) if x1 > x0 and y1 > y0 else None

    def _gripper_shadow_offset(self) -> np.ndarray:
        """Image offset (px) of the gripper's shadow: 0.8–2.5 mm in a random direction."""
        a = self.rng.uniform(0, 2 * np.pi)
        return self.rng.uniform(0.8, 2.5) * self.pose.px_per_mm * np.array([np.cos(a), np.sin(a)])

    def _array_shadow_offset(self) -> np.ndarray:
        """Image offset (px) of the array's own shadow: ``array_shadow_mm`` in the direction
        ``array_shadow_direction_rad`` (random when None)."""
        nu = self.nuisance
        a = nu.array_shadow_direction_rad
        a = float(self.rng.uniform(0, 2 * np.pi)) if a is None else float(a)
        return nu.array_shadow_mm * self.pose.px_per_mm * np.array([np.cos(a), np.sin(a)])

    def _with_array_shadow(self, img: np.ndarray, body: np.ndarray, bbox: tuple[int, int, int, int]) -> np.ndarray:
        """A copy of ``img`` darkened by the array's shadow: its body's coverage ``body`` (drawn
        within ``bbox``) moved by the shadow's offset and softened by a third of a pixel per
        pixel of offset (at least 0.7 px); only the region the shadow can reach is touched."""
        dx, dy = (float(v) for v in self._array_shadow_px)
        sigma = max(0.7, np.hypot(dx, dy) / 3.0)
        x0, y0, x1, y1 = bbox
        pad = int(np.ceil(abs(dx) + abs(dy) + 3 * sigma)) + 1
        x0, y0 = max(x0 - pad, 0), max(y0 - pad, 0)
        x1, y1 = min(x1 + pad, self.width), min(y1 + pad, self.height)
        moved = cv2.warpAffine(body[y0:y1, x0:x1], np.float32([[1, 0, dx], [0, 1, dy]]), (x1 - x0, y1 - y0))
        out = img.copy()  # img may be the shared background
        out[y0:y1, x0:x1] *= 1.0 - self.nuisance.array_shadow * np.clip(cv2.GaussianBlur(moved, (0, 0), sigma), 0, 1)
        return out

    def _draw_gripper(self, img: np.ndarray, state: ArrayState) -> np.ndarray:
        """``img`` with the gripper's soft shadow and the gripper (smeared when it moves) on it."""
        nu = self.nuisance
        jaw = self._gripper(state)[0]
        if self._grip_shadow_px is not None:
            sigma = max(0.4 * self.pose.px_per_mm, 1.0)
            shadow = jaw + self._grip_shadow_px
            box = self._bbox(shadow, int(np.ceil(3 * sigma)))
            if box is not None:
                x0, y0, x1, y1 = box
                cov = cv2.GaussianBlur(self._coverage([shadow], box), (0, 0), sigma)
                img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - nu.shadows * cov)
        pad = int(np.ceil(0.5 * nu.motion_blur_px)) + 1 if nu.motion_blur_px > 0 else 0
        box = self._bbox(jaw, pad)
        if box is not None:
            x0, y0, x1, y1 = box
            grip = self._coverage([jaw], box)
            if pad:  # the gripper moves along the insertion axis
                d = self._image_direction(entry_frame(self.phantom)[1])
                grip = cv2.filter2D(grip, -1, line_kernel(d, nu.motion_blur_px), borderType=cv2.BORDER_CONSTANT)
            img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - grip) + 50.0 * grip
        return img

    # -- bubbles
    def _wall_mm(self) -> float:
        """Half a wall line (mm) and a little more: bubbles keep clear of the wall lines."""
        return 0.5 * self.appearance.wall_width_px / self.pose.px_per_mm + 0.02

    def _bubble_radius(self) -> float:
        """``bubble_radius_mm``, or a radius (mm) drawn log-uniformly from 0.15 mm to the widest
        half channel."""
        if self.nuisance.bubble_radius_mm is not None:
            return float(self.nuisance.bubble_radius_mm)
        return float(np.exp(self.rng.uniform(np.log(0.15), np.log(0.5 * self.phantom.width_max_mm))))

    def _new_free_bubble(self) -> FreeBubble:
        radius = self._bubble_radius()
        speed = self.nuisance.bubble_drift_mm_s * self.rng.uniform(0.5, 1.5) * self.rng.choice([-1.0, 1.0])
        return FreeBubble(
            u0_mm=float(self.rng.uniform(0.0, self._path.u_mm[-1])),
            lateral=float(self.rng.uniform(-1.0, 1.0)),
            radius_mm=radius,
            speed_mm_s=float(speed),
            look=random_bubble_look(self.rng, self.appearance.fluid, float(self.rng.uniform(0, 2 * np.pi))),
        )

    def _new_tip_bubble(self) -> tuple[float, BubbleLook]:
        radius = self._bubble_radius()
        return radius, random_bubble_look(self.rng, self.appearance.fluid, float(self.rng.uniform(0, 2 * np.pi)))

    def tip_bubble(self, state: ArrayState) -> tuple[np.ndarray, float] | None:
        """Centre (mm, phantom frame) and radius (mm) of the bubble drawn ahead of the array's
        tip in ``state``; None when there is none (off, tip outside the channel, no room)."""
        if self._tip_bubble is None:
            return None
        return bubble_ahead_of_tip(state, self._tip_bubble[0], float(self.nuisance.bubble_at_tip), self._path,
                                   phantom=self.phantom, wall_mm=self._wall_mm())

    def bubbles_at(self, state: ArrayState, time_s: float) -> list[tuple[np.ndarray, float, BubbleLook]]:
        """Every bubble drawn at ``time_s`` (s): centre (mm), radius (mm) and look."""
        wall = self._wall_mm()
        out = [(*b.at(time_s, self._path, wall), b.look) for b in self._free_bubbles]
        tip = self.tip_bubble(state)
        if tip is not None:
            out.append((tip[0], tip[1], self._tip_bubble[1]))
        return out

    def _with_bubbles(self, state: ArrayState, time_s: float) -> np.ndarray:
        """The static background with the bubbles at ``time_s`` (s) on it."""
        img = self.background.copy()
        for centre, radius, look in self.bubbles_at(state, time_s):
            paste(img, *bubble_patch(self.pose.to_image(centre)[0], radius * self.pose.px_per_mm, look))
        return img

    # -- glints
    def _new_band_glints(self) -> dict[str, np.ndarray | float]:
        """Per band: flicker frequency (Hz), phase (rad) and peak (0.5–1); the lit side (-0.5..0.5
        of the radius, one lamp for all bands)."""
        n = self.array.n_bands
        return dict(freq=self.rng.uniform(1.5, 7.0, n), phase=self.rng.uniform(0, 2 * np.pi, n),
                    peak=self.rng.uniform(0.5, 1.0, n), side=float(self.rng.uniform(-0.5, 0.5)))

    def _band_glints(
        self, state: ArrayState, bands: np.ndarray, bbox: tuple[int, int, int, int], time_s: float
    ) -> np.ndarray:
        """Additive grey levels of the band glints at ``time_s`` (s): a core kept on the bands'
        coverage and a weaker bloom around it, inside the array's pixel box ``bbox``."""
        g, ppm = self._glint, self.pose.px_per_mm
        out = np.zeros((self.height, self.width), np.float32)
        mids = self.array.band_intervals().mean(axis=1)
        strength = self.nuisance.glints * g["peak"] * glint_flicker(time_s, g["freq"], g["phase"])
        keep = (mids < state.s_mm[-1] - 0.05) & (strength > 1e-3)
        if not keep.any():
            return out
        mids, strength = mids[keep], strength[keep]
        c, s = state.centreline_mm, state.s_mm

        def at(q: np.ndarray) -> np.ndarray:
            return np.stack([np.interp(q, s, c[:, 0]), np.interp(q, s, c[:, 1])], axis=1)

        tangent = at(mids - 0.05) - at(mids + 0.05)  # apical
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        centre = self.pose.to_image(at(mids) + (g["side"] * self.array.radius(mids))[:, None] * normal)
        along = self.pose.to_image(at(mids) + tangent) - self.pose.to_image(at(mids))
        along /= np.linalg.norm(along, axis=1, keepdims=True)
        peak = max(330.0 - self.appearance.band_level, 100.0)  # at full strength a glint saturates
        sig_along = max(0.3 * self.array.band_length_mm * ppm, 0.8)
        x0, y0, x1, y1 = bbox
        h, w = y1 - y0, x1 - x0
        core, bloom = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
        centre = centre - [x0, y0]
        for k in range(len(mids)):
            sig_across = max(0.15 * float(self.array.radius(mids[k])) * ppm, 0.6)
            amp = float(strength[k] * peak)
            (a0, b0, a1, b1), spot = gaussian_spot((h, w), centre[k], along[k], sig_along, sig_across, amp)
            core[b0:b1, a0:a1] += spot
            # a saturated glint blooms past the band onto the body and the fluid
            (a0, b0, a1, b1), spot = gaussian_spot((h, w), centre[k], along[k], 2.5 * sig_along,
                                                   3.0 * sig_across, 0.5 * amp)
            bloom[b0:b1, a0:a1] += spot
        out[y0:y1, x0:x1] = core * bands[y0:y1, x0:x1] + bloom
        return out

    def _plate_glints(self) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
        """Static lamp reflections on the plate (0.15–0.8 mm spots): pixel boxes and the grey
        levels they add."""
        ppm = self.pose.px_per_mm
        out = []
        for _ in range(self.nuisance.plate_glints):
            centre = self.rng.uniform([0, 0], [self.width, self.height])
            a = self.rng.uniform(0, np.pi)
            sig = self.rng.uniform(0.15, 0.8) * ppm
            out.append(gaussian_spot((self.height, self.width), centre, np.array([np.cos(a), np.sin(a)]), sig,
                                     sig / self.rng.uniform(1.0, 3.0), float(self.rng.uniform(60, 220))))
        return out

    # -- motion blur
    def _motion_field(self, state: ArrayState, bbox: tuple[int, int, int, int]) -> np.ndarray:
        """Unit image direction (an (h, w, 2) image of x, y over ``bbox``) in which the array
        moves (apically along itself), near the array; zero elsewhere."""
        x0, y0, x1, y1 = bbox
        length = self.nuisance.motion_blur_px
        c = self.pose.to_image(state.centreline_mm)
        spacing = float(np.median(np.hypot(*np.diff(c, axis=0).T)))
        step = max(1, int(round(6.0 / max(spacing, 1e-6))))  # vertices about 6 px apart
        p = c[np.unique(np.r_[np.arange(0, len(c), step), len(c) - 1])]
        t = -np.gradient(p, axis=0)  # the centreline runs tip to base: apical is backwards
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
        reach = 0.5 * length + 3.0  # the smear reaches ahead of the tip
        p = np.vstack([p[0] + reach * t[0], p])
        t = np.vstack([t[0], t])
        thick = int(np.ceil(2 * state.radius_mm.max() * self.pose.px_per_mm + length + 6))
        field = np.zeros((y1 - y0, x1 - x0, 2), np.float32)
        q = np.round((p - [x0, y0]) * 16).astype(np.int32)
        for j in range(len(p) - 1):
            a, b = (int(q[j, 0]), int(q[j, 1])), (int(q[j + 1, 0]), int(q[j + 1, 1]))
            cv2.line(field, a, b, (float(t[j, 0]), float(t[j, 1])), thick, cv2.LINE_8, 4)
        return field

    def _motion_blurred(
        self, state: ArrayState, bbox: tuple[int, int, int, int], layers: list[np.ndarray | None]
    ) -> list[np.ndarray | None]:
        """The array's layers averaged over the exposure: each pixel near the array samples the
        layers along the array's local direction, ``motion_blur_px`` long and centred on it.
        The layers are overwritten."""
        x0, y0, x1, y1 = bbox
        length = self.nuisance.motion_blur_px
        field = self._motion_field(state, bbox)
        dx, dy = field[..., 0], field[..., 1]
        ys, xs = np.nonzero(np.any(field != 0, axis=2))
        present = [k for k, layer in enumerate(layers) if layer is not None]
        if len(ys) == 0 or not present:
            return layers
        stack = np.dstack([layers[k][y0:y1, x0:x1] for k in present])
        # only the pixels near the array are resampled, laid out as a block of 256-wide rows
        # (OpenCV's maps must stay under 32767 px a side)
        m = len(ys)
        rows = -(-m // 256)

        def block(v: np.ndarray) -> np.ndarray:
            return np.pad(v.astype(np.float32), (0, rows * 256 - m)).reshape(rows, 256)

        ddx, ddy = block(dx[ys, xs]), block(dy[ys, xs])
        fx, fy = block(xs), block(ys)
        n = int(np.clip(np.ceil(length) + 1, 3, 17))
        acc = np.zeros((rows * 256, len(present)), np.float32)
        for u in np.linspace(-0.5 * length, 0.5 * length, n, dtype=np.float32):
            acc += cv2.remap(stack, fx + u * ddx, fy + u * ddy, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0).reshape(rows * 256, len(present))
        acc = acc[:m] / n
        for i, k in enumerate(present):
            layers[k][y0 + ys, x0 + xs] = acc[:, i]
        return layers

    # -- per frame
    def render(self, state: ArrayState, time_s: float = 0.0) -> np.ndarray:
        """One BGR uint8 frame with the array in ``state`` at ``time_s`` (s).

        The time moves what changes by itself during a video (drifting bubbles, flickering
        glints); with those nuisances off it changes nothing.
        """
        ap, nu = self.appearance, self.nuisance
        pad = int(np.ceil(0.5 * nu.motion_blur_px)) + 4 if nu.motion_blur_px > 0 else 0
        body, bands, bbox = self._array_layers(state, pad)
        glint = self._band_glints(state, bands, bbox, time_s) if self._glint is not None and bbox else None
        if nu.motion_blur_px > 0 and bbox is not None:
            body, bands, glint = self._motion_blurred(state, bbox, [body, bands, glint])
        # bubbles lie under the array: they may sit against it but never hide any of it
        img = self._with_bubbles(state, time_s) if nu.has_bubbles else self.background
        if self._array_shadow_px is not None and bbox is not None:  # on the floor, under the array
            img = self._with_array_shadow(img, body, bbox)
        img = img * (1 - body) + ap.array_level * body
        img = img * (1 - bands) + ap.band_level * bands
        if glint is not None:
            x0, y0, x1, y1 = bbox
            img[y0:y1, x0:x1] += glint[y0:y1, x0:x1]
        if nu.distractors:
            img = self._draw_gripper(img, state)
        gain = self.gain
        if nu.flicker > 0:
            gain = gain * float(1.0 + nu.flicker * self.rng.standard_normal())
        img = img * gain
        if self._plate_glint is not None:  # lamp reflections on the plate's top: not shaded
            for (x0, y0, x1, y1), spot in self._plate_glint:
                img[y0:y1, x0:x1] += spot
        if nu.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), nu.blur_sigma_px)
        if nu.noise_sigma > 0:
            img = img + nu.noise_sigma * self.rng.standard_normal(img.shape, dtype=np.float32)
        grey = np.clip(img, 0, 255)
        bgr = np.clip(grey[..., None] * np.asarray(ap.tint, np.float32), 0, 255).round().astype(np.uint8)
        if nu.jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(nu.jpeg_quality)])
            bgr = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        return bgr

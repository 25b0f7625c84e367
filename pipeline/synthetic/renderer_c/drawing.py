"""Renderer C: drawing a frame (appearance, array, nuisances) at twice the resolution, then the camera's degradations."""

from __future__ import annotations

import math
from dataclasses import asdict

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import brentq

from tympani.pipeline.synthetic.renderer_c.geometry import (
    NUISANCE_KEYS,
    SS,
    ArrayConfig,
    ArrayModel,
    Phantom,
    measure_truth,
    sample_pose,
)


# ----------------------------------------------------------------------------------------------
# drawing helpers (all at SS x resolution, float images in [0, 1], BGR)
# ----------------------------------------------------------------------------------------------
def _lum(c):
    return 0.114 * c[0] + 0.587 * c[1] + 0.299 * c[2]


def _colour(lum, tint):
    tint = np.asarray(tint, float)
    return np.clip(lum * tint / max(_lum(tint), 1e-6), 0.0, 1.0).astype(np.float32)


def _fix(pts_ss):
    return np.round(np.asarray(pts_ss) * 16).astype(np.int32).reshape(-1, 1, 2)


def _fill_mask(shape, polys):
    m = np.zeros(shape, np.uint8)
    cv2.fillPoly(m, [_fix(p) for p in polys], 255, cv2.LINE_AA, 4)
    return m.astype(np.float32) / 255.0


def _line_mask(shape, lines, thick, closed=False):
    m = np.zeros(shape, np.uint8)
    cv2.polylines(m, [_fix(p) for p in lines], closed, 255, max(1, int(thick)), cv2.LINE_AA, 4)
    return m.astype(np.float32) / 255.0


def _circle_mask(shape, c, r, thick=-1):
    m = np.zeros(shape, np.uint8)
    cv2.circle(m, (int(round(c[0] * 16)), int(round(c[1] * 16))), max(1, int(round(r * 16))), 255,
               thick if thick < 0 else max(1, int(thick)), cv2.LINE_AA, 4)
    return m.astype(np.float32) / 255.0


def _mix(img, col, alpha):
    """img <- img * (1 - alpha) + col * alpha, in place, on the bounding box of alpha > 0."""
    rows = np.flatnonzero(alpha.any(axis=1))
    if len(rows) == 0:
        return img
    cols = np.flatnonzero(alpha.any(axis=0))
    sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    a = alpha[sl][..., None]
    col = np.asarray(col, np.float32)
    if col.ndim == 3:
        col = col[sl]
    roi = img[sl]
    roi *= (1.0 - a)
    roi += a * col
    return img


def _soft(mask, sigma_px):
    """Gaussian blur of a large mask computed at reduced resolution (fast, smooth)."""
    H, W = mask.shape
    f = max(1, int(sigma_px // 4))
    if f == 1:
        return cv2.GaussianBlur(mask, (0, 0), sigma_px)
    small = cv2.resize(mask, (max(1, W // f), max(1, H // f)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma_px / f)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR)


def _spot(img, x, y, sx, sy, ang, amp, colour=(1.0, 1.0, 1.0)):
    """Screen-blend an anisotropic Gaussian highlight (SS pixel units)."""
    H, W = img.shape[:2]
    R = int(math.ceil(3.2 * max(sx, sy))) + 1
    x0, x1 = max(0, int(x) - R), min(W, int(x) + R + 1)
    y0, y1 = max(0, int(y) - R), min(H, int(y) + R + 1)
    if x0 >= x1 or y0 >= y1:
        return
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    dx, dy = xx - x, yy - y
    c, s = math.cos(ang), math.sin(ang)
    a = (c * dx + s * dy) / max(sx, 1e-3)
    b = (-s * dx + c * dy) / max(sy, 1e-3)
    g = (amp * np.exp(-0.5 * (a * a + b * b)))[..., None]
    roi = img[y0:y1, x0:x1]
    roi[:] = 1.0 - (1.0 - roi) * (1.0 - g * np.asarray(colour, np.float32))


def _line_kernel(length, angle):
    L = max(1.0, float(length))
    n = int(math.ceil(L)) | 1
    k = np.zeros((n + 2, n + 2), np.uint8)
    c = (n + 1) / 2
    dx, dy = 0.5 * (L - 1) * math.cos(angle), 0.5 * (L - 1) * math.sin(angle)
    p0 = (int(round((c - dx) * 16)), int(round((c - dy) * 16)))
    p1 = (int(round((c + dx) * 16)), int(round((c + dy) * 16)))
    cv2.line(k, p0, p1, 255, 1, cv2.LINE_AA, 4)
    k = k.astype(np.float32)
    return k / k.sum()


# ----------------------------------------------------------------------------------------------
# the renderer
# ----------------------------------------------------------------------------------------------
_FLUID_TINTS = [(1.0, 1.0, 1.0), (1.08, 1.03, 0.92), (1.25, 1.05, 0.8), (0.85, 0.95, 1.2),
                (1.0, 1.12, 0.9), (1.15, 1.15, 0.9), (0.92, 1.0, 1.08)]


class Renderer:
    def __init__(self, seed, n_frames, size, px_per_mm, speed_mm_s, fps, depth_range_mm, nuisance):
        self.W, self.H = int(size[0]), int(size[1])
        self.H2, self.W2 = self.H * SS, self.W * SS
        self.fps, self.speed = float(fps), float(speed_mm_s)
        self.n = int(n_frames)
        nz = {k: 0.0 for k in NUISANCE_KEYS}
        for k, v in (nuisance or {}).items():
            if k not in nz:
                raise ValueError(f"unknown nuisance {k!r}; known: {', '.join(NUISANCE_KEYS)}")
            v = float(v)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"nuisance {k!r} strength {v} outside [0, 1]")
            nz[k] = v
        self.nz = nz
        ss = np.random.SeedSequence(int(seed))
        kids = ss.spawn(4 + len(NUISANCE_KEYS))
        self.rng_pose, self.rng_shape, self.rng_app, self.rng_frame = (
            np.random.default_rng(k) for k in kids[:4])
        self.rng_nz = {k: np.random.default_rng(c) for k, c in zip(NUISANCE_KEYS, kids[4:])}

        self.ph = Phantom()
        self.acfg = ArrayConfig()
        self.model = ArrayModel(self.ph, self.acfg, self.rng_shape)
        self.pose, self.pose_meta = sample_pose(self.ph, (self.W, self.H), px_per_mm, self.rng_pose)
        d0, d1 = map(float, depth_range_mm)
        if self.n < 1 or d1 < d0:
            raise ValueError("need n_frames >= 1 and depth_range_mm[1] >= depth_range_mm[0]")
        self.depths = np.linspace(d0, d1, self.n) if self.n > 1 else np.array([d0])
        self.times = np.arange(self.n) / self.fps
        self.shapes = [self.model.shape(D) for D in self.depths]
        self.truths = [measure_truth(self.ph, sh, self.acfg.contact_tol_mm, self.model.rho0)
                       for sh in self.shapes]
        for D, t in zip(self.depths, self.truths):
            if t["min_gap_outer_mm"] < -1e-3 or t["min_gap_inner_mm"] < -1e-3:
                raise RuntimeError(f"array leaves the channel at depth {D:.3f} mm")
        self._choose_appearance()
        self._plan_nuisances()
        self._build_static()

    # -- coordinates ---------------------------------------------------------------------------
    def ss(self, pts_mm):
        return self.pose.to_px(pts_mm) * SS + (SS - 1) / 2.0

    def ss_from_px(self, px):
        return np.asarray(px, float) * SS + (SS - 1) / 2.0

    @property
    def spx(self):  # SS pixels per mm
        return self.pose.px_per_mm * SS

    # -- appearance ----------------------------------------------------------------------------
    def _tint(self, rng, amount):
        if self.gray:
            return np.ones(3)
        return 1.0 + rng.uniform(-amount, amount, 3)

    def _choose_appearance(self):
        r = self.rng_app
        self.gray = bool(r.random() < 0.35)
        a = {}
        a["gray"] = self.gray
        a["bg_lum"] = r.uniform(0.15, 0.85)
        a["bg_tint"] = self._tint(r, 0.25)
        a["bg_lf_amp"] = r.uniform(0.02, 0.14)
        a["bg_hf_amp"] = r.uniform(0.0, 0.04)
        a["bg_grid"] = bool(r.random() < 0.3)
        a["plate_gain"] = r.uniform(0.85, 1.2)
        a["plate_off"] = r.uniform(-0.04, 0.1)
        plate_lum = float(np.clip(a["bg_lum"] * a["plate_gain"] + a["plate_off"], 0.1, 0.95))
        a["plate_lum"] = plate_lum
        a["wall_mode"] = str(r.choice(["lines", "region", "both"], p=[0.4, 0.25, 0.35]))
        if a["wall_mode"] == "lines":
            fl = plate_lum + r.uniform(-0.04, 0.04)
        else:
            sign = 1.0 if r.random() < 0.55 else -1.0
            fl = plate_lum + sign * r.uniform(0.08, 0.3)
        a["fluid_lum"] = fl = float(np.clip(fl, 0.38, 0.95))
        ft = _FLUID_TINTS[int(r.integers(len(_FLUID_TINTS)))]
        a["fluid_tint"] = np.ones(3) if self.gray else np.asarray(ft) * self._tint(r, 0.05)
        a["line_thick_ss"] = int(r.integers(1, 7))
        if a["wall_mode"] == "region":
            a["line_alpha"] = float(r.choice([0.0, r.uniform(0.1, 0.3)]))
        else:
            a["line_alpha"] = r.uniform(0.6, 1.0)
        if r.random() < 0.65:
            a["line_lum"] = fl * r.uniform(0.15, 0.6)
        else:
            a["line_lum"] = min(1.0, fl + r.uniform(0.15, 0.4))
        a["line_tint"] = self._tint(r, 0.1)
        a["array_lum"] = fl * r.uniform(0.18, 0.62)
        a["array_tint"] = self._tint(r, 0.12)
        a["array_edge"] = r.uniform(0.55, 0.95)
        a["array_core"] = r.uniform(1.0, 1.35)
        a["band_lum"] = r.uniform(max(a["array_lum"] + 0.18, 0.35), 1.0)
        a["band_tint"] = np.ones(3) if self.gray else np.asarray(
            [(1.0, 1.0, 1.0), (0.85, 1.0, 1.15), (1.05, 1.0, 0.95)][int(r.integers(3))])
        a["lead_diam"] = r.uniform(0.6, 1.0)
        a["band_pitch"] = r.uniform(0.9, 1.45)
        a["band_len"] = r.uniform(0.3, 0.5)
        a["band_first"] = r.uniform(0.35, 0.75)
        a["light_dir"] = r.uniform(-math.pi, math.pi)
        self.app = a
        cfg = self.acfg
        self.bands = [(a["band_first"] + k * a["band_pitch"],
                       a["band_first"] + k * a["band_pitch"] + a["band_len"])
                      for k in range(cfg.n_bands)]

    # -- nuisance planning (positions fixed per video) -----------------------------------------
    def _plan_nuisances(self):
        nz, ph = self.nz, self.ph
        # doubled walls
        s = nz["doubled_walls"]
        r = self.rng_nz["doubled_walls"]
        self.dbl = None
        if s > 0:
            ang = r.uniform(-math.pi, math.pi)
            par_mm = r.uniform(0.1, 0.1 + 0.4 * s)
            self.dbl = {"parallax_mm": par_mm, "direction_rad_image": ang,
                        "offset_px": [par_mm * self.pose.px_per_mm * math.cos(ang),
                                      par_mm * self.pose.px_per_mm * math.sin(ang)],
                        "contrast": (0.3 + 0.7 * s) * r.uniform(0.6, 1.0),
                        "opposite_polarity": bool(r.random() < 0.25)}
        # bubbles
        self._plan_bubbles()
        # gripper
        s = nz["gripper"]
        r = self.rng_nz["gripper"]
        self.grip = None
        if s > 0:
            self.grip = {"margin_mm": r.uniform(0.3, 1.5) + (1.0 - s) * r.uniform(0.0, 4.0),
                         "jaw_len": r.uniform(2.0, 5.0), "jaw_w": r.uniform(2.5, 6.0) * (0.7 + 0.3 * s),
                         "arm_w": r.uniform(4.0, 10.0), "arm_angle": r.uniform(-0.7, 0.7),
                         "arm_off": r.uniform(-1.5, 1.5),
                         "lum": float(r.choice([r.uniform(0.06, 0.25), r.uniform(0.35, 0.7)])),
                         "tint": self._tint(r, 0.08),
                         "shadow_dir": r.uniform(-math.pi, math.pi),
                         "shadow_len_mm": r.uniform(0.5, 2.5),
                         "shadow_blur_mm": r.uniform(0.4, 1.5),
                         "shadow_depth": s * r.uniform(0.3, 0.6)}
        if self.grip is not None:  # the gripper stays outside the channel (shrink if needed)
            chan = np.zeros((self.H, self.W), np.uint8)
            cv2.fillPoly(chan, [np.round(self.pose.to_px(ph.channel_polygon)).astype(np.int32).reshape(-1, 1, 2)], 255)
            for _ in range(12):
                gm = np.zeros_like(chan)
                for p in self._gripper_polys(self.n - 1):
                    cv2.fillPoly(gm, [np.round(self.pose.to_px(p)).astype(np.int32).reshape(-1, 1, 2)], 255)
                if not np.any((gm > 0) & (chan > 0)):
                    break
                self.grip["arm_w"] *= 0.8
                self.grip["jaw_w"] *= 0.9
                self.grip["margin_mm"] += 0.3
        # motion blur
        s = nz["motion_blur"]
        r = self.rng_nz["motion_blur"]
        self.blur = None
        if s > 0:
            self.blur = {"mode": str(r.choice(["array", "frame"])), "length_px": s * r.uniform(4.0, 14.0)}
        # shadows / illumination
        s = nz["shadows"]
        r = self.rng_nz["shadows"]
        self.light = None
        if s > 0:
            blobs = []
            for _ in range(1 + int(round(3 * s * r.random()))):
                blobs.append((r.uniform(0, self.W), r.uniform(0, self.H), r.uniform(2, 9) * self.pose.px_per_mm,
                              r.uniform(1, 5) * self.pose.px_per_mm, r.uniform(0, math.pi),
                              s * r.uniform(0.2, 0.6)))
            self.light = {"grad": s * r.uniform(0.1, 0.5), "grad_dir": r.uniform(-math.pi, math.pi),
                          "vignette": s * r.uniform(0.1, 0.4), "blobs": blobs,
                          "moving": (r.uniform(-2, 2, 2) * self.pose.px_per_mm, r.uniform(0, self.W),
                                     r.uniform(0, self.H), r.uniform(3, 8) * self.pose.px_per_mm,
                                     s * r.uniform(0.15, 0.45)) if s >= 0.3 else None,
                          "flicker": s * r.uniform(0.04, 0.12), "flicker_hz": r.uniform(3.0, 12.0),
                          "flicker_phase": r.uniform(0, 2 * math.pi)}
        # glints elsewhere (static positions, flicker per frame)
        s = nz["glints"]
        r = self.rng_nz["glints"]
        self.glints_static = []
        if s > 0:
            walls = np.vstack([ph.outer_wall, ph.inner_wall])
            for _ in range(int(round(s * r.uniform(2, 9)))):
                k = int(r.integers(1, len(walls) - 1))
                t = walls[k + 1] - walls[k - 1]
                self.glints_static.append((walls[k], math.atan2(-t[1], t[0]), r.uniform(0.3, 1.0)))

    def _plan_bubbles(self):
        s = self.nz["bubbles"]
        r = self.rng_nz["bubbles"]
        self.bub_plan = []
        self.tip_bubble = None
        if s <= 0:
            return
        ph = self.ph
        sig_first = self.shapes[0]["meta"]["sig_a"]
        sig_last = self.shapes[-1]["meta"]["sig_a"]
        for _ in range(int(round(s * r.uniform(1.0, 6.0)))):
            sig0 = r.uniform(sig_first + 0.5, min(ph.total_sigma - 3.0, sig_last + 8.0))
            th = ph.theta_of_sigma(sig0)
            half = float(ph.width(th) / 2)
            self.bub_plan.append({"sig0": sig0, "R": half * r.uniform(0.25, 0.9),
                                  "v_mm_s": float(r.choice([0.0, r.uniform(-0.5, 1.5)])),
                                  "lat": r.uniform(-1, 1), "contrast": 0.5 + 0.5 * s * r.random()})
        if s >= 0.5:
            self.tip_bubble = {"gap_mm": 0.0 if r.random() < 0.5 else r.uniform(0.1, 1.0),
                               "Rfrac": r.uniform(0.5, 0.95), "contrast": 0.6 + 0.4 * r.random()}
        self.bub_look = {"in_gain": r.uniform(0.1, 0.35), "rim_frac": r.uniform(0.1, 0.28),
                         "rim_lum": r.uniform(0.1, 0.5), "hl": bool(r.random() < 0.7)}

    # -- bubble placement per frame -------------------------------------------------------------
    def _bubble_centre(self, sig, R, lat):
        th = self.ph.theta_of_sigma(np.array([sig]))
        p, _, n = self.ph.frame(th)
        half = float(self.ph.width(th)[0] / 2)
        room = max(half - R, 0.0)
        return (p[0] + np.clip(lat, -1, 1) * room * n[0]), half

    def _bubbles_for_frame(self, i):
        if self.nz["bubbles"] <= 0:
            return []
        ph, sh = self.ph, self.shapes[i]
        t = self.times[i]
        arr_pts, arr_rho = sh["pts"][::5], sh["rho_outline"][::5]
        sig_a = sh["meta"]["sig_a"]
        obstacles = []  # (centre, radius)

        def clearance(c, R):
            d = np.min(np.hypot(*(arr_pts - c).T) - arr_rho) - R
            for oc, orad in obstacles:
                d = min(d, float(np.hypot(*(oc - c))) - orad - R)
            return d

        out = []
        if self.tip_bubble is not None:
            tb = self.tip_bubble
            th_a = ph.theta_of_sigma(np.array([sig_a]))
            R = float(ph.width(th_a)[0] / 2) * tb["Rfrac"]
            half_a = float(ph.width(th_a)[0] / 2)
            lat = np.clip(sh["meta"]["e_apex"] / max(half_a - R, 1e-6), -1, 1)
            g = lambda sg: clearance(self._bubble_centre(sg, R, lat)[0], R) - tb["gap_mm"]
            lo, hi = sig_a - 0.3, sig_a + 4.0
            if g(lo) < 0 < g(hi):
                sg = brentq(g, lo, hi, xtol=1e-6)
                c, half = self._bubble_centre(sg, R, lat)
                R_eff = min(R, 0.98 * half)
                out.append({"role": "tip", "sigma_mm": sg, "centre_mm": c, "r_mm": R_eff,
                            "gap_to_array_mm": clearance(c, R_eff), "contrast": tb["contrast"]})
                obstacles.append((c, R_eff))
        order = sorted(self.bub_plan, key=lambda b: b["sig0"] + b["v_mm_s"] * t)
        for b in order:
            sg = min(b["sig0"] + b["v_mm_s"] * t, ph.total_sigma - 1.0)
            R = b["R"]
            c, half = self._bubble_centre(sg, R, b["lat"])
            if clearance(c, R) < 0.02:
                ok = False
                for step in np.arange(0.05, 12.0, 0.05):
                    sg2 = sg + step
                    if sg2 > ph.total_sigma - 1.0:
                        break
                    c, half = self._bubble_centre(sg2, R, b["lat"])
                    if clearance(c, min(R, 0.97 * half)) >= 0.02:
                        sg, ok = sg2, True
                        break
                if not ok:
                    continue
            R_eff = min(R, 0.97 * half)
            c, half = self._bubble_centre(sg, R_eff, b["lat"])
            out.append({"role": "drift", "sigma_mm": sg, "centre_mm": c, "r_mm": R_eff,
                        "gap_to_array_mm": clearance(c, R_eff), "contrast": b["contrast"]})
            obstacles.append((c, R_eff))
        return out

    # -- gripper geometry ----------------------------------------------------------------------
    def _gripper_polys(self, i):
        """Gripper outline polygons in mm (jaw + arm) for frame i, or []."""
        if self.grip is None:
            return []
        g, ph = self.grip, self.ph
        L = ph.cfg.entry_len_mm
        q_f = L + g["margin_mm"] + (self.depths[-1] - self.depths[i])
        back = -ph.T0  # away from the phantom
        side = ph.n0

        def P(q, v):
            return ph.p0 + q * back + v * side

        jw, jl = g["jaw_w"] / 2, g["jaw_len"]
        jaw = np.array([P(q_f, -jw * 0.8), P(q_f, jw * 0.8), P(q_f + 0.25 * jl, jw), P(q_f + jl, jw),
                        P(q_f + jl, -jw), P(q_f + 0.25 * jl, -jw)])
        a = g["arm_angle"]
        d = math.cos(a) * back + math.sin(a) * side
        nd = np.array([-d[1], d[0]])
        o = P(q_f + 0.7 * jl, g["arm_off"])
        aw = g["arm_w"] / 2
        arm = np.array([o - aw * nd, o + d * 80 - aw * nd, o + d * 80 + aw * nd, o + aw * nd])
        return [jaw, arm]

    # -- static layer --------------------------------------------------------------------------
    def _build_static(self):
        a, r, ph = self.app, self.rng_app, self.ph
        H2, W2 = self.H2, self.W2
        # table / background
        gh, gw = int(r.integers(3, 9)), int(r.integers(4, 12))
        low = cv2.resize(r.normal(size=(gh, gw)).astype(np.float32), (W2, H2), interpolation=cv2.INTER_CUBIC)
        grain = cv2.GaussianBlur(r.normal(size=(H2, W2)).astype(np.float32), (0, 0), 1.2)
        tex = 1.0 + a["bg_lf_amp"] * low + a["bg_hf_amp"] * grain / max(grain.std(), 1e-6)
        bg = _colour(a["bg_lum"], a["bg_tint"])
        img = (tex[..., None] * bg[None, None, :]).astype(np.float32)
        if a["bg_grid"]:  # cutting-mat grid under the plate
            ang = r.uniform(0, math.pi)
            step = 10.0 * self.spx
            cx, cy = r.uniform(0, step, 2)
            lines = []
            Lbig = 3 * (W2 + H2)
            for k in range(-int(Lbig / step), int(Lbig / step)):
                for th in (ang, ang + math.pi / 2):
                    c, s = math.cos(th), math.sin(th)
                    o = np.array([cx, cy]) + k * step * np.array([-s, c])
                    lines.append(np.array([o - Lbig * np.array([c, s]), o + Lbig * np.array([c, s])]))
            m = _line_mask((H2, W2), lines, 2)
            img = _mix(img, bg * r.uniform(0.6, 1.3), m * r.uniform(0.2, 0.6))
        # plate (a rectangle with one side through the entry mouth)
        P = ph.extent_points()
        u = (P - ph.mouth) @ ph.T0
        v = (P - ph.mouth) @ ph.n0
        mg = r.uniform(2.0, 6.0, 3)
        corners_uv = [(0.0, v.min() - mg[0]), (u.max() + mg[1], v.min() - mg[0]),
                      (u.max() + mg[1], v.max() + mg[2]), (0.0, v.max() + mg[2])]
        self.plate_mm = np.array([ph.mouth + cu * ph.T0 + cv * ph.n0 for cu, cv in corners_uv])
        pm = _fill_mask((H2, W2), [self.ss(self.plate_mm)])
        plate = img * a["plate_gain"] + a["plate_off"]
        img = img * (1 - pm[..., None]) + plate * pm[..., None]
        edge_col = _colour(np.clip(a["plate_lum"] + r.choice([-1, 1]) * r.uniform(0.1, 0.35), 0, 1), np.ones(3))
        img = _mix(img, edge_col, _line_mask((H2, W2), [self.ss(self.plate_mm)], int(r.integers(2, 5)), True)
                   * r.uniform(0.3, 0.9))
        # channel fluid (doubled region edge when doubled_walls is on)
        fluid = _colour(a["fluid_lum"], a["fluid_tint"])
        self.fluid_col = fluid
        chan = [self.ss(ph.channel_polygon)]
        cm = _fill_mask((H2, W2), chan)
        if self.dbl is not None and a["wall_mode"] != "lines":
            off = np.array(self.dbl["offset_px"]) * SS
            cm2 = _fill_mask((H2, W2), [chan[0] + off])
            k = 0.5 * self.dbl["contrast"]
            cm = (1 - k) * cm + k * cm2
        fl_tex = 1.0 + 0.03 * cv2.GaussianBlur(r.normal(size=(H2, W2)).astype(np.float32), (0, 0), 6.0) * 4
        img = img * (1 - cm[..., None]) + (fluid[None, None, :] * fl_tex[..., None]) * cm[..., None]
        self.channel_mask = cm
        # wall lines
        walls = [self.ss(w) for w in ph.wall_polylines()]
        self.line_col = _colour(a["line_lum"], a["line_tint"])
        if a["line_alpha"] > 0:
            img = _mix(img, self.line_col, _line_mask((H2, W2), walls, a["line_thick_ss"]) * a["line_alpha"])
        if self.dbl is not None:
            off = np.array(self.dbl["offset_px"]) * SS
            col = self.line_col if a["line_alpha"] > 0 else _colour(
                a["fluid_lum"] * (0.5 if a["fluid_lum"] > a["plate_lum"] else 1.4), np.ones(3))
            if self.dbl["opposite_polarity"]:
                col = _colour(np.clip(2 * a["fluid_lum"] - _lum(col), 0, 1), np.ones(3))
            alpha = self.dbl["contrast"] * max(a["line_alpha"], 0.6)
            img = _mix(img, col, _line_mask((H2, W2), [w + off for w in walls],
                                            max(1, a["line_thick_ss"] - int(r.integers(0, 2)))) * alpha)
        # clutter (screws, ruler) outside the channel
        self.clutter = []
        if self.nz["clutter"] > 0:
            img = self._draw_clutter(img)
        self.static = np.clip(img, 0, 1).astype(np.float32)

    def _keepout(self):
        """Output-resolution mask of where clutter must not go."""
        ph = self.ph
        m = np.zeros((self.H, self.W), np.uint8)
        cv2.fillPoly(m, [np.round(self.pose.to_px(ph.channel_polygon)).astype(np.int32).reshape(-1, 1, 2)], 255)
        k = int(math.ceil(1.5 * self.pose.px_per_mm)) * 2 + 1
        m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        strip = np.array([ph.p0 - 2.5 * ph.n0, ph.p0 - 200 * ph.T0 - 2.5 * ph.n0,
                          ph.p0 - 200 * ph.T0 + 2.5 * ph.n0, ph.p0 + 2.5 * ph.n0])
        polys = [strip] + [p for i in range(self.n) for p in self._gripper_polys(i)]
        for p in polys:
            cv2.fillPoly(m, [np.round(self.pose.to_px(p)).astype(np.int32).reshape(-1, 1, 2)], 255)
        return m > 0

    def _draw_clutter(self, img):
        s, r = self.nz["clutter"], self.rng_nz["clutter"]
        H2, W2 = self.H2, self.W2
        keep = self._keepout()
        spx = self.spx
        # screws
        for _ in range(max(1, int(round(s * r.uniform(1, 5))))):
            R = r.uniform(1.0, 2.5)
            for _try in range(40):
                c_px = np.array([r.uniform(0, self.W - 1), r.uniform(0, self.H - 1)])
                m = np.zeros((self.H, self.W), np.uint8)
                cv2.circle(m, tuple(int(x) for x in np.round(c_px)), int(math.ceil((R + 0.5) * self.pose.px_per_mm)), 255, -1)
                if not np.any(keep & (m > 0)):
                    break
            else:
                continue
            keep |= m > 0
            c = self.ss_from_px(c_px)
            Rs = R * spx
            lum = r.uniform(0.25, 0.8) * (0.6 + 0.4 * s)
            col = _colour(lum, self._tint(r, 0.1))
            img = _mix(img, col * 0.35, _circle_mask((H2, W2), c + Rs * 0.12, Rs * 1.02) * 0.6 * s)  # shadow
            img = _mix(img, col * 0.7, _circle_mask((H2, W2), c, Rs))
            img = _mix(img, col, _circle_mask((H2, W2), c, Rs * 0.85))
            _spot(img, c[0] - 0.35 * Rs, c[1] - 0.35 * Rs, 0.25 * Rs, 0.18 * Rs, r.uniform(0, 3), 0.5)
            ang = r.uniform(0, math.pi)
            d = np.array([math.cos(ang), math.sin(ang)]) * Rs * 0.75
            kind = int(r.integers(3))
            if kind == 0:
                img = _mix(img, col * 0.2, _line_mask((H2, W2), [np.array([c - d, c + d])], max(2, int(0.2 * Rs))))
            elif kind == 1:
                nd = np.array([-d[1], d[0]])
                img = _mix(img, col * 0.2, _line_mask((H2, W2), [np.array([c - d, c + d]), np.array([c - nd, c + nd])],
                                                      max(2, int(0.15 * Rs))))
            else:
                hexa = np.array([c + 0.4 * Rs * np.array([math.cos(ang + k * math.pi / 3), math.sin(ang + k * math.pi / 3)])
                                 for k in range(6)])
                img = _mix(img, col * 0.15, _fill_mask((H2, W2), [hexa]))
            self.clutter.append({"kind": "screw", "centre_px": c_px.tolist(), "r_mm": R})
        # ruler
        if r.random() < 0.4 + 0.6 * s:
            for _try in range(80):
                Lr, Wr = r.uniform(25, 80), r.uniform(3, 8)
                ang = r.uniform(0, math.pi)
                c_px = np.array([r.uniform(0, self.W - 1), r.uniform(0, self.H - 1)])
                d = np.array([math.cos(ang), math.sin(ang)])
                nd = np.array([-d[1], d[0]])
                ppm = self.pose.px_per_mm
                poly = np.array([c_px - d * Lr / 2 * ppm - nd * Wr / 2 * ppm, c_px + d * Lr / 2 * ppm - nd * Wr / 2 * ppm,
                                 c_px + d * Lr / 2 * ppm + nd * Wr / 2 * ppm, c_px - d * Lr / 2 * ppm + nd * Wr / 2 * ppm])
                m = np.zeros((self.H, self.W), np.uint8)
                cv2.fillPoly(m, [np.round(poly).astype(np.int32).reshape(-1, 1, 2)], 255)
                if m.sum() > 0 and not np.any(keep & (m > 0)):
                    break
            else:
                return img
            lum = float(r.choice([r.uniform(0.75, 0.95), r.uniform(0.45, 0.7)]))
            col = _colour(lum, self._tint(r, 0.06))
            img = _mix(img, col, _fill_mask((H2, W2), [self.ss_from_px(poly)]) * (0.6 + 0.4 * s))
            ticks = []
            p_start = c_px - d * Lr / 2 * ppm - nd * Wr / 2 * ppm
            for k in range(int(Lr) + 1):
                tl = (0.45 if k % 10 == 0 else 0.32 if k % 5 == 0 else 0.2) * Wr * ppm
                b = p_start + d * (k + 0.5) * ppm
                ticks.append(self.ss_from_px(np.array([b, b + nd * tl])))
            img = _mix(img, col * 0.15, _line_mask((H2, W2), ticks, max(1, int(round(0.08 * spx)))) * (0.6 + 0.4 * s))
            self.clutter.append({"kind": "ruler", "centre_px": c_px.tolist(), "length_mm": Lr, "width_mm": Wr,
                                 "angle_rad_image": ang})
        return img

    # -- array layer -----------------------------------------------------------------------------
    def _array_layer(self, i):
        a, sh = self.app, self.shapes[i]
        H2, W2 = self.H2, self.W2
        pts, tan = sh["pts"], sh["tangent"]
        nl = np.stack([-tan[:, 1], tan[:, 0]], -1)
        rho0 = self.model.rho0
        k0 = int(round(rho0 / self.model.DS))
        # outline: body from s = rho0 to base, plus a lead beyond the base, plus the cap arc
        base_dir = -tan[-1]
        lead_r = a["lead_diam"] / 2
        lead = pts[-1] + np.linspace(0.3, 80, 40)[:, None] * base_dir
        ln = np.array([-base_dir[1], base_dir[0]])

        def outline(frac):
            rr = sh["rho"][k0:] * frac
            left = pts[k0:] + rr[:, None] * nl[k0:]
            right = pts[k0:] - rr[:, None] * nl[k0:]
            C, t = pts[k0], tan[k0]
            n_ = nl[k0]
            psi = np.linspace(math.pi / 2, -math.pi / 2, 25)
            cap = C + rho0 * frac * (np.cos(psi)[:, None] * t + np.sin(psi)[:, None] * n_)
            lr = lead_r * frac
            lead_l = lead + lr * ln
            lead_r_ = lead - lr * ln
            # ensure lead sides follow the array sides (ln vs nl orientation)
            if np.dot(ln, nl[-1]) < 0:
                lead_l, lead_r_ = lead_r_, lead_l
            return np.vstack([lead_l[::-1], left[::-1], cap, right, lead_r_])

        col = np.zeros((H2, W2, 3), np.float32)
        alpha = _fill_mask((H2, W2), [self.ss(outline(1.0))])
        body = _colour(a["array_lum"], a["array_tint"])
        col[:] = body * a["array_edge"]
        col = _mix(col, body, _fill_mask((H2, W2), [self.ss(outline(0.72))]))
        core = _colour(min(a["array_lum"] * a["array_core"], a["fluid_lum"] - 0.1), a["array_tint"])
        col = _mix(col, core, _fill_mask((H2, W2), [self.ss(outline(0.3))]))
        # bands
        band_col = _colour(a["band_lum"], a["band_tint"])
        band_polys, band_centres = [], []
        for sa, sb in self.bands:
            ka, kb = int(round(sa / self.model.DS)), int(round(sb / self.model.DS)) + 1
            rr = sh["rho"][ka:kb] * 0.98
            left = pts[ka:kb] + rr[:, None] * nl[ka:kb]
            right = pts[ka:kb] - rr[:, None] * nl[ka:kb]
            band_polys.append(self.ss(np.vstack([left, right[::-1]])))
            km = (ka + kb) // 2
            band_centres.append((pts[km], nl[km], tan[km], sh["rho"][km], sb - sa))
        col = _mix(col, band_col, _fill_mask((H2, W2), band_polys))
        # glints on bands
        gs = self.nz["glints"]
        if gs > 0:
            r = self.rng_frame
            ld = math.cos(a["light_dir"])
            for (c, n_, t, rr, bl) in band_centres:
                if r.random() < 0.3 + 0.6 * gs:
                    q = self.ss(c + n_ * rr * 0.45 * ld)
                    tp = self.pose.dir_px(t)
                    _spot(col, q[0], q[1], 0.3 * bl * self.spx, 0.22 * rr * self.spx, math.atan2(tp[1], tp[0]),
                          gs * r.uniform(0.5, 1.0))
        return col, alpha

    # -- lighting field (output resolution) ------------------------------------------------------
    def _illumination(self, i):
        L = self.light
        if L is None:
            return None
        H, W = self.H, self.W
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        f = np.ones((H, W), np.float32)
        c, s = math.cos(L["grad_dir"]), math.sin(L["grad_dir"])
        ramp = ((xx - W / 2) * c + (yy - H / 2) * s) / max(W, H)
        f *= 1.0 + L["grad"] * ramp
        rr = ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
        f *= 1.0 - L["vignette"] * rr
        blobs = list(L["blobs"])
        if L["moving"] is not None:
            vel, x0, y0, sz, dep = L["moving"]
            t = self.times[i]
            blobs.append((x0 + vel[0] * t * 3, y0 + vel[1] * t * 3, sz, sz * 0.6, 0.3, dep))
        for (bx, by, sa, sb, ang, dep) in blobs:
            ca, sa_ = math.cos(ang), math.sin(ang)
            u = ((xx - bx) * ca + (yy - by) * sa_) / sa
            v = (-(xx - bx) * sa_ + (yy - by) * ca) / sb
            f *= 1.0 - dep * np.exp(-0.5 * (u * u + v * v))
        t = self.times[i]
        fl = 1.0 + L["flicker"] * (0.6 * math.sin(2 * math.pi * L["flicker_hz"] * t + L["flicker_phase"])
                                   + 0.4 * float(self.rng_nz["shadows"].normal()))
        return np.clip(f * fl, 0.15, 1.6)

    # -- one frame -------------------------------------------------------------------------------
    def render_frame(self, i):
        a, nz = self.app, self.nz
        H2, W2 = self.H2, self.W2
        img = self.static.copy()
        extra = {}
        # bubbles
        bubbles = self._bubbles_for_frame(i)
        if bubbles:
            look = self.bub_look
            for b in bubbles:
                c = self.ss(b["centre_mm"])
                R = b["r_mm"] * self.spx
                k = b["contrast"] * max(nz["bubbles"], 0.3)
                inner = np.minimum(1.0, self.fluid_col * (1 + look["in_gain"] * k) + 0.12 * k)
                rim = self.fluid_col * (1 - k * (1 - look["rim_lum"]))
                img = _mix(img, inner, _circle_mask((H2, W2), c, R))
                img = _mix(img, rim, _circle_mask((H2, W2), c, R * (1 - look["rim_frac"] / 2),
                                                  max(1, int(round(R * look["rim_frac"])))))
                if look["hl"]:
                    d = np.array([math.cos(a["light_dir"]), math.sin(a["light_dir"])]) * 0.4 * R
                    _spot(img, c[0] + d[0], c[1] + d[1], 0.16 * R, 0.12 * R, 0.0, 0.6 * k)
                b_px = self.pose.to_px(b["centre_mm"])
                b["centre_px"] = b_px
                b["r_px"] = b["r_mm"] * self.pose.px_per_mm
        # array
        col, alpha = self._array_layer(i)
        sh = self.shapes[i]
        if self.blur is not None and self.blur["mode"] == "array":
            tp = self.pose.dir_px(sh["tangent"][0])
            k = _line_kernel(self.blur["length_px"] * SS, math.atan2(tp[1], tp[0]))
            pre = col * alpha[..., None]
            pre = cv2.filter2D(pre, -1, k, borderType=cv2.BORDER_REFLECT)
            alpha = cv2.filter2D(alpha, -1, k, borderType=cv2.BORDER_REFLECT)
            img = img * (1 - alpha[..., None]) + pre
        else:
            img = img * (1 - alpha[..., None]) + col * alpha[..., None]
        # gripper shadow and gripper
        gp = self._gripper_polys(i)
        if gp:
            g = self.grip
            polys = [self.ss(p) for p in gp]
            off = np.array([math.cos(g["shadow_dir"]), math.sin(g["shadow_dir"])]) * g["shadow_len_mm"] * self.spx
            sm = _fill_mask((H2, W2), [p + off for p in polys])
            sm = _soft(sm, g["shadow_blur_mm"] * self.spx)
            img *= (1 - g["shadow_depth"] * sm)[..., None]
            gm = _fill_mask((H2, W2), polys)
            gcol = _colour(g["lum"], g["tint"])
            img = _mix(img, gcol, gm)
            inset = [p.mean(0) + 0.8 * (p - p.mean(0)) for p in polys[:1]]
            img = _mix(img, np.minimum(gcol * 1.25 + 0.04, 1), _fill_mask((H2, W2), inset) * 0.7)
            img = _mix(img, gcol * 0.45, _line_mask((H2, W2), polys, max(2, int(0.08 * self.spx)), True) * 0.8)
            hole = polys[0].mean(0)
            img = _mix(img, gcol * 0.3, _circle_mask((H2, W2), hole, 0.35 * self.spx))
            if nz["glints"] > 0:
                c = polys[0].mean(0)
                _spot(img, c[0], c[1], 0.6 * self.spx, 0.15 * self.spx, self.rng_frame.uniform(0, 3),
                      0.6 * nz["glints"])
            extra["gripper_px"] = [self.pose.to_px(p).tolist() for p in gp]
        # glints elsewhere
        if self.glints_static:
            for (pmm, ang, amp) in self.glints_static:
                if self.rng_frame.random() < 0.75:
                    q = self.ss(pmm)
                    _spot(img, q[0], q[1], 0.35 * self.spx, 0.08 * self.spx, ang,
                          nz["glints"] * amp * self.rng_frame.uniform(0.6, 1.0))
        # to output resolution
        out = cv2.resize(np.clip(img, 0, 1), (self.W, self.H), interpolation=cv2.INTER_AREA)
        if self.blur is not None and self.blur["mode"] == "frame":
            tp = self.pose.dir_px(-self.ph.T0)
            k = _line_kernel(self.blur["length_px"], math.atan2(tp[1], tp[0]))
            out = cv2.filter2D(out, -1, k, borderType=cv2.BORDER_REFLECT)
        ill = self._illumination(i)
        if ill is not None:
            out = out * ill[..., None]
        s = nz["noise"]
        if s > 0:
            r = self.rng_nz["noise"]
            sig = s * 0.045
            out = out + r.normal(0, 1, out.shape).astype(np.float32) * (
                sig + s * 0.03 * np.sqrt(np.clip(out, 0, 1)))
            out = out + (s * 0.01 * r.normal(size=(self.H, 1, 1))).astype(np.float32)
            if self.gray:
                out[..., 1] = out[..., 0]
                out[..., 2] = out[..., 0]
        frame = np.clip(np.round(out * 255), 0, 255).astype(np.uint8)
        s = nz["compression"]
        if s > 0:
            q = int(round(95 - 75 * s))
            ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, q])
            frame = cv2.imdecode(buf, cv2.IMREAD_COLOR)
            extra["jpeg_quality"] = q
        extra["bubbles"] = [{"role": b["role"], "x_px": float(b["centre_px"][0]), "y_px": float(b["centre_px"][1]),
                             "r_px": float(b["r_px"]), "x_mm": float(b["centre_mm"][0]),
                             "y_mm": float(b["centre_mm"][1]), "r_mm": float(b["r_mm"]),
                             "gap_to_array_mm": float(b["gap_to_array_mm"])} for b in bubbles]
        return frame, extra

    # -- truth and info --------------------------------------------------------------------------
    def truth_frame(self):
        rows = []
        for i, (D, t, tr, sh) in enumerate(zip(self.depths, self.times, self.truths, self.shapes)):
            apex_px = self.pose.to_px(sh["pts"][0])
            bot_px = self.pose.to_px(tr["bot_point_mm"])
            rows.append({"frame": i, "time_s": float(t), "depth_mm": float(D),
                         "theta_tip": tr["theta_tip"], "theta_bot": tr["theta_bot"],
                         "theta_con": tr["theta_con"], "in_contact": bool(tr["in_contact"]),
                         "tip_x_px": float(apex_px[0]), "tip_y_px": float(apex_px[1]),
                         "bot_x_px": float(bot_px[0]), "bot_y_px": float(bot_px[1]),
                         "tip_gap_mm": tr["tip_gap_mm"],
                         "insertion_time_s": float(D / self.speed) if self.speed > 0 else float("nan")})
        df = pd.DataFrame(rows)
        df["frame"] = df["frame"].astype(int)
        df["in_contact"] = df["in_contact"].astype(bool)
        return df

    def info(self, frame_extras):
        a = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.app.items()}
        return {
            "pose": self.pose.as_dict(),
            "pose_meta": self.pose_meta,
            "nuisance": dict(self.nz),
            "size": [self.W, self.H], "fps": self.fps, "speed_mm_s": self.speed,
            "n_frames": self.n,
            "time_convention": "time_s = frame / fps (video clock); depth_mm evenly spread over "
                               "depth_range_mm; insertion_time_s = depth_mm / speed_mm_s",
            "effective_speed_mm_s": float((self.depths[-1] - self.depths[0]) / self.times[-1])
            if self.n > 1 else 0.0,
            "speed_consistent": bool(self.n < 2 or abs((self.depths[-1] - self.depths[0]) / self.times[-1]
                                                       - self.speed) <= 1e-6 * max(1.0, self.speed)),
            "phantom": asdict(self.ph.cfg),
            "array": {**asdict(self.acfg), "bands_s_mm": [list(b) for b in self.bands],
                      "tip": "apex of hemispherical cap (radius tip_diameter/2) = centreline end"},
            "shape_model": self.model.params(),
            "appearance": a,
            "doubled_walls": self.dbl,
            "motion_blur": self.blur,
            "gripper": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.grip.items()}
            if self.grip else None,
            "clutter": self.clutter,
            "frames": frame_extras,
        }

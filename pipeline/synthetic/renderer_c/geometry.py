"""Renderer C: the phantom, the array's shape model, the truth measured on it, and the camera pose."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import brentq

NUISANCE_KEYS = ("bubbles", "doubled_walls", "glints", "motion_blur", "shadows", "compression",
                 "gripper", "noise", "clutter")
SS = 2  # supersampling factor used for all geometric drawing


# ----------------------------------------------------------------------------------------------
# configuration
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PhantomConfig:
    """The phantom's dimensions (Cohen et al. 1996 Eq. (1), channel, entry)."""
    a_mm: float = 3.762
    b_per_deg: float = 0.001317
    c_mm: float = 7.967
    d: float = 0.1287
    phi0_deg: float = 5.0
    branch_deg: float = 100.0
    theta_start_deg: float = 10.3
    theta_end_deg: float = 720.0
    width_max_mm: float = 1.5      # channel WIDTH w(theta) = min(width_max, width_frac * r)
    width_frac: float = 0.38       # each wall sits w/2 from the backbone
    entry_len_mm: float = 5.0


@dataclass(frozen=True)
class ArrayConfig:
    """The electrode array's dimensions."""
    length_mm: float = 26.0
    tip_diameter_mm: float = 0.6
    base_diameter_mm: float = 1.2
    n_bands: int = 11
    contact_tol_mm: float = 0.05


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _seg_dist(P, A, B):
    """Distance from points P (...,2) to segments A->B (...,2), broadcasting."""
    AB = B - A
    AP = P - A
    den = np.maximum(np.sum(AB * AB, axis=-1), 1e-18)
    t = np.clip(np.sum(AP * AB, axis=-1) / den, 0.0, 1.0)
    Q = A + t[..., None] * AB
    return np.hypot(P[..., 0] - Q[..., 0], P[..., 1] - Q[..., 1])


def _seg_intersection(p1, p2, q1, q2):
    """Intersection of segments p1p2 and q1q2 or None."""
    r = p2 - p1
    s = q2 - q1
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-15:
        return None
    qp = q1 - p1
    t = (qp[0] * s[1] - qp[1] * s[0]) / den
    u = (qp[0] * r[1] - qp[1] * r[0]) / den
    if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0:
        return p1 + t * r, t, u
    return None


# ----------------------------------------------------------------------------------------------
# phantom geometry
# ----------------------------------------------------------------------------------------------
class Phantom:
    """Geometry of the planar phantom in the phantom frame (mm, origin o_c, CCW angles)."""

    def __init__(self, cfg: PhantomConfig | None = None, wall_step_rad: float = 0.004):
        self.cfg = cfg = cfg or PhantomConfig()
        self.th_s = math.radians(cfg.theta_start_deg)
        self.th_e = math.radians(cfg.theta_end_deg)
        self.th_k = math.radians(cfg.branch_deg)
        # --- backbone arc-length table (theta <-> sigma), sigma = 0 at theta_start
        nA = int(math.ceil((self.th_k - self.th_s) / 2e-4)) + 1
        nB = int(math.ceil((self.th_e - self.th_k) / 2e-4)) + 1
        th = np.concatenate([np.linspace(self.th_s, self.th_k, nA),
                             np.linspace(self.th_k, self.th_e, nB)[1:]])
        p = self.point(th)
        self._tab_th = th
        self._tab_sig = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
        self.total_sigma = float(self._tab_sig[-1])
        self.sigma_kink = float(np.interp(self.th_k, th, self._tab_sig))
        # --- entry
        self.p0, self.T0, self.n0 = (v[0] for v in self.frame(np.array([self.th_s])))
        self.w0 = float(self.width(np.array([self.th_s]))[0])
        self.mouth = self.p0 - cfg.entry_len_mm * self.T0
        self._build_walls(wall_step_rad)

    # -- backbone -----------------------------------------------------------------------------
    def r(self, th):
        """Backbone radius r(theta) (theta in rad; Eq. (1) with phi in degrees)."""
        c = self.cfg
        deg = np.degrees(np.asarray(th, float))
        with np.errstate(invalid="ignore", divide="ignore"):
            ra = c.c_mm * (1.0 - c.d * np.log(deg - c.phi0_deg))
        rb = c.a_mm * np.exp(-c.b_per_deg * deg)
        return np.where(deg < c.branch_deg, ra, rb)

    def dr(self, th, branch=None):
        """dr/dtheta (mm/rad); branch 'A' (< 100 deg), 'B' (>= 100 deg) or None (by theta)."""
        c = self.cfg
        deg = np.degrees(np.asarray(th, float))
        k = 180.0 / math.pi
        with np.errstate(invalid="ignore", divide="ignore"):
            da = -c.c_mm * c.d / (deg - c.phi0_deg) * k
        db = -c.a_mm * c.b_per_deg * np.exp(-c.b_per_deg * deg) * k
        if branch == "A":
            return da
        if branch == "B":
            return db
        return np.where(deg < c.branch_deg, da, db)

    def point(self, th):
        th = np.asarray(th, float)
        r = self.r(th)
        return np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)

    def frame(self, th, branch=None):
        """Backbone point, unit tangent (increasing theta) and unit OUTWARD normal."""
        th = np.asarray(th, float)
        r = self.r(th)
        dr = self.dr(th, branch)
        c, s = np.cos(th), np.sin(th)
        t = np.stack([dr * c - r * s, dr * s + r * c], axis=-1)
        t /= np.linalg.norm(t, axis=-1, keepdims=True)
        n = np.stack([t[..., 1], -t[..., 0]], axis=-1)  # right normal = away from o_c
        return np.stack([r * c, r * s], axis=-1), t, n

    def width(self, th):
        """Channel width w(theta) (the walls are w/2 either side of the backbone)."""
        return np.minimum(self.cfg.width_max_mm, self.cfg.width_frac * self.r(th))

    def theta_of_sigma(self, sig):
        return np.interp(sig, self._tab_sig, self._tab_th)

    def sigma_of_theta(self, th):
        return np.interp(th, self._tab_th, self._tab_sig)

    # -- walls --------------------------------------------------------------------------------
    def _build_walls(self, step):
        th_s, th_k, th_e = self.th_s, self.th_k, self.th_e
        thA = np.linspace(th_s, th_k, int(math.ceil((th_k - th_s) / step)) + 1)
        thB = np.linspace(th_k, th_e, int(math.ceil((th_e - th_k) / step)) + 1)
        pA, _, nA = self.frame(thA, "A")
        pB, _, nB = self.frame(thB, "B")
        hA = self.width(thA)[:, None] / 2
        hB = self.width(thB)[:, None] / 2
        oA, oB = pA + hA * nA, pB + hB * nB
        iA, iB = pA - hA * nA, pB - hB * nB
        # outer wall: inside of the 6.3 deg right turn at 100 deg -> pieces cross; cut there
        hit = None
        m = 60
        for i in range(len(oA) - 2, max(len(oA) - 2 - m, -1), -1):
            for j in range(0, min(m, len(oB) - 1)):
                res = _seg_intersection(oA[i], oA[i + 1], oB[j], oB[j + 1])
                if res is not None:
                    hit = (i, j, res[0])
                    break
            if hit:
                break
        if hit is None:  # pragma: no cover - would mean a changed configuration
            raise RuntimeError("outer wall pieces do not cross at the branch point")
        i, j, X = hit
        outer = np.concatenate([oA[: i + 1], X[None], oB[j + 1:]])
        outer_par = np.concatenate([thA[: i + 1], [th_k], thB[j + 1:]])
        self.outer_cut_point = X
        # inner wall: outside of the turn -> gap; close with an arc about the backbone point
        pk = pA[-1]
        a0 = math.atan2(*(iA[-1] - pk)[::-1])
        a1 = math.atan2(*(iB[0] - pk)[::-1])
        da = (a1 - a0 + math.pi) % (2 * math.pi) - math.pi
        hk = float(hA[-1, 0])
        angs = a0 + da * np.linspace(0, 1, 12)[1:-1]
        arc = pk + hk * np.stack([np.cos(angs), np.sin(angs)], axis=-1)
        inner = np.concatenate([iA, arc, iB])
        inner_par = np.concatenate([thA, np.full(len(arc), th_k), thB])
        # entry straight channel (5 mm, along the tangent at theta_start)
        L = self.cfg.entry_len_mm
        q = np.linspace(L, 0.0, 26)[:-1]
        h0 = self.w0 / 2
        e_out = self.p0 + h0 * self.n0 - q[:, None] * self.T0
        e_in = self.p0 - h0 * self.n0 - q[:, None] * self.T0
        e_par = th_s - 1e-3 * q / L
        self.entry_outer, self.entry_inner = np.vstack([e_out, outer[:1]]), np.vstack([e_in, inner[:1]])
        self.spiral_outer, self.spiral_inner = outer, inner
        self.outer_wall = np.vstack([e_out, outer])
        self.outer_par = np.concatenate([e_par, outer_par])
        self.inner_wall = np.vstack([e_in, inner])
        self.inner_par = np.concatenate([e_par, inner_par])
        self.end_cap = np.vstack([outer[-1], inner[-1]])
        # closed channel outline (open mouth closed straight across for filling)
        self.channel_polygon = np.vstack([self.outer_wall, self.inner_wall[::-1]])

    def wall_polylines(self):
        """Polylines of every wall edge (for drawing): outer, inner (with entry), end cap."""
        return [self.outer_wall, self.inner_wall, self.end_cap]

    def wall_distance(self, pts, which="outer", th_pts=None, halfwin=0.5):
        """Distance from points to the outer/inner wall of their own turn of the channel."""
        pts = np.atleast_2d(np.asarray(pts, float))
        W = self.outer_wall if which == "outer" else self.inner_wall
        par = self.outer_par if which == "outer" else self.inner_par
        if th_pts is None:
            th_pts = self.theta_of_point(pts)
        A, B, spar = W[:-1], W[1:], par[:-1]
        lo = np.searchsorted(spar, th_pts - halfwin, side="left")
        hi = np.searchsorted(spar, th_pts + halfwin, side="right")
        K = int(max(1, np.max(hi - lo)))
        out = np.full(len(pts), np.inf)
        for c0 in range(0, len(pts), 1024):
            sl = slice(c0, c0 + 1024)
            idx = lo[sl, None] + np.arange(K)[None, :]
            valid = idx < hi[sl, None]
            idx = np.minimum(idx, len(A) - 1)
            d = _seg_dist(pts[sl, None, :], A[idx], B[idx])
            d[~valid] = np.inf
            out[sl] = d.min(axis=1)
        return out

    # -- the angle of a point --------------------------------------------------------------------
    def theta_of_point(self, pts):
        """theta = phi + 2 pi k (k >= 0 with r(phi + 2 pi k) closest to |p|); entry: k = 0."""
        pts = np.asarray(pts, float)
        single = pts.ndim == 1
        pts = np.atleast_2d(pts)
        phi = np.arctan2(pts[:, 1], pts[:, 0])
        phi = np.where(phi <= -math.pi, phi + 2 * math.pi, phi)
        rad = np.hypot(pts[:, 0], pts[:, 1])
        ks = np.arange(0, 5)
        cand = phi[:, None] + 2 * math.pi * ks[None, :]
        valid = np.degrees(cand) > self.cfg.phi0_deg
        rc = np.where(valid, self.r(np.where(valid, cand, 1.0)), np.nan)
        diff = np.where(valid, np.abs(rc - rad[:, None]), np.inf)
        th = cand[np.arange(len(pts)), np.argmin(diff, axis=1)]
        # points of the entry channel (behind its end at theta_start) take k = 0
        rel = pts - self.p0
        u = rel @ self.T0
        v = rel @ self.n0
        in_entry = (u < 0) & (u >= -self.cfg.entry_len_mm - 1.0) & (np.abs(v) <= self.w0 / 2 + 1.0)
        th = np.where(in_entry, phi, th)
        return float(th[0]) if single else th

    def extent_points(self):
        return np.vstack([self.outer_wall, self.inner_wall, self.end_cap])


# ----------------------------------------------------------------------------------------------
# array shape model and truth
# ----------------------------------------------------------------------------------------------
class ArrayModel:
    """Invented (non-physical, smooth) shape model of the inserted array.

    The centreline is the entry axis behind theta_start, then an offset of the backbone along
    its outward normal by e(sigma) (sigma = backbone arc length from theta_start):
    a free lateral profile (random level + gentle wave, zero at the entry), blended over a
    transition length into a contact profile that keeps the array's outer edge a constant small
    gap g_c (< contact_tol) from the outer wall from sigma_bot to the tip.  Before the touch
    depth D_touch the tip only approaches the outer wall.  The contact run grows as
    kappa * (depth - D_touch).  The polyline is Gaussian-smoothed (0.15 mm) so it is smooth
    across the 100 deg kink; the tip position is solved so that the arc length from the entry's
    end to the tip apex equals the depth.
    """

    DS = 0.01  # station spacing (mm)

    def __init__(self, phantom: Phantom, cfg: ArrayConfig | None, rng: np.random.Generator):
        self.ph = phantom
        self.cfg = cfg = cfg or ArrayConfig()
        self.rho0 = cfg.tip_diameter_mm / 2
        self.rhob = cfg.base_diameter_mm / 2
        self.lam_f = rng.uniform(-0.6, 0.45)
        self.amp = rng.uniform(0.0, 0.25)
        self.period = rng.uniform(4.0, 10.0)
        self.phase = rng.uniform(0, 2 * math.pi)
        self.sig_in = rng.uniform(1.0, 3.0)
        self.D_touch = rng.uniform(3.0, 8.0)
        self.kappa = rng.uniform(0.35, 0.85)
        self.L_tr = rng.uniform(1.2, 3.0)
        self.g_c = rng.uniform(0.008, 0.02)
        self.g_far = rng.uniform(0.15, 0.3)
        self.R_app = rng.uniform(1.0, 3.0)
        self.smooth_mm = 0.15

    def params(self):
        return {k: float(getattr(self, k)) for k in (
            "lam_f", "amp", "period", "phase", "sig_in", "D_touch", "kappa", "L_tr", "g_c",
            "g_far", "R_app", "smooth_mm")}

    def rho(self, s):
        """Body radius at distance s from the apex (taper measured from the cap centre)."""
        s = np.maximum(np.asarray(s, float), self.rho0)
        L = self.cfg.length_mm
        return self.rho0 + (self.rhob - self.rho0) * (s - self.rho0) / (L - self.rho0)

    def rho_outline(self, s):
        """Drawn half-width: hemispherical cap of radius rho0 on the first rho0 mm."""
        s = np.asarray(s, float)
        cap = np.sqrt(np.clip(self.rho0 ** 2 - (self.rho0 - s) ** 2, 0, None))
        return np.where(s < self.rho0, cap, self.rho(s))

    def _lateral(self, sig, sig_a, D):
        ph = self.ph
        th = ph.theta_of_sigma(sig)
        s_est = (sig_a - sig) * (D / max(sig_a, 1e-6))
        room = ph.width(th) / 2 - self.rho(s_est)
        lam = (self.lam_f + self.amp * np.sin(2 * math.pi * sig / self.period + self.phase))
        lam = lam * _smoothstep(sig / self.sig_in)
        e_free = np.clip(lam * room, -room + 0.02, room - 0.1)
        if D >= self.D_touch:
            g_t = self.g_c
            sig_bot = sig_a - self.kappa * (D - self.D_touch)
        else:
            g_t = self.g_c + (self.g_far - self.g_c) * float(_smoothstep((self.D_touch - D) / self.R_app))
            sig_bot = sig_a
        sig_bot = max(sig_bot, 0.5)
        ltr = min(self.L_tr, sig_bot)
        S = _smoothstep((sig - (sig_bot - ltr)) / ltr)
        e_con = np.maximum(room - g_t, -room + 0.02)
        return th, e_free + S * (e_con - e_free), sig_bot

    def _curve(self, sig_a, D):
        ph, h = self.ph, self.DS
        n = max(20, int(math.ceil(sig_a / h)) + 1)
        sig = np.linspace(0.0, sig_a, n)
        th, e, sig_bot = self._lateral(sig, sig_a, D)
        p, _, nrm = ph.frame(th)
        c = p + e[:, None] * nrm
        L_back = self.cfg.length_mm - D + 1.0
        q = np.arange(L_back, 0.0, -h)[:, None]
        base = ph.p0 - q * ph.T0
        tend = c[-1] - c[-3]
        tend /= np.linalg.norm(tend)
        ext = c[-1] + np.arange(1, 101)[:, None] * h * tend
        full = np.vstack([base, c, ext])
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(full, axis=0).T))])
        L_apex = cum[len(base) + len(c) - 1]
        grid = np.arange(0.0, cum[-1], h)
        res = np.stack([np.interp(grid, cum, full[:, 0]), np.interp(grid, cum, full[:, 1])], -1)
        sm = gaussian_filter1d(res, self.smooth_mm / h, axis=0, mode="nearest")
        cum_s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(sm, axis=0).T))])
        L_apex_s = float(np.interp(L_apex, grid, cum_s))
        # entry's end crossing: (x - p0).T0 changes sign from negative to positive
        u = (sm - ph.p0) @ ph.T0
        k = int(np.argmax(u >= 0))
        f = -u[k - 1] / (u[k] - u[k - 1])
        L_cross = cum_s[k - 1] + f * (cum_s[k] - cum_s[k - 1])
        return sm, cum_s, L_apex_s, L_apex_s - L_cross, {"sig_a": sig_a, "sig_bot_design": sig_bot,
                                                           "e_apex": float(e[-1])}

    def shape(self, D):
        """Centreline for insertion depth D (mm): dict with s (from apex), pts, rho, ..."""
        L = self.cfg.length_mm
        if not (0.4 <= D <= L - 1.0):
            raise ValueError(f"depth {D} mm outside the supported range [0.4, {L - 1.0}]")
        f = lambda sa: self._curve(sa, D)[3] - D
        lo, hi = 0.6 * D, min(1.6 * D + 0.5, self.ph.total_sigma - 1.0)
        sa = brentq(f, lo, hi, xtol=1e-7)
        sm, cum_s, L_apex_s, depth, meta = self._curve(sa, D)
        s = np.arange(0.0, L + 1e-9, self.DS)
        arcs = L_apex_s - s
        pts = np.stack([np.interp(arcs, cum_s, sm[:, 0]), np.interp(arcs, cum_s, sm[:, 1])], -1)
        tan = np.gradient(pts, axis=0)
        tan = -tan / np.linalg.norm(tan, axis=1, keepdims=True)  # pointing towards the apex
        meta.update(depth_solved=float(depth))
        return {"s": s, "pts": pts, "tangent": tan, "rho": self.rho(s),
                "rho_outline": self.rho_outline(s), "depth_mm": float(D), "meta": meta}


def measure_truth(ph: Phantom, shape: dict, contact_tol_mm: float = 0.05, rho0: float | None = None,
                  coarse: int = 5):
    """The three angles measured on a centreline (stations ordered from the apex).

    gap(s) = distance(centreline(s), outer wall of its own turn) - rho(s); on the rounded tip
    (s < rho0) the gap is that of the cap sphere, i.e. the gap at s = rho0.  The contact run is
    the unbroken stretch from the apex with gap <= tol; theta_bot is theta of the centreline
    point where the gap crosses tol (interpolated between stations 0.01 mm apart).
    Gaps are evaluated every `coarse` stations and refined station by station at the crossing.
    """
    s, pts, rho = shape["s"], shape["pts"], shape["rho"]
    rho0 = float(rho[0]) if rho0 is None else rho0
    u = (pts - ph.p0) @ ph.T0
    inside = u > -ph.cfg.entry_len_mm          # stations in front of the mouth (in the channel)
    n_in = int(np.argmin(inside)) if not inside.all() else len(s)
    idx = np.unique(np.concatenate([np.arange(0, n_in, coarse), [n_in - 1]]))
    P = pts[idx]
    th = ph.theta_of_point(P)
    gap_o = ph.wall_distance(P, "outer", th) - rho[idx]
    gap_i = ph.wall_distance(P, "inner", th) - rho[idx]
    k_cap = int(round(rho0 / (s[1] - s[0])))
    g_cap = ph.wall_distance(pts[k_cap:k_cap + 1], "outer")[0] - rho[k_cap]
    g_cap_i = ph.wall_distance(pts[k_cap:k_cap + 1], "inner")[0] - rho[k_cap]
    cap = s[idx] < rho0
    gap_o[cap], gap_i[cap] = g_cap, g_cap_i

    def gap_at(k):  # fine gap at station k (cap rule included)
        if s[k] < rho0:
            return float(g_cap)
        return float(ph.wall_distance(pts[k:k + 1], "outer")[0] - rho[k])

    theta_tip = float(ph.theta_of_point(pts[0]))
    tol = contact_tol_mm
    if gap_o[0] <= tol:
        above = np.nonzero(gap_o > tol)[0]
        if len(above):
            j = int(above[0])
            k_lo, k_hi = int(idx[j - 1]), int(idx[j])
            ks = np.arange(k_lo, k_hi + 1)
            th_f = ph.theta_of_point(pts[ks])
            gf = ph.wall_distance(pts[ks], "outer", th_f) - rho[ks]
            gf[s[ks] < rho0] = g_cap
            m = int(np.nonzero(gf > tol)[0][0])
            fr = (tol - gf[m - 1]) / (gf[m] - gf[m - 1])
            pb = pts[ks[m - 1]] + fr * (pts[ks[m]] - pts[ks[m - 1]])
            s_bot = s[ks[m - 1]] + fr * (s[ks[m]] - s[ks[m - 1]])
        else:  # pragma: no cover - the whole inserted array touching
            pb, s_bot = pts[n_in - 1], s[n_in - 1]
        theta_bot = float(ph.theta_of_point(pb))
        in_contact = True
    else:
        pb, s_bot, theta_bot, in_contact = pts[0], 0.0, theta_tip, False
    return {"theta_tip": theta_tip, "theta_bot": theta_bot, "theta_con": theta_tip - theta_bot,
            "in_contact": in_contact, "tip_gap_mm": float(gap_o[0]), "bot_point_mm": pb,
            "s_bot_mm": float(s_bot), "s_gap_mm": s[idx], "gap_outer": gap_o, "gap_inner": gap_i,
            "n_inside": n_in, "min_gap_outer_mm": float(gap_o.min()),
            "min_gap_inner_mm": float(gap_i.min())}


# ----------------------------------------------------------------------------------------------
# pose
# ----------------------------------------------------------------------------------------------
@dataclass
class Pose:
    centre_x_px: float
    centre_y_px: float
    px_per_mm: float
    rotation_rad: float
    mirrored: bool

    def matrix(self):
        s, a = self.px_per_mm, self.rotation_rad
        m = -1.0 if self.mirrored else 1.0
        c, sn = math.cos(a), math.sin(a)
        return np.array([[s * c * m, -s * sn, self.centre_x_px],
                         [-s * sn * m, -s * c, self.centre_y_px]])

    def to_px(self, pts):
        pts = np.asarray(pts, float)
        A = self.matrix()
        return pts @ A[:, :2].T + A[:, 2]

    def to_mm(self, px):
        A = self.matrix()
        return (np.asarray(px, float) - A[:, 2]) @ np.linalg.inv(A[:, :2]).T

    def dir_px(self, v):
        A = self.matrix()
        d = np.asarray(v, float) @ A[:, :2].T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def as_dict(self):
        d = {"centre_x_px": float(self.centre_x_px), "centre_y_px": float(self.centre_y_px),
             "px_per_mm": float(self.px_per_mm), "rotation_rad": float(self.rotation_rad),
             "mirrored": bool(self.mirrored)}
        d["A_px_from_mm"] = self.matrix().tolist()
        return d


def sample_pose(ph, size, px_per_mm, rng, margin_mm=1.5):
    W, H = size
    rot = float(rng.uniform(-math.pi, math.pi))
    mir = bool(rng.random() < 0.5)
    u_scale = float(rng.random())
    u_x, u_y = float(rng.random()), float(rng.random())
    P = ph.extent_points()
    X = P[:, 0] * (-1 if mir else 1)
    c, s_ = math.cos(rot), math.sin(rot)
    Xr, Yr = c * X - s_ * P[:, 1], s_ * X + c * P[:, 1]
    bw = Xr.max() - Xr.min() + 2 * margin_mm
    bh = Yr.max() - Yr.min() + 2 * margin_mm
    s_max = min((W - 2) / bw, (H - 2) / bh)
    fits = True
    if px_per_mm is None:
        hi = min(40.0, s_max)
        s = 15.0 + u_scale * (hi - 15.0) if hi >= 15.0 else hi
        fits = hi >= 15.0
    else:
        s = float(px_per_mm)
    m = margin_mm * s
    lo_x, hi_x = m - s * Xr.min(), W - 1 - m - s * Xr.max()
    lo_y, hi_y = m + s * Yr.max(), H - 1 - m + s * Yr.min()
    cx = lo_x + u_x * (hi_x - lo_x) if hi_x >= lo_x else 0.5 * (lo_x + hi_x)
    cy = lo_y + u_y * (hi_y - lo_y) if hi_y >= lo_y else 0.5 * (lo_y + hi_y)
    return Pose(float(cx), float(cy), float(s), rot, mir), {"scale_max_fit": float(s_max),
                                                           "scale_range_ok": bool(fits)}

"""The clock offset between a video and its force log, and the settings of a sync.

The offset
----------
``video_t0_s`` from the manifest is used when the trial's cell is filled in (``t0="auto"``,
the default) and assumed exact. When it is blank, the offset is *estimated* (``t0="manifest"``
reads a blank cell as 0 s instead)
(:func:`estimate_offset`): a signal of the force log, ``y(t)``, is compared with a smooth
function of an angle measured in the video, ``x`` at the frame times ``t_k``:

    y(t_k + δ) ≈ β0 + β1 u_k + … + β4 u_k⁴,   u = (x − min x) / (max x − min x)

with ``y`` the robot's ``depth_mm`` against ``theta_tip`` when the log has a depth column
(kinematics, no sensor dynamics), otherwise ``force_g`` against ``theta_con``. ``y`` is first
smoothed with a centred moving average one frame period wide, then read at ``t_k + δ``. ``δ``
maximises R² of the least-squares link (β): a coarse grid over every offset that overlaps the
two records by at least ``min_overlap`` of the shorter one, then bounded scalar refinement.
A time shift of a ramp can be absorbed by the link, so the estimate is pinned mainly by the
*features* of the curves: the start of motion (depth) or of contact (θ_con leaves 0, a kink in
both signals), the stop, changes of slope. A pre-contact plateau in the video (θ_con = 0 exactly)
and some log before and after the video make the estimate much better. A depth ramp alone pins
nothing: a depth-based estimate needs a few measured frames of the robot standing
(:func:`still_frames`), and without them ``signal="auto"`` aligns the force instead, with a
warning.

Uncertainty: ``uncertainty_s = sqrt(stat_se_s² + angle_noise_s² + timing_se_s²)``.

- ``stat_se_s``: from the profile of the residual sum of squares ``S(δ)`` around the optimum:
  a parabola ``S ≈ S_min + a (δ − δ̂)²`` over ±2 frame periods gives ``Var δ̂ = σ² / a`` with
  ``σ² = S_min / (n − p − 1)``, inflated by ``(1 + ρ) / (1 − ρ)`` for the lag-1
  autocorrelation ρ of the residuals (effective sample size).
- ``angle_noise_s`` (force signal only): the time equivalent of one frame's angle noise,
  σ_x / |dx/dt| (σ_x from second differences, the rate from the 10–90 % rise). Noise in θ_con
  (errors in variables) and an exponential force that a quartic link does not quite fit bias
  δ̂ by about this much, and that bias does not average out over frames; on synthetic trials
  the force-based estimate comes out late by 0.3–1 of it. The depth-based estimate showed no
  such bias (its link is nearly linear), so the term is 0 there.
- ``timing_se_s = timing_fraction · frame period`` (default 1/√12: a frame's time stamp may
  be the start, middle or end of its exposure, a uniform ±½-frame ambiguity).

With a depth column, the force-based offset is also computed when possible and reported as
``offset_force_s``; ``force_lag_s = offset_force_s − offset_s`` then estimates how much later
the force responds than the robot (the diagnosis' ``sensor_lag``, plus the bias above). Without a
depth column the force-based offset *absorbs* any sensor lag: a table synced that way hides the
lag from a later diagnosis, so give ``video_t0_s`` (or log depth) when the lag matters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import pandas as pd

from tympani.pipeline.force.forcelog import ForceLogConfig
from tympani.pipeline.model.stats import mad_sd
from tympani.vision.errors import InputError

__all__ = [
    "SyncConfig",
    "OffsetEstimate",
    "frame_period",
    "still_frames",
    "MIN_STILL_FRAMES",
    "estimate_offset",
]


@dataclass(frozen=True)
class SyncConfig:
    """Settings of a sync (:func:`tympani.pipeline.force.sync.sync_manifest`) and of :func:`estimate_offset`.

    Parameters
    ----------
    t0 : {"auto", "manifest", "estimate"}
        Where the offset comes from: ``"auto"`` uses the manifest's ``video_t0_s`` when the
        trial's cell is filled in and estimates it otherwise; ``"manifest"`` always uses the
        manifest (a blank cell is 0 s); ``"estimate"`` always estimates.
    signal : {"auto", "depth", "force"}
        What the estimate aligns: ``"depth"`` (force log ``depth_mm`` against ``theta_tip``),
        ``"force"`` (``force_g`` against ``theta_con``), or ``"auto"`` (depth when the log has a
        usable depth column).
    max_gap_frames : float
        Longest interval between two measured frames that is interpolated across, in frame
        periods (3: up to two failed frames in a row are bridged).
    min_r2 : float
        Smallest R² (0–1) of the link fit for an accepted estimate.
    min_overlap : float
        Fraction (0–1) of the shorter record (video or log) the two must overlap.
    max_abs_offset_s : float or None
        Largest |offset| searched (s); None: every offset allowed by ``min_overlap``.
    link_degree : int
        Degree of the polynomial link between the scaled angle and the log signal.
    coarse_steps : int
        Offsets on the coarse grid (their spacing is never below a quarter frame period).
    timing_fraction : float
        Frame-time ambiguity as a fraction of the frame period (standard deviation).
    check_manifest_t0 : bool
        With a manifest offset, also estimate it and warn when they disagree by more than
        three uncertainties plus a frame period.
    force_log : ForceLogConfig
        How force logs are validated and cleaned.
    """

    t0: Literal["auto", "manifest", "estimate"] = "auto"
    signal: Literal["auto", "depth", "force"] = "auto"
    max_gap_frames: float = 3.0
    min_r2: float = 0.5
    min_overlap: float = 0.8
    max_abs_offset_s: float | None = None
    link_degree: int = 4
    coarse_steps: int = 600
    timing_fraction: float = 1.0 / math.sqrt(12.0)
    check_manifest_t0: bool = True
    force_log: ForceLogConfig = ForceLogConfig()

    def __post_init__(self) -> None:
        if self.t0 not in ("auto", "manifest", "estimate"):
            raise ValueError(f"t0 must be 'auto', 'manifest' or 'estimate', not {self.t0!r}")
        if self.signal not in ("auto", "depth", "force"):
            raise ValueError(f"signal must be 'auto', 'depth' or 'force', not {self.signal!r}")
        if self.max_gap_frames < 1.0:
            raise ValueError("max_gap_frames must be >= 1")
        if not 1 <= self.link_degree <= 8:
            raise ValueError("link_degree must be in 1..8")
        if not 0.0 < self.min_overlap <= 1.0:
            raise ValueError("min_overlap must be in (0, 1]")


@dataclass(frozen=True)
class OffsetEstimate:
    """An estimated clock offset.

    Parameters
    ----------
    offset_s : float
        ``video_t0_s``: force-clock time of video time 0 (s).
    uncertainty_s : float
        Standard uncertainty (s): ``sqrt(stat_se_s**2 + angle_noise_s**2 + timing_se_s**2)``.
    stat_se_s : float
        Statistical part (s), from the residuals (module docstring); inf when the fit does not
        pin the offset. When a depth log could not pin the offset and the force was aligned
        instead, the difference between the two alignments is added in quadrature.
    angle_noise_s : float
        Force signal only (0 for depth): the time equivalent of one frame's angle noise (s), for
        the errors-in-variables and link-shape bias, which does not average out over frames.
    timing_se_s : float
        Frame-time ambiguity part (s).
    signal : str
        ``"depth"`` or ``"force"``.
    r2 : float
        Coefficient of determination of the aligned link fit (0–1).
    frame_period_s : float
        Median frame period of the video (s).
    n_frames : int
        Measured frames used.
    search_s : tuple of float
        Offsets searched (s): (lowest, highest).
    offset_force_s : float or None
        With ``signal="depth"``: the force-based estimate (s), when it could be made.
    force_lag_s : float or None
        ``offset_force_s - offset_s`` (s): how much later the force responds than the robot.
    warnings : tuple of str
        One-line remarks.
    """

    offset_s: float
    uncertainty_s: float
    stat_se_s: float
    angle_noise_s: float
    timing_se_s: float
    signal: str
    r2: float
    frame_period_s: float
    n_frames: int
    search_s: tuple[float, float]
    offset_force_s: float | None = None
    force_lag_s: float | None = None
    warnings: tuple[str, ...] = ()


def frame_period(angles: pd.DataFrame) -> float:
    """Median interval between frames (s) of an angles table (all frames, measured or not)."""
    t = np.asarray(angles["time_s"], dtype=float)
    if t.size < 2:
        raise InputError("angles", "fewer than two frames: no frame period")
    return float(np.median(np.diff(t)))


# --------------------------------------------------------------------------- offset estimate


def _vander(u: np.ndarray, degree: int) -> np.ndarray:
    """Columns 1, u, u², …, u^degree."""
    return np.vander(u, degree + 1, increasing=True)


def _smooth(t: np.ndarray, y: np.ndarray, width_s: float) -> np.ndarray:
    """Centred moving average of ``y`` over ``width_s`` (s) on its own (irregular) clock."""
    if width_s <= 0 or t.size < 3:
        return y.copy()
    c = np.r_[0.0, np.cumsum(y)]
    lo = np.searchsorted(t, t - width_s / 2, side="left")
    hi = np.searchsorted(t, t + width_s / 2, side="right")
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


@dataclass(frozen=True, eq=False)
class _Problem:
    """One offset search: measured frames (video clock, increasing), their link design matrix,
    and the smoothed log signal (force clock).

    The frames inside the log for an offset are a contiguous run ``[i0, i1)``, so the Gram
    matrices ``XᵀX`` of every run come from cumulative sums and a fit costs one pass over y.
    """

    t_frames: np.ndarray
    X: np.ndarray
    t_log: np.ndarray
    y_log: np.ndarray

    def __post_init__(self) -> None:
        outer = self.X[:, :, None] * self.X[:, None, :]
        object.__setattr__(self, "_gram", np.concatenate([np.zeros((1, *outer.shape[1:])), np.cumsum(outer, axis=0)]))

    def window(self, delta: float) -> tuple[int, int]:
        """Frames ``[i0, i1)`` whose time + δ lies inside the log."""
        i0 = int(np.searchsorted(self.t_frames, self.t_log[0] - delta, side="left"))
        i1 = int(np.searchsorted(self.t_frames, self.t_log[-1] - delta, side="right"))
        return i0, max(i0, i1)

    def fit(self, delta: float, run: tuple[int, int] | None = None) -> tuple[float, float, np.ndarray]:
        """Residual sum of squares, total sum of squares and residuals of
        ``y(t_k + δ) ≈ X β`` on the frames of ``run`` (default: those inside the log)."""
        i0, i1 = self.window(delta) if run is None else run
        p = self.X.shape[1]
        if i1 - i0 <= p + 1:
            return math.inf, 0.0, np.empty(0)
        y = np.interp(self.t_frames[i0:i1] + delta, self.t_log, self.y_log)
        Xr = self.X[i0:i1]
        gram = self._gram[i1] - self._gram[i0]  # type: ignore[attr-defined]
        try:
            beta = np.linalg.solve(gram, Xr.T @ y)
        except np.linalg.LinAlgError:
            beta, *_ = np.linalg.lstsq(Xr, y, rcond=None)
        resid = y - Xr @ beta
        yc = y - y.mean()
        return float(resid @ resid), float(yc @ yc), resid

    def r2(self, delta: float, run: tuple[int, int] | None = None) -> float:
        rss, tss, _ = self.fit(delta, run)
        return 1.0 - rss / tss if tss > 0 and math.isfinite(rss) else 0.0


def _search_range(problem: _Problem, cfg: SyncConfig) -> tuple[float, float]:
    v0, v1 = problem.t_frames[0], problem.t_frames[-1]
    f0, f1 = problem.t_log[0], problem.t_log[-1]
    need = cfg.min_overlap * min(v1 - v0, f1 - f0)
    lo, hi = f0 - v1 + need, f1 - v0 - need
    if cfg.max_abs_offset_s is not None:
        lo, hi = max(lo, -cfg.max_abs_offset_s), min(hi, cfg.max_abs_offset_s)
    return float(lo), float(hi)


def _refine(f, lo: float, hi: float, tol: float) -> float:
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": tol})
    return float(res.x)


def _profile_se(problem: _Problem, delta: float, period: float) -> float:
    """Standard error of δ̂ (s) from the curvature of S(δ) over ±2 frame periods, with the
    residuals' lag-1 autocorrelation folded into an effective sample size."""
    half = 2.0 * period
    (a0, a1), (b0, b1) = problem.window(delta - half), problem.window(delta + half)
    run = (max(a0, b0), min(a1, b1))
    n, p = run[1] - run[0], problem.X.shape[1]
    if n < p + 8:
        return math.inf
    grid = np.linspace(-half, half, 21)
    s = np.array([problem.fit(delta + d, run)[0] for d in grid])
    a = float(np.polyfit(grid, s, 2)[0])
    s_min, _, resid = problem.fit(delta, run)
    if not a > 0:
        return math.inf
    sigma2 = s_min / (n - p - 1)
    rho = float(np.corrcoef(resid[:-1], resid[1:])[0, 1]) if np.var(resid) > 0 else 0.0
    rho = min(max(rho, 0.0), 0.99) if math.isfinite(rho) else 0.0
    return math.sqrt(sigma2 * (1 + rho) / (1 - rho) / a)


def _angle_noise_s(t: np.ndarray, x: np.ndarray) -> float:
    """Time equivalent (s) of one frame's angle noise: σ_x / typical |dx/dt|.

    σ_x is a robust estimate from second differences (MAD / √6); the rate is 80 % of the
    angle's range over the time it takes to go from 10 % to 90 % of it.
    """
    if x.size < 8:
        return math.inf
    d2 = np.diff(x, 2)
    sigma = mad_sd(d2) / math.sqrt(6.0)
    lo_v, span = float(np.min(x)), float(np.ptp(x))
    if not span > 0:
        return math.inf
    above10 = np.flatnonzero(x >= lo_v + 0.1 * span)
    above90 = np.flatnonzero(x >= lo_v + 0.9 * span)
    rise = float(t[above90[0]] - t[above10[0]]) if above10.size and above90.size else 0.0
    if not rise > 0:
        return 0.0
    return sigma / (0.8 * span / rise)


def _prepare(angles: pd.DataFrame, force: pd.DataFrame, signal: str, degree: int, where: str) -> tuple[_Problem, np.ndarray]:
    good = angles[angles["ok"].to_numpy(dtype=bool)]
    xcol = "theta_tip" if signal == "depth" else "theta_con"
    ycol = "depth_mm" if signal == "depth" else "force_g"
    t_frames = good["time_s"].to_numpy(dtype=float)
    x = good[xcol].to_numpy(dtype=float)
    if t_frames.size < 3 * (degree + 2):
        raise InputError(where, f"only {t_frames.size} measured frame(s); too few to estimate the clock offset")
    span = float(np.ptp(x))
    if not span > 0:
        raise InputError(where, f"{xcol} is constant over the video; cannot estimate the clock offset "
                                "(give video_t0_s in the manifest)")
    u = (x - x.min()) / span
    log = force
    if "saturated" in log.columns:
        log = log[~log["saturated"].to_numpy(dtype=bool)]
    log = log[np.isfinite(log[ycol].to_numpy(dtype=float))]
    t_log = log["time_s"].to_numpy(dtype=float)
    y = log[ycol].to_numpy(dtype=float)
    if t_log.size < 8 or not np.ptp(y) > 0:
        raise InputError(where, f"{ycol} of the force log is constant or too short; cannot estimate the clock offset")
    period = frame_period(angles)
    return _Problem(t_frames, _vander(u, degree), t_log, _smooth(t_log, y, period)), x


def _estimate_one(angles: pd.DataFrame, force: pd.DataFrame, signal: str, cfg: SyncConfig, where: str) -> OffsetEstimate:
    problem, x = _prepare(angles, force, signal, cfg.link_degree, where)
    period = frame_period(angles)
    lo, hi = _search_range(problem, cfg)
    if not hi > lo:
        raise InputError(where, "the video and the force log are too short to overlap by "
                                f"{100 * cfg.min_overlap:.0f}%; cannot estimate the clock offset")
    n_coarse = int(max(3, min(cfg.coarse_steps, math.ceil((hi - lo) / (period / 4)) + 1)))
    grid = np.linspace(lo, hi, n_coarse)
    scores = np.array([problem.r2(d) for d in grid])
    step = float(grid[1] - grid[0])
    delta = float(grid[int(np.argmax(scores))])
    delta = _refine(lambda d: -problem.r2(d), max(lo, delta - step), min(hi, delta + step), period / 1000)
    r2_best = problem.r2(delta)
    if r2_best < cfg.min_r2:
        what = "depth_mm vs theta_tip" if signal == "depth" else "force_g vs theta_con"
        raise InputError(where, f"{what} do not line up (best R² {r2_best:.2f} < {cfg.min_r2:.2f}); cannot "
                                "estimate the clock offset (give video_t0_s in the manifest)")
    stat = _profile_se(problem, delta, period)
    noise = _angle_noise_s(problem.t_frames, x) if signal == "force" else 0.0
    timing = cfg.timing_fraction * period
    warnings = []
    if not math.isfinite(stat):
        warnings.append("the fit does not pin the offset (flat residual profile)")
    if min(delta - lo, hi - delta) < 2 * period:
        warnings.append(f"the best offset {delta:.4g} s lies at the edge of the searched range [{lo:.4g}, {hi:.4g}] s")
    return OffsetEstimate(
        offset_s=delta,
        uncertainty_s=math.sqrt(stat * stat + noise * noise + timing * timing),
        stat_se_s=stat,
        angle_noise_s=noise,
        timing_se_s=timing,
        signal=signal,
        r2=r2_best,
        frame_period_s=period,
        n_frames=int(problem.t_frames.size),
        search_s=(lo, hi),
        warnings=tuple(warnings),
    )


def _has_depth(force: pd.DataFrame) -> bool:
    if "depth_mm" not in force.columns:
        return False
    d = force["depth_mm"].to_numpy(dtype=float)
    finite = np.isfinite(d)
    return bool(finite.mean() >= 0.8 and np.ptp(d[finite]) > 0) if finite.any() else False


def _motion_span(force: pd.DataFrame) -> tuple[float, float]:
    """Force-clock times (s) of the robot's first and last movement in the log's ``depth_mm``."""
    ok = np.isfinite(force["depth_mm"].to_numpy(dtype=float))
    t = force["time_s"].to_numpy(dtype=float)[ok]
    d = force["depth_mm"].to_numpy(dtype=float)[ok]
    tol = 1e-3 * float(np.ptp(d))  # a _has_depth log has ptp > 0
    left = np.flatnonzero(np.abs(d - d[0]) > tol)  # away from where it started
    arrived = np.flatnonzero(np.abs(d - d[-1]) > tol)  # not yet where it ended
    return float(t[max(left[0] - 1, 0)]), float(t[min(arrived[-1] + 1, t.size - 1)])


def still_frames(angles: pd.DataFrame, force: pd.DataFrame, offset_s: float) -> int:
    """Measured frames that, at offset ``offset_s``, fall where the log has the robot standing and
    show it standing.

    A constant-speed ramp of ``depth_mm`` against ``theta_tip`` fits equally well at any shift
    (the link absorbs it), so a depth-based offset is pinned only by frames from before the start
    or after the stop of the robot's motion. A group of such frames (before the start, after the
    stop) counts only when its ``theta_tip`` spans at most 4 times the angle noise (estimated from
    second differences) and is long enough for a moving tip to leave that band (8 noise SDs at the
    video's mean tip-angle rate): a video whose tip moves where the log stands contradicts the
    offset, and a few slow frames cannot tell standing from moving.

    Parameters
    ----------
    angles : DataFrame
        Angles table on the video clock (``time_s`` s, ``theta_tip`` rad, ``ok``).
    force : DataFrame
        Force log with ``time_s`` (s) and ``depth_mm`` (mm).
    offset_s : float
        ``video_t0_s`` (s).

    Returns
    -------
    int
        The larger of the two groups' frame counts (0 for a group that moves).
    """
    t0, t1 = _motion_span(force)
    t_log = force["time_s"].to_numpy(dtype=float)
    good = angles["ok"].to_numpy(dtype=bool)
    tf = angles["time_s"].to_numpy(dtype=float)[good] + offset_s
    x = angles["theta_tip"].to_numpy(dtype=float)[good]
    d2 = np.diff(x, 2)
    sigma = mad_sd(d2) / math.sqrt(6.0) if d2.size else 0.0
    inside = (tf >= t_log[0]) & (tf <= t_log[-1])
    # a group must be long enough that a moving tip would leave the 4-sigma band within it
    step = float(np.ptp(x)) / max(x.size - 1, 1)  # mean tip angle change a frame (rad)
    need = 8.0 * sigma / step if step > 0 else math.inf
    best = 0
    for group in (inside & (tf < t0), inside & (tf > t1)):
        n = int(np.count_nonzero(group))
        if n >= need and float(np.ptp(x[group])) <= 4.0 * sigma + 1e-12:
            best = max(best, n)
    return best


#: Fewest measured frames of the robot standing for a depth-based offset (see :func:`still_frames`).
MIN_STILL_FRAMES = 3


def estimate_offset(
    angles: pd.DataFrame, force: pd.DataFrame, *, cfg: SyncConfig = SyncConfig(), where: str = "sync"
) -> OffsetEstimate:
    """Estimate ``video_t0_s`` (force-clock time of video time 0) from the data.

    Parameters
    ----------
    angles : DataFrame
        Angles table on the video clock (``time_s`` s, angles rad, ``ok``).
    force : DataFrame
        Force log as read by :func:`~tympani.pipeline.force.forcelog.read_force_log` (``time_s`` s,
        ``force_g`` g, optional ``depth_mm`` mm and ``saturated``).
    cfg : SyncConfig
        ``signal``, ``min_r2``, ``min_overlap``, ``max_abs_offset_s``, ``link_degree``,
        ``coarse_steps``, ``timing_fraction`` are used.
    where : str
        Prefix of error messages (a file or ``"manifest.csv:4"``).

    Returns
    -------
    OffsetEstimate
        Offset (s), its uncertainty (s) and how it was found (see the module docstring).

    Raises
    ------
    InputError
        The data cannot pin the offset (too few frames, no variation, no overlap, R² below
        ``cfg.min_r2``; for depth, too few frames of the robot standing, see :func:`still_frames`,
        in which case ``signal="auto"`` falls back to the force).
    """
    signal = cfg.signal
    if signal == "auto":
        signal = "depth" if _has_depth(force) else "force"
    elif signal == "depth" and not _has_depth(force):
        raise InputError(where, "signal 'depth' asked for, but the force log has no usable depth_mm column")
    est = _estimate_one(angles, force, signal, cfg, where)
    if signal == "depth" and still_frames(angles, force, est.offset_s) < MIN_STILL_FRAMES:
        why = (f"the video shows fewer than {MIN_STILL_FRAMES} measured frames of the robot standing (before its "
               "start or after its stop), so depth_mm cannot pin the offset")
        if cfg.signal == "depth":
            raise InputError(where, f"{why}; give video_t0_s in the manifest")
        try:
            by_force = _estimate_one(angles, force, "force", cfg, where)
        except InputError as exc:
            raise InputError(where, f"{why}, and force_g against theta_con failed too ({exc.problem}); "
                                    "give video_t0_s in the manifest") from None
        # neither alignment is pinned by a feature of the motion: their disagreement is part of the error
        spread = by_force.offset_s - est.offset_s
        stat = math.hypot(by_force.stat_se_s, spread)
        return replace(by_force, stat_se_s=stat,
                       uncertainty_s=math.sqrt(stat**2 + by_force.angle_noise_s**2 + by_force.timing_se_s**2),
                       warnings=by_force.warnings + (
                           f"{why}: aligned force_g on theta_con instead (this absorbs any sensor lag); the depth "
                           f"alignment differs by {spread:+.3g} s, which is counted in the uncertainty",))
    if signal == "depth":
        try:
            other = _estimate_one(angles, force, "force", cfg, where)
        except InputError:
            return est
        est = replace(est, offset_force_s=other.offset_s, force_lag_s=other.offset_s - est.offset_s)
    return est

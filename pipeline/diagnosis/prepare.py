"""The first step of the gap diagnosis: a synced table checked, smoothed, subsampled and made
ready for many fits (:class:`Prepared`).

Rows where the robot stands (before the start and in a dwell after the stop, found from
``depth_mm`` when present) are kept with an instantaneous speed of 0: the base model then uses
``mu(0) = mu_s`` (friction.py's convention), drag vanishes, a lagging sensor relaxes, drift goes
on; lift keeps the trial's run speed (its film takes seconds to squeeze out). These rows carry
the clearest signatures of lag and drift.

Geometry integrals are computed once per dataset (:func:`tympani.pipeline.model.friction.arc_integrals`)
and trials are subsampled to :attr:`tympani.pipeline.diagnosis.config.DiagnosisConfig.rows_per_trial` rows
evenly in time.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from tympani.pipeline.diagnosis.config import CONTACT_WIDTH_MM, DATA_NEEDED, PHASES, DiagnosisConfig
from tympani.pipeline.model.data_needs import has_contact_angles, require
from tympani.pipeline.model.effects import EffectContext
from tympani.pipeline.model.friction import G_N, FrictionMode, FrictionParams, arc_integrals, contact_geometry, stribeck
from tympani.pipeline.model.identify import SYNCED_COLUMNS, not_moving, validate_synced
from tympani.vision.errors import InputError
from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom

__all__ = ["Prepared", "ArcQuadrature", "prepare", "smooth_angles"]


@dataclass(frozen=True, eq=False)
class Prepared:
    """A synced table made ready for many fits (subsampled, with its geometry integrals).

    Attributes
    ----------
    rows : pandas.DataFrame
        The subsampled rows (the synced table's columns + ``v_inst_mm_s``, ``phase``, ``phase_label``,
        ``elapsed_s``), sorted by trial and time.
    y : ndarray
        Measured force (g).
    speed : ndarray
        Nominal speed (mm/s) per row.
    v_inst : ndarray
        Instantaneous speed (mm/s): 0 where the robot stands.
    speeds : ndarray
        Distinct nominal speeds (mm/s), increasing.
    speed_idx : ndarray of int
        Index into ``speeds`` per row.
    mu_speeds, mu_idx : ndarray
        Distinct instantaneous speeds (mm/s) and the index of each row's.
    trial : ndarray of int
        Trial code per row (0..T-1).
    trial_names : ndarray of str
        Name per trial code.
    trial_speed : ndarray
        Nominal speed (mm/s) per trial.
    trial_speed_idx : ndarray of int
        Index into ``speeds`` per trial.
    theta_con : ndarray
        Contact angle (rad) per row (theta_tip - theta_bot, >= 0).
    theta_hi : float
        Largest contact angle (rad): pressures are parametrised by their values at 0 and here.
    a_n, a_t : ndarray, shape (n, 4)
        Normal and friction parts of the force per unit of the four pressure coordinates (g/MPa):
        the force is ``(a_n + mu a_t) @ u``.
    ctx : EffectContext
        The effects' context (wetted length, bump integrals, trial order).
    elapsed_s : ndarray
        Time (s) since the start of the trial's log.
    since_start_s, since_stop_s : ndarray
        Time (s) since the robot started and since it stopped (negative before; ``-inf`` since the
        stop when the trial has no standing rows after its motion, or standing is unknown).
    load_time_g_s : ndarray
        Integral of the measured force over time from the trial's log start (g s).
    phase : ndarray
        Normalised time within the moving part of the trial (0 at the start, 1 at the stop;
        clipped for standing rows).
    phase_label : ndarray of int
        Index into :data:`tympani.pipeline.diagnosis.config.PHASES` per row.
    lag_groups : tuple
        ``(index (T_g, m), valid (T_g, m), dt_s)`` per group of trials with one sample period.
    quad : ArcQuadrature
        Midpoint nodes on every row's contact arc (for effects that act along the arc).
    entry_wetted_mm : ndarray
        Length of array in the entry channel (mm), 0..entry length.
    l_con_mm : ndarray
        Contact arc length on the outer wall (mm).
    standing_known : bool
        Whether standing rows could be found (``depth_mm`` present).
    notes : tuple of str
        What was dropped or looks odd.
    n_rows_in : int
        Usable rows before subsampling.
    """

    rows: pd.DataFrame
    y: np.ndarray
    speed: np.ndarray
    v_inst: np.ndarray
    speeds: np.ndarray
    speed_idx: np.ndarray
    mu_speeds: np.ndarray
    mu_idx: np.ndarray
    trial: np.ndarray
    trial_names: np.ndarray
    trial_speed: np.ndarray
    trial_speed_idx: np.ndarray
    theta_con: np.ndarray
    theta_hi: float
    a_n: np.ndarray
    a_t: np.ndarray
    ctx: EffectContext
    elapsed_s: np.ndarray
    phase: np.ndarray
    phase_label: np.ndarray
    since_start_s: np.ndarray
    since_stop_s: np.ndarray
    load_time_g_s: np.ndarray
    lag_groups: tuple
    quad: "ArcQuadrature"
    entry_wetted_mm: np.ndarray
    l_con_mm: np.ndarray
    standing_known: bool
    notes: tuple[str, ...]
    n_rows_in: int

    @property
    def n(self) -> int:
        """Rows."""
        return len(self.y)

    @property
    def n_trials(self) -> int:
        """Trials."""
        return len(self.trial_names)

    def friction_coefficient(self, law: FrictionParams) -> np.ndarray:
        """Friction coefficient (dimensionless) of ``law`` per row at the row's instantaneous speed.

        Parameters
        ----------
        law : FrictionParams
            The friction law (:func:`tympani.pipeline.model.friction.stribeck`).

        Returns
        -------
        ndarray, shape (n,)
        """
        return stribeck(self.mu_speeds, law)[self.mu_idx]


@dataclass(frozen=True, eq=False)
class ArcQuadrature:
    """Midpoint quadrature nodes on the contact arcs (outer wall) of every row.

    Attributes
    ----------
    u : ndarray, shape (m,)
        Node positions as a fraction of the arc from the tip (``s / l_con`` of the paper's Eq. 6).
    gn, gt : ndarray, shape (n, m)
        ``n_out . x_w`` and ``t . x_w`` at the nodes (dimensionless).
    dtheta : ndarray, shape (n, m)
        Wrap angle (rad) from the contact start to the node.
    ds : ndarray, shape (n,)
        Node length (mm): ``l_con / m``.
    w1 : ndarray, shape (n,)
        ``theta_con / theta_hi`` (the weight of the pressures' values at theta_hi).
    """

    u: np.ndarray
    gn: np.ndarray
    gt: np.ndarray
    dtheta: np.ndarray
    ds: np.ndarray
    w1: np.ndarray


def _arc_quadrature(theta_bot: np.ndarray, theta_tip: np.ndarray, theta_hi: float, phantom: Phantom,
                    friction_mode: FrictionMode, nodes: int = 12) -> ArcQuadrature:
    geom = contact_geometry(phantom)
    s_b, s_t = geom.wall_s(theta_bot), geom.wall_s(theta_tip)
    length = np.maximum(s_t - s_b, 0.0)
    u = (np.arange(nodes) + 0.5) / nodes
    s = s_t[:, None] - u[None, :] * length[:, None]
    k = np.clip(np.searchsorted(geom.s, s, side="right") - 1, 0, len(geom.s) - 2)
    theta = np.interp(s, geom.s, geom.theta)
    dtheta = np.maximum(theta - np.interp(s_b, geom.s, geom.theta)[:, None], 0.0)
    w1 = np.clip((theta_tip - theta_bot) / theta_hi, 0.0, None)
    gt = geom.seg_g[k, 1] if friction_mode == "vector" else np.ones_like(s)
    return ArcQuadrature(u=u, gn=geom.seg_g[k, 0], gt=gt, dtheta=dtheta, ds=length / nodes, w1=w1)


def _subsample_index(n_rows: int, keep: int) -> np.ndarray:
    """At most ``keep`` indices of ``range(n_rows)`` with one constant stride (uniform in time for
    an evenly sampled log, so the lag filter's steps are exact), ending on the last row."""
    stride = max(1, math.ceil(n_rows / keep))
    return np.arange((n_rows - 1) % stride, n_rows, stride)


def _pressure_design(arcs, theta_con: np.ndarray, theta_hi: float,
                     friction_mode: FrictionMode) -> tuple[np.ndarray, np.ndarray]:
    """``a_n, a_t`` (g/MPa): the force is ``(a_n + mu a_t) @ u`` with ``u`` the pressures
    ``(p_tip(0), p_tip(theta_hi), p_bot(0), p_bot(theta_hi))`` (MPa), linear in theta_con."""
    k = CONTACT_WIDTH_MM / G_N
    w1 = np.clip(theta_con / theta_hi, 0.0, None)
    w0 = 1.0 - w1

    def part(col: int) -> np.ndarray:
        tip = arcs.g0[:, col] - arcs.g1[:, col]
        bot = arcs.g1[:, col]
        return k * np.stack([tip * w0, tip * w1, bot * w0, bot * w1], axis=1)

    return part(0), part(1 if friction_mode == "vector" else 2)


def _lag_groups(trial: np.ndarray, time_s: np.ndarray) -> tuple:
    """Trials grouped by sample period, as padded index arrays (rows sorted by trial, time)."""
    starts = np.flatnonzero(np.r_[True, trial[1:] != trial[:-1]])
    ends = np.r_[starts[1:], len(trial)]
    by_dt: dict[float, list[tuple[int, int]]] = {}
    for lo, hi in zip(starts, ends):
        dt = float(np.median(np.diff(time_s[lo:hi]))) if hi - lo > 1 else 1.0
        by_dt.setdefault(float(f"{max(dt, 1e-9):.6g}"), []).append((lo, hi))
    groups = []
    for dt, spans in by_dt.items():
        m = max(hi - lo for lo, hi in spans)
        index = np.empty((len(spans), m), dtype=int)
        valid = np.zeros((len(spans), m), dtype=bool)
        for i, (lo, hi) in enumerate(spans):
            index[i, : hi - lo] = np.arange(lo, hi)
            index[i, hi - lo:] = hi - 1
            valid[i, : hi - lo] = True
        groups.append((index, valid, dt))
    return tuple(groups)


def _phases(trial: np.ndarray, time_s: np.ndarray, standing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised moving time (0..1) and the :data:`tympani.pipeline.diagnosis.config.PHASES` label per row."""
    t = pd.Series(time_s)
    moving_t = t.where(~standing)
    first = moving_t.groupby(trial).transform("min").to_numpy()
    last = moving_t.groupby(trial).transform("max").to_numpy()
    first = np.where(np.isfinite(first), first, t.groupby(trial).transform("min").to_numpy())
    last = np.where(np.isfinite(last), last, t.groupby(trial).transform("max").to_numpy())
    span = np.where(last > first, last - first, 1.0)
    phase = np.clip((time_s - first) / span, 0.0, 1.0)
    label = np.where(standing & (time_s < first), 0, np.where(standing & (time_s > last), 4,
                     1 + np.minimum((phase * 3).astype(int), 2)))
    return phase, label


def _motion_clock(trial: np.ndarray, time_s: np.ndarray, standing: np.ndarray,
                  label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) since the robot started and since it stopped, per row.

    The start is the trial's first moving row (its first row when nothing stands); the stop is the
    first row of the dwell (``-inf`` since the stop when the trial has none).
    """
    t = pd.Series(time_s)
    start = t.where(~standing).groupby(trial).transform("min").to_numpy()
    start = np.where(np.isfinite(start), start, t.groupby(trial).transform("min").to_numpy())
    stop = t.where(label == PHASES.index("dwell")).groupby(trial).transform("min").to_numpy()
    since_stop = np.where(np.isfinite(stop), time_s - stop, -np.inf)
    return time_s - start, since_stop


def smooth_angles(data: pd.DataFrame, width_s: float) -> pd.DataFrame:
    """Each trial's ``theta_tip`` and ``theta_bot`` smoothed in time; ``theta_con`` recomputed.

    A quadratic Savitzky–Golay filter over ``width_s`` (rounded to an odd number of samples at the
    trial's median sampling interval) on the finite values of each trial, sorted by time; trials
    with fewer samples than the window are left as they are.

    Parameters
    ----------
    data : pandas.DataFrame
        Synced rows (``trial``, ``time_s`` s, ``theta_tip`` and ``theta_bot`` rad).
    width_s : float
        Window width (s); 0 returns ``data`` unchanged.

    Returns
    -------
    pandas.DataFrame
        A copy with smoothed angles (same rows, same order).
    """
    if width_s <= 0:
        return data
    out = data.copy()
    t_all = out["time_s"].to_numpy(float)
    cols = {c: out[c].to_numpy(float).copy() for c in ("theta_tip", "theta_bot")}
    for idx in out.groupby("trial", sort=False).indices.values():
        idx = idx[np.argsort(t_all[idx], kind="stable")]
        dt = float(np.median(np.diff(t_all[idx]))) if idx.size > 1 else 0.0
        n = int(round(width_s / dt)) | 1 if dt > 0 else 0
        for x in cols.values():
            ok = idx[np.isfinite(x[idx])]
            if n >= 5 and ok.size > n:
                x[ok] = savgol_filter(x[ok], n, 2, mode="interp")
    for c, x in cols.items():
        out[c] = x
    out["theta_con"] = (out["theta_tip"] - out["theta_bot"]).clip(lower=0.0)
    return out


def prepare(
    table: pd.DataFrame,
    config: DiagnosisConfig = DiagnosisConfig(),
    *,
    source: str | os.PathLike = "<synced table>",
    phantom: Phantom = DEFAULT_PHANTOM,
) -> Prepared:
    """Check a synced table and prepare it for the diagnosis.

    Parameters
    ----------
    table : pandas.DataFrame
        Synced table (``trial``, ``speed_mm_s`` mm/s, ``time_s`` s, ``force_g`` g,
        ``theta_tip``, ``theta_bot``, ``theta_con`` rad; optional ``depth_mm`` mm, which marks the
        rows where the robot stands).
    config : DiagnosisConfig
        Subsampling and data requirements.
    source : str or PathLike
        Named in input errors.
    phantom : Phantom
        Geometry (mm, rad).

    Returns
    -------
    Prepared

    Raises
    ------
    vision.errors.InputError
        Not a valid synced table, too few speeds or repeats, or a constant force (the message says
        what data the diagnosis needs).
    """
    missing = [c for c in SYNCED_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(source, f"missing column(s) {', '.join(missing)}; {DATA_NEEDED}")
    if not has_contact_angles(table):  # tip-only angle tracks: say all the data lack, in one line
        require(table, source, "the diagnosis", min_speeds=config.min_speeds,
                min_trials_per_speed=config.min_trials_per_speed)
    raw_time = pd.to_numeric(table["time_s"], errors="coerce")
    log_start = raw_time.groupby(table["trial"].astype(str)).min()
    data, notes = validate_synced(table, source, min_rows=20, moving_only=False)
    force = data["force_g"].to_numpy(float)
    if np.ptp(force) <= 1e-9 * max(1.0, float(np.max(np.abs(force)))):
        raise InputError(source, f"force_g is constant ({force[0]:.6g} g) in every usable row; {DATA_NEEDED}")
    per_trial = data.groupby("trial")["speed_mm_s"].agg(["nunique", "first", "size"])
    if (per_trial["nunique"] > 1).any():
        bad = per_trial.index[per_trial["nunique"] > 1][0]
        raise InputError(source, f"trial {bad} has more than one speed_mm_s; each trial must be one insertion at one "
                                 f"speed")
    short = per_trial.index[per_trial["size"] < 4]
    if len(short):
        notes.append(f"{len(short)} trial(s) with fewer than 4 usable rows were left out")
        data = data[~data["trial"].isin(short)]
        per_trial = per_trial.drop(short)
    counts = per_trial.groupby("first").size()
    enough = counts[counts >= config.min_trials_per_speed]
    if len(enough) < config.min_speeds:
        found = ", ".join(f"{s:g} mm/s ({n} trial{'s' if n != 1 else ''})" for s, n in counts.items()) or "none"
        raise InputError(source, f"{DATA_NEEDED} (to fit on some speeds, hold one out and measure the scatter "
                                 f"between repeats); found {found}")
    if len(enough) < len(counts):
        dropped = [f"{s:g}" for s in counts.index if s not in enough.index]
        notes.append(f"speed(s) {', '.join(dropped)} mm/s with fewer than {config.min_trials_per_speed} trials were "
                     f"left out")
        data = data[data["speed_mm_s"].isin(enough.index)]
    if np.ptp(data["force_g"].to_numpy(float)) <= 0:
        raise InputError(source, f"force_g is constant in every usable row; {DATA_NEEDED}")
    data = smooth_angles(data.reset_index(drop=True), config.angle_smoothing_s)
    standing_known = "depth_mm" in data.columns and pd.to_numeric(data["depth_mm"], errors="coerce").notna().any()
    standing_all = not_moving(data) if standing_known else np.zeros(len(data), dtype=bool)

    groups = data.groupby("trial", sort=True).indices
    load_time = np.zeros(len(data))
    t_all, f_all = data["time_s"].to_numpy(float), np.clip(data["force_g"].to_numpy(float), 0.0, None)
    for idx in groups.values():  # integral of the force over time from the log's start (g s), per trial
        order = idx[np.argsort(t_all[idx], kind="stable")]
        steps = 0.5 * (f_all[order][1:] + f_all[order][:-1]) * np.diff(t_all[order])
        load_time[order] = np.concatenate([[0.0], np.cumsum(steps)])
    keep = [idx[_subsample_index(len(idx), config.rows_per_trial)] for idx in groups.values()]
    pick = np.concatenate(keep)
    rows = data.iloc[pick].reset_index(drop=True)
    standing = standing_all[pick]
    rows["theta_con"] = (rows["theta_tip"] - rows["theta_bot"]).clip(lower=0.0)
    trial_codes, trial_names = pd.factorize(rows["trial"], sort=True)
    time_s = rows["time_s"].to_numpy(float)
    phase, label = _phases(trial_codes, time_s, standing)
    since_start, since_stop = _motion_clock(trial_codes, time_s, standing, label)
    start = log_start.reindex(rows["trial"].astype(str)).to_numpy(float)
    t_first = pd.Series(time_s).groupby(trial_codes).transform("min").to_numpy()
    speed = rows["speed_mm_s"].to_numpy(float)
    v_inst = np.where(standing, 0.0, speed)
    rows["v_inst_mm_s"] = v_inst
    rows["phase"] = phase
    rows["phase_label"] = label
    rows["elapsed_s"] = time_s - np.where(np.isfinite(start), start, t_first)

    theta_con = rows["theta_con"].to_numpy(float)
    theta_hi = float(max(theta_con.max(), 1e-3))
    bot_r, tip_r = rows["theta_bot"].to_numpy(float), rows["theta_tip"].to_numpy(float)
    arcs = arc_integrals(bot_r, tip_r, phantom)
    a_n, a_t = _pressure_design(arcs, theta_con, theta_hi, config.friction_mode)
    quad = _arc_quadrature(bot_r, tip_r, theta_hi, phantom, config.friction_mode)
    if "depth_mm" in rows.columns and rows["depth_mm"].notna().any():
        depth = pd.to_numeric(rows["depth_mm"], errors="coerce").to_numpy(float)
        entry = np.clip(np.nan_to_num(depth) + phantom.entry_length_mm, 0.0, phantom.entry_length_mm)
    else:  # in contact or in the spiral: the whole entry channel is wetted
        entry = np.where(tip_r > phantom.theta_start, phantom.entry_length_mm, 0.0)
    speeds = np.unique(speed)
    mu_speeds, mu_idx = np.unique(v_inst, return_inverse=True)
    ctx = EffectContext.from_synced(rows, phantom)
    trial_speed = pd.Series(speed).groupby(trial_codes).first().to_numpy()
    if standing_known and standing.any():
        notes.append(f"{int(standing.sum())} of {len(rows)} fitted rows are before the start or in a dwell after the "
                     f"stop (robot standing, from depth_mm): speed 0 there")
    return Prepared(
        rows=rows, y=rows["force_g"].to_numpy(float), speed=speed, v_inst=v_inst, speeds=speeds,
        speed_idx=np.searchsorted(speeds, speed), mu_speeds=mu_speeds, mu_idx=mu_idx.ravel(), trial=trial_codes,
        trial_names=np.asarray(trial_names, dtype=str), trial_speed=trial_speed,
        trial_speed_idx=np.searchsorted(speeds, trial_speed), theta_con=theta_con, theta_hi=theta_hi,
        a_n=a_n, a_t=a_t, ctx=ctx, elapsed_s=rows["elapsed_s"].to_numpy(float), phase=phase,
        phase_label=label, since_start_s=since_start, since_stop_s=since_stop, load_time_g_s=load_time[pick],
        lag_groups=_lag_groups(trial_codes, time_s), quad=quad, entry_wetted_mm=entry,
        l_con_mm=np.nan_to_num(arcs.length_mm), standing_known=bool(standing_known),
        notes=tuple(notes), n_rows_in=len(data),
    )


"""Figures of the force side (the seed paper's Figs. 9–15), as PNG files.

- :func:`plot_force_vs_theta_con`: measured force against θ_con, one panel per speed, with the
  simulated force overlaid (Figs. 9–11);
- :func:`plot_log_force`: ln F against θ_con, all speeds, with the Eq. (8) lines (Fig. 12);
- :func:`plot_bounds`: per speed, the samples, the Eq. (9) curve, its 95 % confidence band and
  the 95 % prediction band (the safety boundary) (Figs. 13–15).

Every function builds its own figure with ``plt.subplots``, saves it and closes it: no pyplot
state is left behind, and the Agg backend is selected before pyplot is imported (no display
needed).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Sequence, Union

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pipeline.bounds import SpeedFit, bands  # noqa: E402

__all__ = ["Simulated", "simulated_table", "plot_force_vs_theta_con", "plot_log_force", "plot_bounds", "write_figures"]

#: Simulated forces: a SPEC §6 simulation table (``speed_mm_s``, ``theta_con`` rad, ``force_g``
#: g), or a callable ``speeds_mm_s -> such a table`` (e.g.
#: ``lambda v: pipeline.friction.simulate("S4", v)``).
Simulated = Union[pd.DataFrame, Callable[[Sequence[float]], pd.DataFrame], None]

_MAX_POINTS = 4000  # per panel and trial group: thin dense logs so PNGs stay small


def simulated_table(simulated: Simulated, speeds_mm_s: Sequence[float]) -> pd.DataFrame | None:
    """The simulated forces as a table (``speed_mm_s``, ``theta_con``, ``force_g``), or None."""
    if simulated is None:
        return None
    table = simulated(list(speeds_mm_s)) if callable(simulated) else simulated
    missing = [c for c in ("speed_mm_s", "theta_con", "force_g") if c not in table.columns]
    if missing:
        raise ValueError(f"simulated forces need columns speed_mm_s, theta_con, force_g (missing {', '.join(missing)})")
    return table


def _speeds(synced: pd.DataFrame) -> list[float]:
    return sorted(float(v) for v in synced["speed_mm_s"].round(9).unique())


def _grid(n: int) -> tuple[int, int]:
    cols = min(n, 3)
    return (n + cols - 1) // cols, cols


def _thin(df: pd.DataFrame, limit: int = _MAX_POINTS) -> pd.DataFrame:
    return df if len(df) <= limit else df.iloc[:: int(np.ceil(len(df) / limit))]


def _panels(n: int, *, sharey: bool = False):
    rows, cols = _grid(n)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False, sharey=sharey)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()[:n]


def _at_speed(df: pd.DataFrame, speed: float) -> pd.DataFrame:
    return df[np.isclose(df["speed_mm_s"].to_numpy(dtype=float), speed, rtol=0, atol=1e-9)]


def _save(fig, path: str | os.PathLike) -> Path:
    from pipeline.io import atomic_open

    out = Path(path)
    try:
        fig.tight_layout()
        with atomic_open(out, "wb") as fh:
            fig.savefig(fh, format="png", dpi=110)
    finally:
        plt.close(fig)
    return out


def plot_force_vs_theta_con(synced: pd.DataFrame, path: str | os.PathLike, *, simulated: Simulated = None) -> Path:
    """Measured force against θ_con per speed, with the simulation overlaid (Figs. 9–11).

    Parameters
    ----------
    synced : DataFrame
        Synced table: ``speed_mm_s`` (mm/s), ``theta_con`` (rad), ``force_g`` (g), ``trial``.
    path : str or PathLike
        PNG to write.
    simulated : DataFrame or callable, optional
        Simulated forces (see :data:`Simulated`); drawn as a line per speed.

    Returns
    -------
    Path
        The PNG.
    """
    speeds = _speeds(synced)
    sim = simulated_table(simulated, speeds)
    fig, axes = _panels(len(speeds), sharey=True)
    for ax, v in zip(axes, speeds):
        part = _at_speed(synced, v)
        part = part[np.isfinite(part["theta_con"]) & np.isfinite(part["force_g"])]
        for _, trial in part.groupby("trial", sort=True) if "trial" in part.columns else [(None, part)]:
            t = _thin(trial)
            ax.plot(t["theta_con"], t["force_g"], ".", ms=1.5, alpha=0.35, color="tab:blue")
        ax.plot([], [], ".", color="tab:blue", label=f"measured ({part['trial'].nunique() if 'trial' in part else 1} trials)")
        if sim is not None:
            s = _at_speed(sim, v).sort_values("theta_con")
            if len(s):
                label = f"simulated ({s['scenario'].iloc[0]})" if "scenario" in s.columns else "simulated"
                ax.plot(s["theta_con"], s["force_g"], "-", color="tab:red", lw=2, label=label)
        ax.set_title(f"{v:g} mm/s")
        ax.set_xlabel("θ_con (rad)")
        ax.set_ylabel("force (g)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle("Insertion force against contact angle")
    return _save(fig, path)


def plot_log_force(synced: pd.DataFrame, fits: Sequence[SpeedFit], path: str | os.PathLike) -> Path:
    """ln F against θ_con for all speeds with the Eq. (8) lines (Fig. 12).

    Parameters
    ----------
    synced : DataFrame
        Synced table (``speed_mm_s`` mm/s, ``theta_con`` rad, ``force_g`` g); only samples
        with F > 0 and θ_con > 0 are drawn.
    fits : sequence of SpeedFit
        Eq. (8) fits (:func:`pipeline.bounds.fit_bounds`).
    path : str or PathLike
        PNG to write.

    Returns
    -------
    Path
    """
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    cmap = plt.get_cmap("viridis")
    speeds = _speeds(synced)
    by_speed = {round(f.speed_mm_s, 9): f for f in fits}
    for i, v in enumerate(speeds):
        color = cmap(0.85 * i / max(len(speeds) - 1, 1))  # stop short of viridis' pale yellow
        part = _at_speed(synced, v)
        part = _thin(part[(part["theta_con"] > 0) & (part["force_g"] > 0)])
        ax.plot(part["theta_con"], np.log(part["force_g"]), ".", ms=1.5, alpha=0.25, color=color)
        fit = by_speed.get(round(v, 9))
        if fit is not None:
            th = np.linspace(fit.theta_con_min, fit.theta_con_max, 50)
            ax.plot(th, fit.c1 + fit.c2 * th, "-", lw=2, color=color,
                    label=f"{v:g} mm/s: ln F = {fit.c1:.2f} + {fit.c2:.2f} θ_con")
    ax.set_xlabel("θ_con (rad)")
    ax.set_ylabel("ln F (F in g)")
    ax.set_title("Eq. (8): log force against contact angle")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_bounds(synced: pd.DataFrame, fits: Sequence[SpeedFit], path: str | os.PathLike) -> Path:
    """Per speed: samples, Eq. (9) curve, 95 % confidence band and prediction band (Figs. 13–15).

    The prediction band (light) is the safety boundary: where one force sample of a new
    insertion is expected; the confidence band (dark) is where the median curve lies.

    Parameters
    ----------
    synced : DataFrame
        Synced table (``speed_mm_s`` mm/s, ``theta_con`` rad, ``force_g`` g).
    fits : sequence of SpeedFit
        Eq. (8) fits.
    path : str or PathLike
        PNG to write.

    Returns
    -------
    Path
    """
    fig, axes = _panels(max(len(fits), 1), sharey=True)
    if not fits:
        axes[0].text(0.5, 0.5, "no speed could be fitted", ha="center", va="center", transform=axes[0].transAxes)
    for ax, fit in zip(axes, fits):
        part = _at_speed(synced, fit.speed_mm_s)
        part = _thin(part[(part["theta_con"] > 0) & np.isfinite(part["force_g"])])
        ax.plot(part["theta_con"], part["force_g"], ".", ms=1.5, alpha=0.3, color="0.4", label="samples")
        b = bands(fit, np.linspace(fit.theta_con_min, fit.theta_con_max, 101))
        pct = f"{100 * fit.level:g}%"
        ax.fill_between(b["theta_con"], b["pi_lo_g"], b["pi_hi_g"], color="tab:orange", alpha=0.25,
                        label=f"{pct} prediction (safety bound)")
        ax.fill_between(b["theta_con"], b["ci_lo_g"], b["ci_hi_g"], color="tab:blue", alpha=0.45,
                        label=f"{pct} confidence (curve)")
        ax.plot(b["theta_con"], b["f_fit_g"], "-", color="tab:blue", lw=1.5, label="exp(c1 + c2 θ_con)")
        ax.set_title(f"{fit.speed_mm_s:g} mm/s (n={fit.n}, {fit.n_trials} trials, SE: {fit.se_method})", fontsize=9)
        ax.set_xlabel("θ_con (rad)")
        ax.set_ylabel("force (g)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle("Eq. (9) fits with 95 % bands")
    return _save(fig, path)


def write_figures(
    synced: pd.DataFrame, fits: Sequence[SpeedFit], out_dir: str | os.PathLike, *, simulated: Simulated = None
) -> list[Path]:
    """Write ``force_vs_theta_con.png``, ``log_force.png`` and ``bounds.png`` to ``out_dir``."""
    out = Path(out_dir)
    return [
        plot_force_vs_theta_con(synced, out / "force_vs_theta_con.png", simulated=simulated),
        plot_log_force(synced, fits, out / "log_force.png"),
        plot_bounds(synced, fits, out / "bounds.png"),
    ]

"""Figures of the force side (the seed paper's Figs. 9–15), as PNG files.

- :func:`plot_force_vs_theta_con`: measured force against θ_con, one panel per speed, with the
  simulated force overlaid (Figs. 9–11);
- :func:`plot_log_force`: ln F against the angle, all speeds, with the Eq. (8) lines
  ``ln F = c1 θ + c2`` (Fig. 12);
- :func:`plot_bounds`: per speed, the samples, the Eq. (9) curve with its 95 % prediction band
  (the paper's safety boundary) and the recommended bound with its band, each labelled with its
  held-out coverage (Figs. 13–15).

The angle is θ_con, or θ_tip when the bounds were fitted against the tip angle.

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

from tympani.pipeline.model.bounds import SpeedFit, bands, form_label  # noqa: E402

__all__ = ["Simulated", "simulated_table", "plot_force_vs_theta_con", "plot_log_force", "plot_bounds", "write_figures"]

#: Simulated forces: a simulation table as ``tympani simulate --out`` writes it (``speed_mm_s``,
#: ``theta_con`` rad, ``force_g`` g), or a callable ``speeds_mm_s -> such a table`` (e.g.
#: ``lambda v: pipeline.model.friction.simulate("S4", v)``).
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
    fig, axes = plt.subplots(rows, cols, figsize=(max(4.2 * cols, 6.4), max(3.4 * rows, 4.4 if n == 1 else 0.0)),
                             squeeze=False, sharey=sharey)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()[:n]


def _at_speed(df: pd.DataFrame, speed: float) -> pd.DataFrame:
    return df[np.isclose(df["speed_mm_s"].to_numpy(dtype=float), speed, rtol=0, atol=1e-9)]


def _save(fig, path: str | os.PathLike) -> Path:
    from tympani.pipeline.io import atomic_open

    out = Path(path)
    try:
        fig.tight_layout()
        with atomic_open(out, "wb") as fh:
            fig.savefig(fh, format="png", dpi=110)
    finally:
        plt.close(fig)
    return out


def _angle_label(angle: str) -> str:
    return "θ_con" if angle == "theta_con" else "θ_tip"


def plot_force_vs_theta_con(synced: pd.DataFrame, path: str | os.PathLike, *, simulated: Simulated = None,
                            angle: str = "theta_con") -> Path:
    """Measured force against the angle per speed, with the simulation overlaid (Figs. 9–11).

    Parameters
    ----------
    synced : DataFrame
        Synced table: ``speed_mm_s`` (mm/s), the angle (rad), ``force_g`` (g), ``trial``.
    path : str or PathLike
        PNG to write.
    simulated : DataFrame or callable, optional
        Simulated forces (see :data:`Simulated`); drawn as a line per speed (against θ_con only).
    angle : {"theta_con", "theta_tip"}
        The angle on the x axis.

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
        part = part[np.isfinite(part[angle]) & np.isfinite(part["force_g"])]
        for _, trial in part.groupby("trial", sort=True) if "trial" in part.columns else [(None, part)]:
            t = _thin(trial)
            ax.plot(t[angle], t["force_g"], ".", ms=1.5, alpha=0.35, color="tab:blue")
        ax.plot([], [], ".", color="tab:blue", label=f"measured ({part['trial'].nunique() if 'trial' in part else 1} trials)")
        if sim is not None and angle == "theta_con":
            s = _at_speed(sim, v).sort_values("theta_con")
            if len(s):
                label = f"simulated ({s['scenario'].iloc[0]})" if "scenario" in s.columns else "simulated"
                ax.plot(s["theta_con"], s["force_g"], "-", color="tab:red", lw=2, label=label)
        ax.set_title(f"{v:g} mm/s")
        ax.set_xlabel(f"{_angle_label(angle)} (rad)")
        ax.set_ylabel("force (g)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle("Insertion force against " + ("contact angle" if angle == "theta_con" else "tip angle"))
    return _save(fig, path)


def plot_log_force(synced: pd.DataFrame, fits: Sequence[SpeedFit], path: str | os.PathLike) -> Path:
    """ln F against the angle for all speeds with the Eq. (8) lines (Fig. 12).

    Parameters
    ----------
    synced : DataFrame
        Synced table (``speed_mm_s`` mm/s, the fits' angle in rad, ``force_g`` g); only samples
        with F > 0 and a positive angle are drawn.
    fits : sequence of SpeedFit
        Eq. (8) fits (:func:`tympani.pipeline.model.bounds.fit_bounds`).
    path : str or PathLike
        PNG to write.

    Returns
    -------
    Path
    """
    angle = fits[0].angle if fits else "theta_con"
    sym = _angle_label(angle)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    cmap = plt.get_cmap("viridis")
    speeds = _speeds(synced)
    by_speed = {round(f.speed_mm_s, 9): f for f in fits}
    for i, v in enumerate(speeds):
        color = cmap(0.85 * i / max(len(speeds) - 1, 1))  # stop short of viridis' pale yellow
        part = _at_speed(synced, v)
        part = _thin(part[(part[angle] > 0) & (part["force_g"] > 0)])
        ax.plot(part[angle], np.log(part["force_g"]), ".", ms=1.5, alpha=0.25, color=color)
        fit = by_speed.get(round(v, 9))
        if fit is not None:
            th = np.linspace(fit.theta_min, fit.theta_max, 50)
            ax.plot(th, fit.c1 * th + fit.c2, "-", lw=2, color=color,
                    label=f"{v:g} mm/s: ln F = {fit.c1:.2f}·{sym} {'+' if fit.c2 >= 0 else '−'} {abs(fit.c2):.2f}")
    ax.set_xlabel(f"{sym} (rad)")
    ax.set_ylabel("ln F (F in g)")
    ax.set_title(f"Eq. (8): ln F = c1·{sym} + c2")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.0f} %"


def plot_bounds(synced: pd.DataFrame, fits: Sequence[SpeedFit], path: str | os.PathLike) -> Path:
    """Per speed: samples, Eq. (9) with its prediction band, and the recommended bound (Figs. 13–15).

    Each band is labelled with its held-out coverage: the share of samples of trials left out
    of its fit that fell inside it (a 95 % band that holds covers about 95 %).

    Parameters
    ----------
    synced : DataFrame
        Synced table (``speed_mm_s`` mm/s, the fits' angle in rad, ``force_g`` g).
    fits : sequence of SpeedFit
        Fits from :func:`tympani.pipeline.model.bounds.fit_bounds`.
    path : str or PathLike
        PNG to write.

    Returns
    -------
    Path
    """
    fig, axes = _panels(max(len(fits), 1), sharey=False)
    if not fits:
        axes[0].text(0.5, 0.5, "no speed could be fitted", ha="center", va="center", transform=axes[0].transAxes)
    for ax, fit in zip(axes, fits):
        sym = _angle_label(fit.angle)
        part = _at_speed(synced, fit.speed_mm_s)
        part = _thin(part[(part[fit.angle] > 0) & np.isfinite(part["force_g"])])
        ax.plot(part[fit.angle], part["force_g"], ".", ms=1.5, alpha=0.3, color="0.45", label="samples")
        b = bands(fit, np.linspace(fit.theta_min, fit.theta_max, 101))
        pct = f"{100 * fit.level:g} %"
        ax.fill_between(b[fit.angle], b["pi_lo_g"], b["pi_hi_g"], color="tab:orange", alpha=0.22,
                        label=f"Eq. (9) {pct} band (held-out {_pct(fit.heldout_coverage_eq9)})")
        ax.plot(b[fit.angle], b["f_fit_g"], "--", color="tab:orange", lw=1.2, label=f"exp(c1·{sym} + c2)")
        ax.plot(b[fit.angle], b["rec_lo_g"], "-", color="tab:blue", lw=1.3)
        ax.plot(b[fit.angle], b["rec_hi_g"], "-", color="tab:blue", lw=1.8,
                label=f"recommended: {form_label(fit.recommended.form)} (held-out {_pct(fit.heldout_coverage)})")
        ax.plot(b[fit.angle], b["rec_fit_g"], ":", color="tab:blue", lw=1.2)
        top = 1.25 * max(float(np.nanmax(part["force_g"])) if len(part) else 0.0, float(b["rec_hi_g"].max()), 1e-3)
        ax.set_ylim(0.0, top)
        eq9_top = float(b["pi_hi_g"].max())
        if eq9_top > top:
            ax.text(0.98, 0.03, f"Eq. (9) band reaches {eq9_top:.3g} g (off scale)", transform=ax.transAxes,
                    ha="right", va="bottom", fontsize=7, color="tab:red")
        ax.set_title(f"{fit.speed_mm_s:g} mm/s ({fit.n_trials} trials, n={fit.n})", fontsize=9)
        ax.set_xlabel(f"{sym} (rad)")
        ax.set_ylabel("force (g)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6.5, loc="upper left")
    fig.suptitle("Safety bounds: Eq. (9) and the recommended bound (95 % prediction bands)", fontsize=10)
    return _save(fig, path)


def write_figures(
    synced: pd.DataFrame, fits: Sequence[SpeedFit], out_dir: str | os.PathLike, *, simulated: Simulated = None
) -> list[Path]:
    """Write ``force_vs_theta_con.png``, ``log_force.png`` and ``bounds.png`` to ``out_dir``.

    The first is drawn against the fits' angle (θ_con, or θ_tip for tip-only data; its name stays).
    """
    out = Path(out_dir)
    angle = fits[0].angle if fits else "theta_con"
    return [
        plot_force_vs_theta_con(synced, out / "force_vs_theta_con.png", simulated=simulated, angle=angle),
        plot_log_force(synced, fits, out / "log_force.png"),
        plot_bounds(synced, fits, out / "bounds.png"),
    ]

"""The seed paper in numbers: TABLE I scenarios, TABLE II forces, TABLE III angles, and the fit.

Zhang, Bhattacharyya & Simaan, *Model and Parameter Identification of Friction during Robotic
Insertion of Cochlear-Implant Electrode Arrays*, ICRA 2009.

- :data:`TABLE_I` and :data:`SCENARIOS`: the simulation scenarios S1–S4 as printed. S3 and S4
  are six steps of (p_tip, p_bot, theta_bot), paired with TABLE II's six theta_con values; S1 and
  S2 hold theta_bot = 1.40 rad at the same six theta_con values. S1–S3 use Coulomb friction,
  S4 the Stribeck law. TABLE I does not say which coefficient the Coulomb scenarios use; the
  paper's words on its Fig. 5 ("S4 is slightly below S3") need one above S4's ``mu(v)``, so
  S1–S3 use the static 0.18 (S4 then lies 5–9 % below S3 at 3 mm/s).
- :data:`TABLE_II`: the simulated S4 force (g) at 0.5, 3 and 7.5 mm/s.
- :data:`TABLE_III`: six (theta_bot, theta_con, theta_tip) triples measured from one video.
- :func:`fit_table_ii`: the constants the paper does not print, fitted to TABLE II.

Fitting TABLE II
----------------
The paper leaves five things open: the effective contact width ``b_c``, the Stribeck velocity
``v_s`` and exponent ``delta_s``, which of the quoted coefficients 0.12 and 0.18 is static, and
the fourth p_bot of TABLE I, printed 0.01 inside an increasing sequence (0.10 is the likely
reading). The model's friction projection (:mod:`tympani.pipeline.model.friction`, ``friction_mode``) is a
sixth choice. The table carries two kinds of information, and each choice is settled by the kind
that speaks to it:

1. **The speed effect** lies in the ratios ``F(v) / F(0.5 mm/s)`` within each step (the table
   rounds to 0.01 g, so a ratio is known to ``0.0029 g · sqrt(1/F_v² + 1/F_0.5²)``). ``v_s`` and
   ``delta_s`` are fitted to these 12 ratios by weighted least squares, for each of the 8
   combinations of the discrete choices; ``b_c`` cancels from them.
2. **The shape** over the six steps fixes ``b_c`` (least squares in ln F over the 18 cells).

The combination kept is the one whose speed-ratio chi-square is smallest among those whose
shape matches (rms relative error under 10 %). A different geometry (the paper's 3-D cochlea
against the planar phantom here) scales a step's force at every speed alike, so it shows in the
shape and not in the ratios: this is why the two are judged apart. Result (``tympani paper``):
p_bot's fourth value 0.10, mu_s = 0.18 (static) and mu_k = 0.12, friction transmitted along the
insertion axis (``"axial"``). The model then falls by 1.05–1.77 % from 0.5 to 7.5 mm/s, step
by step within 0.7 points of the table (1.03–1.94 %), and every cell is within 6.3 %.

What limits the fit: friction is 13–22 % of the sensed force on these arcs (the rest is the
normal pressure projected on the insertion axis), and ``mu_s - mu_k = 0.06``, so Stribeck
friction alone can move the force by a few per cent at most. With the friction vectors summed
before projecting (``"vector"``), the wall turns past 90° from the insertion axis deep in the
spiral and the friction term nearly cancels: at most 1.2 % at step 1 and 0.02 % at step 4,
against 1.0–1.9 % in the table. And ``delta_s`` is barely determined: the ratio chi-square
changes by under 20 % for ``delta_s`` between 0.3 and 1.5 (with ``v_s`` moving from 0.12 to 0.34
mm/s), since all three speeds sit above ``v_s`` (:attr:`TableIIFit.delta_profile`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.optimize import least_squares, nnls

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom

from tympani.pipeline.model.friction import (
    DEFAULT_FRICTION_MODE,
    G_N,
    ArcIntegrals,
    ContactGeometry,
    FrictionMode,
    FrictionParams,
    LinearPressure,
    PiecewisePressure,
    arc_integrals,
    force_from_integrals,
    stribeck,
)

__all__ = [
    "TABLE_I",
    "TABLE_II",
    "TABLE_II_THETA_CON",
    "TABLE_III",
    "PAPER_DROPS_PCT",
    "TABLE_II_DROP_PCT",
    "SIM_COLUMNS",
    "Scenario",
    "SCENARIOS",
    "scenario",
    "simulate",
    "peak_force_change",
    "OptionFit",
    "TableIIFit",
    "fit_table_ii",
    "paper_params",
    "format_table_ii_fit",
]

#: Columns of the simulation table, in order (``step`` is appended).
SIM_COLUMNS = ("scenario", "speed_mm_s", "theta_bot", "theta_tip", "theta_con", "force_g")

#: TABLE II's contact angles (rad): one per step of S3/S4, and the grid of S1/S2.
TABLE_II_THETA_CON: tuple[float, ...] = (1.48, 1.92, 2.44, 3.05, 3.75, 4.28)

#: TABLE I as printed. ``p_bot`` of S3/S4 has the printed 0.01 at step 4 (see :func:`scenario`).
TABLE_I: dict[str, dict] = {
    "S1": dict(theta_bot=1.40, p_tip=0.1, p_bot=0.15, stribeck=False,
               text="theta_bot = 1.40 rad, p_tip = 0.1 MPa, p_bot = 0.15 MPa, fixed"),
    "S2": dict(theta_bot=1.40, p_tip=0.1, p_bot=(0.04, 0.2), stribeck=False,
               text="theta_bot = 1.40 rad, p_tip = 0.1 MPa, p_bot increasing linearly over [0.04, 0.2] MPa"),
    "S3": dict(theta_bot=(1.83, 1.66, 1.48, 1.31, 1.13, 0.96), p_tip=(0.03, 0.04, 0.06, 0.08, 0.09, 0.1),
               p_bot=(0.04, 0.05, 0.07, 0.01, 0.15, 0.2), stribeck=False,
               text="six steps of p_tip, p_bot and theta_bot; Coulomb friction"),
    "S4": dict(theta_bot=(1.83, 1.66, 1.48, 1.31, 1.13, 0.96), p_tip=(0.03, 0.04, 0.06, 0.08, 0.09, 0.1),
               p_bot=(0.04, 0.05, 0.07, 0.01, 0.15, 0.2), stribeck=True,
               text="S3 with the Stribeck friction model"),
}

#: TABLE II: S4's sensed force (g) by speed (mm/s), one value per step (theta_con of
#: :data:`TABLE_II_THETA_CON`).
TABLE_II: dict[float, tuple[float, ...]] = {
    0.5: (0.70, 1.12, 1.91, 2.90, 3.89, 4.63),
    3.0: (0.69, 1.10, 1.89, 2.87, 3.86, 4.55),
    7.5: (0.69, 1.10, 1.88, 2.87, 3.84, 4.54),
}

#: The paper's own words on its model's speed effect: S4 falls by 1.4–1.9 % from 0.5 to 7.5 mm/s.
TABLE_II_DROP_PCT: tuple[float, float] = (1.4, 1.9)

#: The paper's measured peak-force changes against 0.5 mm/s (%), by speed (mm/s).
PAPER_DROPS_PCT: dict[float, float] = {3.0: -24.0, 7.5: -43.0}

#: TABLE III: six angle triples (rad) measured from the video of one insertion (Fig. 8).
TABLE_III = pd.DataFrame({
    "frame": ["8-1", "8-2", "8-3", "8-4", "8-5", "8-6"],
    "theta_bot": [1.68, 1.41, 1.26, 0.94, 0.77, 0.84],
    "theta_con": [1.17, 1.71, 2.23, 3.04, 3.61, 3.63],
    "theta_tip": [2.84, 3.12, 3.49, 3.98, 4.38, 4.47],
})

#: The TABLE II rounding: cells are printed to 0.01 g (uniform error, sd 0.01 / sqrt(12) g).
_ROUNDING_SD_G = 0.01 / np.sqrt(12.0)


# =========================================================================== scenarios


@dataclass(frozen=True)
class Scenario:
    """A scenario of TABLE I: contact arcs and pressures step by step, and a friction law.

    Parameters
    ----------
    name : str
        ``"S1"`` … ``"S4"``.
    description : str
        TABLE I's conditions in words.
    theta_bot, theta_tip : tuple of float
        Contact start and tip angles (rad) at each step.
    p_tip_MPa, p_bot_MPa : tuple of float
        Pressures (MPa) at the tip and the contact start at each step.
    stribeck_law : bool
        Stribeck friction (True) or Coulomb friction ``mu = mu_s`` (False).
    """

    name: str
    description: str
    theta_bot: tuple[float, ...]
    theta_tip: tuple[float, ...]
    p_tip_MPa: tuple[float, ...]
    p_bot_MPa: tuple[float, ...]
    stribeck_law: bool

    @property
    def theta_con(self) -> np.ndarray:
        """Contact angle (rad) at each step."""
        return np.asarray(self.theta_tip) - np.asarray(self.theta_bot)

    def params(self, friction: FrictionParams | None = None) -> FrictionParams:
        """The scenario's parameters: its pressures as piecewise-linear laws of theta_con.

        Parameters
        ----------
        friction : FrictionParams, optional
            Friction constants and contact width (default: :class:`FrictionParams`' defaults,
            the TABLE II fit). Without Stribeck friction ``mu_k`` is set to ``mu_s`` and
            ``mu_v`` to 0 (Coulomb friction at the static coefficient, see the module docstring).
        """
        base = friction if friction is not None else FrictionParams()
        if not self.stribeck_law:
            base = replace(base, mu_k=base.mu_s, mu_v_s_per_mm=0.0)
        con = tuple(float(c) for c in self.theta_con)
        return replace(base, p_tip_MPa=PiecewisePressure(con, self.p_tip_MPa),
                       p_bot_MPa=PiecewisePressure(con, self.p_bot_MPa))


def _steps(value: float | tuple[float, ...], n: int) -> tuple[float, ...]:
    return tuple(float(v) for v in value) if isinstance(value, tuple) else (float(value),) * n


def scenario(name: str, *, p_bot4_MPa: float = 0.10) -> Scenario:
    """One scenario of TABLE I.

    Parameters
    ----------
    name : str
        ``"S1"`` … ``"S4"`` (any case).
    p_bot4_MPa : float
        The reading of S3/S4's fourth p_bot, printed 0.01 MPa; 0.10 (default) is the reading that
        reproduces TABLE II (:func:`fit_table_ii`).

    Raises
    ------
    KeyError
        A name not in TABLE I.
    """
    key = str(name).strip().upper()
    if key not in TABLE_I:
        raise KeyError(f"unknown scenario {name!r}; TABLE I has {', '.join(TABLE_I)}")
    row = TABLE_I[key]
    con = np.asarray(TABLE_II_THETA_CON)
    n = con.size
    bot = _steps(row["theta_bot"], n)
    p_bot = row["p_bot"]
    if key == "S2":  # increasing linearly in theta_con over [0.04, 0.2] MPa across the six steps
        lo, hi = p_bot
        p_bot = tuple(float(x) for x in lo + (hi - lo) * (con - con[0]) / (con[-1] - con[0]))
    p_bot = list(_steps(p_bot, n))
    if key in ("S3", "S4"):
        p_bot[3] = float(p_bot4_MPa)
    return Scenario(
        name=key, description=row["text"], theta_bot=bot,
        theta_tip=tuple(float(b + c) for b, c in zip(bot, con)),
        p_tip_MPa=_steps(row["p_tip"], n), p_bot_MPa=tuple(p_bot), stribeck_law=bool(row["stribeck"]),
    )


#: The four scenarios of TABLE I with the 0.10 MPa reading of S3/S4's fourth p_bot.
SCENARIOS: dict[str, Scenario] = {name: scenario(name) for name in TABLE_I}


def _grid(sc: Scenario, grid: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step label, theta_bot, theta_tip) at the steps or on a finer grid between them."""
    bot, tip = np.asarray(sc.theta_bot), np.asarray(sc.theta_tip)
    if grid is None:
        return np.arange(bot.size, dtype=float), bot, tip
    if grid < 2:
        raise ValueError("grid must be at least 2 points")
    u = np.linspace(0.0, bot.size - 1.0, int(grid))
    k = np.arange(bot.size)
    return u, np.interp(u, k, bot), np.interp(u, k, tip)


def simulate(
    scenario_name: str | Scenario,
    speeds_mm_s: Sequence[float],
    *,
    friction: FrictionParams | None = None,
    grid: int | None = None,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE,
) -> pd.DataFrame:
    """The force model along a scenario at several speeds (the simulation table).

    Parameters
    ----------
    scenario_name : str or Scenario
        ``"S1"`` … ``"S4"`` or a :class:`Scenario`.
    speeds_mm_s : sequence of float
        Insertion speeds (mm/s), each > 0.
    friction : FrictionParams, optional
        Friction constants and contact width (default: the TABLE II fit).
    grid : int, optional
        Points along the scenario (default: its six steps). A finer grid interpolates the
        angles linearly between steps and the pressures linearly in theta_con.
    phantom : Phantom or ContactGeometry
        Geometry.
    friction_mode : {"axial", "vector"}
        See :mod:`tympani.pipeline.model.friction`.

    Returns
    -------
    pandas.DataFrame
        One row per (step, speed), speed-major: ``scenario, speed_mm_s, theta_bot, theta_tip,
        theta_con`` (rad), ``force_g`` (g), ``step`` (0-based; fractional on a finer grid).

    Raises
    ------
    ValueError
        A speed that is not positive and finite.
    """
    sc = scenario_name if isinstance(scenario_name, Scenario) else SCENARIOS[_key(scenario_name)]
    speeds = np.asarray(list(speeds_mm_s), dtype=float)
    if speeds.size == 0 or not np.all(np.isfinite(speeds) & (speeds > 0)):
        raise ValueError(f"speeds must be positive (mm/s), got {', '.join(f'{v:g}' for v in speeds) or 'none'}")
    step, bot, tip = _grid(sc, grid)
    arcs = arc_integrals(bot, tip, phantom)
    force = force_from_integrals(
        ArcIntegrals(arcs.theta_con[None, :], arcs.g0[None], arcs.g1[None], arcs.length_mm[None]),
        speeds[:, None], sc.params(friction), friction_mode=friction_mode,
    )
    n, m = speeds.size, bot.size
    return pd.DataFrame({
        "scenario": sc.name,
        "speed_mm_s": np.repeat(speeds, m),
        "theta_bot": np.tile(bot, n),
        "theta_tip": np.tile(tip, n),
        "theta_con": np.tile(tip - bot, n),
        "force_g": force.ravel(),
        "step": np.tile(step, n),
    })


def _key(name: str) -> str:
    key = str(name).strip().upper()
    if key not in SCENARIOS:
        raise KeyError(f"unknown scenario {name!r}; TABLE I has {', '.join(SCENARIOS)}")
    return key


def peak_force_change(
    scenario_name: str | Scenario = "S4",
    v_ref_mm_s: float = 0.5,
    v_mm_s: float = 7.5,
    *,
    friction: FrictionParams | None = None,
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE,
) -> float:
    """Relative change (%) of a scenario's largest force from ``v_ref_mm_s`` to ``v_mm_s``.

    Negative means the force falls with speed (the paper's experiments: −24 % at 3 mm/s and
    −43 % at 7.5 mm/s; its simulation, TABLE II: −1.4 to −1.9 %).

    Parameters
    ----------
    scenario_name : str or Scenario
        Scenario (default S4).
    v_ref_mm_s, v_mm_s : float
        Reference and compared speeds (mm/s).
    friction : FrictionParams, optional
        Friction constants (default: the TABLE II fit).
    friction_mode : {"axial", "vector"}
        See :mod:`tympani.pipeline.model.friction`.
    """
    table = simulate(scenario_name, [v_ref_mm_s, v_mm_s], friction=friction, friction_mode=friction_mode)
    peaks = table.groupby("speed_mm_s")["force_g"].max()
    return float(100.0 * (peaks[float(v_mm_s)] / peaks[float(v_ref_mm_s)] - 1.0))


# =========================================================================== TABLE II fit


@dataclass(frozen=True)
class OptionFit:
    """The TABLE II fit for one combination of the paper's open choices.

    Attributes
    ----------
    mu_s, mu_k : float
        Static and kinetic coefficients (dimensionless).
    p_bot4_MPa : float
        Reading of S4's fourth p_bot (MPa).
    friction_mode : str
        ``"axial"`` or ``"vector"``.
    v_s_mm_s, delta_s : float
        Stribeck constants fitted to the speed ratios (mm/s, dimensionless).
    v_s_se, delta_s_se : float
        Their standard errors (from the Jacobian, scaled by the reduced chi-square).
    contact_width_mm : float
        ``b_c`` fitted to the cells (mm).
    chi2_speed : float
        Chi-square of the 12 within-step speed ratios against the table's rounding.
    rms_shape_pct, max_cell_pct : float
        Root-mean-square and largest relative cell error (%) over the 18 cells.
    model_g : ndarray, shape (3, 6)
        The model's cells (g), speeds of :data:`TABLE_II` by row.
    """

    mu_s: float
    mu_k: float
    p_bot4_MPa: float
    friction_mode: str
    v_s_mm_s: float
    delta_s: float
    v_s_se: float
    delta_s_se: float
    contact_width_mm: float
    chi2_speed: float
    rms_shape_pct: float
    max_cell_pct: float
    model_g: np.ndarray

    def label(self) -> str:
        """A short description of the option."""
        return (f"mu_s={self.mu_s:g} mu_k={self.mu_k:g}, p_bot4={self.p_bot4_MPa:g} MPa, "
                f"{self.friction_mode}")


@dataclass(frozen=True)
class TableIIFit:
    """Constants fitted to TABLE II (:func:`fit_table_ii`).

    Attributes
    ----------
    chosen : OptionFit
        The combination that reproduces the table (see the module docstring).
    options : tuple of OptionFit
        All 8 combinations, best first.
    friction : FrictionParams
        The chosen friction constants and contact width (pressures are S4's).
    cells : pandas.DataFrame
        Per cell: ``speed_mm_s, step, theta_con, paper_g, model_g, residual_g, residual_pct``.
    drops : pandas.DataFrame
        Per step: ``theta_con``, the paper's and the model's change (%) from 0.5 to 3 and 7.5 mm/s,
        and ``friction_share`` (friction's share of the model's force at 0.5 mm/s).
    delta_profile : pandas.DataFrame
        ``delta_s``, the best ``v_s_mm_s`` at it and ``chi2_speed``: how well ``delta_s`` is fixed.
    """

    chosen: OptionFit
    options: tuple[OptionFit, ...]
    friction: FrictionParams
    cells: pd.DataFrame
    drops: pd.DataFrame
    delta_profile: pd.DataFrame


def _table_ii() -> tuple[np.ndarray, np.ndarray]:
    speeds = np.asarray(sorted(TABLE_II), dtype=float)
    return speeds, np.asarray([TABLE_II[v] for v in speeds], dtype=float)


def _terms(p_bot4: float, mode: FrictionMode, phantom: Phantom | ContactGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the normal and friction integrals of S4 (N/mm, before ``b_c``)."""
    sc = scenario("S4", p_bot4_MPa=p_bot4)
    arcs = arc_integrals(np.asarray(sc.theta_bot), np.asarray(sc.theta_tip), phantom)
    p_tip, p_bot = np.asarray(sc.p_tip_MPa), np.asarray(sc.p_bot_MPa)
    col = 2 if mode == "axial" else 1
    normal = p_tip * arcs.g0[:, 0] + (p_bot - p_tip) * arcs.g1[:, 0]
    along = p_tip * arcs.g0[:, col] + (p_bot - p_tip) * arcs.g1[:, col]
    return normal, along


def _mu(speeds: np.ndarray, mu_s: float, mu_k: float, v_s: float, delta: float) -> np.ndarray:
    return mu_k + (mu_s - mu_k) * np.exp(-np.power(speeds / v_s, delta))


_V_S_BOUNDS = (1e-3, 100.0)
_DELTA_BOUNDS = (0.2, 6.0)


def _fit_option(mu_s: float, mu_k: float, p_bot4: float, mode: FrictionMode,
                phantom: Phantom | ContactGeometry) -> OptionFit:
    speeds, paper = _table_ii()
    normal, along = _terms(p_bot4, mode, phantom)
    ratio = paper[1:] / paper[0]
    ratio_sd = ratio * _ROUNDING_SD_G * np.sqrt(1.0 / paper[1:] ** 2 + 1.0 / paper[0] ** 2)

    def shape(x: np.ndarray) -> np.ndarray:  # model cells up to b_c, x = (ln v_s, delta)
        mu = _mu(speeds, mu_s, mu_k, float(np.exp(x[0])), float(x[1]))
        return normal[None, :] + mu[:, None] * along[None, :]

    def residual(x: np.ndarray) -> np.ndarray:
        m = shape(x)
        return ((m[1:] / m[0] - ratio) / ratio_sd).ravel()

    lo = np.array([np.log(_V_S_BOUNDS[0]), _DELTA_BOUNDS[0]])
    hi = np.array([np.log(_V_S_BOUNDS[1]), _DELTA_BOUNDS[1]])
    best = None
    for x0 in itertools.product(np.linspace(-4.0, 3.0, 8), (0.35, 0.7, 1.5, 3.0)):
        res = least_squares(residual, np.asarray(x0, dtype=float), bounds=(lo, hi))
        if best is None or res.cost < best.cost - 1e-12:
            best = res
    assert best is not None
    chi2 = 2.0 * float(best.cost)
    dof = max(ratio.size - 2, 1)
    jac = np.asarray(best.jac, dtype=float)
    cov = np.linalg.pinv(jac.T @ jac) * max(chi2 / dof, 1.0)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    m = shape(best.x)
    with np.errstate(divide="ignore", invalid="ignore"):
        b_c = float(np.exp(np.mean(np.log(paper / m)))) * G_N if np.all(m > 0) else float("nan")
    model = m * b_c / G_N
    rel = 100.0 * (model / paper - 1.0)
    v_s = float(np.exp(best.x[0]))
    return OptionFit(
        mu_s=mu_s, mu_k=mu_k, p_bot4_MPa=p_bot4, friction_mode=mode, v_s_mm_s=v_s, delta_s=float(best.x[1]),
        v_s_se=v_s * float(se[0]), delta_s_se=float(se[1]), contact_width_mm=b_c, chi2_speed=chi2,
        rms_shape_pct=float(np.sqrt(np.mean(rel ** 2))), max_cell_pct=float(np.max(np.abs(rel))), model_g=model,
    )


def fit_table_ii(
    *,
    mu_pair: tuple[float, float] = (0.12, 0.18),
    p_bot4_readings: Sequence[float] = (0.01, 0.10),
    modes: Sequence[FrictionMode] = ("axial", "vector"),
    shape_limit_pct: float = 10.0,
    phantom: Phantom | ContactGeometry = DEFAULT_PHANTOM,
) -> TableIIFit:
    """Fit the constants the paper does not print to TABLE II (see the module docstring).

    Parameters
    ----------
    mu_pair : tuple of float
        The two quoted friction coefficients (dimensionless), tried both ways round.
    p_bot4_readings : sequence of float
        Readings (MPa) of S4's fourth p_bot.
    modes : sequence of {"axial", "vector"}
        Friction projections tried.
    shape_limit_pct : float
        Largest rms relative cell error (%) for an option to count as matching the shape.
    phantom : Phantom or ContactGeometry
        Geometry.

    Returns
    -------
    TableIIFit
    """
    pairs = [(max(mu_pair), min(mu_pair)), (min(mu_pair), max(mu_pair))]
    options = [_fit_option(float(ms), float(mk), float(p4), m, phantom)
               for (ms, mk), p4, m in itertools.product(pairs, p_bot4_readings, modes)]
    matching = [o for o in options if o.rms_shape_pct <= shape_limit_pct] or options
    chosen = min(matching, key=lambda o: (o.chi2_speed, o.rms_shape_pct))
    ordered = tuple(sorted(options, key=lambda o: (o not in matching, o.chi2_speed, o.rms_shape_pct)))
    friction = replace(FrictionParams(), mu_s=chosen.mu_s, mu_k=chosen.mu_k, v_s_mm_s=chosen.v_s_mm_s,
                       delta_s=chosen.delta_s, mu_v_s_per_mm=0.0, contact_width_mm=chosen.contact_width_mm)
    speeds, paper = _table_ii()
    con = np.asarray(TABLE_II_THETA_CON)
    model = chosen.model_g
    cells = pd.DataFrame({
        "speed_mm_s": np.repeat(speeds, con.size),
        "step": np.tile(np.arange(1, con.size + 1), speeds.size),
        "theta_con": np.tile(con, speeds.size),
        "paper_g": paper.ravel(),
        "model_g": model.ravel(),
    })
    cells["residual_g"] = cells["model_g"] - cells["paper_g"]
    cells["residual_pct"] = 100.0 * cells["residual_g"] / cells["paper_g"]
    normal, along = _terms(chosen.p_bot4_MPa, chosen.friction_mode, phantom)  # type: ignore[arg-type]
    mu_ref = float(stribeck(speeds[0], friction))
    drops = pd.DataFrame({"step": np.arange(1, con.size + 1), "theta_con": con})
    for k, v in enumerate(speeds[1:], start=1):
        drops[_col("paper", v)] = 100.0 * (paper[k] / paper[0] - 1.0)
        drops[_col("model", v)] = 100.0 * (model[k] / model[0] - 1.0)
    drops["friction_share"] = mu_ref * along / (normal + mu_ref * along)
    profile = []
    for delta in (0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0):
        sub = _profile_point(chosen, float(delta), phantom)
        profile.append(dict(delta_s=float(delta), v_s_mm_s=sub[0], chi2_speed=sub[1]))
    return TableIIFit(chosen=chosen, options=ordered, friction=friction, cells=cells, drops=drops,
                      delta_profile=pd.DataFrame(profile))


def _profile_point(option: OptionFit, delta: float, phantom: Phantom | ContactGeometry) -> tuple[float, float]:
    """Best ``v_s`` (mm/s) and the ratio chi-square with ``delta_s`` held at ``delta``."""
    speeds, paper = _table_ii()
    normal, along = _terms(option.p_bot4_MPa, option.friction_mode, phantom)  # type: ignore[arg-type]
    ratio = paper[1:] / paper[0]
    ratio_sd = ratio * _ROUNDING_SD_G * np.sqrt(1.0 / paper[1:] ** 2 + 1.0 / paper[0] ** 2)

    def residual(x: np.ndarray) -> np.ndarray:
        mu = _mu(speeds, option.mu_s, option.mu_k, float(np.exp(x[0])), delta)
        m = normal[None, :] + mu[:, None] * along[None, :]
        return ((m[1:] / m[0] - ratio) / ratio_sd).ravel()

    best = min((least_squares(residual, [x0], bounds=([np.log(_V_S_BOUNDS[0])], [np.log(_V_S_BOUNDS[1])]))
                for x0 in np.linspace(-4.0, 3.0, 8)), key=lambda r: r.cost)
    return float(np.exp(best.x[0])), 2.0 * float(best.cost)


def paper_params() -> FrictionParams:
    """The paper's S4 as one set of parameters with pressure laws linear in theta_con.

    The friction constants and contact width are :class:`FrictionParams`' defaults (the TABLE II
    fit); ``p_tip`` and ``p_bot`` are the least-squares lines through S4's six steps (MPa against
    theta_con in rad) with non-negative coefficients, the form a fit to measured data takes
    (:mod:`tympani.pipeline.model.identify` bounds the intercepts at 0). Synthetic experiments use it as their
    base model; :class:`FrictionParams`' default pressures are these lines.
    """
    sc = SCENARIOS["S4"]
    con = sc.theta_con
    design = np.column_stack([np.ones(con.size), con])
    tip, _ = nnls(design, np.asarray(sc.p_tip_MPa))
    bot, _ = nnls(design, np.asarray(sc.p_bot_MPa))
    return replace(FrictionParams(), p_tip_MPa=LinearPressure(float(tip[0]), float(tip[1])),
                   p_bot_MPa=LinearPressure(float(bot[0]), float(bot[1])))


def format_table_ii_fit(fit: TableIIFit) -> str:
    """The fit as text: TABLE II beside the model cell by cell, the choices and the speed drop."""
    c = fit.chosen
    speeds, _ = _table_ii()
    lines = ["TABLE II (S4, sensed force in g): paper | model | residual"]
    head = "theta_con " + " ".join(f"| {f'v = {v:g} mm/s':^24}" for v in speeds)
    lines += [head, "-" * len(head)]
    for step, part in fit.cells.groupby("step", sort=True):
        cells = " ".join(f"| {r.paper_g:5.2f} {r.model_g:6.3f} {r.residual_pct:+6.1f} %  "
                         for r in part.sort_values("speed_mm_s").itertuples())
        lines.append(f"{part['theta_con'].iloc[0]:9.2f} {cells}")
    worst = fit.cells["residual_pct"].abs().max()
    lines.append(f"largest cell residual {worst:.1f} %, rms {c.rms_shape_pct:.1f} %")
    lines += ["", "Speed effect, change from 0.5 mm/s (%): paper | model"]
    cols = [v for v in speeds[1:]]
    lines.append("step theta_con " + " ".join(f"| {f'{v:g} mm/s':^15}" for v in cols) + " | friction share")
    for _, r in fit.drops.iterrows():
        vals = " ".join(f"| {r[_col('paper', v)]:+6.2f} {r[_col('model', v)]:+6.2f} " for v in cols)
        lines.append(f"{int(r['step']):4d} {r['theta_con']:9.2f} {vals} | {100 * r['friction_share']:5.1f} %")
    model_drop = -fit.drops[_col("model", speeds[-1])]
    lines.append(f"model's drop 0.5 -> {speeds[-1]:g} mm/s: {model_drop.min():.2f}–{model_drop.max():.2f} % "
                 f"(paper: {TABLE_II_DROP_PCT[0]:g}–{TABLE_II_DROP_PCT[1]:g} % in its words, "
                 f"{-fit.drops[_col('paper', speeds[-1])].max():.2f}–{-fit.drops[_col('paper', speeds[-1])].min():.2f} % "
                 "in its table)")
    lines += ["", "Chosen constants (not printed in the paper):",
              f"  mu_s = {c.mu_s:g} (static), mu_k = {c.mu_k:g} (kinetic)",
              f"  S4 p_bot at step 4 = {c.p_bot4_MPa:g} MPa (printed 0.01)",
              f"  friction projection: {c.friction_mode}",
              f"  v_s = {c.v_s_mm_s:.3g} ± {c.v_s_se:.2g} mm/s, delta_s = {c.delta_s:.3g} ± {c.delta_s_se:.2g}",
              f"  b_c = {c.contact_width_mm:.4g} mm (effective contact width)",
              "", "All combinations (speed-ratio chi-square on 12 ratios; shape error over 18 cells):"]
    for o in fit.options:
        mark = "*" if o is c else " "
        lines.append(f" {mark} {o.label():42s} chi2 {o.chi2_speed:8.1f}   rms {o.rms_shape_pct:5.1f} %   "
                     f"max {o.max_cell_pct:5.1f} %")
    lines += ["", "delta_s profile (v_s refitted): " + ", ".join(
        f"{r.delta_s:g}: chi2 {r.chi2_speed:.0f} (v_s {r.v_s_mm_s:.2g})" for r in fit.delta_profile.itertuples())]
    return "\n".join(lines)


def _col(kind: str, speed: float) -> str:
    return f"{kind}_{speed:g}_pct"

"""The truth of a family-A experiment: typed records of what the diagnosis never sees.

:func:`effect_truth` measures a hidden effect against the noise (:class:`EffectTruth`);
:func:`tympani.pipeline.synthetic.family_a.dataset.synthetic_dataset` extends it with the experiment's
configuration, trials and tables (:class:`DatasetTruth`). ``to_json()`` gives the JSON object
written as ``truth/effect.json``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

import numpy as np
import pandas as pd

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom

from tympani.pipeline.model.friction import (
    G_N,
    ArcIntegrals,
    FrictionParams,
    LinearPressure,
    arc_integrals,
    flat_params,
    stribeck,
)
from tympani.pipeline.synthetic.family_a.config import NoiseConfig, Protocol, Variability
from tympani.pipeline.synthetic.family_a.effects import find_effect

__all__ = [
    "SpeedGap",
    "EffectTruth",
    "TrialRecord",
    "TruthTables",
    "PaperDrops",
    "DatasetTruth",
    "rms",
    "unabsorbed_gap",
    "effect_truth",
]


def rms(x: np.ndarray) -> float:
    """Root mean square of the finite values of ``x`` (0 if there are none), in the units of ``x``."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else 0.0


@dataclass(frozen=True)
class SpeedGap:
    """The gap of a hidden effect at one nominal speed.

    Parameters
    ----------
    speed_mm_s : float
        Nominal speed (mm/s).
    gap_rms_g, gap_mean_g : float
        RMS and mean (g) of the noiseless force with minus without the effect.
    noise_rms_g : float
        RMS (g) of the measured minus the noiseless force.
    n : int
        Rows at this speed.
    """

    speed_mm_s: float
    gap_rms_g: float
    gap_mean_g: float
    noise_rms_g: float
    n: int


@dataclass(frozen=True)
class EffectTruth:
    """A hidden effect and its noiseless gap against the noise.

    Parameters
    ----------
    effect : str or None
        Effect name, or None without an effect.
    strength : float
        Its strength (dimensionless; 0 without an effect).
    params : mapping
        Its parameters (units in the names).
    form, library_form : str or None
        The generator's functional form and the library form it differs from.
    kind : {"physical", "sensor"} or None
        Acts on the force at the contact, or on the sensed signal.
    base_params : mapping
        The base model's flat parameters (:func:`tympani.pipeline.model.friction.flat_params`).
    gap_rms_g, gap_mean_g, gap_max_g : float
        RMS, mean and largest magnitude (g) of the noiseless force with minus without the effect.
    noise_rms_g : float
        RMS (g) of the measured minus the noiseless force.
    gap_to_noise : float
        ``gap_rms_g / noise_rms_g`` (dimensionless; inf without noise).
    detectable : bool
        Gap RMS above twice the noise RMS.
    gap_unabsorbed_rms_g : float or None
        What a refit of the pressure laws leaves of the gap (g, :func:`unabsorbed_gap`).
    unabsorbed_to_noise : float or None
        ``gap_unabsorbed_rms_g / noise_rms_g`` (dimensionless).
    gap_by_speed : tuple of SpeedGap
        The gap per nominal speed, slowest first.
    """

    effect: str | None
    strength: float
    params: Mapping[str, float]
    form: str | None
    library_form: str | None
    kind: str | None
    base_params: Mapping[str, float]
    gap_rms_g: float
    gap_mean_g: float
    gap_max_g: float
    noise_rms_g: float
    gap_to_noise: float
    detectable: bool
    gap_unabsorbed_rms_g: float | None
    unabsorbed_to_noise: float | None
    gap_by_speed: tuple[SpeedGap, ...]

    def effect_fields(self) -> dict[str, Any]:
        """The fields of :class:`EffectTruth` by name (to build a record that extends it)."""
        return {f.name: getattr(self, f.name) for f in fields(EffectTruth)}

    def to_json(self) -> dict[str, Any]:
        """The JSON object of the record (key order as the fields)."""
        out = self.effect_fields()
        out["params"] = dict(self.params)
        out["base_params"] = dict(self.base_params)
        out["gap_by_speed"] = [asdict(g) for g in self.gap_by_speed]
        return out


@dataclass(frozen=True)
class TrialRecord:
    """One trial of a family-A dataset.

    Parameters
    ----------
    trial : str
        Trial name (:func:`tympani.pipeline.synthetic.family_a.dataset.trial_name`).
    speed_mm_s, actual_speed_mm_s : float
        Nominal and actual insertion speed (mm/s).
    pressure_scale : float
        Factor (dimensionless) on both pressure laws.
    noise_scale : float
        Factor (dimensionless) on the force noise.
    tare_g : float
        Zero offset (g).
    t_start_s, t_stop_s : float
        When the robot starts and stops (s, force clock).
    n_samples : int
        Force samples of the trial.
    theta_first : float
        Tip angle (rad) at first contact.
    lag : float
        Fraction (dimensionless) of the tip's advance the contact start follows.
    shape : mapping
        The contact policy's shape (:class:`tympani.vision.rendering.ContactPolicy`), field by field.
    """

    trial: str
    speed_mm_s: float
    actual_speed_mm_s: float
    pressure_scale: float
    noise_scale: float
    tare_g: float
    t_start_s: float
    t_stop_s: float
    n_samples: int
    theta_first: float
    lag: float
    shape: Mapping[str, float]


@dataclass(frozen=True)
class TruthTables:
    """The tables of a family-A dataset's truth (not part of its JSON).

    Parameters
    ----------
    frames : pandas.DataFrame
        The measured angles per video frame: ``trial, frame, time_s, theta_tip, theta_bot, theta_con, ok``.
    clean : pandas.DataFrame
        Per row of the synced table, the noiseless ``force_base_g`` and ``force_effect_g`` (g).
    """

    frames: pd.DataFrame
    clean: pd.DataFrame


@dataclass(frozen=True)
class PaperDrops:
    """Peak-force changes of a paper case (:func:`tympani.pipeline.synthetic.family_a.paper.peak_force_drop` tables).

    Parameters
    ----------
    target_change_pct : mapping
        Speed (mm/s, as a string) to the seed paper's change (per cent vs 0.5 mm/s).
    achieved, achieved_noiseless, base_model : pandas.DataFrame
        Per speed ``speed_mm_s, n_trials, peak_force_g, peak_sd_g, change_pct`` of the measured
        force, of the noiseless force with the effect and of the base model alone.
    """

    target_change_pct: Mapping[str, float]
    achieved: pd.DataFrame
    achieved_noiseless: pd.DataFrame
    base_model: pd.DataFrame

    def to_json(self) -> dict[str, Any]:
        """The JSON object of the record (each table as a list of rows)."""
        return dict(target_change_pct=dict(self.target_change_pct), achieved=self.achieved.to_dict("records"),
                    achieved_noiseless=self.achieved_noiseless.to_dict("records"),
                    base_model=self.base_model.to_dict("records"))


@dataclass(frozen=True)
class DatasetTruth(EffectTruth):
    """The truth of a family-A force-and-angles dataset (no video).

    Parameters
    ----------
    noise : NoiseConfig
        Force and angle noise, A/D.
    variability : Variability
        Trial-to-trial variability.
    protocol : Protocol
        Timing of the trials and clocks.
    trials : tuple of TrialRecord
        The trials, in the synced table's order.
    elapsed_s : float
        Wall-clock time (s) of the generation.
    tables : TruthTables
        Per-frame angles and noiseless forces (not in the JSON).
    paper : PaperDrops or None
        Peak-force changes of a paper case (:func:`tympani.pipeline.synthetic.family_a.paper.paper_case`).

    The other parameters are those of :class:`EffectTruth`.
    """

    noise: NoiseConfig
    variability: Variability
    protocol: Protocol
    trials: tuple[TrialRecord, ...]
    elapsed_s: float
    tables: TruthTables
    paper: PaperDrops | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON object written as ``truth/effect.json`` (without the tables)."""
        out = super().to_json()
        out.update(mode="no_video", noise=asdict(self.noise), variability=asdict(self.variability),
                   protocol=asdict(self.protocol), trials=[asdict(t) for t in self.trials], elapsed_s=self.elapsed_s)
        if self.paper is not None:
            out["paper"] = self.paper.to_json()
        return out


def unabsorbed_gap(clean: pd.DataFrame, params: FrictionParams, phantom: Phantom = DEFAULT_PHANTOM, *,
                   arcs: ArcIntegrals | None = None) -> float | None:
    """RMS (g) of the effect that a refit of the base model's pressure laws cannot absorb.

    The four constants of the linear pressure laws (``p_tip0, p_tip1, p_bot0, p_bot1``) are
    refitted by linear least squares to the noiseless force *with* the effect, on all rows, with
    the true friction law, true angles and each trial's true pressure scale (so the base model
    alone is refitted exactly); the RMS of what is left is returned. A smooth change of the
    pressure distribution (or a weak capstan) is largely absorbed this way: such an effect is
    only identifiable through what is left. The friction constants are not refitted (a
    Stribeck refit may absorb part of a speed-dependent effect too).

    Parameters
    ----------
    clean : pandas.DataFrame
        Per row ``theta_tip``, ``theta_bot`` (true, rad), ``sliding_mm_s`` (instantaneous speed,
        mm/s), ``pressure_scale`` (dimensionless), ``force_effect_g`` (g).
    params : FrictionParams
        The base model (linear pressure laws; otherwise None is returned).
    phantom : Phantom
        Geometry.
    arcs : ArcIntegrals, optional
        :func:`tympani.pipeline.model.friction.arc_integrals` of the rows, if already computed.

    Returns
    -------
    float or None
    """

    need = {"theta_tip", "theta_bot", "sliding_mm_s", "pressure_scale", "force_effect_g"}
    if not need <= set(clean.columns) or not (isinstance(params.p_tip_MPa, LinearPressure)
                                              and isinstance(params.p_bot_MPa, LinearPressure)):
        return None
    if arcs is None:
        arcs = arc_integrals(clean["theta_bot"].to_numpy(float), clean["theta_tip"].to_numpy(float), phantom)
    mu = stribeck(clean["sliding_mm_s"].to_numpy(float), params)
    a = arcs.g0[:, 0] + mu * arcs.g0[:, 1]
    b = arcs.g1[:, 0] + mu * arcs.g1[:, 1]
    th = arcs.theta_con
    k = params.contact_width_mm / G_N * clean["pressure_scale"].to_numpy(float)
    x = k[:, None] * np.stack([a - b, th * (a - b), b, th * b], axis=1)
    y = clean["force_effect_g"].to_numpy(float)
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y)
    beta, *_ = np.linalg.lstsq(x[ok], y[ok], rcond=None)
    return rms(y[ok] - x[ok] @ beta)


def effect_truth(effect: str | None, strength: float, values: Mapping[str, float], clean: pd.DataFrame,
                 measured_g: np.ndarray, *, base: FrictionParams, arcs: ArcIntegrals | None = None) -> EffectTruth:
    """The truth of an experiment with a hidden effect: the effect and its gap against the noise.

    Parameters
    ----------
    effect : str or None
        Effect name or None.
    strength : float
        Its strength (dimensionless).
    values : mapping
        Its parameters (units in the names).
    clean : pandas.DataFrame
        Per row ``speed_mm_s`` (mm/s), ``force_base_g`` and ``force_effect_g`` (noiseless, g); for
        :func:`unabsorbed_gap` also ``theta_tip``, ``theta_bot``, ``sliding_mm_s`` and ``pressure_scale``.
    measured_g : ndarray
        The measured force (g) of the same rows.
    base : FrictionParams
        The base model.
    arcs : ArcIntegrals, optional
        Arc integrals of the rows (saves recomputing them for :func:`unabsorbed_gap`).

    Returns
    -------
    EffectTruth
        ``detectable`` is gap RMS > 2 × noise RMS; ``gap_unabsorbed_rms_g`` is None without the
        columns :func:`unabsorbed_gap` needs (0 without an effect).
    """
    eff = find_effect(effect)
    f_base = clean["force_base_g"].to_numpy(float)
    f_eff = clean["force_effect_g"].to_numpy(float)
    gap = f_eff - f_base
    resid = np.asarray(measured_g, dtype=float) - f_eff
    speeds = clean["speed_mm_s"].to_numpy(float)
    by_speed = tuple(SpeedGap(speed_mm_s=float(v), gap_rms_g=rms(gap[speeds == v]),
                              gap_mean_g=float(np.mean(gap[speeds == v])), noise_rms_g=rms(resid[speeds == v]),
                              n=int(np.sum(speeds == v)))
                     for v in np.unique(speeds))
    gap_rms, noise_rms = rms(gap), rms(resid)
    left = unabsorbed_gap(clean, base, arcs=arcs) if eff is not None else 0.0
    return EffectTruth(
        effect=eff.name if eff is not None else None,
        strength=float(strength) if eff is not None else 0.0,
        params=dict(values),
        form=eff.form if eff is not None else None,
        library_form=eff.library_form if eff is not None else None,
        kind=eff.kind if eff is not None else None,
        base_params=_flat(base),
        gap_rms_g=gap_rms,
        gap_mean_g=float(np.mean(gap)) if gap.size else 0.0,
        gap_max_g=float(np.max(np.abs(gap))) if gap.size else 0.0,
        noise_rms_g=noise_rms,
        gap_to_noise=gap_rms / noise_rms if noise_rms > 0 else float("inf"),
        detectable=bool(gap_rms > 2.0 * noise_rms),
        gap_unabsorbed_rms_g=left,
        unabsorbed_to_noise=(left / noise_rms if noise_rms > 0 else float("inf")) if left is not None else None,
        gap_by_speed=by_speed,
    )


def _flat(params: FrictionParams) -> dict[str, float]:
    try:
        return flat_params(params)
    except TypeError:
        return {"repr": repr(params)}  # type: ignore[dict-item]

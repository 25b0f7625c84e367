"""Experiments that would split effects the diagnosis cannot tell apart (docs/diagnosis.md).

For each candidate experiment — a **dwell** after the stop, a **retraction** right after the
insertion, a second lubricant **viscosity**, a **baseline** log before the robot moves — every
fitted effect predicts a signed change of the sensed force (g) relative to what the base model
predicts, at the fastest speed of the data, computed from that effect's fitted parameters
(:mod:`tympani.pipeline.diagnosis.candidates`). The experiment recommended for a set of tied effects is the one whose
predictions differ most between every pair of them (largest smallest pairwise difference).

The predictions are first-order consequences of the library's functional forms
(:mod:`tympani.pipeline.model.effects`), stated with their assumptions:

- ``sensor_lag``: a first-order sensor with time constant tau. At the stop the sensed force is short
  of the true force by the deficit D (≈ tau |dF/dt|); during a dwell it recovers D, 63 % within tau.
  On a retraction the deviation flips sign (the sensed force trails a falling force from above).
  A sensor property: no change with the lubricant.
- ``hydrodynamic_lift``: a film carries the share s(v) = a v^n of the load. On a retraction |F| is
  again lowered by s(v) (towards zero, no sign flip); with twice the viscosity s follows (eta v)^n,
  i.e. s(2v). In a dwell the film drains on a time set by viscosity and load (not by the sensor):
  the plain form does not say how fast, so the dwell splits lift from lag by its *time course*
  only (lag: exactly tau), not by its size. The film variant (built up over a sliding distance,
  squeezed out with a fitted time constant) predicts the dwell's rise; when that time constant
  matches a lag's, only a retraction or a second viscosity splits them.
- ``viscous_drag``: + c v L_wet, opposing the motion: vanishes at once in a dwell, reverses on a
  retraction, doubles with twice the viscosity.
- ``sensor_drift``: d g/s whatever the robot does: visible in a baseline log before any contact.
- ``capstan``: exp(k mu theta_con) amplifies the insertion force; on a retraction the belt friction
  reverses and the factor becomes exp(-k mu theta_con).
- ``pressure_profile``: a pressure shape over the arc; unchanged by dwell, direction or lubricant
  except through mu.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

__all__ = ["EXPERIMENTS", "Experiment", "ExperimentPrediction", "effect_predictions", "splitting_experiments"]

#: Candidate experiments: name -> protocol, in order of preference when they split equally well.
EXPERIMENTS: dict[str, str] = {
    "retraction": "retract at the same speed right after the insertion (fastest speed), logging force and angles",
    "viscosity": "repeat the fastest insertions with a lubricant of twice the viscosity (e.g. 90 % instead of ~80 % "
                 "glycerol)",
    "dwell": "hold the array still for 3 s after the stop at the fastest speed, logging the force",
    "baseline": "log the force for 5 s before the robot moves (array in the lubricant, no contact)",
}



@dataclass(frozen=True)
class ExperimentPrediction:
    """What one fitted effect predicts for one experiment.

    Attributes
    ----------
    change_g : float or None
        Signed change of the sensed force (g) relative to the base model; None when the effect's
        form does not fix it.
    words : str
        The prediction in words.
    """

    change_g: float | None
    words: str


@dataclass(frozen=True)
class Experiment:
    """An experiment and how well it splits a set of effects (:func:`splitting_experiments`).

    Attributes
    ----------
    experiment : str
        Its name (a key of :data:`EXPERIMENTS`).
    protocol : str
        What to do.
    effects : tuple of str
        The effects to split.
    predictions : dict
        Effect -> :class:`ExperimentPrediction`.
    min_difference_g : float or None
        Smallest difference (g) between two effects' predicted changes, among the effects whose
        prediction is fixed; None when fewer than two are.
    complete : bool
        Every effect's prediction is fixed.
    recommended : bool
        The best-ranked experiment.
    """

    experiment: str
    protocol: str
    effects: tuple[str, ...]
    predictions: dict[str, ExperimentPrediction]
    min_difference_g: float | None
    complete: bool
    recommended: bool


_DWELL_S = 3.0
_BASELINE_S = 5.0


def _end_rows(ds) -> np.ndarray:
    """The row at the stop (last moving row) of every trial at the fastest speed."""
    fastest = ds.trial_speed == ds.speeds[-1]
    moving = np.flatnonzero((ds.phase_label >= 1) & (ds.phase_label <= 3) & fastest[ds.trial])
    if moving.size == 0:
        return np.zeros(0, dtype=int)
    ends = [int(moving[ds.trial[moving] == t].max()) for t in np.unique(ds.trial[moving])]
    return np.asarray(ends, dtype=int)


def effect_predictions(ds, fit, model_g: np.ndarray) -> dict:
    """What one fitted effect predicts for each experiment of :data:`EXPERIMENTS`.

    Parameters
    ----------
    ds : pipeline.diagnosis.prepare.Prepared
        The data (the fastest speed's trial ends are used).
    fit : pipeline.diagnosis.candidates.CandidateFit
        A fit of base + one effect to all speeds.
    model_g : ndarray, shape (n,)
        The fit's model force (g) on every row of ``ds``, with its trial gains
        (:func:`tympani.pipeline.diagnosis.candidates.predict`).

    Returns
    -------
    dict
        Experiment name -> ``{"change_g": signed change (g) relative to the base model, or None
        when the form does not fix it, "words": str}``, plus ``"_state"`` with the quantities used
        (speed mm/s, base force at the stop g, effect parameters).
    """
    cand = fit.candidate
    rows = _end_rows(ds)
    v = float(ds.speeds[-1])
    mu = ds.friction_coefficient(fit.friction)
    u = fit.coef[:4]
    normal = (ds.a_n @ u)[rows]
    along = (ds.a_t @ u)[rows]
    f0 = float(np.mean(normal + mu[rows] * along))        # base part at the stop (g)
    f_retract = float(np.mean(normal - mu[rows] * along))  # base part retracting at v (g)
    model = float(np.mean(model_g[rows]))  # with the fit's trial gains
    p = fit.effect_params()
    name = cand.effect
    out: dict = {"_state": dict(speed_mm_s=v, base_force_at_stop_g=f0, model_force_at_stop_g=model, params=p)}

    def put(exp: str, change, words: str) -> None:
        out[exp] = {"change_g": None if change is None else float(change), "words": words}

    if name == "sensor_lag":
        tau = p["tau_s"]
        deficit = f0 - model
        put("dwell", deficit * (1 - math.exp(-_DWELL_S / max(tau, 1e-9))),
            f"the force rises by {deficit:.3g} g after the stop, exponentially with tau = {tau:.3g} s (63 % within "
            f"{tau:.2g} s)")
        put("retraction", +deficit, f"the deviation from the model flips sign: the sensed force trails the falling "
                                    f"force from above by about {deficit:.3g} g (tau |dF/dt|)")
        put("viscosity", 0.0, "no change: the lag belongs to the sensor, not the lubricant")
        put("baseline", 0.0, "nothing before contact")
    elif name == "hydrodynamic_lift":
        a, n = p["lift_share"], p["lift_exponent"]
        s1 = min(a * v**n, 0.95)
        s2 = min(a * (2 * v) ** n, 0.95)
        squeeze = p.get("film_squeeze_s")
        if squeeze is None:
            put("dwell", None, f"up to {s1 * f0:.3g} g returns as the film drains, on a time set by viscosity and "
                               f"load (not a sensor constant; the fitted form does not fix it)")
        else:
            put("dwell", s1 * f0 * (1 - math.exp(-_DWELL_S / max(squeeze, 1e-9))),
                f"the force rises by up to {s1 * f0:.3g} g as the film squeezes out, with the fitted time constant "
                f"{squeeze:.3g} s, and faster with a thinner lubricant (a sensor's lag would not change)")
        put("retraction", -s1 * f_retract, f"|F| stays {100 * s1:.0f} % below the model ({-s1 * f_retract:+.3g} g, "
                                          f"towards zero) also when retracting: no sign flip")
        put("viscosity", -(s2 - s1) * f0, f"share grows with (eta v)^{n:.2f}: the force at the stop falls by a further "
                                          f"{(s2 - s1) * f0:.3g} g ({100 * s1:.0f} % -> {100 * s2:.0f} % below the model)")
        put("baseline", 0.0, "nothing before contact")
    elif name == "viscous_drag":
        c = p["drag_g_s_per_mm2"]
        wet = float(np.mean(ds.ctx.wetted_mm[rows]))
        d = c * v * wet
        put("dwell", -d, f"drops at once by {d:.3g} g when the motion stops")
        put("retraction", -2 * d, f"reverses with the motion: from +{d:.3g} g to -{d:.3g} g relative to the model")
        put("viscosity", +d, f"doubles: a further +{d:.3g} g at the stop")
        put("baseline", 0.0, "nothing while the robot stands")
    elif name == "sensor_drift":
        d = p["drift_g_per_s"]
        put("dwell", d * _DWELL_S, f"keeps drifting at {d:+.3g} g/s ({d * _DWELL_S:+.3g} g over {_DWELL_S:g} s), "
                                   f"unrelated to the stop")
        put("retraction", 0.0, "unaffected by the direction of motion")
        put("viscosity", 0.0, "unaffected by the lubricant")
        put("baseline", d * _BASELINE_S, f"{d * _BASELINE_S:+.3g} g over {_BASELINE_S:g} s with no contact at all")
    elif name == "capstan":
        k = p["capstan_gain"]
        th = float(np.mean(ds.theta_con[rows]))
        m = float(np.mean(mu[rows]))
        amp, att = math.exp(k * m * th), math.exp(-k * m * th)
        put("dwell", 0.0, "no change while standing (static belt friction)")
        put("retraction", f_retract * (att - 1.0) - f0 * (amp - 1.0),
            f"belt friction reverses: the factor exp(k mu theta_con) = {amp:.3g} becomes {att:.3g} "
            f"(theta_con = {th:.2f} rad)")
        put("viscosity", 0.0, "changes only through mu (a lubricant with another mu changes the log-slope over theta_con)")
        put("baseline", 0.0, "nothing before contact")
    elif name == "pressure_profile":
        put("dwell", 0.0, "no change while standing")
        put("retraction", 0.0, "the same pressure shape over theta_con in both directions")
        put("viscosity", 0.0, "no change")
        put("baseline", 0.0, "nothing before contact")
    else:  # an effect this module does not know
        for exp in EXPERIMENTS:
            put(exp, None, "no prediction for this effect")
    return out


def splitting_experiments(ds, fits: Mapping, focus: Sequence[str],
                          model_g: Mapping[str, np.ndarray]) -> tuple[Experiment, ...]:
    """Experiments ranked by how well they split the effects in ``focus``.

    Parameters
    ----------
    ds : pipeline.diagnosis.prepare.Prepared
    fits : mapping
        Candidate name -> CandidateFit (fits to all speeds).
    focus : sequence of str
        Effects to split (the tied ones, or the leader and its runner-up).
    model_g : mapping
        Candidate name -> its fit's model force (g) per row, with the trial gains
        (:func:`tympani.pipeline.diagnosis.candidates.predict`).

    Returns
    -------
    tuple of Experiment
        One per experiment, best first (an incomplete experiment ranks as if its difference were
        half as large); empty for fewer than two effects.
    """
    focus = [e for e in dict.fromkeys(focus) if e in fits and fits[e].candidate.effect is not None]
    if len(focus) < 2:
        return ()
    preds = {e: effect_predictions(ds, fits[e], model_g[e]) for e in focus}
    ranked = []
    for order, (exp, protocol) in enumerate(EXPERIMENTS.items()):
        changes = [preds[e][exp]["change_g"] for e in focus]
        known = [c for c in changes if c is not None]
        diffs = [abs(a - b) for i, a in enumerate(known) for b in known[i + 1:]]
        min_diff = min(diffs) if diffs else None
        complete = len(known) == len(changes)
        predictions = {e: ExperimentPrediction(change_g=preds[e][exp]["change_g"], words=preds[e][exp]["words"])
                       for e in focus}
        ranked.append(((-(min_diff or 0.0) * (1.0 if complete else 0.5), order),
                       dict(experiment=exp, protocol=protocol, effects=tuple(focus), predictions=predictions,
                            min_difference_g=min_diff, complete=complete)))
    ranked.sort(key=lambda item: item[0])
    return tuple(Experiment(**fields, recommended=i == 0) for i, (_, fields) in enumerate(ranked))

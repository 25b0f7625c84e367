"""The verdict of the gap diagnosis (:func:`decide`): ``identified``, ``ambiguous`` or ``no_gap``.

Every candidate is fitted on all speeds but one and predicts the one held out
(leave-one-speed-out; the fold holding out the fastest speed is the extrapolation test). Held-out
mean squared errors are compared with a bootstrap over trials stratified by speed; the rules and
their frozen thresholds are :func:`decide`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from tympani.pipeline.diagnosis.config import DiagnosisConfig

__all__ = ["Decision", "VariantChoice", "decide"]


@dataclass(frozen=True)
class VariantChoice:
    """Whether a richer variant of an effect's kernel replaced its plain one.

    Attributes
    ----------
    variant : str
        The variant's name (:data:`tympani.pipeline.diagnosis.kernels.VARIANTS`).
    used : bool
        Whether it predicts the held-out speeds significantly better than the plain kernel.
    heldout_rmse_plain_g, heldout_rmse_variant_g : float
        Held-out RMSE (g) of the plain kernel and of the variant.
    """

    variant: str
    used: bool
    heldout_rmse_plain_g: float
    heldout_rmse_variant_g: float


@dataclass(frozen=True)
class Decision:
    """The verdict and what it rests on (:func:`decide`).

    Attributes
    ----------
    verdict : str
        ``identified``, ``ambiguous`` or ``no_gap``.
    effect : str or None
        The identified effect.
    reference : str
        ``base`` or ``control``: the one with the smaller held-out MSE.
    leader : str
        The effect with the smallest held-out MSE.
    tied : tuple of str
        The effects the verdict cannot tell apart (ambiguous), or the identified one; empty for
        ``no_gap``.
    explains : tuple of str
        The effects that remove significantly more than ``min_gain`` of the held-out MSE of base
        and of control.
    gain, gain_lo : dict
        Effect -> share of the reference's held-out MSE removed (dimensionless): point and lower
        bound.
    separation_lo : dict
        Effect other than the leader -> lower bound of the share of the leader's gain it misses.
    systematic_g : dict
        Candidate -> systematic misfit (g) of its held-out residual.
    reason : str
        The verdict in words.
    variants : dict
        Effect -> :class:`VariantChoice` of its richer kernel (filled in by
        :func:`tympani.pipeline.diagnosis.analysis.diagnose`).
    """

    verdict: str
    effect: str | None
    reference: str
    leader: str
    tied: tuple[str, ...]
    explains: tuple[str, ...]
    gain: dict[str, float]
    gain_lo: dict[str, float]
    separation_lo: dict[str, float]
    systematic_g: dict[str, float]
    reason: str
    variants: dict[str, VariantChoice] = field(default_factory=dict)


def decide(mse: Mapping[str, float], draws: Mapping[str, np.ndarray], effects: Sequence[str], lof_significant: bool,
           config: DiagnosisConfig = DiagnosisConfig(), systematic: Mapping[str, float] | None = None,
           lof_p: tuple[float, float] = (1.0, 1.0)) -> Decision:
    """The verdict from held-out mean squared errors.

    The *reference* is the better (smaller held-out MSE) of ``base`` and ``control``: an effect
    must beat the paper's model both with its nominal and with its re-identified friction law.
    Rule (thresholds of :class:`tympani.pipeline.diagnosis.config.DiagnosisConfig`, frozen):

    1. An effect *explains a gap* when, at one-sided level ``alpha`` of the bootstrap over trials,
       it removes more than ``min_gain`` of the held-out MSE of base and of control:
       ``quantile_alpha(MSE_r - MSE_e - min_gain MSE_r) > 0`` for r = base and r = control.
    2. ``no_gap`` when base passes the lack-of-fit test (its held-out predictions are within the
       scatter between repeats), or when no effect explains a gap. Except: when base and control
       both fail the test at the stricter level ``unexplained_alpha`` and no effect explains the
       gap, ``ambiguous``: there is a gap of a form no candidate has; the three effects with the
       smallest held-out errors are named, ranked.
    3. Otherwise the leader ``b`` is the effect with the smallest held-out MSE; another effect ``e``
       is *separated* from it when it misses more than ``min_separation`` of the leader's gain
       over the reference: ``quantile_alpha(MSE_e - MSE_b - min_separation (MSE_ref - MSE_b)) > 0``.
       ``identified`` when every other effect is separated, else ``ambiguous`` with the tied ones.
    4. Misfit guard: an effect that explains a gap stays tied with the leader unless its systematic
       misfit ``S`` (noise-corrected RMS of its held-out residual over repeats) satisfies
       ``S_e^2 - S_b^2 > mismatch_factor * S_b^2``.

    Parameters
    ----------
    mse : mapping
        Held-out MSE (g^2) per candidate name (``base``, ``control`` and the effects).
    draws : mapping
        Bootstrap draws of the MSE per candidate (the same draws for all).
    effects : sequence of str
        Effect candidates.
    lof_significant : bool
        Whether base fails the lack-of-fit test (held-out residuals vs repeat scatter).
    config : DiagnosisConfig
    lof_p : tuple of float
        Lack-of-fit p-values of base and control (rule 2).
    systematic : mapping, optional
        Systematic misfit (g) of each effect's held-out residual (rule 4; skipped without it).

    Returns
    -------
    Decision
        Without ``variants``.
    """
    a = config.alpha
    ref = "control" if mse["control"] <= mse["base"] else "base"
    ctrl, ctrl_d = mse[ref], draws[ref]
    gain = {e: 1.0 - mse[e] / ctrl if ctrl > 0 else 0.0 for e in effects}
    gain_lo = {e: float(np.quantile(1.0 - draws[e] / np.maximum(ctrl_d, 1e-300), a)) for e in effects}
    explains = [e for e in effects
                if all(np.quantile(draws[r] - draws[e] - config.min_gain * draws[r], a) > 0 for r in ("base", "control"))]
    leader = min(effects, key=lambda e: mse[e])
    denom = ctrl_d - draws[leader]
    sep_lo = {}
    for e in effects:
        if e != leader:
            with np.errstate(divide="ignore", invalid="ignore"):  # 1e9: "no gain to miss" in that draw
                ratio = np.where(denom > 0, (draws[e] - draws[leader]) / np.where(denom > 0, denom, 1.0), 1e9)
            sep_lo[e] = float(np.quantile(ratio, a))
    def separated(e: str) -> bool:
        if not np.quantile(draws[e] - draws[leader] - config.min_separation * denom, a) > 0:
            return False
        if systematic is None or config.mismatch_factor <= 0 or e not in explains:
            return True
        s_b, s_e = systematic[leader] ** 2, systematic[e] ** 2
        return s_e - s_b > config.mismatch_factor * s_b

    tied = [leader] + sorted((e for e in effects if e != leader and not separated(e)), key=lambda e: mse[e])
    s_ref = systematic.get(ref, 0.0) if systematic is not None else 0.0
    adequate = (systematic is None or config.min_explained <= 0 or s_ref <= 0
                or systematic[leader] ** 2 <= (1.0 - config.min_explained) * s_ref ** 2)
    if leader not in explains and max(lof_p) < config.unexplained_alpha:
        verdict, effect = "ambiguous", None
        tied = sorted(effects, key=lambda e: mse[e])[:3]
        reason = ("the model misses the scatter between repeats on held-out speeds, with its friction law as "
                  "simulated and re-identified, but no effect removes significantly more than "
                  f"{100 * config.min_gain:.0f} % of the held-out error: the gap has a form none of the candidates "
                  f"has; closest: {', '.join(tied)}")
    elif leader not in explains:
        verdict, effect, tied = "no_gap", None, []
        reason = (f"no effect removes significantly more than {100 * config.min_gain:.0f} % of the held-out error of the "
                  f"base model with nominal and with re-identified friction (best: {leader}, {100 * gain[leader]:.0f} % "
                  f"of the {ref}'s, lower bound {100 * gain_lo[leader]:.0f} %)")
    elif not lof_significant:
        verdict, effect, tied = "no_gap", None, []
        reason = ("the paper's model predicts held-out speeds within the scatter between repeats (lack-of-fit test "
                  f"not significant), although {leader} lowers the held-out error by {100 * gain[leader]:.0f} %")
    elif len(tied) == 1 and not adequate:
        verdict, effect = "ambiguous", None
        tied = [leader] + sorted((e for e in effects if e != leader), key=lambda e: mse[e])[:2]
        reason = (f"{leader} explains part of the gap best, but leaves more than {100 * (1 - config.min_explained):.0f} "
                  "% of its repeatable part: its form is not the data's, and another effect in another form may be "
                  f"behind it; ranked: {', '.join(tied)}")
    elif len(tied) == 1:
        verdict, effect = "identified", leader
        runner = min(sep_lo, key=lambda e: mse[e]) if sep_lo else None
        if runner is None:
            tail = ""
        elif sep_lo[runner] >= 1.0:
            tail = f"; the runner-up {runner} does no better than the {ref}"
        else:
            tail = f"; the runner-up {runner} misses at least {100 * sep_lo[runner]:.0f} % of that gain"
        reason = (f"{leader} removes {100 * gain[leader]:.0f} % of the {ref}'s held-out error (lower bound "
                  f"{100 * gain_lo[leader]:.0f} %){tail}")
    else:
        verdict, effect = "ambiguous", None
        reason = (f"{', '.join(tied)} explain the gap about equally well on held-out speeds (none misses "
                  f"significantly more than {100 * config.min_separation:.0f} % of the leader's gain)")
    return Decision(verdict=verdict, effect=effect, reference=ref, leader=leader, tied=tuple(tied),
                    explains=tuple(explains), gain=gain, gain_lo=gain_lo, separation_lo=sep_lo,
                    systematic_g=dict(systematic or {}), reason=reason)

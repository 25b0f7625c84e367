"""How the gap diagnosis works: its configuration and the constants its steps share."""

from __future__ import annotations

from dataclasses import dataclass, field

from tympani.pipeline.model.effects import EFFECTS
from tympani.pipeline.model.friction import DEFAULT_FRICTION_MODE, FrictionMode, FrictionParams

__all__ = ["DiagnosisConfig", "DATA_NEEDED", "PHASES", "CONTACT_WIDTH_MM"]

#: What the diagnosis needs, for error messages.
DATA_NEEDED = ("the diagnosis needs at least 3 insertion speeds with at least 2 trials (repeats) each, "
               "and a force that changes during the insertion")

#: Insertion phases of the "where" analysis.
PHASES = ("before", "early", "middle", "late", "dwell")

#: Contact width (mm) of the pressure integrals, held as in :mod:`tympani.pipeline.model.identify` (only the
#: product of width and pressure enters the force).
CONTACT_WIDTH_MM = FrictionParams().contact_width_mm


@dataclass(frozen=True)
class DiagnosisConfig:
    """How :func:`tympani.pipeline.diagnosis.analysis.diagnose` works. The decision thresholds were
    calibrated on development data (not on evaluation seeds) and are frozen.

    Parameters
    ----------
    rows_per_trial : int
        Rows kept per trial for fitting, evenly spaced in time (count).
    angle_smoothing_s : float
        Width (s) of a quadratic Savitzky–Golay smoother applied to each trial's ``theta_tip`` and
        ``theta_bot`` before the models see them (0: off). Angles measured frame by frame carry
        independent noise that the force does not: through the steep force–angle curve it is the
        largest error left in a correct model's prediction (about 0.04 g of 0.045 g on effect-free
        synthetic data with 0.01 rad angle noise; 0.025 g after smoothing over 0.6 s).
    effects : tuple of str
        Candidate effects (names of :data:`tympani.pipeline.model.effects.EFFECTS`).
    friction : FrictionParams
        Nominal friction law of ``base`` and the effect candidates (``mu_s``, ``mu_k``
        dimensionless, ``v_s_mm_s`` mm/s, ``delta_s``, ``mu_v_s_per_mm`` s/mm); its pressures
        are ignored (always identified).
    friction_mode : {"axial", "vector"}
        Friction projection of the model (:mod:`tympani.pipeline.model.friction`).
    trial_gain : bool
        Fit a per-trial gain on the contact force (mean per speed within its random range of 1).
    gain_bounds : tuple of float
        Bounds of a trial gain (dimensionless).
    level_sd : float
        A speed's mean gain may differ from 1 by up to ``level_sd`` standard errors of a mean of its
        trials' placement scales (dimensionless; 0 pins it at 1).
    starts : int
        Starts of each non-linear fit to all speeds (the first at the defaults, the rest random,
        seeded); held-out fits start from the fit to all speeds.
    bootstrap : int
        Bootstrap resamples of trials (stratified by speed).
    seed : int
        Seed of the random starts and the bootstrap.
    alpha : float
        One-sided level of each bootstrap comparison (dimensionless).
    min_gain : float
        Least share of the control's held-out mean squared error (dimensionless) an effect must
        remove, at level ``alpha``, to count as explaining a gap.
    unexplained_alpha : float
        Level at which base and control must both fail the lack-of-fit test for a gap no effect
        explains to be reported (``ambiguous``) rather than ``no_gap`` (stricter than
        ``lof_alpha``: two tests at 0.05 fail together on 2 of 20 effect-free data sets).
    min_separation : float
        Least share of the leading effect's gain over the control (dimensionless) another effect
        must miss, at level ``alpha``, for the leader to be identified rather than tied with it.
    min_explained : float
        Least share of the reference's systematic misfit (squared) the leader must remove to be
        identified (dimensionless); below it the verdict is ``ambiguous``.
    mismatch_factor : float
        Another effect that explains a gap stays tied with the leader unless its systematic misfit
        (the repeatable part of its held-out residual,
        :func:`tympani.pipeline.diagnosis.evidence.systematic_gap`, squared) exceeds the leader's by more
        than ``mismatch_factor`` times the leader's own (dimensionless): when the leader itself
        leaves a systematic misfit its form is not the data's, and a rival whose misfit is not
        clearly larger may be the right effect in another form.
    lof_alpha : float
        Level of the lack-of-fit test (Holm-corrected over cells).
    phase_bins : int
        Bins of the moving part of a trial (normalised time) in the lack-of-fit test.
    theta_bins : int
        Bins of theta_con (equal width over the contact range) in the "where" analysis.
    min_speeds : int
        Fewest speeds with enough repeats.
    min_trials_per_speed : int
        Fewest trials at a speed for it to count.
    """

    rows_per_trial: int = 56
    angle_smoothing_s: float = 0.6
    effects: tuple[str, ...] = tuple(EFFECTS)
    friction: FrictionParams = field(default_factory=FrictionParams)
    friction_mode: FrictionMode = DEFAULT_FRICTION_MODE
    trial_gain: bool = True
    gain_bounds: tuple[float, float] = (0.5, 1.5)
    level_sd: float = 2.0
    starts: int = 2
    bootstrap: int = 1000
    seed: int = 0
    alpha: float = 0.025
    min_gain: float = 0.05
    unexplained_alpha: float = 0.01
    min_explained: float = 0.5
    min_separation: float = 0.30
    mismatch_factor: float = 2.0
    lof_alpha: float = 0.05
    phase_bins: int = 4
    theta_bins: int = 5
    min_speeds: int = 3
    min_trials_per_speed: int = 2


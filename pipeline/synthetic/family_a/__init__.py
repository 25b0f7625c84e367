"""Synthetic experiments with a hidden unmodelled effect, for blind tests of the diagnosis.

:func:`synthetic_dataset` generates a force-and-angles-only experiment (no video) as a synced
table (docs/file-formats.md), together with a *truth* record (:class:`DatasetTruth`) that the
diagnosis never sees: which effect was hidden (one of those of docs/diagnosis.md), its parameters,
the noise, and how large the effect is compared with the noise.
:func:`write_experiment` writes it as a manifest + angles tables + force logs (what ``tympani
sync`` reads) and ``truth/effect.json``; ``tympani render --effect NAME [--no-video]`` is the
command line. :func:`paper_case` is a dataset calibrated to the seed paper's speed drop.

No inverse crime
----------------
The diagnosis fits the *library* forms of :mod:`tympani.pipeline.model.effects`. The data are generated with
*different* forms, so a diagnosis is always tested on a model-form mismatch. Side by side
(``p(u)`` the paper's Eq. (6) pressure at ``u = s / l_con`` from the tip, ``g_n = n_out . x_w``,
``g_t = t . x_w`` along the outer wall, ``mu = mu(v)`` the Stribeck law, ``b_c`` the contact width):

=================  ==========================================  ==============================================
effect             generator (this module)                     library (:mod:`tympani.pipeline.model.effects`)
=================  ==========================================  ==============================================
hydrodynamic_lift  soft-EHL film, *local* load share acting    ``F (1 - a v^n)``: one share for the whole
                   on the pressure:                            arc, a power law of v, independent of load
                   ``h/h_c = lam v^alpha (p/p_ref)^-beta``
                   (Hamrock–Dowson-like: h ~ (eta v)^0.6–0.67
                   W^-0.21), share ``x^q / (1 + x^q)``,
                   ``p_eff(u) = p(u) (1 - share(u))``; after
                   the stop the film squeezes out,
                   ``h(t) = h_stop / sqrt(1 + t / t_sq)``
viscous_drag       Couette shear ``eta v / gap`` integrated    ``F + c v L_wet`` with ``L_wet`` = depth
                   over the wetted array: a thin film
                   ``h_f`` under the contact strip
                   (``b_c l_con / h_f``) plus the free
                   perimeter ``pi d(s)`` over the local
                   lateral play ``gap(s)`` (narrowing with
                   the channel) along the array in the entry
                   and the spiral; zero when the robot stops
capstan            per-element amplification: each arc        ``F exp(k mu theta_con)``: one global factor
                   element's load (normal + friction) is
                   multiplied by ``exp(kappa mu psi(u))``
                   (kappa ≈ 4 at strength 1),
                   ``psi`` = the wall's tangent turning
                   between the element and the contact start
                   (true wrap angle, incl. the 100° corner)
sensor_lag         two equal poles ``1/(1 + s tau2)^2`` plus   first-order ``1/(1 + s tau)``
                   a dead time ``d`` (``tau_eq ~ 2 tau2 + d``)
sensor_drift       ``r t (1 + c t / 30 s)`` + a random walk    ``r t`` (linear)
                   (diffusion ``sigma``), per-trial rate
                   jitter, from the start of each log
pressure_profile   multiplicative skewed (gamma-shaped) bump   additive symmetric bump ``B 4u(1-u)`` of fixed
                   ``p(s) (1 + beta b(s))``,                   amplitude (g/mm), fixed place on the arc
                   ``b = (s/l_b)^k exp(k (1 - s/l_b))`` at a
                   fixed *arc length* ``l_b`` (the array's
                   bending length, 1.5–3.5 mm) from the tip,
                   so its place ``u = l_b / l_con`` on the
                   arc moves as the contact grows
=================  ==========================================  ==============================================

The physical effects (lift, drag, capstan, profile) change the force *at the contact*; the
generator evaluates them by midpoint quadrature along the arc and adds their difference from the
same quadrature of the base model to the exact base force (:func:`tympani.pipeline.model.friction.insertion_force`),
so ``effect=None`` gives exactly the base model plus noise. The sensor effects (lag, drift) act on
the sensed signal, before the noise and the A/D.

Each effect has a *strength* (0 = absent, 1 = a typical, clearly detectable size; lift at strength
1 is the seed-paper calibration of :func:`paper_case`); its other constants are drawn within
physically plausible ranges (:data:`HIDDEN_EFFECTS`, ``ranges``). At strength 1 (default noise,
5 speeds x 10 trials) the noiseless gap is 3–15 times the noise RMS (about 0.04 g).

How much of an effect a diagnosis can see depends on what the base model absorbs when it is
refitted: the truth reports ``gap_unabsorbed_rms_g``, what is left of the gap after refitting the
four pressure-law constants (:func:`unabsorbed_gap`). A smooth redistribution of the contact
pressure (any fixed profile along ``u``, additive or multiplicative) and a weak capstan are
absorbed almost entirely (>95 % and ~88 %) by the linear-in-theta_con pressure laws; the
generator's capstan and pressure profile are therefore set so that what survives is about twice
the noise at strength 1 (capstan kappa ≈ 4; the bump up to 5x the linear pressure, at a fixed arc
length, so its place on the arc moves with theta_con).

One trial (force clock, ``time_s`` from 0 at the start of the log)::

    0 ≤ t < pre_s        robot still at start_depth_mm (-1 mm: tip in the entry), sensor tared
    pre_s ≤ t < t_stop   insertion at the trial's actual speed (nominal ± 2 %) to depth_mm
    t_stop ≤ t ≤ +dwell  robot holds: no sliding (mu = mu_s), drag vanishes, a lagging sensor
                         relaxes, a lift film squeezes out slowly, drift goes on

Trials differ in their contact growth (:func:`tympani.vision.rendering.random_policy`), their pressure
scale (± 10 %), speed (± 2 %) and noise scale. The force noise is white + AR(1) with a per-trial
scale and a small tare offset, quantised by a 13-bit A/D over ``±range_g``. The angles are the
renderer's geometry (:func:`kinematics_table`, a vectorised twin of
:func:`tympani.vision.rendering.pose_at_depth`, within ~0.015 rad of it) measured at ``angles_fps`` on the
video clock with noise, then interpolated onto the force clock exactly as ``tympani sync`` does;
so writing the experiment and syncing it gives back the same table.

Modules, by step: :mod:`.config` (noise, variability, protocol), :mod:`.kinematics` (true angles
against depth), :mod:`.state` (the rows of trials and quadrature on their contact arcs),
:mod:`.effects` (the hidden effects), :mod:`.dataset` (:func:`synthetic_dataset`), :mod:`.truth`
(the truth records), :mod:`.files` (:func:`write_experiment`), :mod:`.paper` (the paper case).
"""

from __future__ import annotations

from tympani.pipeline.model.paper import PAPER_DROPS_PCT
from tympani.pipeline.synthetic.family_a.config import NoiseConfig, Protocol, ScaledPressure, Variability
from tympani.pipeline.synthetic.family_a.dataset import SYNCED_COLUMNS, synthetic_dataset, trial_name
from tympani.pipeline.synthetic.family_a.effects import (
    HIDDEN_EFFECTS,
    PAPER_LIFT,
    HiddenEffect,
    apply_hidden_effect,
    draw_effect_params,
    hidden_effect_names,
)
from tympani.pipeline.synthetic.family_a.files import write_experiment
from tympani.pipeline.synthetic.family_a.kinematics import angles_at_depth, kinematics_table
from tympani.pipeline.synthetic.family_a.paper import (
    PAPER_VARIABILITY,
    calibrate_paper_lift,
    paper_case,
    peak_force_drop,
)
from tympani.pipeline.synthetic.family_a.state import TrialState
from tympani.pipeline.synthetic.family_a.truth import (
    DatasetTruth,
    EffectTruth,
    PaperDrops,
    SpeedGap,
    TrialRecord,
    TruthTables,
    effect_truth,
    unabsorbed_gap,
)

__all__ = [
    "NoiseConfig",
    "Variability",
    "Protocol",
    "TrialState",
    "HiddenEffect",
    "HIDDEN_EFFECTS",
    "hidden_effect_names",
    "draw_effect_params",
    "apply_hidden_effect",
    "ScaledPressure",
    "kinematics_table",
    "angles_at_depth",
    "trial_name",
    "synthetic_dataset",
    "SYNCED_COLUMNS",
    "EffectTruth",
    "SpeedGap",
    "TrialRecord",
    "TruthTables",
    "PaperDrops",
    "DatasetTruth",
    "effect_truth",
    "unabsorbed_gap",
    "write_experiment",
    "peak_force_drop",
    "paper_case",
    "PAPER_LIFT",
    "PAPER_VARIABILITY",
    "PAPER_DROPS_PCT",
    "calibrate_paper_lift",
]

"""Family-B synthetic force/angle data for blind validation of tympani's gap diagnosis.

This module is an *independent* generator ("family B"): it was written from a physics brief
and the project's contract on geometry, angles, the force model and the effect names only,
without reading the project's own generator (:mod:`tympani.pipeline.synthetic.family_a`, "family A") or its
diagnosis, so the gap diagnosis can be checked on data whose functional forms it was not built
around. The diagnosis' thresholds were set on family A; family B is where they are reported
(``tympani evaluate-diagnosis --family B``).

One call of :func:`generate` produces one synthetic experiment: robotic insertions of a
26 mm tapered electrode array into the planar scala-tympani phantom at several nominal
speeds, several trials per speed, as one long table with one row per force sample.  The
force is the paper's friction model (linear contact pressure on the outer-wall arc from
``theta_bot`` to ``theta_tip``, Stribeck friction transmitted along the insertion axis)
plus, optionally, one hidden *unmodelled effect* (named as the diagnosis names them), passed through a
sensor model (calibration gain, tare offset, white + AR(1) noise, 13-bit quantisation).
The angles are those a video tracker would report: sampled at the video frame rate,
noisy, interpolated onto the force clock.

Units follow the contract: mm, s, rad, mm/s, grams-force (1 g = 9.80665e-3 N), MPa.

Physics of every effect, with equations and parameter ranges, is in the docstrings of
:mod:`.effects` and in ``docs/diagnosis.md``.

Modules, by step: :mod:`.constants`, :mod:`.phantom` (geometry), :mod:`.trajectory` (the tip's
path), :mod:`.contact` (the paper's friction model), :mod:`.draws` (random draws),
:mod:`.kinematics` (robot motion, true angles), :mod:`.effects` (hidden effects, sensor chain),
:mod:`.calibration` (the effect's constants), :mod:`.generator` (:func:`generate`), :mod:`.truth`
(the truth records), :mod:`.summary` (:func:`peak_drop`; ``python -m`` prints a summary).

Example
-------
>>> df, truth = generate("hydrodynamic_lift", seed=3)
>>> truth.snr > 3
True
"""

from __future__ import annotations

from tympani.pipeline.synthetic.family_b.constants import EFFECTS, G_N
from tympani.pipeline.synthetic.family_b.contact import arc_force_g, contact_arc, linear_pressure, stribeck_mu
from tympani.pipeline.synthetic.family_b.generator import generate
from tympani.pipeline.synthetic.family_b.phantom import R_TIP_MM, Curve, Phantom, PhantomGeometry, geometry, point_theta
from tympani.pipeline.synthetic.family_b.summary import peak_drop
from tympani.pipeline.synthetic.family_b.trajectory import tip_path, wall_clearance
from tympani.pipeline.synthetic.family_b.truth import (
    BaseModelTruth,
    GeneratedTruth,
    LinearLawTruth,
    NoiseTruth,
    ReferenceTruth,
    TrialTruth,
)

__all__ = [
    "EFFECTS",
    "G_N",
    "Phantom",
    "PhantomGeometry",
    "Curve",
    "R_TIP_MM",
    "wall_clearance",
    "geometry",
    "point_theta",
    "tip_path",
    "contact_arc",
    "linear_pressure",
    "arc_force_g",
    "stribeck_mu",
    "generate",
    "peak_drop",
    "GeneratedTruth",
    "BaseModelTruth",
    "TrialTruth",
    "LinearLawTruth",
    "ReferenceTruth",
    "NoiseTruth",
]

"""The truth of a family-B experiment: typed records of what the diagnosis never sees.

:func:`tympani.pipeline.synthetic.family_b.generator.generate` returns a :class:`GeneratedTruth`;
``to_json()`` gives its JSON object (plain Python numbers, lists and dicts).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Mapping

from tympani.pipeline.synthetic.family_b.draws import jsonable

__all__ = [
    "BASE_MODEL",
    "FRICTION_WHEN_STOPPED",
    "PER_TRIAL_PRESSURE_SCALE",
    "TrialTruth",
    "LinearLawTruth",
    "ReferenceTruth",
    "BaseModelTruth",
    "NoiseTruth",
    "GeneratedTruth",
]

#: The base model of family B, in words.
BASE_MODEL = "the paper's friction model: linear pressure, axial projection of friction"
#: What the base model's friction does while the robot holds still.
FRICTION_WHEN_STOPPED = "held: mu frozen at mu(v_cruise) during the dwell, so the base force stays at its last value"
#: How each trial's pressures vary.
PER_TRIAL_PRESSURE_SCALE = "p_tip_scale, p_bot_scale in trials (U(0.9, 1.1) each)"


@dataclass(frozen=True)
class TrialTruth:
    """One trial of a family-B experiment: its draws and what its kinematics gave.

    Parameters
    ----------
    speed_actual_mm_s : float
        Cruise speed (mm/s).
    pre_roll_s, dwell_s, accel_s : float
        Hold before the motion, hold after it, raised-cosine ramp time (s).
    d0_mm, final_depth_mm : float
        Start and final depth (mm).
    e_lat_mm, tilt_rad, kappa0_per_mm : float
        Lateral offset (mm), tilt (rad) and free curvature (1/mm) of the array in the entry.
    alpha, beta, lambda_ : float
        Contact-start law constants (dimensionless, rad, rad); ``lambda`` in the JSON.
    p_tip_scale, p_bot_scale : float
        Factors (dimensionless) on the pressure laws.
    gain, tare_g : float
        Sensor calibration gain (dimensionless) and tare offset (g).
    video_start_s : float
        Force-clock time (s) of the first video frame.
    t_motion_start_s, t_motion_stop_s : float
        When the robot starts and stops (s).
    d_hit_mm, theta_hit : float
        Depth (mm) and tip angle (rad) at first contact with the outer wall.
    mu : float
        Friction coefficient at the cruise speed (dimensionless).
    theta_tip_end, theta_bot_end : float
        True angles (rad) at the end of the log.
    effect_params : mapping
        The trial's constants of the hidden effect (empty without one).
    film_ratio_at_stop : float or None
        Lift only: film-thickness ratio (dimensionless) when the robot stops.
    """

    speed_actual_mm_s: float
    pre_roll_s: float
    dwell_s: float
    accel_s: float
    d0_mm: float
    final_depth_mm: float
    e_lat_mm: float
    tilt_rad: float
    kappa0_per_mm: float
    alpha: float
    beta: float
    lambda_: float
    p_tip_scale: float
    p_bot_scale: float
    gain: float
    tare_g: float
    video_start_s: float
    t_motion_start_s: float
    t_motion_stop_s: float
    d_hit_mm: float
    theta_hit: float
    mu: float
    theta_tip_end: float
    theta_bot_end: float
    effect_params: Mapping[str, Any]
    film_ratio_at_stop: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON object of the trial (``lambda`` for ``lambda_``; no ``film_ratio_at_stop`` when None)."""
        out = {("lambda" if k == "lambda_" else k): v for k, v in asdict(self).items()}
        if self.film_ratio_at_stop is None:
            del out["film_ratio_at_stop"]
        return jsonable(out)


@dataclass(frozen=True)
class LinearLawTruth:
    """A linear pressure law ``p = a + b theta_con``: ``a`` (MPa), ``b_per_rad`` (MPa/rad)."""

    a: float
    b_per_rad: float


@dataclass(frozen=True)
class ReferenceTruth:
    """The reference end-of-insertion state that sets the pressure scale.

    Parameters
    ----------
    depth_mm : float
        Its depth (mm).
    theta_tip, theta_bot : float
        Its true angles (rad).
    p_ref_MPa : float
        Mean contact pressure there (MPa).
    """

    depth_mm: float
    theta_tip: float
    theta_bot: float
    p_ref_MPa: float


@dataclass(frozen=True)
class BaseModelTruth:
    """The base model of a family-B experiment (:data:`BASE_MODEL`) and its trials.

    Parameters
    ----------
    mu_k, mu_s : float
        Kinetic and static friction coefficients (dimensionless).
    v_s_mm_s : float
        Stribeck speed (mm/s).
    delta_s : float
        Stribeck exponent (dimensionless).
    b_c_mm : float
        Effective contact width (mm).
    p_tip_MPa, p_bot_MPa : LinearLawTruth
        Pressure laws at the tip and at the contact start.
    target_end_force_g : float
        End force (g) the pressure laws are scaled to.
    reference_state : ReferenceTruth
        The state of that scaling.
    trials : mapping
        Trial name to :class:`TrialTruth`.
    """

    mu_k: float
    mu_s: float
    v_s_mm_s: float
    delta_s: float
    b_c_mm: float
    p_tip_MPa: LinearLawTruth
    p_bot_MPa: LinearLawTruth
    target_end_force_g: float
    reference_state: ReferenceTruth
    trials: Mapping[str, TrialTruth]

    def to_json(self) -> dict[str, Any]:
        """The JSON object of the base model, with its description in words."""
        return jsonable({
            "model": BASE_MODEL,
            "friction_when_stopped": FRICTION_WHEN_STOPPED,
            "mu_k": self.mu_k, "mu_s": self.mu_s, "v_s_mm_s": self.v_s_mm_s, "delta_s": self.delta_s,
            "b_c_mm": self.b_c_mm,
            "p_tip_MPa": asdict(self.p_tip_MPa),
            "p_bot_MPa": asdict(self.p_bot_MPa),
            "per_trial_pressure_scale": PER_TRIAL_PRESSURE_SCALE,
            "target_end_force_g": self.target_end_force_g,
            "reference_state": asdict(self.reference_state),
            "trials": {name: t.to_json() for name, t in self.trials.items()},
        })


@dataclass(frozen=True)
class NoiseTruth:
    """Sensor and video noise of a family-B experiment.

    Parameters
    ----------
    force_rate_hz : float
        Force sampling rate (1/s).
    rms_g : float
        Force-noise RMS (g), ``noise_scale`` included.
    ar1_variance_share : float
        Share (dimensionless) of the noise variance in the AR(1) component.
    ar1_tau_s : float
        Correlation time (s) of the AR(1) component.
    full_scale_g : float
        A/D full scale (g).
    adc_bits : int
        A/D resolution.
    lsb_g : float
        Quantisation step (g).
    gain_spread : float
        Half-width (dimensionless) of the per-trial calibration gain's spread.
    tare_sd_g : float
        Standard deviation (g) of the tare offset.
    fps : float
        Video frame rate (1/s).
    angle_sd_tip, angle_sd_bot : float
        Angle noise (rad) of the tip and the contact start.
    p_missing_frame : float
        Probability (dimensionless) that a frame has no angles.
    noise_scale : float
        Factor (dimensionless) on the force-noise RMS.
    """

    force_rate_hz: float
    rms_g: float
    ar1_variance_share: float
    ar1_tau_s: float
    full_scale_g: float
    adc_bits: int
    lsb_g: float
    gain_spread: float
    tare_sd_g: float
    fps: float
    angle_sd_tip: float
    angle_sd_bot: float
    p_missing_frame: float
    noise_scale: float


@dataclass(frozen=True)
class GeneratedTruth:
    """The truth of a family-B experiment.

    Parameters
    ----------
    effect : str or None
        The hidden effect, or None.
    strength : float
        Its size (dimensionless; 0 absent, 1 typical).
    seed : int
        The seed.
    speeds_mm_s : tuple of float
        Nominal speeds (mm/s).
    trials : int
        Trials per speed.
    dataset_params : mapping
        The data-set-level draws (units in the names).
    effect_params : mapping
        The hidden effect's data-set-level constants (empty without one).
    base : BaseModelTruth
        The base model and the trials.
    noise : NoiseTruth
        Sensor and video noise.
    gap_rms_g : float
        RMS (g) of the sensed force with minus without the effect (no random noise).
    noise_rms_g : float
        RMS (g) of the measured minus the sensed force.
    snr : float
        ``gap_rms_g / noise_rms_g`` (dimensionless; inf without noise).
    gap_unabsorbed_rms_g : float
        RMS (g) of the gap after removing its least-squares projection on the base model's four
        pressure-law columns (pooled).
    snr_unabsorbed : float
        ``gap_unabsorbed_rms_g / noise_rms_g`` (dimensionless).
    """

    effect: str | None
    strength: float
    seed: int
    speeds_mm_s: tuple[float, ...]
    trials: int
    dataset_params: Mapping[str, Any]
    effect_params: Mapping[str, Any]
    base: BaseModelTruth
    noise: NoiseTruth
    gap_rms_g: float
    noise_rms_g: float
    snr: float
    gap_unabsorbed_rms_g: float
    snr_unabsorbed: float

    @property
    def family(self) -> str:
        """The generator family, ``"B"``."""
        return "B"

    def to_json(self) -> dict[str, Any]:
        """The JSON object of the truth (plain Python numbers, lists and dicts)."""
        return jsonable({
            "effect": self.effect, "strength": self.strength, "family": self.family, "seed": self.seed,
            "speeds_mm_s": list(self.speeds_mm_s), "trials": self.trials,
            "params": {"dataset": dict(self.dataset_params), "effect": dict(self.effect_params)},
            "base": self.base.to_json(), "noise": asdict(self.noise),
            "gap_rms_g": self.gap_rms_g, "noise_rms_g": self.noise_rms_g, "snr": self.snr,
            "gap_unabsorbed_rms_g": self.gap_unabsorbed_rms_g, "snr_unabsorbed": self.snr_unabsorbed,
        })

"""Configuration of a family-A experiment: noise, trial variability, protocol, scaled pressure laws."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tympani.pipeline.model.friction import PressureLaw

__all__ = ["NoiseConfig", "Variability", "Protocol", "ScaledPressure"]


@dataclass(frozen=True)
class NoiseConfig:
    """Sensor noise and resolution of a synthetic experiment.

    Parameters
    ----------
    white_g : float
        Standard deviation (g) of white force noise.
    ar_g : float
        Stationary standard deviation (g) of a correlated AR(1) force noise component.
    ar_tau_s : float
        Correlation time (s) of the AR(1) component (lag-1 correlation ``exp(-dt / tau)``).
    trial_scale_sd : float
        Log-normal sigma (dimensionless) of a per-trial factor on both noise components.
    tare_sd_g : float
        Standard deviation (g) of a per-trial zero offset (imperfect tare).
    range_g : float
        Sensor full scale (g): the A/D covers ``[-range_g, range_g]`` and clips beyond.
    bits : int
        A/D resolution (bits); 0 disables quantisation.
    angle_sd_rad : float
        Standard deviation (rad) of the per-frame noise of the measured angles.
    """

    white_g: float = 0.02
    ar_g: float = 0.03
    ar_tau_s: float = 0.3
    trial_scale_sd: float = 0.25
    tare_sd_g: float = 0.01
    range_g: float = 25.0
    bits: int = 13
    angle_sd_rad: float = 0.01

    def lsb_g(self) -> float:
        """Quantisation step (g) of the A/D (0 without quantisation)."""
        return 2.0 * self.range_g / 2**self.bits if self.bits > 0 else 0.0


@dataclass(frozen=True)
class Variability:
    """Trial-to-trial variability of a synthetic experiment.

    Parameters
    ----------
    pressure_frac : float
        Each trial's pressures are scaled by ``U(1 - f, 1 + f)`` (dimensionless).
    speed_frac : float
        Each trial's actual speed is the nominal one times ``U(1 - f, 1 + f)``.
    theta_first_rad : tuple of float
        Range (rad) of the tip angle at first contact (:class:`tympani.vision.rendering.ContactPolicy`).
    lag : tuple of float
        Range (dimensionless, 0–1) of the fraction of the tip's advance the contact start follows.
    paired : bool
        Repeat ``k`` at every speed shares its contact growth and pressure scale (a paired design:
        differences between speeds are not blurred by which placements each speed happened to
        draw). Speed, noise and angle noise stay independent.
    """

    pressure_frac: float = 0.10
    speed_frac: float = 0.02
    theta_first_rad: tuple[float, float] = (1.0, 1.8)
    lag: tuple[float, float] = (0.15, 0.45)
    paired: bool = False


@dataclass(frozen=True)
class Protocol:
    """Timing of each trial and of the measurement clocks.

    Parameters
    ----------
    depth_mm : float
        Depth (mm) where the robot stops.
    start_depth_mm : float
        Depth (mm) of the tip at the start (negative: in the entry channel, behind theta_start).
    pre_s : float
        Time (s) logged before the robot starts.
    dwell_s : float
        Time (s) logged after the robot stops.
    rate_hz : float
        Force sampling rate (1/s).
    angles_fps : float
        Frame rate (1/s) of the angle measurements (video clock).
    video_t0_s : float
        Force-clock time (s) of video frame 0 (the manifest's ``video_t0_s``). Force samples before it
        have no angles (NaN), as after ``tympani sync``.
    """

    depth_mm: float = 15.0
    start_depth_mm: float = -1.0
    pre_s: float = 0.5
    dwell_s: float = 1.0
    rate_hz: float = 50.0
    angles_fps: float = 30.0
    video_t0_s: float = 0.0


@dataclass(frozen=True)
class ScaledPressure:
    """A pressure law (MPa vs theta_con in rad) times a constant factor (dimensionless)."""

    law: PressureLaw
    scale: float

    def __call__(self, theta_con: np.ndarray) -> np.ndarray:
        """Pressure (MPa) at contact angles ``theta_con`` (rad)."""
        return self.scale * np.asarray(self.law(theta_con), dtype=float)

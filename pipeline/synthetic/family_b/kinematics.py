"""Robot motion and true angles against depth (family B)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tympani.pipeline.synthetic.family_b.trajectory import TipPath

__all__ = ["robot_motion", "motion_times", "true_angles"]


def robot_motion(t: np.ndarray, tr: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Depth [mm] and speed [mm/s] of the robot at times ``t`` [s].

    Hold for the pre-roll, raised-cosine acceleration over ``accel_s``, constant speed,
    symmetric deceleration, hold.  The distance covered equals final - initial depth.
    """
    v = tr["speed_actual_mm_s"]
    ta = tr["accel_s"]
    dist = tr["final_depth_mm"] - tr["d0_mm"]
    tm = dist / v + ta  # motion duration
    tau = np.clip(t - tr["pre_roll_s"], 0.0, tm)

    def ramp_dist(x: np.ndarray) -> np.ndarray:  # distance after x s of the raised cosine
        return v * (x / 2.0 - ta / (2.0 * math.pi) * np.sin(math.pi * x / ta))

    d_acc = v * ta / 2.0
    pos = np.where(
        tau < ta, ramp_dist(tau),
        np.where(tau <= tm - ta, d_acc + v * (tau - ta), dist - ramp_dist(tm - tau)),
    )
    tau_raw = t - tr["pre_roll_s"]
    vel = np.where(
        (tau_raw <= 0) | (tau_raw >= tm), 0.0,
        np.where(tau_raw < ta, 0.5 * v * (1 - np.cos(math.pi * tau_raw / ta)),
                 np.where(tau_raw <= tm - ta, v,
                          0.5 * v * (1 - np.cos(math.pi * (tm - tau_raw) / ta)))),
    )
    return tr["d0_mm"] + pos, vel


def motion_times(tr: dict[str, Any]) -> tuple[float, float, float]:
    """(motion start, motion stop, end of log) [s]."""
    v = tr["speed_actual_mm_s"]
    tm = (tr["final_depth_mm"] - tr["d0_mm"]) / v + tr["accel_s"]
    t0 = tr["pre_roll_s"]
    return t0, t0 + tm, t0 + tm + tr["dwell_s"]


def true_angles(depth: np.ndarray, path: TipPath, tr: dict[str, Any],
                floor: float) -> tuple[np.ndarray, np.ndarray]:
    """True tip and contact-start angles [rad] for insertion depths ``depth`` [mm].

    ``theta_tip`` follows the tip path.  After first contact (angle ``theta_hit``), with
    ``q = theta_tip - theta_hit``::

        theta_bot = theta_hit + alpha q - beta (1 - exp(-q / lambda)) + wiggle(q)

    softly floored at ``floor``: alpha < 0 makes the contact spread back towards the base
    (as in the paper's video), alpha > 0 makes its start creep forward.
    """
    th_tip = np.interp(depth, path.depth, path.theta)
    q = np.maximum(th_tip - path.theta_hit, 0.0)
    wig = tr["wiggle_amp"] * (1.0 - np.exp(-q / 0.3)) * (
        0.6 * np.sin(tr["wiggle_k"][0] * q + tr["wiggle_phase"][0])
        + 0.4 * np.sin(tr["wiggle_k"][1] * q + tr["wiggle_phase"][1]))
    raw = path.theta_hit + tr["alpha"] * q - tr["beta"] * (1.0 - np.exp(-q / tr["lambda"])) + wig
    eps = 0.08
    bot = floor + eps * np.logaddexp(0.0, (raw - floor) / eps)
    bot = np.minimum(bot, th_tip)
    contact = depth > path.d_hit
    bot = np.where(contact, bot, th_tip)
    return th_tip, bot

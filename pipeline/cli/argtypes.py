"""Argument types shared by the ``tympani`` subcommands.

Each is an ``argparse`` ``type=`` callable: it turns the text of one option into a value or raises
``argparse.ArgumentTypeError`` with a one-line reason, which :mod:`tympani.pipeline.cli` reports as a usage
error (exit status 2).
"""

from __future__ import annotations

import argparse
import math
from typing import Callable


class UsageError(Exception):
    """Bad command-line usage (argparse errors, conflicting options): exit status 2."""

__all__ = ["UsageError", "positive_int", "nonneg_int", "positive_float", "nonneg_float", "fraction", "int_list", "speed_list"]


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def positive_int(text: str) -> int:
    """An integer >= 1 (a count: workers, frames, resamples)."""
    value = _int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, not {value}")
    return value


def nonneg_int(text: str) -> int:
    """An integer >= 0 (0 usually meaning "never" or "none")."""
    value = _int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, not {value}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (a rate, a duration, a force), in the option's own unit."""
    value = _float(text)
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, not {text}")
    return value


def nonneg_float(text: str) -> float:
    """A finite number >= 0 (an amount that may be none), in the option's own unit."""
    value = _float(text)
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, not {text}")
    return value


def share(text: str) -> float:
    """A number in [0, 1) (a share that may be none)."""
    value = _float(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 0 and below 1, not {text}")
    return value


def fraction(text: str) -> float:
    """A number strictly between 0 and 1 (a coverage level or a probability)."""
    value = _float(text)
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, not {text}")
    return value


def int_list(text: str) -> list[int]:
    """Comma-separated frame numbers >= 0."""
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated frame numbers, got {text!r}") from None
    if not values or any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected frame numbers >= 0, got {text!r}")
    return values


def speed_list(text: str) -> tuple[float, ...]:
    """Comma-separated insertion speeds (mm/s), each finite and > 0."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated speeds in mm/s, got {text!r}") from None
    if not values or not all(0 < v < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected positive speeds in mm/s, got {text!r}")
    return values


def _pair(text: str, ok: Callable[[float, float], bool], expected: str) -> tuple[float, float]:
    """Two comma-separated numbers that ``ok`` accepts, else a usage error saying ``expected``."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 2 or not ok(*values):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return values[0], values[1]


def band_pair(text: str) -> tuple[float, float]:
    """``FROM,LENGTH``: the electrode array's first metal band, its distance (mm) from the tip
    (finite, >= 0) and its length (mm, finite, > 0)."""
    return _pair(text, lambda start, length: 0 <= start < math.inf and 0 < length < math.inf,
                 "the first band's distance from the tip (>= 0) and its length (> 0) in mm (FROM,LENGTH)")


def diameter_pair(text: str) -> tuple[float, float]:
    """``TIP,BASE``: the electrode array's diameters (mm) at its tip and at its base, each finite and > 0."""
    return _pair(text, lambda tip, base: 0 < tip < math.inf and 0 < base < math.inf,
                 "two positive diameters in mm (TIP,BASE)")

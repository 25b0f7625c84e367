"""Log format files: how a lab's own force, depth and angle logs are read (docs/lab-logs.md).

A lab's logs are never in tympani's own form: the clock may be UNIX time in nanoseconds, the
force in newtons with the sign of the sensor's axis and a calibration gain, the insertion depth
in a separate log of the robot's stage, the angles from another tracker in degrees with their
own zero. A *log format* file, one per lab, says how to read them::

    [force]                 # the force log's own columns
    time_column = "%time"   # its clock
    time_unit = "ns"        # s | ms | us | ns
    column = "field.Fz"     # the axial force column
    unit = "N"              # g | mN | N
    sign = -1               # so that pushing the array in reads positive
    gain = 1.0679           # calibration slope, applied after the unit
    [depth]                 # optional: the robot's position log (manifest column `depth`)
    time_column = "%time"
    time_unit = "ns"
    column = "field0"
    unit = "mm"             # um | mm | m
    [angles]                # optional: another tracker's angle track (manifest column `angles`)
    time_column = "time"
    time_unit = "s"
    zero = "motion_start"   # "log" | "motion_start" | seconds on the force clock
    theta_tip = "angle"     # theta_bot / theta_con may be named too
    unit = "deg"            # rad | deg

Every section also takes ``topic`` for a ROS bag (``.bag``, ``.mcap`` or a rosbag2 folder): then
``column`` (and ``theta_*``) name a field of the topic's messages by its path (``wrench.force.z``,
``position[0]``), and ``time_column`` is optional: without it the time a message was recorded
is used (ns); with it, a ``header.stamp``-like field (seconds and nanoseconds) or a number in
``time_unit``. ``[depth]`` also takes ``sign`` (default 1).

This module only parses and checks the file (:func:`read_log_format`); the logs are read by
:mod:`tympani.pipeline.force.labstreams`. A key the file does not know, a missing key, a value of the wrong
type or a unit not listed is an :class:`~tympani.vision.errors.InputError` naming the file and the key.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from tympani.pipeline.force.forcelog import G_PER_N
from tympani.vision.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 has the same parser as the tomli package
    import tomli as tomllib

__all__ = [
    "TIME_UNITS",
    "FORCE_UNITS",
    "DEPTH_UNITS",
    "ANGLE_UNITS",
    "ZERO_WORDS",
    "StreamFormat",
    "ForceFormat",
    "DepthFormat",
    "AnglesFormat",
    "LogFormat",
    "parse_log_format",
    "read_log_format",
]

#: Nanoseconds per unit of a time column.
TIME_UNITS: dict[str, int] = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
#: Grams-force per unit of a force column (1 g = 9.80665e-3 N).
FORCE_UNITS: dict[str, float] = {"g": 1.0, "mN": G_PER_N / 1000.0, "N": G_PER_N}
#: Millimetres per unit of a depth column.
DEPTH_UNITS: dict[str, float] = {"um": 1e-3, "mm": 1.0, "m": 1e3}
#: Radians per unit of an angle column.
ANGLE_UNITS: dict[str, float] = {"rad": 1.0, "deg": math.pi / 180.0}
#: The words ``[angles] zero`` takes besides a number of seconds.
ZERO_WORDS: tuple[str, ...] = ("log", "motion_start")

_SECTIONS = ("force", "depth", "angles")
_STREAM_KEYS = ("topic", "time_column", "time_unit")
_KEYS: dict[str, tuple[str, ...]] = {
    "force": (*_STREAM_KEYS, "column", "unit", "sign", "gain"),
    "depth": (*_STREAM_KEYS, "column", "unit", "sign"),
    "angles": (*_STREAM_KEYS, "zero", "theta_tip", "theta_bot", "theta_con", "unit"),
}
_REQUIRED: dict[str, tuple[str, ...]] = {
    "force": ("column", "unit"),
    "depth": ("column", "unit"),
    "angles": ("zero", "theta_tip", "unit"),
}


@dataclass(frozen=True, kw_only=True)
class StreamFormat:
    """Where one stream's clock is (shared by the three sections).

    Parameters
    ----------
    section : {"force", "depth", "angles"}
        The format file's section, named in messages as ``[section]``.
    time_column : str or None
        The time column of a CSV log, or the time field of a bag's messages; None (bags only):
        the time the message was recorded, in ns.
    time_unit : {"s", "ms", "us", "ns"}
        Unit of ``time_column``. Integer stamps are kept exact (int64) until they are made
        relative to the force log's first sample.
    topic : str or None
        The topic, when the log is a ROS bag.
    """

    section: str
    time_column: str | None
    time_unit: str = "s"
    topic: str | None = None

    @property
    def ns_per_unit(self) -> int:
        """Nanoseconds per unit of the time column."""
        return TIME_UNITS[self.time_unit]

    def key(self, name: str) -> str:
        """``"[section] name"``, how messages name a key of this section."""
        return f"[{self.section}] {name}"


@dataclass(frozen=True, kw_only=True)
class ForceFormat(StreamFormat):
    """The ``[force]`` section.

    Parameters
    ----------
    column : str
        The axial force column (or message field).
    unit : {"g", "mN", "N"}
        Its unit.
    sign : {1, -1}
        Multiplies the force so that pushing the array in reads positive.
    gain : float
        Calibration slope (> 0), applied after the unit.
    """

    column: str
    unit: str
    sign: int = 1
    gain: float = 1.0

    @property
    def to_g(self) -> float:
        """Grams-force per logged unit, sign and gain included."""
        return self.sign * self.gain * FORCE_UNITS[self.unit]


@dataclass(frozen=True, kw_only=True)
class DepthFormat(StreamFormat):
    """The ``[depth]`` section: the robot's position log.

    Parameters
    ----------
    column : str
        The insertion-depth column (or message field).
    unit : {"um", "mm", "m"}
        Its unit.
    sign : {1, -1}
        Multiplies the depth so that inserting reads increasing.
    """

    column: str
    unit: str
    sign: int = 1

    @property
    def to_mm(self) -> float:
        """Millimetres per logged unit, sign included."""
        return self.sign * DEPTH_UNITS[self.unit]


@dataclass(frozen=True, kw_only=True)
class AnglesFormat(StreamFormat):
    """The ``[angles]`` section: another tracker's angle track.

    Parameters
    ----------
    zero : "log", "motion_start" or float
        Where the track's ``t = 0`` is: ``"log"``, the track is on the force log's clock (same
        time column unit rules); ``"motion_start"``, its 0 is when the depth log starts moving;
        a number, its 0 is that many seconds after the force log's first sample.
    theta_tip : str
        The tip-angle column.
    theta_bot, theta_con : str or None
        The contact-start and contact angles, when the tracker has them.
    unit : {"rad", "deg"}
        Unit of the angle columns.
    """

    zero: str | float
    theta_tip: str
    theta_bot: str | None = None
    theta_con: str | None = None
    unit: str = "rad"

    @property
    def to_rad(self) -> float:
        """Radians per logged unit."""
        return ANGLE_UNITS[self.unit]

    @property
    def columns(self) -> dict[str, str]:
        """The angle columns named, keyed by tympani's column name (``theta_tip`` first)."""
        named = {"theta_tip": self.theta_tip, "theta_bot": self.theta_bot, "theta_con": self.theta_con}
        return {k: v for k, v in named.items() if v is not None}


@dataclass(frozen=True)
class LogFormat:
    """A parsed log format file.

    Parameters
    ----------
    path : str
        The file (named in messages).
    force : ForceFormat or None
        ``[force]``; None: the force log is in tympani's own form (``time_s``, ``force_g``/``force_N``).
    depth : DepthFormat or None
        ``[depth]``; None: a depth log, if a trial names one, is in tympani's own form (``time_s``,
        ``depth_mm``).
    angles : AnglesFormat or None
        ``[angles]``; None: angles tables are in tympani's own form (or come from a video).
    """

    path: str
    force: ForceFormat | None = None
    depth: DepthFormat | None = None
    angles: AnglesFormat | None = None


# --------------------------------------------------------------------------- parsing


def _string(name: str, section: str, key: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(name, f"[{section}] {key} must be a non-empty string, not {value!r}")
    return value.strip()


def _unit(name: str, section: str, key: str, value: Any, units: Mapping[str, Any]) -> str:
    text = _string(name, section, key, value)
    if text not in units:
        raise InputError(name, f"[{section}] {key} {text!r} is not one of {', '.join(units)}")
    return text


def _number(name: str, section: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(name, f"[{section}] {key} must be a finite number, not {value!r}")
    return float(value)


def _sign(name: str, section: str, value: Any) -> int:
    number = _number(name, section, "sign", value)
    if number not in (1.0, -1.0):
        raise InputError(name, f"[{section}] sign must be 1 or -1, not {value!r}")
    return int(number)


def _stream_keys(name: str, section: str, table: Mapping[str, Any]) -> dict[str, Any]:
    """The clock keys of one section, checked."""
    topic = _string(name, section, "topic", table["topic"]) if "topic" in table else None
    if "time_column" in table:
        time_column: str | None = _string(name, section, "time_column", table["time_column"])
    elif topic is None:
        raise InputError(name, f"[{section}] missing key 'time_column'")
    else:
        time_column = None  # a bag's record time
    if "time_unit" in table:
        time_unit = _unit(name, section, "time_unit", table["time_unit"], TIME_UNITS)
        if time_column is None and time_unit != "ns":
            raise InputError(name, f"[{section}] time_unit {time_unit!r} without time_column: a bag's record time is "
                                   "in ns; name the time field to use another unit")
    else:
        time_unit = "ns" if time_column is None else "s"
    return {"section": section, "topic": topic, "time_column": time_column, "time_unit": time_unit}


def _zero(name: str, value: Any) -> str | float:
    if isinstance(value, str):
        if value.strip() not in ZERO_WORDS:
            raise InputError(name, f"[angles] zero {value!r} is not one of {', '.join(map(repr, ZERO_WORDS))} "
                                   "or a number of seconds")
        return value.strip()
    return _number(name, "angles", "zero", value)


def _section(name: str, section: str, table: Any) -> StreamFormat:
    if not isinstance(table, dict):
        raise InputError(name, f"[{section}] must be a table of keys, not {table!r}")
    unknown = [k for k in table if k not in _KEYS[section]]
    if unknown:
        raise InputError(name, f"[{section}] unknown key {unknown[0]!r} (known: {', '.join(_KEYS[section])})")
    missing = [k for k in _REQUIRED[section] if k not in table]
    if missing:
        raise InputError(name, f"[{section}] missing key {missing[0]!r}")
    clock = _stream_keys(name, section, table)
    if section == "force":
        gain = _number(name, section, "gain", table["gain"]) if "gain" in table else 1.0
        if not gain > 0:
            raise InputError(name, f"[force] gain must be > 0 (the sign goes in 'sign'), not {table['gain']!r}")
        return ForceFormat(**clock, column=_string(name, section, "column", table["column"]),
                           unit=_unit(name, section, "unit", table["unit"], FORCE_UNITS),
                           sign=_sign(name, section, table["sign"]) if "sign" in table else 1, gain=gain)
    if section == "depth":
        return DepthFormat(**clock, column=_string(name, section, "column", table["column"]),
                           unit=_unit(name, section, "unit", table["unit"], DEPTH_UNITS),
                           sign=_sign(name, section, table["sign"]) if "sign" in table else 1)
    optional = {k: _string(name, section, k, table[k]) for k in ("theta_bot", "theta_con") if k in table}
    return AnglesFormat(**clock, zero=_zero(name, table["zero"]),
                        theta_tip=_string(name, section, "theta_tip", table["theta_tip"]),
                        unit=_unit(name, section, "unit", table["unit"], ANGLE_UNITS), **optional)


def parse_log_format(text: str, *, name: str = "<log format>") -> LogFormat:
    """Parse and check the text of a log format file.

    Parameters
    ----------
    text : str
        TOML.
    name : str
        The file's name, for messages.

    Returns
    -------
    LogFormat

    Raises
    ------
    InputError
        Not TOML, an unknown section or key, a missing key, a wrong type, a unit not listed
        (one line naming the file and the key).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(name, f"not a valid TOML log format file ({exc})") from None
    unknown = [k for k in data if k not in _SECTIONS]
    if unknown:
        raise InputError(name, f"unknown section or key {unknown[0]!r} (known sections: "
                               f"{', '.join(f'[{s}]' for s in _SECTIONS)})")
    if not data:
        raise InputError(name, f"no section: a log format file has {', '.join(f'[{s}]' for s in _SECTIONS)}")
    parts = {s: _section(name, s, data[s]) for s in _SECTIONS if s in data}
    return LogFormat(path=name, **parts)  # type: ignore[arg-type]


def read_log_format(path: str | os.PathLike) -> LogFormat:
    """Read and check a log format file (see the module docstring).

    Parameters
    ----------
    path : str or PathLike
        The TOML file.

    Returns
    -------
    LogFormat

    Raises
    ------
    InputError
        Missing or unreadable file, or a bad format (one line naming the file and the key).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such log format file" if not p.exists() else "log format file is not a file")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read log format file ({type(exc).__name__}: {exc})") from None
    return parse_log_format(text, name=str(p))

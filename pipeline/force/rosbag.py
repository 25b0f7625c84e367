"""Fields of one topic of a ROS bag, read directly (``.bag``, ``.mcap``, rosbag2 folders).

Uses the pure-Python ``rosbags`` package, an optional extra (``pip install 'tympani[ros]'``): no
ROS installation is needed. Messages are read one at a time and only the fields asked for are
kept, as compact arrays.

A field is named by its path in the message, dots between names and ``[i]`` for an element of
an array: ``wrench.force.z``, ``position[0]``, ``data``. A time field that is a ROS time
(``header.stamp``: ``sec`` and ``nanosec``, or ROS 1's ``nsec``) becomes integer nanoseconds,
exactly; without a time field, the time the bag recorded the message is used (ns).
"""

from __future__ import annotations

import os
import re
from array import array
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from tympani.vision.errors import InputError

__all__ = ["BAG_SUFFIXES", "is_bag", "BagFields", "read_bag_fields", "field_value"]

#: File name endings of ROS bags (a rosbag2 folder holds ``metadata.yaml``).
BAG_SUFFIXES: tuple[str, ...] = (".bag", ".mcap", ".db3")

_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")


def is_bag(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a ROS bag: a ``.bag``/``.mcap``/``.db3`` file or a rosbag2 folder."""
    p = Path(path)
    return p.suffix.lower() in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


@dataclass(frozen=True, eq=False)
class BagFields:
    """Fields of one topic's messages.

    Parameters
    ----------
    stamps : ndarray
        Message times: int64 ns for a bag's record time or a ROS time field, else the time
        field's values (int64 or float64, in its own unit).
    values : dict of str to ndarray
        Each field asked for (float64), by the key it was asked under.
    index : ndarray of int64
        1-based number of each message on the topic (for messages: ``"message 12"``).
    msgtype : str
        The topic's message type.
    stamps_ns : bool
        Whether ``stamps`` are ns (the record time, or a ROS time field) rather than a plain
        number in the time field's own unit.
    """

    stamps: np.ndarray
    values: dict[str, np.ndarray]
    index: np.ndarray
    msgtype: str
    stamps_ns: bool = True


def _steps(path: str) -> list[str | int]:
    """``"a.b[2].c"`` -> ``["a", "b", 2, "c"]``; ValueError for a malformed path."""
    out: list[str | int] = []
    for part in path.split("."):
        m = _PART.match(part.strip())
        if not m:
            raise ValueError(f"{path!r} is not a field path (names with dots, [i] for an array element)")
        out.append(m.group(1))
        out.extend(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
    return out


def _fields_of(obj: Any) -> str:
    names = getattr(obj, "__dataclass_fields__", None) or getattr(obj, "__slots__", None) or ()
    return ", ".join(n for n in names if not str(n).startswith("_")) or "none"


def field_value(message: Any, path: str) -> Any:
    """The value at ``path`` in a deserialised message.

    Raises
    ------
    KeyError
        A name the message does not have, or an index past an array's end (the message says
        which, and what there is).
    ValueError
        A malformed path.
    """
    obj = message
    for step in _steps(path):
        if isinstance(step, int):
            try:
                obj = obj[step]
            except (IndexError, TypeError):
                size = len(obj) if hasattr(obj, "__len__") else 0
                raise KeyError(f"no element [{step}] (the array has {size})") from None
        else:
            if not hasattr(obj, step):
                raise KeyError(f"no field {step!r} (fields: {_fields_of(obj)})")
            obj = getattr(obj, step)
    return obj


def _stamp(value: Any) -> int | float:
    """A time field as a number: a ROS time (sec, nanosec/nsec) as int ns, a number as it is."""
    if hasattr(value, "sec"):
        nsec = getattr(value, "nanosec", getattr(value, "nsec", 0))
        return int(value.sec) * 1_000_000_000 + int(nsec)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"not a time or a number ({type(value).__name__})")
    return value.item() if isinstance(value, np.generic) else value


def _number(value: Any) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"not a number ({type(value).__name__})")
    return float(value)


def _typestore() -> Any:
    """The message types for bags that carry no definitions of their own (None: rosbags too old
    to have type stores; bags with definitions still read)."""
    try:
        from rosbags.typesys import Stores, get_typestore

        return get_typestore(Stores.LATEST)
    except (ImportError, AttributeError):  # pragma: no cover - rosbags older than 0.9.20
        return None


def read_bag_fields(
    path: str | os.PathLike,
    topic: str,
    fields: Mapping[str, str],
    *,
    time_field: str | None = None,
    section: str = "force",
    key_of: Mapping[str, str] | None = None,
) -> BagFields:
    """Read some fields of every message of one topic.

    Parameters
    ----------
    path : str or PathLike
        A ``.bag`` (ROS 1), a ``.mcap`` or ``.db3`` file or a rosbag2 folder (ROS 2).
    topic : str
        The topic.
    fields : mapping
        Key -> field path (e.g. ``{"force": "wrench.force.z"}``).
    time_field : str, optional
        Path of the time field; None: the bag's record time (ns).
    section : str
        The log format's section, named in messages (``[force] column ...``).
    key_of : mapping, optional
        Key -> the log format's key that named the field (default ``"column"``), for messages.

    Returns
    -------
    BagFields

    Raises
    ------
    InputError
        ``rosbags`` not installed, an unreadable bag, a topic the bag lacks, a field the
        messages lack or that is not a number, no message on the topic (one line naming the
        bag and the format's key).
    """
    p = Path(path)
    name = str(p)
    key_of = dict(key_of or {})
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise InputError(name, f"[{section}] topic: reading ROS bags needs the optional package rosbags "
                               "(pip install 'tympani[ros]')") from None
    for key, field in fields.items():
        try:
            _steps(field)
        except ValueError as exc:
            raise InputError(name, f"[{section}] {key_of.get(key, 'column')} {exc}") from None
    stamps: array = array("q")
    float_stamps: list[float] | None = None
    ros_time = time_field is None
    values = {k: array("d") for k in fields}
    try:
        store = _typestore()
        with (AnyReader([p], default_typestore=store) if store is not None else AnyReader([p])) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                have = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
                raise InputError(name, f"[{section}] topic {topic!r} is not in the bag (topics: {have})")
            msgtype = conns[0].msgtype
            for n, (conn, recorded, raw) in enumerate(reader.messages(connections=conns), start=1):
                msg = reader.deserialize(raw, conn.msgtype)
                for key, field in fields.items():
                    try:
                        values[key].append(_number(field_value(msg, field)))
                    except (KeyError, TypeError) as exc:
                        raise InputError(name, f"[{section}] {key_of.get(key, 'column')} {field!r}: message {n} "
                                               f"of {topic} ({conn.msgtype}) has {exc.args[0]}") from None
                if time_field is None:
                    stamps.append(int(recorded))
                    continue
                try:
                    value = field_value(msg, time_field)
                    ros_time = hasattr(value, "sec")
                    t = _stamp(value)
                except (KeyError, TypeError) as exc:
                    raise InputError(name, f"[{section}] time_column {time_field!r}: message {n} of {topic} "
                                           f"({conn.msgtype}) has {exc.args[0]}") from None
                if float_stamps is None and isinstance(t, int) and -(2**63) <= t < 2**63:
                    stamps.append(t)
                else:
                    if float_stamps is None:
                        float_stamps = [float(v) for v in stamps]
                    float_stamps.append(float(t))
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own errors for damaged bags
        raise InputError(name, f"[{section}] topic {topic!r}: cannot read the bag ({type(exc).__name__}: {exc})") from None
    n = len(values[next(iter(fields))]) if fields else len(stamps)
    if n == 0:
        raise InputError(name, f"[{section}] topic {topic!r} has no messages")
    times = np.asarray(float_stamps, dtype=np.float64) if float_stamps is not None else np.frombuffer(stamps, dtype=np.int64).copy()
    return BagFields(stamps=times, values={k: np.frombuffer(v, dtype=np.float64).copy() for k, v in values.items()},
                     index=np.arange(1, n + 1, dtype=np.int64), msgtype=msgtype, stamps_ns=ros_time)

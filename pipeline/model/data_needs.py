"""What a synced table lacks for an analysis, said in one line.

Logs from other trackers often give the tip angle only (no contact start ``theta_bot``, no
contact angle ``theta_con``), and a lab's first trials are often at one speed. The friction-model
fit needs the contact angles; the diagnosis needs them and several speeds with repeats. Rather
than a count of "usable rows", :func:`require` says what the data lack, naming what they have
(:class:`NotEnoughData`, an :class:`~tympani.vision.errors.InputError`: exit status 2 on the command
line; ``tympani run`` records the stage as not run and its report gives the same line).
"""

from __future__ import annotations

import os

import pandas as pd

from tympani.vision.errors import InputError

__all__ = ["NotEnoughData", "TIP_ONLY_HINT", "has_contact_angles", "speeds_found", "lacks", "require"]

#: What can be done with tip-only data (said when the contact angles are what is missing).
TIP_ONLY_HINT = "'tympani bounds --angle theta_tip' fits the safety bounds on the tip angle"
_NO_CONTACT = "no theta_bot or theta_con in any row (the angle track gives the tip angle only)"


class NotEnoughData(InputError):
    """The data cannot support an analysis; the message says what they lack."""


def has_contact_angles(table: pd.DataFrame) -> bool:
    """Whether some row with a tip angle also has ``theta_bot`` or ``theta_con``."""
    if "theta_tip" not in table.columns:
        return False
    tip = pd.to_numeric(table["theta_tip"], errors="coerce").notna().to_numpy()
    for col in ("theta_bot", "theta_con"):
        if col in table.columns and (tip & pd.to_numeric(table[col], errors="coerce").notna().to_numpy()).any():
            return True
    return False


def speeds_found(table: pd.DataFrame) -> dict[float, int]:
    """Trials per insertion speed (mm/s -> count), over the rows with a speed and a trial name."""
    if "speed_mm_s" not in table.columns:
        return {}
    speed = pd.to_numeric(table["speed_mm_s"], errors="coerce")
    trial = table["trial"].astype(str) if "trial" in table.columns else pd.Series("all", index=table.index)
    pairs = pd.DataFrame({"speed": speed, "trial": trial}).dropna().drop_duplicates()
    return {float(s): int(n) for s, n in pairs.groupby("speed")["trial"].nunique().sort_index().items()}


def _speeds_text(found: dict[float, int]) -> str:
    if not found:
        return "no insertion speed"
    parts = "; ".join(f"{s:g} mm/s: {n} trial{'s' if n != 1 else ''}" for s, n in found.items())
    return f"{len(found)} insertion speed{'s' if len(found) != 1 else ''} ({parts})"


def lacks(table: pd.DataFrame, *, contact_angles: bool = True, min_speeds: int = 0,
          min_trials_per_speed: int = 1) -> list[str]:
    """What ``table`` lacks, one phrase per need (empty when it has everything).

    Parameters
    ----------
    table : DataFrame
        A synced table (docs/file-formats.md).
    contact_angles : bool
        Whether ``theta_bot``/``theta_con`` are needed.
    min_speeds : int
        Fewest distinct speeds, each with at least ``min_trials_per_speed`` trials.
    min_trials_per_speed : int
        Repeats a speed needs to count.

    Returns
    -------
    list of str
    """
    out = []
    if min_speeds > 0:
        found = speeds_found(table)
        if sum(n >= min_trials_per_speed for n in found.values()) < min_speeds:
            out.append(f"{_speeds_text(found)} where at least {min_speeds} speeds with at least "
                       f"{min_trials_per_speed} trials each are needed")
    if contact_angles and not has_contact_angles(table):
        out.append(_NO_CONTACT)
    return out


def require(table: pd.DataFrame, source: str | os.PathLike, what: str, *, contact_angles: bool = True,
            min_speeds: int = 0, min_trials_per_speed: int = 1) -> None:
    """Raise :class:`NotEnoughData` when the table lacks something ``what`` needs.

    Parameters
    ----------
    table : DataFrame
        A synced table.
    source : str or PathLike
        Named in the message.
    what : str
        The analysis, e.g. ``"the friction-model fit"``.
    contact_angles, min_speeds, min_trials_per_speed
        As :func:`lacks`.

    Raises
    ------
    NotEnoughData
        ``"<source>: <what> cannot run: the data have <...>"``, with :data:`TIP_ONLY_HINT`
        when the contact angles are missing.
    """
    missing = lacks(table, contact_angles=contact_angles, min_speeds=min_speeds,
                    min_trials_per_speed=min_trials_per_speed)
    if missing:
        text = f"{what} cannot run: the data have " + ", and ".join(missing)
        raise NotEnoughData(source, text + (f"; {TIP_ONLY_HINT}" if _NO_CONTACT in missing else ""))

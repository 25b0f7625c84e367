"""Peak resident memory of this process, for the memory figures of ``tympani bench``.

:func:`peak_rss_mib` is read by :mod:`tympani.pipeline.devtools.bench` (the extraction's peak, in a fresh process)
and by :mod:`tympani.pipeline.devtools.logbench` (a big log's reading, in a fresh process).
"""

from __future__ import annotations

import resource
import sys

__all__ = ["peak_rss_mib"]


def peak_rss_mib() -> float:
    """Peak resident set size of this process (MiB).

    On Linux it is ``VmHWM`` of ``/proc/self/status``: the high-water mark of this process's own
    memory map. ``ru_maxrss`` is not used there because exec keeps the larger of the old and the
    new map's peaks, so a child started by a big parent (vfork + exec) would report the parent's.
    Elsewhere it is ``ru_maxrss`` (bytes on macOS, KiB on other systems).

    Returns
    -------
    float
        Peak resident memory (MiB).
    """
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) / 1024.0  # kB
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 / (1024.0 if sys.platform == "darwin" else 1.0)  # bytes on macOS, KiB elsewhere

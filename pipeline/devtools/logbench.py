"""Time and memory of reading a big lab log (the ``logs`` section of ``tympani bench``).

:func:`write_ros_force_csv` writes a force log as ROS's ``rostopic echo -p`` does (``%time`` in
epoch nanoseconds and six force/torque fields, about 150 bytes a row), and :func:`bench_log_read`
reads it through a log format in a fresh Python process (a peak is per process), reporting the
seconds and the peak resident memory, and the resident memory after the imports, so that the
reading's own share shows.

Run alone: ``python -m tympani.pipeline.devtools.logbench [ROWS]`` (default 1,000,000).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tympani.pipeline.devtools.memory import peak_rss_mib

__all__ = ["ROS_FORMAT", "write_ros_force_csv", "bench_log_read", "format_log_bench"]

#: The log format of the written log (force column ``field.Fz`` in N, pushing reads negative).
ROS_FORMAT = """[force]
time_column = "%time"
time_unit = "ns"
column = "field.Fz"
unit = "N"
sign = -1
gain = 1.0679
"""

_HEADER = "%time,field.Fx,field.Fy,field.Fz,field.Tx,field.Ty,field.Tz\n"


def write_ros_force_csv(path: str | os.PathLike, rows: int, *, seed: int = 0, rate_hz: float = 50.0,
                        block: int = 100_000) -> Path:
    """Write a ``rows``-row ROS force log (epoch ns stamps at ``rate_hz`` with jitter, forces in N).

    Parameters
    ----------
    path : str or PathLike
        The CSV to write.
    rows : int
        Data rows.
    seed : int
        Seed of the stamps' jitter and the values.
    rate_hz : float
        Mean sample rate (1/s).
    block : int
        Rows formatted at a time (bounds the writer's memory).

    Returns
    -------
    Path
    """
    rng = np.random.default_rng(seed)
    period_ns = int(1e9 / rate_hz)
    t = 1_566_497_791_436_127_452
    out = Path(path)
    with open(out, "w", encoding="utf-8", newline="") as fh:
        fh.write(_HEADER)
        for start in range(0, rows, block):
            n = min(block, rows - start)
            stamps = t + np.cumsum(rng.integers(period_ns * 9 // 10, period_ns * 11 // 10, n))
            t = int(stamps[-1])
            values = rng.normal(0.0, 0.01, (n, 6))
            values[:, 2] -= np.linspace(0, 0.2, n)
            fh.write("".join(f"{s},{a:.12g},{b:.12g},{c:.12g},{d:.12g},{e:.12g},{f:.12g}\n"
                             for s, (a, b, c, d, e, f) in zip(stamps.tolist(), values.tolist())))
    return out


def _child(path: str, fmt_path: str) -> None:
    """Body of the subprocess: read the log through its format, print one JSON line."""
    from tympani.pipeline.force.labstreams import read_force_stream
    from tympani.pipeline.force.logformat import read_log_format

    fmt = read_log_format(fmt_path)
    before = peak_rss_mib()
    t0 = time.perf_counter()
    data, report, _ = read_force_stream(path, fmt.force)  # type: ignore[arg-type]
    seconds = time.perf_counter() - t0
    print(json.dumps({"import_rss_mib": before, "peak_rss_mib": peak_rss_mib(), "seconds": seconds,
                      "rows": report.n_rows, "samples": len(data)}))


def bench_log_read(rows: int = 1_000_000, *, seed: int = 0, folder: str | os.PathLike | None = None) -> dict:
    """Write a ``rows``-row ROS force log and time reading it in a fresh process.

    Parameters
    ----------
    rows : int
        Data rows of the log.
    seed : int
        Seed of the log's values.
    folder : str or PathLike, optional
        Where to write it (default: a temporary folder, removed afterwards).

    Returns
    -------
    dict
        ``rows``, ``file_mib`` (MiB), ``write_s``, ``seconds`` (reading), ``rows_per_s``,
        ``import_rss_mib`` and ``peak_rss_mib`` (MiB, resident, the reading process),
        ``read_mib`` (peak minus after-imports: what the reading itself held).
    """
    with tempfile.TemporaryDirectory(prefix="tympani-logbench-") as tmp:
        base = Path(folder) if folder is not None else Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        log, fmt = base / "bench_force.csv", base / "bench_format.toml"
        t0 = time.perf_counter()
        write_ros_force_csv(log, rows, seed=seed)
        write_s = time.perf_counter() - t0
        fmt.write_text(ROS_FORMAT, encoding="utf-8")
        done = subprocess.run([sys.executable, "-m", "tympani.pipeline.devtools.logbench", "read", str(log), str(fmt)],
                              capture_output=True, text=True, timeout=3600)
        if done.returncode != 0:
            lines = [line for line in done.stderr.splitlines() if line.strip()]
            raise RuntimeError(f"log-reading subprocess failed: {lines[-1] if lines else 'exit ' + str(done.returncode)}")
        out = json.loads(done.stdout.strip().splitlines()[-1])
        out.update(file_mib=log.stat().st_size / 2**20, write_s=write_s)
    out["rows_per_s"] = out["rows"] / out["seconds"] if out["seconds"] > 0 else float("nan")
    out["read_mib"] = out["peak_rss_mib"] - out["import_rss_mib"]
    return out


def format_log_bench(r: dict) -> str:
    """One line of the figures."""
    return (f"log reading    {r['seconds']:8.2f} s for a {r['rows']:,}-row ROS force CSV ({r['file_mib']:.0f} MiB), "
            f"{r['rows_per_s'] / 1e6:.2f} M rows/s; peak {r['peak_rss_mib']:.0f} MiB resident "
            f"({r['import_rss_mib']:.0f} MiB after the imports: {r['read_mib']:.0f} MiB for the reading), fresh process")



if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "read":
        _child(sys.argv[2], sys.argv[3])
    elif len(sys.argv) <= 2:
        print(format_log_bench(bench_log_read(int(sys.argv[1]) if len(sys.argv) == 2 else 1_000_000)))
    else:
        sys.exit("usage: python -m tympani.pipeline.devtools.logbench [ROWS]")

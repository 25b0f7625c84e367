"""Scale-out: ``tympani extract --scheduler ADDRESS`` on a Dask distributed cluster.

The cluster test starts a real ``distributed.LocalCluster`` on loopback (two worker processes,
one thread each), runs the batch through its address with the command line entry point, and
checks that the angles tables, the registrations and the summary equal a local run's. The other
tests check that Dask stays optional: without it, everything imports and runs, and
``--scheduler`` is a one-line error with exit status 2.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest

from tympani.pipeline.cli import main

#: Columns that record how long a frame took, not what was measured.
TIMING_COLUMNS = ("time_ms",)


def _err_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip()]


def _angles(folder: Path) -> dict[str, pd.DataFrame]:
    tables = {}
    for f in sorted(folder.glob("*.angles.csv")):
        t = pd.read_csv(f)
        tables[f.name] = t.drop(columns=[c for c in TIMING_COLUMNS if c in t.columns])
    return tables


def _registrations(folder: Path) -> dict[str, dict]:
    return {f.name: json.loads(f.read_text()) for f in sorted(folder.glob("*.registration.json"))}


@pytest.fixture(scope="module")
def experiment(tmp_path_factory) -> Path:
    """Three short rendered videos (8 frames, 400x300) with a manifest."""
    from tympani.pipeline.synthetic.experiment import ExperimentConfig, render_experiment

    out = tmp_path_factory.mktemp("dask_exp")
    cfg = ExperimentConfig(speeds_mm_s=(1.5, 3.0, 7.5), trials=1, max_frames=8, width=400, height=300, nuisance=0.2)
    render_experiment(out, cfg, seed=5)
    return out / "manifest.csv"


def test_extract_on_a_dask_cluster_equals_the_local_run(experiment, tmp_path, capsys):
    pytest.importorskip("distributed")
    from distributed import LocalCluster

    local, remote = tmp_path / "local", tmp_path / "dask"
    assert main(["extract", "--manifest", str(experiment), "--out", str(local), "-q"]) == 0
    with LocalCluster(host="127.0.0.1", n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=40) as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        capsys.readouterr()
        code = main(["extract", "--manifest", str(experiment), "--out", str(remote), "-q", "--scheduler", address])
        out, err = capsys.readouterr()
        assert code == 0, err
        assert "3 ok, 0 skipped, 0 failed" in out
        # a rerun through the cluster resumes: every video is skipped
        assert main(["extract", "--manifest", str(experiment), "--out", str(remote), "-q", "--scheduler", address]) == 0
        assert "3 skipped" in capsys.readouterr()[0]
        # tympani run extracts through the cluster too (one trial a speed: no diagnosis, the report says so)
        code = main(["run", "--manifest", str(experiment), "--out", str(tmp_path / "run"), "-q", "--scheduler", address])
        assert code == 0, capsys.readouterr()[1]
        assert (tmp_path / "run" / "report.html").exists()
        assert "--scheduler" in json.loads((tmp_path / "run" / "run.json").read_text())["command"]
    expected, got = _angles(local), _angles(remote)
    assert len(expected) == 3 and got.keys() == expected.keys()
    for name, table in expected.items():
        pd.testing.assert_frame_equal(got[name], table, check_exact=True)
        assert table["ok"].any()
    assert _registrations(remote) == _registrations(local)
    ran = _angles(tmp_path / "run" / "angles")
    assert ran.keys() == expected.keys()
    for name, table in expected.items():
        pd.testing.assert_frame_equal(ran[name], table, check_exact=True)
    assert not [p.name for p in remote.iterdir() if p.name.endswith(".tmp")]
    summary = pd.read_csv(remote / "extract_summary.csv")
    assert summary["status"].tolist() == ["skipped"] * 3
    assert summary["path"].tolist() == pd.read_csv(local / "extract_summary.csv")["path"].tolist()


def test_unreachable_scheduler_is_one_line_exit_2(experiment, tmp_path, capsys):
    pytest.importorskip("distributed")
    import socket

    import dask

    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code = main(["extract", "--manifest", str(experiment), "--out", str(tmp_path / "o"), "-q",
                     "--scheduler", f"tcp://127.0.0.1:{port}"])
    (line,) = _err_lines(capsys.readouterr()[1])
    assert code == 2 and line.startswith(f"tympani: tcp://127.0.0.1:{port}: cannot connect to the Dask scheduler")


def test_scheduler_and_workers_together_is_usage_error(capsys):
    code = main(["extract", "v.mp4", "--out", "o", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"])
    (line,) = _err_lines(capsys.readouterr()[1])
    assert code == 2 and "not both" in line


def test_everything_works_without_dask(experiment, tmp_path):
    """With ``dask`` and ``distributed`` unimportable: every module imports, every command's
    --help works, a local extract runs, and --scheduler is a one-line error with exit 2."""
    video = next((experiment.parent / "videos").glob("*.mp4"))
    script = textwrap.dedent(f"""
        import contextlib, importlib, io, pkgutil, sys
        sys.modules["dask"] = sys.modules["distributed"] = None   # import dask -> ImportError
        import tympani.pipeline as pipeline, tympani.vision as vision
        for pkg in (pipeline, vision):
            for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
                if not m.name.endswith("__main__"):
                    importlib.import_module(m.name)
        from tympani.pipeline.cli import COMMANDS, main
        for name in COMMANDS:
            with contextlib.redirect_stdout(io.StringIO()):
                assert main([name, "--help"]) == 0, name
        assert main(["extract", {str(video)!r}, "--out", {str(tmp_path / "local")!r}, "-q"]) == 0
        code = main(["extract", {str(video)!r}, "--out", {str(tmp_path / "dask")!r}, "-q",
                     "--scheduler", "tcp://127.0.0.1:1"])
        assert code == 2, code
        assert not any(k.split(".")[0] in ("dask", "distributed") and sys.modules[k] is not None for k in sys.modules)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = _err_lines(done.stderr)
    assert len(lines) == 1 and "--scheduler needs Dask's distributed scheduler" in lines[0]
    assert "pip install 'tympani[distributed]'" in lines[0]
    assert (tmp_path / "local" / f"{video.stem}.angles.csv").exists()
    assert not (tmp_path / "dask").exists()

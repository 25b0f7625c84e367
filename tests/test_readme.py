"""The README's Python example runs as printed, on the committed samples."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_python_example_runs(tmp_path):
    code = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), re.S)[1]
    (tmp_path / "samples").symlink_to(ROOT / "samples")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "mu_k" in lines[0] and "RMSE" in lines[0]
    assert [line.split(" mm/s")[0] for line in lines[1:]] == ["0.5", "3", "7.5"]
    assert len(list((tmp_path / "out" / "angles").glob("*.csv"))) >= 6

"""The distribution as a user installs it: one top-level package, ``tympani``.

The project is installed (not editable) into a temporary folder and imported from outside the
checkout, so neither the checkout's folders nor the editable install can stand in for it.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHECK = """
import importlib, importlib.util, pkgutil, sys
import tympani, tympani.vision, tympani.pipeline
assert tympani.__file__.startswith(sys.argv[1]), tympani.__file__
for pkg in (tympani.vision, tympani.pipeline):
    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
print(sorted(name for name in ("vision", "pipeline", "tests", "samples") if importlib.util.find_spec(name)))
print(callable(tympani.extract_video) and callable(tympani.diagnose))
"""


def test_installed_package_is_tympani_only(tmp_path):
    source, target = tmp_path / "source", tmp_path / "site"   # a copy: building writes into the source folder
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".*", "build", "*.egg-info", "__pycache__", "out", "demo_out"))
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(source)],
                   check=True, capture_output=True, cwd=tmp_path)
    assert sorted(p.name for p in target.iterdir() if not p.name.endswith(".dist-info")) == ["bin", "tympani"]
    env = {**os.environ, "PYTHONPATH": str(target)}
    done = subprocess.run([sys.executable, "-c", CHECK, str(target)], capture_output=True, text=True, cwd=tmp_path,
                          env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["[]", "True"]
    version = subprocess.run([str(target / "bin" / "tympani"), "--version"], capture_output=True, text=True,
                             cwd=tmp_path, env=env)
    release = re.search(r'^version = "(.+)"', (ROOT / "pyproject.toml").read_text(encoding="utf-8"), re.M)[1]
    assert version.stdout.strip() == f"tympani {release}"


def test_the_command_line_starts_without_the_analysis():
    """``tympani --help`` imports argparse-level code only: the API names of ``tympani`` load on
    first use, and each command imports its own modules when it runs."""
    code = ("import sys, tympani.pipeline.cli as cli; cli.build_parser(); "
            "heavy = [m for m in ('scipy', 'cv2', 'pandas', 'matplotlib', 'tympani.pipeline.diagnosis.analysis', "
            "'tympani.vision.angles') if m in sys.modules]; print(heavy)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT.parent)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
    code = "import tympani; f = tympani.fit_bounds; print(f.__module__, 'fit_bounds' in dir(tympani))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT.parent)
    assert done.stdout.split() == ["tympani.pipeline.model.bounds", "True"]

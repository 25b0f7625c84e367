"""The README's Python example runs as printed, on the committed samples; the documents' links resolve."""

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


def _anchors(path: Path) -> set[str]:
    """The #anchors GitHub gives the headings of a markdown file (lower case, punctuation but
    hyphens dropped, spaces to hyphens; repeats numbered), code blocks left out."""
    seen: set[str] = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        m = None if fenced else re.match(r"^#{1,6}\s+(.*?)\s*$", line)
        if m:
            slug = re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-")
            anchor, k = slug, 1
            while anchor in seen:
                anchor, k = f"{slug}-{k}", k + 1
            seen.add(anchor)
    return seen


def test_every_link_between_the_documents_resolves():
    """Relative links in the README, the changelog and the docs name files that exist and, with a
    #anchor, a heading of that file."""
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "samples" / "README.md",
             *sorted((ROOT / "docs").glob("*.md"))]
    broken = []
    for page in pages:
        for link in re.findall(r"\]\(([^)\s]+)\)", page.read_text(encoding="utf-8")):
            if re.match(r"^[a-z]+:", link):  # http:, https:, mailto:
                continue
            path, _, anchor = link.partition("#")
            target = (page.parent / path).resolve() if path else page
            if not target.exists():
                broken.append(f"{page.name}: {link} (no such file)")
            elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
                broken.append(f"{page.name}: {link} (no such heading)")
    assert pages[3:] and not broken, broken

"""No tracker words in what a user reads: "issue 24", "issues 24 and 25", "(issue 17)",
"before issue 26", "#24"-style references have no meaning outside the tracker. History
goes to CHANGELOG.md (the one file allowed to name it). Checked in the README, docs/ and
every Python file of the toolkit and the bench (docstrings, comments, help strings and
warnings alike)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TRACKER = re.compile(r"\bissues?\s*[-_#]?\s*\d+|\bissues?[-_]\d+|\(#\d+\)|\bgh-\d+\b", re.I)
"""``issue 24``, ``issues 24 and 25``, ``issue #24``, ``issue-24`` (an anchor), ``(#24)``."""
PYTHON_PACKAGES = ("common", "tpods", "bench", "calibration", "mocap_bridge", "estimator",
                   "benchmarks")
ALLOWED = {"CHANGELOG.md"}


def _hits(paths) -> list[str]:
    out = []
    for path in paths:
        if path.name in ALLOWED:
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            for m in TRACKER.finditer(line):
                out.append(f"{path.relative_to(ROOT)}:{n}: {m.group(0)!r} in {line.strip()[:100]}")
    return out


def test_pattern_finds_the_forms_and_spares_plain_words():
    for text in ("(issue 24)", "before issue 26", "issues 24 and 25", "Issue #7", "see (#12)",
                 "#when-the-model-does-not-fit-a-run-issue-24-item-7"):
        assert TRACKER.search(text), text
    for text in ("the issue that started this", "issue a warning", "24 issues", "tissue 3"):
        assert not TRACKER.search(text), text


def test_no_tracker_words_in_the_readme_and_docs():
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    hits = _hits(paths)
    assert not hits, "\n".join(hits)


def test_no_tracker_words_in_the_python_sources():
    paths = [p for pkg in PYTHON_PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]
    hits = _hits(paths)
    assert not hits, f"{len(hits)} found:\n" + "\n".join(hits[:50])

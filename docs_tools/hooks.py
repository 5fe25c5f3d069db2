"""MkDocs hook (mkdocs.yml ``hooks:``): adds two pages made at every build, never stored in
docs/: ``cli.md``, the CLI reference generated from the parsers
(:mod:`docs_tools.cli_reference`), and ``changelog.md``, the repository's CHANGELOG.md."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # the toolkit and docs_tools, also from a plain mkdocs venv
    sys.path.insert(0, str(ROOT))

from mkdocs.structure.files import File  # noqa: E402

from docs_tools.cli_reference import page  # noqa: E402


def on_files(files, config):
    files.append(File.generated(config, "cli.md", content=page()))
    files.append(File.generated(config, "changelog.md", content=_changelog()))
    return files


def _changelog() -> str:
    """CHANGELOG.md of the repository root, its links into docs/ made relative to the site."""
    return (ROOT / "CHANGELOG.md").read_text().replace("](docs/", "](")

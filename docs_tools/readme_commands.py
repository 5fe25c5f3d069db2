"""The README's shell commands, section by section: every fenced ``sh`` block under each
``##`` heading, one command per line (a trailing backslash continues a line; a ``#``
comment after a command is dropped)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def sections(text: str) -> dict[str, list[str]]:
    """``{heading: [command, ...]}`` of the ``sh`` blocks under each ``##`` heading."""
    out: dict[str, list[str]] = {}
    heading = ""
    in_block = False
    pending = ""
    for line in text.splitlines():
        if not in_block and line.startswith("## "):
            heading = line[3:].strip()
            continue
        if not in_block and re.fullmatch(r"```(sh|bash|shell)\s*", line):
            in_block = True
            continue
        if in_block and line.startswith("```"):
            in_block = False
            continue
        if in_block:
            pending += line.rstrip()
            if pending.endswith("\\"):
                pending = pending[:-1] + " "
                continue
            cmd = " ".join(shlex.split(pending, comments=True))
            pending = ""
            if cmd:
                out.setdefault(heading, []).append(cmd)
    return out


def readme_sections(path: Path = README) -> dict[str, list[str]]:
    return sections(Path(path).read_text())

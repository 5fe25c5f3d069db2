"""The README as a newcomer follows it: at most 200 lines; the two commands `make demo` and
`make test`; the lab day and the own vehicle in five `tpods` commands each, every one of
which the parser accepts; and (marked slow) the commands run in order from a fresh copy of
the repository: `make demo` and the own-vehicle commands to an estimate."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from docs_tools.readme_commands import README, readme_sections
from tpods.cli import build_parser

ROOT = README.parent
QUICK = "Getting started"
LAB_DAY = "The lab day in five steps"
OWN = "Your own vehicle"


def test_readme_is_at_most_200_lines():
    assert len(README.read_text().splitlines()) <= 200


def test_the_two_commands_are_make_demo_and_make_test():
    assert readme_sections()[QUICK] == ["make demo", "make test"]
    targets = re.search(r"^\.PHONY:(.*)$", (ROOT / "Makefile").read_text(), re.M).group(1).split()
    assert {"demo", "test", "docs"} <= set(targets)


@pytest.mark.parametrize("section", [LAB_DAY, OWN])
def test_five_tpods_commands_that_the_parser_accepts(section):
    cmds = readme_sections()[section]
    assert len(cmds) == 5, cmds
    for cmd in cmds:
        argv = shlex.split(cmd)
        assert argv[0] == "tpods", cmd
        build_parser().parse_args(argv[1:])  # SystemExit(2) on an unknown option or command


def _fresh_copy(dest: Path) -> Path:
    """The repository's tracked files (a fresh clone's), without runs/ beyond the fixtures."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    for f in filter(None, files):
        src = ROOT / f
        if src.is_file():
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / f)
    return dest


@pytest.mark.slow
def test_readme_commands_run_in_order_from_a_fresh_copy(tmp_path):
    """make demo (about 2 minutes) and the own vehicle's five commands (about 15 s), in a
    copy of the tracked files, with this environment's installed toolkit; `make test` is
    only named (it is the suite this test belongs to)."""
    repo = _fresh_copy(tmp_path / "repo")
    venv = Path(sys.executable).parent.parent
    env = {**os.environ, "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}",
           "MPLBACKEND": "Agg"}
    sections = readme_sections(repo / "README.md")
    # make demo on this venv (VENV=..., its install stamp taken as up to date)
    proc = subprocess.run(["make", "demo", f"VENV={venv}", "-o", f"{venv}/.installed"],
                          cwd=repo, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert list((repo / "runs").glob("demo-*/report.md")), proc.stdout[-2000:]
    for cmd in sections[OWN]:
        proc = subprocess.run(shlex.split(cmd), cwd=repo, env=env, capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, f"{cmd}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
    assert (repo / "runs" / "aevar-health.toml").is_file()
    estimate = (repo / "runs" / "aevar-estimate" / "estimate.json")
    assert estimate.is_file()

"""docs/use-cases.md runs: every ```python block of the page, in a fresh interpreter from
the repository's root, exits 0 and prints what the page says it prints. The real-run
block (an import and two fits of 208 s by segments, ~20 s) is marked slow."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "use-cases.md"


def blocks() -> list[tuple[str, str]]:
    """(heading, code) of every python block, under its ## heading."""
    out, heading = [], ""
    for part in re.split(r"^(## .*)$", PAGE.read_text(), flags=re.M):
        if part.startswith("## "):
            heading = part[3:].strip()
            continue
        out += [(heading, code) for code in re.findall(r"```python\n(.*?)```", part, re.S)]
    return out


def _run(code: str) -> str:
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout


def table_functions() -> list[tuple[str, str]]:
    """(module, function) of every function the page's table names. A full dotted name
    gives both; a bare name is in the module named before it; ``sub.name`` is a sibling
    module of the one named before it."""
    out, module = [], ""
    for row in re.findall(r"^\| `tpods [^|]+\| (.+) \|$", PAGE.read_text(), re.M):
        for ref in re.findall(r"`([\w.]+)`", row):
            if ref.count(".") >= 2:
                module, name = ref.rsplit(".", 1)
            elif "." in ref:
                sub, name = ref.split(".")
                module = f"{module.rsplit('.', 1)[0]}.{sub}"
            else:
                name = ref
            out.append((module, name))
    return out


def test_the_page_shows_three_calls_and_where_every_use_case_is():
    assert len(blocks()) == 3
    funcs = table_functions()
    assert len(funcs) >= 18
    for module, name in funcs:
        assert callable(getattr(importlib.import_module(module), name, None)), (module, name)


@pytest.mark.parametrize("heading", ["Batch least squares and its Cramér-Rao bound on a "
                                     "recorded run",
                                     "Izz from a bifilar swing tracked by the motion capture"])
def test_a_quick_call_runs(heading):
    code = dict((h, c) for h, c in blocks())[heading]
    out = _run(code).split()
    assert len(out) >= 2 and all(re.fullmatch(r"[-+0-9.e]+", v) for v in out[:2])


@pytest.mark.slow
def test_the_real_run_call_runs_and_finds_the_scale_mass_within_three_sigma():
    code = blocks()[0][1]
    out = _run(code)
    m = re.search(r"mass ([0-9.]+) \+- ([0-9.]+) kg", out)
    assert m, out[-2000:]
    mass, sigma = float(m.group(1)), float(m.group(2))
    assert abs(mass - 23.09) < 3 * sigma

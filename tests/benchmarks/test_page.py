"""docs/bench.md's generator: a tiny bench report and template in, the page out."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.page import GENERATED_NOTE, render, write_page

BENCH = {
    "machine": {"python": "3.11.7", "platform": "Linux-x", "cpus": 2,
                "time": "2026-11-28T12:42:03+0000"},
    "rule": {"text": "noisy host = steal >= 0.5 %"},
    "wall_s": 12.3,
    "cases": {"bench_sim": {"wall_s": 9.564, "cpu_s": 9.727}},
    "summary": {"yes": 1, "NO": 1, "noisy host": 0, "-": 0},
    "results": [
        {"case": "sim 120 s", "metric": "time (s)", "value": 0.1234567, "reference": 0.5,
         "ratio": 4.05, "verdict": "yes", "target": "< 0.5 s | exact"},
        {"case": "sim 120 s", "metric": "error (m)", "value": 3e-11, "reference": None,
         "ratio": None, "verdict": "NO", "target": "< 1e-12"},
    ],
    "failed": [],
}
TEMPLATE = "# Bench\n\n<!-- {generated_note} -->\n\n## The latest run\n\n{results}\n\n## Text\n\nkept\n"


def test_render_puts_the_report_into_the_template():
    page = render(BENCH, TEMPLATE)
    assert GENERATED_NOTE in page
    assert "{results}" not in page and page.endswith("## Text\n\nkept\n")
    assert "From `runs/bench.json` of 2026-11-28T12:42:03+0000: 2 CPUs" in page
    assert "**1 yes, 1 NO, 0 noisy host, 0 not judged; 0 case(s) crashed.**" in page
    assert "| `bench_sim` | 9.564 | 9.727 |" in page
    assert "| sim 120 s | time (s) | 0.1235 | 0.5 | 4.05 | yes | < 0.5 s \\| exact |" in page
    assert "| sim 120 s | error (m) | 3e-11 | n/a | n/a | NO | < 1e-12 |" in page
    assert "Rule: noisy host = steal >= 0.5 %." in page


def test_write_page_reads_the_long_report_beside_it(tmp_path):
    (tmp_path / "bench.json").write_text(json.dumps(BENCH))
    (tmp_path / "bench-long.json").write_text(json.dumps({**BENCH, "failed": ["bench_sweep"]}))
    (tmp_path / "t.md").write_text(TEMPLATE)
    out = write_page(tmp_path / "bench.json", tmp_path / "bench.md", tmp_path / "t.md")
    text = out.read_text()
    assert "### The long cases (`make bench-long`)" in text
    assert "1 case(s) crashed: bench_sweep" in text


def test_every_bench_module_is_a_case():
    """``make bench`` runs every ``benchmarks/bench_*.py`` as a case: each must have ``run()``
    (a helper named bench_* would crash the bench)."""
    import ast

    for f in sorted((Path(__file__).resolve().parents[2] / "benchmarks").glob("bench_*.py")):
        names = {n.name for n in ast.parse(f.read_text()).body if isinstance(n, ast.FunctionDef)}
        assert "run" in names, f"{f.name} has no run(): not a bench case"

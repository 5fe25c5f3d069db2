"""Issue 16: a damaged cell in steps.csv (text, empty, NaN, infinity) is one line naming the
file, line and column, never a traceback and never a step dropped silently."""

from __future__ import annotations

import pandas as pd
import pytest

from bench.fit import check_steps, fit_steps
from common.errors import UserError
from common.thrust_table import ThrustTable
from tests.support.cli import run_in_process


def _steps() -> pd.DataFrame:
    t = ThrustTable.default()
    return pd.DataFrame([{"step": i, "n_open": 1, "duty_pct": float(d), "thrust_gf": float(t.per_nozzle(d, 1)),
                          "n": 10, "std_gf": 0.1, "sem_gf": 0.03}
                         for i, d in enumerate(range(10, 91, 10))])


@pytest.mark.parametrize("col,cell,needle", [
    ("thrust_gf", "abc", "line 4: column thrust_gf: 'abc' is not a number"),
    ("thrust_gf", "", "line 4: column thrust_gf: empty or NaN"),
    ("thrust_gf", "nan", "line 4: column thrust_gf: empty or NaN"),
    ("duty_pct", "inf", "line 4: column duty_pct: inf is not a finite number"),
    ("n_open", "two", "line 4: column n_open: 'two' is not a number"),
    ("std_gf", "x", "line 4: column std_gf: 'x' is not a number"),
])
def test_damaged_cell_names_file_line_and_column(tmp_path, col, cell, needle):
    p = tmp_path / "steps.csv"
    text = _steps().to_csv(index=False).splitlines()
    text.insert(2, "")  # a blank line: pandas skips it, the line numbers must not
    header = text[0].split(",")
    row = text[3].split(",")
    row[header.index(col)] = cell
    text[3] = ",".join(row)
    p.write_text("\n".join(text) + "\n")
    with pytest.raises(UserError, match=f"^{p}: " + needle.replace("(", r"\(")):
        fit_steps(pd.read_csv(p), source=str(p), path=str(p))


def test_empty_std_is_fine_and_counts_more_bad_lines():
    s = _steps()
    s.loc[3, "std_gf"] = float("nan")  # a step of one reading has no std
    assert len(check_steps(s)) == len(s)
    s.loc[[2, 5], "thrust_gf"] = float("nan")
    with pytest.raises(UserError, match=r"line 4: column thrust_gf: empty or NaN \(1 more line\(s\) like it\); "
                                        "delete the line"):
        fit_steps(s)


def test_bench_fit_cli_one_line(tpods_exe, tmp_path):
    run_dir = tmp_path / "session"
    run_dir.mkdir()
    s = _steps()
    raw = pd.DataFrame({"t_s": [0.0, 0.1], "window": [0, 0], "phase": ["zero", "zero"], "step": [-1, -1],
                        "n_open": [0, 0], "duty_pct": [0.0, 0.0], "reading_gf": [0.0, 0.0], "stable": [1, 1]})
    raw.to_csv(run_dir / "raw.csv", index=False)
    s["thrust_gf"] = s["thrust_gf"].astype(object)
    s.loc[4, "thrust_gf"] = "12,5"
    s.to_csv(run_dir / "steps.csv", index=False)
    r = run_in_process("bench", "fit", str(run_dir), "--order", "2")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == (f"tpods: error: {run_dir / 'steps.csv'}: line 6: column thrust_gf: '12,5' is "
                                "not a number; delete the line to leave that step out of the fit")
    assert not (run_dir / "thrust_table.toml").exists()

"""Load-cell CSV logs into the session format (bench.loadcell_import)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.fit import fit_steps
from bench.loadcell_import import parse_columns, parse_valves, read_log
from bench.session import summarize_steps
from common.errors import UserError
from common.thrust_table import GF_TO_N

LOG = """t_s,weight_g,bitmask,pulse_number,phase
0.00,,0,0,baseline
0.02,,0,0,baseline
0.04,0.10,0,0,tare
0.06,0.00,0,0,baseline
0.08,0.00,0,0,baseline
0.10,0.00,5,1,firing
0.12,10.0,5,1,firing
0.14,20.0,5,1,firing
0.16,20.0,0,1,post_pulse
0.18,5.0,0,1,post_pulse
"""


def test_rows_windows_empty_cells_and_tare_phases(tmp_path):
    f = tmp_path / "log.csv"
    f.write_text(LOG)
    log = read_log(f, settle_s=0.03, zero_settle_s=0.0)
    assert log.counts == {"rows": 10, "readings": 7, "empty_force_cells": 2, "tare_rows_skipped": 1}
    raw = log.raw
    assert log.on_off and log.n_valves == 3  # bitmask 5: valves 1 and 3
    assert list(raw["n_open"]) == [0, 0, 2, 2, 2, 0, 0]
    assert list(raw["phase"]) == ["zero", "zero", "settle", "settle", "dwell", "zero", "zero"]
    assert list(raw["d1"]) == [0, 0, 100, 100, 100, 0, 0] and list(raw["d2"]) == [0] * 7
    assert list(raw["step"]) == [-1, -1, 0, 0, 0, -1, -1]
    assert list(raw["line"]) == [5, 6, 7, 8, 9, 10, 11]


def test_units_and_columns(tmp_path):
    f = tmp_path / "log.csv"
    f.write_text("time_ms;force_N;valves\n".replace(";", ",")
                 + "".join(f"{i * 20},{0.4 if 5 <= i < 15 else 0.0},\"[{int(5 <= i < 15)}, 0]\"\n"
                           for i in range(20)))
    cols = parse_columns("t=time_ms,force=force_N,valves=valves")
    log = read_log(f, cols, force_unit="N", valves_as="vector", time_unit="ms", settle_s=0.0,
                   zero_settle_s=0.0)
    assert log.raw["t_s"].iloc[-1] == pytest.approx(0.38)
    assert log.raw["reading_gf"].max() == pytest.approx(0.4 / GF_TO_N)
    assert log.n_valves == 2 and log.columns == {"t": "time_ms", "force": "force_N", "valves": "valves"}


@pytest.mark.parametrize("cell, fmt, duties", [
    ("5", "bitmask", [100, 0, 100]), ("0x80", "bitmask", [0] * 7 + [100]), ("0", "bitmask", [0]),
    ("[1, 0, 1, 0]", "vector", [100, 0, 100, 0]), ("1;0", "vector", [100, 0]),
    ("55.5", "duty", [55.5]), ("[50 50 0 0]", "duty", [50, 50, 0, 0]),
])
def test_valve_cells(cell, fmt, duties):
    assert parse_valves(cell, fmt, "here") == duties


@pytest.mark.parametrize("cell, fmt", [("1.5", "bitmask"), ("-1", "bitmask"), ("x", "bitmask"),
                                       ("[1, 2]", "vector"), ("120", "duty"), ("[]", "vector")])
def test_bad_valve_cells(cell, fmt):
    with pytest.raises(UserError, match="here"):
        parse_valves(cell, fmt, "here")


@pytest.mark.parametrize("text, needle", [
    (LOG.replace("0.12,10.0", "0.12,ten"), "line 8: column weight_g: 'ten' is not a number"),
    (LOG.replace("0.14,20.0,5", "0.14,20.0,z"), "line 9: column bitmask"),
    (LOG.replace("0.16,", "0.11,"), "line 10: column t_s: time 0.11 s does not increase"),
    (LOG.replace("0.18,5.0,0,1,post_pulse", "0.18,5.0"), "line 11: 2 cells for 5 columns"),
    (LOG.replace("weight_g", "grams"), "no column 'weight_g' for force"),
    ("t_s,weight_g,bitmask\n", "no data rows"),
])
def test_damaged_logs_name_the_line_and_column(tmp_path, text, needle):
    f = tmp_path / "log.csv"
    f.write_text(text)
    with pytest.raises(UserError) as exc:
        read_log(f)
    assert needle in str(exc.value) and "\n" not in str(exc.value)


def test_a_duty_staircase_imports_into_todays_polynomial_fit(tmp_path):
    rng = np.random.default_rng(0)
    rows, t = ["t,thrust_g,duty"], 0.0
    for d in (10, 20, 30, 40, 50, 60, 70, 80, 90):
        for duty, dur in ((0, 3.0), (d, 5.0)):
            for _ in range(int(dur * 10)):
                f = 0.0 if duty == 0 else 0.6 * duty - 0.002 * duty**2
                rows.append(f"{t:.2f},{f + rng.normal(0, 0.05):.3f},{duty}")
                t += 0.1
    path = tmp_path / "stairs.csv"
    path.write_text("\n".join(rows) + "\n")
    log = read_log(path, parse_columns("t=t,force=thrust_g,valves=duty"), valves_as="duty")
    assert not log.on_off
    steps = summarize_steps(log.raw)
    assert list(steps["duty_pct"]) == [10, 20, 30, 40, 50, 60, 70, 80, 90]
    fit = fit_steps(steps)
    poly = fit.fits[1][fit.selected[1]]
    assert fit.selected[1] >= 2 and poly.predict(50.0) == pytest.approx(25.0, abs=0.1)

"""`tpods bench import` and `tpods bench fit` on imported load-cell logs (in process, with the
exit code, stdout and stderr a user sees): on/off pulses and a duty staircase; damaged logs
are one line, exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.thrust_table import GF_TO_N
from tests.support.cli import run_in_process
from tests.support.pulse_logs import pulse_log
from tpods.cli import main


def test_import_then_fit_pulses_json(tpods_exe, tmp_path):
    log = pulse_log(tmp_path / "log.csv", {1: 45.0, 2: 38.0}, 0.08, 0.15, seed=3)
    sess = tmp_path / "sess"
    r = run_in_process("bench", "import", str(log), "--out", str(sess), "--settle", "1.5",
            "--zero-settle", "1.5")
    assert r.returncode == 0, r.stderr
    assert "as on/off pulses: 8 steps; 5 empty force cell(s)" in r.stdout
    assert json.loads((sess / "run.json").read_text())["valves"] == "on/off"
    r = run_in_process("bench", "fit", str(sess), "--json", "--scale-rel", "0.002")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert set(d["valves"]) == {"1", "2"}
    for k, f in (("1", 45.0), ("2", 38.0)):
        v = d["valves"][k]
        assert {"force_n", "force_sigma_n", "delay_s", "rise_s", "delay_sigma_s", "rise_sigma_s"} <= set(v)
        assert v["force_n"] == pytest.approx(f * GF_TO_N, abs=3 * v["force_sigma_n"])
        assert v["delay_s"] == pytest.approx(0.08, abs=3 * v["delay_sigma_s"])
        assert v["rise_s"] == pytest.approx(0.15, abs=3 * v["rise_sigma_s"])
    assert d["counts"]["2"]["valve_sets"] == ["1,2"]
    assert d["vehicle_valves"]["delay_s"] == pytest.approx(0.08, abs=0.02)
    assert (sess / "pulse_fit.json").is_file() and (sess / "pulse_fit_edges.png").stat().st_size > 1000
    r = run_in_process("bench", "fit", str(sess), "--out", str(tmp_path / "fitdir"))
    assert r.returncode == 0 and "for the vehicle file: [valves] delay_s" in r.stdout
    assert (tmp_path / "fitdir" / "pulse_fit.json").is_file()


def test_import_a_duty_staircase_and_fit_polynomials(tpods_exe, tmp_path):
    rng = np.random.default_rng(1)
    rows, t = ["time_ms,kg,valves"], 0.0
    for d in (20, 40, 60, 80):
        for duty, n in ((0, 30), (d, 50)):
            for _ in range(n):
                f = 0.0 if duty == 0 else 0.6 * duty - 0.002 * duty**2
                rows.append(f"{t * 1e3:.0f},{(f + rng.normal(0, 0.05)) / 1e3:.6f},\"[{duty}, 0, 0, 0]\"")
                t += 0.1
    log = tmp_path / "stairs.csv"
    log.write_text("\n".join(rows) + "\n")
    sess = tmp_path / "s"
    r = run_in_process("bench", "import", str(log), "--out", str(sess), "--columns",
            "t=time_ms,force=kg,valves=valves", "--force-unit", "kg", "--valves-as", "duty",
            "--time-unit", "ms")
    assert r.returncode == 0, r.stderr
    assert "as duty steps: 4 steps" in r.stdout
    r = run_in_process("bench", "fit", str(sess), "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["thrust_table"].endswith("thrust_table.toml") and "1" in d["selected_order"]


@pytest.mark.parametrize("text, needle", [
    ("t_s,weight_g,bitmask\n0,1,0\n0.02,x,1\n", "line 3: column weight_g: 'x' is not a number"),
    ("t_s,weight_g,bitmask\n0,1,0\n0.02,1,1.5\n", "line 3: column bitmask"),
    ("a,b\n1,2\n", "no column 't_s' for t"),
    ("", "no data rows"),
])
def test_damaged_logs_are_one_line_exit_2(tmp_path, capsys, text, needle):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    assert main(["bench", "import", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpods: error:") and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "o").exists()


def test_bad_columns_option_and_binary_file(tpods_exe, tmp_path):
    f = tmp_path / "log.csv"
    f.write_text("t_s,weight_g,bitmask\n0,1,0\n")
    r = run_in_process("bench", "import", str(f), "--out", str(tmp_path / "o"), "--columns", "x=1")
    assert r.returncode == 2 and "--columns: 'x=1'" in r.stderr and r.stderr.count("\n") == 1
    f.write_bytes(b"\xff\xfe\x00\x01garbage")
    r = run_in_process("bench", "import", str(f), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "unreadable" in r.stderr and r.stderr.count("\n") == 1

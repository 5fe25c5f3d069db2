"""`tpods calibrate pendulum-check` end to end (in process, with the exit code, stdout and
stderr a user sees; the console script itself: tests/tpods/cli/test_main.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibration.swing.pendulum_check import simulate_series
from tests.support.cli import run_in_process
from tpods.cli import main

RADII = np.arange(0.25, 0.751, 0.05)


def _izz_csv(path, scale=1.0, seed=0):
    izz = scale * simulate_series(0.2345, 0.02094, RADII, 3e-5, seed=seed)
    path.write_text("radius_m,izz_kgm2,izz_sigma_kgm2\n"
                    + "".join(f"{r:.2f},{i:.8f},3e-5\n" for r, i in zip(RADII, izz, strict=True)))
    return path


def test_json_and_folder_output(tpods_exe, tmp_path):
    f = _izz_csv(tmp_path / "series.csv")
    r = run_in_process("calibrate", "pendulum-check", str(f), "--test-mass-kg", "0.02094",
            "--json", "--out", str(tmp_path / "check"))
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["verdict"] == "pass" and d["dof"] == len(RADII) - 2
    assert abs(d["test_mass_difference_sigmas"]) < 3
    assert d["i0_kgm2"] == pytest.approx(0.2345, abs=4 * d["i0_sigma_kgm2"])
    assert (tmp_path / "check" / "check.png").stat().st_size > 1000
    assert json.loads((tmp_path / "check" / "result.json").read_text())["verdict"] == "pass"


def test_text_output_and_a_failing_pendulum_warns(tpods_exe, tmp_path):
    f = _izz_csv(tmp_path / "series.csv", scale=0.9)
    r = run_in_process("calibrate", "pendulum-check", str(f), "--test-mass-kg", "0.02094")
    assert r.returncode == 0
    assert "pendulum check FAIL" in r.stdout and "sigma from the known" in r.stderr


def test_periods_with_the_trifilar_geometry(tpods_exe, tmp_path):
    g = 9.80665
    izz = 0.2345 + 0.02094 * RADII**2
    period = np.sqrt(izz * 4 * np.pi**2 * 0.995 / ((0.848 + 0.02094) * g))
    f = tmp_path / "periods.csv"
    f.write_text("# a comment\nradius_m,period_s,period_sigma_s\n"
                 + "".join(f"{r:.2f},{p:.10f},2e-5\n" for r, p in zip(RADII, period, strict=True)))
    base = ["calibrate", "pendulum-check", str(f), "--test-mass-kg", "0.02094"]
    r = run_in_process(*base, "--string-radius", "1.0", "--length", "0.995", "--mass", "0.848",
            "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["test_mass_kg"] == pytest.approx(0.02094, rel=1e-6)
    assert d["i0_kgm2"] == pytest.approx(0.2345, rel=1e-7)
    r = run_in_process(*base, "--spacing", "2.0", "--length", "0.995", "--mass", "0.848", "--json")
    assert json.loads(r.stdout)["i0_kgm2"] == pytest.approx(0.2345, rel=1e-7)  # D = 2R
    r = run_in_process(*base)  # periods without the geometry
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--length" in r.stderr


@pytest.mark.parametrize("text, needle", [
    ("radius_m,izz_kgm2,izz_sigma_kgm2\n0.25,0.236,3e-5\n0.30,abc,3e-5\n0.35,0.237,3e-5\n",
     "line 3: column izz_kgm2: 'abc'"),
    ("radius_m,izz_kgm2\n0.25,0.236\n", "izz_sigma_kgm2"),
    ("radius_m,izz_kgm2,izz_sigma_kgm2\n0.25,0.236\n", "line 2: 2 cells"),
    ("", "empty"),
    ("\x00\xff\xfe", "unreadable"),
])
def test_damaged_series_is_one_line_exit_2(tmp_path, capsys, text, needle):
    f = tmp_path / "s.csv"
    f.write_bytes(text.encode("latin-1"))
    assert main(["calibrate", "pendulum-check", str(f), "--test-mass-kg", "0.02"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpods: error:") and err.count("\n") == 1 and needle in err, err

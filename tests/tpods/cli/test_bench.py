"""The `tpods bench` commands as a user runs them."""

import subprocess
import time

import pandas as pd
import pytest

from bench.ohaus.driver import OhausScout
from bench.valves import ValveController
from common.thrust_table import ThrustTable
from tests.support.cli import run, run_in_process
from tpods.cli import main


def test_help(capsys):
    for cmd in ("characterize", "fit", "emulate"):
        with pytest.raises(SystemExit) as e:
            main(["bench", cmd, "--help"])
        assert e.value.code == 0 and f"usage: tpods bench {cmd}" in capsys.readouterr().out


def test_missing_device_one_line_from_the_installed_command(tpods_exe, tmp_path):
    r = run(tpods_exe, "bench", "characterize", "--valves", str(tmp_path / "nodev"), "--scale",
            "/dev/null", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and r.stderr.startswith("tpods: error: cannot open the valve controller")
    assert len(r.stderr.strip().splitlines()) == 1


def test_user_errors_are_one_line(tmp_path, capsys):
    cases = [
        ("bench", "characterize", "--valves", "x", "--scale", "y", "--duty", "5:95:10", "--out", "o"),
        ("bench", "characterize", "--valves", "x", "--scale", "y", "--duty", "a:b", "--out", "o"),
        ("bench", "characterize", "--valves", "x", "--scale", "y", "--scale-format", "9Q1", "--out", "o"),
        ("bench", "fit", str(tmp_path / "missing")),
        ("bench", "emulate", "--table", str(tmp_path / "none.toml")),
    ]
    for args in cases:
        assert main(list(args)) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("tpods: error: ") and len(err.strip().splitlines()) == 1, err


def test_fit_recomputes_steps_from_raw_and_fixed_order(tpods_exe, tmp_path):
    """A run killed before steps.csv was written still fits (from raw.csv)."""
    table = ThrustTable.default()
    rows, t = [], 0.0
    w = 0
    for k in (1, 2):
        for d in range(10, 91, 10):
            for phase, step, val in (("zero", -1, 0.0), ("dwell", w, float(table.per_nozzle(d, k)))):
                for i in range(5):
                    rows.append((t, w, phase, step if step >= 0 else -1, k if step >= 0 else 0,
                                 d if step >= 0 else 0, val + 0.01 * (i - 2), 1))
                    t += 0.1
            w += 1
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    pd.DataFrame(rows, columns=["t_s", "window", "phase", "step", "n_open", "duty_pct", "reading_gf",
                                "stable"]).to_csv(run_dir / "raw.csv", index=False)
    r = run_in_process("bench", "fit", str(run_dir), "--order", "3", "--pressure-psi", "60")
    assert r.returncode == 0, r.stderr
    fitted = ThrustTable.load(run_dir / "thrust_table.toml")
    assert fitted.pressure_psi == 60 and sorted(fitted.coefficients) == [1, 2]
    for k in (1, 2):
        assert len(fitted.coefficients[k]) == 4
        assert abs(fitted.per_nozzle(55.0, k) - table.per_nozzle(55.0, k)) < 0.05
    assert (run_dir / "thrust_table_orders.png").exists()


def test_emulate_serves_both_devices(tpods_exe, tmp_path):
    proc = subprocess.Popen([tpods_exe, "bench", "emulate", "--duration", "20", "--seed", "2",
                             "--load-g", "720", "--lag-s", "0", "--log-dir", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        paths = {}
        while len(paths) < 2:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            name, path = line.split(": ")
            paths[name] = path.strip()
        with ValveController(paths["valves"]) as v, OhausScout(paths["scale"]) as s:
            assert v.identify().n_channels == 4
            r = s.read("SP")
            assert abs(r.value - 720.0) < 1.5 and r.unit == "g"   # the module on the pan
            v.set_all([90, 0, 0, 0])
            time.sleep(0.1)
            assert abs(s.read("SP").value - 720.0 - table2(90)) < 1.5
            v.off()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert proc.returncode == 0
    log = pd.read_csv(tmp_path / "valves_log.csv")
    assert list(log["d1"]) == [0, 90, 0]


def table2(d):
    return float(ThrustTable.default().per_nozzle(d, 1))

"""`tpods calibrate bifilar --rates/--trace` and `tpods calibrate trifilar` end to end (issue
25): a flight-controller-style gyro log (ms, deg/s, named columns), a pixel trace with and
without an angle scale, trifilar timings; bad logs give one line and exit 2."""

import json
import math

import numpy as np
import pytest

from calibration.swing.bifilar_model import Pendulum
from calibration.swing.sim import simulate_sensor_trace
from tests.support.cli import run_in_process
from tpods.cli import main

I_TRUE = 1.2e-3
BI = ["--mass", "0.72", "--spacing", "0.1", "--length", "1.0", "--u-mass", "0", "--u-spacing", "0",
      "--u-length", "0"]


def _gyro_log(path):
    p = Pendulum(0.72, I_TRUE, 0.10, 1.0, c1=0.004, c2=0.01)
    t, w = simulate_sensor_trace(p, "rate", release_deg=12, duration_s=20, rate_hz=50,
                                 bias=0.03, drift_per_s=1e-4, sway_fraction=0.1, seed=4)
    lines = ["Time,sensYaw,xGyro,yGyro,ZGyro"]
    lines += [f"{1000 * (6.0 + ti):.0f},0.5,0.1,0.2,{math.degrees(wi):.3f}" for ti, wi in zip(t, w, strict=True)]
    lines.insert(40, "6790,,,,")  # a row the logger left empty
    path.write_text("\n".join(lines) + "\n")
    return path


def _pixel_log(path, time_column=True):
    p = Pendulum(0.869, 0.2358, 2.0, 0.995, c1=0.002, c2=0.005)  # a trifilar at R = 1 m
    t, y = simulate_sensor_trace(p, "signal", release_deg=4, duration_s=15, rate_hz=60,
                                 bias=500, gain=800, sway_fraction=0.05, seed=2)
    rows = [f"{ti:.5f}\t{yi:.3f}" for ti, yi in zip(t, y, strict=True)]
    path.write_text(("t\tx\n" if time_column else "") + "\n".join(rows) + "\n")
    return path


def test_bifilar_rates_from_a_gyro_log_in_ms_and_deg_per_s(tpods_exe, tmp_path):
    log = _gyro_log(tmp_path / "gyro.csv")
    r = run_in_process("calibrate", "bifilar", *BI, "--rates", str(log), "--columns",
            "t=Time,rate=ZGyro", "--time-unit", "ms", "--rate-unit", "deg/s", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["method"] == "bifilar-rate-fit" and isinstance(d["warnings"], list)
    assert abs(d["izz_kgm2"] - I_TRUE) < 3 * d["izz_sigma_kgm2"]
    assert d["details"]["offset"] == pytest.approx(0.03, abs=3e-3)  # the gyro bias, rad/s
    assert "1 rows with an empty cell skipped" in r.stderr
    text = run_in_process("calibrate", "bifilar", *BI, "--rates", str(log), "--columns",
               "t=Time,rate=ZGyro", "--time-unit", "ms", "--rate-unit", "deg/s")
    assert text.returncode == 0 and "gyro bias" in text.stdout
    assert "the model describes the trace" in text.stdout and "pendulum sway" in text.stdout


def test_trifilar_pixel_trace_scale_free_and_scaled(tpods_exe, tmp_path):
    log = _pixel_log(tmp_path / "spot.tsv")
    geo = ["calibrate", "trifilar", "--mass", "0.869", "--radius", "1.0", "--length", "0.995",
           "--trace", str(log), "--json"]
    free = json.loads(run_in_process(*geo, "--amplitude-max", "6").stdout)
    assert free["method"] == "trifilar-signal-fit" and "amplitude" in free["contributions_kgm2"]
    assert abs(free["izz_kgm2"] - 0.2358) < 3 * free["izz_sigma_kgm2"]
    assert "radius" in free["contributions_kgm2"] and free["inputs"]["radius_m"] == 1.0
    scaled = json.loads(run_in_process(*geo, "--trace-scale", str(1 / 800)).stdout)
    assert scaled["method"] == "trifilar-trace-fit" and "amplitude" not in scaled["contributions_kgm2"]
    assert abs(scaled["izz_kgm2"] - 0.2358) < 3 * scaled["izz_sigma_kgm2"]
    assert scaled["izz_sigma_kgm2"] < free["izz_sigma_kgm2"]
    assert not any("outside" in w for w in free["warnings"] + scaled["warnings"])


def test_trifilar_times_text(tpods_exe):
    r = run_in_process("calibrate", "trifilar", "--mass", "0.869", "--radius", "1.0", "--length",
            "0.995", "--times", "10.43,10.44,10.42", "--cycles", "10")
    assert r.returncode == 0 and r.stdout.startswith("Izz = ") and "[trifilar-times:" in r.stdout
    assert "radius" in r.stdout and r.stderr == ""


def test_bad_logs_one_line_exit_2(tpods_exe, tmp_path, capsys):
    text = tmp_path / "text.csv"
    text.write_text("t,rate\n" + "".join(f"{i * 0.01},{math.sin(i / 10)}\n" for i in range(50))
                    + "0.5,oops\n")
    short = tmp_path / "short.csv"
    short.write_text("t,rate\n0,1\n0.1,2\n")
    flat = tmp_path / "flat.csv"
    flat.write_text("t,rate\n" + "".join(f"{i * 0.01},{np.random.default_rng(i).normal():.4f}\n"
                                         for i in range(500)))
    cases = [
        (["--rates", str(tmp_path / "none.csv")], "file not found"),
        (["--rates", str(text)], "data row 52: not a number"),
        (["--rates", str(short)], "usable rows"),
        (["--rates", str(text), "--columns", "t=t,rate=gz"], "no column 'gz'"),
        (["--rates", str(text), "--columns", "speed=2"], "--columns"),
        (["--rates", str(flat)], "does not oscillate"),
        (["--times", "16,16.1", "--rate-unit", "deg/s"], "--rate-unit is for --rates"),
        (["--rates", str(text), "--trace-scale", "0.01"], "--trace-scale and --amplitude-max"),
        (["--rates", str(tmp_path)], "is a folder"),
    ]
    for extra, msg in cases:
        try:
            rc = main(["calibrate", "bifilar", *BI, *extra])
        except SystemExit as exc:
            rc = exc.code
        lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert rc == 2 and len(lines) == 1 and msg in lines[0], (extra, lines)
    r = run_in_process("calibrate", "trifilar", "--mass", "1", "--radius", "0.3", "--length",
            "1", "--trace", str(text))
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "not a number" in lines[0], r.stderr

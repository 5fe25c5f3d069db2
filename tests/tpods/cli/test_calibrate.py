"""`tpods calibrate mass|bifilar|combine` end to end (emulated balance on a pty)."""

import json
from pathlib import Path

import numpy as np
import pytest

from calibration.swing.bifilar import Pendulum, simulate_trace
from common.runfolder import write_run
from tests.support.cli import run_in_process
from tpods.cli import main

EXAMPLE = Path(__file__).resolve().parents[3] / "calibration" / "examples" / "truss_two_modules.toml"




def _json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_mass_from_values_and_file(capsys, tmp_path):
    d = _json(capsys, ["calibrate", "mass", "--values", "720.0,720.2,720.4", "--json"])
    assert d["mass_kg"] == pytest.approx(0.7202) and d["mass_sigma_kg"] == pytest.approx(1.447987e-3, rel=1e-5)
    f = tmp_path / "r.txt"
    f.write_text("720.0 g\n720.2\n 733.1 g ?\n720.4 g\n")
    d = _json(capsys, ["calibrate", "mass", "--readings-from", str(f), "--accuracy-g", "0.5",
                       "--json"])
    assert d["n_readings"] == 3 and d["skipped"] == 1
    assert d["u_typeB_kg"] == pytest.approx(0.5e-3 / np.sqrt(3))


def test_mass_from_emulated_scout_over_a_pty(tpods_exe):
    emu = pytest.importorskip("bench.emulators")
    scout = emu.EmulatedScout(None, load_g=812.5, lag_s=0.02, print_rate_hz=100, seed=3,
                              unstable_prob=0.2)
    srv = emu.serve_pty(scout)
    try:
        r = run_in_process("calibrate", "mass", "--scale", srv.path, "--readings", "6", "--json")
    finally:
        srv.stop()
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["n_readings"] == 6
    assert d["mass_kg"] == pytest.approx(0.8125, abs=3e-3)  # emulator noise 0.2 g plus drift
    assert d["std_kg"] < 2e-3


def test_bifilar_times_json(capsys):
    d = _json(capsys, ["calibrate", "bifilar", "--mass", "0.72", "--spacing", "0.1", "--length",
                       "1.0", "--times", "16.4,16.5,16.3", "--cycles", "10", "--json"])
    assert d["method"] == "eq19-times"
    T = np.mean([16.4, 16.5, 16.3]) / 10
    assert d["izz_kgm2"] == pytest.approx(0.72 * 9.80665 * 0.01 * T**2 / (16 * np.pi**2))
    c = d["contributions_kgm2"]
    assert max(c, key=c.get) == "spacing" and d["izz_sigma_kgm2"] > c["spacing"]


def test_bifilar_poses_with_plot_and_tare(capsys, tmp_path):
    p = Pendulum(0.72, 1.5e-3, 0.12, 0.9, c1=0.003, c2=0.01)
    t, psi = simulate_trace(p, duration_s=25, seed=8, yaw_offset_rad=-2.0)
    write_run(tmp_path / "swing", pose_t=t, pose=np.column_stack([0 * t, 0 * t, psi]))
    out = tmp_path / "out"
    d = _json(capsys, ["calibrate", "bifilar", "--mass", "0.72", "--spacing", "0.12", "--length",
                       "0.9", "--poses", str(tmp_path / "swing" / "poses.csv"), "--tare-izz",
                       "1e-4", "--json", "--out", str(out)])
    assert d["method"] == "bifilar-trace-fit"
    assert d["izz_kgm2"] == pytest.approx(1.5e-3 - 1e-4, rel=0.003)
    assert d["details"]["izz_small_angle_kgm2"] > 1.01 * 1.5e-3 - 1e-4
    assert (out / "fit.png").stat().st_size > 10_000 and (out / "result.json").exists()


def test_combine(capsys):
    d = _json(capsys, ["calibrate", "combine", str(EXAMPLE), "--json"])
    assert d["mass_kg"] == pytest.approx(1.985)
    d0 = _json(capsys, ["calibrate", "combine", str(EXAMPLE), "--about", "0.4,0", "--json"])
    assert d0["izz_kgm2"] == pytest.approx(d["izz_com_kgm2"] + d["mass_kg"] * 0.4**2)


def test_bad_input_one_line(tpods_exe, tmp_path, capsys):
    flat = tmp_path / "flat"
    t = np.arange(0, 20, 1 / 120)
    write_run(flat, pose_t=t, pose=np.column_stack([0 * t, 0 * t,
                                                    np.random.default_rng(0).normal(0, 0.02, t.size)]))
    bad_toml = tmp_path / "p.toml"
    bad_toml.write_text("[[part]]\nmass_kg = 1\nposition_m = [0, 0]\n")
    geo = ["--mass", "0.72", "--spacing", "0.1", "--length", "1.0"]
    cases = [
        (["calibrate", "bifilar", "--mass", "0.72", "--spacing", "0.1", "--length", "-1",
          "--times", "16,16.1"], "length"),
        (["calibrate", "bifilar", *geo, "--times", "16.4"], "at least 2 timings"),
        (["calibrate", "bifilar", *geo, "--times", "16,16.1", "--cycles", "0"], "cycles"),
        (["calibrate", "bifilar", *geo, "--poses", str(flat)], "does not oscillate"),
        (["calibrate", "bifilar", *geo, "--poses", str(tmp_path / "none.csv")], "not found"),
        (["calibrate", "mass", "--values", "720"], "at least 2"),
        (["calibrate", "mass", "--readings-from", str(tmp_path / "none.txt")], "not found"),
        (["calibrate", "combine", str(bad_toml)], "izz_kgm2 or shape"),
    ]
    for args, msg in cases[1:]:  # in-process (fast): the same handler main() runs
        try:
            rc = main(args)
        except SystemExit as exc:  # argparse's one-line errors
            rc = exc.code
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert rc == 2 and len(lines) == 1, (args, err)
        assert msg in lines[0], (args, err)
    # and once through the installed console script
    r = run_in_process(*cases[0][0])
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and cases[0][1] in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_bifilar_plausibility_warning_is_one_stderr_line_in_text_mode(tpods_exe):
    # --spacing typed in cm: the result is still printed, the warning goes to stderr
    r = run_in_process("calibrate", "bifilar", "--mass", "0.72", "--spacing", "10", "--length", "1.0",
            "--times", "20.1,20.2,20.0", "--cycles", "10")
    assert r.returncode == 0
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("tpods: warning:")]
    assert len(warn) == 1 and "spacing D = 10 m" in warn[0] and "cm or mm" in warn[0]
    assert r.stdout.startswith("Izz = ") and "warning" not in r.stdout


def test_bifilar_window_takes_both_syntaxes_and_refuses_a_reversed_one(tpods_exe, tmp_path):
    p = Pendulum(0.72, 1.5e-3, 0.12, 0.9, c1=0.003, c2=0.01)
    t, psi = simulate_trace(p, duration_s=30, seed=8)
    d = tmp_path / "swing"
    write_run(d, pose_t=t, pose=np.column_stack([0 * t, 0 * t, psi]))
    base = ("calibrate", "bifilar", "--poses", str(d / "poses.csv"), "--mass", "0.72",
            "--spacing", "0.12", "--length", "0.9", "--json")
    a, b = (run_in_process(*base, "--window", w) for w in ("2:25", "2,25"))
    assert a.returncode == b.returncode == 0, a.stderr + b.stderr
    assert json.loads(a.stdout)["izz_kgm2"] == json.loads(b.stdout)["izz_kgm2"]
    r = run_in_process(*base, "--window", "25,2")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "end must follow its start" in lines[0]

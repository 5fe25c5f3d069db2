import json

import numpy as np

from common.runfolder import read_run
from tests.support.cli import run


def test_help_on_every_level(tpods_exe):
    top = run(tpods_exe, "--help")
    assert top.returncode == 0 and "sim" in top.stdout
    for cmd in ("sim", "demo"):
        r = run(tpods_exe, cmd, "--help")
        assert r.returncode == 0 and "usage: tpods " + cmd in r.stdout


def test_sim_writes_a_valid_run(tpods_exe, tmp_path):
    out = tmp_path / "run"
    r = run(tpods_exe, "sim", "--input", "translate-rotate", "--duration", "14", "--mass", "0.72",
            "--izz", "0.002", "--friction", "0.1,0.001,0.002", "--drop", "0.05", "--seed", "4",
            "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout
    run_ = read_run(out)
    assert run_.truth["mass_kg"] == 0.72 and run_.truth["ct"] == 0.1
    assert run_.pose_t[-1] <= 14.0
    assert json.loads((out / "run.json").read_text())["settings"]["drop"] == 0.05
    # the recorded commands replay: sim from a commands.csv path
    out2 = tmp_path / "run2"
    r2 = run(tpods_exe, "sim", "--input", str(out / "commands.csv"), "--duration", "14",
             "--noise-pos", "0", "--noise-yaw-deg", "0", "--mass", "0.72", "--izz", "0.002",
             "--friction", "0.1,0.001,0.002", "--out", str(out2))
    assert r2.returncode == 0, r2.stderr
    np.testing.assert_allclose(read_run(out2).duty_pct, run_.duty_pct)


def test_user_errors_are_one_line(tpods_exe, tmp_path):
    cases = [
        ("sim", "--out", str(tmp_path / "x"), "--input", "no-such-input"),
        ("sim", "--out", str(tmp_path / "x"), "--mass", "-1"),
        ("sim", "--out", str(tmp_path / "x"), "--thrust-table", str(tmp_path / "none.toml")),
        ("sim", "--out", str(tmp_path / "x"), "--amplitude", "60"),
        ("sim",),
        ("no-such-command",),
    ]
    for args in cases:
        r = run(tpods_exe, *args)
        assert r.returncode == 2, (args, r.stderr)
        assert "Traceback" not in r.stderr
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "error" in lines[0], (args, r.stderr)


def test_a_negative_value_list_is_read_as_the_option_value(tmp_path):
    """argparse would take `-0.8e-3,0.6e-3` for an option; tpods glues it to its option."""
    from tpods.cli import _value_options, build_parser, glue_negative_values, main

    opts = _value_options(build_parser())
    assert "--tilt" in opts and "--json" not in opts
    assert glue_negative_values(["sim", "--tilt", "-0.8e-3,0.6e-3", "--json", "-x"], opts) == \
        ["sim", "--tilt=-0.8e-3,0.6e-3", "--json", "-x"]
    out = tmp_path / "run"
    assert main(["sim", "--duration", "2", "--tilt", "-0.8e-3,0.6e-3", "--out", str(out)]) == 0
    assert read_run(out).truth["ax"] == -0.8e-3 and read_run(out).truth["ay"] == 0.6e-3


def test_option_errors_use_the_documented_prefix(tpods_exe):
    """Every user error is one line `tpods: error: ...` (README), argparse's too."""
    for args, what in ((("sim", "--duration", "abc"), "--duration"),
                       (("estimate", "batch"), "RUN_DIR"),
                       (("no-such-command",), "no-such-command")):
        r = run(tpods_exe, *args)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 2 and len(lines) == 1, (args, r.stderr)
        assert lines[0].startswith("tpods: error: ") and what in lines[0], (args, r.stderr)
        assert "--help" in lines[0]

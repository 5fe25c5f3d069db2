"""``tpods import poses|commands --time-from``: true row times of a log whose time column is a
nominal counter, from its finite-difference velocities or an interval column; the poses and
commands of the same rows on one rebuilt clock; user errors one line, exit 2."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from mocap_bridge.exports.time_from import _digits, rebuild_time_base
from tests.support.cli import run_in_process
from tpods.cli import main

POSES = ["--columns", "t=time,x=x_m,y=y_m,yaw=yaw_rad", "--time-unit", "s"]
CMDS = ["--columns", "t=time,valves=valves", "--time-unit", "s", "--valves", "2"]
VEL = "vx=vx,x=x_m,vy=vy,y=y_m,wz=wz,yaw=yaw_rad"


def _log(n=60, seed=2) -> tuple[pd.DataFrame, np.ndarray]:
    """A log on a nominal 60 ms counter with 1/64 s-step true intervals and a rest stretch."""
    rng = np.random.default_rng(seed)
    dt = rng.choice([3 / 64, 4 / 64, 5 / 64], n - 1)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    x, y, yaw = 0.2 * t, 0.05 * np.sin(t), np.angle(np.exp(1j * (3.0 + 0.5 * t)))
    x[20:25], y[20:25], yaw[20:25] = x[20], y[20], yaw[20]
    d = np.column_stack([np.diff(x), np.diff(y), np.angle(np.exp(1j * np.diff(yaw)))])
    v = np.vstack([[0.0, 0.0, 0.0], d / dt[:, None]])
    df = pd.DataFrame({"time": np.arange(n) * 0.06, "x_m": x, "y_m": y, "yaw_rad": yaw, "vx": v[:, 0],
                       "vy": v[:, 1], "wz": v[:, 2], "dt_ms": np.concatenate([[0.0], dt * 1e3]),
                       "valves": [f"[{i % 2}, 1]" for i in range(n)]})
    return df, t


@pytest.fixture
def log(tmp_path):
    df, t = _log()
    f = tmp_path / "log.csv"
    df.to_csv(f, index=False, float_format="%.17g")
    return f, df, t


def _one_line_error(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tpods: error: "), err
    for n in needles:
        assert n in lines[0], lines[0]


def test_velocities_rebuild_the_true_times_and_the_commands_follow(log, tmp_path):
    f, df, t = log
    out = tmp_path / "run"
    p = run_in_process("import", "poses", str(f), "--out", str(out), *POSES, "--time-from", VEL,
                       "--time-from-units", "m,rad")
    assert p.returncode == 0, p.stderr
    assert "pose times rebuilt from the logged velocities (55 of 59 intervals; 4 filled with the median" in p.stdout
    assert "4 at rest" in p.stdout and "jitter far beyond" in p.stderr
    poses = pd.read_csv(out / "poses.csv")
    ok = np.ones(59, bool)
    ok[20:24] = False
    np.testing.assert_allclose(np.diff(poses.t)[ok], np.diff(t)[ok], atol=1e-11)
    p = run_in_process("import", "commands", str(f), "--out", str(out), *CMDS)
    assert p.returncode == 0, p.stderr
    assert "times mapped through" in p.stdout
    cmds = pd.read_csv(out / "commands.csv")
    np.testing.assert_allclose(cmds.t[:-1], poses.t, atol=1e-9)
    meta = json.loads((out / "run.json").read_text())
    assert meta["source"]["time_base"]["filled"] == {"at_rest": 4}
    assert meta["commands_source"]["time_base"]["mapped_through"] is True


def test_an_interval_column_and_the_same_option_on_the_commands(log, tmp_path):
    f, df, t = log
    out = tmp_path / "run"
    p = run_in_process("import", "commands", str(f), "--out", str(out), *CMDS, "--time-from", "dt=dt_ms",
                       "--time-unit", "s")
    _one_line_error(p.returncode, p.stderr, "--time-unit", "'s'")  # dt_ms says ms, --time-unit s
    cmds = ["--columns", "t=time,valves=valves", "--valves", "2", "--time-from", "dt=dt_ms"]
    df.rename(columns={"time": "time_s"}).to_csv(f, index=False, float_format="%.17g")
    cmds[1] = "t=time_s,valves=valves"
    p = run_in_process("import", "commands", str(f), "--out", str(out), *cmds)
    assert p.returncode == 0, p.stderr
    assert "rebuilt from the interval column (59 of 59 intervals)" in p.stdout
    p = run_in_process("import", "poses", str(f), "--out", str(out), "--columns",
                       "t=time_s,x=x_m,y=y_m,yaw=yaw_rad", "--time-from", "dt=dt_ms")
    assert p.returncode == 0, p.stderr
    poses = pd.read_csv(out / "poses.csv")
    np.testing.assert_allclose(poses.t, t, atol=1e-9)
    np.testing.assert_allclose(pd.read_csv(out / "commands.csv").t[:-1], t, atol=1e-9)


def test_bad_cells_are_counted_not_fatal(log):
    f, df, t = log
    text = f.read_text().splitlines()
    cells = text[10].split(",")
    cells[4] = "n/a"  # vx of row 10
    text[10] = ",".join(cells)
    tb = rebuild_time_base("\n".join(text), VEL, t_column="time", time_unit="s", units=("m", "rad"))
    assert tb.summary["bad_cells"] == 1
    assert tb.summary["determined"] == 55  # y and yaw still give row 10's interval


def test_written_digits():
    assert _digits("0.0125") == (4, 3) and _digits("1e-05") == (5, 1) and _digits("-2.50E+01") == (1, 3)
    assert _digits("12") == (0, 2) and _digits("abc") is None


@pytest.mark.parametrize("extra, needles", [
    (["--time-from", "vx=nope,x=x_m", "--time-from-units", "m,rad"], ["no column 'nope' (for vx)"]),
    (["--time-from", "vx=vx"], ["vx= needs x="]),
    (["--time-from", "dt=dt_ms,vx=vx,x=x_m"], ["give dt=COL alone"]),
    (["--time-from", "vx=zero,x=x_m", "--time-from-units", "m,rad"],
     ["column 'zero' (vx) is 0 in every row while 'x_m' moves"]),
    (["--time-from", "vx=vx,x=x_m,vy=vy,y=y_m,wz=vy,yaw=yaw_rad", "--time-from-units", "m,rad"],
     ["give different intervals", "not finite differences of these positions"]),
    (["--time-from", "vx=vx,x=pos"], ["the length unit of column 'pos' is not stated; give it with --time-from-units"]),
    (["--time-from-units", "m,rad"], ["--time-from-units: give --time-from too"]),
    (["--time-from", "vx=text,x=x_m", "--time-from-units", "m,rad"], ["column 'text' (vx) holds no number"]),
    (["--time-from", "q=vx"], ["--time-from: unknown key 'q'"]),
])
def test_user_errors_are_one_line(log, tmp_path, capsys, extra, needles):
    f, df, t = log
    df["zero"] = 0.0
    df["text"] = "x"
    df["pos"] = df.x_m
    df.to_csv(f, index=False, float_format="%.17g")
    code = main(["import", "poses", str(f), "--out", str(tmp_path / "o"), *POSES, *extra])
    err = capsys.readouterr().err
    _one_line_error(code, err, *needles)
    assert not (tmp_path / "o" / "poses.csv").exists()


def test_nominal_and_rebuilt_imports_are_not_mixed(log, tmp_path, capsys):
    f, df, t = log
    out = str(tmp_path / "run")
    assert main(["import", "commands", str(f), "--out", out, *CMDS]) == 0
    code = main(["import", "poses", str(f), "--out", out, *POSES, "--time-from", VEL, "--time-from-units", "m,rad"])
    _one_line_error(code, capsys.readouterr().err, "commands.csv was imported on the nominal times",
                    "import the commands again after the poses")
    out2 = str(tmp_path / "run2")
    assert main(["import", "poses", str(f), "--out", out2, *POSES]) == 0
    code = main(["import", "commands", str(f), "--out", out2, *CMDS, "--time-from", VEL, "--time-from-units", "m,rad"])
    _one_line_error(code, capsys.readouterr().err, "poses.csv was imported on the nominal times",
                    "import the poses again with the same --time-from")


def test_a_motive_export_needs_columns_for_time_from(tmp_path, capsys):
    from tests.tpods.cli.test_import import HMV

    code = main(["import", "poses", str(HMV), "--out", str(tmp_path / "o"), "--time-from", "dt=3"])
    _one_line_error(code, capsys.readouterr().err, "--time-from reads a plain CSV's columns")

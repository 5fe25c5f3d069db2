"""One rule for every door valve commands come through (common/command_rules.py): a run's
command columns match its vehicle, on/off valves are commanded in percent, and a refused
import leaves no folder behind. Several variants of each mistake, at each door: import,
estimate (read_run), play."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.command_rules import columns_problem, onoff_scale_problem
from tests.support.cli import run_in_process

ROOT = Path(__file__).resolve().parents[2]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"


def _log(tmp: Path, rows: list[list[float]], n: int = 8) -> Path:
    f = tmp / "log.csv"
    f.write_text("time," + ",".join(f"v{i}" for i in range(1, n + 1)) + "\n"
                 + "\n".join(",".join(f"{x:g}" for x in r) for r in rows) + "\n")
    return f


def _import(tmp: Path, log: Path, form: str, out: str = "R"):
    cols = ",".join(["t=time"] + [f"d{i}=v{i}" for i in range(1, 9)])
    return run_in_process("import", "commands", str(log), "--out", str(tmp / out), "--columns",
                          cols, "--vehicle", str(EIGHT), "--time-unit", "s", "--as", form)


@pytest.mark.parametrize("open_value", [1.0, 0.5, 1e-3])
def test_zero_one_states_as_percent_are_refused_at_import_and_leave_no_folder(tmp_path, open_value):
    rows = [[0.0] + [open_value if j == k % 8 else 0.0 for j in range(8)] for k in range(10)]
    for k, r in enumerate(rows):
        r[0] = 0.1 * k
    r = _import(tmp_path, _log(tmp_path, rows), "duty")
    assert r.returncode != 0 and "0/1 valve states read as percent" in r.stderr
    assert "--as columns" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "R").exists()


def test_zero_one_states_read_as_columns_are_fine(tmp_path):
    rows = [[0.1 * k] + [1.0 if j == k % 8 else 0.0 for j in range(8)] for k in range(10)]
    r = _import(tmp_path, _log(tmp_path, rows), "columns")
    assert r.returncode == 0, r.stderr
    d = np.loadtxt(tmp_path / "R" / "commands.csv", delimiter=",", skiprows=1)
    assert set(np.unique(d[:, 1:])) == {0.0, 100.0}


def test_pwm_duties_of_on_off_valves_are_not_mistaken_for_states():
    duty = np.array([[0, 30.0, 0], [55.0, 0, 0], [0, 0, 0]])
    assert onoff_scale_problem(duty, [0, 1, 2]) is None
    assert onoff_scale_problem(np.array([[0, 1.0], [1.0, 0]]), [0, 1]) is not None
    # a table valve's channel (not on/off) is not judged; a run that never opens one is fine
    assert onoff_scale_problem(np.array([[0, 1.0], [1.0, 0]]), [1]) is not None
    assert onoff_scale_problem(np.array([[0, 1.0], [0.0, 0]]), [0]) is None


@pytest.mark.parametrize("header, n, bad", [
    (["t", "d1", "d2", "d3", "d4", "d5"], 4, "d5"),
    (["t"] + [f"d{i}" for i in range(1, 11)], 8, "d9, d10"),
    (["t", "d1", "d2", "note", "d3", "d4", " d7 "], 4, "d7"),
])
def test_columns_beyond_the_vehicle_are_named(header, n, bad):
    p = columns_problem(header, n, "vehicle x")
    assert p is not None and p.startswith(f"column(s) {bad} beyond the {n} valves")
    assert columns_problem(["t", "d1", "d2", "d3", "d4", "note", "d"], 4, "m") is None


def _run_folder(tmp: Path, header_extra: int, scale: float) -> Path:
    from common.vehicle import Vehicle

    run = tmp / "run"
    run.mkdir()
    Vehicle.load(EIGHT).write(run)
    n = 8 + header_extra
    t = np.arange(0, 2.0, 0.1)
    duty = np.zeros((len(t), n))
    duty[np.arange(len(t)), np.arange(len(t)) % 8] = scale
    np.savetxt(run / "commands.csv", np.column_stack([t, duty]), delimiter=",", comments="",
               header="t," + ",".join(f"d{i}" for i in range(1, n + 1)), fmt="%.6g")
    np.savetxt(run / "poses.csv", np.column_stack([t, np.zeros((len(t), 3))]), delimiter=",",
               comments="", header="t,x,y,psi", fmt="%.6g")
    return run


@pytest.mark.parametrize("extra, scale, words", [
    (1, 100.0, "column(s) d9 beyond the 8 valves of vehicle"),
    (3, 100.0, "column(s) d9, d10, d11 beyond"),
    (0, 1.0, "0/1 valve states read as percent"),
])
def test_estimate_refuses_at_read(tmp_path, extra, scale, words):
    run = _run_folder(tmp_path, extra, scale)
    for argv in (["estimate", "batch", str(run)], ["estimate", "batch", str(run), "--segments", "auto"]):
        r = run_in_process(*argv)
        assert r.returncode != 0 and words in r.stderr, r.stderr
        assert "Traceback" not in r.stderr


def test_play_refuses_columns_beyond_the_module(tmp_path):
    f = tmp_path / "commands.csv"
    f.write_text("t,d1,d2,d3,d4,d5\n0,50,0,0,0,50\n1,0,0,0,0,0\n")
    r = run_in_process("run", "play", "--valves", "loop://", "--input", str(f))
    assert r.returncode != 0 and "column(s) d5 beyond the 4 valves of the TPODS module" in r.stderr

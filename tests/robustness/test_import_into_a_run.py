"""Imports into a folder that already holds a run: nothing of another run is kept beside
the new file, an origin of 0.0 is an origin, logs that do not overlap the poses are refused
in either order, and a refused import leaves no folder it created."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.support.cli import run_in_process

EIGHT = Path(__file__).resolve().parents[2] / "vehicles" / "example-8-onoff.toml"
POSE_COLS = "t=time,x=x,y=y,yaw=yaw"
CMD_COLS = "t=time," + ",".join(f"d{i}=v{i}" for i in range(1, 9))


def _poses(tmp: Path, t0: float, n: int = 40, name: str = "poses.csv") -> Path:
    f = tmp / name
    t = t0 + 0.05 * np.arange(n)
    np.savetxt(f, np.column_stack([t, 0.01 * t, 0 * t, 0 * t]), delimiter=",", comments="",
               header="time,x,y,yaw", fmt="%.6f")
    return f


def _valves(tmp: Path, t0: float, n: int = 20, name: str = "valves.csv") -> Path:
    f = tmp / name
    t = t0 + 0.1 * np.arange(n)
    duty = np.zeros((n, 8))
    duty[np.arange(n), np.arange(n) % 8] = 1
    np.savetxt(f, np.column_stack([t, duty]), delimiter=",", comments="",
               header="time," + ",".join(f"v{i}" for i in range(1, 9)), fmt="%.6g")
    return f


def _imp_poses(f: Path, out: Path, *extra: str):
    return run_in_process("import", "poses", str(f), "--out", str(out), "--columns", POSE_COLS,
                          "--units", "m,rad", "--time-unit", "s", *extra)


def _imp_cmds(f: Path, out: Path, *extra: str):
    return run_in_process("import", "commands", str(f), "--out", str(out), "--columns", CMD_COLS,
                          "--vehicle", str(EIGHT), "--time-unit", "s", "--as", "columns", *extra)


@pytest.mark.parametrize("pose_t0", [0.5, 2.0])
def test_an_origin_of_zero_is_an_origin(tmp_path, pose_t0):
    """The commands first, their first row at 0.0 s on the source clock: the poses keep their
    offset (an origin of 0.0 used to read as unset, and the poses took their own)."""
    out = tmp_path / "RUN"
    for r in (_imp_cmds(_valves(tmp_path, 0.0, n=40), out), _imp_poses(_poses(tmp_path, pose_t0), out)):
        assert r.returncode == 0, r.stderr
    meta = json.loads((out / "run.json").read_text())
    assert meta["time_origin_s"] == 0.0
    t_pose = np.loadtxt(out / "poses.csv", delimiter=",", skiprows=1)[:, 0]
    assert abs(t_pose[0] - pose_t0) < 1e-9


@pytest.mark.parametrize("pose_t0, cmd_t0, first", [
    (0.0, 100.0, "poses"), (100.0, 0.0, "poses"),
    (0.0, 100.0, "commands"), (100.0, 0.0, "commands"),
])
def test_logs_that_do_not_overlap_are_refused_in_either_order(tmp_path, pose_t0, cmd_t0, first):
    out = tmp_path / "RUN"
    p, c = _poses(tmp_path, pose_t0), _valves(tmp_path, cmd_t0)
    a, b = (_imp_poses(p, out), lambda: _imp_cmds(c, out)) if first == "poses" else \
        (_imp_cmds(c, out), lambda: _imp_poses(p, out))
    assert a.returncode == 0, a.stderr
    r = b()
    assert r.returncode != 0 and "do not overlap" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_force_into_a_simulated_run_is_refused_and_truth_never_kept(tmp_path):
    sim = tmp_path / "SIM"
    r = run_in_process("sim", "--vehicle", str(EIGHT), "--input", "pulses", "--duration", "4",
                       "--mass", "23", "--izz", "0.3", "--out", str(sim))
    assert r.returncode == 0, r.stderr
    r = _imp_poses(_poses(tmp_path, 0.0), sim, "--force")
    assert r.returncode != 0 and "belongs to a simulated run" in r.stderr
    assert (sim / "truth.csv").exists()  # refused: nothing touched


def test_force_reimport_drops_a_previous_truth(tmp_path):
    out = tmp_path / "RUN"
    assert _imp_poses(_poses(tmp_path, 0.0), out).returncode == 0
    meta = json.loads((out / "run.json").read_text())
    meta["truth"] = {"mass_kg": 2.0, "izz_kgm2": 0.01}
    (out / "run.json").write_text(json.dumps(meta))
    r = _imp_poses(_poses(tmp_path, 0.0, name="p2.csv"), out, "--force")
    assert r.returncode == 0, r.stderr
    assert "truth" not in json.loads((out / "run.json").read_text())
    assert "removed truth of the previous run" in r.stderr


@pytest.mark.parametrize("argv", [
    ["import", "poses", "missing.csv"],
    ["import", "commands", "missing.csv", "--columns", "t=t,d1=a", "--valves", "1"],
])
def test_a_refused_import_leaves_no_folder(tmp_path, argv):
    out = tmp_path / "NEW"
    r = run_in_process(*argv, "--out", str(out), cwd=tmp_path)
    assert r.returncode != 0
    assert not out.exists()


@pytest.mark.parametrize("sep", [";", "\t"])
def test_decimal_comma_logs_import(tmp_path, sep):
    """A spreadsheet of a decimal-comma locale: the header names its columns, numbers use the
    comma (it used to say "no column 'time'" while the header held it)."""
    p = tmp_path / "p.csv"
    t = 0.05 * np.arange(40)
    p.write_text(sep.join(["time", "x", "y", "yaw"]) + "\n" + "\n".join(
        sep.join(f"{v:.4f}".replace(".", ",") for v in (a, 0.01 * a, 0.0, 0.0)) for a in t) + "\n")
    r = _imp_poses(p, tmp_path / "RUN")
    assert r.returncode == 0, r.stderr
    got = np.loadtxt(tmp_path / "RUN" / "poses.csv", delimiter=",", skiprows=1)
    assert np.allclose(got[:, 0], t) and np.allclose(got[:, 1], 0.01 * t, atol=1e-6)

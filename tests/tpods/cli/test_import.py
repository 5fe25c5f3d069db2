"""``tpods import poses|commands`` as a user runs them (the installed console script).

Poses, then the commands of the same recording, into one run folder; the real excerpts of
runs/fixtures/real/ (their SOURCE.md cite them); user errors one line, exit 2.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

from common.thrust_table import ThrustTable
from tests.support.cli import run_in_process
from tpods.cli import main

ROOT = Path(__file__).resolve().parents[3]
AEVAR = ROOT / "runs/fixtures/real/aevarofjord-air-bearing"
HMV = ROOT / "runs/fixtures/real/hmv-s16-motive/sample_optitrack_take_excerpt.csv"
POSE_ARGS = ["--columns", "t=Control_Time,x=Telemetry_X_mm,y=Telemetry_Z_mm,yaw=Telemetry_Yaw_deg",
             "--time-unit", "s"]
CMD_ARGS = ["--columns", "t=Control_Time,valves=Command_Vector", "--time-unit", "s"]


def _one_line_error(p, *needles: str) -> None:
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tpods: error: "), p.stderr
    for n in needles:
        assert n in lines[0], lines[0]


def test_poses_then_commands_into_one_run_folder(tpods_exe, tmp_path):
    out = tmp_path / "aevar"
    csv = str(AEVAR / "real_test_data_excerpt.csv")
    p = run_in_process("import", "poses", csv, "--out", str(out), *POSE_ARGS)
    assert p.returncode == 0, p.stderr
    assert "417 poses over 24.960 s (generic-csv" in p.stdout
    p = run_in_process("import", "commands", csv, "--out", str(out), *CMD_ARGS,
            "--vehicle", str(AEVAR / "vehicle.toml"))
    assert p.returncode == 0, p.stderr
    assert "417 rows and an end row at 25.02 s (command-log/vector, 8 valves" in p.stdout
    assert sorted(f.name for f in out.iterdir()) == ["commands.csv", "poses.csv", "run.json", "vehicle.toml"]
    poses = pd.read_csv(out / "poses.csv")
    cmds = pd.read_csv(out / "commands.csv")
    assert list(poses.columns) == ["t", "x", "y", "psi"]
    assert list(cmds.columns) == ["t", *(f"d{i}" for i in range(1, 9))]
    assert poses.t.iloc[0] == 0.0 and cmds.t.iloc[0] == 0.0  # one origin: Control_Time 54.00 s
    assert set(cmds.iloc[:, 1:].to_numpy().ravel()) == {0.0, 100.0}
    meta = json.loads((out / "run.json").read_text())
    assert meta["kind"] == "import-poses"
    assert meta["time_origin_s"] == pytest.approx(54.0)
    assert meta["source"]["units"] == {"time": "s", "length": "mm", "angle": "deg"}
    assert meta["commands_source"]["thrusters"] == [f"T{i}" for i in range(1, 9)]
    assert meta["commands_counts"]["before_poses"] == 0
    assert (out / "vehicle.toml").read_bytes() == (AEVAR / "vehicle.toml").read_bytes()
    # a second import of the same file is refused without --force, replaced with it
    p = run_in_process("import", "commands", csv, "--out", str(out), *CMD_ARGS, "--valves", "8")
    _one_line_error(p, "commands.csv already exists; add --force")
    p = run_in_process("import", "commands", csv, "--out", str(out), *CMD_ARGS, "--valves", "8", "--force")
    assert p.returncode == 0, p.stderr
    assert not [f for f in out.parent.iterdir() if f.name.startswith(".")]  # no temporaries left


def test_commands_first_then_poses_share_the_commands_origin(tpods_exe, tmp_path):
    log = tmp_path / "log.csv"
    log.write_text("t_s,v\n10.0,\"[1, 0]\"\n10.5,\"[0, 1]\"\n11.0,\"[0, 0]\"\n")
    poses = tmp_path / "poses.csv"
    poses.write_text("t_s,x_m,y_m,yaw_rad\n9.9,0,0,0\n10.2,0.1,0,0\n10.7,0.2,0,0.1\n")
    out = tmp_path / "run"
    p = run_in_process("import", "commands", str(log), "--out", str(out), "--columns", "t=t_s,valves=v",
            "--valves", "2")
    assert p.returncode == 0, p.stderr
    p = run_in_process("import", "poses", str(poses), "--out", str(out), "--columns",
            "t=t_s,x=x_m,y=y_m,yaw=yaw_rad")
    assert p.returncode == 0, p.stderr
    assert "1 before the commands" in p.stdout
    t = pd.read_csv(out / "poses.csv").t.tolist()
    assert t == pytest.approx([0.2, 0.7])
    assert json.loads((out / "run.json").read_text())["counts"]["before_commands"] == 1


def test_a_motive_export_and_a_wrench_log(tpods_exe, tmp_path):
    out = tmp_path / "m"
    p = run_in_process("import", "poses", str(HMV), "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "40 poses over 0.325 s (motive-csv, body Rigid Body 1" in p.stdout
    w = tmp_path / "w.csv"
    w.write_text("time_s,Fx_N,Fy_N,Mz_Nm\n0,0.1,0,0\n0.1,0,0.1,0.001\n0.2,0,0,0\n")
    p = run_in_process("import", "commands", str(w), "--out", str(out), "--columns",
            "t=time_s,fx=Fx_N,fy=Fy_N,mz=Mz_Nm", "--frame", "lab")
    assert p.returncode == 0, p.stderr
    assert (out / "wrench.csv").read_text().splitlines()[0] == "t,fx,fy,mz"
    assert json.loads((out / "run.json").read_text())["wrench_frame"] == "lab"


@pytest.mark.parametrize("args, needles", [
    (["poses", "nope.csv", "--out", "{out}"], ["nope.csv: file not found"]),
    (["poses", "{aevar}", "--out", "{out}"], ["not a Vicon or Motive export", "--columns"]),
    (["poses", "{aevar}", "--out", "{out}", "--columns",
      "t=Control_Time,x=Telemetry_X_mm,y=Telemetry_Z_mm,yaw=Telemetry_Yaw_deg"],
     ["the time unit of column 'Control_Time' is not stated; give it with --time-unit"]),
    (["poses", "{aevar}", "--out", "{out}", "--columns", "t=Control_Time,x=Telemetry_X_mm,y=MPC_Status,"
      "yaw=Telemetry_Yaw_deg", "--time-unit", "s", "--units", "mm,deg"],
     ["line 2, column 22 (MPC_Status): 'OPTIMAL' is not a number"]),
    (["poses", "{hmv}", "--out", "{out}", "--plane", "xx"], ["--plane 'xx'"]),
    (["poses", "{hmv}", "--out", "{out}.json"], ["names a file; tpods import writes a run folder"]),
    (["commands", "{aevar}", "--out", "{out}", "--columns", "t=Control_Time,valves=Command_Vector",
      "--time-unit", "s"], ["give the valves: --vehicle FILE"]),
    (["commands", "{aevar}", "--out", "{out}", "--columns", "t=Control_Time,valves=Command_Vector",
      "--time-unit", "s", "--valves", "4"], ["8 valve states", "the vehicle has 4 valves"]),
    (["commands", "{aevar}", "--out", "{out}", "--columns", "t=Control_Time,valves=Command_Hex",
      "--time-unit", "s", "--valves", "8", "--as", "hex"], ["'0x01000000' sets bits beyond valve 8"]),
])
def test_user_errors_are_one_line(tmp_path, capsys, args, needles):
    fill = {"out": str(tmp_path / "o"), "aevar": str(AEVAR / "real_test_data_excerpt.csv"), "hmv": str(HMV)}
    code = main(["import", *[a.format(**fill) for a in args]])  # in-process: the same main() as tpods
    captured = capsys.readouterr()
    _one_line_error(SimpleNamespace(returncode=code, stderr=captured.err), *needles)
    assert not (tmp_path / "o" / "poses.csv").exists()


def test_a_vehicle_without_thrusters_is_refused(tpods_exe, tmp_path):
    v = tmp_path / "v.toml"
    v.write_text('[vehicle]\nname = "x"\n')
    p = run_in_process("import", "commands", str(AEVAR / "real_test_data_excerpt.csv"), "--out",
            str(tmp_path / "o"), *CMD_ARGS, "--vehicle", str(v))
    _one_line_error(p, "no thrusters")


def test_a_different_vehicle_file_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "vehicle.toml").write_text('[vehicle]\nname = "other"\n')
    v = tmp_path / "v.toml"
    v.write_text('[vehicle]\nname = "v"\n[[thrusters]]\nname = "A"\nposition_m = [0.1, 0]\n'
                 'direction = [0, 1]\nthrust_table = "tables/a.toml"\nsupply = "a"\n'
                 '[[thrusters]]\nname = "B"\nposition_m = [-0.1, 0]\ndirection = [0, -1]\n'
                 'force_n = 0.4\n')
    (tmp_path / "tables").mkdir()
    ThrustTable.default().save(tmp_path / "tables/a.toml")
    table_text = (tmp_path / "tables/a.toml").read_text()
    log = tmp_path / "log.csv"
    log.write_text("t_s,v\n0,\"[1, 0]\"\n1,\"[0, 1]\"\n")
    argv = ["import", "commands", str(log), "--out", str(out), "--columns", "t=t_s,valves=v", "--vehicle", str(v)]
    assert main(argv) == 2
    assert "vehicle.toml already exists; add --force" in capsys.readouterr().err
    assert not (out / "commands.csv").exists()
    assert main([*argv, "--force"]) == 0
    assert (out / "vehicle.toml").read_text() == v.read_text()
    assert (out / "tables/a.toml").read_text() == table_text  # the table it names, beside it
    meta = json.loads((out / "run.json").read_text())
    assert meta["commands_source"]["thrusters"] == ["A", "B"]

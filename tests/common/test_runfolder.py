import json

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import read_run, write_run


def _good(tmp_path):
    t = np.array([0.0, 1.0, 2.0])
    duty = np.array([[50, 50, 50, 50], [20, 0, 20, 0], [0, 0, 0, 0]], float)
    pt = np.linspace(0, 2, 5)
    pose = np.column_stack([pt, -pt, np.zeros_like(pt)])
    return write_run(tmp_path / "run", cmd_t=t, duty_pct=duty, pose_t=pt, pose=pose,
                     meta={"kind": "test"})


def test_round_trip(tmp_path):
    p = _good(tmp_path)
    r = read_run(p)
    assert r.duty_pct.shape == (3, 4) and r.pose.shape == (5, 3)
    assert r.meta == {"kind": "test"} and r.truth is None
    ct, th = r.thrust_profile()
    assert th.shape == (3, 4) and th[2].sum() == 0


def test_run_json_is_optional(tmp_path):
    p = _good(tmp_path)
    (p / "run.json").unlink()
    assert read_run(p).meta == {}


def test_thrusts_csv_wins(tmp_path):
    p = _good(tmp_path)
    (p / "thrusts.csv").write_text("t,T1,T2,T3,T4\n0,0.1,0.1,0,0\n2,0,0,0,0\n")
    t, th = read_run(p).thrust_profile()
    np.testing.assert_allclose(th[0], [0.1, 0.1, 0, 0])


def _expect(p, match):
    with pytest.raises(UserError, match=match) as ei:
        read_run(p)
    assert "\n" not in str(ei.value)
    return str(ei.value)


def test_missing_folder(tmp_path):
    _expect(tmp_path / "nope", "run folder not found")


def test_missing_file(tmp_path):
    p = _good(tmp_path)
    (p / "poses.csv").unlink()
    _expect(p, "poses.csv: file not found")


def test_missing_column(tmp_path):
    p = _good(tmp_path)
    (p / "poses.csv").write_text("t,x,y\n0,0,0\n1,0,0\n")
    _expect(p, r"poses.csv: missing column\(s\) psi")


def test_empty_file(tmp_path):
    p = _good(tmp_path)
    (p / "commands.csv").write_text("")
    _expect(p, "commands.csv: file is empty")
    (p / "commands.csv").write_text("t,d1,d2,d3,d4\n")
    _expect(p, "commands.csv: no data rows")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "abc", ""])
def test_non_finite_value(tmp_path, value):
    p = _good(tmp_path)
    (p / "poses.csv").write_text(f"t,x,y,psi\n0,0,0,0\n1,{value},0,0\n2,0,0,0\n")
    msg = _expect(p, "poses.csv: line 3: column x is not a finite number")
    assert "line 3" in msg


def test_non_increasing_time(tmp_path):
    p = _good(tmp_path)
    (p / "poses.csv").write_text("t,x,y,psi\n0,0,0,0\n1,0,0,0\n1,0,0,0\n")
    _expect(p, "poses.csv: line 4: time 1 does not increase")
    (p / "commands.csv").write_text("t,d1,d2,d3,d4\n0,0,0,0,0\n2,0,0,0,0\n1,0,0,0,0\n")
    _expect(p, "commands.csv: line 4: time 1 does not increase")


def test_poses_outside_commanded_span(tmp_path):
    p = _good(tmp_path)
    (p / "poses.csv").write_text("t,x,y,psi\n0,0,0,0\n1,0,0,0\n2.5,0,0,0\n")
    _expect(p, "poses.csv: line 4: pose time 2.5 s lies outside the commanded span")
    (p / "poses.csv").write_text("t,x,y,psi\n-0.5,0,0,0\n1,0,0,0\n")
    _expect(p, "line 2: pose time -0.5")


def test_duty_out_of_bounds(tmp_path):
    p = _good(tmp_path)
    (p / "commands.csv").write_text("t,d1,d2,d3,d4\n0,0,0,0,0\n1,120,0,0,0\n2,0,0,0,0\n")
    _expect(p, "commands.csv: line 3: duty outside")


def test_bad_run_json(tmp_path):
    p = _good(tmp_path)
    (p / "run.json").write_text("{not json")
    _expect(p, "run.json: not valid JSON")
    (p / "run.json").write_text(json.dumps([1, 2]))
    _expect(p, "run.json: must hold a JSON object")


def test_duty_outside_table_range_names_file(tmp_path):
    p = _good(tmp_path)
    (p / "commands.csv").write_text("t,d1,d2,d3,d4\n0,5,0,0,0\n2,0,0,0,0\n")
    r = read_run(p)
    with pytest.raises(UserError, match="commands.csv: duty 5 % is outside"):
        r.thrust_profile()

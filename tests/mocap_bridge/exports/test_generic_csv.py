"""Plain CSV poses through a column map and units (mocap_bridge/exports/generic_csv.py).

The first bytes are the real log's: AevarOfjord/mpc-air-bearing-satellite
Data/Real_Test/Test/real_test_data.csv at 44b2d08b15e301305bc23a6bbacae63899440252 (MIT),
header and step 0 verbatim (runs/fixtures/real/aevarofjord-air-bearing/SOURCE.md).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.errors import UserError
from mocap_bridge.exports import PoseOptions, detect_format, read_poses
from mocap_bridge.exports.generic_csv import parse_column_map, unit_in_name

AEVAR = (
    "Step,MPC_Start_Time,Control_Time,Actual_Time_Interval,CONTROL_DT,Telemetry_X_mm,Telemetry_Z_mm,"
    "Telemetry_Yaw_deg,Current_X,Current_Y,Current_Yaw,Current_VX,Current_VY,Current_Angular_Vel,Target_X,"
    "Target_Y,Target_Yaw,Error_X,Error_Y,Error_Yaw,MPC_Computation_Time,MPC_Status,MPC_Solver,"
    "MPC_Solver_Time_Limit,MPC_Solve_Time,MPC_Time_Limit_Exceeded,MPC_Fallback_Used,MPC_Objective,"
    "Command_Vector,Command_Hex,Command_Sent_Time,Total_MPC_Loop_Time,Timing_Violation\n"
    "0.0,0.0,0.0,0.06,0.06,2431.8463802337646,-293.34160685539246,-172.29430141922947,2.4318463802337646,"
    "-0.2933416068553924,-3.0071028421890933,0.0062131770194694,-0.0008425359631545,0.261371637295856,1.5,"
    "-0.3030219216653122,-1.6035014957989846,0.9318463802337646,0.0096803148099197,1.4036013463901087,"
    "0.0160000324249267,OPTIMAL,,,0.005002737045288,False,,,\"[1, 0, 1, 0, 1, 0, 1, 0]\",0x10101010,"
    "1.1400000000000006,0.0,False\n"
)
AEVAR_COLUMNS = "t=Control_Time,x=Telemetry_X_mm,y=Telemetry_Z_mm,yaw=Telemetry_Yaw_deg"


def _second_row(text: str) -> str:
    row = text.splitlines()[1].split(",")
    row[2] = "0.06"
    row[5] = "2432.0"
    return text + ",".join(row) + "\n"


def test_the_air_bearing_log_reads_with_its_units_from_the_names():
    text = _second_row(AEVAR)
    assert detect_format(text) == "generic"
    t = read_poses(text, PoseOptions(columns=AEVAR_COLUMNS, time_unit="s"), "real.csv")
    np.testing.assert_allclose(t.t_s, [0.0, 0.06])
    np.testing.assert_allclose(t.x_m, [2.4318463802337646, 2.432])
    np.testing.assert_allclose(t.y_m, -0.29334160685539246)
    assert t.psi_rad[0] == pytest.approx(math.radians(-172.29430141922947))
    assert t.source["units"] == {"time": "s", "length": "mm", "angle": "deg"}
    assert t.source["columns"] == {"t": "Control_Time", "x": "Telemetry_X_mm", "y": "Telemetry_Z_mm",
                                   "yaw": "Telemetry_Yaw_deg"}


def test_a_unit_no_name_states_must_be_given():
    with pytest.raises(UserError, match=r"the time unit of column 'Control_Time' is not stated; give it with --time-unit"):
        read_poses(AEVAR, PoseOptions(columns=AEVAR_COLUMNS), "real.csv")
    text = "time_ms,x,y,yaw\n0,1,2,3\n"
    with pytest.raises(UserError, match=r"the length unit of column 'x', 'y' is not stated; give it with --units"):
        read_poses(text, PoseOptions(columns="t=time_ms,x=x,y=y,yaw=yaw"), "p.csv")
    with pytest.raises(UserError, match=r"the angle unit of column 'yaw' is not stated"):
        read_poses(text, PoseOptions(columns="t=time_ms,x=x,y=y,yaw=yaw", units="m"), "p.csv")
    t = read_poses(text, PoseOptions(columns="t=time_ms,x=x,y=y,yaw=yaw", units="m,deg"), "p.csv")
    assert t.source["units"] == {"time": "ms", "length": "m", "angle": "deg"}


def test_a_given_unit_that_contradicts_a_name_is_refused():
    with pytest.raises(UserError, match=r"column 'Telemetry_X_mm' says length unit 'mm', --units says 'm'"):
        read_poses(AEVAR, PoseOptions(columns=AEVAR_COLUMNS, time_unit="s", units="m,deg"), "real.csv")
    with pytest.raises(UserError, match=r"unknown length unit 'ft'"):
        read_poses("t_s,x,y,yaw\n0,1,2,3\n", PoseOptions(columns="t=t_s,x=x,y=y,yaw=yaw", units="ft,deg"), "p.csv")


def test_columns_by_number_ms_time_plane_and_yaw_sign():
    text = "frame,a,b,c,h\n1000,1,2,3,10\n1020,1,2,4,20\n"
    t = read_poses(text, PoseOptions(columns="t=1,x=2,z=4,y=3,yaw=5", units="m,deg", time_unit="ms",
                                     plane="x-z", yaw_sign=-1.0), "p.csv")
    np.testing.assert_allclose(t.t_s, [0.0, 0.02])
    np.testing.assert_allclose(t.y_m, [-3.0, -4.0])
    np.testing.assert_allclose(np.degrees(t.psi_rad), [-10.0, -20.0])
    assert t.t0_source_s == pytest.approx(1.0)


def test_quaternion_columns_take_the_yaw_about_the_plane_normal():
    s, c = math.sin(math.radians(20)), math.cos(math.radians(20))  # 40 deg about +Y
    text = f"t_s,X_m,Y_m,Z_m,qx,qy,qz,qw\n0,1,0.5,2,0,{s},0,{c}\n"
    t = read_poses(text, PoseOptions(columns="t=t_s,x=X_m,y=Y_m,z=Z_m,qx=qx,qy=qy,qz=qz,qw=qw", plane="zx"), "q.csv")
    assert np.degrees(t.psi_rad[0]) == pytest.approx(40.0)
    assert (t.x_m[0], t.y_m[0]) == (2.0, 1.0)


def test_occluded_and_repeated_rows_are_counted():
    text = "t_s,x_m,y_m,yaw_rad\n0,1,2,0.1\n0.01,,,\n0.02,NaN,2,0.1\n0.02,1,2,0.1\n0.03,1,2,0.1\n0.03,1,2,0.1\n"
    t = read_poses(text, PoseOptions(columns="t=t_s,x=x_m,y=y_m,yaw=yaw_rad"), "p.csv")
    assert t.counts == {"frames": 6, "kept": 3, "occluded": 2, "repeated": 1}


@pytest.mark.parametrize("columns, text, message", [
    ("x=a,y=b,yaw=c", "a,b,c\n1,2,3\n", r"give the time column \(t=COL\)"),
    ("t=a,x=b,y=c", "a,b,c\n1,2,3\n", r"give the orientation"),
    ("t=a,x=b,yaw=c", "a,b,c\n1,2,3\n", r"the floor plane xy needs the y column"),
    ("t=a,x=b,y=nope,yaw=c", "a,b,c\n1,2,3\n", r"no column 'nope' \(for y\) in the header line"),
    ("t=a,x=b,y=c,yaw=d", "a,b,c,d\n1,2,3\n", r"line 2 has 3 cells; column 'd' is missing"),
    ("t=a,x=b,y=c,yaw=d", "a,b,c,d\n1,2,three,4\n", r"p.csv: line 2, column 3 \(c\): 'three' is not a number"),
    ("t=a,x=b,y=c,yaw=d", "a,b,c,d\n,2,3,4\n", r"line 2: the time cell \(a\) is empty"),
    ("t=a,x=b,y=c,yaw=d", "a,b,c,d\n1,2,3,inf\n", r"'inf' is not a finite number"),
    ("t=a,x=b,y=c,yaw=d,w=e", "a,b,c,d\n1,2,3,4\n", r"unknown key 'w'"),
    ("t=a,x", "a,b,c,d\n1,2,3,4\n", r"'x' is not KEY=COLUMN"),
    ("t=a,x=b,y=c,yaw=d", "", r"empty file"),
])
def test_bad_maps_and_cells_are_one_line(columns, text, message):
    with pytest.raises(UserError, match=message):
        read_poses(text, PoseOptions(columns=columns, units="m,rad", time_unit="s"), "p.csv")


def test_export_options_are_refused_with_columns():
    with pytest.raises(UserError, match=r"--body is for Vicon and Motive exports"):
        read_poses(AEVAR, PoseOptions(columns=AEVAR_COLUMNS, time_unit="s", body="sat"), "real.csv")


def test_a_plain_csv_without_columns_asks_for_them():
    with pytest.raises(UserError, match=r"not a Vicon or Motive export.*give the columns with --columns"):
        read_poses(AEVAR, PoseOptions(), "real.csv")


def test_unit_in_name():
    from mocap_bridge.exports.table import LENGTH_M, TIME_S
    assert unit_in_name("Telemetry_X_mm", LENGTH_M) == "mm"
    assert unit_in_name("Time (Seconds)", TIME_S) == "seconds"
    assert unit_in_name("Control_Time", TIME_S) is None
    assert parse_column_map(" t = a , x=b ", ("t", "x")) == {"t": "a", "x": "b"}

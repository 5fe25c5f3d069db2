"""Vicon Tracker and Nexus CSV exports, as the bytes their makers write.

No licensed real Vicon export was found, so the bytes are built from what Vicon documents
and what other people's readers expect, cited beside each (a real Tracker 3 export without
a licence, [QBI], is read by tests/regression/test_real_vicon_tracker.py when you have it):

- [T41] Vicon Tracker 4.1 help, "Exporting data to CSV"
  (https://vicon-help.atlassian.net/wiki/spaces/Tracker41/pages/14320223/Exporting+data+to+CSV):
  the graph plots export, one file per frame rate, Frame and Sub Frame columns.
- [AG6] AG6GR/Vicon_CSV, import_vicon_csv.py at 054ba842da77c9efd3bbf3839ed4256f343a8107
  (a Blender importer for Tracker CSV exports): skips two lines (the ``Objects`` line and
  the rate), reads the object names from ``Global Angle <name>`` cells every 6 columns from
  the third, skips the column and units rows, then per object RX, RY, RZ in radians and
  TX, TY, TZ in mm (divided by 1000); a row with fewer than 8 cells has no data.
- [I24] issue 24: the header rows ``Objects``, the rate, ``Global Angle <subject>:<segment>``
  (and ``Global Position``), ``Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ``, units ``rad ... mm``.
- [NEX] a Nexus "Segments" export as a test generator writes it (stored code index, file id
  21244866227; the index does not name its repository): ``Segments``, ``200``,
  ``,,Subject01:Head,,,,,,Subject01:Head_End,...``, ``Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,...``,
  ``,,deg,deg,deg,mm,mm,mm,...``; a reader of it (file id 52673614714) documents the same
  five lines.
- [KON] Universitaet Konstanz CCU wiki, "Vicon: Data format documentation": a Tracker
  ``Trajectories`` export (marker X, Y, Z only; ``;`` as separator in that locale).
- [QBI] uncobruce/viconplotter, vicon_data/QBii_Square_2m_cw.csv at cd30bc51b1fd4e0cb8d53a200ab22f9b74bcac90
  (a ground robot driven round a 2 m square, exported by Vicon Tracker 3; the repository
  states no licence, so none of its bytes are here): UTF-8 with a byte-order mark, CRLF,
  an empty last line; ``Objects``, ``100``, ``,,Global Angle QBii:QBii,,,,,,`` (one name
  cell for the object's six columns, no ``Global Position`` cell),
  ``Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ``, ``,,rad,rad,rad,mm,mm,mm``; the angles are helical
  and undeclared: after the robot's fourth quarter turn the rotation vector's length is
  near 2 pi with its axis in the floor plane (RX, RY, RZ = -5.80, -2.33, -0.44 rad), a
  level body as helical and a 136 deg tilt as Euler XYZ.
- [QUA] a reader of Tracker exports with quaternions (stored code index, file id
  34625983598): ``Objects``, ``100``, ``,,Global Angle (Quaternion) ...``,
  ``Frame,Sub Frame,TX,TY,TZ,RX,RY,RZ,RW``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.errors import UserError
from mocap_bridge.exports import PoseOptions, detect_format, read_poses
from mocap_bridge.exports.table import FloorPlane
from mocap_bridge.exports.vicon_csv import read_vicon_csv

# [I24] [AG6]: Tracker's Objects export, two objects, CRLF (a Windows program), frame 4 of
# tpods1 occluded (empty cells, [AG6]).
TRACKER = (
    "Objects\r\n"
    "100\r\n"
    ",,Global Angle tpods1:tpods1,,,Global Position tpods1:tpods1,,,Global Angle truss:truss,,,Global Position truss:truss,,\r\n"
    "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,RX,RY,RZ,TX,TY,TZ\r\n"
    ",,rad,rad,rad,mm,mm,mm,rad,rad,rad,mm,mm,mm\r\n"
    "1,0,0,0,0.1,100,200,50,0,0,-1.5,1000,-500,80\r\n"
    "2,0,0,0,0.2,101,202,50,0,0,-1.5,1000,-500,80\r\n"
    "3,0,0,0,0.3,102,204,50,0,0,-1.5,1000,-500,80\r\n"
    "4,0,,,,,,,0,0,-1.5,1000,-500,80\r\n"
    "5,0,0,0,3.1,104,208,50,0,0,-1.5,1000,-500,80\r\n"
)


def test_tracker_objects_export_is_detected_and_read():
    assert detect_format(TRACKER) == "vicon"
    t = read_poses(TRACKER, PoseOptions(body="tpods1"), "tracker.csv")
    np.testing.assert_allclose(t.t_s, [0.0, 0.01, 0.02, 0.04])
    np.testing.assert_allclose(t.x_m, [0.100, 0.101, 0.102, 0.104])
    np.testing.assert_allclose(t.y_m, [0.200, 0.202, 0.204, 0.208])
    np.testing.assert_allclose(t.psi_rad, [0.1, 0.2, 0.3, 3.1])
    assert t.counts == {"frames": 5, "kept": 4, "occluded": 1, "repeated": 0}
    assert t.source["format"] == "vicon-tracker-csv"
    assert t.source["body"] == "tpods1:tpods1"
    assert t.source["rate_hz"] == 100.0
    assert t.source["units"] == {"length": "mm", "angle": "rad"}
    assert t.source["axes"] == {"plane": "xy", "x": "X", "y": "Y", "normal": "+Z"}
    assert t.t0_source_s == pytest.approx(0.01)


def test_the_other_object_by_its_segment_name():
    t = read_poses(TRACKER, PoseOptions(body="truss"), "tracker.csv")
    assert t.counts["kept"] == 5
    np.testing.assert_allclose(t.x_m, 1.0)
    np.testing.assert_allclose(t.psi_rad, -1.5)


def test_two_objects_without_body_is_one_line_naming_them():
    with pytest.raises(UserError, match=r"2 bodies \(tpods1:tpods1, truss:truss\); choose one with --body"):
        read_poses(TRACKER, PoseOptions(), "tracker.csv")
    with pytest.raises(UserError, match=r"--body nope: tracker.csv has no body of that name"):
        read_poses(TRACKER, PoseOptions(body="nope"), "tracker.csv")


# [I24] with Global Angle only (as [AG6] reads it: the name once per 6 columns).
TRACKER_ANGLE_ONLY = (
    "Objects\n100\n"
    ",,Global Angle sat:sat,,,,,\n"
    "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n"
    ",,rad,rad,rad,mm,mm,mm\n"
    "10,0,0,0,-0.5,1.5,2.5,0\n"
    "11,0,0,0,-0.6,1.6,2.6,0\n"
)


def test_a_name_cell_names_the_columns_to_its_right():
    t = read_poses(TRACKER_ANGLE_ONLY, PoseOptions(), "a.csv")
    np.testing.assert_allclose(t.x_m, [0.0015, 0.0016])
    np.testing.assert_allclose(t.psi_rad, [-0.5, -0.6])
    assert t.source["body"] == "sat:sat"


# [NEX]: a Nexus export with a Devices section before the Segments, degrees.
NEXUS = (
    "Devices\n1000\n,,Force Plate,,\nFrame,Sub Frame,Fx,Fy,Fz\n,,N,N,N\n1,0,0,0,0\n1,1,0,0,0\n\n"
    "Segments\n200\n"
    ",,Subject01:Root,,,,,,Subject01:Head,,,,,\n"
    "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,RX,RY,RZ,TX,TY,TZ\n"
    ",,deg,deg,deg,mm,mm,mm,deg,deg,deg,mm,mm,mm\n"
    "1,0,0,0,90,10,20,0,0,0,0,0,0,0\n"
    "2,0,0,0,-179,11,21,0,0,0,0,0,0,0\n"
    "\n"
    "Trajectories\n200\n,,Subject01:M1,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n1,0,1,2,3\n"
)


def test_nexus_segments_section_among_others():
    assert detect_format(NEXUS) == "vicon"
    t = read_poses(NEXUS, PoseOptions(body="Root"), "nexus.csv")
    assert t.source["format"] == "vicon-nexus-csv"
    assert t.source["section"] == "Segments"
    np.testing.assert_allclose(t.t_s, [0.0, 0.005])
    np.testing.assert_allclose(t.x_m, [0.010, 0.011])
    np.testing.assert_allclose(np.degrees(t.psi_rad), [90.0, -179.0])


def test_trajectories_only_is_refused_with_the_reason():
    # [KON]: marker trajectories, ';' separated
    text = "Trajectories;;;;;;;\n100;;;;;;;\n;;1 1936;;;1 1937;;\nFrame;Sub Frame;X;Y;Z;X;Y;Z\n;;mm;mm;mm;mm;mm;mm\n1;0;-391.888;-6180.01;1734.43;-378.647;-6190.14;1713.82\n"
    assert detect_format(text) == "vicon"
    with pytest.raises(UserError, match=r"Trajectories but no Objects or Segments section: marker trajectories hold no orientation"):
        read_poses(text, PoseOptions(), "traj.csv")


def test_quaternion_objects_export():
    # [QUA]: translation first, then RX, RY, RZ, RW; a quarter turn about +Z
    s = math.sqrt(0.5)
    text = ("Objects\n100\n,,Global Angle (Quaternion) b:b,,,,Global Position b:b,,,\n"
            "Frame,Sub Frame,TX,TY,TZ,RX,RY,RZ,RW\n,,mm,mm,mm,,,,\n"
            f"1,0,5,6,7,0,0,{s},{s}\n2,0,5,6,7,0,0,0,1\n")
    t = read_poses(text, PoseOptions(), "q.csv")
    np.testing.assert_allclose(t.psi_rad, [math.pi / 2, 0.0], atol=1e-12)
    assert t.source["units"]["angle"] == "quaternion"


def _tilted(rotation_cells: str) -> str:
    return ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n"
            f",,rad,rad,rad,mm,mm,mm\n1,0,{rotation_cells},0,0,0\n")


def test_undeclared_euler_or_helical_is_accepted_level_and_asked_tilted():
    t = read_poses(_tilted("0,0,1.2"), PoseOptions(), "level.csv")
    assert t.psi_rad[0] == pytest.approx(1.2)
    assert "euler-xyz = helical" in t.source["rotation"]
    with pytest.raises(UserError, match=r"euler-xyz or helical.*give --rotation euler-xyz\|helical"):
        read_poses(_tilted("0.4,0.3,1.2"), PoseOptions(), "tilted.csv")
    e = read_poses(_tilted("0.4,0.3,1.2"), PoseOptions(rotation="euler-xyz"), "tilted.csv")
    h = read_poses(_tilted("0.4,0.3,1.2"), PoseOptions(rotation="helical"), "tilted.csv")
    assert e.psi_rad[0] != pytest.approx(h.psi_rad[0], abs=1e-3)
    assert e.source["rotation"] == "euler-xyz (given)"


def test_a_declared_rotation_kind_is_used():
    text = _tilted("0.4,0.3,1.2").replace("Global Angle b:b", "Global Angle (Helical) b:b")
    h = read_poses(text, PoseOptions(), "h.csv")
    assert h.psi_rad[0] == pytest.approx(read_poses(_tilted("0.4,0.3,1.2"), PoseOptions(rotation="helical"), "t").psi_rad[0])
    assert h.source["rotation"] == "helical (named in the header)"


def test_euler_xyz_yaw_is_the_heading_of_the_body_x_axis():
    # R = Rx(0.4) Ry(0.3) Rz(1.2): the body x axis is R[:, 0]
    from mocap_bridge.exports.table import euler_matrices
    r = euler_matrices(np.array([[0.4, 0.3, 1.2]]), "xyz")[0]
    t = read_poses(_tilted("0.4,0.3,1.2"), PoseOptions(rotation="euler-xyz"), "tilted.csv")
    assert t.psi_rad[0] == pytest.approx(math.atan2(r[1, 0], r[0, 0]))


@pytest.mark.parametrize("text, message", [
    ("Objects\n100\n,,Global Angle b:b,,,,,\n", r"the Objects header is cut short"),
    ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY\n,,rad,rad,rad,mm,mm\n1,0,0,0,0,0,0\n",
     r"body b:b has no column TZ"),
    ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n,,rad,rad,rad,mm,mm,mm\n"
     "1,0,0,0,0,1,2,3\n2,0,0,0,0,1,x2,3\n", r"bad.csv: line 7, column 7 \(TY\): 'x2' is not a number"),
    ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n,,rad,rad,rad,inch,inch,inch\n"
     "1,0,0,0,0,1,2,3\n", r"unknown length unit 'inch'"),
    ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n1,0,0,0,0,1,2,3\n",
     r"no units row under the column row \(line 5\); give the units with --units"),
    ("Objects\nfast\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n,,rad,rad,rad,mm,mm,mm\n",
     r"line 2: the frame rate 'fast' is not a number"),
    ("Objects\n0\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n,,rad,rad,rad,mm,mm,mm\n",
     r"line 2: the frame rate 0 Hz is not positive"),
    ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n,,rad,rad,rad,mm,mm,mm\n1,0,,,,,,\n",
     r"no frame with a pose \(1 data rows, 1 occluded\)"),
    ("Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n,,rad,rad,rad,mm,mm,mm\n"
     "2,0,0,0,0,1,2,3\n1,0,0,0,0,1,2,3\n", r"time goes back at kept frame 2"),
])
def test_damaged_exports_are_one_line_naming_the_place(text, message):
    with pytest.raises(UserError, match=message):
        read_vicon_csv(text, what="bad.csv")


def test_units_row_and_given_units():
    no_units = "Objects\n100\n,,Global Angle b:b,,,,,\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n1,0,0,0,90,1000,0,0\n"
    t = read_vicon_csv(no_units, units=("mm", "deg"))
    assert t.x_m[0] == pytest.approx(1.0)
    assert t.psi_rad[0] == pytest.approx(math.pi / 2)
    with pytest.raises(UserError, match=r"says length unit 'mm', --units says 'm'"):
        read_vicon_csv(TRACKER, body="tpods1", units=("m", None))


def test_plane_and_yaw_sign_for_a_y_up_vicon():
    t = read_vicon_csv(TRACKER, body="tpods1", plane=FloorPlane.parse("x-z"))
    np.testing.assert_allclose(t.y_m, -0.050)
    t2 = read_poses(TRACKER, PoseOptions(body="tpods1", yaw_sign=-1.0), "t.csv")
    np.testing.assert_allclose(t2.psi_rad, [-0.1, -0.2, -0.3, -3.1])
    assert t2.source["yaw_sign"] == -1.0


def _near_two_pi(w: np.ndarray) -> str:
    """Helical cells of the small rotation ``w`` (rad) written as Tracker writes it after a
    full turn [QBI]: length 2 pi - |w| about the opposite axis (the same rotation)."""
    n = float(np.linalg.norm(w))
    return ",".join(f"{c:.6f}" for c in -(2 * math.pi - n) * w / n)


def test_a_level_body_past_a_full_turn_is_read_as_helical():
    # [QBI]'s layout; the rows are ours: a quarter turn, then a full turn plus a 0.9 deg
    # tilt and 0.46 deg of yaw, whose helical vector is near 2 pi with its axis mostly in
    # the floor plane
    w = np.array([0.015, 0.006, 0.008])
    text = ("\ufeffObjects\r\n100\r\n,,Global Angle QBii:QBii,,,,,,\r\n"
            "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ\r\n,,rad,rad,rad,mm,mm,mm\r\n"
            "1,0,0.010000,0.004000,-1.570796,-995.182861,-99.083923,167.123489\r\n"
            f"2,0,{_near_two_pi(w)},-998.507019,138.898529,170.335892\r\n\r\n")
    assert detect_format(text) == "vicon"
    t = read_poses(text, PoseOptions(), "QBii_Square_2m_cw.csv")
    assert t.source["format"] == "vicon-tracker-csv" and t.source["body"] == "QBii:QBii"
    assert t.source["rotation"].startswith("helical (undeclared; the only reading that keeps "
                                           "the body level")
    want = read_poses(text, PoseOptions(rotation="helical"), "h.csv").psi_rad
    np.testing.assert_allclose(t.psi_rad, want)
    assert t.psi_rad[1] == pytest.approx(0.008, abs=2e-4)  # ~ the small rotation's yaw
    np.testing.assert_allclose(t.x_m, [-0.995182861, -0.998507019])
    # a body tilted under both readings is still a question, never a guess
    with pytest.raises(UserError, match="give --rotation"):
        read_poses(text.replace("0.010000,0.004000,-1.570796", "0.4,0.3,1.2"), PoseOptions(), "x.csv")

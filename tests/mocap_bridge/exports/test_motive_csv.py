"""OptiTrack Motive CSV exports, as Motive writes them.

- [HMV] a real Motive 1.21 export: cmuphyscomp/hmv-s16
  python/rhinoscripts/sample_optitrack_take.csv at 7863c66ed645b463b72aef98a5c484a18cc9f396
  (BSD-3-Clause); its first 47 lines are runs/fixtures/real/hmv-s16-motive/ (SOURCE.md there).
- [OPT] OptiTrack, "Data Export: CSV" (https://docs.optitrack.com/motive/data-export/data-export-csv):
  the export options (units, axis convention, rotation type: quaternion or Euler orders).
- [123] the 1.23 layout as a reader of Motive exports documents it (stored code index, file id
  54993264671; the index does not name its repository): line 0 ``Format Version,1.23,...``,
  1 blank, 2 ``,Type,Rigid Body,...``, 3 ``,Name,<body>,...``, 4 ``,ID,<guid>,...``,
  5 ``,,Rotation,Rotation,Position,...``, 6 ``Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,...``.
- [125] the 1.25 layout in another project's test fixture (file id 55171076002): header keys
  ``Take Notes`` and ``Length Units,Millimeters``, and a ``,Parent,...`` row after ``,ID,...``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.errors import UserError
from mocap_bridge.exports import PoseOptions, detect_format, read_poses
from mocap_bridge.exports.motive_csv import read_motive_csv
from mocap_bridge.exports.table import FloorPlane

ROOT = Path(__file__).resolve().parents[3]
HMV = ROOT / "runs/fixtures/real/hmv-s16-motive/sample_optitrack_take_excerpt.csv"


def test_the_real_1_21_export():
    # [HMV]: bytes as Motive wrote them (CRLF, a quoted GUID row, trailing empty cells)
    raw = HMV.read_bytes()
    assert raw.startswith(b"Format Version,1.21,Take Name,Take 2016-01-05 03.49.50 PM,")
    assert b"\r\n" in raw
    text = raw.decode("utf-8")
    assert detect_format(text) == "motive"
    t = read_poses(text, PoseOptions(), "take.csv")
    assert t.counts == {"frames": 40, "kept": 40, "occluded": 0, "repeated": 0}
    assert t.source["body"] == "Rigid Body 1"
    assert t.source["format_version"] == "1.21"
    assert t.source["rate_hz"] == 120.0
    assert t.source["units"] == {"length": "Meters", "angle": "quaternion"}
    assert t.source["axes"] == {"plane": "x-z", "x": "X", "y": "-Z", "normal": "+Y"}
    np.testing.assert_allclose(t.t_s[:3], [0.0, 0.008333, 0.016667])
    assert t.t_s[-1] == pytest.approx(0.325)
    # frame 0: position 0.060002, 0.019150, 0.076611; quaternion ~(0, 0, 0, -1)
    assert t.x_m[0] == pytest.approx(0.060002)
    assert t.y_m[0] == pytest.approx(-0.076611)
    assert abs(t.psi_rad).max() < 1e-3


def test_the_real_export_in_the_source_frame_of_a_z_forward_lab():
    t = read_poses(HMV.read_text(), PoseOptions(plane="zx"), "take.csv")
    assert t.x_m[0] == pytest.approx(0.076611)
    assert t.y_m[0] == pytest.approx(0.060002)


def _motive_123(rows: str, *, rot: str = "Quaternion", units: str = "Millimeters", parent: bool = False) -> str:
    # [123] [125]: labelled header rows, "Time (Seconds)"
    quat = rot == "Quaternion"
    n = 8 if quat else 7
    head = ",,Rotation,Rotation,Rotation," + ("Rotation," if quat else "") + "Position,Position,Position,Mean Marker Error"
    axes = "Frame,Time (Seconds),X,Y,Z," + ("W," if quat else "") + "X,Y,Z,"
    return (f"Format Version,1.23,Take Name,Take 1,Take Notes,,Capture Frame Rate,240.000000,"
            f"Export Frame Rate,240.000000,Capture Start Time,2024-01-01 10.00.00.000 AM,"
            f"Capture Start Frame,0,Total Frames in Take,3,Total Exported Frames,3,Rotation Type,{rot},"
            f"Length Units,{units},Coordinate Space,Global\n\n"
            ",Type," + ",".join(["Rigid Body"] * n) + "\n"
            ",Name," + ",".join(["sat"] * n) + "\n"
            ",ID," + ",".join(["1"] * n) + "\n"
            + (",Parent," + ",".join([""] * n) + "\n" if parent else "")
            + head + "\n" + axes + "\n" + rows)


def test_a_1_23_export_with_an_occluded_frame():
    s = math.sin(math.radians(15)), math.cos(math.radians(15))  # 30 deg about +Y
    text = _motive_123(f"0,0.000000,0,{s[0]},0,{s[1]},100,50,-200,0.0001\n"
                       "1,0.004167,,,,,,,,\n"
                       f"2,0.008333,0,{s[0]},0,{s[1]},101,50,-201,0.0001\n", parent=True)
    t = read_poses(text, PoseOptions(), "m123.csv")
    assert t.counts == {"frames": 3, "kept": 2, "occluded": 1, "repeated": 0}
    np.testing.assert_allclose(t.x_m, [0.100, 0.101])
    np.testing.assert_allclose(t.y_m, [0.200, 0.201])  # table y = -Motive Z
    np.testing.assert_allclose(np.degrees(t.psi_rad), [30.0, 30.0])  # counter-clockwise about +Y
    assert t.source["rate_hz"] == 240.0
    # the same turn in the zx plane (x = Z, y = X: normal +Y too) reads the same yaw
    t2 = read_poses(text, PoseOptions(plane="zx"), "m123.csv")
    np.testing.assert_allclose(np.degrees(t2.psi_rad), [30.0, 30.0])
    # and with the normal down (xz: normal -Y) the other way
    t3 = read_poses(text, PoseOptions(plane="xz"), "m123.csv")
    np.testing.assert_allclose(np.degrees(t3.psi_rad), [-30.0, -30.0])


def test_an_euler_export_level_and_tilted():
    # [OPT]: Rotation Type XYZ, degrees
    text = _motive_123("0,0.0,0,45,0,10,0,0,0.0001\n", rot="XYZ", units="Meters")
    t = read_poses(text, PoseOptions(), "e.csv")
    assert np.degrees(t.psi_rad[0]) == pytest.approx(45.0)
    assert t.source["rotation_type"] == "XYZ"
    tilted = _motive_123("0,0.0,20,45,10,10,0,0,0.0001\n", rot="XYZ", units="Meters")
    with pytest.raises(UserError, match=r"intrinsic or extrinsic.*give --rotation intrinsic\|extrinsic"):
        read_poses(tilted, PoseOptions(), "e.csv")
    assert read_poses(tilted, PoseOptions(rotation="intrinsic"), "e.csv").counts["kept"] == 1


@pytest.mark.parametrize("text, message", [
    ("Format Version,1.21,Rotation Type,Quaternion,Length Units,Meters\n\n,,Rigid Body\n",
     r"the header is cut short: no 'Frame,Time,...' column row"),
    ("Format Version,1.21,Length Units,Meters\n\nFrame,Time,X\n0,0,1\n",
     r"the header is cut short above line 3"),
    ("Format Version,1.21,Rotation Type,Quaternion,Length Units,Meters\n\n,,Rigid Body,Rigid Body,Rigid Body\n"
     ",,b,b,b\n,,Rotation,Rotation,Position\nFrame,Time,X,Y,X\n", r"rigid body b has no column Position Y"),
    ("Format Version,1.21,Rotation Type,Quaternion,Length Units,Meters\n\n,,Marker,Marker,Marker\n"
     ",,m1,m1,m1\n,,Position,Position,Position\nFrame,Time,X,Y,Z\n", r"no Rigid Body columns \(only Marker\)"),
    ("Format Version,1.21,Rotation Type,Quaternion,Length Units,Furlongs\n\n"
     ",,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body\n"
     ",,b,b,b,b,b,b,b\n,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position\n"
     "Frame,Time,X,Y,Z,W,X,Y,Z\n0,0,0,0,0,1,0,0,0\n", r"unknown length unit 'Furlongs'"),
    ("Format Version,1.21,Rotation Type,Quaternion\n\n"
     ",,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body\n"
     ",,b,b,b,b,b,b,b\n,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position\n"
     "Frame,Time,X,Y,Z,W,X,Y,Z\n0,0,0,0,0,1,0,0,0\n", r"line 1 has no Length Units; give the unit with --units"),
    ("Format Version,1.21,Rotation Type,Quaternion,Length Units,Meters\n\n"
     ",,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body\n"
     ",,b,b,b,b,b,b,b\n,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position\n"
     "Frame,Time,X,Y,Z,W,X,Y,Z\n0,0,0,0,0,1,0,0,0\n1,0.01,0,0,0,1,0,oops,0\n",
     r"bad.csv: line 8, column 8 \(b Y\): 'oops' is not a number"),
    ("Take Name,x\n", r"not a Motive CSV export"),
])
def test_damaged_exports_are_one_line(text, message):
    with pytest.raises(UserError, match=message):
        read_motive_csv(text, what="bad.csv")


def test_units_given_for_a_header_without_them_and_a_contradiction_refused():
    text = HMV.read_text().replace(",Length Units,Meters", "")
    with pytest.raises(UserError, match="no Length Units"):
        read_motive_csv(text)
    t = read_motive_csv(text, units=("mm", None))
    assert t.x_m[0] == pytest.approx(0.060002e-3)
    with pytest.raises(UserError, match="line 1 says Length Units Meters, --units says mm"):
        read_motive_csv(HMV.read_text(), units=("mm", None))


def test_nan_cells_count_as_occluded():
    text = HMV.read_text().replace("\r\n", "\n").splitlines()
    parts = text[10].split(",")
    parts[2] = "NaN"
    text[10] = ",".join(parts)
    t = read_motive_csv("\n".join(text) + "\n", plane=FloorPlane.parse("x-z"))
    assert t.counts == {"frames": 40, "kept": 39, "occluded": 1, "repeated": 0}

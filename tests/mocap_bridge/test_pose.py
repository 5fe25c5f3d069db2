"""Pose maths and the payload schema (pure functions)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from mocap_bridge.pose import (
    SCHEMA,
    AxisMap,
    PoseSample,
    decode_pose,
    encode_pose,
    euler_xyz_to_quat,
    pose_key,
    sanitize_chunk,
    wrap_pi,
    yaw_heading,
    yaw_quat,
    yaw_twist,
)

angles = st.floats(-math.pi, math.pi, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(angles, st.floats(-1.5, 1.5), angles)
def test_euler_xyz_matches_scipy_intrinsic_xyz(rx, ry, rz):
    q = np.array(euler_xyz_to_quat(rx, ry, rz))
    ref = Rotation.from_euler("XYZ", [rx, ry, rz]).as_quat()  # (x, y, z, w)
    assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-12
    # Vicon's SDK recovers ry = asin(R[0, 2]) from R = Rx Ry Rz
    R = Rotation.from_quat(q).as_matrix()
    assert math.asin(R[0, 2]) == pytest.approx(ry, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(angles, st.floats(-0.3, 0.3), st.floats(-0.3, 0.3))
def test_yaw_heading_is_angle_of_projected_body_x_axis(psi, roll, pitch):
    q = Rotation.from_euler("ZYX", [psi, pitch, roll]).as_quat()
    R = Rotation.from_quat(q).as_matrix()
    expected = math.atan2(R[1, 0], R[0, 0])
    got = yaw_heading(*q)
    assert -math.pi < got <= math.pi
    assert abs(wrap_pi(got - expected)) < 1e-12
    assert abs(wrap_pi(got - psi)) < 1e-9  # ZYX: the first angle is the heading


def test_yaw_of_level_body_and_wrap():
    for psi in (0.0, 0.5, -2.0, 3.0, math.pi, -math.pi, 7.0):
        q = yaw_quat(psi)
        for f in (yaw_heading, yaw_twist):
            y = f(*q)
            assert -math.pi < y <= math.pi
            assert abs(wrap_pi(y - psi)) < 1e-12
    assert wrap_pi(-math.pi) == math.pi
    assert yaw_heading(*yaw_quat(-math.pi)) == math.pi


def test_y_up_mapping_puts_lab_y_on_the_table_normal():
    # Y-up lab: a body 1 m along lab X, 2 m up (lab Y), 3 m along lab Z, turned +30 deg
    # about the vertical (lab Y).
    psi = math.radians(30)
    q_lab = Rotation.from_euler("y", psi).as_quat()
    s = PoseSample("b", 1, 0.0, 0.0, 1.0, 2.0, 3.0, *q_lab)
    x, y, z, qx, qy, qz, qw, yaw = AxisMap(up="y").apply(s)
    assert (x, y, z) == pytest.approx((1.0, -3.0, 2.0))
    # table frame = M @ lab frame with M = Rx(+90 deg); lab +Y is the table normal, so a
    # turn about lab +Y is a pure yaw of the same size on the table
    R_tab = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
    M = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    R_lab = Rotation.from_quat(q_lab).as_matrix()
    assert np.allclose(R_tab, M @ R_lab)
    assert yaw == pytest.approx(math.atan2(R_tab[1, 0], R_tab[0, 0]))
    assert abs(yaw) == pytest.approx(psi)


def test_axis_map_offsets_and_twist_projection():
    q = Rotation.from_euler("ZYX", [1.0, 0.4, 0.5]).as_quat()
    s = PoseSample("b", 1, 0.0, 0.0, 1.0, 2.0, 0.5, *q)
    h = AxisMap().apply(s)
    tw = AxisMap(projection="twist").apply(s)
    assert h[7] == pytest.approx(1.0, abs=1e-12)
    assert tw[7] != pytest.approx(h[7], abs=1e-3)  # tilted body: the two differ
    off = AxisMap(yaw_offset_rad=math.pi, origin_m=(1.0, 1.0, 0.0)).apply(s)
    assert off[:3] == pytest.approx((0.0, 1.0, 0.5))
    assert off[7] == pytest.approx(wrap_pi(1.0 + math.pi))
    with pytest.raises(ValueError):
        AxisMap(up="x")


def test_encode_decode_round_trip_and_occlusion():
    pose = (0.1, -0.2, 0.03, 0.0, 0.0, math.sin(0.25), math.cos(0.25), 0.5)
    raw = encode_pose("tpods 1", 42, 1000.5, 1000.51, pose, t_src=3.25)
    d = decode_pose(raw)
    assert d["schema"] == SCHEMA and d["body"] == "tpods 1" and d["frame"] == 42
    assert (d["x"], d["y"], d["z"], d["qx"], d["qy"], d["qz"], d["qw"], d["yaw"]) == pose  # exact
    assert d["t"] == 1000.5 and d["t_recv"] == 1000.51 and d["t_src"] == 3.25
    t_epoch = 1763770000.1234567  # times keep full double precision
    assert decode_pose(encode_pose("b", 1, t_epoch, t_epoch, pose))["t"] == t_epoch
    import numpy as np  # numpy scalars (e.g. from a live producer) encode as plain numbers
    d_np = decode_pose(encode_pose("b", np.int64(3), np.float64(2.5), np.float64(2.5),
                                   tuple(np.float64(v) for v in pose), t_src=np.float64(1.5)))
    assert d_np["frame"] == 3 and d_np["t"] == 2.5 and d_np["t_src"] == 1.5
    assert d["occluded"] is False
    occ = decode_pose(encode_pose("b", 7, 1.0, 1.0, None))
    assert occ["occluded"] is True and occ["x"] is None and occ["yaw"] is None
    assert occ["t_src"] is None
    # a NaN anywhere in the pose is published as occluded, never as numbers
    nan_pose = decode_pose(encode_pose("b", 8, 1.0, 1.0, (math.nan,) + pose[1:]))
    assert nan_pose["occluded"] is True and nan_pose["x"] is None
    json.loads(encode_pose("b", 8, 1.0, 1.0, (math.inf,) + pose[1:]))  # valid JSON


@pytest.mark.parametrize("payload", [
    b"", b"not json", b"[1, 2]", b'{"schema": "tpods.pose/1"}',
    b'{"schema":"tpods.pose/1","body":"b","frame":1,"t":1,"t_recv":1,"occluded":false}',
    b'{"schema":"tpods.pose/1","body":"b","frame":true,"t":1,"t_recv":1,"occluded":true}',
    b'{"schema":"tpods.pose/1","body":"b","frame":1,"t":"x","t_recv":1,"occluded":true}',
    b'{"schema":"tpods.pose/2","body":"b","frame":1,"t":1,"t_recv":1,"occluded":true}',
    b'\xff\xfe',
])
def test_decode_rejects_and_counts_malformed(payload):
    c: dict[str, int] = {}
    assert decode_pose(payload, c) is None
    assert c == {"malformed": 1}


def test_decode_counts_other_schemas_separately():
    c: dict[str, int] = {}
    assert decode_pose(b'{"schema":"tpods.mocap-stats/1","t":1}', c) is None
    assert c == {"other_schema": 1}


def test_keys_are_sanitised():
    assert pose_key("tpods/mocap/", "TPODS 1/a*b") == "tpods/mocap/TPODS_1_a_b/pose"
    assert sanitize_chunk("") == "_" and sanitize_chunk("..") == "_.."
    assert sanitize_chunk("mod-1.v2") == "mod-1.v2"

"""Vicon DataStream SDK source against what the SDK and its Python bindings document.

Sources read (each expected value below names the one it comes from):

[DSSDK]  Vicon's Python module ``vicon_dssdk/ViconDataStream.py`` (docstrings with
         examples), as vendored in riccardodelmedico/Crazyflie, vicon_dssdk/ViconDataStream.py.
[SDKH]   The SDK 1.11 C++ header shipped with pyvicon-datastream:
         steffensc/pyvicon-datatstream-module,
         lib_src/vicondatastream-1.11.0/Vicon/CrossMarket/DataStream/ViconDataStreamSDK_CPP/
         IDataStreamClientBase.h (Result, Direction, StreamMode enums).
[PVPY]   steffensc/pyvicon-datatstream-module, pyvicon_datastream/pyvicon_datastream.py
         (Result / StreamMode / Direction enums, return shapes, quaternion docstring).
[PVCPP]  steffensc/pyvicon-datatstream-module, pyvicon_datastream/pyvicon_datastream_wrapper.cpp
         (what the C extension returns on failure, occlusion, and the quaternion order).
[PVTOOLS] steffensc/pyvicon-datatstream-module, pyvicon_datastream/tools.py (class name
         PyVicon, set-up sequence: enable_segment_data, ServerPush, Forward/Left/Up).

The fakes (tests/mocap_bridge/test_vicon_sdk.py) return what these sources say each call returns.
"""

from __future__ import annotations

import math

import pytest

from mocap_bridge.sources.vicon_sdk import ViconSDKSource
from tests.mocap_bridge.test_vicon_sdk import (
    PV,
    Direction,
    FakeDSSDK,
    FakePyVicon,
    Script,
    StreamMode,
)

# [DSSDK] EnableSegmentData docstring: GetSegmentGlobalTranslation("Alice", "Root") ->
# ((-522.2945270748643, -1.56943597526001, 1119.1174983031265), False); millimetres
# ("x, y and z are in millimeters with respect to the global origin").
ALICE_MM = (-522.2945270748643, -1.56943597526001, 1119.1174983031265)
# [DSSDK] GetFrameNumber docstring example: 361496.
FRAME = 361496
# [DSSDK] GetLatencyTotal docstring: "total latency in seconds", example 0.0124434.
LATENCY_S = 0.0124434
# [DSSDK] GetSegmentGlobalRotationQuaternion: "(x, y, z, w) where w is the real component";
# 0.5 rad about z written that way:
Q_XYZW = (0.0, 0.0, math.sin(0.25), math.cos(0.25))


def _source(backend, items, **kw):
    script = Script(items)
    if backend == "vicon_dssdk":
        return ViconSDKSource("vicon-pc", client=FakeDSSDK(script), server_push="PUSH",
                              axis_mapping=("F", "L", "U"), clock=lambda: 500.0, **kw)
    return ViconSDKSource("vicon-pc", client=FakePyVicon(script), pv_module=PV,
                          clock=lambda: 500.0, **kw)


BOTH = pytest.mark.parametrize("backend", ["vicon_dssdk", "pyvicon"])


@BOTH
def test_documented_example_values(backend):
    # [DSSDK] GetSubjectRootSegmentName docstring example returns "Hips": the pose read is
    # the root segment's, not a segment named like the subject.
    src = _source(backend, [(FRAME, LATENCY_S, {"Alice": ("Hips", ALICE_MM, False, Q_XYZW, False)})])
    (p,) = src.read_frame()
    assert (p.body, p.frame) == ("Alice", FRAME)
    assert p.t == pytest.approx(500.0 - 0.0124434) and p.t_recv == 500.0   # seconds
    assert (p.x, p.y, p.z) == pytest.approx((-0.5222945270748643, -0.00156943597526001,
                                             1.1191174983031265))        # mm -> m
    assert (p.qx, p.qy, p.qz, p.qw) == pytest.approx(Q_XYZW) and not p.occluded


def test_connect_default_port_801():
    # [DSSDK] Connect: "The function defaults to connecting on port 801."
    script = Script([])
    ViconSDKSource("vicon-pc", client=FakeDSSDK(script))
    assert script.calls[0] == "Connect vicon-pc:801"
    script = Script([])
    ViconSDKSource("10.0.0.2:801", client=FakePyVicon(script), pv_module=PV)
    assert script.calls[0] == "connect 10.0.0.2:801"


@BOTH
def test_set_up_server_push_and_z_up_axis_mapping(backend):
    # [DSSDK] SetAxisMapping: "+X forward, +Y left, and +Z up"; "Z-up: SetAxisMapping(
    # Forward, Left, Up )". [SDKH] StreamMode::ServerPush = 2, Direction Forward = 4,
    # Left = 2, Up = 0. [PVTOOLS] sets ServerPush and (Forward, Left, Up) the same way.
    src = _source(backend, [])
    if backend == "pyvicon":
        assert src.client.mode is StreamMode.ServerPush and StreamMode.ServerPush.value == 2
        assert src.client.axes == (Direction.Forward, Direction.Left, Direction.Up)
        assert [d.value for d in src.client.axes] == [4, 2, 0]
    else:
        assert src.client.axes == ("F", "L", "U")


@BOTH
def test_no_frame_is_not_an_error_and_does_not_repeat_the_last_frame(backend):
    # [DSSDK] GetFrame: "return True if a frame was available. False if the server is not
    # currently streaming data" (ret == NoFrame returns False, does not raise).
    # [PVPY] get_frame returns Result.NoFrame (value 10, [SDKH]).
    body = {"m": ("m", (1.0, 2.0, 3.0), False, (0.0, 0.0, 0.0, 1.0), False)}
    src = _source(backend, [(7, 0.0, body), "NOFRAME"])
    assert [p.frame for p in src.read_frame()] == [7]
    # the fakes still hold frame 7 after NoFrame, like the SDK's last frame: it must not
    # be read again as if it were new
    assert src.read_frame() is None
    assert src.counters["no_frame"] == 1 and src.counters["frame_errors"] == 0


@BOTH
def test_occluded_segment_published_occluded_not_counted_bad(backend):
    # [DSSDK] GetSegmentGlobalRotationEulerXYZ: "Occluded will be True if the segment was
    # absent at this frame. In this case the rotation will be [0,0,0]" (the fake of
    # vicon_dssdk returns zeros with the flag). [PVCPP] pyvicon returns None when
    # out.Occluded is set.
    src = _source(backend, [(3, 0.0, {"m": ("m", (5.0, 5.0, 5.0), True, Q_XYZW, True)})])
    (p,) = src.read_frame()
    assert p.occluded and math.isnan(p.x)
    assert src.counters["bad_values"] == 0


def test_pyvicon_quaternion_is_w_first():
    # [PVCPP] pyvicon_get_segment_global_quaternion builds (Rotation[3], Rotation[0],
    # Rotation[1], Rotation[2]); [PVPY] docstring "Return the quaternion as : w,x,y,z".
    # The same rotation read through both bindings gives the same (x, y, z, w).
    script = Script([(1, 0.0, {"m": ("m", (0.0, 0.0, 0.0), False, Q_XYZW, False)})])
    client = FakePyVicon(script)
    src = ViconSDKSource("h", client=client, pv_module=PV)
    (p,) = src.read_frame()
    raw = client.get_segment_global_quaternion("m", "m")  # what the binding itself returns
    assert tuple(raw) == pytest.approx((math.cos(0.25), 0.0, 0.0, math.sin(0.25)))
    assert (p.qx, p.qy, p.qz, p.qw) == pytest.approx(Q_XYZW)


def test_pyvicon_result_code_outside_its_enum_is_counted():
    # [SDKH] Result::Enum goes up to NotPresent (27); [PVPY] Result stops at
    # HapticAlreadySet = 21, so Result(27) raises ValueError inside get_frame().
    class Newer(FakePyVicon):
        def get_frame(self):
            raise ValueError("27 is not a valid Result")

    src = ViconSDKSource("h", client=Newer(Script([])), pv_module=PV)
    assert src.read_frame() is None and src.counters["frame_errors"] == 1


def test_pyvicon_subject_name_failure_returns_none_and_is_skipped():
    # [PVCPP] pyvicon_get_subject_name: Py_RETURN_NONE when the result is not Success.
    class Flaky(FakePyVicon):
        def get_subject_name(self, index):
            return None if index == 0 else super().get_subject_name(index)

    body = {"a": ("a", (1.0, 1.0, 1.0), False, Q_XYZW, False),
            "b": ("b", (2.0, 2.0, 2.0), False, Q_XYZW, False)}
    src = ViconSDKSource("h", client=Flaky(Script([(1, 0.0, body)])), pv_module=PV)
    assert [p.body for p in src.read_frame()] == ["b"]
    assert src.counters["subject_errors"] == 1


@BOTH
def test_no_latency_information_means_zero(backend):
    # [DSSDK] GetLatencyTotal: "If no latency information is available then all
    # latencies will be reported as 0.0" -> capture time = receive time.
    src = _source(backend, [(1, 0.0, {"m": ("m", (1.0, 1.0, 1.0), False, Q_XYZW, False)})])
    (p,) = src.read_frame()
    assert p.t == p.t_recv == 500.0


@BOTH
def test_root_segment_failure_is_not_cached(backend):
    # [DSSDK] GetSubjectRootSegmentName raises InvalidSubjectName; [PVCPP] returns None.
    # A failed look-up falls back to the subject's name for this frame only.
    class Once:
        n = 0

    body = {"obj": ("root", (1.0, 1.0, 1.0), False, Q_XYZW, False)}
    src = _source(backend, [(1, 0.0, body), (2, 0.0, body)])
    real = src.sdk.root_segment

    def flaky(subject):
        Once.n += 1
        if Once.n == 1:
            raise RuntimeError("InvalidSubjectName")
        return real(subject)

    src.sdk.root_segment = flaky
    (p1,) = src.read_frame()
    (p2,) = src.read_frame()
    # "obj" is not a segment: vicon_dssdk raises InvalidSegmentName (counted), pyvicon
    # returns None, which it also returns for an occluded segment ([PVCPP])
    assert p1.occluded
    assert src.counters["subject_errors"] == (1 if backend == "vicon_dssdk" else 0)
    assert not p2.occluded and p2.x == pytest.approx(0.001)

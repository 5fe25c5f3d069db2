"""The DataStream SDK code path, with a fake client object."""

from __future__ import annotations

import enum
import itertools
import math
import sys
import threading
import time
import types

import numpy as np
import pytest

from common.errors import DeviceError, UserError
from mocap_bridge.bridge import Bridge
from mocap_bridge.pose import decode_pose
from mocap_bridge.sources import open_source
from mocap_bridge.sources.vicon_sdk import ViconSDKSource
from tests.support.net import Collector, subscribe_ready, wait_for


class SDKError(Exception):
    pass


class FakeClient:
    """Mimics vicon_dssdk.ViconDataStream.Client for a scripted list of frames.

    Each frame: (frame_number, latency_s, {subject: ((x, y, z) mm, occ_t, (qx, qy, qz, qw), occ_r)}).
    """

    def __init__(self, frames, connect_after: int = 0):
        self.frames = list(frames)
        self.i = -1
        self.calls: list[str] = []
        self.connect_after = connect_after
        self.connected = False
        self.mode = None
        self.done = threading.Event()

    def Connect(self, host):
        self.calls.append(f"Connect {host}")
        if self.connect_after > 0:
            self.connect_after -= 1
            raise SDKError("no server")
        self.connected = True

    def IsConnected(self):
        return self.connected

    def EnableSegmentData(self):
        self.calls.append("EnableSegmentData")

    def SetStreamMode(self, mode):
        self.mode = mode

    def GetFrame(self):
        self.i += 1
        if self.i >= len(self.frames):
            self.done.set()
            raise SDKError("no frame")
        return True

    def GetFrameNumber(self):
        return self.frames[self.i][0]

    def GetLatencyTotal(self):
        return self.frames[self.i][1]

    def GetSubjectNames(self):
        return list(self.frames[self.i][2])

    def GetSubjectRootSegmentName(self, subj):
        return subj + "_root"

    def GetSegmentGlobalTranslation(self, subj, seg):
        assert seg == subj + "_root"
        p, occ, _, _ = self.frames[self.i][2][subj]
        return p, occ

    def GetSegmentGlobalRotationQuaternion(self, subj, seg):
        _, _, q, occ = self.frames[self.i][2][subj]
        return q, occ

    def Disconnect(self):
        self.calls.append("Disconnect")


S = math.sin(0.3)
C = math.cos(0.3)
FRAMES = [
    (500, 0.010, {"mod": ((1000.0, -500.0, 20.0), False, (0.0, 0.0, S, C), False),
                  "hidden": ((0.0, 0.0, 0.0), True, (0.0, 0.0, 0.0, 1.0), True)}),
    (501, 0.012, {"mod": ((1010.0, -500.0, 20.0), False, (0.0, 0.0, S, C), True)}),  # rotation occluded
    (501, 0.012, {"mod": ((1010.0, -500.0, 20.0), False, (0.0, 0.0, S, C), False)}),  # repeat
    (503, 0.008, {"mod": ((math.nan, 0.0, 0.0), False, (0.0, 0.0, S, C), False)}),   # NaN
    (504, 0.008, {"mod": ((1.0, 2.0, 3.0), False, (0.0, 0.0, 1.0005 * S, 1.0005 * C), False)}),
    (505, 0.008, {"mod": ((1.0, 2.0, 3.0), False, (0.0, 0.0, 0.0, 0.0), False)}),      # zero quaternion
    (506, 0.008, {"mod": ((1.0, 2.0, 3.0), False, (0.0, 0.0, 2 * S, 2 * C), False)}),  # not a rotation
]


def test_sdk_source_reads_frames_with_latency_and_occlusion():
    clock = iter([100.0 + k for k in range(10)])
    cl = FakeClient(FRAMES, connect_after=2)
    src = ViconSDKSource("vicon-pc", client=cl, server_push="PUSH", clock=lambda: next(clock),
                         connect_timeout_s=5.0)
    assert cl.calls[:3] == ["Connect vicon-pc:801"] * 3 and cl.mode == "PUSH"
    b = src.read_frame()
    mod, hidden = b
    assert (mod.body, mod.frame, mod.t_recv) == ("mod", 500, 100.0)
    assert mod.t == pytest.approx(99.99)
    assert (mod.x, mod.y, mod.z) == pytest.approx((1.0, -0.5, 0.02))
    assert (mod.qz, mod.qw) == pytest.approx((S, C)) and not mod.occluded
    assert hidden.occluded
    assert src.read_frame()[0].occluded  # rotation flagged occluded
    src.read_frame()
    assert src.read_frame()[0].occluded  # NaN translation
    p = src.read_frame()[0]
    assert not p.occluded and (p.qz, p.qw) == pytest.approx((S, C), abs=1e-12)  # renormalised
    assert src.read_frame()[0].occluded  # zero quaternion is not a rotation
    assert src.read_frame()[0].occluded  # norm 2: garbage, not silently renormalised
    assert src.counters["bad_values"] == 3
    assert src.read_frame() is None and src.counters["frame_errors"] == 1
    src.close()
    assert cl.calls[-1] == "Disconnect"


def test_sdk_source_gives_up_with_one_line_error():
    with pytest.raises(DeviceError, match="cannot connect"):
        ViconSDKSource("nowhere", client=FakeClient([], connect_after=10**6), connect_timeout_s=0.3)


def test_sdk_missing_is_a_user_error():
    pytest.importorskip("tpods")
    try:
        import vicon_dssdk  # noqa: F401
        pytest.skip("the real SDK is installed")
    except ImportError:
        pass
    with pytest.raises(UserError, match="vicon_dssdk"):
        open_source("vicon-sdk:localhost")


def test_sdk_frames_through_the_bridge(zenoh_pair):
    pub_s, sub_s, _ = zenoh_pair
    col = Collector()
    sub = subscribe_ready(pub_s, sub_s, "lab/mocap/**", col)
    cl = FakeClient(FRAMES)
    src = ViconSDKSource("h:801", client=cl, server_push=None)
    stop = threading.Event()
    t = threading.Thread(target=lambda: Bridge(pub_s, prefix="lab/mocap").run(src, stop=stop))
    t.start()
    assert cl.done.wait(10.0)
    assert wait_for(lambda: len(col.of_key("/pose")) >= 7, 10.0)
    stop.set()
    t.join(10.0)
    assert not t.is_alive()
    sub.undeclare()
    mod = [decode_pose(p) for p in col.of_key("lab/mocap/mod/pose")]
    assert [d["frame"] for d in mod] == [500, 501, 503, 504, 505, 506]
    assert [d["occluded"] for d in mod] == [False, True, True, False, True, True]
    assert mod[0]["x"] == pytest.approx(1.0) and mod[0]["yaw"] == pytest.approx(0.6)
    hidden = [decode_pose(p) for p in col.of_key("lab/mocap/hidden/pose")]
    assert len(hidden) == 1 and hidden[0]["occluded"] and hidden[0]["x"] is None


# ---------------------------------------------------------------- both back ends
#
# The same scripted scene played through a fake of each binding's API:
#   vicon_dssdk: Vicon's ViconDataStream.py (read: a vendored copy in
#     riccardodelmedico/Crazyflie, vicon_dssdk/ViconDataStream.py): failures raise
#     DataStreamException; GetFrame() returns False on NoFrame; GetSegmentGlobalTranslation
#     -> ((x, y, z) mm, occluded); GetSegmentGlobalRotationQuaternion -> ((x, y, z, w), occluded);
#     GetLatencyTotal() in seconds.
#   pyvicon-datastream (read: steffensc/pyvicon-datatstream-module,
#     pyvicon_datastream/pyvicon_datastream.py and pyvicon_datastream_wrapper.cpp, tools.py):
#     methods return a Result enum or None instead of raising; get_segment_global_translation
#     -> np.array([x, y, z]) mm, or None when occluded or failed; get_segment_global_quaternion
#     -> np.array([w, x, y, z]) (the wrapper builds it from Rotation[3], [0], [1], [2]) or None;
#     get_frame_number() an unsigned int; get_latency_total() the SDK's Total, seconds.

class DataStreamException(Exception):
    """Stands for vicon_dssdk.ViconDataStream.DataStreamException (carries a result name)."""


class Result(enum.Enum):  # values as pyvicon_datastream.Result (the SDK's Result::Enum order)
    Unknown = 0
    Success = 2
    ClientAlreadyConnected = 5
    ClientConnectionFailed = 6
    NotConnected = 9
    NoFrame = 10
    InvalidSubjectName = 13
    InvalidSegmentName = 14


class StreamMode(enum.Enum):  # pyvicon_datastream.StreamMode
    ClientPull = 0
    ClientPullPreFetch = 1
    ServerPush = 2


class Direction(enum.Enum):  # pyvicon_datastream.Direction
    Up = 0
    Down = 1
    Left = 2
    Right = 3
    Forward = 4
    Backward = 5


class Script:
    """A scene both fakes play: a list of frames, "NOFRAME" and "LOST" items.

    A frame: (number, latency_s, {subject: (root_segment, (x, y, z) mm, occ_t,
    (qx, qy, qz, qw), occ_r)}). "LOST": the connection drops; the next ``refuse``
    connection attempts fail. When the list is used up, ``stop`` is set and every
    further call gets NoFrame.
    """

    def __init__(self, items, stop=None, refuse: int = 2):
        self.items = list(items)
        self.i = -1
        self.cur = None
        self.connected = False
        self.refuse_left = 0
        self.refuse = refuse
        self.stop = stop
        self.calls: list[str] = []

    def connect(self) -> bool:
        self.calls.append("connect")
        if self.refuse_left > 0:
            self.refuse_left -= 1
            return False
        self.connected = True
        return True

    def next(self) -> str:
        if not self.connected:
            return "NotConnected"
        self.i += 1
        if self.i >= len(self.items):
            if self.stop is not None:
                self.stop.set()
            return "NoFrame"
        item = self.items[self.i]
        if item == "LOST":
            self.connected = False
            self.refuse_left = self.refuse
            return "NotConnected"
        if item == "NOFRAME":
            return "NoFrame"
        self.cur = item
        return "Success"

    def segment(self, subj, seg):
        """(translation, occ_t, quaternion xyzw, occ_r) or a failure name."""
        bodies = self.cur[2]
        if subj not in bodies:
            return "InvalidSubjectName"
        root, p, occ_t, q, occ_r = bodies[subj]
        if seg != root:
            return "InvalidSegmentName"
        return p, occ_t, q, occ_r


class FakeDSSDK:
    """vicon_dssdk.ViconDataStream.Client over a Script (failures raise)."""

    def __init__(self, script: Script):
        self.s = script
        self.axes = None

    def Connect(self, host):
        self.s.calls.append(f"Connect {host}")
        if not self.s.connect():
            raise DataStreamException("ClientConnectionFailed")

    def IsConnected(self):
        return self.s.connected

    def EnableSegmentData(self):
        if not self.s.connected:
            raise DataStreamException("NotConnected")

    def SetStreamMode(self, mode):
        self.s.calls.append(f"mode {mode}")

    def SetAxisMapping(self, x, y, z):
        self.axes = (x, y, z)

    def GetFrame(self):
        r = self.s.next()
        if r == "NoFrame":
            return False  # documented: False, not an exception
        if r != "Success":
            raise DataStreamException(r)
        return True

    def GetFrameNumber(self):
        return self.s.cur[0]

    def GetLatencyTotal(self):
        return self.s.cur[1]

    def GetSubjectNames(self):
        return list(self.s.cur[2])

    def GetSubjectRootSegmentName(self, subj):
        if subj not in self.s.cur[2]:
            raise DataStreamException("InvalidSubjectName")
        return self.s.cur[2][subj][0]

    def GetSegmentGlobalTranslation(self, subj, seg):
        r = self.s.segment(subj, seg)
        if isinstance(r, str):
            raise DataStreamException(r)
        p, occ, _, _ = r
        return ((0.0, 0.0, 0.0) if occ else tuple(p)), occ  # occluded: zeros + flag

    def GetSegmentGlobalRotationQuaternion(self, subj, seg):
        r = self.s.segment(subj, seg)
        if isinstance(r, str):
            raise DataStreamException(r)
        _, _, q, occ = r
        return ((0.0, 0.0, 0.0, 0.0) if occ else tuple(q)), occ

    def Disconnect(self):
        self.s.calls.append("Disconnect")


class FakePyVicon:
    """pyvicon_datastream.PyVicon over a Script (failures: Result codes or None)."""

    def __init__(self, script: Script):
        self.s = script
        self.axes = None
        self.mode = None

    def connect(self, host):
        self.s.calls.append(f"connect {host}")
        return Result.Success if self.s.connect() else Result.ClientConnectionFailed

    def is_connected(self):
        return self.s.connected

    def enable_segment_data(self):
        return Result.Success if self.s.connected else Result.NotConnected

    def set_stream_mode(self, mode):
        if not isinstance(mode, StreamMode):  # the real one checks its enum type
            raise RuntimeError("set_stream_mode expects a StreamMode")
        self.mode = mode
        return Result.Success

    def set_axis_mapping(self, x, y, z):
        assert all(isinstance(d, Direction) for d in (x, y, z))
        self.axes = (x, y, z)
        return Result.Success

    def get_frame(self):
        return Result[self.s.next()]

    def get_frame_number(self):
        return self.s.cur[0]

    def get_latency_total(self):
        return self.s.cur[1]

    def get_subject_count(self):
        return len(self.s.cur[2])

    def get_subject_name(self, index):
        names = list(self.s.cur[2])
        return names[index] if 0 <= index < len(names) else None

    def get_subject_root_segment_name(self, name):
        b = self.s.cur[2].get(name)
        return None if b is None else b[0]

    def get_segment_global_translation(self, subj, seg):
        r = self.s.segment(subj, seg)
        if isinstance(r, str) or r[1]:
            return None
        return np.array(r[0])

    def get_segment_global_quaternion(self, subj, seg):
        r = self.s.segment(subj, seg)
        if isinstance(r, str) or r[3]:
            return None
        qx, qy, qz, qw = r[2]
        return np.array([qw, qx, qy, qz])

    def disconnect(self):
        self.s.calls.append("disconnect")
        return Result.Success


PV = types.SimpleNamespace(Result=Result, StreamMode=StreamMode, Direction=Direction,
                           PyVicon=FakePyVicon)

Q30 = (0.0, 0.0, math.sin(0.15), math.cos(0.15))  # 0.3 rad about z, (x, y, z, w)
SCENE = [
    (10, 0.004, {"mod": ("mod", (1000.0, -500.0, 20.0), False, Q30, False),
                 "Alice": ("Hips", (-522.3, -1.6, 1119.1), False, (0.0, 0.0, 0.0, 1.0), False),
                 "hidden": ("hidden", (0.0, 0.0, 0.0), True, (0.0, 0.0, 0.0, 1.0), True)}),
    "NOFRAME",
    (11, 0.004, {"mod": ("mod", (1001.0, -500.0, 20.0), False, Q30, True),   # rotation occluded
                 "Alice": ("Hips", (-522.0, -1.0, 1119.0), True, (0.0, 0.0, 0.0, 1.0), False)}),
    (12, 0.005, {"mod": ("mod", (math.nan, -500.0, 20.0), False, Q30, False)}),  # NaN
    (13, 0.005, {"mod": ("mod", (1.0, 2.0, 3.0), False, (0.0, 0.0, math.inf, 1.0), False)}),  # inf
    "LOST",
    (20, 0.006, {"mod": ("mod", (1003.0, -500.0, 20.0), False, Q30, False)}),
    (21, math.nan, {"mod": ("mod", (1004.0, -500.0, 20.0), False, Q30, False)}),  # no latency
]


def _open(backend: str, items, stop=None, **kw):
    script = Script(items, stop=stop)
    clock = itertools.count(1000.0)
    if backend == "vicon_dssdk":
        return ViconSDKSource("vicon-pc", client=FakeDSSDK(script), server_push="PUSH",
                              axis_mapping=("F", "L", "U"), clock=lambda: next(clock),
                              reconnect_period_s=0.01, **kw), script
    return ViconSDKSource("vicon-pc", client=FakePyVicon(script), pv_module=PV,
                          clock=lambda: next(clock), reconnect_period_s=0.01, **kw), script


def _plain(p):
    return tuple(None if isinstance(v, float) and math.isnan(v) else v for v in p)


def _run(backend: str, items):
    stop = threading.Event()
    src, script = _open(backend, items, stop=stop)
    poses = [_plain(p) for batch in src.batches(stop) for p in batch]
    src.close()
    return src, script, poses


@pytest.mark.parametrize("backend", ["vicon_dssdk", "pyvicon"])
def test_backend_reads_the_scene(backend):
    src, script, poses = _run(backend, SCENE)
    assert src.backend == backend
    # set-up: server push and the SDK's Z-up axis mapping (Forward, Left, Up) set explicitly
    if backend == "pyvicon":
        assert src.client.mode is StreamMode.ServerPush
        assert src.client.axes == (Direction.Forward, Direction.Left, Direction.Up)
    else:
        assert "mode PUSH" in script.calls and src.client.axes == ("F", "L", "U")
    by = {(p[0], p[1]): p for p in poses}
    assert [(p[0], p[1], p[11]) for p in poses] == [
        ("mod", 10, False), ("Alice", 10, False), ("hidden", 10, True),
        ("mod", 11, True), ("Alice", 11, True), ("mod", 12, True), ("mod", 13, True),
        ("mod", 20, False), ("mod", 21, False)]
    mod = by[("mod", 10)]
    assert mod[2] == pytest.approx(1000.0 - 0.004) and mod[3] == 1000.0  # t = t_recv - latency
    assert mod[4:7] == pytest.approx((1.0, -0.5, 0.02))                    # mm -> m
    assert mod[7:11] == pytest.approx(Q30)                                  # (x, y, z, w) kept
    assert by[("Alice", 10)][4:7] == pytest.approx((-0.5223, -0.0016, 1.1191))  # root "Hips"
    assert by[("hidden", 10)][4:11] == (None,) * 7                          # no fake zeros
    assert by[("mod", 21)][2] == by[("mod", 21)][3]                         # NaN latency -> 0
    c = src.counters
    assert (c["bad_values"], c["no_frame"], c["disconnects"], c["reconnects"]) == (2, 2, 1, 1)
    # connections: one at start; after "LOST", two refused attempts, then the third
    assert script.calls.count("connect") == 4


def test_both_backends_give_the_same_poses():
    _, _, a = _run("vicon_dssdk", SCENE)
    _, _, b = _run("pyvicon", SCENE)
    assert len(a) == 9 and a == b


@pytest.mark.parametrize("backend", ["vicon_dssdk", "pyvicon"])
def test_lost_connection_is_reestablished_and_set_up_again(backend):
    items = [(1, 0.0, {"m": ("m", (1.0, 2.0, 3.0), False, (0.0, 0.0, 0.0, 1.0), False)}),
             "LOST",
             (2, 0.0, {"m": ("m", (1.0, 2.0, 3.0), False, (0.0, 0.0, 0.0, 1.0), False)})]
    stop = threading.Event()
    src, script = _open(backend, items, stop=stop)
    got = [p.frame for batch in src.batches(stop) for p in batch]
    assert got == [1, 2]
    assert src.counters["disconnects"] == 1 and src.counters["reconnects"] == 1
    # one connect at start, the failed frame, two refused attempts, the third succeeds
    assert script.calls.count("connect") == 4
    if backend == "pyvicon":
        assert src.client.mode is StreamMode.ServerPush  # set again after reconnecting


def test_reconnect_loop_ends_when_stopped():
    stop = threading.Event()
    src, script = _open("pyvicon", ["LOST"])
    script.refuse = 10**9
    t0 = time.monotonic()
    threading.Timer(0.2, stop.set).start()
    assert list(src.batches(stop)) == []
    assert time.monotonic() - t0 < 5.0
    assert src.counters["disconnects"] == 1 and src.counters["reconnects"] == 0


def test_pyvicon_connection_refused_is_one_line_device_error():
    script = Script([])
    script.refuse_left = 10**9
    with pytest.raises(DeviceError, match=r"cannot connect .* at h:801 \(pyvicon: connect: "
                                          r"ClientConnectionFailed\)"):
        ViconSDKSource("h", client=FakePyVicon(script), pv_module=PV, connect_timeout_s=0.3)


def test_bad_port_is_a_user_error():
    with pytest.raises(UserError, match="HOST:PORT"):
        ViconSDKSource("h:80x", client=FakeDSSDK(Script([])))


def _no_bindings(monkeypatch):
    monkeypatch.setitem(sys.modules, "vicon_dssdk", None)  # import raises ImportError
    monkeypatch.setitem(sys.modules, "pyvicon_datastream", None)


def test_neither_binding_the_cli_says_what_to_install(monkeypatch, capsys):
    from tpods.cli import main

    _no_bindings(monkeypatch)
    assert main(["mocap", "bridge", "--source", "vicon-sdk:192.168.1.5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpods: error: no Vicon DataStream SDK")
    assert "pip install '.[vicon]'" in err[0] and "Windows" in err[0] and "vicon_dssdk" in err[0]


def test_auto_prefers_vicon_dssdk_and_falls_back_to_pyvicon(monkeypatch):
    from mocap_bridge.sources import vicon_sdk

    made = []

    class DSClient(FakeDSSDK):
        StreamMode = types.SimpleNamespace(EServerPush="PUSH")
        AxisMapping = types.SimpleNamespace(EForward="F", ELeft="L", EUp="U")

        def __init__(self):
            super().__init__(Script([]))
            made.append("dssdk")

    class PVClient(FakePyVicon):
        def __init__(self):
            super().__init__(Script([]))
            made.append("pyvicon")

    dssdk = types.SimpleNamespace(Client=DSClient, DataStreamException=DataStreamException)
    pv = types.SimpleNamespace(Result=Result, StreamMode=StreamMode, Direction=Direction,
                               PyViconDatastream=PVClient)  # early class name
    monkeypatch.setattr(vicon_sdk, "_import_dssdk", lambda: dssdk)
    monkeypatch.setattr(vicon_sdk, "_import_pyvicon", lambda: pv)
    src = ViconSDKSource("h")
    assert src.backend == "vicon_dssdk" and src.client.axes == ("F", "L", "U")
    assert ViconSDKSource("h", backend="pyvicon").backend == "pyvicon"

    def missing():
        raise ImportError("No module named 'vicon_dssdk'")

    monkeypatch.setattr(vicon_sdk, "_import_dssdk", missing)
    assert ViconSDKSource("h").backend == "pyvicon"
    assert made == ["dssdk", "pyvicon", "pyvicon"]
    with pytest.raises(UserError, match="vicon_dssdk back end is not importable"):
        ViconSDKSource("h", backend="vicon_dssdk")
    with pytest.raises(UserError, match="unknown Vicon SDK back end"):
        ViconSDKSource("h", backend="nexus")


@pytest.mark.parametrize("backend", ["vicon_dssdk", "pyvicon"])
def test_scene_through_the_bridge_both_backends(zenoh_pair, backend):
    pub_s, sub_s, _ = zenoh_pair
    col = Collector()
    sub = subscribe_ready(pub_s, sub_s, "lab/mocap/**", col)
    stop = threading.Event()
    src, _ = _open(backend, SCENE, stop=threading.Event())
    t = threading.Thread(target=lambda: Bridge(pub_s, prefix="lab/mocap").run(src, stop=stop))
    t.start()
    assert wait_for(lambda: len(col.of_key("/pose")) >= 9, 10.0)
    stop.set()
    t.join(10.0)
    assert not t.is_alive()
    sub.undeclare()
    mod = [decode_pose(p) for p in col.of_key("lab/mocap/mod/pose")]
    assert [d["frame"] for d in mod] == [10, 11, 12, 13, 20, 21]
    assert [d["occluded"] for d in mod] == [False, True, True, True, False, False]
    assert mod[0]["yaw"] == pytest.approx(0.3) and mod[0]["x"] == pytest.approx(1.0)
    alice = [decode_pose(p) for p in col.of_key("lab/mocap/Alice/pose")]
    assert [d["occluded"] for d in alice] == [False, True]


def test_set_up_refused_is_one_line_device_error():
    # EnableSegmentData raising (e.g. NotConnected right after Connect) used to escape the
    # constructor as a DataStreamException traceback
    class Refuses(FakeDSSDK):
        def EnableSegmentData(self):
            raise DataStreamException("NotConnected")

    with pytest.raises(DeviceError, match=r"set-up failed: NotConnected"):
        ViconSDKSource("h", client=Refuses(Script([])), connect_timeout_s=0.3)

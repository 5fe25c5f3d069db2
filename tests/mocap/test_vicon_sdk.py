"""The DataStream SDK code path, with a fake client object."""

from __future__ import annotations

import math
import threading

import pytest

from mocap_bridge.bridge import Bridge
from mocap_bridge.pose import decode_pose
from mocap_bridge.sources import open_source
from mocap_bridge.sources.vicon_sdk import ViconSDKSource
from tests.mocap.conftest import Collector, subscribe_ready, wait_for
from tpods.errors import DeviceError, UserError


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

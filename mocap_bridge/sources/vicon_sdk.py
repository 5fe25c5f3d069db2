"""Vicon DataStream SDK source (``vicon_dssdk``, from Vicon's installer, not on PyPI).

Server-push mode; per frame: frame number, total latency, and for each subject the
root segment's global translation (mm) and rotation quaternion with their occlusion
flags. The client object is injectable so the code path is tested without the SDK.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from mocap_bridge.pose import PoseSample, occluded_sample
from tpods.errors import DeviceError, UserError


def _import_sdk():
    try:
        from vicon_dssdk import ViconDataStream  # type: ignore[import-not-found]
    except ImportError:
        raise UserError("the Vicon DataStream SDK (vicon_dssdk) is not installed; install it "
                        "from Vicon's DataStream SDK package, or use --source vicon-udp") from None
    return ViconDataStream


class ViconSDKSource:
    """Poses from a Vicon DataStream server.

    Args:
        host: ``HOST`` or ``HOST:PORT`` (default port 801).
        client: an object with the SDK's ``Client`` methods (tests pass a fake);
            default ``vicon_dssdk.ViconDataStream.Client()``.
        server_push: the push constant for ``SetStreamMode`` (taken from the SDK when
            the client is created here).
        clock: host clock, s (``time.time``).
    """

    in_table_frame = False

    def __init__(self, host: str, client: Any = None, server_push: Any = None,
                 clock: Callable[[], float] = time.time, connect_timeout_s: float = 10.0) -> None:
        self.host = host if ":" in host else f"{host}:801"
        self.name = f"vicon-sdk:{self.host}"
        self.clock = clock
        self.counters = {"frames": 0, "frame_errors": 0, "bad_values": 0}
        self._exc: tuple[type[BaseException], ...] = (Exception,)
        if client is None:
            sdk = _import_sdk()
            client = sdk.Client()
            server_push = sdk.Client.StreamMode.EServerPush
            self._exc = (sdk.DataStreamException,)
        self.client = client
        self._connect(server_push, connect_timeout_s)
        self._segments: dict[str, str] = {}

    def _connect(self, server_push: Any, timeout_s: float) -> None:
        c = self.client
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                c.Connect(self.host)
            except Exception:
                pass
            if c.IsConnected():
                break
            if time.monotonic() > deadline:
                raise DeviceError(f"cannot connect to the Vicon DataStream server at {self.host}")
            time.sleep(0.2)
        c.EnableSegmentData()
        if server_push is not None:
            c.SetStreamMode(server_push)

    def _segment(self, subject: str) -> str:
        seg = self._segments.get(subject)
        if seg is None:
            try:
                seg = self.client.GetSubjectRootSegmentName(subject)
            except Exception:
                seg = subject  # Tracker objects have one segment named like the subject
            self._segments[subject] = seg
        return seg

    def read_frame(self) -> list[PoseSample] | None:
        """Wait for the next frame (server push) and return its poses, or None."""
        c = self.client
        try:
            c.GetFrame()
            frame = int(c.GetFrameNumber())
            latency = float(c.GetLatencyTotal())
            subjects = list(c.GetSubjectNames())
        except self._exc:
            self.counters["frame_errors"] += 1
            return None
        t_recv = self.clock()
        if not math.isfinite(latency) or latency < 0:
            latency = 0.0
        t = t_recv - latency
        out = []
        for subj in subjects:
            seg = self._segment(subj)
            try:
                (tx, ty, tz), occ_t = c.GetSegmentGlobalTranslation(subj, seg)
                (qx, qy, qz, qw), occ_r = c.GetSegmentGlobalRotationQuaternion(subj, seg)
            except self._exc:
                out.append(occluded_sample(subj, frame, t, t_recv))
                continue
            vals = (tx, ty, tz, qx, qy, qz, qw)
            finite = all(math.isfinite(v) for v in vals)
            norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw) if finite else 0.0
            if occ_t or occ_r or not finite or abs(norm - 1.0) > 1e-3:
                if not (occ_t or occ_r):
                    self.counters["bad_values"] += 1
                out.append(occluded_sample(subj, frame, t, t_recv))
                continue
            out.append(PoseSample(subj, frame, t, t_recv, tx * 1e-3, ty * 1e-3, tz * 1e-3,
                                  qx / norm, qy / norm, qz / norm, qw / norm))
        self.counters["frames"] += 1
        return out

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        while not stop.is_set():
            batch = self.read_frame()
            if batch:
                yield batch
            elif batch is None:
                time.sleep(0.01)  # server hiccup: do not spin

    def close(self) -> None:
        try:
            self.client.Disconnect()
        except Exception:
            pass

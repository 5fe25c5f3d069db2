"""``tpods view``: the Foxglove WebSocket server fed from Zenoh (tpods/viewer.py).

A protocol client (the ``websockets`` library, subprotocol ``foxglove.sdk.v1``: the SDK's
name for the Foxglove WebSocket protocol v1, which it no longer accepts under the old name
``foxglove.websocket.v1``) checks the advertised channels, subscribes and decodes the binary
message frames (opcode 1, subscription id, log time, payload) and the time frames (opcode 2).
The protobuf FrameTransform is decoded by hand (no protobuf library here), field numbers as in
the schema the server advertises.
"""

from __future__ import annotations

import json
import math
import signal
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path

import pytest
from websockets.sync.client import connect

from common.wire import (
    cmd_key,
    encode_command,
    encode_estimate,
    encode_pose,
    estimate_key,
    pose_key,
)
from tests.support.net import free_port, matching, wait_for
from tpods.cli import main
from tpods.view_layout import layout, layout_json, topics_in
from tpods.viewer import CLOCK_TOPIC, STATS_TOPIC, LiveView, estimate_view, topics_for

ROOT = Path(__file__).resolve().parents[2]
SUBPROTOCOL = "foxglove.sdk.v1"
T0 = 1763770000.0


# ------------------------------------------------------------------ a protocol client

def _varint(buf: bytes, i: int) -> tuple[int, int]:
    v = shift = 0
    while True:
        b = buf[i]
        i += 1
        v |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return v, i


def pb_fields(buf: bytes) -> dict[int, object]:
    """A protobuf message's fields by number (varint, fixed64 as double, length-delimited)."""
    out: dict[int, object] = {}
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        num, wt = key >> 3, key & 7
        if wt == 0:
            v, i = _varint(buf, i)
        elif wt == 1:
            v = struct.unpack_from("<d", buf, i)[0]
            i += 8
        elif wt == 2:
            n, i = _varint(buf, i)
            v = bytes(buf[i:i + n])
            i += n
        else:
            raise AssertionError(f"unexpected wire type {wt}")
        out[num] = v
    return out


def decode_frame_transform(buf: bytes) -> dict[str, object]:
    f = pb_fields(buf)
    ts, tr, rot = (pb_fields(f.get(k, b"")) for k in (1, 4, 5))
    return {"sec": ts.get(1, 0), "nsec": ts.get(2, 0), "parent": f.get(2, b"").decode(),
            "child": f.get(3, b"").decode(),
            "translation": tuple(tr.get(k, 0.0) for k in (1, 2, 3)),
            "rotation": tuple(rot.get(k, 0.0) for k in (1, 2, 3, 4))}


class Client:
    """Foxglove WebSocket client: channels advertised, messages per topic, time frames."""

    def __init__(self, url: str) -> None:
        self._cm = connect(url, subprotocols=[SUBPROTOCOL], open_timeout=5)
        self.ws = self._cm.__enter__()
        self.channels: dict[str, dict] = {}
        self.server_info: dict | None = None
        self.subs: dict[int, str] = {}
        self.msgs: dict[str, list[tuple[int, bytes]]] = {}
        self.times: list[int] = []
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        try:
            for m in self.ws:
                if isinstance(m, str):
                    d = json.loads(m)
                    with self.lock:
                        if d["op"] == "serverInfo":
                            self.server_info = d
                        elif d["op"] == "advertise":
                            for ch in d["channels"]:
                                self.channels[ch["topic"]] = ch
                    continue
                op = m[0]
                if op == 1:
                    sub_id, log_ns = struct.unpack_from("<IQ", m, 1)
                    with self.lock:
                        self.msgs.setdefault(self.subs[sub_id], []).append((log_ns, bytes(m[13:])))
                elif op == 2:
                    with self.lock:
                        self.times.append(struct.unpack_from("<Q", m, 1)[0])
        except Exception:  # the connection closed
            pass

    def subscribe(self, topics) -> None:
        subs = []
        with self.lock:
            for topic in topics:
                sid = len(self.subs) + 1
                self.subs[sid] = topic
                subs.append({"id": sid, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def got(self, topic: str) -> list[tuple[int, bytes]]:
        with self.lock:
            return list(self.msgs.get(topic, []))

    def json(self, topic: str) -> list[tuple[int, dict]]:
        return [(t, json.loads(p)) for t, p in self.got(topic)]

    def close(self) -> None:
        self._cm.__exit__(None, None, None)
        self.thread.join(5)


def ns(t: float) -> int:
    return int(round(t * 1e9))


def _publishers(session, keys, unwatched=()):
    pubs = {k: session.declare_publisher(k) for k in keys}
    assert wait_for(lambda: all(matching(p) for p in pubs.values()), 10.0), "viewer not subscribed"
    return pubs | {k: session.declare_publisher(k) for k in unwatched}


def _estimate(body: str, t: float, mass: float, sm: float, izz: float, si: float, **kw) -> dict:
    d = {"schema": "tpods.estimate/1", "body": body, "seq": 3, "t": t, "frame": 7, "t_pub": t + 0.002,
         "method": "ls-ekf", "phase": "catching-up", "mass_kg": mass, "mass_sigma_kg": sm,
         "izz_kgm2": izz, "izz_sigma_kgm2": si, "mass_sigma_noise_kg": sm * 0.6,
         "mass_sigma_thrust_kg": sm * 0.8, "izz_sigma_noise_kgm2": si * 0.6,
         "izz_sigma_thrust_kgm2": si * 0.8,
         "state": dict.fromkeys(("x", "y", "psi", "u", "v", "r"), 0.0),
         "state_sigma": dict.fromkeys(("x", "y", "psi", "u", "v", "r"), 0.1),
         "n_updates": 420, "nis": 2.7, "diverged": False, "inconsistent": True}
    d.update(kw)
    return d


# ------------------------------------------------------------------ tests

def test_view_advertises_and_serves_what_zenoh_carries(zenoh_pair):
    pub, sub, _ep = zenoh_pair
    with LiveView(sub, port=0, bodies=["tpods1", "tpods2"], pose_rate=0) as view:
        cl = Client(f"ws://127.0.0.1:{view.port}")
        try:
            expected = {t for b in ("tpods1", "tpods2") for t in topics_for(b).values()}
            expected |= {CLOCK_TOPIC, STATS_TOPIC}
            assert wait_for(lambda: expected <= set(cl.channels), 5.0), sorted(cl.channels)
            assert cl.server_info["capabilities"] == ["time"]
            ch = cl.channels
            assert (ch["/tpods/tpods1/frame"]["schemaName"], ch["/tpods/tpods1/frame"]["encoding"],
                    ch["/tpods/tpods1/frame"]["schemaEncoding"]) == (
                "foxglove.FrameTransform", "protobuf", "protobuf")
            for kind in ("pose", "duty", "estimate", "health"):
                c = ch[f"/tpods/tpods1/{kind}"]
                assert (c["schemaName"], c["encoding"], c["schemaEncoding"]) == (
                    f"tpods.view.{kind}/1", "json", "jsonschema")
                assert json.loads(c["schema"])["title"] == f"tpods.view.{kind}/1"
            assert ch[CLOCK_TOPIC]["schemaName"] == "tpods.view.clock/1"

            cl.subscribe(sorted(expected))
            assert wait_for(lambda: all(c.has_sinks() for b in view.bodies.values()
                                        for c in (b.frame, b.pose, b.duty, b.estimate, b.health)),
                            5.0)
            assert wait_for(lambda: view._clock.has_sinks(), 5.0)

            keys = [pose_key("tpods/mocap", b) for b in ("tpods1", "tpods2", "tpods3")]
            keys += [cmd_key("tpods1"), estimate_key("tpods1")]
            pubs = _publishers(pub, keys[:2] + keys[3:], unwatched=[keys[2]])  # tpods3: not shown
            poses = [(1, T0 + 0.00, (0.10, -0.20, 0.01, 0, 0, 0.38, 0.92, 0.78)),
                     (2, T0 + 0.01, None),                          # occluded
                     (3, T0 + 0.02, (0.12, -0.19, 0.01, 0, 0, -0.5, 0.86, -1.05))]
            for frame, t, p in poses:
                pubs[keys[0]].put(encode_pose("tpods1", frame, t, t + 0.003, p))
            # keys are not ordered among each other: tpods2's pose (the newest) once these are in
            assert wait_for(lambda: len(cl.got(CLOCK_TOPIC)) == 3, 5.0), view.counters
            pubs[keys[1]].put(encode_pose("tpods2", 9, T0 + 0.03, T0 + 0.031,
                                          (1.5, 0.5, 0.0, 0, 0, 0, 1, 0.0)))
            pubs[keys[2]].put(encode_pose("tpods3", 1, T0, T0, (0, 0, 0, 0, 0, 0, 1, 0.0)))
            pubs[keys[0]].put(b"not json")                               # malformed: counted
            pubs[keys[0]].put(b'{"schema": "tpods.pose/1", "body": "tpods1"}')
            pubs[keys[3]].put(encode_command("tpods1", 1, T0 + 0.005, [50, 0, 25.5, 100]))
            pubs[keys[3]].put(encode_command("tpods1", 2, T0 + 0.015, [0, 0, 0, 0], kind="end"))
            pubs[keys[3]].put(b'{"schema":"tpods.cmd/1","seq":3,"t":1.0,"duty":[1,2]}')
            est = _estimate("tpods1", T0 + 0.02, 2.27, 0.013, 3.78e-3, 2.1e-5)
            pubs[keys[4]].put(encode_estimate(est))
            pubs[keys[4]].put(encode_estimate({**est, "mass_kg": "heavy"}))
            pubs[keys[4]].put(b"\xff\xfe")

            def arrived() -> bool:
                return (len(cl.got("/tpods/tpods1/pose")) == 3 and len(cl.got("/tpods/tpods1/frame")) == 2
                        and len(cl.got("/tpods/tpods2/frame")) == 1 and len(cl.got("/tpods/tpods1/duty")) == 2
                        and len(cl.got("/tpods/tpods1/health")) == 1
                        and view.counters.get("estimate_received", 0) == 3
                        and view.counters.get("cmd_received", 0) == 3)
            assert wait_for(arrived, 5.0), (view.counters, {t: len(v) for t, v in cl.msgs.items()})

            # poses: the JSON pose and the 3D frame (yaw as a quaternion about z), log time = t
            got = cl.json("/tpods/tpods1/pose")
            assert [t for t, _ in got] == [ns(t) for _, t, _ in poses]
            for (_, d), (frame, t, p) in zip(got, poses, strict=True):
                assert (d["body"], d["frame"], d["t"], d["occluded"]) == ("tpods1", frame, t, p is None)
                if p is None:
                    assert [d[k] for k in ("x", "y", "z", "yaw", "yaw_deg")] == [None] * 5
                else:
                    assert (d["x"], d["y"], d["z"], d["yaw"]) == (p[0], p[1], p[2], p[7])
                    assert d["yaw_deg"] == pytest.approx(math.degrees(p[7]), abs=1e-12)
            frames = cl.got("/tpods/tpods1/frame")
            for (log_ns, payload), (_, t, p) in zip(frames, [poses[0], poses[2]], strict=True):
                f = decode_frame_transform(payload)
                assert log_ns == ns(t) and f["sec"] * 10**9 + f["nsec"] == ns(t)
                assert (f["parent"], f["child"]) == ("table", "tpods1")
                assert f["translation"] == (p[0], p[1], p[2])
                assert f["rotation"] == pytest.approx((0.0, 0.0, math.sin(p[7] / 2),
                                                       math.cos(p[7] / 2)), abs=1e-15)
            f2 = decode_frame_transform(cl.got("/tpods/tpods2/frame")[0][1])
            assert (f2["child"], f2["translation"], f2["rotation"]) == (
                "tpods2", (1.5, 0.5, 0.0), (0.0, 0.0, 0.0, 1.0))

            # duties, per channel
            duty = cl.json("/tpods/tpods1/duty")
            assert [t for t, _ in duty] == [ns(T0 + 0.005), ns(T0 + 0.015)]
            assert duty[0][1] == {"body": "tpods1", "t": T0 + 0.005, "seq": 1, "kind": "set",
                                  "duty": [50.0, 0.0, 25.5, 100.0], "d1": 50.0, "d2": 0.0,
                                  "d3": 25.5, "d4": 100.0}
            assert duty[1][1]["kind"] == "end" and duty[1][1]["duty"] == [0.0] * 4

            # the estimate with its 1-sigma band and the parts of sigma; the health
            (log_ns, e), = cl.json("/tpods/tpods1/estimate")
            assert log_ns == ns(T0 + 0.02)
            assert (e["mass_kg"], e["mass_sigma_kg"], e["izz_kgm2"], e["izz_sigma_kgm2"]) == (
                2.27, 0.013, 3.78e-3, 2.1e-5)
            assert (e["mass_lo_kg"], e["mass_hi_kg"]) == (2.27 - 0.013, 2.27 + 0.013)
            assert (e["izz_lo_kgm2"], e["izz_hi_kgm2"]) == (3.78e-3 - 2.1e-5, 3.78e-3 + 2.1e-5)
            assert (e["mass_sigma_noise_kg"], e["mass_sigma_thrust_kg"]) == (0.013 * 0.6, 0.013 * 0.8)
            assert (e["izz_sigma_noise_kgm2"], e["izz_sigma_thrust_kgm2"]) == (2.1e-5 * 0.6, 2.1e-5 * 0.8)
            assert (e["phase"], e["method"], e["t_pub"]) == ("catching-up", "ls-ekf", T0 + 0.022)
            (_, h), = cl.json("/tpods/tpods1/health")
            assert {k: h[k] for k in ("n_updates", "nis", "diverged", "inconsistent", "phase",
                                      "status", "status_level")} == {
                "n_updates": 420, "nis": 2.7, "diverged": False, "inconsistent": True,
                "phase": "catching-up", "status": "inconsistent", "status_level": 1}
            assert h["lag_s"] == pytest.approx(0.002, abs=1e-6)

            # the run's clock: lab time of the newest pose, on its channel and as server time
            assert wait_for(lambda: cl.times and cl.times[-1] == ns(T0 + 0.03), 5.0), cl.times
            assert wait_for(lambda: len(cl.got(CLOCK_TOPIC)) == 4, 5.0)  # time frames overtake data
            clock = [d for _, d in cl.json(CLOCK_TOPIC)]
            assert [d["t_lab"] for d in clock] == [T0, T0 + 0.01, T0 + 0.02, T0 + 0.03]  # occluded too
            assert [d["body"] for d in clock] == ["tpods1"] * 3 + ["tpods2"]

            # bad messages counted and skipped; other bodies not shown
            c = view.counters
            assert c["pose_skipped"] == 2 and c["cmd_skipped"] == 1 and c["estimate_skipped"] == 2
            assert c["malformed"] == 5 and c.get("errors", 0) == 0
            assert c["pose_received"] == 6  # 5 of tpods1, 1 of tpods2: tpods3 not subscribed
            assert "tpods3" not in view.bodies and "/tpods/tpods3/pose" not in cl.channels
            assert (c["pose_shown"], c["cmd_shown"], c["estimate_shown"]) == (4, 2, 1)
        finally:
            cl.close()


def test_view_every_body_seen_and_decimation(zenoh_pair):
    pub, sub, _ep = zenoh_pair
    with LiveView(sub, port=0, pose_rate=10) as view:
        cl = Client(f"ws://127.0.0.1:{view.port}")
        try:
            assert wait_for(lambda: CLOCK_TOPIC in cl.channels, 5.0)
            assert not any(t.startswith("/tpods/b9/") for t in cl.channels)
            key = pose_key("tpods/mocap", "b9")
            p = _publishers(pub, [key])[key]
            p.put(encode_pose("b9", 1, T0, T0, (0.0, 0.0, 0.0, 0, 0, 0, 1, 0.0)))
            assert wait_for(lambda: set(topics_for("b9").values()) <= set(cl.channels), 5.0)
            cl.subscribe(["/tpods/b9/pose"])
            assert wait_for(lambda: view.bodies["b9"].pose.has_sinks(), 5.0)
            # 10 Hz: of poses 0.05 s apart every other one; an old one (a restarted clock) starts over
            ts = [T0 + 1.0 + 0.05 * k for k in range(6)] + [T0 - 100.0]
            for k, t in enumerate(ts):
                p.put(encode_pose("b9", 10 + k, t, t, (0.1 * k, 0.0, 0.0, 0, 0, 0, 1, 0.0)))
            assert wait_for(lambda: len(cl.got("/tpods/b9/pose")) == 4, 5.0), view.counters
            assert [d["t"] for _, d in cl.json("/tpods/b9/pose")] == [ts[0], ts[2], ts[4], ts[6]]
            assert view.counters["pose_decimated"] == 3
        finally:
            cl.close()


def test_estimate_view_keeps_nulls_and_refuses_wrong_types():
    est = _estimate("b", T0, 2.0, 0.1, 1e-3, 1e-5, nis=None, mass_sigma_thrust_kg=None)
    e, h = estimate_view("b", est)
    assert (e["mass_sigma_thrust_kg"], h["nis"], h["status"]) == (None, None, "inconsistent")
    e, h = estimate_view("b", {**est, "mass_sigma_kg": None, "diverged": True})
    assert (e["mass_lo_kg"], e["mass_hi_kg"], h["status_level"]) == (None, None, 2)
    for bad in ({"t": None}, {"mass_kg": "2"}, {"n_updates": 1.5}, {"phase": 3}):
        assert estimate_view("b", {**est, **bad}) is None


def test_layout_is_the_shipped_file_and_uses_only_served_topics(tmp_path, capsys):
    shipped = ROOT / "docs" / "foxglove" / "tpods_layout.json"
    assert shipped.read_text() == layout_json(), "regenerate: tpods view --write-layout ... --force"
    served = set(topics_for("tpods1").values()) | {CLOCK_TOPIC}
    assert topics_in(layout()) <= served
    out = tmp_path / "two.json"
    assert main(["view", "--write-layout", str(out), "--body", "a", "--body", "b"]) == 0
    doc = json.loads(out.read_text())
    assert topics_in(doc) <= set(topics_for("a").values()) | set(topics_for("b").values()) | {CLOCK_TOPIC}
    assert main(["view", "--write-layout", str(out)]) == 2
    assert "already exists; add --force" in capsys.readouterr().err


@pytest.mark.parametrize("host", ["999.1.1.1", "busy"])
def test_view_port_in_use_or_bad_host_is_one_line(host, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        args = ["view", "--port", str(port), "--host", "127.0.0.1" if host == "busy" else host,
                "--no-multicast", "--listen", f"tcp/127.0.0.1:{free_port()}"]
        assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpods: error: cannot serve on"), err
    assert ("choose another --port" if host == "busy" else "check --host") in err[0]


def test_view_cli_through_a_connected_endpoint_and_ctrl_c(tpods_exe, zenoh_pair):
    """As with a router: the viewer connects to an endpoint (here the test's listening peer)."""
    pub, _sub, ep = zenoh_pair
    port = free_port()
    proc = subprocess.Popen([tpods_exe, "view", "--port", str(port), "--body", "tpods1",
                             "--connect", ep, "--no-multicast", "--pose-rate", "0", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cl = None
    try:
        assert "serving on ws://localhost:" in proc.stderr.readline()
        cl = Client(f"ws://127.0.0.1:{port}")
        assert wait_for(lambda: "/tpods/tpods1/pose" in cl.channels, 5.0)
        cl.subscribe(["/tpods/tpods1/pose"])
        key = pose_key("tpods/mocap", "tpods1")
        p = _publishers(pub, [key])[key]
        frame = [0]

        def shown() -> bool:  # the subscription may land after a put: put until one arrives
            frame[0] += 1
            p.put(encode_pose("tpods1", frame[0], T0 + frame[0], T0, (1, 2, 0, 0, 0, 0, 1, 0.0)))
            time.sleep(0.02)
            return bool(cl.got("/tpods/tpods1/pose"))
        assert wait_for(shown, 5.0)
        d = cl.json("/tpods/tpods1/pose")[0][1]
        assert (d["x"], d["y"], d["body"]) == (1.0, 2.0, "tpods1")
    finally:
        if cl is not None:
            cl.close()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "view: stopped;" in out and "estimates shown for 1 bodies" in out

"""The Vicon Tracker fixture: an emulated Tracker stream captured through the bridge's real
capture path, and its replay through the bridge and the recorder.

``python -m tests.support.fixtures_vicon`` (re)makes ``runs/fixtures/vicon-tracker/``:
``tracker.pcap`` (3 s at 100 Hz of two bodies, ``tpods1`` circling and ``truss`` turning
slowly, with occlusions and one malformed datagram, every datagram padded to Tracker's
1024-byte Data Block Size, sent on loopback to a ``ViconUDPSource`` capturing into the
file while a bridge publishes) and the goldens beside it (``golden/<body>/poses.csv`` and
``golden/counters.json``) from :func:`replay_and_record`, written by
tests/support/golden.py. ``--goldens-only`` recomputes the goldens from the checked-in
capture (as ``make golden`` / ``pytest tests/regression --update-goldens`` does).
tests/regression/test_vicon_fixture.py compares against them.
"""

from __future__ import annotations

import json
import math
import socket
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

from common.zenoh_net import open_session
from mocap_bridge.bridge import Bridge
from mocap_bridge.recorder import Recorder, subscribe
from mocap_bridge.sources.pcap import PcapSource
from mocap_bridge.sources.vicon_udp import ViconUDPSource, tracker_datagrams
from tests.support.net import free_port, matching, wait_for

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "runs" / "fixtures" / "vicon-tracker"
PCAP = "tracker.pcap"
BODIES = ("tpods1", "truss")
RATE_HZ = 100.0
N_FRAMES = 300
FIRST_FRAME = 52_000
BLOCK = 1024
MALFORMED_AFTER = 150
"""The malformed datagram goes out after this many frames."""
NAN6 = (math.nan,) * 6
ZERO6 = (0.0,) * 6


def tracker_frames(n: int = N_FRAMES, rate_hz: float = RATE_HZ) -> list[tuple[int, list]]:
    """``(frame number, object items)`` of the emulated Tracker: mm and rad, Euler XYZ.

    Occlusions: ``tpods1`` is NaN (not seen) for frames 40-47 and 200, ``truss`` sends
    Tracker's all-zero placeholder for frames 100-111 and NaN at 250."""
    out = []
    for k in range(n):
        t = k / rate_hz
        a = 0.9 * t
        p1 = (600.0 + 350.0 * math.cos(a), -200.0 + 350.0 * math.sin(a), 41.5,
              0.002 * math.sin(3 * t), -0.003 * math.cos(2 * t), math.remainder(a + math.pi / 2, 2 * math.pi))
        p2 = (-800.0 + 5.0 * t, 300.0 - 2.5 * t, 55.25, 0.0005, -0.0004, math.remainder(-0.4 * t + 3.0, 2 * math.pi))
        if 40 <= k < 48 or k == 200:
            p1 = NAN6
        if 100 <= k < 112:
            p2 = ZERO6
        if k == 250:
            p2 = NAN6
        out.append((FIRST_FRAME + k, [(0, "tpods1", p1), (0, "truss", p2)]))
    return out


def occluded_count(frames: list[tuple[int, list]]) -> int:
    return sum(1 for _, items in frames for _, _, v in items
               if v == ZERO6 or not all(math.isfinite(x) for x in v))


def malformed_datagram(frame: int) -> bytes:
    """Announces an object item of 2000 bytes in a 1024-byte block: cannot fit."""
    d = struct.pack("<IBBH", frame, 1, 0, 2000)
    return d + bytes(BLOCK - len(d))


def capture_emulated(path: Path, frames: list[tuple[int, list]] | None = None,
                     rate_hz: float = RATE_HZ, malformed_after: int | None = MALFORMED_AFTER,
                     session=None) -> tuple[list[bytes], dict]:
    """Send the emulated stream on loopback at ``rate_hz`` to a bridge running a
    ``ViconUDPSource`` that captures into ``path``; returns the datagrams sent (in order)
    and the source counters once everything was received."""
    frames = tracker_frames() if frames is None else frames
    own = session is None
    if own:
        session = open_session(listen=[f"tcp/127.0.0.1:{free_port()}"], no_multicast=True)
    src = ViconUDPSource(port=0, bind="127.0.0.1", capture=path, on_notice=None)
    bridge = Bridge(session, prefix="fixture/mocap", stats_period_s=0.5)
    stop = threading.Event()
    th = threading.Thread(target=bridge.run, args=(src,), kwargs={"stop": stop}, daemon=True)
    th.start()
    sent: list[bytes] = []
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        start = time.perf_counter() + 0.05
        for k, (f, items) in enumerate(frames):
            left = start + k / rate_hz - time.perf_counter()
            if left > 0:
                time.sleep(left)
            for d in tracker_datagrams(f, items, BLOCK):
                tx.sendto(d, src.address)
                sent.append(d)
            if malformed_after is not None and k + 1 == malformed_after:
                d = malformed_datagram(f)
                tx.sendto(d, src.address)
                sent.append(d)
        assert wait_for(lambda: src.counters["datagrams"] >= len(sent), 10.0), "datagrams lost"
    finally:
        stop.set()
        th.join(10.0)
        src.close()
        tx.close()
        if own:
            session.close()
    return sent, dict(src.counters)


def replay_and_record(pcap: Path, out: Path) -> dict:
    """Replay ``pcap`` through ``PcapSource`` (as fast as possible) and the bridge on one
    loopback Zenoh peer, recorded by ``Recorder`` on another; returns the counters
    (``bridge``: per-body published/occluded/duplicates/gaps, ``source``, ``recorder``)."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    pub = open_session(listen=[ep], no_multicast=True)
    sub = open_session(connect=[ep], no_multicast=True)
    try:
        assert wait_for(lambda: len(pub.info.peers_zid()) > 0, 10.0), "peers did not connect"
        rec = Recorder(out, key="tpods/mocap/*/pose")
        s = subscribe(sub, "tpods/mocap/*/pose", rec)
        probe = pub.declare_publisher("tpods/mocap/probe/pose")
        assert wait_for(lambda: matching(probe), 10.0), "recorder never matched"
        probe.undeclare()
        src = PcapSource(pcap, rate_scale=0.0, on_notice=None, on_warning=None)
        bridge = Bridge(pub, stats_period_s=10.0)
        stats = bridge.run(src)
        src.close()
        total = stats.totals()["published"]
        assert wait_for(lambda: rec.counters["received"] >= total, 20.0), "poses lost"
        s.undeclare()
        rcounters = rec.close()
    finally:
        sub.close()
        pub.close()
    bodies = {name: {"published": b.published, "occluded": b.occluded,
                     "duplicates": b.duplicates, "gaps": b.gaps}
              for name, b in sorted(stats.bodies.items())}
    keep = ("datagrams", "malformed", "items", "padded", "skipped_items", "pcap_records", "udp",
            "non_udp", "truncated_records")
    return {"bridge": bodies, "source": {k: stats.source_counters.get(k, 0) for k in keep},
            "recorder": {k: rcounters[k] for k in ("received", "recorded", "occluded",
                                                   "malformed", "not_increasing")}}


def flat_counters(counters: dict) -> dict[str, float]:
    """``{"bridge": {"tpods1": {"occluded": 9}}}`` -> ``{"bridge.tpods1.occluded": 9}``."""
    out: dict[str, float] = {}

    def walk(prefix: str, d: dict) -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(f"{prefix}{k}.", v)
            else:
                out[f"{prefix}{k}"] = v
    walk("", counters)
    return out


def check_goldens(rec: Path, counters: dict, fixture: Path = FIXTURE) -> None:
    """The replay's ``poses.csv`` of each body and its counters against ``fixture/golden``
    (tests/support/golden.py: poses to 1e-12, counters exactly; rewritten instead with
    ``--update-goldens``)."""
    import pandas as pd

    from tests.support.golden import check_frame, check_values

    for body in BODIES:
        check_frame(pd.read_csv(rec / body / "poses.csv"), fixture / "golden" / body / "poses.csv",
                    atol=1e-12, what=f"{body}/poses.csv")
    check_values(flat_counters(counters), fixture / "golden" / "counters.json", atol=0.0,
                 what="the bridge, source and recorder counters")


def write_goldens(fixture: Path = FIXTURE) -> dict:
    """Replay the fixture's capture and (re)write ``golden/`` beside it, printing what
    moved; returns the counters."""
    from tests.support import golden

    with tempfile.TemporaryDirectory() as tmp:
        counters = replay_and_record(fixture / PCAP, Path(tmp) / "rec")
        old = golden.UPDATE["on"]
        golden.UPDATE["on"] = True
        try:
            check_goldens(Path(tmp) / "rec", counters, fixture)
        finally:
            golden.UPDATE["on"] = old
    return counters


def make(fixture: Path = FIXTURE) -> dict:
    """Capture the emulated stream into ``fixture/tracker.pcap``, then the goldens."""
    fixture.mkdir(parents=True, exist_ok=True)
    tmp = fixture / (PCAP + ".new")
    _, counters = capture_emulated(tmp)
    assert counters["captured"] == counters["datagrams"] and counters["malformed"] == 1
    tmp.replace(fixture / PCAP)
    return write_goldens(fixture)


def main(argv: list[str]) -> int:
    counters = write_goldens() if "--goldens-only" in argv else make()
    print(json.dumps(counters, indent=2, sort_keys=True))
    print(f"wrote {FIXTURE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))

"""pcap capture of the Tracker stream and its replay (issue 19).

The capture is read back with dpkt, a pcap library that is not ours; replays go through
the same Tracker parser and bridge as live datagrams."""

from __future__ import annotations

import math
import os
import signal
import socket
import struct
import subprocess
import threading
import time

import dpkt
import pytest

from mocap_bridge.bridge import Bridge
from mocap_bridge.capture import LINKTYPE_RAW, PcapReader, PcapWriter, capture_path
from mocap_bridge.pose import decode_pose
from mocap_bridge.sources import open_source
from mocap_bridge.sources.pcap import PcapSource
from mocap_bridge.sources.vicon_udp import DatagramDecoder, ViconUDPSource, build_datagram
from tests.support.cli import run_in_process
from tests.support.fixtures_vicon import capture_emulated, tracker_frames
from tests.support.net import Collector, RunningBridge, free_port, subscribe_ready, wait_for

POSE_VALUES = ("body", "frame", "x", "y", "z", "qx", "qy", "qz", "qw", "yaw", "occluded")


def _values(payloads: list[bytes]) -> list[tuple]:
    return [tuple(d[k] for k in POSE_VALUES) for d in map(decode_pose, payloads)]


def _dpkt_records(path) -> tuple[int, list[tuple[float, dpkt.ip.IP]]]:
    with open(path, "rb") as f:
        r = dpkt.pcap.Reader(f)
        return r.datalink(), [(ts, dpkt.ip.IP(buf)) for ts, buf in r]


def _ip_header_checksum_ok(ip: dpkt.ip.IP) -> bool:
    hdr = bytes(ip)[:20]
    s = sum(struct.unpack("!10H", hdr))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return s == 0xFFFF


def _replay(zenoh_pair, path, prefix, speed=0.0) -> tuple[Collector, Bridge, PcapSource]:
    pub_s, sub_s, _ = zenoh_pair
    col = Collector()
    sub = subscribe_ready(pub_s, sub_s, f"{prefix}/*/pose", col)
    src = PcapSource(path, rate_scale=speed, on_notice=None, on_warning=None)
    bridge = Bridge(pub_s, prefix=prefix, stats_period_s=0.5)
    bridge.run(src)
    src.close()
    n = bridge.stats.totals()["published"]
    assert wait_for(lambda: len(col) >= n, 10.0)
    sub.undeclare()
    return col, bridge, src


def test_capture_holds_every_datagram_for_dpkt_and_replays_to_the_same_poses(zenoh_pair, tmp_path):
    """Live: emulator -> ViconUDPSource(capture) -> bridge -> Zenoh. The file, read by
    dpkt, holds every datagram's bytes in order with the real ports; replayed through
    --source pcap it publishes the very same pose values (same floats)."""
    pub_s, sub_s, _ = zenoh_pair
    path = tmp_path / "live.pcap"
    frames = tracker_frames(60)
    t_before = time.time()
    sent, counters = capture_emulated(path, frames, rate_hz=200.0, malformed_after=30)
    t_after = time.time()
    assert counters["captured"] == len(sent) == 61 and counters["malformed"] == 1
    assert counters["capture_errors"] == 0

    link, recs = _dpkt_records(path)
    assert link == LINKTYPE_RAW
    assert [bytes(ip.udp.data) for _, ip in recs] == sent
    ts = [t for t, _ in recs]
    assert ts == sorted(ts) and t_before <= ts[0] and ts[-1] <= t_after
    assert ts[-1] - ts[0] == pytest.approx(59 / 200.0, abs=0.1)  # the pace it was sent at
    ports = {(ip.udp.sport, ip.udp.dport) for _, ip in recs}
    assert len(ports) == 1 and all(p > 0 for p in ports.pop())
    for _, ip in recs:
        assert ip.p == 17 and ip.src == ip.dst == socket.inet_aton("127.0.0.1")
        assert ip.len == 28 + len(ip.udp.data) and ip.udp.ulen == 8 + len(ip.udp.data)
        assert _ip_header_checksum_ok(ip)

    # the same datagrams live through a bridge on our pair, then the capture replayed
    live = Collector()
    sub = subscribe_ready(pub_s, sub_s, "live/*/pose", live)
    src = ViconUDPSource(port=0, bind="127.0.0.1", on_notice=None)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with RunningBridge(Bridge(pub_s, prefix="live"), src):
        for k, d in enumerate(sent):
            tx.sendto(d, src.address)
            assert wait_for(lambda k=k: src.counters["datagrams"] > k, 5.0)
        assert wait_for(lambda: len(live) >= 120, 10.0)
    tx.close()
    sub.undeclare()
    replayed, bridge, rsrc = _replay(zenoh_pair, path, "replay")
    assert len(live.items) == 120 and _values(live.of_key("/pose")) == _values(replayed.of_key("/pose"))
    assert rsrc.counters["malformed"] == 1 and rsrc.counters["datagrams"] == 61
    assert bridge.stats.totals()["occluded"] == sum(
        1 for _, its in frames for _, _, v in its if v == (0.0,) * 6 or not all(map(math.isfinite, v)))
    # t_src: the capture time relative to the first datagram, from the file's timestamps
    dec = [decode_pose(p) for p in replayed.of_key("/pose")]
    assert dec[0]["t_src"] == 0.0
    assert dec[-1]["t_src"] == pytest.approx(ts[-1] - ts[0], abs=2e-6)


def test_replay_keeps_the_recorded_pace_scaled(tmp_path):
    """Datagrams 0.1 s apart in the file come out 0.1 s / speed apart."""
    path = tmp_path / "paced.pcap"
    with open(path, "wb") as f:
        w = dpkt.pcap.Writer(f, linktype=dpkt.pcap.DLT_EN10MB)
        for k in range(5):
            w.writepkt(_eth_udp(build_datagram(k + 1, [(0, "m", (1.0, 2.0, 3.0, 0, 0, 0.1))], 256)),
                       ts=1000.0 + 0.1 * k)
    for speed, span in ((1.0, 0.4), (4.0, 0.1)):
        src = PcapSource(path, rate_scale=speed)
        t0 = time.monotonic()
        got = [(b[0].t_src, time.monotonic() - t0) for b in src.batches(threading.Event())]
        src.close()
        assert [round(t, 9) for t, _ in got] == [0.0, 0.1, 0.2, 0.3, 0.4]
        assert span - 0.01 <= got[-1][1] < span + 0.25
    src = PcapSource(path, rate_scale=0.0)  # as fast as possible
    t0 = time.monotonic()
    assert len(list(src.batches(threading.Event()))) == 5 and time.monotonic() - t0 < 0.1


def _eth_udp(payload: bytes, sport=40000, dport=51001, src="192.168.10.2", dst="192.168.10.1") -> bytes:
    udp = dpkt.udp.UDP(sport=sport, dport=dport, data=payload)
    udp.ulen = len(udp)
    ip = dpkt.ip.IP(src=socket.inet_aton(src), dst=socket.inet_aton(dst), p=dpkt.ip.IP_PROTO_UDP,
                    data=udp, ttl=64)
    ip.len = len(ip)
    eth = dpkt.ethernet.Ethernet(src=b"\x00\x11\x22\x33\x44\x55", dst=b"\x66\x77\x88\x99\xaa\xbb",
                                 type=dpkt.ethernet.ETH_TYPE_IP, data=ip)
    return bytes(eth)


def _other_packets() -> list[bytes]:
    """What a capture on a lab network also holds: ARP, TCP, UDP to another port (mDNS)."""
    arp = dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\xff" * 6, type=dpkt.ethernet.ETH_TYPE_ARP,
                                 data=dpkt.arp.ARP())
    tcp = dpkt.ip.IP(src=b"\x0a\0\0\1", dst=b"\x0a\0\0\2", p=dpkt.ip.IP_PROTO_TCP,
                     data=dpkt.tcp.TCP(sport=1, dport=2))
    tcp.len = len(tcp)
    eth_tcp = dpkt.ethernet.Ethernet(type=dpkt.ethernet.ETH_TYPE_IP, data=tcp)
    return [bytes(arp), bytes(eth_tcp), _eth_udp(b"hello from another service", sport=5353, dport=5353)]


@pytest.mark.parametrize("fmt", ["pcap", "pcap-ns", "pcapng"])
def test_ethernet_capture_written_by_dpkt_replays(tmp_path, fmt):
    """A tcpdump/Wireshark-like capture (Ethernet/IPv4/UDP, written by dpkt's own
    writers, pcap or pcapng) replays through the Tracker parser; other packets are
    counted, and ?port= keeps only the Tracker stream."""
    frames = tracker_frames(20)
    datagrams = [build_datagram(f, items, 1024) for f, items in frames]
    path = tmp_path / f"wire.{'pcapng' if fmt == 'pcapng' else 'pcap'}"
    with open(path, "wb") as f:
        if fmt == "pcapng":
            w = dpkt.pcapng.Writer(f, linktype=dpkt.pcap.DLT_EN10MB)
        else:
            w = dpkt.pcap.Writer(f, linktype=dpkt.pcap.DLT_EN10MB, nano=fmt == "pcap-ns")
        extra = _other_packets()
        for k, d in enumerate(datagrams):
            if k % 7 == 3:
                w.writepkt(extra[k % 3], ts=2000.0 + 0.01 * k - 0.001)
            w.writepkt(_eth_udp(d), ts=2000.0 + 0.01 * k)
    ref_dec = DatagramDecoder()
    ref = [s for d in datagrams for s in ref_dec.decode(d, 0.0)]

    src = open_source(f"pcap:{path}?speed=0&port=51001")
    got = [s for b in src.batches(threading.Event()) for s in b]
    src.close()
    c = src.counters
    assert all(
        (a.body, a.frame, a.occluded) == (b.body, b.frame, b.occluded)
        and (a.occluded or (a.x, a.y, a.z, a.qx, a.qy, a.qz, a.qw) == (b.x, b.y, b.z, b.qx, b.qy, b.qz, b.qw))
        for a, b in zip(got, ref, strict=True))
    assert [round(s.t_src, 6) for s in got[::2]] == [round(0.01 * k, 6) for k in range(20)]
    assert c["datagrams"] == 20 and c["malformed"] == 0
    assert c["non_udp"] == 2 and c["other_port"] == 1 and c["pcap_records"] == 23
    # without the port filter the mDNS datagram reaches the parser and is malformed
    src = PcapSource(path, rate_scale=0, on_notice=None)
    assert sum(len(b) for b in src.batches(threading.Event())) == len(ref)
    assert src.counters["malformed"] == 1 and src.counters["non_udp"] == 2


def test_other_link_layers_vlan_and_fragments(tmp_path):
    """802.1Q-tagged Ethernet, Linux cooked (tcpdump -i any) and IP fragments (counted,
    not reassembled) are read by the reader."""
    d = build_datagram(7, [(0, "m", (1.0, 2.0, 3.0, 0, 0, 0.1))], 256)
    eth = _eth_udp(d)
    vlan = eth[:12] + b"\x81\x00\x00\x05" + eth[12:]
    frag = bytearray(eth)
    frag[14 + 6] |= 0x20  # more fragments
    path = tmp_path / "vlan.pcap"
    with open(path, "wb") as f:
        w = dpkt.pcap.Writer(f, linktype=dpkt.pcap.DLT_EN10MB)
        for k, pkt in enumerate((eth, vlan, bytes(frag))):
            w.writepkt(pkt, ts=10.0 + k)
    r = PcapReader(path)
    got = list(r)
    r.close()
    assert [g.payload for g in got] == [d, d] and r.counters["ip_fragments"] == 1
    assert got[0].src == ("192.168.10.2", 40000) and got[0].dst == ("192.168.10.1", 51001)
    sll = b"\x00\x00\x00\x01\x00\x06" + bytes(8) + b"\x08\x00" + eth[14:]
    path = tmp_path / "sll.pcap"
    with open(path, "wb") as f:
        w = dpkt.pcap.Writer(f, linktype=113)
        w.writepkt(sll, ts=1.0)
    assert [g.payload for g in PcapReader(path)] == [d]


def _write_capture(path, n=10) -> list[bytes]:
    sent = [build_datagram(f, [(0, "a", (float(f), 2.0, 3.0, 0, 0, 0.2)), (0, "b", (1.0, -1.0, 0.5, 0, 0, 1.0))], 1024)
            for f in range(1, n + 1)]
    with PcapWriter(path) as w:
        for k, d in enumerate(sent):
            w.write(d, ("10.0.0.5", 51000), ("10.0.0.9", 51001), 1.7e9 + 0.01 * k)
    return sent


@pytest.mark.parametrize("cut", [7, 16 + 20, 16 + 1000])  # in a record header / IP header / payload
def test_truncated_file_gives_every_whole_record_and_counts_the_broken_one(tmp_path, cut):
    path = tmp_path / "cut.pcap"
    sent = _write_capture(path)
    size = path.stat().st_size
    rec = 16 + 28 + 1024
    assert size == 24 + 10 * rec
    path.write_bytes(path.read_bytes()[: 24 + 9 * rec + cut])
    warnings = []
    src = PcapSource(path, rate_scale=0, on_warning=warnings.append)
    got = [s for b in src.batches(threading.Event()) for s in b]
    src.close()
    assert [s.frame for s in got[::2]] == list(range(1, 10)) and len(got) == 18
    assert src.counters["truncated_records"] == 1 and src.counters["datagrams"] == 9
    assert len(warnings) == 1 and "ends in the middle" in warnings[0]
    # dpkt reads the whole records (it may then stop on the broken one, or not see it)
    got_dpkt = []
    with open(path, "rb") as f:
        try:
            for _, buf in dpkt.pcap.Reader(f):
                got_dpkt.append(buf)
        except dpkt.NeedData:
            pass
    assert [bytes(dpkt.ip.IP(b).udp.data) for b in got_dpkt[:9]] == sent[:9]


def test_damaged_record_length_stops_reading_with_a_count(tmp_path):
    path = tmp_path / "bad.pcap"
    _write_capture(path, 3)
    b = bytearray(path.read_bytes())
    rec = 16 + 28 + 1024
    b[24 + rec + 8:24 + rec + 12] = struct.pack("<I", 1 << 30)
    path.write_bytes(bytes(b))
    src = PcapSource(path, rate_scale=0, on_warning=None)
    assert sum(len(x) for x in src.batches(threading.Event())) == 2
    assert src.counters["damaged_records"] == 1


def test_write_error_stops_the_capture_not_the_source(tmp_path):
    counters = {}
    warnings = []
    w = PcapWriter(tmp_path / "full.pcap", counters=counters, on_warning=warnings.append)
    w.write(b"abc", ("127.0.0.1", 1), ("127.0.0.1", 2), 1.0)
    os.close(w._fd)
    w._fd = os.open("/dev/full", os.O_WRONLY)  # every write: ENOSPC
    w.write(b"abc", ("127.0.0.1", 1), ("127.0.0.1", 2), 2.0)
    w.write(b"abc", ("127.0.0.1", 1), ("127.0.0.1", 2), 3.0)
    assert counters == {"captured": 1, "capture_errors": 1} and w.closed
    assert len(warnings) == 1 and "capture stopped after 1 datagrams" in warnings[0]
    with open(tmp_path / "full.pcap", "rb") as f:
        assert len(list(dpkt.pcap.Reader(f))) == 1


def test_capture_path_rules(tmp_path):
    from common.errors import UserError

    f = capture_path(tmp_path / "a.pcap")
    assert f == tmp_path / "a.pcap"
    f.write_bytes(b"x")
    with pytest.raises(UserError, match="already exists; add --force"):
        capture_path(f)
    assert capture_path(f, force=True) == f
    d = capture_path(tmp_path / "caps" / "day1", now=0.0)
    assert d.parent == tmp_path / "caps" / "day1" and d.name.startswith("vicon-udp-19")
    assert d.suffix == ".pcap" and d.parent.is_dir()
    with pytest.raises(UserError, match="classic pcap"):
        capture_path(tmp_path / "x.pcapng")


# ---------------------------------------------------------------- the command line


@pytest.mark.parametrize("content, msg", [
    (b"poses,t,x\n1,2,3\n" * 4, "not a pcap or pcapng file (it starts with 'poses,t,')"),
    (b"", "not a pcap file (empty)"),
    (struct.pack("<I", 0xA1B2C3D4) + bytes(6), "pcap header cut short (10 of 24 bytes)"),
    (None, "no such file"),
])
def test_not_a_pcap_is_one_line_error(tpods_exe, tmp_path, content, msg):
    path = tmp_path / "x.pcap"
    if content is not None:
        path.write_bytes(content)
    r = run_in_process("mocap", "bridge", "--source", f"pcap:{path}", "--no-multicast")
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [f"tpods: error: {path}: {msg}"], r.stderr


@pytest.mark.parametrize("args, msg", [
    (["--source", "replay:x", "--capture", "c.pcap"], "--capture records the raw datagrams of --source vicon-udp"),
    (["--source", "sim", "--capture", "c.pcap"], "--capture records the raw datagrams"),
    (["--source", "pcap:c.pcap?speed=fast"], "speed must be a number"),
    (["--source", "pcap:c.pcap?rate=2"], "unknown option 'rate=2'"),
    (["--source", "pcap:c.pcap?port=70000"], "bad UDP port 70000"),
    (["--source", "pcap:"], "--source pcap needs a file"),
])
def test_capture_and_pcap_user_errors(tpods_exe, tmp_path, args, msg):
    r = run_in_process("mocap", "bridge", *args, "--no-multicast", cwd=tmp_path)
    assert r.returncode == 2 and msg in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_cli_replays_a_truncated_capture_and_reports_it(tpods_exe, tmp_path):
    path = tmp_path / "cut.pcap"
    _write_capture(path, 5)
    path.write_bytes(path.read_bytes()[:-100])
    r = run_in_process("mocap", "bridge", "--source", f"pcap:{path}", "--speed", "0", "--listen",
                       f"tcp/127.0.0.1:{free_port()}", "--no-multicast", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "published 8 poses of 2 bodies" in r.stdout
    assert "4 datagrams, 0 malformed" in r.stdout and "1 truncated record (file cut)" in r.stdout
    assert "ends in the middle of a record (after 4 whole records)" in r.stderr
    assert "Traceback" not in r.stderr


def test_sigkill_leaves_a_readable_capture_missing_at_most_the_last_100_ms(tpods_exe, tmp_path):
    """`tpods mocap bridge --capture`, killed with SIGKILL while the stream runs: dpkt
    reads the whole file, and its last datagram is at most 0.1 s older than the kill."""
    port = free_port(socket.SOCK_DGRAM)
    cap = tmp_path / "caps"
    p = subprocess.Popen([tpods_exe, "mocap", "bridge", "--source", f"vicon-udp:{port}",
                          "--bind", "127.0.0.1", "--capture", str(cap), "--quiet",
                          "--listen", f"tcp/127.0.0.1:{free_port()}", "--no-multicast"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stop = threading.Event()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send():
        f = 0
        while not stop.is_set():
            f += 1
            tx.sendto(build_datagram(f, [(0, "m", (float(f), 2.0, 3.0, 0, 0, 0.1))], 1024),
                      ("127.0.0.1", port))
            time.sleep(0.002)

    th = threading.Thread(target=send, daemon=True)
    try:
        th.start()

        def records() -> int:
            files = list(cap.glob("*.pcap")) if cap.is_dir() else []
            return (files[0].stat().st_size - 24) // (16 + 28 + 1024) if files else 0

        assert wait_for(lambda: records() > 200, 60.0), "the bridge never captured"
        t_kill = time.time()
        os.kill(p.pid, signal.SIGKILL)
        p.wait(10)
    finally:
        stop.set()
        th.join(5)
        tx.close()
        if p.poll() is None:
            p.kill()
        p.communicate()
    (f,) = cap.glob("vicon-udp-*.pcap")
    # Linux can cut a write at a page boundary when SIGKILL arrives during it (mm/filemap.c
    # generic_perform_write stops on a pending fatal signal and returns the bytes copied), so
    # the file ends on a whole record or in at most one part of the last one; our reader
    # counts that one as "truncated record (file cut)", dpkt is given the whole records
    rec = 16 + 28 + 1024
    size = f.stat().st_size
    tail = (size - 24) % rec
    src = PcapSource(f, rate_scale=0)
    n_read = sum(1 for b in src.batches(threading.Event()) for _ in b)
    src.close()
    assert src.counters["truncated_records"] == (1 if tail else 0)
    assert src.counters["datagrams"] == (size - 24) // rec and n_read > 200
    whole = tmp_path / "whole.pcap"
    whole.write_bytes(f.read_bytes()[: size - tail])
    with open(whole, "rb") as fh:
        recs = [(ts, dpkt.ip.IP(b)) for ts, b in dpkt.pcap.Reader(fh)]
    assert len(recs) > 200 and len(recs) == (size - 24) // rec
    assert recs[-1][0] >= t_kill - 0.1
    frames = [struct.unpack_from("<I", bytes(ip.udp.data))[0] for _, ip in recs]
    assert frames == list(range(frames[0], frames[0] + len(frames)))  # in order, none missing

"""Vicon Tracker UDP: parsing, and datagrams through the bridge onto Zenoh."""

from __future__ import annotations

import math
import random
import socket
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap_bridge.bridge import Bridge
from mocap_bridge.pose import decode_pose, euler_xyz_to_quat, yaw_heading
from mocap_bridge.sources.vicon_udp import (
    DatagramDecoder,
    MalformedDatagram,
    ViconUDPSource,
    build_datagram,
    parse_datagram,
)
from tests.mocap.conftest import Collector, RunningBridge, subscribe_ready, wait_for


def _item(i, name, x=100.0, y=-250.0, z=12.5, rx=0.01, ry=-0.02, rz=1.0):
    return (i, name, (x, y, z, rx, ry, rz))


def test_layout_is_packed_little_endian():
    d = build_datagram(0x01020304, [_item(1, "a"), _item(2, "bb", x=5.0)])
    assert len(d) == 5 + 2 * 75
    assert d[:5] == b"\x04\x03\x02\x01\x02"
    assert d[5] == 1 and d[6:8] == b"\x48\x00" and d[8:10] == b"a\0"
    assert struct.unpack_from("<d", d, 5 + 3 + 24)[0] == 100.0
    # the second item starts at byte 80 (native alignment would put it elsewhere)
    assert d[80] == 2 and struct.unpack_from("<d", d, 80 + 27)[0] == 5.0
    frame, items = parse_datagram(d)
    assert frame == 0x01020304
    assert [(i, n) for i, n, _ in items] == [(1, "a"), (2, "bb")]
    assert items[1][2] == (5.0, -250.0, 12.5, 0.01, -0.02, 1.0)


@pytest.mark.parametrize("mutate", [
    lambda d: d[:4],                       # truncated header
    lambda d: d[:-1],                      # truncated item
    lambda d: d + b"\0",                   # trailing byte
    lambda d: d[:4] + bytes([3]) + d[5:],  # count says 3, holds 2
    lambda d: d[:6] + b"\x49\x00" + d[8:],  # item size 73
    lambda d: d[:8] + b"\0" * 24 + d[32:],  # empty name
    lambda d: d[:8] + b"\xff\xfe" + d[10:],  # not UTF-8
    lambda d: build_datagram(1, [_item(i, f"b{i}") for i in range(14)]),  # 1055 bytes > 1024
])
def test_malformed_datagrams_raise(mutate):
    good = build_datagram(9, [_item(1, "a"), _item(2, "b")])
    with pytest.raises(MalformedDatagram):
        parse_datagram(mutate(good))


def test_decoder_units_quaternion_and_occlusion():
    dec = DatagramDecoder(latency_s=0.004)
    d = build_datagram(77, [_item(1, "mod1", 1500.0, -250.0, 12.5, 0.01, -0.02, 2.5),
                            _item(2, "gone", math.nan, 0, 0, 0, 0, 0),
                            _item(3, "zeros", 0, 0, 0, 0, 0, 0)])
    out = dec.decode(d, 100.0)
    assert [s.body for s in out] == ["mod1", "gone", "zeros"]
    a = out[0]
    assert (a.x, a.y, a.z) == pytest.approx((1.5, -0.25, 0.0125))
    assert (a.qx, a.qy, a.qz, a.qw) == pytest.approx(euler_xyz_to_quat(0.01, -0.02, 2.5))
    assert a.t == pytest.approx(99.996) and a.t_recv == 100.0 and a.frame == 77
    assert not a.occluded and out[1].occluded and out[2].occluded
    assert dec.decode(d[:-3], 100.0) is None
    assert dec.counters["datagrams"] == 2 and dec.counters["malformed"] == 1
    dec.zero_is_occluded = False
    assert not dec.decode(d, 1.0)[2].occluded


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=1100))
def test_decoder_never_raises_on_random_bytes(data):
    dec = DatagramDecoder()
    out = dec.decode(data, 0.0)
    assert (out is None) == (dec.counters["malformed"] == 1)
    if out is not None:  # a random datagram can only be valid with an exact length
        assert (len(data) - 5) % 75 == 0


# ---------------------------------------------------------------- over Zenoh


def _bridge_setup(zenoh_pair, prefix="tpods/mocap"):
    pub_s, sub_s, _ = zenoh_pair
    col = Collector()
    sub = subscribe_ready(pub_s, sub_s, f"{prefix}/**", col)
    src = ViconUDPSource(port=0, bind="127.0.0.1")
    bridge = Bridge(pub_s, prefix=prefix, stats_period_s=0.2)
    return col, sub, src, bridge


def test_udp_to_zenoh_values_duplicates_gaps_occlusion(zenoh_pair):
    pub_s, sub_s, _ = zenoh_pair
    col, sub, src, bridge = _bridge_setup(zenoh_pair)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    frames = [
        (10, [_item(1, "mod 1", 1000.0, 2000.0, 50.0, 0.0, 0.0, 0.5), _item(2, "ref", 1, 2, 3, 0, 0, 0.1)]),
        (10, [_item(1, "mod 1", 9999.0, 0, 0, 0, 0, 0)]),            # repeated frame: dropped
        (11, [_item(1, "mod 1", math.nan, 0, 0, 0, 0, 0), _item(2, "ref", 1, 2, 3, 0, 0, 0.2)]),
        (14, [_item(1, "mod 1", -500.0, 250.0, 0.0, 0.1, -0.1, 3.0)]),  # 12, 13 missing
        (13, [_item(2, "ref", 1, 2, 3, 0, 0, 0.3)]),                 # late but new for "ref"
        (12, [_item(1, "mod 1", 1, 1, 1, 0, 0, 0)]),                 # older than 14: dropped
    ]
    with RunningBridge(bridge, src) as rb:
        for k, (f, items) in enumerate(frames):
            tx.sendto(build_datagram(f, items), src.address)
            assert wait_for(lambda k=k: src.counters["datagrams"] > k, 5.0)
        assert wait_for(lambda: len(col.of_key("/pose")) >= 6, 10.0)
        assert wait_for(lambda: len(col.of_key("/stats")) >= 1, 10.0)
        # liveliness token of the running bridge
        replies = list(sub_s.liveliness().get("tpods/mocap/bridge/**", timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is not None
        rb.stop()
    tx.close()
    sub.undeclare()
    mod = [decode_pose(p) for p in col.of_key("tpods/mocap/mod_1/pose")]
    ref = [decode_pose(p) for p in col.of_key("tpods/mocap/ref/pose")]
    assert [d["frame"] for d in mod] == [10, 11, 14]
    assert [d["frame"] for d in ref] == [10, 11, 13]
    m0 = mod[0]
    assert m0["body"] == "mod 1" and not m0["occluded"]
    assert (m0["x"], m0["y"], m0["z"]) == pytest.approx((1.0, 2.0, 0.05))
    assert m0["yaw"] == pytest.approx(0.5) and m0["qz"] == pytest.approx(math.sin(0.25))
    assert m0["t"] <= m0["t_recv"]
    assert mod[1]["occluded"] is True and mod[1]["x"] is None
    q = euler_xyz_to_quat(0.1, -0.1, 3.0)
    assert (mod[2]["qx"], mod[2]["qy"], mod[2]["qz"], mod[2]["qw"]) == pytest.approx(q)
    assert mod[2]["yaw"] == pytest.approx(yaw_heading(*q))
    st_ = bridge.stats.bodies
    assert st_["mod 1"].duplicates == 2 and st_["mod 1"].gaps == 2 and st_["mod 1"].occluded == 1
    assert st_["ref"].duplicates == 0 and st_["ref"].gaps == 1
    # the last stats message (published at close) holds the same counts
    import json
    last = json.loads(col.of_key("/stats")[-1]) if wait_for(
        lambda: json.loads(col.of_key("/stats")[-1])["published"] == 6, 5.0) else None
    assert last is not None and last["schema"] == "tpods.mocap-stats/1"
    assert last["duplicates"] == 2 and last["gaps"] == 3 and last["occluded"] == 1
    assert last["datagrams"] == 6 and last["malformed"] == 0
    assert last["bodies"]["mod 1"]["last_frame"] == 14


def test_fuzz_random_truncated_oversized_between_valid(zenoh_pair):
    """Thousands of bad datagrams between valid ones: every valid pose published,
    every bad datagram counted, no crash."""
    col, sub, src, bridge = _bridge_setup(zenoh_pair)
    rng = random.Random(1234)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    n_valid = n_bad = n_poses = 0
    expected: dict[tuple[str, int], float] = {}
    frame = 1000
    with RunningBridge(bridge, src) as rb:
        for i in range(3000):
            kind = rng.random()
            if kind < 0.25:
                frame += 1
                items = [_item(j, f"b{j}", x=rng.uniform(-3e3, 3e3)) for j in range(rng.randint(1, 13))]
                for _, name, vals in items:
                    expected[(name, frame)] = vals[0] * 1e-3
                data = build_datagram(frame, items)
                n_valid += 1
                n_poses += len(items)
            else:
                good = build_datagram(rng.randint(0, 2**32 - 1),
                                      [_item(j, f"x{j}") for j in range(rng.randint(1, 13))])
                r = rng.random()
                if r < 0.3:
                    data = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 1400)))
                    if len(data) >= 5 and (len(data) - 5) % 75 == 0:
                        data += b"\0"  # keep "random" always invalid by length
                elif r < 0.6:
                    data = good[: rng.randint(0, len(good) - 1)]
                elif r < 0.8:
                    data = good + bytes(rng.randint(1, 1200))
                else:
                    b = bytearray(good)
                    b[6] = rng.choice([0, 71, 73, 255])  # wrong item size
                    data = bytes(b)
                n_bad += 1
            tx.sendto(data, src.address)
            if i % 100 == 99:  # pace so the loopback socket buffer never overflows
                assert wait_for(lambda k=i + 1: src.counters["datagrams"] >= k, 10.0)
        assert wait_for(lambda: src.counters["datagrams"] == n_valid + n_bad, 10.0)
        assert wait_for(lambda: len(col.of_key("/pose")) >= n_poses, 20.0)
        rb.stop()
    tx.close()
    sub.undeclare()
    assert src.counters["malformed"] == n_bad
    got = {}
    for p in col.of_key("/pose"):
        d = decode_pose(p)
        assert d is not None
        got[(d["body"], d["frame"])] = d["x"]
    assert len(col.of_key("/pose")) == n_poses
    assert got.keys() == expected.keys()
    assert all(got[k] == pytest.approx(v) for k, v in expected.items())
    tot = bridge.stats.totals()
    assert tot["published"] == n_poses and tot["duplicates"] == 0

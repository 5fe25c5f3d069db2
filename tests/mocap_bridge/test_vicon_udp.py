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
    tracker_datagrams,
    walk_datagram,
)
from tests.support.net import Collector, RunningBridge, subscribe_ready, wait_for


def _item(i, name, x=100.0, y=-250.0, z=12.5, rx=0.01, ry=-0.02, rz=1.0):
    """An object item. Tracker sends ItemID 0 for objects (UoBFlightLab/vicon_udp
    src/ViconTracker/UDPInterface.hpp, ``enum ItemID { Object = 0 }``); ``i`` is kept in
    the signature for readability of the call sites and must be 0."""
    assert i == 0
    return (i, name, (x, y, z, rx, ry, rz))


def test_layout_is_packed_little_endian():
    d = build_datagram(0x01020304, [_item(0, "a"), _item(0, "bb", x=5.0)])
    assert len(d) == 5 + 2 * 75
    assert d[:5] == b"\x04\x03\x02\x01\x02"
    assert d[5] == 0 and d[6:8] == b"\x48\x00" and d[8:10] == b"a\0"
    assert struct.unpack_from("<d", d, 5 + 3 + 24)[0] == 100.0
    # the second item starts at byte 80 (native alignment would put it elsewhere)
    assert d[80] == 0 and d[81:83] == b"\x48\x00"
    assert struct.unpack_from("<d", d, 80 + 27)[0] == 5.0
    frame, items = parse_datagram(d)
    assert frame == 0x01020304
    assert [(i, n) for i, n, _ in items] == [(0, "a"), (0, "bb")]
    assert items[1][2] == (5.0, -250.0, 12.5, 0.01, -0.02, 1.0)


@pytest.mark.parametrize("mutate", [
    lambda d: d[:4],                       # truncated header
    lambda d: d[:-1],                      # truncated item
    lambda d: d[:4] + bytes([3]) + d[5:],  # count says 3, holds 2
    lambda d: d[:4] + bytes([3]) + d[5:] + b"\0\0",  # 3rd item header cut after 2 bytes
    lambda d: d[:6] + b"\x49\x00" + d[8:],  # item 1 claims 73 bytes: item 2 no longer fits
    lambda d: d + bytes(65508 - len(d)),   # longer than any UDP payload
])
def test_malformed_datagrams_raise(mutate):
    """Only a datagram whose announced items do not fit in its bytes is malformed."""
    good = build_datagram(9, [_item(0, "a"), _item(0, "b")])
    with pytest.raises(MalformedDatagram):
        parse_datagram(mutate(good))


@pytest.mark.parametrize("block", [None, 256, 512, 1024, 1400])
def test_padding_after_the_last_item_is_ignored_whatever_it_holds(block):
    """Tracker pads every datagram to its Data Block Size (256/512/1024; UoBFlightLab/
    vicon_udp src/common.cpp accepts exactly those lengths). The tail is not read."""
    items = [_item(0, "a", 1.0), _item(0, "bb", 2.0)]
    bare = build_datagram(5, items)
    d = build_datagram(5, items, block)
    assert len(d) == (block or len(bare)) and d.startswith(bare)
    assert parse_datagram(d) == parse_datagram(bare)
    junk = bare + bytes(range(256))[: (block or len(bare)) - len(bare)]  # non-zero tail
    assert parse_datagram(junk) == parse_datagram(bare)
    assert walk_datagram(d).padding == len(d) - len(bare)


def test_items_of_other_types_and_sizes_are_skipped_by_their_size():
    """A receiver walks by ItemDataSize and skips what is not an object (UoBFlightLab/
    vicon_udp UDPInterface.hpp: ``if ItemID == Object ... itemOffset += 3 + size``)."""
    d = build_datagram(7, [_item(0, "a", 1.0)], 512,
                       extra_items=[(5, b"\x01" * 40), (0, b"\x02" * 80), (9, b"")])
    d = d[:5] + d[5 + 75:5 + 75 + 43 + 83 + 3] + d[5:5 + 75] + d[5 + 75 + 43 + 83 + 3:]
    parsed = walk_datagram(d)  # items: type 5, object of 80 bytes, type 9, object "a"
    assert parsed.frame == 7 and [n for _, n, _ in parsed.objects] == ["a"]
    assert parsed.objects[0][2][0] == 1.0
    assert parsed.skipped == [(5, "type"), (0, "size"), (9, "type")]
    dec = DatagramDecoder()
    (only,) = dec.decode(d, 1.0)
    assert only.body == "a" and only.x == pytest.approx(1e-3)
    c = dec.counters
    assert c["malformed"] == 0 and c["items"] == 1 and c["skipped_items"] == 3
    assert c["skipped_type_5"] == 1 and c["skipped_type_9"] == 1 and c["skipped_object_size"] == 1
    assert c["padded"] == 1
    dec.decode(d, 2.0)
    assert c["skipped_type_5"] == 2 and len(dec.notices) == 3  # one notice per kind


def test_bad_names_skip_the_item_not_the_datagram():
    good = build_datagram(9, [_item(0, "a"), _item(0, "b")])
    empty = good[:8] + b"\0" * 24 + good[32:]
    latin = good[:8] + b"\xff\xfe" + good[10:]
    for d in (empty, latin):
        dec = DatagramDecoder()
        assert [s.body for s in dec.decode(d, 0.0)] == ["b"]
        assert dec.counters["skipped_object_name"] == 1 and dec.counters["malformed"] == 0


def test_name_at_tracker_limit_warns_once():
    seen = []
    dec = DatagramDecoder(on_notice=seen.append)
    long = "a_rather_long_object_nam"  # 24 characters: Tracker keeps 23
    d = build_datagram(1, [_item(0, long[:23]), _item(0, "short")])
    for _ in range(3):
        assert [s.body for s in dec.decode(d, 0.0)] == [long[:23], "short"]
    assert len(seen) == 1 and "23" in seen[0] and long[:23] in seen[0]


def test_tracker_datagrams_split_a_frame_into_padded_blocks():
    items = [_item(0, f"b{j}", float(j)) for j in range(8)]
    blocks = tracker_datagrams(3, items, 256)  # 3 objects per 256-byte block
    assert [len(b) for b in blocks] == [256, 256, 256]
    got = [parse_datagram(b) for b in blocks]
    assert {f for f, _ in got} == {3}
    assert [it for _, its in got for it in its] == items
    with pytest.raises(ValueError):
        build_datagram(1, items[:4], 256)


def test_decoder_units_quaternion_and_occlusion():
    dec = DatagramDecoder(latency_s=0.004)
    d = build_datagram(77, [_item(0, "mod1", 1500.0, -250.0, 12.5, 0.01, -0.02, 2.5),
                            _item(0, "gone", math.nan, 0, 0, 0, 0, 0),
                            _item(0, "zeros", 0, 0, 0, 0, 0, 0)])
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


def _reference_walk(data):
    """Independent oracle for the property test, written from UoBFlightLab/vicon_udp
    UDPInterface.hpp (walk by ItemDataSize) with bounds checks added: the number of
    object items, or None when an announced item does not fit."""
    if len(data) < 5:
        return None
    off, objects = 5, 0
    for _ in range(data[4]):
        if off + 3 > len(data):
            return None
        size = data[off + 1] | data[off + 2] << 8
        if off + 3 + size > len(data):
            return None
        objects += data[off] == 0 and size == 72
        off += 3 + size
    return objects


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(
    st.binary(max_size=1100),
    # structured: a few items of random types and sizes, then padding
    st.builds(lambda frame, items, pad: struct.pack("<IB", frame, len(items)) + b"".join(
        struct.pack("<BH", t, len(body)) + body for t, body in items) + pad,
        st.integers(0, 2**32 - 1),
        st.lists(st.tuples(st.sampled_from([0, 0, 1, 3, 255]),
                           st.one_of(st.binary(min_size=72, max_size=72), st.binary(max_size=90))),
                 max_size=6),
        st.binary(max_size=300)),
))
def test_decoder_never_raises_on_random_bytes(data):
    dec = DatagramDecoder()
    out = dec.decode(data, 0.0)
    assert (out is None) == (dec.counters["malformed"] == 1)
    ref = _reference_walk(data)
    assert (out is None) == (ref is None)
    if out is not None:  # every object item is a pose or a counted skip (bad name)
        assert len(out) + dec.counters.get("skipped_object_name", 0) == ref


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
        (10, [_item(0, "mod 1", 1000.0, 2000.0, 50.0, 0.0, 0.0, 0.5), _item(0, "ref", 1, 2, 3, 0, 0, 0.1)]),
        (10, [_item(0, "mod 1", 9999.0, 0, 0, 0, 0, 0)]),            # repeated frame: dropped
        (11, [_item(0, "mod 1", math.nan, 0, 0, 0, 0, 0), _item(0, "ref", 1, 2, 3, 0, 0, 0.2)]),
        (14, [_item(0, "mod 1", -500.0, 250.0, 0.0, 0.1, -0.1, 3.0)]),  # 12, 13 missing
        (13, [_item(0, "ref", 1, 2, 3, 0, 0, 0.3)]),                 # late but new for "ref"
        (12, [_item(0, "mod 1", 1, 1, 1, 0, 0, 0)]),                 # older than 14: dropped
    ]
    with RunningBridge(bridge, src) as rb:
        for k, (f, items) in enumerate(frames):
            tx.sendto(build_datagram(f, items, 1024), src.address)  # padded as Tracker sends
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
                items = [_item(0, f"b{j}", x=rng.uniform(-3e3, 3e3)) for j in range(rng.randint(1, 13))]
                for _, name, vals in items:
                    expected[(name, frame)] = vals[0] * 1e-3
                # as Tracker sends: padded to its block size, sometimes an item of another type
                extra = [(rng.choice([1, 2, 7]), bytes(rng.randint(0, 20)))] if rng.random() < 0.3 else []
                size = 5 + 75 * len(items) + sum(3 + len(b) for _, b in extra)
                block = next(b for b in (256, 512, 1024) if b >= size)
                data = build_datagram(frame, items, block, extra_items=extra)
                n_valid += 1
                n_poses += len(items)
            else:
                good = build_datagram(rng.randint(0, 2**32 - 1),
                                      [_item(0, f"x{j}") for j in range(rng.randint(1, 13))])
                r = rng.random()
                if r < 0.3:  # random bytes announcing 255 items that cannot fit
                    data = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 760)))
                    if len(data) >= 5:
                        data = data[:4] + b"\xff" + data[5:]
                elif r < 0.6:
                    data = good[: rng.randint(0, len(good) - 1)]
                elif r < 0.8:  # announces more items than it holds
                    data = good[:4] + bytes([good[4] + rng.randint(1, 100)]) + good[5:]
                else:  # the first item claims more bytes than the datagram has
                    b = bytearray(good)
                    b[6:8] = struct.pack("<H", rng.randint(len(good), 65535))
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


def test_tracker_capture_padded_to_every_block_size_is_bridged_whole(zenoh_pair):
    """Issue 14's acceptance: a capture as Tracker sends it (padded to 256, 512 and 1024
    bytes, items of another type in some datagrams, a few really broken datagrams) gives
    every object pose, with the values of the unpadded capture, and malformed equal to
    the broken datagrams only."""
    rng = random.Random(14)
    names = ["tpods1", "tpods2", "truss", "ref"]
    frames = []
    for f in range(1, 61):
        items = [_item(0, n, rng.uniform(-2e3, 2e3), rng.uniform(-2e3, 2e3), rng.uniform(0, 50),
                       rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-3, 3))
                 for n in names]
        if f % 7 == 0:
            items[1] = _item(0, "tpods2", math.nan, 0, 0, 0, 0, 0)  # occluded
        frames.append((f, items))

    def unpadded_reference():
        dec = DatagramDecoder()
        return {(s.body, s.frame): s for f, items in frames for s in dec.decode(build_datagram(f, items), 0.0)}

    ref = unpadded_reference()
    for block in (256, 512, 1024):
        col, sub, src, bridge = _bridge_setup(zenoh_pair, prefix=f"cap{block}")
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        n_sent = n_broken = 0
        with RunningBridge(bridge, src) as rb:
            for f, items in frames:
                for d in tracker_datagrams(f, items, block):
                    if f % 5 == 0:  # a marker item of another type, ahead of the objects
                        d = (struct.pack("<IB", f, d[4] + 1) + b"\x03\x0c\x00" + b"\x01" * 12
                             + d[5:block - 15])
                        assert len(d) == block
                    tx.sendto(d, src.address)
                    n_sent += 1
                if f % 20 == 0:  # really broken: announces an item that does not fit
                    tx.sendto(struct.pack("<IBBH", f, 1, 0, 200) + bytes(50), src.address)
                    n_sent += 1
                    n_broken += 1
                assert wait_for(lambda k=n_sent, c=src.counters: c["datagrams"] >= k, 5.0)
            assert wait_for(lambda c=col: len(c.of_key("/pose")) >= len(ref), 10.0)
            rb.stop()
        tx.close()
        sub.undeclare()
        got = {(d["body"], d["frame"]): d for d in map(decode_pose, col.of_key("/pose"))}
        assert len(col.of_key("/pose")) == len(ref) and got.keys() == ref.keys()
        for key, s in ref.items():
            d = got[key]
            if s.occluded:
                assert d["occluded"] and d["x"] is None
            else:
                assert (d["x"], d["y"], d["z"]) == (s.x, s.y, s.z)
                assert (d["qx"], d["qy"], d["qz"], d["qw"]) == (s.qx, s.qy, s.qz, s.qw)
        c = src.counters
        assert c["malformed"] == n_broken == 3
        assert c["skipped_type_3"] == sum(len(tracker_datagrams(f, it, block)) for f, it in frames if f % 5 == 0)
        assert c["padded"] == n_sent - n_broken  # every Tracker datagram carried padding


def test_console_line_names_skipped_items():
    from mocap_bridge.stats import BridgeStats, console_line

    st_ = BridgeStats(source="vicon-udp:51001")
    dec = DatagramDecoder()
    st_.source_counters = dec.counters
    assert "skipped" not in console_line(st_.snapshot())
    dec.decode(build_datagram(1, [_item(0, "a")], 256, extra_items=[(4, b"xy")]), 0.0)
    line = console_line(st_.snapshot())
    assert "skipped items 1" in line and "malformed 0" in line

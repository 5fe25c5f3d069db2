"""Vicon Tracker UDP object stream: datagrams as Tracker sends them, byte by byte.

The bytes below are written out by hand from public descriptions of the stream, not
produced by our encoder, so that they cannot share its assumptions:

- UoBFlightLab/vicon_udp, ``src/ViconTracker/UDPInterface.hpp``: packed little-endian
  structs ``{uint32 FrameNumber; uint8 ItemsInBlock; Items[]}``, each item
  ``{uint8 ItemID; uint16 ItemDataSize; data}``, an object (ItemID 0) as
  ``{char ItemName[24]; double TransX, TransY, TransZ, RotX, RotY, RotZ}``; the receiver
  walks items by ``ItemDataSize`` and skips unknown item types.
- UoBFlightLab/vicon_udp, ``src/common.cpp``: a datagram is accepted only when it is
  256, 512 or 1024 bytes long (Tracker pads to its "Data Block Size"); translation in
  mm (divided by 1000), rotation as Euler XYZ in rad.
- Nick-Zhang1996/BuzzRacer, ``src/vicon.py``: reads the first object at fixed offsets
  (name ``data[8:32]``, x ``data[32:40]`` ... rz ``data[72:80]``) from a 256/512-byte
  receive buffer, port 51001.
"""

from __future__ import annotations

import math
import struct

import pytest

from mocap_bridge.pose import euler_xyz_to_quat
from mocap_bridge.sources.vicon_udp import (
    DatagramDecoder,
    MalformedDatagram,
    build_datagram,
    parse_datagram,
    walk_datagram,
)

# frame 1000, one item; item 0: type 0 (object), size 72, name "tpods1",
# x 1500.0 mm, y -250.5 mm, z 30.0 mm, rx 0.0, ry 0.0, rz 1.5 rad; zero padding to 256.
FRAME_1000 = bytes.fromhex(
    "e8030000" "01"                                   # FrameNumber 1000, ItemsInBlock 1
    "00" "4800"                                       # ItemID 0 (object), ItemDataSize 72
    + "74706f647331" + "00" * 18                      # "tpods1", NUL padded to 24
    + "0000000000709740"                              # TransX 1500.0 (mm)
    + "0000000000506fc0"                              # TransY -250.5
    + "0000000000003e40"                              # TransZ 30.0
    + "0000000000000000" * 2                          # RotX 0.0, RotY 0.0
    + "000000000000f83f"                              # RotZ 1.5 (rad)
)
PADDED_256 = FRAME_1000 + bytes(256 - len(FRAME_1000))


def test_hand_written_datagram_has_the_documented_offsets():
    assert len(FRAME_1000) == 5 + 75
    # BuzzRacer src/vicon.py reads these offsets of the first object
    assert struct.unpack("<i", PADDED_256[0:4])[0] == 1000 and PADDED_256[4] == 1
    assert PADDED_256[8:32].rstrip(b"\0") == b"tpods1"
    assert struct.unpack("<d", PADDED_256[32:40])[0] == 1500.0
    assert struct.unpack("<d", PADDED_256[72:80])[0] == 1.5
    # our encoder writes the same bytes
    assert build_datagram(1000, [(0, "tpods1", (1500.0, -250.5, 30.0, 0.0, 0.0, 1.5))], 256) == PADDED_256


@pytest.mark.parametrize("block", [256, 512, 1024])
def test_padded_datagram_decodes_to_the_pose(block):
    d = FRAME_1000 + bytes(block - len(FRAME_1000))
    dec = DatagramDecoder()
    (s,) = dec.decode(d, 10.0)
    assert s.body == "tpods1" and s.frame == 1000 and not s.occluded
    assert (s.x, s.y, s.z) == (1.5, -0.2505, 0.03)        # mm -> m, as common.cpp divides by 1000
    assert (s.qx, s.qy, s.qz, s.qw) == pytest.approx(euler_xyz_to_quat(0.0, 0.0, 1.5))
    assert s.qz == pytest.approx(math.sin(0.75)) and s.qw == pytest.approx(math.cos(0.75))
    assert dec.counters == {"datagrams": 1, "malformed": 0, "items": 1, "bytes": block,
                            "padded": 1, "skipped_items": 0}


def test_item_of_another_type_before_the_object_is_skipped_by_its_size():
    # ItemsInBlock 2: an item of type 1 with 4 data bytes, then the object above
    d = (bytes.fromhex("e8030000" "02" "01" "0400" "deadbeef") + FRAME_1000[5:])
    d += bytes(512 - len(d))
    parsed = walk_datagram(d)
    assert parsed.skipped == [(1, "type")]
    assert [(i, n, v) for i, n, v in parsed.objects] == [
        (0, "tpods1", (1500.0, -250.5, 30.0, 0.0, 0.0, 1.5))]
    assert parsed.padding == 512 - (5 + 7 + 75)


def test_padding_bytes_are_not_read_even_when_not_zero():
    d = FRAME_1000 + b"\xff" * (1024 - len(FRAME_1000))
    assert parse_datagram(d) == parse_datagram(FRAME_1000)


def test_announced_items_that_do_not_fit_are_malformed_even_when_padded():
    # ItemsInBlock says 2 but the second item's header lands in the padding and claims
    # 0xffff bytes: the datagram is broken, not padded
    d = bytearray(PADDED_256)
    d[4] = 2
    d[80:83] = b"\x00\xff\xff"
    with pytest.raises(MalformedDatagram, match="item 2 of 2"):
        walk_datagram(bytes(d))


def test_occluded_object_sent_as_nan_is_published_occluded():
    nan = struct.pack("<d", math.nan).hex()
    d = bytes.fromhex("e9030000" "01" "00" "4800" + "74706f647331" + "00" * 18 + nan * 6)
    (s,) = DatagramDecoder().decode(d + bytes(256 - len(d)), 0.0)
    assert s.occluded and math.isnan(s.x) and s.frame == 1001  # published as null (docs/mocap.md)

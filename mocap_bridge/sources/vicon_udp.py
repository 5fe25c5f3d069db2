"""Vicon Tracker UDP object stream: parser (pure) and socket source.

Datagram layout, little-endian, packed (no alignment)::

    uint32 frame, uint8 item_count,
    item_count x [uint8 id, uint16 size (=72), char[24] name (NUL padded),
                  float64 tx, ty, tz (mm), float64 rx, ry, rz (rad, Euler XYZ)]

75 bytes per item after the 5-byte header; datagrams are at most 1024 bytes.
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from collections.abc import Iterator

from mocap_bridge.pose import PoseSample, euler_xyz_to_quat, occluded_sample
from tpods.errors import UserError

DEFAULT_PORT = 51001
MAX_DATAGRAM = 1024
HEADER = struct.Struct("<IB")
ITEM = struct.Struct("<BH24s6d")
ITEM_DATA_SIZE = 72
assert HEADER.size == 5 and ITEM.size == 75


class MalformedDatagram(ValueError):
    """The datagram does not follow the Tracker object-stream layout."""


def parse_datagram(data: bytes) -> tuple[int, list[tuple[int, str, tuple[float, ...]]]]:
    """Parse one datagram into ``(frame, [(item_id, name, (tx, ty, tz, rx, ry, rz)), ...])``.

    Translation in mm, rotation in rad, exactly as sent (NaN kept). Raises
    :class:`MalformedDatagram` for a wrong length (truncated or oversized), a wrong item
    size, an empty or non-UTF-8 name.
    """
    n = len(data)
    if n < HEADER.size:
        raise MalformedDatagram(f"truncated header ({n} bytes)")
    if n > MAX_DATAGRAM:
        raise MalformedDatagram(f"oversized datagram ({n} bytes)")
    frame, count = HEADER.unpack_from(data, 0)
    expected = HEADER.size + ITEM.size * count
    if n != expected:
        raise MalformedDatagram(f"{count} items need {expected} bytes, got {n}")
    items = []
    for item_id, size, raw_name, tx, ty, tz, rx, ry, rz in ITEM.iter_unpack(
            memoryview(data)[HEADER.size:]):
        if size != ITEM_DATA_SIZE:
            raise MalformedDatagram(f"item size {size}, expected {ITEM_DATA_SIZE}")
        raw = raw_name.split(b"\0", 1)[0]
        try:
            name = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise MalformedDatagram("item name is not UTF-8") from None
        if not name.strip() or not name.isprintable():
            raise MalformedDatagram("empty or unprintable item name")
        items.append((item_id, name, (tx, ty, tz, rx, ry, rz)))
    return frame, items


def build_datagram(frame: int, items: list[tuple[int, str, tuple[float, ...]]]) -> bytes:
    """Inverse of :func:`parse_datagram` (for emulators, tests and the bench)."""
    out = [HEADER.pack(frame, len(items))]
    for item_id, name, vals in items:
        out.append(ITEM.pack(item_id, ITEM_DATA_SIZE, name.encode()[:24], *vals))
    return b"".join(out)


def item_to_sample(frame: int, name: str, vals: tuple[float, ...], t: float, t_recv: float,
                   zero_is_occluded: bool = True) -> PoseSample:
    """One item as a pose sample (mm to m, Euler XYZ to quaternion).

    Non-finite values mean occluded; so do six exact zeros when ``zero_is_occluded``
    (a placeholder some set-ups send for an object not seen; a real pose is never
    exactly zero in all six values).
    """
    tx, ty, tz, rx, ry, rz = vals
    if not (math.isfinite(tx) and math.isfinite(ty) and math.isfinite(tz)
            and math.isfinite(rx) and math.isfinite(ry) and math.isfinite(rz)) or (
            zero_is_occluded and tx == 0.0 and ty == 0.0 and tz == 0.0
            and rx == 0.0 and ry == 0.0 and rz == 0.0):
        return occluded_sample(name, frame, t, t_recv)
    qx, qy, qz, qw = euler_xyz_to_quat(rx, ry, rz)
    return PoseSample(name, frame, t, t_recv, tx * 1e-3, ty * 1e-3, tz * 1e-3, qx, qy, qz, qw)


class DatagramDecoder:
    """Datagram bytes to pose samples, counting what is malformed (no I/O).

    Counters: ``datagrams`` (all received), ``malformed`` (skipped whole), ``items``.
    """

    def __init__(self, latency_s: float = 0.0, zero_is_occluded: bool = True) -> None:
        self.latency_s = latency_s
        self.zero_is_occluded = zero_is_occluded
        self.counters = {"datagrams": 0, "malformed": 0, "items": 0, "bytes": 0}
        self.last_error: str = ""

    def decode(self, data: bytes, t_recv: float) -> list[PoseSample] | None:
        c = self.counters
        c["datagrams"] += 1
        c["bytes"] += len(data)
        try:
            frame, items = parse_datagram(data)
        except (MalformedDatagram, struct.error) as exc:
            c["malformed"] += 1
            self.last_error = str(exc)
            return None
        c["items"] += len(items)
        t = t_recv - self.latency_s
        zo = self.zero_is_occluded
        return [item_to_sample(frame, name, vals, t, t_recv, zo) for _, name, vals in items]


class ViconUDPSource:
    """Receive the Tracker object stream on a UDP socket.

    Args:
        port: UDP port (Tracker's default 51001; 0 picks a free one, see ``address``).
        bind: local address to bind ("0.0.0.0" for all interfaces).
        latency_s: fixed latency subtracted from the receive time to get ``t``
            (the UDP stream does not report Tracker's own latency).
    """

    in_table_frame = False

    def __init__(self, port: int = DEFAULT_PORT, bind: str = "0.0.0.0", latency_s: float = 0.0,
                 zero_is_occluded: bool = True, rcvbuf_bytes: int = 4 << 20) -> None:
        self.decoder = DatagramDecoder(latency_s, zero_is_occluded)
        self.counters = self.decoder.counters
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
        except OSError:
            pass
        try:
            self.sock.bind((bind, port))
        except OSError as exc:
            self.sock.close()
            raise UserError(f"cannot bind UDP {bind}:{port} ({exc.strerror or exc})") from None
        self.sock.settimeout(0.2)
        self.address = self.sock.getsockname()
        self.name = f"vicon-udp:{self.address[1]}"

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        recv = self.sock.recv
        decode = self.decoder.decode
        now = time.time
        while not stop.is_set():
            try:
                data = recv(65536)
            except TimeoutError:
                continue
            except OSError:
                if stop.is_set() or self.sock.fileno() < 0:
                    return
                raise
            batch = decode(data, now())
            if batch:
                yield batch

    def close(self) -> None:
        self.sock.close()

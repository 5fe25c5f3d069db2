"""Vicon Tracker UDP object stream: parser (pure) and socket source.

Datagram layout, little-endian, packed (no alignment)::

    uint32 FrameNumber, uint8 ItemsInBlock,
    ItemsInBlock x [uint8 ItemID, uint16 ItemDataSize, ItemDataSize bytes of data]
    zero or more bytes of padding up to Tracker's "Data Block Size"

An object item (ItemID 0) holds 72 bytes: ``char[24]`` name (NUL padded, so at most
23 characters survive), ``float64`` tx, ty, tz (mm) and rx, ry, rz (rad, Euler XYZ):
75 bytes per object after the 5-byte header. Tracker pads every datagram to its
configured block size (256, 512 or 1024 bytes; 1024 by default), so the items are
walked one by one by ``ItemDataSize`` and whatever follows the last announced item is
ignored. Items of another type, and object items of another size, are skipped by
their size and counted. Sources: UoBFlightLab/vicon_udp ``src/ViconTracker/
UDPInterface.hpp`` (packed structs, walk by ``ItemDataSize``, skip unknown types) and
``src/common.cpp`` (accepts 256/512/1024-byte datagrams); Nick-Zhang1996/BuzzRacer
``src/vicon.py`` (fixed offsets of the first object). docs/mocap.md has the table.
"""

from __future__ import annotations

import math
import os
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from common.errors import UserError
from mocap_bridge.capture import PcapWriter
from mocap_bridge.pose import PoseSample, euler_xyz_to_quat, occluded_sample

DEFAULT_PORT = 51001
BLOCK_SIZES = (256, 512, 1024)
"""Tracker's "Data Block Size" choices; every datagram is padded to one of them."""
DEFAULT_BLOCK_SIZE = 1024
MAX_UDP_PAYLOAD = 65507
HEADER = struct.Struct("<IB")
ITEM_HEADER = struct.Struct("<BH")
OBJECT = struct.Struct("<24s6d")
ITEM = struct.Struct("<BH24s6d")
ITEM_DATA_SIZE = 72
OBJECT_ITEM_ID = 0
NAME_MAX_CHARS = 23
"""Tracker writes the name as a C string in 24 bytes: a longer name is cut to 23."""
CAPTURE_FLUSH_S = 0.05
"""--capture hands waiting datagrams to the file when the oldest is this old ..."""
CAPTURE_IDLE_S = 0.05
"""... or when no datagram came for this long: a kill loses at most the last 0.1 s."""
_IP_PKTINFO = getattr(socket, "IP_PKTINFO", 8)  # Linux's value; Python 3.11 lacks the name
assert HEADER.size == 5 and ITEM.size == 75 and OBJECT.size == ITEM_DATA_SIZE


class MalformedDatagram(ValueError):
    """The datagram does not follow the Tracker object-stream layout."""


@dataclass
class ParsedDatagram:
    """One datagram, walked item by item.

    ``objects``: ``(item_id, name, (tx, ty, tz, rx, ry, rz))`` of every valid object item.
    ``skipped``: ``(item_id, reason)`` of every announced item that was skipped (another
    item type, an object of another size, an empty or non-UTF-8 name).
    ``padding``: bytes after the last announced item.
    """

    frame: int
    objects: list[tuple[int, str, tuple[float, ...]]] = field(default_factory=list)
    skipped: list[tuple[int, str]] = field(default_factory=list)
    padding: int = 0


def walk_datagram(data: bytes) -> ParsedDatagram:
    """Walk one datagram by ``ItemDataSize``; see the module docstring for the layout.

    Raises :class:`MalformedDatagram` only when the datagram itself is broken: shorter
    than its header, longer than a UDP payload, or announcing items that do not fit in
    its bytes. Values are returned as sent (mm, rad; NaN kept).
    """
    n = len(data)
    if n < HEADER.size:
        raise MalformedDatagram(f"truncated header ({n} bytes)")
    if n > MAX_UDP_PAYLOAD:
        raise MalformedDatagram(f"oversized datagram ({n} bytes)")
    frame, count = HEADER.unpack_from(data, 0)
    out = ParsedDatagram(frame)
    off = HEADER.size
    for k in range(count):
        if off + ITEM_HEADER.size > n:
            raise MalformedDatagram(
                f"{count} items announced, item {k + 1} starts beyond the {n} bytes")
        item_id, size = ITEM_HEADER.unpack_from(data, off)
        start = off + ITEM_HEADER.size
        end = start + size
        if end > n:
            raise MalformedDatagram(
                f"item {k + 1} of {count} needs {size} bytes at offset {start}, "
                f"the datagram has {n}")
        off = end
        if item_id != OBJECT_ITEM_ID:
            out.skipped.append((item_id, "type"))
            continue
        if size != ITEM_DATA_SIZE:
            out.skipped.append((item_id, "size"))
            continue
        raw_name, tx, ty, tz, rx, ry, rz = OBJECT.unpack_from(data, start)
        raw = raw_name.split(b"\0", 1)[0]
        try:
            name = raw.decode("utf-8")
        except UnicodeDecodeError:
            out.skipped.append((item_id, "name"))
            continue
        if not name.strip() or not name.isprintable():
            out.skipped.append((item_id, "name"))
            continue
        out.objects.append((item_id, name, (tx, ty, tz, rx, ry, rz)))
    out.padding = n - off
    return out


def parse_datagram(data: bytes) -> tuple[int, list[tuple[int, str, tuple[float, ...]]]]:
    """``(frame, [(item_id, name, (tx, ty, tz, rx, ry, rz)), ...])`` of the object items.

    Translation in mm, rotation in rad, exactly as sent (NaN kept). Padding and skipped
    items are dropped (see :func:`walk_datagram` for them). Raises
    :class:`MalformedDatagram` as :func:`walk_datagram` does.
    """
    parsed = walk_datagram(data)
    return parsed.frame, parsed.objects


def build_datagram(frame: int, items: list[tuple[int, str, tuple[float, ...]]],
                   block_size: int | None = None,
                   extra_items: list[tuple[int, bytes]] = ()) -> bytes:
    """Inverse of :func:`parse_datagram` (for emulators, tests and the bench).

    ``items`` are object items, sent with the item id given (Tracker sends 0; another id
    makes a receiver skip the item); ``extra_items`` ``(item_id, data)`` are appended
    after them as raw items of any type. ``block_size`` pads the
    datagram with zero bytes to that size, as Tracker does (None: no padding);
    ValueError when the items do not fit in it.
    """
    out = [HEADER.pack(frame, len(items) + len(extra_items))]
    for item_id, name, vals in items:
        out.append(ITEM.pack(item_id, ITEM_DATA_SIZE, name.encode()[:24], *vals))
    for item_id, data in extra_items:
        out.append(ITEM_HEADER.pack(item_id, len(data)) + bytes(data))
    d = b"".join(out)
    if block_size is not None:
        if len(d) > block_size:
            raise ValueError(f"{len(d)} bytes of items do not fit a {block_size}-byte block")
        d += bytes(block_size - len(d))
    return d


def tracker_datagrams(frame: int, items: list[tuple[int, str, tuple[float, ...]]],
                      block_size: int = DEFAULT_BLOCK_SIZE) -> list[bytes]:
    """The datagrams Tracker sends for one frame: object items packed into as many
    ``block_size`` blocks as they need (each a datagram with the frame number and its
    own item count), every block padded with zeros to ``block_size`` bytes."""
    per_block = (block_size - HEADER.size) // ITEM.size
    if per_block < 1:
        raise ValueError(f"a {block_size}-byte block holds no object item")
    if not items:
        return [build_datagram(frame, [], block_size)]
    return [build_datagram(frame, items[i:i + per_block], block_size)
            for i in range(0, len(items), per_block)]


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


def _stderr_notice(msg: str) -> None:
    print(f"vicon-udp: warning: {msg}", file=sys.stderr, flush=True)


class DatagramDecoder:
    """Datagram bytes to pose samples, counting what is malformed or skipped (no I/O).

    Counters: ``datagrams`` (all received), ``malformed`` (skipped whole: the announced
    items do not fit), ``items`` (object poses decoded), ``bytes``, ``padded`` (datagrams
    with bytes after the last item, as Tracker sends them), ``skipped_items`` (announced
    items not used) split into ``skipped_type_<ID>`` (items of another type),
    ``skipped_object_size`` (object items whose size is not 72) and
    ``skipped_object_name`` (empty, unprintable or non-UTF-8 names).

    ``on_notice(message)`` is called once per kind of surprise (a skipped item type, a
    name at Tracker's 23-character limit, ...); the messages are also kept in ``notices``.
    """

    def __init__(self, latency_s: float = 0.0, zero_is_occluded: bool = True,
                 on_notice: Callable[[str], None] | None = None) -> None:
        self.latency_s = latency_s
        self.zero_is_occluded = zero_is_occluded
        self.on_notice = on_notice
        self.counters = {"datagrams": 0, "malformed": 0, "items": 0, "bytes": 0, "padded": 0,
                         "skipped_items": 0}
        self.last_error: str = ""
        self.notices: list[str] = []
        self._noticed: set[object] = set()

    def _notice(self, key: object, msg: str) -> None:
        if key in self._noticed:
            return
        self._noticed.add(key)
        self.notices.append(msg)
        if self.on_notice is not None:
            self.on_notice(msg)

    def _count_skipped(self, skipped: list[tuple[int, str]]) -> None:
        c = self.counters
        c["skipped_items"] += len(skipped)
        for item_id, reason in skipped:
            if reason == "type":
                key = f"skipped_type_{item_id}"
                self._notice(key, f"skipping items of type {item_id} (only objects, type 0, "
                                  f"carry poses); counted as {key}")
            else:
                key = f"skipped_object_{reason}"
                self._notice(key, f"skipping object items with a bad {reason} "
                                  f"(counted as {key})")
            c[key] = c.get(key, 0) + 1

    def decode(self, data: bytes, t_recv: float) -> list[PoseSample] | None:
        c = self.counters
        c["datagrams"] += 1
        c["bytes"] += len(data)
        try:
            parsed = walk_datagram(data)
        except (MalformedDatagram, struct.error) as exc:
            c["malformed"] += 1
            self.last_error = str(exc)
            return None
        if parsed.padding:
            c["padded"] += 1
        if parsed.skipped:
            self._count_skipped(parsed.skipped)
        objects = parsed.objects
        c["items"] += len(objects)
        t = t_recv - self.latency_s
        zo = self.zero_is_occluded
        frame = parsed.frame
        out = []
        for _, name, vals in objects:
            if len(name) >= NAME_MAX_CHARS:
                self._notice(("name", name),
                             f"object name {name!r} has {len(name)} characters: Tracker cuts "
                             f"names to {NAME_MAX_CHARS}, so it may be truncated (objects "
                             "whose names share their first 23 characters would be merged)")
            out.append(item_to_sample(frame, name, vals, t, t_recv, zo))
        return out


class ViconUDPSource:
    """Receive the Tracker object stream on a UDP socket.

    Args:
        port: UDP port (Tracker's default 51001; 0 picks a free one, see ``address``).
        bind: local address to bind ("0.0.0.0" for all interfaces).
        latency_s: fixed latency subtracted from the receive time to get ``t``
            (the UDP stream does not report Tracker's own latency).
        on_notice: called once per kind of skipped item or suspicious name (default:
            a ``vicon-udp: warning:`` line on stderr).
        capture: a pcap file to write every received datagram to, with its receive time
            and its real addresses and ports (:class:`mocap_bridge.capture.PcapWriter`;
            counters ``captured``, ``capture_errors``). Replay it with
            :class:`mocap_bridge.sources.pcap.PcapSource`.
    """

    in_table_frame = False

    def __init__(self, port: int = DEFAULT_PORT, bind: str = "0.0.0.0", latency_s: float = 0.0,
                 zero_is_occluded: bool = True, rcvbuf_bytes: int = 4 << 20,
                 on_notice: Callable[[str], None] | None = _stderr_notice,
                 capture: str | os.PathLike | None = None) -> None:
        self.decoder = DatagramDecoder(latency_s, zero_is_occluded, on_notice)
        self.counters = self.decoder.counters
        self.capture: PcapWriter | None = None
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
        self._pktinfo = False
        if capture is not None:
            if self.address[0] == "0.0.0.0" and sys.platform.startswith("linux"):
                try:  # the datagram's own destination address, for the capture's IP header
                    self.sock.setsockopt(socket.IPPROTO_IP, _IP_PKTINFO, 1)
                    self._pktinfo = True
                except OSError:
                    pass
            try:
                self.capture = PcapWriter(capture, counters=self.counters,
                                          flush_every_s=CAPTURE_FLUSH_S)
            except BaseException:
                self.sock.close()
                raise

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        if self.capture is not None:
            yield from self._captured_batches(stop)
            return
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

    def _captured_batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        """The receive loop of :meth:`batches` with every datagram also written to the
        capture file (one ``writev`` per datagram, before it is parsed)."""
        decode = self.decoder.decode
        write = self.capture.write
        now = time.time
        dst = self.address
        pktinfo = self._pktinfo
        flush = self.capture.flush
        recvmsg = self.sock.recvmsg
        recvfrom = self.sock.recvfrom
        self.sock.settimeout(CAPTURE_IDLE_S)
        last_val = None
        while not stop.is_set():
            try:
                if pktinfo:
                    data, anc, _, src = recvmsg(65536, 64)
                    t = now()
                    for level, kind, val in anc:
                        # the destination rarely changes: decode it only when it does
                        if val != last_val and level == socket.IPPROTO_IP and \
                                kind == _IP_PKTINFO and len(val) >= 12:
                            dst = (socket.inet_ntoa(val[8:12]), self.address[1])
                            last_val = val
                else:
                    data, src = recvfrom(65536)
                    t = now()
            except TimeoutError:
                flush()  # the stream paused: what waits goes to the file now
                continue
            except OSError:
                if stop.is_set() or self.sock.fileno() < 0:
                    return
                raise
            write(data, src, dst, t)
            batch = decode(data, t)
            if batch:
                yield batch

    def close(self) -> None:
        self.sock.close()
        if self.capture is not None:
            self.capture.close()

"""Reading raw datagram captures: the UDP datagrams of a pcap or pcapng file.

Classic pcap (microsecond or nanosecond, either byte order) and pcapng (section header,
interface descriptions with ``if_tsresol`` and ``if_tsoffset``, enhanced, simple and
obsolete packet blocks), as tcpdump and Wireshark write them. Link types: Ethernet (with
802.1Q/802.1ad tags), raw IP (101, 228, 229 and the platform values 12 and 14), BSD
loopback (0, 108), Linux cooked (113, 276); the unwrapping is
:func:`mocap_bridge.pcap.formats.udp_of`. UDP over IPv4 and IPv6 is returned; everything
else is counted and skipped (see :class:`PcapReader` counters). A file that ends in the
middle of a record gives every whole record and counts the broken one
(``truncated_records``).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, NamedTuple

from common.errors import UserError
from mocap_bridge.pcap.formats import (
    MAX_RECORD,
    PCAP_MAGIC_NS,
    PCAP_MAGIC_US,
    PCAPNG_BOM,
    PCAPNG_SHB,
    _link_supported,
    udp_of,
)


class Datagram(NamedTuple):
    """One UDP datagram read from a capture: time in integer nanoseconds since the epoch."""

    t_ns: int
    src: tuple[str, int]
    dst: tuple[str, int]
    payload: bytes


READER_COUNTERS = ("pcap_records", "udp", "non_udp", "other_port", "ip_fragments", "cut_short",
                   "unsupported_link", "truncated_records", "damaged_records")


def _fmt_head(b: bytes) -> str:
    shown = b[:8]
    if shown and all(32 <= c < 127 for c in shown):
        return repr(shown.decode("ascii"))
    return shown.hex(" ") or "nothing"


class PcapReader:
    """Iterate the UDP datagrams of a pcap or pcapng file (see the module docstring).

    Counters (in ``counters``, a dict that may be shared with a decoder): ``pcap_records``
    (packets read), ``udp`` (UDP datagrams returned), ``non_udp`` (other protocols, ARP,
    TCP, ...), ``other_port`` (UDP not matching ``port``), ``ip_fragments`` (fragments of
    a larger datagram: not reassembled), ``cut_short`` (packets cut by the snap length),
    ``unsupported_link`` (packets of a link type not read), ``truncated_records`` (the
    file ends inside a record), ``damaged_records`` (a record header that cannot be
    right, e.g. a length over 64 MiB: reading stops there).

    ``port``: keep only UDP whose source or destination port is this one (None: all).
    Raises :class:`UserError` (one line) when the file is missing or not a capture.
    """

    def __init__(self, path: str | os.PathLike, port: int | None = None,
                 counters: dict[str, int] | None = None,
                 on_warning: Callable[[str], None] | None = None) -> None:
        self.path = Path(path)
        self.port = port
        self.counters = counters if counters is not None else {}
        for k in READER_COUNTERS:
            self.counters.setdefault(k, 0)
        self.on_warning = on_warning
        if self.path.is_dir():
            raise UserError(f"{self.path} is a folder, not a pcap file")
        try:
            self._f: BinaryIO = open(self.path, "rb")  # noqa: SIM115 (closed by close())
        except FileNotFoundError:
            raise UserError(f"{self.path}: no such file") from None
        except OSError as exc:
            raise UserError(f"{self.path}: cannot read it ({exc.strerror or exc})") from None
        try:
            head = self._f.read(24)
            self._probe(head)
        except BaseException:
            self._f.close()
            raise

    def _probe(self, head: bytes) -> None:
        p = self.path
        if len(head) < 4:
            what = "empty" if not head else f"only {len(head)} bytes"
            raise UserError(f"{p}: not a pcap file ({what})")
        self.ng = False
        for endian in ("<", ">"):
            (magic,) = struct.unpack(endian + "I", head[:4])
            if magic in (PCAP_MAGIC_US, PCAP_MAGIC_NS):
                if len(head) < 24:
                    raise UserError(f"{p}: pcap header cut short ({len(head)} of 24 bytes)")
                _, major, minor, zone, _, snap, network = struct.unpack(endian + "IHHiIII", head)
                self.endian = endian
                self.nano = magic == PCAP_MAGIC_NS
                self.linktype = network & 0xFFFF
                self.fcs_len = 2 * (network >> 29) if network & 0x10000000 else 0
                self.zone_ns = zone * 1_000_000_000
                if not _link_supported(self.linktype):
                    raise UserError(f"{p}: link type {self.linktype} is not supported (read: "
                                    "Ethernet, raw IP, Linux cooked, BSD loopback)")
                return
        if struct.unpack("<I", head[:4])[0] == PCAPNG_SHB:
            if len(head) < 12:
                raise UserError(f"{p}: pcapng header cut short ({len(head)} bytes)")
            bom = head[8:12]
            if bom == struct.pack("<I", PCAPNG_BOM):
                self.endian = "<"
            elif bom == struct.pack(">I", PCAPNG_BOM):
                self.endian = ">"
            else:
                raise UserError(f"{p}: not a pcap file (pcapng byte-order magic missing)")
            self.ng = True
            self._head = head
            return
        raise UserError(f"{p}: not a pcap or pcapng file (it starts with {_fmt_head(head)})")

    # -- records ------------------------------------------------------------

    def _truncated(self, what: str) -> None:
        self.counters["truncated_records"] += 1
        if self.on_warning is not None:
            self.on_warning(f"{self.path} ends in the middle of a {what} (after "
                            f"{self.counters['pcap_records']} whole records): the broken record "
                            "is skipped")

    def _damaged(self, what: str) -> None:
        self.counters["damaged_records"] += 1
        if self.on_warning is not None:
            self.on_warning(f"{self.path}: {what} after {self.counters['pcap_records']} records; "
                            "the rest of the file is not read")

    def packets(self) -> Iterator[tuple[int, int, bytes, int]]:
        """``(t_ns, link type, bytes, fcs length)`` of every packet record."""
        return self._ng_packets() if self.ng else self._pcap_packets()

    def _pcap_packets(self) -> Iterator[tuple[int, int, bytes, int]]:
        f = self._f
        rec = struct.Struct(self.endian + "IIII")
        frac = 1 if self.nano else 1000
        lt, fcs, zone = self.linktype, self.fcs_len, self.zone_ns
        read = f.read
        while True:
            h = read(16)
            if not h:
                return
            if len(h) < 16:
                self._truncated("record header")
                return
            sec, sub, incl, _orig = rec.unpack(h)
            if incl > MAX_RECORD:
                self._damaged(f"a record of {incl} bytes")
                return
            data = read(incl)
            if len(data) < incl:
                self._truncated("record")
                return
            self.counters["pcap_records"] += 1
            yield sec * 1_000_000_000 + sub * frac - zone, lt, data, fcs

    def _ng_packets(self) -> Iterator[tuple[int, int, bytes, int]]:
        f = self._f
        e = self.endian
        u32 = struct.Struct(e + "I")
        buf = self._head  # first 24 bytes already read
        ifaces: list[tuple[int, int, int, int]] = []  # linktype, ticks/s, offset_ns, snaplen
        while True:
            if len(buf) < 8:
                buf += f.read(8 - len(buf))
                if not buf:
                    return
                if len(buf) < 8:
                    self._truncated("block header")
                    return
            btype = u32.unpack_from(buf, 0)[0]
            if btype == PCAPNG_SHB and len(buf) >= 12:  # a new section may switch byte order
                bom = buf[8:12]
                if bom == struct.pack(">I", PCAPNG_BOM) and e != ">":
                    e = ">"
                elif bom == struct.pack("<I", PCAPNG_BOM) and e != "<":
                    e = "<"
                u32 = struct.Struct(e + "I")
                btype = u32.unpack_from(buf, 0)[0]
                ifaces = []
            blen = u32.unpack_from(buf, 4)[0]
            if blen < 12 or blen % 4 or blen > MAX_RECORD:
                self._damaged(f"a block of {blen} bytes")
                return
            rest = f.read(blen - len(buf)) if blen > len(buf) else b""
            block = (buf + rest)[:blen]
            carry = buf[blen:] if len(buf) > blen else b""
            buf = carry
            if len(block) < blen:
                self._truncated("block")
                return
            body = block[8:-4]
            if btype == 1:  # interface description
                if len(body) < 8:
                    continue
                lt, _, snap = struct.unpack_from(e + "HHI", body, 0)
                ticks, offset = 1_000_000, 0
                off = 8
                while off + 4 <= len(body):
                    code, olen = struct.unpack_from(e + "HH", body, off)
                    val = body[off + 4:off + 4 + olen]
                    if code == 0:
                        break
                    if code == 9 and olen >= 1:  # if_tsresol
                        r = val[0]
                        ticks = 2 ** (r & 0x7F) if r & 0x80 else 10 ** r
                    elif code == 14 and olen >= 8:  # if_tsoffset, seconds
                        offset = struct.unpack(e + "q", val[:8])[0] * 1_000_000_000
                    off += 4 + (olen + 3) // 4 * 4
                ifaces.append((lt, ticks, offset, snap))
            elif btype in (6, 2):  # enhanced packet, obsolete packet
                if btype == 6:
                    if len(body) < 20:
                        continue
                    ifid, hi, lo, cap, _orig = struct.unpack_from(e + "IIIII", body, 0)
                    data = body[20:20 + cap]
                else:
                    if len(body) < 20:
                        continue
                    ifid, _drops, hi, lo, cap, _orig = struct.unpack_from(e + "HHIIII", body, 0)
                    data = body[20:20 + cap]
                if ifid >= len(ifaces):
                    self._damaged(f"a packet of undeclared interface {ifid}")
                    return
                lt, ticks, offset, _ = ifaces[ifid]
                ts = (hi << 32) | lo
                self.counters["pcap_records"] += 1
                self._last_ts = t_ns = ts * 1_000_000_000 // ticks + offset
                yield t_ns, lt, data, 0
            elif btype == 3:  # simple packet: interface 0, no timestamp
                if not ifaces or len(body) < 4:
                    continue
                orig = u32.unpack_from(body, 0)[0]
                lt, _, _, snap = ifaces[0]
                cap = min(orig, snap or orig, len(body) - 4)
                self.counters["pcap_records"] += 1
                yield getattr(self, "_last_ts", 0), lt, body[4:4 + cap], 0
            # other blocks (statistics, name resolution, ...) are skipped

    def __iter__(self) -> Iterator[Datagram]:
        c = self.counters
        port = self.port
        for t_ns, lt, data, fcs in self.packets():
            if fcs:
                data = data[:-fcs]
            r = udp_of(lt, data)
            if r is None:
                c["non_udp"] += 1
                continue
            if isinstance(r, str):
                c[r] += 1
                continue
            src, dst, payload = r
            if port is not None and port != src[1] and port != dst[1]:
                c["other_port"] += 1
                continue
            c["udp"] += 1
            yield Datagram(t_ns, src, dst, payload)

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> PcapReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_pcap(path: str | os.PathLike, port: int | None = None, **kw) -> PcapReader:
    """A :class:`PcapReader` (the file is checked now)."""
    return PcapReader(path, port=port, **kw)

"""Raw datagram captures as standard pcap files: the writer the bridge uses and a reader.

**Writing** (:class:`PcapWriter`). Classic libpcap format, as Wireshark, tcpdump, dpkt and
scapy read it: a 24-byte global header (magic ``a1b2c3d4`` little-endian, version 2.4,
snap length 262144, link type 101 ``LINKTYPE_RAW``: every packet starts with its IP
header), then one record per datagram: ``ts_sec, ts_usec, incl_len, orig_len`` (uint32
each) and a synthesized IPv4 header (20 bytes, a correct header checksum, DF set, TTL 64,
the real source and destination addresses and ports) + UDP header (8 bytes, checksum 0:
"none", legal for IPv4) + the datagram's bytes exactly as received. The timestamp is the
bridge's receive time (``time.time()``, microseconds). Records go to an unbuffered
descriptor in ``writev`` calls of whole records only, so the file always ends on a whole
record: every record (``flush_every_s=0``) or, as the bridge does, the records of up to
50 ms at a time and whenever the stream pauses for 50 ms (one system call per 100
datagrams at Tracker's 2 kHz instead of 100): a SIGKILL loses at most the last 0.1 s. A
write error (disk full, folder removed) stops the capture with one warning and is
counted; it never stops the bridge.

**Reading** (:func:`open_pcap`). Classic pcap (microsecond or nanosecond, either byte
order) and pcapng (section header, interface descriptions with ``if_tsresol`` and
``if_tsoffset``, enhanced, simple and obsolete packet blocks), as tcpdump and Wireshark
write them. Link types: Ethernet (with 802.1Q/802.1ad tags), raw IP (101, 228, 229 and
the platform values 12 and 14), BSD loopback (0, 108), Linux cooked (113, 276).
UDP over IPv4 and IPv6 is returned; everything else is counted and skipped (see
:class:`PcapReader` counters). A file that ends in the middle of a record gives every
whole record and counts the broken one (``truncated_records``).
"""

from __future__ import annotations

import os
import socket
import struct
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, NamedTuple

from common.errors import UserError

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_BOM = 0x1A2B3C4D
LINKTYPE_NULL = 0
LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_LOOP = 108
LINKTYPE_LINUX_SLL = 113
LINKTYPE_IPV4 = 228
LINKTYPE_IPV6 = 229
LINKTYPE_LINUX_SLL2 = 276
SNAPLEN = 262144
MAX_RECORD = 1 << 26
"""A record announcing more than 64 MiB is not a packet: the file is damaged from there."""

_GLOBAL = struct.Struct("<IHHiIII")
_REC = struct.Struct("<IIII")
_IP_UDP = struct.Struct("!BBHHHBBH4s4sHHHH")
_PCAP_SUFFIXES = (".pcap", ".cap")


# ------------------------------------------------------------------ writer


def capture_path(spec: str | os.PathLike, *, force: bool = False, prefix: str = "vicon-udp",
                 now: float | None = None) -> Path:
    """The file ``--capture SPEC`` names, checked before anything runs.

    A name ending in ``.pcap`` is that file (refused if it exists, unless ``force``);
    anything else is a folder (created when missing) that receives
    ``<prefix>-YYYYmmdd-HHMMSS.pcap``. Errors are one-line :class:`UserError`."""
    s = str(spec)
    if not s.strip():
        raise UserError("--capture is empty; give a FILE.pcap or a folder")
    p = Path(s)
    if p.suffix.lower() in _PCAP_SUFFIXES:
        if p.is_dir():
            raise UserError(f"--capture {p} is a folder, not a file; choose another --capture")
        if p.exists() and not force:
            raise UserError(f"{p} already exists; add --force to replace it or choose another "
                            "--capture")
        folder = p.parent
    else:
        if p.suffix.lower() == ".pcapng":
            raise UserError(f"--capture {p}: the bridge writes classic pcap; name the file "
                            f"{p.with_suffix('.pcap')}")
        folder = p
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if now is None else now))
        p = folder / f"{prefix}-{stamp}.pcap"
        k = 1
        while p.exists():
            k += 1
            p = folder / f"{prefix}-{stamp}-{k}.pcap"
    if folder.exists() and not folder.is_dir():
        raise UserError(f"--capture {p}: {folder} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--capture {p}: cannot create {folder} ({exc.strerror or exc})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UserError(f"--capture {p}: cannot write in {folder} (permission denied)")
    return p


def _warn(msg: str) -> None:
    print(f"capture: warning: {msg}", file=sys.stderr, flush=True)


class PcapWriter:
    """Write datagrams to a classic pcap file (LINKTYPE_RAW, IPv4 + UDP headers synthesized).

    ``counters`` (a dict, e.g. the source's): ``captured`` (records written),
    ``capture_errors`` (1 when a write failed: capture stopped there). ``write`` never
    raises.

    ``flush_every_s``: records are handed to the kernel in one ``writev`` once the oldest
    waiting one is this old (by the receive times given to :meth:`write`), or by
    :meth:`flush` (the source calls it whenever its socket is idle for 50 ms); 0 writes
    every record at once. Only whole records are written, so a SIGKILL loses at most the
    records of the last ``flush_every_s`` (+ 50 ms when the stream stops) and leaves a
    file every reader reads to its end."""

    def __init__(self, path: str | os.PathLike, counters: dict[str, int] | None = None,
                 on_warning: Callable[[str], None] | None = _warn,
                 flush_every_s: float = 0.0) -> None:
        self.path = Path(path)
        self.flush_every_s = flush_every_s
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        self._first_t = 0.0
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as exc:
            raise UserError(f"--capture {self.path}: cannot create it ({exc.strerror or exc})") from None
        try:
            os.write(self._fd, _GLOBAL.pack(PCAP_MAGIC_US, 2, 4, 0, 0, SNAPLEN, LINKTYPE_RAW))
        except OSError as exc:
            os.close(self._fd)
            raise UserError(f"--capture {self.path}: cannot write it ({exc.strerror or exc})") from None
        self.counters = counters if counters is not None else {}
        self.counters.setdefault("captured", 0)
        self.counters.setdefault("capture_errors", 0)
        self.on_warning = on_warning
        self.last_error = ""
        self._ident = 0
        self._addr_key: tuple | None = None
        self._addr: tuple[bytes, bytes, int, int, int] = (b"", b"", 0, 0, 0)

    @property
    def closed(self) -> bool:
        return self._fd < 0

    def _addresses(self, src: tuple, dst: tuple) -> tuple[bytes, bytes, int, int, int]:
        key = (src, dst)
        if key != self._addr_key:
            try:
                s = socket.inet_aton(src[0])
                d = socket.inet_aton(dst[0])
            except (OSError, TypeError, IndexError):
                s = d = bytes(4)
            # constant part of the header checksum: version/IHL/TOS, flags (DF), TTL/proto,
            # both addresses
            part = 0x4500 + 0x4000 + 0x4011
            for b in (s, d):
                part += (b[0] << 8 | b[1]) + (b[2] << 8 | b[3])
            self._addr = (s, d, int(src[1]), int(dst[1]), part)
            self._addr_key = key
        return self._addr

    def write(self, data: bytes, src: tuple, dst: tuple, t: float) -> None:
        """Append one datagram received at host time ``t`` from ``src`` at ``dst``
        (``(ip, port)`` tuples)."""
        if self._fd < 0:
            return
        n = len(data)
        s, d, sport, dport, part = self._addr if (src, dst) == self._addr_key else self._addresses(src, dst)
        ip_len = n + 28
        ident = self._ident = (self._ident + 1) & 0xFFFF
        ck = part + ip_len + ident
        ck = (ck & 0xFFFF) + (ck >> 16)
        ck = (ck & 0xFFFF) + (ck >> 16)
        us = int(t * 1e6 + 0.5)
        hdr = _REC.pack(us // 1_000_000, us % 1_000_000, ip_len, ip_len) + _IP_UDP.pack(
            0x45, 0, ip_len, ident, 0x4000, 64, 17, ~ck & 0xFFFF, s, d, sport, dport, n + 8, 0)
        if not self.flush_every_s:
            try:
                w = os.writev(self._fd, (hdr, data))
                if w != 44 + n:
                    raise OSError(f"short write ({w} of {44 + n} bytes)")
            except (OSError, ValueError) as exc:
                self._fail(exc)
                return
            self.counters["captured"] += 1
            return
        pending = self._pending
        if not pending:
            self._first_t = t
        pending.append(hdr)
        pending.append(data)
        self._pending_bytes += 44 + n
        if t - self._first_t >= self.flush_every_s or len(pending) >= 1000:
            self.flush()

    def flush(self) -> None:
        """Write the waiting records (whole records, one ``writev``)."""
        pending = self._pending
        if not pending or self._fd < 0:
            return
        want = self._pending_bytes
        records = len(pending) // 2
        self._pending = []
        self._pending_bytes = 0
        try:
            w = os.writev(self._fd, pending)
            if w != want:
                raise OSError(f"short write ({w} of {want} bytes)")
        except (OSError, ValueError) as exc:
            self._fail(exc)
            return
        self.counters["captured"] += records

    def _fail(self, exc: Exception) -> None:
        self.counters["capture_errors"] += 1
        self.last_error = getattr(exc, "strerror", None) or str(exc)
        self.close()
        if self.on_warning is not None:
            self.on_warning(f"writing {self.path} failed ({self.last_error}); capture stopped "
                            f"after {self.counters['captured']} datagrams, the bridge goes on")

    def close(self) -> None:
        if self._fd >= 0:
            self.flush()
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PcapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ------------------------------------------------------------------ reader


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


def _link_supported(lt: int) -> bool:
    return lt in (LINKTYPE_NULL, LINKTYPE_ETHERNET, LINKTYPE_RAW, LINKTYPE_LOOP, LINKTYPE_LINUX_SLL,
                  LINKTYPE_IPV4, LINKTYPE_IPV6, LINKTYPE_LINUX_SLL2, 12, 14)


_VLAN = (0x8100, 0x88A8, 0x9100)


def udp_of(linktype: int, pkt: bytes):
    """``(src, dst, payload)`` of a UDP packet; None for another protocol; a counter name
    (``ip_fragments``, ``cut_short``, ``unsupported_link``) for UDP that cannot be read."""
    n = len(pkt)
    if linktype == LINKTYPE_ETHERNET:
        off = 12
        if n < 14:
            return None
        etype = pkt[12] << 8 | pkt[13]
        while etype in _VLAN and off + 6 <= n:
            off += 4
            etype = pkt[off] << 8 | pkt[off + 1]
        off += 2
        if etype == 0x0800:
            return _ipv4(pkt, off)
        if etype == 0x86DD:
            return _ipv6(pkt, off)
        return None
    if linktype in (LINKTYPE_RAW, LINKTYPE_IPV4, LINKTYPE_IPV6, 12, 14):
        if not n:
            return None
        v = pkt[0] >> 4
        return _ipv4(pkt, 0) if v == 4 else _ipv6(pkt, 0) if v == 6 else None
    if linktype in (LINKTYPE_NULL, LINKTYPE_LOOP):
        if n < 4:
            return None
        fam = int.from_bytes(pkt[:4], "big" if linktype == LINKTYPE_LOOP else sys.byteorder)
        if fam not in (2, 24, 28, 30) and linktype == LINKTYPE_NULL:  # written on another host
            fam = int.from_bytes(pkt[:4], "little" if sys.byteorder == "big" else "big")
        if fam == 2:
            return _ipv4(pkt, 4)
        if fam in (24, 28, 30):
            return _ipv6(pkt, 4)
        return None
    if linktype in (LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2):
        hl, po = (16, 14) if linktype == LINKTYPE_LINUX_SLL else (20, 0)
        if n < hl:
            return None
        proto = pkt[po] << 8 | pkt[po + 1]
        if proto == 0x0800:
            return _ipv4(pkt, hl)
        if proto == 0x86DD:
            return _ipv6(pkt, hl)
        return None
    return "unsupported_link"


def _udp(pkt: bytes, off: int, end: int, src: str, dst: str):
    if off + 8 > end:
        return "cut_short"
    sport, dport, ulen = struct.unpack_from("!HHH", pkt, off)
    if ulen < 8:
        ulen = end - off  # 0: a jumbogram or an offloaded checksum: take what is there
    if off + ulen > end:
        return "cut_short"
    return (src, sport), (dst, dport), bytes(pkt[off + 8:off + ulen])


def _ipv4(pkt: bytes, off: int):
    n = len(pkt)
    if off + 20 > n:
        return "cut_short" if off + 10 <= n and pkt[off + 9] == 17 else None
    ihl = (pkt[off] & 0x0F) * 4
    if pkt[off + 9] != 17:
        return None
    if ihl < 20:
        return None
    total = pkt[off + 2] << 8 | pkt[off + 3]
    frag = (pkt[off + 6] << 8 | pkt[off + 7]) & 0x3FFF  # MF flag and offset
    if frag:
        return "ip_fragments"
    end = off + total if total else n  # 0: TSO/offloaded length
    if end > n:
        return "cut_short"
    src = socket.inet_ntoa(pkt[off + 12:off + 16])
    dst = socket.inet_ntoa(pkt[off + 16:off + 20])
    return _udp(pkt, off + ihl, end, src, dst)


def _ipv6(pkt: bytes, off: int):
    n = len(pkt)
    if off + 40 > n:
        return None
    plen = pkt[off + 4] << 8 | pkt[off + 5]
    nh = pkt[off + 6]
    src = socket.inet_ntop(socket.AF_INET6, pkt[off + 8:off + 24])
    dst = socket.inet_ntop(socket.AF_INET6, pkt[off + 24:off + 40])
    end = off + 40 + plen if plen else n
    if end > n:
        return "cut_short"
    p = off + 40
    while nh in (0, 43, 60, 44):
        if p + 8 > end:
            return None
        if nh == 44:
            return "ip_fragments"
        nh, p = pkt[p], p + (pkt[p + 1] + 1) * 8
    if nh != 17:
        return None
    return _udp(pkt, p, end, src, dst)

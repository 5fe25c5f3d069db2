"""Writing raw datagram captures as classic pcap files: the writer the bridge uses.

Classic libpcap format, as Wireshark, tcpdump, dpkt and scapy read it: a 24-byte global
header (magic ``a1b2c3d4`` little-endian, version 2.4, snap length 262144, link type 101
``LINKTYPE_RAW``: every packet starts with its IP header), then one record per datagram:
``ts_sec, ts_usec, incl_len, orig_len`` (uint32 each) and a synthesized IPv4 header (20
bytes, a correct header checksum, DF set, TTL 64, the real source and destination
addresses and ports) + UDP header (8 bytes, checksum 0: "none", legal for IPv4) + the
datagram's bytes exactly as received. The timestamp is the bridge's receive time
(``time.time()``, microseconds). Records go to an unbuffered descriptor in ``writev``
calls of whole records only: every record (``flush_every_s=0``) or, as the bridge does, the
records of up to 50 ms at a time and whenever the stream pauses for 50 ms (one system call
per 100 datagrams at Tracker's 2 kHz instead of 100): a SIGKILL loses at most the last
0.1 s. A SIGKILL during a write can cut it at a page boundary (Linux keeps the bytes copied
before the pending fatal signal), leaving part of one record at the end, which
:class:`~mocap_bridge.pcap.reader.PcapReader` counts as a truncated record. A write error (disk full,
folder removed) stops the capture with one warning and is counted; it never stops the
bridge. :func:`capture_path` checks the file or folder ``--capture`` names.
"""

from __future__ import annotations

import os
import socket
import struct
import sys
import time
from collections.abc import Callable
from pathlib import Path

from common.errors import UserError
from mocap_bridge.pcap.formats import LINKTYPE_RAW, PCAP_MAGIC_US, SNAPLEN

_GLOBAL = struct.Struct("<IHHiIII")
_REC = struct.Struct("<IIII")
_IP_UDP = struct.Struct("!BBHHHBBH4s4sHHHH")
_PCAP_SUFFIXES = (".pcap", ".cap")


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

"""The pcap formats' numbers, and one captured packet unwrapped down to its UDP datagram.

Magic numbers, link types, the snap length the bridge writes and the largest record
believed (:mod:`mocap_bridge.pcap.writer` writes files with them,
:mod:`mocap_bridge.pcap.reader` reads them) and :func:`udp_of`: the link layers read
(Ethernet with 802.1Q/802.1ad tags, raw IP 101, 228, 229 and the platform values 12 and
14, BSD loopback 0 and 108, Linux cooked 113 and 276), then IPv4 or IPv6 (extension
headers walked; fragments counted, not reassembled), then UDP.
"""

from __future__ import annotations

import socket
import struct
import sys

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

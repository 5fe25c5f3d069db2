"""Raw datagram captures as standard pcap files: where the writer and the reader live.

The bridge writes classic pcap (:class:`PcapWriter`, :func:`capture_path`:
:mod:`mocap_bridge.pcap.writer`) and reads pcap or pcapng (:func:`open_pcap`,
:class:`PcapReader`, :class:`Datagram`: :mod:`mocap_bridge.pcap.reader`); the formats'
numbers and the unwrapping of one packet down to its UDP datagram (:func:`udp_of`) are in
:mod:`mocap_bridge.pcap.formats`. This module re-exports them all, so
``from mocap_bridge.capture import ...`` keeps working; it holds no code of its own.
"""

from __future__ import annotations

from mocap_bridge.pcap.formats import (  # noqa: F401  (re-exported)
    _VLAN,
    LINKTYPE_ETHERNET,
    LINKTYPE_IPV4,
    LINKTYPE_IPV6,
    LINKTYPE_LINUX_SLL,
    LINKTYPE_LINUX_SLL2,
    LINKTYPE_LOOP,
    LINKTYPE_NULL,
    LINKTYPE_RAW,
    MAX_RECORD,
    PCAP_MAGIC_NS,
    PCAP_MAGIC_US,
    PCAPNG_BOM,
    PCAPNG_SHB,
    SNAPLEN,
    _ipv4,
    _ipv6,
    _link_supported,
    _udp,
    udp_of,
)
from mocap_bridge.pcap.reader import (  # noqa: F401  (re-exported)
    READER_COUNTERS,
    Datagram,
    PcapReader,
    _fmt_head,
    open_pcap,
)
from mocap_bridge.pcap.writer import (  # noqa: F401  (re-exported)
    _GLOBAL,
    _IP_UDP,
    _PCAP_SUFFIXES,
    _REC,
    PcapWriter,
    _warn,
    capture_path,
)

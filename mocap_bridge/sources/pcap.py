"""Replay a capture of the Tracker UDP stream (pcap or pcapng) through the Tracker parser.

``--source pcap:FILE[?speed=X&port=N]``: every UDP datagram of the file (the bridge's own
``--capture`` files, or tcpdump/Wireshark captures: Ethernet, raw IP, Linux cooked;
IPv4 or IPv6) goes through the same :class:`DatagramDecoder` as live datagrams, at the
recorded pace times ``speed`` (0: as fast as possible). ``port`` keeps only datagrams to
or from that UDP port (tcpdump's ``udp port N``); other packets are counted and skipped
(see :class:`mocap_bridge.capture.PcapReader`), as are malformed datagrams.

Times of the published samples, as for the other replays (:mod:`playback`): ``t`` the
nominal host time (start + recorded offset / speed, minus ``--latency-ms``), ``t_recv``
the actual emission time, ``t_src`` the capture time relative to the first datagram
played (s, from the file's integer timestamps, so two replays give the same floats and
a recorder writes the same ``poses.csv``). Poses are in the mocap frame: the bridge's
axis mapping applies, as it does live.
"""

from __future__ import annotations

import math
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from common.errors import UserError
from mocap_bridge.capture import PcapReader
from mocap_bridge.pose import PoseSample
from mocap_bridge.sources.playback import Pacer
from mocap_bridge.sources.vicon_udp import DatagramDecoder, _stderr_notice

QUERY_KEYS = ("speed", "port")


def _warn(msg: str) -> None:
    print(f"pcap: warning: {msg}", file=sys.stderr, flush=True)


def parse_spec(arg: str) -> tuple[Path, dict[str, str]]:
    """``FILE[?key=value&...]`` to the path and its options (a file whose own name holds
    a ``?`` is taken whole when it exists)."""
    if "?" in arg and not Path(arg).exists():
        path, _, query = arg.rpartition("?")
        opts = {}
        for part in filter(None, query.split("&")):
            k, eq, v = part.partition("=")
            if k not in QUERY_KEYS or not eq:
                raise UserError(f"--source pcap:{arg}: unknown option {part!r}; use "
                                "pcap:FILE?speed=X&port=N")
            opts[k] = v
        return Path(path), opts
    return Path(arg), {}


class PcapSource:
    """Datagrams of a capture file through the Tracker parser, paced as recorded.

    Counters: the decoder's (``datagrams``, ``malformed``, ``items``, ...) and the
    reader's (``pcap_records``, ``non_udp``, ``other_port``, ``truncated_records``, ...)
    in one dict.
    """

    in_table_frame = False

    def __init__(self, path: str | Path, rate_scale: float = 1.0, port: int | None = None,
                 latency_s: float = 0.0, zero_is_occluded: bool = True,
                 on_notice: Callable[[str], None] | None = _stderr_notice,
                 on_warning: Callable[[str], None] | None = _warn) -> None:
        if rate_scale < 0 or not math.isfinite(rate_scale):
            raise UserError(f"pcap speed must be >= 0, got {rate_scale:g}")
        if port is not None and not 0 <= port <= 65535:
            raise UserError(f"bad UDP port {port} for the pcap source")
        self.decoder = DatagramDecoder(latency_s, zero_is_occluded, on_notice)
        self.counters = self.decoder.counters
        self.reader = PcapReader(path, port=port, counters=self.counters, on_warning=on_warning)
        self.path = Path(path)
        self.rate_scale = rate_scale
        self.port = port
        self.name = f"pcap:{path}"

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        decode = self.decoder.decode
        t0_ns = pacer = None
        for dg in self.reader:
            if stop.is_set():
                return
            if t0_ns is None:
                t0_ns, pacer = dg.t_ns, Pacer(self.rate_scale)
            t_src = (dg.t_ns - t0_ns) / 1e9
            times = pacer.due(t_src, stop)
            if times is None:
                return
            t_recv, t_nom = times
            batch = decode(dg.payload, t_nom)
            if batch:
                yield [s._replace(t_recv=t_recv, t_src=t_src) for s in batch]

    def close(self) -> None:
        self.reader.close()

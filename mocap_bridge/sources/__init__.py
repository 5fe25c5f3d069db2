"""Pose sources for the bridge.

Every source is an object with::

    name: str                      # for the stats ("vicon-udp:51001", "replay:runs/x", ...)
    in_table_frame: bool           # True when poses are already in the table frame
    counters: dict[str, int]       # source-level counts (datagrams, malformed, ...)
    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]
    def close(self) -> None

``batches`` yields lists of :class:`mocap_bridge.pose.PoseSample` (one list per datagram
or mocap frame) until the source ends or ``stop`` is set; it never blocks longer than
about 0.2 s without checking ``stop``. Live producers push into
:class:`mocap_bridge.sources.push.PushSource`; the plant simulator's source is
:class:`tpods.sim_source.SimSource` (it needs the estimator).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from common.errors import UserError
from mocap_bridge.sources.pcap import PcapSource, parse_spec
from mocap_bridge.sources.replay import ReplaySource
from mocap_bridge.sources.vicon_sdk import ViconSDKSource
from mocap_bridge.sources.vicon_udp import DEFAULT_PORT, ViconUDPSource


def open_source(spec: str, *, rate_scale: float = 1.0, bind: str = "0.0.0.0",
                body: str | None = None, latency_s: float = 0.0,
                capture: str | os.PathLike | None = None):
    """Build a source from its command-line spec.

    ``vicon-udp[:PORT]``, ``vicon-sdk:HOST[:PORT]``, ``replay:RUN_DIR``,
    ``pcap:FILE[?speed=X&port=N]`` (``sim[:RUN_DIR]`` is handled by the command line, see
    :mod:`tpods.sim_source`). ``capture``: a pcap file receiving the raw datagrams
    (``vicon-udp`` only; see :mod:`mocap_bridge.capture`).
    """
    kind, _, arg = spec.partition(":")
    if capture is not None and kind != "vicon-udp":
        raise UserError(f"--capture records the raw datagrams of --source vicon-udp; {kind!r} "
                        "has none to capture (record its poses with tpods mocap record)")
    if kind == "pcap":
        if not arg:
            raise UserError("--source pcap needs a file, e.g. pcap:runs/tracker.pcap")
        path, opts = parse_spec(arg)
        try:
            speed = float(opts["speed"]) if "speed" in opts else rate_scale
            port = int(opts["port"]) if "port" in opts else None
        except ValueError:
            raise UserError(f"--source pcap:{arg}: speed must be a number and port an "
                            "integer") from None
        if not (speed >= 0 and math.isfinite(speed)):
            raise UserError(f"--source pcap:{arg}: speed must be >= 0 (0: as fast as possible)")
        if port is not None and not 0 <= port <= 65535:
            raise UserError(f"--source pcap:{arg}: bad UDP port {port}")
        return PcapSource(path, rate_scale=speed, port=port, latency_s=latency_s)
    if kind == "vicon-udp":
        try:
            port = int(arg) if arg else DEFAULT_PORT
        except ValueError:
            raise UserError(f"bad UDP port in --source {spec!r}") from None
        if not 0 <= port <= 65535:
            raise UserError(f"bad UDP port in --source {spec!r}")
        return ViconUDPSource(port=port, bind=bind, latency_s=latency_s, capture=capture)
    if kind == "vicon-sdk":
        if not arg:
            raise UserError("--source vicon-sdk needs a host, e.g. vicon-sdk:192.168.1.5")
        return ViconSDKSource(arg)
    if kind == "replay":
        if not arg:
            raise UserError("--source replay needs a folder, e.g. replay:runs/sim-1")
        return ReplaySource(Path(arg), rate_scale=rate_scale, body=body)
    raise UserError(f"unknown source {spec!r}; use vicon-udp[:PORT], vicon-sdk:HOST, "
                    "replay:RUN_DIR, pcap:FILE or sim[:RUN_DIR]")  # sim: tpods.sim_source, via the CLI

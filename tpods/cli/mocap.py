"""``tpods mocap bridge`` and ``tpods mocap record``: thin shells over the package."""

from __future__ import annotations

import argparse
import math
import sys
import threading
from pathlib import Path

from common.argtypes import nonneg_float, positive_float
from common.console import Console
from common.errors import UserError
from common.outputs import add_force, stream_folder
from common.zenoh_net import add_zenoh_options
from tpods.cli.options import add_quiet
from tpods.cli.parser import command, group
from tpods.cli.stopping import wait_for_stop, zenoh_session


def register(sub) -> None:
    """Add this package's commands to the `tpods` parser."""
    g = group(sub, "mocap", "motion-capture poses onto Zenoh: bridge and recorder")

    p = command(g, "bridge", cmd_bridge, help="publish mocap poses on Zenoh")
    p.add_argument("--source", default="vicon-udp",
                   help="vicon-udp[:PORT] (Tracker UDP stream, default port 51001), "
                        "vicon-sdk:HOST[:PORT] (DataStream SDK), replay:RUN_DIR (run folder or "
                        "recording), pcap:FILE[?speed=X&port=N] (a Tracker capture: ours, "
                        "tcpdump's or Wireshark's), sim[:RUN_DIR] (plant simulator); default "
                        "vicon-udp")
    p.add_argument("--capture", default=None, metavar="FILE.pcap|DIR",
                   help="vicon-udp: also write every received datagram to a pcap file "
                        "(Wireshark opens it; replay with --source pcap:FILE); a folder gets "
                        "vicon-udp-<date>-<time>.pcap")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --capture file (default: refuse)")
    p.add_argument("--bind", default="0.0.0.0", help="UDP bind address (default 0.0.0.0)")
    p.add_argument("--rate-scale", "--speed", type=nonneg_float, default=1.0, metavar="X",
                   help="replay/pcap/sim speed: 1 real time, 10 ten times faster, 0 as fast as "
                        "possible (default 1)")
    p.add_argument("--prefix", default="tpods/mocap", metavar="P",
                   help="key prefix (default tpods/mocap)")
    p.add_argument("--body", default=None,
                   help="body name for replay of a run folder / sim (default: folder name / tpods1)")
    p.add_argument("--up", choices=("z", "y"), default="z",
                   help="mocap axis along the table normal (default z)")
    p.add_argument("--projection", choices=("heading", "twist"), default="heading",
                   help="yaw from the body x axis projected on the table (heading) or the twist "
                        "about the normal (default heading)")
    p.add_argument("--yaw-offset-deg", type=float, default=0.0, help="added to every yaw, degrees")
    p.add_argument("--latency-ms", type=nonneg_float, default=0.0,
                   help="vicon-udp: fixed latency subtracted from the receive time (default 0)")
    p.add_argument("--keep-zero-poses", action="store_true",
                   help="vicon-udp: publish an all-zero pose as a pose (default: occluded)")
    p.add_argument("--congestion", choices=("block", "drop"), default="block",
                   help="zenoh congestion control (default block: nothing dropped silently)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S seconds (default: until the source ends or Ctrl-C)")
    p.add_argument("--wait-subscriber", type=nonneg_float, default=0.0, metavar="S",
                   help="wait up to S seconds for a subscriber before publishing (useful for "
                        "replay/sim; default 0)")
    p.add_argument("--quiet", action="store_true", help="no console line of statistics")
    add_zenoh_options(p)

    r = command(g, "record", cmd_record, help="record poses from Zenoh into run folders")
    r.add_argument("--key", default="tpods/mocap/**", help="key expression (default tpods/mocap/**)")
    r.add_argument("--out", required=True, metavar="RUN_DIR",
                   help="output folder, or a file X.mcap (only the MCAP recording)")
    r.add_argument("--mcap", action="store_true",
                   help="also record the Zenoh messages to OUT/recording.mcap")
    add_force(r)
    r.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S seconds (default: Ctrl-C)")
    r.add_argument("--t0", type=float, default=None, metavar="EPOCH_S",
                   help="host time of t = 0 for live sources (default: first sample)")
    add_quiet(r)
    add_zenoh_options(r)


def cmd_bridge(args: argparse.Namespace) -> int:
    """Publish rigid-body poses on tpods/mocap/<body>/pose (JSON, schema tpods.pose/1), statistics
    on tpods/mocap/stats every second."""

    from mocap_bridge.bridge import Bridge
    from mocap_bridge.pose import AxisMap
    from mocap_bridge.sources import open_source
    from mocap_bridge.stats import console_line

    if not args.prefix.strip("/"):
        raise UserError("--prefix must not be empty")
    if not math.isfinite(args.yaw_offset_deg):
        raise UserError("--yaw-offset-deg must be finite")
    kind, _, arg = args.source.partition(":")
    capture = None
    if args.capture is not None:
        from mocap_bridge.capture import capture_path

        if kind != "vicon-udp":
            raise UserError(f"--capture records the raw datagrams of --source vicon-udp; {kind!r} "
                            "has none to capture (record its poses with tpods mocap record)")
        capture = capture_path(args.capture, force=args.force)
    if kind == "sim":
        from tpods.sim_source import SimSource

        source = SimSource.from_run(Path(arg) if arg else None, rate_scale=args.rate_scale,
                                    body=args.body or "tpods1")
    else:
        source = open_source(args.source, rate_scale=args.rate_scale, bind=args.bind,
                             body=args.body, latency_s=args.latency_ms * 1e-3, capture=capture)
    if args.keep_zero_poses and hasattr(source, "decoder"):
        source.decoder.zero_is_occluded = False
    console = Console(args.quiet)
    stop = threading.Event()
    try:
        with zenoh_session(args, stop) as session:
            bridge = Bridge(session, prefix=args.prefix,
                            axis_map=AxisMap(up=args.up, projection=args.projection,
                                             yaw_offset_rad=math.radians(args.yaw_offset_deg)),
                            congestion=args.congestion,
                            on_stats=lambda snap: console.show(console_line(snap)))
            print(f"bridge: {source.name} -> {bridge.prefix}/<body>/pose "
                  f"(zenoh id {session.zid()})", file=sys.stderr)
            if capture is not None:
                print(f"bridge: capturing datagrams to {capture}", file=sys.stderr)
            if args.wait_subscriber > 0 and not bridge.wait_for_subscriber(args.wait_subscriber):
                print(f"bridge: no subscriber after {args.wait_subscriber:g} s, publishing "
                      "anyway", file=sys.stderr)
            bridge.run(source, stop=stop, duration_s=args.duration)
    finally:
        source.close()
        console.end()
    tot = bridge.stats.totals()
    src = bridge.stats.source_counters
    extra = f", {src.get('datagrams', 0)} datagrams, {src.get('malformed', 0)} malformed" \
        if "datagrams" in src else ""
    if "pcap_records" in src:  # --source pcap: what the file held besides Tracker datagrams
        extra += "".join(f", {src[k]} {label}" for k, label in (
            ("non_udp", "non-UDP packets skipped"), ("other_port", "on other ports skipped"),
            ("ip_fragments", "IP fragments skipped"), ("cut_short", "cut short by the snap length"),
            ("truncated_records", "truncated record (file cut)"),
            ("damaged_records", "damaged record")) if src.get(k))
    if capture is not None:
        extra += f", {src.get('captured', 0)} captured to {capture}"
        if src.get("capture_errors"):
            extra += " (capture stopped by a write error)"
    print(f"bridge: published {tot['published']} poses of {len(bridge.stats.bodies)} bodies "
          f"({tot['occluded']} occluded, {tot['duplicates']} duplicates dropped, "
          f"{tot['gaps']} missing frames{extra})")
    if tot["published"] == 0:  # a lab user expects a bridge that bridged nothing to fail
        raise UserError(nothing_published(kind, arg, source.name, src))
    return 0


def nothing_published(kind: str, arg: str, name: str, counters: dict) -> str:
    """The refusal of a bridge run that published no pose: what arrived, where to look."""
    from mocap_bridge.sources.vicon_udp import DEFAULT_PORT

    if kind == "vicon-udp":
        got = counters.get("datagrams", 0)
        why = (f"{got} datagrams arrived but none held a pose (not Vicon Tracker's UDP object "
               "stream?)" if got else f"no datagram arrived on UDP port {arg or DEFAULT_PORT}: is Vicon "
               "Tracker streaming to this host and port (Tracker's UDP object stream settings, "
               "--bind, the firewall)?")
    else:
        why = f"the source {name} gave none (an empty recording, or the wrong body/--source?)"
    return f"the bridge published no poses: {why}"


def cmd_record(args: argparse.Namespace) -> int:
    """Write OUT/<body>/poses.csv (t,x,y,psi) and OUT/<body>/samples.csv, flushed as samples
    arrive; with --mcap also OUT/recording.mcap (every message on the key, one channel per Zenoh
    key); --out X.mcap writes only that MCAP file."""

    from common.mcap.log import McapLog
    from common.outputs import is_mcap, stream_file
    from common.plausible import check_finite_time
    from mocap_bridge.recorder import Recorder, subscribe

    check_finite_time(args.t0, "--t0")  # before the folder is made
    if is_mcap(args.out):
        return _record_mcap_only(args, stream_file(args.out, force=args.force))
    console = Console(args.quiet)
    stop = threading.Event()
    out = stream_folder(args.out, force=args.force, command="tpods mocap record")
    log = McapLog(out / "recording.mcap", meta={"command": "tpods mocap record",
                                                "key": args.key}) if args.mcap else None
    rec = Recorder(out, key=args.key, t0=args.t0, mcap=log)

    def console_line() -> None:
        c = rec.counters
        console.show(f"record: {len(rec.bodies)} bodies | received {c['received']} | "
                     f"poses {c['recorded']} | occluded {c['occluded']} | "
                     f"malformed {c['malformed']}")

    try:
        with zenoh_session(args, stop) as session:
            sub = subscribe(session, args.key, rec)
            wait_for_stop(stop, args.duration, console_line)
            sub.undeclare()
    except BaseException:
        rec.close("incomplete")  # recording.json says so; what was written stays
        raise
    finally:  # nothing received is no success: recording.json says failed, exit 2 below
        counters = rec.close(None if rec.counters["received"] else "failed")
        console.end()
    print(f"record: {counters['recorded']} poses of {len(rec.bodies)} bodies written to {rec.out} "
          f"({counters['occluded']} occluded, {counters['malformed']} malformed, "
          f"{counters['not_increasing']} out of order)")
    if log is not None:
        print(f"record: {log.counters['messages']} messages on {len(log.topics)} keys written to "
              f"{log.path}")
    if counters.get("write_errors"):
        raise UserError(f"{counters['write_errors']} samples could not be written to {rec.out} "
                        f"({rec.last_error})")
    if not counters["received"]:
        raise UserError(nothing_received(args.key))
    return 0


def nothing_received(key: str) -> str:
    """The refusal of a recording that received no message on ``key``."""
    return (f"received nothing on {key}: is `tpods mocap bridge` running on the same Zenoh "
            "network (--connect/--listen), and does --key match its --prefix?")


def _record_mcap_only(args: argparse.Namespace, path: Path) -> int:
    """``tpods mocap record --out X.mcap``: every message on the key into one MCAP file."""
    from common.mcap.log import McapLog, subscribe

    console = Console(args.quiet)
    stop = threading.Event()
    log = McapLog(path, meta={"command": "tpods mocap record", "key": args.key})
    status = "incomplete"
    try:
        with zenoh_session(args, stop) as session:
            sub = subscribe(session, args.key, log)
            wait_for_stop(stop, args.duration, lambda: console.show(
                f"record: {log.counters['messages']} messages on {len(log.topics)} keys"))
            sub.undeclare()
        log.drain(count_errors=True)  # what is still queued for the background writer counts too
        status = "incomplete" if log.counters.get("write_errors") else \
            "complete" if log.counters["messages"] else "failed"
    finally:
        log.close(status)
        console.end()
    print(f"record: {log.counters['messages']} messages on {len(log.topics)} keys written to {path}")
    if log.counters.get("write_errors"):
        raise UserError(f"{log.counters['write_errors']} messages could not be written to {path}")
    if not log.counters["messages"]:
        raise UserError(nothing_received(args.key))
    return 0

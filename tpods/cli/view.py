"""``tpods view``: watch a run live in Foxglove (:mod:`tpods.viewer`)."""

from __future__ import annotations

import argparse
import sys
import threading

from common.argtypes import nonneg_float
from common.console import Console
from common.errors import UserError
from common.outputs import add_force
from common.zenoh_net import add_zenoh_options
from tpods.cli.options import add_key_prefixes, add_quiet, check_key_prefixes
from tpods.cli.parser import command
from tpods.cli.stopping import zenoh_session

DEFAULT_HOST = "127.0.0.1"  # = tpods.viewer.DEFAULT_HOST (not imported: it loads foxglove)
DEFAULT_PORT = 8765


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port must be a whole number, got {text!r}") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 0-65535, got {v}")
    return v


def register(sub) -> None:
    """Add ``tpods view`` to the `tpods` parser."""
    p = command(
        sub, "view", cmd_view, help="serve the live poses, duties and estimates to Foxglove")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to serve on (default {DEFAULT_HOST}; 0.0.0.0 for other hosts)")
    p.add_argument("--port", type=_port, default=DEFAULT_PORT,
                   help=f"WebSocket port (default {DEFAULT_PORT}; 0: any free port)")
    p.add_argument("--body", action="append", default=None,
                   help="body to show (repeatable; default: every body seen)")
    p.add_argument("--pose-rate", type=nonneg_float, default=50.0, metavar="HZ",
                   help="poses forwarded per body and second (default 50; 0: every pose)")
    add_key_prefixes(p)
    p.add_argument("--write-layout", metavar="FILE.json", default=None,
                   help="write a Foxglove layout for the --body names (default tpods1) to FILE "
                        "and exit")
    add_force(p, "--write-layout")
    add_quiet(p)
    add_zenoh_options(p)


def cmd_view(args: argparse.Namespace) -> int:
    """Subscribe to the poses, valve commands and live estimates on Zenoh and serve them over the
    Foxglove WebSocket protocol: open Foxglove (desktop app or app.foxglove.dev), connect to
    ws://localhost:8765 and load docs/foxglove/tpods_layout.json. Channels per body:
    /tpods/<body>/frame (foxglove.FrameTransform), pose, duty, estimate (with the 1-sigma band),
    health; /tpods/clock (lab time of the last pose). Ctrl-C ends it."""

    check_key_prefixes(args)
    if args.body is not None and not all(b.strip() for b in args.body):
        raise UserError("--body must not be empty")
    if not args.host.strip():
        raise UserError("--host must not be empty")
    if args.write_layout is not None:
        return _write_layout(args)

    from tpods.viewer import LiveView

    view = LiveView(None, host=args.host, port=args.port, bodies=args.body,
                    prefix=args.prefix, mocap_prefix=args.mocap_prefix, pose_rate=args.pose_rate)
    view.start_server()  # a port in use or a bad host: one line, before Zenoh
    console = Console(args.quiet)
    stop = threading.Event()
    try:
        with zenoh_session(args, stop) as view.session:
            try:
                view.subscribe()
                print(f"view: serving on {view.url} (Foxglove: Open connection -> Foxglove "
                      f"WebSocket -> {view.url}; layout docs/foxglove/tpods_layout.json)",
                      file=sys.stderr, flush=True)
                while not stop.wait(0.5):
                    console.show(view.status_line())
            finally:
                view.close()  # its subscribers before the session
    finally:
        view.close()
        console.end()
    c = view.counters
    print(f"view: stopped; {c.get('pose_shown', 0)} poses, {c.get('cmd_shown', 0)} commands, "
          f"{c.get('estimate_shown', 0)} estimates shown for {len(view.bodies)} bodies; "
          f"{c.get('malformed', 0)} malformed skipped")
    return 0


def _write_layout(args: argparse.Namespace) -> int:
    from tpods.view_layout import write_layout

    print(f"wrote {write_layout(args.write_layout, args.body, force=args.force)}")
    return 0

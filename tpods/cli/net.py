"""``tpods net router``: the Zenoh router of a lab of several hosts (a thin shell over
:mod:`common.zenoh_router`)."""

from __future__ import annotations

import argparse
import sys
import threading

from common.argtypes import positive_float
from common.zenoh_net import add_zenoh_options
from tpods.cli.options import add_quiet
from tpods.cli.parser import command, group
from tpods.cli.stopping import stop_on_signals


def register(sub) -> None:
    """Add ``tpods net`` to the `tpods` parser."""
    g = group(sub, "net", "the lab network: a Zenoh router joining the hosts")
    p = command(g, "router", cmd_router, help="run a Zenoh router (eclipse-zenoh, router mode)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C or SIGTERM)")
    add_quiet(p)
    add_zenoh_options(p)


def cmd_router(args: argparse.Namespace) -> int:
    """Run an eclipse-zenoh session in router mode until Ctrl-C or SIGTERM: the hub that
    the mocap, module and estimator hosts connect to (--connect tcp/ROUTER:7447
    --no-multicast on each). It listens on --listen (default tcp/[::]:7447: every address,
    port 7447), connects to other routers given with --connect, and takes TLS and access
    control from --zenoh-config FILE. It prints the endpoints it listens on, one line per
    session that joins or leaves (unless --quiet), and exits 0 when stopped."""
    from common.zenoh_router import serve_router

    stop = threading.Event()

    def ready(run) -> None:
        eps = ", ".join(run.locators) if run.locators else "(endpoints not readable: admin " \
                                                           "space off in the config file)"
        print(f"router: zid {run.zid} listening on {eps}", flush=True)

    def peers(joined: set[str], left: set[str]) -> None:
        if args.quiet:
            return
        for z in sorted(joined):
            print(f"router: session {z} joined", file=sys.stderr, flush=True)
        for z in sorted(left):
            print(f"router: session {z} left", file=sys.stderr, flush=True)

    with stop_on_signals(stop):
        run = serve_router(args, stop, on_ready=ready, on_peers=peers, duration_s=args.duration)
    print(f"router: stopped after {run.elapsed_s:.1f} s; {len(run.peers_seen)} sessions met",
          flush=True)
    return 0

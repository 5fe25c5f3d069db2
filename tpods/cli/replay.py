"""``tpods replay FILE.mcap``: a recording back onto Zenoh (:mod:`common.mcap.replay`)."""

from __future__ import annotations

import argparse
import sys
import threading
import time

from common.argtypes import nonneg_float
from common.console import Console
from common.zenoh_net import add_zenoh_options
from tpods.cli.options import add_quiet
from tpods.cli.parser import command
from tpods.cli.stopping import zenoh_session


def register(sub) -> None:
    """Add ``tpods replay`` to the `tpods` parser."""
    p = command(
        sub, "replay", cmd_replay, help="publish an MCAP recording back onto Zenoh with its timing")
    p.add_argument("file", metavar="FILE.mcap", help="the recording")
    p.add_argument("--speed", type=nonneg_float, default=1.0, metavar="X",
                   help="1 recorded pace, 2 twice as fast, 0 as fast as possible (default 1)")
    p.add_argument("--prefix", action="append", default=None, metavar="P",
                   help="remap the keys: OLD=NEW replaces a leading OLD (e.g. tpods=lab2), a plain "
                        "P is put in front of every key (repeatable; default: the recorded keys)")
    p.add_argument("--wait-subscriber", type=nonneg_float, default=0.0, metavar="S",
                   help="wait up to S seconds for a subscriber of the first key before "
                        "publishing (default 0)")
    add_quiet(p)
    add_zenoh_options(p)


def cmd_replay(args: argparse.Namespace) -> int:
    """Publish every message of an MCAP file (from `tpods mocap record`, `tpods estimate live
    --mcap` or `tpods export mcap`) on the Zenoh key it was recorded from, payload unchanged, at
    the recorded pace. A file cut by a kill (no summary) is replayed up to its last complete
    chunk."""

    from common.mcap.log import iter_messages
    from common.mcap.replay import remapper, replay

    remap = remapper(args.prefix)
    next(iter(iter_messages(args.file)), None)  # a missing or non-MCAP file: one line, before Zenoh
    console = Console(args.quiet)
    stop = threading.Event()
    try:
        with zenoh_session(args, stop) as session:
            res = replay(session, args.file, speed=args.speed, remap=remap, stop=stop,
                         wait_subscriber_s=args.wait_subscriber,
                         on_progress=lambda p: console.show(
                             f"replay: {p['published']} messages | t {p['t_s']:.1f} s"))
            time.sleep(0.2)  # let the last messages leave before the session closes
    finally:
        console.end()
    how = "" if res["complete"] else " (file without summary: read up to its last complete chunk)"
    print(f"replay: {res['published']} messages on {len(res['keys'])} keys, {res['span_s']:.3f} s "
          f"of recording in {res['elapsed_s']:.3f} s{how}")
    if stop.is_set():
        print("replay: stopped", file=sys.stderr)
    return 0

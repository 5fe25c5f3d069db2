"""``tpods export mcap RUN_DIR --out FILE.mcap``: a run folder as MCAP (:mod:`common.mcap.export`)."""

from __future__ import annotations

import argparse

from common.outputs import add_force
from tpods.cli.options import add_key_prefixes
from tpods.cli.parser import command, group


def register(sub) -> None:
    """Add the ``tpods export`` group."""
    g = group(sub, "export", "convert recordings to other formats")
    p = command(
        g, "mcap", cmd_export_mcap,
        help="a run folder as an MCAP file of the Zenoh messages it stands for")
    p.add_argument("run", metavar="RUN_DIR", help="the run folder")
    p.add_argument("--out", required=True, metavar="FILE.mcap", help="the MCAP file to write")
    add_force(p)
    p.add_argument("--body", default=None,
                   help="body name in the keys and payloads (default: run.json's body, else the "
                        "folder name)")
    add_key_prefixes(p, "command/estimate/truth")
    p.add_argument("--t0", type=float, default=None, metavar="EPOCH_S",
                   help="host time of the run's t = 0 (default: run.json t0_lab, else 0: run time)")


def cmd_export_mcap(args: argparse.Namespace) -> int:
    """Write poses.csv (one tpods.pose/1 message per row on <mocap-prefix>/<body>/pose),
    commands.csv (tpods.cmd/1 on <prefix>/<body>/cmd), estimates.csv (tpods.estimate/1 on
    <prefix>/<body>/estimate) and truth.csv (tpods.truth/1 on <prefix>/<body>/truth) where
    present, in time order, with their JSON schemas. `tpods replay` publishes the file."""

    from common.mcap.export import export_run_file

    info = export_run_file(args.run, args.out, force=args.force, body=args.body, prefix=args.prefix,
                           mocap_prefix=args.mocap_prefix, t0=args.t0)
    counts = ", ".join(f"{n} {f}" for f, n in info["counts"].items())
    print(f"wrote {info['path']}: {info['messages']} messages for body {info['body']} ({counts} rows)")
    return 0

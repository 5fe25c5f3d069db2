"""``tpods import poses|commands``: other labs' recordings as a run folder (the use cases
are :mod:`mocap_bridge.exports.run_import`; this module parses and prints)."""

from __future__ import annotations

import argparse
import sys

from common.outputs import add_force
from tpods.cli.parser import command, group

_FORMS = ("vector", "bitmask", "hex", "bits", "columns", "duty", "wrench")


def register(sub) -> None:
    """Add the ``tpods import`` group."""
    g = group(sub, "import", "other labs' recordings (Vicon, Motive, CSV logs) as a run folder")
    p = command(
        g, "poses", cmd_import_poses,
        help="a Vicon/Motive export or any CSV as poses.csv of a run folder")
    p.add_argument("file", metavar="FILE", help="the export or CSV file")
    p.add_argument("--out", required=True, metavar="RUN", help="the run folder (created, or one that "
                   "already holds the commands of the same recording)")
    p.add_argument("--body", default=None, metavar="NAME",
                   help="the body (Vicon subject:segment or its part, Motive rigid body name) when "
                        "the file holds several")
    p.add_argument("--columns", default=None, metavar="MAP",
                   help="read FILE as a plain CSV: t=COL,x=COL,y=COL,yaw=COL (or z=, qx=,qy=,qz=,qw= "
                        "for a quaternion); COL is a header name or a 1-based number")
    p.add_argument("--units", default=None, metavar="LENGTH,ANGLE",
                   help="units the file does not state: m|cm|mm and rad|deg (e.g. mm,deg)")
    p.add_argument("--time-unit", default=None, metavar="s|ms",
                   help="the unit of the --columns time column, unless its name states it")
    p.add_argument("--plane", default=None, metavar="AB",
                   help="the mocap axes that are the table's x and y, each optionally signed: xy "
                        "(default for Vicon and --columns), x-z (default for Motive, Y-up), zx, ... "
                        "(a leading minus needs =: --plane=-yx)")
    p.add_argument("--yaw-sign", type=float, default=1.0, choices=(1.0, -1.0), metavar="1|-1",
                   help="multiply the yaw by -1 when the source turns the other way")
    p.add_argument("--rotation", default=None, metavar="KIND",
                   help="the rotation convention when the file does not say and the body tilts: "
                        "euler-xyz|helical (Vicon RX,RY,RZ), intrinsic|extrinsic (Motive Euler)")
    add_time_from(p, "poses")
    add_force(p, "RUN/poses.csv")

    c = command(
        g, "commands", cmd_import_commands,
        help="a valve or force log as commands.csv or wrench.csv of a run folder")
    c.add_argument("file", metavar="FILE", help="the log (CSV with a header line)")
    c.add_argument("--out", required=True, metavar="RUN", help="the run folder")
    who = c.add_mutually_exclusive_group()
    who.add_argument("--vehicle", default=None, metavar="FILE",
                     help="the vehicle file (vehicle.toml): its [[thrusters]] give the valve count "
                          "and order; copied into RUN")
    who.add_argument("--valves", type=int, default=None, metavar="N", help="the number of valves")
    c.add_argument("--columns", required=True, metavar="MAP",
                   help="t=COL and valves=COL (one cell per row), or d1=COL..dN=COL, or "
                        "fx=COL,fy=COL,mz=COL")
    c.add_argument("--as", dest="form", default=None, choices=_FORMS,
                   help="how to read the valve cells (a vector [1, 0, ...] is recognised by itself)")
    c.add_argument("--frame", default="body", choices=("body", "lab"),
                   help="the frame of a wrench (default body)")
    c.add_argument("--time-unit", default=None, metavar="s|ms",
                   help="the unit of the time column, unless its name states it")
    c.add_argument("--units", default=None, metavar="FORCE,MOMENT",
                   help="wrench units the column names do not state: N|mN and Nm|mNm")
    add_time_from(c, "commands")
    add_force(c, "RUN/commands.csv (wrench.csv)")


def add_time_from(p, rows: str) -> None:
    """The ``--time-from`` and ``--time-from-units`` options of an import (``rows``: what
    the rows are, for the help)."""
    p.add_argument("--time-from", default=None, metavar="MAP",
                   help=f"rebuild the {rows}' times when the t= column is a nominal counter: "
                        "vx=COL,x=COL,vy=COL,y=COL,wz=COL,yaw=COL names logged finite-difference "
                        "velocities (per second) and the positions they differentiate (any of the "
                        "pairs), each row's interval is dX/VX from the best resolved one; or dt=COL, "
                        "a column of each row's interval since the previous row (unit: --time-unit). "
                        "Rows at rest take the median interval. The first row keeps its nominal time; "
                        "the map is kept in RUN/time_base.csv for the other import")
    p.add_argument("--time-from-units", default=None, metavar="LENGTH,ANGLE",
                   help="units of the --time-from positions (m|cm|mm, rad|deg; velocities per "
                        "second of the same) unless their names state them")


def _warn(w: str) -> None:
    print(f"tpods: warning: {w}", file=sys.stderr)


def _report(res) -> int:
    for line in res.lines:
        print(line)
    return 0


def cmd_import_poses(args: argparse.Namespace) -> int:
    """Read a pose recording and write RUN/poses.csv (t,x,y,psi in s, m, rad; t from the first kept
    frame) and RUN/run.json (kind import-poses, the source, the counts of skipped frames). Vicon
    Tracker (Objects) and Nexus (Segments) CSV exports and OptiTrack Motive CSV exports are
    recognised from their header; any other CSV is read through --columns and --units. Occluded
    frames (empty or NaN cells) are skipped and counted; a bad cell is one error naming it."""
    from mocap_bridge.exports.run_import import import_poses

    return _report(import_poses(
        args.file, args.out, body=args.body, columns=args.columns, units=args.units,
        time_unit=args.time_unit, plane=args.plane, yaw_sign=args.yaw_sign, rotation=args.rotation,
        time_from=args.time_from, time_from_units=args.time_from_units, force=args.force,
        on_warning=_warn))


def cmd_import_commands(args: argparse.Namespace) -> int:
    """Read a command log and write RUN/commands.csv (t,d1..dN: duty percent, an on/off valve 0 or
    100, in the vehicle's thruster order) or RUN/wrench.csv (t,fx,fy,mz in N, N m; its frame in
    run.json), each row held until the next; an end row one median step after the last. Valve
    states are read as vectors "[1, 0, ...]", integer or hex bitmasks (bit i = valve i+1), bit
    strings, per-valve on/off or duty columns. Times share the poses' origin when RUN already
    holds the poses of the same recording."""
    from mocap_bridge.exports.run_import import import_commands

    return _report(import_commands(
        args.file, args.out, args.columns, vehicle=args.vehicle, valves=args.valves,
        form=args.form, frame=args.frame, time_unit=args.time_unit, units=args.units,
        time_from=args.time_from, time_from_units=args.time_from_units, force=args.force,
        on_warning=_warn))

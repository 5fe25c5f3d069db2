"""``tpods calibrate mass|bifilar|trifilar|combine|thrust``: ground-truth mass and Izz (thin
shell; the pendulums' commands are in :mod:`tpods.cli.calibrate_swing`, the in-situ thrust
calibration in :mod:`tpods.cli.calibrate_thrust`)."""

from __future__ import annotations

import argparse
import sys

from common.argtypes import float_list, int_at_least, nonneg_float, positive_float
from tpods.cli.calibrate_swing import cmd_pendulum as cmd_bifilar  # noqa: F401 - re-exported
from tpods.cli.calibrate_swing import register_bifilar, register_trifilar
from tpods.cli.calibrate_thrust import (
    design_calibration,  # noqa: F401  (re-exported)
    print_json_indented,
    register_thrust,
)
from tpods.cli.parser import command, group


def register(sub) -> None:
    """Add this package's commands to the `tpods` parser."""
    cal = group(sub, "calibrate", "ground-truth mass (balance) and Izz (bifilar pendulum, parts); in-situ thrust "
                 "calibration from a known body")
    _register_mass(cal)
    register_bifilar(cal)
    register_trifilar(cal)
    _register_combine(cal)
    register_thrust(cal)
    from tpods.cli.calibrate_pendulum import register_pendulum_check

    register_pendulum_check(cal)


_print_json = print_json_indented


# ------------------------------------------------------------------------------ mass


def _register_mass(cal) -> None:
    p = command(
        cal, "mass", cmd_mass, help="mass from N stable balance readings, with a GUM uncertainty")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--scale", metavar="URL",
                     help="serial port or pyserial URL of an OHAUS Scout balance")
    src.add_argument("--readings-from", metavar="FILE",
                     help="readings taken by hand, one per line ('720.1', '720.1 g'; "
                          "'?' marks unstable and is skipped)")
    src.add_argument("--values", type=float_list(), metavar="V1,V2,...",
                     help="readings on the command line, in --unit")
    p.add_argument("--readings", type=int_at_least(1), default=10,
                   help="stable readings to take from the balance (default 10)")
    p.add_argument("--accuracy-g", type=nonneg_float, default=2.5,
                   help="stated balance accuracy +-a in grams (default 2.5, the paper's)")
    p.add_argument("--resolution-g", type=nonneg_float, default=0.0,
                   help="display resolution d in grams, adds d/(2 sqrt 3) (default 0: inside "
                        "the accuracy)")
    p.add_argument("--unit", default="g", help="unit of numbers without one (default g)")
    p.add_argument("--baudrate", type=int_at_least(1), default=9600, help="default 9600")
    p.add_argument("--bytesize", type=int, choices=(7, 8), default=8, help="default 8")
    p.add_argument("--parity", choices=("N", "E", "O"), default="N", help="default N")
    p.add_argument("--stopbits", type=int, choices=(1, 2), default=1, help="default 1")
    p.add_argument("--timeout", type=positive_float, default=5.0,
                   help="seconds to wait for one stable reading (default 5)")
    p.add_argument("--capture", metavar="FILE.jsonl|DIR", default=None,
                   help="with --scale: record a byte-exact transcript of the balance's serial link "
                        "(docs/recordings.md) into FILE.jsonl, or DIR/scale.serial.jsonl; replay it "
                        "with --scale replay://PATH")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def cmd_mass(args: argparse.Namespace) -> int:
    """Mean, standard deviation and combined standard uncertainty (repeatability s/sqrt(N) and the
    balance's +-accuracy as a rectangular bound, a/sqrt(3)) of N stable readings, in kg. Give
    exactly one source: --scale, --readings-from or --values."""
    import contextlib

    from calibration.weigh import mass_lines, weigh

    bar = contextlib.nullcontext()
    if args.scale:
        from tqdm import tqdm

        bar = tqdm(total=args.readings, desc="stable readings", unit="rd", file=sys.stderr,
                   disable=args.json or None)
    with bar:
        res = weigh(scale=args.scale, readings_from=args.readings_from, values=args.values,
                    readings=args.readings, accuracy_g=args.accuracy_g,
                    resolution_g=args.resolution_g, unit=args.unit, capture=args.capture,
                    progress=bar.update if args.scale else None, baudrate=args.baudrate,
                    bytesize=args.bytesize, parity=args.parity, stopbits=args.stopbits,
                    timeout=args.timeout)
    for w in res.warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.json:
        _print_json(res.to_dict())
        return 0
    print("\n".join(mass_lines(res, args.accuracy_g)))
    return 0


# --------------------------------------------------------------------------- combine


def _register_combine(cal) -> None:
    p = command(
        cal, "combine", cmd_combine,
        help="mass and Izz of a structure from its parts (parallel-axis theorem)")
    p.add_argument("parts", metavar="PARTS.toml")
    p.add_argument("--about", type=float_list(2), default=None, metavar="X,Y",
                   help="report Izz about this point, m (default: the file's 'about', else the "
                        "centre of mass)")
    p.add_argument("--compare", default=None, metavar="ESTIMATE.json",
                   help="compare with an estimate (tpods estimate batch --json, or its "
                        "estimate.json): mass, Izz about the centre of mass, the centre of mass; "
                        "the parts' positions must be in the tracked frame of the run")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def cmd_combine(args: argparse.Namespace) -> int:
    """Combine parts (mass, Izz about own centre, position in the plane) from a PARTS.toml into the
    structure's mass, centre of mass and Izz about a point (see
    calibration/examples/truss_two_modules.toml)."""

    from calibration.composite import combine_file

    rep = combine_file(args.parts, args.about)
    for w in rep.warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.compare:
        rep.compare_with(args.compare)
    if args.json:
        _print_json(rep.to_dict())
        return 0
    print("\n".join(rep.lines(args.compare)))
    return 0

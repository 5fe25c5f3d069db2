"""``tpods calibrate mass|bifilar|trifilar|combine|thrust``: ground-truth mass and Izz (thin
shell; the pendulums' commands are in :mod:`tpods.cli.calibrate_swing`, the in-situ thrust
calibration in :mod:`tpods.cli.calibrate_thrust`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from common.argtypes import float_list, int_at_least, nonneg_float, positive_float
from common.errors import DeviceError, UserError
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


def _scale_readings(args) -> tuple[list[float], int]:
    from calibration.mass import take_readings

    try:
        from bench.ohaus.driver import NotALoadReading, OhausScout
    except ImportError:
        raise UserError("--scale needs the OHAUS driver (bench/ohaus/driver.py), which is not installed; "
                        "use --readings-from FILE or --values") from None
    from tqdm import tqdm

    capture = _mass_capture(args.capture)
    with OhausScout(args.scale, baudrate=args.baudrate, bytesize=args.bytesize,
                    parity=args.parity, stopbits=args.stopbits, timeout=args.timeout,
                    stable_timeout=args.timeout, capture=capture) as scale, \
            tqdm(total=args.readings, desc="stable readings", unit="rd", file=sys.stderr,
                 disable=args.json or None) as bar:
        def read():
            try:
                return scale.read(mode="SP")
            except NotALoadReading:
                raise
            except DeviceError:  # only lines that are not weight lines, twice: not a balance
                if scale.n_readings == 0 and scale.n_garbage >= 2:
                    ex = scale.garbage_examples[-1].decode("ascii", "replace").strip()
                    raise NotALoadReading(
                        f"the device at {args.scale} (--scale) does not answer like an OHAUS "
                        f"balance: {scale.n_garbage} replies that are not weight lines, the last "
                        f"{ex!r} (is it the balance, at --baudrate {args.baudrate}, "
                        f"--bytesize {args.bytesize}, --parity {args.parity}?)") from None
                raise

        return take_readings(read, args.readings, progress=bar.update, fatal=(NotALoadReading,))


def _mass_capture(target: str | None):
    """--capture FILE.jsonl or DIR (-> DIR/scale.serial.jsonl); an existing file is refused."""
    if target is None:
        return None
    p = Path(target)
    p = p if p.name.endswith(".jsonl") else p / "scale.serial.jsonl"
    if p.exists():
        raise UserError(f"--capture: {p} already exists; choose another file or folder")
    if p.parent.exists() and not p.parent.is_dir():
        raise UserError(f"--capture {target}: {p.parent} is not a folder")
    return p


def cmd_mass(args: argparse.Namespace) -> int:
    """Mean, standard deviation and combined standard uncertainty (repeatability s/sqrt(N) and the
    balance's +-accuracy as a rectangular bound, a/sqrt(3)) of N stable readings, in kg. Give
    exactly one source: --scale, --readings-from or --values."""

    from calibration.mass import mass_from_readings, parse_readings_text, to_kg

    to_kg(1.0, args.unit)  # validates --unit
    if args.capture and not args.scale:
        raise UserError("--capture records the balance's serial link: it needs --scale")
    if args.scale:
        readings, skipped = _scale_readings(args)
    elif args.readings_from:
        path = Path(args.readings_from)
        if not path.is_file():
            raise UserError(f"{path}: file not found")
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            raise UserError(f"{path}: not a text file") from None
        readings, skipped = parse_readings_text(text, args.unit, str(path))
    else:
        readings, skipped = [to_kg(v, args.unit) for v in args.values], 0
    res = mass_from_readings(readings, args.accuracy_g * 1e-3, args.resolution_g * 1e-3,
                             skipped=skipped, unit=None if args.scale else args.unit)
    for w in res.warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.json:
        _print_json(res.to_dict())
        return 0
    print(f"mass = {res.mass_kg:.6g} kg +- {res.u_combined_kg:.2g} kg (standard uncertainty, k=1; "
          f"expanded U = {res.expanded_kg:.2g} kg, k=2)")
    print(f"  {res.n_readings} stable readings, std {res.std_kg * 1e3:.3g} g"
          + (f", {skipped} unstable skipped" if skipped else ""))
    print(f"  Type A (repeatability s/sqrt(N)) {res.u_typeA_kg * 1e3:.3g} g; Type B (+-{args.accuracy_g:g}"
          f" g rectangular, a/sqrt(3)) {res.u_typeB_kg * 1e3:.3g} g"
          + (f"; resolution {res.u_resolution_kg * 1e3:.3g} g" if res.u_resolution_kg else ""))
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

    from calibration.composite import combine, load_parts, plausibility_warnings

    parts, about = load_parts(args.parts)
    if args.about is not None:
        about = tuple(args.about)
    res = combine(parts, about)
    for w in plausibility_warnings(parts, res):
        print(f"tpods: warning: {w}", file=sys.stderr)
    rows = _compare_rows(res, args.compare) if args.compare else None
    if args.json:
        _print_json({**res.to_dict(), **({"comparison": rows} if rows is not None else {})})
        return 0
    print(f"mass = {res.mass_kg:.6g} +- {res.mass_sigma_kg:.2g} kg ({len(parts)} parts)")
    print(f"centre of mass = ({res.com_m[0]:.5g}, {res.com_m[1]:.5g}) m")
    print(f"Izz about ({res.about_m[0]:.5g}, {res.about_m[1]:.5g}) m = {res.izz_kgm2:.6g} +- "
          f"{res.izz_sigma_kgm2:.2g} kg m^2")
    print(f"Izz about the centre of mass = {res.izz_com_kgm2:.6g} +- {res.izz_com_sigma_kgm2:.2g} kg m^2")
    for r in res.parts:
        print(f"  {r['name']:32s} m {r['mass_kg']:.4g} kg  Izz own {r['izz_own_kgm2']:.3g}  "
              f"+ m d^2 {r['parallel_axis_kgm2']:.3g} kg m^2")
    if rows is not None:
        print(f"compared with {args.compare} (difference in combined sigmas):")
        for r in rows:
            z = "-" if r["difference_sigmas"] is None else f"{r['difference_sigmas']:+.1f}"
            print(f"  {r['quantity']:22s} parts {r['ground_truth']:.6g} +- "
                  f"{r['ground_truth_sigma']:.2g}   estimate {r['estimate']:.6g} +- "
                  f"{r['estimate_sigma']:.2g} {r['unit']}   difference {r['difference']:+.3g} ({z})")
    return 0


def _compare_rows(res, path: str) -> list[dict]:
    from calibration.composite import compare

    try:
        est = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise UserError(f"--compare {path}: not found") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise UserError(f"--compare {path}: not an estimate's JSON ({exc})") from None
    if not isinstance(est, dict):
        raise UserError(f"--compare {path}: not an estimate's JSON object")
    return compare(res, est)

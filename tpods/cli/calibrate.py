"""``tpods calibrate mass|bifilar|trifilar|combine|thrust``: ground-truth mass and Izz, and the
in-situ thrust calibration from a body of known mass and Izz (thin shell; the pendulums'
commands are in :mod:`tpods.cli.calibrate_swing`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from common.argtypes import float_list, int_at_least, nonneg_float, positive_float, time_window
from common.errors import DeviceError, UserError
from common.outputs import add_force, result_output
from tpods.cli.calibrate_swing import cmd_pendulum as cmd_bifilar  # noqa: F401 - re-exported
from tpods.cli.calibrate_swing import register_bifilar, register_trifilar
from tpods.cli.options import add_noise_sigmas
from tpods.cli.parser import group


def register(sub) -> None:
    """Add this package's commands to the `tpods` parser."""
    cal = group(sub, "calibrate", "ground-truth mass (balance) and Izz (bifilar pendulum, parts); in-situ thrust "
                 "calibration from a known body")
    _register_mass(cal)
    register_bifilar(cal)
    register_trifilar(cal)
    _register_combine(cal)
    _register_thrust(cal)


def _print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")


# ------------------------------------------------------------------------------ mass


def _register_mass(cal) -> None:
    p = cal.add_parser(
        "mass", help="mass from N stable balance readings, with a GUM uncertainty",
        description="Mean, standard deviation and combined standard uncertainty (repeatability "
                    "s/sqrt(N) and the balance's +-accuracy as a rectangular bound, a/sqrt(3)) of "
                    "N stable readings, in kg. Give exactly one source: --scale, --readings-from "
                    "or --values.")
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
    p.set_defaults(func=cmd_mass)


def _scale_readings(args) -> tuple[list[float], int]:
    from calibration.mass import take_readings

    try:
        from bench.ohaus import NotALoadReading, OhausScout
    except ImportError:
        raise UserError("--scale needs the OHAUS driver (bench/ohaus.py), which is not installed; "
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
    p = cal.add_parser(
        "combine", help="mass and Izz of a structure from its parts (parallel-axis theorem)",
        description="Combine parts (mass, Izz about own centre, position in the plane) from a "
                    "PARTS.toml into the structure's mass, centre of mass and Izz about a point "
                    "(see calibration/examples/truss_two_modules.toml).")
    p.add_argument("parts", metavar="PARTS.toml")
    p.add_argument("--about", type=float_list(2), default=None, metavar="X,Y",
                   help="report Izz about this point, m (default: the file's 'about', else the "
                        "centre of mass)")
    p.add_argument("--compare", default=None, metavar="ESTIMATE.json",
                   help="compare with an estimate (tpods estimate batch --json, or its "
                        "estimate.json): mass, Izz about the centre of mass, the centre of mass; "
                        "the parts' positions must be in the tracked frame of the run")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_combine)


def cmd_combine(args: argparse.Namespace) -> int:
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


# ---------------------------------------------------------------------------- thrust


def _register_thrust(cal) -> None:
    p = cal.add_parser(
        "thrust", help="in-situ thrust calibration from a run of a body of known mass and Izz",
        description="Estimate per-thruster efficiencies and/or per-nozzle-count scale factors of "
                    "a thrust table from a run of a body whose mass and Izz are known (balance "
                    "and bifilar pendulum), with the initial state (and friction/tilt with "
                    "--model), and write a new table: the original coefficients, plus "
                    "[calibration] with the factors and their covariance (measurement noise, "
                    "the known values' uncertainty and the table's own, propagated). Every "
                    "estimator reads it and carries its uncertainty. A run that cannot separate "
                    "the factors (a thruster never opened; --per both on a run with one nozzle "
                    "count, such as the phase-shifted sine) is refused; 'tpods design --for "
                    "thrust-calibration' designs one that can.")
    p.add_argument("run_dir", metavar="RUN_DIR", help="run folder of the known body")
    p.add_argument("--mass", type=positive_float, required=True, metavar="KG",
                   help="known mass of the body, kg")
    p.add_argument("--mass-sigma", type=nonneg_float, default=0.0, metavar="KG",
                   help="its standard uncertainty, kg (default 0; tpods calibrate mass gives it)")
    p.add_argument("--izz", type=positive_float, required=True, metavar="KGM2",
                   help="known Izz of the body, kg m^2")
    p.add_argument("--izz-sigma", type=nonneg_float, default=0.0, metavar="KGM2",
                   help="its standard uncertainty, kg m^2 (default 0; tpods calibrate bifilar "
                        "gives it)")
    p.add_argument("--thrust-table", required=True, metavar="T.toml",
                   help="the table to calibrate ('table2': the built-in Table 2)")
    p.add_argument("--per", choices=("thruster", "nozzles", "both"), default="thruster",
                   help="thruster: efficiency of each thruster (default); nozzles: scale of each "
                        "nozzle count the run uses; both: efficiencies and the scales of the "
                        "other counts relative to the count the run holds longest")
    p.add_argument("--model", choices=("ideal", "friction", "friction+tilt"), default="ideal",
                   help="nuisance parameters estimated beside the factors: ideal (none, "
                        "default), friction (ct, cr, kb), friction+tilt (also ax, ay)")
    p.add_argument("--window", type=time_window, default=None, metavar="T0:T1",
                   help="use only poses with T0 <= t <= T1, s; T0,T1 is read too")
    p.add_argument("--clamp", action="store_true",
                   help="clamp duties outside the table's valid range instead of refusing them")
    add_noise_sigmas(p)
    p.add_argument("--out", required=True, metavar="NEW.toml|DIR",
                   help="the calibrated table (NEW.toml), or a folder that receives "
                        "thrust_table.toml and calibration.json")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_force(p)
    p.set_defaults(func=cmd_thrust)


def cmd_thrust(args: argparse.Namespace) -> int:
    from common.outputs import not_an_input
    from common.plausible import body_problems
    from common.runfolder import read_run
    from common.thrust_table import ThrustTable
    from estimator.batch.thrust_calibration import calibrate_run

    out = result_output(args.out, "thrust_table.toml", force=args.force,
                        command="tpods calibrate thrust")
    builtin = args.thrust_table.lower() == "table2"
    not_an_input(out, args.run_dir, None if builtin else args.thrust_table)
    table = ThrustTable.default() if builtin else ThrustTable.load(args.thrust_table)
    run = read_run(args.run_dir)
    for p in body_problems(args.mass, args.izz):  # before the fit, which may then fail
        print(f"tpods: warning: the known body (--mass, --izz): {p}: implausible for an "
              "air-table body (kg and kg m^2?)", file=sys.stderr)
    if args.window:
        run = run.window(*args.window)
    res = calibrate_run(run, table, mass_kg=args.mass, izz_kgm2=args.izz,
                        mass_sigma_kg=args.mass_sigma, izz_sigma_kgm2=args.izz_sigma,
                        per=args.per, model=args.model, sigma_pos_m=args.sigma_pos,
                        sigma_yaw_rad=math.radians(args.sigma_yaw_deg), clamp=args.clamp)
    if not res.converged:
        raise UserError(f"{run.path}: the calibration did not converge "
                        f"({res.iterations} iterations); no table written")
    new = res.new_table(table, run=str(run.path))
    doc = res.to_dict()
    doc.update({"run": str(run.path), "thrust_table": "built-in Table 2" if builtin
                else args.thrust_table, "out": str(out.main)})
    with out.writing_main() as (main, d):  # d: None for --out FILE.toml
        new.save(main)
        if d is not None:
            (d / "calibration.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    warnings = list(res.warnings)
    if args.mass_sigma == 0 or args.izz_sigma == 0:
        warnings.append("--mass-sigma/--izz-sigma not given: the factors' sigma leaves out the "
                        "known values' uncertainty")
    for w in warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.json:
        _print_json(doc)
        return 0
    print(f"thrust calibration on {run.path} ({len(res.t)} poses, t = {res.t[0]:.3f}.."
          f"{res.t[-1]:.3f} s; --per {res.per}, --model {res.model})")
    print(f"  known body: m = {args.mass:.6g} +/- {args.mass_sigma:.2g} kg, "
          f"Izz = {args.izz:.6g} +/- {args.izz_sigma:.2g} kg m^2")
    print(f"  converged; {res.iterations} iterations, horizons "
          f"{', '.join(f'{h:.1f}' for h in res.stages)} s")
    b = res.budget()
    lim = res.limited_by()
    print(f"  {'factor':<16} {'value':>8} {'sigma':>8}   {'noise':>8} {'mass':>8} {'Izz':>8} "
          f"{'table':>8}   limited by")
    for n, v in zip(res.names, res.values, strict=True):
        p = b[n]
        print(f"  {n:<16} {v:8.4f} {p['total']:8.2g}   {p['noise']:8.2g} {p['mass']:8.2g} "
              f"{p['izz']:8.2g} {p['table']:8.2g}   {lim[n]}")
    if res.reference_count is not None:
        print(f"  nozzle_scale.{res.reference_count} held at "
              f"{table.nozzle_factor(res.reference_count):g} (reference count: the efficiencies "
              "carry the common level)")
    if res.absorbed:
        print(f"  calibrated away (removed from the table's [uncertainty]): {', '.join(res.absorbed)}")
    for e, v in res.extras.items():
        print(f"  {e:<5} = {v:.4g} +/- {res.extras_sigma[e]:.2g}")
    rms = res.rms_residuals()
    print(f"  rms residuals: x {rms[0] * 100:.3f} cm, y {rms[1] * 100:.3f} cm, "
          f"yaw {math.degrees(rms[2]):.3f} deg")
    print(f"  wrote {out.main}" + (", calibration.json" if out.is_folder else ""))
    return 0


def design_calibration(args: argparse.Namespace, table, settings, out_folder) -> int:
    """``tpods design --for thrust-calibration``: the D-optimal gated sine for the factors
    ``--per`` (m and Izz known: ``--mass``, ``--izz``), written as commands.csv and
    design.json into ``out_folder`` (a checked :class:`common.outputs.ResultFolder`)."""
    import numpy as np
    from tqdm import tqdm

    from estimator.batch.calibration_design import evaluate_calibration, search_calibration
    from estimator.plant.inputs import make_input

    compared = []
    for spec in ["phase-sine", "translate-rotate", *args.compare]:
        cmd_t, duty = make_input(spec, args.duration, args.cmd_rate)
        try:
            compared.append(evaluate_calibration(cmd_t, duty, table, settings, args.per, label=spec))
        except UserError as exc:
            raise UserError(f"{spec}: {exc}") from None
    total = args.candidates + args.refine * args.refine_evals
    with tqdm(total=total, desc="design", unit="eval", file=sys.stderr, leave=False,
              disable=None) as bar:
        res = search_calibration(table, settings, per=args.per, n_random=args.candidates,
                                 n_refine=args.refine, refine_evals=args.refine_evals,
                                 omega_range=tuple(args.omega_range), seed=args.seed,
                                 progress=bar.update)
    best = res.best
    doc = {"for": "thrust-calibration", "per": args.per, "best": best.to_dict(),
           "compared": [e.to_dict() for e in compared], "evaluated": res.evaluated,
           "settings": {"duration_s": args.duration, "cmd_rate_hz": args.cmd_rate,
                        "pose_rate_hz": args.pose_rate, "table_size_m": list(args.table_size),
                        "margin_m": args.margin, "max_yaw_rate_rad_s": args.max_yaw_rate,
                        "mass_kg": args.mass, "izz_kgm2": args.izz},
           "commands_csv": str(out_folder.path / "commands.csv")}
    with out_folder.writing() as d:
        np.savetxt(d / "commands.csv", np.column_stack([best.cmd_t, best.duty_pct]), delimiter=",",
                   header="t,d1,d2,d3,d4", comments="", fmt="%.10g")
        (d / "design.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    if args.json:
        _print_json(doc)
        return 0
    print(f"D-optimal thrust-calibration input over {args.duration:g} s (--per {args.per}, "
          f"m = {args.mass:g} kg and Izz = {args.izz:g} kg m^2 known; {res.evaluated} sequences)")
    print(f"  {'input':<44} {'log det':>9} {'max sd':>8} {'counts open':>12} {'excursion x,y m':>16}  fits")
    for e in [*compared, best]:
        lab = e.label if len(e.label) <= 44 else e.label[:41] + "..."
        sd = f"{e.sigma.max():8.2g}" if e.sigma.size and np.all(np.isfinite(e.sigma)) else f"{'-':>8}"
        counts = ",".join(str(k) for k in sorted(e.counts_s))
        print(f"  {lab:<44} {e.logdet:9.3f} {sd} {counts:>12} {e.excursion_m[0]:7.2f},"
              f"{e.excursion_m[1]:7.2f}  {'yes' if e.feasible else 'NO: ' + e.reason}")
    print(f"  best: {best.spec.describe()}")
    print(f"  wrote {out_folder.path / 'commands.csv'} (play it or simulate it with tpods sim "
          "--input), design.json")
    return 0

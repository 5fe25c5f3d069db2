"""``tpods calibrate thrust``: the in-situ thrust calibration from a run of a body of known
mass (and Izz, or Izz estimated with the factors), and ``tpods design --for
thrust-calibration`` (thin shell over :mod:`estimator.batch.thrust_calibration.calibrate`)."""

from __future__ import annotations

import argparse
import json
import math
import sys

from common.argtypes import nonneg_float, positive_float, time_window
from common.errors import UserError
from common.outputs import add_force, result_output
from tpods.cli.options import add_noise_sigmas
from tpods.cli.parser import command


def print_json_indented(obj) -> None:
    """``obj`` as one indented JSON object on stdout (the calibrate commands' form)."""
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")


_print_json = print_json_indented


def register_thrust(cal) -> None:
    p = command(
        cal, "thrust", cmd_thrust,
        help="in-situ thrust calibration from a run of a body of known mass and Izz")
    p.add_argument("run_dir", metavar="RUN_DIR", help="run folder of the known body")
    p.add_argument("--mass", type=positive_float, required=True, metavar="KG",
                   help="known mass of the body, kg")
    p.add_argument("--mass-sigma", type=nonneg_float, default=0.0, metavar="KG",
                   help="its standard uncertainty, kg (default 0; tpods calibrate mass gives it)")
    p.add_argument("--izz", type=positive_float, default=None, metavar="KGM2",
                   help="known Izz of the body, kg m^2 (omit it: Izz is estimated with the "
                        "factors, only the mass known)")
    p.add_argument("--izz-sigma", type=nonneg_float, default=0.0, metavar="KGM2",
                   help="its standard uncertainty, kg m^2 (default 0; tpods calibrate bifilar "
                        "gives it)")
    p.add_argument("--thrust-table", default=None, metavar="T.toml",
                   help="the table to calibrate ('table2': the built-in Table 2); a vehicle "
                        "run of on/off valves needs none (its vehicle.toml is calibrated)")
    p.add_argument("--vehicle", default=None, metavar="FILE",
                   help="vehicle.toml of the run (default: the run folder's): its valves' "
                        "forces are calibrated and --out writes a new vehicle.toml")
    p.add_argument("--per", choices=("thruster", "nozzles", "both", "common"), default="thruster",
                   help="thruster: efficiency of each thruster (default); nozzles: scale of each "
                        "nozzle count the run uses; both: efficiencies and the scales of the "
                        "other counts relative to the count the run holds longest; common: one "
                        "scale of every thrust")
    p.add_argument("--model", choices=("ideal", "friction", "friction+tilt"), default="ideal",
                   help="nuisance parameters estimated beside the factors: ideal (none, "
                        "default), friction (ct, cr, kb), friction+tilt (also ax, ay)")
    p.add_argument("--estimate-com", action="store_true",
                   help="estimate the centre of mass's offset cx, cy from the tracked origin "
                        "with the factors (default: at the tracked origin)")
    p.add_argument("--window", type=time_window, default=None, metavar="T0:T1",
                   help="use only poses with T0 <= t <= T1, s; T0,T1 is read too")
    p.add_argument("--clamp", action="store_true",
                   help="clamp duties outside the table's valid range instead of refusing them")
    add_noise_sigmas(p)
    p.add_argument("--out", required=True, metavar="NEW.toml|DIR",
                   help="the calibrated table (NEW.toml), or a folder that receives "
                        "thrust_table.toml and calibration.json")
    p.add_argument("--segments", default=None, metavar="LEN|auto|none",
                   help="a vehicle of on/off valves: fit the whole run as shooting segments "
                        "(each its own initial state; length 5s, auto, or none: single "
                        "shooting, the default); efficiencies with damping, tilt and the dead "
                        "time, a dead thruster marked")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_force(p)


def cmd_thrust(args: argparse.Namespace) -> int:
    """Estimate per-thruster efficiencies and/or per-nozzle-count scale factors of a thrust table
    from a run of a body whose mass and Izz are known (balance and bifilar pendulum), with the
    initial state (and friction/tilt with --model), and write a new table: the original
    coefficients, plus [calibration] with the factors and their covariance (measurement noise,
    the known values' uncertainty and the table's own, propagated). Every estimator reads it and
    carries its uncertainty. A run that cannot separate the factors (a thruster never opened;
    --per both on a run with one nozzle count, such as the phase-shifted sine) is refused;
    'tpods design --for thrust-calibration' designs one that can. Without --izz, Izz is
    estimated with the factors (only the mass known), with its total sigma; a run that does not
    inform both (no rotation, or no net force) is refused. A factor near zero or negative names
    a dead or reversed thruster (and no table is written for a non-positive one)."""

    import numpy as np

    from tpods.cli import calibrate_thrust_segments as by_segments

    if by_segments.wanted(args):
        return by_segments.cmd_thrust_segments(args)
    from common.argtypes import vehicle_file
    from common.outputs import not_an_input
    from common.plausible import body_problems
    from common.runfolder import read_run
    from common.thrust_table import ThrustTable
    from estimator.batch.thrust_calibration.calibrate import calibrate_run

    run = read_run(args.run_dir, vehicle_file(args.vehicle) if args.vehicle else None)
    vehicle = run.structure if hasattr(run.structure, "thrusters") else None
    if vehicle is None and args.thrust_table is None:
        raise UserError("--thrust-table is needed: the run is not a vehicle run (no vehicle.toml "
                        "in it and no --vehicle)")
    if run.structure is not None and vehicle is None:
        raise UserError(f"{run.path}: a structure run: its modules' tables are calibrated one "
                        "module at a time (calibrate thrust is not built for structures)")
    out = result_output(args.out, "vehicle.toml" if vehicle is not None else "thrust_table.toml",
                        force=args.force, command="tpods calibrate thrust")
    builtin = args.thrust_table is not None and args.thrust_table.lower() == "table2"
    not_an_input(out, args.run_dir, None if builtin or args.thrust_table is None
                 else args.thrust_table)
    table = (None if args.thrust_table is None else ThrustTable.default() if builtin
             else ThrustTable.load(args.thrust_table))
    if vehicle is not None:
        table = vehicle.with_table(table) if table is not None else vehicle
    if args.izz is None and args.izz_sigma:
        raise UserError("--izz-sigma is the uncertainty of a known --izz; without --izz, Izz is "
                        "estimated (its sigma is reported)")
    for p in body_problems(args.mass, args.izz):  # before the fit, which may then fail
        print(f"tpods: warning: the known body (--mass, --izz): {p}: implausible for an "
              "air-table body (kg and kg m^2?)", file=sys.stderr)
    if args.window:
        run = run.window(*args.window)
    # a vehicle of on/off valves, per thruster, Izz estimated: a run single shooting cannot
    # carry is fitted by segments instead (said), whatever single shooting raised
    by_parts = (vehicle is not None and args.per == "thruster" and args.izz is None
                and args.thrust_table is None and args.segments is None
                and all(t.table is None for t in vehicle.thrusters))
    try:
        res = calibrate_run(run, table, mass_kg=args.mass, izz_kgm2=args.izz,
                            mass_sigma_kg=args.mass_sigma, izz_sigma_kgm2=args.izz_sigma,
                            per=args.per, model=args.model, sigma_pos_m=args.sigma_pos,
                            sigma_yaw_rad=math.radians(args.sigma_yaw_deg), clamp=args.clamp,
                            estimate_com=args.estimate_com)
        failed = None if res.converged else f"did not converge ({res.iterations} iterations)"
    except UserError as exc:
        if not by_parts:
            raise
        failed = f"failed ({exc})"
    if failed and by_parts:
        print(f"tpods: warning: single shooting {failed}: one initial state cannot carry this "
              "run; fitting it by segments instead (--segments auto)", file=sys.stderr)
        args.segments = "auto"
        return by_segments.cmd_thrust_segments(args)
    if failed:
        raise UserError(f"{run.path}: the calibration {failed}; no table written")
    doc = res.to_dict()
    unusable = [n for n, v in zip(res.names, res.values, strict=True) if v <= 0]
    doc.update({"run": str(run.path), "thrust_table": "built-in Table 2" if builtin
                else args.thrust_table, "out": None if unusable else str(out.main)})
    if vehicle is not None:
        doc["vehicle"] = vehicle.name
    if not unusable:
        with out.writing_main() as (main, d):  # d: None for --out FILE.toml
            if vehicle is not None:
                import tomli_w

                from common.vehicle_toml import vehicle_document
                from estimator.batch.thrust_calibration.vehicle import calibrated_vehicle

                v = calibrated_vehicle(vehicle, res.names, res.values, res.cov, str(main))
                main.write_text(f"# tpods calibrate thrust {run.path}: in-flight factors "
                                f"{dict(zip(res.names, np.round(res.values, 5).tolist(), strict=True))} "
                                f"(--mass {args.mass:g}); force_sigma_n = the factors' total "
                                "sigma\n" + tomli_w.dumps(vehicle_document(
                                    v.name, v.thrusters, v.valves, v.body, main.parent,
                                    supplies=v.supplies)))
            else:
                res.new_table(table, run=str(run.path)).save(main)
            if d is not None:
                (d / "calibration.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    warnings = list(res.warnings)
    if args.mass_sigma == 0 or (args.izz is not None and args.izz_sigma == 0):
        warnings.append("--mass-sigma/--izz-sigma not given: the factors' sigma leaves out the "
                        "known values' uncertainty")
    for w in warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.json:
        _print_json(doc)
    if unusable:
        raise UserError(f"{run.path}: {', '.join(unusable)} not positive (a dead or reversed "
                        "thruster, see the warnings): a table cannot hold it; no table written")
    if args.json:
        return 0
    print(f"thrust calibration on {run.path} ({len(res.t)} poses, t = {res.t[0]:.3f}.."
          f"{res.t[-1]:.3f} s; --per {res.per}, --model {res.model})")
    if res.izz is None:
        print(f"  known body: m = {args.mass:.6g} +/- {args.mass_sigma:.2g} kg, "
              f"Izz = {args.izz:.6g} +/- {args.izz_sigma:.2g} kg m^2")
    else:
        iz = res.izz
        print(f"  known body: m = {args.mass:.6g} +/- {args.mass_sigma:.2g} kg; Izz estimated: "
              f"{iz['izz_kgm2']:.6g} +/- {iz['izz_sigma_kgm2']:.2g} kg m^2 (noise "
              f"{iz['izz_sigma_noise_kgm2']:.2g}, mass {iz['izz_sigma_mass_kgm2']:.2g}, table "
              f"{iz['izz_sigma_table_kgm2']:.2g})")
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

"""``tpods calibrate thrust``: the in-situ thrust calibration from a run of a body of known
mass (and Izz, or Izz estimated with the factors), and ``tpods design --for
thrust-calibration`` (thin shell over :mod:`estimator.batch.thrust_calibration.run` and
:func:`estimator.batch.calibration_design.design_thrust_calibration`)."""

from __future__ import annotations

import argparse
import json
import sys

from common.argtypes import nonneg_float, positive_float, time_window
from common.errors import UserError
from common.outputs import add_force
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

    from estimator.batch.thrust_calibration.run import calibrate_thrust_run

    cal = calibrate_thrust_run(
        args.run_dir, args.mass, args.out, mass_sigma=args.mass_sigma, izz=args.izz,
        izz_sigma=args.izz_sigma, thrust_table=args.thrust_table, vehicle=args.vehicle,
        per=args.per, model=args.model, estimate_com=args.estimate_com, window=args.window,
        clamp=args.clamp, sigma_pos=args.sigma_pos, sigma_yaw_deg=args.sigma_yaw_deg,
        segments=args.segments, force=args.force,
        on_warning=lambda w: print(f"tpods: warning: {w}", file=sys.stderr))
    if args.json:
        _print_json(cal.doc)
    if cal.refusal:
        raise UserError(cal.refusal)
    if not args.json:
        print("\n".join(cal.lines))
    return 0


def design_calibration(args: argparse.Namespace, table, settings, out_folder) -> int:
    """``tpods design --for thrust-calibration``: the D-optimal gated sine for the factors
    ``--per`` (m and Izz known: ``--mass``, ``--izz``), written as commands.csv and
    design.json into ``out_folder`` (a checked :class:`common.outputs.ResultFolder`)."""
    from tqdm import tqdm

    from estimator.batch.calibration_design import design_thrust_calibration

    total = args.candidates + args.refine * args.refine_evals
    with tqdm(total=total, desc="design", unit="eval", file=sys.stderr, leave=False,
              disable=None) as bar:
        d = design_thrust_calibration(
            table, settings, out_folder, per=args.per, compare=tuple(args.compare),
            candidates=args.candidates, refine=args.refine, refine_evals=args.refine_evals,
            omega_range=tuple(args.omega_range), seed=args.seed, progress=bar.update)
    if args.json:
        _print_json(d.doc)
        return 0
    print("\n".join(d.lines))
    return 0

"""``tpods design``: D-optimal input design (:mod:`estimator.reports.design_report`), for m
and Izz or, with ``--for thrust-calibration``, for the thrust table's in-situ factors
(:func:`tpods.cli.calibrate.design_calibration`)."""

from __future__ import annotations

import argparse

from common.argtypes import (
    IZZ_KGM2,
    MASS_KG,
    float_list,
    nonneg_float,
    positive_float,
)
from common.outputs import ResultFolder, add_force
from tpods.cli.estimate_output import print_json
from tpods.cli.options import (
    add_cmd_rate,
    add_json_flag,
    add_pose_rate,
    add_random_seed,
    add_sim_duration,
    add_structure_or_vehicle,
    add_thrust_table,
)
from tpods.cli.parser import command


def register(sub) -> None:
    """Add ``tpods design`` to the `tpods` parser."""
    d = command(
        sub, "design", cmd_design,
        help="D-optimal input design (phase-shifted sines) under a workspace bound")
    add_sim_duration(d)
    add_cmd_rate(d)
    add_pose_rate(d)
    d.add_argument("--mass", type=MASS_KG, default=None,
                   help="assumed mass, kg (default the paper's module; a --vehicle/--structure: "
                        "its [body], else needed)")
    d.add_argument("--izz", type=IZZ_KGM2, default=None,
                   help="assumed Izz, kg m^2 (default as --mass)")
    d.add_argument("--table-size", type=float_list(2), default=[2.0, 2.0], metavar="W,H",
                   help="table size in metres, module starting at its centre (default 2,2)")
    d.add_argument("--margin", type=nonneg_float, default=0.0,
                   help="keep the module centre this far from the table edge, m (default 0)")
    d.add_argument("--max-yaw-rate", type=positive_float, default=None, metavar="RAD_S",
                   help="also require |r| <= this along the predicted trajectory (default: no limit)")
    add_thrust_table(d)
    d.add_argument("--noise-pos", type=positive_float, default=0.01, help="position sigma, m")
    d.add_argument("--noise-yaw-deg", type=positive_float, default=1.0, help="yaw sigma, deg")
    d.add_argument("--candidates", type=int, default=64, help="random candidates (default 64)")
    d.add_argument("--refine", type=int, default=2, help="Nelder-Mead refinements (default 2)")
    d.add_argument("--refine-evals", type=int, default=60,
                   help="evaluations per refinement (default 60)")
    d.add_argument("--omega-range", type=float_list(2), default=[0.2, 4.0], metavar="LO,HI",
                   help="frequency search range, rad/s (default 0.2,4)")
    d.add_argument("--compare", nargs="*", default=[], metavar="INPUT",
                   help="also score these inputs: phase-sine, translate-rotate, or commands.csv paths")
    add_random_seed(d)
    d.add_argument("--out", required=True, metavar="DIR",
                   help="write commands.csv (the best input), design.json and figures here")
    add_force(d)
    d.add_argument("--for", dest="design_for", choices=("mass-izz", "thrust-calibration"),
                   default="mass-izz",
                   help="mass-izz: phase-shifted sines, D-optimal for m and Izz (default); "
                        "thrust-calibration: gated sines that open the thrusters in different "
                        "numbers, D-optimal for the thrust table's in-situ factors with m and "
                        "Izz known (for tpods calibrate thrust)")
    d.add_argument("--per", choices=("thruster", "nozzles", "both"), default="both",
                   help="--for thrust-calibration: the factors to design for (default both)")
    add_json_flag(d)
    add_structure_or_vehicle(d, "design for a structure (structure.toml): every module's duties "
                        "together, D-optimal on m, Izz, cx, cy; --mass/--izz and the centre of "
                        "mass default to the file's [body] values or its geometry")


def cmd_design(args: argparse.Namespace) -> int:
    """Compare input sequences by the D-optimal criterion (log det of the Fisher information of
    mass and Izz, initial state marginalised) and search the phase-shifted-sine family
    (amplitude, frequency, phases; duties inside the table's valid range) for the best one whose
    predicted trajectory stays on the table. Writes the best sequence as commands.csv."""
    from estimator.reports.design_report import design_inputs, design_settings

    out_folder = ResultFolder(args.out, force=args.force, command="tpods design")
    search = dict(candidates=args.candidates, refine=args.refine, refine_evals=args.refine_evals,
                  omega_range=args.omega_range, compare=args.compare)
    table, settings = design_settings(
        duration_s=args.duration, cmd_rate_hz=args.cmd_rate, pose_rate_hz=args.pose_rate,
        mass_kg=args.mass, izz_kgm2=args.izz, table_size_m=args.table_size, margin_m=args.margin,
        max_yaw_rate=args.max_yaw_rate, noise_pos_m=args.noise_pos,
        noise_yaw_deg=args.noise_yaw_deg, structure=args.structure,
        thrust_table=args.thrust_table, design_for=args.design_for, **search)
    if args.design_for == "thrust-calibration":
        from tpods.cli.calibrate import design_calibration

        args.mass, args.izz = settings.plant.mass_kg, settings.plant.izz_kgm2
        return design_calibration(args, table, settings, out_folder)
    rep = design_inputs(table, settings, seed=args.seed, structure=args.structure, **search)
    with out_folder.writing() as d:
        out = rep.write(d, out_folder.path)
    if args.json:
        print_json(out)
        return 0
    for line in rep.lines(out_folder.path):
        print(line)
    return 0

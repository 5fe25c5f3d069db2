"""``tpods design``: D-optimal input design (:mod:`estimator.batch.design`), for m and Izz
or, with ``--for thrust-calibration``, for the thrust table's in-situ factors
(:func:`tpods.cli.calibrate.design_calibration`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from common.argtypes import (
    IZZ_KGM2,
    MASS_KG,
    float_list,
    nonneg_float,
    positive_float,
)
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
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


def _check_design_size(args: argparse.Namespace) -> None:
    """Refuse a design that will not fit in memory (one candidate's bound, and every scored
    candidate's trajectory, which the search keeps), naming the options; announce a long one."""
    import tpods.cli.sizes as sizes

    n_poses = sizes.samples(args.duration, args.pose_rate)
    n_cmds = sizes.samples(args.duration, args.cmd_rate)
    evals = 1 + args.candidates + args.refine * args.refine_evals + len(args.compare)
    one_bytes, one_s = sizes.crlb_cost(sizes.crlb_segments(n_poses, n_cmds, args.duration), 2)
    kept = evals * sizes.DESIGN_KEPT_BYTES_PER_POSE * n_poses
    span = (f"--duration {sizes.number(args.duration)} s at --pose-rate "
            f"{sizes.number(args.pose_rate)} Hz and --cmd-rate {sizes.number(args.cmd_rate)} Hz")
    # one candidate (its bound and what the search keeps of it), then all of them
    sizes.refuse_if_too_big(
        f"{span} is {sizes.samples_text(args.duration, args.pose_rate)} poses and "
        f"{sizes.samples_text(args.duration, args.cmd_rate)} command rows per candidate",
        one_bytes + kept / evals, "lower --duration, --pose-rate or --cmd-rate")
    sizes.refuse_if_too_big(
        f"{evals} candidates (1 + --candidates {args.candidates} + --refine {args.refine} "
        f"x --refine-evals {args.refine_evals}"
        f"{f' + {len(args.compare)} --compare' if args.compare else ''}) of "
        f"{sizes.samples_text(args.duration, args.pose_rate)} "
        f"poses each ({span})",
        one_bytes + kept, "lower --candidates, --refine-evals, --duration or --pose-rate")
    sizes.announce(evals * one_s, f"scoring {evals} candidates")


def cmd_design(args: argparse.Namespace) -> int:
    """Compare input sequences by the D-optimal criterion (log det of the Fisher information of
    mass and Izz, initial state marginalised) and search the phase-shifted-sine family
    (amplitude, frequency, phases; duties inside the table's valid range) for the best one whose
    predicted trajectory stays on the table. Writes the best sequence as commands.csv."""

    from tqdm import tqdm

    from common.thrust_table import load_thrust_table
    from estimator.batch.design import DesignSettings, evaluate_commands, search
    from estimator.plant.inputs import make_input
    from estimator.plant.model import PlantParams

    out_folder = ResultFolder(args.out, force=args.force, command="tpods design")
    if args.candidates < 1 or args.refine < 0 or args.refine_evals < 1:
        raise UserError("--candidates and --refine-evals must be >= 1, --refine >= 0")
    if args.omega_range[0] <= 0 or args.omega_range[1] <= args.omega_range[0]:
        raise UserError("--omega-range must be LO,HI with 0 < LO < HI")
    if min(args.table_size) <= 2 * args.margin:
        raise UserError("--table-size must exceed twice the --margin")
    if getattr(args, "structure", None):
        from common.layout_files import load_layout

        known = load_layout(args.structure).body.known()
        if all(n in known for n in ("mass", "izz", "cx", "cy")):
            raise UserError(f"{args.structure}: [body] gives mass, Izz and the centre of mass as "
                            "known: nothing left to design for (give a value a sigma, or drop it)")
    _check_design_size(args)
    table = load_thrust_table(args.thrust_table)
    structure = None
    if not getattr(args, "structure", None):
        args.mass = PAPER_MASS_KG if args.mass is None else args.mass
        args.izz = PAPER_IZZ_KGM2 if args.izz is None else args.izz
    plant = PlantParams(args.mass or PAPER_MASS_KG, args.izz or PAPER_IZZ_KGM2)
    if getattr(args, "structure", None):
        from common.layout_files import load_layout

        if args.design_for == "thrust-calibration":
            raise UserError("--for thrust-calibration is not built for structures yet")
        if args.compare:
            raise UserError("--compare takes single-module inputs; a structure design "
                            "compares with the phase-shifted sine over all its channels")
        structure = load_layout(args.structure)
        g = structure.initial_guess()
        body = structure.body
        if structure.kind == "vehicle" and not structure.is_single_at_origin and (
                (args.mass is None and body.mass_kg is None) or (args.izz is None and body.izz_kgm2 is None)):
            # its initial guess is the paper's 2.3 kg module: a design for another body
            raise UserError(f"{args.structure}: states no [body] mass_kg and izz_kgm2: give "
                            "--mass and --izz (the design depends on them; the paper's module "
                            "is not this vehicle)")
        plant = PlantParams(args.mass if args.mass is not None else g["mass"],
                            args.izz if args.izz is not None else g["izz"], cx=g["cx"], cy=g["cy"])
        args.mass, args.izz = plant.mass_kg, plant.izz_kgm2
    settings = DesignSettings(args.duration, args.cmd_rate, args.pose_rate, args.noise_pos,
                              math.radians(args.noise_yaw_deg), plant,
                              tuple(args.table_size), args.margin, args.max_yaw_rate, structure)
    if args.design_for == "thrust-calibration":
        from tpods.cli.calibrate import design_calibration

        return design_calibration(args, table, settings, out_folder)
    compared = []
    for spec in args.compare:
        cmd_t, duty = make_input(spec, args.duration, args.cmd_rate)
        try:
            compared.append(evaluate_commands(cmd_t, duty, table, settings, spec))
        except UserError as exc:
            raise UserError(f"{spec}: {exc}") from None
    total = 1 + args.candidates + args.refine * args.refine_evals
    with tqdm(total=total, desc="design", unit="eval", file=sys.stderr, leave=False,
              disable=None) as bar:
        res = search(table, settings, n_random=args.candidates, n_refine=args.refine,
                     refine_evals=args.refine_evals, omega_range=tuple(args.omega_range),
                     seed=args.seed, progress=bar.update)
    with out_folder.writing() as d:
        out = _write_design(args, res, compared, d, out_folder.path)
    return _print_design(args, res, compared, out, out_folder.path)


def _write_design(args: argparse.Namespace, res, compared, d: Path, final: Path) -> dict:
    """Write the design into ``d`` (the temporary folder that becomes ``final``)."""
    import numpy as np

    from estimator.reports.plots.batch import plot_sensitivities

    best = res.best
    n_ch = best.duty_pct.shape[1]
    np.savetxt(d / "commands.csv", np.column_stack([best.cmd_t, best.duty_pct]), delimiter=",",
               header="t," + ",".join(f"d{i + 1}" for i in range(n_ch)), comments="", fmt="%.10g")
    if getattr(args, "structure", None):
        import shutil

        shutil.copyfile(args.structure, d / "structure.toml")

    def row(e):
        return {"label": e.label, "logdet_info": e.logdet, "feasible": e.feasible,
                "max_yaw_rate_rad_s": float(np.abs(e.crlb.states[:, 5]).max()),
                "excursion_x_m": e.excursion_m[0], "excursion_y_m": e.excursion_m[1],
                "crlb_mass_sigma_kg": e.crlb.mass_sigma_kg,
                "crlb_izz_sigma_kgm2": e.crlb.izz_sigma_kgm2,
                **({"crlb_com_x_sigma_m": e.crlb.sigma_of("cx"),
                    "crlb_com_y_sigma_m": e.crlb.sigma_of("cy")} if "cx" in e.crlb.names else {}),
                **({"amplitude_pct": e.spec.amplitude_pct, "omega_rad_s": e.spec.omega_rad_s,
                    "phases_rad": list(e.spec.phases_rad), "mean_pct": e.spec.mean_pct}
                   if e.spec else {})}

    out = {"best": row(best), "paper": row(res.paper), "compared": [row(e) for e in compared],
           "evaluated": res.evaluated, "improvement_logdet": best.logdet - res.paper.logdet,
           "settings": {"duration_s": args.duration, "cmd_rate_hz": args.cmd_rate,
                        "pose_rate_hz": args.pose_rate, "table_size_m": list(args.table_size),
                        "margin_m": args.margin, "max_yaw_rate_rad_s": args.max_yaw_rate,
                        "mass_kg": args.mass, "izz_kgm2": args.izz},
           "criterion_parameters": list(best.crlb.names),
           "commands_csv": str(final / "commands.csv")}
    (d / "design.json").write_text(json.dumps(out, indent=2) + "\n")
    for e, name in ((best, "sensitivities_best.png"), (res.paper, "sensitivities_paper.png")):
        t = np.arange(len(e.crlb.sens_x)) / args.pose_rate
        plot_sensitivities(t, e.crlb.sens_x[:, :, :2], e.crlb.names[:2], [args.mass, args.izz],
                           d / name, title=e.label)
    return out


def _print_design(args: argparse.Namespace, res, compared, out: dict, final: Path) -> int:
    """Print the design (one JSON object with --json), the best beside the paper's input."""
    import numpy as np

    best = res.best
    if args.json:
        print_json(out)
        return 0
    half = np.asarray(args.table_size) / 2 - args.margin
    print(f"D-optimal design over {args.duration:g} s ({res.evaluated} sequences scored; "
          f"workspace |x|,|y| <= {half[0]:g}, {half[1]:g} m from the start)")
    print(f"  {'input':<44} {'log det':>9} {'sd(m) kg':>10} {'sd(Izz)':>10} {'excursion x,y m':>17}  fits")
    for e in [res.paper, *compared, best]:
        lab = e.label if len(e.label) <= 44 else e.label[:41] + "..."
        print(f"  {lab:<44} {e.logdet:9.3f} {e.crlb.mass_sigma_kg:10.3g} "
              f"{e.crlb.izz_sigma_kgm2:10.3g} {e.excursion_m[0]:8.2f},{e.excursion_m[1]:7.2f}  "
              f"{'yes' if e.feasible else 'NO'}")
    print(f"  best: {best.spec.describe()}")
    print(f"  log det gain over the paper's input: {best.logdet - res.paper.logdet:+.3f}")
    print(f"  wrote {final / 'commands.csv'} (play it or simulate it with tpods sim --input), design.json")
    return 0

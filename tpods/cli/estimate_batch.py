"""CLI of the batch least-squares estimator, the CRLB and the Table 3 report.

``register`` adds ``tpods estimate batch`` (every method; the filter options from
:mod:`tpods.cli.estimate_ekf`, the segment fit :mod:`tpods.cli.estimate_segments`),
``tpods estimate crlb`` and ``tpods report table3`` (``tpods design``:
:mod:`tpods.cli.design`). Handlers parse, call the use case
(:func:`estimator.reports.batch_report.estimate_batch`,
:func:`estimator.reports.bound_report.crlb_report`,
:func:`estimator.reports.table3.write_table3`) and print or write what it returns.
"""

from __future__ import annotations

import argparse
import math

from common.argtypes import (
    INITIAL_KEYS,
    IZZ_KGM2,
    MASS_KG,
    at_values,
    key_values,
    nearest,
    positive_float,
)
from common.outputs import ResultFolder, not_an_input, result_output
from tpods.cli import estimate_ekf as cli_ekf
from tpods.cli import estimate_realism as cli_realism
from tpods.cli import estimate_segments as cli_segments
from tpods.cli.estimate_output import report, warn
from tpods.cli.options import (
    add_json_flag,
    add_noise_seed,
    add_noise_sigmas,
    add_report_out,
    add_result_out,
    add_sim_duration,
    add_structure_or_vehicle,
    add_thrust_table,
)
from tpods.cli.parser import command


def name_list(text: str) -> tuple[str, ...]:
    from estimator.batch.input_params import INPUT_NAMES
    from estimator.plant.model import PARAM_NAMES

    names = tuple(INITIAL_KEYS.get(n.strip().lower(), n.strip()) for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in PARAM_NAMES]
    if bad or not names or len(set(names)) != len(names):
        every = (*PARAM_NAMES, *INPUT_NAMES, "drop.<supply>")
        hint = nearest(bad[0], (*PARAM_NAMES, *INPUT_NAMES)) if bad else ""
        raise argparse.ArgumentTypeError(f"expected distinct names from {', '.join(every)}, got "
                                         f"{text!r}{hint}")
    return names


def batch_name_list(text: str) -> tuple[str, ...]:
    """:func:`name_list` plus a vehicle's input parameters delay, drop, drop.<supply>."""
    from estimator.batch.input_params import split_names

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    plant, inputs = split_names(names)
    if len(set(inputs)) != len(inputs):
        raise argparse.ArgumentTypeError(f"names repeat in {text!r}")
    return (name_list(",".join(plant)) if plant else ()) + inputs


def register(sub, est, rep) -> None:
    """Add this module's commands: ``sub`` top level, ``est`` under estimate, ``rep`` under report."""
    p = command(
        est, "batch", cmd_batch,
        help="estimate mass and Izz from a run (batch least squares, EKF, LS+EKF)")
    p.add_argument("run_dir", metavar="RUN_DIR", help="run folder (commands.csv, poses.csv)")
    p.add_argument("--method", choices=("ls", "ekf", "ls-ekf"), default="ls",
                   help="estimator (default ls)")
    _common_model_options(p)
    p.add_argument("--window", default=None, metavar="T0:T1",
                   help="use only poses with T0 <= t <= T1 (seconds; either side may be empty)")
    p.add_argument("--initial", type=key_values, default={}, metavar="m=1,izz=0.005",
                   help="initial guess (any of m, izz, ct, cr, kb, ax, ay, cx, cy, x, y, psi, u, v, r)")
    p.add_argument("--estimate", type=batch_name_list, default=None, metavar="NAMES",
                   help="parameters to estimate, comma-separated (default mass,izz; a structure "
                        "run: mass,izz,cx,cy less the --fixed ones); a vehicle of on/off valves "
                        "also delay (valve dead time, s) and drop (shared-supply drop per other "
                        "open valve; drop.<supply> for one supply's own)")
    add_structure_or_vehicle(p, "structure.toml: read RUN_DIR as a structure run (default: its own "
                        "structure.toml, if any); estimates the centre of mass cx, cy too")
    p.add_argument("--fixed", type=key_values, default={}, metavar="NAME=VALUE,...",
                   help="values of parameters that are not estimated (arm, ct, cr, kb, ax, ay, "
                        "cx, cy, or mass/izz when not estimated)")
    p.add_argument("--tol", type=positive_float, default=1e-8,
                   help="largest scaled correction at convergence (default 1e-8)")
    p.add_argument("--max-iter", type=int, default=50, help="iteration cap per stage (default 50)")
    p.add_argument("--delay-scan", action="store_true",
                   help="--method ls: test for a valve dead time: re-fit with the commands "
                        "shifted by 0..--delay-max-ms, profile likelihood, best delay with its "
                        "95 %% interval and the likelihood-ratio test against none")
    p.add_argument("--delay-max-ms", type=positive_float, default=100.0, metavar="MS",
                   help="largest delay of --delay-scan, ms (default 100; 11 steps)")
    add_json_flag(p)
    add_result_out(p, "estimate.json, residuals.csv and residuals.png (Fig. 5)", "estimate")
    cli_ekf.add_batch_options(p)
    cli_realism.add_model_option(p)  # --model ideal|friction|friction+tilt|auto
    cli_segments.add_options(p)

    c = command(
        est, "crlb", cmd_crlb,
        help="Cramér-Rao bound on mass and Izz for a recorded or planned command sequence")
    c.add_argument("run_dir", metavar="RUN_DIR", help="run folder, or commands-only folder/CSV")
    _common_model_options(c)
    c.add_argument("--mass", type=MASS_KG, default=None, help="assumed mass, kg")
    c.add_argument("--izz", type=IZZ_KGM2, default=None, help="assumed Izz, kg m^2")
    c.add_argument("--pose-rate", type=positive_float, default=120.0,
                   help="pose rate for a planned sequence, Hz (default 120)")
    c.add_argument("--window", default=None, metavar="T0:T1", help="restrict to poses in T0..T1")
    add_structure_or_vehicle(c, "structure.toml: a structure's sequence (4N duty columns); bounds "
                        "mass, izz, cx, cy (default: the run folder's own structure.toml)")
    c.add_argument("--estimate", type=batch_name_list, default=None, metavar="NAMES",
                   help="a structure: the parameters to bound (default mass,izz,cx,cy less "
                        "the [body] values known without a sigma); a vehicle run of on/off "
                        "valves also delay and drop: the joint bound of estimate batch's fit")
    c.add_argument("--at", type=at_values, default={}, metavar="NAME=VALUE,...",
                   help="with delay/drop in --estimate: the point of the bound (any of mass, "
                        "izz, cx, cy in kg, kg m^2, m; delay in s; drop per other open valve); "
                        "default the run's truth, else the vehicle's values")
    add_json_flag(c)
    add_result_out(c, "crlb.json and sensitivities.png (Fig. 6)", "bounds")
    cli_realism.add_model_option(c, auto=False)

    r = command(
        rep, "table3", cmd_table3,
        help="reproduce the paper's Table 3 (orbit follower vs phase-shifted sine)")
    add_report_out(r)
    add_sim_duration(r)
    add_noise_seed(r)
    add_thrust_table(r)


def _common_model_options(p) -> None:
    add_thrust_table(p)
    p.add_argument("--clamp", action="store_true",
                   help="clamp duties into the table's valid range instead of refusing")
    add_noise_sigmas(p)


def cmd_batch(args: argparse.Namespace) -> int:
    """Estimate the initial state, mass and Izz of a run folder. --method ls is the paper's
    Algorithm 1 (batch nonlinear least squares); ekf and ls-ekf run the filters. Default initial
    guess: m = 1 kg, Izz = 0.005 kg m^2, pose from the first measurement, velocities zero;
    default prior diffuse."""
    from estimator.reports.batch_report import check_delay_scan, estimate_batch

    check_delay_scan(args.delay_scan, args.estimate, args.method)
    args.out_folder = result_output(args.out, "estimate.json", force=args.force,
                                    command="tpods estimate batch")
    not_an_input(args.out_folder, args.run_dir, args.thrust_table)
    if cli_segments.wanted(args):
        return cli_segments.cmd_segments(args)
    rep = estimate_batch(
        args.run_dir, args.thrust_table, delay_scan=args.delay_scan, delay_max_ms=args.delay_max_ms,
        log=cli_realism.selection_log(args), warn=warn, method=args.method, model=args.model,
        window=args.window, clamp=args.clamp, estimate=args.estimate, fixed=args.fixed,
        initial=args.initial, sigma_pos_m=args.sigma_pos,
        sigma_yaw_rad=math.radians(args.sigma_yaw_deg), tol=args.tol, max_iter=args.max_iter,
        select_alpha=args.select_alpha, filter_options=cli_ekf.filter_options(args),
        structure=args.structure)
    return report(args.out_folder, rep, args.json)


def cmd_crlb(args: argparse.Namespace) -> int:
    """Fisher information and Cramér-Rao bound of mass and Izz, the initial state marginalised
    (Schur complement). RUN_DIR is a run folder, or a folder or commands.csv holding only
    commands (poses are then planned at --pose-rate). The plant is the run's truth when run.json
    has one, else --mass/--izz (default the paper's 2.268 kg, 3.78e-3 kg m^2)."""
    from estimator.reports.bound_report import crlb_report

    out_folder = result_output(args.out, "crlb.json", force=args.force, command="tpods estimate crlb")
    not_an_input(out_folder, args.run_dir, args.thrust_table)
    rep = crlb_report(args.run_dir, args.thrust_table, clamp=args.clamp,
                      pose_rate_hz=args.pose_rate, structure=args.structure, window=args.window,
                      mass_kg=args.mass, izz_kgm2=args.izz, model=args.model,
                      sigma_pos_m=args.sigma_pos, sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
                      estimate=args.estimate, at=args.at,
                      keep_sensitivities=out_folder is not None and out_folder.is_folder)
    for w in rep.warnings:
        warn(w)
    return report(out_folder, rep, args.json)


def cmd_table3(args: argparse.Namespace) -> int:
    """Simulate both input cases of the paper's Table 3, estimate mass and Izz by batch least
    squares from m = 1, Izz = 0.005, compute the CRLB of each case and write report.md,
    table3.json and figures (Fig. 5 residuals, Fig. 6 sensitivities) beside the paper's numbers."""

    from common.thrust_table import load_thrust_table
    from estimator.reports.table3 import write_table3

    out_folder = ResultFolder(args.out, force=args.force, command="tpods report table3")
    table = load_thrust_table(args.thrust_table)
    with out_folder.writing() as d:
        path = out_folder.final(write_table3(d, duration_s=args.duration, seed=args.seed, table=table,
                                             table_name=args.thrust_table or "built-in Table 2",
                                             log=print))
    print(f"wrote {path}")
    return 0

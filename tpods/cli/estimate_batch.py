"""CLI of the batch least-squares estimator, the CRLB and the Table 3 report.

``register`` adds ``tpods estimate batch`` (all methods: ``ls`` here,
``ekf``/``ls-ekf`` delegated to :mod:`tpods.cli.estimate_ekf`), ``tpods estimate crlb``
and ``tpods report table3`` (``tpods design``: :mod:`tpods.cli.design`). Handlers are thin: parse, call the use case
(:func:`estimator.estimate.estimate_run`, :func:`estimator.estimate.bound_sequence`), print
or write.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from common.argtypes import (
    IZZ_KGM2,
    MASS_KG,
    positive_float,
)
from common.errors import UserError
from common.outputs import ResultFolder, not_an_input, result_output
from tpods.cli import estimate_ekf as cli_ekf
from tpods.cli import estimate_realism as cli_realism
from tpods.cli import estimate_segments as cli_segments
from tpods.cli.estimate_output import (  # noqa: F401 - budget_lines, filter_budget: re-exported
    budget_lines,
    centre_of_mass_lines,
    filter_budget,
    structure_body_lines,
    write_json,
)
from tpods.cli.estimate_output import print_json as _print_json
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

_INITIAL_KEYS = {"m": "mass", "mass": "mass", "izz": "izz", "ct": "ct", "cr": "cr", "kb": "kb",
                 "ax": "ax", "ay": "ay", "x": "x", "y": "y", "psi": "psi", "u": "u", "v": "v",
                 "r": "r", "arm": "arm", "cx": "cx", "cy": "cy"}


SEGMENTS_HINT_S = 30.0
"""A single-shooting fit longer than this that does not converge points to --segments."""

_AT_KEYS = {"m": "mass", "mass": "mass", "izz": "izz", "cx": "cx", "cy": "cy", "delay": "delay",
            "drop": "drop"}


def key_values(text: str, keys: dict[str, str] | None = None) -> dict[str, float]:
    """``"m=1,izz=0.005"`` -> {"mass": 1.0, "izz": 0.005} (argparse type); ``keys`` the
    accepted names and what each means (default the initial-guess names)."""
    keys = _INITIAL_KEYS if keys is None else keys
    out: dict[str, float] = {}
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE items, got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        if k.lower() not in keys:
            raise argparse.ArgumentTypeError(f"unknown name {k!r}{_nearest(k, keys)}; use "
                                             f"{', '.join(sorted(set(keys)))}")
        try:
            val = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {v!r} (for {k})") from None
        if not math.isfinite(val):
            raise argparse.ArgumentTypeError(f"{k} must be finite")
        _check_range(keys[k.lower()], val)
        out[keys[k.lower()]] = val
    return out


def _check_range(name: str, val: float) -> None:
    """The ranges vehicle.toml enforces, for a value given on the command line
    (:mod:`common.plausible_inputs`; a drop's upper bound needs the vehicle: checked where
    it is known)."""
    from common.plausible_inputs import check_positive, check_time_s

    try:
        if name in ("mass", "izz"):
            check_positive(val, name)
        elif name == "delay":
            check_time_s(val, name)
        elif name == "drop" and val < 0:
            raise UserError(f"drop must be >= 0, got {val:g}")
    except UserError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def at_values(text: str) -> dict[str, float]:
    """``--at mass=23,delay=0.03``: the point of a vehicle's joint bound (argparse type)."""
    return key_values(text, _AT_KEYS)


def _nearest(name: str, choices) -> str:
    """`` (did you mean X?)`` for the closest of ``choices``, or ''."""
    import difflib

    close = difflib.get_close_matches(name.lower(), [c.lower() for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def name_list(text: str) -> tuple[str, ...]:
    from estimator.batch.input_params import INPUT_NAMES
    from estimator.plant.model import PARAM_NAMES

    names = tuple(_INITIAL_KEYS.get(n.strip().lower(), n.strip()) for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in PARAM_NAMES]
    if bad or not names or len(set(names)) != len(names):
        every = (*PARAM_NAMES, *INPUT_NAMES, "drop.<supply>")
        hint = _nearest(bad[0], (*PARAM_NAMES, *INPUT_NAMES)) if bad else ""
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

    from estimator.estimate import estimate_run

    if args.delay_scan and args.estimate and "delay" in args.estimate:
        raise UserError("--delay-scan profiles a dead time the fit holds fixed; --estimate with "
                        "delay estimates it with the body: give one of them")
    if args.delay_scan and args.method != "ls":
        raise UserError(f"--delay-scan re-fits the batch least squares: it needs --method ls, "
                        f"not {args.method}")
    args.out_folder = result_output(args.out, "estimate.json", force=args.force,
                                    command="tpods estimate batch")
    not_an_input(args.out_folder, args.run_dir, args.thrust_table)
    if cli_segments.wanted(args):
        return cli_segments.cmd_segments(args)
    # the run folder and the table are read by estimate_run once the options are checked
    est = estimate_run(
        args.run_dir, args.thrust_table, method=args.method, model=args.model, window=args.window,
        clamp=args.clamp, estimate=args.estimate, fixed=args.fixed, initial=args.initial,
        sigma_pos_m=args.sigma_pos, sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
        tol=args.tol, max_iter=args.max_iter, select_alpha=args.select_alpha,
        filter_options=cli_ekf.filter_options(args), log=cli_realism.selection_log(args),
        structure=args.structure)
    body_lines = _warn_implausible_body(est, args)
    if est.ext is not None:
        rc = cli_realism.report_ext(est, args)
        if not args.json:
            for line in structure_body_lines(est.to_dict()):
                print(line)
        return rc
    if est.filter is not None:
        return cli_ekf.report_filter(est, args)
    res = est.batch
    run = est.run
    out = est.to_dict()
    if body_lines:
        out["warnings"] = [*out.get("warnings", []), *body_lines]
    scan = _delay_scan(est, args, out) if args.delay_scan else None
    if args.out_folder is not None:
        from estimator.reports.plots.batch import plot_poses_fit, plot_residuals

        with args.out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            write_json(main, out)
            if d is not None:
                np.savetxt(d / "residuals.csv", np.column_stack([res.t, res.residuals]), delimiter=",",
                           header="t,res_x_m,res_y_m,res_psi_rad", comments="", fmt="%.10g")
                plot_residuals(res.t, res.residuals, d / "residuals.png", sigma_pos_m=args.sigma_pos,
                               sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
                               title=f"Batch LS residuals: {run.path.name}")
                rows = np.searchsorted(run.pose_t, res.t)
                plot_poses_fit(res.t, run.pose[rows], res.residuals, d / "poses_fit.png",
                               title=f"Batch LS: measured poses and the fitted model, "
                                     f"{run.path.name}")
    if not res.converged:
        hint = ("; a run this long cannot be integrated from one initial state unless the model "
                "is exact: fit it by segments (--segments auto)"
                if res.t[-1] - res.t[0] > SEGMENTS_HINT_S else "")
        print(f"tpods: warning: {res.message}; the estimate below is not a converged solution"
              f"{hint}", file=sys.stderr)
    if args.json:
        _print_json(out)
        return 0
    print(f"batch least squares on {run.path} ({len(res.t)} poses, "
          f"t = {res.t[0]:.3f}..{res.t[-1]:.3f} s)")
    print(f"  {res.message}; {res.iterations} iterations, horizons "
          f"{', '.join(f'{h:.1f}' for h in res.stages)} s, {res.elapsed_s:.2f} s")
    what = "1 sigma, total" if res.cov_thrust is not None else "1 sigma, noise only"
    print(f"  mass  = {res.mass_kg:.6g} kg      +/- {res.mass_sigma_kg:.3g} ({what})")
    print(f"  Izz   = {res.izz_kgm2:.6g} kg m^2  +/- {res.izz_sigma_kgm2:.3g} ({what})")
    for line in budget_lines(res.budget()):
        print(line)
    if not math.isnan(res.corr_mass_izz):
        print(f"  corr(mass, Izz) = {res.corr_mass_izz:+.3f}")
    for n in res.names:
        if n not in ("mass", "izz"):
            i = 6 + res.names.index(n)
            print(f"  {n:<5} = {res.z0[i]:.6g} +/- {res.sigma[i]:.3g}")
    for line in centre_of_mass_lines(out) + structure_body_lines(out):
        print(line)
    rms = res.rms_residuals()
    print(f"  rms residuals: x {rms[0] * 100:.3f} cm, y {rms[1] * 100:.3f} cm, "
          f"yaw {math.degrees(rms[2]):.3f} deg")
    if "truth_mass_kg" in out:
        print(f"  truth: mass {out['truth_mass_kg']:.6g} kg (error {out['mass_rel_error'] * 100:+.3f} %), "
              f"Izz {out['truth_izz_kgm2']:.6g} (error {out['izz_rel_error'] * 100:+.3f} %)")
    if "crlb_mass_sigma_kg" in out:
        print(f"  CRLB at truth: mass {out['crlb_mass_sigma_kg']:.3g} kg, "
              f"Izz {out['crlb_izz_sigma_kgm2']:.3g} kg m^2")
    if scan is not None:
        print(f"  delay scan: {scan.describe()}")
    if args.out_folder is not None:
        print(f"  wrote {args.out_folder.main}"
              + (", residuals.csv, residuals.png, poses_fit.png" if args.out_folder.is_folder else ""))
    return 0


def _delay_scan(est, args: argparse.Namespace, out: dict):
    """``--delay-scan``: the profile likelihood of a valve dead time on the fitted run,
    into ``out["delay_scan"]`` (and a warning when one is found)."""
    from common.thrust_table import load_thrust_table
    from estimator.batch.delay_scan import delay_warning, run_delay_scan

    grid = np.linspace(0.0, args.delay_max_ms * 1e-3, 11)
    scan = run_delay_scan(est.run, load_thrust_table(args.thrust_table), est.batch,
                          clamp=args.clamp, sigma_pos_m=args.sigma_pos,
                          sigma_yaw_rad=math.radians(args.sigma_yaw_deg), delays_s=grid)
    out["delay_scan"] = scan.to_dict()
    w = delay_warning(scan)
    if w:
        print(f"tpods: warning: {w}", file=sys.stderr)
        out["warnings"] = [*out.get("warnings", []), w]
    return scan


def _warn_implausible_body(est, args: argparse.Namespace) -> list[str]:
    """One stderr line (and, for ls, an entry in the JSON's warnings) when the estimated
    mass or Izz is implausible for an air-table body, naming the thrust table's unit."""
    from common.thrust_table import load_thrust_table
    from estimator.batch.least_squares import body_warnings

    fit = est.batch if est.batch is not None else (est.filter.result if est.filter is not None
                                                   else est.ext)
    if fit is None or (est.batch is not None and not est.batch.converged and
                       "no information" in est.batch.message):
        return []  # an uninformative fit is reported as such
    v = est.run.structure
    if est.run.thrust_n is not None:
        source, unit = f"{est.run.path / 'thrusts.csv'} (in N)", None
    elif getattr(v, "kind", None) == "vehicle" and not v.tables():
        source, unit = f"{v.source}: its valves' force_n (in N)", None
    elif args.thrust_table:
        source, unit = args.thrust_table, load_thrust_table(args.thrust_table).unit
    else:
        source, unit = "the built-in Table 2", "gf"
    lines = body_warnings(fit.mass_kg, fit.izz_kgm2, source, unit)
    for w in lines:
        print(f"tpods: warning: {w}", file=sys.stderr)
    return lines


def cmd_crlb(args: argparse.Namespace) -> int:
    """Fisher information and Cramér-Rao bound of mass and Izz, the initial state marginalised
    (Schur complement). RUN_DIR is a run folder, or a folder or commands.csv holding only
    commands (poses are then planned at --pose-rate). The plant is the run's truth when run.json
    has one, else --mass/--izz (default the paper's 2.268 kg, 3.78e-3 kg m^2)."""

    from common.thrust_table import load_thrust_table
    from estimator.estimate import bound_sequence, load_sequence

    out_folder = result_output(args.out, "crlb.json", force=args.force, command="tpods estimate crlb")
    not_an_input(out_folder, args.run_dir, args.thrust_table)
    if args.estimate and any(n in ("delay", "drop") or n.startswith("drop.") for n in args.estimate):
        from tpods.cli.estimate_crlb_inputs import cmd_crlb_inputs

        return cmd_crlb_inputs(args, out_folder)  # the joint bound with the valves
    if args.at:
        raise UserError("--at sets the point of a vehicle's joint bound: name delay or drop "
                        "in --estimate (else --mass and --izz)")
    table = load_thrust_table(args.thrust_table)
    _check_crlb_size(args)  # planned poses: before they are allocated
    seq = load_sequence(args.run_dir, table, args.clamp, args.pose_rate, structure=args.structure)
    if seq.structure is not None and args.thrust_table:
        seq.structure.check_table_option()
    _check_crlb_size(args, seq)
    b = bound_sequence(seq, path=args.run_dir, window=args.window, mass_kg=args.mass,
                       izz_kgm2=args.izz, model=args.model, sigma_pos_m=args.sigma_pos,
                       sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
                       keep_sensitivities=out_folder is not None and out_folder.is_folder,
                       estimate=args.estimate)
    c, pose_t, mass, izz, kind, source = b.crlb, b.pose_t, b.mass_kg, b.izz_kgm2, b.kind, b.plant_source
    out = b.to_dict()
    if out_folder is not None:
        from estimator.reports.plots.batch import plot_sensitivities

        with out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            main.write_text(json.dumps(out, indent=2) + "\n")
            if d is not None:
                plot_sensitivities(pose_t, c.sens_x[:, :, :2], c.names[:2],
                                   [{"mass": mass, "izz": izz}.get(n, 1.0) for n in c.names[:2]],
                                   d / "sensitivities.png",
                                   title=f"Sensitivities of {Path(args.run_dir).name}")
    if args.json:
        _print_json(out)
        return 0
    print(f"Cramér-Rao bound of {args.run_dir} ({kind}, {c.n_poses} poses over "
          f"{out['duration_s']:.1f} s; plant from {source}: m = {mass:g} kg, Izz = {izz:g} kg m^2)")
    if "mass" in c.names:
        print(f"  mass  sigma >= {c.mass_sigma_kg:.4g} kg      ({out['crlb_mass_rel'] * 100:.4f} %)")
    if "izz" in c.names:
        print(f"  Izz   sigma >= {c.izz_sigma_kgm2:.4g} kg m^2  ({out['crlb_izz_rel'] * 100:.4f} %)")
    corr = out["crlb_corr_mass_izz"]
    print((f"  correlation {corr:+.3f}, " if corr is not None else "  ")
          + f"log det(information) {c.logdet:.3f}")
    for line in structure_body_lines(out):
        print(line)
    if out["thrust_uncertainty"]["included"] and {"mass", "izz"} <= set(c.names):
        print(f"  with the thrust table's uncertainty: mass sigma {out['mass_sigma_total_kg']:.4g} kg "
              f"(thrust part {out['mass_sigma_thrust_kg']:.4g}), Izz sigma "
              f"{out['izz_sigma_total_kgm2']:.4g} kg m^2 (thrust part {out['izz_sigma_thrust_kgm2']:.4g})")
    elif not out["thrust_uncertainty"]["included"]:
        print(f"tpods: warning: {out['thrust_uncertainty']['note']}", file=sys.stderr)
    if c.names[:2] == ("mass", "izz"):
        for line in cli_realism.crlb_lines(c):  # the extended model's other bounds
            print(line)
    else:  # a structure with a known mass or Izz: the others
        from estimator.plant.parameter_sets import PARAM_UNITS

        for n, sg in zip(c.names, c.sigma, strict=True):
            if n not in ("mass", "izz"):
                print(f"  {n:<5} sigma >= {sg:.4g} {PARAM_UNITS[n]}")
    if out_folder is not None:
        print(f"  wrote {out_folder.main}" + (" and sensitivities.png" if out_folder.is_folder else ""))
    return 0


def _check_crlb_size(args: argparse.Namespace, seq=None) -> None:
    """Refuse a bound that will not fit in memory, naming --pose-rate (planned poses) or the
    run's size, and announce a long one. Without ``seq``: a planned sequence's poses from
    its commands' span and --pose-rate, before they are allocated."""
    import tpods.cli.sizes as sizes
    from estimator.plant.inputs import from_commands_csv
    from estimator.plant.parameter_sets import DEFAULT_MODEL, MODELS

    n_params = len(MODELS[args.model or DEFAULT_MODEL])
    if seq is None:
        p = Path(args.run_dir)
        if p.is_dir() and (p / "poses.csv").exists():
            return  # a recorded run: its poses are read, checked below
        csv = p / "commands.csv" if p.is_dir() else p
        if not csv.is_file():
            return  # load_sequence names what is missing
        cmd_t, _ = from_commands_csv(csv)
        span, n_cmds = float(cmd_t[-1] - cmd_t[0]), len(cmd_t)
        n_poses = sizes.samples(span, args.pose_rate)
        what = (f"--pose-rate {sizes.number(args.pose_rate)} Hz over the {sizes.number(span)} s of "
                f"{csv} is {sizes.samples_text(span, args.pose_rate)} planned poses")
        fix = "lower --pose-rate"
    else:
        span = float(seq.pose_t[-1] - seq.pose_t[0]) if len(seq.pose_t) else 0.0
        n_cmds, n_poses = len(seq.cmd_t), float(len(seq.pose_t))
        what = f"{args.run_dir} holds {n_poses:.0f} poses over {sizes.number(span)} s"
        fix = "restrict it with --window"
    segments = sizes.crlb_segments(n_poses, n_cmds, span)
    n_bytes, seconds = sizes.crlb_cost(segments, n_params)
    sizes.refuse_if_too_big(what, n_bytes, fix)
    if seq is not None:
        sizes.announce(seconds, f"the bound over {n_poses:.0f} poses")


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

"""CLI of the EKF, LS-initialised EKF and Monte Carlo.

``register`` adds ``tpods estimate montecarlo`` (the use case
:func:`estimator.reports.montecarlo_report.montecarlo_study`), ``tpods report ekf`` and
``tpods report sweep``; ``add_batch_options(parser)`` adds the filter options to
``tpods estimate batch`` and ``estimate live``, ``filter_options(args)`` reads them back.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from common.argtypes import fraction, int_at_least, nonneg_float, positive_float
from common.errors import UserError
from common.outputs import ResultFolder, result_output
from tpods.cli.estimate_output import report
from tpods.cli.options import (
    add_cmd_rate,
    add_input_choice,
    add_json_flag,
    add_pose_rate,
    add_random_seed,
    add_report_out,
    add_result_out,
    add_sim_duration,
    add_structure_or_vehicle,
)
from tpods.cli.parser import command


def _state_values(what: str):
    def parse(text: str) -> dict[int, float]:
        from estimator.filters.ekf import parse_state_values

        try:
            vals = parse_state_values(text, what)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if any(v < 0 for v in vals.values()):
            raise argparse.ArgumentTypeError(f"{what} values must be non-negative")
        return vals

    return parse


def _filter_options(p, preset_default: str) -> None:
    from estimator.filters.ekf import PRESETS

    g = p.add_argument_group("filter (ekf, ls-ekf)")
    g.add_argument("--preset", choices=sorted(PRESETS), default=preset_default,
                   help=f"filter setting (default {preset_default}; paper: 1e-4 kg^2/Hz on mass, "
                        "initial std 0.1 m, 0.1 m, 5 deg, 0.1 m/s, 0.1 m/s, 2 deg/s, 1 kg, "
                        "2e-3 kg m^2)")
    g.add_argument("--process-noise", type=_state_values("Q"), default={}, metavar="NAME=Q,...",
                   help="process-noise spectral density per state, SI units^2/s "
                        "(e.g. mass=1e-4,izz=1e-10); overrides the preset")
    g.add_argument("--sigma0", type=_state_values("sigma"), default={}, metavar="NAME=S,...",
                   help="initial standard deviations, SI units (psi, r in rad, rad/s)")
    g.add_argument("--underweight", type=nonneg_float, default=0.0, metavar="ALPHA",
                   help="underweighting alpha: S = (1+alpha) HPH^T + R while triggered "
                        "(default 0: off)")
    g.add_argument("--uw-trigger", type=positive_float, default=1.0, metavar="K",
                   help="underweight while the largest eigenvalue of R^-1/2 HPH^T R^-1/2 exceeds "
                        "K (default 1: predicted pose uncertainty dominates R)")
    g.add_argument("--ls-window", type=positive_float, default=20.0, metavar="SECONDS",
                   help="ls-ekf: batch LS on the first SECONDS of the run (default 20)")
    g.add_argument("--ls-start", choices=("reuse", "handoff"), default="reuse",
                   help="ls-ekf: reuse = filter the whole run from the LS start (the paper; "
                        "uses the window's poses twice); handoff = propagate the LS fit to "
                        "the end of the window and filter only the later poses")


def filter_options(args):
    """The filter options of a parsed command line (see :func:`_filter_options`)."""
    from estimator.estimate import FilterOptions

    return FilterOptions(preset=args.preset, process_noise=args.process_noise, sigma0=args.sigma0,
                         underweight=args.underweight, uw_trigger=args.uw_trigger,
                         ls_window_s=args.ls_window, ls_start=args.ls_start)


def _filter_config(args, base=None, sigma_pos: float | None = None,
                   sigma_yaw_rad: float | None = None, fixed: dict | None = None):
    from estimator.estimate import filter_config

    return filter_config(filter_options(args), base, sigma_pos_m=sigma_pos,
                         sigma_yaw_rad=sigma_yaw_rad, fixed=fixed)


# --------------------------------------------------------------------------------------
# estimate batch --method ekf|ls-ekf


def add_batch_options(parser) -> None:
    """Add the filter options (``--ls-window``, ``--underweight``, ...) to ``estimate batch``."""
    _filter_options(parser, "paper")


# --------------------------------------------------------------------------------------
# estimate montecarlo, report ekf


def register(sub, est, rep) -> None:
    """Add this module's commands: ``sub`` top level, ``est`` under estimate, ``rep`` under report."""
    p = command(
        est, "montecarlo", cmd_montecarlo, help="Monte Carlo consistency of the EKF (Figs. 9, 10)")
    p.add_argument("--runs", type=int_at_least(2), default=500, help="number of runs (default 500)")
    p.add_argument("--spread", type=fraction, default=0.5,
                   help="relative half-width of the uniform m, Izz draw (default 0.5)")
    add_sim_duration(p)
    add_input_choice(p)
    p.add_argument("--method", choices=("ekf", "ls-ekf"), default="ekf",
                   help="filter start (default ekf)")
    add_random_seed(p)
    add_pose_rate(p)
    add_cmd_rate(p)
    p.add_argument("--drop", type=fraction, default=0.0, help="fraction of frames dropped")
    add_json_flag(p)
    add_result_out(p, "montecarlo.json, history.csv, runs.csv and the figures", "summary")
    g = p.add_argument_group(
        "structure",
        "--structure F: a Monte Carlo of batch LS on the structure: m and Izz drawn within "
        "+/- SPREAD of the structure's start (its [body] values, else the modules' layout), cx, "
        "cy within +/- COM_SPREAD of its centre of mass; each run simulated with the "
        "structure's virtual thrusts and fitted for mass, izz, cx, cy. Reports bias, sample "
        "std against the mean reported sigma, NEES (4 dof) with its 95 %% bounds and the "
        "fractions within 2 and 3 sigma; --out DIR writes montecarlo.json and runs.csv. The "
        "filter options do not apply")
    add_structure_or_vehicle(g, "structure.toml")
    g.add_argument("--com-spread", type=nonneg_float, default=0.02, metavar="M",
                   help="half-width of the uniform cx, cy draw, m (default 0.02)")
    g.add_argument("--noise-pos", type=positive_float, default=None, metavar="M",
                   help="position noise sigma, m (default 0.01; the module's filter Monte Carlo "
                        "uses 0.01)")
    g.add_argument("--noise-yaw-deg", type=positive_float, default=None, metavar="DEG",
                   help="yaw noise sigma, deg (default 1)")
    _filter_options(p, "no-process-noise")

    r = command(
        rep, "ekf", cmd_report_ekf,
        help="EKF and LS+EKF RMSE beside the paper's (120 s synthetic scenario)")
    add_report_out(r)
    add_sim_duration(r)
    r.add_argument("--seeds", type=int, default=5, help="number of noise seeds (default 5)")
    r.add_argument("--ls-window", type=positive_float, default=20.0, help="seconds (default 20)")
    add_json_flag(r)

    r = command(
        rep, "sweep", cmd_report_sweep,
        help="every estimator on many simulated runs unlike the paper's")
    add_report_out(r)
    r.add_argument("--runs", type=int_at_least(1), default=300, help="cases (default 300)")
    r.add_argument("--seed", type=int_at_least(0), default=0, help="random seed (default 0)")
    r.add_argument("--methods", default="ls,ekf,ls-ekf", help="comma-separated (default all)")
    r.add_argument("--workers", type=int_at_least(1), default=1,
                   help="processes (default 1; the cases are independent)")
    r.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def cmd_montecarlo(args: argparse.Namespace) -> int:
    """Draw m and Izz uniformly within +/- SPREAD of 2.268 kg and 3.78e-3 kg m^2, simulate each run
    with 1 cm / 1 deg pose noise and filter it; all runs are vectorised. Reports bias, sample
    std against filter sigma, average NEES with its 95 % chi-square bounds and the fraction of
    final errors inside 3 sigma. The default filter is the paper's without process noise (the
    simulated parameters are constant); the filter starts at the nominal values with the uniform
    draw's standard deviation."""
    from estimator.reports.montecarlo_report import check_montecarlo, montecarlo_study

    sizes = dict(runs=args.runs, duration_s=args.duration, pose_rate_hz=args.pose_rate,
                 cmd_rate_hz=args.cmd_rate)
    noise = dict(noise_pos_m=args.noise_pos, noise_yaw_deg=args.noise_yaw_deg)
    check_montecarlo(**sizes, structure=args.structure, method=args.method, **noise)
    out_folder = result_output(args.out, "montecarlo.json", force=args.force,
                               command="tpods estimate montecarlo")
    rep = montecarlo_study(**sizes, **noise, spread=args.spread, input=args.input,
                           method=args.method, seed=args.seed, drop=args.drop,
                           structure=args.structure, com_spread_m=args.com_spread,
                           filter_options=filter_options(args))
    if rep.interrupted:
        print(f"tpods: interrupted {rep.interrupted}; writing the statistics so far", file=sys.stderr)
    return report(out_folder, rep, args.json, 130 if rep.interrupted else 0)


def cmd_report_ekf(args: argparse.Namespace) -> int:
    """Simulate the paper's 120 s phase-sine scenario for several noise seeds, run the EKF, the
    paper's LS+EKF and the handoff variant, and write report.md, ekf_report.json and Fig.
    7/8-style plots."""

    from tqdm import tqdm

    from estimator.reports.ekf import build_report, summary_lines

    out_folder = ResultFolder(args.out, force=args.force, command="tpods report ekf")
    if args.seeds < 1:
        raise UserError("--seeds must be at least 1")
    if args.ls_window >= args.duration:
        raise UserError("--ls-window must be shorter than --duration")
    bar = tqdm(total=args.seeds, desc="seeds", unit="seed")
    try:
        with out_folder.writing() as d:
            rep = build_report(args.duration, tuple(range(args.seeds)), ls_window_s=args.ls_window,
                               out_dir=d, progress=lambda _s: bar.update(1))
    finally:
        bar.close()
    if args.json:
        slim = {k: {"summary": v["summary"], "paper": v["paper"]}
                for k, v in rep["methods"].items()}
        sys.stdout.write(json.dumps({"scenario": rep["scenario"], "methods": slim}) + "\n")
        return 0
    for line in summary_lines(rep):
        print(line)
    print(f"wrote {Path(args.out) / 'report.md'}, ekf_report.json and figures")
    return 0


def cmd_report_sweep(args: argparse.Namespace) -> int:
    """Draw RUNS cases (0.3-8 kg, Izz 5e-4-5e-2 kg m^2, 20-120 s, 0-30 %% drops, 0.5-5 mm / 0.2-2
    deg poses, phase-sine or translate-rotate), simulate each, estimate it with ls, ekf (default
    start) and ls-ekf as 'estimate batch' does (true noise given), and write report.md (the
    table) and sweep.json (every run). Target: final errors within 4 sigma in >= 99 %% of runs,
    none beyond 6 sigma without a flag."""

    from tqdm import tqdm

    from estimator.reports.sweep import run_sweep

    out_folder = ResultFolder(args.out, force=args.force)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    bar = tqdm(total=args.runs, desc="sweep", unit="run")
    try:
        res = run_sweep(args.runs, args.seed, methods, workers=args.workers,
                        progress=lambda n: bar.update(n - bar.n))
    finally:
        bar.close()
    with out_folder.writing() as d:
        (d / "report.md").write_text("# Estimator sweep\n\n" + res.markdown())
        (d / "sweep.json").write_text(json.dumps(res.to_dict(), indent=1, default=str) + "\n")
    if args.json:
        sys.stdout.write(json.dumps(res.to_dict()["summary"]) + "\n")
        return 0
    print(res.markdown(), end="")
    print(f"wrote {Path(args.out) / 'report.md'}, sweep.json")
    return 0

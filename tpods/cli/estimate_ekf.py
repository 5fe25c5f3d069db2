"""CLI of the EKF, LS-initialised EKF and Monte Carlo.

``register`` adds ``tpods estimate montecarlo`` and ``tpods report ekf``;
``add_batch_options(parser)`` adds the filter options to ``tpods estimate batch``,
``filter_options(args)`` reads them back and ``report_filter(estimate, args)`` writes and
prints the result of ``--method ekf|ls-ekf`` (computed by
:func:`estimator.estimate.estimate_run`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from common.argtypes import fraction, int_at_least, nonneg_float, positive_float
from common.errors import UserError
from common.outputs import ResultFolder, result_output
from tpods.cli.estimate_output import budget_lines, filter_budget, write_json
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


def ls_window_warning(ls_window_s: float, span_s: float, what: str = "the run") -> str | None:
    """The warning line when ``--ls-window`` covers all of ``span_s`` seconds of poses (the LS
    start then uses every pose and the filter has nothing left to add), else None."""
    if ls_window_s < span_s:
        return None
    return (f"tpods: warning: --ls-window {ls_window_s:g} s covers all of {what} ({span_s:.3g} s "
            f"of poses): the LS start uses every pose and the filter adds nothing to it; give "
            f"--ls-window below {span_s:.3g} s, or use --method ls")


def report_filter(est, args) -> int:
    """Write and print ``tpods estimate batch --method ekf|ls-ekf`` (the ideal model)."""
    from estimator.filters.ekf import STATE_NAMES

    fe, run, out, has_truth = est.filter, est.run, est.to_dict(), est.has_truth
    r = fe.result
    if fe.ls is not None and len(r.t):
        line = ls_window_warning(args.ls_window, float(r.t[-1] - r.t[0]),
                                 "the run" if args.window is None else "the --window")
        if line:
            print(line, file=sys.stderr)
    out_folder = getattr(args, "out_folder", None)
    if out_folder is not None:
        from estimator.reports.plots.ekf import plot_error_bounds

        with out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            write_json(main, out)
            cols = ["t"] + list(STATE_NAMES) + [f"sigma_{n}" for n in STATE_NAMES] + ["updated", "nis",
                                                                                       "underweighted"]
            if d is not None:
                np.savetxt(d / "history.csv", np.column_stack([r.t, r.x, r.sigma, r.updated, r.nis,
                                                               r.triggered]),
                           delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
                plot_error_bounds(r.t, r.x[:, 6:8], r.sigma[:, 6:8], d / "errors.png",
                                  (out["truth_mass_kg"], out["truth_izz_kgm2"]) if has_truth else None,
                                  title=f"{args.method}{' (' + fe.ls_start + ')' if fe.ls else ''}: "
                                        f"{run.path.name}")
    if r.diverged:
        print("tpods: warning: the filter diverged (non-physical parameters or innovations far "
              "larger than their covariance); try --method ls-ekf", file=sys.stderr)
    elif r.inconsistent:
        print(f"tpods: warning: the filter is inconsistent (mean NIS {r.nis_tail_mean:.3g} over the "
              "last 10 % of updates, 3 expected): its sigma understates the error; try --method "
              "ls-ekf", file=sys.stderr)
    if args.json:
        sys.stdout.write(json.dumps(out, default=str) + "\n")
        return 0
    label = args.method + (f" ({fe.ls_start}, LS window {fe.ls_window_s:g} s)" if fe.ls else "")
    print(f"{label} on {run.path} ({len(r.t)} poses, t = {r.t[0]:.3f}..{r.t[-1]:.3f} s)")
    if fe.ls is not None:
        print(f"  LS start: mass {fe.ls.mass_kg:.6g} +/- {fe.ls.mass_sigma_kg:.3g} kg, "
              f"Izz {fe.ls.izz_kgm2:.6g} +/- {fe.ls.izz_sigma_kgm2:.3g} kg m^2")
    print(f"  mass  = {r.mass_kg:.6g} kg      +/- {out['mass_sigma_kg']:.3g} (1 sigma)")
    print(f"  Izz   = {r.izz_kgm2:.6g} kg m^2  +/- {out['izz_sigma_kgm2']:.3g} (1 sigma)")
    for line in budget_lines(filter_budget(out)):
        print(line)
    print(f"  mean NIS {out['nis_mean']:.3g} (3 expected), "
          f"{out['underweighted_updates']} underweighted updates")
    if has_truth:
        print(f"  truth: mass {out['truth_mass_kg']:.6g} kg (error {out['mass_rel_error'] * 100:+.3f} %), "
              f"Izz {out['truth_izz_kgm2']:.6g} (error {out['izz_rel_error'] * 100:+.3f} %)")
        print(f"  RMSE over the run: mass {out['rmse_mass_kg']:.4g} kg, "
              f"Izz {out['rmse_izz_kgm2']:.4g} kg m^2")
    if out_folder is not None:
        print(f"  wrote {out_folder.main}" + (", history.csv, errors.png" if out_folder.is_folder else ""))
    return 0


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


def check_montecarlo_size(args: argparse.Namespace) -> None:
    """Refuse a Monte Carlo that will not fit in memory (the check ``sim`` and ``estimate
    crlb`` make), naming the options; from the options, before any allocation."""
    from tpods.cli import sizes

    n_poses = sizes.samples(args.duration, args.pose_rate)
    n_cmds = sizes.samples(args.duration, args.cmd_rate)
    n_bytes = sizes.montecarlo_bytes(n_poses, n_cmds, args.runs, args.structure is not None)
    sizes.refuse_if_too_big(
        f"--duration {sizes.number(args.duration)} s at --pose-rate {sizes.number(args.pose_rate)} "
        f"Hz and --cmd-rate {sizes.number(args.cmd_rate)} Hz is "
        f"{sizes.samples_text(args.duration, args.pose_rate)} poses and "
        f"{sizes.samples_text(args.duration, args.cmd_rate)} command rows per run",
        n_bytes, "lower --duration, --pose-rate or --cmd-rate")


def _run_study(run, cfg, stopped_at):
    """Run a Monte Carlo study ``run(cfg)`` with its progress bar and return it with its
    summary; after Ctrl-C, say on stderr where it stopped (``stopped_at(result)``)."""
    res = run(cfg, progress=True)
    summ = res.summary()
    if res.interrupted:
        print(f"tpods: interrupted {stopped_at(res)}; writing the statistics so far",
              file=sys.stderr)
    return res, summ


def cmd_montecarlo(args: argparse.Namespace) -> int:
    """Draw m and Izz uniformly within +/- SPREAD of 2.268 kg and 3.78e-3 kg m^2, simulate each run
    with 1 cm / 1 deg pose noise and filter it; all runs are vectorised. Reports bias, sample
    std against filter sigma, average NEES with its 95 % chi-square bounds and the fraction of
    final errors inside 3 sigma. The default filter is the paper's without process noise (the
    simulated parameters are constant); the filter starts at the nominal values with the uniform
    draw's standard deviation."""

    check_montecarlo_size(args)
    if args.structure is not None:
        return _montecarlo_structure(args)
    for opt in ("noise_pos", "noise_yaw_deg"):
        if getattr(args, opt) is not None:
            raise UserError(f"--{opt.replace('_', '-')} is for --structure runs; the module's "
                            "filter Monte Carlo simulates 1 cm / 1 deg pose noise")
    from estimator.montecarlo import MC_FILTER, McConfig, config_dict, run_montecarlo
    from estimator.reports.plots.ekf import plot_mc_averages, plot_mc_runs

    out_folder = result_output(args.out, "montecarlo.json", force=args.force,
                               command="tpods estimate montecarlo")
    base = MC_FILTER if args.preset == "no-process-noise" else None
    cfg_f = _filter_config(args, base)
    if args.method == "ls-ekf" and args.ls_window >= args.duration:
        raise UserError("--ls-window must be shorter than --duration")
    try:
        cfg = McConfig(runs=args.runs, spread=args.spread, duration_s=args.duration,
                       input=args.input, method=args.method, seed=args.seed,
                       pose_rate_hz=args.pose_rate, cmd_rate_hz=args.cmd_rate, drop=args.drop,
                       ls_window_s=args.ls_window, ls_start=args.ls_start, filter=cfg_f)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    res, summ = _run_study(run_montecarlo, cfg, lambda res: f"at t = {res.t[-1]:.2f} s")
    if out_folder is not None:
        with out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            write_json(main, {"summary": summ, "config": config_dict(cfg)})
            if d is not None:
                cols, data = res.history_table()
                np.savetxt(d / "history.csv", data, delimiter=",", header=",".join(cols), comments="",
                           fmt="%.8g")
                runs = np.column_stack([np.arange(cfg.runs), res.truth, res.final_err[:, 6:8],
                                        res.final_sigma[:, 6:8], res.rmse])
                np.savetxt(d / "runs.csv", runs, delimiter=",", comments="", fmt="%.8g",
                           header="run,mass_kg,izz_kgm2,final_err_mass_kg,final_err_izz_kgm2,"
                                  "final_sigma_mass_kg,final_sigma_izz_kgm2,rmse_mass_kg,rmse_izz_kgm2")
                tag = f"{cfg.method}{' (' + cfg.ls_start + ')' if cfg.method == 'ls-ekf' else ''}"
                plot_mc_runs(res.t, res.ex_err, res.ex_sigma, d / "mc_runs.png",
                             title=f"Monte Carlo {tag}: {res.ex_err.shape[0]} of {cfg.runs} runs")
                plot_mc_averages(res, d / "mc_averages.png",
                                 title=f"Monte Carlo {tag}, {cfg.runs} runs, spread +/-{cfg.spread:g}")
    code = 130 if res.interrupted else 0
    if args.json:
        sys.stdout.write(json.dumps(summ) + "\n")
        return code
    s = summ
    b = s["nees_param_bounds"]
    bf = s["nees_full_bounds"]
    print(f"Monte Carlo: {cfg.runs} runs x {cfg.duration_s:g} s, {cfg.input}, method {cfg.method}"
          f"{' (' + cfg.ls_start + ')' if cfg.method == 'ls-ekf' else ''}, spread +/-{cfg.spread:g}, "
          f"{res.elapsed_s:.1f} s")
    print(f"  final bias   mass {s['final_bias_mass_kg']:+.3g} kg, Izz {s['final_bias_izz_kgm2']:+.3g} kg m^2")
    print(f"  final std    mass {s['final_std_mass_kg']:.3g} (filter sigma {s['final_sigma_mass_kg']:.3g}), "
          f"Izz {s['final_std_izz_kgm2']:.3g} (filter sigma {s['final_sigma_izz_kgm2']:.3g})")
    print(f"  avg NEES m,Izz  mean {s['nees_param_mean']:.3g}, bounds [{b[0]:.3g}, {b[1]:.3g}], "
          f"inside {100 * s['nees_param_inside_frac']:.0f} % of times")
    print(f"  avg NEES state  mean {s['nees_full_mean']:.3g}, bounds [{bf[0]:.3g}, {bf[1]:.3g}], "
          f"inside {100 * s['nees_full_inside_frac']:.0f} % of times")
    print(f"  final errors inside 3 sigma: mass {100 * s['within_3sigma_mass']:.1f} %, "
          f"Izz {100 * s['within_3sigma_izz']:.1f} %; runs with final (m, Izz) NEES above the "
          f"99.9 % chi-square point: {100 * s['final_outlier_frac']:.1f} %")
    if cfg.filter.underweight > 0:
        print(f"  underweighted updates: {100 * s['underweighted_frac']:.2f} %")
    if s["ls_failed"]:
        print(f"  {s['ls_failed']} runs whose LS fit failed started from the ekf initialisation")
    if out_folder is not None:
        print(f"  wrote {out_folder.main}" + (", history.csv, runs.csv, mc_runs.png, mc_averages.png"
                                              if out_folder.is_folder else ""))
    return code


def _montecarlo_structure(args: argparse.Namespace) -> int:
    """``tpods estimate montecarlo --structure F``: batch LS on simulated structure runs
    (:mod:`estimator.montecarlo_structure`)."""
    import math

    from common.layout_files import load_layout
    from estimator.montecarlo_structure import (
        StructureMcConfig,
        run_structure_montecarlo,
        summary_lines,
    )

    if args.method != "ekf":
        raise UserError("--method: a structure's Monte Carlo fits batch LS (drop --method)")
    out_folder = result_output(args.out, "montecarlo.json", force=args.force,
                               command="tpods estimate montecarlo")
    cfg = StructureMcConfig(
        load_layout(args.structure), runs=args.runs, spread=args.spread,
        com_spread_m=args.com_spread, duration_s=args.duration, input=args.input,
        seed=args.seed, pose_rate_hz=args.pose_rate, cmd_rate_hz=args.cmd_rate, drop=args.drop,
        noise_pos_m=args.noise_pos if args.noise_pos is not None else 0.01,
        noise_yaw_rad=math.radians(args.noise_yaw_deg if args.noise_yaw_deg is not None else 1.0))
    res, summ = _run_study(run_structure_montecarlo, cfg, lambda res: f"after {res.done} runs")
    if out_folder is not None:
        with out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            write_json(main, {"summary": summ, "config": cfg.to_dict(),
                              "failed_runs": res.messages})
            if d is not None:
                cols, data = res.runs_table()
                np.savetxt(d / "runs.csv", data, delimiter=",", header=",".join(cols),
                           comments="", fmt="%.10g")
    code = 130 if res.interrupted else 0
    if args.json:
        sys.stdout.write(json.dumps(summ) + "\n")
        return code
    for line in summary_lines(res):
        print(line)
    if out_folder is not None:
        print(f"  wrote {out_folder.main}" + (", runs.csv" if out_folder.is_folder else ""))
    return code


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

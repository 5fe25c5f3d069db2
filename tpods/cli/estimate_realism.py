"""CLI hooks of the model options (issue 9): ``--model`` for ``estimate batch`` and
``estimate crlb``, the extended-state filters, and ``tpods report realism``.

The batch/CRLB commands (:mod:`tpods.cli.estimate_batch`) call
:func:`add_model_option`, :func:`before_batch`, :func:`annotate`, :func:`crlb_names` and
:func:`crlb_extra`; everything else happens here.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from estimator.plant.parameter_sets import (
    DEFAULT_MODEL,
    MODEL_CHOICES,
    MODELS,
    fixed_for,
    model_of,
    resolve_names,
)


def add_model_option(p, auto: bool = True) -> None:
    """Add ``--model`` (and for batch ``--select-alpha``) to a parser."""
    choices = MODEL_CHOICES if auto else tuple(MODELS)
    p.add_argument("--model", choices=choices, default=None,
                   help="plant model: ideal = mass, Izz (default); friction = + viscous friction "
                        "ct, cr and yaw bias kb; friction+tilt = + table tilt ax, ay"
                        + ("; auto = choose by likelihood-ratio test" if auto else ""))
    if auto:
        p.add_argument("--select-alpha", type=float, default=1e-3, metavar="P",
                       help="--model auto: level of the likelihood-ratio tests (default 1e-3)")


def _run_thrusts(args):
    from common.runfolder import read_run
    from common.thrust_table import load_thrust_table
    from estimator.batch.least_squares import parse_window

    run = read_run(args.run_dir)
    window = parse_window(getattr(args, "window", None))
    if window != (None, None):
        run = run.window(*window)
    table = load_thrust_table(getattr(args, "thrust_table", None))
    cmd_t, thrust = run.thrust_profile(table, clamp=getattr(args, "clamp", False))
    return run, cmd_t, thrust


def before_batch(args: argparse.Namespace) -> int | None:
    """Resolve ``--model`` into ``args.estimate``/``args.fixed``; run ``auto`` selection.

    Returns an exit code when it handled the command itself (the extended-state filters
    for ``--method ekf|ls-ekf`` with a non-ideal model), else None.
    """
    model = getattr(args, "model", None)
    if model is None:
        args.model = model_of(args.estimate) or "custom"
        return None
    if model == "auto":
        if not 0 < args.select_alpha < 1:
            raise UserError("--select-alpha must lie in (0, 1)")
        from estimator.batch.model_select import select_model

        run, cmd_t, thrust = _run_thrusts(args)
        sel = select_model(run.pose_t, run.pose, cmd_t, thrust, alpha=args.select_alpha,
                           fixed={k: v for k, v in args.fixed.items()},
                           sigma_pos_m=args.sigma_pos,
                           sigma_yaw_rad=math.radians(args.sigma_yaw_deg))
        args.model_selection = sel
        model = sel.chosen
        out = sys.stderr if args.json else sys.stdout
        print(f"model selection on {run.path} (--model auto):", file=out)
        for line in sel.table_lines():
            print(line, file=out)
        _start_at(args, sel.fits[model])
    args.model = model
    args.estimate = resolve_names(model, args.estimate)
    args.fixed = fixed_for(model, {k: v for k, v in args.fixed.items()})
    if args.method != "ls" and model != DEFAULT_MODEL:
        return run_ext_filter(args)
    if args.method == "ls" and model != DEFAULT_MODEL and not hasattr(args, "model_selection"):
        # fit the nested smaller models first: the larger fit then starts at (and can only
        # improve on) their optimum, which is more robust than the paper's start alone
        from estimator.batch.model_select import fit_models

        run, cmd_t, thrust = _run_thrusts(args)
        order = list(MODELS)
        fits = fit_models(run.pose_t, run.pose, cmd_t, thrust, order[:order.index(model) + 1],
                          fixed={k: v for k, v in args.fixed.items() if k not in args.estimate},
                          initial=args.initial, sigma_pos_m=args.sigma_pos,
                          sigma_yaw_rad=math.radians(args.sigma_yaw_deg))
        _start_at(args, fits[model])
    return None


def _start_at(args: argparse.Namespace, fit) -> None:
    """Start the batch fit of ``cmd_batch`` at a staged fit's optimum (when it converged)."""
    from estimator.plant.model import STATE_NAMES

    r = fit.result
    if r.converged and np.all(np.isfinite(r.z0)):
        args.initial = dict(zip(STATE_NAMES + tuple(r.names), r.z0.tolist(), strict=True))
        args.start_note = f"started at the staged fit's optimum ({fit.start})"


def annotate(out: dict[str, Any], args: argparse.Namespace) -> None:
    """Add the model option (and the auto-selection record) to a batch JSON object."""
    out["model"] = getattr(args, "model", DEFAULT_MODEL)
    if getattr(args, "start_note", None):
        out["start"] = args.start_note
    sel = getattr(args, "model_selection", None)
    if sel is not None:
        out["model_selection"] = sel.to_dict()


def crlb_names(args: argparse.Namespace) -> tuple[str, ...]:
    """Parameters of ``estimate crlb --model``."""
    return MODELS[getattr(args, "model", None) or DEFAULT_MODEL]


def crlb_extra(c, args: argparse.Namespace) -> dict[str, Any]:
    """JSON keys of the extended bound: every parameter's sigma and the correlations."""
    out: dict[str, Any] = {"model": getattr(args, "model", None) or DEFAULT_MODEL,
                           "estimated": list(c.names)}
    for n, s in zip(c.names, c.sigma, strict=True):
        if n not in ("mass", "izz"):
            out[f"crlb_{n}_sigma"] = float(s)
    sd = np.where(c.sigma > 0, c.sigma, 1.0)
    out["crlb_correlation"] = (c.cov / np.outer(sd, sd)).tolist()
    return out


def crlb_lines(c) -> list[str]:
    """Text lines of the bounds on the parameters beyond mass and Izz."""
    from estimator.plant.parameter_sets import PARAM_UNITS

    return [f"  {n:<5} sigma >= {s:.4g} {PARAM_UNITS[n]}"
            for n, s in zip(c.names[2:], c.sigma[2:], strict=True)]


def run_ext_filter(args: argparse.Namespace) -> int:
    """``estimate batch --method ekf|ls-ekf --model friction|friction+tilt``."""
    from estimator.filters.ekf_ext import SIGMA0, ExtEkfConfig, estimate_ext

    run, cmd_t, thrust = _run_thrusts(args)
    names = tuple(args.estimate)
    sig_meas = (args.sigma_pos, args.sigma_pos, math.radians(args.sigma_yaw_deg))
    from estimator.filters.ekf import STATE_NAMES as EKF_NAMES

    q = {EKF_NAMES[i]: v for i, v in args.process_noise.items() if v}
    try:
        cfg = ExtEkfConfig(names=names, fixed=dict(args.fixed), sigma_meas=sig_meas, q_psd=q)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    x0 = cfg.default_x0(run.pose[0])
    for k, v in (args.initial or {}).items():
        if k not in cfg.labels:
            raise UserError(f"--initial {k}: not estimated by --model {args.model}")
        x0[cfg.labels.index(k)] = v
    P0 = cfg.default_P0()
    for i, v in args.sigma0.items():
        P0[i, i] = v**2
    ls_kwargs = {"tol": args.tol, "max_iter": args.max_iter}
    if args.initial:
        ls_kwargs["initial"] = dict(args.initial)
    r, ls = estimate_ext(run.pose_t, run.pose, cmd_t, thrust, cfg, args.method, x0=x0, P0=P0,
                         ls_window_s=args.ls_window, ls_start=args.ls_start, ls_kwargs=ls_kwargs)
    out: dict[str, Any] = {"method": args.method, "model": args.model, "run": str(run.path)}
    out.update(r.to_dict())
    if ls is not None:
        out["ls"] = {"mass_kg": ls.mass_kg, "mass_sigma_kg": ls.mass_sigma_kg,
                     "izz_kgm2": ls.izz_kgm2, "izz_sigma_kgm2": ls.izz_sigma_kgm2,
                     "converged": ls.converged, "n_poses": int(len(ls.t)),
                     "ls_window_s": args.ls_window, "ls_start": args.ls_start}
    sel = getattr(args, "model_selection", None)
    if sel is not None:
        out["model_selection"] = sel.to_dict()
    truth = run.truth or {}
    if "mass_kg" in truth and "izz_kgm2" in truth:
        tm, ti = float(truth["mass_kg"]), float(truth["izz_kgm2"])
        rm, ri = r.rmse(tm, ti)
        out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                    "mass_error_kg": r.mass_kg - tm, "izz_error_kgm2": r.izz_kgm2 - ti,
                    "rmse_mass_kg": rm, "rmse_izz_kgm2": ri})
    if args.out:
        d = Path(args.out)
        d.mkdir(parents=True, exist_ok=True)
        (d / "estimate.json").write_text(json.dumps(out, indent=2, default=str) + "\n")
        cols = ["t", *r.labels, *(f"sigma_{n}" for n in r.labels), "updated", "nis"]
        np.savetxt(d / "history.csv", np.column_stack([r.t, r.x, r.sigma, r.updated, r.nis]),
                   delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
    if r.diverged:
        print("tpods: warning: the extended filter diverged (non-physical parameters or "
              "innovations far larger than their covariance); try --method ls-ekf",
              file=sys.stderr)
    if args.json:
        sys.stdout.write(json.dumps(out, default=str) + "\n")
        return 0
    print(f"{args.method} with --model {args.model} on {run.path} ({len(r.t)} poses)")
    for n in r.names:
        v, s = r.final(n)
        print(f"  {n:<5} = {v:.6g} +/- {s:.3g} (1 sigma; prior sigma {SIGMA0[n]:g})")
    if "truth_mass_kg" in out:
        print(f"  RMSE over the run: mass {out['rmse_mass_kg']:.4g} kg, "
              f"Izz {out['rmse_izz_kgm2']:.4g} kg m^2")
    return 0


# --------------------------------------------------------------------------------------
# tpods report realism


def register(sub, est, rep) -> None:
    """Add ``tpods report realism``."""
    from common.argtypes import positive_float

    r = rep.add_parser(
        "realism", help="friction, yaw bias and tilt estimated jointly vs the ideal model "
                        "(simulated 14 s translate-rotate runs of a 0.72 kg module)",
        description="Simulate the paper's experiment (0.72 kg module, 14 s translate-then-rotate "
                    "input, 120 Hz poses) with friction, a yaw bias and a small tilt, and compare "
                    "the ideal model, the ideal model with friction hand-set to a wrong value and "
                    "the jointly estimated models, beside the paper's experimental RMSE; model "
                    "selection, residual whiteness, identifiability (correlations) and a Monte "
                    "Carlo over friction, bias and tilt values.")
    r.add_argument("--out", required=True, metavar="DIR", help="report folder")
    r.add_argument("--runs", type=int, default=40,
                   help="Monte Carlo runs over friction/bias/tilt values (default 40)")
    r.add_argument("--seeds", type=int, default=5,
                   help="noise seeds of the fixed-truth comparison (default 5)")
    r.add_argument("--seed", type=int, default=0, help="base random seed (default 0)")
    r.add_argument("--duration", type=positive_float, default=14.0, help="seconds (default 14)")
    r.add_argument("--no-ekf", action="store_true", help="skip the extended-state LS+EKF rows")
    r.set_defaults(func=cmd_report_realism)


def cmd_report_realism(args: argparse.Namespace) -> int:
    from estimator.reports.realism import write_report

    if args.runs < 2 or args.seeds < 1:
        raise UserError("--runs must be >= 2 and --seeds >= 1")
    path = write_report(args.out, runs=args.runs, seeds=args.seeds, seed=args.seed,
                        duration_s=args.duration, with_ekf=not args.no_ekf, log=print)
    print(f"wrote {path}")
    return 0

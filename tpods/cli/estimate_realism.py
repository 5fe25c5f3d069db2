"""CLI hooks of the model options: ``--model`` for ``estimate batch`` and
``estimate crlb``, the extended-state filters, and ``tpods report realism``.

The batch/CRLB commands (:mod:`tpods.cli.estimate_batch`, which this module does not
import) call :func:`add_model_option`,
:func:`selection_log` (where ``--model auto`` prints its table), :func:`report_ext` (the
output of the extended-state filters) and :func:`crlb_lines`; the use cases themselves
are :func:`estimator.estimate.estimate_run` and :func:`estimator.estimate.bound_sequence`.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from common.argtypes import random_seed
from common.errors import UserError
from common.outputs import ResultFolder
from estimator.plant.parameter_sets import MODEL_CHOICES, MODELS
from tpods.cli.estimate_output import budget_lines, centre_of_mass_lines, filter_budget, write_json
from tpods.cli.options import add_report_out
from tpods.cli.parser import command


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


def selection_log(args: argparse.Namespace):
    """Where ``estimate_run`` reports: the ``--model auto`` selection table to stderr under
    ``--json``, else stdout; plausibility warnings (``tpods: warning: ...``) to stderr."""
    out = sys.stderr if args.json else sys.stdout

    def log(line: str) -> None:
        print(line, file=sys.stderr if line.startswith("tpods: warning:") else out)
    return log


def crlb_lines(c) -> list[str]:
    """Text lines of the bounds on the parameters beyond mass and Izz."""
    from estimator.plant.parameter_sets import PARAM_UNITS

    return [f"  {n:<5} sigma >= {s:.4g} {PARAM_UNITS[n]}"
            for n, s in zip(c.names[2:], c.sigma[2:], strict=True)]


def report_ext(est, args: argparse.Namespace) -> int:
    """Write and print ``estimate batch --method ekf|ls-ekf --model friction|friction+tilt``."""
    from estimator.filters.ext import SIGMA0

    r, run, out = est.ext, est.run, est.to_dict()
    out_folder = getattr(args, "out_folder", None)
    if out_folder is not None:
        with out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            write_json(main, out)
            cols = ["t", *r.labels, *(f"sigma_{n}" for n in r.labels), "updated", "nis"]
            if d is not None:
                np.savetxt(d / "history.csv", np.column_stack([r.t, r.x, r.sigma, r.updated, r.nis]),
                           delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
    if r.diverged:
        print("tpods: warning: the extended filter diverged (non-physical parameters or "
              "innovations far larger than their covariance); try --method ls-ekf",
              file=sys.stderr)
    if args.json:
        sys.stdout.write(json.dumps(out, default=str) + "\n")
        return 0
    print(f"{args.method} with --model {est.model} on {run.path} ({len(r.t)} poses)")
    for n in r.names:
        v, s = r.final(n)
        print(f"  {n:<5} = {v:.6g} +/- {s:.3g} (1 sigma, noise; prior sigma {SIGMA0[n]:g})")
    # a structure: its centre of mass as estimate batch --method ls prints it
    for line in budget_lines(filter_budget(out)) + centre_of_mass_lines(out):
        print(line)
    if "truth_mass_kg" in out:
        print(f"  RMSE over the run: mass {out['rmse_mass_kg']:.4g} kg, "
              f"Izz {out['rmse_izz_kgm2']:.4g} kg m^2")
    return 0


# --------------------------------------------------------------------------------------
# tpods report realism


def register(sub, est, rep) -> None:
    """Add ``tpods report realism``."""
    from common.argtypes import positive_float

    r = command(
        rep, "realism", cmd_report_realism,
        help="friction, yaw bias and tilt estimated jointly vs the ideal model "
             "(simulated 14 s translate-rotate runs of a 0.72 kg module)")
    add_report_out(r)
    r.add_argument("--runs", type=int, default=40,
                   help="Monte Carlo runs over friction/bias/tilt values (default 40)")
    r.add_argument("--seeds", type=int, default=5,
                   help="noise seeds of the fixed-truth comparison (default 5)")
    r.add_argument("--seed", type=random_seed, default=0, help="base random seed (default 0)")
    r.add_argument("--duration", type=positive_float, default=14.0, help="seconds (default 14)")
    r.add_argument("--no-ekf", action="store_true", help="skip the extended-state LS+EKF rows")


def cmd_report_realism(args: argparse.Namespace) -> int:
    """Simulate the paper's experiment (0.72 kg module, 14 s translate-then-rotate input, 120 Hz
    poses) with friction, a yaw bias and a small tilt, and compare the ideal model, the ideal
    model with friction hand-set to a wrong value and the jointly estimated models, beside the
    paper's experimental RMSE; model selection, residual whiteness, identifiability
    (correlations) and a Monte Carlo over friction, bias and tilt values."""

    from estimator.reports.realism import write_report

    out_folder = ResultFolder(args.out, force=args.force, command="tpods report realism")
    if args.runs < 2 or args.seeds < 1:
        raise UserError("--runs must be >= 2 and --seeds >= 1")
    with out_folder.writing() as d:
        path = out_folder.final(write_report(d, runs=args.runs, seeds=args.seeds, seed=args.seed,
                                             duration_s=args.duration, with_ekf=not args.no_ekf,
                                             log=print))
    print(f"wrote {path}")
    return 0

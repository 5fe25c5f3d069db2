"""CLI hooks of the model options: ``--model`` for ``estimate batch`` and
``estimate crlb`` (:func:`add_model_option`), where ``--model auto`` prints its table
(:func:`selection_log`), and ``tpods report realism``
(:func:`estimator.reports.realism.write_report`).
"""

from __future__ import annotations

import argparse
import sys

from common.argtypes import random_seed
from common.errors import UserError
from common.outputs import ResultFolder
from estimator.plant.parameter_sets import MODEL_CHOICES, MODELS
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

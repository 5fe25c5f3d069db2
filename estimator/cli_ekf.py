"""CLI of the EKF, LS-initialised EKF and Monte Carlo.

Owner: issue 4. ``register`` adds ``tpods estimate montecarlo`` and the EKF report;
``add_batch_options(parser)`` adds the filter options to ``tpods estimate batch`` and
``run_filter_method(args)`` runs ``--method ekf|ls-ekf`` for it.
"""

from __future__ import annotations


def register(sub, est, rep) -> None:
    """Add this module's commands: ``sub`` top level, ``est`` under estimate, ``rep`` under report."""


def add_batch_options(parser) -> None:
    """Add the filter options (``--ls-window``, ``--underweight``, ...) to ``estimate batch``."""


def run_filter_method(args) -> int:
    """Run ``tpods estimate batch --method ekf|ls-ekf``."""
    from tpods.errors import UserError

    raise UserError(f"--method {args.method} is not implemented yet (issue 4)")

"""CLI of the EKF, LS-initialised EKF and Monte Carlo.

Owner: issue 4. ``register`` adds ``tpods estimate montecarlo`` and the EKF report;
``add_batch_options(parser)`` adds the filter options to ``tpods estimate batch`` and
``run_filter_method(args)`` runs ``--method ekf|ls-ekf`` for it.
"""

from __future__ import annotations


def register(sub, est, rep) -> None:
    """Add this module's commands: ``sub`` top level, ``est`` under estimate, ``rep`` under report."""

"""CLI of the batch least-squares estimator, the CRLB, input design and the Table 3 report.

Owner: issue 3. ``register`` adds ``tpods estimate batch`` (all methods: ``ls`` here,
``ekf``/``ls-ekf`` delegated to :mod:`estimator.cli_ekf`), ``tpods estimate crlb``,
``tpods design`` and ``tpods report table3``.
"""

from __future__ import annotations


def register(sub, est, rep) -> None:
    """Add this module's commands: ``sub`` top level, ``est`` under estimate, ``rep`` under report."""

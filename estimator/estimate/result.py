"""The result of :func:`estimator.estimate.estimate_run`: :class:`Estimate`, whose
``to_dict()`` is the JSON object ``tpods estimate batch --json`` prints."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from common.runfolder import Run
from estimator.batch.crlb import CRLBResult
from estimator.batch.least_squares import BatchResult
from estimator.batch.model_select import ModelSelection
from estimator.filters.ekf import EkfConfig, FilterEstimate
from estimator.filters.ext import ExtEkfConfig, ExtEkfResult


@dataclass
class Estimate:
    """Result of :func:`estimator.estimate.estimate_run`.

    ``method`` and ``model`` as used (``model`` is the chosen one under ``auto``, or
    ``"custom"`` for a parameter set no model names); ``run`` the run as estimated (the
    window applied). Exactly one of ``batch`` (``ls``), ``filter`` (``ekf``/``ls-ekf``,
    ideal model) and ``ext`` (``ekf``/``ls-ekf``, extended model; ``ext_ls`` its LS start)
    is set. ``selection`` is the ``auto`` model selection, ``start_note`` how the LS fit
    was started when a staged fit gave the start; ``config`` and ``x0`` the filter's setting
    and start; ``crlb`` the bound at the truth (``ls`` on a simulated run).
    """

    method: str
    model: str
    run: Run
    data: dict[str, Any]
    batch: BatchResult | None = None
    filter: FilterEstimate | None = None
    ext: ExtEkfResult | None = None
    ext_ls: BatchResult | None = None
    selection: ModelSelection | None = None
    start_note: str | None = None
    config: EkfConfig | ExtEkfConfig | None = None
    x0: np.ndarray | None = None
    crlb: CRLBResult | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of ``tpods estimate batch --json`` (same keys, same order)."""
        return dict(self.data)

    @property
    def has_truth(self) -> bool:
        return "truth_mass_kg" in self.data

    @property
    def converged(self) -> bool:
        """False when the batch fit did not converge, a filter diverged or a filter's
        parameter learnt nothing from the run."""
        if self.batch is not None:
            return bool(self.batch.converged)
        if self.filter is not None:
            return self.filter.converged
        return not self.ext.diverged

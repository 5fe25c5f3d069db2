"""A start for a batch fit when nothing gives the mass or Izz, on arrays.

A vehicle's vehicle.toml may say nothing of its mass and Izz, and it may be ten times the
paper's module (an air-bearing satellite of 23 kg), from which the fit does not converge.
:func:`scan_masses`: the first :data:`SCAN_SPAN_S` of the poses fitted from a few masses a
decade apart (Izz from the thrusters' reach as radius of gyration), a few iterations each;
the fit with the lowest cost gives the start of the whole fit. Used by the live estimator's
window fit (:mod:`estimator.live.scan_job`); ``tpods estimate batch`` scans a run folder
with the same constants (:mod:`estimator.estimate.vehicle_start`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from common.errors import UserError

SCAN_MASSES_KG = (0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
SCAN_SPAN_S = 10.0
SCAN_ITERATIONS = 15


def scan_masses(pose_t: np.ndarray, pose: np.ndarray, cmd_t: np.ndarray, thrust_n: np.ndarray,
                reach_m: float, kw: Mapping[str, Any]) -> dict[str, float] | None:
    """``{"mass": kg, "izz": kg m^2}`` of the lowest-cost short fit of the first
    :data:`SCAN_SPAN_S` of ``pose_t`` (the batch LS keywords ``kw``, its ``initial``
    overridden), or None when no start gave a physical fit. ``reach_m``: the farthest
    thruster from the tracked origin, m."""
    from estimator.batch.least_squares import batch_ls

    pose_t = np.asarray(pose_t, dtype=float)
    n = max(int(np.searchsorted(pose_t, pose_t[0] + SCAN_SPAN_S, "right")), min(len(pose_t), 10))
    r2 = max(reach_m, 0.05) ** 2 / 2.0
    best: tuple[float, dict[str, float]] | None = None
    for m in SCAN_MASSES_KG:
        args = {**kw, "initial": {**dict(kw.get("initial") or {}), "mass": m, "izz": m * r2},
                "max_iter": SCAN_ITERATIONS}
        try:
            res = batch_ls(pose_t[:n], np.asarray(pose)[:n], cmd_t, thrust_n, **args)
        except (UserError, ValueError, FloatingPointError, np.linalg.LinAlgError):
            continue
        cost = float(res.cost_history[-1]) if res.cost_history else math.inf
        if math.isfinite(cost) and res.mass_kg > 0 and res.izz_kgm2 > 0 and (
                best is None or cost < best[0]):
            best = (cost, {"mass": float(res.mass_kg), "izz": float(res.izz_kgm2)})
    return None if best is None else best[1]

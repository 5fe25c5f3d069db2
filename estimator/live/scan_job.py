"""Background job of the live ``ls-ekf`` on a vehicle whose mass and Izz nothing
gives: a short mass scan (:func:`estimator.batch.mass_scan.scan_masses`) for the start,
then the window's batch fit (:func:`estimator.live.worker.ls_job`) from it.

Kept free of heavy imports at module level, like :mod:`estimator.live.worker` (a spawned
worker imports this module to find the job).
"""

from __future__ import annotations

import time
from typing import Any

from estimator.live.worker import ls_job


def scan_ls_job(pose_t, pose, cmd_t, thrust_n, kw: dict[str, Any], sens=None,
                reach_m: float = 0.05):
    """:func:`~estimator.live.worker.ls_job` from the start of the mass scan (the
    caller's ``kw["initial"]`` where the scan finds nothing). Returns ``(BatchResult,
    seconds)``, the seconds the scan's included."""
    from estimator.batch.mass_scan import scan_masses  # lazy: after the worker's init()

    t_a = time.perf_counter()
    start = scan_masses(pose_t, pose, cmd_t, thrust_n, reach_m, kw)
    if start is not None:
        kw = {**kw, "initial": {**dict(kw.get("initial") or {}), **start}}
    res, _ = ls_job(pose_t, pose, cmd_t, thrust_n, kw, sens)
    return res, time.perf_counter() - t_a

"""Background worker of the live ``ls-ekf``: the batch fit, in its own low-priority process.

Kept free of heavy imports at module level: a spawned worker imports this module to find
its initializer, lowers its priority first, and only then imports numpy/scipy.
"""

from __future__ import annotations

import contextlib
import os
import time


def init() -> None:
    """Yield the CPU to the live loop (lower priority), before any heavy import."""
    with contextlib.suppress(OSError, AttributeError):
        os.nice(10)


def warm() -> None:
    """Import the batch estimator now, not when the window is complete."""
    import estimator.batch.least_squares  # noqa: F401  # lazy: after init() lowered the priority


def ls_job(pose_t, pose, cmd_t, thrust_n, kw, sens=None):
    """Batch LS on the first window. Returns ``(BatchResult, seconds)``; with ``sens`` (the
    thrust table's :class:`~common.thrust_uncertainty.ThrustSensitivity` of the commands)
    the result carries the table's consider covariance too (total sigma)."""
    from estimator.batch.least_squares import batch_ls  # lazy: after init() lowered the priority

    t_a = time.perf_counter()
    res = batch_ls(pose_t, pose, cmd_t, thrust_n, **kw)
    if sens is not None and res.converged:
        from estimator.batch.consider import batch_consider

        c = batch_consider(res, cmd_t, sens, sigma_pos_m=kw["sigma_pos_m"],
                           sigma_yaw_rad=kw["sigma_yaw_rad"])
        if all(c.cov_thrust.ravel() == c.cov_thrust.ravel()):  # no NaN
            res.add_thrust_covariance(c.cov_thrust, c.names)
    res.fisher = None  # not needed by the live estimator
    res.reference = None  # nor the fit's trajectory (kept for batch_consider, done above)
    return res, time.perf_counter() - t_a

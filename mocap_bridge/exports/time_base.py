"""Pose times rebuilt from a log's own finite-difference velocities.

Some labs log a nominal control clock (a fixed step per row) beside velocities computed as
finite differences of the poses over the TRUE interval: ``v_k = (p_k - p_{k-1}) / dt_k``.
Then ``dt_k = (p_k - p_{k-1}) / v_k`` for any component that moved; the best conditioned of
x, y and yaw (largest speed over its resolution) is taken per row, and a row where nothing
moved (at rest) takes the median of the determined intervals.
"""

from __future__ import annotations

import numpy as np

RESOLUTION = (0.02, 0.02, 0.05)
"""Speeds (m/s, m/s, rad/s) below which a component does not determine its interval."""


def intervals_from_velocities(pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(dt (N-1,), determined (N-1,) bool)`` from positions ``pos`` (N, 3: x, y in m, yaw
    in rad) and their logged finite-difference velocities ``vel`` (N, 3); rows where no
    component determines the interval (or it comes out non-positive or non-finite) get the
    median of the others."""
    pos = np.asarray(pos, float)
    vel = np.asarray(vel, float)
    d = np.diff(pos, axis=0)
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    v = vel[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        score = np.abs(v) / np.asarray(RESOLUTION)
        score = np.where(np.isfinite(score), score, -1.0)
        best = np.argmax(score, axis=1)
        rows = np.arange(len(d))
        dt = d[rows, best] / v[rows, best]
    ok = (score[rows, best] > 1.0) & np.isfinite(dt) & (dt > 0)
    if not ok.any():
        raise ValueError("no row's velocity determines its interval (the body never moves, or "
                         "the velocity columns are not finite differences of the poses)")
    dt = np.where(ok, dt, np.median(dt[ok]))
    return dt, ok


def rebuilt_times(t_nominal: np.ndarray, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
    """(N,) pose times: the first nominal time, then the rebuilt intervals."""
    dt, _ = intervals_from_velocities(pos, vel)
    return float(np.asarray(t_nominal, float)[0]) + np.concatenate([[0.0], np.cumsum(dt)])

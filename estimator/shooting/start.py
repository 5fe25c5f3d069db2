"""A start for the mass and Izz of a segment fit from the equation error: accelerations from
smoothed poses regressed on the commanded thrusts (no integration, so no start to diverge
from). Far from exact (it ignores tilt, damping, the dead time and the centre of mass) but
within tens of percent, where the segment fit converges; the paper's 2.3 kg module is a
start 10x off for a 23 kg vehicle and 100x off in Izz."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import savgol_filter

from estimator.shooting.inputs import ThrustChannels

SMOOTH_S = 0.6
"""Savitzky-Golay window, s (quadratic): long enough to differentiate mm noise twice."""


def equation_error_start(pose_t, pose, ch: ThrustChannels) -> dict[str, float]:
    """``{"mass": kg, "izz": kg m^2}`` (either left out where the run does not inform it)."""
    t = np.asarray(pose_t, float)
    if len(t) < 10:
        return {}
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], dt)
    if len(grid) < 10:
        return {}
    x = np.interp(grid, t, pose[:, 0])
    y = np.interp(grid, t, pose[:, 1])
    psi = np.interp(grid, t, np.unwrap(pose[:, 2]))
    win = max(5, int(round(SMOOTH_S / dt)) | 1)
    if win >= len(grid):
        return {}
    ax, ay, apsi = (savgol_filter(q, win, 2, deriv=2, delta=dt) for q in (x, y, psi))
    psi_s = savgol_filter(psi, win, 2)
    # the commanded body wrench, smoothed by the same filter as the accelerations
    avg = ch.step_average(grid - 0.5 * dt, grid + 0.5 * dt, 0.0)[:, 0, :]  # (n, N) thrusts
    w = avg @ ch.wrench.T
    fx, fy, mz = (savgol_filter(w[:, k], win, 2) for k in range(3))
    c, s = np.cos(psi_s), np.sin(psi_s)
    fxl, fyl = c * fx - s * fy, s * fx + c * fy
    out = {}
    ff = float(np.sum(fxl ** 2 + fyl ** 2))
    fa = float(np.sum(fxl * ax + fyl * ay))
    if ff > 0 and fa > 0:
        out["mass"] = ff / fa
    mm = float(np.sum(mz * mz))
    ma = float(np.sum(mz * apsi))
    if mm > 0 and ma > 0:
        out["izz"] = mm / ma
    return {k: v for k, v in out.items() if math.isfinite(v) and v > 0}

"""Figures of the batch estimator: residuals (paper Fig. 5) and sensitivities (Fig. 6). PNG, Agg."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

matplotlib.use("Agg")  # PNG files only, no window

UNITS = {"mass": "kg", "izz": "kg m$^2$", "ct": "N s/m", "cr": "N m s", "kb": "N s",
         "ax": "m/s$^2$", "ay": "m/s$^2$"}
STATE_LABELS = ("x [m]", "y [m]", r"$\psi$ [rad]", "u [m/s]", "v [m/s]", "r [rad/s]")


def _save(fig, path: str | Path) -> Path:
    """Lay out, write (110 dpi) and close ``fig``; the path written."""
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_residuals(t: np.ndarray, residuals: np.ndarray, path: str | Path, *, title: str = "",
                   sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0)) -> Path:
    """Residuals of x, y (cm) and yaw (deg) against time with +/-3 sigma lines (Fig. 5)."""
    t = np.asarray(t) - t[0]
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    data = [(residuals[:, 0] * 100, sigma_pos_m * 100, "x residual [cm]"),
            (residuals[:, 1] * 100, sigma_pos_m * 100, "y residual [cm]"),
            (np.degrees(residuals[:, 2]), math.degrees(sigma_yaw_rad), "yaw residual [deg]")]
    for ax, (r, s, lab) in zip(axes, data, strict=True):
        ax.plot(t, r, ".", ms=1.5, alpha=0.6)
        for k in (-3, 3):
            ax.axhline(k * s, color="r", lw=0.8, ls="--")
        ax.axhline(0, color="k", lw=0.6)
        ax.set_ylabel(lab)
        ax.text(0.01, 0.95, f"mean {r.mean():+.3g}, rms {np.sqrt(np.mean(r**2)):.3g}",
                transform=ax.transAxes, va="top", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or "Least-squares residuals (dashed: +/-3 sigma of the noise)")
    return _save(fig, path)


def plot_poses_fit(t: np.ndarray, pose: np.ndarray, residuals: np.ndarray, path: str | Path, *,
                   title: str = "") -> Path:
    """The measured poses (dots) against the fitted model's (line): x, y (m) and yaw (deg)
    against time, the model's poses being ``pose - residuals``; ``pose`` (N, 3) at ``t``."""
    t = np.asarray(t, float)
    pose = np.asarray(pose, float)
    yaw = np.unwrap(pose[:, 2])
    model = np.column_stack([pose[:, 0] - residuals[:, 0], pose[:, 1] - residuals[:, 1],
                             yaw - residuals[:, 2]])
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for ax, meas, fit, lab in zip(axes, (pose[:, 0], pose[:, 1], np.degrees(yaw)),
                                  (model[:, 0], model[:, 1], np.degrees(model[:, 2])),
                                  ("x [m]", "y [m]", "yaw [deg]"), strict=True):
        ax.plot(t - t[0], meas, ".", ms=2, alpha=0.6, label="measured")
        ax.plot(t - t[0], fit, "-", lw=1.0, color="C3", label="fitted model")
        ax.set_ylabel(lab)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or "Measured poses and the fitted model")
    return _save(fig, path)


def plot_sensitivities(t: np.ndarray, sens_x: np.ndarray, names, theta, path: str | Path, *,
                       title: str = "") -> Path:
    """State sensitivities ``theta_j dx_i/dtheta_j`` (N, 6, p) against time (Fig. 6).

    Each column is scaled by its parameter value (the change of the state for a 100 %
    change of the parameter), so mass and Izz columns compare directly. The first three
    rows are the outputs (x, y, psi), i.e. the output sensitivities S_y,theta.
    """
    t = np.asarray(t) - t[0]
    p = len(names)
    fig, axes = plt.subplots(6, p, figsize=(4.2 * p, 9), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        for i in range(6):
            ax = axes[i, j]
            ax.plot(t, sens_x[:, i, j] * theta[j], lw=1.0, color="C0" if i < 3 else "C1")
            ax.axhline(0, color="k", lw=0.4)
            if j == 0:
                ax.set_ylabel(STATE_LABELS[i], fontsize=8)
            if i == 0:
                ax.set_title(f"theta * d(state)/d(theta), theta = {name}", fontsize=9)
            ax.tick_params(labelsize=7)
        axes[-1, j].set_xlabel("time [s]")
    fig.suptitle(title or r"Sensitivities $\theta\,\partial x/\partial\theta$ (blue: outputs)")
    return _save(fig, path)

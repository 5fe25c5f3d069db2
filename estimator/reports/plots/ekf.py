"""Figures of the filters: error and 3-sigma histories (paper Figs. 7, 8, 14) and the
Monte Carlo plots (Figs. 9, 10). Matplotlib with the Agg backend, PNG files."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

matplotlib.use("Agg")  # PNG files only, no window


_LABELS = (("mass", "kg"), ("Izz", "kg m$^2$"))


def plot_error_bounds(t, est, sigma, path, truth=None, title: str = "") -> Path:
    """m and Izz error (or estimate, without truth) inside +/- 3 sigma, two panels.

    Args:
        t: (N,) s. est: (N, 2) estimates of m (kg) and Izz (kg m^2). sigma: (N, 2).
        truth: (m, Izz) or None (then the estimate is drawn with its 3-sigma band).
    """
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes):
        name, unit = _LABELS[j]
        s3 = 3 * sigma[:, j]
        if truth is not None:
            draw_error_band(ax, t, est[:, j] - truth[j], s3, f"{name} error [{unit}]")
        else:
            ax.fill_between(t, est[:, j] - s3, est[:, j] + s3, color="tab:blue", alpha=0.2,
                            label=r"$\pm 3\sigma$")
            ax.plot(t, est[:, j], color="tab:red", lw=1, label="estimate")
            ax.set_ylabel(f"{name} [{unit}]")
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right", fontsize=8)
    return save_time_panels(fig, axes, path, title)


def draw_error_band(ax, t, e, s3, ylabel: str, ylabel_fontsize: float | None = None) -> None:
    """One panel of an error history: the error ``e`` inside its +/- 3 sigma band ``s3``
    (same units, arrays over time ``t``, s), the y range fitted to the last 90 % of the run."""
    ax.fill_between(t, -s3, s3, color="tab:blue", alpha=0.2, label=r"$\pm 3\sigma$")
    ax.plot(t, e, color="tab:red", lw=1, label="error")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_ylabel(ylabel, **({} if ylabel_fontsize is None else {"fontsize": ylabel_fontsize}))
    if len(t) > 1:
        late = t >= t[0] + 0.1 * (t[-1] - t[0])
        lim = 1.3 * max(float(np.max(np.abs(e[late]))), float(np.max(s3[late])))
        if np.isfinite(lim) and lim > 0:
            ax.set_ylim(-lim, lim)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


def save_time_panels(fig, axes, path, title: str = "") -> Path:
    """Label the shared time axis, title the top panel (if ``title``), write the PNG and
    close the figure."""
    axes[-1].set_xlabel("time [s]")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_mc_runs(t, ex_err, ex_sigma, path, title: str = "") -> Path:
    """Fig. 9 style: errors of individual Monte Carlo runs with their +/- 3 sigma envelopes.

    ex_err, ex_sigma: (K, N, 2) for m and Izz.
    """
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes):
        name, unit = _LABELS[j]
        for k in range(ex_err.shape[0]):
            ax.plot(t, ex_err[k, :, j], lw=0.6, color="tab:red", alpha=0.5)
            ax.plot(t, 3 * ex_sigma[k, :, j], lw=0.6, color="tab:blue", alpha=0.5)
            ax.plot(t, -3 * ex_sigma[k, :, j], lw=0.6, color="tab:blue", alpha=0.5)
        lim = np.percentile(3 * ex_sigma[:, len(t) // 20:, j], 95) * 1.5
        if np.isfinite(lim) and lim > 0:
            ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{name} error [{unit}]")
        ax.grid(alpha=0.3)
    axes[0].plot([], [], color="tab:red", label="error (one line per run)")
    axes[0].plot([], [], color="tab:blue", label=r"$\pm 3\sigma$ of that run")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(title or "Monte Carlo runs")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_mc_averages(res, path, title: str = "") -> Path:
    """Fig. 10 style: bias, sample std and filter sigma of m and Izz, and the average NEES."""
    t = res.t
    fig, axes = plt.subplots(3, 1, figsize=(8, 8.5), sharex=True)
    for j, ax in enumerate(axes[:2]):
        name, unit = _LABELS[j]
        c = 6 + j
        ax.plot(t, res.bias[:, c], color="tab:red", lw=1, label="mean error (bias)")
        ax.plot(t, 3 * res.std[:, c], color="tab:green", lw=1, label=r"$\pm 3\times$ sample std")
        ax.plot(t, -3 * res.std[:, c], color="tab:green", lw=1)
        ax.plot(t, 3 * res.sigma[:, c], color="tab:blue", lw=1, ls="--",
                label=r"$\pm 3\times$ filter $\sigma$")
        ax.plot(t, -3 * res.sigma[:, c], color="tab:blue", lw=1, ls="--")
        lim = np.percentile(3 * np.maximum(res.std[len(t) // 20:, c], res.sigma[len(t) // 20:, c]),
                            95) * 1.5
        if np.isfinite(lim) and lim > 0:
            ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    ax.semilogy(t, res.nees_param, color="tab:red", lw=1, label="average NEES (m, Izz)")
    ax.axhline(res.bounds_param[0], color="tab:red", ls=":", lw=1)
    ax.axhline(res.bounds_param[1], color="tab:red", ls=":", lw=1, label="95 % bounds (2 dof)")
    ok = np.isfinite(res.nees_full)
    ax.semilogy(t[ok], res.nees_full[ok], color="tab:purple", lw=1,
                label="average NEES (full state)")
    ax.axhline(res.bounds_full[0], color="tab:purple", ls=":", lw=1)
    ax.axhline(res.bounds_full[1], color="tab:purple", ls=":", lw=1, label="95 % bounds (8 dof)")
    if np.any(res.triggered > 0):
        ax2 = ax.twinx()
        ax2.plot(t, res.triggered, color="0.5", lw=0.8)
        ax2.set_ylabel("underweighted fraction", color="0.4")
        ax2.set_ylim(0, 1.05)
    ax.set_ylabel("NEES")
    ax.set_xlabel("time [s]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper right", fontsize=7)
    axes[0].set_title(title or f"Monte Carlo averages ({res.config.runs} runs)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

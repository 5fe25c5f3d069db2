"""The figures of the realism report (:mod:`estimator.reports.realism`; matplotlib, Agg, PNG)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from scipy import stats


def realism_figures(out: Path, first_sel: Mapping[str, Any], mc) -> None:
    """Write residuals.png, acf.png and montecarlo.png of a realism report into ``out``:
    each model's residuals and their autocorrelation on scenario B, the Monte Carlo's
    normalised errors and NEES (``mc``: :class:`estimator.reports.realism.MonteCarlo`)."""
    matplotlib.use("Agg")  # PNG files only, no window
    key = [k for k in first_sel if k.startswith("B")]
    sel, res = first_sel[key[0]] if key else next(iter(first_sel.values()))
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    scale = (100, 100, 180 / math.pi)
    units = ("x [cm]", "y [cm]", "yaw [deg]")
    for m, f in sel.fits.items():
        r = f.result
        for j in range(3):
            axes[j].plot(r.t, r.residuals[:, j] * scale[j], lw=0.6, label=m)
    for j in range(3):
        axes[j].set_ylabel(units[j])
        axes[j].grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle("Residuals of each model, scenario B (friction + bias + tilt)")
    fig.tight_layout()
    fig.savefig(out / "residuals.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2))
    for m, f in sel.fits.items():
        for j in range(3):
            axes[j].plot(f.acf[j], marker=".", lw=0.8, label=m)
    n = len(sel.fits[next(iter(sel.fits))].result.t)
    for j, lab in enumerate(("x", "y", "yaw")):
        axes[j].axhline(1.96 / math.sqrt(n), color="k", lw=0.5, ls="--")
        axes[j].axhline(-1.96 / math.sqrt(n), color="k", lw=0.5, ls="--")
        axes[j].set_title(f"residual autocorrelation, {lab}")
        axes[j].set_xlabel("lag (poses)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "acf.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    z = mc.err / mc.sigma
    axes[0].boxplot(z, tick_labels=list(mc.names))
    axes[0].axhline(3, color="r", lw=0.6, ls="--")
    axes[0].axhline(-3, color="r", lw=0.6, ls="--")
    axes[0].set_title("normalised errors (error / reported sigma)")
    axes[1].hist(mc.nees, bins=15, density=True, alpha=0.6)
    xs = np.linspace(0, max(mc.nees.max(), 1), 200)
    axes[1].plot(xs, stats.chi2.pdf(xs, len(mc.names)), "k-", lw=1,
                 label=f"chi2({len(mc.names)})")
    axes[1].set_title("per-run NEES")
    axes[1].legend()
    fig.tight_layout()
    fig.savefig(out / "montecarlo.png", dpi=110)
    plt.close(fig)

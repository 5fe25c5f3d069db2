"""Figure of a fit by segments: the residuals of every segment, the segments' borders and
the excluded stretches shaded. PNG, Agg."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from estimator.reports.plots.batch import _save

matplotlib.use("Agg")


def plot_segment_residuals(fit, path: str | Path, *, sigma=(0.01, math.radians(1.0)),
                           title: str = "") -> Path:
    """Residuals x, y (cm) and yaw (deg) against time, alternate segments in two colours,
    +/-3 stated sigma dashed, excluded stretches shaded and labelled."""
    fig, axes = plt.subplots(4, 1, figsize=(10, 8.5), sharex=True,
                             gridspec_kw={"height_ratios": [3, 3, 3, 2]})
    data = [(fit.residuals[:, 0] * 100, sigma[0] * 100, "x residual [cm]"),
            (fit.residuals[:, 1] * 100, sigma[0] * 100, "y residual [cm]"),
            (np.degrees(fit.residuals[:, 2]), math.degrees(sigma[1]), "yaw residual [deg]")]
    colours = np.where(fit.segment % 2 == 0, "tab:blue", "tab:orange")
    for ax, (r, s, lab) in zip(axes[:3], data, strict=True):
        ax.scatter(fit.t, r, c=colours, s=1.5, alpha=0.7, linewidths=0)
        for k in (-3, 3):
            ax.axhline(k * s, color="r", lw=0.8, ls="--")
        ax.axhline(0, color="k", lw=0.6)
        ax.set_ylabel(lab)
    mid = np.array([0.5 * (fit.t[fit.segment == s][0] + fit.t[fit.segment == s][-1])
                    for s in range(fit.plan.n)])
    width = np.array([fit.t[fit.segment == s][-1] - fit.t[fit.segment == s][0]
                      for s in range(fit.plan.n)])
    axes[3].bar(mid, fit.segment_rms[:, 0] * 100, width=width, color="tab:blue", alpha=0.6,
                label="x rms [cm]")
    axes[3].bar(mid, np.degrees(fit.segment_rms[:, 2]), width=width * 0.5, color="tab:green",
                alpha=0.6, label="yaw rms [deg]")
    axes[3].set_ylabel("rms per segment")
    axes[3].legend(loc="upper right", fontsize=8)
    for a, b, why in fit.plan.excluded:
        for ax in axes:
            ax.axvspan(a, b, color="r", alpha=0.12)
        axes[0].text(a, axes[0].get_ylim()[1], why.split(" (")[0].split(":")[0], fontsize=7,
                     va="top", color="darkred")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or f"Residuals by segment ({fit.plan.n} segments of {fit.plan.length_s:g} s)")
    return _save(fig, path)

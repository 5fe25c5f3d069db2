"""Plots of a characterisation run (matplotlib, Agg, PNG).

- :func:`plot_fit_orders`: paper Figure 3 style, per nozzle count the per-step mean
  thrust (error bars: standard deviation of the readings) and every order's fit,
  the selected order drawn bold.
- :func:`plot_time_series`: paper Figure 2b style, duty and balance reading against
  time over the whole session.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from bench.fit import ThrustFit

matplotlib.use("Agg")  # PNG files only, no window


def plot_fit_orders(result: ThrustFit, path: str | Path, truth=None) -> Path:
    """Figure 3 style: data and fits of each order, one panel per nozzle count.

    ``truth``: optional ThrustTable drawn dashed for comparison.
    """
    ks = sorted(result.fits)
    ncol = 2 if len(ks) > 1 else 1
    nrow = math.ceil(len(ks) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6 * ncol, 4 * nrow), squeeze=False)
    colors = {1: "tab:blue", 2: "tab:orange", 3: "tab:green", 4: "tab:purple"}
    for ax, k in zip(axes.ravel(), ks, strict=False):
        d, z, sd = result.data[k]
        dd = np.linspace(d.min(), d.max(), 200)
        for n, f in sorted(result.fits[k].items()):
            sel = n == result.selected[k]
            ax.plot(dd, f.predict(dd), color=colors.get(n, None), lw=2.5 if sel else 1.0,
                    alpha=1.0 if sel else 0.7,
                    label=f"order {n}: rms {f.rms:.2f} gf" + (" (selected)" if sel else ""))
        if truth is not None and k in truth.coefficients:
            ax.plot(dd, truth.per_nozzle(dd, k), "k--", lw=1, label="reference table")
        ax.errorbar(d, z, yerr=np.where(np.isfinite(sd), sd, 0.0), fmt="ko", ms=4, capsize=3,
                    label="step mean ± std")
        ax.set_title(f"{k} nozzle(s) open")
        ax.set_xlabel("PWM duty cycle (%)")
        ax.set_ylabel("thrust per nozzle (gf)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes.ravel()[len(ks):]:
        ax.set_visible(False)
    fig.suptitle(f"Least-squares fits of orders {', '.join(str(n) for n in sorted(result.fits[ks[0]]))} "
                 f"(selection: {result.criterion if result.order_request == 'auto' else 'fixed'})")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_time_series(raw: pd.DataFrame, path: str | Path, steps: pd.DataFrame | None = None) -> Path:
    """Figure 2b style: balance reading (gf) and commanded duty (%) against time (s).

    ``raw``: raw.csv frame; ``steps``: steps.csv frame (drift-corrected step means
    drawn as horizontal bars over each dwell).
    """
    fig, ax = plt.subplots(figsize=(12, 4.5))
    r = raw[raw["phase"] != "check"]
    t = r["t_s"].to_numpy()
    ax.plot(t, r["reading_gf"].to_numpy(), ".", ms=2, color="0.5", label="balance reading")
    unstable = r["stable"].to_numpy() == 0
    if unstable.any():
        ax.plot(t[unstable], r["reading_gf"].to_numpy()[unstable], "x", ms=3, color="tab:red",
                label="unstable (?)")
    if steps is not None and len(steps):
        for i, s in enumerate(steps.itertuples()):
            ax.hlines(s.thrust_gf, s.t_start_s, s.t_end_s, color="tab:blue", lw=2,
                      label="step mean (drift-corrected)" if i == 0 else None)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("thrust (gf)")
    ax.grid(alpha=0.3)
    ax2 = ax.twinx()
    duty = r["duty_pct"].to_numpy()
    ax2.step(t, duty, where="post", color="tab:orange", lw=1, label="duty cycle")
    ax2.set_ylabel("duty cycle (%)", color="tab:orange")
    ax2.set_ylim(0, 100)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper left", fontsize=8)
    ax.set_title("Thrust of the nozzle under test and duty cycle against time")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

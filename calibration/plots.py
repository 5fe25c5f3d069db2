"""Plots of the calibration results (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_trace_fit(fit, path: str | Path) -> Path:
    """Yaw trace, nonlinear fit and damped-sine (small-angle) fit, with residuals."""
    path = Path(path)
    t = fit.t - fit.t[0]
    off = fit.details["yaw_offset_rad"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                   gridspec_kw={"height_ratios": [2, 1]})
    ax1.plot(t, np.degrees(fit.psi - off), ".", ms=2, color="0.6", label="mocap yaw")
    ax1.plot(t, np.degrees(fit.psi_fit - off), "-", lw=1, color="C0",
             label=f"nonlinear fit: Izz = {fit.izz_kgm2:.5g} +- {fit.izz_sigma_kgm2:.2g} kg m$^2$")
    ax1.plot(t, np.degrees(fit.psi_small - off), "--", lw=0.8, color="C3",
             label=f"damped sine: Eq. 19 gives {fit.details['izz_small_angle_kgm2']:.5g} "
                   f"({100 * fit.details['amplitude_correction']:+.2f} % correction)")
    lo, hi = ax1.get_ylim()
    ax1.set_ylim(lo, hi + 0.45 * (hi - lo))  # room for the legend above the swing
    ax1.set_ylabel("yaw - equilibrium (deg)")
    ax1.legend(loc="upper right", fontsize=8)
    ax1.set_title("Bifilar pendulum: trace fit")
    ax2.plot(t, np.degrees(fit.psi - fit.psi_fit), ".", ms=2, color="C0", label="nonlinear fit")
    ax2.plot(t, np.degrees(fit.psi - fit.psi_small), ".", ms=1, color="C3", alpha=0.4,
             label="damped sine")
    # running means over ~1/8 period make systematic misfit visible under the noise
    per = fit.details["period0_s"]
    k = max(1, int(round(per / 8 / max(float(np.median(np.diff(t))), 1e-9))))
    ker = np.ones(k) / k
    for res, col, lab in ((fit.psi - fit.psi_fit, "C0", "nonlinear fit, running mean"),
                          (fit.psi - fit.psi_small, "C3", "damped sine, running mean")):
        ax2.plot(t, np.degrees(np.convolve(res, ker, mode="same")), "-", lw=1.2, color=col,
                 label=lab)
    rms = fit.details["residual_rms_deg"]
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_ylabel("residual (deg)")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="upper right", fontsize=8, title=f"fit rms {rms:.3g} deg")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_signal_fit(fit, path: str | Path) -> Path:
    """Any swing trace (yaw, gyro rate, pixels) with the reported model and the damped-sine
    (period) fit, and their residuals (:class:`calibration.swing.trace_fit.SwingFit`)."""
    path = Path(path)
    d = fit.details
    t = fit.t - fit.t[0]
    unit = {"rad": "rad", "rad/s": "rad/s", "units": "signal units"}[d["unit"]]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                   gridspec_kw={"height_ratios": [2, 1]})
    ax1.plot(t, fit.y, ".", ms=2, color="0.6", label=f"{d['signal']} trace")
    ax1.plot(t, fit.y_fit, "-", lw=1, color="C0",
             label=f"{fit.method}: Izz = {fit.izz_kgm2:.5g} +- {fit.izz_sigma_kgm2:.2g} kg m$^2$")
    ax1.plot(t, fit.y_period, "--", lw=0.8, color="C3",
             label=f"damped sine: period method {d['izz_period_kgm2']:.5g} kg m$^2$")
    lo, hi = ax1.get_ylim()
    ax1.set_ylim(lo, hi + 0.45 * (hi - lo))
    ax1.set_ylabel(unit)
    ax1.legend(loc="upper right", fontsize=8)
    ax1.set_title(f"{fit.inputs.get('suspension', 'pendulum').capitalize()} pendulum: "
                  f"{'model describes the trace' if d['model_describes_trace'] else 'model does NOT describe the trace'}")
    ax2.plot(t, fit.y - fit.y_fit, ".", ms=2, color="C0", label="reported model")
    ax2.plot(t, fit.y - fit.y_period, ".", ms=1, color="C3", alpha=0.4, label="damped sine")
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_ylabel(f"residual ({unit})")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="upper right", fontsize=8,
               title=f"rms {d['residual_rms']:.3g} = {d['residual_to_noise']:.2g} x noise")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_budget(result, path: str | Path) -> Path:
    """Bar chart of the per-input contributions to u(Izz)."""
    path = Path(path)
    items = [(k, v) for k, v in result.contributions_kgm2.items() if v > 0]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    if items:
        names, vals = zip(*items, strict=True)
        ax.barh(names, vals, color="C0")
    total = result.izz_sigma_kgm2
    ax.axvline(total, color="C3", lw=1, label=f"combined u = {total:.3g}")
    ax.set_xlabel("contribution to u(Izz), kg m$^2$")
    rel = total / result.izz_kgm2 if result.izz_kgm2 else math.nan
    ax.set_title(f"Izz = {result.izz_kgm2:.5g} kg m$^2$ ({100 * rel:.2g} %)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

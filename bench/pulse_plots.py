"""Plots of an on/off pulse fit (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from bench.pulse_fit import PulseFit, fopdt_step  # noqa: E402


def plot_pulse_edges(raw: pd.DataFrame, fit: PulseFit, path: str | Path) -> Path:
    """Left: every opening edge of each valve, aligned at its command, normalised by its
    step, with the first-order-plus-dead-time curve of the valve's mean delay and rise.
    Right: the same for the closing edges."""
    path = Path(path)
    t = raw["t_s"].to_numpy(dtype=float)
    y = raw["reading_gf"].to_numpy(dtype=float)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
    for ax, opening in zip(axes, (True, False), strict=True):
        for i, (valve, row) in enumerate(sorted(fit.valves.items())):
            kd, kr = ("delay_s", "rise_s") if opening else ("close_delay_s", "fall_s")
            col = f"C{i % 10}"
            for e in (e for e in fit.edges if e.valves == (valve,) and e.opening == opening):
                sel = (t >= e.t_command_s - 0.5) & (t < e.t_command_s + 2.5)
                y0 = np.median(y[sel & (t < e.t_command_s)]) if np.any(sel & (t < e.t_command_s)) else 0.0
                ax.plot(t[sel] - e.t_command_s, (y[sel] - y0) / e.step_gf, "-", lw=0.5,
                        color=col, alpha=0.35)
            if row.get(kd) is not None:
                x = np.linspace(-0.5, 2.5, 300)
                ax.plot(x, fopdt_step(np.array([0.0, 1.0, row[kd], row[kr]]), x, 0.0), "-", lw=2,
                        color=col, label=f"valve {valve}: {kd[:-2].replace('_', ' ')} "
                                         f"{row[kd] * 1e3:.0f} ms, {kr[:-2]} {row[kr] * 1e3:.0f} ms")
        ax.axvline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel("time from the valve command (s)")
        ax.set_title("opening edges" if opening else "closing edges")
        ax.legend(loc="lower right" if opening else "upper right", fontsize=7)
    axes[0].set_ylabel("reading change / step (held readings)")
    fig.suptitle(f"On/off pulses: readings held {fit.update_period_s * 1e3:.0f} ms "
                 f"(rows every {fit.row_period_s * 1e3:.0f} ms)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

"""Derive the per-radius swing periods of the morloy/trifilar-mass-prop test-mass series
(runs/fixtures/real/morloy-trifilar-series/) from the laser-dot pixel traces:

    python -m tests.support.morloy_series_periods SOURCE/data/Inertia runs/fixtures/real/morloy-trifilar-series

SOURCE is a checkout of https://github.com/morloy/trifilar-mass-prop at commit
f4989ebb99832d8cfb7e52de13c9e1adc3747224. Each trace ``<series>/<radius>.csv`` (tab-separated
``x y`` pixel coordinates of the dot, 240 frames per second) gives one period by
:func:`calibration.swing.pendulum_periods.swing_period` on the x coordinate; the periods of a series go
to ``periods-<series>.csv`` (``radius_m,period_s,period_sigma_s``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from calibration.swing.pendulum_periods import SwingPeriod, swing_period

FPS = 240.0
SERIES = ("5s", "10s", "20s")
RADII_M = (0.25, 0.30, 0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65, 0.70, 0.75)


def trace_period(path: str | Path) -> SwingPeriod:
    """The period of one trace file (header ``x y``, tab-separated, one row per frame)."""
    d = np.genfromtxt(path, names=True)
    x = np.asarray(d["x"], dtype=float)
    return swing_period(np.arange(len(x)) / FPS, x)


def derive(inertia_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """Write ``periods-<series>.csv`` for every series; returns the files."""
    files = []
    for s in SERIES:
        lines = ["radius_m,period_s,period_sigma_s,n_frames"]
        for r in RADII_M:
            p = trace_period(Path(inertia_dir) / s / f"{r:.2f}.csv")
            lines.append(f"{r:.2f},{p.period_s:.9f},{p.period_sigma_s:.3e},{p.n_samples}")
        f = Path(out_dir) / f"periods-{s}.csv"
        f.write_text("\n".join(lines) + "\n")
        files.append(f)
    return files


if __name__ == "__main__":  # pragma: no cover - the fixture's derivation
    for f in derive(sys.argv[1], sys.argv[2]):
        print(f"wrote {f}")

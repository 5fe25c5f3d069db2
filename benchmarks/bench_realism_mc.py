"""Realism: a 200-run Monte Carlo of the friction+tilt model (``make bench-long``).

Rows: the Monte Carlo over friction, bias and tilt values with its average NEES against the
two-sided 95 % chi-square bounds (7 parameters; m and Izz), and the spread of error/sigma.
Moved out of ``benchmarks/bench_realism.py`` (which keeps the fit's time) because it takes
minutes.
"""

from __future__ import annotations

import time

import numpy as np


def run() -> list[dict]:
    from estimator.reports.realism import monte_carlo

    rows = []
    runs = 200
    t0 = time.perf_counter()
    mc = monte_carlo(runs, seed=99, model="friction+tilt")
    elapsed = time.perf_counter() - t0
    s = mc.summary()
    lo, hi = s["nees_bounds"]
    lo2, hi2 = s["nees_mass_izz_bounds"]
    rows.append({"case": f"realism MC {runs} runs", "metric": "average NEES (7 params)",
                 "value": s["nees_mean"], "reference": float(len(mc.names)),
                 "ratio": s["nees_mean"] / len(mc.names), "ok": bool(lo < s["nees_mean"] < hi),
                 "target": f"in [{lo:.2f}, {hi:.2f}] (95 %); {elapsed:.0f} s; "
                           f"converged {s['converged']}/{runs}"})
    rows.append({"case": f"realism MC {runs} runs", "metric": "average NEES (m, Izz)",
                 "value": s["nees_mass_izz_mean"], "reference": 2.0,
                 "ratio": s["nees_mass_izz_mean"] / 2.0,
                 "ok": bool(lo2 < s["nees_mass_izz_mean"] < hi2),
                 "target": f"in [{lo2:.2f}, {hi2:.2f}] (95 %); max |bias t| "
                           f"{max(abs(v) for v in s['bias_t_stat'].values()):.2f}"})
    z = mc.err / mc.sigma
    rows.append({"case": f"realism MC {runs} runs", "metric": "std(error/sigma) m, Izz",
                 "value": float(np.std(z[:, 0], ddof=1)), "reference": float(np.std(z[:, 1], ddof=1)),
                 "ratio": 1.0, "ok": None,
                 "target": "value = mass, reference = Izz; 1 for an efficient, consistent fit"})
    return rows


if __name__ == "__main__":  # pragma: no cover
    for row in run():
        print(row)

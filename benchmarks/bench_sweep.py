"""The estimator sweep: every estimator on 300 simulated runs unlike the paper's.

Rows per method (ls, ekf, ls-ekf): the share of final errors within 4 sigma (target
>= 99 %) and the number of runs beyond 6 sigma without a flag (target 0); the time of the
whole sweep. Same as ``tpods report sweep --runs 300`` (seed 0).
"""

from __future__ import annotations

import time


def run() -> list[dict]:
    from estimator.reports.sweep import TARGET_FRACTION, run_sweep

    t0 = time.perf_counter()
    res = run_sweep(300, seed=0, workers=2)
    elapsed = time.perf_counter() - t0
    rows = []
    for method, s in res.summary().items():
        rows.append({"case": f"sweep 300 runs, {method}", "metric": "final error within 4 sigma",
                     "value": s["within_4sigma_frac"], "reference": TARGET_FRACTION,
                     "ratio": s["within_4sigma_frac"] / TARGET_FRACTION,
                     "ok": bool(s["within_4sigma_frac"] >= TARGET_FRACTION),
                     "target": f">= {TARGET_FRACTION:.0%} of runs; worst {s['worst_sigma']:.3g} "
                               f"sigma; flagged {s['flagged']}"})
        rows.append({"case": f"sweep 300 runs, {method}", "metric": "beyond 6 sigma unflagged",
                     "value": s["beyond_6sigma_unflagged"], "reference": 0, "ratio": 1.0,
                     "ok": s["beyond_6sigma_unflagged"] == 0,
                     "target": f"0; worst unflagged {s['worst_unflagged_sigma']:.3g} sigma; "
                               f"sweep {elapsed:.0f} s (2 workers)"})
    return rows

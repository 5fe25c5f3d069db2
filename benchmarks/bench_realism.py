"""Realism: cost of the jointly estimated friction+tilt fit.

Row: the batch fit of the friction+tilt model on the paper's 14 s experiment against the
ideal fit of the same run (time ratio: what the 5 extra parameters cost). The 200-run
Monte Carlo of the same model is ``benchmarks/bench_realism_mc.py`` (``make bench-long``).
"""

from __future__ import annotations

import time

from benchmarks.host import Window


def run() -> list[dict]:
    from estimator.reports.realism import TRUTH, fit_row, simulate_run

    res, cmd_t, thrust = simulate_run(TRUTH, 7)
    t_ideal, t_ext = [], []
    w = Window()
    for _ in range(2):
        t0 = time.perf_counter()
        fit_row(res, cmd_t, thrust, "ideal")
        t_ideal.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ext = fit_row(res, cmd_t, thrust, "friction+tilt")
        t_ext.append(time.perf_counter() - t0)
    w.stop()
    rows = [{"case": "friction+tilt fit 14 s", "metric": "batch LS solve time, s",
             "value": min(t_ext), "reference": min(t_ideal), "ratio": min(t_ideal) / min(t_ext),
             "ok": bool(ext.converged and min(t_ext) < 5.0),
             "target": "< 5 s from the paper's guess; reference = ideal model on the same run",
             **w.timed(ok_untimed=bool(ext.converged))}]
    return rows

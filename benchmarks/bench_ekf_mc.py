"""EKF speed, the Monte Carlo (``make bench-long``: it takes a minute or more): 500 runs x
120 s x 120 Hz, simulation included, against simulating and filtering run by run (3 runs
timed, scaled to 500). Moved out of ``benchmarks/bench_ekf.py``.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.bench_ekf import _load
from benchmarks.host import Window
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from estimator.filters.ekf import PAPER, run_ekf
from estimator.montecarlo import McConfig, run_montecarlo
from estimator.reports.ekf import first_pose_start, simulate_paper


def run() -> list[dict]:
    rows = []
    # Monte Carlo: 500 runs x 120 s x 120 Hz, against simulate + single filter per run
    cfg = McConfig(runs=500, duration_s=120.0)
    w = Window()
    t0, c0 = time.perf_counter(), time.process_time()
    mc = run_montecarlo(cfg)
    t_mc = time.perf_counter() - t0
    c_mc = time.process_time() - c0
    w.stop()
    n_sub = 3
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    for i in range(n_sub):
        m = PAPER_MASS_KG * (1 + rng.uniform(-0.5, 0.5))
        izz = PAPER_IZZ_KGM2 * (1 + rng.uniform(-0.5, 0.5))
        r = simulate_paper(120.0, i, m, izz)
        x0 = first_pose_start(PAPER, r.pose)
        x0[6:8] = (PAPER_MASS_KG, PAPER_IZZ_KGM2)
        run_ekf(r.pose_t, r.pose, r.cmd_t, r.thrust_n, PAPER, x0)
    t_loop = (time.perf_counter() - t0) / n_sub * cfg.runs
    rows.append({"case": "ekf montecarlo 500x120s", "metric": "wall time, s",
                 "value": t_mc, "reference": t_loop, "ratio": t_loop / t_mc, "ok": t_mc < 60.0,
                 "target": f"< 60 s incl. simulation ({c_mc:.0f} CPU s, {_load()}); reference: "
                           f"simulate + single filter per run, {n_sub} runs scaled to 500; "
                           f"{len(mc.t) * cfg.runs / t_mc:.3g} run-poses/s", **w.timed()})
    return rows


if __name__ == "__main__":  # pragma: no cover
    for r in run():
        print(r)

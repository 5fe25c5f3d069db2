"""Hand-written numerical routines against the library that would serve (docs/architecture.md,
"Hand-written where a library serves"): is each one still worth its code?

A routine stays hand-written only while the library costs something measured here. Rows:

1. ``common.chi2`` (the chi-square tail and quantiles) against ``scipy.special``: the CPU
   that ``import scipy.special`` adds to a fresh process that already imports numpy (the
   live estimator imports no scipy at all), median of 3 processes each. Kept while that is
   at least 50 ms; its agreement with ``scipy.stats.chi2`` is reported beside it.
2. ``estimator.filters.vec.inv_sym3`` (inverses of R symmetric 3x3 matrices by cofactors)
   against ``numpy.linalg.inv`` on R = 500 (the Monte Carlo's batch). Kept while at least
   1.25x faster.
3. The multiple-shooting solver (``estimator.shooting.solve.levenberg_marquardt``, Schur
   reduction of the block-arrow normal equations) against ``scipy.optimize.least_squares``
   (``trf`` with the same sparse Jacobian, ``lsmr``) on the paper's 120 s run by 5 s
   segments, both from the same start. Kept while at least 1.25x faster to the same mass
   (within 1e-4 relative).
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

import numpy as np

from benchmarks.host import Window

ENOUGH_IMPORT_S = 0.05
ENOUGH_SPEEDUP = 1.25


def run() -> list[dict]:
    return [_chi2(), _inv_sym3(), _shooting()]


def _cpu_of(code: str) -> float:
    """CPU seconds (user + system) of a fresh ``python -c code``, median of 3."""
    out = []
    for _ in range(3):
        r = subprocess.run([sys.executable, "-c", "import os, sys\n" + code +
                            "\nt = os.times(); print(t.user + t.system)"],
                           capture_output=True, text=True, check=True)
        out.append(float(r.stdout.split()[-1]))
    return statistics.median(out)


def _chi2() -> dict:
    from scipy import stats

    from common import chi2

    base = _cpu_of("import numpy")
    with_scipy = _cpu_of("import numpy, scipy.special")
    cost = with_scipy - base
    x = np.linspace(0.01, 80.0, 400)
    worst = 0.0
    for df in (1, 2, 3, 6, 8, 20):
        ref = stats.chi2.sf(x, df)
        worst = max(worst, float(np.max(np.abs(chi2.sf(x, df) - ref) / np.maximum(ref, 1e-300))))
    keep = cost >= ENOUGH_IMPORT_S
    return {"case": "common.chi2 against scipy.special (import cost of a fresh process)",
            "metric": "CPU s that import scipy.special adds to import numpy",
            "value": cost, "reference": base, "ratio": cost / base if base > 0 else None,
            "ok": bool(keep and worst < 1e-10),
            "target": f">= {ENOUGH_IMPORT_S * 1e3:.0f} ms to keep it; agreement with "
                      f"scipy.stats.chi2.sf {worst:.1e} relative (df 1-20, x 0.01-80)"}


def _inv_sym3() -> dict:
    from estimator.filters.vec import inv_sym3

    rng = np.random.default_rng(3)
    A = rng.normal(size=(500, 3, 3))
    S = A @ A.transpose(0, 2, 1) + 0.5 * np.eye(3)
    w = Window()
    ours = min(_timeit(lambda: inv_sym3(S)) for _ in range(5))
    lib = min(_timeit(lambda: np.linalg.inv(S)) for _ in range(5))
    w.stop()
    err = float(np.max(np.abs(inv_sym3(S) - np.linalg.inv(S))))
    ratio = lib / ours
    return {"case": "inv_sym3 against numpy.linalg.inv (500 symmetric 3x3)",
            "metric": "time per call, s", "value": ours, "reference": lib, "ratio": ratio,
            "ok": bool(ratio >= ENOUGH_SPEEDUP and err < 1e-9),
            "target": f">= {ENOUGH_SPEEDUP}x to keep it; largest difference {err:.1e}",
            **w.timed(ok_untimed=err < 1e-9)}


def _timeit(fn, n: int = 200) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n


def _paper_problem():
    from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
    from common.thrust_table import load_thrust_table
    from estimator.plant.inputs import make_input
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate
    from estimator.shooting.fit import _theta0
    from estimator.shooting.inputs import vehicle_channels
    from estimator.shooting.problem import ShootingProblem
    from estimator.shooting.segments import plan_segments
    from estimator.shooting.vehicles import module_vehicle

    cmd_t, duty = make_input("phase-sine", 120.0, 50.0, 20.0, 1.0)
    sim = simulate(cmd_t, duty, PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2),
                   config=SimConfig(seed=4))
    v = module_vehicle(load_thrust_table(None))
    ch = vehicle_channels(v, cmd_t, duty)
    plan = plan_segments(sim.pose_t, sim.pose, 5.0)
    names = ("mass", "izz")
    prob = ShootingProblem(sim.pose_t, sim.pose, plan, ch, names, {},
                           np.array([0.001, 0.001, np.radians(0.1)]))
    theta = _theta0(names, {"mass": 1.0, "izz": 0.005}, {})
    return prob, prob.initial_states(), theta


def _scipy_fit(prob, s0: np.ndarray, theta: np.ndarray):
    from scipy import sparse
    from scipy.optimize import least_squares

    S, p = prob.n_seg, len(theta)
    seg_row = np.repeat(prob.seg, 3)
    R = len(seg_row)
    rows_s = np.repeat(np.arange(R), 6)
    cols_s = (6 * seg_row[:, None] + np.arange(6)[None, :]).ravel()
    rows_g = np.repeat(np.arange(R), p)
    cols_g = np.tile(6 * S + np.arange(p), R)
    rows = np.concatenate([rows_s, rows_g])
    cols = np.concatenate([cols_s, cols_g])

    def split(x):
        return x[:6 * S].reshape(S, 6), x[6 * S:]

    def fun(x):
        s, th = split(x)
        return prob.residuals(s, th)[0]

    def jac(x):
        s, th = split(x)
        _, Js, Jg = prob.jacobian(s, th)
        return sparse.csr_matrix((np.concatenate([Js.ravel(), Jg.ravel()]), (rows, cols)),
                                 shape=(R, 6 * S + p))

    x0 = np.concatenate([s0.ravel(), theta])
    res = least_squares(fun, x0, jac=jac, method="trf", tr_solver="lsmr", x_scale="jac")
    return split(res.x)[1], res


def _shooting() -> dict:
    from estimator.shooting.solve import levenberg_marquardt

    prob, s0, theta = _paper_problem()
    w = Window()
    t0 = time.perf_counter()
    lm = levenberg_marquardt(prob, s0, theta)
    ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    th_lib, res = _scipy_fit(prob, s0, theta)
    lib = time.perf_counter() - t0
    w.stop()
    m_ours = float(prob.values(lm.theta[None])["mass"][0])
    m_lib = float(prob.values(th_lib[None])["mass"][0])
    same = bool(lm.converged and res.success and abs(m_ours - m_lib) < 1e-4 * m_ours)
    ratio = lib / ours
    return {"case": "Schur LM against scipy least_squares (trf, sparse) on 24 segments",
            "metric": "time to converge, s", "value": ours, "reference": lib, "ratio": ratio,
            "ok": bool(same and ratio >= ENOUGH_SPEEDUP),
            "target": f">= {ENOUGH_SPEEDUP}x to keep it; mass {m_ours:.5f} (ours, "
                      f"{lm.iterations} iterations) against {m_lib:.5f} (scipy, {res.nfev} "
                      "evaluations)",
            **w.timed(ok_untimed=same)}

"""Batch least squares on 120 s of 120 Hz poses: the single-module fit against a plain RK4
pass over the run (the machine's speed, measured beside it), the cost of generality (every
inactive effect given at zero), its time from the paper's guess (m = 1 kg, Izz = 0.005)
against the 2 s target, and the cost of the thrust table's consider term.

The race against ``scipy.optimize.least_squares`` on the same problem takes minutes:
``benchmarks/bench_batch_scipy.py`` (``make bench-long``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.host import Window
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import thrust_sensitivity
from estimator.batch.consider import batch_consider
from estimator.batch.crlb import make_grid
from estimator.batch.least_squares import batch_ls
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams, wrench
from estimator.plant.sim import SimConfig, simulate

# a bench fit's coefficient covariance (the demo's, 1 nozzle; gf^2, ascending powers)
_COEF_COV = [[0.0195, -1.50e-3, 3.15e-5, -1.93e-7], [-1.50e-3, 1.31e-4, -2.91e-6, 1.85e-8],
             [3.15e-5, -2.91e-6, 6.72e-8, -4.39e-10], [-1.93e-7, 1.85e-8, -4.39e-10, 2.93e-12]]


def _uncertain_table() -> ThrustTable:
    d = ThrustTable.default().to_dict()
    d["uncertainty"] = {"scale_rel": 0.01}
    d["fit"] = {"nozzles": {str(k): {"covariance": _COEF_COV} for k in range(1, 5)}}
    return ThrustTable.from_dict(d)


def _plain_rk4_pass(s0, dts, w, m, izz) -> list:
    """The machine's speed: one plain-Python RK4 pass of the ideal plant over the run's
    segments (the bench's own code, independent of the estimator's)."""
    x, y, psi, u, v, r = (float(a) for a in s0)
    out = []

    def rate(psi, u, v, r, fx, fy, mz):
        c, sn = math.cos(psi), math.sin(psi)
        return u * c - v * sn, u * sn + v * c, r, fx / m + r * v, fy / m - r * u, mz / izz

    for h, (fx, fy, mz) in zip(dts, w, strict=True):
        k1 = rate(psi, u, v, r, fx, fy, mz)
        k2 = rate(psi + h / 2 * k1[2], u + h / 2 * k1[3], v + h / 2 * k1[4], r + h / 2 * k1[5],
                  fx, fy, mz)
        k3 = rate(psi + h / 2 * k2[2], u + h / 2 * k2[3], v + h / 2 * k2[4], r + h / 2 * k2[5],
                  fx, fy, mz)
        k4 = rate(psi + h * k3[2], u + h * k3[3], v + h * k3[4], r + h * k3[5], fx, fy, mz)
        x, y, psi, u, v, r = (a + h / 6 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in
                              zip((x, y, psi, u, v, r), k1, k2, k3, k4, strict=True))
        out.append((x, y, psi, u, v, r))
    return out


FIT_TARGET_S = 0.5
"""The single-module fit's time before the centre-of-mass and structure work."""
PASSES_TARGET = 7.7
"""The fit in plain RK4 passes over the run (the machine's speed, measured beside it): 0.5 s
+10 % is 7.7 passes of 71 ms on the 2-core bench machine; the fit with every effect compiled
in (zeros included) took 8.5 before the fit was made faster, 6.1-6.3 after."""
GENERALITY_TARGET = 1.10
"""Fit with every inactive effect given at zero (friction, tilt, a centre of mass at the
tracked origin: a one-module structure) over the plain fit: inactive effects cost nothing
(the same code runs; 1.10 leaves room for the CPU time's scatter on a shared machine, an
effect compiled in with zeros costs 1.2-1.3x)."""
# every parameter beyond mass and Izz given at zero: a one-module structure whose centre of
# mass is at the tracked origin, no friction, a level table
ZERO_EFFECTS = {"ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0, "cx": 0.0, "cy": 0.0}


def _timed(fn):
    """``(result, wall s, CPU s)`` of ``fn()``."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _fit_rows(sim, repeats: int = 5) -> tuple[list[dict], float, object]:
    """The fit from the paper's guess against a plain RK4 pass (machine speed) and against
    itself with every inactive effect given at zero, each the minimum of ``repeats`` runs
    taken in turns. The ratios are of CPU times (the machine is shared: other work stretches
    the wall time of whichever case it meets); returns the rows, the fit's CPU time and the
    fit."""
    g = make_grid(sim.cmd_t, sim.thrust_n, sim.pose_t)
    dts = np.diff(g.events).tolist()
    w = wrench(g.seg_thrust).tolist()
    wall, cpu, cpu_gen, cpu_pass = [], [], [], []
    window = Window()
    for _ in range(repeats):
        fit, tw, tc = _timed(lambda: batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n))
        wall.append(tw)
        cpu.append(tc)
        gen, _, tc = _timed(lambda: batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n,
                                             fixed=ZERO_EFFECTS))
        cpu_gen.append(tc)
        _, _, tc = _timed(lambda f=fit: _plain_rk4_pass(f.z0[:6], dts, w, f.mass_kg, f.izz_kgm2))
        cpu_pass.append(tc)
    window.stop()
    tf, tg, tp = min(cpu), min(cpu_gen), min(cpu_pass)
    same = bool(np.array_equal(fit.z0, gen.z0) and np.array_equal(fit.cov, gen.cov))
    rows = [
        {"case": "batch LS 120 s @120 Hz", "metric": "single-module fit / plain RK4 pass",
         "value": tf, "reference": tp, "ratio": tf / tp,
         "ok": bool(tf / tp <= PASSES_TARGET and fit.converged),
         "target": f"<= {PASSES_TARGET:g} passes (CPU s, min of {repeats}; wall {min(wall):.3f} s, "
                   f"{FIT_TARGET_S:g} s +/- 10 % before the centre of mass; one pass over "
                   f"{len(dts)} segments {tp * 1e3:.0f} ms)",
         **window.timed(ok_untimed=bool(fit.converged))},
        {"case": "batch LS 120 s @120 Hz", "metric": "generality: inactive effects at 0 / fit",
         "value": tg, "reference": tf, "ratio": tg / tf,
         "ok": bool(tg / tf <= GENERALITY_TARGET and same),
         "target": f"<= {GENERALITY_TARGET:g}x (CPU s; ct, cr, kb, ax, ay, cx, cy given at 0: a "
                   f"one-module structure, centre of mass at the origin; estimates and "
                   f"covariance {'bit for bit' if same else 'DIFFER'})",
         **window.timed(ok_untimed=same)},
    ]
    return rows, tf, fit


SIGMA_POS_M, SIGMA_YAW_RAD = 0.01, math.radians(1.0)


def paper_run():
    """(simulated run, command times, duties): 120 s of the paper's module at 120 Hz."""
    cmd_t, duty = phase_sine(120.0, 50.0)
    truth = PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2)
    return simulate(cmd_t, duty, truth, config=SimConfig(seed=0)), cmd_t, duty


def fit_from_paper_guess(sim):
    """(result, best of 2 solve times s, the host window of the two solves)."""
    times = []
    w_far = Window()
    for _ in range(2):
        t0 = time.perf_counter()
        ours_far = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
        times.append(time.perf_counter() - t0)
    w_far.stop()
    return ours_far, min(times), w_far


def run() -> list[dict]:
    sim, cmd_t, duty = paper_run()
    sp, sy = SIGMA_POS_M, SIGMA_YAW_RAD
    fit_rows, cpu_fit, fit = _fit_rows(sim)
    ours_far, t_far, w_far = fit_from_paper_guess(sim)
    # the thrust table's uncertainty as a consider term, at most 1.5x the fit alone
    table = _uncertain_table()
    sens = thrust_sensitivity(table, duty)
    t_cons = []
    w_cons = Window()
    for _ in range(3):
        cons, _, tc = _timed(lambda: batch_consider(fit, cmd_t, sens, sigma_pos_m=sp,
                                                    sigma_yaw_rad=sy))
        t_cons.append(tc)
    tc = min(t_cons)  # CPU s, as the fit's cpu_fit
    w_cons.stop()
    ratio_c = (cpu_fit + tc) / cpu_fit
    thrust_rel = math.sqrt(cons.cov_thrust[6, 6]) / fit.mass_kg
    return fit_rows + [
        {"case": "batch LS 120 s @120 Hz", "metric": "fit + thrust consider term / fit alone",
         "value": cpu_fit + tc, "reference": cpu_fit, "ratio": ratio_c,
         "ok": bool(ratio_c <= 1.5 and np.all(np.isfinite(cons.cov_thrust))),
         "target": f"<= 1.5x (CPU s; consider {tc:.3f} s over {len(sens.names)} table parameters: "
                   f"scale_rel 1 % + a bench fit's coefficient covariance; mass thrust sigma "
                   f"{thrust_rel:.2%})",
         **w_cons.timed(ok_untimed=bool(np.all(np.isfinite(cons.cov_thrust))))},
        {"case": "batch LS 120 s @120 Hz", "metric": "solve time from paper guess, s",
         "value": t_far, "reference": 2.0, "ratio": 2.0 / t_far,
         "ok": bool(t_far < 2.0 and ours_far.converged),
         "target": f"< 2 s ({ours_far.iterations} it, converged {ours_far.converged}); "
                   "reference = the target (scipy's time and agreement: make bench-long)",
         **w_far.timed(ok_untimed=bool(ours_far.converged))},
    ]


if __name__ == "__main__":
    for row in run():
        print(row)

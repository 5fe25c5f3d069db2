"""Simulator speed against scipy's solve_ivp at equal accuracy."""

from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

from benchmarks.host import Window
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.thrust_table import ThrustTable
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams, dynamics, integrate_zoh
from estimator.plant.sim import SimConfig, pose_times, simulate


def _ivp(cmd_t, thrust, t_out, p, rtol, atol):
    kw = p.kwargs()
    cur = np.zeros(6)
    out = [cur]
    for j in range(len(cmd_t) - 1):
        a, b = cmd_t[j], cmd_t[j + 1]
        ts = t_out[(t_out > a) & (t_out <= b)]
        te = np.union1d(ts, [b])
        sol = solve_ivp(lambda _t, x, T=thrust[j]: dynamics(x, T, **kw), (a, b), cur, t_eval=te,
                        rtol=rtol, atol=atol, method="DOP853")
        cur = sol.y[:, -1]
        out.extend(sol.y.T[np.isin(te, ts)])
    return np.array(out)


def run() -> list[dict]:
    duration = 120.0
    p = PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2)
    cmd_t, duty = phase_sine(duration, 50.0)
    thrust = ThrustTable.default().thrust_n(duty)
    t_out = pose_times(0.0, duration, 120.0)
    truth = _ivp(cmd_t, thrust, t_out, p, 1e-13, 1e-14)

    w = Window()
    t0 = time.perf_counter()
    ours = integrate_zoh(np.zeros(6), cmd_t, thrust, t_out, p)
    t_ours = time.perf_counter() - t0
    err_ours = np.abs(ours[:, :3] - truth[:, :3]).max()

    # solve_ivp at a tolerance giving no better accuracy than ours
    t0 = time.perf_counter()
    ref = _ivp(cmd_t, thrust, t_out, p, 1e-8, 1e-10)
    t_ref = time.perf_counter() - t0
    err_ref = np.abs(ref[:, :3] - truth[:, :3]).max()

    t0 = time.perf_counter()
    simulate(cmd_t, duty, p, config=SimConfig())
    t_full = time.perf_counter() - t0
    w.stop()
    return [
        {"case": "sim 120 s @120 Hz", "metric": "simulated s per wall s", "value": duration / t_ours,
         "reference": duration / t_ref, "ratio": t_ref / t_ours, "ok": t_full < 2.0,
         "target": f"full simulate() < 2 s (took {t_full:.2f} s); max err ours {err_ours:.1e} m, "
                   f"solve_ivp {err_ref:.1e} m", **w.timed()},
    ]

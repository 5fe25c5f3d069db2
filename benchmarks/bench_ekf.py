"""EKF speed: the single filter against a plain filterpy loop (the Monte Carlo against
looping the single filter takes minutes: ``benchmarks/bench_ekf_mc.py``, ``make bench-long``)."""

from __future__ import annotations

import os
import time

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from benchmarks.host import Window
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from estimator.filters.ekf import PAPER, make_schedule, run_ekf
from estimator.plant.model import PlantParams, integrate_zoh, wrap_angle
from estimator.plant.sim import SimConfig, simulate
from estimator.reports.ekf import first_pose_start, simulate_paper


def _plain_filterpy(res, n_poses: int, cfg=PAPER) -> float:
    """A straightforward filterpy EKF: RK4 state propagation, F by central differences."""
    t, pose = res.pose_t[:n_poses], res.pose[:n_poses]

    def fx(z, t0, t1):
        p = PlantParams(max(z[6], 1e-6), max(z[7], 1e-9))
        s = integrate_zoh(z[:6], res.cmd_t, res.thrust_n, np.array([t0, t1]), p, max_step=0.01)
        return np.concatenate([s[-1], z[6:]])

    f = ExtendedKalmanFilter(dim_x=8, dim_z=3)
    f.x = first_pose_start(cfg, pose).reshape(8, 1)
    f.P = cfg.P0.copy()
    f.R = cfg.R
    H = np.eye(3, 8)

    def resid(a, b):
        d = a - b
        d[2] = wrap_angle(d[2])
        return d

    t0 = time.perf_counter()
    for k in range(n_poses):
        if k:
            z = f.x.ravel()
            F = np.zeros((8, 8))
            for j in range(8):
                h = 1e-6 * max(abs(z[j]), 1e-3)
                zp, zm = z.copy(), z.copy()
                zp[j] += h
                zm[j] -= h
                F[:, j] = (fx(zp, t[k - 1], t[k]) - fx(zm, t[k - 1], t[k])) / (2 * h)
            f.F = F
            f.Q = np.diag(np.asarray(cfg.q_psd) * (t[k] - t[k - 1]))
            f.x = fx(z, t[k - 1], t[k]).reshape(8, 1)
            f.P = F @ f.P @ F.T + f.Q
        f.update(pose[k].reshape(3, 1), lambda _x: H, lambda x: x[:3], R=f.R, residual=resid)
    return n_poses / (time.perf_counter() - t0)


def _single(res) -> tuple[float, float]:
    """(updates per wall second, updates per CPU second of this process), best of 2."""
    make_schedule(res.pose_t, res.cmd_t, res.thrust_n)  # warm caches
    best = (0.0, 0.0)
    for _ in range(2):
        t0, c0 = time.perf_counter(), time.process_time()
        run_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n, PAPER,
                first_pose_start(PAPER, res.pose))
        n = len(res.pose_t)
        best = max(best, (n / (time.perf_counter() - t0), n / (time.process_time() - c0)))
    return best


def _load() -> str:
    try:
        return f"load avg {os.getloadavg()[0]:.1f}"
    except OSError:
        return "load avg n/a"


def run() -> list[dict]:
    rows = []
    res = simulate_paper(120.0, 0)
    w = Window()
    ours, ours_cpu = _single(res)
    w.stop()
    ref = _plain_filterpy(res, 600)
    rows.append({"case": "ekf single 120 Hz", "metric": "pose updates per s (predict+update)",
                 "value": ours, "reference": ref, "ratio": ours / ref, "ok": ours >= 20000,
                 "limit": 20000.0, "better": "higher",
                 "target": f">= 20000 /s; {ours_cpu:.3g} per CPU s, {_load()}; reference: "
                           "filterpy EKF, numerical Jacobian (600 poses); 50 Hz commands split "
                           "1/3 of the intervals", **w.timed()})
    from estimator.plant.inputs import phase_sine

    cmd_t, duty = phase_sine(20.0, 50.0)
    fast = simulate(cmd_t, duty, PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2), config=SimConfig(pose_rate_hz=2000))
    w = Window()
    ours2, ours2_cpu = _single(fast)
    w.stop()
    rows.append({"case": "ekf single 2 kHz", "metric": "pose updates per s (predict+update)",
                 "value": ours2, "reference": ref, "ratio": ours2 / ref, "ok": ours2 >= 20000,
                 "limit": 20000.0, "better": "higher",
                 "target": f">= 20000 /s (2 kHz stream, 20 s); {ours2_cpu:.3g} per CPU s, "
                           f"{_load()}", **w.timed()})

    return rows


if __name__ == "__main__":  # pragma: no cover
    for r in run():
        print(r)


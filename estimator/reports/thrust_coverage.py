"""Does the total sigma cover the real error when the thrust table is wrong?

:func:`coverage` simulates runs whose TRUE thrusts are drawn from a table's stated
uncertainty (``thrust_sensitivity``: a draw ``dc ~ N(0, P_c)`` moves every command row's
thrusts by ``J dc``), estimates each with batch least squares on the NOMINAL table, adds the
consider covariance and counts how often the final error lies within ``k`` total sigma and
within ``k`` noise sigma. For a Gaussian error the expected fraction within 2 sigma is 0.954.
Used by the tests (200 runs) and ``make bench-long`` (more).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from common.thrust_table import ThrustTable
from common.thrust_uncertainty import thrust_sensitivity
from estimator.batch.consider import batch_consider
from estimator.batch.least_squares import batch_ls
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

INPUTS = ("phase-sine", "translate-rotate")


@dataclass
class Coverage:
    """Fractions of runs whose final (m, Izz) error lies within ``k`` sigma.

    Attributes:
        runs: number of runs; k: the multiple of sigma.
        total: (2,) within k total sigma (noise + thrust); noise: (2,) within k noise sigma.
        z_total: (runs, 2) errors in total sigmas (m, Izz).
        not_converged: runs whose fit did not converge (left out of the fractions).
    """

    runs: int
    k: float
    total: np.ndarray
    noise: np.ndarray
    z_total: np.ndarray
    not_converged: int


def coverage(table: ThrustTable, runs: int, seed: int = 0, *, duration_s: float = 15.0,
             pose_rate_hz: float = 30.0, sigma_pos_m: float = 0.003,
             sigma_yaw_rad: float = math.radians(0.5), mass_range=(0.8, 4.0),
             izz_range=(2e-3, 1e-2), k: float = 2.0, progress: bool = False,
             start_at_truth: bool = False) -> Coverage:
    """See the module doc. Runs alternate between the two inputs (30 % amplitude).
    ``start_at_truth``: each fit starts from the drawn m, Izz over the whole span (the
    tests: the converged estimates, not the path from the default guess; cheaper)."""
    rng = np.random.default_rng(seed)
    inputs = {name: make_input(name, duration_s, 50.0, 30.0, 1.0) for name in INPUTS}
    sens = {name: thrust_sensitivity(table, duty) for name, (_, duty) in inputs.items()}
    chol = {name: np.linalg.cholesky(s.covariance + 1e-30 * np.eye(len(s.names)))
            for name, s in sens.items()}
    z_total, z_noise = [], []
    bad = 0
    for i in tqdm(range(runs), desc="coverage", unit="run", disable=not progress, leave=False):
        name = INPUTS[i % 2]
        cmd_t, duty = inputs[name]
        s = sens[name]
        true_thrust = np.maximum(s.thrust_n + s.jacobian @ (chol[name] @ rng.standard_normal(len(s.names))), 0)
        m, izz = rng.uniform(*mass_range), rng.uniform(*izz_range)
        run = simulate(cmd_t, duty, PlantParams(m, izz), table,
                       SimConfig(pose_rate_hz=pose_rate_hz, noise_pos_m=sigma_pos_m,
                                 noise_yaw_rad=sigma_yaw_rad, seed=int(rng.integers(1 << 30))),
                       thrust_n=true_thrust)
        start = {"initial": {"mass": m, "izz": izz}, "horizon0_s": None} if start_at_truth else {}
        res = batch_ls(run.pose_t, run.pose, cmd_t, s.thrust_n, sigma_pos_m=sigma_pos_m,
                       sigma_yaw_rad=sigma_yaw_rad, **start)
        if not res.converged:
            bad += 1
            continue
        c = batch_consider(res, cmd_t, s, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
        err = res.z0[6:] - np.array([m, izz])
        total = np.sqrt(res.sigma[6:] ** 2 + np.diag(c.cov_thrust)[6:])
        z_total.append(err / total)
        z_noise.append(err / res.sigma[6:])
    zt, zn = np.array(z_total), np.array(z_noise)
    return Coverage(runs, k, np.mean(np.abs(zt) < k, axis=0), np.mean(np.abs(zn) < k, axis=0),
                    zt, bad)

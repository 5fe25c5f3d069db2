"""The noise variance behind a fitted table's covariance (bench/fit.py ``pool_noise``):
the stated sigma of the table at a duty must be the rms of its error over repeated benches.

Before: a cubic on 9 steps stated ``s^2 (H^T H)^-1`` with ``s^2`` from 5 residual dof, so
the error over the stated sigma was Student-t(5): rms 1.29 and |z| > 2 in 10 % of fits; a
cubic on 5 steps (the quick bench) left 1 dof, a Cauchy error over sigma."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bench.fit import fit_steps
from common.thrust_table import ThrustTable

TABLE = ThrustTable.default()
PROBE = np.array([15.0, 20.0, 25.0, 50.0, 80.0])


def _z(duties, noise_gf, order, reps, seed=0):
    """(reps, 4 counts, probes) error of the fitted table over its stated sigma."""
    rng = np.random.default_rng(seed)
    out, notes = [], set()
    for _ in range(reps):
        rows = [(k, d, t + noise_gf(k) * rng.standard_normal())
                for k in (1, 2, 3, 4)
                for d, t in zip(duties, TABLE.per_nozzle(duties, k), strict=True)]
        fit = fit_steps(pd.DataFrame(rows, columns=["n_open", "duty_pct", "thrust_gf"]), order)
        notes.add(fit.noise["note"])
        zz = []
        for k in (1, 2, 3, 4):
            f = fit.fits[k][fit.selected[k]]
            h = PROBE[:, None] ** np.arange(f.order + 1)
            sd = np.sqrt(np.einsum("ij,jk,ik->i", h, f.covariance, h))
            zz.append((h @ f.coefficients - TABLE.per_nozzle(PROBE, k)) / sd)
        out.append(zz)
    return np.array(out), notes


@pytest.mark.parametrize("duties, order", [(np.arange(10.0, 91.0, 10.0), 3),
                                           (np.arange(10.0, 91.0, 10.0), "auto"),
                                           (np.arange(10.0, 91.0, 20.0), 3)])
def test_stated_sigma_is_the_rms_error(duties, order):
    z, notes = _z(duties, lambda k: 0.05, order, 300)
    rms = np.sqrt(np.mean(z ** 2))
    # 300 x 20 correlated z; the old s^2 gave 1.29 (5 dof) or a Cauchy (1 dof)
    assert 0.9 < rms < 1.12, rms
    assert 0.03 < np.mean(np.abs(z) > 2.0) < 0.075
    assert all("scaled by nu/(nu-2)" in n for n in notes)


def test_counts_with_enough_dof_keep_their_own_variance():
    """Noise growing with the count (1x to 4x): each count's own variance, each covered."""
    z, notes = _z(np.arange(10.0, 91.0, 10.0), lambda k: 0.02 * k, 3, 300, seed=1)
    rms_k = np.sqrt(np.mean(z ** 2, axis=(0, 2)))
    assert np.all((rms_k > 0.88) & (rms_k < 1.15)), rms_k
    assert all(n.startswith("each nozzle count's own residual variance") for n in notes)


def test_quick_bench_pools_and_reports_it():
    fit = fit_steps(pd.DataFrame(
        [(k, d, t + 0.05 * e) for k in (1, 2, 3, 4)
         for d, t, e in zip((10.0, 30.0, 50.0, 70.0, 90.0),
                            TABLE.per_nozzle(np.array([10.0, 30.0, 50.0, 70.0, 90.0]), k),
                            np.random.default_rng(2).standard_normal(5), strict=True)],
        columns=["n_open", "duty_pct", "thrust_gf"]), 3)
    assert fit.noise["pooled"] and fit.noise["nozzles"]["1"]["dof"] == 4
    assert fit.noise["nozzles"]["1"]["t_inflation"] == pytest.approx(2.0)
    assert fit.table().extra["fit"]["noise"]["pooled"] is True

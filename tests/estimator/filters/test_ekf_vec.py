"""Vectorised filter against the filterpy filter; the Monte Carlo's truth and consistency."""

from __future__ import annotations

import numpy as np

from estimator.filters.ekf import PAPER, run_filterpy
from estimator.filters.vec import run_ekf_vec
from estimator.montecarlo import (
    MC_FILTER,
    McConfig,
    TruthStream,
    make_scenario,
    nees_bounds,
    run_montecarlo,
)
from estimator.plant.model import PlantParams, integrate_zoh
from estimator.reports.ekf import first_pose_start
from tests.support.sim import on_grid


def test_vectorised_filter_equals_filterpy(runs_mixed):
    cfg = PAPER.with_(underweight=0.7)
    grids = [on_grid(r) for r in runs_mixed]
    t = grids[0][0]
    pose = np.stack([g[1] for g in grids])
    mask = np.stack([g[2] for g in grids])
    x0 = np.stack([first_pose_start(cfg, r.pose) for r in runs_mixed])
    x0[1, 6:8] = (1.7, 2.9e-3)  # different starts per run
    vec = run_ekf_vec(t, pose, mask, runs_mixed[0].cmd_t, runs_mixed[0].thrust_n, cfg, x0)
    for i, r in enumerate(runs_mixed):
        ref = run_filterpy(t, pose[i], r.cmd_t, r.thrust_n, cfg, x0[i], use=mask[i])
        np.testing.assert_allclose(vec.x[i], ref.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(vec.sigma[i], ref.sigma, rtol=1e-8, atol=1e-15)
        np.testing.assert_array_equal(vec.triggered[i], ref.triggered)
        np.testing.assert_allclose(vec.nis[i], ref.nis, rtol=1e-7)
        assert not mask[i].all()


def test_streamed_truth_equals_integrate_zoh():
    cfg = McConfig(runs=3, duration_s=5.0, noise_pos_m=0.0, noise_yaw_rad=0.0,
                   truth_max_step_s=1 / 480)
    t, cmd_t, thrust = make_scenario(cfg)
    truth = np.array([[2.0, 3e-3], [1.2, 2e-3], [3.1, 6e-3]])
    s0 = np.array([[0.0] * 6, [0.05, -0.02, 0.1, 0.01, 0.0, 0.02], [0.0, 0.0, 1.0, 0.0, 0.05, 0.0]])
    stream = TruthStream(cfg, t, cmd_t, thrust, truth, s0, np.random.default_rng(0))
    got = np.stack([stream.advance(k)[0].copy() for k in range(len(t))], axis=1)
    for i in range(3):
        ref = integrate_zoh(s0[i], cmd_t, thrust, t, PlantParams(*truth[i]))
        np.testing.assert_allclose(got[i], ref, rtol=0, atol=1e-10)


def test_nees_bounds():
    lo, hi = nees_bounds(40, 2)
    assert 1.3 < lo < 2 < hi < 2.8


def test_small_monte_carlo_ls_ekf_handoff_is_consistent():
    """40 runs x 20 s, m and Izz within +/-50 %: LS start, then the filter (each pose once)."""
    cfg = McConfig(runs=40, duration_s=20.0, method="ls-ekf", ls_start="handoff",
                   ls_window_s=8.0, seed=11, filter=MC_FILTER)
    res = run_montecarlo(cfg)
    lo, hi = res.bounds_param
    after = res.t > 8.0
    # the time-averaged average NEES lies inside the 95 % bounds ...
    assert lo <= np.mean(res.nees_param[after]) <= hi
    # ... and so does the average NEES at most times
    assert res.nees_inside("param", 8.0) > 0.85
    assert res.ls_failed == 0
    assert np.all(res.within_3sigma() >= 0.9)
    # bias small against the spread
    assert np.all(np.abs(res.bias[-1, 6:8]) < 3 * res.std[-1, 6:8] / np.sqrt(40) + 1e-12)


def test_small_monte_carlo_ekf_is_consistent_near_the_truth():
    """EKF alone, m and Izz within +/-10 %: average NEES inside the 95 % bounds."""
    cfg = McConfig(runs=40, duration_s=20.0, spread=0.1, seed=5, drop=0.1, filter=MC_FILTER)
    res = run_montecarlo(cfg)
    lo, hi = res.bounds_param
    assert lo <= np.mean(res.nees_param) <= hi
    # slightly over-confident at times (seeds 0-5 give 69-100 % of times inside)
    assert res.nees_inside("param") > 0.5
    assert np.all(res.within_3sigma() >= 0.9)


def test_fused_batch_physics_matches_model():
    from estimator.filters.ekf import _JAC_POS, propagate
    from estimator.filters.vec import propagate_batch, rhs_batch, rhs_jac_batch
    from estimator.plant.model import dynamics, jac_params, jac_state, wrench

    rng = np.random.default_rng(2)
    s = rng.normal(size=(7, 6))
    s[0, 3:5] = 0.0  # zero speed: the kb term's derivative is taken as 0
    m, izz = rng.uniform(0.5, 4, 7), rng.uniform(1e-3, 8e-3, 7)
    thr = rng.uniform(0, 0.4, 4)
    for known in ((0.0,) * 5, (0.05, 2e-4, 1e-3, 0.01, -0.02)):
        kw = dict(zip(("ct", "cr", "kb", "ax", "ay"), known, strict=True))
        sd, jac = rhs_jac_batch(s, wrench(thr), m, izz, known)
        np.testing.assert_allclose(sd, dynamics(s, thr, m, izz, **kw), rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(rhs_batch(s, wrench(thr), m, izz, known), sd, rtol=1e-15)
        full = np.zeros((7, 8, 8))
        full[:, :6, :6] = jac_state(s, thr, m, izz, **kw)
        full[:, :6, 6:] = jac_params(s, thr, m, izz, **kw, names=("mass", "izz"))
        ours = np.zeros((7, 8, 8))
        for q, (i, j) in enumerate(_JAC_POS):
            ours[:, i, j] = jac[:, q]
        np.testing.assert_allclose(ours, full, rtol=1e-12, atol=1e-12)
        x = np.column_stack([s * 0.1, m, izz])
        segs, ws = [0.004, 0.0045], [tuple(wrench(thr)), tuple(wrench(thr[::-1]))]
        xb, pb = propagate_batch(x, segs, ws, known)
        for r in range(7):
            xr, pr = propagate(x[r], segs, ws, known)
            np.testing.assert_allclose(xb[r], xr, rtol=1e-13, atol=1e-15)
            np.testing.assert_allclose(pb[r], pr, rtol=1e-11, atol=1e-13)


def test_monte_carlo_statistics_match_the_runs():
    """Streamed sums give the same bias, sample std and filter sigma as the stored runs."""
    res = run_montecarlo(McConfig(runs=6, duration_s=2.0, seed=3, n_examples=6))
    np.testing.assert_allclose(res.bias[:, 6:8], res.ex_err.mean(axis=0), atol=1e-15)
    np.testing.assert_allclose(res.std[:, 6:8], res.ex_err.std(axis=0, ddof=1), rtol=1e-8,
                               atol=1e-12)
    np.testing.assert_allclose(res.sigma[:, 6:8], np.sqrt((res.ex_sigma**2).mean(axis=0)),
                               rtol=1e-12)
    np.testing.assert_allclose(res.final_err[:, 6:8], res.ex_err[:, -1], rtol=0, atol=0)


def test_monte_carlo_interrupt_keeps_the_statistics_so_far():
    def stop(k):
        if k >= 479:
            raise KeyboardInterrupt

    res = run_montecarlo(McConfig(runs=4, duration_s=6.0, seed=1), on_step=stop)
    assert res.interrupted
    assert len(res.t) == 479 and res.bias.shape == (479, 8) and res.ex_err.shape[1] == 479
    np.testing.assert_allclose(res.final_err[:, 6:8], res.ex_err[:, -1])
    assert res.summary()["interrupted"] and np.all(np.isfinite(res.rmse))

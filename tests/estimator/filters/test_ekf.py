"""The single filter: Jacobians and STM, filterpy vs lean path, P, underweighting, 3 sigma."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.filters.ekf import (
    _JAC_POS,
    NX,
    PAPER,
    TpodsEKF,
    _rhs_jac,
    ekf_update,
    estimate_filter,
    propagate,
    run_ekf,
    run_filterpy,
    uw_ratio,
)
from estimator.plant.model import dynamics, jac_params, jac_state, wrench
from estimator.plant.propagate import rk4_stm
from estimator.reports.ekf import first_pose_start
from tests.support.sim import on_grid, sim_run

KNOWN = (0.05, 2e-4, 1e-3, 0.01, -0.02)  # ct, cr, kb, ax, ay


def test_scalar_jacobian_matches_model():
    rng = np.random.default_rng(0)
    for k in range(20):
        s = rng.normal(size=6)
        if k == 0:
            s[3:5] = 0.0  # zero speed: the kb term's derivative is taken as 0
        thr = rng.uniform(0, 0.4, 4)
        m, izz = rng.uniform(0.5, 4), rng.uniform(1e-3, 8e-3)
        kw = dict(mass=m, izz=izz, ct=KNOWN[0], cr=KNOWN[1], kb=KNOWN[2], ax=KNOWN[3], ay=KNOWN[4])
        full = np.zeros((NX, NX))
        full[:6, :6] = jac_state(s, thr, **kw)
        full[:6, 6:] = jac_params(s, thr, **kw, names=("mass", "izz"))
        ours = np.zeros((NX, NX))
        vals = []
        sdot = _rhs_jac(s[2], s[3], s[4], s[5], *wrench(thr), m, izz, *KNOWN, vals)
        np.testing.assert_allclose(sdot, dynamics(s, thr, **kw), rtol=1e-13, atol=1e-13)
        for (i, j), v in zip(_JAC_POS, vals, strict=True):
            ours[i, j] = v
        np.testing.assert_allclose(ours, full, rtol=1e-12, atol=1e-12)


def test_propagate_equals_rk4_stm_over_segments():
    rng = np.random.default_rng(1)
    z = np.array([0.1, -0.2, 0.4, 0.05, -0.03, 0.6, 1.9, 3.1e-3])
    dts = [0.003, 0.0, 0.012]  # a zero-length segment and one split by max_step
    thr = [rng.uniform(0, 0.4, 4) for _ in dts]
    z1, phi = propagate(z, dts, [tuple(wrench(t)) for t in thr], KNOWN, max_step_s=0.005)
    params = dict(mass=z[6], izz=z[7], ct=KNOWN[0], cr=KNOWN[1], kb=KNOWN[2], ax=KNOWN[3],
                  ay=KNOWN[4])
    s, ref = z[:6], np.eye(NX)
    for dt, t in zip(dts, thr, strict=True):
        if dt > 0:
            s, p = rk4_stm(s, t, dt, params, ("mass", "izz"), n_sub=math.ceil(dt / 0.005 - 1e-9))
            ref = p @ ref
    np.testing.assert_allclose(z1[:6], s, rtol=0, atol=1e-14)
    np.testing.assert_allclose(phi, ref, rtol=1e-11, atol=1e-13)
    # and the transition matrix is the derivative of the propagation
    num = np.zeros((NX, NX))
    for j in range(NX):
        h = 1e-6 * max(abs(z[j]), 1e-3)
        zp, zm = z.copy(), z.copy()
        zp[j] += h
        zm[j] -= h
        ws = [tuple(wrench(t)) for t in thr]
        num[:, j] = (propagate(zp, dts, ws, KNOWN, 0.005)[0] - propagate(zm, dts, ws, KNOWN, 0.005)[0]) / (2 * h)
    np.testing.assert_allclose(phi, num, rtol=1e-5, atol=1e-6)


def test_lean_filter_equals_filterpy(runs_mixed):
    cfg = PAPER.with_(underweight=1.0)
    for res in runs_mixed:
        x0 = first_pose_start(cfg, res.pose)
        a = run_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n, cfg, x0)
        b = run_filterpy(res.pose_t, res.pose, res.cmd_t, res.thrust_n, cfg, x0)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a.sigma, b.sigma, rtol=1e-8, atol=1e-15)
        np.testing.assert_array_equal(a.triggered, b.triggered)
        np.testing.assert_allclose(a.nis, b.nis, rtol=1e-7)
        assert a.triggered.any()  # the first updates (P0 >> R) are underweighted


def test_filterpy_class_uses_column_vectors_and_wrapped_yaw():
    f = TpodsEKF(PAPER, x0=np.array([0, 0, math.pi - 0.01, 0, 0, 0, 2.0, 4e-3]))
    f.update_pose([0.0, 0.0, -math.pi + 0.01])  # 0.02 rad across the wrap, not -2 pi
    assert f.x.shape == (NX, 1)
    assert abs(f.y[2, 0] - 0.02) < 1e-12
    assert abs(f.x[2, 0] - (math.pi - 0.01)) < 0.02


def test_covariance_stays_symmetric_positive_definite():
    res = sim_run(1.8, 3.0e-3, seed=4, duration=60.0, drop=0.1)
    r = run_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n, PAPER,
                first_pose_start(PAPER, res.pose), keep_cov=True)
    cov = r.cov
    assert np.abs(cov - np.swapaxes(cov, 1, 2)).max() <= 1e-12 * np.abs(cov).max()
    # PD in scaled coordinates (the diagonal spans 12 orders of magnitude)
    d = np.sqrt(np.einsum("kii->ki", cov))
    corr = cov / (d[:, :, None] * d[:, None, :])
    assert np.linalg.eigvalsh(corr)[:, 0].min() > 0


@pytest.mark.parametrize("mass,izz,seed", [(1.3, 2.1e-3, 0), (2.268, 3.78e-3, 1), (3.4, 5.7e-3, 2)])
def test_ls_ekf_final_within_3_sigma_and_beats_ekf(mass, izz, seed):
    res = sim_run(mass, izz, seed, duration=30.0, drop=0.05)
    truth = np.array([mass, izz])
    ekf = estimate_filter(res.pose_t, res.pose, res.cmd_t, res.thrust_n, "ekf", PAPER,
                          x0=first_pose_start(PAPER, res.pose)).result
    for start in ("reuse", "handoff"):
        ls = estimate_filter(res.pose_t, res.pose, res.cmd_t, res.thrust_n, "ls-ekf", PAPER,
                             ls_window_s=8.0, ls_start=start).result
        assert np.all(np.abs(ls.x[-1, 6:8] - truth) <= 3 * ls.sigma[-1, 6:8]), start
        assert np.all(np.array(ls.rmse(mass, izz)) < np.array(ekf.rmse(mass, izz))), start


@pytest.mark.parametrize("mass,izz,seed", [(1.3, 2.1e-3, 3), (2.268, 3.78e-3, 4), (3.4, 5.7e-3, 5)])
def test_ekf_final_within_3_sigma_from_a_fair_start(mass, izz, seed):
    """EKF alone, started 8 % off with a matching sigma, handling drops and yaw wraps."""
    res = sim_run(mass, izz, seed, duration=30.0, drop=0.1)
    truth = np.array([mass, izz])
    x0 = first_pose_start(PAPER, res.pose)
    x0[6:8] = truth * 0.92
    cfg = PAPER.with_(sigma0=PAPER.sigma0[:6] + (0.1 * mass, 0.1 * izz))
    r = run_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n, cfg, x0)
    assert np.ptp(res.states[:, 2]) > 2 * math.pi  # the yaw wrapped in the measurements
    assert np.all(np.abs(r.x[-1, 6:8] - truth) <= 3 * r.sigma[-1, 6:8])
    assert not r.diverged and not r.inconsistent


def test_non_uniform_times_and_fast_or_slow_commands():
    for pose_rate, cmd_rate in ((30.0, 100.0), (240.0, 10.0)):
        res = sim_run(2.0, 3.3e-3, seed=7, duration=20.0, pose_rate=pose_rate, cmd_rate=cmd_rate)
        rng = np.random.default_rng(0)
        keep = np.sort(rng.choice(len(res.pose_t), size=len(res.pose_t) * 2 // 3, replace=False))
        keep[0] = 0
        t, pose = res.pose_t[keep], res.pose[keep]
        assert np.ptp(np.diff(t)) > 0  # irregular spacing
        x0 = first_pose_start(PAPER, pose)
        x0[6:8] = (1.9, 3.1e-3)
        cfg = PAPER.with_(sigma0=PAPER.sigma0[:6] + (0.2, 3e-4))
        r = run_ekf(t, pose, res.cmd_t, res.thrust_n, cfg, x0)
        assert np.all(np.abs(r.x[-1, 6:8] - [2.0, 3.3e-3]) <= 3 * r.sigma[-1, 6:8])
        assert 1.5 < np.nanmean(r.nis) < 6


def test_dropped_frames_equal_masked_updates():
    res = sim_run(2.5, 4e-3, seed=8, duration=6.0, drop=0.3)
    t, pose, mask = on_grid(res)
    a = run_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n)
    b = run_ekf(t, pose, res.cmd_t, res.thrust_n, use=mask)
    # same data; only the RK4 step boundaries differ
    np.testing.assert_allclose(a.x[-1], b.x[-1], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(a.sigma[-1], b.sigma[-1], rtol=1e-4)


def _prior(scale):
    rng = np.random.default_rng(3)
    A = rng.normal(size=(NX, NX))
    P = A @ A.T * 1e-6 + np.eye(NX) * 1e-6
    P[:3, :3] *= scale
    return P


def test_underweighting_changes_the_update_only_while_triggered():
    z = np.array([0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 2.0, 4e-3])
    meas = [0.01, -0.02, 0.12]
    # the additive (direct) form: the closed-form check below is of the gain itself
    on = PAPER.with_(underweight=0.5, uw_trigger=1.0, param_form="direct")
    off = PAPER.with_(underweight=0.0, param_form="direct")
    small, large = _prior(1.0), _prior(1e4)
    assert uw_ratio(small, PAPER.R) < 1.0 < uw_ratio(large, PAPER.R)
    # the closed-form trigger equals the eigenvalue definition
    w = 1 / np.sqrt(np.diag(PAPER.R))
    assert math.isclose(uw_ratio(large, PAPER.R),
                        np.linalg.eigvalsh(large[:3, :3] * np.outer(w, w))[-1], rel_tol=1e-9)
    # not triggered: bit-identical to the plain update
    za, Pa, (_, ta) = ekf_update(z, small, meas, on)
    zb, Pb, _ = ekf_update(z, small, meas, off)
    assert not ta
    np.testing.assert_array_equal(za, zb)
    np.testing.assert_array_equal(Pa, Pb)
    # triggered: the gain uses (1 + alpha) HPH^T + R, Joseph form
    za, Pa, (_, ta) = ekf_update(z, large, meas, on)
    zb, Pb, _ = ekf_update(z, large, meas, off)
    assert ta
    assert not np.allclose(za, zb)
    H = np.eye(3, NX)
    K = large @ H.T @ np.linalg.inv(1.5 * H @ large @ H.T + PAPER.R)
    y = np.array(meas) - z[:3]
    np.testing.assert_allclose(za, z + K @ y, rtol=1e-10, atol=1e-15)
    A = np.eye(NX) - K @ H
    np.testing.assert_allclose(Pa, A @ large @ A.T + K @ PAPER.R @ K.T, rtol=1e-9, atol=1e-18)
    # underweighting keeps more uncertainty than the plain update
    assert np.all(np.diag(Pa) >= np.diag(Pb) * (1 - 1e-12))
    # the filterpy class agrees in both regimes
    for P in (small, large):
        f = TpodsEKF(on, x0=z, P0=P)
        f.update_pose(meas)
        zr, Pr, (_, tr) = ekf_update(z, P, meas, on)
        assert f.triggered == tr
        np.testing.assert_allclose(f.x.ravel(), zr, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(f.P, Pr, rtol=1e-8, atol=1e-18)


def test_initial_rates_from_poses():
    from estimator.filters.ekf import initial_rates

    res = sim_run(2.0, 3.3e-3, seed=9, duration=12.0)
    for t0 in (3.0, 8.0):
        k = np.searchsorted(res.pose_t, t0)
        rates, sig = initial_rates(res.pose_t[k:], res.pose[k:])
        assert np.all(np.abs(rates - res.states[k, 3:6]) <= 4 * sig + 0.02)
        assert np.all(sig < 0.1)


def test_broken_down_covariance_is_diverged_and_reported_without_a_crash():
    """A filter that blew up (a sweep: 0.45 kg, 30 % drops, 0.8 mm poses from the 1 kg guess)
    ended with a negative Izz variance; to_dict raised a math domain error (a traceback in
    ``estimate batch --method ekf``). Now: no sigma (NaN) and ``diverged``."""
    res = sim_run(1.9, 3.2e-3, seed=1, duration=2.0)
    fe = estimate_filter(res.pose_t, res.pose, res.cmd_t, res.thrust_n, "ekf", PAPER,
                         x0=first_pose_start(PAPER, res.pose))
    assert not fe.result.diverged
    P = fe.result.P.copy()
    P[7, 7] = -5e-42
    fe.result.P = P
    d = fe.to_dict()
    assert d["diverged"] is True
    assert math.isnan(d["izz_sigma_kgm2"]) and d["corr_mass_izz"] is None
    assert d["mass_sigma_kg"] == pytest.approx(math.sqrt(P[6, 6]))


def test_extended_filter_with_a_negative_variance_is_diverged():
    """The extended filter clamps a negative variance to a zero sigma; it must not pass as
    a converged estimate with sigma 0."""
    from estimator.filters.ext import ExtEkfConfig, run_ext_ekf

    res = sim_run(1.9, 3.2e-3, seed=1, duration=2.0)
    r = run_ext_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n,
                    ExtEkfConfig(names=("mass", "izz")))
    assert not r.diverged
    r.P = r.P.copy()
    r.P[7, 7] = -1e-40
    assert r.diverged and r.to_dict()["diverged"] is True


def test_ls_ekf_names_the_parameter_its_window_cannot_determine():
    """LS window without torque (translate-then-rotate, first 6 s): Izz has an infinite
    variance. ls-ekf refused with 'non-physical start (mass or Izz <= 0)', which was not the
    reason (found by a parameter sweep)."""
    from common.errors import UserError
    from estimator.plant.inputs import translate_rotate
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate

    cmd_t, duty = translate_rotate(6.0, 50.0)
    sim = simulate(cmd_t, duty, PlantParams(1.5, 6e-3), config=SimConfig(seed=3))
    with pytest.raises(UserError, match=r"do not determine izz.*--ls-window") as exc:
        estimate_filter(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n, "ls-ekf", PAPER)
    assert "non-physical" not in str(exc.value)


def test_extended_filter_that_blows_up_stops_with_nan_not_a_traceback():
    """The 7-parameter filter from its default prior on a light module (0.35 kg, Izz 8e-4,
    friction, 1 mm / 0.3 deg poses) overflows; the yaw wrap of the next update raised
    'math domain error' (a traceback from ``estimate batch --method ekf --model
    friction+tilt``; found by a parameter sweep). Now: NaN from the blow-up on, diverged,
    and no numpy warnings on the terminal."""
    import warnings

    from estimator.filters.ext import ExtEkfConfig, run_ext_ekf
    from estimator.plant.inputs import translate_rotate
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate

    cmd_t, duty = translate_rotate(10.0, 50.0)
    sim = simulate(cmd_t, duty, PlantParams(0.35, 8e-4, ct=0.1, cr=3e-4, kb=1e-3),
                   config=SimConfig(noise_pos_m=0.001, noise_yaw_rad=math.radians(0.3), seed=3))
    # the direct form (m, Izz corrected additively) blows up here; the inverse form, the
    # default since issue 17, stays finite but is still flagged diverged
    cfg = ExtEkfConfig(names=("mass", "izz", "ct", "cr", "kb", "ax", "ay"),
                       sigma_meas=(0.001, 0.001, math.radians(0.3)), param_form="direct")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = run_ext_ekf(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n, cfg)
        inv = run_ext_ekf(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n,
                          ExtEkfConfig(names=cfg.names, sigma_meas=cfg.sigma_meas))
    assert r.diverged and r.to_dict()["diverged"] is True
    assert np.isnan(r.x[-1]).all()
    assert np.isfinite(r.x[0]).all()  # the start is kept
    assert inv.diverged and np.isfinite(inv.x[-1]).all()

"""The extended-state EKF: same filter as the 8-state one when only m, Izz are estimated,
consistent with friction estimated when started by batch LS."""

import math

import numpy as np
import pytest

from estimator.filters.ekf import PAPER, run_ekf
from estimator.filters.ext import ExtEkfConfig, estimate_ext, joseph_update, run_ext_ekf
from estimator.plant.parameter_sets import MODELS
from estimator.reports.realism import FRICTION, IZZ_KGM2, MASS_KG, simulate_run, truth_params


@pytest.fixture(scope="module")
def friction_run():
    return simulate_run(FRICTION, 41, duration_s=14.0)


def test_matches_the_8_state_filter(friction_run):
    res, cmd_t, thrust = friction_run
    cfg8 = PAPER.with_(q_psd=(0.0,) * 8, **FRICTION)
    x0 = np.array(cfg8.x0)
    x0[:3] = res.pose[0]
    x0[6:] = (0.9, 1.5e-3)
    P0 = np.diag(np.square([0.1, 0.1, math.radians(5), 0.1, 0.1, math.radians(2), 0.3, 5e-4]))
    a = run_ekf(res.pose_t, res.pose, cmd_t, thrust, cfg8, x0, P0)
    cfg = ExtEkfConfig(names=("mass", "izz"), fixed=FRICTION)
    b = run_ext_ekf(res.pose_t, res.pose, cmd_t, thrust, cfg, x0, P0)
    # same filter to round-off (in units of the filter's own sigma). (With process noise
    # the two differ slightly: ekf adds Q dt once per pose interval, this filter per segment.)
    assert np.max(np.abs(b.x - a.x) / a.sigma) < 1e-8
    np.testing.assert_allclose(b.sigma, a.sigma, rtol=1e-9)
    np.testing.assert_allclose(b.nis[1:], a.nis[1:], rtol=1e-7)


def test_joseph_update_wraps_yaw_and_keeps_P_symmetric():
    z = np.array([0.0, 0.0, math.pi - 0.01, 0, 0, 0, 1.0, 1e-3])
    P = np.diag([1e-2, 1e-2, 1e-2, 1, 1, 1, 1, 1e-6])
    z1, P1, nis = joseph_update(z, P, [0.0, 0.0, -math.pi + 0.01], np.diag([1e-4, 1e-4, 1e-4]))
    assert abs(z1[2] - (math.pi + 0.0098)) < 1e-3  # moved across +pi, not back by 2 pi
    assert nis < 1.0
    np.testing.assert_allclose(P1, P1.T)
    assert np.all(np.linalg.eigvalsh(P1) > 0)


def test_ls_ekf_friction_within_3_sigma(friction_run):
    res, cmd_t, thrust = friction_run
    r, ls = estimate_ext(res.pose_t, res.pose, cmd_t, thrust,
                         ExtEkfConfig(names=MODELS["friction"]), "ls-ekf", ls_window_s=10.0,
                         ls_start="handoff")
    assert ls.converged
    tp = truth_params(FRICTION)
    for n in r.names:
        v, s = r.final(n)
        assert abs(v - tp[n]) < 3 * s, (n, v, tp[n], s)
    assert not r.diverged
    assert r.updated.sum() == np.sum(res.pose_t > res.pose_t[0] + 10.0)  # each pose used once
    rm, ri = r.rmse(MASS_KG, IZZ_KGM2)
    assert rm < 0.05 * MASS_KG and ri < 0.05 * IZZ_KGM2
    assert np.all(np.linalg.eigvalsh(r.P) > 0)


def test_config_refusals():
    with pytest.raises(ValueError):
        ExtEkfConfig(names=("ct", "cr"))
    with pytest.raises(ValueError):
        ExtEkfConfig(names=("mass", "izz", "drag"))
    with pytest.raises(ValueError):
        ExtEkfConfig(q_psd={"ax": 1.0})  # ax is not estimated by the default friction model

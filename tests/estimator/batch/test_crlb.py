"""Sensitivities, Fisher information and the CRLB against independent finite differences."""

import math

import numpy as np
import pytest

from estimator.batch.crlb import (
    chain_stm,
    crlb,
    fisher_information,
    make_grid,
    marginal_information,
    reference_states,
    sensitivities,
    trajectory_stm,
)
from estimator.plant.inputs import phase_sine, translate_rotate
from estimator.plant.model import PlantParams, integrate_zoh
from estimator.plant.propagate import rk4_stm
from estimator.plant.sim import pose_times

NAMES = ("mass", "izz")


def _setup(duration=6.0, cmd_rate=50.0, pose_rate=120.0, input_="sine"):
    if input_ == "sine":
        cmd_t, duty = phase_sine(duration, cmd_rate)
    else:
        cmd_t, duty = translate_rotate(duration, cmd_rate)
    from common.thrust_table import ThrustTable

    thrust = ThrustTable.default().thrust_n(duty)
    t = pose_times(0.0, duration, pose_rate)
    return cmd_t, thrust, t


def _fd_outputs(z, cmd_t, thrust, t, names=NAMES, fixed=None):
    """Poses predicted by the foundation's integrator (an independent code path)."""
    kw = dict(fixed or {})
    kw.update(dict(zip(names, z[6:], strict=True)))
    p = PlantParams(kw.pop("mass"), kw.pop("izz"), **kw)
    return integrate_zoh(z[:6], cmd_t, thrust, t, p, max_step=1 / 960)[:, :3]


def _fd_jacobian(z, cmd_t, thrust, t, names=NAMES, fixed=None):
    J = np.zeros((len(t), 3, len(z)))
    for j in range(len(z)):
        h = 1e-6 * max(abs(z[j]), 1e-3 if j >= 6 else 1.0)
        zp, zm = z.copy(), z.copy()
        zp[j] += h
        zm[j] -= h
        J[:, :, j] = (_fd_outputs(zp, cmd_t, thrust, t, names, fixed)
                      - _fd_outputs(zm, cmd_t, thrust, t, names, fixed)) / (2 * h)
    return J


@pytest.mark.parametrize("input_,cmd_rate", [("sine", 50.0), ("translate-rotate", 30.0)])
def test_sensitivities_match_finite_differences(input_, cmd_rate):
    cmd_t, thrust, t = _setup(8.0, cmd_rate, 120.0, input_)
    s0 = np.array([0.1, -0.2, 0.5, 0.03, -0.02, 0.4])
    z = np.concatenate([s0, [1.7, 4.5e-3]])
    x, phi = trajectory_stm(s0, cmd_t, thrust, t, {"mass": 1.7, "izz": 4.5e-3})
    J = _fd_jacobian(z, cmd_t, thrust, t)
    scale = np.abs(J).max(axis=(0, 1))
    np.testing.assert_allclose(phi[:, :3, :] / scale, J / scale, atol=2e-6)
    np.testing.assert_allclose(x[:, :3], _fd_outputs(z, cmd_t, thrust, t), atol=1e-8)
    # Eq. 18: output sensitivities are the first three rows of the state sensitivities
    xs, sx, sy = sensitivities(cmd_t, thrust, t, {"mass": 1.7, "izz": 4.5e-3}, s0=s0)
    np.testing.assert_allclose(sy, sx[:, :3, :])
    np.testing.assert_allclose(sx, phi[:, :, 6:])


def test_sensitivities_with_friction_parameters():
    cmd_t, thrust, t = _setup(5.0)
    names = ("mass", "izz", "ct", "cr", "kb", "ax", "ay")
    vals = [2.0, 3e-3, 0.2, 3e-4, 1e-3, 0.01, -0.02]
    s0 = np.array([0.0, 0.0, 0.2, 0.05, 0.02, 0.3])
    _, phi = trajectory_stm(s0, cmd_t, thrust, t, dict(zip(names, vals, strict=True)), names)
    J = _fd_jacobian(np.concatenate([s0, vals]), cmd_t, thrust, t, names)
    scale = np.abs(J).max(axis=(0, 1))
    np.testing.assert_allclose(phi[:, :3, :] / scale, J / scale, atol=2e-6)


def test_fisher_and_crlb_against_finite_difference_information():
    cmd_t, thrust, t = _setup(10.0)
    params = {"mass": 2.268, "izz": 3.78e-3}
    s0 = np.zeros(6)
    sp, sy = 0.01, math.radians(1.0)
    c = crlb(t, cmd_t, thrust, params, s0=s0, sigma_pos_m=sp, sigma_yaw_rad=sy)
    J = _fd_jacobian(np.concatenate([s0, [2.268, 3.78e-3]]), cmd_t, thrust, t)
    W = np.array([sp**-2, sp**-2, sy**-2])
    F_fd = np.einsum("kin,i,kim->nm", J, W, J)
    d = np.sqrt(np.diag(F_fd))
    np.testing.assert_allclose(c.fisher / np.outer(d, d), F_fd / np.outer(d, d), atol=1e-5)
    # marginal bound (Schur complement) = parameter block of the full inverse
    full_inv = np.linalg.inv(F_fd)
    np.testing.assert_allclose(c.cov, full_inv[6:, 6:], rtol=1e-4)
    np.testing.assert_allclose(c.sigma, np.sqrt(np.diag(full_inv)[6:]), rtol=1e-4)
    assert c.logdet == pytest.approx(np.linalg.slogdet(marginal_information(F_fd))[1], rel=1e-6)
    # marginalising the initial state can only lose information
    assert np.all(c.sigma > 1 / np.sqrt(np.diag(F_fd)[6:]))


def test_chain_matches_sequential_product_and_segments_reproduce_trajectory():
    cmd_t, thrust, t = _setup(3.0, 50.0, 90.0)
    g = make_grid(cmd_t, thrust, t, max_step=0.01)
    assert np.diff(g.events).max() <= 0.01 + 1e-12
    assert set(np.round(cmd_t[1:-1], 12)) <= set(np.round(g.events, 12))
    st = reference_states(np.zeros(6), g, {"mass": 2.0, "izz": 4e-3})
    ends, phi = rk4_stm(st[:-1], g.seg_thrust, np.diff(g.events), {"mass": 2.0, "izz": 4e-3})
    np.testing.assert_allclose(ends, st[1:], atol=1e-12)
    cur = np.eye(8)
    seq = [cur[:6]]
    for k in range(len(phi)):
        cur = phi[k] @ cur
        seq.append(cur[:6])
    seq = np.array(seq)[g.node_pos]
    np.testing.assert_allclose(chain_stm(phi, g.node_pos), seq, rtol=1e-10, atol=1e-12)


def test_fisher_weights_and_noise_scaling():
    cmd_t, thrust, t = _setup(4.0)
    _, phi = trajectory_stm(np.zeros(6), cmd_t, thrust, t, {"mass": 2.0, "izz": 4e-3})
    F1 = fisher_information(phi, 0.01, 0.02)
    F2 = fisher_information(phi, 0.02, 0.04)
    np.testing.assert_allclose(F1, 4 * F2)
    Fw = fisher_information(phi, 0.01, 0.02, weights=np.full(len(t), 0.5))
    np.testing.assert_allclose(Fw, 0.5 * F1)

import numpy as np

from estimator.plant.model import PlantParams, integrate_zoh
from estimator.plant.propagate import rk4_stm, segment_thrust, zoh_segments

RNG = np.random.default_rng(7)
NAMES = ("mass", "izz", "ct", "cr", "kb", "ax", "ay")


def _params(theta):
    return dict(zip(NAMES, theta, strict=True))


def test_stm_matches_finite_differences():
    theta = np.array([1.9, 4.1e-3, 0.2, 1e-3, 2e-3, 0.01, -0.02])
    s0 = np.array([0.1, 0.2, 0.4, 0.05, -0.04, 0.6])
    T = np.array([0.2, 0.05, 0.1, 0.3])
    dt = 0.05
    _, Phi = rk4_stm(s0, T, dt, _params(theta), NAMES, n_sub=4)
    z0 = np.concatenate([s0, theta])
    fd = np.zeros((13, 13))
    for j in range(13):
        h = 1e-6 * max(1.0, abs(z0[j]))
        zp, zm = z0.copy(), z0.copy()
        zp[j] += h
        zm[j] -= h
        sp, _ = rk4_stm(zp[:6], T, dt, _params(zp[6:]), NAMES, n_sub=4)
        sm, _ = rk4_stm(zm[:6], T, dt, _params(zm[6:]), NAMES, n_sub=4)
        fd[:6, j] = (sp - sm) / (2 * h)
    fd[6:, 6:] = np.eye(7)
    np.testing.assert_allclose(Phi, fd, rtol=1e-5, atol=1e-8)


def test_vectorised_segments_match_scalar_integrator():
    # propagating every segment from the reference states reproduces the trajectory
    cmd_t = np.array([0.0, 0.13, 0.5, 0.77, 1.0])
    thrust = RNG.uniform(0, 0.3, (5, 4))
    t_nodes = np.linspace(0, 1.0, 13)
    p = PlantParams(1.5, 3e-3)
    events, idx, pos = zoh_segments(cmd_t, t_nodes)
    assert set(cmd_t[1:-1]) <= set(events)
    ref = integrate_zoh(np.zeros(6), cmd_t, thrust, events, p)
    s_end, Phi = rk4_stm(ref[:-1], segment_thrust(thrust, idx), np.diff(events),
                         {"mass": 1.5, "izz": 3e-3}, n_sub=64)
    np.testing.assert_allclose(s_end, ref[1:], atol=1e-10)
    assert Phi.shape == (len(events) - 1, 8, 8)
    np.testing.assert_array_equal(pos, np.searchsorted(events, t_nodes))

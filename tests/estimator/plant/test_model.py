import numpy as np
import pytest

from estimator.plant.model import (
    PARAM_NAMES,
    PlantParams,
    dynamics,
    integrate_zoh,
    jac_params,
    jac_state,
    wrap_angle,
    wrench,
)

RNG = np.random.default_rng(1)
P_FULL = dict(mass=1.7, izz=4.2e-3, arm=0.05, ct=0.3, cr=2e-3, kb=4e-3, ax=0.01, ay=-0.02,
              cx=0.03, cy=-0.02)  # issue 18: the centre of mass off the tracked origin


def _fd_state(s, T, p, eps=1e-6):
    J = np.zeros((6, 6))
    for j in range(6):
        d = np.zeros(6)
        d[j] = eps
        J[:, j] = (dynamics(s + d, T, **p) - dynamics(s - d, T, **p)) / (2 * eps)
    return J


@pytest.mark.parametrize("params", [dict(mass=2.268, izz=3.78e-3), P_FULL])
def test_state_jacobian_matches_finite_differences(params):
    for _ in range(20):
        s = RNG.normal(size=6) * [1, 1, 3, 0.2, 0.2, 1]
        T = RNG.uniform(0, 0.4, 4)
        J = jac_state(s, T, **params)
        np.testing.assert_allclose(J, _fd_state(s, T, params), rtol=1e-6, atol=1e-7)


def test_param_jacobian_matches_finite_differences():
    names = PARAM_NAMES
    for _ in range(20):
        s = RNG.normal(size=6) * [1, 1, 3, 0.2, 0.2, 1]
        T = RNG.uniform(0, 0.4, 4)
        J = jac_params(s, T, **P_FULL, names=names)
        for j, n in enumerate(names):
            key = n
            h = 1e-7 * max(1.0, abs(P_FULL[key]))
            pp, pm = dict(P_FULL), dict(P_FULL)
            pp[key] += h
            pm[key] -= h
            fd = (dynamics(s, T, **pp) - dynamics(s, T, **pm)) / (2 * h)
            np.testing.assert_allclose(J[:, j], fd, rtol=1e-5, atol=1e-6, err_msg=n)


def test_jacobians_broadcast_over_runs():
    s = RNG.normal(size=(5, 6))
    T = RNG.uniform(0, 0.4, (5, 4))
    m = RNG.uniform(1, 3, 5)
    izz = RNG.uniform(1e-3, 1e-2, 5)
    Jb = jac_state(s, T, m, izz, ct=0.1)
    Pb = jac_params(s, T, m, izz, ct=0.1)
    fb = dynamics(s, T, m, izz, ct=0.1)
    for i in range(5):
        np.testing.assert_allclose(Jb[i], jac_state(s[i], T[i], m[i], izz[i], ct=0.1))
        np.testing.assert_allclose(Pb[i], jac_params(s[i], T[i], m[i], izz[i], ct=0.1))
        np.testing.assert_allclose(fb[i], dynamics(s[i], T[i], m[i], izz[i], ct=0.1))


def test_wrench_geometry():
    # valves 1,2 push +y; 2,3 push +x; 1,3 turn positive
    np.testing.assert_allclose(wrench([1, 1, 0, 0]), [0, np.sqrt(2), 0], atol=1e-15)
    np.testing.assert_allclose(wrench([0, 1, 1, 0]), [np.sqrt(2), 0, 0], atol=1e-15)
    np.testing.assert_allclose(wrench([1, 0, 1, 0]), [0, 0, 0.1], atol=1e-15)


def test_free_motion_keeps_speed_and_yaw_rate():
    s0 = np.array([0.1, -0.2, 0.3, 0.05, -0.03, 0.7])
    t = np.linspace(0, 60, 601)
    states = integrate_zoh(s0, [0.0, 60.0], np.zeros((2, 4)), t, PlantParams(2.0, 4e-3))
    speed = np.hypot(states[:, 3], states[:, 4])
    np.testing.assert_allclose(speed, np.hypot(0.05, 0.03), rtol=1e-10)
    np.testing.assert_allclose(states[:, 5], 0.7, rtol=1e-12)
    np.testing.assert_allclose(states[:, 2], 0.3 + 0.7 * t, rtol=1e-10)
    # lab-frame velocity is constant, so the centre moves on a straight line
    vel0 = np.array([0.05 * np.cos(0.3) + 0.03 * np.sin(0.3), 0.05 * np.sin(0.3) - 0.03 * np.cos(0.3)])
    np.testing.assert_allclose(states[-1, :2], s0[:2] + vel0 * 60, atol=1e-8)


def test_wrap_angle_range():
    a = np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi + 1e-3, 0.0, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    assert w[0] == np.pi

"""The nonlinear bifilar model: small-angle limit, energy, pendulum limit, integrators."""

import math

import numpy as np
import pytest
from scipy.special import ellipk

from calibration.swing.bifilar import (
    Pendulum,
    model_theta,
    simulate_swing,
    swing_accel,
    swing_energy,
)

GEOMS = [Pendulum(0.72, 1.2e-3, 0.10, 1.0), Pendulum(2.268, 3.78e-3, 0.30, 0.5),
         Pendulum(3.0, 0.05, 0.30, 1.5)]


@pytest.mark.parametrize("p", GEOMS)
@pytest.mark.parametrize("rise", [True, False])
def test_small_angle_limit_is_eq19(p, rise):
    """Linearised about rest, th'' = -(m g D^2 / (4 h Izz)) th - c1 th' (Eq. 19's oscillator)."""
    c1, c2 = 0.05, 0.3
    w2 = p.mass_kg * 9.80665 * p.spacing_m**2 / (4 * p.length_m * p.izz_kgm2)  # by hand
    assert p.omega0_sq == pytest.approx(w2)
    assert p.period0_s == pytest.approx(4 * math.pi * math.sqrt(p.length_m * p.izz_kgm2 / (
        p.mass_kg * 9.80665 * p.spacing_m**2)))
    e = 1e-6
    def f(th, om):
        return swing_accel(th, om, w2, c1, c2, p.spacing_m, p.length_m, vertical_ke=rise)
    assert f(0.0, 0.0) == 0.0
    assert (f(e, 0) - f(-e, 0)) / (2 * e) == pytest.approx(-w2, rel=1e-6)
    assert (f(0, e) - f(0, -e)) / (2 * e) == pytest.approx(-c1, rel=1e-5)
    # cubic term: sin/q ~ th - th^3/6 + (D/h)^2 th^3/8 (Jardin & Mueller restoring term)
    th = 0.05
    cubic = (f(th, 0) + w2 * th) / (-w2 * th**3)
    # and the rise KE divides by 1 + mu th^2 (mu = m D^4 / (16 h^2 Izz)): another -mu th^3
    mu = p.mass_kg * p.spacing_m**4 / (16 * p.length_m**2 * p.izz_kgm2) if rise else 0.0
    assert cubic == pytest.approx(-1 / 6 + (p.spacing_m / p.length_m) ** 2 / 8 - mu, rel=0.01)


@pytest.mark.parametrize("p", GEOMS)
def test_tiny_swing_follows_the_linear_solution(p):
    c1 = 0.02
    q = Pendulum(p.mass_kg, p.izz_kgm2, p.spacing_m, p.length_m, c1=c1)
    w0 = math.sqrt(q.omega0_sq)
    t = np.linspace(0, 10 * q.period0_s, 2001)
    a = 1e-5
    th, _ = simulate_swing(q, t, a)
    wd = math.sqrt(w0**2 - c1**2 / 4)
    lin = a * np.exp(-c1 * t / 2) * (np.cos(wd * t) + c1 / (2 * wd) * np.sin(wd * t))
    assert np.max(np.abs(th - lin)) < 1e-4 * a


@pytest.mark.parametrize("p", GEOMS)
def test_undamped_model_conserves_the_lagrangian_energy(p):
    t = np.linspace(0, 8 * p.period0_s, 3001)
    th, om = simulate_swing(p, t, math.radians(40))
    E = swing_energy(th, om, p)
    assert np.ptp(E) < 1e-8 * E[0]
    # without the rise term the model conserves the energy without it
    p2 = Pendulum(p.mass_kg, p.izz_kgm2, p.spacing_m, p.length_m, vertical_ke=False)
    th2, om2 = simulate_swing(p2, t, math.radians(40))
    E2 = swing_energy(th2, om2, p2)
    assert np.ptp(E2) < 1e-8 * E2[0]
    assert np.ptp(swing_energy(th2, om2, p)) > 1e3 * np.ptp(E2)  # and the terms do differ


@pytest.mark.parametrize("amp_deg", [10, 20, 40])
def test_short_strings_ratio_to_zero_is_the_simple_pendulum(amp_deg):
    """D/h -> 0: restoring w0^2 sin th, period 4 K(sin^2(th0/2)) / w0."""
    p = Pendulum(1.0, 1e-3, 1e-3, 10.0, vertical_ke=False)
    w0 = math.sqrt(p.omega0_sq)
    th0 = math.radians(amp_deg)
    T = 4 * ellipk(math.sin(th0 / 2) ** 2) / w0
    t = np.array([0.0, T / 2, T])
    th, om = simulate_swing(p, t, th0)
    np.testing.assert_allclose(th, [th0, -th0, th0], atol=1e-7)
    assert abs(om[1]) < 1e-6 * w0


@pytest.mark.parametrize("p", GEOMS)
def test_fast_fit_integrator_matches_tight_solver(p):
    q = Pendulum(p.mass_kg, p.izz_kgm2, p.spacing_m, p.length_m, c1=0.01, c2=0.05)
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 15 * q.period0_s, 1500))
    t[0] = 0.0
    ref, _ = simulate_swing(q, t, math.radians(20))
    fast = model_theta(t, math.radians(20), 0.0, q.omega0_sq, 0.01, 0.05, q.spacing_m, q.length_m)
    # RK4 at 48 steps per period: phase error ~1e-6 of a cycle per cycle (Izz bias ~1e-6)
    assert np.max(np.abs(fast - ref)) < 1e-4  # rad: 0.006 deg, far below 1 deg mocap noise

"""The test-mass check (calibration.swing.pendulum_check) and the scale-free period of a swing
trace (calibration.swing.pendulum_periods) on simulated data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.swing.pendulum_check import (
    PendulumGeometry,
    check_series,
    izz_from_periods,
    simulate_series,
)
from calibration.swing.pendulum_periods import swing_period
from common.errors import UserError

RADII = np.arange(0.25, 0.751, 0.05)


def test_a_series_returns_the_known_test_mass_within_its_sigma_over_seeds():
    pulls = []
    for seed in range(40):
        izz = simulate_series(0.2345, 0.02094, RADII, 5e-5, seed=seed)
        res = check_series(RADII, izz, np.full_like(RADII, 5e-5), 0.02094)
        pulls.append((res.test_mass_kg - 0.02094) / res.test_mass_sigma_kg)
        assert abs(res.i0_kgm2 - 0.2345) < 4 * res.i0_sigma_kgm2
    pulls = np.array(pulls)
    assert np.mean(np.abs(pulls) < 1) > 0.55 and np.all(np.abs(pulls) < 4)
    assert 0.75 < np.std(pulls) < 1.3  # the sigma is the error's size


def test_a_right_pendulum_passes_and_a_miscalibrated_one_fails():
    izz = simulate_series(0.2345, 0.02094, RADII, 2e-5, seed=1)
    good = check_series(RADII, izz, np.full_like(RADII, 2e-5), 0.02094, 1e-5)
    assert good.verdict == "pass" and not good.reasons and "PASS" in good.verdict_line
    assert good.p_value > 0.01 and good.dof == len(RADII) - 2
    assert good.scale_factor == pytest.approx(1.0, abs=3 * good.scale_factor_sigma)
    bad = check_series(RADII, 0.95 * izz, np.full_like(RADII, 2e-5), 0.02094, 1e-5)  # 5 % scale
    assert bad.verdict == "fail" and "sigma from the known" in bad.reasons[0]
    assert bad.scale_factor == pytest.approx(0.95, abs=0.02)


def test_scatter_beyond_the_sigmas_fails_on_the_chi_square_and_scales_the_sigmas():
    izz = simulate_series(0.2345, 0.02094, RADII, 2e-4, seed=2)  # noise 10x the stated sigma
    res = check_series(RADII, izz, np.full_like(RADII, 2e-5), 0.02094)
    assert res.verdict == "fail" and any("scatter" in r for r in res.reasons)
    assert res.birge_ratio > 3 and res.p_value < 1e-6


def test_radius_uncertainty_enters_as_an_effective_variance():
    izz = simulate_series(0.2345, 0.02094, RADII, 2e-5, seed=3)
    a = check_series(RADII, izz, np.full_like(RADII, 2e-5), 0.02094)
    b = check_series(RADII, izz, np.full_like(RADII, 2e-5), 0.02094,
                     radius_sigma_m=np.full_like(RADII, 2e-3))
    assert b.test_mass_sigma_kg > a.test_mass_sigma_kg and b.chi2 < a.chi2


def test_periods_through_the_geometry_and_a_common_scale_sigma():
    geo = PendulumGeometry(1.0, 0.995, 0.848, 5e-4, 5e-4, 5e-4)
    izz_true = 0.2345 + 0.02094 * RADII**2
    period = np.sqrt(izz_true * 4 * math.pi**2 * 0.995 / ((0.848 + 0.02094) * geo.g_mps2))
    izz, s, rel = izz_from_periods(RADII, period, np.full_like(RADII, 5e-5), geo, 0.02094)
    np.testing.assert_allclose(izz, izz_true, rtol=1e-12)
    assert rel == pytest.approx(math.sqrt(1e-6 + (5e-4 / 0.995) ** 2 + (5e-4 / 0.86894) ** 2))
    res = check_series(RADII, izz, s, 0.02094, scale_rel_sigma=rel)
    assert res.i0_sigma_kgm2 >= rel * res.i0_kgm2 and res.verdict == "pass"


@pytest.mark.parametrize("bad, msg", [
    (dict(radius_m=[0.3, 0.3, 0.3]), "two or more radii"),
    (dict(radius_m=[0.3, 0.4], izz_kgm2=[0.2, 0.21], izz_sigma_kgm2=[1e-5] * 2), "at least 3 swings"),
    (dict(izz_sigma_kgm2=[1e-5, 0.0, 1e-5]), "positive inertia sigma"),
    (dict(izz_kgm2=[0.2, math.nan, 0.2]), "not a finite number"),
])
def test_refusals(bad, msg):
    args = dict(radius_m=[0.3, 0.4, 0.5], izz_kgm2=[0.2, 0.21, 0.22], izz_sigma_kgm2=[1e-5] * 3)
    args.update(bad)
    with pytest.raises(UserError, match=msg):
        check_series(args["radius_m"], args["izz_kgm2"], args["izz_sigma_kgm2"], 0.02)


def _trace(seed: int, period: float, fps: float = 240.0, duration: float = 10.0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration, 1 / fps)
    y = (120 * np.exp(-0.02 * t) * np.sin(2 * math.pi * t / period + rng.uniform(0, 6))
         + 30 * np.exp(-0.05 * t) * np.sin(2 * math.pi * t / 1.99 + rng.uniform(0, 6))  # sway
         + 500 + 0.5 * t + rng.normal(0, 1.5, t.size))
    return t, y


def test_swing_period_recovers_the_period_within_its_sigma_over_seeds():
    pulls = []
    for seed in range(12):
        t, y = _trace(seed, 1.0475)
        p = swing_period(t, y)
        assert p.second_period_s == pytest.approx(1.99, rel=1e-2)
        pulls.append((p.period_s - 1.0475) / p.period_sigma_s)
    assert np.all(np.abs(pulls) < 4) and np.mean(np.abs(pulls) < 2) > 0.8


def test_swing_period_is_scale_free_and_refuses_a_flat_trace():
    t, y = _trace(0, 1.05)
    a, b = swing_period(t, y), swing_period(t, -0.01 * y + 7)
    assert a.period_s == pytest.approx(b.period_s, rel=1e-9)
    with pytest.raises(UserError, match="constant"):
        swing_period(t, np.ones_like(t))
    with pytest.raises(UserError, match="do not increase"):
        swing_period(t[::-1], y)

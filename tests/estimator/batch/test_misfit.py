"""Model misfit said out loud (issue 24, item 7): a run simulated with a 30 ms valve dead
time (the commands shifted before simulating) is flagged by its structured residuals, and
the delay scan finds the delay within its interval with a significant likelihood ratio;
clean runs raise no warning over seeds (false alarms); the calibration flags the same run."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from estimator.batch.delay_scan import batch_delay_scan, profile, shift_commands
from estimator.batch.least_squares import batch_ls
from estimator.batch.misfit import MISFIT_RATIO, RUNS_Z, misfit_warnings, runs_z
from estimator.batch.thrust_calibration.calibrate import calibrate_thrust
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

PLANT = PlantParams(2.268, 3.78e-3)
SIG_YAW = math.radians(1.0)


def _sim(delay_s: float, seed: int, duration_s: float = 30.0):
    cmd_t, duty = phase_sine(duration_s)
    ct, d = shift_commands(cmd_t, duty, delay_s)  # the valves act delay_s late
    s = simulate(ct, d, PLANT, config=SimConfig(seed=seed))
    keep = s.pose_t <= cmd_t[-1]
    return s.pose_t[keep], s.pose[keep], cmd_t, duty


def _fit(pose_t, pose, cmd_t, duty):
    thrust = ThrustTable.default().thrust_n(duty)
    return thrust, batch_ls(pose_t, pose, cmd_t, thrust, names=("mass", "izz"), fixed={},
                            initial={}, sigma_pos_m=0.01, sigma_yaw_rad=SIG_YAW)


def test_runs_test_white_and_structured():
    rng = np.random.default_rng(0)
    assert all(abs(runs_z(rng.normal(size=3000))) < RUNS_Z for _ in range(20))
    assert runs_z(np.sin(np.linspace(0, 20, 3000))) < -RUNS_Z
    assert runs_z(np.ones(10)) == 0.0


def test_clean_runs_raise_no_misfit_warning():
    for seed in (1, 2, 3, 4):
        pose_t, pose, cmd_t, duty = _sim(0.0, seed)
        _, fit = _fit(pose_t, pose, cmd_t, duty)
        assert misfit_warnings(fit.residuals, 0.01, SIG_YAW) == [], seed


def test_misfit_size_warning_names_the_causes():
    rng = np.random.default_rng(1)
    res = rng.normal(size=(500, 3)) * np.array([0.03, 0.01, SIG_YAW])  # x at 3x the noise
    (w,) = misfit_warnings(res, 0.01, SIG_YAW)
    assert "x 3" in w and f"more than {MISFIT_RATIO:g}x" in w
    for cause in ("valve dead time", "shared supply", "damping", "dead or reversed", "--delay-scan"):
        assert cause in w


def test_valve_delay_flagged_and_found_by_the_scan():
    pose_t, pose, cmd_t, duty = _sim(0.030, seed=1)
    thrust, fit = _fit(pose_t, pose, cmd_t, duty)
    w = misfit_warnings(fit.residuals, 0.01, SIG_YAW)
    assert len(w) == 1 and "structured residuals" in w[0] and "yaw z = " in w[0]
    scan = batch_delay_scan(pose_t, pose, cmd_t, thrust, fit, sigma_pos_m=0.01,
                            sigma_yaw_rad=SIG_YAW)
    lo, hi = scan.interval_s
    assert lo <= 0.030 <= hi and hi - lo < 0.005, scan.describe()
    assert abs(scan.best_s - 0.030) < 3 * scan.sigma_s
    assert scan.found and scan.lr > 100 and "valve dead time" in scan.describe()
    # over seeds: the error within 3 sigma (the sigma from the profile's curvature)
    for seed in (2, 3):
        pose_t, pose, cmd_t, duty = _sim(0.030, seed=seed)
        thrust, fit = _fit(pose_t, pose, cmd_t, duty)
        s = batch_delay_scan(pose_t, pose, cmd_t, thrust, fit, sigma_pos_m=0.01,
                             sigma_yaw_rad=SIG_YAW, delays_s=np.linspace(0, 0.06, 7))
        assert abs(s.best_s - 0.030) < 3 * s.sigma_s, (seed, s.describe())


def test_clean_run_scan_finds_no_delay():
    pose_t, pose, cmd_t, duty = _sim(0.0, seed=2)
    thrust, fit = _fit(pose_t, pose, cmd_t, duty)
    scan = batch_delay_scan(pose_t, pose, cmd_t, thrust, fit, sigma_pos_m=0.01,
                            sigma_yaw_rad=SIG_YAW, delays_s=(0.0, 0.01, 0.02, 0.03))
    assert not scan.found and scan.interval_s[0] == 0.0


def test_profile_of_a_parabola():
    scan = profile(lambda d: 100.0 + 1e6 * (d - 0.042) ** 2, np.arange(0, 0.1001, 0.01), 1000, 8)
    assert scan.best_s == pytest.approx(0.042, abs=1e-6)
    assert scan.sigma_s == pytest.approx(0.001, rel=1e-6)
    assert scan.interval_s == pytest.approx((0.042 - 1.96e-3, 0.042 + 1.96e-3), abs=1e-6)
    assert scan.lr == pytest.approx(1e6 * 0.042**2, rel=1e-6)


def test_calibration_flags_the_delayed_run():
    pose_t, pose, cmd_t, duty = _sim(0.030, seed=1)
    r = calibrate_thrust(pose_t, pose, cmd_t, duty, ThrustTable.default(), mass_kg=PLANT.mass_kg,
                         izz_kgm2=None, per="common")
    assert any("structured residuals" in w for w in r.warnings), r.warnings
    assert r.misfit["axes"]["yaw"]["runs_z"] < -RUNS_Z

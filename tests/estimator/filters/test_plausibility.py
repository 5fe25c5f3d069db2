"""Plausibility after the filters (issue 16): residuals far from the stated noise warn,
naming the likely causes; a parameter the run holds no information on is not converged."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.runfolder import Run
from estimator.estimate import estimate_run
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate


def _run(duration=12.0, inp="phase-sine", duty=None, seed=3, mass=1.6, izz=4e-3) -> Run:
    cmd_t, d = make_input(inp, duration, 50.0)
    if duty is not None:
        d = duty(cmd_t, d)
    res = simulate(cmd_t, d, PlantParams(mass, izz),
                   config=SimConfig(noise_pos_m=0.002, noise_yaw_rad=math.radians(0.5), seed=seed))
    return Run(Path("plausibility"), res.cmd_t, res.duty_pct, res.pose_t, res.pose,
               meta={"truth": {"mass_kg": mass, "izz_kgm2": izz}})


def _estimate(run, method="ekf", **kw):
    log: list[str] = []
    kw.setdefault("sigma_pos_m", 0.002)
    kw.setdefault("sigma_yaw_rad", math.radians(0.5))
    est = estimate_run(run, None, method=method, log=log.append, **kw)
    return est, est.to_dict(), log


@pytest.mark.parametrize("method", ["ekf", "ls-ekf"])
def test_a_plausible_run_is_converged_without_warnings(method):
    est, d, log = _estimate(_run(), method, filter_options=None)
    assert est.converged and d["converged"] is True
    assert "warnings" not in d and "message" not in d
    assert not [w for w in log if "warning" in w and "uncertainty" not in w]
    assert 0.5 < d["rms_residual_x_m"] / 0.002 < 1.5


def test_no_thrust_is_not_converged_naming_why():
    run = _run(duty=lambda t, d: np.zeros_like(d))
    est, d, log = _estimate(run)
    assert not est.converged and d["converged"] is False
    assert "mass, izz have no information" in d["message"] and "no thrust" in d["message"]
    assert any("no thrust" in w and w.startswith("tpods: warning:") for w in log)


def test_no_torque_leaves_izz_without_information():
    # the first 7 s of translate-rotate translate only: no torque
    est, d, log = _estimate(_run(duration=6.5, inp="translate-rotate"))
    assert not est.converged
    assert "izz has no information" in d["message"] and "no torque" in d["message"]
    assert "mass:" not in d["message"]


def test_poses_in_millimetres_warn():
    run = _run()
    run.pose[:, :2] *= 1000.0
    est, d, log = _estimate(run)
    assert any("millimetres" in w for w in d.get("warnings", []))
    assert any("millimetres" in w and w.startswith("tpods: warning:") for w in log)


def test_yaw_in_degrees_warns():
    run = _run()
    run.pose[:, 2] = np.degrees(np.unwrap(run.pose[:, 2]))
    est, d, log = _estimate(run)
    assert any("degrees" in w for w in d.get("warnings", []))


def test_stated_noise_far_too_large_warns_for_ls_ekf():
    est, d, log = _estimate(_run(), "ls-ekf", sigma_pos_m=0.05)
    assert any("below the stated noise" in w for w in d.get("warnings", []))

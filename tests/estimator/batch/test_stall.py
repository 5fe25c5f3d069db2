"""A batch fit whose model does not fit (a thruster weaker than its table says) stops on the
relative cost change, not converged, saying so; a fit within the noise runs to ``tol`` as
before (:data:`estimator.batch.least_squares.STALL_RTOL`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from estimator.batch import least_squares as ls
from estimator.batch import ls_problem
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams, integrate_zoh


@pytest.fixture(scope="module")
def weak_thruster_run():
    """20 s of the phase sine on a module whose thruster 3 gives 4 % less than Table 2."""
    cmd_t, duty = phase_sine(20.0)
    d = ThrustTable.default().to_dict()
    d["calibration"] = {"efficiency": [1.0, 1.0, 0.96, 1.0], "source": "test"}
    true = ThrustTable.from_dict(d)
    pose_t = np.arange(1, 20 * 120) / 120.0
    s = integrate_zoh(np.zeros(6), cmd_t, true.thrust_n(duty, clamp=True),
                      np.concatenate([[0.0], pose_t]), PlantParams(2.268, 3.78e-3))[1:]
    rng = np.random.default_rng(0)
    pose = s[:, :3] + rng.normal(0.0, 1.0, (len(pose_t), 3)) * [0.01, 0.01, math.radians(1)]
    return (pose_t, pose, cmd_t, true.thrust_n(duty, clamp=True),
            ThrustTable.default().thrust_n(duty, clamp=True))


def test_a_fit_of_the_wrong_table_stalls_not_converged(weak_thruster_run):
    pose_t, pose, cmd_t, _, table2 = weak_thruster_run
    res = ls.batch_ls(pose_t, pose, cmd_t, table2)
    assert not res.converged
    assert res.message.startswith("not converged: stalled") and "does not fit" in res.message
    # it stopped on STALL_STEPS small relative cost changes in a row, far above the noise
    # (before: on to 32 iterations, 22 steps rejected)
    last = np.asarray(res.cost_history[-ls.STALL_STEPS - 1:])
    assert np.all(-np.diff(last) < ls.STALL_RTOL * last[:-1])
    assert last[-1] > ls.MISFIT_RATIO * 3 * len(pose_t)
    assert res.iterations < 20


def test_a_fit_within_the_noise_is_not_touched(weak_thruster_run, monkeypatch):
    pose_t, pose, cmd_t, true, _ = weak_thruster_run
    res = ls.batch_ls(pose_t, pose, cmd_t, true)
    assert res.converged and res.message == "converged"
    monkeypatch.setattr(ls_problem, "STALL_STEPS", 10**9)  # no stall criterion: the same fit
    ref = ls.batch_ls(pose_t, pose, cmd_t, true)
    np.testing.assert_array_equal(res.z0, ref.z0)
    assert res.iterations == ref.iterations

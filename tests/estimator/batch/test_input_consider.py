"""The joint valve fit's total sigma (issue 24, estimator/batch/input_consider.py): the
vehicle's stated force_sigma_n considered at the joint solution. Its sensitivity is what a
re-fit with one valve's force changed moves the estimate by (to first order); a supply's
drop_sigma is considered only while that drop is not estimated."""

from __future__ import annotations

import dataclasses

import numpy as np

from common.vehicle import Vehicle
from common.vehicle_toml import Supply
from estimator.batch.input_consider import joint_consider
from estimator.batch.input_params import fit_input_params
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate
from tests.estimator.batch.test_input_params import EIGHT, START, TRUTH

NOISE = {"sigma_pos_m": 0.01, "sigma_yaw_rad": np.radians(1.0)}


def _run():
    """``(pose_t, pose, cmd_t, duty)`` of a 20 s pulse-groups run of the 30 ms / 3 % truth."""
    truth = Vehicle.load(EIGHT).with_input_params(TRUTH["delay"], {"main": TRUTH["drop"]})
    cmd_t, duty = make_input("pulse-groups", 20.0, n_channels=8)
    hold_t, thrust = truth.input_profile(cmd_t, duty)
    params = PlantParams(TRUTH["mass"], TRUTH["izz"], cx=TRUTH["cx"], cy=TRUTH["cy"])
    sim = simulate(cmd_t, duty, params, None, SimConfig(seed=2), thrust_n=thrust, thrust_t=hold_t)
    return sim.pose_t, sim.pose, cmd_t, duty


def test_the_considered_shift_is_what_a_refit_with_another_force_gives():
    pose_t, pose, cmd_t, duty = _run()
    model = Vehicle.load(EIGHT)  # force_sigma_n = 0.005 N per valve
    res = fit_input_params(pose_t, pose, model, cmd_t, duty, initial=START, **NOISE)
    c = joint_consider(res, pose, model, cmd_t, duty, ("delay", "drop"), **NOISE)
    assert res.names == ("mass", "izz", "cx", "cy", "delay", "drop")
    assert c.names == tuple(f"T{i}:force" for i in range(1, 9))
    assert np.allclose(np.diag(c.cov_thrust)[6:], (c.sensitivity[6:] ** 2).sum(1) * 0.005**2)
    dc = 0.005
    th = list(model.thrusters)
    th[0] = dataclasses.replace(th[0], force_n=th[0].force_n + dc)
    moved = fit_input_params(pose_t, pose, dataclasses.replace(model, thrusters=tuple(th)),
                             cmd_t, duty, initial=START, **NOISE)
    shift = (moved.z0 - res.z0)[6:]
    predicted = -c.sensitivity[6:, 0] * dc  # S: the sensitivity of the predicted poses' fit
    sigma = res.sigma[6:]  # noise only: a second-order remainder is small against it
    for j, name in enumerate(res.names):
        assert abs(shift[j] - predicted[j]) < 0.15 * abs(predicted[j]) + 0.05 * sigma[j], (
            name, shift, predicted, sigma)
    assert abs(shift[0] / predicted[0] - 1) < 0.15  # the mass moves by ~1 sigma
    res.add_thrust_covariance(c.cov_thrust, c.names)
    assert np.all(res.sigma[6:] > np.sqrt(np.diag(res.cov_noise))[6:])


def test_a_supply_drop_sigma_is_considered_only_while_the_drop_is_not_estimated():
    pose_t, pose, cmd_t, duty = _run()
    v = Vehicle.load(EIGHT)
    v = dataclasses.replace(  # no force_sigma_n; [supplies.main] drop 0 +- 0.01
        v, thrusters=tuple(dataclasses.replace(t, force_sigma_n=None) for t in v.thrusters),
        supplies=(Supply("main", 0.0, 0.01),))
    both = fit_input_params(pose_t, pose, v, cmd_t, duty, initial=START, **NOISE)
    assert "drop" in both.names
    assert joint_consider(both, pose, v, cmd_t, duty, ("delay", "drop"), **NOISE) is None
    delay = fit_input_params(pose_t, pose, v, cmd_t, duty, input_names=("delay",),
                             initial=START, **NOISE)
    c = joint_consider(delay, pose, v, cmd_t, duty, ("delay",), **NOISE)
    assert c is not None and c.names == ("main:drop",)

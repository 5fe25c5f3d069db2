"""The centre of mass off the tracked origin (issue 18: a structure's cx, cy).

- the tracked pose's Jacobian (output.output_jacobian with the transition matrices) equals
  finite differences of the simulated tracked poses, for the initial state, m, Izz, cx, cy;
- batch least squares estimates m, Izz about the centre of mass, cx and cy with sigma within
  10 % of the Cramér-Rao bound and errors within 3.5 sigma, for offsets of 1-5 cm;
- without an offset nothing changes (the effect is not even compiled in).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.batch.crlb import crlb, make_grid, reference_states, trajectory_stm
from estimator.batch.least_squares import batch_ls
from estimator.plant.inputs import make_input
from estimator.plant.model import EVERY_EFFECT, PlantParams, active_effects
from estimator.plant.output import output_jacobian, tracked_pose
from estimator.plant.sim import SimConfig, simulate

NAMES = ("mass", "izz", "cx", "cy")


def test_tracked_pose_jacobian_matches_finite_differences():
    cmd_t, duty = make_input("translate-rotate", 20.0, 50.0, 30.0, 1.0)
    from common.thrust_table import ThrustTable

    thrust = ThrustTable.default().thrust_n(duty)
    t = np.arange(0.0, 20.0, 1 / 30)
    p = dict(mass=1.9, izz=4.5e-3, arm=0.05, ct=0.02, cr=1e-4, cx=0.03, cy=-0.02)
    z0 = np.array([0.1, -0.2, 0.4, 0.01, -0.02, 0.1, 1.9, 4.5e-3, 0.03, -0.02])
    x, phi = trajectory_stm(z0[:6], cmd_t, thrust, t, p, NAMES)
    H = output_jacobian(x, phi, NAMES, p["cx"], p["cy"])

    def poses(z):
        q = dict(p, mass=z[6], izz=z[7], cx=z[8], cy=z[9])
        g = make_grid(cmd_t, thrust, t)
        return tracked_pose(reference_states(z[:6], g, q)[g.node_pos], q["cx"], q["cy"])

    for j in range(len(z0)):
        h = 1e-6 * max(abs(z0[j]), 1e-3)
        zp, zm = z0.copy(), z0.copy()
        zp[j] += h
        zm[j] -= h
        fd = (poses(zp) - poses(zm)) / (2 * h)
        scale = np.max(np.abs(fd)) + 1e-12
        assert np.max(np.abs(fd - H[:, :, j])) < 2e-4 * scale, j


def test_no_offset_compiles_nothing_new():
    assert len(active_effects({"ct": 0.0}, ("mass", "izz"))) == len(EVERY_EFFECT) - 4
    assert active_effects({"cx": 0.02}, ()) == active_effects({}, ("cy",))


@pytest.mark.parametrize("c, inp, seed", [((0.03, 0.0), "translate-rotate", 1),
                                          ((-0.01, 0.02), "phase-sine", 2),
                                          ((0.05, -0.04), "translate-rotate", 3)])
def test_batch_estimates_the_centre_of_mass_efficiently(c, inp, seed):
    truth = PlantParams(2.5, 6e-3, cx=c[0], cy=c[1])
    cmd_t, duty = make_input(inp, 60.0, 50.0, 30.0, 1.0)
    cfg = SimConfig(seed=seed, drop=0.05, noise_pos_m=0.003, noise_yaw_rad=math.radians(0.5))
    sim = simulate(cmd_t, duty, truth, config=cfg)
    res = batch_ls(sim.pose_t, sim.pose, cmd_t, sim.thrust_n, names=NAMES,
                   sigma_pos_m=0.003, sigma_yaw_rad=math.radians(0.5))
    assert res.converged, res.message
    bound = crlb(sim.pose_t, cmd_t, sim.thrust_n, truth.kwargs(), s0=np.zeros(6), names=NAMES,
                 sigma_pos_m=0.003, sigma_yaw_rad=math.radians(0.5))
    true = np.array([2.5, 6e-3, c[0], c[1]])
    sig = res.sigma[6:]
    assert np.all(np.abs(res.z0[6:] - true) < 3.5 * sig), (res.z0[6:], true, sig)
    assert np.all(np.abs(sig / bound.sigma - 1) < 0.10), sig / bound.sigma

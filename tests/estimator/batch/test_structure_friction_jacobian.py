"""issue 18: friction, yaw bias and tilt on a structure (centre of mass off the tracked
origin). The plant's states are the centre of mass's, so viscous friction and tilt act at
it and the rotational drag and the translation-induced torque are about it; the sensitivity
of the tracked poses to the initial state and to every parameter of the friction+tilt model
plus cx, cy (transition matrices and output.output_jacobian, what batch LS and the CRLB use)
equals finite differences of simulated tracked poses."""

from __future__ import annotations

import numpy as np

from common.thrust_table import ThrustTable
from estimator.batch.crlb import make_grid, reference_states, trajectory_stm
from estimator.plant.inputs import make_input
from estimator.plant.output import output_jacobian, tracked_pose

NAMES = ("mass", "izz", "cx", "cy", "ct", "cr", "kb", "ax", "ay")


def test_tracked_pose_jacobian_with_friction_and_tilt_matches_finite_differences():
    cmd_t, duty = make_input("phase-sine", 15.0, 50.0, 20.0, 1.0, n_channels=8)
    from common.structure import Module, Structure

    s = Structure("pair", (Module("a", (-0.22, 0.0), 0.0, ThrustTable.default()),
                           Module("b", (0.22, 0.04), 90.0, ThrustTable.default())))
    thrust = s.virtual_thrust(duty)
    t = np.arange(0.0, 15.0, 1 / 30)
    p = dict(mass=1.7, izz=0.032, arm=0.05, cx=0.012, cy=-0.03, ct=0.2, cr=2e-3, kb=3e-3,
             ax=1e-3, ay=-5e-4)
    z0 = np.array([0.1, -0.2, 0.4, 0.01, -0.02, 0.1, *(p[n] for n in NAMES)])
    x, phi = trajectory_stm(z0[:6], cmd_t, thrust, t, p, NAMES)
    H = output_jacobian(x, phi, NAMES, p["cx"], p["cy"])

    def poses(z):
        q = dict(p, **dict(zip(NAMES, z[6:], strict=True)))
        g = make_grid(cmd_t, thrust, t)
        return tracked_pose(reference_states(z[:6], g, q)[g.node_pos], q["cx"], q["cy"])

    for j in range(len(z0)):
        h = 1e-6 * max(abs(z0[j]), 1e-3)
        zp, zm = z0.copy(), z0.copy()
        zp[j] += h
        zm[j] -= h
        fd = (poses(zp) - poses(zm)) / (2 * h)
        scale = np.max(np.abs(fd)) + 1e-12
        assert scale > 0 and np.max(np.abs(fd - H[:, :, j])) < 2e-4 * scale, j


def test_friction_and_tilt_act_at_the_centre_of_mass():
    """Coasting with no thrust, a structure whose centre of mass is 3 cm off the tracked
    origin: viscous friction and tilt act at the centre of mass, so they never turn it (no
    yaw rate appears), and the centre of mass follows the point-mass law; a yaw rate decays
    by cr/Izz alone, whatever the offset."""
    from estimator.plant.model import PlantParams, integrate_zoh

    p = PlantParams(1.6, 0.03, ct=0.2, cr=2e-3, kb=0.0, ax=1e-3, ay=-5e-4, cx=0.03, cy=-0.02)
    t = np.linspace(0.0, 10.0, 101)
    cmd_t = np.array([0.0, 10.0])
    zero = np.zeros((2, 4))
    s = integrate_zoh([0.0, 0.0, 0.0, 0.1, -0.05, 0.0], cmd_t, zero, t, p)
    assert np.max(np.abs(s[:, 2])) < 1e-15 and np.max(np.abs(s[:, 5])) < 1e-15
    k = p.ct / p.mass_kg  # u' = -k u + ax (psi = 0): u = ax/k + (u0 - ax/k) e^{-kt}
    u = p.ax / k + (0.1 - p.ax / k) * np.exp(-k * t)
    v = p.ay / k + (-0.05 - p.ay / k) * np.exp(-k * t)
    np.testing.assert_allclose(s[:, 3], u, rtol=0, atol=1e-10)
    np.testing.assert_allclose(s[:, 4], v, rtol=0, atol=1e-10)
    # the tracked frame is the centre of mass moved by -c (yaw 0): a rigid shift
    pose = tracked_pose(s, p.cx, p.cy)
    np.testing.assert_allclose(pose[:, :2], s[:, :2] - [p.cx, p.cy], atol=1e-15)
    spin = integrate_zoh([0.0, 0.0, 0.0, 0.0, 0.0, 0.5], cmd_t, zero, t, p)
    np.testing.assert_allclose(spin[:, 5], 0.5 * np.exp(-p.cr / p.izz_kgm2 * t), atol=1e-9)

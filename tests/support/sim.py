"""Simulated runs for filter tests: a run and its poses on the nominal grid."""

from __future__ import annotations

import numpy as np

from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, pose_times, simulate


def sim_run(mass=2.268, izz=3.78e-3, seed=0, duration=20.0, drop=0.0, pose_rate=120.0,
            cmd_rate=50.0, input_name="phase-sine"):
    cmd_t, duty = make_input(input_name, duration, cmd_rate)
    return simulate(cmd_t, duty, PlantParams(mass, izz),
                    config=SimConfig(seed=seed, drop=drop, pose_rate_hz=pose_rate, clamp=True))


def on_grid(res, rate=120.0):
    """Poses of a run with dropped frames placed on the full grid with a mask."""
    t = pose_times(res.cmd_t[0], res.cmd_t[-1], rate)
    mask = np.isin(np.round(t * rate), np.round(res.pose_t * rate))
    pose = np.zeros((len(t), 3))
    pose[mask] = res.pose
    return t, pose, mask

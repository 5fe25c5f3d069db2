"""Simulated vehicle runs for the segment fit's tests, made by the plant's own exact
integrator (:func:`estimator.plant.sim.simulate`), not by the segment fit's RK4."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from common.vehicle import Vehicle
from estimator.plant.inputs import pulse_groups
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

ROOT = Path(__file__).resolve().parents[3]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"


def vehicle(dead: str | None = None, delay_s: float = 0.0) -> Vehicle:
    v = Vehicle.load(EIGHT)
    if dead is not None:
        v = replace(v, thrusters=tuple(replace(t, health="dead") if t.name == dead else t
                                       for t in v.thrusters))
    return v.with_input_params(delay_s=delay_s) if delay_s else v


def sim_run(seed: int, duration_s: float = 60.0, *, dead: str | None = None,
            mass: float = 23.09, izz: float = 0.31, tilt=(0.0, 0.0), friction=(0.0, 0.0, 0.0),
            delay_s: float = 0.0, pose_rate_hz: float = 30.0, noise_pos_m: float = 0.003,
            noise_yaw_deg: float = 0.3):
    """``(pose_t, pose, cmd_t, duty)`` of an 8-valve run under random pulse groups (1-3
    valves open at once, seeded); ``dead`` names
    a thruster that gives no thrust (the estimator is given the healthy vehicle)."""
    v = vehicle(dead, delay_s)
    cmd_t, duty = pulse_groups(duration_s, v.n_channels, seed=seed)
    thrust_t, virtual = v.input_profile(cmd_t, duty)
    ct, cr, kb = friction
    params = PlantParams(mass, izz, ct=ct, cr=cr, kb=kb, ax=tilt[0], ay=tilt[1])
    cfg = SimConfig(pose_rate_hz=pose_rate_hz, noise_pos_m=noise_pos_m,
                    noise_yaw_rad=math.radians(noise_yaw_deg), seed=seed)
    res = simulate(cmd_t, duty, params, None, cfg, thrust_n=virtual, thrust_t=thrust_t)
    return res.pose_t, res.pose, cmd_t, duty

"""Simulated vehicle runs for the segment fit's tests, made by the plant's own exact
integrator (:func:`estimator.plant.disturbed.disturbed_run`), not by the segment fit's RK4."""

from __future__ import annotations

from pathlib import Path

from common.vehicle import Vehicle
from estimator.plant.disturbed import Disturbance, disturbed_run
from estimator.plant.model import PlantParams

ROOT = Path(__file__).resolve().parents[3]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"


def vehicle() -> Vehicle:
    """The 8-valve example vehicle as its file states it (healthy, no dead time)."""
    return Vehicle.load(EIGHT)


def sim_run(seed: int, duration_s: float = 60.0, *, dead: str | None = None,
            stuck: str | None = None,
            mass: float = 23.09, izz: float = 0.31, tilt=(0.0, 0.0), friction=(0.0, 0.0, 0.0),
            delay_s: float = 0.0, disturbance: Disturbance = Disturbance(),
            pose_rate_hz: float = 30.0):
    """``(pose_t, pose, cmd_t, duty)`` of an 8-valve run under random pulse groups (1-3
    valves open at once, seeded); ``dead`` names a thruster that gives no thrust (the
    estimator is given the healthy vehicle)."""
    ct, cr, kb = friction
    params = PlantParams(mass, izz, ct=ct, cr=cr, kb=kb, ax=tilt[0], ay=tilt[1])
    res = disturbed_run(vehicle(), seed, duration_s, params, dead=dead, stuck=stuck, delay_s=delay_s,
                        disturbance=disturbance, pose_rate_hz=pose_rate_hz)
    return res.pose_t, res.pose, res.cmd_t, res.duty_pct

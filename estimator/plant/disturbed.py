"""Simulated vehicle runs with what a real table adds: tilt, drag, a valve dead time, a dead
thruster and slow random disturbance forces (a tether, air currents, a hose), for the tests
and benchmarks of estimators that may leave them out.

The run is integrated exactly by :func:`estimator.plant.sim.simulate` (the plant's own
integrator, not an estimator's); the disturbance is a body-frame wrench, an
Ornstein-Uhlenbeck process held on a 0.1 s grid, added to the vehicle's virtual thrusts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from common.layout import virtual_from_wrench
from common.vehicle import Vehicle
from estimator.plant.inputs import pulse_groups
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, SimResult, simulate

DISTURBANCE_STEP_S = 0.1


@dataclass(frozen=True)
class Disturbance:
    """A body-frame random wrench: standard deviations (N, N, N m) and correlation time, s."""

    force_n: float = 0.0
    moment_nm: float = 0.0
    tau_s: float = 5.0


def with_dead(vehicle: Vehicle, dead: str | None) -> Vehicle:
    """``vehicle`` with thruster ``dead`` marked ``health = "dead"`` (no thrust)."""
    if dead is None:
        return vehicle
    if dead not in [t.name for t in vehicle.thrusters]:
        raise ValueError(f"no thruster {dead!r}")
    return replace(vehicle, thrusters=tuple(replace(t, health="dead") if t.name == dead else t
                                            for t in vehicle.thrusters))


def ou_wrench(t: np.ndarray, d: Disturbance, rng: np.random.Generator) -> np.ndarray:
    """(len(t), 3) an Ornstein-Uhlenbeck wrench sampled at times ``t`` (held between)."""
    out = np.zeros((len(t), 3))
    sd = np.array([d.force_n, d.force_n, d.moment_nm])
    if not np.any(sd):
        return out
    a = math.exp(-DISTURBANCE_STEP_S / d.tau_s)
    x = rng.normal(0.0, 1.0, 3) * sd
    for k in range(len(t)):
        out[k] = x
        x = a * x + math.sqrt(1 - a * a) * rng.normal(0.0, 1.0, 3) * sd
    return out


def disturbed_run(vehicle: Vehicle, seed: int, duration_s: float, params: PlantParams, *,
                  dead: str | None = None, stuck: str | None = None, delay_s: float = 0.0,
                  disturbance: Disturbance = Disturbance(), pose_rate_hz: float = 30.0,
                  noise_pos_m: float = 0.003, noise_yaw_deg: float = 0.3) -> SimResult:
    """A run of ``vehicle`` under random pulse groups (1-3 valves open at once, seeded) with
    the true valve ``delay_s``, thruster ``dead`` giving nothing and ``disturbance``; the
    plant ``params`` carry the tilt and drag; thruster ``stuck`` pushes all the time (stuck
    open; the returned commands are the commanded ones)."""
    v = with_dead(vehicle, dead).with_input_params(delay_s=delay_s)
    cmd_t, duty = pulse_groups(duration_s, v.n_channels, seed=seed)
    real = duty.copy()
    if stuck is not None:
        real[:, [t.name for t in v.thrusters].index(stuck)] = 100.0
    thrust_t, virtual = v.input_profile(cmd_t, real)
    rng = np.random.default_rng(10_000 + seed)
    if disturbance.force_n or disturbance.moment_nm:
        grid = np.arange(cmd_t[0], cmd_t[-1], DISTURBANCE_STEP_S)
        t = np.union1d(thrust_t, grid)
        rows = np.clip(np.searchsorted(thrust_t, t, side="right") - 1, 0, len(thrust_t) - 1)
        dist = ou_wrench(grid, disturbance, rng)
        drow = np.clip(np.searchsorted(grid, t, side="right") - 1, 0, len(grid) - 1)
        virtual = virtual[rows] + virtual_from_wrench(dist[drow], v.arm_m)
        thrust_t = t
    cfg = SimConfig(pose_rate_hz=pose_rate_hz, noise_pos_m=noise_pos_m,
                    noise_yaw_rad=math.radians(noise_yaw_deg), seed=seed)
    res = simulate(cmd_t, real, params, None, cfg, thrust_n=virtual, thrust_t=thrust_t)
    res.duty_pct = duty  # what the valves were commanded, not what they did
    return res

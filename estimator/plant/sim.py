"""Simulator: the TPODS plant under zero-order-hold thruster commands, with mocap noise.

Pure computation in :func:`simulate`; :func:`write_sim_run` stores the result as a
run folder (commands.csv, poses.csv, truth.csv and run.json with the truth).
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import common
from common.errors import UserError
from common.runfolder import write_run
from common.thrust_table import ThrustTable, load_thrust_table
from estimator.plant.model import PlantParams, integrate_zoh, wrap_angle
from estimator.plant.output import tracked_pose


@dataclass
class SimConfig:
    """Measurement settings of a simulated run."""

    pose_rate_hz: float = 120.0
    noise_pos_m: float = 0.01
    noise_yaw_rad: float = math.radians(1.0)
    drop: float = 0.0
    seed: int | None = 0
    initial_state: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    clamp: bool = False


@dataclass
class SimResult:
    """Everything a simulated run holds (SI units).

    Attributes:
        cmd_t, duty_pct, thrust_n: (Nc,), (Nc, 4), (Nc, 4): the held commands.
        thrust_t: the times of ``thrust_n``'s rows when they are not ``cmd_t`` (a vehicle's
            valve timing), else None.
        pose_t: (N,) kept pose times, s.
        pose: (N, 3) measured x, y (m) and yaw (rad, wrapped to (-pi, pi]).
        states: (N, 6) true states at pose_t (yaw continuous).
        params: the true plant.
    """

    cmd_t: np.ndarray
    duty_pct: np.ndarray
    thrust_n: np.ndarray
    pose_t: np.ndarray
    pose: np.ndarray
    states: np.ndarray
    params: PlantParams
    config: SimConfig
    extra: dict[str, Any] = field(default_factory=dict)
    thrust_t: np.ndarray | None = None


def pose_times(t_start: float, t_end: float, rate_hz: float) -> np.ndarray:
    """Nominal mocap frame times from t_start to t_end inclusive, s."""
    if rate_hz <= 0:
        raise UserError(f"pose rate must be positive, got {rate_hz:g} Hz")
    n = int(math.floor((t_end - t_start) * rate_hz + 1e-9))
    return t_start + np.arange(n + 1) / rate_hz


def simulate(cmd_t: np.ndarray, duty_pct: np.ndarray, params: PlantParams,
             table: ThrustTable | None = None, config: SimConfig | None = None,
             thrust_n: np.ndarray | None = None, thrust_t: np.ndarray | None = None) -> SimResult:
    """Simulate a run: exact integration under the held commands, then noisy, thinned poses.

    Args:
        cmd_t: (Nc,) command times, s; the last row ends the run.
        duty_pct: (Nc, 4) duty percent per valve.
        params: true plant.
        table: thrust table mapping duty to thrust (default: the paper's Table 2).
        config: measurement settings.
        thrust_n: optional (Nc, 4) thrusts in N overriding the table.
        thrust_t: the times of ``thrust_n``'s rows when they are not ``cmd_t`` (a vehicle's
            valve dead time and rise, :meth:`common.vehicle.Vehicle.input_profile`); the
            poses still span ``cmd_t``.
    """
    config = config or SimConfig()
    if not 0.0 <= config.drop < 1.0:
        raise UserError(f"drop fraction must lie in [0, 1), got {config.drop:g}")
    if params.mass_kg <= 0 or params.izz_kgm2 <= 0:
        raise UserError("mass and Izz must be positive")
    cmd_t = np.asarray(cmd_t, dtype=float)
    duty_pct = np.asarray(duty_pct, dtype=float)
    if thrust_n is None:
        thrust_n = load_thrust_table(None).thrust_n(duty_pct, config.clamp) if table is None \
            else table.thrust_n(duty_pct, config.clamp)
    t_all = pose_times(cmd_t[0], cmd_t[-1], config.pose_rate_hz)
    hold_t = cmd_t if thrust_t is None else np.asarray(thrust_t, dtype=float)
    states_all = integrate_zoh(np.asarray(config.initial_state, float), hold_t, thrust_n, t_all, params)
    rng = np.random.default_rng(config.seed)
    keep = np.ones(len(t_all), dtype=bool)
    if config.drop > 0:
        keep[1:] = rng.random(len(t_all) - 1) >= config.drop
    n = len(t_all)
    noise = np.column_stack([
        rng.normal(0.0, config.noise_pos_m, n) if config.noise_pos_m > 0 else np.zeros(n),
        rng.normal(0.0, config.noise_pos_m, n) if config.noise_pos_m > 0 else np.zeros(n),
        rng.normal(0.0, config.noise_yaw_rad, n) if config.noise_yaw_rad > 0 else np.zeros(n),
    ])
    # the poses of the TRACKED frame (the states are the centre of mass's; the same without
    # an offset)
    pose = tracked_pose(states_all, params.cx, params.cy) + noise
    pose[:, 2] = wrap_angle(pose[:, 2])
    return SimResult(cmd_t, duty_pct, thrust_n, t_all[keep], pose[keep], states_all[keep],
                     params, config, thrust_t=None if thrust_t is None else hold_t)


def truth_dict(res: SimResult) -> dict[str, Any]:
    p = res.params
    return {
        "mass_kg": p.mass_kg, "izz_kgm2": p.izz_kgm2, "arm_m": p.arm_m,
        "ct": p.ct, "cr": p.cr, "kb": p.kb, "ax": p.ax, "ay": p.ay,
        **({"cx": p.cx, "cy": p.cy} if p.com_offset else {}),
        "initial_state": list(res.config.initial_state),
    }


def write_sim_run(res: SimResult, out: str | Path, input_name: str = "",
                  thrust_table_name: str = "built-in Table 2") -> Path:
    """Write a simulated run folder with its truth (run.json and truth.csv)."""
    c = res.config
    meta = {
        "kind": "simulation",
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "software": f"tpods {common.__version__}",
        "settings": {
            "input": input_name, "duration_s": float(res.cmd_t[-1] - res.cmd_t[0]),
            "pose_rate_hz": c.pose_rate_hz, "noise_pos_m": c.noise_pos_m,
            "noise_yaw_rad": c.noise_yaw_rad, "drop": c.drop, "seed": c.seed,
            "thrust_table": thrust_table_name, "clamp": c.clamp,
        },
        "truth": truth_dict(res),
    }
    path = write_run(out, cmd_t=res.cmd_t, duty_pct=res.duty_pct, pose_t=res.pose_t,
                     pose=res.pose, meta=meta)
    np.savetxt(path / "truth.csv", np.column_stack([res.pose_t, res.states]), delimiter=",",
               header="t,x,y,psi,u,v,r", comments="", fmt="%.12g")
    return path


def summary_lines(res: SimResult) -> list[str]:
    """Human-readable summary of a simulated run."""
    s = res.states
    dur = res.cmd_t[-1] - res.cmd_t[0]
    n_nom = len(pose_times(res.cmd_t[0], res.cmd_t[-1], res.config.pose_rate_hz))
    speed = np.hypot(s[:, 3], s[:, 4])
    return [
        f"duration        {dur:.2f} s, {len(res.cmd_t)} command rows, "
        f"{len(res.pose_t)} poses ({n_nom - len(res.pose_t)} dropped)",
        f"truth           m = {res.params.mass_kg:.4g} kg, Izz = {res.params.izz_kgm2:.4g} kg m^2",
        f"excursion       x {s[:, 0].min():+.3f}..{s[:, 0].max():+.3f} m, "
        f"y {s[:, 1].min():+.3f}..{s[:, 1].max():+.3f} m",
        f"max speed       {speed.max():.3f} m/s, max |r| {np.abs(s[:, 5]).max():.3f} rad/s, "
        f"yaw turned {math.degrees(s[-1, 2] - s[0, 2]):+.1f} deg",
    ]

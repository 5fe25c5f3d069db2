"""The orbit follower: a closed-loop controller tracking a phase-shifted-sine position setpoint.

This is the paper's first (uninformed) input case for Table 3: a PD controller
drives the module along ``x_d = A sin(w t)``, ``y_d = A sin(w t + phase) - A sin(phase)``
(amplitude A = 0.1 m, period 60 s, phase pi/2: a circle of radius A through the
start point) while holding the yaw at its initial value. The logged duty commands
are what the estimators see.

Thrust allocation: the desired body wrench ``(Fx, Fy, Mz)`` is mapped to four
non-negative thrusts by the pseudo-inverse of the geometry matrix plus the null-space
direction ``(1, 1, 1, 1)`` (which adds no force or moment), shifted so the smallest
thrust is zero. Thrusts below half the table's smallest thrust close the valve, the
others are raised to at least that thrust and capped at the largest; duties come from
the inverse of the thrust table for the number of open valves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.thrust_table import GF_TO_N, ThrustTable
from estimator.plant.model import ARM_M, SQRT1_2, PlantParams, integrate_zoh, wrap_angle


def geometry_matrix(arm_m: float = ARM_M) -> np.ndarray:
    """(3, 4) matrix B with ``(Fx, Fy, Mz) = B @ T``."""
    s = SQRT1_2
    return np.array([[-s, s, s, -s], [s, s, -s, -s], [arm_m, -arm_m, arm_m, -arm_m]])


def allocate(wrench_body: np.ndarray, arm_m: float = ARM_M) -> np.ndarray:
    """Non-negative thrusts (4,), N, realising a body wrench (3,) (N, N, N m) exactly."""
    B = geometry_matrix(arm_m)
    t = np.linalg.pinv(B) @ np.asarray(wrench_body, float)
    return t - t.min()


class InverseTable:
    """Duty (percent) giving a wanted per-nozzle thrust, for each number of open valves."""

    def __init__(self, table: ThrustTable, n_grid: int = 801):
        lo, hi = table.duty_range
        self.duty = np.linspace(lo, hi, n_grid)
        self.thrust = {}
        self.coef = {}
        unit = GF_TO_N if table.unit == "gf" else 1.0
        for k in range(1, 5):
            kk = k if k in table.coefficients else table.max_nozzles
            self.coef[k] = np.asarray(table.coefficients[kk], float) * unit
            t = np.zeros((n_grid, 4))
            t[:, :k] = self.duty[:, None]
            self.thrust[k] = table.thrust_n(t)[:, 0]
            if np.any(np.diff(self.thrust[k]) <= 0):
                raise UserError(f"thrust table is not increasing in duty for {kk} open nozzle(s); "
                                "cannot invert it for the controller")

    def t_min(self, k: int) -> float:
        return float(self.thrust[k][0])

    def t_max(self, k: int) -> float:
        return float(self.thrust[k][-1])

    def duties(self, thrust_n: np.ndarray) -> np.ndarray:
        """(4,) duty percent for wanted thrusts (4,), N; 0 = closed."""
        thrust_n = np.asarray(thrust_n, float)
        # the number of open valves depends on the thrusts and changes the table row
        k = int(np.count_nonzero(thrust_n > 0.5 * self.t_min(max(1, np.count_nonzero(thrust_n > 0)))))
        duty = np.zeros(4)
        if k == 0:
            return duty
        tmin = self.t_min(k)
        open_ = thrust_n > 0.5 * tmin
        want = np.clip(thrust_n[open_], tmin, self.t_max(k))
        d = np.interp(want, self.thrust[k], self.duty)
        # polish on the polynomial itself (Newton), the grid only gives the start
        c = self.coef[k]
        dc = np.polynomial.polynomial.polyder(c)
        for _ in range(3):
            f = np.polynomial.polynomial.polyval(d, c) - want
            d = np.clip(d - f / np.polynomial.polynomial.polyval(d, dc), self.duty[0], self.duty[-1])
        duty[open_] = d
        return duty


@dataclass
class OrbitFollower:
    """PD orbit follower (gains per unit of the controller's nominal mass and Izz).

    Attributes:
        amplitude_m, period_s, phase_rad: the setpoint (0.1 m, 60 s, pi/2).
        wn_pos, zeta_pos: position loop natural frequency (rad/s) and damping.
        wn_yaw, zeta_yaw: yaw loop natural frequency (rad/s) and damping.
        mass_kg, izz_kgm2: the controller's nominal plant (the paper's values).
    """

    amplitude_m: float = 0.1
    period_s: float = 60.0
    phase_rad: float = math.pi / 2
    wn_pos: float = 0.5
    zeta_pos: float = 1.0
    wn_yaw: float = 1.0
    zeta_yaw: float = 1.0
    mass_kg: float = PAPER_MASS_KG
    izz_kgm2: float = PAPER_IZZ_KGM2
    arm_m: float = ARM_M

    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (2,), velocity (2,), acceleration (2,) of the setpoint at ``t``, lab frame."""
        w = 2 * math.pi / self.period_s
        a, ph = self.amplitude_m, self.phase_rad
        pos = np.array([a * math.sin(w * t), a * math.sin(w * t + ph) - a * math.sin(ph)])
        vel = np.array([a * w * math.cos(w * t), a * w * math.cos(w * t + ph)])
        acc = np.array([-a * w * w * math.sin(w * t), -a * w * w * math.sin(w * t + ph)])
        return pos, vel, acc

    def wrench(self, t: float, state: np.ndarray, origin: np.ndarray, psi_ref: float) -> np.ndarray:
        """Desired body wrench (Fx, Fy, Mz) for the state (6,) at time ``t``."""
        x, y, psi, u, v, r = state
        c, s = math.cos(psi), math.sin(psi)
        vel = np.array([u * c - v * s, u * s + v * c])
        pos_d, vel_d, acc_d = self.setpoint(t)
        e = pos_d + origin - np.array([x, y])
        ed = vel_d - vel
        acc = acc_d + self.wn_pos**2 * e + 2 * self.zeta_pos * self.wn_pos * ed
        f_lab = self.mass_kg * acc
        fx = c * f_lab[0] + s * f_lab[1]
        fy = -s * f_lab[0] + c * f_lab[1]
        mz = self.izz_kgm2 * (self.wn_yaw**2 * wrap_angle(psi_ref - psi)
                              - 2 * self.zeta_yaw * self.wn_yaw * r)
        return np.array([fx, fy, float(mz)])


def run_orbit_follower(duration_s: float, plant: PlantParams, table: ThrustTable,
                       controller: OrbitFollower | None = None, cmd_rate_hz: float = 10.0,
                       initial_state=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)):
    """Close the loop on the true plant and log the commands.

    The controller sees the true state at each command time (a perfect state
    estimate); the commands it sends are held until the next command time.

    Returns:
        ``(cmd_t (Nc,), duty_pct (Nc, 4), states (Nc, 6))``; the last command row
        closes every valve at ``duration_s``.
    """
    if duration_s <= 0 or cmd_rate_hz <= 0:
        raise UserError("duration and command rate must be positive")
    ctl = controller or OrbitFollower()
    inv = InverseTable(table)
    n = int(math.floor(duration_s * cmd_rate_hz + 1e-9))
    t = np.arange(n) / cmd_rate_hz
    t = t[t < duration_s - 1e-12]
    state = np.asarray(initial_state, float)
    origin = state[:2].copy()
    psi_ref = float(state[2])
    duties = np.zeros((len(t) + 1, 4))
    states = np.zeros((len(t) + 1, 6))
    for j, tj in enumerate(t):
        states[j] = state
        w = ctl.wrench(float(tj), state, origin, psi_ref)
        duties[j] = inv.duties(allocate(w, ctl.arm_m))
        thrust = table.thrust_n(duties[j][None, :])
        t_next = t[j + 1] if j + 1 < len(t) else duration_s
        state = integrate_zoh(state, np.array([tj, t_next]), np.vstack([thrust, thrust]),
                              np.array([tj, t_next]), plant)[-1]
    states[-1] = state
    return np.append(t, duration_s), duties, states

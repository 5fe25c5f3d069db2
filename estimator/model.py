"""Planar rigid-body plant of a TPODS module on an air table.

State ``s = (x, y, psi, u, v, r)``: lab-frame position (m) and yaw (rad), body-frame
velocities (m/s) and yaw rate (rad/s). Inputs: the four thruster forces
``T = (T1, T2, T3, T4)`` in newtons. Parameters: mass (kg), Izz (kg m^2), moment arm
d (m), viscous friction ``ct`` (N s/m) and ``cr`` (N m s/rad), translation-induced
yaw torque ``kb`` (N m s/m) and a constant lab-frame tilt acceleration ``(ax, ay)``
(m/s^2).

Kinematics are the physically consistent form (the paper's Eqs. 1-2 omit the
rotation from body to lab frame)::

    xdot = u cos(psi) - v sin(psi)        ydot = u sin(psi) + v cos(psi)
    psidot = r
    udot = Fx/m + r v + ( ax cos psi + ay sin psi)
    vdot = Fy/m - r u + (-ax sin psi + ay cos psi)
    rdot = Mz/Izz
    Fx = (T2 + T3 - T1 - T4)/sqrt(2) - ct u
    Fy = (T1 + T2 - T3 - T4)/sqrt(2) - ct v
    Mz = d (T1 + T3 - T2 - T4) - cr r + kb sqrt(u^2 + v^2)

All array functions broadcast over leading dimensions: ``s`` has shape (..., 6),
``thrust_n`` (..., 4) and every parameter is a scalar or an array broadcastable
to the leading shape. This lets the Monte Carlo propagate many runs at once.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

STATE_NAMES = ("x", "y", "psi", "u", "v", "r")
PARAM_NAMES = ("mass", "izz", "ct", "cr", "kb", "ax", "ay")
"""Parameters that :func:`jac_params` can differentiate with respect to."""

ARM_M = 0.05
"""Nominal moment arm of the TPODS thrusters, metres."""

SQRT1_2 = math.sqrt(0.5)


@dataclass(frozen=True)
class PlantParams:
    """Physical parameters of the plant (SI units)."""

    mass_kg: float
    izz_kgm2: float
    arm_m: float = ARM_M
    ct: float = 0.0
    cr: float = 0.0
    kb: float = 0.0
    ax: float = 0.0
    ay: float = 0.0

    def kwargs(self) -> dict[str, float]:
        """Keyword arguments for the array functions of this module."""
        d = asdict(self)
        return {"mass": d.pop("mass_kg"), "izz": d.pop("izz_kgm2"), "arm": d.pop("arm_m"), **d}

    @property
    def has_friction(self) -> bool:
        return any(v != 0.0 for v in (self.ct, self.cr, self.kb, self.ax, self.ay))


def wrench(thrust_n: np.ndarray, arm: float = ARM_M) -> np.ndarray:
    """Thruster-only body force and moment ``(Fx, Fy, Mz)``, shape (..., 3), N and N m."""
    t = np.asarray(thrust_n, dtype=float)
    t1, t2, t3, t4 = t[..., 0], t[..., 1], t[..., 2], t[..., 3]
    fx = (t2 + t3 - t1 - t4) * SQRT1_2
    fy = (t1 + t2 - t3 - t4) * SQRT1_2
    mz = arm * (t1 + t3 - t2 - t4)
    return np.stack([fx, fy, mz], axis=-1)


def dynamics(s, thrust_n, mass, izz, arm=ARM_M, ct=0.0, cr=0.0, kb=0.0, ax=0.0, ay=0.0):
    """State derivative ``sdot``, shape (..., 6)."""
    s = np.asarray(s, dtype=float)
    w = wrench(thrust_n, arm)
    psi, u, v, r = s[..., 2], s[..., 3], s[..., 4], s[..., 5]
    c, sn = np.cos(psi), np.sin(psi)
    speed = np.hypot(u, v)
    out = np.empty(np.broadcast_shapes(s.shape, w.shape[:-1] + (6,)))
    out[..., 0] = u * c - v * sn
    out[..., 1] = u * sn + v * c
    out[..., 2] = r
    out[..., 3] = (w[..., 0] - ct * u) / mass + r * v + ax * c + ay * sn
    out[..., 4] = (w[..., 1] - ct * v) / mass - r * u - ax * sn + ay * c
    out[..., 5] = (w[..., 2] - cr * r + kb * speed) / izz
    return out


def jac_state(s, thrust_n, mass, izz, arm=ARM_M, ct=0.0, cr=0.0, kb=0.0, ax=0.0, ay=0.0):
    """Analytic ``df/ds``, shape (..., 6, 6).

    The ``kb*sqrt(u^2+v^2)`` term is not differentiable at zero speed; its
    derivative is taken as 0 there (the one-sided limits average to 0).
    """
    s = np.asarray(s, dtype=float)
    lead = np.broadcast_shapes(s.shape[:-1], np.shape(thrust_n)[:-1], np.shape(mass),
                               np.shape(izz))
    psi, u, v, r = s[..., 2], s[..., 3], s[..., 4], s[..., 5]
    c, sn = np.cos(psi), np.sin(psi)
    speed = np.hypot(u, v)
    safe = np.where(speed > 0, speed, 1.0)
    du_speed = np.where(speed > 0, u / safe, 0.0)
    dv_speed = np.where(speed > 0, v / safe, 0.0)
    J = np.zeros(lead + (6, 6))
    J[..., 0, 2] = -u * sn - v * c
    J[..., 0, 3] = c
    J[..., 0, 4] = -sn
    J[..., 1, 2] = u * c - v * sn
    J[..., 1, 3] = sn
    J[..., 1, 4] = c
    J[..., 2, 5] = 1.0
    J[..., 3, 2] = -ax * sn + ay * c
    J[..., 3, 3] = -ct / mass
    J[..., 3, 4] = r
    J[..., 3, 5] = v
    J[..., 4, 2] = -ax * c - ay * sn
    J[..., 4, 3] = -r
    J[..., 4, 4] = -ct / mass
    J[..., 4, 5] = -u
    J[..., 5, 3] = kb * du_speed / izz
    J[..., 5, 4] = kb * dv_speed / izz
    J[..., 5, 5] = -cr / izz
    return J


def jac_params(s, thrust_n, mass, izz, arm=ARM_M, ct=0.0, cr=0.0, kb=0.0, ax=0.0, ay=0.0,
               names: tuple[str, ...] = ("mass", "izz")):
    """Analytic ``df/dtheta`` for the parameters ``names`` (from PARAM_NAMES), shape (..., 6, p)."""
    s = np.asarray(s, dtype=float)
    w = wrench(thrust_n, arm)
    lead = np.broadcast_shapes(s.shape[:-1], w.shape[:-1], np.shape(mass), np.shape(izz))
    psi, u, v, r = s[..., 2], s[..., 3], s[..., 4], s[..., 5]
    c, sn = np.cos(psi), np.sin(psi)
    speed = np.hypot(u, v)
    J = np.zeros(lead + (6, len(names)))
    for j, name in enumerate(names):
        if name == "mass":
            J[..., 3, j] = -(w[..., 0] - ct * u) / mass**2
            J[..., 4, j] = -(w[..., 1] - ct * v) / mass**2
        elif name == "izz":
            J[..., 5, j] = -(w[..., 2] - cr * r + kb * speed) / izz**2
        elif name == "ct":
            J[..., 3, j] = -u / mass
            J[..., 4, j] = -v / mass
        elif name == "cr":
            J[..., 5, j] = -r / izz
        elif name == "kb":
            J[..., 5, j] = speed / izz
        elif name == "ax":
            J[..., 3, j] = c
            J[..., 4, j] = -sn
        elif name == "ay":
            J[..., 3, j] = sn
            J[..., 4, j] = c
        else:
            raise ValueError(f"unknown parameter {name!r}; choose from {PARAM_NAMES}")
    return J


# --------------------------------------------------------------------------------------
# Fast scalar path and the exact zero-order-hold integrator used by the simulator.


def _rhs_scalar(x, y, psi, u, v, r, fx, fy, mz, m, izz, ct, cr, kb, ax, ay):
    c = math.cos(psi)
    sn = math.sin(psi)
    return (
        u * c - v * sn,
        u * sn + v * c,
        r,
        (fx - ct * u) / m + r * v + ax * c + ay * sn,
        (fy - ct * v) / m - r * u - ax * sn + ay * c,
        (mz - cr * r + kb * math.hypot(u, v)) / izz,
    )


def _rk4_hold(state, dt, n_sub, fx, fy, mz, m, izz, ct, cr, kb, ax, ay):
    """Advance a 6-tuple by ``dt`` seconds in ``n_sub`` RK4 steps under a constant wrench."""
    h = dt / n_sub
    h2 = 0.5 * h
    x, y, psi, u, v, r = state
    for _ in range(n_sub):
        k1 = _rhs_scalar(x, y, psi, u, v, r, fx, fy, mz, m, izz, ct, cr, kb, ax, ay)
        k2 = _rhs_scalar(x + h2 * k1[0], y + h2 * k1[1], psi + h2 * k1[2], u + h2 * k1[3],
                         v + h2 * k1[4], r + h2 * k1[5], fx, fy, mz, m, izz, ct, cr, kb, ax, ay)
        k3 = _rhs_scalar(x + h2 * k2[0], y + h2 * k2[1], psi + h2 * k2[2], u + h2 * k2[3],
                         v + h2 * k2[4], r + h2 * k2[5], fx, fy, mz, m, izz, ct, cr, kb, ax, ay)
        k4 = _rhs_scalar(x + h * k3[0], y + h * k3[1], psi + h * k3[2], u + h * k3[3],
                         v + h * k3[4], r + h * k3[5], fx, fy, mz, m, izz, ct, cr, kb, ax, ay)
        h6 = h / 6.0
        x += h6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        y += h6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        psi += h6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        u += h6 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3])
        v += h6 * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4])
        r += h6 * (k1[5] + 2 * k2[5] + 2 * k3[5] + k4[5])
    return (x, y, psi, u, v, r)


def integrate_zoh(s0, cmd_t, thrust_n, t_out, params: PlantParams, max_step: float = 1 / 480):
    """Integrate the plant under zero-order-hold thrusts, never stepping across a switch.

    Args:
        s0: initial state (6,) at ``t_out[0]``.
        cmd_t: (Nc,) increasing switch times, s; row j of ``thrust_n`` holds on
            ``[cmd_t[j], cmd_t[j+1])``; before ``cmd_t[0]`` thrust is zero.
        thrust_n: (Nc, 4) thruster forces, N.
        t_out: (N,) non-decreasing output times, s.
        params: plant parameters.
        max_step: largest RK4 step, s. The default gives < 1e-9 m error over
            120 s for the TPODS accelerations.

    Returns:
        (N, 6) states at ``t_out``; psi is continuous (not wrapped).
    """
    from estimator.propagate import segment_thrust, zoh_segments

    events, cmd_idx, out_pos = zoh_segments(cmd_t, t_out)
    w = wrench(segment_thrust(thrust_n, cmd_idx), params.arm_m).tolist()
    p = (params.mass_kg, params.izz_kgm2, params.ct, params.cr, params.kb, params.ax, params.ay)
    dts = np.diff(events)
    nsub = np.maximum(1, np.ceil(dts / max_step - 1e-9)).astype(int)
    states = np.empty((len(events), 6))
    state = tuple(float(a) for a in s0)
    states[0] = state
    for i in range(len(dts)):
        if dts[i] > 0:
            wi = w[i]
            state = _rk4_hold(state, dts[i], int(nsub[i]), wi[0], wi[1], wi[2], *p)
        states[i + 1] = state
    return states[out_pos]


def wrap_angle(a):
    """Wrap angles to (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    w = np.mod(a + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)

"""The nonlinear large-angle model of a bifilar pendulum: equations, energy, simulation.

Geometry: strings of length ``h`` (m), attached ``D`` (m) apart on the body and
directly above at the top, the body's centre of mass midway between them. Angles
in radians, times in seconds, SI throughout.

The model: with q = sqrt(1 - (D/h)^2 (1 - cos th) / 2), w0^2 = m g D^2 / (4 h Izz)
and mu = w0^2 D^2 / (4 g h) = m D^4 / (16 h^2 Izz),

    (1 + mu s^2/q^2) th'' = -w0^2 s/q - mu (s/q^2) (cos th + (D/h)^2 s^2 / (4 q^2)) th'^2
                            - c1 th' - c2 |th'| th'          (s = sin th)

``vertical_ke=False`` drops the mu terms (Jardin & Mueller's form). The small-angle
limit is th'' = -w0^2 th - c1 th', i.e. Equation 19 with T = 2 pi / w0.
:func:`simulate_swing` integrates it tightly (for emulated swings),
:func:`model_theta` fast (fixed-step RK4, for the fit in :mod:`calibration.swing.bifilar_fit`),
:func:`model_state` the same with the rate th' (for gyro traces, :mod:`calibration.swing.trace_fit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.integrate import solve_ivp

from calibration.swing.bifilar_eq19 import G_STANDARD


@dataclass(frozen=True)
class Pendulum:
    """A bifilar pendulum: the body (mass, Izz) and the suspension geometry.

    Damping per unit inertia: ``c1`` viscous (1/s), ``c2`` quadratic (1/rad); the
    torques are K1 = c1 Izz (N m s) and K2 = c2 Izz (N m s^2).
    """

    mass_kg: float
    izz_kgm2: float
    spacing_m: float
    length_m: float
    c1: float = 0.0
    c2: float = 0.0
    g: float = G_STANDARD
    vertical_ke: bool = True

    @property
    def omega0_sq(self) -> float:
        """Small-angle w0^2 = m g D^2 / (4 h Izz), rad^2/s^2."""
        return self.mass_kg * self.g * self.spacing_m**2 / (4.0 * self.length_m * self.izz_kgm2)

    @property
    def period0_s(self) -> float:
        """Small-angle undamped period (Equation 19 inverted), s."""
        return 2.0 * math.pi / math.sqrt(self.omega0_sq)


def _coeffs(omega0_sq: float, spacing_m: float, length_m: float, g: float, vertical_ke: bool):
    r2 = (spacing_m / length_m) ** 2
    mu = omega0_sq * spacing_m**2 / (4.0 * g * length_m) if vertical_ke else 0.0
    return r2, mu


def swing_accel(theta, omega, omega0_sq: float, c1: float, c2: float, spacing_m: float,
                length_m: float, g: float = G_STANDARD, vertical_ke: bool = True):
    """Angular acceleration th'' (rad/s^2) of the bifilar model (broadcasts over arrays)."""
    r2, mu = _coeffs(omega0_sq, spacing_m, length_m, g, vertical_ke)
    th = np.asarray(theta, float)
    om = np.asarray(omega, float)
    s, c = np.sin(th), np.cos(th)
    q2 = 1.0 - 0.5 * r2 * (1.0 - c)
    if np.any(q2 <= 0):
        raise ValueError("the strings cannot reach: (D/h)^2 (1 - cos th)/2 >= 1")
    q = np.sqrt(q2)
    num = (omega0_sq * s / q + mu * s / q2 * (c + 0.25 * r2 * s * s / q2) * om * om
           + c1 * om + c2 * np.abs(om) * om)
    return -num / (1.0 + mu * s * s / q2)


def swing_energy(theta, omega, p: Pendulum):
    """Mechanical energy (J) of the undamped model: rotation + rise of the body."""
    th = np.asarray(theta, float)
    D, h = p.spacing_m, p.length_m
    S = np.sqrt(h * h - D * D * np.sin(th / 2) ** 2)
    z = h - S
    dz = D * D * np.sin(th) / (4.0 * S)
    ke = 0.5 * (p.izz_kgm2 + (p.mass_kg * dz * dz if p.vertical_ke else 0.0)) * np.asarray(omega) ** 2
    return ke + p.mass_kg * p.g * z


def simulate_swing(p: Pendulum, t_s, theta0_rad: float, omega0_rad_s: float = 0.0,
                   rtol: float = 1e-11, atol: float = 1e-13) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the model tightly (DOP853) from t_s[0]; returns theta, omega at t_s, (N,)."""
    t = np.asarray(t_s, float)
    w2 = p.omega0_sq

    def f(_t, y):
        return [y[1], float(swing_accel(y[0], y[1], w2, p.c1, p.c2, p.spacing_m, p.length_m, p.g,
                                        p.vertical_ke))]

    sol = solve_ivp(f, (t[0], t[-1]), [theta0_rad, omega0_rad_s], t_eval=t, method="DOP853",
                    rtol=rtol, atol=atol)
    if not sol.success:  # pragma: no cover - the model is smooth
        raise RuntimeError(sol.message)
    return sol.y[0], sol.y[1]


def simulate_trace(p: Pendulum, *, release_deg: float = 20.0, duration_s: float = 30.0,
                   rate_hz: float = 120.0, noise_deg: float = 1.0, drop: float = 0.0,
                   yaw_offset_rad: float = 0.0, seed: int | None = 0, wrap: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A mocap yaw trace of a swing released from rest at ``release_deg``.

    Returns (t, psi): kept frame times (s) and yaw (rad) = offset + theta + white noise
    of ``noise_deg`` sigma, wrapped to (-pi, pi] if ``wrap``; a fraction ``drop`` of the
    frames is removed at random (the first is kept).
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    theta, _ = simulate_swing(p, t, math.radians(release_deg))
    psi = yaw_offset_rad + theta + rng.normal(0.0, math.radians(noise_deg), n)
    keep = rng.random(n) >= drop
    keep[0] = True
    t, psi = t[keep], psi[keep]
    if wrap:
        psi = np.angle(np.exp(1j * psi))
    return t, psi


# Fast integrator for the fit: fixed-step RK4 on a uniform grid in plain floats, then
# cubic Hermite interpolation (theta, theta') at the sample times.


# The loop is compiled once per form (with and without the mu terms) with the acceleration
# written out at each of its four uses: a Python call per RK4 stage costs about a sixth of
# the fit (the fit integrates hundreds of times). Same operations in the same order as
# the plain function.
_ACC = """\
{i}s = sin({x})
{i}c = cos({x})
{i}q2 = 1.0 - hr2 * (1.0 - c)
{i}if q2 <= 0.0:
{i}    raise FloatingPointError
{i}num = w2 * s / sqrt(q2) + c1 * {v} + c2 * abs({v}) * {v}
"""
_ACC_MU = """\
{i}num += mu * s / q2 * (c + qr2 * s * s / q2) * {v} * {v}
{i}{out} = -num / (1.0 + mu * s * s / q2)
"""
_ACC_PLAIN = "{i}{out} = -num\n"


def _acc_src(x: str, v: str, out: str, mu: bool, i: str = "        ") -> str:
    """Source of ``out = th''(x, v)`` (theta, rate) at indentation ``i``."""
    return _ACC.format(i=i, x=x, v=v) + (_ACC_MU if mu else _ACC_PLAIN).format(i=i, v=v, out=out)


@cache
def _rk4_loop(mu: bool):
    src = ("def f(th, om, dt, n, w2, c1, c2, r2, mu):\n"
           "    hr2 = 0.5 * r2\n    qr2 = 0.25 * r2\n"
           + _acc_src("th", "om", "a", mu, "    ")
           + "    ths, oms, acs = [th], [om], [a]\n    h2, h6 = 0.5 * dt, dt / 6.0\n"
           "    for _ in range(n):\n        k2x = om + h2 * a\n"
           + _acc_src("th + h2 * om", "k2x", "k2v", mu)
           + "        k3x = om + h2 * k2v\n"
           + _acc_src("th + h2 * k2x", "k3x", "k3v", mu)
           + "        k4x = om + dt * k3v\n"
           + _acc_src("th + dt * k3x", "k4x", "k4v", mu)
           + "        th += h6 * (om + 2 * k2x + 2 * k3x + k4x)\n"
           "        om += h6 * (a + 2 * k2v + 2 * k3v + k4v)\n"
           + _acc_src("th", "om", "a", mu)
           + "        ths.append(th)\n        oms.append(om)\n        acs.append(a)\n"
           "    return ths, oms, acs\n")
    ns = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
    exec(compile(src, "<bifilar rk4>", "exec"), ns)  # noqa: S102 -- code built from _ACC
    return ns["f"]


def _rk4_grid(th: float, om: float, dt: float, n: int, w2: float, c1: float, c2: float,
              r2: float, mu: float) -> tuple[list[float], list[float], list[float]]:
    """``n`` RK4 steps of ``dt`` from ``(th, om)``: theta, its rate and acceleration at every
    node (the equation of the module doc; FloatingPointError where the strings go slack)."""
    return _rk4_loop(bool(mu))(th, om, dt, n, w2, c1, c2, r2, mu)


def _hermite(t: np.ndarray, t0: float, dt: float, y: np.ndarray, dy: np.ndarray) -> np.ndarray:
    u = (t - t0) / dt
    i = np.clip(np.floor(u).astype(int), 0, len(y) - 2)
    s = u - i
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * y[i] + (s3 - 2 * s2 + s) * dt * dy[i]
            + (-2 * s3 + 3 * s2) * y[i + 1] + (s3 - s2) * dt * dy[i + 1])


def _grid(t: np.ndarray, theta0: float, omega_init: float, omega0_sq: float, c1: float,
          c2: float, spacing_m: float, length_m: float, g: float, vertical_ke: bool,
          steps_per_period: int) -> tuple[float, list[float], list[float], list[float]]:
    """The RK4 grid over t[0]..t[-1]: (step, theta, th', th'') at its nodes."""
    r2, mu = _coeffs(omega0_sq, spacing_m, length_m, g, vertical_ke)
    span = float(t[-1] - t[0])
    dt_max = 2.0 * math.pi / math.sqrt(max(omega0_sq, 1e-12)) / steps_per_period
    n = max(1, int(math.ceil(span / dt_max)))
    dt = span / n if span > 0 else 1.0
    return (dt, *_rk4_grid(theta0, omega_init, dt, n, omega0_sq, c1, c2, r2, mu))


def model_theta(t: np.ndarray, theta0: float, omega_init: float, omega0_sq: float, c1: float,
                c2: float, spacing_m: float, length_m: float, g: float = G_STANDARD,
                vertical_ke: bool = True, steps_per_period: int = 48) -> np.ndarray:
    """Model theta (rad) at times t (s, increasing, from t[0]) by RK4 + Hermite interpolation."""
    dt, ths, oms, _ = _grid(t, theta0, omega_init, omega0_sq, c1, c2, spacing_m, length_m, g,
                            vertical_ke, steps_per_period)
    return _hermite(np.asarray(t) - t[0], 0.0, dt, np.asarray(ths), np.asarray(oms))


def model_state(t: np.ndarray, theta0: float, omega_init: float, omega0_sq: float, c1: float,
                c2: float, spacing_m: float, length_m: float, g: float = G_STANDARD,
                vertical_ke: bool = True, steps_per_period: int = 48
                ) -> tuple[np.ndarray, np.ndarray]:
    """Model theta (rad) and its rate th' (rad/s) at times t (s, increasing, from t[0]):
    RK4 on a uniform grid, Hermite interpolation of theta (slopes th') and of th' (slopes th'')."""
    dt, ths, oms, acs = _grid(t, theta0, omega_init, omega0_sq, c1, c2, spacing_m, length_m, g,
                              vertical_ke, steps_per_period)
    tt = np.asarray(t) - t[0]
    om = np.asarray(oms)
    return (_hermite(tt, 0.0, dt, np.asarray(ths), om), _hermite(tt, 0.0, dt, om, np.asarray(acs)))
